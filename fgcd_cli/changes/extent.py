"""Growing significant seeds to the extent of their change (the a-contrario decision's last step).

A seed found at some level of the ladder (:mod:`fgcd_cli.changes.significance`) holds the pixels above
that level; the change it marks reaches further down its flank. ``docs/change-detection.md``,
"Significance of each region (a-contrario)".
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["grow_to_extent"]

_EIGHT = np.ones((3, 3), bool)


def grow_to_extent(
    seeds: np.ndarray, score: np.ndarray, valid: np.ndarray, *, background: float, fraction: float
) -> np.ndarray:
    """Grow each seed region into connected pixels whose excess reaches ``fraction`` of its peak excess.

    Parameters
    ----------
    seeds : ndarray, HxW bool
    score : ndarray, HxW float
    valid : ndarray, HxW bool
    background : float, score of unchanged pixels (median).
    fraction : float in [0, 1); 0 returns the seeds.

    Returns
    -------
    ndarray, HxW bool
    """
    if fraction <= 0 or not seeds.any():
        return seeds & valid
    # Each seed grows inside its bounding box padded by its larger side (at least 8 px).
    # The binary morphological reconstruction of the seed in the allowed pixels is the
    # union of the 8-connected components of the allowed pixels that hold a seed pixel:
    # labelling them gives it, several times faster, with no statistic over the frame.
    labels, _ = ndimage.label(seeds, structure=_EIGHT)
    out = np.zeros(seeds.shape, bool)
    h, w = seeds.shape
    for i, window in enumerate(ndimage.find_objects(labels)):
        pad = max(8, int(max(window[0].stop - window[0].start, window[1].stop - window[1].start)))
        ys = slice(max(0, window[0].start - pad), min(h, window[0].stop + pad))
        xs = slice(max(0, window[1].start - pad), min(w, window[1].stop + pad))
        seed = labels[ys, xs] == i + 1
        excess = np.maximum(score[ys, xs].astype(np.float32) - np.float32(background), 0.0)
        allowed = (excess >= fraction * excess[seed].max()) & valid[ys, xs]
        # The seed obeys the same rule: a strong change found at a low level carries
        # the low level's flank (and any gain halo) in its seed component.
        core = seed & allowed
        if not core.any():
            core = seed
        components, _ = ndimage.label(allowed | core, structure=_EIGHT)
        reached = np.unique(components[core])
        out[ys, xs] |= np.isin(components, reached[reached > 0])
    return out & valid
