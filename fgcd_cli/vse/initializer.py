"""Map initialisation: two views with enough translation (monocular) or the first textured frame (RGB-D).

Both start from a reference frame with enough trackable corners; a scene
that offers too few of them for ``VseConfig.init_fail_frames`` frames makes
the engine ``failed`` (docs/vse.md, "Design and why", item 6). The monocular
map needs translation: the two views must not be explainable by a rotation
alone, and the median triangulation angle must reach
``VseConfig.init_min_parallax_deg`` (item 2). Its scale is set by a median
scene depth of 1 map unit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

from fgcd_cli.vse.frontend import Tracks
from fgcd_cli.vse.landmarks import lift_with_depth
from fgcd_cli.vse.twoview import planar_two_view, rotation_only_residual_px, triangulate_pair
from fgcd_cli.vse.types import VseStatus
from fgcd_core.se3 import make_pose

if TYPE_CHECKING:
    from fgcd_cli.vse.engine_view import EngineView

__all__ = ["TwoViewInitializer", "DepthInitializer"]


@dataclass(frozen=True, kw_only=True)
class _Reference:
    """The first view of a two-view initialisation."""

    ids: np.ndarray
    uv: np.ndarray  # undistorted pixels
    uv_raw: np.ndarray
    image: np.ndarray
    u8: np.ndarray
    timestamp_s: float


class _TextureGate:
    """Reference frames with enough corners; counts the frames without (``failed`` after too many)."""

    def __init__(self) -> None:
        self.frames_without_texture = 0

    def reference_tracks(self, eng: EngineView, img_u8: np.ndarray) -> bool:
        """Replace the engine's tracks by fresh corners of ``img_u8``; whether there are enough."""
        cfg = eng.config
        eng.tracks = Tracks()
        eng.detect(img_u8, cfg.max_features)
        n = len(eng.tracks)
        if n >= cfg.init_min_inliers:
            self.frames_without_texture = 0
            return True
        self.frames_without_texture += 1
        if self.frames_without_texture >= cfg.init_fail_frames:
            eng.status = VseStatus.FAILED
            eng.message = (
                f"failed: only {n} trackable corners per frame for {self.frames_without_texture} frames "
                f"(need {cfg.init_min_inliers}); the scene is too weakly textured for visual SLAM"
            )
            eng.tracks = Tracks()
        else:
            eng.message = f"initialising: only {n} trackable corners (need {cfg.init_min_inliers}); too little texture"
        return False


