"""``--deterministic``: one option definition for `fgcd demo`, `fgcd relocate` and the benches that relocate.

The parallel rACR loop varies from run to run (docs/relocation.md, "Reproducibility"); with
``--deterministic`` its threads are stepped in a fixed order and the native thread pools pinned to one
thread before the heavy libraries load, so that the same seeds reproduce a figure exactly.
"""

from __future__ import annotations

import typer

__all__ = ["DETERMINISTIC", "deterministic_setup"]

DETERMINISTIC = typer.Option(
    False,
    "--deterministic",
    help="Step the relocation's threads (VSE, alignment, adjustment) in a fixed order and pin native thread "
    "pools to one thread: the same seeds give the same figures (slower; time on the rig counts the steps).",
)


def deterministic_setup(deterministic: bool) -> None:
    """Pin the native thread pools when ``--deterministic`` is given (call before the use case is imported)."""
    if deterministic:
        from fgcd_cli.app.determinism import pin_native_threads

        pin_native_threads()
