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

import ctypes
import math
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, replace
from functools import lru_cache, partial
from pathlib import Path

import cv2
import numpy as np
from scipy import ndimage

from fgcd_cli.changes.cue_labels import label_regions, relief_colour_cues
from fgcd_cli.changes.dense import refine_dense, warp_with_flow
from fgcd_cli.changes.cues import shift_tolerant_difference
from fgcd_cli.changes.detect import ChangeResult, empty_result, regions_with_significance, result_warnings
from fgcd_cli.changes.illumination import normalize_local_gain, prepare_gain_weight
from fgcd_cli.changes.images import image_health
from fgcd_cli.changes.regions import ChangeRegion, clean_mask, refine_to_local_peak
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
        out = crop.astype(np.float32)
        out /= np.float32(np.iinfo(crop.dtype).max)  # bit-identical to to_float_image
        return out
    return np.clip(np.nan_to_num(crop.astype(np.float32), nan=0.0), 0.0, 1.0)


def _downscale(image: np.ndarray, size_wh: tuple[int, int]) -> np.ndarray:
    """Area-averaged version of a whole image at ``size_wh``: 8-bit stays 8-bit, others become float32 [0, 1].

    8-bit images are averaged as they are (the result is rounded to 1/255, far below
    what registration and the photometric cues resolve); others through one float
    copy. :func:`_as_float` gives the float32 [0, 1] image either way.
    """
    array = np.asarray(image)
    h, w = array.shape[:2]
    if array.dtype == np.uint8:
        return array if (w, h) == size_wh else cv2.resize(array, size_wh, interpolation=cv2.INTER_AREA)
    full = _crop_float(array, 0, h, 0, w)
    return full if (w, h) == size_wh else cv2.resize(full, size_wh, interpolation=cv2.INTER_AREA)


def _as_float(small: np.ndarray) -> np.ndarray:
    """float32 [0, 1] version of a :func:`_downscale` result (as :func:`to_float_image` converts)."""
    return _crop_float(small, 0, small.shape[0], 0, small.shape[1]) if small.dtype == np.uint8 else small


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


@dataclass(kw_only=True)
class _Sampling:
    """Where one tile reads the current image: computed once per tile, shared by all its lightings."""

    shape: tuple[int, int]
    """Height and width of the pixels the tile reads."""
    box: tuple[int, int, int, int] | None
    """lo_y, hi_y, lo_x, hi_x of the crop of the current image that holds every sample (None: no finite sample)."""
    map_x: np.ndarray | None
    """float32 sampling maps relative to the crop (-1e6 where the sample is not finite)."""
    map_y: np.ndarray | None
    seen: np.ndarray
    not_compared: np.ndarray | None


_MAP_ROWS = 64
"""Rows of a tile whose sampling maps are computed at a time (their float64 temporaries then stay in cache)."""


def _tile_maps_in_bands(geom: _Geometry, ext: tuple[int, int, int, int], cur_shape: tuple[int, int]):
    """:func:`_tile_maps` of a whole tile, computed band of rows by band of rows (the same values, faster)."""
    y0, y1, x0, x1 = ext
    shape = (y1 - y0, x1 - x0)
    map_x, map_y, seen = np.empty(shape), np.empty(shape), np.empty(shape, bool)
    not_compared = None
    for b0 in range(y0, y1, _MAP_ROWS):
        b1 = min(y1, b0 + _MAP_ROWS)
        rows = slice(b0 - y0, b1 - y0)
        map_x[rows], map_y[rows], seen[rows], band_not_compared = _tile_maps(geom, (b0, b1, x0, x1), cur_shape)
        if band_not_compared is not None:
            if not_compared is None:
                not_compared = np.empty(shape, bool)
            not_compared[rows] = band_not_compared
    return map_x, map_y, seen, not_compared


