"""The diff use case (``fgcd diff``): compare a visit with its station's reference, or two sets of image files, and write the products.

Plain functions (no typer); the CLI parses options and renders what they return.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fgcd_cli.app.diff_geometry import campaign_pixel_area, reference_geometry
from fgcd_cli.app.diff_options import (
    check_diff_options,
    check_stored_diff,
    checked_edge_check_px,
    contrast_options,
    default_edge_check_px,
)
from fgcd_cli.app.lamp_image import dark_world, flash_name
from fgcd_cli.app.visit_logs import coarse_log_rows, relocation_log_rows, relocation_residual_text
from fgcd_cli.archive.freshness import ANALYSIS_RELPATH, AnalysisOptions, analysis_inputs, analysis_record
from fgcd_cli.campaign import schema
from fgcd_cli.campaign.atomic import atomic_write_bytes, check_writable, sha256_file
from fgcd_cli.changes.config import DetectionConfig
from fgcd_cli.changes.detect import detect_changes
from fgcd_cli.changes.images import check_stack_sizes, to_float_image, to_gray
from fgcd_cli.changes.io import expand_image_args, read_image, read_mask
from fgcd_cli.changes.result import ChangeResult
from fgcd_cli.errors import AlgorithmError, CampaignError, UserInputError
from fgcd_cli.metrics.afd import FdfConfig, FdfResult, compute_fdf
from fgcd_cli.metrics.change_scores import truth_report
from fgcd_cli.report.html import ReportContext
from fgcd_cli.report.pose_check import geometry_text, relocation_check_text
from fgcd_cli.report.products import diff_products, result_summary

Progress = Callable[[str], None] | None
TileProgress = Callable[[int, int, str], None] | None

LARGE_FRAME_PX = 8_000_000
"""Frames above this many pixels are compared tile by tile in bounded memory
(:func:`fgcd_cli.changes.tiled.pipeline.detect_changes_tiled`; ``docs/change-detection.md``, "Large frames")."""


def _say(progress: Progress, message: str) -> None:
    if progress is not None:
        progress(message)


def measure_fdf(ref_image: np.ndarray, cur_image: np.ndarray) -> FdfResult | None:
    """FDF with the authors' SIFT protocol, falling back to the grid variant; None if both fail."""
    ref = to_gray(to_float_image(ref_image, name="reference image"))
    cur = to_gray(to_float_image(cur_image, name="current image"))
    if ref.shape != cur.shape:
        return None
    for method in ("sift", "grid"):
        try:
            return compute_fdf(ref, cur, config=FdfConfig(method=method))
        except AlgorithmError:
            continue
    return None


def _write_dir(output: Path, files: dict[str, bytes]) -> None:
    output.mkdir(parents=True, exist_ok=True)
    for name, data in files.items():
        atomic_write_bytes(output / name, data)


@dataclass(frozen=True, kw_only=True)
class BareDiffRequest:
    """A comparison of image files (``fgcd diff --ref ... --cur ...``).

    Attributes
    ----------
    ref, cur : list of str
        Image files or glob patterns, one per lighting, in the same order.
    output : Path
        Directory the products are written to.
    roi : Path or None
        Region of interest: a mask of the reference pixels to compare (``--roi``); None compares the whole frame.
    truth : Path or None
        Mask of the true changes (scores the result).
    score_mask : Path or None
        Where ``truth`` is scored (an evaluator's region, never given to the detector); None: the ROI, else every pixel.
    mm_per_px : float or None
        Scale of the reference image, millimetres per pixel.
    register : bool
        Register the current images onto the reference first.
    edge_check_px : int or None
        Region-level edge check shift, pixels (None: :data:`fgcd_cli.app.diff_options.EDGE_CHECK_PX`; 0: off).
    ambient_index : int or None
        0-based index of the ambient-only image (left out of photometric stereo).
    min_contrast : float or None
        Contrast floor of a reported region (``--min-contrast``; None: the detector's default, 0: off).
    """

    ref: list[str]
    cur: list[str]
    output: Path
    roi: Path | None = None
    truth: Path | None = None
    score_mask: Path | None = None
    mm_per_px: float | None = None
    register: bool = True
    edge_check_px: int | None = None
    ambient_index: int | None = None
    min_contrast: float | None = None

    def __post_init__(self) -> None:
        check_diff_options(
            mm_per_px=self.mm_per_px,
            edge_check_px=self.edge_check_px,
            ambient_index=self.ambient_index,
            min_contrast=self.min_contrast,
            files={"--roi": self.roi, "--truth": self.truth, "--score-mask": self.score_mask},
        )


