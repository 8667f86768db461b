"""`fgcd relocate --resume`: the journal of a visit in progress, the decision to continue or start over,
and the guarded return to where the interrupted visit stopped."""

from __future__ import annotations

import json
from pathlib import Path
import math
from types import SimpleNamespace

import numpy as np
import pytest

from drivers.manual import ManualPlatform
from drivers.platform import GuardLimits, MotionGuard
from fgcd_cli.app.visit_journal import JournalWriter, ResumeMode, decide_resume, journal_path, return_to
from fgcd_core.se3 import exp_se3, pose_distance

OPTIONS = {"driver": "sim", "light": "led:3"}


@pytest.fixture
def station(tmp_path):
    return SimpleNamespace(name="s1", path=tmp_path / "stations" / "s1")


def _record(i):
    return SimpleNamespace(to_json=lambda: json.dumps({"iteration": i, "g": 0.1 / i}))


def _pose(x_mm):
    T = np.eye(4)
    T[0, 3] = x_mm / 1000
    return T


def _interrupted(station, n):
    new = decide_resume(station, resume=False, options=OPTIONS)
    journal = JournalWriter(station, options=OPTIONS, decision=new)
    for i in range(1, n + 1):
        journal.record(_record(i), _pose(i))
    return journal


def test_resume_continues_after_the_last_recorded_adjustment(station):
    _interrupted(station, 3)
    decision = decide_resume(station, resume=True, options=OPTIONS)
    assert decision.mode == ResumeMode.CONTINUED and "after its 3 adjustment(s)" in decision.reason
    assert [r["iteration"] for r in decision.records] == [1, 2, 3]
    np.testing.assert_allclose(decision.T_base_flange, _pose(3))
    # continuing appends: the journal keeps the earlier adjustments
    JournalWriter(station, options=OPTIONS, decision=decision).record(_record(4), _pose(4))
    assert len(decide_resume(station, resume=True, options=OPTIONS).records) == 4


def test_a_line_cut_by_a_killed_process_is_dropped_not_fatal(station):
    _interrupted(station, 2)
    with open(journal_path(station), "a", encoding="utf-8") as f:
        f.write('{"record": {"itera')  # SIGKILL mid-write
    decision = decide_resume(station, resume=True, options=OPTIONS)
    assert decision.mode == ResumeMode.CONTINUED and len(decision.records) == 2


@pytest.mark.parametrize("damage, mode, words", [
    (None, ResumeMode.STARTED_OVER, "no interrupted visit"),
    (b"\x00garbage\n{}\n", ResumeMode.STARTED_OVER, "damaged"),
    ("options", ResumeMode.STARTED_OVER, "another light"),
    ("empty", ResumeMode.STARTED_OVER, "no adjustment yet"),
])
def test_resume_starts_over_cleanly_and_says_why(station, damage, mode, words):
    if damage == "options":
        _interrupted(station, 2)
        decision = decide_resume(station, resume=True, options={**OPTIONS, "light": "front"})
    elif damage == "empty":
        _interrupted(station, 0)
        decision = decide_resume(station, resume=True, options=OPTIONS)
    else:
        if damage is not None:
            journal_path(station).parent.mkdir(parents=True)
            journal_path(station).write_bytes(damage)
        decision = decide_resume(station, resume=True, options=OPTIONS)
    assert decision.mode == mode and words in decision.reason and decision.records == []
    # starting over truncates the old journal
    JournalWriter(station, options=OPTIONS, decision=decision)
    assert decide_resume(station, resume=True, options=OPTIONS).reason.endswith("no adjustment yet: starting over")


def test_without_resume_a_left_journal_is_named_and_replaced(station):
    _interrupted(station, 2)
    decision = decide_resume(station, resume=False, options=OPTIONS)
    assert decision.mode == ResumeMode.NEW and "--resume would continue it" in decision.reason


def test_return_to_moves_in_guarded_steps_to_the_recorded_pose():
    platform = ManualPlatform(ask=lambda text: "", say=lambda text: None)
    guard = MotionGuard(platform, GuardLimits(max_step_m=0.01, max_step_rad=math.radians(2)))
    target = exp_se3(np.r_[0.025, -0.01, 0.005, 0.0, 0.05, 0.0])  # 27.4 mm, 2.9 deg
    steps = return_to(guard, target)
    assert steps == 4  # ceil(27.4 / 9) = 4 translation steps; ceil(2.86 / 1.8) = 2 rotation steps
    mm, deg = pose_distance(platform.flange_pose(), target)
    assert mm < 1e-6 and deg < 1e-6


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_an_interrupted_simulated_revisit_is_continued_by_resume(tmp_path):
    """Ctrl-C after the first adjustment of a simulated revisit, then `--resume`: continued, log kept."""
    from drivers.sim.rig import build_sim_rig
    from fgcd_cli.app.capture import CaptureRequest, plan_capture, run_capture
    from fgcd_cli.app.relocate import RevisitRequest, plan_revisit, run_revisit
    from fgcd_cli.campaign import init_campaign, open_campaign
    from fgcd_cli.campaign.schema import RELOCATION_LOG

    camp = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim", "sim": {"scene": "stele", "seed": 0}})
    # stands in for `fgcd calibrate hand-eye` (tested elsewhere): the simulated rig's mounting
    camp.write_rig("handeye", {"T_flange_cam": build_sim_rig(scene="stele", seed=0).ground_truth
                               .T_flange_cam_true().tolist()})
    run_capture(camp, plan_capture(camp, CaptureRequest(station="s1", light="led:3")))

    def interrupt(record):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_revisit(plan_revisit(camp.path, RevisitRequest(station="s1")), on_record=interrupt)
    station = open_campaign(camp.path).station("s1")
    assert station.visits() == []  # nothing committed
    left = decide_resume(station, resume=True, options={"driver": "sim", "light": "led:3"})
    assert left.mode == ResumeMode.CONTINUED and len(left.records) == 1

    outcome = run_revisit(plan_revisit(camp.path, RevisitRequest(station="s1", resume=True)))
    assert outcome.resume.mode == ResumeMode.CONTINUED
    log_lines = (Path(outcome.result.observation_path) / RELOCATION_LOG).read_text().splitlines()
    assert len(log_lines) == 1 + outcome.result.relocation.adjustments  # the earlier adjustment first
    assert not journal_path(station).exists()


def test_campaign_verify_warns_of_an_interrupted_visit(tmp_path):
    from fgcd_cli.campaign import init_campaign
    from fgcd_cli.campaign.verify import verify_campaign_dir

    camp = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim"})
    station = camp.station_or_create("s1")
    _interrupted(station, 1)
    report = verify_campaign_dir(camp.path)
    assert report.ok  # a warning, not damage
    assert [p.kind for p in report.problems] == ["interrupted-visit"]
    assert "--resume" in report.problems[0].detail
