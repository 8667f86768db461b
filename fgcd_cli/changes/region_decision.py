"""The decision on a fused score: significant regions (a-contrario or hysteresis), their cleaning and the
region-level edge check; and the same decision made again with other constants on a finished detection.

Steps 5 to 10 of ``docs/change-detection.md``, "Change detection pipeline"; :func:`fgcd_cli.changes.detect.detect_changes`
chains them after the score.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from fgcd_cli.changes.clip_check import clip_explained_regions
from fgcd_cli.changes.config import DecisionRule, DetectionConfig, RegionConfig
from fgcd_cli.changes.contrast import region_contrasts, set_contrasts
from fgcd_cli.changes.edge_check import edge_explained_regions
from fgcd_cli.changes.images import to_float_image
from fgcd_cli.changes.regions import ChangeRegion, clean_mask, refine_to_local_peak, regions_with_significance
from fgcd_cli.changes.rescan import seeds_under_nulls
from fgcd_cli.changes.result import WHY_NOT_REPORTED, ChangeResult
from fgcd_cli.changes.score import PairScore
from fgcd_cli.changes.significance import (
    Decision,
    SignificantRegion,
    acontrario_config,
    acontrario_decision,
    merge_decisions,
)
from fgcd_cli.changes.threshold import ThresholdInfo, robust_hysteresis_threshold

__all__ = [
    "Regions",
    "edge_checked_pixels",
    "faint_regions",
    "clipped_regions",
    "SetAside",
    "set_aside_regions",
    "decide",
    "decide_again",
    "decide_regions",
    "region_mask",
    "two_scale_decision",
]


@dataclass(kw_only=True)
class Regions:
    """The decision on a score map (result of :func:`decide_regions`)."""

    mask: np.ndarray
    """HxW bool, the cleaned change mask."""
    regions: list[ChangeRegion]
    labels: np.ndarray
    """HxW int32, region id per pixel."""
    threshold: ThresholdInfo
    significance: Decision

    def seed_level(self, rule: DecisionRule) -> float:
        """The score level at which ``rule`` seeds regions: the a-contrario ``seed_p`` quantile, or the
        hysteresis seed (what the region-level checks compare their recomputed scores with)."""
        return self.significance.seed_level if rule == DecisionRule.ACONTRARIO else self.threshold.high

    def set_aside(self, pixels: np.ndarray, score: np.ndarray, pixel_area_mm2) -> None:
        """``pixels`` (HxW bool) leave the mask; the regions are labelled again from what is left."""
        self.mask &= ~pixels
        self.regions, self.labels = regions_with_significance(self.mask, score, self.significance, pixel_area_mm2)


def decide_regions(
    score: np.ndarray,
    valid: np.ndarray,
    *,
    pixel_area_mm2,
    config: DetectionConfig,
    settings: dict,
    fine_score: np.ndarray | None = None,
) -> Regions:
    """:func:`decide` on the score (and its finer smoothing), and the regions of its mask with their
    significance and area."""
    mask, threshold, significance = decide(
        score, valid, config=config.regions, fine_score=fine_score, **_scales(config)
    )
    settings["seed_level"] = significance.seed_level
    regions, labels = regions_with_significance(mask, score, significance, pixel_area_mm2)
    return Regions(mask=mask, regions=regions, labels=labels, threshold=threshold, significance=significance)


def decide(
    score: np.ndarray,
    valid: np.ndarray,
    *,
    config: RegionConfig | None = None,
    smooth_sigma_px: float = 2.0,
    fine_score: np.ndarray | None = None,
    fine_sigma_px: float = 0.0,
) -> tuple[np.ndarray, ThresholdInfo, Decision]:
    """The changed pixels of a fused score map.

    Both rules are evaluated: the hysteresis threshold is kept as a reference (and
    is what the a-contrario scan is compared with in the report), the a-contrario
    decision gives every region its significance.

    Parameters
    ----------
    score, valid : ndarray, HxW float32 / bool, the fused score and the compared pixels.
    config : RegionConfig, optional (default: the shipped one)
    smooth_sigma_px : float, the score's smoothing (its correlation area bounds the a-contrario cluster area).
    fine_score : ndarray, HxW float32, optional
        The same score at the finer smoothing ``fine_sigma_px``: both maps are scanned, the number of
        tests counted over both, and the significant regions of either are kept.

    Returns
    -------
    mask : ndarray, HxW bool, the cleaned change mask (inside ``valid``)
    threshold : ThresholdInfo, the hysteresis threshold's statistics
    significance : Decision, the a-contrario scan
    """
    config = config or RegionConfig()
    raw_mask, threshold = robust_hysteresis_threshold(score, valid, k_high=config.k_high, k_low=config.k_low)
    significance = two_scale_decision(
        score, valid, config=config, smooth_sigma_px=smooth_sigma_px, fine_score=fine_score, fine_sigma_px=fine_sigma_px
    )
    acontrario = significance.mask if config.decision == DecisionRule.ACONTRARIO else None
    return region_mask(acontrario, raw_mask, score, valid, threshold=threshold, config=config), threshold, significance


def two_scale_decision(
    score: np.ndarray,
    valid: np.ndarray,
    *,
    config: RegionConfig,
    smooth_sigma_px: float,
    fine_score: np.ndarray | None,
    fine_sigma_px: float,
) -> Decision:
    """The a-contrario decision on the score, and on its finer smoothing when given (one family of tests)."""
    maps = [(score, smooth_sigma_px)] + ([(fine_score, fine_sigma_px)] if fine_score is not None else [])
    test = dataclasses.replace(acontrario_config(config), score_maps=len(maps))
    return merge_decisions(
        [acontrario_decision(s, valid, config=test, min_cluster_area_px=4.0 * np.pi * sigma**2) for s, sigma in maps],
        max_candidates=test.max_candidates,
    )


def region_mask(
    acontrario_mask: np.ndarray | None,
    hysteresis_mask: np.ndarray | None,
    score: np.ndarray,
    valid: np.ndarray,
    *,
    threshold: ThresholdInfo,
    config: RegionConfig,
) -> np.ndarray:
    """The decision rule's mask, cleaned, inside ``valid``.

    A-contrario: the significant regions grown to their extent (``acontrario_mask``).
    Hysteresis: the thresholded pixels trimmed to their local peak
    (:func:`fgcd_cli.changes.regions.refine_to_local_peak`). Then regions up to
    ``min_region_px`` are dropped and holes up to ``max_hole_px`` filled.
    """
    if config.decision == DecisionRule.ACONTRARIO:
        raw_mask = acontrario_mask
    else:
        raw_mask = refine_to_local_peak(
            hysteresis_mask,
            score,
            background=threshold.median,
            fraction=config.edge_fraction,
            radius_px=config.edge_radius_px,
        )
    return clean_mask(raw_mask, min_region_px=config.min_region_px, max_hole_px=config.max_hole_px) & valid


def edge_checked_pixels(
    found: Regions, *, refs, scored: PairScore, valid: np.ndarray, config: DetectionConfig, settings: dict
) -> np.ndarray | None:
    """The pixels of the regions the edge check (:mod:`fgcd_cli.changes.edge_check`) sets aside, or None
    when the check did not run; counted in ``settings``."""
    if config.edge_check.edge_check_px <= 0 or not found.regions:
        return None
    check = edge_explained_regions(
        found.labels,
        len(found.regions),
        refs=refs,
        scored=scored,
        valid=valid,
        seed_level=found.seed_level(config.regions.decision),
        score=config.score,
        config=config.edge_check,
    )
    settings["edge_explained_regions"] = check.n_explained
    settings["edge_compact_kept_regions"] = check.n_compact_kept
    return check.explained


def faint_regions(
    found: Regions, *, refs, scored: PairScore, config: DetectionConfig, settings: dict
) -> list[ChangeRegion] | None:
    """The regions below ``config.regions.min_contrast`` (:mod:`fgcd_cli.changes.contrast`), or None when
    the floor is off; counted in ``settings["low_contrast_regions"]``."""
    floor = config.regions.min_contrast
    if floor <= 0 or not found.regions:
        return None
    contrast = region_contrasts(found.labels, len(found.regions), refs=refs, normalized=scored.normalized)
    faint = [region for region, value in zip(found.regions, contrast) if value < floor]
    settings["low_contrast_regions"] = len(faint)
    settings["min_contrast"] = floor
    return faint


def _scales(config: DetectionConfig) -> dict:
    """The detection's two smoothings (px), as :func:`decide` and :func:`two_scale_decision` take them."""
    return {"smooth_sigma_px": config.score.smooth_sigma_px, "fine_sigma_px": config.score.fine_smooth_sigma_px}