@dataclass(frozen=True, kw_only=True)
class BareDetection:
    """What :func:`detect_bare` read and found: the files, their images, the ROI, the result and its FDF."""

    ref_paths: list[Path]
    cur_paths: list[Path]
    ref_images: list[np.ndarray]
    cur_images: list[np.ndarray]
    roi: np.ndarray | None
    result: ChangeResult
    fdf: FdfResult | None


def detect_bare(
    request: BareDiffRequest, *, progress: Progress = None, tile_progress: TileProgress = None
) -> BareDetection:
    """Read the image files and detect their changes as ``fgcd diff --ref ... --cur ...`` does, writing nothing.

    ``fgcd bench changes`` scores this very detection; :func:`run_bare` writes its products.
    """
    r = request
    ref_paths = expand_image_args(r.ref, what="--ref")
    cur_paths = expand_image_args(r.cur, what="--cur")
    if r.ambient_index is not None and not 0 <= r.ambient_index < len(ref_paths):
        raise UserInputError(f"--ambient-index {r.ambient_index} is outside 0..{len(ref_paths) - 1}")
    ref_images = [read_image(p) for p in ref_paths]
    cur_images = [read_image(p) for p in cur_paths]
    check_stack_sizes(ref_images, cur_images)  # before any work is announced
    roi = read_mask(r.roi) if r.roi is not None else None
    area = None if r.mm_per_px is None else np.full(ref_images[0].shape[:2], r.mm_per_px**2)
    _say(progress, f"comparing {len(ref_images)} lighting(s)…")
    if ref_images[0].shape[0] * ref_images[0].shape[1] > LARGE_FRAME_PX:
        from fgcd_cli.changes.tiled.pipeline import detect_changes_tiled

        _say(
            progress,
            f"{ref_images[0].shape[1]}x{ref_images[0].shape[0]} px: comparing tile by tile "
            "(no edge check, no FDF on frames this large)",
        )
        result = detect_changes_tiled(
            ref_images,
            cur_images,
            roi=roi,
            pixel_area_mm2=area,
            progress=tile_progress,
            config=DetectionConfig.from_options(register=r.register, ambient_index=r.ambient_index),
        )
        fdf = None
    else:
        result = detect_changes(
            ref_images,
            cur_images,
            roi=roi,
            pixel_area_mm2=area,
            config=DetectionConfig.from_options(
                register=r.register,
                edge_check_px=checked_edge_check_px(default_edge_check_px(r.edge_check_px)),
                ambient_index=r.ambient_index,
                **contrast_options(r.min_contrast),
            ),
        )
        same_size = ref_images[0].shape == cur_images[0].shape
        fdf = measure_fdf(ref_images[0], cur_images[0]) if result.comparable or same_size else None
    return BareDetection(
        ref_paths=ref_paths,
        cur_paths=cur_paths,
        ref_images=ref_images,
        cur_images=cur_images,
        roi=roi,
        result=result,
        fdf=fdf,
    )


