"""Use case: a real motion platform on its own (``fgcd platform check | move | home``).

Which platform (option > campaign.toml ``[rig]`` > default; never the simulator's),
the platform opened and always closed (Ctrl-C stops it again on the way out),
its state and pose, a relative move through the motion guard, the homing cycle.
These write nothing. Also :func:`hardware_error_kind`: which hardware an
exception is a failure of (the one line ``fgcd`` prints for it).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fgcd_cli.errors import UserInputError, run_record

__all__ = [
    "PlatformMove",
    "MoveRequest",
    "hardware_error_kind",
    "home_platform",
    "move_platform",
    "opened_platform",
    "plan_move",
    "platform_rig",
    "platform_state",
    "pose_dict",
]


def hardware_error_kind(exc: BaseException) -> str | None:
    """``"platform"`` or ``"camera"`` when ``exc`` is that hardware's failure (exit 7), else None."""
    try:
        from fgcd_core.platform import PlatformError
        from fgcd_drivers.cameras import CameraError
    except Exception:  # pragma: no cover - drivers always ship with fgcd
        return None
    if isinstance(exc, PlatformError):
        return "platform"
    if isinstance(exc, CameraError):
        return "camera"
    return None


def platform_rig(campaign_dir: Path | None, given):
    """The platform to open: each value from the option, else the campaign's [rig], else the default.

    Parameters
    ----------
    campaign_dir : Path or None
        ``-c CAMPAIGN`` (CampaignError, exit 3, when it is not a campaign).
    given : fgcd_cli.app.rig_options.RigOptions
        ``--driver``, ``--port``, ``--host``, ``--baud`` as given.

    Returns
    -------
    fgcd_cli.app.rig_options.EffectiveRig

    Raises
    ------
    UserInputError
        No driver and no campaign, the simulator (its platform lives in a simulated rig), a missing address.
    """
    from fgcd_cli.app.rig_options import resolve_rig
    from fgcd_drivers.connect import DRIVERS

    campaign = None
    if campaign_dir is not None:
        from fgcd_cli.campaign.store import open_campaign

        campaign = open_campaign(campaign_dir)
    driver = given.driver
    if driver is None and campaign is None:
        raise UserInputError(f"give --driver ({', '.join(d for d in DRIVERS if d != 'sim')}) or -c CAMPAIGN")
    if driver == "sim" or (driver is None and campaign.rig_config.get("driver", "sim") == "sim"):
        raise UserInputError("the sim platform lives in a simulated rig: use 'fgcd sim' commands")
    # Rule: the address a driver needs is an option the user forgot, not a hardware fault.
    return resolve_rig(campaign, given)


def _options(timeout_s: float | None) -> tuple[dict, dict]:
    if timeout_s is None:
        return {}, {}
    grbl = dict(answer_timeout_s=timeout_s, banner_timeout_s=timeout_s, open_banner_wait_s=min(timeout_s, 2.0))
    ur = dict(preflight_timeout_s=timeout_s)
    return grbl, ur


@contextmanager
def opened_platform(rig, timeout_s: float | None) -> Iterator:
    """The platform of ``rig`` connected for the block, and closed after it (stopped again on Ctrl-C).

    Parameters
    ----------
    rig : fgcd_cli.app.rig_options.EffectiveRig
        From :func:`platform_rig`.
    timeout_s : float or None
        Answer / pre-flight timeout in seconds (None: the driver's default).

    Yields
    ------
    fgcd_core.platform.Platform
    """
    from fgcd_drivers.connect import PlatformSpec, open_platform

    if timeout_s is not None and not (math.isfinite(timeout_s) and timeout_s > 0):
        raise UserInputError("--timeout must be a positive number of seconds")
    run_record.no_writes()
    grbl_options, ur_options = _options(timeout_s)
    platform = open_platform(
        rig.driver,
        spec=PlatformSpec(
            port=rig.port, baud=rig.baud, host=rig.host, grbl_options=grbl_options, ur_options=ur_options, connect=False
        ),
    )
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


def pose_dict(T: np.ndarray) -> dict:
    """A flange pose as printed: position in mm, rotation vector in degrees, and the matrix."""
    from scipy.spatial.transform import Rotation

    rotvec = Rotation.from_matrix(T[:3, :3]).as_rotvec()
    return {
        "position_mm": [round(float(v) * 1000.0, 4) for v in T[:3, 3]],
        "rotation_vector_deg": [round(math.degrees(float(v)), 4) for v in rotvec],
        "T_base_flange": T,
    }


