"""``fgcd bench paper``: the plan, resuming from the per-run files, the summary keys and the report."""

import json
import math

import pytest

from fgcd_cli.bench import paper
from fgcd_cli.bench.paper_report import markdown


def test_quick_plan_covers_table2_table5_and_the_led_sweep():
    runs = paper.plan(quick=True)
    labels = {(r.experiment, r.label) for r in runs}
    assert labels == {("table2", "racr"), ("table2", "acr"), ("table5", "racr-serial"), ("fig7", "racr"),
                      ("fig7", "acr")}
    # every method of a case starts from the same pose (the paper's "same initial pose")
    t2 = [r for r in runs if r.experiment in ("table2", "table5")]
    for case in {r.case for r in t2}:
        starts = {(r.offset_mm, r.offset_deg, r.session_seed) for r in t2 if r.case == case}
        assert len(starts) == 1
    sweep = [r for r in runs if r.experiment == "fig7"]
    assert all(r.reference_light == "led:12" for r in sweep)
    assert len({r.path(__import__("pathlib").Path("o")) for r in runs}) == len(runs)


def test_full_plan_is_the_20_cases_and_72_sweep_positions():
    runs = paper.plan(quick=False)
    assert len({r.case for r in runs if r.experiment == "table2"}) == 20
    assert len([r for r in runs if r.experiment == "fig7" and r.label == "racr"]) == 6 * 12


def fake_result(spec, afd):
    return {"experiment": spec.experiment, "case": spec.case, "label": spec.label, "method": str(spec.method),
            "afd_px": afd, "success": afd < 3.0, "adjustments": 4, "session_s": 40.0 if spec.label != "racr-serial"
            else 50.0, "platform_s": 30.0, "scene": spec.world.scene, "reference_light": spec.reference_light,
            "visit_light": spec.visit_light}


def test_a_rerun_resumes_from_the_run_files(tmp_path, monkeypatch):
    calls = []

    def fake_run(spec, out, worlds, say):
        calls.append(spec)
        if len(calls) == 3:
            raise KeyboardInterrupt  # killed mid-way
        return fake_result(spec, 0.4 if spec.label != "acr" else 5.0)

    monkeypatch.setattr(paper, "_run_spec", fake_run)
    with pytest.raises(KeyboardInterrupt):
        paper.run(quick=True, out=tmp_path)
    assert len(list((tmp_path / "runs").rglob("*.json"))) == 2
    data = paper.run(quick=True, out=tmp_path)
    total = len(paper.plan(quick=True))
    assert len(calls) == 3 + total - 2  # the two finished runs were not run again
    assert len(data["runs"]) == total
    s = data["summary"]
    for key in ("racr_success_rate", "acr_success_rate", "racr_mean_afd_px", "acr_mean_afd_px",
                "racr_mean_iterations", "acr_mean_iterations", "racr_mean_rig_s", "acr_mean_rig_s",
                "parallel_over_serial_speedup", "led_sweep_success_rate"):
        assert key in s and math.isfinite(s[key]), key
    assert s["racr_success_rate"] == 1.0 and s["acr_success_rate"] == 0.0
    assert s["parallel_over_serial_speedup"] == pytest.approx(50.0 / 40.0)
    text = (tmp_path / "paper.md").read_text()
    assert "**5.00**" in text and "316.7" in text  # ACR's failures marked; the paper's figures beside ours
    assert (tmp_path / "table2_afd.png").stat().st_size > 1000
    assert json.loads((tmp_path / "summary.json").read_text())["summary"]["led_sweep_runs"] == 3


def test_report_marks_paused_runs():
    runs = [{"experiment": "table2", "case": "c1", "label": "acr", "afd_px": 12.0, "success": False,
             "error": "ACR paused at adjustment 2: only 3 SIFT matches", "scene": "stele"}]
    data = {"runs": runs, "summary": paper.summarise(runs), "paper": paper.PAPER}
    text = markdown(data)
    assert "**12.00** (paused)" in text and "only 3 SIFT matches" in text
