"""The benchmarks' truth-based self-knowledge keys (issue 25): confident_wrong_runs and the hand-over rate."""

import math

import pytest

from fgcd_cli.bench.relocate import (
    CONFIDENT_WRONG_AFD_PX,
    CONFIDENT_WRONG_MM,
    confident_wrong,
    coverage_2sigma,
    handover_summary,
    residual_z,
)


def test_a_converged_run_truly_far_is_confidently_wrong():
    # the runs: "converged" at an estimated 0.39 px while truly 2.84 px / 16.9 mm away
    assert confident_wrong({"converged": True, "afd_px": 2.84, "pose_err_mm": 16.9})
    # within the pixel bound but millimetres off (a sideways shift a turn hides)
    assert confident_wrong({"converged": True, "afd_px": 0.4, "pose_err_mm": CONFIDENT_WRONG_MM + 0.1})
    assert confident_wrong({"converged": True, "afd_px": CONFIDENT_WRONG_AFD_PX + 0.01, "pose_err_mm": 1.0})
    # missing truth never counts as right
    assert confident_wrong({"converged": True, "afd_px": math.nan, "pose_err_mm": 1.0})


def test_a_right_or_an_honestly_paused_run_is_not():
    assert not confident_wrong({"converged": True, "afd_px": 0.4, "pose_err_mm": 0.9})
    assert not confident_wrong({"converged": False, "afd_px": 40.0, "pose_err_mm": 200.0})
    assert not confident_wrong({"error": "motion paused", "success": False, "afd_px": 40.0})


def test_handover_rate_counts_only_runs_where_the_stage_ran():
    rows = [{"coarse": {"handed_over": True}}, {"coarse": {"handed_over": False}}, {"coarse": None}, {}]
    s = handover_summary(rows)
    assert s == {"coarse_ran": 2, "coarse_handed_over": 1, "handover_rate": 0.5}
    assert math.isnan(handover_summary([{}])["handover_rate"])


def test_coverage_counts_the_runs_whose_truth_lies_within_two_stated_sigmas():
    # the demo: "residual 0.33 ± 0.17 mm" while the truth is 1.10 mm, 4.5 sigma away
    assert residual_z({"residual_mm": 0.33, "residual_sigma_mm": 0.17, "pose_err_mm": 1.10}) == pytest.approx(
        4.53, abs=0.01
    )
    rows = [
        {"residual_mm": 0.33, "residual_sigma_mm": 0.17, "pose_err_mm": 1.10},  # 4.5 sigma: not covered
        {"residual_mm": 0.76, "residual_sigma_mm": 0.21, "pose_err_mm": 1.16},  # 1.9 sigma: covered
        {"residual_mm": 1.26, "residual_sigma_mm": 0.84, "pose_err_mm": 1.93},  # 0.8 sigma: covered
        {"residual_mm": None, "residual_sigma_mm": None, "pose_err_mm": 3.0},  # stated nothing: not counted
    ]
    assert coverage_2sigma(rows) == pytest.approx(2 / 3)
    assert math.isnan(coverage_2sigma(rows[3:]))
