"""Feature front-ends: KLT corner tracking (monocular/RGB-D engines) and ORB matching (sparse engine).

Both follow a set of tracks from the previous frame into the current one and
detect new features away from the existing tracks; the engine above them is
shared. All positions are raw (distorted) image pixels.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["KltFrontend", "OrbFrontend", "occupancy_mask", "orb_describe"]


def occupancy_mask(shape: tuple[int, int], points: np.ndarray, radius_px: float, border_px: int) -> np.ndarray:
    """uint8 mask, 255 where a new feature may be detected (away from ``points`` and the border)."""
    h, w = shape
    mask = np.zeros((h, w), np.uint8)
    mask[border_px : h - border_px, border_px : w - border_px] = 255
    r = max(1, int(round(radius_px)))
    for x, y in np.asarray(points, dtype=float).reshape(-1, 2):
        if np.isfinite(x) and np.isfinite(y):
            cv2.circle(mask, (int(round(x)), int(round(y))), r, 0, -1)
    return mask


def orb_describe(orb: cv2.ORB, image_u8: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ORB descriptors at given pixels.

    Returns
    -------
    desc : (K, 32) uint8 ndarray
    index : (K,) int ndarray
        Which of ``points`` got a descriptor (OpenCV drops those near the border).
    """
    kps = [cv2.KeyPoint(float(x), float(y), 31.0, -1, 0, 0, i) for i, (x, y) in enumerate(points)]
    kps, desc = orb.compute(image_u8, kps)
    if desc is None or not kps:
        return np.zeros((0, 32), np.uint8), np.zeros(0, int)
    return desc, np.array([k.class_id for k in kps], dtype=int)


def _corner_response(img_u8: np.ndarray) -> np.ndarray:
    """Absolute corner response (H, W) float32: the minimum eigenvalue of the 7x7 structure tensor, OpenCV units."""
    return cv2.cornerMinEigenVal(img_u8, 7, 3)


def _strong(response: np.ndarray, pts: np.ndarray, min_response: float) -> np.ndarray:
    """(N,) bool: which points (N, 2) have a :func:`_corner_response` reaching ``min_response``; relative
    quality thresholds alone turn sensor noise on a blank wall into "corners"."""
    xi = np.clip(np.round(pts[:, 0]).astype(int), 0, response.shape[1] - 1)
    yi = np.clip(np.round(pts[:, 1]).astype(int), 0, response.shape[0] - 1)
    return response[yi, xi] >= min_response


