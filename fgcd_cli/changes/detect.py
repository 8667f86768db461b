"""Top-level fine-grained change detection, as a sequence of named steps.

register (:func:`align_stacks`) → dense refine (inside it) → score (:func:`score_stacks`)
→ decide (:func:`decide`) → edge check (:func:`apply_edge_check`) → cues / labels
(:func:`label_cues`) → result. Each step takes the :mod:`fgcd_cli.changes.config`
section it needs; :func:`detect_changes` chains them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from fgcd_cli.changes.config import (
    CueConfig,
    DecisionRule,
    DetectionConfig,
    RegionConfig,
    RegistrationConfig,
    ScoreConfig,
)
from fgcd_cli.changes.cues.labels import CueMaps, label_regions, relief_colour_cues
from fgcd_cli.changes.dense.refine import DenseAlignment, refine_dense, warp_with_flow
from fgcd_cli.changes.edge_check import edge_explained_regions
from fgcd_cli.changes.illumination import normalize_shading
from fgcd_cli.changes.images import check_side_inputs, image_health, to_float_image, to_gray, validate_stacks
from fgcd_cli.changes.regions import (
    ChangeRegion,
    clean_mask,
    refine_to_local_peak,
    regions_with_significance,
    set_brightness_changes,
)
from fgcd_cli.changes.registration import Registration, RegistrationInit, register_to_reference, warp_to_reference
from fgcd_cli.changes.result import (
    CUES_COMPUTED,
    ChangeResult,
    detection_settings,
    empty_result,
    result_warnings,
    unreported_candidates,
)
from fgcd_cli.changes.score import PairScore, ScoreOptions, score_pair
from fgcd_cli.changes.significance import Decision, acontrario_config, acontrario_decision, merge_decisions
from fgcd_cli.changes.threshold import ThresholdInfo, robust_hysteresis_threshold
from fgcd_cli.errors import UserInputError

__all__ = [
    "DetectionConfig",
    "decide",
    "detect_changes",
    "empty_result",
    "regions_with_significance",
    "result_warnings",
]

Progress = Callable[[int, int, str], None]


def detect_changes(
    ref_images: list[np.ndarray],
    cur_images: list[np.ndarray],
    *,
    roi: np.ndarray | None = None,
    pixel_area_mm2: np.ndarray | None = None,
    shading_ref: list[np.ndarray] | None = None,
    shading_cur: list[np.ndarray] | None = None,
    config: DetectionConfig | None = None,
    progress: Progress | None = None,
) -> ChangeResult:
    """Find fine-grained changes between a reference and a current observation.

    Parameters
    ----------
    ref_images, cur_images : list of ndarray, HxW or HxWx3, uint8/uint16/float in [0, 1]
        One image per lighting, the same lightings in the same order in both lists, all of
        one size; the camera may have moved a few pixels between the observations.
    roi : ndarray, HxW bool, optional
        Pixels of the reference to compare (e.g. the object, not the background).
    pixel_area_mm2 : ndarray, HxW float, optional
        Surface area seen by each reference pixel, mm² (:mod:`fgcd_cli.changes.regions`).
    shading_ref, shading_cur : list of ndarray, HxW float, optional
        Per-lighting Lambertian shading maps in the reference frame
        (:func:`fgcd_cli.changes.illumination.shading_from_normals`); when given, the
        current images are re-lit to the reference lighting before the local gain correction.
    config : DetectionConfig, optional
        Every option, by stage (default: the shipped detector); build one from flat option
        names with :meth:`DetectionConfig.from_options` (``from_options(k_high=14, dense=False)``).
    progress : callable ``progress(done, total, label)``, optional, called after each step.

    Returns
    -------
    ChangeResult
        ``comparable`` is False (with a reason) for black, textureless or non-overlapping
        pairs. Raises :class:`UserInputError` for inconsistent input.
    """
    config = DetectionConfig() if config is None else config
    settings = detection_settings(config, lightings=len(ref_images), shading=shading_ref is not None)
    step = _Steps(progress, total=4)
    refs, curs, roi = _check_inputs(
        ref_images,
        cur_images,
        roi=roi,
        pixel_area_mm2=pixel_area_mm2,
        shading=(shading_ref, shading_cur),
        config=config.registration,
    )
    shape = refs[0].shape[:2]
    grays_ref, grays_cur = [to_gray(im) for im in refs], [to_gray(im) for im in curs]
    problem = stack_health(grays_ref, grays_cur)
    if problem:
        return empty_result(shape, problem, None, settings)
    alignment = align_stacks(
        curs, grays_ref, grays_cur, roi=roi, config=config.registration, margin_px=comparison_margin_px(config.score)
    )
    if isinstance(alignment, str):
        return empty_result(shape, alignment, None, settings)
    if alignment.valid.sum() < 100:
        return empty_result(
            shape, "cannot compare: fewer than 100 pixels are seen in both images", alignment.registration, settings
        )
    step("registered")
    if shading_ref is not None:
        alignment.warped = [
            normalize_shading(ref, warped, shading_ref=s_ref, shading_cur=s_cur)
            for ref, warped, s_ref, s_cur in zip(refs, alignment.warped, shading_ref, shading_cur)
        ]
    scored = score_stacks(refs, alignment, score=config.score, regions=config.regions, settings=settings)
    step("scored")
    valid = alignment.valid
    found = decide_regions(
        scored.score,
        valid,
        pixel_area_mm2=pixel_area_mm2,
        config=config,
        settings=settings,
        fine_score=scored.fine_score,
    )
    step("decided")
    explained = apply_edge_check(
        found, refs=refs, scored=scored, valid=valid, pixel_area_mm2=pixel_area_mm2, config=config, settings=settings
    )
    cue_maps = label_cues(
        refs,
        scored.normalized,
        found.regions,
        found.labels,
        valid=valid,
        config=config.cue_labels,
        smooth_sigma_px=config.score.smooth_sigma_px,
        settings=settings,
    )
    set_brightness_changes(found.regions, found.labels, refs, scored.normalized)
    step("labelled")
    return ChangeResult(
        comparable=True,
        score=scored.score,
        fine_score=scored.fine_score,
        mask=found.mask,
        labels=found.labels,
        valid=valid,
        regions=found.regions,
        registration=alignment.registration,
        threshold=found.threshold,
        current_registered=[np.clip(image, 0.0, 1.0) for image in scored.normalized],
        settings=settings,
        warnings=result_warnings(found.mask, valid, alignment.registration, register=config.registration.register),
        edge_explained=explained,
        candidates=unreported_candidates(found.significance, found.mask),
        not_compared=alignment.not_compared,
        dense=alignment.dense,
        cue_maps=cue_maps,
        pair_score=scored,
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
    apply_edge_check(
        found, refs=refs, scored=result.pair_score, valid=result.valid, pixel_area_mm2=None, config=config, settings={}
    )
    return found.mask


class _Steps:
    """``progress(done, total, label)`` after each step (nothing without a callback)."""

    def __init__(self, progress: Progress | None, *, total: int) -> None:
        self.progress, self.total, self.done = progress, total, 0

    def __call__(self, label: str) -> None:
        self.done += 1
        if self.progress is not None:
            self.progress(self.done, self.total, label)


def _check_inputs(ref_images, cur_images, *, roi, pixel_area_mm2, shading, config: RegistrationConfig):
    """Validate and convert the stacks (float32 [0, 1]) and the region of interest (bool); raises UserInputError."""
    refs, curs = validate_stacks(ref_images, cur_images)
    roi = check_side_inputs(
        refs[0].shape[:2],
        len(refs),
        roi=roi,
        pixel_area_mm2=pixel_area_mm2,
        registration_lighting=config.registration_lighting,
    )
    if (shading[0] is None) != (shading[1] is None):
        raise UserInputError("give shading maps for both the reference and the current observation, or neither")
    return refs, curs, roi


def stack_health(grays_ref: list[np.ndarray], grays_cur: list[np.ndarray]) -> str | None:
    """Why the pair cannot be compared (the first black, saturated or textureless image), or None."""
    for label, grays in (("reference", grays_ref), ("current", grays_cur)):
        for i, gray in enumerate(grays):
            problem = image_health(gray)
            if problem:
                return f"cannot compare: {label} image {i + 1}: {problem}"
    return None


def comparison_margin_px(config: ScoreConfig) -> int:
    """Distance kept from the border of the seen area: the cue's shift and the score's smoothing reach."""
    return int(np.ceil(max(config.shift_radius_px, config.smooth_sigma_px * 2)))


@dataclass(kw_only=True)
class Alignment:
    """The current stack in the reference frame (result of :func:`align_stacks`)."""

    registration: Registration
    warped: list[np.ndarray]
    """Current images resampled into the reference frame, float32."""
    valid: np.ndarray
    """HxW bool, compared pixels: evaluation area, seen in every current image, aligned, away from the border."""
    seen_all: np.ndarray
    """HxW bool, pixels seen in every current image."""
    dense: DenseAlignment | None = None
    not_compared: np.ndarray | None = None


def align_stacks(curs, grays_ref, grays_cur, *, roi, config: RegistrationConfig, margin_px: int) -> Alignment | str:
    """Bring the current stack into the reference frame: homography, then (``config.dense``) the parallax flow.

    Returns a reason string when the pair cannot be registered.
    """
    shape, k = grays_ref[0].shape, config.registration_lighting
    if config.register:
        registration = register_to_reference(grays_ref[k], grays_cur[k])
        if not registration.ok:
            return f"cannot compare: {registration.reason}"
    else:
        registration = Registration(H_cur_ref=np.eye(3), ok=True, init=RegistrationInit.NONE, overlap_fraction=1.0)
    area = np.ones(shape, bool) if roi is None else roi.copy()
    dense_fit = not_compared = None
    if config.dense:
        warped_gray, seen = warp_to_reference(grays_cur[k], registration.H_cur_ref, shape)
        dense_fit = refine_dense(grays_ref[k], warped_gray, valid=area & seen)
        not_compared = dense_fit.not_compared & area
    warped_images = []
    seen_all = np.ones(shape, bool)
    for cur in curs:
        if dense_fit is not None:
            warped, seen = warp_with_flow(cur, registration.H_cur_ref, dense_fit.flow)
        else:
            warped, seen = warp_to_reference(cur, registration.H_cur_ref, shape)
        seen_all &= seen
        warped_images.append(warped)
    valid = area & seen_all
    if not_compared is not None:
        valid &= ~not_compared
    # Keep away from the border of the seen area: the gain field and shifts are biased there.
    if margin_px > 0:
        valid = cv2.erode(valid.astype(np.uint8), np.ones((2 * margin_px + 1, 2 * margin_px + 1), np.uint8)).astype(
            bool
        )
    return Alignment(
        registration=registration,
        warped=warped_images,
        valid=valid,
        seen_all=seen_all,
        dense=dense_fit,
        not_compared=not_compared,
    )


def score_stacks(
    refs: list[np.ndarray], alignment: Alignment, *, score: ScoreConfig, regions: RegionConfig, settings: dict
) -> PairScore:
    """The fused score of the aligned stacks (:func:`fgcd_cli.changes.score.score_pair`); records its rounds."""
    scored = score_pair(
        refs,
        alignment.warped,
        valid=alignment.valid,
        seen_all=alignment.seen_all,
        options=ScoreOptions.from_config(score, suspect=regions),
    )
    settings["robust_gain_rounds"] = scored.robust_rounds
    if scored.edge_band_fraction is not None:
        settings["edge_band_fraction"] = scored.edge_band_fraction
    return scored


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
        score,
        valid,
        config=config.regions,
        smooth_sigma_px=config.score.smooth_sigma_px,
        fine_score=fine_score,
        fine_sigma_px=config.score.fine_smooth_sigma_px,
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


def apply_edge_check(
    found: Regions,
    *,
    refs,
    scored: PairScore,
    valid: np.ndarray,
    pixel_area_mm2,
    config: DetectionConfig,
    settings: dict,
) -> np.ndarray | None:
    """The region-level edge check (:mod:`fgcd_cli.changes.edge_check`): the regions it sets aside leave
    ``found`` (mask, regions, labels); returns their pixels, or None when the check did not run."""
    if config.edge_check.edge_check_px <= 0 or not found.regions:
        return None
    acontrario = config.regions.decision == DecisionRule.ACONTRARIO
    check = edge_explained_regions(
        found.labels,
        len(found.regions),
        refs=refs,
        scored=scored,
        valid=valid,
        seed_level=found.significance.seed_level if acontrario else found.threshold.high,
        score=config.score,
        config=config.edge_check,
    )
    settings["edge_explained_regions"] = check.n_explained
    settings["edge_compact_kept_regions"] = check.n_compact_kept
    if check.explained.any():
        found.mask &= ~check.explained
        found.regions, found.labels = regions_with_significance(
            found.mask, scored.score, found.significance, pixel_area_mm2
        )
    return check.explained


def label_cues(
    refs,
    normalized,
    regions: list[ChangeRegion],
    labels: np.ndarray,
    *,
    valid: np.ndarray,
    config: CueConfig,
    smooth_sigma_px: float,
    settings: dict,
) -> CueMaps | None:
    """Relief / colour cue maps of the pair and a label per region (``config.cues``), recorded in ``settings``."""
    if not config.cues:
        return None
    cue_maps = relief_colour_cues(
        refs,
        [np.clip(image, 0.0, 1.0) for image in normalized],
        valid=valid,
        ambient_index=config.ambient_index,
        light_dirs=config.light_dirs,
    )
    label_regions(regions, labels, cue_maps, valid=valid, smooth_sigma_px=smooth_sigma_px)
    settings["cues"] = cue_maps.reason or CUES_COMPUTED
    return cue_maps
