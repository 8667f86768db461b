"""`fgcd relocate --resume`: the journal of a visit in progress, the decision to continue or start over,
and the guarded return to where the interrupted visit stopped."""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from fgcd_cli.app.visit_journal import JournalWriter, ResumeMode, decide_resume, journal_path, return_to
from fgcd_core.platform import GuardLimits, MotionGuard
from fgcd_core.se3 import exp_se3, pose_distance
from fgcd_drivers.manual import ManualPlatform

OPTIONS = {"driver": "sim", "light": "led:3"}


@pytest.fixture
def station(tmp_path):
    path = tmp_path / "stations" / "s1"

    def visit_names():  # as fgcd_cli.campaign.store.Station: committed visit folders, oldest first
        folder = path / "visits"
        return (
            sorted(p.name for p in folder.iterdir() if p.is_dir() and not p.name.startswith("."))
            if folder.is_dir()
            else []
        )

    return SimpleNamespace(name="s1", path=path, visit_names=visit_names)


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
    assert decision.mode == ResumeMode.CONTINUED and "after its 3 adjustments" in decision.reason
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


@pytest.mark.parametrize(
    "damage, mode, words",
    [
        (None, ResumeMode.STARTED_OVER, "no interrupted visit"),
        (b"\x00garbage\n{}\n", ResumeMode.STARTED_OVER, "damaged"),
        ("options", ResumeMode.STARTED_OVER, "another light"),
        ("empty", ResumeMode.STARTED_OVER, "no adjustment yet"),
    ],
)
def test_resume_starts_over_cleanly_and_says_why(station, damage, mode, words):
    if damage == "options":
        _interrupted(station, 2)
        decision = decide_resume(station, resume=True, options={**OPTIONS, "light": "front"})
    elif damage == "empty":  # a start line alone (an older fgcd wrote it before the first adjustment)
        journal_path(station).parent.mkdir(parents=True)
        journal_path(station).write_text(json.dumps({"kind": "start", "options": OPTIONS}) + "\n")
        decision = decide_resume(station, resume=True, options=OPTIONS)
    else:
        if damage is not None:
            journal_path(station).parent.mkdir(parents=True)
            journal_path(station).write_bytes(damage)
        decision = decide_resume(station, resume=True, options=OPTIONS)
    assert decision.mode == mode and words in decision.reason and decision.records == []
    # starting over replaces the old journal with the first adjustment, not before
    before = journal_path(station).read_bytes() if journal_path(station).exists() else None
    journal = JournalWriter(station, options=OPTIONS, decision=decision)
    assert (journal_path(station).read_bytes() if journal_path(station).exists() else None) == before
    journal.record(_record(1), _pose(1))
    assert len(decide_resume(station, resume=True, options=OPTIONS).records) == 1


def test_resume_starts_a_new_visit_when_the_journal_outlived_its_committed_visit(station):
    _interrupted(station, 2)  # killed after the commit, before the journal's removal
    visit = station.path / "visits" / "20261201T000000000Z"
    visit.mkdir(parents=True)
    (visit / "relocation.jsonl").write_text("".join(_record(i).to_json() + "\n" for i in (1, 2)))
    decision = decide_resume(station, resume=True, options=OPTIONS)
    assert (
        decision.mode == ResumeMode.STARTED_OVER
        and "already written (visits/20261201T000000000Z)" in decision.reason
        and not decision.records
    )
    (visit / "relocation.jsonl").write_text(_record(1).to_json() + "\n")  # another revisit's log: continue
    assert decide_resume(station, resume=True, options=OPTIONS).mode == ResumeMode.CONTINUED


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
    from fgcd_cli.app.capture import CaptureRequest, plan_capture, run_capture
    from fgcd_cli.app.revisit import RevisitRequest, plan_revisit, run_revisit
    from fgcd_cli.campaign.schema import RELOCATION_LOG
    from fgcd_cli.campaign.store import init_campaign, open_campaign
    from fgcd_drivers.sim.rig import build_sim_rig

    camp = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim", "sim": {"scene": "stele", "seed": 0}})
    # stands in for `fgcd calibrate hand-eye` (tested elsewhere): the simulated rig's mounting
    camp.write_rig(
        "handeye", {"T_flange_cam": build_sim_rig(scene="stele", seed=0).ground_truth.T_flange_cam_true().tolist()}
    )
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


def test_campaign_verify_notes_an_interrupted_visit(tmp_path):
    from fgcd_cli.campaign.store import init_campaign
    from fgcd_cli.campaign.verify import verify_campaign_dir

    camp = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim"})
    station = camp.station_or_create("s1")
    _interrupted(station, 1)
    report = verify_campaign_dir(camp.path)
    assert report.ok  # a note: neither damage nor a leftover to delete (it is a resumable revisit)
    assert [(p.kind, p.severity) for p in report.problems] == [("interrupted-visit", "note")]
    assert "--resume" in report.problems[0].detail


