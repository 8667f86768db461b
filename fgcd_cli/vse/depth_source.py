"""Where the depth of a new landmark comes from: two keyframes (monocular) or the depth image (RGB-D).

The choice also fixes the initialisation (two views with parallax, or the
first textured frame) and whether map units are metres.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np

from fgcd_cli.vse.initializer import DepthInitializer, TwoViewInitializer
from fgcd_cli.vse.landmarks import KeyframeRecord, lift_with_depth, triangulate_new

if TYPE_CHECKING:
    from fgcd_cli.vse.engine_view import EngineView

__all__ = ["DepthSource", "Triangulation", "DepthImage"]


class DepthSource(Protocol):
    """What the engine needs of a depth source."""

    metric: bool
    """Map units are metres (every frame then needs a depth image)."""

    def reset(self) -> None:
        """Forget any initialisation in progress."""

    def initialize(self, eng: EngineView, img_u8: np.ndarray, frame_image: np.ndarray) -> None:
        """One frame before the map exists."""

    def on_keyframe(self, eng: EngineView, kf: KeyframeRecord) -> None:
        """Landmarks for the new keyframe's tracks, before the bundle adjustment."""

    def on_new_tracks(self, eng: EngineView, kf: KeyframeRecord) -> None:
        """Landmarks for the tracks detected in the new keyframe."""


class Triangulation:
    """Monocular: landmarks triangulated from their first keyframe; the map is up to scale."""

    metric = False

    def __init__(self) -> None:
        self.initializer = TwoViewInitializer()

    def reset(self) -> None:
        self.initializer = TwoViewInitializer()

    def initialize(self, eng: EngineView, img_u8: np.ndarray, frame_image: np.ndarray) -> None:
        self.initializer.step(eng, img_u8, frame_image)

    def on_keyframe(self, eng: EngineView, kf: KeyframeRecord) -> None:
        triangulate_new(
            kf,
            eng.kfs,
            eng.landmarks,
            eng.K,
            min_angle_deg=eng.frontend.min_triangulation_deg,
            reproj_inlier_px=eng.config.reproj_inlier_px,
        )

    def on_new_tracks(self, eng: EngineView, kf: KeyframeRecord) -> None:
        """New tracks wait for a second keyframe."""


class DepthImage:
    """RGB-D: landmarks from the depth image of their keyframe; the map is metric (scale 1)."""

    metric = True

    def __init__(self) -> None:
        self.initializer = DepthInitializer()

    def reset(self) -> None:
        self.initializer = DepthInitializer()

    def initialize(self, eng: EngineView, img_u8: np.ndarray, frame_image: np.ndarray) -> None:
        self.initializer.step(eng, img_u8, frame_image)

    def on_keyframe(self, eng: EngineView, kf: KeyframeRecord) -> None:
        lift_with_depth(eng.camera, eng.landmarks, kf, eng.tracks.ids, eng.tracks.pts)

    def on_new_tracks(self, eng: EngineView, kf: KeyframeRecord) -> None:
        lift_with_depth(eng.camera, eng.landmarks, kf, eng.tracks.ids, eng.tracks.pts)
