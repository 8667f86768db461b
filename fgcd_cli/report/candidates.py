"""Plain-text wording of the a-contrario significance: NFA values, candidates, the "no significant change" verdict.

Shared by the CLI (``fgcd diff``) and the HTML report so that both say the same
thing. Everything works on the JSON form of ``regions.json`` (plain dicts), so
the CLI can word what it is handed without the detection's objects.
"""

from __future__ import annotations

import math

from fgcd_cli.changes.config import EPSILON
from fgcd_cli.changes.significance import SignificantRegion


def nfa_value(log10_nfa: float | None) -> float | None:
    """``10 ** log10_nfa`` (0.0 below the smallest float, ``inf`` above the largest), or None."""
    if log10_nfa is None or not math.isfinite(log10_nfa):
        return None if log10_nfa is None or math.isnan(log10_nfa) else (0.0 if log10_nfa < 0 else math.inf)
    return 10.0**log10_nfa if log10_nfa < 308 else math.inf


def nfa_text(log10_nfa: float | None) -> str:
    """A number of false alarms, readable at any magnitude: ``"1e-12"``, ``"3.2e-05"``, ``"0.041"``, ``"3.2"``, ``"2.1e+03"``.

    Formatted from the log10 so that an NFA of 1e-400 (below the smallest float) still prints.
    Returns ``"–"`` when the value is missing.
    """
    if log10_nfa is None or math.isnan(log10_nfa):
        return "–"
    if math.isinf(log10_nfa):
        return "0" if log10_nfa < 0 else "inf"
    exponent = math.floor(log10_nfa)
    mantissa = round(10.0 ** (log10_nfa - exponent), 1)
    if mantissa >= 10.0:
        mantissa, exponent = 1.0, exponent + 1
    if -2 <= exponent <= 1:
        return f"{mantissa * 10.0**exponent:.2g}"
    digits = f"{mantissa:g}"
    return f"{digits}e{'+' if exponent > 0 else '-'}{abs(exponent):02d}"


def p_text(p_level: float | None) -> str:
    """A survival probability with two significant digits (``"0.005"``, ``"1.2e-05"``)."""
    if p_level is None or not math.isfinite(p_level):
        return "–"
    return f"{p_level:.2g}"


def candidate_dict(candidate: SignificantRegion) -> dict:
    """JSON form of a candidate (as in ``regions.json``): its fields plus ``nfa = 10 ** log10_nfa``.

    Parameters
    ----------
    candidate : SignificantRegion
        One of :attr:`fgcd_cli.changes.detect.ChangeResult.candidates`.

    Returns
    -------
    dict with ``log10_nfa``, ``nfa``, ``p_level``, ``area_px``, ``centroid_xy`` (reference
    image pixels, x right, y down), ``peak_score`` and ``why`` (why it was not reported).
    """
    return {
        "log10_nfa": float(candidate.log10_nfa),
        "nfa": nfa_value(float(candidate.log10_nfa)),
        "p_level": float(candidate.p_level),
        "area_px": int(candidate.area_px),
        "centroid_xy": [float(candidate.centroid_xy[0]), float(candidate.centroid_xy[1])],
        "peak_score": float(candidate.peak_score),
        "why": candidate.why,
    }


def candidate_text(candidate: dict) -> str:
    """``"NFA = 3.2 (p = 0.0012) at (120, 45), 34 px"`` for a candidate in its JSON form."""
    x, y = candidate["centroid_xy"]
    return (
        f"NFA = {nfa_text(candidate.get('log10_nfa'))} (p = {p_text(candidate.get('p_level'))}) "
        f"at ({x:.0f}, {y:.0f}), {candidate['area_px']} px"
    )


def settings_epsilon(settings: dict | None) -> float:
    """The ε a result was decided with, from its ``settings`` (results written before it was recorded: the default)."""
    return float((settings or {}).get("epsilon") or EPSILON)


