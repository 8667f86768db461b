"""Recovery after tracking loss: the pose of a frame found again against the keyframes.

Keyframes nearest the last known pose are tried first (at most
:data:`MAX_KEYFRAMES_TRIED`): KLT from the keyframe started at the landmarks'
projections at the last pose (the robot moves slowly, the view usually comes
back nearby), then ORB matches to the keyframe's landmarks with PnP-RANSAC for
a coarse pose followed by the same KLT step (docs/vse.md, "Design and why",
item 5). Every keyframe is indexed for this when it is made: its ORB
features tied to the landmark observed within :data:`ORB_TIE_PX`.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import cv2
import numpy as np

from fgcd_cli.vse.frontend import Tracks
from fgcd_cli.vse.landmarks import KeyframeRecord, LandmarkMap
from fgcd_cli.vse.types import VseStatus
from fgcd_core.se3 import invert_pose, make_pose

if TYPE_CHECKING:
    from fgcd_cli.vse.engine_view import EngineView

__all__ = ["Relocalizer", "MAX_KEYFRAMES_TRIED", "ORB_TIE_PX"]

MAX_KEYFRAMES_TRIED = 6
ORB_TIE_PX = 3.0


class Relocalizer:
    """Keyframe index (ORB) and the relocalisation of a lost engine."""

    def __init__(self) -> None:
        self.orb = cv2.ORB_create(nfeatures=1500)

    def index_keyframe(self, kf: KeyframeRecord, landmarks: LandmarkMap) -> None:
        """ORB descriptors of a new keyframe tied to the landmarks observed within ``ORB_TIE_PX``."""
        ok = landmarks.ok[kf.track_ids]
        kp, desc = self.orb.detectAndCompute(kf.image_u8, None)
        if desc is not None and ok.sum() > 0:
            from scipy.spatial import cKDTree

            xy = np.array([p.pt for p in kp])
            dist, nn = cKDTree(kf.uv_raw[ok]).query(xy, distance_upper_bound=ORB_TIE_PX)
            hit = np.isfinite(dist)
            kf.orb_desc = desc[hit]
            kf.orb_ids = kf.track_ids[ok][nn[hit]]

    def relocalize(self, eng: EngineView, img_u8: np.ndarray, frame_image: np.ndarray) -> None:
        """Find the pose of a frame after tracking loss; on success the frame becomes a keyframe."""
        eng.lost_frames += 1
        c_last = invert_pose(eng.T_cam_map)[:3, 3]
        kfs = eng.kfs
        order = sorted(range(len(kfs)), key=lambda k: np.linalg.norm(invert_pose(kfs[k].T_cam_map)[:3, 3] - c_last))[
            :MAX_KEYFRAMES_TRIED
        ]
        cur_orb = None
        for k in order:
            kf = kfs[k]
            T = self._locate_from_keyframe(eng, kf, img_u8, eng.T_cam_map)
            if T is None:
                if cur_orb is None:
                    kp, desc = self.orb.detectAndCompute(img_u8, None)
                    cur_orb = (np.array([p.pt for p in kp]) if kp else np.zeros((0, 2)), desc)
                T_coarse = self._orb_pose(eng, kf, *cur_orb)
                if T_coarse is not None:
                    T = self._locate_from_keyframe(eng, kf, img_u8, T_coarse)
            if T is None:
                continue
            eng.T_cam_map = T
            eng.velocity = np.eye(4)
            eng.status = VseStatus.TRACKING
            eng.message = f"relocalised against keyframe {kf.id} after {eng.lost_frames - 1} lost frames"
            eng.lost_frames = 0
            t0 = time.perf_counter()
            eng.insert_keyframe(img_u8, frame_image)
            eng.mapping_time += time.perf_counter() - t0
            return
        eng.message = f"lost for {eng.lost_frames} frames: no keyframe matches the view"

    def _locate_from_keyframe(
        self, eng: EngineView, kf: KeyframeRecord, img_u8: np.ndarray, T_guess: np.ndarray
    ) -> np.ndarray | None:
        """Pose from KLT tracks keyframe -> frame started at the projections at ``T_guess``."""
        cfg = eng.config
        ok_lm = eng.landmarks.ok[kf.track_ids]
        ids_kf, uv_kf = kf.track_ids[ok_lm], kf.uv_raw[ok_lm]
        if len(ids_kf) < cfg.min_tracked_landmarks:
            return None
        proj, inview = eng.project(T_guess, eng.landmarks.points[ids_kf])
        if inview.sum() < cfg.min_tracked_landmarks:
            return None
        pts, okk = eng.frontend.klt.track(kf.image_u8, img_u8, uv_kf[inview], proj[inview])
        if okk.sum() < cfg.min_tracked_landmarks:
            return None
        tr = Tracks()
        tr.add(ids_kf[inview][okk], pts[okk])
        eng.frontend.describe(tr, img_u8, self.orb)
        saved = eng.tracks
        eng.tracks = tr
        T = eng.locate(T_guess)
        if T is None:
            eng.tracks = saved
        return T

    @staticmethod
    def _orb_pose(eng: EngineView, kf: KeyframeRecord, kp_xy: np.ndarray, desc: np.ndarray | None) -> np.ndarray | None:
        """Coarse pose from ORB matches between a keyframe's landmarks and the frame (keypoints ``kp_xy`` (K, 2))."""
        cfg = eng.config
        if desc is None or kf.orb_desc is None or len(kf.orb_desc) < cfg.min_tracked_landmarks:
            return None
        matches = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(kf.orb_desc, desc, k=2)
        good = [m[0] for m in matches if len(m) == 2 and m[0].distance < 0.8 * m[1].distance and m[0].distance < 64]
        if len(good) < cfg.min_tracked_landmarks:
            return None
        lm_ids = kf.orb_ids[[m.queryIdx for m in good]]
        X = eng.landmarks.points[lm_ids]
        uv = eng.undistort_pts(kp_xy[[m.trainIdx for m in good]])
        succ, rvec, tvec, inl = cv2.solvePnPRansac(
            X, uv, eng.K, None, iterationsCount=300, reprojectionError=8.0, confidence=0.999
        )
        if not succ or inl is None or len(inl) < cfg.min_tracked_landmarks // 2:
            return None
        return make_pose(cv2.Rodrigues(rvec)[0], tvec.ravel())
