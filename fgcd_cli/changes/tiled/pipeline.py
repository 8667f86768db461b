"""Bounded-memory, full-resolution change detection for large frames (20-45 MP), tile by tile.

:func:`detect_changes_tiled` computes what :func:`fgcd_cli.changes.detect.detect_changes`
computes (same cue, same light-gain normalisation, same robust gain rounds, same
decision), with these differences of *where* and *at which resolution* each stage runs:

- **Images stay 8-bit.** The stacks are kept as given (uint8 HxWx3: 14 x 24 MP is
  ~1 GB); a float32 copy exists only for the tile being processed, one lighting
  at a time.
- **Coarse-to-fine alignment.** The homography (:func:`register_to_reference`) and
  the dense parallax field (:func:`refine_dense`) are estimated on grey images
  downscaled to ``work_px`` on the long side (``cv2.INTER_AREA``). The parallax
  is smooth at the refinement's 57 px scale, so nothing is lost there; the
  homography is conjugated to full resolution with OpenCV's pixel-centre
  convention (``x_full = f (x_work + 0.5) - 0.5``), the flow is upsampled per
  tile (bilinear, values times ``f``), and each tile of the current image is
  resampled once, through homography and flow together (as
  :func:`~fgcd_cli.changes.dense.refine.warp_with_flow`).
- **Tiles for the per-lighting cue, a global null model.** Per tile (with an
  overlap that covers the gain windows) and per lighting: the light gain
  (:func:`~fgcd_cli.changes.illumination.normalize_local_gain`) and the symmetric
  shift-tolerant difference, whose core is written into one full-size float16
  map per lighting. A tile reads what its core's values depend on: the narrow
  gain window's reach (4 sigma) and the shift in the first pass, the whole
  overlap only in the robust rounds, whose wide window reaches that far. The
  workers take the tiles' lightings one by one; a tile's sampling maps and the
  blurs of its gain weight are computed once and shared by its lightings.
  **Median rule:** each lighting's difference is divided by its median over
  *all* compared pixels of the frame (a global null model, as in the untiled
  detector), never by a per-tile median: a per-tile median would make the final
  threshold a local one, so a tile full of change or of strong texture would
  raise its own floor. The fusion (mean over lightings of
  difference / median), the score smoothing, the robust gain rounds' suspect
  threshold and the decision (hysteresis or a-contrario, cleaning, regions) run
  once on the full-size maps, exactly as in ``detect_changes``.
- **Photometric cue labels** (relief / colour) are computed at the working
  resolution, with the regions mapped down, to keep time bounded; their maps are
  computed in a second thread while the a-contrario scan runs.

Not supported here (use ``detect_changes``): shading normalisation, the
gain-invariant structure cue, the edge tolerance and the region-level edge check.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import partial

import cv2
import numpy as np

from fgcd_cli.changes.config import OPTION_SECTION, DetectionConfig, ScoreConfig
from fgcd_cli.changes.images import check_side_inputs
from fgcd_cli.changes.registration import Registration
from fgcd_cli.changes.result import (
    CUES_COMPUTED,
    ChangeResult,
    detection_settings,
    empty_result,
    result_warnings,
    unreported_candidates,
)
from fgcd_cli.changes.threshold import robust_hysteresis_threshold
from fgcd_cli.changes.tiled.decision import decide_tiled
from fgcd_cli.changes.tiled.geometry import Geometry, Tile, scale_matrix, tile_grid
from fgcd_cli.changes.tiled.inputs import check_stacks
from fgcd_cli.changes.tiled.schedule import opencv_threads
from fgcd_cli.changes.tiled.tile_scores import TiledScore
from fgcd_cli.changes.tiled.working import Small, cue_maps_small, label_cues_small, working_resolution
from fgcd_cli.errors import UserInputError

__all__ = ["detect_changes_tiled"]

Progress = Callable[[int, int, str], None]

_UNSUPPORTED = ("structure_weight", "edge_tolerance_px", "edge_contrast", "edge_check_px", "edge_check_band_fraction")
"""Options of ``detect_changes`` this path does not implement (module docstring)."""


def detect_changes_tiled(
    ref_images: Sequence[np.ndarray],
    cur_images: Sequence[np.ndarray],
    *,
    roi: np.ndarray | None = None,
    pixel_area_mm2: np.ndarray | None = None,
    config: DetectionConfig | None = None,
    progress: Progress | None = None,
) -> ChangeResult:
    """:func:`fgcd_cli.changes.detect.detect_changes` for large frames, in bounded memory.

    Parameters
    ----------
    ref_images, cur_images : sequences of ndarray, HxW or HxWx3, uint8 (best), uint16 or float in [0, 1]
        One image per lighting, as for ``detect_changes``. They are never converted
        as a whole: keep them 8-bit (:func:`load_images`) to bound the memory.
    roi, pixel_area_mm2 : as for ``detect_changes`` (full resolution).
    config : DetectionConfig, optional
        As for ``detect_changes``; its ``tiling`` section (:class:`~fgcd_cli.changes.config.TilingConfig`)
        sets the tiles, the working and decision resolutions and the workers. The options
        this path does not implement must keep their defaults.
    progress : callable ``progress(done, total, label)``, optional
        Called after every tile of every pass (``label`` names the pass and the tile),
        and once per whole-frame stage.

    Returns
    -------
    ChangeResult
        ``current_registered`` is left empty (it would be a full-size float stack);
        ``dense`` and ``cue_maps`` are at the working resolution
        (``settings["work_scale"]`` gives the factor).
    """
    config = _tiled_config(config)
    shape, _ = check_stacks(ref_images, cur_images)
    n = len(ref_images)
    roi = check_side_inputs(
        shape,
        n,
        roi=roi,
        pixel_area_mm2=pixel_area_mm2,
        registration_lighting=config.registration.registration_lighting,
    )
    plan = _Plan.of(shape, config)
    report = _Report(progress, total=1 + len(plan.tiles) * plan.passes + 1)
    settings = _tiled_settings(config, n, plan)
    small = working_resolution(
        ref_images, cur_images, plan.work_wh, roi=roi, config=config.registration, workers=config.tiling.workers
    )
    if isinstance(small, tuple):
        report(small[0], units=report.total)
        return empty_result(shape, small[1], None, settings)
    registration, geom = _to_full_resolution(small, plan)
    report("registered (working resolution)")
    # The finer smoothing is scanned only where the decision runs at full resolution (`tiled.decision`).
    score_config = (
        config.score
        if max(shape) <= config.tiling.decision_px
        else dataclasses.replace(config.score, fine_smooth_sigma_px=0.0)
    )
    tiled = TiledScore(
        ref_images,
        cur_images,
        geom,
        plan.tiles,
        roi=roi,
        workers=config.tiling.workers,
        score=score_config,
        report=report,
    )
    tiled.run_pass(0, None)
    valid = tiled.valid()
    if valid.sum() < 100:
        report("nothing to compare", units=report.total - report.done)
        return empty_result(
            shape, "cannot compare: fewer than 100 pixels are seen in both images", registration, settings
        )
    score, fine, settings["robust_gain_rounds"] = _robust_rounds(tiled, valid, config)
    report.done = 1 + len(plan.tiles) * plan.passes  # rounds skipped by the early exits
    not_compared = tiled.not_compared
    del tiled
    mask, regions, labels, threshold, significance, cue_maps = _decide_and_label(
        (score, fine), valid, small, pixel_area_mm2=pixel_area_mm2, config=config, plan=plan, settings=settings
    )
    report("decided")
    return ChangeResult(
        comparable=True,
        score=score,
        fine_score=fine,
        mask=mask,
        labels=labels,
        valid=valid,
        regions=regions,
        registration=registration,
        threshold=threshold,
        current_registered=[],
        settings=settings,
        warnings=result_warnings(mask, valid, registration, register=config.registration.register),
        edge_explained=None,
        candidates=unreported_candidates(significance, mask),
        not_compared=not_compared,
        dense=small.dense_fit,
        cue_maps=cue_maps,
    )


def _tiled_config(config: DetectionConfig | None) -> DetectionConfig:
    """The configuration (default: the shipped one); refuses what this path does not implement."""
    config = DetectionConfig() if config is None else config
    defaults = DetectionConfig()
    for name in _UNSUPPORTED:
        section = OPTION_SECTION[name]
        if getattr(getattr(config, section), name) != getattr(getattr(defaults, section), name):
            raise UserInputError(f"{name} is not supported tile by tile (use detect_changes)")
    if config.tiling.tile_px < 64:
        raise UserInputError(f"tile size {config.tiling.tile_px} px is too small (at least 64 px)")
    return config


class _Report:
    """Progress in units: the working-resolution stage, each tile of each gain pass, the decision."""

    def __init__(self, progress: Progress | None, *, total: int) -> None:
        self.progress, self.total, self.done = progress, total, 0

    def __call__(self, label: str, *, units: int = 1) -> None:
        self.done += units
        if self.progress is not None:
            self.progress(min(self.done, self.total), self.total, label)


@dataclass(frozen=True, kw_only=True)
class _Plan:
    """Sizes of a tiled run: the tiles, their overlap, the working resolution and its scale factors."""

    tiles: list[Tile]
    overlap_px: int
    passes: int
    """Gain passes at most: the first and the robust rounds."""
    work_wh: tuple[int, int]
    full_wh: tuple[int, int]
    fx: float
    fy: float

    @classmethod
    def of(cls, shape: tuple[int, int], config: DetectionConfig) -> _Plan:
        h, w = shape
        tiling, score = config.tiling, config.score
        overlap_px = tiling.overlap_px
        if overlap_px is None:
            overlap_px = default_overlap_px(score)
        scale = max(1.0, max(h, w) / float(tiling.work_px))
        ws, hs = max(2, int(round(w / scale))), max(2, int(round(h / scale)))
        return cls(
            tiles=tile_grid(shape, tiling.tile_px, overlap_px),
            overlap_px=overlap_px,
            passes=1 + max(0, score.robust_gain_rounds),
            work_wh=(ws, hs),
            full_wh=(w, h),
            fx=w / ws,
            fy=h / hs,
        )


def default_overlap_px(score: ScoreConfig) -> int:
    """Context read around each tile: three sigma of the wide gain window that the gain normalisation
    falls back to next to large changes (``4 * gain_sigma_px``, far beyond the window it normally uses),
    plus the shift and 2 px of interpolation."""
    return int(math.ceil(3 * 4 * score.gain_sigma_px)) + score.shift_radius_px + 2


def _tiled_settings(config: DetectionConfig, lightings: int, plan: _Plan) -> dict:
    """``detect_changes``' settings without the options this path lacks, plus the tiling's."""
    settings = detection_settings(config, lightings=lightings, shading=False)
    del settings["edge_contrast"]
    tiling = config.tiling
    settings["tiled"] = {
        "tile_px": tiling.tile_px,
        "overlap_px": plan.overlap_px,
        "tiles": len(plan.tiles),
        "workers": tiling.workers,
        "medians": "global (all compared pixels of the frame)",
    }
    settings["work_scale"] = float(max(plan.fx, plan.fy))
    settings["work_size_wh"] = list(plan.work_wh)
    return settings


def _to_full_resolution(small: Small, plan: _Plan) -> tuple[Registration, Geometry]:
    """The working-resolution registration conjugated to full resolution, and the tiles' sampling geometry."""
    (ws, hs), (w, h), fx, fy = plan.work_wh, plan.full_wh, plan.fx, plan.fy
    reg_small = small.registration
    A = scale_matrix(fx, fy)
    H_full = A @ reg_small.H_cur_ref @ np.linalg.inv(A)
    H_full = H_full / H_full[2, 2]
    registration = Registration(
        H_cur_ref=H_full,
        ok=reg_small.ok,
        reason=reg_small.reason,
        ecc_correlation=reg_small.ecc_correlation,
        overlap_fraction=reg_small.overlap_fraction,
        sift_inliers=reg_small.sift_inliers,
        init=reg_small.init,
        settings=dict(reg_small.settings, resolution=f"{ws}x{hs} (area-downscaled), conjugated to {w}x{h}"),
    )
    dense_fit = small.dense_fit
    geom = Geometry(
        H_full=H_full,
        flow_work=None if dense_fit is None else dense_fit.flow,
        not_compared_work=None if dense_fit is None else dense_fit.not_compared,
        fx=fx,
        fy=fy,
        max_flow_full=0.0 if dense_fit is None else dense_fit.max_flow_px * max(fx, fy),
    )
    return registration, geom