def run_bare(request: BareDiffRequest, *, progress: Progress = None, tile_progress: TileProgress = None) -> dict:
    """Compare image files (one per lighting) and write the products into ``output``.

    ``ambient_index`` (0-based) names the image taken under ambient light only; it is
    left out of the photometric-stereo fit that labels regions relief / colour.
    """
    r = request
    truth = _read_truth(r.truth, r.score_mask)  # a damaged file refused before the detection
    found = detect_bare(r, progress=progress, tile_progress=tile_progress)
    result, fdf = found.result, found.fdf
    if truth is not None:
        _check_truth_shape(truth, result.mask.shape)  # before any product is written
    metadata = {
        "reference images": [str(p) for p in found.ref_paths],
        "current images": [str(p) for p in found.cur_paths],
    }
    if r.mm_per_px is not None:
        metadata["scale (mm per px)"] = r.mm_per_px
    context = ReportContext(
        metadata=metadata,
        title="Change report",
        subtitle=f"{found.ref_paths[0].resolve().parent} — reference vs current",
    )
    files = diff_products(
        ref_images=found.ref_images, cur_images=found.cur_images, result=result, fdf=fdf, context=context
    )
    _write_dir(r.output, files)
    data = result_summary(result, fdf)
    data["output"] = str(r.output)
    if truth is not None:
        data["scores"] = truth_report(result.mask, result.score, truth.truth, eval_mask=truth.scored_in(found.roi))
    return data


@dataclass(frozen=True)
class _Truth:
    """An evaluator's ground truth (``--truth``) and where it is scored (``--score-mask``; None: the ROI)."""

    truth: np.ndarray
    score_mask: np.ndarray | None

    def scored_in(self, roi: np.ndarray | None) -> np.ndarray | None:
        return self.score_mask if self.score_mask is not None else roi


def _read_truth(truth: Path | None, score_mask: Path | None, shape: tuple[int, int] | None = None) -> _Truth | None:
    """Read ``--truth`` and ``--score-mask`` (never given to the detector); with ``shape``, check their size."""
    if truth is None:
        return None
    read = _Truth(read_mask(truth), read_mask(score_mask) if score_mask is not None else None)
    if shape is not None:
        _check_truth_shape(read, shape)
    return read


def _check_truth_shape(truth: _Truth, shape: tuple[int, ...]) -> None:
    masks = [truth.truth] + ([truth.score_mask] if truth.score_mask is not None else [])
    if any(m.shape != tuple(shape[:2]) for m in masks):
        raise UserInputError(
            f"--truth and --score-mask must have the reference image's size ({shape[1]} x {shape[0]} px)"
        )


def _paired_lightings(reference, visit) -> tuple[list[str], list[str]]:
    """The reference's and the visit's image names compared pairwise.

    Every lighting both observations hold, in the reference's order (a dark-world reference's lamp
    image with the visit's image of that lamp alone, where the visit holds one). When they
    share none (an outdoor reference under one day's sun, a visit under
    another's: no rig takes the reference's sun again, docs/change-detection.md,
    "Campaign diffs"), each observation's own day light, the first of its
    lightings, is compared across lightings.
    """
    ref_names = [n for n in (reference.metadata.get("lightings") or reference.image_names()) if reference.has_image(n)]
    visit_order = list(visit.metadata.get("lightings") or visit.image_names())
    visit_names = [n for n in visit_order if visit.has_image(n)]
    shared = [n for n in ref_names if n in visit_names]
    if shared and dark_world(reference.metadata):
        # a dark world's lamp image is the lamp alone: where the visit holds that lamp's own image
        # (its day added light, app/lamp_image.lamp_alone_now), that is what it is compared with
        return shared, [flash_name(n) if flash_name(n) in visit_names else n for n in shared]
    if shared:
        return shared, shared
    if not ref_names or not visit_names:
        raise CampaignError(
            f"visit {visit.name} has no image to compare with the reference's lightings ({', '.join(ref_names) or 'none'})"
        )
    return ref_names[:1], visit_names[:1]


def _pairing_note(lightings: list[str], visit_lightings: list[str]) -> str:
    """What the progress line adds about the pairing of :func:`_paired_lightings` (empty: like with like)."""
    if lightings == visit_lightings:
        return ""
    if all(v in (n, flash_name(n)) for n, v in zip(lightings, visit_lightings)):
        return " (the dark reference's lamp images against the visit's images of the lamp alone)"
    return f" across lightings ({lightings[0]} against {visit_lightings[0]})"


