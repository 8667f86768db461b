"""Regions followed across visits (archive/tracking.py) and the site page, on masks drawn here."""

from __future__ import annotations

import shutil
import subprocess
from datetime import UTC, datetime, timedelta

import cv2
import numpy as np
import pytest

from fgcd_cli.archive.tracking import MATCH_DILATION_PX, TrackStatus, VisitRegions, track_regions

SHAPE = (120, 160)
T0 = datetime(2024, 1, 1, tzinfo=UTC)
MM2_PER_PX = 0.25


def _disc(cx: float, cy: float, r: float) -> np.ndarray:
    y, x = np.mgrid[0 : SHAPE[0], 0 : SHAPE[1]]
    return (x - cx) ** 2 + (y - cy) ** 2 <= r * r


def _visit(i: int, discs: list[tuple[float, float, float]], *, comparable: bool = True) -> VisitRegions:
    mask = np.zeros(SHAPE, bool)
    regions = []
    for cx, cy, r in discs:
        d = _disc(cx, cy, r)
        mask |= d
        ys, xs = np.nonzero(d)
        regions.append(
            {
                "area_px": int(d.sum()),
                "area_mm2": float(d.sum()) * MM2_PER_PX,
                "bbox_xywh": [int(xs.min()), int(ys.min()), int(np.ptp(xs)) + 1, int(np.ptp(ys)) + 1],
                "centroid_xy": [float(xs.mean()), float(ys.mean())],
            }
        )
    return VisitRegions(
        visit=f"v{i}",
        date=T0 + timedelta(days=91 * i),
        comparable=comparable,
        regions=regions if comparable else [],
        mask=mask if comparable else np.zeros(SHAPE, bool),
    )


def test_a_growing_region_a_new_one_and_a_stable_one_are_told_apart():
    # Region A grows (r 5 -> 7 -> 9, its centre moving by 1 px a visit: a relocation's residual);
    # B stays (r 6, within its boundary ring); C appears at the last visit far from both.
    visits = [
        _visit(0, []),
        _visit(1, [(40, 40, 5), (110, 80, 6)]),
        _visit(2, [(41, 40, 7), (110, 81, 6)]),
        _visit(3, [(42, 41, 9), (111, 80, 6), (60, 100, 4)]),
    ]
    tracks = track_regions(visits)
    assert [t.first_seen for t in tracks] == ["v1", "v1", "v3"]
    a, b, c = tracks
    assert (a.status, b.status, c.status) == (TrackStatus.GROWING, TrackStatus.STABLE, TrackStatus.NEW)
    assert a.unit == "mm²" and list(a.areas) == ["v1", "v2", "v3"]
    assert a.areas["v3"] == pytest.approx(_disc(42, 41, 9).sum() * MM2_PER_PX)
    # growth: the least-squares slope of area over time; the discs' areas rise ~pi (r^2) per 91 days
    t = np.array([91, 182, 273]) / 365.25
    y = np.array([_disc(40, 40, 5).sum(), _disc(41, 40, 7).sum(), _disc(42, 41, 9).sum()]) * MM2_PER_PX
    assert a.growth_per_year == pytest.approx(np.polyfit(t, y, 1)[0], rel=1e-9)
    assert abs(b.growth_per_year) < 0.1 * a.growth_per_year
    assert c.growth_per_year is None and c.areas == {"v3": pytest.approx(_disc(60, 100, 4).sum() * MM2_PER_PX)}


def test_a_region_missed_at_one_visit_keeps_its_track_and_an_uncomparable_visit_is_unknown():
    visits = [_visit(0, [(50, 50, 6)]), _visit(1, [], comparable=False), _visit(2, []), _visit(3, [(51, 50, 6)])]
    tracks = track_regions(visits)
    assert len(tracks) == 1
    areas = tracks[0].areas
    assert areas["v1"] is None and areas["v2"] == 0.0 and areas["v3"] > 0


def test_regions_farther_apart_than_the_match_tolerance_are_two_tracks():
    gap = MATCH_DILATION_PX + 2  # the discs' edges are this far apart at the second visit
    visits = [_visit(0, [(40, 60, 6)]), _visit(1, [(40 + 12 + gap, 60, 6)])]
    tracks = track_regions(visits)
    assert len(tracks) == 2 and tracks[0].status == TrackStatus.GONE and tracks[1].status == TrackStatus.NEW


def _stations():
    from fgcd_cli.app.archive_history import StationHistory, _latest_gains

    def station(name, visits):
        h = StationHistory(
            campaign="c",
            station=name,
            analysed=[v.visit for v in visits],
            dates={v.visit: v.date for v in visits},
            tracks=track_regions(visits),
        )
        _latest_gains(h)
        return h

    calm = station("calm", [_visit(0, [(50, 50, 6)]), _visit(1, [(50, 50, 6)])])
    worse = station("worse", [_visit(0, [(50, 50, 4)]), _visit(1, [(50, 50, 9)])])
    return calm, worse


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.mark.skipif(CHROMIUM is None, reason="headless Chromium not installed")
def test_site_page_renders_in_chromium(tmp_path):
    from fgcd_cli.report.site import render_site_page

    calm, worse = _stations()
    page = tmp_path / "site.html"
    page.write_text(render_site_page(site="test", stations=[worse, calm]), encoding="utf-8")
    shot = tmp_path / "shot.png"
    cmd = [
        CHROMIUM,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        f"--user-data-dir={tmp_path / 'profile'}",
        f"--screenshot={shot}",
        "--window-size=1400,2000",
        page.as_uri(),
    ]
    subprocess.run(cmd, capture_output=True, timeout=120)
    image = cv2.imread(str(shot))
    assert image is not None and image.shape[:2] == (2000, 1400)
    assert np.count_nonzero(image.max(axis=2) < 100) > 5000  # not blank: dark text, table rules, chart axes
    # the first region's line of the area-vs-date chart (#c2185b) is drawn
    b, g, r = (image[..., i].astype(int) for i in range(3))
    assert np.count_nonzero((abs(r - 194) < 30) & (g < 70) & (abs(b - 91) < 40)) > 30


def test_site_page_ranks_the_station_with_growing_damage_first():
    from fgcd_cli.report.site import render_site_page

    calm, worse = _stations()
    ranked = sorted([calm, worse], key=lambda s: -s.rank_score)
    assert [s.station for s in ranked] == ["worse", "calm"] and calm.rank_score == 0.0
    page = render_site_page(site="test", stations=ranked)
    assert page.index("st-worse") < page.index("st-calm") and page.count("data:image/png;base64,") == 2
