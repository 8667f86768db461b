"""A dense z-depth of the reference image from its observation's metric point cloud."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage
from scipy.interpolate import griddata
from scipy.spatial import cKDTree

from fgcd_core.camera import pinhole_pixels

__all__ = ["ReferenceGeometry", "depth_from_cloud", "geometry_from_cloud", "smooth_known"]

SUPPORT_SPACINGS = 2.0
"""A pixel's depth is known when a cloud point projects within this many mean spacings of it."""


@dataclass(frozen=True, kw_only=True)
class ReferenceGeometry:
    """What a campaign knows of the reference's 3D, at the reference image's size."""

    depth: np.ndarray
    """HxW float, z-depth in metres where a cloud point lies near (NaN elsewhere): what the warp uses."""
    interpolated_depth: np.ndarray
    """HxW float, z-depth interpolated over the cloud's whole convex hull (NaN outside it): the smooth
    surface between points, the best guess of a pixel's area where the cloud has a hole."""
    K: np.ndarray
    """3x3 camera matrix of the reference image (and of the visit's: one camera), px."""
    spacing_px: float
    """Mean distance between the cloud's projected points, px (the depth's resolution)."""


def projected_cloud(
    points_ref: np.ndarray, T_ref_cam: np.ndarray, K: np.ndarray, shape: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """The cloud's points that project into the image: their pixel positions (N x 2, px) and z-depths (N, m)."""
    h, w = shape
    T_cam_ref = np.linalg.inv(np.asarray(T_ref_cam, dtype=np.float64))
    points = np.asarray(points_ref, dtype=np.float64).reshape(-1, 3)
    cam = points @ T_cam_ref[:3, :3].T + T_cam_ref[:3, 3]
    cam = cam[cam[:, 2] > 1e-6]
    if len(cam) == 0:
        return np.zeros((0, 2)), np.zeros(0)
    uv = pinhole_pixels(K, cam)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
    return uv[inside], cam[inside, 2]


def depth_consistent(uv: np.ndarray, z: np.ndarray, *, neighbours: int = 8, k_sigma: float = 3.5) -> np.ndarray:
    """The projected points whose depth agrees with their image neighbours' (a semi-dense cloud's outliers out).

    Rule: a point's depth is compared with the median depth of its ``neighbours`` nearest projected points;
    it is kept unless the difference exceeds ``k_sigma`` robust standard deviations (1.4826 MAD) of those
    differences over the whole cloud. On a depth edge a point agrees with the majority of its own side.

    Parameters
    ----------
    uv : ndarray, Nx2 float, px; z : ndarray, N float, m.

    Returns
    -------
    ndarray, N bool.
    """
    if len(z) <= neighbours:
        return np.ones(len(z), bool)
    _, index = cKDTree(uv).query(uv, k=neighbours + 1)
    difference = z - np.median(z[index[:, 1:]], axis=1)
    spread = 1.4826 * np.median(np.abs(difference - np.median(difference)))
    if spread <= 0:
        return np.ones(len(z), bool)
    return np.abs(difference - np.median(difference)) <= k_sigma * spread


def depth_from_cloud(
    points_ref: np.ndarray, T_ref_cam: np.ndarray, K: np.ndarray, shape: tuple[int, int]
) -> np.ndarray:
    """Z-depth of every pixel, interpolated linearly between the cloud's projected points.

    Parameters
    ----------
    points_ref : ndarray, Nx3 float, metres, in the ``ref`` frame.
    T_ref_cam : ndarray, 4x4, the camera's pose in the ``ref`` frame.
    K : ndarray, 3x3 camera matrix (pixels) of the image the depth is for.
    shape : (H, W) of that image.

    Returns
    -------
    ndarray, HxW float64, metres along the optical axis; NaN outside the convex hull of the projected
    points (and everywhere when fewer than 10 project into the image).
    """
    return _interpolated(*_consistent_projection(points_ref, T_ref_cam, K, shape), shape)


def geometry_from_cloud(
    points_ref: np.ndarray, T_ref_cam: np.ndarray, K: np.ndarray, shape: tuple[int, int]
) -> ReferenceGeometry | None:
    """The reference's :class:`ReferenceGeometry` from its metric cloud (None when the cloud does not
    cover the image); ``spacing_px`` is ``sqrt(covered pixels / projected points)``."""
    uv, z = _consistent_projection(points_ref, T_ref_cam, K, shape)
    interpolated = _interpolated(uv, z, shape)
    covered = int(np.isfinite(interpolated).sum())
    if covered == 0:
        return None
    spacing = float(np.sqrt(covered / len(z)))
    # Between points farther apart than a few spacings (slivers along the hull, holes in a semi-dense
    # cloud) the interpolated depth is a guess: the warp leaves it to the homography there.
    empty = np.ones(shape, np.uint8)
    cols, rows = np.rint(uv).astype(int).T
    empty[rows, cols] = 0
    far = cv2.distanceTransform(empty, cv2.DIST_L2, 5) > SUPPORT_SPACINGS * spacing
    return ReferenceGeometry(
        depth=np.where(far, np.nan, interpolated),
        interpolated_depth=interpolated,
        K=np.asarray(K, dtype=np.float64),
        spacing_px=spacing,
    )


def _consistent_projection(points_ref, T_ref_cam, K, shape) -> tuple[np.ndarray, np.ndarray]:
    """:func:`projected_cloud` without the points :func:`depth_consistent` drops."""
    uv, z = projected_cloud(points_ref, T_ref_cam, K, shape)
    keep = depth_consistent(uv, z)
    return uv[keep], z[keep]


def _interpolated(uv: np.ndarray, z: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Linear interpolation of the points' depths over the image (NaN outside their hull; all NaN below 10)."""
    if len(z) < 10:
        return np.full(shape, np.nan)
    h, w = shape
    grid_v, grid_u = np.mgrid[0:h, 0:w]
    return griddata(uv, z, (grid_u, grid_v), method="linear")


def smooth_known(values: np.ndarray, sigma_px: float) -> np.ndarray:
    """Gaussian smoothing of the finite pixels of ``values`` only (normalised convolution); NaN stays NaN.

    Parameters
    ----------
    values : ndarray, HxW float (NaN where unknown).
    sigma_px : float, 0 returns a copy.

    Returns
    -------
    ndarray, HxW float64.
    """
    values = np.asarray(values, dtype=np.float64)
    if sigma_px <= 0:
        return values.copy()
    known = np.isfinite(values)
    weight = ndimage.gaussian_filter(known.astype(np.float64), sigma_px)
    smoothed = ndimage.gaussian_filter(np.where(known, values, 0.0), sigma_px) / np.maximum(weight, 1e-9)
    return np.where(known, smoothed, np.nan)
