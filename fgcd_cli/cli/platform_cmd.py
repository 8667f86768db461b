"""``fgcd platform check | move | home``: talk to a real platform (GRBL stage, UR arm, a person).

Platform failures (``fgcd_core.platform.PlatformError``) propagate to ``main()``,
which prints one line and exits with code 7; a missing ``--port``/``--host`` is
bad input (exit 2). Ctrl-C stops the platform first (the guard trips, and the
platform is told to stop again on the way out) and exits with code 130 with one
line saying whether it was moving; these commands write nothing.
"""

from __future__ import annotations

from pathlib import Path

import typer

from fgcd_cli.cli import options as opt
from fgcd_cli.cli.output import confirmer, debug, emit
from fgcd_cli.errors import HardwareError

app = typer.Typer(help="Check, move and home a motion platform (GRBL stage, UR arm, manual).", no_args_is_help=True)


def _rig(campaign: Path | None, driver: str | None, port: str | None, baud: int | None, host: str | None):
    """The platform to open (:func:`fgcd_cli.app.platform.platform_rig`; exit 2/3)."""
    from fgcd_cli.app.platform import platform_rig
    from fgcd_cli.app.rig_options import RigOptions

    return platform_rig(campaign, RigOptions(driver=driver, port=port, host=host, baud=baud))


CampaignOpt = typer.Option(None, "--campaign", "-c", help="Campaign whose campaign.toml [rig] names the platform.")
DriverOpt = opt.DRIVER
PortOpt = opt.PORT
BaudOpt = opt.BAUD
HostOpt = opt.HOST
TimeoutOpt = typer.Option(None, "--timeout", help="Answer/pre-flight timeout in seconds (driver default if unset).")
JsonOpt = typer.Option(False, "--json", help="Print one JSON object.")


@app.command("check")
def check(
    campaign: Path | None = CampaignOpt,
    driver: str | None = DriverOpt,
    port: str | None = PortOpt,
    baud: int | None = BaudOpt,
    host: str | None = HostOpt,
    timeout: float = TimeoutOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Connect, print the state and the flange pose; exit 0 only when healthy."""
    from fgcd_cli.app.platform import opened_platform, platform_state

    with opened_platform(_rig(campaign, driver, port, baud, host), timeout) as platform:
        data = platform_state(platform)

    def render(console) -> None:
        mark = "[green]healthy[/green]" if data["healthy"] else "[red]NOT healthy[/red]"
        console.print(f"[bold]{platform.name}[/bold]: {mark}")
        for key in ("banner", "greeting", "state", "alarm", "robot_mode", "safety_problem"):
            if data.get(key) is not None:
                console.print(f"  {key}: {data[key]}")
        p = data["pose"]["position_mm"]
        r = data["pose"]["rotation_vector_deg"]
        console.print(f"  flange position: {p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f} mm")
        console.print(f"  flange rotation vector: {r[0]:.3f}, {r[1]:.3f}, {r[2]:.3f} deg")
        console.print(f"  DoF {data['dof']} ({', '.join(data['controllable'])})")

    emit(data, as_json=as_json, render=render)
    if not data["healthy"]:
        reason = data.get("safety_problem") or data.get("state") or "see above"
        raise HardwareError(f"platform '{platform.name}' is connected but not healthy ({reason})")


@app.command("move")
def move(
    campaign: Path | None = CampaignOpt,
    driver: str | None = DriverOpt,
    port: str | None = PortOpt,
    baud: int | None = BaudOpt,
    host: str | None = HostOpt,
    dx: float = typer.Option(0.0, "--dx", help="Translation along flange x, mm."),
    dy: float = typer.Option(0.0, "--dy", help="Translation along flange y, mm."),
    dz: float = typer.Option(0.0, "--dz", help="Translation along flange z, mm."),
    rx: float = typer.Option(0.0, "--rx", help="Rotation vector x component in the flange frame, degrees."),
    ry: float = typer.Option(0.0, "--ry", help="Rotation vector y component, degrees."),
    rz: float = typer.Option(0.0, "--rz", help="Rotation vector z component, degrees."),
    yes: bool = opt.YES,
    max_step_mm: float = typer.Option(50.0, "--max-step-mm", help="Guard: largest translation, mm."),
    max_step_deg: float = typer.Option(10.0, "--max-step-deg", help="Guard: largest rotation, degrees."),
    speed_fraction: float = typer.Option(0.5, "--speed-fraction", help="Fraction (0, 1] of the platform's speed."),
    timeout: float = TimeoutOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Relative move in the flange frame through the motion guard; exit 0 once arrived."""
    from fgcd_cli.app.platform import MoveRequest, move_platform, opened_platform, plan_move

    move = plan_move(
        MoveRequest(
            translation_mm=(dx, dy, dz),
            rotation_deg=(rx, ry, rz),
            max_step_mm=max_step_mm,
            max_step_deg=max_step_deg,
            speed_fraction=speed_fraction,
        )
    )
    confirm = confirmer(yes=yes)
    with opened_platform(_rig(campaign, driver, port, baud, host), timeout) as platform:
        data, result = move_platform(platform, move, confirm=confirm, say=debug)

    def render(console) -> None:
        p = data["reached"]["position_mm"]
        console.print(f"[green]arrived[/green] at {p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f} mm in {result.duration_s:.2f} s")
        if result.unreachable:
            console.print(
                f"[yellow]not performed[/yellow] (platform lacks these axes): {', '.join(result.unreachable)}"
            )

    emit(data, as_json=as_json, render=render)


@app.command("home")
def home(
    campaign: Path | None = CampaignOpt,
    driver: str | None = DriverOpt,
    port: str | None = PortOpt,
    baud: int | None = BaudOpt,
    host: str | None = HostOpt,
    yes: bool = opt.YES,
    timeout: float = TimeoutOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Run the platform's homing cycle (GRBL $H; clears an alarm)."""
    from fgcd_cli.app.platform import home_platform, opened_platform

    confirm = confirmer(yes=yes)
    with opened_platform(_rig(campaign, driver, port, baud, host), timeout) as platform:
        data = home_platform(platform, confirm=confirm)
    emit(data, as_json=as_json)
