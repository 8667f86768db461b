"""The benchmarks' truth-based self-knowledge keys (issue 25): confident_wrong_runs and the hand-over rate."""

import math

from fgcd_cli.bench.relocate import CONFIDENT_WRONG_AFD_PX, CONFIDENT_WRONG_MM, confident_wrong, handover_summary


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
