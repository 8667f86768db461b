"""Never silent: without a reported region, regions.json, the CLI and the report name the strongest candidate."""

import json
import re
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from rich.console import Console

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from changes.conftest import textured_scene, translate  # noqa: E402

from fgcd_cli.changes.regions import ChangeRegion  # noqa: E402
from fgcd_cli.changes.result import ChangeResult
from fgcd_cli.changes.significance import SignificantRegion  # noqa: E402
from fgcd_cli.changes.threshold import ThresholdInfo  # noqa: E402
from fgcd_cli.cli.diff_cmd import _render  # noqa: E402
from fgcd_cli.report.candidates import nfa_text  # noqa: E402
from fgcd_cli.report.figures import CANDIDATE_RGB, CHANGE_RGB, CUE_RGB, change_overlay  # noqa: E402
from fgcd_cli.report.products import diff_products, result_summary  # noqa: E402

FGCD = [sys.executable, "-c", "from fgcd_cli.cli.app import main; main()"]
SIZE = 128
CANDIDATES = [
    SignificantRegion(log10_nfa=0.5, p_level=0.0012, area_px=34, centroid_xy=(40.2, 90.7), peak_score=6.0),
    SignificantRegion(log10_nfa=1.3, p_level=0.004, area_px=12, centroid_xy=(100.0, 20.0), peak_score=5.0),
    SignificantRegion(log10_nfa=1.6, p_level=0.005, area_px=9, centroid_xy=(20.0, 20.0), peak_score=4.5),
    SignificantRegion(log10_nfa=2.0, p_level=0.005, area_px=5, centroid_xy=(64.0, 64.0), peak_score=4.2),
]


def _result(*, regions=(), labels=None, candidates=CANDIDATES) -> ChangeResult:
    """A comparable result built by hand: ``regions`` with ``labels``, and ``candidates``."""
    shape = (SIZE, SIZE)
    labels = np.zeros(shape, np.int32) if labels is None else labels
    return ChangeResult(
        comparable=True,
        score=np.ones(shape, np.float32),
        mask=labels > 0,
        labels=labels,
        valid=np.ones(shape, bool),
        regions=list(regions),
        registration=None,
        threshold=ThresholdInfo(
            method="hysteresis",
            median=1.0,
            sigma_upper=0.2,
            k_high=20,
            k_low=10,
            high=5.0,
            low=3.0,
            changed_fraction=float((labels > 0).mean()),
        ),
        settings={"decision": "hysteresis", "epsilon": 1.0},
        candidates=list(candidates),
    )


def _scene() -> np.ndarray:
    return np.repeat(textured_scene(SIZE)[:, :, None], 3, axis=2)


def _printed(data: dict) -> str:
    console = Console(record=True, width=200, color_system=None)
    _render(data)(console)
    return console.export_text()


def test_regions_json_carries_candidates_and_region_significance():
    labels = np.zeros((SIZE, SIZE), np.int32)
    labels[10:20, 60:70] = 1
    region = ChangeRegion(
        id=1,
        area_px=100,
        area_mm2=None,
        bbox_xywh=(60, 10, 10, 10),
        centroid_xy=(64.5, 14.5),
        mean_score=8.0,
        max_score=12.0,
        log10_nfa=-12.0,
        cue="relief",
    )
    files = diff_products(ref_images=[_scene()], cur_images=[_scene()], result=_result(regions=[region], labels=labels))
    summary = json.loads(files["regions.json"])
    assert summary["regions"][0]["log10_nfa"] == -12.0 and summary["regions"][0]["cue"] == "relief"
    assert summary["regions"][0]["nfa"] == pytest.approx(1e-12)
    assert len(summary["candidates"]) == len(CANDIDATES)
    first = summary["candidates"][0]
    assert first == {
        "log10_nfa": 0.5,
        "nfa": pytest.approx(10**0.5),
        "p_level": 0.0012,
        "area_px": 34,
        "centroid_xy": [40.2, 90.7],
        "peak_score": 6.0,
        "why": "",  # built by hand here; the detector says why (tests/changes/test_clip_check.py)
    }


def test_report_without_region_says_no_significant_change_and_names_the_candidate():
    html = diff_products(ref_images=[_scene()], cur_images=[_scene()], result=_result())["report.html"].decode()
    verdict = re.search(r'<div class="verdict[^"]*">(.*?)</div>', html).group(1)
    assert "No significant change" in verdict and "No change found" not in html
    assert nfa_text(0.5) == "3.2" and "NFA = 3.2" in verdict
    assert "(40, 91)" in verdict and "34 px" in verdict and "p = 0.0012" in verdict
    assert "Candidates not reported" in html and html.count("<td>c") == len(CANDIDATES)
    assert "dashed amber" in html  # the overlay's legend says how candidates are drawn


