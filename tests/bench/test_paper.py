"""``fgcd bench paper``: the plan, resuming from the per-run files, the summary keys and the report."""

import json
import math

import pytest

from fgcd_cli.bench.paper import main as paper
from fgcd_cli.bench.paper.report import markdown


def test_quick_plan_covers_every_experiment():
    runs = paper.plan(quick=True)
    labels = {(r.experiment, r.label) for r in runs}
    assert {
        ("table2", "racr"),
        ("table2", "acr"),
        ("table5", "racr-serial"),
        ("fig7", "racr"),
        ("fig7", "acr"),
        ("table3", "racr-no-handeye"),
        ("table3", "acr-handeye"),
        ("table4", "racr"),
        ("table4", "acr"),
        ("fig6", "racr-sparse"),
        ("revisit", "racr-usual"),
    } <= labels
    # s55 scores Table 2's visits and adds no relocation; every other experiment runs at least once
    # (and Figs. 4, 6, 12 bring their own pure-rACR baseline, "pure")
    assert {r.experiment for r in runs} == set(paper.EXPERIMENTS) - {"s55"} | {"pure"}
    assert any(r.experiment == "fig12" and r.ablation for r in runs)
    assert any(r.experiment == "fig4" and r.reference_noise > 0 for r in runs)
    # each world's runs are together, so a world is set up once and its runs follow
    worlds = [r.world.name for r in runs]
    assert worlds == sorted(worlds, key=worlds.index)
    # every method of a case starts from the same pose (the paper's "same initial pose")
    t2 = [r for r in runs if r.experiment in ("table2", "table5")]
    for case in {r.case for r in t2}:
        starts = {(r.offset_mm, r.offset_deg, r.session_seed) for r in t2 if r.case == case}
        assert len(starts) == 1
    sweep = [r for r in runs if r.experiment == "fig7"]
    assert all(r.reference_light == "led:12" for r in sweep)
    assert len({r.path(__import__("pathlib").Path("o")) for r in runs}) == len(runs)


def test_full_plan_is_the_20_cases_the_72_sweep_positions_and_the_paper_s_other_experiments():
    runs = paper.plan(quick=False)
    assert len({r.case for r in runs if r.experiment == "table2"}) == 20
    assert len([r for r in runs if r.experiment == "fig7" and r.label == "racr"]) == 6 * 12
    by = lambda e: [r for r in runs if r.experiment == e]  # noqa: E731
    assert len({r.case for r in by("table4")}) == 9  # W1-3, R1-3, V1-3
    # a weakly textured wall is no place for a target-free hand-eye: the same rig is calibrated elsewhere
    weak = [r.world for r in by("table4") if r.case.startswith("W")]
    assert weak and all(w.calibration_scene == "relief_panel" and w.scene != w.calibration_scene for w in weak)
    assert all(r.world.calibration_scene == "" for r in by("table2"))
    assert len({r.case for r in by("fig6")}) == 5 and all(r.vse == "sparse" for r in by("fig6"))  # S1-5
    assert {r.ablation for r in by("fig12")} == {"", "P", "F", "S"} and len({r.case for r in by("fig12")}) == 3
    assert sorted({r.reference_noise for r in by("fig4")}) == [0.01, 0.02, 0.04, 0.08, 0.16]


def test_each_variant_sets_the_loop_options_it_names():
    from fgcd_cli.bench.paper.runs import loop_config

    runs = {r.label: r for r in paper.plan(quick=False, experiments=("fig12",), cases=["indoor-2"])}
    assert loop_config(runs["no-F"]).fine is False
    assert loop_config(runs["no-P"]).fine_align.refine_keyframes is False
    assert loop_config(runs["no-S"]).fast_align.scale.estimate is False
    assert loop_config(runs["alpha-0.6"]).fine_align.alpha == 0.6
    default = loop_config(paper.plan(quick=True, experiments=("table2",))[0])
    assert default.fine and default.fine_align.refine_keyframes and default.fast_align.scale.estimate
    assert default.fine_align.alpha == 0.2 and default.image_refine and default.image_fallback
    # the figures that measure the alignment run the paper's pure rACR, their baseline too
    figs = paper.plan(quick=False, experiments=("fig4", "fig6", "fig12"))
    assert all(not loop_config(r).image_refine and not loop_config(r).image_fallback for r in figs)
    assert {r.case for r in figs if r.experiment == "pure"} == {r.case for r in figs if r.experiment != "pure"}


def test_the_reference_noise_has_the_stated_spread():
    import numpy as np

    from fgcd_cli.bench.paper.runs import _noisy_reference
    from fgcd_cli.relocation.config import ReferenceData

    pts = np.random.default_rng(0).uniform(0, 0.5, (20000, 3))
    ref = ReferenceData(points=pts, intensities=np.zeros(len(pts)), T_ref_camref=np.eye(4))
    noisy = _noisy_reference(0.04)(ref)
    width = float(np.max(np.ptp(pts, axis=0)))
    assert np.std(noisy.points - pts) == pytest.approx(0.04 * width, rel=0.03)
    assert _noisy_reference(0.0) is None


