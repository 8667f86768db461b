"""Geometry of the tiled detector: the tile grid, and where each tile samples the current image.

The homography is conjugated to full resolution with OpenCV's pixel-centre
convention (``x_full = f (x_work + 0.5) - 0.5``, :func:`scale_matrix`), the
working-resolution flow is upsampled per tile (bilinear, values times ``f``), and
each tile of the current image is resampled once, through homography and flow
together (as :func:`fgcd_cli.changes.dense.refine.warp_with_flow`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from fgcd_cli.changes.registration import WARP_INTERPOLATION
from fgcd_cli.changes.tiled.inputs import crop_float


def scale_matrix(fx: float, fy: float) -> np.ndarray:
    """Working-resolution pixel -> full-resolution pixel (pixel centres at integers, OpenCV resize convention)."""
    return np.array([[fx, 0.0, 0.5 * fx - 0.5], [0.0, fy, 0.5 * fy - 0.5], [0.0, 0.0, 1.0]])


@dataclass(kw_only=True)
class Tile:
    index: int
    core: tuple[int, int, int, int]
    """y0, y1, x0, x1 of the pixels this tile writes."""
    ext: tuple[int, int, int, int]
    """y0, y1, x0, x1 of the pixels it reads (core grown by the overlap, clipped to the frame)."""


def tile_grid(shape: tuple[int, int], tile_px: int, overlap_px: int) -> list[Tile]:
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
            tiles.append(
                Tile(index=len(tiles), core=(int(y0), int(y1), int(x0), int(x1)), ext=tuple(int(v) for v in ext))
            )
    return tiles


@dataclass(kw_only=True)
class Geometry:
    H_full: np.ndarray
    """3x3, full-resolution reference pixel -> full-resolution current pixel."""
    flow_work: np.ndarray | None
    """hxwx2 float32 at working resolution (working px), or None (no dense refinement)."""
    not_compared_work: np.ndarray | None
    fx: float
    fy: float
    max_flow_full: float


def tile_maps(geom: Geometry, ext: tuple[int, int, int, int], cur_shape: tuple[int, int]):
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
            not_compared = cv2.remap(
                geom.not_compared_work.astype(np.uint8),
                map_wx,
                map_wy,
                cv2.INTER_NEAREST,
                borderMode=cv2.BORDER_REPLICATE,
            ).astype(bool)
    H = geom.H_full
    den = H[2, 0] * x + H[2, 1] * y + H[2, 2]
    map_x = (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / den
    map_y = (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / den
    ch, cw = cur_shape
    seen = (den > 0) & (map_x >= 0) & (map_x <= cw - 1) & (map_y >= 0) & (map_y <= ch - 1)
    return map_x, map_y, seen, not_compared


@dataclass(kw_only=True)
class Sampling:
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


def _tile_maps_in_bands(geom: Geometry, ext: tuple[int, int, int, int], cur_shape: tuple[int, int]):
    """:func:`tile_maps` of a whole tile, computed band of rows by band of rows (the same values, faster)."""
    y0, y1, x0, x1 = ext
    shape = (y1 - y0, x1 - x0)
    map_x, map_y, seen = np.empty(shape), np.empty(shape), np.empty(shape, bool)
    not_compared = None
    for b0 in range(y0, y1, _MAP_ROWS):
        b1 = min(y1, b0 + _MAP_ROWS)
        rows = slice(b0 - y0, b1 - y0)
        map_x[rows], map_y[rows], seen[rows], band_not_compared = tile_maps(geom, (b0, b1, x0, x1), cur_shape)
        if band_not_compared is not None:
            if not_compared is None:
                not_compared = np.empty(shape, bool)
            not_compared[rows] = band_not_compared
    return map_x, map_y, seen, not_compared


def tile_sampling(geom: Geometry, ext: tuple[int, int, int, int], cur_shape: tuple[int, int]) -> Sampling:
    """The tile's maps (:func:`tile_maps`) and the crop of the current image they read."""
    map_x, map_y, seen, not_compared = _tile_maps_in_bands(geom, ext, cur_shape)
    ch, cw = cur_shape
    shape = map_x.shape
    finite = np.isfinite(map_x) & np.isfinite(map_y)
    if not finite.any():
        return Sampling(shape=shape, box=None, map_x=None, map_y=None, seen=seen, not_compared=not_compared)
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
    return Sampling(shape=shape, box=(lo_y, hi_y, lo_x, hi_x), map_x=mx, map_y=my, seen=seen, not_compared=not_compared)


def warp_tile(cur: np.ndarray, sampling: Sampling) -> np.ndarray:
    """Resample the current image at the tile's maps, reading (and converting to float) only the needed crop.

    As :func:`warp_with_flow` on the whole image: ``changes.registration.WARP_INTERPOLATION``, clipped
    to [0, 1], the range of every image the tiled pipeline reads (the whole-image warp clips to the
    source's own range), border reflected about the image's own border (the crop reaches the border on any side
    where a sample falls outside).
    """
    if sampling.box is None:
        return np.zeros(sampling.shape + np.asarray(cur).shape[2:3], np.float32)
    src = crop_float(cur, *sampling.box)
    # Any sample outside the image lies beyond a side the crop reaches (it holds every
    # sample inside, plus 2 px), so reflecting about the crop's edge is reflecting about the image's.
    warped = cv2.remap(src, sampling.map_x, sampling.map_y, WARP_INTERPOLATION, borderMode=cv2.BORDER_REFLECT)
    return np.clip(warped, 0.0, 1.0, out=warped)
