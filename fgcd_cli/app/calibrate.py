"""Use case: hand-eye calibration on an opened rig, with a board or target-free (rACR §3.2).

One flow for `fgcd calibrate hand-eye`, `fgcd demo` and `fgcd bench calibrate`:
the platform makes the procedure's motions behind its guard, the camera sees a
board (``target``) or the monocular VSE tracks the scene (``target-free``: hand-eye
and map scale, refined on the images of every rest pose; docs/calibration.md, "3. Hand-eye and map scale").
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

from fgcd_cli.app.session import MAX_SCALE_RESIDUAL_MM
from fgcd_cli.calibration.handeye.result import HandEyeResult
from fgcd_cli.calibration.procedure import TargetFreeRun, TargetRun
from fgcd_cli.errors import UserInputError
from fgcd_core.camera import PinholeCamera

__all__ = [
    "HandEyeMode",
    "HandEyePlan",
    "HandEyeRequest",
    "HandEyeRig",
    "HandEyeCalibration",
    "MAX_HANDEYE_RMS_MM",
    "MAX_HANDEYE_REPROJECTION_PX",
    "calibrate_sim_handeye",
    "calibrate_sim_intrinsics",
    "check_handeye_options",
    "handeye_rotation_deg",
    "handeye_unusable",
    "plan_handeye",
    "run_handeye",
    "store_handeye",
]

ProgressCallback = Callable[[int, int, str], None]

#: Rotation about each axis of the target-free exploration, degrees (the CLI's ``--rotation-deg`` default).
TARGET_FREE_ROTATION_DEG = 8.0
#: Rotation about each axis of the board procedure when the target-free default was left as is, degrees.
TARGET_ROTATION_DEG = 15.0


class HandEyeMode(StrEnum):
    """How the camera motion is measured: a ChArUco board, or the VSE (target-free, with the map scale)."""

    TARGET = "target"
    TARGET_FREE = "target-free"


@dataclass(frozen=True, kw_only=True)
class HandEyeRequest:
    """What a hand-eye calibration should do.

    Attributes
    ----------
    mode : HandEyeMode
    translation_mm : float
        Exploration translation (target-free), millimetres.
    rotation_deg : float
        Rotation about each axis, degrees; in ``target`` mode the target-free
        default (:data:`TARGET_FREE_ROTATION_DEG`) stands for the board procedure's
        own (:data:`TARGET_ROTATION_DEG`).
    board_file : Path, optional
        Board sidecar JSON (``target`` mode).
    refine : bool
        Target-free: refine ``X`` on the images and re-estimate the scale.
    """

    mode: HandEyeMode = HandEyeMode.TARGET_FREE
    translation_mm: float = 30.0
    rotation_deg: float = TARGET_FREE_ROTATION_DEG
    board_file: Path | None = None
    refine: bool = True


@dataclass(frozen=True, kw_only=True)
class HandEyeRig:
    """What the hand-eye needs of a rig (:class:`fgcd_cli.app.rig.RigHandles` has it too).

    Attributes
    ----------
    guard : fgcd_core.platform.MotionGuard
    camera_source : object with ``grab()``
    intrinsics : PinholeCamera
        Intrinsics of the frames ``camera_source`` gives (undistorted: the ideal pinhole).
    """

    guard: Any
    camera_source: Any
    intrinsics: PinholeCamera


@dataclass(frozen=True, kw_only=True)
class HandEyeCalibration:
    """Outcome of :func:`run_handeye`.

    Attributes
    ----------
    result : HandEyeResult
        The hand-eye to store (target: the best solver's).
    record : dict
        The JSON form: the result (target: with every solver's), ``skipped_stops``.
    run : TargetFreeRun or TargetRun
        The procedure's samples (target-free: the VSE engine, still tracking).
    """

    result: HandEyeResult
    record: dict
    run: TargetFreeRun | TargetRun


def _monocular_vse(camera: PinholeCamera):
    from fgcd_cli.vse.engine import MonocularVSE

    return MonocularVSE(camera)


def run_handeye(
    rig: Any,
    request: HandEyeRequest | None = None,
    *,
    say: Callable[[str], None] | None = None,
    on_progress: ProgressCallback | None = None,
    vse_factory: Callable[[PinholeCamera], Any] | None = None,
) -> HandEyeCalibration:
    """Run the hand-eye procedure of ``request`` on an opened rig.

    Parameters
    ----------
    rig : HandEyeRig or RigHandles
        ``guard``, ``camera_source``, ``intrinsics``.
    request : HandEyeRequest, optional
        Default: target-free with the default motions.
    say : callable(str), optional
        One line per stop.
    on_progress : callable(done, total, label), optional
        Progress of the motions, then of the refinement (``total <= 0``: length unknown).
    vse_factory : callable(PinholeCamera) -> engine, optional
        The target-free VSE (default :class:`fgcd_cli.vse.MonocularVSE`).

    Returns
    -------
    HandEyeCalibration

    Raises
    ------
    CalibrationError
        Degenerate motions, a VSE that cannot track, a board not seen.
    fgcd_core.platform.PlatformError
        A motion failed or was refused.
    """
    from fgcd_cli.calibration.procedure import TargetFreeRunConfig, TargetRunConfig, run_target, run_target_free

    request = request or HandEyeRequest()
    if request.mode == HandEyeMode.TARGET_FREE:
        run = run_target_free(
            rig.guard,
            rig.camera_source,
            vse_factory or _monocular_vse,
            camera=rig.intrinsics,
            config=TargetFreeRunConfig(
                translation_m=request.translation_mm / 1000, rotation_deg=request.rotation_deg, refine=request.refine
            ),
            progress=say,
            on_progress=on_progress,
        )
        result, record = run.result, run.result.to_dict()
    else:
        from fgcd_cli.calibration.board import load_board_sidecar

        rotation = request.rotation_deg if request.rotation_deg != TARGET_FREE_ROTATION_DEG else TARGET_ROTATION_DEG
        run = run_target(
            rig.guard,
            rig.camera_source,
            load_board_sidecar(request.board_file),
            camera=rig.intrinsics,
            config=TargetRunConfig(rotation_deg=rotation),
            progress=say,
            on_progress=on_progress,
        )
        result, record = run.result.best, run.result.to_dict()
    record["skipped_stops"] = {str(k): v for k, v in run.skipped.items()}
    return HandEyeCalibration(result=result, record=record, run=run)


def calibrate_sim_handeye(
    campaign,
    scenario,
    *,
    say: Callable[[str], None],
    camera: PinholeCamera | None = None,
    on_progress: ProgressCallback | None = None,
) -> dict:
    """Target-free hand-eye + scale on the simulated rig of ``scenario``; stored in the campaign rig.

    Parameters
    ----------
    campaign : Campaign
        Receives ``rig/handeye.json`` (the result's JSON form).
    scenario : SimScenario
        The simulated world.
    say : callable(str)
        Progress lines (the rig's events and one line per stop).
    camera : PinholeCamera, optional
        Calibrated intrinsics (the simulated camera's nominal ones when None).
    on_progress : callable(done, total, label), optional

    Returns
    -------
    dict
        The stored record.
    """
    from fgcd_cli.app.rig import open_sim_rig

    rig = open_sim_rig(scenario, T_flange_cam=None, intrinsics=camera, on_event=say, on_progress=on_progress)
    try:
        calibration = run_handeye(rig.handles, HandEyeRequest(), say=say, on_progress=on_progress)
    finally:
        rig.close()
    record = {
        **calibration.result.to_dict(),
        "mode": str(HandEyeMode.TARGET_FREE),
        "driver": "sim",
        "rig": {"driver": "sim"},
    }
    unusable = handeye_unusable(calibration.result)
    if unusable is not None:  # the demo and the benches keep it, as --accept-residual does, and say so
        say(f"warning: {unusable}; kept for this simulated campaign (`fgcd calibrate hand-eye` refuses it)")
        record["residual_accepted"] = unusable
    campaign.write_rig("handeye", record)
    return record


def calibrate_sim_intrinsics(
    campaign, scenario, *, views: int = 16, say: Callable[[str], None], on_progress: ProgressCallback | None = None
):
    """ChArUco intrinsics of the simulated rig's camera (board views); stored in the campaign rig."""
    from fgcd_cli.app.intrinsics import sim_board_views
    from fgcd_cli.calibration.board import BoardSpec
    from fgcd_cli.calibration.intrinsics import calibrate_intrinsics
    from fgcd_cli.calibration.rig_files import save_intrinsics

    board = BoardSpec(squares_x=9, squares_y=6, square_m=0.025, marker_m=0.018, dictionary="DICT_5X5_100")
    images = sim_board_views(scenario, board, views, on_progress=on_progress)
    if on_progress is not None:
        on_progress(0, 0, "calibrating the intrinsics (ChArUco)")
    result = calibrate_intrinsics(images, board, names=[f"view_{i:02d}" for i in range(views)])
    save_intrinsics(campaign, result)
    say(f"intrinsics: fx {result.camera.fx:.1f} px, RMS {result.rms_px:.3f} px over {result.n_views} views")
    return result.camera


# ----------------------------------------------------------------------------- `fgcd calibrate hand-eye` on a campaign
#: Largest motion-pair residual RMS (mm) of a hand-eye that is stored. Every capture and revisit fits its
#: session's map scale through this hand-eye over the same kind of guarded motions and explores again when
#: that fit leaves more than app.session.MAX_SCALE_RESIDUAL_MM (12 mm, 40 % of the 30 mm exploration): a
#: hand-eye whose own calibration motions leave more would fail that check in every later session
#: (docs/calibration.md, "When a result is refused").
MAX_HANDEYE_RMS_MM = MAX_SCALE_RESIDUAL_MM
#: Largest reprojection RMS (px) of the target-free image refinement that is stored: good runs give
#: 0.2-0.25 px (docs/calibration.md, "Reading the result"); beyond 1 px the stop images disagree with X
#: (blur, a moving scene, wrong intrinsics) by more than the sub-pixel AFD the relocation aims for.
MAX_HANDEYE_REPROJECTION_PX = 1.0


def check_handeye_options(*, mode: str, translation_mm: float, rotation_deg: float) -> None:
    """Refuse a bad mode or motion size before anything is opened or moved (the rig is checked by the plan)."""
    if mode not in tuple(HandEyeMode):
        raise UserInputError(f"unknown mode '{mode}' (target or target-free)")
    if mode == HandEyeMode.TARGET_FREE:
        from fgcd_cli.calibration.motions import exploration_motions

        # refuse bad motion sizes before connecting to a platform
        exploration_motions(translation_m=translation_mm / 1000, rotation_deg=rotation_deg)


def handeye_rotation_deg(T_flange_cam) -> np.ndarray:
    """The rotation vector of a hand-eye ``T_flange_cam`` (4x4), degrees (how it is printed)."""
    from fgcd_core.se3 import log_so3

    return np.degrees(log_so3(np.asarray(T_flange_cam)[:3, :3]))


@dataclass(frozen=True, kw_only=True)
class HandEyePlan:
    """A hand-eye run checked before anything is opened or moved (:func:`plan_handeye`).

    Attributes
    ----------
    rig : fgcd_cli.app.rig_options.EffectiveRig
        Driver, address, baud rate and camera (option > campaign.toml [rig] > default).
    scenario : SimScenario or None
        The simulated world (simulator only): ``--scene``/``--seed``, else the campaign's ``[rig.sim]``.
    intrinsics : IntrinsicsResult or None
        The campaign's calibrated intrinsics (None: the simulated camera's nominal ones).
    request : HandEyeRequest
    """

    rig: Any
    scenario: Any
    intrinsics: Any
    request: HandEyeRequest


def _handeye_world(campaign, rig, *, scene: str | None, seed: int | None):
    """The simulated world of a hand-eye run: the options, else the campaign's ``[rig.sim]`` (UserInputError)."""
    from fgcd_cli.app.scenario import SimScenario, check_scenario
    from fgcd_cli.campaign.records import campaign_world
    from fgcd_drivers.connect import Driver

    if rig.driver != Driver.SIM:
        if scene is not None or seed is not None:
            raise UserInputError(
                f"--scene and --seed choose a simulated world: they need --driver sim, not {rig.driver}"
            )
        return None
    default = SimScenario()
    world = (
        campaign_world(campaign)
        if campaign is not None
        else {"scene": default.scene, "seed": default.seed, "noise": default.noise}
    )
    return check_scenario(
        SimScenario(scene=scene or world["scene"], seed=world["seed"] if seed is None else seed, noise=world["noise"])
    )


def plan_handeye(
    campaign, given, request: HandEyeRequest, *, scene: str | None = None, seed: int | None = None
) -> HandEyePlan:
    """Check a hand-eye run in the order a person fixes it; nothing is opened, moved or written.

    The rig (``given``: :class:`fgcd_cli.app.rig_options.RigOptions`; driver, then its address) -> the mode
    against the driver (no board in the simulator; a board file) -> the world -> the intrinsics (a real camera
    needs calibrated ones) -> the campaign's rig: a hand-eye made on one rig is never stored into a campaign
    of another, whatever ``--driver`` says (docs/calibration.md, "Which rig a hand-eye belongs to").
    """
    from fgcd_cli.app.rig_options import check_campaign_rig, resolve_rig
    from fgcd_cli.calibration.rig_files import load_intrinsics
    from fgcd_drivers.connect import Driver

    rig = resolve_rig(campaign, given)
    if request.mode == HandEyeMode.TARGET and rig.driver == Driver.SIM:
        raise UserInputError("the simulated scenes hold no calibration board: use --mode target-free with --driver sim")
    if request.mode == HandEyeMode.TARGET and request.board_file is None:
        raise UserInputError("--mode target needs --board <sidecar.json> describing the printed board")
    scenario = _handeye_world(campaign, rig, scene=scene, seed=seed)
    intrinsics = load_intrinsics(campaign) if campaign is not None else None
    if intrinsics is None and rig.driver != Driver.SIM:
        where = "this campaign has none" if campaign is not None else "give -c CAMPAIGN"
        raise UserInputError(
            f"hand-eye with a real camera needs calibrated intrinsics ({where}): "
            "run `fgcd calibrate intrinsics --images DIR -c CAMPAIGN` first"
        )
    check_campaign_rig(campaign, rig, what="a hand-eye")
    return HandEyePlan(rig=rig, scenario=scenario, intrinsics=intrinsics, request=request)


def handeye_unusable(result: HandEyeResult) -> str | None:
    """Why a hand-eye is not usable (its residuals beyond :data:`MAX_HANDEYE_RMS_MM` / ``_PX``), or None."""
    import math

    rms = result.rms_mm
    if not math.isfinite(rms) or rms > MAX_HANDEYE_RMS_MM:
        return (
            f"the hand-eye's motion pairs disagree by {rms:.1f} mm RMS, beyond the {MAX_HANDEYE_RMS_MM:.0f} mm "
            f"a session's scale fit accepts"
        )
    px = (result.refinement or {}).get("rms_px")
    if px is not None and (not math.isfinite(px) or px > MAX_HANDEYE_REPROJECTION_PX):
        return (
            f"the hand-eye's image refinement reprojects at {px:.2f} px RMS, beyond "
            f"{MAX_HANDEYE_REPROJECTION_PX:.0f} px (blur, a moving scene or wrong intrinsics)"
        )
    return None


def store_handeye(campaign, plan: HandEyePlan, calibration: HandEyeCalibration, *, accept_residual: bool = False):
    """Store a hand-eye in the campaign rig with the rig that made it; ``(path or None, refusal or None)``.

    Rule: a hand-eye beyond the residual limits is not stored (the caller exits 6) unless
    ``accept_residual``; then it is stored with the reason in ``residual_accepted``.
    """
    from fgcd_cli.calibration.rig_files import save_handeye

    unusable = handeye_unusable(calibration.result)
    if campaign is None or (unusable is not None and not accept_residual):
        return None, unusable
    extra = {
        "mode": str(plan.request.mode),
        "driver": plan.rig.driver,
        "rig": plan.rig.record(),
        "limits": {"rms_mm": MAX_HANDEYE_RMS_MM, "reprojection_px": MAX_HANDEYE_REPROJECTION_PX},
    }
    if unusable is not None:
        extra["residual_accepted"] = unusable
    return save_handeye(campaign, calibration.result, extra=extra), None