def platform_state(platform) -> dict:
    """``fgcd platform check``'s record: the driver's state (``healthy``...), the flange pose, DoF and workspace."""
    describe = getattr(platform, "describe", None)
    state = describe() if describe is not None else {"driver": platform.name, "healthy": True}
    caps = platform.capabilities()
    return {
        **state,
        "pose": pose_dict(platform.flange_pose()),
        "dof": caps.dof,
        "controllable": list(caps.controllable),
        "workspace_min_mm": [v * 1000 for v in caps.workspace_min_m],
        "workspace_max_mm": [v * 1000 for v in caps.workspace_max_m],
    }


@dataclass(frozen=True, kw_only=True)
class MoveRequest:
    """A relative move in the flange frame (``fgcd platform move``).

    Attributes
    ----------
    translation_mm : tuple of 3 float
        ``--dx``, ``--dy``, ``--dz``, mm.
    rotation_deg : tuple of 3 float
        ``--rx``, ``--ry``, ``--rz``: rotation vector in the flange frame, degrees.
    max_step_mm, max_step_deg : float
        The guard's largest translation and rotation.
    speed_fraction : float
        Fraction (0, 1] of the platform's speed.
    """

    translation_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    max_step_mm: float = 50.0
    max_step_deg: float = 10.0
    speed_fraction: float = 0.5


@dataclass(frozen=True, kw_only=True)
class PlatformMove:
    """A checked move (:func:`plan_move`): the flange motion and the guard's limits."""

    request: MoveRequest
    T_flange_delta: np.ndarray
    limits: object


def plan_move(request: MoveRequest) -> PlatformMove:
    """Check a move's values before anything is opened (UserInputError, exit 2)."""
    from scipy.spatial.transform import Rotation

    from fgcd_core.platform import GuardLimits

    r = request
    values = [*r.translation_mm, *r.rotation_deg, r.max_step_mm, r.max_step_deg, r.speed_fraction]
    if not all(math.isfinite(v) for v in values):
        raise UserInputError("motion values must be finite numbers")
    if not (0.0 < r.speed_fraction <= 1.0):
        raise UserInputError("--speed-fraction must be in (0, 1]")
    if r.max_step_mm <= 0 or r.max_step_deg <= 0:
        raise UserInputError("--max-step-mm and --max-step-deg must be positive")
    T_flange_delta = np.eye(4)
    T_flange_delta[:3, :3] = Rotation.from_rotvec(np.radians(list(r.rotation_deg))).as_matrix()
    T_flange_delta[:3, 3] = np.array(r.translation_mm) / 1000.0
    limits = GuardLimits(
        max_step_m=r.max_step_mm / 1000.0, max_step_rad=math.radians(r.max_step_deg), speed_fraction=r.speed_fraction
    )
    return PlatformMove(request=r, T_flange_delta=T_flange_delta, limits=limits)


def move_platform(platform, move: PlatformMove, *, confirm: Callable[[str], bool] | None, say: Callable[[str], None]):
    """Make ``move`` through the motion guard on an opened platform; ``(record, MoveResult)``.

    Parameters
    ----------
    platform : fgcd_core.platform.Platform
        From :func:`opened_platform`.
    move : PlatformMove
    confirm : callable(str) -> bool, or None
        Asked before the motion (None: ``--yes``).
    say : callable(str)
        The debugging line naming the motion.

    Returns
    -------
    tuple of (dict, fgcd_core.platform.MoveResult)
        ``fgcd platform move``'s record and the guard's result.
    """
    from fgcd_core.platform import MotionGuard

    (dx, dy, dz), (rx, ry, rz) = move.request.translation_mm, move.request.rotation_deg
    guard = MotionGuard(platform, move.limits, confirm=confirm)
    say(f"moving {platform.name} by ({dx:.3f}, {dy:.3f}, {dz:.3f}) mm, ({rx:.3f}, {ry:.3f}, {rz:.3f}) deg")
    with run_record.motion():
        result = guard.move_by(move.T_flange_delta)
    error_mm = float(np.linalg.norm(result.T_base_flange_reached[:3, 3] - result.T_base_flange_commanded[:3, 3])) * 1000
    return {
        "driver": platform.name,
        "arrived": True,
        "reached": pose_dict(result.T_base_flange_reached),
        "target": pose_dict(result.T_base_flange_target),
        "unreachable": list(result.unreachable),
        "position_error_mm": error_mm,
        "duration_s": result.duration_s,
    }, result


def home_platform(platform, *, confirm: Callable[[str], bool] | None) -> dict:
    """Run the homing cycle of an opened platform (GRBL ``$H``; clears an alarm); ``fgcd platform home``'s record.

    Raises
    ------
    UserInputError
        ``confirm`` said no.
    """
    if confirm is not None and not confirm(f"Home '{platform.name}' now? The axes will move to their switches."):
        raise UserInputError("homing not confirmed")
    with run_record.motion():
        platform.home()
    return {"driver": platform.name, "homed": True, "pose": pose_dict(platform.flange_pose())}
