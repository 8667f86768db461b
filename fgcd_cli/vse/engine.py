"""The visual SLAM engines: monocular (semi-dense), sparse (ORB) and RGB-D.

One engine class does the work; the variants differ only in their front-end
(KLT corners or ORB matches), in where the depth of a new point comes from
(two-view triangulation or the depth image) and in what the cloud holds
(semi-dense keyframe depth, depth-image pixels, or the sparse landmarks).

Pipeline for each frame (``process``):

1. follow the tracks of the previous frame (KLT, or ORB matching);
2. before the map exists: two-view initialisation from the essential matrix,
   accepted only with enough parallax (pure rotation never initialises);
3. afterwards: pose by PnP-RANSAC on the tracked landmarks, refined by a
   robust motion-only Gauss-Newton;
4. new keyframe when the baseline over the scene depth, the rotation, or the
   fraction of still-tracked landmarks asks for it; then triangulate new
   landmarks, detect new corners, run the windowed bundle adjustment and
   compute the semi-dense depth of keyframes that have enough neighbours;
5. when a frame cannot be located the state is ``lost``; later frames are
   relocalised against recent keyframes (ORB matches to their landmarks, PnP,
   then KLT from the keyframe for sub-pixel tracks).
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from fgcd_cli.geometry.camera import PinholeCamera
from fgcd_cli.geometry.se3 import invert_pose, log_so3, make_pose, rotation_angle_rad, transform_points
from fgcd_cli.vse.ba import (bundle_adjust_rejecting_outliers, outlier_threshold_px,
                            projection_residuals, refine_pose)
from fgcd_cli.vse.features import KltFrontend, OrbFrontend, orb_describe, to_gray_f32, to_gray_u8
from fgcd_cli.vse.semidense import SemiDenseDepth, fuse_across_keyframes, keyframe_depth
from fgcd_cli.vse.types import Keyframe, MapCloud, VseConfig, VseState

__all__ = ["MonocularVSE", "SparseVSE", "RgbdVSE"]


@dataclass(kw_only=True)
class _KF:
    """Internal keyframe record (mutable: BA moves its pose)."""

    id: int
    T_cam_map: np.ndarray
    image: np.ndarray  # raw float32 [0, 1]
    image_u8: np.ndarray  # raw uint8
    undist: np.ndarray  # undistorted float32
    timestamp_s: float
    track_ids: np.ndarray  # (n,) ids of tracks observed here
    uv: np.ndarray  # (n, 2) undistorted pixels
    uv_raw: np.ndarray  # (n, 2) raw pixels
    depth: np.ndarray | None = None  # RGB-D only: (H, W) metres
    semidense: SemiDenseDepth | None = None
    orb_desc: np.ndarray | None = None
    orb_ids: np.ndarray | None = None
    published_image: np.ndarray | None = field(default=None, repr=False)


class _Tracks:
    """Active feature tracks (struct of arrays)."""

    def __init__(self) -> None:
        self.ids = np.zeros(0, np.int64)
        self.pts = np.zeros((0, 2))  # raw pixels in the latest frame
        self.desc = np.zeros((0, 32), np.uint8)  # ORB front-end only

    def __len__(self) -> int:
        return len(self.ids)

    def keep(self, mask: np.ndarray) -> None:
        self.ids = self.ids[mask]
        self.pts = self.pts[mask]
        if len(self.desc) == len(mask):
            self.desc = self.desc[mask]

    def add(self, ids: np.ndarray, pts: np.ndarray, desc: np.ndarray | None = None) -> None:
        self.ids = np.concatenate([self.ids, ids])
        self.pts = np.vstack([self.pts, pts]) if len(pts) else self.pts
        if desc is not None and len(desc):
            base = self.desc if len(self.desc) == len(self.ids) - len(ids) else np.zeros((len(self.ids) - len(ids), 32), np.uint8)
            self.desc = np.vstack([base, desc])


class _EngineBase:
    """Shared engine; use :class:`MonocularVSE`, :class:`SparseVSE` or :class:`RgbdVSE`."""

    # ray angle a new landmark needs: KLT positions are good to ~0.1 px, ORB
    # keypoints to ~0.5 px (no sub-pixel refinement), so ORB waits for more parallax
    _min_triangulation_deg = 0.5
    # outliers judged against the residuals' own noise level (ba.bundle_adjust_rejecting_outliers):
    # right for KLT tracks, whose sub-pixel noise is the same everywhere; ORB keypoints are
    # quantised at their pyramid level (noise grows 1.2x per level), so one scale per window
    # rejects good coarse-level matches (measured: sparse mural 6 legs 9.7 -> 19.4 mm ATE)
    _noise_level_outliers = True
    _frontend_kind = "klt"
    _cloud_kind = "semidense"
    _metric = False

    def __init__(self, camera: PinholeCamera, *, config: VseConfig = VseConfig()) -> None:
        if not isinstance(camera, PinholeCamera):
            raise TypeError("camera must be a fgcd_cli.geometry.PinholeCamera")
        self.camera = camera
        self.config = config
        self.K = camera.K
        if camera.has_distortion:
            self._undist_maps = cv2.initUndistortRectifyMap(
                camera.K, np.array(camera.dist), None, camera.K, (camera.width, camera.height), cv2.CV_32FC1
            )
        else:
            self._undist_maps = None
        if self._frontend_kind == "klt":
            self.frontend = KltFrontend(window_px=config.klt_window_px, levels=config.klt_levels,
                                        fb_max_px=config.klt_fb_max_px, min_distance_px=config.min_feature_distance_px,
                                        min_corner_response=config.min_corner_response)
        else:
            self.frontend = OrbFrontend(n_features=max(2 * config.max_features, 1000),
                                        min_distance_px=config.min_feature_distance_px * 0.6,
                                        min_corner_response=config.min_corner_response)
        self._orb = cv2.ORB_create(nfeatures=1500)
        self.reset()

    # ------------------------------------------------------------------ public API
    def reset(self) -> None:
        """Forget the map and start initialising again from the next frame."""
        self._status = "initializing"
        self._message = "waiting for frames"
        self._tracks = _Tracks()
        self._next_track_id = 0
        self._lm = np.full((1024, 3), np.nan)
        self._lm_ok = np.zeros(1024, bool)
        self._kfs: list[_KF] = []
        self._next_kf_id = 0
        self._prev_u8: np.ndarray | None = None
        self._T_cam_map: np.ndarray | None = None
        self._T_prev_cam_map: np.ndarray | None = None
        self._velocity = np.eye(4)
        self._init_ref: dict | None = None
        self._frames = 0
        self._frames_without_texture = 0
        self._lost_frames = 0
        self._track_times: deque[float] = deque(maxlen=30)
        self._total_times: deque[float] = deque(maxlen=30)
        self._timestamp = float("nan")
        self._cloud_cache: MapCloud | None = None
        self._fused_parts: dict[int, tuple] = {}  # keyframe id -> (poses key, cloud part)
        self._state = self._snapshot()

    def state(self) -> VseState:
        """The latest published snapshot (cheap; safe to hold)."""
        return self._state

    def process(self, frame_image: np.ndarray, timestamp_s: float, depth: np.ndarray | None = None) -> VseState:
        """Process one frame synchronously and return the new state.

        Parameters
        ----------
        frame_image : (H, W) uint8/float32 or (H, W, 3) ndarray
            The camera image (raw, with the camera's distortion).
        timestamp_s : float
            Capture time, seconds.
        depth : (H, W) ndarray, optional
            z-depth in metres, 0 where unknown (required by :class:`RgbdVSE`).
        """
        t0 = time.perf_counter()
        img_u8 = to_gray_u8(frame_image)
        if img_u8.shape != (self.camera.height, self.camera.width):
            raise ValueError(f"frame is {img_u8.shape}, camera is {(self.camera.height, self.camera.width)}")
        if self._status == "failed":
            self._frames += 1
            self._state = self._snapshot()
            return self._state
        self._frames += 1
        self._timestamp = float(timestamp_s)
        self._mapping_time = 0.0
        self._depth = None if depth is None else np.asarray(depth, dtype=float)
        if self._metric and self._depth is None:
            raise ValueError("the RGB-D engine needs a depth image with every frame")
        if self._T_cam_map is None:
            self._initialize(img_u8, frame_image)
        elif self._status == "lost":
            self._relocalize(img_u8, frame_image)
        else:
            self._track(img_u8, frame_image)
        self._prev_u8 = img_u8
        # the snapshot rebuilds the cloud after a keyframe (cross-keyframe fusion): mapping time
        t_snap = time.perf_counter()
        state = self._snapshot()
        dt = time.perf_counter() - t0
        self._mapping_time += time.perf_counter() - t_snap
        self._total_times.append(dt)
        self._track_times.append(max(dt - self._mapping_time, 1e-6))
        self._state = replace(state, track_fps=self._fps(self._track_times), overall_fps=self._fps(self._total_times))
        return self._state

    # ------------------------------------------------------------------ helpers
    def _undistort_pts(self, pts: np.ndarray) -> np.ndarray:
        if self._undist_maps is None or len(pts) == 0:
            return np.asarray(pts, dtype=float).reshape(-1, 2)
        rays = self.camera.normalized_rays(pts)
        return np.column_stack([rays[:, 0] * self.K[0, 0] + self.K[0, 2], rays[:, 1] * self.K[1, 1] + self.K[1, 2]])

    def _undistort_img(self, img_f32: np.ndarray) -> np.ndarray:
        if self._undist_maps is None:
            return img_f32
        return cv2.remap(img_f32, self._undist_maps[0], self._undist_maps[1], cv2.INTER_LINEAR)

    def _project(self, T_cam_map: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Raw pixels of map points and whether they are in view."""
        return self.camera.project(transform_points(T_cam_map, X))

    def _ensure_lm_capacity(self, n: int) -> None:
        if n <= len(self._lm):
            return
        cap = max(n, 2 * len(self._lm))
        lm = np.full((cap, 3), np.nan)
        lm[: len(self._lm)] = self._lm
        ok = np.zeros(cap, bool)
        ok[: len(self._lm_ok)] = self._lm_ok
        self._lm, self._lm_ok = lm, ok

    def _new_track_ids(self, k: int) -> np.ndarray:
        ids = np.arange(self._next_track_id, self._next_track_id + k, dtype=np.int64)
        self._next_track_id += k
        self._ensure_lm_capacity(self._next_track_id)
        return ids

    def _follow(self, img_u8: np.ndarray, guess: np.ndarray | None = None) -> None:
        """Move the tracks into the new image, dropping those lost."""
        if len(self._tracks) == 0:
            return
        if self._frontend_kind == "klt":
            new, ok = self.frontend.track(self._prev_u8, img_u8, self._tracks.pts, guess)
            self._tracks.pts = new
            self._tracks.keep(ok)
        else:
            prior = self._tracks.pts if guess is None else guess
            new, desc, ok = self.frontend.match(self._tracks.desc, prior, img_u8)
            self._tracks.pts = new
            self._tracks.desc = desc
            self._tracks.keep(ok)

    def _detect(self, img_u8: np.ndarray, max_new: int) -> None:
        if self._frontend_kind == "klt":
            pts = self.frontend.detect(img_u8, self._tracks.pts, max_new)
            if len(pts):
                self._tracks.add(self._new_track_ids(len(pts)), pts)
        else:
            pts, desc = self.frontend.detect(img_u8, self._tracks.pts, max_new)
            if len(pts):
                if len(self._tracks.desc) != len(self._tracks):
                    self._tracks.desc = np.zeros((len(self._tracks), 32), np.uint8)
                self._tracks.add(self._new_track_ids(len(pts)), pts, desc)

    def _fps(self, times) -> float:
        return float(len(times) / sum(times)) if times else 0.0

    # ------------------------------------------------------------------ initialisation
    def _initialize(self, img_u8: np.ndarray, frame_image: np.ndarray) -> None:
        cfg = self.config
        if self._init_ref is None or len(self._tracks) < cfg.init_min_inliers:
            self._start_init_reference(img_u8, frame_image)
            return
        self._follow(img_u8)
        if len(self._tracks) < cfg.init_min_inliers:
            self._message = f"initialising: only {len(self._tracks)} corners survived; restarting from this frame"
            self._start_init_reference(img_u8, frame_image)
            return
        ref_uv = self._init_ref["uv"]
        id_to_row = {int(i): k for k, i in enumerate(self._init_ref["ids"])}
        rows = np.array([id_to_row[int(i)] for i in self._tracks.ids])
        p0 = ref_uv[rows]
        p1 = self._undistort_pts(self._tracks.pts)
        rot_residual_px = self._rotation_only_residual_px(p0, p1)
        if rot_residual_px < math.radians(cfg.init_min_translation_parallax_deg) * self.K[0, 0]:
            self._message = (
                f"initialising: the views differ by a rotation only (residual {rot_residual_px:.2f} px); "
                "need parallax from translation, pure rotation cannot initialise"
            )
            return
        E, mask = cv2.findEssentialMat(p0, p1, self.K, method=cv2.RANSAC, prob=0.999, threshold=1.0)
        if E is None or E.shape != (3, 3):
            self._message = "initialising: no essential matrix yet (move the camera sideways)"
            return
        # distanceThresh: OpenCV's default (50 baselines) drops points far away relative to a
        # short exploration baseline (1.5 cm at 1.2 m is 80 baselines); keep all but infinity
        _, R, t, mask2, _ = cv2.recoverPose(E, p0, p1, self.K, distanceThresh=1e6, mask=mask.copy())
        inl = mask2.ravel() > 0
        R, t, inl = self._planar_two_view(p0, p1, R, t, inl)
        if inl.sum() < cfg.init_min_inliers:
            self._message = f"initialising: {int(inl.sum())} inliers, need {cfg.init_min_inliers}"
            return
        T10 = make_pose(R, t.ravel())  # cam1 <- cam0, unit baseline
        X, good, angles = self._triangulate_pair(np.eye(4), T10, p0[inl], p1[inl])
        med_par = float(np.degrees(np.median(angles))) if len(angles) else 0.0
        if med_par < cfg.init_min_parallax_deg or good.sum() < cfg.init_min_inliers:
            self._message = (
                f"initialising: median parallax {med_par:.2f} deg < {cfg.init_min_parallax_deg} deg "
                "(the motion needs translation, pure rotation cannot initialise)"
            )
            return
        # scale: median depth 1 map unit
        med_depth = float(np.median(X[good][:, 2]))
        T10[:3, 3] /= med_depth
        ids_in = self._tracks.ids[inl]
        self._make_map_from_two_views(img_u8, frame_image, T10, ids_in, p0[inl], p1[inl])

    def _planar_two_view(self, p0: np.ndarray, p1: np.ndarray, R: np.ndarray, t: np.ndarray, inl: np.ndarray):
        """The two-view motion when the scene is (nearly) a plane: from the homography.

        A stele or a mural seen from 1-2 m over a few-cm baseline is a plane to
        within a fraction of a pixel of parallax; the essential matrix is then
        ill-conditioned and RANSAC often returns a wrong motion (measured: the
        stele initialised with the translation 70 deg off in 2 of 3 sequences).
        As ORB-SLAM does, the homography is preferred when it explains (almost)
        as many matches as the essential matrix. Its decomposition has up to
        two solutions with (nearly) every point in front of both cameras; of
        these the plane that faces the camera is taken, since the tool always
        looks at the surface it monitors (the other solution's normal lies
        along the translation, i.e. sideways).

        Returns ``(R, t, inliers)``: unchanged when the scene is not planar.
        """
        cfg = self.config
        H, hmask = cv2.findHomography(p0, p1, cv2.RANSAC, 1.0)
        if H is None:
            return R, t, inl
        hin = hmask.ravel() > 0
        if hin.sum() < cfg.init_planar_ratio * inl.sum():
            return R, t, inl
        n, Rs, ts, normals = cv2.decomposeHomographyMat(H, self.K)
        solutions = []
        for R_i, t_i, n_i in zip(Rs, ts, normals):
            norm = float(np.linalg.norm(t_i))
            if norm < 1e-12:
                continue
            t_i = np.asarray(t_i, dtype=float).reshape(3, 1) / norm
            _, good, _ = self._triangulate_pair(np.eye(4), make_pose(np.asarray(R_i, float), t_i.ravel()), p0[hin], p1[hin])
            solutions.append((int(good.sum()), abs(float(n_i[2, 0])), np.asarray(R_i, float), t_i))
        if not solutions:
            return R, t, inl
        most = max(v[0] for v in solutions)
        # points in front of both cameras (ORB-SLAM's test), then the plane facing the camera
        front = [v for v in solutions if v[0] >= 0.9 * most]
        _, _, R_h, t_h = max(front, key=lambda v: v[1])
        return R_h, t_h, hin

    def _rotation_only_residual_px(self, uv0: np.ndarray, uv1: np.ndarray) -> float:
        """Median misfit (pixels) of the best pure rotation between two views' bearings.

        Solves Wahba's problem (Kabsch without translation, twice, dropping the
        worst 20 %); translation parallax is what a rotation cannot explain.
        """
        Kinv = np.linalg.inv(self.K)
        b0 = (Kinv @ np.column_stack([uv0, np.ones(len(uv0))]).T).T
        b1 = (Kinv @ np.column_stack([uv1, np.ones(len(uv1))]).T).T
        b0 /= np.linalg.norm(b0, axis=1, keepdims=True)
        b1 /= np.linalg.norm(b1, axis=1, keepdims=True)
        use = np.ones(len(b0), bool)
        for _ in range(2):
            U, _, Vt = np.linalg.svd(b1[use].T @ b0[use])
            D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
            R = U @ D @ Vt
            ang = np.arccos(np.clip(np.sum(b1 * (b0 @ R.T), axis=1), -1, 1))
            use = ang <= np.percentile(ang, 80)
        return float(np.median(ang) * self.K[0, 0])

    def _start_init_reference(self, img_u8: np.ndarray, frame_image: np.ndarray) -> None:
        cfg = self.config
        self._tracks = _Tracks()
        self._detect(img_u8, cfg.max_features)
        n = len(self._tracks)
        if n < cfg.init_min_inliers:
            self._frames_without_texture += 1
            self._init_ref = None
            if self._frames_without_texture >= cfg.init_fail_frames:
                self._status = "failed"
                self._message = (
                    f"failed: only {n} trackable corners per frame for {self._frames_without_texture} frames "
                    f"(need {cfg.init_min_inliers}); the scene is too weakly textured for visual SLAM"
                )
                self._tracks = _Tracks()
            else:
                self._message = f"initialising: only {n} trackable corners (need {cfg.init_min_inliers}); too little texture"
            return
        self._frames_without_texture = 0
        self._init_ref = {
            "ids": self._tracks.ids.copy(),
            "uv": self._undistort_pts(self._tracks.pts),
            "uv_raw": self._tracks.pts.copy(),
            "image": frame_image,
            "u8": img_u8,
            "timestamp_s": self._timestamp,
            "depth": self._depth,
        }
        self._message = "initialising: reference frame set, waiting for parallax"
        if self._metric:
            self._make_map_from_depth(img_u8, frame_image)

    def _triangulate_pair(self, T0: np.ndarray, T1: np.ndarray, uv0: np.ndarray, uv1: np.ndarray):
        """Triangulate undistorted pixel pairs between two map-to-camera poses.

        Returns points (N, 3) in the map, a validity mask and the ray angles (radians).
        """
        P0 = self.K @ T0[:3]
        P1 = self.K @ T1[:3]
        Xh = cv2.triangulatePoints(P0, P1, uv0.T.astype(float), uv1.T.astype(float))
        X = (Xh[:3] / Xh[3]).T
        c0 = invert_pose(T0)[:3, 3]
        c1 = invert_pose(T1)[:3, 3]
        d0 = X - c0
        d1 = X - c1
        cosang = np.sum(d0 * d1, axis=1) / np.maximum(np.linalg.norm(d0, axis=1) * np.linalg.norm(d1, axis=1), 1e-12)
        angles = np.arccos(np.clip(cosang, -1, 1))
        z0 = transform_points(T0, X)[:, 2]
        z1 = transform_points(T1, X)[:, 2]
        good = np.isfinite(X).all(axis=1) & (z0 > 0) & (z1 > 0)
        for T, uv in ((T0, uv0), (T1, uv1)):
            Xc = transform_points(T, X)
            with np.errstate(invalid="ignore", divide="ignore"):
                pr = (Xc[:, :2] / Xc[:, 2:3]) * [self.K[0, 0], self.K[1, 1]] + [self.K[0, 2], self.K[1, 2]]
            good &= np.linalg.norm(pr - uv, axis=1) < self.config.reproj_inlier_px
        return X, good, angles[good]

    def _add_keyframe(self, img_u8: np.ndarray, frame_image, T_cam_map: np.ndarray, ids: np.ndarray, uv_raw: np.ndarray,
                      timestamp_s: float, depth: np.ndarray | None) -> _KF:
        img_f = to_gray_f32(frame_image)
        kf = _KF(
            id=self._next_kf_id,
            T_cam_map=T_cam_map.copy(),
            image=img_f,
            image_u8=img_u8,
            undist=self._undistort_img(img_f),
            timestamp_s=timestamp_s,
            track_ids=np.asarray(ids, np.int64).copy(),
            uv=self._undistort_pts(uv_raw),
            uv_raw=np.asarray(uv_raw, float).copy(),
            depth=None if depth is None else np.asarray(depth, float),
        )
        self._next_kf_id += 1
        self._kfs.append(kf)
        return kf

    def _make_map_from_two_views(self, img_u8, frame_image, T10, ids, uv0, uv1) -> None:
        ref = self._init_ref
        kf0 = self._add_keyframe(ref["u8"], ref["image"], np.eye(4), ref["ids"], ref["uv_raw"], ref["timestamp_s"], None)
        # keep only tracks that survived into this frame in kf1
        kf1 = self._add_keyframe(img_u8, frame_image, T10, self._tracks.ids, self._tracks.pts, self._timestamp, None)
        X, good, _ = self._triangulate_pair(np.eye(4), T10, uv0, uv1)
        self._lm[ids[good]] = X[good]
        self._lm_ok[ids[good]] = True
        self._run_ba()
        self._T_cam_map = self._kfs[-1].T_cam_map.copy()
        self._T_prev_cam_map = self._T_cam_map.copy()
        self._status = "tracking"
        self._message = f"initialised with {int(good.sum())} landmarks"
        self._init_ref = None
        self._detect(img_u8, self.config.max_features - len(self._tracks))
        # new corners are observed in kf1
        self._record_new_observations(kf1)
        self._after_keyframe()
        _ = kf0

    def _make_map_from_depth(self, img_u8, frame_image) -> None:
        """RGB-D initialisation: the first textured frame is the map origin."""
        kf = self._add_keyframe(img_u8, frame_image, np.eye(4), self._tracks.ids, self._tracks.pts, self._timestamp, self._depth)
        self._lift_with_depth(kf, self._tracks.ids, self._tracks.pts)
        self._T_cam_map = np.eye(4)
        self._T_prev_cam_map = np.eye(4)
        self._status = "tracking"
        self._message = f"initialised from depth with {int(self._lm_ok[self._tracks.ids].sum())} landmarks"
        self._init_ref = None
        self._after_keyframe()

    def _lift_with_depth(self, kf: _KF, ids: np.ndarray, pts_raw: np.ndarray) -> None:
        """Landmarks from the depth image for tracks that have none."""
        if kf.depth is None or len(ids) == 0:
            return
        need = ~self._lm_ok[ids]
        if not np.any(need):
            return
        pts = pts_raw[need]
        d = cv2.remap(kf.depth.astype(np.float32), pts[:, 0].astype(np.float32).reshape(-1, 1),
                      pts[:, 1].astype(np.float32).reshape(-1, 1), cv2.INTER_NEAREST).ravel()
        # reject depth discontinuities: the 3x3 neighbourhood must agree within 1 %
        dil = cv2.dilate(kf.depth.astype(np.float32), np.ones((3, 3), np.uint8))
        ero = cv2.erode(kf.depth.astype(np.float32), np.ones((3, 3), np.uint8))
        xi = np.clip(np.round(pts[:, 0]).astype(int), 0, kf.depth.shape[1] - 1)
        yi = np.clip(np.round(pts[:, 1]).astype(int), 0, kf.depth.shape[0] - 1)
        smooth = (dil[yi, xi] - ero[yi, xi]) < 0.01 * np.maximum(d, 1e-6)
        ok = np.isfinite(d) & (d > 0) & smooth
        Xc = self.camera.unproject(pts[ok], d[ok])
        X = transform_points(invert_pose(kf.T_cam_map), Xc)
        sel = ids[need][ok]
        self._lm[sel] = X
        self._lm_ok[sel] = True

    # ------------------------------------------------------------------ tracking
    def _track(self, img_u8: np.ndarray, frame_image: np.ndarray) -> None:
        cfg = self.config
        T_pred = self._velocity @ self._T_cam_map
        guess = None
        if self._frontend_kind == "orb" and len(self._tracks):
            lm_ids = self._tracks.ids
            guess = self._tracks.pts.copy()
            has = self._lm_ok[lm_ids]
            if np.any(has):
                uvp, inv = self._project(T_pred, self._lm[lm_ids[has]])
                g = guess[has]
                g[inv] = uvp[inv]
                guess[has] = g
        self._follow(img_u8, guess)
        T = self._locate(T_pred)
        if T is None:
            self._status = "lost"
            self._lost_frames = 1
            self._message = "lost: too few landmarks tracked in this frame; relocalising against keyframes"
            return
        self._velocity = T @ invert_pose(self._T_cam_map)
        self._T_prev_cam_map = self._T_cam_map
        self._T_cam_map = T
        self._status = "tracking"
        self._message = f"tracking {len(self._tracks)} features, {len(self._kfs)} keyframes"
        if self._need_keyframe(T):
            t0 = time.perf_counter()
            self._insert_keyframe(img_u8, frame_image)
            self._mapping_time += time.perf_counter() - t0

    def _locate(self, T_pred: np.ndarray) -> np.ndarray | None:
        """Pose of the current frame from tracked landmarks (PnP-RANSAC + robust refinement)."""
        cfg = self.config
        ids = self._tracks.ids
        has = self._lm_ok[ids] if len(ids) else np.zeros(0, bool)
        if has.sum() < cfg.min_tracked_landmarks:
            return None
        X = self._lm[ids[has]]
        uv = self._undistort_pts(self._tracks.pts[has])
        rvec, _ = cv2.Rodrigues(T_pred[:3, :3])
        tvec = T_pred[:3, 3].reshape(3, 1).copy()
        ok, rvec, tvec, inl = cv2.solvePnPRansac(
            X, uv, self.K, None, rvec=rvec.copy(), tvec=tvec, useExtrinsicGuess=True, iterationsCount=100,
            reprojectionError=cfg.reproj_inlier_px * 2, confidence=0.999, flags=cv2.SOLVEPNP_ITERATIVE,
        )
        if not ok or inl is None or len(inl) < cfg.min_tracked_landmarks:
            return None
        T0 = make_pose(cv2.Rodrigues(rvec)[0], tvec.ravel())
        inl = inl.ravel()
        T, _ = refine_pose(T0, X[inl], uv[inl], self.K, huber_px=cfg.reproj_inlier_px * 0.5)
        T, res = refine_pose(T, X, uv, self.K, iterations=3, huber_px=cfg.reproj_inlier_px * 0.5)
        good = res < cfg.reproj_inlier_px
        if good.sum() < cfg.min_tracked_landmarks:
            return None
        # the pose from the observations within the measured noise level only (see
        # _outlier_threshold_px); the tracks beyond it are kept, the bundle adjustment judges them
        fit = res < self._outlier_threshold_px(res[good])
        if self._noise_level_outliers and fit.sum() >= cfg.min_tracked_landmarks and not fit.all():
            T, _ = refine_pose(T, X[fit], uv[fit], self.K, iterations=5, huber_px=cfg.reproj_inlier_px * 0.5)
            r, _ = projection_residuals(T[None], X, np.zeros(len(X), np.int64), np.arange(len(X)), uv, self.K)
            good = np.linalg.norm(r, axis=1) < cfg.reproj_inlier_px
        # drop the tracks of outlying landmarks
        keep = np.ones(len(ids), bool)
        keep[np.flatnonzero(has)[~good]] = False
        self._tracks.keep(keep)
        return T

    def _need_keyframe(self, T: np.ndarray) -> bool:
        cfg = self.config
        last = self._kfs[-1]
        c_last = invert_pose(last.T_cam_map)[:3, 3]
        c_now = invert_pose(T)[:3, 3]
        depth = self._median_depth(last)
        baseline_ratio = np.linalg.norm(c_now - c_last) / max(depth, 1e-9)
        rot = math.degrees(rotation_angle_rad(T[:3, :3] @ last.T_cam_map[:3, :3].T))
        last_lms = last.track_ids[self._lm_ok[last.track_ids]]
        still = np.isin(last_lms, self._tracks.ids).sum() / max(len(last_lms), 1)
        return bool(baseline_ratio > cfg.kf_min_baseline_ratio or rot > cfg.kf_max_rotation_deg
                    or still < cfg.kf_min_tracked_fraction)

    def _median_depth(self, kf: _KF) -> float:
        ids = kf.track_ids[self._lm_ok[kf.track_ids]]
        if len(ids) == 0:
            return 1.0
        z = transform_points(kf.T_cam_map, self._lm[ids])[:, 2]
        z = z[z > 0]
        return float(np.median(z)) if len(z) else 1.0

    def _insert_keyframe(self, img_u8: np.ndarray, frame_image) -> None:
        cfg = self.config
        kf = self._add_keyframe(img_u8, frame_image, self._T_cam_map, self._tracks.ids, self._tracks.pts, self._timestamp,
                                self._depth)
        if self._metric:
            self._lift_with_depth(kf, self._tracks.ids, self._tracks.pts)
        else:
            self._triangulate_new(kf)
        self._run_ba()
        self._T_cam_map = self._kfs[-1].T_cam_map.copy()
        self._detect(img_u8, cfg.max_features - len(self._tracks))
        self._record_new_observations(kf)
        if self._metric:
            self._lift_with_depth(kf, self._tracks.ids, self._tracks.pts)
        self._after_keyframe()

    def _record_new_observations(self, kf: _KF) -> None:
        """Add tracks born in this keyframe to its observation list."""
        new = ~np.isin(self._tracks.ids, kf.track_ids)
        if np.any(new):
            kf.track_ids = np.concatenate([kf.track_ids, self._tracks.ids[new]])
            kf.uv_raw = np.vstack([kf.uv_raw, self._tracks.pts[new]])
            kf.uv = np.vstack([kf.uv, self._undistort_pts(self._tracks.pts[new])])

    def _triangulate_new(self, kf: _KF) -> None:
        """Landmarks for tracks without one, from their first keyframe and this one."""
        ids = kf.track_ids
        need = ~self._lm_ok[ids]
        if not np.any(need):
            return
        cand = ids[need]
        uv_now = kf.uv[need]
        # first keyframe observing each candidate
        first_uv = np.full((len(cand), 2), np.nan)
        first_kf = np.full(len(cand), -1)
        for k, other in enumerate(self._kfs[:-1]):
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
        for k in np.unique(first_kf[first_kf >= 0]):
            sel = first_kf == k
            X, good, _ = self._triangulate_pair(self._kfs[k].T_cam_map, kf.T_cam_map, first_uv[sel], uv_now[sel])
            c0 = invert_pose(self._kfs[k].T_cam_map)[:3, 3]
            c1 = invert_pose(kf.T_cam_map)[:3, 3]
            d0, d1 = X - c0, X - c1
            cosang = np.sum(d0 * d1, axis=1) / np.maximum(np.linalg.norm(d0, axis=1) * np.linalg.norm(d1, axis=1), 1e-12)
            good &= np.degrees(np.arccos(np.clip(cosang, -1, 1))) > self._min_triangulation_deg
            ids_k = cand[sel][good]
            self._lm[ids_k] = X[good]
            self._lm_ok[ids_k] = True

    def _run_ba(self) -> None:
        cfg = self.config
        window = self._kfs[-cfg.ba_window :]
        C = len(window)
        if C < 2:
            return
        obs_cam, obs_id, obs_uv = [], [], []
        for c, kf in enumerate(window):
            ok = self._lm_ok[kf.track_ids]
            obs_cam.append(np.full(ok.sum(), c))
            obs_id.append(kf.track_ids[ok])
            obs_uv.append(kf.uv[ok])
        obs_cam = np.concatenate(obs_cam)
        obs_id = np.concatenate(obs_id)
        obs_uv = np.vstack(obs_uv)
        uniq, inv, counts = np.unique(obs_id, return_inverse=True, return_counts=True)
        multi = counts[inv] >= 2
        if multi.sum() < 10:
            return
        obs_cam, obs_id, obs_uv = obs_cam[multi], obs_id[multi], obs_uv[multi]
        uniq, obs_pt = np.unique(obs_id, return_inverse=True)
        # gauge: the two oldest keyframes of the window are held (pose and scale);
        # with only two keyframes, the first one (the scale then rests on the damping)
        fixed = np.zeros(C, bool)
        fixed[: 2 if C >= 3 else 1] = True
        # outliers at the measured noise level of the window, not at a fixed pixel count (see ba.py)
        res, bad = bundle_adjust_rejecting_outliers(
            np.stack([kf.T_cam_map for kf in window]), self._lm[uniq], obs_cam, obs_pt, obs_uv, self.K,
            fixed_cams=fixed, iterations=cfg.ba_iterations, huber_px=1.0, outlier_sigmas=cfg.outlier_sigmas,
            outlier_min_px=cfg.outlier_min_px if self._noise_level_outliers else 3.0 * cfg.reproj_inlier_px,
            outlier_max_px=3.0 * cfg.reproj_inlier_px, max_rounds=4 if self._noise_level_outliers else 1,
        )
        for c, kf in enumerate(window):
            kf.T_cam_map = res.T_cam_map[c]
        self._lm[uniq] = res.points
        if np.any(bad):
            bad_ids = set(zip(obs_cam[bad].tolist(), obs_id[bad].tolist()))
            for c, kf in enumerate(window):
                ids_c = {i for (cc, i) in bad_ids if cc == c}
                if ids_c:
                    keep = ~np.isin(kf.track_ids, list(ids_c))
                    kf.track_ids, kf.uv, kf.uv_raw = kf.track_ids[keep], kf.uv[keep], kf.uv_raw[keep]
            # a landmark whose observations are mostly bad is dropped with its track
            bad_count = np.bincount(obs_pt[bad], minlength=len(uniq))
            all_count = np.bincount(obs_pt, minlength=len(uniq))
            drop = uniq[bad_count * 2 >= all_count]
            self._lm_ok[drop] = False
            self._tracks.keep(~np.isin(self._tracks.ids, drop))

    def _outlier_threshold_px(self, residual_px: np.ndarray) -> float:
        cfg = self.config
        return outlier_threshold_px(residual_px, sigmas=cfg.outlier_sigmas, min_px=cfg.outlier_min_px,
                                    max_px=3.0 * cfg.reproj_inlier_px)

    def _after_keyframe(self) -> None:
        """Keyframe bookkeeping: ORB descriptors for relocalisation, semi-dense depth."""
        self._cloud_cache = None
        kf = self._kfs[-1]
        # ORB features of the keyframe tied to the landmark observed within 3 px (relocalisation)
        ok = self._lm_ok[kf.track_ids]
        kp, desc = self._orb.detectAndCompute(kf.image_u8, None)
        if desc is not None and ok.sum() > 0:
            from scipy.spatial import cKDTree

            xy = np.array([p.pt for p in kp])
            dist, nn = cKDTree(kf.uv_raw[ok]).query(xy, distance_upper_bound=3.0)
            hit = np.isfinite(dist)
            kf.orb_desc = desc[hit]
            kf.orb_ids = kf.track_ids[ok][nn[hit]]
        if self._cloud_kind == "semidense" and self.config.semidense:
            self._update_semidense()

    # ------------------------------------------------------------------ semi-dense depth
    def _depth_neighbors(self, k: int) -> list[int]:
        """Indices of keyframes usable as stereo partners of keyframe ``k`` (good baseline), best first."""
        cfg = self.config
        kf = self._kfs[k]
        c = invert_pose(kf.T_cam_map)[:3, 3]
        depth = self._median_depth(kf)
        cands = []
        for j, other in enumerate(self._kfs):
            if j == k or abs(j - k) > 2 * cfg.semidense_neighbors:
                continue
            b = np.linalg.norm(invert_pose(other.T_cam_map)[:3, 3] - c) / max(depth, 1e-9)
            rot = math.degrees(rotation_angle_rad(other.T_cam_map[:3, :3] @ kf.T_cam_map[:3, :3].T))
            if 0.5 * cfg.kf_min_baseline_ratio <= b <= 0.4 and rot < 25.0:
                cands.append((abs(j - k), -b, j))
        cands.sort()
        return [j for _, _, j in cands[: cfg.semidense_neighbors]]

    def _update_semidense(self) -> None:
        """Depth for keyframes that have stereo partners on both sides (each keyframe once)."""
        n = len(self._kfs)
        for k in range(max(0, n - 5), n - 1):
            if self._kfs[k].semidense is not None:
                continue
            nbs = self._depth_neighbors(k)
            if not any(j > k for j in nbs) or len(nbs) < min(2, self.config.semidense_min_views):
                continue
            self._compute_semidense(k, nbs)

    def _compute_semidense(self, k: int, nbs: list[int]) -> None:
        cfg = self.config
        kf = self._kfs[k]
        ids = kf.track_ids[self._lm_ok[kf.track_ids]]
        if len(ids) < 10:
            return
        z = transform_points(kf.T_cam_map, self._lm[ids])[:, 2]
        z = z[z > 0]
        if len(z) < 10:
            return
        rho = 1.0 / z
        lo, hi = float(np.percentile(rho, 1)) * 0.7, float(np.percentile(rho, 99)) * 1.3
        neighbors = [(self._kfs[j].undist, self._kfs[j].T_cam_map @ invert_pose(kf.T_cam_map)) for j in nbs]
        kf.semidense = keyframe_depth(
            kf.undist, neighbors, self.K, (lo, hi),
            grad_threshold=cfg.semidense_grad_threshold, max_points=cfg.semidense_max_points_per_kf,
            cell_px=cfg.semidense_cell_px, min_views=cfg.semidense_min_views, max_rel_sigma=2.0 * cfg.semidense_max_rel_sigma,
        )

    # ------------------------------------------------------------------ relocalisation
    def _relocalize(self, img_u8: np.ndarray, frame_image) -> None:
        """Find the pose of a frame after tracking loss, against the keyframes.

        Keyframes nearest the last known pose are tried first: KLT from the
        keyframe started at the landmarks' projections at the last pose (the
        robot moves slowly, the view usually comes back nearby), then ORB
        matches to the keyframe's landmarks with PnP-RANSAC for a coarse pose
        followed by the same KLT step.
        """
        cfg = self.config
        self._lost_frames += 1
        c_last = invert_pose(self._T_cam_map)[:3, 3]
        order = sorted(range(len(self._kfs)),
                       key=lambda k: np.linalg.norm(invert_pose(self._kfs[k].T_cam_map)[:3, 3] - c_last))[:6]
        cur_orb = None
        for k in order:
            kf = self._kfs[k]
            T = self._locate_from_keyframe(kf, img_u8, self._T_cam_map)
            if T is None:
                if cur_orb is None:
                    kp, desc = self._orb.detectAndCompute(img_u8, None)
                    cur_orb = (np.array([p.pt for p in kp]) if kp else np.zeros((0, 2)), desc)
                T_coarse = self._orb_pose(kf, *cur_orb)
                if T_coarse is not None:
                    T = self._locate_from_keyframe(kf, img_u8, T_coarse)
            if T is None:
                continue
            self._T_prev_cam_map = self._T_cam_map
            self._T_cam_map = T
            self._velocity = np.eye(4)
            self._status = "tracking"
            self._message = f"relocalised against keyframe {kf.id} after {self._lost_frames - 1} lost frames"
            self._lost_frames = 0
            t0 = time.perf_counter()
            self._insert_keyframe(img_u8, frame_image)
            self._mapping_time += time.perf_counter() - t0
            return
        self._message = f"lost for {self._lost_frames} frames: no keyframe matches the view"

    def _locate_from_keyframe(self, kf: _KF, img_u8: np.ndarray, T_guess: np.ndarray) -> np.ndarray | None:
        """Pose from KLT tracks keyframe -> frame started at the projections at ``T_guess``."""
        cfg = self.config
        ok_lm = self._lm_ok[kf.track_ids]
        ids_kf, uv_kf = kf.track_ids[ok_lm], kf.uv_raw[ok_lm]
        if len(ids_kf) < cfg.min_tracked_landmarks:
            return None
        proj, inview = self._project(T_guess, self._lm[ids_kf])
        if inview.sum() < cfg.min_tracked_landmarks:
            return None
        klt = self.frontend if self._frontend_kind == "klt" else KltFrontend()
        pts, okk = klt.track(kf.image_u8, img_u8, uv_kf[inview], proj[inview])
        if okk.sum() < cfg.min_tracked_landmarks:
            return None
        tr = _Tracks()
        tr.add(ids_kf[inview][okk], pts[okk])
        if self._frontend_kind == "orb":
            d, idx = orb_describe(self._orb, img_u8, tr.pts)
            keep = np.zeros(len(tr), bool)
            keep[idx] = True
            tr.keep(keep)
            tr.desc = d
        saved = self._tracks
        self._tracks = tr
        T = self._locate(T_guess)
        if T is None:
            self._tracks = saved
        return T

    def _orb_pose(self, kf: _KF, kp_xy: np.ndarray, desc: np.ndarray | None) -> np.ndarray | None:
        """Coarse pose from ORB matches between a keyframe's landmarks and the frame."""
        cfg = self.config
        if desc is None or kf.orb_desc is None or len(kf.orb_desc) < cfg.min_tracked_landmarks:
            return None
        matches = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(kf.orb_desc, desc, k=2)
        good = [m[0] for m in matches if len(m) == 2 and m[0].distance < 0.8 * m[1].distance and m[0].distance < 64]
        if len(good) < cfg.min_tracked_landmarks:
            return None
        lm_ids = kf.orb_ids[[m.queryIdx for m in good]]
        X = self._lm[lm_ids]
        uv = self._undistort_pts(kp_xy[[m.trainIdx for m in good]])
        succ, rvec, tvec, inl = cv2.solvePnPRansac(X, uv, self.K, None, iterationsCount=300,
                                                  reprojectionError=8.0, confidence=0.999)
        if not succ or inl is None or len(inl) < cfg.min_tracked_landmarks // 2:
            return None
        return make_pose(cv2.Rodrigues(rvec)[0], tvec.ravel())

    # ------------------------------------------------------------------ snapshot
    def _cloud(self) -> MapCloud:
        if self._cloud_kind == "landmarks":
            if self._cloud_cache is not None:
                return self._cloud_cache
            ids = np.flatnonzero(self._lm_ok[: self._next_track_id])
            if len(ids) == 0:
                return MapCloud()
            # keyframe of first observation and its pixel
            kf_of = np.full(len(ids), -1, np.int64)
            pix = np.full((len(ids), 2), np.nan)
            inten = np.zeros(len(ids), np.float32)
            sig = np.full(len(ids), np.nan)
            pos = {int(i): r for r, i in enumerate(ids)}
            for kf in self._kfs:
                for i, uv in zip(kf.track_ids, kf.uv_raw):
                    r = pos.get(int(i))
                    if r is not None and kf_of[r] < 0:
                        kf_of[r] = kf.id
                        pix[r] = uv
                        xi = int(np.clip(round(uv[0]), 0, kf.image.shape[1] - 1))
                        yi = int(np.clip(round(uv[1]), 0, kf.image.shape[0] - 1))
                        inten[r] = kf.image[yi, xi]
            # nominal depth sigma of a landmark: 0.5 px of disparity over a baseline of
            # twice the keyframe spacing (sigma_z = z * 0.5 px / (f * baseline / z) / z * z)
            ratio = 2.0 * self.config.kf_min_baseline_ratio
            for kf in self._kfs:
                sel = kf_of == kf.id
                if np.any(sel):
                    z = transform_points(kf.T_cam_map, self._lm[ids[sel]])[:, 2]
                    sig[sel] = np.abs(z) * 0.5 / (self.K[0, 0] * ratio)
            keep = kf_of >= 0
            self._cloud_cache = MapCloud(points=self._lm[ids[keep]].copy(), intensities=inten[keep],
                                         keyframe_ids=kf_of[keep], depth_sigma=sig[keep], pixels=pix[keep])
            return self._cloud_cache
        if self._cloud_cache is not None:
            return self._cloud_cache
        parts = []
        with_depth = [kf for kf in self._kfs if kf.semidense is not None and len(kf.semidense.inv_depth)]
        # monocular only: a depth camera's per-keyframe depths are its own measurements
        reach = self.config.semidense_cross_fusion_keyframes if self._cloud_kind == "semidense" else 0
        for a, kf in enumerate(with_depth):
            sd = kf.semidense
            partners = [o for b, o in enumerate(with_depth) if b != a and abs(b - a) <= reach]
            # the fused part only changes when a pose involved (bundle adjustment) or a partner changes
            key = tuple((o.id, o.T_cam_map.tobytes()) for o in [kf, *partners])
            hit = self._fused_parts.get(kf.id)
            if hit is not None and hit[0] == key:
                parts.append(hit[1])
                continue
            rho, rho_sig = sd.inv_depth, sd.inv_depth_sigma
            if partners:
                # the same surface seen from other keyframes: their estimates carry independent reference noise
                others = [(o.semidense.pixels, o.semidense.inv_depth, o.semidense.inv_depth_sigma,
                           kf.T_cam_map @ invert_pose(o.T_cam_map)) for o in partners]
                rho, rho_sig, _ = fuse_across_keyframes(self.K, (sd.pixels, rho, rho_sig), others)
            keep = rho_sig / rho < self.config.semidense_max_rel_sigma
            rho, rho_sig, pix = rho[keep], rho_sig[keep], sd.pixels[keep]
            depth = 1.0 / rho
            Xc = np.column_stack([(pix[:, 0] - self.K[0, 2]) / self.K[0, 0],
                                  (pix[:, 1] - self.K[1, 2]) / self.K[1, 1], np.ones(len(pix))]) * depth[:, None]
            X = transform_points(invert_pose(kf.T_cam_map), Xc)
            part = (X, sd.intensities[keep], np.full(len(X), kf.id, np.int64), rho_sig * depth**2, self._distort_px(pix))
            self._fused_parts[kf.id] = (key, part)
            parts.append(part)
        if not parts:
            return MapCloud()
        n = sum(len(p[0]) for p in parts)
        cap = self.config.cloud_max_points
        # uniform stride over the cloud (no preference for precise points: the accuracy is not selected)
        sel = np.linspace(0, n - 1, cap).astype(int) if 0 < cap < n else slice(None)
        self._cloud_cache = MapCloud(
            points=np.vstack([p[0] for p in parts])[sel],
            intensities=np.concatenate([p[1] for p in parts]).astype(np.float32)[sel],
            keyframe_ids=np.concatenate([p[2] for p in parts])[sel],
            depth_sigma=np.concatenate([p[3] for p in parts])[sel],
            pixels=np.vstack([p[4] for p in parts])[sel],
        )
        return self._cloud_cache

    def _distort_px(self, uv_undist: np.ndarray) -> np.ndarray:
        """Raw-image pixels of undistorted pixels (identity without distortion)."""
        if not self.camera.has_distortion or len(uv_undist) == 0:
            return uv_undist
        rays = np.column_stack([(uv_undist[:, 0] - self.K[0, 2]) / self.K[0, 0],
                                (uv_undist[:, 1] - self.K[1, 2]) / self.K[1, 1], np.ones(len(uv_undist))])
        return self.camera.project(rays)[0]

    def _snapshot(self) -> VseState:
        kfs = []
        for kf in self._kfs:
            if kf.published_image is None:
                img = kf.image.copy()
                img.setflags(write=False)
                kf.published_image = img
            kfs.append(Keyframe(id=kf.id, T_map_cam=invert_pose(kf.T_cam_map), image=kf.published_image,
                                timestamp_s=kf.timestamp_s))
        cloud = self._cloud() if self._kfs else MapCloud()
        return VseState(
            status=self._status,
            message=self._message,
            T_map_cam=None if self._T_cam_map is None else invert_pose(self._T_cam_map),
            keyframes=tuple(kfs),
            cloud=cloud,
            frames_processed=self._frames,
            track_fps=self._fps(self._track_times),
            overall_fps=self._fps(self._total_times),
            scale_is_metric=self._metric,
            timestamp_s=self._timestamp,
        )


class MonocularVSE(_EngineBase):
    """Monocular engine: KLT tracking, PnP, windowed bundle adjustment and a semi-dense cloud (up to scale).

    Parameters
    ----------
    camera : PinholeCamera
        Intrinsics of the frames (from calibration).
    config : VseConfig
        Options.
    """

    _frontend_kind = "klt"
    _cloud_kind = "semidense"
    _metric = False


class SparseVSE(_EngineBase):
    """Feature-based variant (ORB matching, landmark cloud), for the paper's rACR-ORB comparison."""

    _frontend_kind = "orb"
    _cloud_kind = "landmarks"
    _min_triangulation_deg = 1.5
    _noise_level_outliers = False
    _metric = False


class RgbdVSE(_EngineBase):
    """RGB-D engine: same tracking, metric map (scale 1) from the depth of each frame.

    ``process(image, timestamp_s, depth=...)`` needs the z-depth image in
    metres (0 where unknown). The cloud holds the high-gradient pixels of each
    keyframe with their measured depth.
    """

    _frontend_kind = "klt"
    _cloud_kind = "depth"
    _metric = True

    def _after_keyframe(self) -> None:
        super()._after_keyframe()
        kf = self._kfs[-1]
        if kf.depth is None:
            return
        from fgcd_cli.vse.semidense import select_pixels

        px = select_pixels(kf.undist, grad_threshold=self.config.semidense_grad_threshold,
                           max_points=self.config.semidense_max_points_per_kf)
        raw = self._distort_px(px.astype(float))
        d = cv2.remap(kf.depth.astype(np.float32), raw[:, 0].astype(np.float32).reshape(-1, 1),
                      raw[:, 1].astype(np.float32).reshape(-1, 1), cv2.INTER_NEAREST).ravel().astype(float)
        ok = np.isfinite(d) & (d > 0)
        px, d = px[ok], d[ok]
        sig = self.config.depth_sigma_rel * d
        kf.semidense = SemiDenseDepth(pixels=px.astype(float), inv_depth=1.0 / d, inv_depth_sigma=sig / d**2,
                                      n_views=np.ones(len(d), int), intensities=kf.undist[px[:, 1], px[:, 0]].astype(np.float32))