def is_significant(log10_nfa: float | None, *, epsilon: float) -> bool:
    """Whether a log10 NFA is below ``log10(epsilon)`` (the a-contrario rule's acceptance)."""
    if log10_nfa is None or math.isnan(log10_nfa):
        return False
    return log10_nfa < math.log10(epsilon)


def region_significance_text(log10_nfa: float | None, *, epsilon: float) -> str:
    """A reported region's significance: ``"NFA 1e-12"``, or ``"not significant (NFA ≥ 1)"`` without a significant seed."""
    if log10_nfa is None:
        return f"not significant (NFA ≥ {epsilon:g})"
    return f"NFA {nfa_text(log10_nfa)}"


def no_change_line(candidates: list[dict], *, epsilon: float) -> str:
    """The one line said when no region is reported, naming the strongest candidate.

    ``"no significant change; strongest candidate NFA = 3.2 (p = 0.0012) at (120, 45), 34 px"``.
    When that candidate is itself significant (the hysteresis rule did not report it),
    the line says so instead of "no significant change".
    """
    if not candidates:
        return "no significant change; no candidate region"
    strongest = candidates[0]
    if is_significant(strongest.get("log10_nfa"), epsilon=epsilon):
        return (
            f"no change reported, but the strongest candidate is significant: {candidate_text(strongest)}"
            " (not kept by the threshold rule; check it by eye)"
        )
    return f"no significant change; strongest candidate {candidate_text(strongest)}"


def set_aside_text(n_set_aside: int) -> str:
    """``"; 1 candidate set aside along an edge"`` (empty for none): what a verdict adds for the edge check."""
    if n_set_aside <= 0:
        return ""
    return f"; {n_set_aside} candidate{'s' if n_set_aside > 1 else ''} set aside along an edge"


def faint_text(settings: dict | None) -> str:
    """``"2 faint regions (contrast below 20 % in every lighting) not reported: listed among the candidates"``,
    or ``""``: what a report and the command line say about the contrast floor
    (:func:`fgcd_cli.changes.region_decision.faint_regions`)."""
    settings = settings or {}
    n = int(settings.get("low_contrast_regions") or 0)
    if n <= 0:
        return ""
    floor = float(settings.get("min_contrast") or 0.0)
    return (
        f"{n} faint region{'s' if n > 1 else ''} (contrast below {floor * 100:.0f} % in every lighting) "
        "not reported: listed among the candidates (--min-contrast 0 reports them)"
    )


def clipped_text(settings: dict | None) -> str:
    """``"2 regions explained by clipped pixels (...) not reported: listed among the candidates"``, or
    ``""``: what a report and the command line say about the clip check
    (:func:`fgcd_cli.changes.region_decision.clipped_regions`)."""
    n = int((settings or {}).get("clipped_regions") or 0)
    if n <= 0:
        return ""
    return (
        f"{n} region{'s' if n > 1 else ''} explained by clipped pixels (a lighting saturates there, or is too dark "
        "to measure, in both observations, and the rest shows no change) not reported: listed among the candidates"
    )


def contrast_text(contrast: float | None, lightings, n_lightings: int | None = None) -> str:
    """``"42 % (lightings 1, 3 of 4)"`` or ``""`` when not computed: a region's contrast at its strongest and
    the lightings that show it (:func:`fgcd_cli.changes.contrast.set_contrasts`)."""
    if contrast is None:
        return ""
    shown = ", ".join(str(k) for k in lightings or ()) if n_lightings != 1 else ""
    of = f" of {n_lightings}" if n_lightings else ""
    return f"{contrast * 100:.0f} %" + (f" (lighting{'s' if len(lightings) > 1 else ''} {shown}{of})" if shown else "")


def tone_text(tone: str | None, brightness_change: float | None) -> str:
    """``"darker by 28 %"``, ``"brighter by 15 %"``, ``"mixed"`` (the lightings disagree: relief shades
    both ways) or ``""`` when not computed (:func:`fgcd_cli.changes.regions.set_brightness_changes`)."""
    if tone is None or brightness_change is None:
        return ""
    if tone == "mixed":
        return "mixed"
    return f"{tone} by {abs(brightness_change) * 100:.0f} %"
