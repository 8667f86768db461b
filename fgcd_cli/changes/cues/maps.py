"""Per-pixel change cues between the reference and a registered, light-normalized current image.

Each cue is HxW float32, larger = more likely changed, in the reference frame.
"""

from __future__ import annotations

import cv2
import numpy as np

from fgcd_cli.changes.images import to_gray

_STRIP_ROWS = 32
"""Rows processed at a time by the shift-tolerant difference (its arrays then stay in cache)."""


def _min_shifted_difference(fixed: np.ndarray, moving: np.ndarray, radius_px: int) -> np.ndarray:
    """``min over |s| <= r of |fixed(x) - moving(x + s)|``, channels summed (L1); HxW float32.

    Computed strip by strip (:data:`_STRIP_ROWS` rows): every pixel's value is the same
    as on the whole image, but the shifted differences of a strip stay in cache.
    """
    h, w = fixed.shape[:2]
    padded = cv2.copyMakeBorder(moving, radius_px, radius_px, radius_px, radius_px, cv2.BORDER_REFLECT)
    out = np.empty((h, w), np.float32)
    for y0 in range(0, h, _STRIP_ROWS):
        y1 = min(h, y0 + _STRIP_ROWS)
        strip = fixed[y0:y1]
        best = None
        for dy in range(-radius_px, radius_px + 1):
            for dx in range(-radius_px, radius_px + 1):
                shifted = padded[radius_px + dy + y0 : radius_px + dy + y1, radius_px + dx : radius_px + dx + w]
                diff = cv2.absdiff(strip, shifted)
                if diff.ndim == 3:  # channel sum through OpenCV: numpy's reduction over the last axis is ~10x slower
                    diff = cv2.transform(diff, np.ones((1, diff.shape[2]), np.float32))
                best = diff if best is None else np.minimum(best, diff, out=best)
        out[y0:y1] = best
    return out


def shift_tolerant_difference(
    ref_image: np.ndarray, cur_image: np.ndarray, *, radius_px: int = 1, symmetric: bool = True
) -> np.ndarray:
    """Absolute difference, minimized over small shifts, in both directions.

    The minimum over shifts of up to ``radius_px`` absorbs residual misregistration
    at edges (sub-pixel to 1 px) while a real change, larger than the shift, survives.
    It must be taken both ways (``symmetric``): shifting only the current image
    explains away a *new* feature narrower than ``2 * radius_px`` (a 2 px crack:
    every crack pixel has a crack-free neighbour to shift to), and shifting only
    the reference would do the same to a *lost* one. A misregistered edge is
    explained in both directions, a thin change in neither, so the larger of the
    two minima is kept. Colour channels are summed (L1).

    Parameters
    ----------
    ref_image, cur_image : ndarray, HxW or HxWx3 float32 in [0, 1].
    radius_px : int
        Largest shift tried in x and y, pixels.
    symmetric : bool
        Take the larger of the two one-sided minima (False: shift the current image only).

    Returns
    -------
    ndarray, HxW float32 (intensity units, summed over channels).
    """
    if radius_px <= 0:
        diff = np.abs(np.asarray(ref_image, np.float32) - np.asarray(cur_image, np.float32))
        return (diff.sum(axis=2) if diff.ndim == 3 else diff).astype(np.float32)
    ref_image = np.asarray(ref_image, np.float32)  # OpenCV reads row-strided views as they are
    cur_image = np.asarray(cur_image, np.float32)
    if not symmetric:
        return _min_shifted_difference(ref_image, cur_image, radius_px)
    return _symmetric_min_difference(ref_image, cur_image, radius_px)


