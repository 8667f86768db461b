"""The ACR baseline loop (Tian et al., reference [1] of paper 000): 2D relative pose and bisection on the scale.

Each adjustment measures the reference camera seen from the current one
(:mod:`fgcd_cli.relocation.acr.pose`: rotation and a *unit* translation
direction), rotates by the measured rotation and translates along the measured
direction by the current step length. The step length is the unknown scale;
ACR finds it by bisection (paper 000 §5.3, "the bisection strategy"): it starts
from a guess and is halved whenever the measured direction reverses between
two successive adjustments (the camera overshot the reference), otherwise kept.
The hand-eye is taken as the identity (ACR needs no calibration; its
convergence holds for hand-eye rotation errors below 45°, Tian et al.).

The stop rule is the loop's image-space rule: the measured AFD (mean
displacement of the matched features, FDF protocol) at most ``stop_afd_px``.
ACR has no metric estimate of the remaining offset, so the rule in mm
(docs/relocation.md, "Stop rules") cannot apply; the log says so. The run also
ends, not converged, when the bisection step falls below ``min_step_m`` or the
adjustment budget is spent; it pauses (AlgorithmError) when the matches give
no trustworthy pose.

The rig is injected (:class:`AcrRig`): grab an image, move the flange through
the guard, a clock of rig time. Nothing here knows the truth: ``evaluate`` is
the simulator's evaluation hook, written into the log only.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from fgcd_cli.errors import AlgorithmError
from fgcd_cli.relocation.acr.pose import AcrPoseConfig, RelativePose, measure_relative_pose
from fgcd_cli.relocation.log import AdjustmentRecord, RelocationResult
from fgcd_cli.relocation.session import SessionTiming
from fgcd_core.se3 import exp_so3, flange_motion, log_so3, make_pose, rotation_angle_rad

__all__ = ["AcrConfig", "AcrRig", "Bisection", "acr_camera_motion", "acr_relocate"]


@dataclass(frozen=True, kw_only=True)
class AcrConfig:
    """Options of the ACR loop.

    Attributes
    ----------
    pose : AcrPoseConfig
        The two-view measurement (model: essential matrix or homography).
    max_adjustments : int
        Step budget. 30: the paper's ACR needed 18.6 adjustments on average where it
        succeeded (Table 3), so rACR's budget of 12 would cut it short.
    initial_step_m : float
        First guess of the translation length, metres: the loop's largest step
        (``RelocationConfig.max_step_m``); bisection only shortens it.
    min_step_m : float
        The run ends when the bisection step falls below this, metres: 0.1 mm, the
        accuracy level ACR reaches on a precision platform (paper 000 §2).
    max_step_rad : float
        Largest rotation of one adjustment (the loop's ``max_step_rad``).
    stop_afd_px : float
        Converged when the measured AFD is at most this (the loop's image-space rule).
    use_handeye : bool
        Move with the rig's calibrated hand-eye instead of the identity (the paper's
        ``ACR_w/X``, paper 000 Table 3); the use case passes it to :func:`acr_relocate`.
    """

    pose: AcrPoseConfig = AcrPoseConfig()
    max_adjustments: int = 30
    initial_step_m: float = 0.05
    min_step_m: float = 1e-4
    max_step_rad: float = math.radians(10.0)
    stop_afd_px: float = 0.5
    use_handeye: bool = False


@dataclass(frozen=True, kw_only=True)
class AcrRig:
    """What the ACR loop needs of a rig (all plain callables; the use case builds them).

    Attributes
    ----------
    grab : callable() -> (H, W) ndarray
        The current undistorted image (grey or colour, float in [0, 1] or uint8).
    move : callable((4, 4) ndarray) -> None
        Move the flange by a motion in the flange frame, through the motion guard.
    timing : SessionTiming
        The run's rig time; ``grab`` and ``move`` add to it, the loop adds its computation.
    say : callable(str), optional
    evaluate : callable() -> dict, optional
        Evaluation hook (simulator only): the truth written into each log record.
    on_record : callable(AdjustmentRecord), optional
    measure : callable(reference, current, K, config=AcrPoseConfig) -> RelativePose
        The two-view measurement (default :func:`measure_relative_pose`; tests inject a perfect one).
    """

    grab: Callable[[], np.ndarray]
    move: Callable[[np.ndarray], None]
    timing: SessionTiming = field(default_factory=SessionTiming)
    say: Callable[[str], None] | None = None
    evaluate: Callable[[], dict] | None = None
    on_record: Callable[[AdjustmentRecord], None] | None = None
    measure: Callable[..., RelativePose] = measure_relative_pose


class Bisection:
    """The step length of ACR's translation: halved whenever the measured direction reverses.

    ``previous`` is the last direction moved along, expressed in the camera frame
    reached after that motion, so that it compares with the next measurement.
    """

    def __init__(self, initial_step_m: float):
        self.step_m = float(initial_step_m)
        self.previous: np.ndarray | None = None
        self.halvings = 0

    def length(self, t_dir: np.ndarray) -> float:
        """The step length along ``t_dir`` (unit, current camera frame), halved on a reversal."""
        if self.previous is not None and float(np.dot(self.previous, t_dir)) < 0.0:
            self.step_m /= 2.0
            self.halvings += 1
        return self.step_m

    def moved(self, M_cam: np.ndarray, t_dir: np.ndarray) -> None:
        """Record the camera motion made (``M_cam``, (4, 4), in the old camera frame) along ``t_dir``."""
        self.previous = np.asarray(M_cam, dtype=float)[:3, :3].T @ np.asarray(t_dir, dtype=float)


def acr_camera_motion(pose: RelativePose, step_m: float, *, max_step_rad: float) -> np.ndarray:
    """The camera motion of one ACR adjustment, (4, 4), metres, in the current camera frame.

    The measured rotation (clamped to ``max_step_rad`` along its axis) and ``step_m``
    along the measured unit direction.
    """
    phi = log_so3(pose.R_cur_ref)
    angle = float(np.linalg.norm(phi))
    if angle > max_step_rad:
        phi = phi * (max_step_rad / angle)
    return make_pose(exp_so3(phi), step_m * np.asarray(pose.t_dir, dtype=float))


def _record(
    rig: AcrRig, *, iteration: int, stage: str, pose: RelativePose, M_flange: np.ndarray, step_m: float, t_start: float
) -> AdjustmentRecord:
    """One log line: ACR has no metric pose, so ``T_ref_cam`` and ``offset_mm`` are NaN."""
    nan = math.nan
    return AdjustmentRecord(
        iteration=iteration,
        t_wall_s=time.monotonic() - t_start,
        t_session_s=rig.timing.total_s,
        stage=stage,
        g=float(np.linalg.norm(M_flange - np.eye(4))),
        offset_mm=nan,
        offset_deg=math.degrees(rotation_angle_rad(pose.R_cur_ref)) if pose.ok else nan,
        T_ref_cam=np.full((4, 4), nan).tolist(),
        M_flange_commanded=np.asarray(M_flange).tolist(),
        clamped=False,
        vse_status="none",
        vse_points=0,
        alignment_ok=pose.ok,
        alignment_reason=pose.reason,
        scale=nan,
        sigma=nan,
        afd_est_px=pose.measured_afd_px,
        truth=rig.evaluate() if rig.evaluate else None,
        image={
            "matches": pose.matches,
            "inliers": pose.inliers,
            "measured_afd_px": pose.measured_afd_px,
            "t_dir": np.asarray(pose.t_dir).tolist(),
            "step_mm": 1000.0 * step_m,
            "stop_rule": "measured AFD only (ACR has no metric offset estimate)",
        },
    )


def _measure(rig: AcrRig, reference_image: np.ndarray, K: np.ndarray, config: AcrConfig) -> RelativePose:
    """Grab and measure; the computation counts as rig time (the platform stands still)."""
    current = rig.grab()
    t0 = time.monotonic()
    pose = rig.measure(reference_image, current, K, config=config.pose)
    rig.timing.wait_s += time.monotonic() - t0
    return pose


def acr_relocate(
    rig: AcrRig,
    reference_image: np.ndarray,
    K: np.ndarray,
    *,
    T_flange_cam: np.ndarray | None = None,
    config: AcrConfig = AcrConfig(),
) -> RelocationResult:
    """Drive the camera to the view of ``reference_image`` with ACR (module docstring).

    Parameters
    ----------
    rig : AcrRig
    reference_image : (H, W) or (H, W, 3) ndarray
        The one reference image (undistorted).
    K : (3, 3) ndarray
        Intrinsics of the ideal pinhole of both images.
    T_flange_cam : (4, 4) ndarray, optional
        Hand-eye used to turn camera motions into flange motions; ACR proper takes the
        identity (None), ``ACR_w/X`` of the paper's Table 3 passes the calibration.
    config : AcrConfig

    Returns
    -------
    RelocationResult
        Converged when the measured AFD met ``stop_afd_px``; records, rig and platform times.

    Raises
    ------
    AlgorithmError
        No trustworthy relative pose (too few matches or inliers, ambiguous solution): motion paused.
    """
    X = np.eye(4) if T_flange_cam is None else np.asarray(T_flange_cam, dtype=float)
    stage = str(config.pose.model)
    bisection, records, t_start = Bisection(config.initial_step_m), [], time.monotonic()
    result = RelocationResult(
        False, f"not converged after {config.max_adjustments} adjustments", config.max_adjustments
    )
    for iteration in range(1, config.max_adjustments + 1):
        pose = _measure(rig, reference_image, K, config)
        done = pose.ok and pose.measured_afd_px <= config.stop_afd_px
        step_m = 0.0 if (done or not pose.ok) else bisection.length(pose.t_dir)
        M_cam = acr_camera_motion(pose, step_m, max_step_rad=config.max_step_rad) if pose.ok else np.eye(4)
        too_small = pose.ok and not done and step_m < config.min_step_m
        M_flange = np.eye(4) if (done or too_small) else flange_motion(X, M_cam)
        records.append(
            _record(rig, iteration=iteration, stage=stage, pose=pose, M_flange=M_flange, step_m=step_m, t_start=t_start)
        )
        if rig.on_record:
            rig.on_record(records[-1])
        if not pose.ok:
            result.records = records
            raise AlgorithmError(f"ACR paused at adjustment {iteration}: {pose.reason}")
        if done:
            result = RelocationResult(
                True,
                f"measured AFD {pose.measured_afd_px:.2f} px <= {config.stop_afd_px} px "
                f"({pose.inliers} inliers; ACR has no metric offset estimate)",
                iteration,
            )
            break
        if too_small:
            result = RelocationResult(
                False,
                f"bisection step {step_m * 1e3:.3f} mm below {config.min_step_m * 1e3} mm "
                f"with the measured AFD at {pose.measured_afd_px:.2f} px",
                iteration,
            )
            break
        if rig.say:
            rig.say(
                f"ACR adjustment {iteration}: step {step_m * 1e3:.1f} mm, turn "
                f"{math.degrees(rotation_angle_rad(M_cam[:3, :3])):.2f} deg, measured AFD "
                f"{pose.measured_afd_px:.2f} px"
            )
        rig.move(M_flange)
        bisection.moved(M_cam, pose.t_dir)
    result.records = records
    result.wall_s = time.monotonic() - t_start
    result.session_s, result.platform_s = rig.timing.total_s, rig.timing.platform_s
    result.synthetic_s = rig.timing.synthetic_s
    return result
