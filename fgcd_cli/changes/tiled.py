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
  :func:`~fgcd_cli.changes.dense.warp_with_flow`).
- **Tiles for the per-lighting cue, a global null model.** Per tile (with an
  overlap that covers the gain windows) and per lighting: the light gain
  (:func:`~fgcd_cli.changes.illumination.normalize_local_gain`) and the symmetric
  shift-tolerant difference, whose core is written into one full-size float16
  map per lighting. **Median rule:** each lighting's difference is divided by
  its median over *all* compared pixels of the frame (a global null model, as in
  the untiled detector), never by a per-tile median: a per-tile median would
  make the final threshold a local one, so a tile full of change or of strong
  texture would raise its own floor. The fusion (mean over lightings of
  difference / median), the score smoothing, the robust gain rounds' suspect
  threshold and the decision (hysteresis or a-contrario, cleaning, regions) run
  once on the full-size maps, exactly as in ``detect_changes``.
- **Photometric cue labels** (relief / colour) are computed at the working
  resolution, with the regions mapped down, to keep time bounded.

Not supported here (use ``detect_changes``): shading normalisation, the
gain-invariant structure cue, the edge tolerance and the region-level edge check.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from fgcd_cli.changes.cue_labels import label_regions, relief_colour_cues
from fgcd_cli.changes.dense import refine_dense, warp_with_flow
from fgcd_cli.changes.cues import shift_tolerant_difference
from fgcd_cli.changes.detect import ChangeResult, empty_result, regions_with_significance, result_warnings
from fgcd_cli.changes.illumination import normalize_local_gain
from fgcd_cli.changes.images import image_health
from fgcd_cli.changes.regions import clean_mask, refine_to_local_peak
from fgcd_cli.changes.registration import Registration, register_to_reference, warp_to_reference
from fgcd_cli.changes.significance import acontrario_decision, grow_to_extent
from fgcd_cli.changes.threshold import robust_hysteresis_threshold
from fgcd_cli.errors import UserInputError

Progress = Callable[[int, int, str], None]


def load_images(paths: Sequence[str | os.PathLike], *, workers: int = 2) -> list[np.ndarray]:
    """Read image files as 8-bit RGB arrays (HxWx3 uint8), the memory-light input of :func:`detect_changes_tiled`.

    16-bit files are reduced to 8 bits (the detector's cue resolution is far coarser
    than 1/255); a missing or unreadable file raises :class:`UserInputError`.
    """
    def read(path) -> np.ndarray:
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            raise UserInputError(f"cannot read image {path}")
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB, dst=image)

    if workers > 1 and len(paths) > 1:
        with ThreadPoolExecutor(max_workers=workers) as pool:  # PNG decoding releases the GIL
            return list(pool.map(read, paths))
    return [read(path) for path in paths]


# --------------------------------------------------------------------------- input


def _check_stacks(ref_images, cur_images) -> tuple[tuple[int, int], int]:
    """Validate without converting (the stacks may be large); returns (H, W) and the channel count."""
    if len(ref_images) == 0 or len(cur_images) == 0:
        raise UserInputError("need at least one reference and one current image")
    if len(ref_images) != len(cur_images):
        raise UserInputError(
            f"{len(ref_images)} reference image(s) but {len(cur_images)} current image(s): "
            "give one current image per reference lighting, in the same order"
        )
    first = np.asarray(ref_images[0])
    shape, ndim = first.shape[:2], first.ndim
    for i, image in enumerate(list(ref_images) + list(cur_images)):
        which = f"reference image {i + 1}" if i < len(ref_images) else f"current image {i - len(ref_images) + 1}"
        image = np.asarray(image)
        if image.ndim not in (2, 3) or image.shape[0] < 2 or image.shape[1] < 2:
            raise UserInputError(f"{which}: expected an HxW or HxWx3 image, got shape {image.shape}")
        if image.ndim == 3 and image.shape[2] not in (1, 3, 4):
            raise UserInputError(f"{which}: expected 1, 3 or 4 channels, got {image.shape[2]}")
        if image.shape[:2] != shape:
            raise UserInputError(
                f"{which} is {image.shape[1]}x{image.shape[0]} px but reference image 1 is {shape[1]}x{shape[0]} px: "
                "all images must have the same size"
            )
        if image.ndim != ndim:
            raise UserInputError("mixing colour and grey images: give all images in colour or all in grey")
        if not (np.issubdtype(image.dtype, np.integer) or np.issubdtype(image.dtype, np.floating)):
            raise UserInputError(f"{which}: unsupported pixel type {image.dtype}")
    return shape, (1 if ndim == 2 else 3)


