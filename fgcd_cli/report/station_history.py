"""The station history page (``fgcd report``): a station's visits against its reference, self-contained HTML.

:class:`VisitSummary` is what the page shows of one visit; :func:`render_station_history`
writes the page: the latest visit's verdict, the change over time, the regions followed
across visits, one table row and one change-map thumbnail per visit.
"""

from __future__ import annotations

import html
from dataclasses import dataclass, field

import numpy as np

from fgcd_cli.report.areas import area_mm2_text
from fgcd_cli.report.charts import history_png
from fgcd_cli.report.html_page import _figure, _human_date, _img, _page


def _fmt(value, digits: int = 2) -> str:
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "–"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return html.escape(str(value))


@dataclass(kw_only=True)
class VisitSummary:
    """What the station history shows for one visit."""

    name: str
    date: str
    comparable: bool
    reason: str = ""
    regions: int = 0
    changed_px: int = 0
    changed_mm2: float | None = None
    afd_px: float | None = None
    overlay_png: bytes | None = None
    extra: dict = field(default_factory=dict)


def render_station_history(
    *,
    station: str,
    site: str,
    reference_date: str,
    reference_png: bytes | None,
    visits: list[VisitSummary],
    tracks_html: str = "",
) -> str:
    """HTML text of a station's history across visits (one row and one thumbnail per visit).

    ``tracks_html``: the regions followed across visits (:func:`fgcd_cli.report.site.tracks_section`).
    """
    visits = [VisitSummary(**{**v.__dict__, "date": _human_date(v.date)}) for v in visits]
    reference_date = _human_date(reference_date)
    parts = [
        f"<h1>Station {html.escape(station)}: history</h1>",
        f'<div class="sub">Site {html.escape(site)} · reference observation {html.escape(reference_date)} · '
        f"{len(visits)} visit{'s' if len(visits) != 1 else ''}</div>",
    ]
    damaged = [v.name for v in visits if v.extra.get("damaged")]
    if damaged:
        parts.append(
            f'<div class="verdict cannot">Damaged or missing visit(s), not compared: {html.escape(", ".join(damaged))} '
            "(each row says why; run <code>fgcd campaign verify</code>).</div>"
        )
    if not visits:
        parts.append('<div class="verdict cannot">No visit yet: only the reference observation exists.</div>')
    else:
        parts.append(_latest_verdict(visits[-1]))
        parts += _change_over_time(visits)
        if tracks_html:
            parts.append("<h2>Regions over time</h2>" + tracks_html)
        parts.append(_visits_table(visits))
        parts += _change_maps(visits, reference_png, reference_date)
    return _page(f"Station {station} history", "".join(parts))


def _latest_verdict(last: VisitSummary) -> str:
    """The page's verdict: what the latest visit found against the reference, or why it was not compared.

    Parameters
    ----------
    last : VisitSummary
        The latest visit (its date already human-readable).

    Returns
    -------
    str
        One ``<div class="verdict ...">`` element.
    """
    if last.comparable:
        area = (
            area_mm2_text(last.changed_mm2, last.changed_px)
            if last.changed_mm2 is not None
            else f"{last.changed_px} px"
        )
        cls = "verdict" if last.regions else "verdict none"
        return (
            f'<div class="{cls}">Latest visit {html.escape(last.date)}: <b>{last.regions} changed region(s)</b>, '
            f"{area} against the reference.</div>"
        )
    return f'<div class="verdict cannot">Latest visit {html.escape(last.date)} not compared: {html.escape(last.reason)}</div>'


def _change_over_time(visits: list[VisitSummary]) -> list[str]:
    """The "Change over time" chart of the compared visits (changed area and AFD per visit).

    Parameters
    ----------
    visits : list of VisitSummary
        Every visit, oldest first; those not compared are left out of the chart.

    Returns
    -------
    list of str
        The section's heading and chart, or nothing when no visit was compared.
    """
    comparable = [v for v in visits if v.comparable]
    if not comparable:
        return []
    chart = history_png(
        [v.date for v in comparable],
        [v.changed_mm2 for v in comparable],
        [v.changed_px for v in comparable],
        [v.afd_px for v in comparable],
    )
    return ["<h2>Change over time</h2>", _img(chart, "history")]


def _visits_table(visits: list[VisitSummary]) -> str:
    """The "Visits" table: one row per visit with its status, regions, changed area and AFD.

    Parameters
    ----------
    visits : list of VisitSummary
        Every visit, oldest first (damaged ones say so in their status).

    Returns
    -------
    str
        The section's heading and table.
    """
    rows = []
    for v in visits:
        area_mm2 = area_mm2_text(v.changed_mm2, v.changed_px, unit=False)
        status = (
            "compared"
            if v.comparable
            else f"{'damaged' if v.extra.get('damaged') else 'not compared'}: {html.escape(v.reason)}"
        )
        rows.append(
            f'<tr><td class="l">{html.escape(v.date)}</td><td class="l">{status}</td><td>{v.regions}</td>'
            f"<td>{v.changed_px}</td><td>{area_mm2}</td><td>{_fmt(v.afd_px)}</td></tr>"
        )
    return (
        '<h2>Visits</h2><table><tr><th class="l">visit</th><th class="l">status</th><th>regions</th>'
        "<th>changed px</th><th>changed mm²</th><th>AFD (px)</th></tr>" + "".join(rows) + "</table>"
    )


def _change_maps(visits: list[VisitSummary], reference_png: bytes | None, reference_date: str) -> list[str]:
    """The "Change maps per visit" thumbnails: the reference, then each visit's change map.

    Parameters
    ----------
    visits : list of VisitSummary
        Every visit, oldest first; those without a change map are left out.
    reference_png : bytes or None
        The reference image as PNG.
    reference_date : str
        The reference observation's date (human-readable), its caption.

    Returns
    -------
    list of str
        The section's heading and figures, or nothing when there is no image to show.
    """
    thumbs = [v for v in visits if v.overlay_png]
    if not (thumbs or reference_png):
        return []
    parts = ['<h2>Change maps per visit</h2><div class="pair">']
    if reference_png:
        parts.append(_figure(reference_png, f"Reference {reference_date}"))
    for v in thumbs:
        parts.append(_figure(v.overlay_png, f"Visit {v.date}: {v.regions} region(s)"))
    parts.append("</div>")
    return parts
