"""The per-lighting difference maps of a large frame, tile by tile, and their fusion under a global null model.

Per tile (with an overlap that covers the gain windows) and per lighting: the
light gain (:func:`fgcd_cli.changes.illumination.normalize_local_gain`) and the
symmetric shift-tolerant difference, whose core is written into one full-size
float16 map per lighting. Median rule: each lighting's difference is divided by
its median over *all* compared pixels of the frame, never by a per-tile median
(``docs/change-detection.md``, large frames).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

from fgcd_cli.changes.config import ScoreConfig
from fgcd_cli.changes.cues.maps import shift_tolerant_difference
from fgcd_cli.changes.detect import comparison_margin_px
from fgcd_cli.changes.illumination import normalize_local_gain, prepare_gain_weight
from fgcd_cli.changes.score import smooth_at_two_scales
from fgcd_cli.changes.tiled.geometry import Geometry, Tile, tile_sampling, warp_tile
from fgcd_cli.changes.tiled.inputs import crop_float
from fgcd_cli.changes.tiled.schedule import median_float16, release_free_memory, run_tiles


class TiledScore:
    """The per-lighting difference maps of the whole frame, computed tile by tile, and their fusion."""

    def __init__(
        self,
        ref_images,
        cur_images,
        geom: Geometry,
        tiles: list[Tile],
        *,
        roi,
        workers: int,
        score: ScoreConfig,
        report,
    ):
        """``geom`` carries the dense flow when the dense refinement ran (then ``not_compared`` is kept)."""
        self.refs, self.curs, self.geom, self.tiles = ref_images, cur_images, geom, tiles
        self.shape = np.asarray(ref_images[0]).shape[:2]
        self.roi, self.workers, self.report, self.score = roi, workers, report, score
        self.gain_sigma_px, self.shift_radius_px = score.gain_sigma_px, score.shift_radius_px
        self.smooth_sigma_px = score.smooth_sigma_px
        self.fine_smooth_sigma_px = score.fine_smooth_sigma_px
        self.seen_all = np.zeros(self.shape, bool)
        self.not_compared = np.zeros(self.shape, bool) if geom.flow_work is not None else None
        self.differences = [np.zeros(self.shape, np.float16) for _ in ref_images]
        first = np.asarray(ref_images[0])
        self.grey = first.ndim == 2 or first.shape[2] == 1

    def _read_box(self, tile: Tile, pass_index: int) -> tuple[int, int, int, int]:
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

        def prepare(tile: Tile):
            y0, y1, x0, x1 = box = self._read_box(tile, pass_index)
            cy0, cy1, cx0, cx1 = tile.core
            sampling = tile_sampling(self.geom, box, self.shape)
            if pass_index == 0:
                core = (slice(cy0 - y0, cy1 - y0), slice(cx0 - x0, cx1 - x0))
                self.seen_all[cy0:cy1, cx0:cx1] = sampling.seen[core]
                if sampling.not_compared is not None and self.not_compared is not None:
                    self.not_compared[cy0:cy1, cx0:cx1] = sampling.not_compared[core]
            sampling.seen = sampling.not_compared = None
            region = (
                slice(max(y0, cy0 - r) - y0, min(y1, cy1 + r) - y0),
                slice(max(x0, cx0 - r) - x0, min(x1, cx1 + r) - x0),
            )
            weight = None
            if weight_map is not None:
                image_shape = (y1 - y0, x1 - x0) if self.grey else (y1 - y0, x1 - x0, 3)
                weight = prepare_gain_weight(
                    weight_map[y0:y1, x0:x1].astype(np.float32), self.gain_sigma_px, image_shape, region=region
                )
            return box, region, sampling, weight

        def work(tile: Tile, context, k: int) -> None:
            (y0, y1, x0, x1), region, sampling, weight = context
            ref = crop_float(self.refs[k], y0, y1, x0, x1)
            warped = warp_tile(self.curs[k], sampling)
            normalized = normalize_local_gain(ref, warped, sigma_px=self.gain_sigma_px, weight=weight, region=region)
            del warped
            diff = shift_tolerant_difference(ref[region], normalized, radius_px=r)
            cy0, cy1, cx0, cx1 = tile.core
            ry0, rx0 = y0 + region[0].start, x0 + region[1].start  # the region's corner in the frame
            self.differences[k][cy0:cy1, cx0:cx1] = diff[cy0 - ry0 : cy1 - ry0, cx0 - rx0 : cx1 - rx0]

        def finished(tile: Tile) -> None:
            self.report(f"{label}: tile {tile.index + 1}/{len(self.tiles)}")

        run_tiles(self.tiles, len(self.refs), prepare, work, finished, self.workers)
        release_free_memory()

    def valid(self) -> np.ndarray:
        """Compared pixels: in the area, seen, aligned by the refinement, away from the border by the cue's reach."""
        area = np.ones(self.shape, bool) if self.roi is None else self.roi
        valid = area & self.seen_all
        if self.not_compared is not None:
            self.not_compared &= area
            valid &= ~self.not_compared
        margin_px = comparison_margin_px(self.score)
        if margin_px > 0:
            kernel = np.ones((2 * margin_px + 1, 2 * margin_px + 1), np.uint8)
            valid = cv2.erode(valid.astype(np.uint8), kernel).astype(bool)
        return valid

    def fuse(self, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Mean over lightings of each difference over its median on every compared pixel of the frame, smoothed
        (and at the finer smoothing, or None: :func:`fgcd_cli.changes.score.smooth_at_two_scales`).

        A global null model: never a per-tile median (the threshold would become a local one).
        The sum runs in bands of rows, over the workers (each pixel's sum in lighting order).
        """
        n = len(self.differences)
        medians = [median_float16(d[valid]) if valid.any() else 0.0 for d in self.differences]
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
        fused, fine = smooth_at_two_scales(
            fused, smooth_sigma_px=self.smooth_sigma_px, fine_sigma_px=self.fine_smooth_sigma_px
        )
        fused[~valid] = 0.0
        if fine is not None:
            fine[~valid] = 0.0
        return fused, fine


_FUSE_ROWS = 128
"""Rows per band of the fusion sum (its arrays then stay in cache)."""