def _seeds(
    found: Regions,
    score: np.ndarray,
    fine_score: np.ndarray | None,
    valid: np.ndarray,
    within: np.ndarray,
    config: DetectionConfig,
) -> np.ndarray:
    """The seed pixels of the significant regions the detection's decision rule finds on ``score`` (and on
    ``fine_score``, the same at the finer smoothing, as :func:`decide_regions` does) where they reach
    ``within``: a-contrario, under the nulls ``found`` was decided under (:mod:`fgcd_cli.changes.rescan`)."""
    if config.regions.decision == DecisionRule.ACONTRARIO:
        maps = [score] + ([fine_score] if fine_score is not None else [])
        if len(found.significance.nulls) == len(maps):
            return seeds_under_nulls(maps, valid, found.significance.nulls, within)
        decision = two_scale_decision(score, valid, config=config.regions, fine_score=fine_score, **_scales(config))
        return decision.seed_index > 0 if decision.seed_index is not None else decision.mask
    mask, threshold = robust_hysteresis_threshold(
        score, valid, k_high=config.regions.k_high, k_low=config.regions.k_low
    )
    return mask & (score >= threshold.high)


def clipped_regions(
    found: Regions,
    *,
    refs,
    scored: PairScore,
    valid: np.ndarray,
    config: DetectionConfig,
    settings: dict,
    faint: list[ChangeRegion],
) -> list[ChangeRegion] | None:
    """The regions, other than the ``faint`` ones, whose evidence comes from clipped pixels only
    (:mod:`fgcd_cli.changes.clip_check`), or None when the check is off; counted in
    ``settings["clipped_regions"]``."""
    if not config.regions.clip_check or not found.regions:
        return None
    check = clip_explained_regions(
        found.labels,
        len(found.regions),
        refs=refs,
        scored=scored,
        valid=valid,
        significant=lambda measured, fine, within: _seeds(found, measured, fine, valid, within, config),
        score=config.score,
    )
    faint_ids = {region.id for region in faint}
    clipped = [region for region in found.regions if region.id in check.region_ids and region.id not in faint_ids]
    settings["clipped_regions"] = len(clipped)
    return clipped


