"""Hand-eye with a calibration target (classical ``AX = XB``), several solvers compared.

The solvers are OpenCV's ``cv2.calibrateHandEye`` (Tsai, Park, Horaud, Andreff,
Daniilidis). Inputs in fgcd's convention: ``T_base_flange`` is OpenCV's
``gripper2base``; the board pose in the camera ``T_cam_target`` (what
``solvePnP`` returns) is OpenCV's ``target2cam``; the output ``cam2gripper`` is
``T_flange_cam``. ``method=`` is passed by keyword: passed positionally OpenCV
silently ignores it and runs Tsai.

Quality measure per sample: the board is fixed in the base frame, so
``T_base_target_i = T_base_flange_i @ X @ T_cam_target_i`` must be the same
for every sample; its spread around the mean is the per-sample residual.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from enum import StrEnum

import cv2
import numpy as np

from fgcd_cli.calibration.errors import CalibrationError
from fgcd_cli.calibration.handeye.linear import pair_residuals
from fgcd_cli.calibration.handeye.result import HandEyeResult, utc_now
from fgcd_cli.calibration.samples import (
    check_rotation_diversity,
    motion_pairs,
    relative_motions,
    rotation_axis_spread_deg,
    validate_poses,
)
from fgcd_cli.errors import UserInputError
from fgcd_core.se3 import log_so3, make_pose, pose_distance, project_to_so3

__all__ = ["TargetHandEyeResult", "TargetSolver", "solve_handeye_target", "OPENCV_METHODS", "target_sample_residuals"]


class TargetSolver(StrEnum):
    """OpenCV's hand-eye solvers by name (the ``method`` of a board hand-eye)."""

    TSAI = "TSAI"
    PARK = "PARK"
    HORAUD = "HORAUD"
    ANDREFF = "ANDREFF"
    DANIILIDIS = "DANIILIDIS"


OPENCV_METHODS: dict[str, int] = {
    TargetSolver.TSAI: cv2.CALIB_HAND_EYE_TSAI,
    TargetSolver.PARK: cv2.CALIB_HAND_EYE_PARK,
    TargetSolver.HORAUD: cv2.CALIB_HAND_EYE_HORAUD,
    TargetSolver.ANDREFF: cv2.CALIB_HAND_EYE_ANDREFF,
    TargetSolver.DANIILIDIS: cv2.CALIB_HAND_EYE_DANIILIDIS,
}
#: Solvers disagreeing by more than this (mm, degrees) mean the motions are too weak.
AGREEMENT_NOTE_MM, AGREEMENT_NOTE_DEG = 5.0, 0.5


@dataclass(frozen=True, kw_only=True)
class TargetHandEyeResult:
    """Hand-eye from board observations: the chosen solution and every solver's.

    Attributes
    ----------
    best : HandEyeResult
        The solver with the smallest RMS per-sample residual (``scale`` is None).
    per_method : dict of str to HandEyeResult
        Every solver that produced a result.
    failed : dict of str to str
        Solvers that failed, with the reason.
    agreement_mm, agreement_deg : float
        Largest difference between any two solvers' ``X``: a spread of several
        millimetres or tenths of degrees means the motions are too weak.
    T_base_target : (4, 4) ndarray
        Board pose in the base frame implied by the best solution (mean over samples).
    """

    best: HandEyeResult
    per_method: dict[str, HandEyeResult]
    failed: dict[str, str]
    agreement_mm: float
    agreement_deg: float
    T_base_target: np.ndarray
    created_utc: str = field(default_factory=utc_now)

    @property
    def T_flange_cam(self) -> np.ndarray:
        """The chosen hand-eye ``X``."""
        return self.best.T_flange_cam

    def to_dict(self) -> dict:
        """JSON-friendly form: the best solution plus the comparison."""
        data = self.best.to_dict()
        data["methods"] = {
            name: {
                "T_flange_cam": np.asarray(r.T_flange_cam).tolist(),
                "rms_mm": r.rms_mm,
                "rms_deg": r.rms_deg,
            }
            for name, r in self.per_method.items()
        }
        data["failed_methods"] = dict(self.failed)
        data["agreement_mm"] = self.agreement_mm
        data["agreement_deg"] = self.agreement_deg
        data["T_base_target"] = np.asarray(self.T_base_target).tolist()
        return data


