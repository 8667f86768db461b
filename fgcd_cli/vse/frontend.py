"""The engine's tracking front-ends: the active feature tracks and the two ways of following them.

A front-end moves the tracks of the previous frame into the current one and
detects new features away from the surviving tracks. :class:`KltTracking`
(Shi-Tomasi corners and pyramidal Lucas-Kanade, sub-pixel) serves the
monocular and RGB-D engines, :class:`OrbTracking` (ORB matches gated by the
predicted position) the sparse engine. Each also states the two choices that
depend on the precision of its keypoints (see docs/vse.md, "Design and why"):
the ray angle a new landmark needs and whether outliers are judged against the
residuals' own noise level. All positions are raw (distorted) image pixels.
"""

from __future__ import annotations

from collections.abc import Callable
from enum import StrEnum
from typing import Protocol

import cv2
import numpy as np

from fgcd_cli.vse.features import KltFrontend, OrbFrontend, orb_describe
from fgcd_cli.vse.types import VseConfig

__all__ = ["FrontendKind", "Tracks", "TrackingFrontend", "KltTracking", "OrbTracking"]

DESCRIPTOR_BYTES = 32  # ORB descriptor length


class FrontendKind(StrEnum):
    """Which feature front-end an engine runs."""

    KLT = "klt"
    ORB = "orb"


class Tracks:
    """Active feature tracks (struct of arrays).

    Attributes
    ----------
    ids : (N,) int64 ndarray
        Track id, which is also the id of the track's landmark.
    pts : (N, 2) float64 ndarray
        Raw pixels in the latest frame.
    desc : (N, 32) uint8 ndarray
        ORB descriptor of the track's first observation (ORB front-end only;
        empty otherwise).
    """

    def __init__(self) -> None:
        self.ids = np.zeros(0, np.int64)
        self.pts = np.zeros((0, 2))
        self.desc = np.zeros((0, DESCRIPTOR_BYTES), np.uint8)

    def __len__(self) -> int:
        return len(self.ids)

    def keep(self, mask: np.ndarray) -> None:
        """Keep the tracks where ``mask`` (N,) is true."""
        self.ids = self.ids[mask]
        self.pts = self.pts[mask]
        if len(self.desc) == len(mask):
            self.desc = self.desc[mask]

    def add(self, ids: np.ndarray, pts: np.ndarray, desc: np.ndarray | None = None) -> None:
        """Append tracks ``ids`` (K,) at ``pts`` (K, 2), with descriptors (K, 32) when given."""
        self.ids = np.concatenate([self.ids, ids])
        self.pts = np.vstack([self.pts, pts]) if len(pts) else self.pts
        if desc is not None and len(desc):
            n_old = len(self.ids) - len(ids)
            base = self.desc if len(self.desc) == n_old else np.zeros((n_old, DESCRIPTOR_BYTES), np.uint8)
            self.desc = np.vstack([base, desc])


class TrackingFrontend(Protocol):
    """What the engine needs of a front-end."""

    kind: FrontendKind
    min_triangulation_deg: float
    """Ray angle (degrees) a new landmark needs between its two keyframes."""
    noise_level_outliers: bool
    """Judge outliers against the residuals' own noise level (``ba.outlier_threshold_px``)."""
    klt: KltFrontend
    """The KLT tracker relocalisation refines with (sub-pixel tracks from a keyframe)."""

    def follow(self, tracks: Tracks, prev_u8: np.ndarray, img_u8: np.ndarray, guess: np.ndarray | None) -> None:
        """Move ``tracks`` into ``img_u8``, dropping those lost (``guess``: (N, 2) predicted pixels)."""

    def detect(self, tracks: Tracks, img_u8: np.ndarray, max_new: int, new_ids: Callable[[int], np.ndarray]) -> None:
        """Add up to ``max_new`` tracks away from the existing ones (``new_ids(k)`` gives fresh ids)."""

    def motion_guess(
        self, tracks: Tracks, has_landmark: np.ndarray, projected: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
    ) -> np.ndarray | None:
        """Predicted pixels (N, 2) of the tracks, or None to start from their previous positions."""

    def describe(self, tracks: Tracks, img_u8: np.ndarray, orb: cv2.ORB) -> None:
        """Give tracks built by relocalisation what this front-end matches with."""


