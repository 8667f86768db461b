"""Automatic threshold of a change score from its own robust statistics.

Changed pixels are 0.3-4 % of an image: Otsu or 2-class k-means need two
populations of comparable size and find nothing useful there. Instead the
background (unchanged) distribution is described by robust statistics that
the few changed pixels cannot move (median and the median deviation of the
upper half), and changes are the pixels far in its tail, grown by hysteresis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from skimage.filters import apply_hysteresis_threshold

# Normal-distribution constant: the median of |x - mu| is 0.6745 sigma.
_MAD_TO_SIGMA = 1.0 / 0.6745


@dataclass(kw_only=True)
class ThresholdInfo:
    """How the automatic threshold was derived (all values in score units)."""

    method: str
    median: float
    sigma_upper: float
    """Robust spread of the upper half of the background: median(s - median | s > median) / 0.6745."""
    k_high: float
    k_low: float
    high: float
    """Seed threshold = median + k_high * sigma_upper."""
    low: float
    """Growing threshold = median + k_low * sigma_upper (hysteresis)."""
    changed_fraction: float
    """Fraction of valid pixels above threshold after hysteresis."""


def robust_hysteresis_threshold(
    score: np.ndarray,
    valid: np.ndarray,
    *,
    k_high: float = 20.0,
    k_low: float = 10.0,
) -> tuple[np.ndarray, ThresholdInfo]:
    """Threshold a change score at median + k * robust upper spread, with hysteresis.

    Parameters
    ----------
    score : ndarray, HxW float
        Larger = more likely changed.
    valid : ndarray, HxW bool
        Pixels whose statistics count and that may be flagged.
    k_high, k_low : float
        Seed and growing thresholds in units of ``sigma_upper``. The fused score's
        background is heavy-tailed (texture, cast shadows, sub-pixel residuals), so
        the thresholds are far larger than the 3-5 of a Gaussian; the defaults were
        chosen on a plateau of the development data (docs/change-detection.md, "Change detection pipeline").

    Returns
    -------
    mask : ndarray, HxW bool
    info : ThresholdInfo
    """
    values = score[valid]
    if values.size == 0:
        raise ValueError("no valid pixel to derive a threshold from")
    median = float(np.median(values))
    upper = values[values > median] - median
    sigma = float(np.median(upper)) * _MAD_TO_SIGMA if upper.size else 0.0
    if sigma <= 0:
        sigma = float(np.std(values)) or 1e-12
    high = median + k_high * sigma
    low = median + k_low * sigma
    masked = np.where(valid, score, -np.inf)
    mask = apply_hysteresis_threshold(masked, low, high) & valid
    info = ThresholdInfo(
        method="median + k*sigma_upper, hysteresis",
        median=median,
        sigma_upper=sigma,
        k_high=float(k_high),
        k_low=float(k_low),
        high=float(high),
        low=float(low),
        changed_fraction=float(mask[valid].mean()),
    )
    return mask, info
