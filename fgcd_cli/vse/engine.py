"""The visual SLAM engine and its variants: monocular (semi-dense), sparse (ORB) and RGB-D.

:class:`VisualSlamEngine` runs one pipeline; a variant is the choice of three
parts passed to it as objects (docs/vse.md, "Engines"):

* the front-end (:mod:`~fgcd_cli.vse.frontend`): KLT corners or ORB matches;
* the depth source (:mod:`~fgcd_cli.vse.depth_source`): two-view
  triangulation (with the two-view initialisation) or the depth image;
* the cloud builder (:mod:`~fgcd_cli.vse.cloud`): semi-dense keyframe depth,
  depth-image pixels, or the sparse landmarks.

:class:`MonocularVSE`, :class:`SparseVSE` and :class:`RgbdVSE` compose them;
:func:`make_engine` picks one by :class:`VseVariant`.

Pipeline for each frame (:meth:`VisualSlamEngine.process`):

1. follow the tracks of the previous frame (KLT, or ORB matching);
2. before the map exists: initialisation (:mod:`~fgcd_cli.vse.initializer`);
3. afterwards: pose by PnP-RANSAC on the tracked landmarks, refined by a
   robust motion-only Gauss-Newton;
4. new keyframe when the baseline over the scene depth, the rotation, or the
   fraction of still-tracked landmarks asks for it; then new landmarks, new
   corners, the windowed bundle adjustment (:mod:`~fgcd_cli.vse.mapping`) and
   the cloud builder's per-keyframe depths;
5. when a frame cannot be located the state is ``lost``; later frames are
   relocalised against recent keyframes (:mod:`~fgcd_cli.vse.relocalizer`).
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import replace
from enum import StrEnum

import cv2
import numpy as np

from fgcd_cli.vse.ba import outlier_threshold_px, projection_residuals, refine_pose
from fgcd_cli.vse.cloud import CloudBuilder, DepthImageCloud, LandmarkCloud, SemiDenseCloud
from fgcd_cli.vse.depth_source import DepthImage, DepthSource, Triangulation
from fgcd_cli.vse.frontend import KltTracking, OrbTracking, TrackingFrontend, Tracks
from fgcd_cli.vse.landmarks import KeyframeRecord, LandmarkMap, median_depth
from fgcd_cli.vse.mapping import windowed_bundle_adjustment
from fgcd_cli.vse.relocalizer import Relocalizer
from fgcd_cli.vse.types import Keyframe, MapCloud, VseConfig, VseState, VseStatus
from fgcd_core.camera import PinholeCamera
from fgcd_core.imaging import to_gray_f32, to_gray_u8
from fgcd_core.se3 import invert_pose, make_pose, rotation_angle_rad, transform_points

__all__ = ["VisualSlamEngine", "MonocularVSE", "SparseVSE", "RgbdVSE", "VseVariant", "make_engine"]

_FPS_WINDOW = 30  # frames the published frame rates average over


class VisualSlamEngine:
    """The engine: one pipeline, its variant given by its parts.

    Parameters
    ----------
    camera : PinholeCamera
        Intrinsics of the frames (from calibration).
    config : VseConfig
        Options.
    frontend : TrackingFrontend
        Feature tracking (:class:`~fgcd_cli.vse.frontend.KltTracking` or ``OrbTracking``).
    depth_source : DepthSource
        Depth of new landmarks (:class:`~fgcd_cli.vse.depth_source.Triangulation` or ``DepthImage``).
    cloud : CloudBuilder
        The published cloud (:mod:`~fgcd_cli.vse.cloud`).

    Notes
    -----
    The attributes below ``reset`` are the pipeline's state, shared with its
    parts; callers use :meth:`process`, :meth:`state` and :meth:`reset`.
    """

    def __init__(
        self,
        camera: PinholeCamera,
        *,
        config: VseConfig = VseConfig(),
        frontend: TrackingFrontend,
        depth_source: DepthSource,
        cloud: CloudBuilder,
    ) -> None:
        if not isinstance(camera, PinholeCamera):
            raise TypeError("camera must be a fgcd_core.camera.PinholeCamera")
        self.camera = camera
        self.config = config
        self.K = camera.K
        if camera.has_distortion:
            self._undist_maps = cv2.initUndistortRectifyMap(
                camera.K, np.array(camera.dist), None, camera.K, (camera.width, camera.height), cv2.CV_32FC1
            )
        else:
            self._undist_maps = None
        self.frontend = frontend
        self.depth_source = depth_source
        self.cloud_builder = cloud
        self.relocalizer = Relocalizer()
        self.reset()

    # ------------------------------------------------------------------ public API
    def reset(self) -> None:
        """Forget the map and start initialising again from the next frame."""
        self.status = VseStatus.INITIALIZING
        self.message = "waiting for frames"
        self.tracks = Tracks()
        self.landmarks = LandmarkMap()
        self.kfs: list[KeyframeRecord] = []
        self._next_kf_id = 0
        self._prev_u8: np.ndarray | None = None
        self.T_cam_map: np.ndarray | None = None
        self.velocity = np.eye(4)
        self._frames = 0
        self.lost_frames = 0
        self._track_times: deque[float] = deque(maxlen=_FPS_WINDOW)
        self._total_times: deque[float] = deque(maxlen=_FPS_WINDOW)
        self.timestamp = float("nan")
        self.depth: np.ndarray | None = None
        self.mapping_time = 0.0
        self.depth_source.reset()
        self.cloud_builder.reset()
        self._state = self._snapshot()

    def state(self) -> VseState:
        """The latest published snapshot (cheap; safe to hold)."""
        return self._state

    @property
    def metric(self) -> bool:
        """Map units are metres; :meth:`process` then needs a depth image with every frame."""
        return self.depth_source.metric

    def process(self, frame_image: np.ndarray, timestamp_s: float, depth: np.ndarray | None = None) -> VseState:
        """Process one frame synchronously and return the new state.

        Parameters
        ----------
        frame_image : (H, W) or (H, W, 3|4) ndarray
            The camera image (raw, with the camera's distortion): uint8, or
            float32/float64 in [0, 1] (grey conversion: :mod:`fgcd_core.imaging`).
        timestamp_s : float
            Capture time, seconds.
        depth : (H, W) ndarray, optional
            z-depth in metres, 0 where unknown (required by a metric engine, :class:`RgbdVSE`).
        """
        t0 = time.perf_counter()
        img_u8 = to_gray_u8(frame_image)
        if img_u8.shape != (self.camera.height, self.camera.width):
            raise ValueError(f"frame is {img_u8.shape}, camera is {(self.camera.height, self.camera.width)}")
        self._frames += 1
        if self.status == VseStatus.FAILED:
            self._state = self._snapshot()
            return self._state
        self.timestamp = float(timestamp_s)
        self.mapping_time = 0.0
        self.depth = None if depth is None else np.asarray(depth, dtype=float)
        if self.depth_source.metric and self.depth is None:
            raise ValueError("the RGB-D engine needs a depth image with every frame")
        if self.T_cam_map is None:
            self.depth_source.initialize(self, img_u8, frame_image)
        elif self.status == VseStatus.LOST:
            self.relocalizer.relocalize(self, img_u8, frame_image)
        else:
            self._track(img_u8, frame_image)
        self._prev_u8 = img_u8
        # the snapshot rebuilds the cloud after a keyframe (cross-keyframe fusion): mapping time
        t_snap = time.perf_counter()
        state = self._snapshot()
        dt = time.perf_counter() - t0
        self.mapping_time += time.perf_counter() - t_snap
        self._total_times.append(dt)
        self._track_times.append(max(dt - self.mapping_time, 1e-6))
        self._state = replace(state, track_fps=_fps(self._track_times), overall_fps=_fps(self._total_times))
        return self._state

    # ------------------------------------------------------------------ shared with the parts
    def undistort_pts(self, pts: np.ndarray) -> np.ndarray:
        """Undistorted pixels (N, 2) of raw pixels (N, 2)."""
        if self._undist_maps is None or len(pts) == 0:
            return np.asarray(pts, dtype=float).reshape(-1, 2)
        rays = self.camera.normalized_rays(pts)
        return np.column_stack([rays[:, 0] * self.K[0, 0] + self.K[0, 2], rays[:, 1] * self.K[1, 1] + self.K[1, 2]])

    def distort_px(self, uv_undist: np.ndarray) -> np.ndarray:
        """Raw-image pixels (N, 2) of undistorted pixels (identity without distortion)."""
        if not self.camera.has_distortion or len(uv_undist) == 0:
            return uv_undist
        rays = np.column_stack(
            [
                (uv_undist[:, 0] - self.K[0, 2]) / self.K[0, 0],
                (uv_undist[:, 1] - self.K[1, 2]) / self.K[1, 1],
                np.ones(len(uv_undist)),
            ]
        )
        return self.camera.project(rays)[0]

    def project(self, T_cam_map: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Raw pixels (N, 2) of map points ``X`` (N, 3) and whether they are in view (N,)."""
        return self.camera.project(transform_points(T_cam_map, X))

    def follow(self, img_u8: np.ndarray, guess: np.ndarray | None = None) -> None:
        """Move the tracks into the new image, dropping those lost."""
        self.frontend.follow(self.tracks, self._prev_u8, img_u8, guess)

    def detect(self, img_u8: np.ndarray, max_new: int) -> None:
        """New tracks (at most ``max_new``) away from the existing ones."""
        self.frontend.detect(self.tracks, img_u8, max_new, self.landmarks.new_ids)

    def add_keyframe(
        self,
        img_u8: np.ndarray,
        frame_image: np.ndarray,
        T_cam_map: np.ndarray,
        ids: np.ndarray,
        uv_raw: np.ndarray,
        timestamp_s: float,
        depth: np.ndarray | None,
    ) -> KeyframeRecord:
        """Append a keyframe observing tracks ``ids`` (n,) at raw pixels ``uv_raw`` (n, 2)."""
        img_f = to_gray_f32(frame_image)
        kf = KeyframeRecord(
            id=self._next_kf_id,
            T_cam_map=T_cam_map.copy(),
            image=img_f,
            image_u8=img_u8,
            undist=img_f if self._undist_maps is None else cv2.remap(img_f, *self._undist_maps, cv2.INTER_LINEAR),
            timestamp_s=timestamp_s,
            track_ids=np.asarray(ids, np.int64).copy(),
            uv=self.undistort_pts(uv_raw),
            uv_raw=np.asarray(uv_raw, float).copy(),
            depth=None if depth is None else np.asarray(depth, float),
        )
        self._next_kf_id += 1
        self.kfs.append(kf)
        return kf

    def run_ba(self) -> None:
        """Windowed bundle adjustment of the latest keyframes."""
        windowed_bundle_adjustment(self)

    def record_new_observations(self, kf: KeyframeRecord) -> None:
        """Add tracks born in this keyframe to its observation list."""
        new = ~np.isin(self.tracks.ids, kf.track_ids)
        if np.any(new):
            kf.track_ids = np.concatenate([kf.track_ids, self.tracks.ids[new]])
            kf.uv_raw = np.vstack([kf.uv_raw, self.tracks.pts[new]])
            kf.uv = np.vstack([kf.uv, self.undistort_pts(self.tracks.pts[new])])

    def after_keyframe(self) -> None:
        """Keyframe bookkeeping: ORB index for relocalisation, the cloud builder's per-keyframe work."""
        self.relocalizer.index_keyframe(self.kfs[-1], self.landmarks)
        self.cloud_builder.after_keyframe(self)

    def insert_keyframe(self, img_u8: np.ndarray, frame_image: np.ndarray) -> None:
        """The current frame becomes a keyframe: new landmarks, bundle adjustment, new corners."""
        kf = self.add_keyframe(
            img_u8, frame_image, self.T_cam_map, self.tracks.ids, self.tracks.pts, self.timestamp, self.depth
        )
        self.depth_source.on_keyframe(self, kf)
        self.run_ba()
        self.T_cam_map = self.kfs[-1].T_cam_map.copy()
        self.detect(img_u8, self.config.max_features - len(self.tracks))
        self.record_new_observations(kf)
        self.depth_source.on_new_tracks(self, kf)
        self.after_keyframe()

    def locate(self, T_pred: np.ndarray) -> np.ndarray | None:
        """Pose of the current frame from tracked landmarks (PnP-RANSAC + robust refinement); drops the
        tracks of outlying landmarks. None when too few landmarks fit."""
        cfg = self.config
        ids = self.tracks.ids
        has = self.landmarks.ok[ids] if len(ids) else np.zeros(0, bool)
        if has.sum() < cfg.min_tracked_landmarks:
            return None
        X = self.landmarks.points[ids[has]]
        uv = self.undistort_pts(self.tracks.pts[has])
        T = self._pnp(T_pred, X, uv)
        if T is None:
            return None
        T, res = refine_pose(T, X, uv, self.K, iterations=3, huber_px=cfg.reproj_inlier_px * 0.5)
        good = res < cfg.reproj_inlier_px
        if good.sum() < cfg.min_tracked_landmarks:
            return None
        # the pose from the observations within the measured noise level only (docs/vse.md,
        # "Design and why", item 3); the tracks beyond it are kept, the bundle adjustment judges them
        fit = res < outlier_threshold_px(
            res[good], sigmas=cfg.outlier_sigmas, min_px=cfg.outlier_min_px, max_px=3.0 * cfg.reproj_inlier_px
        )
        if self.frontend.noise_level_outliers and fit.sum() >= cfg.min_tracked_landmarks and not fit.all():
            T, _ = refine_pose(T, X[fit], uv[fit], self.K, iterations=5, huber_px=cfg.reproj_inlier_px * 0.5)
            r, _ = projection_residuals(T[None], X, np.zeros(len(X), np.int64), np.arange(len(X)), uv, self.K)
            good = np.linalg.norm(r, axis=1) < cfg.reproj_inlier_px
        keep = np.ones(len(ids), bool)
        keep[np.flatnonzero(has)[~good]] = False
        self.tracks.keep(keep)
        return T

    # ------------------------------------------------------------------ tracking
    def _pnp(self, T_pred: np.ndarray, X: np.ndarray, uv: np.ndarray) -> np.ndarray | None:
        """PnP-RANSAC from the predicted pose, refined on its inliers; None with too few inliers."""
        cfg = self.config
        rvec, _ = cv2.Rodrigues(T_pred[:3, :3])
        tvec = T_pred[:3, 3].reshape(3, 1).copy()
        ok, rvec, tvec, inl = cv2.solvePnPRansac(
            X,
            uv,
            self.K,
            None,
            rvec=rvec.copy(),
            tvec=tvec,
            useExtrinsicGuess=True,
            iterationsCount=100,
            reprojectionError=cfg.reproj_inlier_px * 2,
            confidence=0.999,
            flags=cv2.SOLVEPNP_ITERATIVE,
        )
        if not ok or inl is None or len(inl) < cfg.min_tracked_landmarks:
            return None
        T0 = make_pose(cv2.Rodrigues(rvec)[0], tvec.ravel())
        inl = inl.ravel()
        T, _ = refine_pose(T0, X[inl], uv[inl], self.K, huber_px=cfg.reproj_inlier_px * 0.5)
        return T

    def _track(self, img_u8: np.ndarray, frame_image: np.ndarray) -> None:
        T_pred = self.velocity @ self.T_cam_map
        lm_ids = self.tracks.ids
        guess = self.frontend.motion_guess(
            self.tracks, self.landmarks.ok[lm_ids], lambda has: self.project(T_pred, self.landmarks.points[lm_ids[has]])
        )
        self.follow(img_u8, guess)
        T = self.locate(T_pred)
        if T is None:
            self.status = VseStatus.LOST
            self.lost_frames = 1
            self.message = "lost: too few landmarks tracked in this frame; relocalising against keyframes"
            return
        self.velocity = T @ invert_pose(self.T_cam_map)
        self.T_cam_map = T
        self.status = VseStatus.TRACKING
        self.message = f"tracking {len(self.tracks)} features, {len(self.kfs)} keyframes"
        if self._need_keyframe(T):
            t0 = time.perf_counter()
            self.insert_keyframe(img_u8, frame_image)
            self.mapping_time += time.perf_counter() - t0

    def _need_keyframe(self, T: np.ndarray) -> bool:
        cfg = self.config
        last = self.kfs[-1]
        c_last = invert_pose(last.T_cam_map)[:3, 3]
        c_now = invert_pose(T)[:3, 3]
        depth = median_depth(last, self.landmarks)
        baseline_ratio = np.linalg.norm(c_now - c_last) / max(depth, 1e-9)
        rot = math.degrees(rotation_angle_rad(T[:3, :3] @ last.T_cam_map[:3, :3].T))
        last_lms = last.landmark_ids(self.landmarks)
        still = np.isin(last_lms, self.tracks.ids).sum() / max(len(last_lms), 1)
        return bool(
            baseline_ratio > cfg.kf_min_baseline_ratio
            or rot > cfg.kf_max_rotation_deg
            or still < cfg.kf_min_tracked_fraction
        )

    # ------------------------------------------------------------------ snapshot
    def _snapshot(self) -> VseState:
        kfs = []
        for kf in self.kfs:
            if kf.published_image is None:
                img = kf.image.copy()
                img.setflags(write=False)
                kf.published_image = img
            kfs.append(
                Keyframe(
                    id=kf.id, T_map_cam=invert_pose(kf.T_cam_map), image=kf.published_image, timestamp_s=kf.timestamp_s
                )
            )
        return VseState(
            status=self.status,
            message=self.message,
            T_map_cam=None if self.T_cam_map is None else invert_pose(self.T_cam_map),
            keyframes=tuple(kfs),
            cloud=self.cloud_builder.cloud(self) if self.kfs else MapCloud(),
            frames_processed=self._frames,
            track_fps=_fps(self._track_times),
            overall_fps=_fps(self._total_times),
            scale_is_metric=self.depth_source.metric,
            timestamp_s=self.timestamp,
        )


def _fps(times) -> float:
    return float(len(times) / sum(times)) if times else 0.0


class MonocularVSE(VisualSlamEngine):
    """Monocular engine: KLT tracking, PnP, windowed bundle adjustment and a semi-dense cloud (up to scale).

    Parameters
    ----------
    camera : PinholeCamera
        Intrinsics of the frames (from calibration).
    config : VseConfig
        Options.
    """

    def __init__(self, camera: PinholeCamera, *, config: VseConfig = VseConfig()) -> None:
        super().__init__(
            camera, config=config, frontend=KltTracking(config), depth_source=Triangulation(), cloud=SemiDenseCloud()
        )


class SparseVSE(VisualSlamEngine):
    """Feature-based variant (ORB matching, landmark cloud), for the paper's rACR-ORB comparison."""

    def __init__(self, camera: PinholeCamera, *, config: VseConfig = VseConfig()) -> None:
        super().__init__(
            camera, config=config, frontend=OrbTracking(config), depth_source=Triangulation(), cloud=LandmarkCloud()
        )


class RgbdVSE(VisualSlamEngine):
    """RGB-D engine: same tracking, metric map (scale 1) from the depth of each frame.

    ``process(image, timestamp_s, depth=...)`` needs the z-depth image in
    metres (0 where unknown). The cloud holds the high-gradient pixels of each
    keyframe with their measured depth.
    """

    def __init__(self, camera: PinholeCamera, *, config: VseConfig = VseConfig()) -> None:
        super().__init__(
            camera, config=config, frontend=KltTracking(config), depth_source=DepthImage(), cloud=DepthImageCloud()
        )


class VseVariant(StrEnum):
    """The engine variants by name (as on the command line)."""

    MONO = "mono"
    SPARSE = "sparse"
    RGBD = "rgbd"


_VARIANTS: dict[VseVariant, type[VisualSlamEngine]] = {
    VseVariant.MONO: MonocularVSE,
    VseVariant.SPARSE: SparseVSE,
    VseVariant.RGBD: RgbdVSE,
}


def make_engine(
    variant: VseVariant | str, camera: PinholeCamera, *, config: VseConfig = VseConfig()
) -> VisualSlamEngine:
    """The engine of a variant (``ValueError`` for an unknown name)."""
    return _VARIANTS[VseVariant(variant)](camera, config=config)