def _crop_float(image: np.ndarray, y0: int, y1: int, x0: int, x1: int) -> np.ndarray:
    """float32 [0, 1] copy of a crop (grey or RGB; alpha dropped), as :func:`to_float_image` converts."""
    crop = np.asarray(image)[y0:y1, x0:x1]
    if crop.ndim == 3:
        crop = crop[:, :, 0] if crop.shape[2] == 1 else crop[:, :, :3]
    if np.issubdtype(crop.dtype, np.integer):
        return crop.astype(np.float32) / np.float32(np.iinfo(crop.dtype).max)  # bit-identical to to_float_image
    return np.clip(np.nan_to_num(crop.astype(np.float32), nan=0.0), 0.0, 1.0)


def _downscale_float(image: np.ndarray, size_wh: tuple[int, int]) -> np.ndarray:
    """Area-averaged float32 [0, 1] version of a whole image at ``size_wh``.

    8-bit images are averaged as they are (the result is rounded to 1/255, far below
    what registration and the photometric cues resolve); others through one float copy.
    """
    array = np.asarray(image)
    h, w = array.shape[:2]
    if array.dtype == np.uint8 and (w, h) != size_wh:
        small = cv2.resize(array, size_wh, interpolation=cv2.INTER_AREA)
        return _crop_float(small, 0, size_wh[1], 0, size_wh[0])
    full = _crop_float(array, 0, h, 0, w)
    return full if (w, h) == size_wh else cv2.resize(full, size_wh, interpolation=cv2.INTER_AREA)


# ------------------------------------------------------------------- geometry


def _scale_matrix(fx: float, fy: float) -> np.ndarray:
    """Working-resolution pixel -> full-resolution pixel (pixel centres at integers, OpenCV resize convention)."""
    return np.array([[fx, 0.0, 0.5 * fx - 0.5], [0.0, fy, 0.5 * fy - 0.5], [0.0, 0.0, 1.0]])


def _translation(dx: float, dy: float) -> np.ndarray:
    return np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])


@dataclass(kw_only=True)
class _Tile:
    index: int
    core: tuple[int, int, int, int]
    """y0, y1, x0, x1 of the pixels this tile writes."""
    ext: tuple[int, int, int, int]
    """y0, y1, x0, x1 of the pixels it reads (core grown by the overlap, clipped to the frame)."""


def tile_grid(shape: tuple[int, int], tile_px: int, overlap_px: int) -> list[_Tile]:
    """Row-major tiles of at most ``tile_px`` (equal sizes, rounded) with ``overlap_px`` of context on each side."""
    h, w = shape
    ny, nx = max(1, math.ceil(h / tile_px)), max(1, math.ceil(w / tile_px))
    ys = np.linspace(0, h, ny + 1).round().astype(int)
    xs = np.linspace(0, w, nx + 1).round().astype(int)
    tiles = []
    for i in range(ny):
        for j in range(nx):
            y0, y1, x0, x1 = ys[i], ys[i + 1], xs[j], xs[j + 1]
            ext = (max(0, y0 - overlap_px), min(h, y1 + overlap_px), max(0, x0 - overlap_px), min(w, x1 + overlap_px))
            tiles.append(_Tile(index=len(tiles), core=(int(y0), int(y1), int(x0), int(x1)),
                               ext=tuple(int(v) for v in ext)))
    return tiles


