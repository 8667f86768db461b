"""The pair's marginal model of the a-contrario decision: each pixel's ``-log p``.

A pixel is only as surprising as its least surprising explanation: the empirical tail of the pair's
own score over its background pixels, or half-normal sensor noise with the score's median as its
median (:mod:`fgcd_cli.changes.significance`, "marginal").
"""

from __future__ import annotations

import numpy as np
from scipy import special

__all__ = ["empirical_neglog_survival", "halfnormal_neglog_survival", "scan_neglogp"]


def empirical_neglog_survival(score: np.ndarray, valid: np.ndarray, *, sample: np.ndarray | None = None) -> np.ndarray:
    """``-log P(S >= s)`` of every pixel under the empirical distribution of ``score[valid]``.

    Parameters
    ----------
    score : ndarray, HxW float
    valid : ndarray, HxW bool
    sample : ndarray, HxW bool, optional
        Pixels whose scores form the distribution (default: ``valid``), e.g. the
        compared pixels outside the regions already found significant.

    Returns
    -------
    ndarray, HxW float32 (0 outside ``valid``; at most ``log(2N)`` for N valid pixels).
    """
    values = np.sort(score[valid if sample is None else sample & valid])
    rank = np.searchsorted(values, score, side="left")
    return np.where(valid, _neglog_survival_of_rank(rank, values.size), 0.0).astype(np.float32)


def _neglog_survival_of_rank(rank: np.ndarray, n: int) -> np.ndarray:
    """``-log P(S >= s)`` of scores with ``rank`` of ``n`` sample values below them (the +0.5 continuity
    correction keeps the most extreme pixel finite: at most ``log(2n)``)."""
    return -np.log(np.clip((n - rank + 0.5) / n, 0.5 / n, 1.0))


def scan_neglogp(
    values: np.ndarray, score: np.ndarray, valid: np.ndarray, halfnormal: np.ndarray, *, floor: float
) -> np.ndarray:
    """A pixel's ``-log p`` as the scan reads it: the smaller of the empirical one (under the sorted (M,)
    sample ``values``, as :func:`empirical_neglog_survival`) and ``halfnormal``, where it reaches ``floor`` (the
    lowest level scanned); 0 elsewhere.

    The scan looks at nothing below its lowest level, so only the pixels above the sample's
    ``exp(-floor)`` quantile are ranked (a few percent of the frame instead of all of it).
    """
    out = np.zeros(score.shape, np.float32)
    n = values.size
    # empirical -log p >= floor  <=>  rank >= first: rank counts the sample below the score
    first = int(np.ceil(n + 0.5 - n * np.exp(-floor)))
    if n == 0 or first > n:
        return out
    candidates = valid & (score > values[first - 1]) if first >= 1 else valid
    idx = np.flatnonzero(candidates)
    rank = np.searchsorted(values, score.ravel()[idx], side="left")
    empirical = _neglog_survival_of_rank(rank, n).astype(np.float32)
    value = np.minimum(empirical, halfnormal.ravel()[idx])
    out.ravel()[idx] = np.where(value >= floor, value, 0.0)
    return out


def halfnormal_neglog_survival(relative_score: np.ndarray) -> np.ndarray:
    """``-log P(S >= s)`` when ``S`` is half-normal with median 1 (the absolute value of Gaussian noise).

    Parameters
    ----------
    relative_score : ndarray, HxW float, score divided by its median.

    Returns
    -------
    ndarray, HxW float32.
    """
    # median |N(0, 1)| = 0.6745, so s * 0.6745 is in units of the noise's sigma.
    z = np.asarray(relative_score, np.float64) * 0.6745
    return (-(special.log_ndtr(-z) + np.log(2.0))).clip(min=0.0).astype(np.float32)
