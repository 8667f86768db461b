"""The visit's residual pose, measured against the reference image and its depth (PnP).

Rule: the reference's features, lifted to 3D by its depth, and their matches in the visit's image fix the
visit camera's pose relative to the reference camera: the relocation image stage's PnP fit
(:func:`fgcd_cli.relocation.image.pnp_fit.pnp_fit`: SQPnP in RANSAC, then Levenberg-Marquardt on the inliers).

No uncertainty is stated: the matching noise misses the reference cloud's own error, which dominates
(docs/change-detection.md, "Geometry of a campaign diff").
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from fgcd_cli.relocation.image.pnp_fit import pnp_fit
from fgcd_core.imaging import match_sift, to_gray_u8

__all__ = ["PnpOptions", "ResidualPose", "residual_pose"]


@dataclass(frozen=True, kw_only=True)
class PnpOptions:
    """Constants of :func:`residual_pose`."""

    reprojection_px: float = 1.5
    """RANSAC inlier distance (px): a sub-pixel registration leaves its inliers within a pixel."""
    min_inliers: int = 30
    """Fewer inliers and the pose is not trusted (the warp falls back to the image registration)."""


@dataclass(frozen=True, kw_only=True)
class ResidualPose:
    """Result of :func:`residual_pose`."""

    ok: bool
    reason: str = ""
    """Why the pose was not measured (empty when ``ok``)."""
    T_cur_ref: np.ndarray = field(default_factory=lambda: np.eye(4))
    """4x4: reference-camera coordinates to visit-camera coordinates (metres)."""
    matches: int = 0
    inliers: int = 0
    rms_px: float = float("nan")

    @property
    def translation_mm(self) -> float:
        """Distance between the two camera centres, mm."""
        return float(np.linalg.norm(self.T_cur_ref[:3, 3]) * 1e3)

    @property
    def rotation_deg(self) -> float:
        """Angle of the relative rotation, degrees."""
        return float(np.rad2deg(np.linalg.norm(cv2.Rodrigues(self.T_cur_ref[:3, :3])[0])))


def residual_pose(
    ref_gray: np.ndarray,
    cur_gray: np.ndarray,
    depth: np.ndarray,
    K: np.ndarray,
    *,
    options: PnpOptions | None = None,
) -> ResidualPose:
    """The visit camera's pose relative to the reference camera, from the reference depth.

    Parameters
    ----------
    ref_gray, cur_gray : ndarray, HxW float in [0, 1] (or uint8), the two images under one lighting.
    depth : ndarray, HxW float, the reference's z-depth, metres (NaN where unknown).
    K : ndarray, 3x3, the camera matrix of both images (one camera).
    options : PnpOptions, optional

    Returns
    -------
    ResidualPose
    """
    options = options or PnpOptions()
    K = np.asarray(K, dtype=np.float64)
    pts_ref, pts_cur = match_sift(to_gray_u8(ref_gray), to_gray_u8(cur_gray))
    h, w = depth.shape
    if len(pts_ref):
        col = np.clip(np.rint(pts_ref[:, 0]).astype(int), 0, w - 1)
        row = np.clip(np.rint(pts_ref[:, 1]).astype(int), 0, h - 1)
        z = depth[row, col]
    else:
        z = np.zeros(0)
    known = np.isfinite(z) & (z > 0)
    if known.sum() < options.min_inliers:
        return ResidualPose(ok=False, reason=f"{int(known.sum())} matches on the reference depth", matches=len(z))
    uv, z = pts_ref[known], z[known]
    X = np.column_stack([(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(z))]) * z[:, None]
    # The image stage's PnP (SQPnP in RANSAC, Levenberg-Marquardt on the inliers): one rule for both.
    found, fit = pnp_fit(X, uv, pts_cur[known], K, ransac_px=options.reprojection_px, min_inliers=options.min_inliers)
    if fit is None:
        return ResidualPose(ok=False, reason=f"{found} PnP inliers of {len(z)} matches", matches=len(z), inliers=found)
    return ResidualPose(ok=True, T_cur_ref=fit.M_cam, matches=len(z), inliers=len(fit.inliers), rms_px=fit.rms_px)
