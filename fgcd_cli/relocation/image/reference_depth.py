"""Depth of the reference surface at reference-image pixels, from the reference cloud (the image stage's 2D-3D).

The final image stage (:mod:`fgcd_cli.relocation.image.refine`) and the scene
uncertainty lift reference keypoints to 3D with these: the front-most surface
near each pixel (occlusions), each point on its pixel's ray.
"""

from __future__ import annotations

import numpy as np

__all__ = ["LAYER_GAP_REL", "front_layer_depth", "lift_reference_pixels", "reference_depth_lookup"]

# Two depths of one surface point in the semi-dense cloud differ by less than the fusion gate (2.5,
# :func:`~fgcd_cli.vse.semidense.fuse_estimates`) times the kept points' largest relative sigma
# (``VseConfig.semidense_max_rel_sigma``, 2 %): a larger step between consecutive depths
# separates two surfaces (an occlusion), a smaller one is the cloud's own noise.
LAYER_GAP_REL = 0.05


def front_layer_depth(z: np.ndarray, dist_px: np.ndarray, *, layer_gap_rel: float = LAYER_GAP_REL) -> float:
    """Depth of the front-most surface among cloud points near a pixel.

    Parameters
    ----------
    z : (K,) ndarray
        z-depths of the points projected near the pixel, metres (K >= 1).
    dist_px : (K,) ndarray
        Their image distances to the pixel.
    layer_gap_rel : float
        A step between consecutive sorted depths above this fraction starts a surface behind.

    Returns
    -------
    float
        Inverse-distance weighted mean depth of the points before the first such step. Taking
        only the points near the minimum instead would pick the cloud's noise: the nearest of a
        few noisy depths of one surface is biased toward the camera by about a sigma.
    """
    order = np.argsort(z)
    zs = z[order]
    steps = np.flatnonzero(np.diff(zs) > layer_gap_rel * zs[:-1])
    layer = order[: steps[0] + 1] if len(steps) else order
    w = 1.0 / (dist_px[layer] + 0.5)
    return float(np.sum(w * z[layer]) / np.sum(w))


def reference_depth_lookup(
    ref_points: np.ndarray, T_ref_camref: np.ndarray, camera, pixels: np.ndarray, *, radius_px: float = 2.0
) -> np.ndarray:
    """Depth of the reference surface at given reference-image pixels, from the reference cloud.

    Parameters
    ----------
    ref_points : (N, 3) ndarray
        Reference cloud, metres, ``ref`` frame.
    T_ref_camref : (4, 4) ndarray
        Reference camera pose.
    camera : PinholeCamera
        Intrinsics of the (undistorted) reference image.
    pixels : (M, 2) ndarray
        ``(u, v)`` pixels of the reference image.
    radius_px : float
        Largest distance from a pixel to a projected cloud point.

    Returns
    -------
    (M,) ndarray
        z-depth in metres, NaN where no cloud point projects close enough. Of the
        points within the radius, the front-most surface is taken (occlusion,
        :func:`front_layer_depth`), and within it an inverse-distance weighted mean.
    """
    from scipy.spatial import cKDTree

    P = np.asarray(ref_points, dtype=float)
    Xc = (P - T_ref_camref[:3, 3]) @ T_ref_camref[:3, :3]
    z = Xc[:, 2]
    front = z > 1e-6
    Xc, z = Xc[front], z[front]
    uv = np.column_stack([camera.fx * Xc[:, 0] / z + camera.cx, camera.fy * Xc[:, 1] / z + camera.cy])
    out = np.full(len(pixels), np.nan)
    if len(uv) == 0 or len(pixels) == 0:
        return out
    tree = cKDTree(uv)
    for i, nbrs in enumerate(tree.query_ball_point(np.asarray(pixels, dtype=float), r=radius_px)):
        if not nbrs:
            continue
        nbrs = np.asarray(nbrs)
        out[i] = front_layer_depth(z[nbrs], np.linalg.norm(uv[nbrs] - pixels[i], axis=1))
    return out


def lift_reference_pixels(
    pixels: np.ndarray, *, ref_points: np.ndarray, T_ref_camref: np.ndarray, camera, radius_px: float
) -> tuple[np.ndarray, np.ndarray]:
    """Reference-image pixels lifted to 3D by the reference cloud (the image localizer's 2D-3D points).

    Parameters
    ----------
    pixels : (N, 2) ndarray
        ``(u, v)`` pixels of the reference image.
    ref_points : (M, 3) ndarray
        Reference cloud, metres, ``ref`` frame.
    T_ref_camref : (4, 4) ndarray
        Reference camera pose.
    camera : PinholeCamera
    radius_px : float
        See :func:`reference_depth_lookup`.

    Returns
    -------
    X : (K, 3) ndarray
        The points with a depth, on each pixel's ray, in the reference camera frame, metres.
    has : (N,) bool ndarray
        Which pixels got a depth (``K = has.sum()``).
    """
    p = np.asarray(pixels, dtype=float).reshape(-1, 2)
    z = reference_depth_lookup(ref_points, T_ref_camref, camera, p, radius_px=radius_px)
    has = np.isfinite(z)
    p, z = p[has], z[has]
    X = (
        np.column_stack([(p[:, 0] - camera.cx) / camera.fx, (p[:, 1] - camera.cy) / camera.fy, np.ones(len(p))])
        * z[:, None]
    )
    return X, has
