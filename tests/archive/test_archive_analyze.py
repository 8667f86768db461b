"""`fgcd archive analyze` on three small simulated campaigns, on a real Dask cluster (worker processes, 127.0.0.1).

The archive must give each visit the regions `fgcd diff -c` gives it (the same
use case, run serially here on a copy), skip what is up to date, redo only a
visit whose results were deleted, report a visit with a damaged image while the
others complete, and finish the rest after a run killed midway.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

distributed = pytest.importorskip("distributed")

from fgcd_cli.app.archive import ArchiveRequest, analyze_archive, plan_archive  # noqa: E402
from fgcd_cli.app.archive_task import VisitStatus  # noqa: E402
from fgcd_cli.app.diff import CampaignDiffRequest, run_campaign  # noqa: E402
from fgcd_cli.archive.discovery import archive_visits, find_campaigns  # noqa: E402
from fgcd_cli.archive.freshness import ANALYSIS_RELPATH, Freshness  # noqa: E402
from fgcd_cli.bench.archive.data import SyntheticArchiveConfig, build_synthetic_archive  # noqa: E402
from fgcd_cli.campaign import schema  # noqa: E402
from fgcd_cli.campaign.store import open_campaign  # noqa: E402

REGIONS = schema.change_relpath(schema.REGIONS_JSON)
# 256 x 192 px at 800 px focal: the benchmark's 1.5 mm per pixel on a smaller field, a few seconds per visit.
CONFIG = SyntheticArchiveConfig(campaigns=3, stations=1, visits=2, changes=1, width=256, height=192, focal_px=800.0)


@pytest.fixture(scope="module")
def cluster():
    with distributed.LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
        scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
    ) as local:
        yield local


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    """Three campaigns x 1 station x 2 visits (the second with one change), never analysed."""
    root = tmp_path_factory.mktemp("archive") / "pristine"
    build_synthetic_archive(root, CONFIG)
    return root


@pytest.fixture(scope="module")
def expected(pristine, tmp_path_factory):
    """Each visit's regions from the diff use case itself, run serially on a copy."""
    copy = tmp_path_factory.mktemp("serial") / "archive"
    shutil.copytree(pristine, copy)
    out = {}
    for key in archive_visits(find_campaigns([copy])):
        data = run_campaign(
            request=CampaignDiffRequest(campaign=Path(key.campaign), station=key.station, visit=key.visit)
        )
        out[(Path(key.campaign).name, key.station, key.visit)] = _regions(data)
    return out


def _regions(summary: dict) -> list[tuple]:
    return [(r["area_px"], tuple(r["bbox_xywh"])) for r in summary["regions"]]


def _same_regions(got: dict, want: dict) -> bool:
    """The same regions visit by visit, up to the detector's own run-to-run variation.

    Two runs of the diff on the same inputs, in one process or two, may differ by
    a pixel at a region's edge (the registration is not bit-deterministic run to
    run: docs/benchmarks.md, "Archive analysis on Dask (`fgcd bench archive`)").
    So: the same number of regions per visit, each box within 1 px, each area
    within the region's one-pixel boundary ring (its box perimeter).
    """
    if got.keys() != want.keys():
        return False
    for key in want:
        if len(got[key]) != len(want[key]):
            return False
        for (area_a, box_a), (area_b, box_b) in zip(sorted(got[key]), sorted(want[key])):
            if max(abs(a - b) for a, b in zip(box_a, box_b)) > 1 or abs(area_a - area_b) > 2 * (box_b[2] + box_b[3]):
                return False
    return True


def _stored_regions(root: Path) -> dict:
    out = {}
    for key in archive_visits(find_campaigns([root])):
        visit = open_campaign(Path(key.campaign)).station(key.station).visit(key.visit)
        out[(Path(key.campaign).name, key.station, key.visit)] = _regions(visit.json(REGIONS))
    return out


def _copy(pristine: Path, tmp_path: Path, *only: str) -> Path:
    root = tmp_path / "archive"
    if only:
        for name in only:
            shutil.copytree(pristine / name, root / name)
    else:
        shutil.copytree(pristine, root)
    return root


def test_two_workers_match_the_diff_skip_when_up_to_date_and_redo_only_what_was_deleted(
    pristine, expected, cluster, tmp_path
):
    root = _copy(pristine, tmp_path)
    request = ArchiveRequest(roots=[root], scheduler=cluster.scheduler_address)
    first = analyze_archive(request)
    assert (first.count(VisitStatus.DONE), first.count(VisitStatus.FAILED)) == (6, 0)
    assert first.workers == 2 and first.scheduler.startswith("tcp://127.0.0.1:")
    assert _same_regions(_stored_regions(root), expected)
    assert sum(bool(r) for r in expected.values()) >= 2  # not a vacuous comparison: changed visits show regions
    assert not _same_regions({k: [] for k in expected}, expected)
    again = analyze_archive(request)
    assert again.count(VisitStatus.SKIPPED) == 6
    victim = (
        root
        / "site-1"
        / "stations"
        / "S01"
        / "visits"
        / sorted(os.listdir(root / "site-1" / "stations" / "S01" / "visits"))[-1]
    )
    shutil.rmtree(victim / schema.CHANGES_DIR)
    _, planned = plan_archive(request)
    assert [p.key.visit for p in planned if p.needs_work] == [victim.name]
    third = analyze_archive(request)
    redone = [o for o in third.outcomes if o.status == VisitStatus.DONE]
    assert [(Path(o.key.campaign).name, o.key.visit) for o in redone] == [("site-1", victim.name)]
    assert third.count(VisitStatus.SKIPPED) == 5 and _same_regions(_stored_regions(root), expected)
    _check_history(root, _stored_regions(root))