@dataclass(frozen=True, kw_only=True)
class CampaignDiffRequest:
    """A comparison of a station's visit with its reference (``fgcd diff -c ... -s ...``).

    Attributes
    ----------
    campaign : Path
    station : str
    visit : str or None
        The visit's name (None: the latest).
    roi : Path or None
        Region of interest: a mask of the reference pixels to compare (``--roi``); None compares the whole frame.
    mm_per_px : float or None
        Scale of the reference image, millimetres per pixel (None: from the reference's metric cloud).
    register : bool
        Register the current images onto the reference first.
    output : Path or None
        A folder that also receives the products (they are always stored in the visit).
    edge_check_px : int or None
        Region-level edge check shift, pixels (None: :data:`fgcd_cli.app.diff_options.EDGE_CHECK_PX`; 0: off).
    min_contrast : float or None
        As :class:`BareDiffRequest`'s.
    geometry : bool
        Warp the visit's images by the reference depth (its metric cloud) and the residual pose measured
        against it, and leave depth edges uncompared (:mod:`fgcd_cli.changes.geometry`); False: the
        homography, as a bare diff.
    force : bool
        Replace a stored diff of the visit that was made with other options
        (without it such a diff is kept and the request refused,
        :func:`fgcd_cli.app.diff_options.check_stored_diff`).
    truth, score_mask : Path or None
        As :class:`BareDiffRequest`'s, in the reference image's frame (an evaluator's; the
        stored products never depend on them).
    """

    campaign: Path
    station: str
    visit: str | None = None
    roi: Path | None = None
    mm_per_px: float | None = None
    register: bool = True
    output: Path | None = None
    edge_check_px: int | None = None
    min_contrast: float | None = None
    geometry: bool = True
    force: bool = False
    truth: Path | None = None
    score_mask: Path | None = None

    def __post_init__(self) -> None:
        check_diff_options(
            mm_per_px=self.mm_per_px,
            edge_check_px=self.edge_check_px,
            min_contrast=self.min_contrast,
            files={"--roi": self.roi, "--truth": self.truth, "--score-mask": self.score_mask},
        )

    def options(self) -> AnalysisOptions:
        """The options this diff is made with, as its record (``changes/analysis.json``) states them."""
        return AnalysisOptions(
            edge_check_px=self.edge_check_px,
            min_contrast=self.min_contrast,
            mm_per_px=self.mm_per_px,
            register=self.register,
            eval_mask_sha256=sha256_file(self.roi) if self.roi is not None else None,
            geometry=self.geometry,
        )