def _symmetric_min_difference(ref: np.ndarray, cur: np.ndarray, radius_px: int) -> np.ndarray:
    """``max(min_s |ref(x) - cur(x + s)|, min_s |cur(x) - ref(x + s)|)``, channels summed (L1); HxW float32.

    Both minima read the same differences: ``|cur(x) - ref(x + s)|`` is
    ``E_{-s}(x + s)`` with ``E_t(p) = |ref(p) - cur(p + t)|``. Each ``E_t`` is computed
    once, on the image grown by the radius (the reference reflected there, the current
    image reflected by twice the radius), and both minima are taken from it: the same
    values as two separate passes (``|a - b| = |b - a|`` exactly), half the differences.
    Strip by strip (:data:`_STRIP_ROWS` rows), as :func:`_min_shifted_difference`.
    """
    r = radius_px
    h, w = ref.shape[:2]
    ref_pad = cv2.copyMakeBorder(ref, r, r, r, r, cv2.BORDER_REFLECT)  # index (i, j): pixel (i - r, j - r)
    cur_pad = cv2.copyMakeBorder(cur, 2 * r, 2 * r, 2 * r, 2 * r, cv2.BORDER_REFLECT)  # pixel (i - 2r, j - 2r)
    shifts = [(dy, dx) for dy in range(-r, r + 1) for dx in range(-r, r + 1)]
    out = np.empty((h, w), np.float32)
    for y0 in range(0, h, _STRIP_ROWS):
        y1 = min(h, y0 + _STRIP_ROWS)
        rows = ref_pad[y0 : y1 + 2 * r]  # pixels y0 - r .. y1 + r - 1, x = -r .. w + r - 1
        grown = {}
        for dy, dx in shifts:
            diff = cv2.absdiff(rows, cur_pad[y0 + r + dy : y1 + 3 * r + dy, r + dx : r + dx + w + 2 * r])
            if diff.ndim == 3:
                diff = cv2.transform(diff, np.ones((1, diff.shape[2]), np.float32))
            grown[dy, dx] = diff
        forward = backward = None
        for dy, dx in shifts:
            f = grown[dy, dx][r : r + y1 - y0, r : r + w]
            b = grown[-dy, -dx][r + dy : r + dy + y1 - y0, r + dx : r + dx + w]
            forward = f.copy() if forward is None else np.minimum(forward, f, out=forward)
            backward = b.copy() if backward is None else np.minimum(backward, b, out=backward)
        np.maximum(forward, backward, out=out[y0:y1])
    return out


def local_ncc_dissimilarity(ref_gray: np.ndarray, cur_gray: np.ndarray, *, sigma_px: float = 2.0) -> np.ndarray:
    """``1 - NCC`` in a Gaussian window: insensitive to local gain and offset.

    Returns HxW float32 in [0, 2]; flat areas (no variance) give ~0.
    """
    blur = lambda x: cv2.GaussianBlur(x, (0, 0), sigma_px)  # noqa: E731
    mean_ref, mean_cur = blur(ref_gray), blur(cur_gray)
    var_ref = blur(ref_gray * ref_gray) - mean_ref**2
    var_cur = blur(cur_gray * cur_gray) - mean_cur**2
    cov = blur(ref_gray * cur_gray) - mean_ref * mean_cur
    eps = 1e-4  # (0.01 intensity)^2: below that a window is flat and the NCC meaningless
    ncc = (cov + eps) / np.sqrt(np.maximum(var_ref + eps, 1e-12) * np.maximum(var_cur + eps, 1e-12))
    return (1.0 - ncc).astype(np.float32)


def relative_to_median(cue: np.ndarray, valid: np.ndarray, *, median: float | None = None) -> np.ndarray:
    """Divide a non-negative cue by its median over ``valid`` pixels (dimensionless, median 1).

    ``median`` given: divide by that instead (another cue's median, to compare with it).
    """
    if median is None:
        values = cue[valid]
        median = float(np.median(values)) if values.size else 0.0
    floor = 1e-6 if median <= 0 else 0.0
    return (np.maximum(cue, 0.0) / (median + floor + 1e-12)).astype(np.float32)


def envelope_distance(image: np.ndarray, other: np.ndarray, *, radius_px: int = 1) -> np.ndarray:
    """Distance of each pixel of ``image`` to the [min, max] envelope of ``other`` around it.

    Zero where ``image`` lies between the smallest and the largest value of
    ``other`` in the (2r+1)² window: any shift of up to ``radius_px`` with linear
    (sub-pixel) interpolation of ``other`` produces such values, so the difference
    can be explained by a misalignment of that size. Colour channels are summed (L1).

    Returns HxW float32 (intensity units, summed over channels).
    """
    image = np.asarray(image, np.float32)
    other = np.asarray(other, np.float32)
    kernel = np.ones((2 * radius_px + 1, 2 * radius_px + 1), np.uint8)
    low = cv2.erode(other, kernel, borderType=cv2.BORDER_REFLECT)
    high = cv2.dilate(other, kernel, borderType=cv2.BORDER_REFLECT)
    distance = np.maximum(low - image, 0.0) + np.maximum(image - high, 0.0)
    if distance.ndim == 3:
        distance = distance.sum(axis=2)
    return distance.astype(np.float32)