def _check_history(root: Path, stored: dict) -> None:
    """Each region of a station's changed (second) visit starts a track there; every campaign has its site page."""
    from fgcd_cli.app.archive_history import HistoryRequest, archive_history

    sites = archive_history(HistoryRequest(roots=[root]))
    assert len(sites) == 3 and all(Path(site.page).is_file() for site in sites)
    for site in sites:
        (station,) = site.stations
        first, second = station.analysed
        if not stored[(Path(site.campaign).name, "S01", first)]:
            assert len(station.tracks) == len(stored[(Path(site.campaign).name, "S01", second)])
            assert all(t.first_seen == second and t.status.value == "new" for t in station.tracks)


def test_one_worker_reports_a_damaged_image_and_completes_the_other_visit(pristine, expected, tmp_path):
    root = _copy(pristine, tmp_path, "site-2")
    visits = root / "site-2" / "stations" / "S01" / "visits"
    first, second = sorted(os.listdir(visits))
    image = visits / first / "images" / "led-6.png"
    data = bytearray(image.read_bytes())
    data[len(data) // 2] ^= 0xFF  # one flipped byte: the PNG may still decode, its checksum no longer matches
    image.write_bytes(bytes(data))
    result = analyze_archive(ArchiveRequest(roots=[root], workers=1))
    assert result.workers == 1
    status = {o.key.visit: o for o in result.outcomes}
    assert status[first].status == VisitStatus.FAILED
    assert "led-6.png" in status[first].reason and "checksum" in status[first].reason
    assert "\n" not in status[first].reason
    assert status[second].status == VisitStatus.DONE
    stored = open_campaign(root / "site-2").station("S01").visit(second).json(REGIONS)
    key = ("site-2", "S01", second)
    assert _same_regions({key: _regions(stored)}, {key: expected[key]})
    assert not (visits / first / ANALYSIS_RELPATH).exists()


def test_cli_dry_run_lists_the_work_and_bad_roots_are_one_line(pristine, tmp_path):
    env = {**os.environ, "COLUMNS": "200"}
    fgcd = str(Path(sys.executable).parent / "fgcd")
    out = subprocess.run(
        [fgcd, "archive", "analyze", str(pristine), "--dry-run", "--json"],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    assert out.returncode == 0, out.stderr
    data = json.loads(out.stdout)
    assert (data["campaigns"], data["visits"], data["to_do"]) == (3, 6, 6)
    assert {p["state"] for p in data["planned"]} == {Freshness.NOT_ANALYSED.value}
    bad = subprocess.run(
        [fgcd, "archive", "analyze", str(tmp_path / "nowhere")], capture_output=True, text=True, timeout=120, env=env
    )
    assert bad.returncode == 2 and bad.stderr.strip().count("\n") == 0 and "Traceback" not in bad.stderr
    # nobody listens on port 9 (discard): an unreachable scheduler is one line and the operating-system code
    lost = subprocess.run(
        [fgcd, "archive", "analyze", str(pristine), "--scheduler", "tcp://127.0.0.1:9"],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    assert lost.returncode == 1 and "Dask scheduler" in lost.stderr and lost.stderr.strip().count("\n") == 0


@pytest.mark.slow
def test_a_run_killed_midway_is_finished_by_the_next(pristine, expected, cluster, tmp_path):
    root = _copy(pristine, tmp_path)
    fgcd = str(Path(sys.executable).parent / "fgcd")
    proc = subprocess.Popen(
        [fgcd, "archive", "analyze", str(root), "--workers", "1", "--json"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    records = lambda: sorted(root.glob(f"*/stations/*/visits/*/{ANALYSIS_RELPATH}"))  # noqa: E731
    deadline = time.monotonic() + 240
    while not records() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)  # the whole run: client, scheduler and worker processes
    proc.wait(timeout=30)
    finished_before = len(records())
    assert 1 <= finished_before < 6
    result = analyze_archive(ArchiveRequest(roots=[root], scheduler=cluster.scheduler_address))
    assert result.count(VisitStatus.FAILED) == 0
    assert result.count(VisitStatus.SKIPPED) == finished_before
    assert result.count(VisitStatus.DONE) == 6 - finished_before
    assert _same_regions(_stored_regions(root), expected)


@pytest.mark.slow
def test_ctrl_c_cancels_the_rest_in_one_line_and_the_next_run_finishes(pristine, expected, cluster, tmp_path):
    root = _copy(pristine, tmp_path)
    fgcd = str(Path(sys.executable).parent / "fgcd")
    proc = subprocess.Popen(
        [fgcd, "archive", "analyze", str(root), "--workers", "1"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    deadline = time.monotonic() + 240
    while not list(root.glob(f"*/stations/*/visits/*/{ANALYSIS_RELPATH}")) and time.monotonic() < deadline:
        time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130
    assert err.strip().count("\n") == 0 and err.startswith("interrupted") and "Traceback" not in err
    result = analyze_archive(ArchiveRequest(roots=[root], scheduler=cluster.scheduler_address))
    assert result.count(VisitStatus.FAILED) == 0 and result.count(VisitStatus.SKIPPED) >= 1
    assert _same_regions(_stored_regions(root), expected)


@pytest.mark.slow
def test_one_worker_matches_the_diff_on_every_visit(pristine, expected, tmp_path):
    root = _copy(pristine, tmp_path)
    result = analyze_archive(ArchiveRequest(roots=[root], workers=1))
    assert result.workers == 1 and result.count(VisitStatus.DONE) == 6
    assert _same_regions(_stored_regions(root), expected)
