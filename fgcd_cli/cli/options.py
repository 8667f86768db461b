"""The options every `fgcd` command spells the same way, and the conventions of its help (one place).

Rule (docs/user-guide.md, "Options every command shares"): one name and one
default rule per concept. The rig: ``--driver/-d``, ``--port``, ``--host``,
``--baud``, ``--camera`` take the explicit option, else the campaign's
``campaign.toml [rig]``, else the default (:mod:`fgcd_cli.app.rig_options`);
``--scene`` the campaign's ``[rig.sim] scene``, else ``stele``; ``--light`` is
the one lighting option (a comma list where several lightings make sense);
``--yes/-y`` answers the first-motion confirmation; ``--campaign/-c``; ``--json``.
"""

from __future__ import annotations

import typer

from fgcd_cli.app.rig_options import DEFAULT_BAUD, DEFAULT_CAMERA, DEFAULT_DRIVER, DEFAULT_SCENE

__all__ = [
    "BAUD",
    "CAMERA",
    "CAMPAIGN",
    "DRIVER",
    "HOST",
    "JSON",
    "PORT",
    "SCENE",
    "YES",
    "install_help_conventions",
    "light_option",
]

DRIVER = typer.Option(
    None,
    "--driver",
    "-d",
    help=f"Platform driver: sim, grbl, ur or manual (default: the campaign's [rig] driver, else {DEFAULT_DRIVER}).",
)
PORT = typer.Option(None, "--port", help="GRBL serial device, e.g. /dev/ttyUSB0 (default: the campaign's [rig] port).")
HOST = typer.Option(
    None, "--host", help="UR controller address, e.g. 192.168.0.10 (default: the campaign's [rig] host)."
)
BAUD = typer.Option(None, "--baud", help=f"GRBL baud rate (default: the campaign's [rig] baud, else {DEFAULT_BAUD}).")
CAMERA = typer.Option(
    None,
    "--camera",
    help=f"OpenCV camera: an index or a device path such as /dev/video2 "
    f"(default: the campaign's [rig] camera, else {DEFAULT_CAMERA}).",
)
SCENE = typer.Option(
    None,
    "--scene",
    help=f"Simulator scene (default: the campaign's [rig.sim] scene, else {DEFAULT_SCENE}; `fgcd sim scenes`).",
)
YES = typer.Option(False, "--yes", "-y", help="Answer the first-motion confirmation (scripts).")
CAMPAIGN = typer.Option(..., "--campaign", "-c", help="Campaign directory.")
JSON = typer.Option(False, "--json", help="Print one JSON object.")


def light_option(default: str | None, help: str):  # noqa: A002 - typer's own keyword
    """The one lighting option, ``--light`` (its help says whether a comma list is taken)."""
    return typer.Option(default, "--light", help=help)


def install_help_conventions() -> None:
    """Two rules of every ``--help``, installed once (``cli/app.py``) for all commands.

    - Help text is plain text: ``[rig.lights]`` prints as written. typer renders
      help as rich markup, where a bracketed word is a style tag and vanishes.
    - A flag shows no value placeholder: typer's rich help prints ``<bool>``
      after ``--yes`` (its plain help does not).
    """
    from rich.markup import escape
    from typer import core, rich_utils

    if getattr(rich_utils, "_fgcd_conventions", False):
        return
    make_rich_text = rich_utils._make_rich_text

    def plain_text(*, text: str, style: str = "", markup_mode):
        return make_rich_text(text=escape(text), style=style, markup_mode=markup_mode)

    display_type_rich = core.TyperOption.display_type_rich

    def no_flag_placeholder(self, ctx):
        if getattr(self, "is_flag", False) and not getattr(self, "count", False):
            return None
        return display_type_rich(self, ctx)

    rich_utils._make_rich_text = plain_text
    core.TyperOption.display_type_rich = no_flag_placeholder
    rich_utils._fgcd_conventions = True
