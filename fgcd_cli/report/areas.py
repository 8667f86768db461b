"""Areas as text, to the precision the pixel size allows.

An area measured by counting pixels is known to about one pixel's footprint at
best (a region's outline moves by a pixel with noise and resampling). Digits
finer than the decade of that footprint are noise: at 5 mm² per pixel an area
is printed to the mm² (``976 mm²``), at 0.04 mm² per pixel to the hundredth.
Shared by the reports and the CLI so that both print the same figure.
"""

from __future__ import annotations

import math

__all__ = ["area_decimals", "area_mm2_text", "round_area_mm2"]


def area_decimals(pixel_mm2: float | None) -> int:
    """Decimals worth printing for an area measured with pixels of ``pixel_mm2`` mm² each.

    Parameters
    ----------
    pixel_mm2 : float or None
        Footprint of one pixel on the object (mm²); a region's mean is
        ``area_mm2 / area_px``.

    Returns
    -------
    int
        ``max(0, -floor(log10(pixel_mm2)))``: 0 for a footprint of 1 mm² or more,
        1 for 0.1-0.99 mm², 2 for 0.01-0.099 mm², ...; 1 when the footprint is unknown.
    """
    if pixel_mm2 is None or not math.isfinite(pixel_mm2) or pixel_mm2 <= 0:
        return 1
    return max(0, -math.floor(math.log10(pixel_mm2)))


def _pixel_mm2(area_mm2: float, area_px: int | float | None) -> float | None:
    if not area_px or area_px <= 0:
        return None
    return area_mm2 / float(area_px)


def round_area_mm2(area_mm2: float | None, area_px: int | float | None) -> float | None:
    """``area_mm2`` rounded to the decimals its mean pixel footprint allows (None stays None)."""
    if area_mm2 is None or not math.isfinite(area_mm2):
        return None
    return round(float(area_mm2), area_decimals(_pixel_mm2(area_mm2, area_px)))


def area_mm2_text(area_mm2: float | None, area_px: int | float | None, *, unit: bool = True) -> str:
    """An area as text to the precision its pixels allow: ``"976 mm²"`` (195 px of 5 mm²), ``"3.48 mm²"``.

    Parameters
    ----------
    area_mm2 : float or None
        Area on the object; None or NaN gives ``"–"``.
    area_px : int or float or None
        The pixels the area was counted from (their mean footprint sets the precision).
    unit : bool, keyword-only
        Append ``" mm²"``.
    """
    if area_mm2 is None or not math.isfinite(area_mm2):
        return "–"
    # no pixel, no area: an exact zero, not a measurement
    decimals = 0 if area_mm2 == 0 else area_decimals(_pixel_mm2(area_mm2, area_px))
    return f"{area_mm2:.{decimals}f}" + (" mm²" if unit else "")
