"""Top-level fine-grained change detection, as a sequence of named steps.

register (:func:`align_stacks`) → dense refine (inside it) → score (:func:`score_stacks`)
→ decide and edge check (:mod:`fgcd_cli.changes.region_decision`) → cues / labels
(:func:`label_cues`) → result. Each step takes the :mod:`fgcd_cli.changes.config`
section it needs; :func:`detect_changes` chains them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from fgcd_cli.changes.config import (
    CueConfig,
    DetectionConfig,
    RegionConfig,
    RegistrationConfig,
    ScoreConfig,
)
from fgcd_cli.changes.cues.labels import CueMaps, label_regions, relief_colour_cues
from fgcd_cli.changes.dense.refine import DenseAlignment, refine_dense, warp_with_flow, warp_with_maps
from fgcd_cli.changes.geometry.depth import ReferenceGeometry
from fgcd_cli.changes.geometry.stack_warp import GeometryWarp, geometry_warp
from fgcd_cli.changes.illumination import normalize_shading
from fgcd_cli.changes.images import check_side_inputs, image_health, to_gray, validate_stacks
from fgcd_cli.changes.region_decision import decide_regions, set_aside_regions
from fgcd_cli.changes.regions import (
    ChangeRegion,
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
from fgcd_cli.errors import UserInputError

__all__ = [
    "DetectionConfig",
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
    shading: tuple[list[np.ndarray], list[np.ndarray]] | None = None,
    geometry: ReferenceGeometry | None = None,
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
    shading : (list of ndarray, list of ndarray), optional
        Per-lighting Lambertian shading maps (reference, current; HxW, reference frame;
        :func:`fgcd_cli.changes.illumination.shading_from_normals`): the current images are re-lit first.
    geometry : ReferenceGeometry, optional
        The reference's depth: the current images are warped by it and the residual pose measured against
        it, not the homography; depth edges are not compared (:mod:`fgcd_cli.changes.geometry`).
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
    settings = detection_settings(config, lightings=len(ref_images), shading=shading is not None)
    step = _Steps(progress, total=4)
    refs, curs, roi = _check_inputs(
        ref_images,
        cur_images,
        roi=roi,
        pixel_area_mm2=pixel_area_mm2,
        shading=shading,
        config=config.registration,
    )
    shape = refs[0].shape[:2]
    grays_ref, grays_cur = [to_gray(im) for im in refs], [to_gray(im) for im in curs]
    problem = stack_health(grays_ref, grays_cur)
    if problem:
        return empty_result(shape, problem, None, settings)
    alignment = align_stacks(curs, grays_ref, grays_cur, roi=roi, config=config, geometry=geometry)
    if isinstance(alignment, str):
        return empty_result(shape, alignment, None, settings)
    if alignment.valid.sum() < 100:
        return empty_result(
            shape, "cannot compare: fewer than 100 pixels are seen in both images", alignment.registration, settings
        )
    step("registered")
    _relight_and_record(refs, alignment, shading=shading, settings=settings)
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
    set_aside = set_aside_regions(
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
        edge_explained=set_aside.edge,
        candidates=unreported_candidates(found.significance, found.mask, first=set_aside.listed),
        not_compared=alignment.not_compared,
        dense=alignment.dense,
        cue_maps=cue_maps,
        pair_score=scored,
    )


def _relight_and_record(refs, alignment: Alignment, *, shading, settings: dict) -> None:
    """Re-light the registered current images to the reference lighting (when shading maps are given) and
    record the geometry warp in ``settings``."""
    if alignment.geometry is not None:
        settings["geometry"] = geometry_settings(alignment.geometry)
    if shading is not None:
        alignment.warped = [
            normalize_shading(ref, warped, shading_ref=s_ref, shading_cur=s_cur)
            for ref, warped, s_ref, s_cur in zip(refs, alignment.warped, *shading)
        ]


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
    if shading is not None and (len(shading) != 2 or any(len(maps) != len(refs) for maps in shading)):
        raise UserInputError("give shading maps as (reference maps, current maps), one per lighting each")
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
    geometry: GeometryWarp | None = None


def align_stacks(
    curs,
    grays_ref,
    grays_cur,
    *,
    roi,
    config: DetectionConfig,
    geometry: ReferenceGeometry | None = None,
) -> Alignment | str:
    """Bring the current stack into the reference frame: homography (or, with ``geometry``, the reference
    depth and the residual pose measured against it), then (``config.registration.dense``) the parallax flow.

    Returns a reason string when the pair cannot be registered.
    """
    margin_px, tolerance_px = comparison_margin_px(config.score), config.score.shift_radius_px
    registration_config = config.registration
    shape, k = grays_ref[0].shape, registration_config.registration_lighting
    if registration_config.register:
        registration = register_to_reference(grays_ref[k], grays_cur[k])
        if not registration.ok:
            return f"cannot compare: {registration.reason}"
    else:
        registration = Registration(H_cur_ref=np.eye(3), ok=True, init=RegistrationInit.NONE, overlap_fraction=1.0)
    area = np.ones(shape, bool) if roi is None else roi.copy()
    geo = None
    if geometry is not None and registration_config.register:
        geo = geometry_warp(geometry, grays_ref[k], grays_cur[k], registration.H_cur_ref, tolerance_px=tolerance_px)

    def warp(image, flow=None):
        if geo is not None and geo.map_x is not None:
            return warp_with_maps(image, geo.map_x, geo.map_y, flow)
        if flow is not None:
            return warp_with_flow(image, registration.H_cur_ref, flow)
        return warp_to_reference(image, registration.H_cur_ref, shape)

    dense_fit = not_compared = None
    if registration_config.dense:
        warped_gray, seen = warp(grays_cur[k])
        dense_fit = refine_dense(grays_ref[k], warped_gray, valid=area & seen)
        not_compared = dense_fit.not_compared & area
    if geo is not None and geo.not_compared is not None:
        not_compared = (geo.not_compared & area) | (not_compared if not_compared is not None else False)
    warped_images = []
    seen_all = np.ones(shape, bool)
    for cur in curs:
        warped, seen = warp(cur, dense_fit.flow if dense_fit is not None else None)
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
        geometry=geo,
    )


def geometry_settings(geo: GeometryWarp) -> dict:
    """What a detection records of its geometry warp: the residual pose measured, or why not."""
    pose = geo.pose
    if not pose.ok:
        return {"warp": "homography (the residual pose was not measured)", "reason": pose.reason}
    return {
        "warp": "reference depth and residual pose",
        "residual_pose_mm": round(pose.translation_mm, 3),
        "residual_pose_deg": round(pose.rotation_deg, 4),
        "T_cur_ref": np.round(pose.T_cur_ref, 9).tolist(),
        "pnp_inliers": pose.inliers,
        "pnp_matches": pose.matches,
        "pnp_rms_px": round(pose.rms_px, 3),
        "depth_fraction": round(geo.depth_fraction, 4),
        "depth_edge_fraction": round(float(geo.not_compared.mean()), 4) if geo.not_compared is not None else 0.0,
    }


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
