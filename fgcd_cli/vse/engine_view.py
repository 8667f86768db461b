"""What the parts of a VSE (initializer, depth source, cloud builder, mapping, relocalizer) see of their engine.

The engine (:class:`fgcd_cli.vse.engine.VisualSlamEngine`) is composed of these
parts and hands itself to each of them; the parts are typed against this
protocol instead of the engine, so the engine imports its parts and no part
imports the engine (no import circle, docs/architecture.md, "Modules").
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from fgcd_cli.vse.frontend import TrackingFrontend, Tracks
from fgcd_cli.vse.landmarks import KeyframeRecord, LandmarkMap
from fgcd_cli.vse.types import VseConfig, VseStatus
from fgcd_core.camera import PinholeCamera


class EngineView(Protocol):
    """The engine's state and steps a part reads and calls.

    Attributes
    ----------
    camera : PinholeCamera
        The camera model; ``K`` (3, 3) its intrinsic matrix, pixels.
    config : VseConfig
        The engine's options.
    frontend : TrackingFrontend
        Feature detection and tracking (KLT or ORB).
    tracks : Tracks
        The tracks followed into the current frame.
    landmarks : LandmarkMap
        The map's 3D points, map units.
    kfs : list of KeyframeRecord
        The keyframes, oldest first.
    T_cam_map : (4, 4) ndarray or None
        The current camera pose (map -> camera); None before initialisation.
    velocity : (4, 4) ndarray
        The last inter-frame motion (constant-velocity prediction).
    status, message
        The tracking status and its one-line reason.
    timestamp : float
        The current frame's time, seconds.
    depth : (H, W) ndarray or None
        The current frame's depth, metres (RGB-D only).
    lost_frames : int
        Frames since tracking was lost.
    mapping_time : float
        Seconds spent in mapping (bundle adjustment, cloud) so far.
    """

    camera: PinholeCamera
    K: np.ndarray
    config: VseConfig
    frontend: TrackingFrontend
    tracks: Tracks
    landmarks: LandmarkMap
    kfs: list[KeyframeRecord]
    T_cam_map: np.ndarray | None
    velocity: np.ndarray
    status: VseStatus
    message: str
    timestamp: float
    depth: np.ndarray | None
    lost_frames: int
    mapping_time: float

    def undistort_pts(self, pts: np.ndarray) -> np.ndarray: ...

    def distort_px(self, uv_undist: np.ndarray) -> np.ndarray: ...

    def project(self, T_cam_map: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...

    def follow(self, img_u8: np.ndarray, guess: np.ndarray | None = None) -> None: ...

    def detect(self, img_u8: np.ndarray, max_new: int) -> None: ...

    def add_keyframe(
        self,
        img_u8: np.ndarray,
        frame_image: np.ndarray,
        T_cam_map: np.ndarray,
        ids: np.ndarray,
        uv_raw: np.ndarray,
        timestamp_s: float,
        depth: np.ndarray | None,
    ) -> KeyframeRecord: ...

    def run_ba(self) -> None: ...

    def record_new_observations(self, kf: KeyframeRecord) -> None: ...

    def after_keyframe(self) -> None: ...

    def insert_keyframe(self, img_u8: np.ndarray, frame_image: np.ndarray) -> None: ...

    def locate(self, T_pred: np.ndarray) -> np.ndarray | None: ...
