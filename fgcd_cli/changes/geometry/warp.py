"""Where each reference pixel lies in the visit's image, by the reference depth and the residual pose;
and the depth edges where that warp cannot be trusted (docs/change-detection.md, "Geometry of a campaign diff")."""

from __future__ import annotations

import cv2
import numpy as np

from fgcd_core.camera import pinhole_pixels

__all__ = ["depth_warp_maps", "parallax_edges"]


def depth_warp_maps(depth: np.ndarray, K: np.ndarray, T_cur_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The visit-image position of every reference pixel: back-projected by its depth, moved by the
    residual pose, projected again (one camera, no distortion: the images are the campaign's rectified ones).

    Parameters
    ----------
    depth : ndarray, HxW float, reference z-depth, metres (NaN where unknown).
    K : ndarray, 3x3 camera matrix, px.
    T_cur_ref : ndarray, 4x4, reference-camera to visit-camera coordinates, metres.

    Returns
    -------
    map_x, map_y : ndarray, HxW float32, px in the visit image (NaN where the depth is unknown or the
    point falls behind the visit camera); ``cv2.remap`` maps.
    """
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    z = np.asarray(depth, dtype=np.float64)
    X = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=-1)
    R, t = np.asarray(T_cur_ref, dtype=np.float64)[:3, :3], np.asarray(T_cur_ref, dtype=np.float64)[:3, 3]
    Xc = (X @ R.T + t).reshape(-1, 3)
    uv = np.full((len(Xc), 2), np.nan)
    ahead = Xc[:, 2] > 1e-6  # NaN depths compare False: unknown stays NaN
    uv[ahead] = pinhole_pixels(K, Xc[ahead])
    map_x, map_y = uv[:, 0].reshape(h, w), uv[:, 1].reshape(h, w)
    return map_x.astype(np.float32), map_y.astype(np.float32)


def parallax_edges(map_x: np.ndarray, map_y: np.ndarray, *, tolerance_px: float, window_px: int) -> np.ndarray:
    """Pixels near a depth edge whose parallax jump the score would not tolerate.

    Rule: across a depth edge the warp's displacement jumps by the parallax difference of the two
    surfaces; one side is occluded or uncovered over that width in the visit image, and the interpolated
    depth is wrong along the edge. Where the displacement varies by more than ``tolerance_px`` (the
    score's shift tolerance) within ``window_px`` (the cloud's sampling: an edge is only located to it),
    the pixel is not compared, together with a margin as wide as the jump (the occluded strip).

    Parameters
    ----------
    map_x, map_y : ndarray, HxW float32, :func:`depth_warp_maps` (NaN where unknown).
    tolerance_px : float, displacement variation the score tolerates, px.
    window_px : int, radius of the neighbourhood the variation is measured in, px.

    Returns
    -------
    ndarray, HxW bool.
    """
    h, w = map_x.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    known = np.isfinite(map_x) & np.isfinite(map_y)
    kernel = np.ones((2 * window_px + 1, 2 * window_px + 1), np.uint8)
    jump = np.zeros((h, w), np.float32)
    for displacement in (map_x - u, map_y - v):
        # Over the known pixels only: an unknown neighbour neither raises the max nor lowers the min.
        highest = cv2.dilate(np.where(known, displacement, -1e9).astype(np.float32), kernel)
        lowest = cv2.erode(np.where(known, displacement, 1e9).astype(np.float32), kernel)
        jump = np.maximum(jump, np.where(known, highest - lowest, 0.0).astype(np.float32))
    edges = (jump > tolerance_px) & known
    if not edges.any():
        return edges
    margins = np.ceil(jump).astype(np.int32)
    out = np.zeros((h, w), bool)
    for margin in np.unique(margins[edges]):
        grow = np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)
        out |= cv2.dilate((edges & (margins == margin)).astype(np.uint8), grow).astype(bool)
    return out
