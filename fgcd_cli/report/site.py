"""The site page (``fgcd archive history``): a campaign's stations ranked by new or growing damage, self-contained HTML.

Each station gets its region tracks (area per visit, first seen, growth rate),
its change-over-time chart (:mod:`fgcd_cli.report.track_chart`) and the latest
change map as thumbnails (PNG embedded as base64: the page is one file).
"""

from __future__ import annotations

import html

import numpy as np

from fgcd_cli.report.html_page import _figure, _human_date, _page
from fgcd_cli.report.track_chart import track_area_png

__all__ = ["growth_text", "render_site_page", "tracks_section"]

_STATUS_ORDER = {"new": 0, "growing": 1, "shrinking": 2, "stable": 3, "gone": 4}


def growth_text(value: float | None, unit: str) -> str:
    """``+12.3 mm²/year``, or ``–`` when a region was seen at one visit only."""
    if value is None or not np.isfinite(value):
        return "–"
    return f"{round(value, 1) + 0.0:+.1f} {unit}/year"  # + 0.0: no "-0.0" for a stable region


def _area(value: float | None, unit: str) -> str:
    return "–" if value is None else f"{value:.1f} {unit}"


def _tracks_table(history) -> str:
    if not history.tracks:
        return '<p class="small">No change region at any analysed visit.</p>'
    rows = []
    latest = history.analysed[-1] if history.analysed else None
    for t in sorted(history.tracks, key=lambda t: (_STATUS_ORDER[t.status.value], t.id)):
        rows.append(
            f'<tr><td>{t.id}</td><td class="l">{html.escape(t.status.value)}</td>'
            f'<td class="l">{html.escape(_human_date(t.first_seen))}</td>'
            f"<td>{_area(t.areas.get(latest), history.unit)}</td>"
            f"<td>{_area(t.change_since_previous, history.unit)}</td>"
            f"<td>{html.escape(growth_text(t.growth_per_year, history.unit))}</td>"
            f"<td>({t.centroid_xy[0]:.0f}, {t.centroid_xy[1]:.0f})</td></tr>"
        )
    return (
        '<table><tr><th>region</th><th class="l">status</th><th class="l">first seen</th>'
        "<th>area now</th><th>since previous visit</th><th>growth rate</th><th>where (ref. px)</th></tr>"
        + "".join(rows)
        + "</table>"
    )


def tracks_section(history, *, figures: str = "") -> str:
    """HTML of one station's tracks: the area-vs-date chart (after ``figures``) and the table (also ``fgcd report``)."""
    chart = track_area_png(history.tracks, history.dates, unit=history.unit)
    missing = (
        f'<p class="small">Not analysed yet (run <code>fgcd archive analyze</code>): '
        f"{html.escape(', '.join(history.not_analysed))}</p>"
        if history.not_analysed
        else ""
    )
    return (
        '<div class="pair">'
        + figures
        + _figure(chart, f"Area of each region per visit ({history.unit})")
        + "</div>"
        + _tracks_table(history)
        + missing
    )


def _ranking_table(stations: list) -> str:
    rows = []
    for rank, s in enumerate(stations, 1):
        latest = _human_date(s.analysed[-1]) if s.analysed else "not analysed"
        rows.append(
            f'<tr><td>{rank}</td><td class="l"><a href="#st-{html.escape(s.station)}">'
            f'{html.escape(s.station)}</a></td><td class="l">{html.escape(latest)}</td>'
            f"<td>{s.count_new()}</td><td>{_area(s.new_area, s.unit)}</td><td>{s.count_growing()}</td>"
            f"<td>{_area(s.grown_area, s.unit)}</td><td>{len(s.tracks)}</td>"
            f"<td>{len(s.analysed)}/{len(s.analysed) + len(s.not_analysed)}</td></tr>"
        )
    return (
        '<table><tr><th>rank</th><th class="l">station</th><th class="l">latest visit</th>'
        "<th>new regions</th><th>new area</th><th>growing regions</th><th>area added</th>"
        "<th>regions tracked</th><th>visits analysed</th></tr>" + "".join(rows) + "</table>"
    )


def _station_block(s) -> str:
    parts = [
        f'<h2 id="st-{html.escape(s.station)}">Station {html.escape(s.station)}</h2>',
        f'<div class="sub">new: {s.count_new()} region(s), {_area(s.new_area, s.unit)} · growing: '
        f"{s.count_growing()} region(s), +{_area(s.grown_area, s.unit)} since the visit before</div>",
    ]
    overlay = (
        _figure(s.overlay_png, f"Latest change map ({_human_date(s.analysed[-1])})")
        if s.overlay_png and s.analysed
        else ""
    )
    parts.append(tracks_section(s, figures=overlay))
    return "".join(parts)


def render_site_page(*, site: str, stations: list) -> str:
    """HTML text of the site page: stations ranked by new plus grown area at their latest visit.

    Parameters
    ----------
    site : str
    stations : list of StationHistory
        Already ranked (:mod:`fgcd_cli.app.archive_history`), each with ``tracks``,
        ``dates``, ``unit``, ``new_area``, ``grown_area``, ``overlay_png``.
    """
    total = sum(len(s.analysed) + len(s.not_analysed) for s in stations)
    head = [
        f"<h1>Site {html.escape(site)}: change over time</h1>",
        f'<div class="sub">{len(stations)} station(s) · {total} visit(s) · ranked by new plus grown area at '
        "the latest visit (regions followed across visits by overlap in the reference image)</div>",
    ]
    if not stations:
        head.append('<div class="verdict cannot">No station in this campaign.</div>')
        return _page(f"Site {site}", "".join(head))
    head.append("<h2>Stations by new or growing damage</h2>" + _ranking_table(stations))
    return _page(f"Site {site}", "".join(head + [_station_block(s) for s in stations]))