def run_campaign(request: CampaignDiffRequest, *, progress: Progress = None) -> dict:
    """Compare a station's visit with its reference; store the products in the visit (``changes/``, ``report.html``).

    The options are checked when the request is made; a stored diff made with other
    options is refused before any image is read (:func:`fgcd_cli.app.diff_options.check_stored_diff`). The
    products are followed by ``changes/analysis.json``, the record of the options and
    inputs (:mod:`fgcd_cli.archive.freshness`).
    """
    from fgcd_cli.campaign.store import open_campaign

    r = request
    t0 = time.perf_counter()
    camp = open_campaign(r.campaign)
    st = camp.station(r.station)
    reference = st.reference()
    observation = st.visit(r.visit)
    options = r.options()
    replaced = check_stored_diff(observation, options, force=r.force)
    check_writable(observation.path)  # the products go into the visit: refused before the computation
    lightings, visit_lightings = _paired_lightings(reference, observation)
    ref_images = [reference.image(n) for n in lightings]
    cur_images = [observation.image(n) for n in visit_lightings]
    check_stack_sizes(ref_images, cur_images)
    shape = ref_images[0].shape[:2]
    truth = _read_truth(r.truth, r.score_mask, shape)
    geometry = reference_geometry(reference, shape)
    area, scale_note = campaign_pixel_area(geometry, shape, r.mm_per_px)
    mask = read_mask(r.roi) if r.roi is not None else None
    edge_check = checked_edge_check_px(default_edge_check_px(r.edge_check_px))
    across = _pairing_note(lightings, visit_lightings)
    _say(progress, f"station {r.station}, visit {observation.name}: comparing {len(lightings)} lighting(s){across}…")
    # The campaign names its lightings: the ambient one is left out of the photometric-stereo fit.
    result = detect_changes(
        ref_images,
        cur_images,
        roi=mask,
        pixel_area_mm2=area,
        geometry=geometry if r.geometry else None,
        config=DetectionConfig.from_options(
            register=r.register,
            edge_check_px=edge_check,
            ambient_index=lightings.index("ambient") if "ambient" in lightings else None,
            **contrast_options(r.min_contrast),
        ),
    )
    fdf = measure_fdf(ref_images[0], cur_images[0])
    check = relocation_check_text((observation.metadata.get("relocation") or {}).get("residual"), result.settings)
    metadata = {
        "site": camp.site,
        "station": r.station,
        "visit": observation.name,
        "lightings": lightings
        if not across
        else [f"{a} (reference) against {b} (visit)" for a, b in zip(lightings, visit_lightings)],
        "metric scale": scale_note,
        **({"scale (mm per px)": r.mm_per_px} if r.mm_per_px is not None else {}),
        "relocation": observation.metadata.get("relocation") or {},
        "relocation residual (its own estimate)": relocation_residual_text(observation),
        "warp": geometry_text(result.settings),
        "relocation check": check or "not made (no stated residual or no measured pose)",
        "edge check": _edge_check_text(edge_check, result.settings),
    }
    from fgcd_cli.app.scene_uncertainty import cached_scene_uncertainty

    context = ReportContext(
        relocation_log=relocation_log_rows(observation),
        metadata=metadata,
        scene_map=cached_scene_uncertainty(st),
        coarse_log=coarse_log_rows(observation),
        title=f"Station {r.station}: change report",
        subtitle=f"{camp.site} · reference vs visit {observation.name}",
    )
    files = diff_products(ref_images=ref_images, cur_images=cur_images, result=result, fdf=fdf, context=context)
    _store_products(st, observation, files, fdf, options=options, inputs=analysis_inputs(reference, observation), t0=t0)
    if r.output is not None:
        _write_dir(r.output, files)
    data = result_summary(result, fdf)
    data["output"] = str(r.output or observation.path)
    data["visit"] = observation.name
    if check:
        data["relocation_check"] = check
    if replaced:
        data["warnings"] = [*data.get("warnings", []), replaced]
    if truth is not None:
        data["scores"] = truth_report(result.mask, result.score, truth.truth, eval_mask=truth.scored_in(mask))
    return data


def _edge_check_text(edge_check: int, settings: dict) -> str:
    """The report's line on the edge check a diff made."""
    if not edge_check:
        return "off"
    return (
        f"{edge_check} px: {settings.get('edge_explained_regions', 0)} region(s) along strong edges set aside "
        "(cyan outlines)"
    )


def _store_products(
    st,
    observation,
    files: dict[str, bytes],
    fdf: FdfResult | None,
    *,
    options: AnalysisOptions,
    inputs: dict[str, str],
    t0: float,
) -> None:
    """The products in the visit, then the record of the options and inputs they were made with, last."""
    for name, data in files.items():
        observation.add_derived(schema.change_relpath(name), data)
    if fdf is not None:
        observation.add_derived(schema.AFD_JSON, json.dumps(fdf.as_dict(), indent=1).encode())
    visit = st.visit(observation.name)  # the manifest now lists the products
    record = analysis_record(visit, inputs=inputs, options=options, seconds=time.perf_counter() - t0)
    visit.add_derived(ANALYSIS_RELPATH, (json.dumps(record, indent=1) + "\n").encode("utf-8"))
