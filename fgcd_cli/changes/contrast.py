"""Region contrast: how strongly a region's change shows, as a fraction of the surface's own brightness.

A region's *contrast* is the peak, over its pixels, every lighting and every colour
channel, of the locally averaged difference between the light-normalised current
image and the reference, divided by the reference's median brightness in the
region (a Weber contrast: 0.3 = 30 % darker or brighter at its strongest). Unlike
the score's strength, which is in units of the pair's own noise, it does not grow
as a pair gets cleaner, so it is what a floor on reported changes is stated in
(``RegionConfig.min_contrast``, docs/change-detection.md, "Contrast floor").
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

#: Local averaging of the difference before its peak is taken (Gaussian sigma, px): a single
#: pixel's noise is not a change's contrast.
CONTRAST_SIGMA_PX = 1.0

#: A region darker than this (reference median, [0, 1] units) has its contrast taken against it,
#: so that a region in deep shadow is not given an unbounded contrast by a near-zero denominator.
MIN_BRIGHTNESS = 0.02


def region_contrasts(
    labels: np.ndarray,
    n_regions: int,
    *,
    refs: list[np.ndarray],
    normalized: list[np.ndarray],
    sigma_px: float = CONTRAST_SIGMA_PX,
) -> np.ndarray:
    """Each region's contrast (module docstring).

    Parameters
    ----------
    labels : (H, W) int array, region ids 1..n_regions (0 elsewhere).
    n_regions : int
    refs : list of (H, W) or (H, W, 3) float32 arrays in [0, 1], the reference images (one per lighting).
    normalized : list of arrays shaped as ``refs``, the current images registered and re-lit to the
        reference (:attr:`fgcd_cli.changes.score.PairScore.normalized`).
    sigma_px : float, the local averaging of the difference (Gaussian sigma, pixels).

    Returns
    -------
    (n_regions,) float64 array, dimensionless (0.25: 25 %); entry ``i`` is region ``i + 1``'s.
    """
    contrast = np.zeros(n_regions)
    if n_regions == 0:
        return contrast
    index = np.arange(1, n_regions + 1)
    for ref, cur in zip(refs, normalized):
        ref = np.asarray(ref, np.float32)
        cur = np.asarray(cur, np.float32)
        difference = cv2.GaussianBlur(cur - ref, (0, 0), sigma_px) if sigma_px > 0 else cur - ref
        channels = range(ref.shape[2]) if ref.ndim == 3 else [None]
        for c in channels:
            ref_c = ref if c is None else ref[..., c]
            diff_c = difference if c is None else difference[..., c]
            peak = np.asarray(ndimage.maximum(np.abs(diff_c), labels, index), float)
            brightness = np.asarray(ndimage.median(ref_c, labels, index), float)
            contrast = np.maximum(contrast, peak / np.maximum(brightness, MIN_BRIGHTNESS))
    return contrast
