"""The windowed bundle adjustment of the engine's latest keyframes (docs/vse.md, "Design and why", item 3).

The window's two oldest keyframes are held (pose and scale; with only two
keyframes, the first one, and the scale then rests on the damping). Outliers
are judged at the measured noise level of the window for front-ends with
sub-pixel tracks, at a fixed threshold otherwise
(:func:`~fgcd_cli.vse.ba.bundle_adjust_rejecting_outliers`); a rejected
observation leaves its keyframe, and a landmark whose observations are
mostly rejected is dropped with its track.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from fgcd_cli.vse.ba import OutlierRejectionConfig, bundle_adjust_rejecting_outliers
from fgcd_cli.vse.landmarks import KeyframeRecord

if TYPE_CHECKING:
    from fgcd_cli.vse.engine_view import EngineView

__all__ = ["windowed_bundle_adjustment"]

_MIN_OBSERVATIONS = 10  # observations of landmarks seen twice a window needs to be adjusted


def _window_observations(window: list[KeyframeRecord], lm_ok: np.ndarray):
    """Observations of landmarks seen at least twice in the window: ``(obs_cam, obs_id, obs_uv)`` or None."""
    obs_cam, obs_id, obs_uv = [], [], []
    for c, kf in enumerate(window):
        ok = lm_ok[kf.track_ids]
        obs_cam.append(np.full(ok.sum(), c))
        obs_id.append(kf.track_ids[ok])
        obs_uv.append(kf.uv[ok])
    obs_cam = np.concatenate(obs_cam)
    obs_id = np.concatenate(obs_id)
    obs_uv = np.vstack(obs_uv)
    _, inv, counts = np.unique(obs_id, return_inverse=True, return_counts=True)
    multi = counts[inv] >= 2
    if multi.sum() < _MIN_OBSERVATIONS:
        return None
    return obs_cam[multi], obs_id[multi], obs_uv[multi]


def _rejection_config(eng: EngineView) -> OutlierRejectionConfig:
    cfg = eng.config
    noise_level = eng.frontend.noise_level_outliers
    return OutlierRejectionConfig(
        iterations=cfg.ba_iterations,
        huber_px=1.0,
        outlier_sigmas=cfg.outlier_sigmas,
        outlier_min_px=cfg.outlier_min_px if noise_level else 3.0 * cfg.reproj_inlier_px,
        outlier_max_px=3.0 * cfg.reproj_inlier_px,
        max_rounds=4 if noise_level else 1,
    )


def windowed_bundle_adjustment(eng: EngineView) -> None:
    """Adjust the last ``VseConfig.ba_window`` keyframes and their landmarks in place."""
    window = eng.kfs[-eng.config.ba_window :]
    C = len(window)
    if C < 2:
        return
    obs = _window_observations(window, eng.landmarks.ok)
    if obs is None:
        return
    obs_cam, obs_id, obs_uv = obs
    uniq, obs_pt = np.unique(obs_id, return_inverse=True)
    fixed = np.zeros(C, bool)
    fixed[: 2 if C >= 3 else 1] = True
    res, bad = bundle_adjust_rejecting_outliers(
        np.stack([kf.T_cam_map for kf in window]),
        eng.landmarks.points[uniq],
        obs_cam,
        obs_pt,
        obs_uv,
        eng.K,
        fixed_cams=fixed,
        config=_rejection_config(eng),
    )
    for c, kf in enumerate(window):
        kf.T_cam_map = res.T_cam_map[c]
    eng.landmarks.points[uniq] = res.points
    if np.any(bad):
        _drop_outliers(eng, window, obs_cam[bad], obs_id[bad], uniq, obs_pt, bad)


def _drop_outliers(
    eng: EngineView,
    window: list[KeyframeRecord],
    bad_cam: np.ndarray,
    bad_id: np.ndarray,
    uniq: np.ndarray,
    obs_pt: np.ndarray,
    bad: np.ndarray,
) -> None:
    """Remove rejected observations from their keyframes; drop landmarks rejected in half their observations."""
    bad_ids = set(zip(bad_cam.tolist(), bad_id.tolist()))
    for c, kf in enumerate(window):
        ids_c = {i for (cc, i) in bad_ids if cc == c}
        if ids_c:
            keep = ~np.isin(kf.track_ids, list(ids_c))
            kf.track_ids, kf.uv, kf.uv_raw = kf.track_ids[keep], kf.uv[keep], kf.uv_raw[keep]
    bad_count = np.bincount(obs_pt[bad], minlength=len(uniq))
    all_count = np.bincount(obs_pt, minlength=len(uniq))
    drop = uniq[bad_count * 2 >= all_count]
    eng.landmarks.ok[drop] = False
    eng.tracks.keep(~np.isin(eng.tracks.ids, drop))