def edge_band(ref_image: np.ndarray, *, radius_px: int = 2, contrast: float = 3.0) -> np.ndarray:
    """Pixels within ``radius_px`` of a strong edge of the reference image.

    An edge pixel's 3x3 intensity range exceeds ``contrast`` times the median 3x3
    range of the image (scale-free: the same in dark and bright images, textured
    or not). Occlusion and depth edges, thin high-contrast lines and strong texture
    edges are where a sub-pixel relocation residual (parallax, resampling blur,
    aliasing) changes the image most.

    Returns HxW bool.
    """
    return _edge_bands(ref_image, radius_px=radius_px, contrasts=(contrast,))[0]


def _edge_bands(image: np.ndarray, *, radius_px: int, contrasts: tuple[float, ...]) -> list[np.ndarray]:
    """:func:`edge_band` of one image at several contrasts (its 3x3 range and their median found once)."""
    gray = to_gray(np.asarray(image, np.float32))
    kernel = np.ones((3, 3), np.uint8)
    local_range = cv2.dilate(gray, kernel) - cv2.erode(gray, kernel)
    typical = max(float(np.median(local_range)), 1e-6)
    grow = np.ones((2 * radius_px + 1, 2 * radius_px + 1), np.uint8)
    return [cv2.dilate((local_range > c * typical).astype(np.uint8), grow).astype(bool) for c in contrasts]


def edge_band_either_phase(
    ref_image: np.ndarray, cur_image: np.ndarray, *, radius_px: int = 2, contrast: float = 3.0
) -> np.ndarray:
    """:func:`edge_band` of the reference, and of the current image where the reference shows the same
    edge at half the contrast or more.

    Rule: a line narrower than a pixel is integrated by the pixel it falls in; seen again
    from a viewpoint a fraction of a millimetre away it falls at another sub-pixel phase,
    and split over two pixels it keeps at least half its depth in the deeper one. So a
    thin line the reference happened to see shallow (below ``contrast``) but the current
    image sees deep is still the reference's edge: the band takes the current image's
    strong edges where the reference's range is at least ``contrast / 2`` times its
    median (docs/change-detection.md, "Change detection pipeline", step 8). On textured
    stone that half contrast is common, so a new mark there may lie in the band too; it
    stays a change only through the edge check's other rules (the envelope, the shape),
    which ``tests/changes/test_edge_check.py`` checks for a new crack.

    Returns HxW bool.
    """
    own, seen_at_half = _edge_bands(ref_image, radius_px=radius_px, contrasts=(contrast, contrast / 2.0))
    return own | (edge_band(cur_image, radius_px=radius_px, contrast=contrast) & seen_at_half)


def edge_tolerant_difference(
    ref_image: np.ndarray,
    cur_image: np.ndarray,
    *,
    radius_px: int = 1,
    edge_radius_px: int = 2,
    edge_contrast: float = 3.0,
    band: np.ndarray | None = None,
) -> np.ndarray:
    """:func:`shift_tolerant_difference`, with a wider, two-sided tolerance near strong edges.

    Near strong reference edges (see :func:`edge_band`) a relocation residual of
    a few millimetres moves, blurs or hides thin structures by up to a pixel or
    two (parallax at depth edges, occlusion of grazing walls, resampling of the
    warp). There a difference only counts if neither image is explained by the
    other within ``edge_radius_px``: the current pixel lies outside the reference's
    min/max envelope *and* the reference pixel outside the current one's
    (:func:`envelope_distance`). A stain or loss wider than the envelope still
    differs from both; a thin line that a sub-pixel shift thins, blurs or moves
    does not. Elsewhere the plain shift-tolerant difference applies.

    Returns HxW float32 (intensity units, summed over channels).
    """
    base = shift_tolerant_difference(ref_image, cur_image, radius_px=radius_px)
    if edge_radius_px <= 0:
        return base
    if band is None:
        band = edge_band(ref_image, radius_px=edge_radius_px, contrast=edge_contrast)
    two_sided = np.minimum(
        envelope_distance(cur_image, ref_image, radius_px=edge_radius_px),
        envelope_distance(ref_image, cur_image, radius_px=edge_radius_px),
    )
    return np.where(band, np.minimum(base, two_sided), base).astype(np.float32)
