"""The engine's published cloud, and the per-keyframe depths behind it.

Three builders, one per kind of cloud:

* :class:`SemiDenseCloud` (monocular): each keyframe that has stereo partners
  on both sides gets its semi-dense depth (:func:`~fgcd_cli.vse.semidense.keyframe_depth`);
  the cloud fuses each keyframe's depths with those of its neighbours in the
  keyframe list (:func:`~fgcd_cli.vse.semidense.fuse_across_keyframes`);
* :class:`DepthImageCloud` (RGB-D): the high-gradient pixels of each keyframe
  with their measured depth (not fused: they are measurements);
* :class:`LandmarkCloud` (sparse): the landmarks.

docs/vse.md, "Design and why", item 4. A cloud is rebuilt only after a new
keyframe; a keyframe's fused part is reused until a pose involved changes.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Protocol

import cv2
import numpy as np

from fgcd_cli.vse.landmarks import KeyframeRecord, median_depth
from fgcd_cli.vse.semidense import (
    KeyframeDepthConfig,
    SemiDenseDepth,
    fuse_across_keyframes,
    keyframe_depth,
    select_pixels,
)
from fgcd_cli.vse.types import MapCloud, VseConfig
from fgcd_core.se3 import invert_pose, rotation_angle_rad, transform_points

if TYPE_CHECKING:
    from fgcd_cli.vse.engine_view import EngineView

__all__ = ["CloudBuilder", "SemiDenseCloud", "DepthImageCloud", "LandmarkCloud"]

# keyframes after which a keyframe's semi-dense depth is no longer tried
_SEMIDENSE_LOOKBACK = 5
# stereo partners of a keyframe: baseline at most this fraction of its median depth, rotation below this
_PARTNER_MAX_BASELINE_RATIO = 0.4
_PARTNER_MAX_ROTATION_DEG = 25.0


class CloudBuilder(Protocol):
    """What the engine needs of a cloud builder."""

    def reset(self) -> None:
        """Forget every cached cloud part."""

    def after_keyframe(self, eng: EngineView) -> None:
        """A keyframe was added (the cloud is stale; per-keyframe depths may be due)."""

    def cloud(self, eng: EngineView) -> MapCloud:
        """The current cloud (cached until the next keyframe)."""


class LandmarkCloud:
    """The sparse landmarks, each with the keyframe and pixel of its first observation."""

    def __init__(self) -> None:
        self._cache: MapCloud | None = None

    def reset(self) -> None:
        self._cache = None

    def after_keyframe(self, eng: EngineView) -> None:
        self._cache = None

    def cloud(self, eng: EngineView) -> MapCloud:
        if self._cache is None:
            self._cache = landmark_cloud(
                eng.kfs,
                eng.landmarks.points,
                eng.landmarks.ok[: eng.landmarks.next_id],
                eng.K,
                kf_min_baseline_ratio=eng.config.kf_min_baseline_ratio,
            )
        return self._cache


def landmark_cloud(
    kfs: list[KeyframeRecord], points: np.ndarray, ok: np.ndarray, K: np.ndarray, *, kf_min_baseline_ratio: float
) -> MapCloud:
    """Cloud of the landmarks ``points[ok]`` seen in a keyframe.

    The depth sigma of a landmark is nominal: 0.5 px of disparity over a
    baseline of twice the keyframe spacing ``kf_min_baseline_ratio`` (of the
    depth ``z``), ``sigma_z = z * 0.5 px / (f * 2 * ratio)``.
    """
    ids = np.flatnonzero(ok)
    if len(ids) == 0:
        return MapCloud()
    kf_of = np.full(len(ids), -1, np.int64)
    pix = np.full((len(ids), 2), np.nan)
    inten = np.zeros(len(ids), np.float32)
    sig = np.full(len(ids), np.nan)
    pos = {int(i): r for r, i in enumerate(ids)}
    for kf in kfs:
        for i, uv in zip(kf.track_ids, kf.uv_raw):
            r = pos.get(int(i))
            if r is not None and kf_of[r] < 0:
                kf_of[r] = kf.id
                pix[r] = uv
                xi = int(np.clip(round(uv[0]), 0, kf.image.shape[1] - 1))
                yi = int(np.clip(round(uv[1]), 0, kf.image.shape[0] - 1))
                inten[r] = kf.image[yi, xi]
    ratio = 2.0 * kf_min_baseline_ratio
    for kf in kfs:
        sel = kf_of == kf.id
        if np.any(sel):
            z = transform_points(kf.T_cam_map, points[ids[sel]])[:, 2]
            sig[sel] = np.abs(z) * 0.5 / (K[0, 0] * ratio)
    keep = kf_of >= 0
    return MapCloud(
        points=points[ids[keep]].copy(),
        intensities=inten[keep],
        keyframe_ids=kf_of[keep],
        depth_sigma=sig[keep],
        pixels=pix[keep],
    )


class _FusedKeyframeCloud:
    """The cloud of the keyframes' per-pixel depths, each fused with its ``reach`` neighbours' (0: none)."""

    def __init__(self) -> None:
        self._cache: MapCloud | None = None
        self._parts: dict[int, tuple] = {}  # keyframe id -> (poses key, cloud part)

    def reset(self) -> None:
        self._cache = None
        self._parts = {}

    def after_keyframe(self, eng: EngineView) -> None:
        self._cache = None

    def _reach(self, config: VseConfig) -> int:
        return 0

    def cloud(self, eng: EngineView) -> MapCloud:
        if self._cache is not None:
            return self._cache
        parts = []
        with_depth = [kf for kf in eng.kfs if kf.semidense is not None and len(kf.semidense.inv_depth)]
        reach = self._reach(eng.config)
        for a, kf in enumerate(with_depth):
            partners = [o for b, o in enumerate(with_depth) if b != a and abs(b - a) <= reach]
            # the fused part only changes when a pose involved (bundle adjustment), a partner, or the depths
            # searched again (the geometry they were searched with) change
            key = tuple((o.id, o.T_cam_map.tobytes(), o.semidense_stereo) for o in [kf, *partners])
            hit = self._parts.get(kf.id)
            if hit is None or hit[0] != key:
                hit = (key, self._part(eng, kf, partners))
                self._parts[kf.id] = hit
            parts.append(hit[1])
        self._cache = _stacked(parts, eng.config.cloud_max_points)
        return self._cache

    @staticmethod
    def _part(eng: EngineView, kf: KeyframeRecord, partners: list[KeyframeRecord]) -> tuple:
        """One keyframe's points: (X, intensities, keyframe ids, depth sigma, raw pixels)."""
        K = eng.K
        sd = kf.semidense
        rho, rho_sig = sd.inv_depth, sd.inv_depth_sigma
        if partners:
            # the same surface seen from other keyframes: their estimates carry independent reference noise
            others = [
                (
                    o.semidense.pixels,
                    o.semidense.inv_depth,
                    o.semidense.inv_depth_sigma,
                    kf.T_cam_map @ invert_pose(o.T_cam_map),
                )
                for o in partners
            ]
            rho, rho_sig, _ = fuse_across_keyframes(K, (sd.pixels, rho, rho_sig), others)
        keep = rho_sig / rho < eng.config.semidense_max_rel_sigma
        rho, rho_sig, pix = rho[keep], rho_sig[keep], sd.pixels[keep]
        depth = 1.0 / rho
        Xc = (
            np.column_stack([(pix[:, 0] - K[0, 2]) / K[0, 0], (pix[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(pix))])
            * depth[:, None]
        )
        X = transform_points(invert_pose(kf.T_cam_map), Xc)
        return X, sd.intensities[keep], np.full(len(X), kf.id, np.int64), rho_sig * depth**2, eng.distort_px(pix)


def _stacked(parts: list[tuple], cap: int) -> MapCloud:
    """The parts in one cloud, thinned to ``cap`` points (0: no cap) by a uniform stride.

    The stride prefers no point (precise ones are not selected: the accuracy is
    not chosen); ``VseConfig.cloud_max_points`` says why there is a cap.
    """
    if not parts:
        return MapCloud()
    n = sum(len(p[0]) for p in parts)
    sel = np.linspace(0, n - 1, cap).astype(int) if 0 < cap < n else slice(None)
    return MapCloud(
        points=np.vstack([p[0] for p in parts])[sel],
        intensities=np.concatenate([p[1] for p in parts]).astype(np.float32)[sel],
        keyframe_ids=np.concatenate([p[2] for p in parts])[sel],
        depth_sigma=np.concatenate([p[3] for p in parts])[sel],
        pixels=np.vstack([p[4] for p in parts])[sel],
    )


class SemiDenseCloud(_FusedKeyframeCloud):
    """Monocular: semi-dense keyframe depths by epipolar search, fused across keyframes."""

    def _reach(self, config: VseConfig) -> int:
        return config.semidense_cross_fusion_keyframes

    def after_keyframe(self, eng: EngineView) -> None:
        super().after_keyframe(eng)
        if eng.config.semidense:
            self._update_depths(eng)

    @staticmethod
    def _update_depths(eng: EngineView) -> None:
        """Depth for recent keyframes that have stereo partners on both sides (each keyframe once), and again
        for those whose stereo geometry bundle adjustment has moved since (``VseConfig.semidense_refresh``)."""
        kfs = eng.kfs
        n = len(kfs)
        for k in range(max(0, n - _SEMIDENSE_LOOKBACK), n - 1):
            if kfs[k].semidense is not None:
                continue
            nbs = depth_partners(eng, k)
            if not any(j > k for j in nbs) or len(nbs) < min(2, eng.config.semidense_min_views):
                continue
            _search_depths(eng, k, nbs)
        if eng.config.semidense_refresh:
            for k in range(max(0, n - eng.config.ba_window), n):
                stereo = kfs[k].semidense_stereo
                if stereo is not None and stereo != _stereo_key(eng, k, stereo[0]):
                    _search_depths(eng, k, [j for j in range(n) if kfs[j].id in stereo[0]])


def _stereo_key(eng: EngineView, k: int, partner_ids: tuple[int, ...]) -> tuple:
    """The stereo geometry keyframe ``k``'s depths are searched with: its partners' ids and every pose involved."""
    poses = {kf.id: kf.T_cam_map.tobytes() for kf in eng.kfs if kf.id in partner_ids}
    return (partner_ids, eng.kfs[k].T_cam_map.tobytes(), tuple(poses.get(i) for i in partner_ids))


def _search_depths(eng: EngineView, k: int, nbs: list[int]) -> None:
    """Search keyframe ``k``'s semi-dense depths with partners ``nbs`` (indices) and note the geometry used.

    Why again after bundle adjustment: a depth searched along the epipolar lines of poses that the
    adjustment has since corrected carries their error as a tilt of the keyframe's cloud against its
    own camera, which the alignment then reads as a pose offset (docs/vse.md, "Design and why", item 4).
    """
    kf = eng.kfs[k]
    sd = semidense_of_keyframe(eng, k, nbs)
    if sd is not None or kf.semidense is None:
        kf.semidense = sd
    kf.semidense_stereo = _stereo_key(eng, k, tuple(eng.kfs[j].id for j in nbs))


def depth_partners(eng: EngineView, k: int) -> list[int]:
    """Indices of keyframes usable as stereo partners of keyframe ``k`` (good baseline), nearest first."""
    cfg = eng.config
    kf = eng.kfs[k]
    c = invert_pose(kf.T_cam_map)[:3, 3]
    depth = median_depth(kf, eng.landmarks)
    cands = []
    for j, other in enumerate(eng.kfs):
        if j == k or abs(j - k) > 2 * cfg.semidense_neighbors:
            continue
        b = np.linalg.norm(invert_pose(other.T_cam_map)[:3, 3] - c) / max(depth, 1e-9)
        rot = math.degrees(rotation_angle_rad(other.T_cam_map[:3, :3] @ kf.T_cam_map[:3, :3].T))
        if 0.5 * cfg.kf_min_baseline_ratio <= b <= _PARTNER_MAX_BASELINE_RATIO and rot < _PARTNER_MAX_ROTATION_DEG:
            cands.append((abs(j - k), -b, j))
    cands.sort()
    return [j for _, _, j in cands[: cfg.semidense_neighbors]]


def semidense_of_keyframe(eng: EngineView, k: int, nbs: list[int]) -> SemiDenseDepth | None:
    """Semi-dense depth of keyframe ``k`` from partners ``nbs``, searched over the inverse depths of its
    landmarks (1st-99th percentile, widened by 30 %); None with fewer than 10 landmarks in front."""
    cfg = eng.config
    kf = eng.kfs[k]
    ids = kf.landmark_ids(eng.landmarks)
    if len(ids) < 10:
        return None
    z = transform_points(kf.T_cam_map, eng.landmarks.points[ids])[:, 2]
    z = z[z > 0]
    if len(z) < 10:
        return None
    rho = 1.0 / z
    lo, hi = float(np.percentile(rho, 1)) * 0.7, float(np.percentile(rho, 99)) * 1.3
    neighbors = [(eng.kfs[j].undist, eng.kfs[j].T_cam_map @ invert_pose(kf.T_cam_map)) for j in nbs]
    return keyframe_depth(
        kf.undist,
        neighbors,
        eng.K,
        (lo, hi),
        config=KeyframeDepthConfig(
            grad_threshold=cfg.semidense_grad_threshold,
            max_points=cfg.semidense_max_points_per_kf,
            cell_px=cfg.semidense_cell_px,
            min_views=cfg.semidense_min_views,
            max_rel_sigma=2.0 * cfg.semidense_max_rel_sigma,
        ),
    )


class DepthImageCloud(_FusedKeyframeCloud):
    """RGB-D: each keyframe's high-gradient pixels with their measured depth (sigma ``depth_sigma_rel * z``)."""

    def after_keyframe(self, eng: EngineView) -> None:
        super().after_keyframe(eng)
        kf = eng.kfs[-1]
        if kf.depth is None:
            return
        cfg = eng.config
        px = select_pixels(
            kf.undist, grad_threshold=cfg.semidense_grad_threshold, max_points=cfg.semidense_max_points_per_kf
        )
        raw = eng.distort_px(px.astype(float))
        d = (
            cv2.remap(
                kf.depth.astype(np.float32),
                raw[:, 0].astype(np.float32).reshape(-1, 1),
                raw[:, 1].astype(np.float32).reshape(-1, 1),
                cv2.INTER_NEAREST,
            )
            .ravel()
            .astype(float)
        )
        ok = np.isfinite(d) & (d > 0)
        px, d = px[ok], d[ok]
        sig = cfg.depth_sigma_rel * d
        kf.semidense = SemiDenseDepth(
            pixels=px.astype(float),
            inv_depth=1.0 / d,
            inv_depth_sigma=sig / d**2,
            n_views=np.ones(len(d), int),
            intensities=kf.undist[px[:, 1], px[:, 0]].astype(np.float32),
        )
