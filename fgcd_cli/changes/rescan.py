"""The detection's a-contrario decision made again on another score map of the same pair, under the
null the detection decided under, and only where it is asked.

A region-level check (the clip check, :mod:`fgcd_cli.changes.clip_check`) recomputes the score with
some evidence left out and asks whether the decision still seeds a significant region inside a few
regions. The null model is the pair's, not the map's: the background's marginal distribution, its
cluster area and the number of tests are those of the detection's own scan
(:class:`fgcd_cli.changes.significance.ScanNull`), so the question is "would the detection have found
this region on the evidence that is left?", and the answer costs the components that reach the
regions asked about, not a scan of the frame under a null estimated again (``docs/change-detection.md``,
"Change detection pipeline", step 10).

Within one component of the lowest level the ladder and the exclusion principle are those of the whole
frame (components of the lowest level are disjoint, and every higher level lies inside one of them), so
the seeds found are the seeds the full scan would find there under that null.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from fgcd_cli.changes.marginal import halfnormal_neglog_survival, scan_neglogp
from fgcd_cli.changes.significance import ScanNull, level_components, scan_levels

__all__ = ["seeds_under_nulls"]

_EIGHT = np.ones((3, 3), bool)


def seeds_under_nulls(
    scores: list[np.ndarray], valid: np.ndarray, nulls: tuple[ScanNull, ...], within: np.ndarray
) -> np.ndarray:
    """Seed pixels of the regions significant under the kept nulls, among the components that reach ``within``.

    Parameters
    ----------
    scores : list of (H, W) float32, one map per null (the same smoothings, in the same order, as the
        detection scanned).
    valid : (H, W) bool, the compared pixels.
    nulls : tuple of ScanNull, the detection's (:attr:`fgcd_cli.changes.significance.Decision.nulls`).
    within : (H, W) bool, the pixels asked about.

    Returns
    -------
    (H, W) bool, the seeds of every significant region whose lowest-level component meets ``within``.
    """
    if len(scores) != len(nulls):
        raise ValueError(f"{len(scores)} score maps for {len(nulls)} kept nulls")
    seeds = np.zeros(valid.shape, bool)
    for score, null in zip(scores, nulls):
        seeds |= _seeds_under(np.asarray(score, np.float32), valid, null, within)
    return seeds


def _seeds_under(score: np.ndarray, valid: np.ndarray, null: ScanNull, within: np.ndarray) -> np.ndarray:
    """:func:`seeds_under_nulls` for one map and its null."""
    if len(null.levels) == 0 or null.sorted_background.size == 0:
        return np.zeros(valid.shape, bool)
    # the pixel's -log p as the scan computed it: the empirical tail or half-normal noise, the less surprising
    neglogp = scan_neglogp(
        null.sorted_background,
        score,
        valid,
        halfnormal_neglog_survival(score / max(null.median, 1e-12)),
        floor=float(null.levels[0]),
    )
    base, _ = ndimage.label((neglogp >= null.levels[0]) & valid, structure=_EIGHT)
    reached = np.unique(base[within & (base > 0)])
    if reached.size == 0:
        return np.zeros(valid.shape, bool)
    asked = np.isin(base, reached)
    _, _, significant, _ = scan_levels(
        score,
        null.levels,
        level_components(neglogp, asked, null.levels),
        area=null.area,
        n_tests=null.n_tests,
        epsilon=null.epsilon,
        max_candidates=0,
    )
    return significant