def _sampling(geom: _Geometry, ext: tuple[int, int, int, int], cur_shape: tuple[int, int]) -> _Sampling:
    """The tile's maps (:func:`_tile_maps`) and the crop of the current image they read."""
    map_x, map_y, seen, not_compared = _tile_maps_in_bands(geom, ext, cur_shape)
    ch, cw = cur_shape
    shape = map_x.shape
    finite = np.isfinite(map_x) & np.isfinite(map_y)
    if not finite.any():
        return _Sampling(shape=shape, box=None, map_x=None, map_y=None, seen=seen, not_compared=not_compared)
    everywhere = bool(finite.all())
    lo_x = int(max(0, math.floor(map_x.min() if everywhere else np.nanmin(np.where(finite, map_x, np.inf))) - 2))
    hi_x = int(min(cw, math.ceil(map_x.max() if everywhere else np.nanmax(np.where(finite, map_x, -np.inf))) + 3))
    lo_y = int(max(0, math.floor(map_y.min() if everywhere else np.nanmin(np.where(finite, map_y, np.inf))) - 2))
    hi_y = int(min(ch, math.ceil(map_y.max() if everywhere else np.nanmax(np.where(finite, map_y, -np.inf))) + 3))
    if hi_x <= lo_x or hi_y <= lo_y:
        lo_x, hi_x, lo_y, hi_y = 0, min(cw, 2), 0, min(ch, 2)
    if everywhere:
        map_x -= lo_x
        map_y -= lo_y
        mx, my = map_x.astype(np.float32), map_y.astype(np.float32)
    else:
        mx = np.where(finite, map_x - lo_x, -1e6).astype(np.float32)
        my = np.where(finite, map_y - lo_y, -1e6).astype(np.float32)
    return _Sampling(shape=shape, box=(lo_y, hi_y, lo_x, hi_x), map_x=mx, map_y=my, seen=seen,
                     not_compared=not_compared)


