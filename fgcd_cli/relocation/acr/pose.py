"""The ACR baseline's measurement: relative pose to one reference image from 2D matches (Tian et al.).

ACR (reference [1] of paper 000; ``../shared/notes/algorithms.md``, "The ACR
baseline") knows only the reference *image*: no depth, no hand-eye. Each step
matches the current image with it (SIFT and the ratio test, the project's one
matcher :func:`fgcd_core.imaging.match_sift`) and estimates the relative camera
pose up to the scale of its translation:

* ``acr``: the 5-point essential matrix with RANSAC (``cv2.findEssentialMat``),
  decomposed by ``cv2.recoverPose`` (the solution with most points in front of
  both cameras);
* ``acr-h`` (the paper's H-CR, homography-based relocation): a RANSAC
  homography decomposed by ``cv2.decomposeHomographyMat``, keeping the solution
  whose plane is in front of the camera for the inliers and faces it most.

The measured AFD is the mean displacement of the homography inliers between
the two images, the authors' FDF protocol (:mod:`fgcd_cli.metrics.afd`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

import cv2
import numpy as np

from fgcd_cli.changes.registration import ransac_homography
from fgcd_core.imaging import match_sift, to_gray_u8

__all__ = ["AcrModel", "AcrPoseConfig", "RelativePose", "measure_relative_pose", "relative_pose_from_matches"]


class AcrModel(StrEnum):
    """Which two-view model gives an ACR step (``fgcd relocate --method``)."""

    ESSENTIAL = "acr"
    """5-point essential matrix (Tian et al.)."""
    HOMOGRAPHY = "acr-h"
    """Homography decomposition (H-CR, the homography-guided step)."""


@dataclass(frozen=True, kw_only=True)
class AcrPoseConfig:
    """Options of the two-view measurement.

    Attributes
    ----------
    model : AcrModel
    ratio : float
        Lowe ratio of the SIFT matching (the FDF protocol's 0.75).
    max_features : int
        SIFT keypoints per image (as :class:`fgcd_cli.metrics.afd.FdfConfig`).
    ransac_px : float
        RANSAC threshold of the essential matrix / homography, pixels (1 px: the
        matching's own accuracy on sharp features; OpenCV's documented default).
    afd_ransac_px : float
        RANSAC threshold of the homography whose inliers measure the AFD (the FDF protocol's 3 px).
    min_inliers : int
        Fewest RANSAC inliers for a trustworthy pose: 12, as the FDF's minimum
        (3x the homography's minimal set, 2.4x the essential matrix's).
    min_front_fraction : float
        ``recoverPose`` must place at least this fraction of the inliers in front of both
        cameras; fewer means it chose among near-equal wrong solutions (notes, "recoverPose
        occasionally picks the wrong one").
    """

    model: AcrModel = AcrModel.ESSENTIAL
    ratio: float = 0.75
    max_features: int = 4000
    ransac_px: float = 1.0
    afd_ransac_px: float = 3.0
    min_inliers: int = 12
    min_front_fraction: float = 0.5


@dataclass(frozen=True, kw_only=True)
class RelativePose:
    """The reference camera seen from the current one, translation known only in direction.

    Attributes
    ----------
    ok : bool
    reason : str
        "ok" or why not.
    R_cur_ref : (3, 3) ndarray
        Rotation of the reference camera in the current camera frame (the rotation the camera must make).
    t_dir : (3,) ndarray
        Unit direction, in the current camera frame, from the current to the reference camera centre.
    matches, inliers : int
        Ratio-test matches and RANSAC inliers of the model.
    measured_afd_px : float
        Mean displacement of the homography inliers (FDF protocol), pixels; NaN without one.
    """

    ok: bool
    reason: str
    R_cur_ref: np.ndarray
    t_dir: np.ndarray
    matches: int = 0
    inliers: int = 0
    measured_afd_px: float = math.nan


def _failed(reason: str, *, matches: int = 0, inliers: int = 0, afd: float = math.nan) -> RelativePose:
    return RelativePose(
        ok=False,
        reason=reason,
        R_cur_ref=np.eye(3),
        t_dir=np.zeros(3),
        matches=matches,
        inliers=inliers,
        measured_afd_px=afd,
    )


def _measured_afd(p_cur: np.ndarray, p_ref: np.ndarray, ransac_px: float) -> float:
    """Mean inlier displacement under a RANSAC homography (the authors' FDF/AFD protocol)."""
    _, inl = ransac_homography(p_ref, p_cur, ransac_px=ransac_px)
    if inl.sum() < 4:
        return math.nan
    return float(np.linalg.norm(p_cur[inl] - p_ref[inl], axis=1).mean())


def _essential(p_cur: np.ndarray, p_ref: np.ndarray, K: np.ndarray, config: AcrPoseConfig):
    """``X_ref = R X_cur + t`` (unit t) from the 5-point essential matrix; (R, t, inliers) or a reason."""
    cv2.setRNGSeed(0)  # the same pair gives the same pose every time
    # Rule: a model locally optimised on all inliers (USAC_ACCURATE), not plain RANSAC's best
    # minimal sample, whose translation direction is unreliable on a revisit's short baseline
    # (docs/relocation.md, "The ACR baseline").
    E, mask = cv2.findEssentialMat(p_cur, p_ref, K, method=cv2.USAC_ACCURATE, prob=0.999, threshold=config.ransac_px)
    if E is None or mask is None or E.shape != (3, 3):
        return "no essential matrix (degenerate matches)"
    inliers = int(mask.sum())
    if inliers < config.min_inliers:
        return f"only {inliers} essential-matrix inliers (need {config.min_inliers})"
    # distanceThresh: points up to 1e6 baselines away count (OpenCV's default of 50 drops the whole
    # object of a revisit, whose baseline is a few centimetres at a metre and more)
    front, R, t, _, _ = cv2.recoverPose(E, p_cur, p_ref, K, distanceThresh=1e6, mask=mask.copy())
    if front < config.min_front_fraction * inliers:
        return f"recoverPose put only {front} of {inliers} inliers in front of both cameras (ambiguous solution)"
    return R, t.ravel(), inliers


def _normalised(pixels: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pixels as normalised image coordinates ``K^-1 [x y 1]``, (N, 1, 2) float32 (the form OpenCV's filter takes)."""
    return cv2.undistortPoints(pixels.reshape(-1, 1, 2).astype(np.float64), K, None).astype(np.float32)


def _homography(p_cur: np.ndarray, p_ref: np.ndarray, K: np.ndarray, config: AcrPoseConfig):
    """``X_ref = R X_cur + t`` (unit t) from a homography decomposition; (R, t, inliers) or a reason."""
    cv2.setRNGSeed(0)
    H, mask = cv2.findHomography(p_cur, p_ref, cv2.RANSAC, config.ransac_px, maxIters=5000, confidence=0.999)
    if H is None:
        return "no homography (degenerate matches)"
    inl = mask.ravel().astype(bool)
    if inl.sum() < config.min_inliers:
        return f"only {int(inl.sum())} homography inliers (need {config.min_inliers})"
    _, Rs, ts, ns = cv2.decomposeHomographyMat(H, K)
    keep = cv2.filterHomographyDecompByVisibleRefpoints(Rs, ns, _normalised(p_cur[inl], K), _normalised(p_ref[inl], K))
    candidates = [int(i) for i in np.asarray(keep).ravel()] if keep is not None else list(range(len(Rs)))
    if not candidates:
        return "no homography decomposition keeps the points in front of the camera"
    # Rule: the object faces the camera: its plane normal (in the current frame) is closest to the optical axis
    best = max(candidates, key=lambda i: abs(float(ns[i].ravel()[2])))
    t = ts[best].ravel()
    norm = float(np.linalg.norm(t))
    return Rs[best], (t / norm if norm > 0 else t), int(inl.sum())


def relative_pose_from_matches(
    p_cur: np.ndarray, p_ref: np.ndarray, K: np.ndarray, *, config: AcrPoseConfig = AcrPoseConfig()
) -> RelativePose:
    """The reference camera in the current camera's frame, up to scale, from matched pixels.

    Parameters
    ----------
    p_cur, p_ref : (N, 2) ndarray
        Matched pixels ``(x, y)`` of the current and the reference (undistorted) images.
    K : (3, 3) ndarray
        Intrinsic matrix of the ideal pinhole both images share.
    config : AcrPoseConfig

    Returns
    -------
    RelativePose
        ``R_cur_ref`` and the unit ``t_dir`` of the camera motion to the reference, in the
        current camera frame; ``ok=False`` with the reason when the evidence is too weak.
    """
    p_cur = np.asarray(p_cur, dtype=np.float64).reshape(-1, 2)
    p_ref = np.asarray(p_ref, dtype=np.float64).reshape(-1, 2)
    n = len(p_cur)
    if n < max(5, config.min_inliers):
        return _failed(f"only {n} SIFT matches with the reference image (need {config.min_inliers})", matches=n)
    afd = _measured_afd(p_cur, p_ref, config.afd_ransac_px)
    solve = _essential if config.model == AcrModel.ESSENTIAL else _homography
    out = solve(p_cur, p_ref, np.asarray(K, dtype=np.float64), config)
    if isinstance(out, str):
        return _failed(out, matches=n, afd=afd)
    R_ref_cur, t_ref_cur, inliers = out
    # X_ref = R X_cur + t: the reference camera in the current frame is [R^T | -R^T t]
    R_cur_ref = np.asarray(R_ref_cur, dtype=float).T
    t_dir = -R_cur_ref @ np.asarray(t_ref_cur, dtype=float)
    norm = float(np.linalg.norm(t_dir))
    return RelativePose(
        ok=True,
        reason="ok",
        R_cur_ref=R_cur_ref,
        t_dir=t_dir / norm if norm > 0 else t_dir,
        matches=n,
        inliers=inliers,
        measured_afd_px=afd,
    )


def measure_relative_pose(
    reference_image: np.ndarray, current_image: np.ndarray, K: np.ndarray, *, config: AcrPoseConfig = AcrPoseConfig()
) -> RelativePose:
    """SIFT matches of two images, then :func:`relative_pose_from_matches`.

    Parameters
    ----------
    reference_image, current_image : (H, W) or (H, W, 3) ndarray
        Undistorted images (uint8, uint16 or float in [0, 1]).
    K : (3, 3) ndarray
    config : AcrPoseConfig
    """
    ref = to_gray_u8(np.asarray(reference_image))
    cur = to_gray_u8(np.asarray(current_image))
    p_ref, p_cur = match_sift(ref, cur, ratio=config.ratio, max_features=config.max_features)
    return relative_pose_from_matches(p_cur, p_ref, K, config=config)
