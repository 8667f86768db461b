"""Target-free hand-eye refined on the images of the platform's rest poses (structure from known motion).

The rACR linear solve (:func:`fgcd_cli.calibration.handeye.linear.solve_handeye_scale`)
works on the camera motions the monocular VSE reports. Over the small motions a
heritage site allows, those poses carry slowly varying errors of several
millimetres and a few tenths of a degree (the rotation/translation ambiguity of a
monocular map of a shallow scene), and ``t_X`` is found from camera
translations divided by rotation angles of ~0.1 rad: the VSE errors reach
``t_X`` amplified about tenfold.

The refinement goes back to the images: a bundle adjustment over the views with
the camera poses tied to the reported flange poses
(:mod:`fgcd_cli.calibration.handeye.model`), on feature tracks
(:mod:`fgcd_cli.calibration.handeye.tracks`), twice: observations off by more than
``reject_px`` after the first pass are removed. The map scale does not enter
(the flange poses are metric); it is estimated afterwards
(:mod:`fgcd_cli.calibration.handeye.target_free`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from fgcd_cli.calibration.errors import CalibrationError
from fgcd_cli.calibration.handeye.model import HandPoses, Observations, initial_landmarks, residuals
from fgcd_cli.calibration.handeye.schur_lm import Adjusted, lm_handeye
from fgcd_cli.calibration.handeye.tracks import MatchConfig, feature_tracks
from fgcd_core.se3 import pose_distance

__all__ = ["BAHandEyeResult", "RefineConfig", "refine_handeye_images", "refine_handeye_tracks"]

#: The rotation scale is observable only if the platform turned by more than this (the procedures turn by ~8 degrees).
MIN_ROTATION_FOR_SCALE_DEG = 2.0
#: Above this reprojection RMS (pixels) the result carries a note: the platform did not reach the
#: poses it reports, or blur, a moving scene or wrong intrinsics (docs/calibration.md, "Target-free").
HIGH_RMS_PX = 0.6


@dataclass(frozen=True, kw_only=True)
class RefineConfig:
    """Options of the adjustment.

    Attributes
    ----------
    reject_px : float
        Observations with a larger reprojection error after the first pass are dropped.
    min_points : int
        Fewer scene points seen from two views or more raise.
    estimate_rotation_scale : bool
        Also estimate the scale of the platform's reported rotations (when it
        turned by more than :data:`MIN_ROTATION_FOR_SCALE_DEG`).
    """

    reject_px: float = 2.0
    min_points: int = 60
    estimate_rotation_scale: bool = True


@dataclass(frozen=True, kw_only=True)
class BAHandEyeResult:
    """Outcome of :func:`refine_handeye_images`.

    Attributes
    ----------
    T_flange_cam : (4, 4) ndarray
        Refined hand-eye.
    std_mm, std_deg : float
        One-sigma uncertainty of the translation (norm of the per-axis sigmas) and
        rotation of ``X`` from the Gauss-Newton covariance scaled by the residuals.
    rms_px : float
        Reprojection RMS of the kept observations, pixels.
    n_points, n_observations : int
        Scene points and image observations kept.
    per_image_rms_px : (N,) ndarray
        Reprojection RMS per stop image (NaN for an image without observations).
    change_mm, change_deg : float
        How far the refinement moved ``X`` from the initial value.
    notes : list of str
        Warnings.
    points_base : (M, 3) ndarray
        The adjusted scene points in the platform base frame, metres.
    rotation_scale, rotation_scale_std : float
        Ratio of the platform's true rotations to the reported ones, estimated
        with ``X`` (see :class:`~fgcd_cli.calibration.handeye.model.HandPoses`),
        and its one-sigma; 1.0 / NaN when not estimated.
    """

    T_flange_cam: np.ndarray
    std_mm: float
    std_deg: float
    rms_px: float
    n_points: int
    n_observations: int
    per_image_rms_px: np.ndarray
    change_mm: float
    change_deg: float
    notes: list[str] = field(default_factory=list)
    points_base: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    rotation_scale: float = 1.0
    rotation_scale_std: float = float("nan")


def refine_handeye_images(
    T_base_flange: Sequence[np.ndarray],
    images: Sequence[np.ndarray],
    K: np.ndarray,
    T_flange_cam_init: np.ndarray,
    *,
    dist: Sequence[float] | None = None,
    match: MatchConfig | None = None,
    config: RefineConfig | None = None,
) -> BAHandEyeResult:
    """Refine the hand-eye on the view images with the camera poses tied to the flange poses.

    Parameters
    ----------
    T_base_flange : sequence of N (4, 4) ndarray
        Reported flange poses at the views, metres.
    images : sequence of N images
        The camera image at each view, **undistorted** (ideal pinhole ``K``) unless ``dist`` is given.
    K : (3, 3) ndarray
        Intrinsic matrix of the undistorted images.
    T_flange_cam_init : (4, 4) ndarray
        Initial hand-eye (the linear solve); must be within a few degrees and
        centimetres for the triangulation to start.
    dist : sequence of float, optional
        OpenCV distortion coefficients if the images are *not* undistorted; the
        keypoints are then undistorted before the adjustment.
    match : MatchConfig, optional
        Feature matching (ratio, RANSAC threshold, features, match window, anchors).
    config : RefineConfig, optional
        Adjustment options.

    Returns
    -------
    BAHandEyeResult

    Raises
    ------
    CalibrationError
        Too few matched points between the images (low texture, too large motions).
    """
    if len(T_base_flange) != len(images):
        raise CalibrationError(f"{len(T_base_flange)} flange poses but {len(images)} stop images")
    tracks = feature_tracks(images, K, dist=dist, config=match)
    return refine_handeye_tracks(T_base_flange, tracks, K, T_flange_cam_init, config=config)


def refine_handeye_tracks(
    T_base_flange: Sequence[np.ndarray],
    tracks: Sequence[Sequence[tuple[int, Sequence[float]]]],
    K: np.ndarray,
    T_flange_cam_init: np.ndarray,
    *,
    config: RefineConfig | None = None,
) -> BAHandEyeResult:
    """Bundle adjustment of ``X`` and the scene points from feature tracks across the views.

    Parameters
    ----------
    T_base_flange : sequence of N (4, 4) ndarray
        Reported flange poses, metres.
    tracks : sequence of tracks
        Each track lists ``(view_index, (u, v))`` observations of one scene point
        (undistorted pixels), at least two views.
    K : (3, 3) ndarray
        Pinhole intrinsics of the undistorted images.
    T_flange_cam_init : (4, 4) ndarray
        Initial hand-eye.
    config : RefineConfig, optional
        Adjustment options (default: :class:`RefineConfig`).
    """
    config = config or RefineConfig()
    hand = np.stack([np.asarray(T, dtype=float) for T in T_base_flange])
    K = np.asarray(K, dtype=float)
    X0 = np.asarray(T_flange_cam_init, dtype=float)
    pts0, obs = initial_landmarks(hand, tracks, K, X0)
    if len(pts0) < config.min_points:
        raise CalibrationError(
            f"only {len(pts0)} scene points were matched between the stop images (need {config.min_points}): "
            "the scene has too little texture or the stops are too far apart"
        )
    poses = HandPoses(hand)
    turned = np.max(np.linalg.norm(poses.phi, axis=1)) > math.radians(MIN_ROTATION_FOR_SCALE_DEG)
    s0 = 1.0 if config.estimate_rotation_scale and turned else None
    X, P, s_rot, _ = lm_handeye(poses, K, X0, pts0, obs, rotation_scale=s0)
    P, obs = _drop_outliers(poses, K, X, P, obs, s_rot, config)
    adjusted = lm_handeye(poses, K, X, P, obs, rotation_scale=None if s0 is None else s_rot)
    return _result(poses, K, X0, adjusted, obs, estimated=s0 is not None)


def _drop_outliers(
    poses: HandPoses, K: np.ndarray, X: np.ndarray, P: np.ndarray, obs: Observations, s_rot: float, config: RefineConfig
) -> tuple[np.ndarray, Observations]:
    """Observations off by ``reject_px`` or more go, then the landmarks left with fewer than two observations."""
    r = residuals(poses.inv(s_rot), K, X, P, obs)
    keep = np.linalg.norm(r, axis=1) < config.reject_px
    counts = np.bincount(obs.pt[keep], minlength=len(P))
    keep &= counts[obs.pt] >= 2
    used = np.flatnonzero(counts >= 2)
    if len(used) < config.min_points:
        raise CalibrationError(
            f"only {len(used)} scene points are consistent across the stop images (need {config.min_points})"
        )
    remap = -np.ones(len(P), int)
    remap[used] = np.arange(len(used))
    return P[used], obs.subset(keep, remap)


def _result(
    poses: HandPoses, K: np.ndarray, X0: np.ndarray, adjusted: Adjusted, obs: Observations, *, estimated: bool
) -> BAHandEyeResult:
    """Residual statistics, covariance and notes of the adjusted model."""
    X, P, s_rot, S = adjusted
    n = len(poses.T)
    r = residuals(poses.inv(s_rot), K, X, P, obs)
    rms = float(np.sqrt(np.mean(np.sum(r**2, axis=1))))
    per_image = np.array(
        [
            float(np.sqrt(np.mean(np.sum(r[obs.cam == i] ** 2, axis=1)))) if np.any(obs.cam == i) else float("nan")
            for i in range(n)
        ]
    )
    # covariance of the hand-eye (and rotation scale): inverse Schur complement times the residual variance
    dof = max(r.size - len(S) - 3 * len(P), 1)
    sigma2 = float(np.sum(r**2)) / dof
    try:
        d = np.sqrt(np.clip(np.diag(np.linalg.inv(S)) * sigma2, 0, None))
        std_mm = float(np.linalg.norm(d[:3])) * 1000.0
        std_deg = math.degrees(float(np.linalg.norm(d[3:6])))
        s_std = float(d[6]) if len(d) > 6 else float("nan")
    except np.linalg.LinAlgError:  # pragma: no cover - singular: X not observable from these stops
        std_mm = std_deg = s_std = float("inf")
    change_mm, change_deg = pose_distance(X, X0)
    return BAHandEyeResult(
        T_flange_cam=X,
        std_mm=std_mm,
        std_deg=std_deg,
        rms_px=rms,
        n_points=len(P),
        n_observations=len(obs.cam),
        per_image_rms_px=per_image,
        change_mm=change_mm,
        change_deg=change_deg,
        notes=_notes(s_rot, s_std, rms, estimated=estimated),
        points_base=P,
        rotation_scale=s_rot,
        rotation_scale_std=s_std,
    )


def _notes(s_rot: float, s_std: float, rms: float, *, estimated: bool) -> list[str]:
    """A rotation scale off by more than 3 sigma (and 0.03 %), and a high reprojection RMS."""
    notes = []
    if estimated and abs(s_rot - 1.0) > max(3.0 * s_std, 3e-4):
        notes.append(
            f"the platform's rotations are {abs(s_rot - 1) * 100:.2f} % {'longer' if s_rot > 1 else 'shorter'} than "
            f"it reports (+-{s_std * 100:.2f} %, from the images): the hand-eye accounts for it, but the platform's "
            "own calibration is off"
        )
    if rms > HIGH_RMS_PX:
        notes.append(
            f"image refinement: reprojection RMS {rms:.2f} px is high: the platform did not reach the poses it "
            "reports (check its calibration and repeatability), or blur, a moving scene or wrong intrinsics"
        )
    return notes