@dataclass(frozen=True)
class SetAside:
    """What :func:`set_aside_regions` took out of the change mask (HxW bool each; None: the step did not run)."""

    edge: np.ndarray | None
    """The regions the edge check explains."""
    unreported: np.ndarray | None
    """The regions below the contrast floor and those explained by clipped pixels."""
    listed: tuple[SignificantRegion, ...] = ()
    """The same regions as candidates (strongest first), so that the report lists them first."""


def set_aside_regions(
    found: Regions,
    *,
    refs,
    scored: PairScore,
    valid: np.ndarray,
    pixel_area_mm2,
    config: DetectionConfig,
    settings: dict,
) -> SetAside:
    """Steps 8 to 10 of ``docs/change-detection.md``: the regions the edge check explains, then those
    below the contrast floor and those explained by clipped pixels, leave ``found`` (mask, regions,
    labels; they stay among the unreported candidates, listed first); each region left gets its
    contrast and the lightings that show it (:func:`fgcd_cli.changes.contrast.set_contrasts`)."""
    explained = edge_checked_pixels(found, refs=refs, scored=scored, valid=valid, config=config, settings=settings)
    if explained is not None and explained.any():
        found.set_aside(explained, scored.score, pixel_area_mm2)
    faint = faint_regions(found, refs=refs, scored=scored, config=config, settings=settings)
    clipped = clipped_regions(
        found, refs=refs, scored=scored, valid=valid, config=config, settings=settings, faint=faint or []
    )
    if faint is None and clipped is None:
        set_contrasts(found.regions, found.labels, refs, scored.normalized)
        return SetAside(edge=explained, unreported=None)
    unreported = {region.id: region for region in (faint or []) + (clipped or [])}
    unreported_mask = np.isin(found.labels, list(unreported))
    faint_ids = {region.id for region in faint or []}
    listed = as_candidates(
        list(unreported.values()),
        scored.score,
        valid,
        why={i: WHY_NOT_REPORTED["faint" if i in faint_ids else "clipped"] for i in unreported},
    )
    if unreported:
        found.set_aside(unreported_mask, scored.score, pixel_area_mm2)
    set_contrasts(found.regions, found.labels, refs, scored.normalized)
    return SetAside(edge=explained, unreported=unreported_mask, listed=listed)