class TwoViewInitializer(_TextureGate):
    """Monocular initialisation: a reference frame, then the first later frame with enough parallax."""

    def __init__(self) -> None:
        super().__init__()
        self.reference: _Reference | None = None

    def step(self, eng: EngineView, img_u8: np.ndarray, frame_image: np.ndarray) -> None:
        """Try to initialise the map with this frame (``eng.message`` says why not)."""
        cfg = eng.config
        if self.reference is None or len(eng.tracks) < cfg.init_min_inliers:
            self._set_reference(eng, img_u8, frame_image)
            return
        eng.follow(img_u8)
        if len(eng.tracks) < cfg.init_min_inliers:
            eng.message = f"initialising: only {len(eng.tracks)} corners survived; restarting from this frame"
            self._set_reference(eng, img_u8, frame_image)
            return
        id_to_row = {int(i): k for k, i in enumerate(self.reference.ids)}
        rows = np.array([id_to_row[int(i)] for i in eng.tracks.ids])
        p0 = self.reference.uv[rows]
        p1 = eng.undistort_pts(eng.tracks.pts)
        motion = self._relative_motion(eng, p0, p1)
        if motion is None:
            return
        T10, inl = motion
        self._make_map(eng, img_u8, frame_image, T10, eng.tracks.ids[inl], p0[inl], p1[inl])

    def _set_reference(self, eng: EngineView, img_u8: np.ndarray, frame_image: np.ndarray) -> None:
        if not self.reference_tracks(eng, img_u8):
            self.reference = None
            return
        self.reference = _Reference(
            ids=eng.tracks.ids.copy(),
            uv=eng.undistort_pts(eng.tracks.pts),
            uv_raw=eng.tracks.pts.copy(),
            image=frame_image,
            u8=img_u8,
            timestamp_s=eng.timestamp,
        )
        eng.message = "initialising: reference frame set, waiting for parallax"

    @staticmethod
    def _relative_motion(eng: EngineView, p0: np.ndarray, p1: np.ndarray):
        """``(T10, inliers)``: camera 1 from camera 0 at a median depth of 1, or None (message set)."""
        cfg, K = eng.config, eng.K
        rot_residual_px = rotation_only_residual_px(K, p0, p1)
        if rot_residual_px < math.radians(cfg.init_min_translation_parallax_deg) * K[0, 0]:
            eng.message = (
                f"initialising: the views differ by a rotation only (residual {rot_residual_px:.2f} px); "
                "need parallax from translation, pure rotation cannot initialise"
            )
            return None
        E, mask = cv2.findEssentialMat(p0, p1, K, method=cv2.RANSAC, prob=0.999, threshold=1.0)
        if E is None or E.shape != (3, 3):
            eng.message = "initialising: no essential matrix yet (move the camera sideways)"
            return None
        # distanceThresh: OpenCV's default (50 baselines) drops points far away relative to a
        # short exploration baseline (1.5 cm at 1.2 m is 80 baselines); keep all but infinity
        _, R, t, mask2, _ = cv2.recoverPose(E, p0, p1, K, distanceThresh=1e6, mask=mask.copy())
        inl = mask2.ravel() > 0
        R, t, inl = planar_two_view(
            K, p0, p1, R, t, inl, planar_ratio=cfg.init_planar_ratio, reproj_inlier_px=cfg.reproj_inlier_px
        )
        if inl.sum() < cfg.init_min_inliers:
            eng.message = f"initialising: {int(inl.sum())} inliers, need {cfg.init_min_inliers}"
            return None
        T10 = make_pose(R, t.ravel())  # cam1 <- cam0, unit baseline
        X, good, angles = triangulate_pair(K, np.eye(4), T10, p0[inl], p1[inl], reproj_inlier_px=cfg.reproj_inlier_px)
        med_par = float(np.degrees(np.median(angles))) if len(angles) else 0.0
        if med_par < cfg.init_min_parallax_deg or good.sum() < cfg.init_min_inliers:
            eng.message = (
                f"initialising: median parallax {med_par:.2f} deg < {cfg.init_min_parallax_deg} deg "
                "(the motion needs translation, pure rotation cannot initialise)"
            )
            return None
        T10[:3, 3] /= float(np.median(X[good][:, 2]))
        return T10, inl

    def _make_map(
        self,
        eng: EngineView,
        img_u8: np.ndarray,
        frame_image: np.ndarray,
        T10: np.ndarray,
        ids: np.ndarray,
        uv0: np.ndarray,
        uv1: np.ndarray,
    ) -> None:
        """Keyframes 0 (the reference) and 1 (this frame), the landmarks of the inlier tracks ``ids`` (N,)
        at ``uv0``/``uv1`` (N, 2)."""
        ref = self.reference
        eng.add_keyframe(ref.u8, ref.image, np.eye(4), ref.ids, ref.uv_raw, ref.timestamp_s, None)
        # keep only tracks that survived into this frame in kf1
        kf1 = eng.add_keyframe(img_u8, frame_image, T10, eng.tracks.ids, eng.tracks.pts, eng.timestamp, None)
        X, good, _ = triangulate_pair(eng.K, np.eye(4), T10, uv0, uv1, reproj_inlier_px=eng.config.reproj_inlier_px)
        eng.landmarks.set(ids[good], X[good])
        eng.run_ba()
        eng.T_cam_map = eng.kfs[-1].T_cam_map.copy()
        eng.status = VseStatus.TRACKING
        eng.message = f"initialised with {int(good.sum())} landmarks"
        self.reference = None
        eng.detect(img_u8, eng.config.max_features - len(eng.tracks))
        # new corners are observed in kf1
        eng.record_new_observations(kf1)
        eng.after_keyframe()


class DepthInitializer(_TextureGate):
    """RGB-D initialisation: the first textured frame is the map origin, its landmarks from the depth image."""

    def step(self, eng: EngineView, img_u8: np.ndarray, frame_image: np.ndarray) -> None:
        """Initialise the map with this frame when it has enough corners."""
        if not self.reference_tracks(eng, img_u8):
            return
        tracks = eng.tracks
        kf = eng.add_keyframe(img_u8, frame_image, np.eye(4), tracks.ids, tracks.pts, eng.timestamp, eng.depth)
        lift_with_depth(eng.camera, eng.landmarks, kf, tracks.ids, tracks.pts)
        eng.T_cam_map = np.eye(4)
        eng.status = VseStatus.TRACKING
        eng.message = f"initialised from depth with {int(eng.landmarks.ok[tracks.ids].sum())} landmarks"
        eng.after_keyframe()