def fake_result(spec, afd):
    return {
        "experiment": spec.experiment,
        "case": spec.case,
        "label": spec.label,
        "method": str(spec.method),
        "afd_px": afd,
        "success": afd < 3.0,
        "adjustments": 4,
        "session_s": 40.0 if spec.label != "racr-serial" else 50.0,
        "platform_s": 30.0,
        "scene": spec.world.scene,
        "reference_light": spec.reference_light,
        "visit_light": spec.visit_light,
    }


def test_a_rerun_resumes_from_the_run_files(tmp_path, monkeypatch):
    calls = []

    def fake_run(spec, out, worlds, say, deterministic=False):
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
    for key in (
        "racr_success_rate",
        "acr_success_rate",
        "racr_mean_afd_px",
        "acr_mean_afd_px",
        "racr_mean_iterations",
        "acr_mean_iterations",
        "racr_mean_rig_s",
        "acr_mean_rig_s",
        "parallel_over_serial_speedup",
        "led_sweep_success_rate",
    ):
        assert key in s and math.isfinite(s[key]), key
    assert s["racr_success_rate"] == 1.0 and s["acr_success_rate"] == 0.0
    assert s["parallel_over_serial_speedup"] == pytest.approx(50.0 / 40.0)
    text = (tmp_path / "paper.md").read_text()
    assert "**5.00**" in text and "316.7" in text  # ACR's failures marked; the paper's figures beside ours
    assert (tmp_path / "table2_afd.png").stat().st_size > 1000
    assert json.loads((tmp_path / "summary.json").read_text())["summary"]["led_sweep_runs"] == len(
        paper.QUICK["fig7_clock"]
    )  # 1 scene
    for section in ("Table 3", "Table 4", "Fig. 4", "Fig. 6", "Fig. 12"):
        assert f"### {section}" in text, section
    assert "12.35" in text and "256.4" in text  # the paper's Table 4 and Table 3 beside ours
    assert (tmp_path / "fig12_alpha_ablations.png").stat().st_size > 1000
    assert (tmp_path / "fig4_reference_noise.png").stat().st_size > 1000


def test_report_marks_paused_runs():
    runs = [
        {
            "experiment": "table2",
            "case": "c1",
            "label": "acr",
            "afd_px": 12.0,
            "success": False,
            "error": "ACR paused at adjustment 2: only 3 SIFT matches",
            "scene": "stele",
        }
    ]
    data = {"runs": runs, "summary": paper.summarise(runs), "paper": paper.PAPER}
    text = markdown(data)
    assert "**12.00** (paused)" in text and "only 3 SIFT matches" in text


def test_report_shows_change_detection_after_each_method():
    runs = [
        {
            "experiment": "s55",
            "case": "indoor-2",
            "label": "racr",
            "afd_px": 0.2,
            "f1": 0.81,
            "false_regions": 0,
            "scene": "relief_panel",
        },
        {
            "experiment": "s55",
            "case": "indoor-2",
            "label": "acr",
            "afd_px": 4.1,
            "f1": 0.37,
            "false_regions": 5,
            "scene": "relief_panel",
        },
    ]
    data = {"runs": runs, "summary": paper.summarise(runs), "paper": paper.PAPER}
    text = markdown(data)
    assert "| indoor-2 | relief_panel | 0.20 | 0.81 | 0 | 4.10 | 0.37 | 5 |" in text
    assert data["summary"]["s55_racr_mean_f1"] == pytest.approx(0.81)
    assert data["summary"]["s55_acr_false_regions"] == 5


def test_the_summary_scores_stated_residuals_against_the_truth_and_pure_racrs_median_error():
    def run(experiment, label, err_mm, stated_mm, sigma_mm):
        return {
            "experiment": experiment,
            "label": label,
            "method": "racr",
            "case": "indoor-1",
            "success": True,
            "afd_px": 0.3,
            "pose_err_mm": err_mm,
            "residual_mm": stated_mm,
            "residual_sigma_mm": sigma_mm,
            "adjustments": 2,
            "session_s": 20.0,
            "platform_s": 10.0,
        }

    rows = [
        run("table2", "racr", 1.0, 0.8, 0.2),  # 1 sigma: covered
        run("pure", "racr-pure", 6.0, 1.0, 1.0),  # 5 sigma: not covered
        run("pure", "racr-pure", 4.0, 3.5, 0.5),  # 1 sigma: covered
        run("pure", "racr-pure", 9.0, 8.0, 1.0),
    ]
    summary = paper.summarise(rows)
    assert summary["racr_coverage_2sigma"] == pytest.approx(3 / 4)
    assert summary["pure_racr_median_error_mm"] == 6.0