def test_report_says_so_when_the_unreported_candidate_is_significant():
    significant = SignificantRegion(log10_nfa=-3.0, p_level=1e-4, area_px=20, centroid_xy=(50.0, 50.0), peak_score=9.0)
    html = diff_products(ref_images=[_scene()], cur_images=[_scene()], result=_result(candidates=[significant]))[
        "report.html"
    ].decode()
    assert "No change reported" in html and "NFA = 1e-03" in html and "No significant change" not in html


def test_report_without_candidate_is_still_explicit():
    html = diff_products(ref_images=[_scene()], cur_images=[_scene()], result=_result(candidates=[]))[
        "report.html"
    ].decode()
    assert "No significant change" in html and "no candidate region" in html
    assert "Candidates not reported" not in html


def test_region_table_has_significance_and_cue_columns():
    labels = np.zeros((SIZE, SIZE), np.int32)
    labels[10:20, 60:70] = 1
    labels[80:86, 10:16] = 2
    regions = [
        ChangeRegion(
            id=1,
            area_px=100,
            area_mm2=None,
            bbox_xywh=(60, 10, 10, 10),
            centroid_xy=(64.5, 14.5),
            mean_score=8.0,
            max_score=12.0,
            log10_nfa=-12.0,
            cue="colour",
        ),
        ChangeRegion(
            id=2,
            area_px=36,
            area_mm2=None,
            bbox_xywh=(10, 80, 6, 6),
            centroid_xy=(12.5, 82.5),
            mean_score=6.0,
            max_score=7.0,
        ),
    ]
    html = diff_products(ref_images=[_scene()], cur_images=[_scene()], result=_result(regions=regions, labels=labels))[
        "report.html"
    ].decode()
    assert "<th>significance (NFA)</th>" in html and '<th class="l">cue</th>' in html
    assert "<td>1e-12</td>" in html and '<td class="l">colour</td>' in html
    assert "not significant (NFA ≥ 1)" in html  # region 2 holds no significant seed
    assert "green = colour, magenta = no cue" in html  # the overlay's cue legend


def test_overlay_draws_candidates_faintly_and_regions_by_cue():
    image = np.full((SIZE, SIZE, 3), 0.5, np.float32)
    labels = np.zeros((SIZE, SIZE), np.int32)
    labels[10:20, 60:70] = 1
    labels[100:110, 100:110] = 2
    regions = [
        ChangeRegion(
            id=1,
            area_px=100,
            area_mm2=None,
            bbox_xywh=(60, 10, 10, 10),
            centroid_xy=(64.5, 14.5),
            mean_score=8.0,
            max_score=12.0,
            cue="relief",
        ),
        ChangeRegion(
            id=2,
            area_px=100,
            area_mm2=None,
            bbox_xywh=(100, 100, 10, 10),
            centroid_xy=(104.5, 104.5),
            mean_score=8.0,
            max_score=12.0,
        ),
    ]
    plain = change_overlay(image, labels, regions)
    drawn = change_overlay(image, labels, regions, candidates=CANDIDATES[:1])
    # The candidate's circle is drawn around its centroid, nowhere near the regions, and only part-way
    # towards the candidate colour (half-transparent), with no pixel of the regions' tint.
    touched = np.any(drawn != plain, axis=2)
    ys, xs = np.nonzero(touched)
    assert touched.sum() > 20 and np.hypot(xs - 40, ys - 91).max() < 25  # circle and "c1" label
    grey = plain[touched].astype(float)
    changed = drawn[touched].astype(float)
    towards = np.linalg.norm(changed - grey, axis=1) / np.linalg.norm(np.array(CANDIDATE_RGB) - grey, axis=1)
    assert towards.max() < 0.8
    assert not np.all(drawn[touched] == CHANGE_RGB, axis=1).any()
    # Relief regions are outlined in their cue colour, regions without a cue in magenta.
    assert np.all(drawn[10, 60:70] == CUE_RGB["relief"], axis=1).any()
    assert np.all(drawn[100, 100:110] == CHANGE_RGB, axis=1).any()


def test_cli_without_region_prints_the_strongest_candidates():
    printed = _printed(result_summary(_result()) | {"output": "out"})
    lines = printed.splitlines()
    assert lines[0] == "no significant change; strongest candidate NFA = 3.2 (p = 0.0012) at (40, 91), 34 px"
    assert lines[1].strip() == "candidate 2: NFA = 20 (p = 0.004) at (100, 20), 12 px"
    assert lines[2].strip().startswith("candidate 3: NFA = 40")
    assert "candidate 4" not in printed  # the strongest three only; all are in regions.json