def as_candidates(
    regions: list[ChangeRegion], score: np.ndarray, valid: np.ndarray, *, why: dict[int, str] | None = None
) -> tuple[SignificantRegion, ...]:
    """Regions not reported, as the report's candidates (strongest first): their significance, the share
    of compared pixels scoring at least their peak (its level p), area, centre, peak score and, from
    ``why`` (region id -> reason), why each was not reported."""
    compared = score[valid]
    return tuple(
        SignificantRegion(
            log10_nfa=float(r.log10_nfa) if r.log10_nfa is not None else 0.0,
            p_level=float((compared >= r.max_score).mean()) if compared.size else 1.0,
            area_px=r.area_px,
            centroid_xy=r.centroid_xy,
            peak_score=r.max_score,
            why=(why or {}).get(r.id, ""),
        )
        for r in sorted(regions, key=lambda r: -r.max_score)
    )


def decide_again(result: ChangeResult, ref_images: list[np.ndarray], config: DetectionConfig) -> np.ndarray:
    """The change mask :func:`detect_changes` gives on ``result``'s score with ``config``'s decision and edge check.

    For a benchmark's grid of decision constants: the same score, decided and edge-checked as the
    detector does (registration and scoring are not redone, so ``config``'s other sections are unused).

    Parameters
    ----------
    result : ChangeResult, a comparable detection that kept its ``pair_score``.
    ref_images : list of (H, W[, 3]) ndarray, the reference stack it was detected on.
    config : DetectionConfig

    Returns
    -------
    (H, W) bool ndarray, the changed pixels.
    """
    if result.pair_score is None:
        raise ValueError("the detection did not keep its pair score")
    fine_score = result.fine_score if config.score.fine_smooth_sigma_px > 0 else None
    if fine_score is None and config.score.fine_smooth_sigma_px > 0:
        raise ValueError("the decision scans a finer smoothing that the detection did not compute")
    found = decide_regions(
        result.score, result.valid, pixel_area_mm2=None, config=config, settings={}, fine_score=fine_score
    )
    refs = [to_float_image(im, name=f"reference image {i + 1}") for i, im in enumerate(ref_images)]
    set_aside_regions(
        found, refs=refs, scored=result.pair_score, valid=result.valid, pixel_area_mm2=None, config=config, settings={}
    )
    return found.mask