def _robust_rounds(
    tiled: TiledScore, valid: np.ndarray, config: DetectionConfig
) -> tuple[np.ndarray, np.ndarray | None, int]:
    """The fused score after the robust gain rounds, its finer smoothing (or None), and the rounds run.

    As :func:`fgcd_cli.changes.score.score_pair`, on the full frame: the suspect set is
    decided by the whole frame's threshold, the gain re-estimated without it.
    """
    score, fine = tiled.fuse(valid)
    gain_weight = None
    rounds = 0
    for r in range(config.score.robust_gain_rounds):
        _, first = robust_hysteresis_threshold(score, valid, k_high=config.regions.k_high, k_low=config.regions.k_low)
        suspect = (score > first.low) & valid
        if suspect.mean() > 0.5 * valid.mean():
            break
        suspect = cv2.dilate(suspect.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        new_weight = tiled.seen_all & ~suspect
        if rounds and np.array_equal(new_weight, gain_weight):
            break
        gain_weight = new_weight
        del score, fine, suspect
        tiled.run_pass(r + 1, gain_weight)
        score, fine = tiled.fuse(valid)
        rounds += 1
    return score, fine, rounds


def _decide_and_label(
    scores, valid, small: Small, *, pixel_area_mm2, config: DetectionConfig, plan: _Plan, settings: dict
):
    """Decision on the full frame (as ``detect_changes``), the cue maps alongside at the working resolution.

    ``scores`` is the fused score and its finer smoothing (or None).

    One thread beside the decision: the cue maps (photometric stereo), then the threshold.
    Returns ``(mask, regions, labels, threshold, significance, cue maps or None)``.
    """
    (ws, hs), fx, fy = plan.work_wh, plan.fx, plan.fy
    smooth_sigma_px, workers = config.score.smooth_sigma_px, config.tiling.workers
    cue_job = None
    if config.cue_labels.cues:
        cue_job = partial(
            cue_maps_small,
            small,
            valid,
            small.dense_fit,
            gain_sigma_px=config.score.gain_sigma_px / max(fx, fy),
            config=config.cue_labels,
        )
    with opencv_threads(1 if workers > 1 else None), ThreadPoolExecutor(max_workers=1) as aside:
        mask, regions, labels, threshold, significance, cue_maps = decide_tiled(
            scores,
            valid,
            aside,
            cue_job,
            pixel_area_mm2=pixel_area_mm2,
            config=config.regions,
            decision_px=config.tiling.decision_px,
            smoothing_px=(smooth_sigma_px, config.score.fine_smooth_sigma_px),
        )
        settings["significance_scale"] = significance.settings.get("scale", 1.0)
        if cue_maps is not None:
            cue_maps, valid_small = cue_maps.result()
            label_cues_small(
                cue_maps, valid_small, regions, labels, (ws, hs), smooth_sigma_px=smooth_sigma_px, fx=fx, fy=fy
            )
            settings["cues"] = (cue_maps.reason or CUES_COMPUTED) + f", at {ws}x{hs}"
    return mask, regions, labels, threshold, significance, cue_maps
