"""Feature tracks across the images of the platform's rest poses (target-free hand-eye).

SIFT features per image on locally equalised grey images, ratio-test matches
between image pairs checked by a RANSAC fundamental matrix, tracks by
union-find (a track seen twice in one image is dropped), and the linear (DLT)
triangulation that starts the adjustment (docs/calibration.md, "Target-free").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from fgcd_core.imaging import DescriptorMatcher, U8Rounding, clahe, match_descriptors, sift_features, to_gray_u8

__all__ = [
    "MatchConfig",
    "Features",
    "Track",
    "gray_u8",
    "stop_features",
    "undistort_features",
    "pair_list",
    "pair_matches",
    "build_tracks",
    "feature_tracks",
    "triangulate_dlt",
]

#: Local equalisation before SIFT (OpenCV CLAHE clip limit, tiles per side): see :func:`stop_features`.
CLAHE_CLIP, CLAHE_TILES = 3.0, 8
#: An image pair with fewer one-to-one ratio-test matches is not matched.
MIN_PAIR_MATCHES = 20

#: Keypoints ``(N, 2)`` in pixels and their SIFT descriptors ``(N, 128)`` of one image.
Features = tuple[np.ndarray, np.ndarray]
#: One scene point: ``(image_index, (u, v))`` observations, pixels.
Track = list[tuple[int, np.ndarray]]


@dataclass(frozen=True, kw_only=True)
class MatchConfig:
    """How the images are matched into tracks.

    Attributes
    ----------
    ratio : float
        SIFT ratio test (Lowe).
    ransac_px : float
        Fundamental-matrix RANSAC threshold, pixels.
    n_features : int
        SIFT features per image.
    max_points : int
        Keep at most this many tracks (the longest) to bound the run time.
    match_window : int, optional
        None: match every pair of images (a dozen stops). Else the images are a
        sequence along the platform's path, and image ``i`` is matched with
        ``i+1 .. i+match_window`` and, if it is one of ``anchors``, with every
        other anchor.
    anchors : tuple of int
        Indices of the images matched with each other in any case (the stops).
    """

    ratio: float = 0.8
    ransac_px: float = 1.0
    n_features: int = 1500
    max_points: int = 3000
    match_window: int | None = None
    anchors: tuple[int, ...] = ()


def gray_u8(image: np.ndarray) -> np.ndarray:
    """A camera frame as 8-bit grey (Rec. 601 luma for colour; floats in [0, 1] scaled and truncated)."""
    return to_gray_u8(np.asarray(image), rounding=U8Rounding.TRUNCATE_F32)


def stop_features(images: Sequence[np.ndarray], *, n_features: int = 1500) -> list[Features]:
    """SIFT keypoints ``(N, 2)`` and descriptors of every stop image.

    The images are equalised locally (CLAHE) first. Why: SIFT drops extrema
    below a fixed contrast, and on dim stone lit by a lamp that moves with the
    camera the raw images keep mostly large blobs of shading whose centres shift
    as the light moves with the camera, which biases ``X``; equalised images keep
    mostly small-scale texture, which does not move with the light
    (docs/calibration.md, "Target-free"; measurements in docs/lab/2026-11-22-calibrate.md,
    "2026-11-25: the bias explained, the target met").
    """
    return [
        sift_features(clahe(gray_u8(img), clip_limit=CLAHE_CLIP, tiles=CLAHE_TILES), n_features=n_features)
        for img in images
    ]


def undistort_features(features: list[Features], K: np.ndarray, dist: Sequence[float] | None) -> list[Features]:
    """Keypoints of distorted images moved to the ideal pinhole ``K`` (unchanged when ``dist`` is None or zeros)."""
    if dist is None or not np.any(np.asarray(dist, dtype=float) != 0):
        return features
    K_ = np.asarray(K, dtype=float)
    return [
        (
            cv2.undistortPoints(xy.reshape(-1, 1, 2), K_, np.asarray(dist, dtype=float), P=K_).reshape(-1, 2)
            if len(xy)
            else xy,
            desc,
        )
        for xy, desc in features
    ]


def pair_list(n: int, match_window: int | None = None, anchors: Sequence[int] = ()) -> list[tuple[int, int]]:
    """The image pairs ``(i, j)``, ``i < j``, to match (see :class:`MatchConfig`)."""
    if match_window is None:
        return [(i, j) for i in range(n) for j in range(i + 1, n)]
    pairs = {(i, j) for i in range(n) for j in range(i + 1, min(n, i + 1 + int(match_window)))}
    stops = sorted({int(a) for a in (anchors or ()) if 0 <= int(a) < n})
    pairs |= {(a, b) for k, a in enumerate(stops) for b in stops[k + 1 :]}
    return sorted(pairs)


def pair_matches(f_a: Features, f_b: Features, *, ratio: float, ransac_px: float) -> np.ndarray:
    """Index pairs ``(k_a, k_b)`` of ratio-test matches consistent with one fundamental matrix, ``(M, 2)`` int."""
    (xy_a, d_a), (xy_b, d_b) = f_a, f_b
    if len(xy_a) < 8 or len(xy_b) < 8:
        return np.zeros((0, 2), int)
    # approximate nearest neighbours (kd-trees) instead of brute force: the same matches at a
    # fraction of the cost; one-to-one: keypoints of b matched twice are dropped
    idx = match_descriptors(d_a, d_b, ratio=ratio, matcher=DescriptorMatcher.FLANN, one_to_one=True)
    if len(idx) < MIN_PAIR_MATCHES:
        return np.zeros((0, 2), int)
    _F, mask = cv2.findFundamentalMat(xy_a[idx[:, 0]], xy_b[idx[:, 1]], cv2.FM_RANSAC, ransac_px, 0.999)
    if mask is None:
        return np.zeros((0, 2), int)
    return idx[mask.ravel().astype(bool)]


def build_tracks(
    features: Sequence[Features], pairs: Sequence[tuple[int, int]], matches: Sequence[np.ndarray]
) -> list[list[tuple[int, int]]]:
    """Union-find over ``(image, keypoint)`` nodes; tracks seen twice in one image are dropped.

    Returns
    -------
    list of list of (int, int)
        Each track as ``(image_index, keypoint_index)`` members, at least two images.
    """
    offsets = np.cumsum([0] + [len(f[0]) for f in features])
    parent = np.arange(offsets[-1])

    def find(a: int) -> int:
        root = a
        while parent[root] != root:
            root = parent[root]
        while parent[a] != root:
            parent[a], a = root, parent[a]
        return root

    for (i, j), m in zip(pairs, matches):
        for ka, kb in m:
            ra, rb = find(offsets[i] + ka), find(offsets[j] + kb)
            if ra != rb:
                parent[rb] = ra
    groups: dict[int, list[tuple[int, int]]] = {}
    for img in range(len(features)):
        for k in range(len(features[img][0])):
            groups.setdefault(find(offsets[img] + k), []).append((img, k))
    out = []
    for members in groups.values():
        imgs = [m[0] for m in members]
        if len(members) >= 2 and len(set(imgs)) == len(imgs):
            out.append(members)
    return out


def feature_tracks(
    images: Sequence[np.ndarray],
    K: np.ndarray,
    *,
    dist: Sequence[float] | None = None,
    config: MatchConfig = MatchConfig(),
) -> list[Track]:
    """Tracks of undistorted pixels across the images, the longest first (at most ``config.max_points``).

    Parameters
    ----------
    images : sequence of N images
        Grey or colour, uint8 or float.
    K : (3, 3) ndarray
        Intrinsic matrix; with ``dist`` the keypoints are undistorted to it.
    dist : sequence of float, optional
        OpenCV distortion coefficients if the images are *not* undistorted.
    config : MatchConfig

    Returns
    -------
    list of Track
    """
    features = undistort_features(stop_features(images, n_features=config.n_features), K, dist)
    pairs = pair_list(len(images), config.match_window, config.anchors)
    matches = [pair_matches(features[i], features[j], ratio=config.ratio, ransac_px=config.ransac_px) for i, j in pairs]
    tracks = build_tracks(features, pairs, matches)
    tracks.sort(key=len, reverse=True)
    return [[(img, features[img][0][k]) for img, k in members] for members in tracks[: config.max_points]]


def triangulate_dlt(P_list: Sequence[np.ndarray], uv: Sequence[np.ndarray]) -> np.ndarray:
    """Linear (DLT) triangulation of one point from several views.

    Parameters
    ----------
    P_list : sequence of (3, 4) ndarray
        Projection matrices ``K [R | t]``.
    uv : sequence of (2,) ndarray
        The point's pixel in each view.

    Returns
    -------
    (3,) ndarray
        The point (NaN when at infinity).
    """
    rows = []
    for P, (u, v) in zip(P_list, uv):
        rows.append(u * P[2] - P[0])
        rows.append(v * P[2] - P[1])
    _, _, vt = np.linalg.svd(np.asarray(rows))
    Xh = vt[-1]
    return Xh[:3] / Xh[3] if abs(Xh[3]) > 1e-12 else np.full(3, np.nan)