@dataclass(kw_only=True)
class _Geometry:
    H_full: np.ndarray
    """3x3, full-resolution reference pixel -> full-resolution current pixel."""
    flow_work: np.ndarray | None
    """hxwx2 float32 at working resolution (working px), or None (no dense refinement)."""
    not_compared_work: np.ndarray | None
    fx: float
    fy: float
    max_flow_full: float


def _tile_maps(geom: _Geometry, ext: tuple[int, int, int, int], cur_shape: tuple[int, int]):
    """Sampling maps of one tile into the current image, through homography and upsampled flow.

    Returns (map_x, map_y) in current-image pixels (float64), ``seen`` (bool, inside the
    current image) and ``not_compared`` (bool, from the working-resolution refinement, or None).
    """
    y0, y1, x0, x1 = ext
    xs = np.arange(x0, x1, dtype=np.float64)[None, :]
    ys = np.arange(y0, y1, dtype=np.float64)[:, None]
    x = np.broadcast_to(xs, (y1 - y0, x1 - x0)).copy()
    y = np.broadcast_to(ys, (y1 - y0, x1 - x0)).copy()
    not_compared = None
    if geom.flow_work is not None:
        # Full pixel X sits at (X + 0.5) / f - 0.5 in the working grid; the flow (working px) times f.
        wx = ((xs + 0.5) / geom.fx - 0.5).astype(np.float32)
        wy = ((ys + 0.5) / geom.fy - 0.5).astype(np.float32)
        map_wx = np.broadcast_to(wx, x.shape).astype(np.float32)
        map_wy = np.broadcast_to(wy, x.shape).astype(np.float32)
        flow = cv2.remap(geom.flow_work, map_wx, map_wy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        x += flow[..., 0] * geom.fx
        y += flow[..., 1] * geom.fy
        if geom.not_compared_work is not None:
            not_compared = cv2.remap(geom.not_compared_work.astype(np.uint8), map_wx, map_wy, cv2.INTER_NEAREST,
                                     borderMode=cv2.BORDER_REPLICATE).astype(bool)
    H = geom.H_full
    den = H[2, 0] * x + H[2, 1] * y + H[2, 2]
    map_x = (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / den
    map_y = (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / den
    ch, cw = cur_shape
    seen = (den > 0) & (map_x >= 0) & (map_x <= cw - 1) & (map_y >= 0) & (map_y <= ch - 1)
    return map_x, map_y, seen, not_compared


def _warp_tile(cur: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    """Resample the current image at the tile's maps, reading (and converting to float) only the needed crop.

    Equal to :func:`warp_with_flow` on the whole image: bilinear, border reflected about
    the image's own border (the crop reaches the border on any side where a sample falls outside).
    """
    ch, cw = np.asarray(cur).shape[:2]
    finite = np.isfinite(map_x) & np.isfinite(map_y)
    if not finite.any():
        return np.zeros(map_x.shape + np.asarray(cur).shape[2:3], np.float32)
    lo_x = int(max(0, math.floor(np.nanmin(np.where(finite, map_x, np.inf))) - 2))
    hi_x = int(min(cw, math.ceil(np.nanmax(np.where(finite, map_x, -np.inf))) + 3))
    lo_y = int(max(0, math.floor(np.nanmin(np.where(finite, map_y, np.inf))) - 2))
    hi_y = int(min(ch, math.ceil(np.nanmax(np.where(finite, map_y, -np.inf))) + 3))
    if hi_x <= lo_x or hi_y <= lo_y:
        lo_x, hi_x, lo_y, hi_y = 0, min(cw, 2), 0, min(ch, 2)
    src = _crop_float(cur, lo_y, hi_y, lo_x, hi_x)
    mx = np.where(finite, map_x - lo_x, -1e6).astype(np.float32)
    my = np.where(finite, map_y - lo_y, -1e6).astype(np.float32)
    # Any sample outside the image lies beyond a side the crop reaches (it holds every
    # sample inside, plus 2 px), so reflecting about the crop's edge is reflecting about the image's.
    return cv2.remap(src, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


# --------------------------------------------------------------------- cues


def _lighting_difference(ref: np.ndarray, warped: np.ndarray, *, gain_sigma_px: float, shift_radius_px: int,
                         weight: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """One lighting of one tile: local-gain normalisation, then the difference cue (as ``score._fuse``)."""
    normalized = normalize_local_gain(ref, warped, sigma_px=gain_sigma_px, weight=weight)
    return shift_tolerant_difference(ref, normalized, radius_px=shift_radius_px), normalized


# --------------------------------------------------------------------- main


def detect_changes_tiled(
    ref_images: Sequence[np.ndarray],
    cur_images: Sequence[np.ndarray],
    *,
    eval_mask: np.ndarray | None = None,
    pixel_area_mm2: np.ndarray | None = None,
    tile_px: int = 2048,
    overlap_px: int | None = None,
    work_px: int = 1600,
    workers: int = 2,
    progress: Progress | None = None,
    register: bool = True,
    gain_sigma_px: float = 12.0,
    shift_radius_px: int = 1,
    smooth_sigma_px: float = 2.0,
    k_high: float = 20.0,
    k_low: float = 10.0,
    min_region_px: int = 30,
    max_hole_px: int = 30,
    registration_lighting: int = 0,
    robust_gain_rounds: int = 1,
    edge_fraction: float = 0.2,
    edge_radius_px: int = 6,
    decision: str = "acontrario",
    epsilon: float = 1.0,
    seed_p: float = 0.005,
    extent_fraction: float = 0.3,
    decision_px: int = 1000,
    dense: bool = True,
    cues: bool = True,
    ambient_index: int | None = 0,
    light_dirs: np.ndarray | None = None,
) -> ChangeResult:
    """:func:`fgcd_cli.changes.detect.detect_changes` for large frames, in bounded memory.

    Parameters
    ----------
    ref_images, cur_images : sequences of ndarray, HxW or HxWx3, uint8 (best), uint16 or float in [0, 1]
        One image per lighting, as for ``detect_changes``. They are never converted
        as a whole: keep them 8-bit (:func:`load_images`) to bound the memory.
    eval_mask, pixel_area_mm2 : as for ``detect_changes`` (full resolution).
    tile_px : int
        Largest tile side, pixels (the frame is cut into equal tiles of at most this side).
    overlap_px : int, optional
        Context read around each tile. Default ``ceil(3 * 4 * gain_sigma_px) + shift_radius_px + 2``:
        three sigma of the wide gain window that the gain normalisation falls back to
        next to large changes (and so far beyond the 12 px window it normally uses).
    work_px : int
        Long side of the working resolution for registration, dense refinement and
        photometric cue labels (frames smaller than that are processed as they are).
    decision_px : int
        Long side at which the a-contrario scan runs (score area-averaged; its seeds
        are grown to their extent on the full-resolution score). Frames up to that
        size are scanned as they are, exactly as by ``detect_changes``.
    workers : int
        Threads over tiles (OpenCV and numpy release the GIL in the heavy parts).
    progress : callable ``progress(done, total, label)``, optional
        Called after every tile of every pass (``label`` names the pass and the tile),
        and once per whole-frame stage.
    Other parameters : as for ``detect_changes``.

    Returns
    -------
    ChangeResult
        ``current_registered`` is left empty (it would be a full-size float stack);
        ``dense`` and ``cue_maps`` are at the working resolution
        (``settings["work_scale"]`` gives the factor).
    """
    if decision not in ("hysteresis", "acontrario"):
        raise UserInputError(f"unknown decision rule {decision!r}: use hysteresis or acontrario")
    if tile_px < 64:
        raise UserInputError(f"tile size {tile_px} px is too small (at least 64 px)")
    shape, _ = _check_stacks(ref_images, cur_images)
    h, w = shape
    n = len(ref_images)
    if eval_mask is not None:
        eval_mask = np.asarray(eval_mask).astype(bool)
        if eval_mask.shape != shape:
            raise UserInputError(f"evaluation mask is {eval_mask.shape[1]}x{eval_mask.shape[0]} px, images are {w}x{h} px")
    if pixel_area_mm2 is not None and np.asarray(pixel_area_mm2).shape != shape:
        raise UserInputError("pixel area map must have the reference image's size")
    if not 0 <= registration_lighting < n:
        raise UserInputError(f"registration lighting {registration_lighting} out of range 0..{n - 1}")
    if overlap_px is None:
        overlap_px = int(math.ceil(3 * 4 * gain_sigma_px)) + shift_radius_px + 2
    scale = max(1.0, max(h, w) / float(work_px))
    ws, hs = max(2, int(round(w / scale))), max(2, int(round(h / scale)))
    fx, fy = w / ws, h / hs
    tiles = tile_grid(shape, tile_px, overlap_px)
    passes = 1 + max(0, robust_gain_rounds)
    # Progress units: the working-resolution stage, each tile of each gain pass, the decision.
    total = 1 + len(tiles) * passes + 1
    done = [0]

    def report(label: str, *, units: int = 1) -> None:
        done[0] += units
        if progress is not None:
            progress(min(done[0], total), total, label)

    settings = {
        "lightings": n, "gain_sigma_px": gain_sigma_px, "shift_radius_px": shift_radius_px,
        "structure_weight": 0.0, "smooth_sigma_px": smooth_sigma_px, "k_high": k_high, "k_low": k_low,
        "min_region_px": min_region_px, "max_hole_px": max_hole_px, "registration_lighting": registration_lighting,
        "robust_gain_rounds_max": robust_gain_rounds, "edge_fraction": edge_fraction, "edge_radius_px": edge_radius_px,
        "edge_tolerance_px": 0, "edge_check_px": 0, "shading_normalization": False, "decision": decision,
        "epsilon": epsilon, "seed_p": seed_p, "extent_fraction": extent_fraction, "dense": dense,
        "tiled": {"tile_px": tile_px, "overlap_px": overlap_px, "tiles": len(tiles), "workers": workers,
                  "medians": "global (all compared pixels of the frame)"},
        "work_scale": float(max(fx, fy)), "work_size_wh": [ws, hs],
    }

    # ---- working resolution: health, registration, dense parallax -----------------------
    refs_small = [_downscale_float(im, (ws, hs)) for im in ref_images]
    curs_small = [_downscale_float(im, (ws, hs)) for im in cur_images]
    gray = lambda im: im if im.ndim == 2 else im.mean(axis=2).astype(np.float32)  # noqa: E731 (as images.to_gray)
    grays_ref = [gray(im) for im in refs_small]
    grays_cur = [gray(im) for im in curs_small]
    for label, grays in (("reference", grays_ref), ("current", grays_cur)):
        for i, g in enumerate(grays):
            problem = image_health(g)
            if problem:
                report("checked", units=total)
                return empty_result(shape, f"cannot compare: {label} image {i + 1}: {problem}", None, settings)
    mask_small = None
    if eval_mask is not None:
        mask_small = cv2.resize(eval_mask.astype(np.uint8), (ws, hs), interpolation=cv2.INTER_NEAREST).astype(bool)
    if register:
        reg_small = register_to_reference(grays_ref[registration_lighting], grays_cur[registration_lighting])
        if not reg_small.ok:
            report("registration failed", units=total)
            return empty_result(shape, f"cannot compare: {reg_small.reason}", None, settings)
    else:
        reg_small = Registration(H_cur_ref=np.eye(3), ok=True, init="none", overlap_fraction=1.0)
    A = _scale_matrix(fx, fy)
    H_full = A @ reg_small.H_cur_ref @ np.linalg.inv(A)
    H_full = H_full / H_full[2, 2]
    registration = Registration(H_cur_ref=H_full, ok=reg_small.ok, reason=reg_small.reason,
                                ecc_correlation=reg_small.ecc_correlation, overlap_fraction=reg_small.overlap_fraction,
                                sift_inliers=reg_small.sift_inliers, init=reg_small.init,
                                settings=dict(reg_small.settings, resolution=f"{ws}x{hs} (area-downscaled), "
                                              f"conjugated to {w}x{h}"))
    area_small = np.ones((hs, ws), bool) if mask_small is None else mask_small
    dense_fit = None
    if dense:
        warped_gray, seen_small = warp_to_reference(grays_cur[registration_lighting], reg_small.H_cur_ref, (hs, ws))
        dense_fit = refine_dense(grays_ref[registration_lighting], warped_gray, valid=area_small & seen_small)
    geom = _Geometry(H_full=H_full, flow_work=None if dense_fit is None else dense_fit.flow,
                     not_compared_work=None if dense_fit is None else dense_fit.not_compared,
                     fx=fx, fy=fy, max_flow_full=0.0 if dense_fit is None else dense_fit.max_flow_px * max(fx, fy))
    del grays_cur
    report("registered (working resolution)")

    # ---- tiles: per-lighting difference maps, in gain passes --------------------------
    margin_px = int(np.ceil(max(shift_radius_px, smooth_sigma_px * 2)))
    seen_all = np.zeros(shape, bool)
    not_compared = np.zeros(shape, bool) if dense else None
    differences = [np.zeros(shape, np.float16) for _ in range(n)]

    def run_pass(pass_index: int, weight_map: np.ndarray | None) -> None:
        def one(tile: _Tile) -> _Tile:
            y0, y1, x0, x1 = tile.ext
            cy0, cy1, cx0, cx1 = tile.core
            core = (slice(cy0 - y0, cy1 - y0), slice(cx0 - x0, cx1 - x0))
            map_x, map_y, seen, nc = _tile_maps(geom, tile.ext, shape)
            if pass_index == 0:
                seen_all[cy0:cy1, cx0:cx1] = seen[core]
                if nc is not None:
                    not_compared[cy0:cy1, cx0:cx1] = nc[core]
            weight = None if weight_map is None else weight_map[y0:y1, x0:x1].astype(np.float32)
            for k in range(n):
                ref = _crop_float(ref_images[k], y0, y1, x0, x1)
                warped = _warp_tile(cur_images[k], map_x, map_y)
                diff, _ = _lighting_difference(ref, warped, gain_sigma_px=gain_sigma_px,
                                               shift_radius_px=shift_radius_px, weight=weight)
                differences[k][cy0:cy1, cx0:cx1] = diff[core]
            return tile

        label = "gain pass" if pass_index == 0 else f"robust gain round {pass_index}"
        if workers > 1 and len(tiles) > 1:
            with ThreadPoolExecutor(max_workers=workers) as pool:
                # map() yields in submission order: progress is reported tile by tile, in order.
                for tile in pool.map(one, tiles):
                    report(f"{label}: tile {tile.index + 1}/{len(tiles)}")
        else:
            for tile in tiles:
                one(tile)
                report(f"{label}: tile {tile.index + 1}/{len(tiles)}")

    def fuse(valid: np.ndarray) -> tuple[np.ndarray, list[float]]:
        # Global null model: each lighting's cue over its median on every compared pixel of the frame.
        medians = [float(np.median(d[valid].astype(np.float32))) if valid.any() else 0.0 for d in differences]
        fused = np.zeros(shape, np.float32)
        for d, m in zip(differences, medians):
            cv2.scaleAdd(d.astype(np.float32), 1.0 / (n * (m + (1e-6 if m <= 0 else 0.0) + 1e-12)), fused, dst=fused)
        if smooth_sigma_px > 0:
            fused = cv2.GaussianBlur(fused, (0, 0), smooth_sigma_px)
        fused[~valid] = 0.0
        return fused, medians

    run_pass(0, None)
    area = np.ones(shape, bool) if eval_mask is None else eval_mask
    valid = area & seen_all
    if not_compared is not None:
        not_compared &= area
        valid &= ~not_compared
    if margin_px > 0:
        valid = cv2.erode(valid.astype(np.uint8), np.ones((2 * margin_px + 1, 2 * margin_px + 1), np.uint8)).astype(bool)
    if valid.sum() < 100:
        report("nothing to compare", units=total - done[0])
        return empty_result(shape, "cannot compare: fewer than 100 pixels are seen in both images", registration, settings)
    score, medians = fuse(valid)
    # Robust gain rounds (as score.score_pair, on the full frame): the suspect set is
    # decided by the whole frame's threshold, the gain re-estimated without it.
    gain_weight = None
    rounds = 0
    for r in range(robust_gain_rounds):
        _, first = robust_hysteresis_threshold(score, valid, k_high=k_high, k_low=k_low)
        suspect = (score > first.low) & valid
        if suspect.mean() > 0.5 * valid.mean():
            break
        suspect = cv2.dilate(suspect.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        new_weight = seen_all & ~suspect
        if rounds and np.array_equal(new_weight, gain_weight):
            break
        gain_weight = new_weight
        run_pass(r + 1, gain_weight)
        score, medians = fuse(valid)
        rounds += 1
    done[0] = 1 + len(tiles) * passes  # rounds skipped by the early exits
    settings["robust_gain_rounds"] = rounds
    del differences, gain_weight

    # ---- decision on the full frame (as detect_changes) ---------------------------------
    raw_mask, threshold = robust_hysteresis_threshold(score, valid, k_high=k_high, k_low=k_low)
    significance = _significance_coarse(score, valid, decision_px=decision_px, epsilon=epsilon, seed_p=seed_p,
                                        extent_fraction=extent_fraction, smooth_sigma_px=smooth_sigma_px)
    settings["significance_scale"] = significance.settings.get("scale", 1.0)
    if decision == "acontrario":
        # Seeds found at the decision resolution, grown to their extent on the full-resolution score.
        if significance.settings["scale"] == 1.0 or significance.seed_index is None:
            raw_mask = significance.mask
        else:
            raw_mask = grow_to_extent(significance.seed_index > 0, score, valid, background=threshold.median,
                                      fraction=extent_fraction)
    else:
        raw_mask = refine_to_local_peak(raw_mask, score, background=threshold.median, fraction=edge_fraction,
                                        radius_px=edge_radius_px)
    mask = clean_mask(raw_mask, min_region_px=min_region_px, max_hole_px=max_hole_px) & valid
    del raw_mask
    regions, labels = regions_with_significance(mask, score, significance, pixel_area_mm2)

    cue_maps = None
    if cues:
        cue_maps = _cue_labels_small(refs_small, curs_small, regions, labels, valid, reg_small, dense_fit,
                                     gain_sigma_px=gain_sigma_px / max(fx, fy), smooth_sigma_px=smooth_sigma_px,
                                     ambient_index=ambient_index, light_dirs=light_dirs, fx=fx, fy=fy)
        settings["cues"] = (cue_maps.reason or "relief and colour (photometric stereo)") + f", at {ws}x{hs}"
    report("decided")
    return ChangeResult(
        comparable=True, score=score, mask=mask, labels=labels, valid=valid, regions=regions,
        registration=registration, threshold=threshold, current_registered=[], settings=settings,
        warnings=result_warnings(mask, valid, registration, register=register), edge_explained=None,
        candidates=sorted((c for c in significance.candidates + significance.regions
                           if not mask[int(round(c.centroid_xy[1])), int(round(c.centroid_xy[0]))]),
                          key=lambda c: c.log10_nfa)[:5],
        not_compared=not_compared, dense=dense_fit, cue_maps=cue_maps,
    )


def _cue_labels_small(refs_small, curs_small, regions, labels, valid, reg_small, dense_fit, *, gain_sigma_px,
                      smooth_sigma_px, ambient_index, light_dirs, fx, fy):
    """Relief / colour label per region from photometric stereo at the working resolution."""
    hs, ws = refs_small[0].shape[:2]
    normalized = []
    for ref, cur in zip(refs_small, curs_small):
        if dense_fit is not None:
            warped, _ = warp_with_flow(cur, reg_small.H_cur_ref, dense_fit.flow)
        else:
            warped, _ = warp_to_reference(cur, reg_small.H_cur_ref, (hs, ws))
        normalized.append(np.clip(normalize_local_gain(ref, warped, sigma_px=max(gain_sigma_px, 1.0)), 0.0, 1.0))
    # A working pixel is compared when most of the full pixels it covers are.
    valid_small = cv2.resize(valid.astype(np.float32), (ws, hs), interpolation=cv2.INTER_AREA) > 0.5
    labels_small = cv2.resize(labels, (ws, hs), interpolation=cv2.INTER_NEAREST)
    for region in regions:  # a region narrower than a working pixel keeps its centroid pixel
        if not (labels_small == region.id).any():
            cx, cy = region.centroid_xy
            labels_small[min(hs - 1, int((cy + 0.5) / fy)), min(ws - 1, int((cx + 0.5) / fx))] = region.id
    cue_maps = relief_colour_cues(refs_small, normalized, valid=valid_small, ambient_index=ambient_index,
                                  light_dirs=light_dirs)
    label_regions(regions, labels_small, cue_maps, valid=valid_small | (labels_small > 0),
                  smooth_sigma_px=max(smooth_sigma_px / max(fx, fy), 0.5))
    return cue_maps


def _significance_coarse(score, valid, *, decision_px, epsilon, seed_p, extent_fraction, smooth_sigma_px):
    """The a-contrario scan on the score area-averaged to ``decision_px`` (long side), seeds mapped back.

    The scan's cost grows faster than the pixel count (one labelling per level and
    per round: 39 s at 4.4 MP); at the decision resolution it stays a few seconds.
    Its meaning is kept: the number of tests is ``N / A`` times the levels, and both
    the compared pixels ``N`` and the cluster area ``A`` shrink by the same factor.
    Returns a :class:`Decision` whose ``seed_index`` is at full resolution and whose
    regions' centroids and areas are in full-resolution pixels.
    """
    h, w = score.shape
    scale = max(1.0, max(h, w) / float(decision_px))
    if scale <= 1.0:
        result = acontrario_decision(score, valid, epsilon=epsilon, seed_p=seed_p, extent_fraction=extent_fraction,
                                     min_cluster_area_px=4.0 * np.pi * smooth_sigma_px**2)
        result.settings["scale"] = 1.0
        return result
    ws, hs = max(2, int(round(w / scale))), max(2, int(round(h / scale)))
    fx, fy = w / ws, h / hs
    coverage = cv2.resize(valid.astype(np.float32), (ws, hs), interpolation=cv2.INTER_AREA)
    small = cv2.resize(np.where(valid, score, 0.0).astype(np.float32), (ws, hs), interpolation=cv2.INTER_AREA)
    small_valid = coverage > 0.5
    small = np.where(small_valid, small / np.maximum(coverage, 1e-6), 0.0).astype(np.float32)
    # Correlation area of the smoothing at this scale, at least one pixel.
    sigma = smooth_sigma_px / max(fx, fy)
    result = acontrario_decision(small, small_valid, epsilon=epsilon, seed_p=seed_p, extent_fraction=extent_fraction,
                                 min_cluster_area_px=max(1.0, 4.0 * np.pi * sigma**2))
    seed_index = np.zeros((h, w), np.int32)
    if result.seed_index is not None:
        seed_index = cv2.resize(result.seed_index.astype(np.int32), (w, h), interpolation=cv2.INTER_NEAREST)

    def up(region):
        cx, cy = region.centroid_xy
        return replace(region, centroid_xy=(fx * (cx + 0.5) - 0.5, fy * (cy + 0.5) - 0.5),
                       area_px=int(round(region.area_px * fx * fy)))

    return replace(result, seed_index=seed_index, regions=[up(r) for r in result.regions],
                   candidates=[up(r) for r in result.candidates], cluster_area_px=result.cluster_area_px * fx * fy,
                   settings=dict(result.settings, scale=float(max(fx, fy)),
                                 resolution=f"{ws}x{hs} (score area-averaged)"))
