"""``fgcd platform check | move | home``: talk to a real platform (GRBL stage, UR arm, a person).

Platform failures (``fgcd_drivers.platform.PlatformError``) propagate to ``main()``,
which prints one line and exits with code 7; a missing ``--port``/``--host`` is
bad input (exit 2). Ctrl-C stops the platform first (the guard trips, and the
platform is told to stop again on the way out) and exits with code 130 with one
line saying whether it was moving; these commands write nothing.
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import typer
from scipy.spatial.transform import Rotation

from fgcd_cli.cli import options as opt
from fgcd_cli.cli.output import confirmer, debug, emit
from fgcd_cli.errors import HardwareError, UserInputError, run_record
from fgcd_drivers.connect import DRIVERS, PlatformSpec, open_platform
from fgcd_drivers.platform import GuardLimits, MotionGuard

app = typer.Typer(help="Check, move and home a motion platform (GRBL stage, UR arm, manual).", no_args_is_help=True)



def _options(timeout_s: float | None) -> tuple[dict, dict]:
    if timeout_s is None:
        return {}, {}
    grbl = dict(answer_timeout_s=timeout_s, banner_timeout_s=timeout_s, open_banner_wait_s=min(timeout_s, 2.0))
    ur = dict(preflight_timeout_s=timeout_s)
    return grbl, ur


def _rig(campaign, driver: str | None, port: str | None, baud: int | None, host: str | None):
    """The platform to open: each value from the option, else the campaign's [rig], else the default (exit 2/3)."""
    from fgcd_cli.app.rig_options import RigOptions, resolve_rig

    if campaign is not None:
        from fgcd_cli.campaign import open_campaign

        campaign = open_campaign(campaign)
    if driver is None and campaign is None:
        raise UserInputError(f"give --driver ({', '.join(d for d in DRIVERS if d != 'sim')}) or -c CAMPAIGN")
    if driver == "sim" or (driver is None and campaign.rig_config.get("driver", "sim") == "sim"):
        raise UserInputError("the sim platform lives in a simulated rig: use 'fgcd sim' commands")
    # Rule: the address a driver needs is an option the user forgot, not a hardware fault.
    return resolve_rig(campaign, RigOptions(driver=driver, port=port, host=host, baud=baud))


@contextmanager
def _opened(rig, timeout_s: float | None):
    if timeout_s is not None and not (math.isfinite(timeout_s) and timeout_s > 0):
        raise UserInputError("--timeout must be a positive number of seconds")
    driver, port, baud, host = rig.driver, rig.port, rig.baud, rig.host
    run_record.no_writes()
    grbl_options, ur_options = _options(timeout_s)
    platform = open_platform(driver, spec=PlatformSpec(port=port, baud=baud, host=host, grbl_options=grbl_options,
                                                       ur_options=ur_options, connect=False))
    try:
        platform.connect()
        run_record.platform_connected(platform.name)
        yield platform
    except KeyboardInterrupt:
        # The guard/driver already stopped a motion; stop again in case Ctrl-C came
        # between two commands. main() prints the line and exits 130.
        platform.stop()
        raise
    finally:
        platform.close()


def _pose_dict(T: np.ndarray) -> dict:
    rotvec = Rotation.from_matrix(T[:3, :3]).as_rotvec()
    return {
        "position_mm": [round(float(v) * 1000.0, 4) for v in T[:3, 3]],
        "rotation_vector_deg": [round(math.degrees(float(v)), 4) for v in rotvec],
        "T_base_flange": T,
    }


def _describe(platform) -> dict:
    describe = getattr(platform, "describe", None)
    return describe() if describe is not None else {"driver": platform.name, "healthy": True}


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
    with _opened(_rig(campaign, driver, port, baud, host), timeout) as platform:
        state = _describe(platform)
        caps = platform.capabilities()
        data = {
            **state,
            "pose": _pose_dict(platform.flange_pose()),
            "dof": caps.dof,
            "controllable": list(caps.controllable),
            "workspace_min_mm": [v * 1000 for v in caps.workspace_min_m],
            "workspace_max_mm": [v * 1000 for v in caps.workspace_max_m],
        }

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
    values = [dx, dy, dz, rx, ry, rz, max_step_mm, max_step_deg, speed_fraction]
    if not all(math.isfinite(v) for v in values):
        raise UserInputError("motion values must be finite numbers")
    if not (0.0 < speed_fraction <= 1.0):
        raise UserInputError("--speed-fraction must be in (0, 1]")
    if max_step_mm <= 0 or max_step_deg <= 0:
        raise UserInputError("--max-step-mm and --max-step-deg must be positive")
    T_flange_delta = np.eye(4)
    T_flange_delta[:3, :3] = Rotation.from_rotvec(np.radians([rx, ry, rz])).as_matrix()
    T_flange_delta[:3, 3] = np.array([dx, dy, dz]) / 1000.0
    limits = GuardLimits(
        max_step_m=max_step_mm / 1000.0, max_step_rad=math.radians(max_step_deg), speed_fraction=speed_fraction
    )
    confirm = confirmer(yes=yes)
    with _opened(_rig(campaign, driver, port, baud, host), timeout) as platform:
        guard = MotionGuard(platform, limits, confirm=confirm)
        debug(f"moving {platform.name} by ({dx:.3f}, {dy:.3f}, {dz:.3f}) mm, ({rx:.3f}, {ry:.3f}, {rz:.3f}) deg")
        with run_record.motion():
            result = guard.move_by(T_flange_delta)
    error_mm = float(np.linalg.norm(result.T_base_flange_reached[:3, 3] - result.T_base_flange_commanded[:3, 3])) * 1000
    data = {
        "driver": platform.name,
        "arrived": True,
        "reached": _pose_dict(result.T_base_flange_reached),
        "target": _pose_dict(result.T_base_flange_target),
        "unreachable": list(result.unreachable),
        "position_error_mm": error_mm,
        "duration_s": result.duration_s,
    }

    def render(console) -> None:
        p = data["reached"]["position_mm"]
        console.print(f"[green]arrived[/green] at {p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f} mm in {result.duration_s:.2f} s")
        if result.unreachable:
            console.print(f"[yellow]not performed[/yellow] (platform lacks these axes): {', '.join(result.unreachable)}")

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
    confirm = confirmer(yes=yes)
    with _opened(_rig(campaign, driver, port, baud, host), timeout) as platform:
        if confirm is not None and not confirm(f"Home '{platform.name}' now? The axes will move to their switches."):
            raise UserInputError("homing not confirmed")
        with run_record.motion():
            platform.home()
        pose = _pose_dict(platform.flange_pose())
    emit({"driver": platform.name, "homed": True, "pose": pose}, as_json=as_json)
