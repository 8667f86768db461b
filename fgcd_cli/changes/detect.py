"""Top-level fine-grained change detection: register, normalize light, fuse cues, threshold, regions."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy import ndimage

from fgcd_cli.changes.cue_labels import CueMaps, label_regions, relief_colour_cues
from fgcd_cli.changes.edge_check import edge_explained_regions
from fgcd_cli.changes.dense import DenseAlignment, refine_dense, warp_with_flow
from fgcd_cli.changes.illumination import normalize_shading
from fgcd_cli.changes.images import image_health, to_gray, validate_stacks
from fgcd_cli.changes.regions import ChangeRegion, clean_mask, refine_to_local_peak
from fgcd_cli.changes.registration import Registration, register_to_reference, warp_to_reference
from fgcd_cli.changes.score import ScoreOptions, score_pair
from fgcd_cli.changes.significance import Decision, SignificantRegion, acontrario_decision
from fgcd_cli.changes.threshold import ThresholdInfo, robust_hysteresis_threshold
from fgcd_cli.errors import UserInputError


@dataclass(kw_only=True)
class ChangeResult:
    """Everything :func:`detect_changes` found, in the reference image's frame."""

    comparable: bool
    """False when the pair cannot be compared honestly (see ``reason``); then the maps are empty."""
    reason: str = ""
    score: np.ndarray
    """HxW float32 fused change score (dimensionless, background median ~1; 0 outside ``valid``)."""
    mask: np.ndarray
    """HxW bool, changed pixels after threshold and cleaning."""
    labels: np.ndarray
    """HxW int32, region id per pixel (0 = unchanged)."""
    valid: np.ndarray
    """HxW bool, pixels that were compared (evaluation mask ∩ seen in the current image)."""
    regions: list[ChangeRegion]
    registration: Registration | None
    threshold: ThresholdInfo | None
    current_registered: list[np.ndarray] = field(default_factory=list)
    """Current images resampled into the reference frame, light-normalized (float32)."""
    settings: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    edge_explained: np.ndarray | None = None
    """HxW bool, pixels of the regions the region-level edge check set aside (``edge_check_px``), or None."""
    candidates: list[SignificantRegion] = field(default_factory=list)
    """The strongest a-contrario regions that were not reported (for "no significant change; strongest candidate ...")."""
    not_compared: np.ndarray | None = None
    """HxW bool, pixels of the evaluation area the dense refinement could not align (left out, not changed)."""
    dense: DenseAlignment | None = None
    """The dense parallax refinement after the homography, when it ran."""
    cue_maps: CueMaps | None = None
    """Relief and colour cue maps (photometric stereo), when they were computed."""

    @property
    def detection_level(self) -> float | None:
        """Score at which the decision starts a region: the a-contrario seed level (the ``seed_p``
        quantile of the pair's null), or the hysteresis rule's high threshold; None without a decision."""
        if self.settings.get("decision") == "acontrario" and self.settings.get("seed_level") is not None:
            return float(self.settings["seed_level"])
        return self.threshold.high if self.threshold is not None else None

    @property
    def changed_fraction(self) -> float:
        """Fraction of compared pixels flagged as changed."""
        return float(self.mask[self.valid].mean()) if self.valid.any() else 0.0


def empty_result(shape: tuple[int, int], reason: str, registration: Registration | None, settings: dict) -> ChangeResult:
    """The result of a pair that cannot be compared honestly (``comparable=False``, empty HxW maps)."""
    return ChangeResult(
        comparable=False,
        reason=reason,
        score=np.zeros(shape, np.float32),
        mask=np.zeros(shape, bool),
        labels=np.zeros(shape, np.int32),
        valid=np.zeros(shape, bool),
        regions=[],
        registration=registration,
        threshold=None,
        settings=settings,
    )


