"""Map scale of a monocular VSE session from the depths of its keyframes (target-free calibration).

The camera *positions* the VSE reports carry errors of millimetres (a few % of
the small motions of a calibration); the depths of its map are consistent to a
few tenths of a percent across keyframes, so they are what fixes the scale
(docs/calibration.md, "Target-free").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fgcd_cli.calibration.errors import CalibrationError
from fgcd_core.camera import pinhole_pixels
from fgcd_core.se3 import invert_pose, transform_points

__all__ = ["KeyframeDepths", "scale_from_depths"]


@dataclass(frozen=True, kw_only=True)
class KeyframeDepths:
    """What :func:`scale_from_depths` needs of one VSE keyframe.

    Attributes
    ----------
    T_base_flange : (4, 4) ndarray
        Reported flange pose when the keyframe's image was taken.
    T_map_cam : (4, 4) ndarray
        The keyframe's pose in the map (map units).
    pixels : (P, 2) ndarray
        Pixels of the keyframe's cloud points (``MapCloud.pixels``).
    points_map : (P, 3) ndarray
        Those points in the map frame (``MapCloud.points``).
    """

    T_base_flange: np.ndarray
    T_map_cam: np.ndarray
    pixels: np.ndarray
    points_map: np.ndarray


def scale_from_depths(
    points_base: np.ndarray,
    T_flange_cam: np.ndarray,
    keyframes: Sequence[KeyframeDepths],
    K: np.ndarray,
    *,
    max_px: float = 1.5,
    min_matches: int = 100,
) -> tuple[float, float, int]:
    """Map scale as the ratio of metric to map depths of the same pixels of the VSE keyframes.

    The metric depths come from the image refinement's scene points (base frame)
    seen from the keyframe's metric camera pose ``T_base_flange @ X``; the map
    depths from the VSE's own cloud points measured in that keyframe.

    Parameters
    ----------
    points_base : (M, 3) ndarray
        Refined scene points, base frame, metres.
    T_flange_cam : (4, 4) ndarray
        Refined hand-eye.
    keyframes : sequence of KeyframeDepths
    K : (3, 3) ndarray
        Intrinsics of the undistorted images.
    max_px : float
        A scene point matches the keyframe's cloud pixel nearest to its projection within this distance.
    min_matches : int
        Fewer matched pixels raise.

    Returns
    -------
    scale, spread, n : float, float, int
        Median ratio (metres per map unit), robust relative spread of the per-keyframe
        medians (1.4826 MAD / median), and the number of matched pixels.

    Raises
    ------
    CalibrationError
        Fewer than ``min_matches`` pixels matched.
    """
    P = np.asarray(points_base, dtype=float)
    X = np.asarray(T_flange_cam, dtype=float)
    per_kf, ratios = [], []
    for kf in keyframes:
        if len(kf.pixels) == 0 or len(P) == 0:
            continue
        r = _depth_ratios(P, X, kf, K, max_px)
        if r is not None and len(r) >= 10:
            per_kf.append(float(np.median(r)))
            ratios.append(r)
    n = int(sum(len(r) for r in ratios))
    if n < min_matches:
        raise CalibrationError(f"only {n} pixels of the VSE keyframes matched the refined scene points")
    allr = np.concatenate(ratios)
    scale = float(np.median(allr))
    med = np.asarray(per_kf)
    spread = float(1.4826 * np.median(np.abs(med - np.median(med))) / scale) if len(med) > 1 else float("nan")
    return scale, spread, n


def _depth_ratios(P: np.ndarray, X: np.ndarray, kf: KeyframeDepths, K: np.ndarray, max_px: float) -> np.ndarray | None:
    """Metric over map depth of the scene points matched to one keyframe's cloud pixels (None: no match)."""
    from scipy.spatial import cKDTree

    T_cam_base = invert_pose(np.asarray(kf.T_base_flange, dtype=float) @ X)
    pc = transform_points(T_cam_base, P)
    uv, z_metric = pinhole_pixels(K, pc), pc[:, 2]
    T_cam_map = invert_pose(np.asarray(kf.T_map_cam, dtype=float))
    z_map = (np.asarray(kf.points_map, dtype=float) @ T_cam_map[:3, :3].T + T_cam_map[:3, 3])[:, 2]
    dist, nn = cKDTree(np.asarray(kf.pixels, dtype=float)).query(uv, distance_upper_bound=max_px)
    ok = np.isfinite(dist) & (z_metric > 0)
    if not np.any(ok):
        return None
    zm = z_map[nn[ok]]
    good = zm > 0
    return z_metric[ok][good] / zm[good]