class KltTracking:
    """KLT corner tracking: sub-pixel tracks (~0.1 px), so a new landmark needs 0.5 deg of parallax."""

    kind = FrontendKind.KLT
    min_triangulation_deg = 0.5
    noise_level_outliers = True

    def __init__(self, config: VseConfig) -> None:
        self.klt = KltFrontend(
            window_px=config.klt_window_px,
            levels=config.klt_levels,
            fb_max_px=config.klt_fb_max_px,
            min_distance_px=config.min_feature_distance_px,
            min_corner_response=config.min_corner_response,
        )

    def follow(self, tracks: Tracks, prev_u8: np.ndarray, img_u8: np.ndarray, guess: np.ndarray | None) -> None:
        if len(tracks) == 0:
            return
        new, ok = self.klt.track(prev_u8, img_u8, tracks.pts, guess)
        tracks.pts = new
        tracks.keep(ok)

    def detect(self, tracks: Tracks, img_u8: np.ndarray, max_new: int, new_ids: Callable[[int], np.ndarray]) -> None:
        pts = self.klt.detect(img_u8, tracks.pts, max_new)
        if len(pts):
            tracks.add(new_ids(len(pts)), pts)

    def motion_guess(self, tracks, has_landmark, projected) -> None:
        return None

    def describe(self, tracks: Tracks, img_u8: np.ndarray, orb: cv2.ORB) -> None:
        return None


class OrbTracking:
    """ORB matching (ORB-SLAM-like, the paper's rACR-ORB comparison).

    ORB keypoints are good to ~0.5 px (no sub-pixel refinement), so a new
    landmark waits for 1.5 deg of parallax. They are quantised at their pyramid
    level (the noise grows 1.2x per level), so one noise scale per window would
    reject good coarse-level matches: outliers are judged against a fixed
    threshold instead (docs/vse.md, "Design and why").
    """

    kind = FrontendKind.ORB
    min_triangulation_deg = 1.5
    noise_level_outliers = False

    def __init__(self, config: VseConfig) -> None:
        self.orb = OrbFrontend(
            n_features=max(2 * config.max_features, 1000),
            min_distance_px=config.min_feature_distance_px * 0.6,
            min_corner_response=config.min_corner_response,
        )
        self.klt = KltFrontend()

    def follow(self, tracks: Tracks, prev_u8: np.ndarray, img_u8: np.ndarray, guess: np.ndarray | None) -> None:
        if len(tracks) == 0:
            return
        prior = tracks.pts if guess is None else guess
        new, desc, ok = self.orb.match(tracks.desc, prior, img_u8)
        tracks.pts = new
        tracks.desc = desc
        tracks.keep(ok)

    def detect(self, tracks: Tracks, img_u8: np.ndarray, max_new: int, new_ids: Callable[[int], np.ndarray]) -> None:
        pts, desc = self.orb.detect(img_u8, tracks.pts, max_new)
        if len(pts):
            if len(tracks.desc) != len(tracks):
                tracks.desc = np.zeros((len(tracks), DESCRIPTOR_BYTES), np.uint8)
            tracks.add(new_ids(len(pts)), pts, desc)

    def motion_guess(
        self, tracks: Tracks, has_landmark: np.ndarray, projected: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
    ) -> np.ndarray | None:
        """Tracks with a landmark start the search at its projection at the predicted pose.

        ``projected(mask)`` returns the raw pixels and in-view flags of the
        landmarks of ``tracks[mask]``.
        """
        if not len(tracks):
            return None
        guess = tracks.pts.copy()
        if np.any(has_landmark):
            uvp, inv = projected(has_landmark)
            g = guess[has_landmark]
            g[inv] = uvp[inv]
            guess[has_landmark] = g
        return guess

    def describe(self, tracks: Tracks, img_u8: np.ndarray, orb: cv2.ORB) -> None:
        d, idx = orb_describe(orb, img_u8, tracks.pts)
        keep = np.zeros(len(tracks), bool)
        keep[idx] = True
        tracks.keep(keep)
        tracks.desc = d
