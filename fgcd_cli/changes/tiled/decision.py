"""The tiled detector's decision on the full frame, with the a-contrario scan at the decision resolution."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import cv2
import numpy as np

from fgcd_cli.changes.config import DecisionRule, RegionConfig
from fgcd_cli.changes.extent import grow_to_extent
from fgcd_cli.changes.region_decision import region_mask, two_scale_decision
from fgcd_cli.changes.regions import regions_with_significance
from fgcd_cli.changes.significance import acontrario_config, acontrario_decision
from fgcd_cli.changes.threshold import robust_hysteresis_threshold
from fgcd_cli.changes.tiled.schedule import release_free_memory


def decide_tiled(
    scores,
    valid,
    aside: ThreadPoolExecutor,
    cue_job: Callable | None,
    *,
    pixel_area_mm2,
    config: RegionConfig,
    decision_px: int,
    smoothing_px: tuple[float, float],
):
    """Threshold, a-contrario scan at the decision resolution, growth, cleaning and regions (as ``detect_changes``).

    ``scores``: the fused score and its finer smoothing (or None); ``smoothing_px``: their sigmas.

    ``cue_job`` (the cue maps), then the threshold, run on ``aside`` while the scan runs
    here; they start once the scan's full-frame temporaries are freed (the cue maps'
    photometric stereo is the run's largest memory). Returns ``(mask, regions, labels,
    threshold, significance, cue maps future or None)``.
    """
    (score, fine_score), (smooth_sigma_px, fine_sigma_px) = scores, smoothing_px
    beside = {}

    def start_beside() -> None:
        release_free_memory()
        if cue_job is not None:
            beside["cues"] = aside.submit(cue_job)
        beside["threshold"] = aside.submit(
            robust_hysteresis_threshold, score, valid, k_high=config.k_high, k_low=config.k_low
        )

    significance = significance_coarse(
        score,
        valid,
        config=config,
        decision_px=decision_px,
        smooth_sigma_px=smooth_sigma_px,
        on_grid=start_beside,
        fine=(fine_score, fine_sigma_px),
    )
    hysteresis, threshold = beside["threshold"].result()
    acontrario = None
    if config.decision == DecisionRule.ACONTRARIO:
        hysteresis = None  # only the hysteresis rule reads it: one full-frame mask less in memory
        # Seeds found at the decision resolution, grown to their extent on the full-resolution score.
        if significance.settings["scale"] == 1.0 or significance.seed_index is None:
            acontrario = significance.mask
        else:
            acontrario = grow_to_extent(
                significance.seed_index > 0, score, valid, background=threshold.median, fraction=config.extent_fraction
            )
    mask = region_mask(acontrario, hysteresis, score, valid, threshold=threshold, config=config)
    del hysteresis, acontrario
    regions, labels = regions_with_significance(mask, score, significance, pixel_area_mm2)
    return mask, regions, labels, threshold, significance, beside.get("cues")


def significance_coarse(
    score,
    valid,
    *,
    config: RegionConfig,
    decision_px: int,
    smooth_sigma_px: float,
    on_grid: Callable[[], None] | None = None,
    fine: tuple | None = None,
):
    """The a-contrario scan on the score area-averaged to ``decision_px`` (long side), seeds mapped back.

    The scan's cost grows faster than the pixel count (one labelling per level and
    per round), so it runs at the decision resolution.
    Its meaning is kept: the number of tests is ``N / A`` times the levels, and both
    the compared pixels ``N`` and the cluster area ``A`` shrink by the same factor.
    Returns a :class:`Decision` whose ``seed_index`` is at full resolution and whose
    regions' centroids and areas are in full-resolution pixels. ``on_grid`` is called
    once the score is on the decision grid, before the scan. ``fine`` (the score at a finer
    smoothing, and its sigma) is scanned beside it only at full resolution: on a coarser decision
    grid the area averaging is already coarser than both smoothings.
    """
    h, w = score.shape
    scale = max(1.0, max(h, w) / float(decision_px))
    on_grid = on_grid or (lambda: None)
    if scale <= 1.0:
        on_grid()
        fine_score, fine_sigma_px = fine if fine is not None else (None, 0.0)
        result = two_scale_decision(
            score,
            valid,
            config=config,
            smooth_sigma_px=smooth_sigma_px,
            fine_score=fine_score,
            fine_sigma_px=fine_sigma_px,
        )
        result.settings["scale"] = 1.0
        return result
    ws, hs = max(2, int(round(w / scale))), max(2, int(round(h / scale)))
    fx, fy = w / ws, h / hs
    coverage = cv2.resize(valid.astype(np.float32), (ws, hs), interpolation=cv2.INTER_AREA)
    small = cv2.resize(np.where(valid, score, 0.0).astype(np.float32), (ws, hs), interpolation=cv2.INTER_AREA)
    small_valid = coverage > 0.5
    small = np.where(small_valid, small / np.maximum(coverage, 1e-6), 0.0).astype(np.float32)
    on_grid()
    # Correlation area of the smoothing at this scale, at least one pixel.
    sigma = smooth_sigma_px / max(fx, fy)
    result = acontrario_decision(
        small, small_valid, config=acontrario_config(config), min_cluster_area_px=max(1.0, 4.0 * np.pi * sigma**2)
    )
    seed_index = np.zeros((h, w), np.int32)
    if result.seed_index is not None:
        seed_index = cv2.resize(result.seed_index.astype(np.int32), (w, h), interpolation=cv2.INTER_NEAREST)

    def up(region):
        cx, cy = region.centroid_xy
        return replace(
            region,
            centroid_xy=(fx * (cx + 0.5) - 0.5, fy * (cy + 0.5) - 0.5),
            area_px=int(round(region.area_px * fx * fy)),
        )

    return replace(
        result,
        seed_index=seed_index,
        regions=[up(r) for r in result.regions],
        candidates=[up(r) for r in result.candidates],
        cluster_area_px=result.cluster_area_px * fx * fy,
        settings=dict(result.settings, scale=float(max(fx, fy)), resolution=f"{ws}x{hs} (score area-averaged)"),
    )