class KltFrontend:
    """Shi-Tomasi corners followed by pyramidal Lucas-Kanade with a forward-backward check."""

    name = "klt"

    def __init__(
        self,
        *,
        window_px: int = 21,
        levels: int = 3,
        fb_max_px: float = 0.5,
        min_distance_px: float = 12.0,
        min_corner_response: float = 1e-3,
    ):
        self.window = (int(window_px), int(window_px))
        self.levels = int(levels)
        self.fb_max_px = float(fb_max_px)
        self.min_distance_px = float(min_distance_px)
        self.min_corner_response = float(min_corner_response)
        self._criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)

    def track(
        self, prev_u8: np.ndarray, cur_u8: np.ndarray, pts: np.ndarray, guess: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Follow ``pts`` (N, 2) from ``prev_u8`` into ``cur_u8``.

        Returns
        -------
        new_pts : (N, 2) float64 ndarray
        ok : (N,) bool ndarray
            Tracked, inside the image and forward-backward consistent.
        """
        n = len(pts)
        if n == 0:
            return np.zeros((0, 2)), np.zeros(0, bool)
        p0 = np.asarray(pts, np.float32).reshape(-1, 1, 2)
        flags = 0
        p1 = None
        if guess is not None:
            p1 = np.asarray(guess, np.float32).reshape(-1, 1, 2).copy()
            flags = cv2.OPTFLOW_USE_INITIAL_FLOW
        p1, st1, _ = cv2.calcOpticalFlowPyrLK(
            prev_u8, cur_u8, p0, p1, winSize=self.window, maxLevel=self.levels, criteria=self._criteria, flags=flags
        )
        p0b, st2, _ = cv2.calcOpticalFlowPyrLK(
            cur_u8,
            prev_u8,
            p1,
            p0.copy(),
            winSize=self.window,
            maxLevel=self.levels,
            criteria=self._criteria,
            flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
        )
        p1 = p1.reshape(-1, 2).astype(float)
        fb = np.linalg.norm(p0b.reshape(-1, 2) - p0.reshape(-1, 2), axis=1)
        h, w = cur_u8.shape
        inside = (p1[:, 0] >= 2) & (p1[:, 0] <= w - 3) & (p1[:, 1] >= 2) & (p1[:, 1] <= h - 3)
        ok = (st1.ravel() == 1) & (st2.ravel() == 1) & (fb < self.fb_max_px) & inside
        return p1, ok

    def detect(self, img_u8: np.ndarray, existing: np.ndarray, max_new: int) -> np.ndarray:
        """New corners (K, 2) away from ``existing`` points, subpixel-refined."""
        if max_new <= 0:
            return np.zeros((0, 2))
        mask = occupancy_mask(img_u8.shape, existing, self.min_distance_px, border_px=self.window[0] // 2 + 2)
        response = _corner_response(img_u8)
        strongest = float(response[mask > 0].max(initial=0.0))
        if strongest < self.min_corner_response:
            return np.zeros((0, 2))
        # Rule: the absolute response is the only threshold. OpenCV's qualityLevel is relative to the
        # image's strongest corner, so one dark pit or glint under a torch (100x the texture's response)
        # would hide every other corner; expressed relative to that maximum it is min_corner_response.
        corners = cv2.goodFeaturesToTrack(
            img_u8,
            maxCorners=int(max_new),
            qualityLevel=min(1.0, self.min_corner_response / strongest),
            minDistance=self.min_distance_px,
            mask=mask,
            blockSize=7,
        )
        if corners is None:
            return np.zeros((0, 2))
        corners = corners.reshape(-1, 2)
        corners = corners[_strong(response, corners, self.min_corner_response)].reshape(-1, 1, 2)
        if len(corners) == 0:
            return np.zeros((0, 2))
        corners = cv2.cornerSubPix(
            img_u8,
            corners.astype(np.float32),
            (4, 4),
            (-1, -1),
            (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 0.01),
        )
        return corners.reshape(-1, 2).astype(float)


class OrbFrontend:
    """ORB features matched to the tracks' descriptors inside a search radius (sparse, ORB-SLAM-like).

    Each track keeps the descriptor of its first observation; matching is a
    brute-force Hamming search gated by the distance to the track's previous
    position (slow robot motion), with a ratio test.
    """

    name = "orb"

    def __init__(
        self,
        *,
        n_features: int = 2000,
        search_radius_px: float = 20.0,
        max_hamming: int = 50,
        ratio: float = 0.8,
        min_distance_px: float = 8.0,
        min_corner_response: float = 1e-3,
    ):
        self.orb = cv2.ORB_create(nfeatures=int(n_features), scaleFactor=1.2, nlevels=4, fastThreshold=10)
        self.min_corner_response = float(min_corner_response)
        self.search_radius_px = float(search_radius_px)
        self.max_hamming = int(max_hamming)
        self.ratio = float(ratio)
        self.min_distance_px = float(min_distance_px)
        self._matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
        self._cache_key = None
        self._cache: tuple[np.ndarray, np.ndarray] | None = None

    def features(self, img_u8: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """ORB keypoints (K, 2) and descriptors (K, 32) of an image (cached for the latest image)."""
        # keep a reference to the cached image: an id() alone can be reused by a new array
        if self._cache_key is img_u8 and self._cache is not None:
            return self._cache
        key = img_u8
        kps, desc = self.orb.detectAndCompute(img_u8, None)
        if desc is None:
            out = (np.zeros((0, 2)), np.zeros((0, 32), np.uint8))
        else:
            pts = np.array([k.pt for k in kps], float)
            strong = _strong(_corner_response(img_u8), pts, self.min_corner_response)
            out = (pts[strong], desc[strong])
        self._cache_key, self._cache = key, out
        return out

    def match(
        self, desc_tracks: np.ndarray, pos_tracks: np.ndarray, img_u8: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Match track descriptors into the image.

        Returns
        -------
        new_pts : (N, 2) ndarray
        new_desc : (N, 32) uint8 ndarray
        ok : (N,) bool ndarray
        """
        n = len(desc_tracks)
        new_pts = np.full((n, 2), np.nan)
        new_desc = np.array(desc_tracks, copy=True)
        ok = np.zeros(n, bool)
        kp, desc = self.features(img_u8)
        if n == 0 or len(kp) == 0:
            return new_pts, new_desc, ok
        d2 = ((pos_tracks[:, None, :] - kp[None, :, :]) ** 2).sum(-1)
        allowed = (d2 <= self.search_radius_px**2).astype(np.uint8)
        matches = self._matcher.knnMatch(np.ascontiguousarray(desc_tracks), desc, k=2, mask=allowed)
        best = np.full(n, -1)
        bestd = np.full(n, np.inf)
        good = np.zeros(n, bool)
        for m in matches:
            if not m:
                continue
            i = m[0].queryIdx
            second = m[1].distance if len(m) > 1 else np.inf
            best[i], bestd[i] = m[0].trainIdx, m[0].distance
            good[i] = m[0].distance <= self.max_hamming and m[0].distance < self.ratio * second
        # one feature for one track: keep the best track per feature
        taken = set()
        for i in np.argsort(bestd):
            if not good[i]:
                continue
            if best[i] in taken:
                good[i] = False
                continue
            taken.add(best[i])
        # a track keeps the descriptor of its first observation (as a map point
        # does in ORB-SLAM): updating it every frame lets matches drift to neighbours
        new_pts[good] = kp[best[good]]
        ok[good] = True
        return new_pts, new_desc, ok

    def detect(self, img_u8: np.ndarray, existing: np.ndarray, max_new: int) -> tuple[np.ndarray, np.ndarray]:
        """Features (K, 2) with descriptors (K, 32) away from ``existing`` points."""
        kp, desc = self.features(img_u8)
        if max_new <= 0 or len(kp) == 0:
            return np.zeros((0, 2)), np.zeros((0, 32), np.uint8)
        mask = occupancy_mask(img_u8.shape, existing, self.min_distance_px, border_px=16)
        xi = np.clip(np.round(kp[:, 0]).astype(int), 0, img_u8.shape[1] - 1)
        yi = np.clip(np.round(kp[:, 1]).astype(int), 0, img_u8.shape[0] - 1)
        keep = np.flatnonzero(mask[yi, xi] > 0)[:max_new]
        return kp[keep], desc[keep]