def test_cli_region_lines_show_significance_and_cue():
    labels = np.zeros((SIZE, SIZE), np.int32)
    labels[10:20, 60:70] = 1
    labels[80:86, 10:16] = 2
    regions = [
        ChangeRegion(
            id=1,
            area_px=100,
            area_mm2=0.25,
            bbox_xywh=(60, 10, 10, 10),
            centroid_xy=(64.5, 14.5),
            mean_score=8.0,
            max_score=12.0,
            log10_nfa=-12.0,
            cue="both",
        ),
        ChangeRegion(
            id=2,
            area_px=36,
            area_mm2=None,
            bbox_xywh=(10, 80, 6, 6),
            centroid_xy=(12.5, 82.5),
            mean_score=6.0,
            max_score=7.0,
        ),
    ]
    printed = _printed(result_summary(_result(regions=regions, labels=labels)) | {"output": "out"})
    # strength: the peak score over the detection level (5.0 here: 12 / 5 and 7 / 5)
    assert "#1: strength 2.4, 100 px, 0.250 mm² at (64, 14), NFA 1e-12, both" in printed  # to the 0.0025 mm²
    assert "#2: strength 1.4, 36 px at (12, 82), not significant (NFA ≥ 1)" in printed
    assert "strongest candidate" not in printed
    # listed strongest first, not largest first: a small strong region before a large weak one
    regions[1] = replace(regions[1], max_score=30.0)
    printed = _printed(result_summary(_result(regions=regions, labels=labels)) | {"output": "out"})
    assert printed.index("#2: strength 6.0") < printed.index("#1: strength 2.4")


def test_diff_json_output_is_one_object_with_candidates(tmp_path):
    ref = textured_scene(192)
    for name, image in (("ref", ref), ("cur", translate(ref, 1.2, -0.7))):
        cv2.imwrite(str(tmp_path / f"{name}.png"), np.round(image * 255).astype(np.uint8))
    out = tmp_path / "out"
    proc = subprocess.run(
        [
            *FGCD,
            "diff",
            "--ref",
            str(tmp_path / "ref.png"),
            "--cur",
            str(tmp_path / "cur.png"),
            "-o",
            str(out),
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    assert isinstance(data["candidates"], list)
    assert json.loads((out / "regions.json").read_text())["candidates"] == data["candidates"]
    for candidate in data["candidates"]:
        assert candidate["nfa"] == pytest.approx(10 ** candidate["log10_nfa"])
    human = subprocess.run(
        [*FGCD, "diff", "--ref", str(tmp_path / "ref.png"), "--cur", str(tmp_path / "cur.png"), "-o", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    if not data["regions"]:
        assert human.stdout.startswith("no significant change; ")


def _set_aside_result() -> ChangeResult:
    """No reported region; the edge check set one region aside."""
    result = _result()
    result.edge_explained = np.zeros((SIZE, SIZE), bool)
    result.edge_explained[30:34, 40:70] = True
    result.settings["edge_explained_regions"] = 1
    return result


def test_set_aside_region_is_named_in_the_verdict_and_the_cli_summary():
    result = _set_aside_result()
    html = diff_products(ref_images=[_scene()], cur_images=[_scene()], result=result)["report.html"].decode()
    verdict = re.search(r'<div class="verdict[^"]*">(.*?)</div>', html, re.S).group(1)
    assert "0 changes; 1 candidate set aside along an edge" in verdict
    printed = _printed({**result_summary(result), "output": "out"})
    assert "0 changes; 1 candidate set aside along an edge" in printed


def test_verdict_has_no_set_aside_note_when_the_check_set_nothing_aside():
    html = diff_products(ref_images=[_scene()], cur_images=[_scene()], result=_result())["report.html"].decode()
    assert "set aside along an edge" not in html
    assert "set aside" not in _printed({**result_summary(_result()), "output": "out"})


def test_the_report_names_the_strongest_region_and_lists_regions_strongest_first():
    from fgcd_cli.report.html import ReportContext, render_diff_report

    labels = np.zeros((SIZE, SIZE), np.int32)
    labels[5:95, 2:8] = 1  # a long weak strip along an edge: the largest
    labels[60:66, 60:66] = 2  # a small strong loss
    strip = ChangeRegion(
        id=1,
        area_px=540,
        area_mm2=None,
        bbox_xywh=(2, 5, 6, 90),
        centroid_xy=(4.5, 49.5),
        mean_score=6.0,
        max_score=12.0,
    )
    loss = ChangeRegion(
        id=2,
        area_px=36,
        area_mm2=None,
        bbox_xywh=(60, 60, 6, 6),
        centroid_xy=(62.5, 62.5),
        mean_score=60.0,
        max_score=120.0,
    )
    image = np.full((SIZE, SIZE), 0.5, np.float32)
    page = render_diff_report(
        ref_image=image, cur_image=image, result=_result(regions=[strip, loss], labels=labels), context=ReportContext()
    )
    assert "Strongest: region 2, 24.0 × the detection level" in page
    table = page[page.index("<h2>Changed regions</h2>") :]
    assert table.index("<tr><td>2</td>") < table.index("<tr><td>1</td>")
