"""The engine's map: landmark positions by track id, the keyframes that observe them, and new landmarks
(triangulated between keyframes, or lifted with a depth image)."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from fgcd_cli.vse.semidense import SemiDenseDepth
from fgcd_cli.vse.twoview import ray_angles_rad, triangulate_pair
from fgcd_core.camera import PinholeCamera
from fgcd_core.se3 import invert_pose, transform_points

__all__ = ["LandmarkMap", "KeyframeRecord", "median_depth", "triangulate_new", "lift_with_depth"]

_INITIAL_CAPACITY = 1024


class LandmarkMap:
    """Landmark positions indexed by track id (a track and its landmark share the id).

    Attributes
    ----------
    points : (C, 3) float64 ndarray
        Map-frame positions, NaN where none; ``C`` grows with the ids handed out.
    ok : (C,) bool ndarray
        Whether the track has a landmark.
    next_id : int
        The next track id to hand out.
    """

    def __init__(self) -> None:
        self.points = np.full((_INITIAL_CAPACITY, 3), np.nan)
        self.ok = np.zeros(_INITIAL_CAPACITY, bool)
        self.next_id = 0

    def _ensure_capacity(self, n: int) -> None:
        if n <= len(self.points):
            return
        cap = max(n, 2 * len(self.points))
        points = np.full((cap, 3), np.nan)
        points[: len(self.points)] = self.points
        ok = np.zeros(cap, bool)
        ok[: len(self.ok)] = self.ok
        self.points, self.ok = points, ok

    def new_ids(self, k: int) -> np.ndarray:
        """``k`` fresh track ids (int64), room for their landmarks included."""
        ids = np.arange(self.next_id, self.next_id + k, dtype=np.int64)
        self.next_id += k
        self._ensure_capacity(self.next_id)
        return ids

    def set(self, ids: np.ndarray, X: np.ndarray) -> None:
        """Landmarks ``ids`` (K,) at map points ``X`` (K, 3)."""
        self.points[ids] = X
        self.ok[ids] = True


@dataclass(kw_only=True)
class KeyframeRecord:
    """The engine's keyframe (mutable: bundle adjustment moves its pose and drops observations).

    Attributes
    ----------
    T_cam_map : (4, 4) ndarray
        Map-to-camera pose.
    image, image_u8 : (H, W) ndarrays
        Raw grey image, float32 in [0, 1] and uint8.
    undist : (H, W) float32 ndarray
        The image remapped to the ideal pinhole.
    track_ids : (n,) int64 ndarray
        Tracks observed here; ``uv`` (n, 2) their undistorted and ``uv_raw`` (n, 2) raw pixels.
    depth : (H, W) ndarray or None
        RGB-D only: z-depth in metres.
    semidense : SemiDenseDepth or None
        The keyframe's per-pixel depths once computed.
    semidense_stereo : tuple or None
        What they were searched with: the partner keyframes' ids and the poses of
        the keyframe and its partners at the time (``vse.cloud``'s refresh rule).
    orb_desc, orb_ids : ndarrays or None
        ORB descriptors of the keyframe tied to the landmarks they lie on (relocalisation).
    """

    id: int
    T_cam_map: np.ndarray
    image: np.ndarray
    image_u8: np.ndarray
    undist: np.ndarray
    timestamp_s: float
    track_ids: np.ndarray
    uv: np.ndarray
    uv_raw: np.ndarray
    depth: np.ndarray | None = None
    semidense: SemiDenseDepth | None = None
    semidense_stereo: tuple | None = field(default=None, repr=False)
    orb_desc: np.ndarray | None = None
    orb_ids: np.ndarray | None = None
    published_image: np.ndarray | None = field(default=None, repr=False)

    def landmark_ids(self, landmarks: LandmarkMap) -> np.ndarray:
        """Ids of the tracks observed here that have a landmark."""
        return self.track_ids[landmarks.ok[self.track_ids]]


def median_depth(kf: KeyframeRecord, landmarks: LandmarkMap) -> float:
    """Median z-depth (map units) of the landmarks a keyframe observes; 1 when it has none in front."""
    ids = kf.landmark_ids(landmarks)
    if len(ids) == 0:
        return 1.0
    z = transform_points(kf.T_cam_map, landmarks.points[ids])[:, 2]
    z = z[z > 0]
    return float(np.median(z)) if len(z) else 1.0


def _first_observations(cand: np.ndarray, keyframes: list[KeyframeRecord]) -> tuple[np.ndarray, np.ndarray]:
    """For each track id in ``cand`` (K,): the index of the first of ``keyframes`` observing it (-1: none)
    and its undistorted pixel there (K, 2)."""
    first_uv = np.full((len(cand), 2), np.nan)
    first_kf = np.full(len(cand), -1)
    for k, other in enumerate(keyframes):
        pos = np.searchsorted(other.track_ids, cand) if np.all(np.diff(other.track_ids) >= 0) else None
        if pos is None:
            order = np.argsort(other.track_ids)
            sorted_ids = other.track_ids[order]
            p = np.searchsorted(sorted_ids, cand)
            p = np.clip(p, 0, len(sorted_ids) - 1)
            hit = (sorted_ids[p] == cand) if len(sorted_ids) else np.zeros(len(cand), bool)
            rows = order[p]
        else:
            p = np.clip(pos, 0, max(len(other.track_ids) - 1, 0))
            hit = (other.track_ids[p] == cand) if len(other.track_ids) else np.zeros(len(cand), bool)
            rows = p
        newhit = hit & (first_kf < 0)
        first_kf[newhit] = k
        first_uv[newhit] = other.uv[rows[newhit]]
    return first_kf, first_uv


def triangulate_new(
    kf: KeyframeRecord,
    keyframes: list[KeyframeRecord],
    landmarks: LandmarkMap,
    K: np.ndarray,
    *,
    min_angle_deg: float,
    reproj_inlier_px: float,
) -> None:
    """Landmarks for the tracks of ``kf`` that have none, from their first keyframe and ``kf``.

    Parameters
    ----------
    kf : KeyframeRecord
        The new keyframe (the last of ``keyframes``).
    keyframes : list of KeyframeRecord
        All keyframes, oldest first.
    K : (3, 3) ndarray
        Pinhole intrinsics (undistorted pixels).
    min_angle_deg : float
        Ray angle a landmark needs (the precision of the front-end's keypoints).
    reproj_inlier_px : float
        Reprojection tolerance of :func:`~fgcd_cli.vse.twoview.triangulate_pair`.
    """
    ids = kf.track_ids
    need = ~landmarks.ok[ids]
    if not np.any(need):
        return
    cand = ids[need]
    uv_now = kf.uv[need]
    first_kf, first_uv = _first_observations(cand, keyframes[:-1])
    for k in np.unique(first_kf[first_kf >= 0]):
        sel = first_kf == k
        T0 = keyframes[k].T_cam_map
        X, good, _ = triangulate_pair(
            K, T0, kf.T_cam_map, first_uv[sel], uv_now[sel], reproj_inlier_px=reproj_inlier_px
        )
        angles = ray_angles_rad(X, invert_pose(T0)[:3, 3], invert_pose(kf.T_cam_map)[:3, 3])
        good &= np.degrees(angles) > min_angle_deg
        landmarks.set(cand[sel][good], X[good])


def lift_with_depth(
    camera: PinholeCamera, landmarks: LandmarkMap, kf: KeyframeRecord, ids: np.ndarray, pts_raw: np.ndarray
) -> None:
    """Landmarks from the keyframe's depth image for the tracks ``ids`` (K,) at raw pixels ``pts_raw`` (K, 2)
    that have none (RGB-D)."""
    if kf.depth is None or len(ids) == 0:
        return
    need = ~landmarks.ok[ids]
    if not np.any(need):
        return
    pts = pts_raw[need]
    d = cv2.remap(
        kf.depth.astype(np.float32),
        pts[:, 0].astype(np.float32).reshape(-1, 1),
        pts[:, 1].astype(np.float32).reshape(-1, 1),
        cv2.INTER_NEAREST,
    ).ravel()
    # reject depth discontinuities: the 3x3 neighbourhood must agree within 1 %
    dil = cv2.dilate(kf.depth.astype(np.float32), np.ones((3, 3), np.uint8))
    ero = cv2.erode(kf.depth.astype(np.float32), np.ones((3, 3), np.uint8))
    xi = np.clip(np.round(pts[:, 0]).astype(int), 0, kf.depth.shape[1] - 1)
    yi = np.clip(np.round(pts[:, 1]).astype(int), 0, kf.depth.shape[0] - 1)
    smooth = (dil[yi, xi] - ero[yi, xi]) < 0.01 * np.maximum(d, 1e-6)
    ok = np.isfinite(d) & (d > 0) & smooth
    Xc = camera.unproject(pts[ok], d[ok])
    X = transform_points(invert_pose(kf.T_cam_map), Xc)
    landmarks.set(ids[need][ok], X)
