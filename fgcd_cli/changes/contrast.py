"""Region contrast: how strongly a region's change shows, as a fraction of the surface's own brightness.

A region's *contrast* is the peak, over its pixels, every lighting and every colour
channel, of the locally averaged difference between the light-normalised current
image and the reference, divided by the mean of the two images' median brightness in
the region (0.3 = 30 % darker or brighter at its strongest; the same whichever
observation is the reference). Unlike the score's strength, which is in units of the
pair's own noise, it does not grow as a pair gets cleaner, so it is what a floor on
reported changes is stated in (``RegionConfig.min_contrast``; docs/change-detection.md,
"Change detection pipeline", step 9).
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

#: Local averaging of the difference before its peak is taken (Gaussian sigma, px): a single
#: pixel's noise is not a change's contrast.
CONTRAST_SIGMA_PX = 1.0

#: A region darker than this (mean of the two medians, [0, 1] units) has its contrast taken against it,
#: so that a region in deep shadow is not given an unbounded contrast by a near-zero denominator.
MIN_BRIGHTNESS = 0.02


def lighting_contrasts(
    labels: np.ndarray,
    n_regions: int,
    *,
    refs: list[np.ndarray],
    normalized: list[np.ndarray],
    sigma_px: float = CONTRAST_SIGMA_PX,
) -> np.ndarray:
    """Each region's contrast under each lighting (module docstring), its strongest colour channel.

    The brightness a difference is divided by is the mean of the reference's and the current
    image's medians over the region, so that swapping the two observations gives the same contrast
    (a stain 40 % darker and the same stain removed read alike).

    Parameters
    ----------
    labels : (H, W) int array, region ids 1..n_regions (0 elsewhere).
    n_regions : int
    refs : list of K (H, W) or (H, W, 3) float32 arrays in [0, 1], the reference images (one per lighting).
    normalized : list of K arrays shaped as ``refs``, the current images registered and re-lit to the
        reference (:attr:`fgcd_cli.changes.score.PairScore.normalized`).
    sigma_px : float, the local averaging of the difference (Gaussian sigma, pixels).

    Returns
    -------
    (n_regions, K) float64 array, dimensionless (0.25: 25 %); row ``i`` is region ``i + 1``'s.
    """
    contrast = np.zeros((n_regions, len(refs)))
    if n_regions == 0:
        return contrast
    index = np.arange(1, n_regions + 1)
    # The per-region statistics run on the regions' pixels only: scipy's labelled median sorts every
    # pixel it is given, and the regions hold a few percent of the frame.
    inside = labels > 0
    region_labels = labels[inside]
    for k, (ref, cur) in enumerate(zip(refs, normalized)):
        ref = np.asarray(ref, np.float32)
        cur = np.asarray(cur, np.float32)
        difference = cv2.GaussianBlur(cur - ref, (0, 0), sigma_px) if sigma_px > 0 else cur - ref
        ref, cur, difference = ref[inside], cur[inside], difference[inside]
        channels = (
            [(ref, cur, difference)]
            if ref.ndim == 1
            else [(ref[:, c], cur[:, c], difference[:, c]) for c in range(ref.shape[1])]
        )
        for ref_c, cur_c, difference_c in channels:
            peak = np.asarray(ndimage.maximum(np.abs(difference_c), region_labels, index), float)
            brightness = 0.5 * (
                np.asarray(ndimage.median(ref_c, region_labels, index), float)
                + np.asarray(ndimage.median(cur_c, region_labels, index), float)
            )
            contrast[:, k] = np.maximum(contrast[:, k], peak / np.maximum(brightness, MIN_BRIGHTNESS))
    return contrast


def region_contrasts(labels: np.ndarray, n_regions: int, *, refs, normalized, sigma_px: float = CONTRAST_SIGMA_PX):
    """Each region's contrast at its strongest lighting: (n_regions,) float64 (see :func:`lighting_contrasts`)."""
    per_lighting = lighting_contrasts(labels, n_regions, refs=refs, normalized=normalized, sigma_px=sigma_px)
    return per_lighting.max(axis=1) if per_lighting.size else np.zeros(n_regions)


def set_contrasts(regions, labels: np.ndarray, refs: list[np.ndarray], normalized: list[np.ndarray]) -> None:
    """Set each region's ``contrast`` and ``lightings``: the 1-based numbers of the lightings that show it,
    those where its contrast is at least half its strongest (what a conservator looks at first).

    ``regions``: list of :class:`fgcd_cli.changes.regions.ChangeRegion`, ids 1..n matching ``labels``.
    """
    if not regions:
        return
    per_lighting = lighting_contrasts(labels, max(r.id for r in regions), refs=refs, normalized=normalized)
    for region in regions:
        row = per_lighting[region.id - 1]
        strongest = float(row.max())
        region.contrast = strongest
        region.lightings = tuple(int(k) + 1 for k in np.flatnonzero(row >= 0.5 * strongest))
