"""Plain data of the visual SLAM engine: configuration, keyframes, cloud and state.

Everything here is immutable once published: a :class:`VseState` is a snapshot
that other threads may hold for as long as they like while the engine moves on.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import Protocol, runtime_checkable

import numpy as np

__all__ = [
    "VseStatus",
    "VseConfig",
    "Keyframe",
    "MapCloud",
    "VseState",
    "FrameLike",
    "FrameSource",
]


class VseStatus(StrEnum):
    """Tracking status of an engine (a ``str``: compares, formats and serialises as its value)."""

    INITIALIZING = "initializing"
    TRACKING = "tracking"
    LOST = "lost"
    FAILED = "failed"


@runtime_checkable
class FrameLike(Protocol):
    """What the engine needs of a camera frame (``fgcd_drivers.cameras.Frame`` fits)."""

    image: np.ndarray
    timestamp_s: float


@runtime_checkable
class FrameSource(Protocol):
    """Anything with ``grab() -> frame``; frames may carry an optional ``.depth``."""

    def grab(self) -> FrameLike:  # pragma: no cover - protocol
        ...


@dataclass(frozen=True, kw_only=True)
class VseConfig:
    """Options of the engine (defaults tuned for 640x480, slow robot motion).

    Attributes
    ----------
    max_features : int
        Tracked corners kept alive (KLT) or ORB features per frame (sparse).
    min_feature_distance_px : float
        Minimum spacing of new corners, pixels (at full resolution).
    min_corner_response : float
        Absolute minimum eigenvalue of a corner's 7x7 structure tensor (OpenCV
        units): sensor noise of 1 grey level on a blank surface gives ~2e-5 (it grows
        with the noise variance), the simulated stele ~1e-3, strong texture ~4e-2.
    klt_window_px, klt_levels : int
        Lucas-Kanade window size and pyramid levels.
    klt_fb_max_px : float
        Forward-backward consistency threshold of KLT, pixels.
    init_min_parallax_deg : float
        Median triangulation angle two views need before the map is created;
        pure rotation gives ~0 and never initialises.
    init_min_translation_parallax_deg : float
        Median residual (degrees of ray angle) of the best rotation-only fit
        between the two views that the initialisation needs: the parallax that
        only a translation produces (a pure rotation leaves ~0.005 deg of noise;
        3 cm of sideways motion before a relief 0.6 m away ~0.15 deg).
    init_min_inliers : int
        Essential-matrix inliers needed to initialise.
    init_fail_frames : int
        Frames without enough texture (corners) after which the status becomes
        ``"failed"`` rather than ``"initializing"``.
    min_tracked_landmarks : int
        Below this many PnP inliers the frame is lost.
    reproj_inlier_px : float
        Reprojection threshold (pixels) of PnP RANSAC and map-point outliers.
    kf_min_baseline_ratio : float
        New keyframe once the distance to the last keyframe over the median
        scene depth exceeds this.
    kf_max_rotation_deg : float
        ... or the rotation from the last keyframe exceeds this ...
    kf_min_tracked_fraction : float
        ... or fewer than this fraction of the last keyframe's landmarks are still tracked.
    ba_window : int
        Keyframes optimised by the windowed bundle adjustment.
    outlier_sigmas : float
        An observation is an outlier when its reprojection error exceeds this
        many times the robust noise scale of the residuals (from their median;
        chi-square with 2 degrees of freedom: 4 sigma is exceeded with
        probability 3e-4). KLT tracks are good to ~0.05 px on slow motion, so a
        fixed pixel threshold let tracks that slide along occluding contours
        (errors of 1-20 px, absorbed by a wrong landmark depth) bias the poses.
    outlier_min_px : float
        ... but never below this many pixels (the tails of KLT errors).
    ba_iterations : int
        Levenberg-Marquardt iterations of each bundle adjustment.
    semidense : bool
        Compute the semi-dense cloud of keyframes (off for the sparse variant).
    semidense_max_points_per_kf : int
        Cap on semi-dense pixels per keyframe.
    semidense_grad_threshold : float
        Minimum gradient magnitude (grey levels/pixel on the [0, 1] scale times 255).
    semidense_cell_px : int
        At most one semi-dense pixel per square of this side (pixels).
    semidense_neighbors : int
        Neighbouring keyframes searched per keyframe (multi-view fusion).
    semidense_min_views : int
        Consistent depth observations a semi-dense point needs to be kept.
    semidense_max_rel_sigma : float
        Publish points whose depth sigma over depth, after the fusion across
        keyframes, is below this (a keyframe keeps its own estimates up to twice
        this, so that fusion can bring them under it).
    semidense_refresh : bool
        Search a keyframe's semi-dense depths again, with the same stereo
        partners, when bundle adjustment has moved the keyframe or a partner
        since they were searched (docs/vse.md, "Design and why", item 4).
    semidense_cross_fusion_keyframes : int
        A keyframe's semi-dense depths are fused with the estimates of the same
        surface points from the keyframes up to this many places away in the
        keyframe list (0: off).
    cloud_max_points : int
        The published semi-dense/depth cloud is thinned by a uniform stride to
        at most this many points (0: no cap). The photometric alignment samples
        all points in one ``cv2.remap`` call, which refuses more than 32767.
    depth_sigma_rel : float
        RGB-D only: relative depth noise of the sensor (sigma / depth).
    """

    max_features: int = 900
    min_feature_distance_px: float = 12.0
    min_corner_response: float = 2e-4
    klt_window_px: int = 21
    klt_levels: int = 3
    klt_fb_max_px: float = 0.5
    init_min_parallax_deg: float = 0.5
    init_min_translation_parallax_deg: float = 0.02
    init_min_inliers: int = 60
    init_planar_ratio: float = 0.9
    """Initialise from the homography when it explains this fraction of the
    essential matrix's inliers (a plane-like scene, see ``twoview.planar_two_view``)."""
    init_fail_frames: int = 40
    min_tracked_landmarks: int = 25
    reproj_inlier_px: float = 2.0
    kf_min_baseline_ratio: float = 0.008
    kf_max_rotation_deg: float = 6.0
    kf_min_tracked_fraction: float = 0.6
    ba_window: int = 8
    outlier_sigmas: float = 4.0
    outlier_min_px: float = 0.5
    ba_iterations: int = 8
    semidense: bool = True
    semidense_max_points_per_kf: int = 12000
    semidense_grad_threshold: float = 6.0
    semidense_cell_px: int = 3
    semidense_neighbors: int = 4
    semidense_min_views: int = 2
    semidense_max_rel_sigma: float = 0.02
    semidense_refresh: bool = True
    semidense_cross_fusion_keyframes: int = 6
    cloud_max_points: int = 30000
    depth_sigma_rel: float = 0.002


