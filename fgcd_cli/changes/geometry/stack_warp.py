"""The current stack's warp into the reference frame by the reference depth and the measured residual pose."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgcd_cli.changes.geometry.depth import ReferenceGeometry
from fgcd_cli.changes.geometry.pnp import ResidualPose, residual_pose
from fgcd_cli.changes.geometry.warp import depth_warp_maps, parallax_edges
from fgcd_cli.changes.registration import homography_points

__all__ = ["GeometryWarp", "geometry_warp"]


@dataclass(frozen=True, kw_only=True)
class GeometryWarp:
    """Result of :func:`geometry_warp`."""

    pose: ResidualPose
    map_x: np.ndarray | None = None
    """HxW float32, visit-image x of every reference pixel (None when the pose was not measured)."""
    map_y: np.ndarray | None = None
    not_compared: np.ndarray | None = None
    """HxW bool, depth edges whose parallax jump the score does not tolerate."""
    depth_fraction: float = 0.0
    """Fraction of the pixels warped by the depth (the others by the image registration)."""


def geometry_warp(
    geometry: ReferenceGeometry,
    ref_gray: np.ndarray,
    cur_gray: np.ndarray,
    H_cur_ref: np.ndarray,
    *,
    tolerance_px: float,
) -> GeometryWarp:
    """Warp maps from the reference depth and the residual pose measured against it.

    Where the depth is unknown (outside the cloud) the image registration's homography maps the pixel.
    When the pose cannot be measured, nothing is warped by the depth (``map_x`` is None) and the caller
    keeps the homography.

    Parameters
    ----------
    geometry : ReferenceGeometry
    ref_gray, cur_gray : ndarray, HxW float in [0, 1], the registration lighting's images.
    H_cur_ref : ndarray, 3x3, reference pixel -> current pixel (the image registration).
    tolerance_px : float, the score's shift tolerance (:func:`parallax_edges`).

    Returns
    -------
    GeometryWarp
    """
    pose = residual_pose(ref_gray, cur_gray, geometry.depth, geometry.K)
    if not pose.ok:
        return GeometryWarp(pose=pose)
    map_x, map_y = depth_warp_maps(geometry.depth, geometry.K, pose.T_cur_ref)
    edges = parallax_edges(map_x, map_y, tolerance_px=tolerance_px, window_px=max(1, int(np.ceil(geometry.spacing_px))))
    by_depth = np.isfinite(map_x) & np.isfinite(map_y)
    h, w = map_x.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    h_x, h_y, _ = homography_points(H_cur_ref, u, v)
    map_x, map_y = np.where(by_depth, map_x, h_x), np.where(by_depth, map_y, h_y)
    return GeometryWarp(pose=pose, map_x=map_x, map_y=map_y, not_compared=edges, depth_fraction=float(by_depth.mean()))