def _adjustment(i: int):
    from fgcd_cli.relocation.log import AdjustmentRecord

    return AdjustmentRecord(
        iteration=i,
        t_wall_s=1.0,
        t_session_s=1.0,
        stage="fine",
        g=0.1,
        offset_mm=2.0,
        offset_deg=0.1,
        T_ref_cam=np.eye(4).tolist(),
        M_flange_commanded=np.eye(4).tolist(),
        clamped=False,
        vse_status="tracking",
        vse_points=100,
        alignment_ok=True,
        alignment_reason="ok",
        scale=1.0,
        sigma=0.0,
        afd_est_px=1.0,
    )


def _relocate_interrupted(tmp_path, monkeypatch, capsys, *, adjustments: int) -> tuple[int, str, Path]:
    """`fgcd relocate` in-process on a stand-in rig, Ctrl-C after ``adjustments`` adjustments: (code, stderr, journal)."""
    import fgcd_cli.app.revisit as relocate_uc
    import fgcd_cli.app.rig as rig_uc
    from fgcd_cli.campaign.store import init_campaign
    from fgcd_cli.cli.app import app, run

    camp = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim", "sim": {"scene": "stele", "seed": 0}})
    camp.write_rig("handeye", {"T_flange_cam": np.eye(4).tolist()})
    meta = {"lightings": ["led:3"], "driver": "sim", "scenario": {"scene": "stele", "seed": 0, "noise": "default"}}
    with camp.station_or_create("s1").write_reference(meta) as w:
        w.add_image("led:3", np.zeros((4, 4), np.uint8))
        w.commit()
    platform = ManualPlatform(ask=lambda prompt: "", say=lambda text: None)
    handles = SimpleNamespace(guard=MotionGuard(platform, GuardLimits()), say=lambda text: None)
    monkeypatch.setattr(
        rig_uc, "open_rig", lambda request, hooks=None: rig_uc.OpenedRig(handles=handles, close=lambda: None)
    )

    def relocate_and_capture(rig, station, request, hooks):
        for i in range(1, adjustments + 1):
            hooks.on_record(_adjustment(i))
        raise KeyboardInterrupt

    monkeypatch.setattr(relocate_uc, "relocate_and_capture", relocate_and_capture)
    code = run(app, ["relocate", "-c", str(camp.path), "-s", "s1", "--yes", "--json"])
    return code, capsys.readouterr().err, journal_path(camp.station("s1"))


def test_ctrl_c_in_a_revisit_says_the_journal_is_kept_for_resume(tmp_path, monkeypatch, capsys):
    # Before: "...; nothing was written" while visits/.in-progress.jsonl stayed behind.
    code, err, journal = _relocate_interrupted(tmp_path, monkeypatch, capsys, adjustments=2)
    assert code == 130 and journal.exists()
    assert err.strip().splitlines()[-1] == (
        "interrupted (Ctrl-C): the manual platform was not moving; no visit was written; "
        f"the journal {journal} is kept for `fgcd relocate --resume`"
    )
    from fgcd_cli.campaign.store import open_campaign

    station = open_campaign(journal.parents[3]).station("s1")
    assert len(decide_resume(station, resume=True, options=OPTIONS).records) == 2


def test_ctrl_c_before_the_first_adjustment_leaves_no_journal(tmp_path, monkeypatch, capsys):
    code, err, journal = _relocate_interrupted(tmp_path, monkeypatch, capsys, adjustments=0)
    assert code == 130 and not journal.exists()
    assert (
        err.strip().splitlines()[-1] == "interrupted (Ctrl-C): the manual platform was not moving; nothing was written"
    )


def test_the_kept_journal_is_no_longer_claimed_once_the_visit_is_committed(station):
    from fgcd_cli.errors import RunRecord, run_record

    run_record.reset()
    run_record.no_writes()
    journal = _interrupted(station, 1)
    assert run_record.writes_clause() == (
        f"no visit was written; the journal {journal.path} is kept for `fgcd relocate --resume`"
    )
    with run_record.writing("the visit of station 's1'"):
        assert run_record.writes_clause().startswith("not written: the visit of station 's1'; the journal ")
        journal.remove()
    assert run_record.writes_clause() == "wrote the visit of station 's1'"
    run_record.reset()
    assert run_record.kept == RunRecord().kept


def test_a_short_write_on_a_nearly_full_disk_still_writes_the_whole_line(station, monkeypatch):
    import fgcd_cli.app.visit_journal as journal_mod

    real = journal_mod.os.write

    def short(fd, data):  # the kernel writes at most 7 bytes per call
        return real(fd, bytes(data[:7]))

    monkeypatch.setattr(journal_mod.os, "write", short)
    _interrupted(station, 2)
    monkeypatch.setattr(journal_mod.os, "write", real)
    decision = decide_resume(station, resume=True, options=OPTIONS)
    assert decision.mode == ResumeMode.CONTINUED and [r["iteration"] for r in decision.records] == [1, 2]