@dataclass(frozen=True, kw_only=True)
class Keyframe:
    """A keyframe as other modules see it.

    Attributes
    ----------
    id : int
        Identifier, increasing within a session.
    T_map_cam : (4, 4) ndarray
        Pose in the map frame (up to scale for the monocular engine).
    image : (H, W) float32 ndarray
        Grayscale image in [0, 1].
    timestamp_s : float
        Capture time of the frame, seconds.
    """

    id: int
    T_map_cam: np.ndarray
    image: np.ndarray
    timestamp_s: float


def _empty(shape, dtype=float) -> np.ndarray:
    return np.zeros(shape, dtype=dtype)


@dataclass(frozen=True, kw_only=True)
class MapCloud:
    """The engine's point cloud in the map frame.

    Attributes
    ----------
    points : (N, 3) float64 ndarray
        Map-frame positions (map units: metres for RGB-D, up to scale for mono).
    intensities : (N,) float32 ndarray
        Grey value in [0, 1] of the pixel the point came from.
    keyframe_ids : (N,) int64 ndarray
        Keyframe each point was measured in.
    depth_sigma : (N,) float64 ndarray
        One-sigma uncertainty of the point's depth along its keyframe ray, map units.
    pixels : (N, 2) float64 ndarray
        ``(u, v)`` pixel of the point in its keyframe.
    normals : (N, 3) ndarray or None
        Unit normals in the map frame when known.
    """

    points: np.ndarray = field(default_factory=lambda: _empty((0, 3)))
    intensities: np.ndarray = field(default_factory=lambda: _empty((0,), np.float32))
    keyframe_ids: np.ndarray = field(default_factory=lambda: _empty((0,), np.int64))
    depth_sigma: np.ndarray = field(default_factory=lambda: _empty((0,)))
    pixels: np.ndarray = field(default_factory=lambda: _empty((0, 2)))
    normals: np.ndarray | None = None

    def __len__(self) -> int:
        return int(len(self.points))


@dataclass(frozen=True, kw_only=True)
class VseState:
    """Snapshot of the engine after a frame.

    Attributes
    ----------
    status : VseStatus
        ``initializing``, ``tracking``, ``lost`` or ``failed``. ``lost`` means the
        last frame could not be located (the engine keeps trying to relocalise
        against its keyframes); ``failed`` means the scene cannot be tracked at
        all (e.g. no texture) and the cloud stays empty.
    message : str
        One line for a person explaining the status.
    T_map_cam : (4, 4) ndarray or None
        Latest camera pose in the map frame; ``None`` before initialisation.
    keyframes : tuple of Keyframe
        All keyframes, oldest first.
    cloud : MapCloud
        Semi-dense cloud (monocular), depth-image cloud (RGB-D) or landmarks (sparse).
    frames_processed : int
        Frames given to the engine since the last reset.
    track_fps : float
        Frames per second of the tracking front-end (pose of each frame),
        averaged over recent frames; mapping (bundle adjustment and depth
        estimation of keyframes) is counted in ``overall_fps``.
    overall_fps : float
        Frames per second including the mapping work done in :meth:`process`.
    scale_is_metric : bool
        True for the RGB-D engine (map units are metres).
    timestamp_s : float
        Timestamp of the latest frame.
    """

    status: VseStatus
    message: str
    T_map_cam: np.ndarray | None
    keyframes: tuple[Keyframe, ...] = ()
    cloud: MapCloud = field(default_factory=MapCloud)
    frames_processed: int = 0
    track_fps: float = 0.0
    overall_fps: float = 0.0
    scale_is_metric: bool = False
    timestamp_s: float = float("nan")
