"""Scheduling of the tiled detector: tiles over worker threads, OpenCV's own threads, heap trimming, float16 medians."""

from __future__ import annotations

import ctypes
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from functools import lru_cache

import cv2
import numpy as np

from fgcd_cli.changes.tiled.geometry import Tile


def release_free_memory() -> None:
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
def opencv_threads(count: int | None):
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


def median_float16(values: np.ndarray) -> float:
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


def run_tiles(tiles: list[Tile], n: int, prepare: Callable, work: Callable, finished: Callable, workers: int) -> None:
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
    with opencv_threads(1), ThreadPoolExecutor(max_workers=workers) as pool:
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