def _warp_tile(cur: np.ndarray, sampling: _Sampling) -> np.ndarray:
    """Resample the current image at the tile's maps, reading (and converting to float) only the needed crop.

    Equal to :func:`warp_with_flow` on the whole image: bilinear, border reflected about
    the image's own border (the crop reaches the border on any side where a sample falls outside).
    """
    if sampling.box is None:
        return np.zeros(sampling.shape + np.asarray(cur).shape[2:3], np.float32)
    src = _crop_float(cur, *sampling.box)
    # Any sample outside the image lies beyond a side the crop reaches (it holds every
    # sample inside, plus 2 px), so reflecting about the crop's edge is reflecting about the image's.
    return cv2.remap(src, sampling.map_x, sampling.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


# ------------------------------------------------------------ tile scheduling


def _release_free_memory() -> None:
    """Hand the heap memory freed so far back to the system (glibc's ``malloc_trim``; elsewhere a no-op).

    glibc keeps freed blocks of up to 32 MB (the size of a tile's planes and of the
    working-resolution images) in its heaps, one per thread, so the resident memory
    of a stage includes what the previous stages freed; trimming between stages
    keeps the peak at what is live.
    """
    trim = getattr(_libc(), "malloc_trim", None)
    if trim is not None:
        trim(0)


@lru_cache(maxsize=1)
def _libc():
    try:
        return ctypes.CDLL(None)
    except OSError:
        return None


@contextmanager
def _opencv_threads(count: int | None):
    """Run a block with OpenCV's own thread pool at ``count`` threads (None: as it is), then restore it.

    While Python threads already keep every core busy, OpenCV's threads only add switching.
    """
    if count is None:
        yield
        return
    before = cv2.getNumThreads()
    cv2.setNumThreads(count)
    try:
        yield
    finally:
        cv2.setNumThreads(before)


def _median_float16(values: np.ndarray) -> float:
    """``np.median(values.astype(np.float32))`` of a 1-D float16 array, by counting its 2^16 bit patterns."""
    bits = values.view(np.uint16)
    if bits.size == 0 or int(bits.max()) >= 0x7C00:  # negative, infinite or NaN values: sort them
        return float(np.median(values.astype(np.float32)))
    cumulative = np.cumsum(np.bincount(bits))
    half = bits.size // 2

    def value_at(rank: int) -> np.float32:  # the rank-th smallest value (0-based)
        return np.uint16(np.searchsorted(cumulative, rank, side="right")).view(np.float16).astype(np.float32)

    if bits.size % 2:
        return float(value_at(half))
    return float(np.mean(np.array([value_at(half - 1), value_at(half)], np.float32)))


def _run_tiles(tiles: list[_Tile], n: int, prepare: Callable, work: Callable, finished: Callable,
               workers: int) -> None:
    """Run ``work(tile, context, k)`` for every lighting ``k`` of every tile, ``context = prepare(tile)``.

    Work is spread over ``workers`` threads lighting by lighting (a tile's lightings
    run side by side), and ``finished(tile)`` is called tile by tile, in order. A
    tile's context is prepared once, when its turn comes, and dropped when its
    lightings are done, so at most about one tile per worker is in memory.
    """
    if workers <= 1 or len(tiles) * n <= 1:
        for tile in tiles:
            context = prepare(tile)
            for k in range(n):
                work(tile, context, k)
            del context
            finished(tile)
        return
    with _opencv_threads(1), ThreadPoolExecutor(max_workers=workers) as pool:
        # The pool takes jobs in submission order: a tile's preparation is under way
        # before any of its lightings waits for it, so a waiting worker never deadlocks.
        pending = []
        for tile in tiles:
            context = pool.submit(prepare, tile)
            jobs = [pool.submit(lambda t, c, k: work(t, c.result(), k), tile, context, k) for k in range(n)]
            pending.append((tile, jobs))
            del context
        try:
            for i, (tile, jobs) in enumerate(pending):
                for job in jobs:
                    job.result()
                pending[i] = None
                finished(tile)
        except BaseException:
            pool.shutdown(wait=True, cancel_futures=True)
            raise


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
    small = _working_resolution(ref_images, cur_images, (ws, hs), eval_mask=eval_mask, register=register,
                                dense=dense, registration_lighting=registration_lighting, workers=workers)
    if isinstance(small, tuple):
        report(small[0], units=total)
        return empty_result(shape, small[1], None, settings)
    reg_small = small.registration
    A = _scale_matrix(fx, fy)
    H_full = A @ reg_small.H_cur_ref @ np.linalg.inv(A)
    H_full = H_full / H_full[2, 2]
    registration = Registration(H_cur_ref=H_full, ok=reg_small.ok, reason=reg_small.reason,
                                ecc_correlation=reg_small.ecc_correlation, overlap_fraction=reg_small.overlap_fraction,
                                sift_inliers=reg_small.sift_inliers, init=reg_small.init,
                                settings=dict(reg_small.settings, resolution=f"{ws}x{hs} (area-downscaled), "
                                              f"conjugated to {w}x{h}"))
    dense_fit = small.dense_fit
    geom = _Geometry(H_full=H_full, flow_work=None if dense_fit is None else dense_fit.flow,
                     not_compared_work=None if dense_fit is None else dense_fit.not_compared,
                     fx=fx, fy=fy, max_flow_full=0.0 if dense_fit is None else dense_fit.max_flow_px * max(fx, fy))
    report("registered (working resolution)")

    # ---- tiles: per-lighting difference maps, in gain passes --------------------------
    tiled = _TiledScore(ref_images, cur_images, geom, tiles, eval_mask=eval_mask, dense=dense, workers=workers,
                        gain_sigma_px=gain_sigma_px, shift_radius_px=shift_radius_px, smooth_sigma_px=smooth_sigma_px,
                        report=report)
    tiled.run_pass(0, None)
    valid = tiled.valid()
    if valid.sum() < 100:
        report("nothing to compare", units=total - done[0])
        return empty_result(shape, "cannot compare: fewer than 100 pixels are seen in both images", registration, settings)
    score = tiled.fuse(valid)
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
        new_weight = tiled.seen_all & ~suspect
        if rounds and np.array_equal(new_weight, gain_weight):
            break
        gain_weight = new_weight
        del score, suspect
        tiled.run_pass(r + 1, gain_weight)
        score = tiled.fuse(valid)
        rounds += 1
    done[0] = 1 + len(tiles) * passes  # rounds skipped by the early exits
    settings["robust_gain_rounds"] = rounds
    not_compared = tiled.not_compared
    del tiled, gain_weight

    # ---- decision on the full frame (as detect_changes); cue maps alongside ------------
    # One thread beside the decision: the cue maps (photometric stereo), then the threshold.
    cue_job = None
    if cues:
        cue_job = partial(_cue_maps_small, small, valid, dense_fit, gain_sigma_px=gain_sigma_px / max(fx, fy),
                          ambient_index=ambient_index, light_dirs=light_dirs)
    with _opencv_threads(1 if workers > 1 else None), ThreadPoolExecutor(max_workers=1) as aside:
        mask, regions, labels, threshold, significance, cue_maps = _decide(
            score, valid, aside, cue_job, pixel_area_mm2=pixel_area_mm2, decision=decision, k_high=k_high,
            k_low=k_low, epsilon=epsilon, seed_p=seed_p, extent_fraction=extent_fraction, decision_px=decision_px,
            smooth_sigma_px=smooth_sigma_px, edge_fraction=edge_fraction, edge_radius_px=edge_radius_px,
            min_region_px=min_region_px, max_hole_px=max_hole_px)
        settings["significance_scale"] = significance.settings.get("scale", 1.0)
        if cue_maps is not None:
            cue_maps, valid_small = cue_maps.result()
            _label_cues(cue_maps, valid_small, regions, labels, (ws, hs), smooth_sigma_px=smooth_sigma_px, fx=fx, fy=fy)
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


# ------------------------------------------------------------- working resolution


@dataclass(kw_only=True)
class _Small:
    """The stacks at the working resolution (8-bit kept 8-bit) and what was estimated there."""

    refs: list[np.ndarray]
    curs: list[np.ndarray]
    registration: Registration
    dense_fit: object | None


def _working_resolution(ref_images, cur_images, size_wh, *, eval_mask, register, dense, registration_lighting,
                        workers) -> _Small | tuple[str, str]:
    """Downscale the stacks, check them, register and refine at the working resolution.

    Returns ``(progress label, reason)`` when the pair cannot be compared.
    """
    ws, hs = size_wh
    images = list(ref_images) + list(cur_images)
    n = len(ref_images)
    pair = (registration_lighting, n + registration_lighting)

    def prepare(image):  # resizing and numpy release the GIL
        small = _downscale(image, size_wh)
        gray = _gray(_as_float(small))
        return small, gray, image_health(gray)

    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
        # The registration pair first: it registers here while the pool prepares the
        # other images. Any image's problem is reported before the registration's.
        order = list(pair) + [i for i in range(2 * n) if i not in pair]
        jobs = dict(zip(order, (pool.submit(prepare, images[i]) for i in order)))
        (_, gray_ref, problem_ref), (_, gray_cur, problem_cur) = jobs[pair[0]].result(), jobs[pair[1]].result()
        reg_small = Registration(H_cur_ref=np.eye(3), ok=True, init="none", overlap_fraction=1.0)
        if register and not (problem_ref or problem_cur):
            reg_small = register_to_reference(gray_ref, gray_cur)
        smalls = []
        for i in range(2 * n):
            small, _, problem = jobs.pop(i).result()
            if problem:
                label, index = ("reference", i + 1) if i < n else ("current", i - n + 1)
                return "checked", f"cannot compare: {label} image {index}: {problem}"
            smalls.append(small)
    if not reg_small.ok:
        return "registration failed", f"cannot compare: {reg_small.reason}"
    dense_fit = None
    if dense:
        area_small = np.ones((hs, ws), bool)
        if eval_mask is not None:
            area_small = cv2.resize(eval_mask.astype(np.uint8), (ws, hs), interpolation=cv2.INTER_NEAREST).astype(bool)
        warped_gray, seen_small = warp_to_reference(gray_cur, reg_small.H_cur_ref, (hs, ws))
        dense_fit = refine_dense(gray_ref, warped_gray, valid=area_small & seen_small)
    return _Small(refs=smalls[:n], curs=smalls[n:], registration=reg_small, dense_fit=dense_fit)


def _gray(image: np.ndarray) -> np.ndarray:
    """Channel mean, as :func:`fgcd_cli.changes.images.to_gray` (``image.mean(axis=2)``, the same float32 sums)."""
    if image.ndim == 2:
        return image
    if image.shape[2] == 3 and image.dtype == np.float32:  # numpy's reduction over a last axis of 3 is ~4x slower
        return (image[:, :, 0] + image[:, :, 1] + image[:, :, 2]) / np.float32(3)
    return image.mean(axis=2).astype(np.float32)


# ---------------------------------------------------------------------- tiles


class _TiledScore:
    """The per-lighting difference maps of the whole frame, computed tile by tile, and their fusion."""

    def __init__(self, ref_images, cur_images, geom: _Geometry, tiles: list[_Tile], *, eval_mask, dense, workers,
                 gain_sigma_px, shift_radius_px, smooth_sigma_px, report):
        self.refs, self.curs, self.geom, self.tiles = ref_images, cur_images, geom, tiles
        self.shape = np.asarray(ref_images[0]).shape[:2]
        self.eval_mask, self.workers, self.report = eval_mask, workers, report
        self.gain_sigma_px, self.shift_radius_px, self.smooth_sigma_px = gain_sigma_px, shift_radius_px, smooth_sigma_px
        self.seen_all = np.zeros(self.shape, bool)
        self.not_compared = np.zeros(self.shape, bool) if dense else None
        self.differences = [np.zeros(self.shape, np.float16) for _ in ref_images]
        first = np.asarray(ref_images[0])
        self.grey = first.ndim == 2 or first.shape[2] == 1

    def _read_box(self, tile: _Tile, pass_index: int) -> tuple[int, int, int, int]:
        """Pixels a tile reads in a pass: its overlap in the robust rounds (the wide gain window
        reaches that far), only the narrow gain window's and the shift's reach in the first pass."""
        if pass_index > 0:
            return tile.ext
        (cy0, cy1, cx0, cx1), (y0, y1, x0, x1) = tile.core, tile.ext
        reach = (int(round(self.gain_sigma_px * 8 + 1)) | 1) // 2 + self.shift_radius_px
        return max(y0, cy0 - reach), min(y1, cy1 + reach), max(x0, cx0 - reach), min(x1, cx1 + reach)

    def run_pass(self, pass_index: int, weight_map: np.ndarray | None) -> None:
        """One gain pass over every tile and lighting (``weight_map``: the robust rounds' gain weight).

        Each tile reads :meth:`_read_box` and writes its core. The gain is wanted on the
        core and the shift's reach around it only (``region``, relative to the box).
        """
        label = "gain pass" if pass_index == 0 else f"robust gain round {pass_index}"
        r = self.shift_radius_px

        def prepare(tile: _Tile):
            y0, y1, x0, x1 = box = self._read_box(tile, pass_index)
            cy0, cy1, cx0, cx1 = tile.core
            sampling = _sampling(self.geom, box, self.shape)
            if pass_index == 0:
                core = (slice(cy0 - y0, cy1 - y0), slice(cx0 - x0, cx1 - x0))
                self.seen_all[cy0:cy1, cx0:cx1] = sampling.seen[core]
                if sampling.not_compared is not None and self.not_compared is not None:
                    self.not_compared[cy0:cy1, cx0:cx1] = sampling.not_compared[core]
            sampling.seen = sampling.not_compared = None
            region = (slice(max(y0, cy0 - r) - y0, min(y1, cy1 + r) - y0),
                      slice(max(x0, cx0 - r) - x0, min(x1, cx1 + r) - x0))
            weight = None
            if weight_map is not None:
                image_shape = (y1 - y0, x1 - x0) if self.grey else (y1 - y0, x1 - x0, 3)
                weight = prepare_gain_weight(weight_map[y0:y1, x0:x1].astype(np.float32), self.gain_sigma_px,
                                             image_shape, region=region)
            return box, region, sampling, weight

        def work(tile: _Tile, context, k: int) -> None:
            (y0, y1, x0, x1), region, sampling, weight = context
            ref = _crop_float(self.refs[k], y0, y1, x0, x1)
            warped = _warp_tile(self.curs[k], sampling)
            normalized = normalize_local_gain(ref, warped, sigma_px=self.gain_sigma_px, weight=weight, region=region)
            del warped
            diff = shift_tolerant_difference(ref[region], normalized, radius_px=r)
            cy0, cy1, cx0, cx1 = tile.core
            ry0, rx0 = y0 + region[0].start, x0 + region[1].start  # the region's corner in the frame
            self.differences[k][cy0:cy1, cx0:cx1] = diff[cy0 - ry0:cy1 - ry0, cx0 - rx0:cx1 - rx0]

        def finished(tile: _Tile) -> None:
            self.report(f"{label}: tile {tile.index + 1}/{len(self.tiles)}")

        _run_tiles(self.tiles, len(self.refs), prepare, work, finished, self.workers)
        _release_free_memory()

    def valid(self) -> np.ndarray:
        """Compared pixels: in the area, seen, aligned by the refinement, away from the border by the cue's reach."""
        area = np.ones(self.shape, bool) if self.eval_mask is None else self.eval_mask
        valid = area & self.seen_all
        if self.not_compared is not None:
            self.not_compared &= area
            valid &= ~self.not_compared
        margin_px = int(np.ceil(max(self.shift_radius_px, self.smooth_sigma_px * 2)))
        if margin_px > 0:
            kernel = np.ones((2 * margin_px + 1, 2 * margin_px + 1), np.uint8)
            valid = cv2.erode(valid.astype(np.uint8), kernel).astype(bool)
        return valid

    def fuse(self, valid: np.ndarray) -> np.ndarray:
        """Mean over lightings of each difference over its median on every compared pixel of the frame, smoothed.

        A global null model: never a per-tile median (the threshold would become a local one).
        The sum runs in bands of rows, over the workers (each pixel's sum in lighting order).
        """
        n = len(self.differences)
        medians = [_median_float16(d[valid]) if valid.any() else 0.0 for d in self.differences]
        scales = [1.0 / (n * (m + (1e-6 if m <= 0 else 0.0) + 1e-12)) for m in medians]
        fused = np.zeros(self.shape, np.float32)

        def add(rows: slice) -> None:
            for d, scale in zip(self.differences, scales):
                fused[rows] = cv2.scaleAdd(d[rows].astype(np.float32), scale, fused[rows])

        bands = [slice(y, min(self.shape[0], y + _FUSE_ROWS)) for y in range(0, self.shape[0], _FUSE_ROWS)]
        if self.workers > 1 and len(bands) > 1:
            with ThreadPoolExecutor(max_workers=self.workers) as pool:
                list(pool.map(add, bands))
        else:
            for rows in bands:
                add(rows)
        if self.smooth_sigma_px > 0:
            fused = cv2.GaussianBlur(fused, (0, 0), self.smooth_sigma_px)
        fused[~valid] = 0.0
        return fused


_FUSE_ROWS = 128
"""Rows per band of the fusion sum (its arrays then stay in cache)."""


# ------------------------------------------------------------------- decision


def _decide(score, valid, aside: ThreadPoolExecutor, cue_job: Callable | None, *, pixel_area_mm2, decision, k_high,
            k_low, epsilon, seed_p, extent_fraction, decision_px, smooth_sigma_px, edge_fraction, edge_radius_px,
            min_region_px, max_hole_px):
    """Threshold, a-contrario scan at the decision resolution, growth, cleaning and regions (as ``detect_changes``).

    ``cue_job`` (the cue maps), then the threshold, run on ``aside`` while the scan runs
    here; they start once the scan's full-frame temporaries are freed (the cue maps'
    photometric stereo is the run's largest memory). Returns ``(mask, regions, labels,
    threshold, significance, cue maps future or None)``.
    """
    beside = {}

    def start_beside() -> None:
        _release_free_memory()
        if cue_job is not None:
            beside["cues"] = aside.submit(cue_job)
        beside["threshold"] = aside.submit(robust_hysteresis_threshold, score, valid, k_high=k_high, k_low=k_low)

    significance = _significance_coarse(score, valid, decision_px=decision_px, epsilon=epsilon, seed_p=seed_p,
                                        extent_fraction=extent_fraction, smooth_sigma_px=smooth_sigma_px,
                                        on_grid=start_beside)
    raw_mask, threshold = beside["threshold"].result()
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
    return mask, regions, labels, threshold, significance, beside.get("cues")


# ----------------------------------------------------------------------- cues


def _cue_maps_small(small: _Small, valid, dense_fit, *, gain_sigma_px, ambient_index, light_dirs):
    """Relief and colour cue maps from photometric stereo at the working resolution, and the compared pixels there."""
    hs, ws = small.refs[0].shape[:2]
    reg_small = small.registration
    refs, normalized = [], []
    # The working-resolution images are not needed after this: dropped as they are converted.
    pairs, small.refs, small.curs = list(zip(small.refs, small.curs)), [], []
    while pairs:
        ref, cur = pairs.pop(0)
        ref, cur = _as_float(ref), _as_float(cur)
        if dense_fit is not None:
            warped, _ = warp_with_flow(cur, reg_small.H_cur_ref, dense_fit.flow)
        else:
            warped, _ = warp_to_reference(cur, reg_small.H_cur_ref, (hs, ws))
        normalized.append(np.clip(normalize_local_gain(ref, warped, sigma_px=max(gain_sigma_px, 1.0)), 0.0, 1.0))
        refs.append(ref)
    # A working pixel is compared when most of the full pixels it covers are.
    valid_small = cv2.resize(valid.astype(np.float32), (ws, hs), interpolation=cv2.INTER_AREA) > 0.5
    _release_free_memory()
    cue_maps = relief_colour_cues(refs, normalized, valid=valid_small, ambient_index=ambient_index,
                                  light_dirs=light_dirs)
    return cue_maps, valid_small


def _label_cues(cue_maps, valid_small, regions, labels, size_wh, *, smooth_sigma_px, fx, fy) -> None:
    """Relief / colour label per region, the regions mapped down to the cue maps' resolution."""
    ws, hs = size_wh
    labels_small = cv2.resize(labels, (ws, hs), interpolation=cv2.INTER_NEAREST)
    for region in regions:  # a region narrower than a working pixel keeps its centroid pixel
        if not (labels_small == region.id).any():
            cx, cy = region.centroid_xy
            labels_small[min(hs - 1, int((cy + 0.5) / fy)), min(ws - 1, int((cx + 0.5) / fx))] = region.id
    label_regions(regions, labels_small, cue_maps, valid=valid_small | (labels_small > 0),
                  smooth_sigma_px=max(smooth_sigma_px / max(fx, fy), 0.5))


def _significance_coarse(score, valid, *, decision_px, epsilon, seed_p, extent_fraction, smooth_sigma_px,
                         on_grid: Callable[[], None] | None = None):
    """The a-contrario scan on the score area-averaged to ``decision_px`` (long side), seeds mapped back.

    The scan's cost grows faster than the pixel count (one labelling per level and
    per round: 39 s at 4.4 MP); at the decision resolution it stays a few seconds.
    Its meaning is kept: the number of tests is ``N / A`` times the levels, and both
    the compared pixels ``N`` and the cluster area ``A`` shrink by the same factor.
    Returns a :class:`Decision` whose ``seed_index`` is at full resolution and whose
    regions' centroids and areas are in full-resolution pixels. ``on_grid`` is called
    once the score is on the decision grid, before the scan.
    """
    h, w = score.shape
    scale = max(1.0, max(h, w) / float(decision_px))
    on_grid = on_grid or (lambda: None)
    if scale <= 1.0:
        on_grid()
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
    on_grid()
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
