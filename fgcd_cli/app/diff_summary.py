"""The lines that summarise a diff's result on a terminal (``fgcd diff``'s text output).

A region with its area and significance, the "no significant change" line with
the strongest candidates, the regions an edge check set aside: the same wording
as the HTML report (:mod:`fgcd_cli.report.areas`, :mod:`fgcd_cli.report.candidates`).
"""

from __future__ import annotations

__all__ = ["no_change_lines", "region_line", "result_epsilon", "set_aside_line", "strongest_first"]


def strongest_first(regions: list[dict]) -> list[dict]:
    """A diff's regions (JSON form) strongest first, as the report lists them (``changes.regions.by_evidence``)."""
    from fgcd_cli.changes.regions import evidence_rank

    return sorted(regions, key=lambda r: evidence_rank(r["max_score"], r["area_px"], r["id"]))


def region_line(region: dict, *, epsilon: float) -> str:
    """``#1: strength 24.1, 340 px, 3.40 mm² at (200, 60), NFA 1e-12, colour, darker by 28 %`` (what is known)."""
    from fgcd_cli.report.areas import area_mm2_text
    from fgcd_cli.report.candidates import contrast_text, region_significance_text, tone_text

    mm2 = f", {area_mm2_text(region['area_mm2'], region['area_px'])}" if region.get("area_mm2") is not None else ""
    x, y = region["centroid_xy"]
    cue = f", [bold]{region['cue']}[/bold]" if region.get("cue") else ""
    significance = region_significance_text(region.get("log10_nfa"), epsilon=epsilon)
    strength = f"strength {region['strength']:.1f}, " if region.get("strength") is not None else ""
    tone = tone_text(region.get("tone"), region.get("brightness_change"))
    tone = f", {tone}" if tone else ""
    contrast = contrast_text(region.get("contrast"), region.get("lightings"))
    contrast = f", contrast {contrast}" if contrast else ""
    return (
        f"#{region['id']}: {strength}{region['area_px']} px{mm2} at ({x:.0f}, {y:.0f}), "
        f"{significance}{cue}{tone}{contrast}"
    )


def no_change_lines(candidates: list[dict], *, epsilon: float, more: int = 2) -> list[str]:
    """The "no significant change; strongest candidate ..." line and up to ``more`` further candidates."""
    from fgcd_cli.report.candidates import candidate_text, no_change_line

    lines = [no_change_line(candidates, epsilon=epsilon)]
    lines += [f"  candidate {k}: {candidate_text(c)}" for k, c in enumerate(candidates[1 : 1 + more], start=2)]
    return lines


def set_aside_line(regions: int, set_aside: int) -> str:
    """``N changes`` and the ``set_aside`` regions the edge check explained (shown in cyan in the report)."""
    from fgcd_cli.report.candidates import set_aside_text

    return (
        f"{regions} change{'s' if regions != 1 else ''}{set_aside_text(set_aside)} "
        f"(cyan in the report; --edge-check 0 reports {'them' if set_aside != 1 else 'it'})"
    )


def faint_line(data: dict) -> str:
    """The regions the contrast floor left out of a diff result (its JSON form), or ``""``."""
    from fgcd_cli.report.candidates import faint_text

    return faint_text(data.get("settings"))


def clipped_line(data: dict) -> str:
    """The regions the clip check left out of a diff result (its JSON form), or ``""``."""
    from fgcd_cli.report.candidates import clipped_text

    return clipped_text(data.get("settings"))


def result_epsilon(data: dict) -> float:
    """The ε a diff result (its JSON form) was decided with."""
    from fgcd_cli.report.candidates import settings_epsilon

    return settings_epsilon(data.get("settings"))


def warp_line(data: dict) -> str:
    """``warp: by the reference depth; visit measured ...`` for a campaign diff ("" for bare images)."""
    from fgcd_cli.report.pose_check import geometry_text

    settings = data.get("settings") or {}
    return f"warp: {geometry_text(settings)}" if "geometry" in settings else ""