def regions_with_significance(mask, score, significance: Decision, pixel_area_mm2):
    """Regions of the final mask (as :func:`fgcd_cli.changes.regions.extract_regions`: numbered by
    decreasing area), each with the log10 NFA of the most significant a-contrario seed it holds.

    The per-region sums run over the list of mask pixels rather than whole-frame arrays
    (a change mask covers a few percent of a large frame).
    """
    raw_labels, count = ndimage.label(mask, structure=np.ones((3, 3), dtype=bool))
    if count == 0:
        return [], np.zeros(mask.shape, np.int32)
    pixels = np.flatnonzero(raw_labels)
    raw = raw_labels.ravel()[pixels]
    areas = np.bincount(raw, minlength=count + 1)[1:].astype(np.float64)
    order = np.argsort(-areas, kind="stable")
    relabel = np.zeros(count + 1, np.int32)
    relabel[order + 1] = np.arange(1, count + 1)
    labels = relabel[raw_labels]
    del raw_labels
    ids = relabel[raw]
    counts = np.bincount(ids, minlength=count + 1)[1:]
    ys, xs = np.divmod(pixels, mask.shape[1])
    values = score.ravel()[pixels]
    means = np.bincount(ids, weights=values, minlength=count + 1)[1:] / counts.astype(np.float64)
    cy = np.bincount(ids, weights=ys.astype(np.float64), minlength=count + 1)[1:] / counts
    cx = np.bincount(ids, weights=xs.astype(np.float64), minlength=count + 1)[1:] / counts
    by_id = np.argsort(ids, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    maxima = np.maximum.reduceat(values[by_id], starts)
    y_lo, y_hi = np.minimum.reduceat(ys[by_id], starts), np.maximum.reduceat(ys[by_id], starts)
    x_lo, x_hi = np.minimum.reduceat(xs[by_id], starts), np.maximum.reduceat(xs[by_id], starts)
    area_mm2 = [None] * count
    if pixel_area_mm2 is not None:
        area_map = np.asarray(pixel_area_mm2).ravel()[pixels]
        known = np.bincount(ids, weights=np.isfinite(area_map).astype(np.float64), minlength=count + 1)[1:]
        metric = np.bincount(ids, weights=np.nan_to_num(area_map.astype(np.float64), nan=0.0), minlength=count + 1)[1:]
        # Extrapolate over pixels without 3D data at the region's mean pixel area.
        area_mm2 = [float(metric[i] * counts[i] / known[i]) if known[i] > 0 else None for i in range(count)]
    nfa = [None] * count
    if significance.seed_index is not None:
        seeds = significance.seed_index.ravel()[pixels]
        for region_id, seed in set(zip(ids[seeds > 0].tolist(), seeds[seeds > 0].tolist())):
            value = significance.regions[seed - 1].log10_nfa
            nfa[region_id - 1] = value if nfa[region_id - 1] is None else min(nfa[region_id - 1], value)
    regions = [
        ChangeRegion(id=i + 1, area_px=int(counts[i]), area_mm2=area_mm2[i],
                     bbox_xywh=(int(x_lo[i]), int(y_lo[i]), int(x_hi[i] - x_lo[i] + 1), int(y_hi[i] - y_lo[i] + 1)),
                     centroid_xy=(float(cx[i]), float(cy[i])), mean_score=float(means[i]), max_score=float(maxima[i]),
                     log10_nfa=None if nfa[i] is None else float(nfa[i]))
        for i in range(count)
    ]
    return regions, labels


def detect_changes(
    ref_images: list[np.ndarray],
    cur_images: list[np.ndarray],
    *,
    eval_mask: np.ndarray | None = None,
    pixel_area_mm2: np.ndarray | None = None,
    shading_ref: list[np.ndarray] | None = None,
    shading_cur: list[np.ndarray] | None = None,
    register: bool = True,
    gain_sigma_px: float = 12.0,
    shift_radius_px: int = 1,
    structure_weight: float = 0.0,
    smooth_sigma_px: float = 2.0,
    k_high: float = 20.0,
    k_low: float = 10.0,
    min_region_px: int = 30,
    max_hole_px: int = 30,
    registration_lighting: int = 0,
    robust_gain_rounds: int = 1,
    edge_fraction: float = 0.2,
    edge_radius_px: int = 6,
    edge_tolerance_px: int = 0,
    edge_contrast: float = 3.0,
    edge_check_px: int = 0,
    edge_check_band_fraction: float = 0.8,
    decision: str = "acontrario",
    epsilon: float = 1.0,
    seed_p: float = 0.005,
    extent_fraction: float = 0.3,
    dense: bool = True,
    cues: bool = True,
    ambient_index: int | None = 0,
    light_dirs: np.ndarray | None = None,
) -> ChangeResult:
    """Find fine-grained changes between a reference and a current observation.

    Parameters
    ----------
    ref_images, cur_images : list of ndarray, HxW or HxWx3, uint8/uint16/float in [0, 1]
        One image per lighting, the same lightings in the same order in both lists.
        All images must have the same size. The camera may have moved slightly
        between the observations (a few pixels after relocation).
    eval_mask : ndarray, HxW bool, optional
        Pixels of the reference to compare (e.g. the object, not the background).
    pixel_area_mm2 : ndarray, HxW float, optional
        Surface area seen by each reference pixel, mm² (see
        :func:`fgcd_cli.changes.regions.pixel_area_from_points` /
        :func:`~fgcd_cli.changes.regions.pixel_area_from_depth`); gives region areas in mm².
    shading_ref, shading_cur : list of ndarray, HxW float, optional
        Per-lighting Lambertian shading maps in the reference frame (from the
        observation's normals and the capture's light directions, see
        :func:`fgcd_cli.changes.illumination.shading_from_normals`). When given,
        the current images are re-lit to the reference lighting before the local
        gain correction.
    register : bool
        Register the current images on the reference (homography, ECC on gradients).
    gain_sigma_px : float
        Scale of the smooth light-gain field removed per lighting, pixels.
    shift_radius_px : int
        Residual misregistration absorbed by the difference cue, pixels.
    structure_weight : float
        Weight in [0, 1] of the gain-invariant local-NCC cue against the colour difference cue.
    smooth_sigma_px : float
        Gaussian smoothing of the fused score, pixels.
    k_high, k_low : float
        Automatic threshold (see :func:`fgcd_cli.changes.threshold.robust_hysteresis_threshold`).
    min_region_px, max_hole_px : int
        Regions up to this size are dropped / holes up to this size filled.
    registration_lighting : int
        Index of the lighting used to estimate the registration (the most diffuse one is best).
    edge_fraction, edge_radius_px : float, int
        Region trimming: pixels whose score excess is below ``edge_fraction`` of
        the largest excess within ``edge_radius_px`` are dropped (see
        :func:`fgcd_cli.changes.regions.refine_to_local_peak`; 0 disables).
    edge_tolerance_px, edge_contrast : int, float
        Near strong reference edges (3x3 intensity range above ``edge_contrast``
        times its image median, grown by ``edge_tolerance_px``) a difference counts
        only if neither image lies within the other's min/max envelope over
        ``edge_tolerance_px``: a relocation residual of a few mm thins, blurs or
        moves thin structures there by up to ~1-2 px (see
        :func:`fgcd_cli.changes.cues.edge_tolerant_difference`). 0 (default)
        disables it: it also hides small changes on strong texture edges, so it is
        for pairs known to be relocated only to a few mm (campaign diffs use the
        region-level ``edge_check_px`` below instead).
    edge_check_px, edge_check_band_fraction : int, float
        Region-level edge check (0 disables), :mod:`fgcd_cli.changes.edge_check`:
        a region mostly in the reference's strong-edge band, explained by a shift
        of up to ``edge_check_px`` and shaped like a band along the edge is set
        aside (its pixels leave the mask; it stays a candidate). Unlike
        ``edge_tolerance_px`` it leaves the pixels of every other region
        untouched. Counts: ``settings["edge_explained_regions"]`` (set aside) and
        ``settings["edge_compact_kept_regions"]`` (compact, kept).
    robust_gain_rounds : int
        Re-estimations of the light-gain field without the pixels the previous
        score flags as suspect (0: one plain estimate, the change biases it).
    decision : {"hysteresis", "acontrario"}
        Which rule decides the regions. Either way every region carries its
        a-contrario significance (``ChangeRegion.log10_nfa``, see
        :func:`fgcd_cli.changes.significance.acontrario_decision`) and the strongest
        regions not reported are kept in ``candidates``.
    epsilon, seed_p, extent_fraction : float
        The a-contrario test: tolerated false regions per image under the pair's own
        null, lowest level tested (empirical tail probability), extent of a region
        (fraction of its peak excess).
    dense : bool
        After the homography, estimate the residual parallax as a smooth dense flow
        (:func:`fgcd_cli.changes.dense.refine_dense`) and resample the current images
        through both at once; pixels it cannot align are *not compared*
        (``ChangeResult.not_compared``) instead of changed.
    cues : bool
        Fit photometric stereo to both stacks and label each region ``relief``,
        ``colour`` or ``both`` (:mod:`fgcd_cli.changes.cue_labels`); needs three
        directional lightings besides the ambient one.
    ambient_index : int or None
        Index of the ambient lighting in the stacks (None: all are directional).
    light_dirs : ndarray, Kx3, optional
        Known light directions in the camera frame (calibrated photometric stereo).

    Returns
    -------
    ChangeResult
        ``comparable`` is False (with a reason) for black, textureless or
        non-overlapping pairs. Raises :class:`UserInputError` for inconsistent input.
    """
    settings = {
        "lightings": len(ref_images),
        "gain_sigma_px": gain_sigma_px,
        "shift_radius_px": shift_radius_px,
        "structure_weight": structure_weight,
        "smooth_sigma_px": smooth_sigma_px,
        "k_high": k_high,
        "k_low": k_low,
        "min_region_px": min_region_px,
        "max_hole_px": max_hole_px,
        "registration_lighting": registration_lighting,
        "robust_gain_rounds_max": robust_gain_rounds,
        "edge_fraction": edge_fraction,
        "edge_radius_px": edge_radius_px,
        "edge_tolerance_px": edge_tolerance_px,
        "edge_contrast": edge_contrast,
        "edge_check_px": edge_check_px,
        "shading_normalization": shading_ref is not None,
        "decision": decision,
        "epsilon": epsilon,
        "seed_p": seed_p,
        "extent_fraction": extent_fraction,
        "dense": dense,
    }
    if decision not in ("hysteresis", "acontrario"):
        raise UserInputError(f"unknown decision rule {decision!r}: use hysteresis or acontrario")
    refs, curs = validate_stacks(ref_images, cur_images)
    shape = refs[0].shape[:2]
    if eval_mask is not None:
        eval_mask = np.asarray(eval_mask).astype(bool)
        if eval_mask.shape != shape:
            raise UserInputError(f"evaluation mask is {eval_mask.shape[1]}x{eval_mask.shape[0]} px, images are {shape[1]}x{shape[0]} px")
    if pixel_area_mm2 is not None and np.asarray(pixel_area_mm2).shape != shape:
        raise UserInputError("pixel area map must have the reference image's size")
    if not 0 <= registration_lighting < len(refs):
        raise UserInputError(f"registration lighting {registration_lighting} out of range 0..{len(refs) - 1}")
    if (shading_ref is None) != (shading_cur is None):
        raise UserInputError("give shading maps for both the reference and the current observation, or neither")

    grays_ref = [to_gray(im) for im in refs]
    grays_cur = [to_gray(im) for im in curs]
    for label, grays in (("reference", grays_ref), ("current", grays_cur)):
        for i, gray in enumerate(grays):
            problem = image_health(gray)
            if problem:
                return empty_result(shape, f"cannot compare: {label} image {i + 1}: {problem}", None, settings)

    alignment = _align(refs, curs, grays_ref, grays_cur, eval_mask=eval_mask, register=register, dense=dense,
                       registration_lighting=registration_lighting, margin_px=int(np.ceil(max(shift_radius_px,
                                                                                             smooth_sigma_px * 2))))
    if isinstance(alignment, str):
        return empty_result(shape, alignment, None, settings)
    registration, warped_images, valid, seen_all, dense_fit, not_compared = alignment
    if valid.sum() < 100:
        return empty_result(shape, "cannot compare: fewer than 100 pixels are seen in both images", registration, settings)
    if shading_ref is not None:
        warped_images = [normalize_shading(ref, warped, shading_ref=s_ref, shading_cur=s_cur)
                         for ref, warped, s_ref, s_cur in zip(refs, warped_images, shading_ref, shading_cur)]

    options = ScoreOptions(gain_sigma_px=gain_sigma_px, shift_radius_px=shift_radius_px,
                           structure_weight=structure_weight, smooth_sigma_px=smooth_sigma_px,
                           robust_gain_rounds=robust_gain_rounds, edge_tolerance_px=edge_tolerance_px,
                           edge_contrast=edge_contrast, suspect_k_high=k_high, suspect_k_low=k_low)
    scored = score_pair(refs, warped_images, valid=valid, seen_all=seen_all, options=options)
    score, normalized_images, medians = scored.score, scored.normalized, scored.medians
    settings["robust_gain_rounds"] = scored.robust_rounds
    if scored.edge_band_fraction is not None:
        settings["edge_band_fraction"] = scored.edge_band_fraction

    mask, threshold, significance = decide(score, valid, decision=decision, k_high=k_high, k_low=k_low,
                                           epsilon=epsilon, seed_p=seed_p, extent_fraction=extent_fraction,
                                           edge_fraction=edge_fraction, edge_radius_px=edge_radius_px,
                                           min_region_px=min_region_px, max_hole_px=max_hole_px,
                                           smooth_sigma_px=smooth_sigma_px)
    settings["seed_level"] = significance.seed_level
    regions, labels = regions_with_significance(mask, score, significance, pixel_area_mm2)
    explained = None
    if edge_check_px > 0 and regions:
        check = edge_explained_regions(
            labels, len(regions), refs=refs, normalized_images=normalized_images, medians=medians, valid=valid,
            seed_level=significance.seed_level if decision == "acontrario" else threshold.high,
            shift_radius_px=shift_radius_px, smooth_sigma_px=smooth_sigma_px, edge_check_px=edge_check_px,
            edge_contrast=edge_contrast, band_fraction=edge_check_band_fraction,
        )
        explained = check.explained
        settings["edge_explained_regions"] = check.n_explained
        settings["edge_compact_kept_regions"] = check.n_compact_kept
        if explained.any():
            mask &= ~explained
            regions, labels = regions_with_significance(mask, score, significance, pixel_area_mm2)
    cue_maps = None
    if cues:
        cue_maps = relief_colour_cues(refs, [np.clip(image, 0.0, 1.0) for image in normalized_images], valid=valid,
                                      ambient_index=ambient_index, light_dirs=light_dirs)
        label_regions(regions, labels, cue_maps, valid=valid, smooth_sigma_px=smooth_sigma_px)
        settings["cues"] = cue_maps.reason or "relief and colour (photometric stereo)"
    return ChangeResult(
        comparable=True,
        score=score,
        mask=mask,
        labels=labels,
        valid=valid,
        regions=regions,
        registration=registration,
        threshold=threshold,
        current_registered=[np.clip(image, 0.0, 1.0) for image in normalized_images],
        settings=settings,
        warnings=result_warnings(mask, valid, registration, register=register),
        edge_explained=explained,
        candidates=sorted((c for c in significance.candidates + significance.regions
                           if not mask[int(round(c.centroid_xy[1])), int(round(c.centroid_xy[0]))]),
                          key=lambda c: c.log10_nfa)[:5],
        not_compared=not_compared,
        dense=dense_fit,
        cue_maps=cue_maps,
    )


def decide(score: np.ndarray, valid: np.ndarray, *, decision: str = "acontrario", k_high: float = 20.0,
           k_low: float = 10.0, epsilon: float = 1.0, seed_p: float = 0.005, extent_fraction: float = 0.3,
           edge_fraction: float = 0.2, edge_radius_px: int = 6, min_region_px: int = 30, max_hole_px: int = 30,
           smooth_sigma_px: float = 2.0) -> tuple[np.ndarray, ThresholdInfo, Decision]:
    """The changed pixels of a fused score map (see :func:`detect_changes` for every option).

    Both rules are evaluated: the hysteresis threshold is kept as a reference (and
    is what the a-contrario scan is compared with in the report), the a-contrario
    decision gives every region its significance.

    Returns
    -------
    mask : ndarray, HxW bool, the cleaned change mask (inside ``valid``)
    threshold : ThresholdInfo, the hysteresis threshold's statistics
    significance : Decision, the a-contrario scan
    """
    raw_mask, threshold = robust_hysteresis_threshold(score, valid, k_high=k_high, k_low=k_low)
    significance = acontrario_decision(score, valid, epsilon=epsilon, seed_p=seed_p, extent_fraction=extent_fraction,
                                       min_cluster_area_px=4.0 * np.pi * smooth_sigma_px**2)
    if decision == "acontrario":
        raw_mask = significance.mask
    else:
        raw_mask = refine_to_local_peak(raw_mask, score, background=threshold.median, fraction=edge_fraction,
                                        radius_px=edge_radius_px)
    return clean_mask(raw_mask, min_region_px=min_region_px, max_hole_px=max_hole_px) & valid, threshold, significance


def result_warnings(mask: np.ndarray, valid: np.ndarray, registration: Registration, *, register: bool) -> list[str]:
    """Warnings a conservator should read with the map (too much flagged, registration without features)."""
    warnings = []
    fraction = float(mask[valid].mean())
    if fraction > 0.25:
        warnings.append(
            f"{fraction * 100:.0f} % of the compared area flagged: lighting or viewpoint may differ too much for a fine-grained comparison"
        )
    if registration.init == "identity" and register:
        warnings.append("features did not match; registration started from the identity (gradient ECC only)")
    return warnings


def _align(refs, curs, grays_ref, grays_cur, *, eval_mask, register: bool, dense: bool, registration_lighting: int,
           margin_px: int):
    """Bring the current stack into the reference frame: homography, then (``dense``) the parallax flow.

    Returns a reason string when the pair cannot be registered, else
    ``(registration, warped images, valid, seen_all, dense fit or None, not_compared or None)``.
    """
    shape = grays_ref[0].shape
    if register:
        registration = register_to_reference(grays_ref[registration_lighting], grays_cur[registration_lighting])
        if not registration.ok:
            return f"cannot compare: {registration.reason}"
    else:
        registration = Registration(H_cur_ref=np.eye(3), ok=True, init="none", overlap_fraction=1.0)
    area = np.ones(shape, bool) if eval_mask is None else eval_mask.copy()
    dense_fit = not_compared = None
    if dense:
        warped_gray, seen = warp_to_reference(grays_cur[registration_lighting], registration.H_cur_ref, shape)
        dense_fit = refine_dense(grays_ref[registration_lighting], warped_gray, valid=area & seen)
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
        valid = cv2.erode(valid.astype(np.uint8), np.ones((2 * margin_px + 1, 2 * margin_px + 1), np.uint8)).astype(bool)
    return registration, warped_images, valid, seen_all, dense_fit, not_compared