def _mean_pose(poses: Sequence[np.ndarray]) -> np.ndarray:
    """Chordal mean of rigid poses (rotation: projected mean matrix, translation: mean)."""
    R = project_to_so3(np.mean([T[:3, :3] for T in poses], axis=0))
    return make_pose(R, np.mean([T[:3, 3] for T in poses], axis=0))


def target_sample_residuals(
    T_flange_cam: np.ndarray, T_base_flange: Sequence[np.ndarray], T_cam_target: Sequence[np.ndarray]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Spread of the implied board pose in the base frame.

    Returns
    -------
    residuals_mm, residuals_deg : (N,) ndarray
        Distance of each sample's ``T_base_target_i`` from their mean: mm, degrees.
        The translation is measured at the board origin.
    T_base_target : (4, 4) ndarray
        Their mean.
    """
    X = np.asarray(T_flange_cam, dtype=float)
    implied = [F @ X @ C for F, C in zip(T_base_flange, T_cam_target)]
    mean = _mean_pose(implied)
    dist = np.array([pose_distance(mean, T) for T in implied])
    return dist[:, 0], dist[:, 1], mean


def solve_handeye_target(
    T_base_flange: Sequence[np.ndarray],
    T_cam_target: Sequence[np.ndarray],
    *,
    methods: Sequence[str] = ("TSAI", "PARK", "HORAUD", "ANDREFF", "DANIILIDIS"),
) -> TargetHandEyeResult:
    """Hand-eye ``T_flange_cam`` from flange poses and board poses in the camera.

    Parameters
    ----------
    T_base_flange : sequence of N (4, 4) ndarray
        Reported flange poses, metres.
    T_cam_target : sequence of N (4, 4) ndarray
        Board poses in the camera frame (``solvePnP``), metres.
    methods : sequence of str
        OpenCV solvers to run and compare.

    Returns
    -------
    TargetHandEyeResult
        The solver with the smallest residual, all solvers and their agreement.

    Raises
    ------
    UserInputError
        Mismatched lengths, invalid poses or an unknown method name.
    CalibrationError
        Fewer than 3 samples, degenerate rotations, or every solver failed.
    """
    _check_inputs(T_base_flange, T_cam_target, methods)
    hand = validate_poses(T_base_flange, "flange pose")
    board = validate_poses(T_cam_target, "board pose")
    index_pairs = motion_pairs(len(hand), "all")
    MB = relative_motions(hand, index_pairs)
    # Camera motion between samples from the fixed board: inv(T_cam_i_target) ... = T_cam_i_target inv(T_cam_j_target).
    MA = [board[i] @ np.linalg.inv(board[j]) for i, j in index_pairs]
    rotating = check_rotation_diversity([M[:3, :3] for M in MB])
    common = {
        "n_samples": len(hand),
        "n_pairs": len(index_pairs),
        "pairs": index_pairs,
        "axis_spread_deg": rotation_axis_spread_deg([M[:3, :3] for m, M in zip(rotating, MB) if m]),
        "max_rotation_deg": max(math.degrees(float(np.linalg.norm(log_so3(M[:3, :3])))) for M in MB),
    }
    per_method: dict[str, HandEyeResult] = {}
    failed: dict[str, str] = {}
    for name in methods:
        name = name.upper()
        X = _opencv_solve(hand, board, name, failed)
        if X is None:
            continue
        res_mm, res_deg, _ = target_sample_residuals(X, hand, board)
        pair_mm, pair_deg = pair_residuals(X, MB, MA)
        per_method[name] = HandEyeResult(
            T_flange_cam=X,
            scale=None,
            method=name,
            residuals_mm=pair_mm,
            residuals_deg=pair_deg,
            sample_residuals_mm=res_mm,
            sample_residuals_deg=res_deg,
            **common,
        )
    if not per_method:
        raise CalibrationError("every hand-eye solver failed: " + "; ".join(f"{k}: {v}" for k, v in failed.items()))
    rms = {name: float(np.sqrt(np.mean(np.square(r.sample_residuals_mm)))) for name, r in per_method.items()}
    best_name = min(rms, key=rms.get)
    agreement_mm, agreement_deg = _agreement(per_method)
    best = replace(per_method[best_name], notes=_notes(agreement_mm, agreement_deg, failed))
    _, _, T_base_target = target_sample_residuals(best.T_flange_cam, hand, board)
    return TargetHandEyeResult(
        best=best,
        per_method=per_method,
        failed=failed,
        agreement_mm=agreement_mm,
        agreement_deg=agreement_deg,
        T_base_target=T_base_target,
    )


def _check_inputs(
    T_base_flange: Sequence[np.ndarray], T_cam_target: Sequence[np.ndarray], methods: Sequence[str]
) -> None:
    """Refuse mismatched lengths, fewer than 3 samples and unknown solver names."""
    if len(T_base_flange) != len(T_cam_target):
        raise UserInputError(
            f"{len(T_base_flange)} flange poses but {len(T_cam_target)} board poses: need one of each per sample"
        )
    if len(T_base_flange) < 3:
        raise CalibrationError(
            f"too few samples: {len(T_base_flange)} given, at least 3 needed (12-20 is a good target)"
        )
    unknown = [m for m in methods if m.upper() not in OPENCV_METHODS]
    if unknown or not methods:
        raise UserInputError(f"unknown hand-eye method(s) {unknown}; choose from {', '.join(OPENCV_METHODS)}")


def _opencv_solve(
    hand: list[np.ndarray], board: list[np.ndarray], name: str, failed: dict[str, str]
) -> np.ndarray | None:
    """``X`` from one OpenCV solver, or None with the reason recorded in ``failed``."""
    R_g2b = [T[:3, :3] for T in hand]
    t_g2b = [T[:3, 3].reshape(3, 1) for T in hand]
    R_t2c = [T[:3, :3] for T in board]
    t_t2c = [T[:3, 3].reshape(3, 1) for T in board]
    try:
        R, t = cv2.calibrateHandEye(R_g2b, t_g2b, R_t2c, t_t2c, method=OPENCV_METHODS[name])
    except cv2.error as exc:
        failed[name] = str(exc).strip().splitlines()[-1] if str(exc).strip() else "OpenCV error"
        return None
    if R is None or t is None or not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        failed[name] = "no finite solution"
        return None
    return make_pose(project_to_so3(R), np.asarray(t, dtype=float).reshape(3))


def _agreement(per_method: dict[str, HandEyeResult]) -> tuple[float, float]:
    """Largest difference between any two solvers' ``X``: mm, degrees."""
    names = list(per_method)
    agreement_mm = 0.0
    agreement_deg = 0.0
    for a in range(len(names)):
        for b in range(a + 1, len(names)):
            d_mm, d_deg = pose_distance(per_method[names[a]].T_flange_cam, per_method[names[b]].T_flange_cam)
            agreement_mm = max(agreement_mm, d_mm)
            agreement_deg = max(agreement_deg, d_deg)
    return agreement_mm, agreement_deg


def _notes(agreement_mm: float, agreement_deg: float, failed: dict[str, str]) -> list[str]:
    """Warnings: solvers that disagree (weak motions), solvers that failed."""
    notes = []
    if agreement_deg > AGREEMENT_NOTE_DEG or agreement_mm > AGREEMENT_NOTE_MM:
        notes.append(
            f"solvers disagree by up to {agreement_mm:.1f} mm / {agreement_deg:.2f} deg: "
            "add samples with larger rotations about different axes"
        )
    if failed:
        notes.append("failed solvers: " + ", ".join(failed))
    return notes
