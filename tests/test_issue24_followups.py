"""Issue 24 follow-ups in capture, relocate, calibrate hand-eye and demo.

1. the first-motion confirmation is asked on stderr, and refused up front
   without a terminal and without --yes (exit 2, nothing created);
2. Ctrl-C says which platform was in use, whether it was moving, and whether
   the reference / visit was written (``run_record``);
3. a hardware driver without its address is bad input (exit 2), before
   anything is created;
4. the demo checks its closed-set options before it calibrates;
5. relocation reports its steps to a progress bar.
"""

from __future__ import annotations

import io
import json
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from fgcd_cli.campaign import init_campaign, open_campaign
from fgcd_cli.cli.app import app, run
from fgcd_cli.errors import run_record

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.timeout(300)


def fgcd(*args, timeout=240) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fgcd_cli.cli.app", *map(str, args)], capture_output=True,
                          text=True, cwd=ROOT, timeout=timeout, stdin=subprocess.DEVNULL)


def _lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]


def one_line(text: str, *mentions: str) -> str:
    lines = _lines(text)
    assert len(lines) == 1, text
    assert "Traceback" not in text
    for word in mentions:
        assert word in lines[0], lines[0]
    return lines[0]


@pytest.fixture
def camp(tmp_path):
    """A simulator campaign (stele) with a hand-eye and a station 's' holding a (stand-in) reference."""
    c = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim", "sim": {"scene": "stele", "seed": 0}})
    c.write_rig("handeye", {"T_flange_cam": np.eye(4).tolist()})
    meta = {"lightings": ["front"], "driver": "sim", "scenario": {"scene": "stele", "seed": 0, "noise": "default"}}
    with c.create_station("s").write_reference(meta) as w:
        w.add_image("front", np.zeros((4, 4), np.uint8))
        w.commit()
    return c


def _stations(c) -> list[str]:
    return sorted(p.name for p in (c.path / "stations").iterdir())


# ----------------------------------------------------------------------------- 1: confirmation
@pytest.mark.parametrize("command", ["capture", "relocate", "hand-eye"])
def test_no_terminal_and_no_yes_is_refused_before_anything_is_created(camp, command):
    before = _stations(camp)
    args = {"capture": ["capture", "-c", camp.path, "-s", "new"],
            "relocate": ["relocate", "-c", camp.path, "-s", "s"],
            "hand-eye": ["calibrate", "hand-eye", "--driver", "sim", "-c", camp.path]}[command]
    r = fgcd(*args, "--json", timeout=120)
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    line = one_line(r.stderr, "needs a terminal", "--yes")
    assert line.startswith("error:"), line
    assert json.loads(r.stdout) == {"error": line, "code": 2}  # stdout: one object, no prompt
    assert _stations(camp) == before
    assert not list(camp.path.glob("stations/s/visits/*"))
    assert open_campaign(camp.path).read_rig("handeye")["T_flange_cam"] == np.eye(4).tolist()


@pytest.fixture
def stand_in_rig(monkeypatch):
    """``open_rig`` replaced by a stand-in that records its options and asks the first-motion question."""
    import fgcd_cli.app.rig as app_rig
    import fgcd_cli.app.rig as rigs

    seen: dict = {}

    def open_rig(request=None, *, hooks=None, **kwargs):
        if request is not None:  # the use cases' typed form: RigRequest + RigHooks
            kwargs = {**request.__dict__, **hooks.__dict__}
        seen.update(kwargs)
        if kwargs.get("confirm") is not None:
            seen["answer"] = kwargs["confirm"]("First motion of this session on 'sim': move flange by (1, 0, 0) mm. "
                                               "Proceed?")
        platform = SimpleNamespace(name="sim", stop=lambda: seen.setdefault("stopped", True))
        guard = SimpleNamespace(platform=platform, trip=lambda reason: seen.setdefault("tripped", reason))
        handles = SimpleNamespace(guard=guard)
        return rigs.OpenedRig(handles=handles, close=lambda: seen.setdefault("closed", True), sim=None,
                              info={"scenario": None})

    monkeypatch.setattr(rigs, "open_rig", open_rig)
    monkeypatch.setattr(app_rig, "open_rig", open_rig)
    return seen


def _result(path="visit"):
    reloc = SimpleNamespace(converged=True, reason="ok", adjustments=1, wall_s=1.0, session_s=1.0, records=[],
                            residual=None)
    return SimpleNamespace(observation_path=path, relocation=reloc, coarse=None, cloud_points=0, images=["front"],
                           scale=SimpleNamespace(scale=1.0))


def test_the_first_motion_question_is_asked_on_stderr(camp, stand_in_rig, monkeypatch, capsys):
    import fgcd_cli.cli.output as output
    import fgcd_cli.app.relocate as capture_uc

    monkeypatch.setattr(output, "stdin_is_terminal", lambda: True)
    monkeypatch.setattr(sys, "stdin", io.StringIO("y\n"))
    monkeypatch.setattr(capture_uc, "relocate_and_capture", lambda *a, **k: _result())
    assert run(app, ["relocate", "-c", str(camp.path), "-s", "s", "--json"]) == 0
    out, err = capsys.readouterr()
    assert stand_in_rig["answer"] is True
    assert "Proceed?" in err and "Proceed?" not in out
    assert json.loads(out)["converged"] is True  # stdout is the one JSON object


# ----------------------------------------------------------------------------- 2: Ctrl-C line
def test_ctrl_c_during_a_relocation_names_the_platform_and_the_unwritten_visit(camp, stand_in_rig, monkeypatch,
                                                                               capsys):
    import fgcd_cli.app.relocate as capture_uc

    def interrupted(rig, station, **kwargs):
        with run_record.motion():
            raise KeyboardInterrupt

    monkeypatch.setattr(capture_uc, "relocate_and_capture", interrupted)
    assert run(app, ["relocate", "-c", str(camp.path), "-s", "s", "--yes"]) == 130
    assert _lines(capsys.readouterr().err)[-1] == \
        "interrupted (Ctrl-C): the sim platform was stopped mid-motion; nothing was written"
    assert stand_in_rig["tripped"] and stand_in_rig["closed"]  # the platform was told to stop, the rig closed


def test_ctrl_c_during_a_capture_says_nothing_written_and_leaves_no_station(camp, stand_in_rig, monkeypatch, capsys):
    import fgcd_cli.app.capture as capture_uc

    def interrupted(rig, station, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(capture_uc, "capture_reference", interrupted)
    assert run(app, ["capture", "-c", str(camp.path), "-s", "new", "--yes"]) == 130
    assert _lines(capsys.readouterr().err)[-1] == \
        "interrupted (Ctrl-C): the sim platform was not moving; nothing was written"
    assert "new" not in _stations(camp)


def test_ctrl_c_during_a_handeye_run_names_the_platform_and_keeps_the_old_calibration(camp, stand_in_rig,
                                                                                       monkeypatch, capsys):
    import fgcd_cli.cli.calibrate_cmd as calibrate_cmd

    def interrupted(handles, **kwargs):
        assert handles.guard.platform.name == "sim"
        with run_record.motion():
            raise KeyboardInterrupt

    monkeypatch.setattr(calibrate_cmd, "_run_handeye", interrupted)
    assert run(app, ["calibrate", "hand-eye", "--driver", "sim", "-c", str(camp.path), "--yes"]) == 130
    assert _lines(capsys.readouterr().err)[-1] == \
        "interrupted (Ctrl-C): the sim platform was stopped mid-motion; nothing was written"
    assert stand_in_rig["tripped"] and stand_in_rig["closed"]
    assert open_campaign(camp.path).read_rig("handeye")["T_flange_cam"] == np.eye(4).tolist()


class _Guard:
    """A guard whose ``k``-th motion is interrupted (Ctrl-C)."""

    def __init__(self, interrupt_at: int | None = None):
        self.moves = 0
        self.interrupt_at = interrupt_at
        self.platform = SimpleNamespace(flange_pose=lambda: np.eye(4), name="sim")

    def move_by(self, step):
        self.moves += 1
        if self.moves == self.interrupt_at:
            raise KeyboardInterrupt
        return SimpleNamespace(duration_s=0.1)


class _Vse:
    def __init__(self, interrupt_after: int | None = None):
        self.frames = 0
        self.interrupt_after = interrupt_after

    def latest(self):
        self.frames += 1
        if self.interrupt_after is not None and self.frames > self.interrupt_after:
            raise KeyboardInterrupt
        return SimpleNamespace(frames_processed=self.frames, status="tracking")

    def stop(self):
        pass


@pytest.mark.parametrize("where", ["in a sub-step", "between sub-steps"])
def test_a_sub_stepped_motion_is_in_progress_until_its_last_sub_step(where):
    from fgcd_core.se3 import exp_se3
    from fgcd_cli.relocation.session import VseSession

    run_record.reset()
    M = exp_se3(np.r_[0.02, 0, 0, 0, 0, 0])  # 20 mm: 4 sub-steps
    VseSession(guard=_Guard(), vse=_Vse()).move_by(M)
    assert run_record.moving is False  # a finished motion
    guard, vse = (_Guard(interrupt_at=2), _Vse()) if where == "in a sub-step" else (_Guard(), _Vse(interrupt_after=4))
    with pytest.raises(KeyboardInterrupt):
        VseSession(guard=guard, vse=vse).move_by(M)
    assert run_record.moving is True
    run_record.reset()


def test_the_rig_guard_marks_its_motions_and_not_its_question():
    from fgcd_cli.app.rig import _recorded_guard

    asked = []

    def confirm(text):
        asked.append(run_record.moving)
        return True

    class Platform:
        name = "sim"

        def __init__(self):
            self.pose = np.eye(4)
            self.during = None

        def flange_pose(self):
            return self.pose.copy()

        def capabilities(self):
            return SimpleNamespace(workspace_min_m=(-1, -1, -1), workspace_max_m=(1, 1, 1),
                                   controllable=("x", "y", "z", "rx", "ry", "rz"))

        def move_to(self, T, speed_fraction=1.0):
            self.during = run_record.moving
            self.pose = T
            return SimpleNamespace(duration_s=0.0)

        def stop(self):
            pass

    from fgcd_drivers.platform import GuardLimits

    run_record.reset()
    platform = Platform()
    guard = _recorded_guard(platform, GuardLimits(), confirm)
    target = np.eye(4)
    target[0, 3] = 0.001
    guard.move_to(target)
    assert asked == [False] and platform.during is True and run_record.moving is False
    run_record.reset()


def test_the_reference_is_named_not_written_when_ctrl_c_comes_while_writing(monkeypatch):
    import fgcd_cli.app.capture as capture_uc
    from fgcd_cli.relocation.session import ScaleEstimate

    class Cloud:
        points = np.random.default_rng(0).random((1200, 3))
        intensities = np.ones(1200)

        def __len__(self):
            return len(self.points)

    cloud = Cloud()
    state = SimpleNamespace(status="tracking", T_map_cam=np.eye(4), cloud=cloud, keyframes=[])
    session = SimpleNamespace(move_to_flange=lambda *a, **k: 0.0, tracking_state=lambda: state,
                              settle=lambda **k: state, timing=SimpleNamespace(platform_s=0.0))
    scale = ScaleEstimate(scale=1.0, scale_std=0.0, n_samples=3, residual_rms_mm=0.0, method="test")
    monkeypatch.setattr(capture_uc, "start_session",
                        lambda rig, **k: (session, SimpleNamespace(stop=lambda: None), scale, np.eye(4)))
    monkeypatch.setattr(capture_uc, "grab_images", lambda rig, lightings: {"front": np.zeros((4, 4), np.float32)})

    class Writer:
        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def add_image(self, name, img):
            raise KeyboardInterrupt

    station = SimpleNamespace(name="north-wall", write_reference=lambda meta: Writer())
    rig = capture_uc.RigHandles(guard=SimpleNamespace(platform=SimpleNamespace(flange_pose=lambda: np.eye(4))),
                                camera_source=None, intrinsics=SimpleNamespace(to_dict=lambda: {}),
                                T_flange_cam=np.eye(4), vse_factory=lambda: None)
    run_record.reset()
    with pytest.raises(KeyboardInterrupt):
        capture_uc.capture_reference(rig, station, lightings=["front"])
    assert run_record.writes_clause() == "not written: the reference of station 'north-wall'"
    run_record.reset()


def test_the_visit_is_named_not_written_when_ctrl_c_comes_while_writing(monkeypatch):
    import fgcd_cli.alignment as alignment
    import fgcd_cli.app.relocate as capture_uc
    from fgcd_cli.relocation.session import ScaleEstimate

    class Cloud:
        points = np.zeros((10, 3))
        intensities = np.ones(10)

        def __len__(self):
            return 10

    state = SimpleNamespace(status="tracking", T_map_cam=np.eye(4), cloud=Cloud())
    session = SimpleNamespace(tracking_state=lambda: state, settle=lambda **k: state)
    scale = ScaleEstimate(scale=1.0, scale_std=0.0, n_samples=3, residual_rms_mm=0.0, method="test")
    reference = SimpleNamespace(points=np.zeros((10, 3)), intensities=np.ones(10), T_ref_camref=np.eye(4))
    result = SimpleNamespace(converged=True, reason="ok", adjustments=1, wall_s=1.0, session_s=1.0, platform_s=1.0,
                             synthetic_s=0.0, records=[], residual=None)
    monkeypatch.setattr(capture_uc, "load_reference", lambda station: reference)
    monkeypatch.setattr(alignment, "ReferenceIndex", lambda *a, **k: None)
    monkeypatch.setattr(alignment, "initial_guess", lambda **k: SimpleNamespace(T_ref_cur=np.eye(4), source="test",
                                                                                 fast=None))
    monkeypatch.setattr(capture_uc, "start_revisit_session",
                        lambda rig, station, reference, **k: (session, SimpleNamespace(stop=lambda: None), scale, None))
    monkeypatch.setattr(capture_uc, "relocate", lambda ctx: result)
    monkeypatch.setattr(capture_uc, "reference_images", lambda station: {})
    monkeypatch.setattr(capture_uc, "grab_images", lambda rig, lightings: {"front": np.zeros((4, 4), np.float32)})

    class Writer:
        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def add_image(self, name, img):
            raise KeyboardInterrupt

    from fgcd_cli.relocation.config import RelocationConfig

    station = SimpleNamespace(name="north-wall", new_visit=lambda meta: Writer())
    rig = capture_uc.RigHandles(guard=SimpleNamespace(platform=SimpleNamespace(flange_pose=lambda: np.eye(4))),
                                camera_source=None, intrinsics=SimpleNamespace(to_dict=lambda: {}),
                                T_flange_cam=np.eye(4), vse_factory=lambda: None)
    run_record.reset()
    with pytest.raises(KeyboardInterrupt):
        capture_uc.relocate_and_capture(rig, station, capture_uc.RelocateRequest(
            config=RelocationConfig(mode="parallel"), lightings=["front"], coarse=None))
    assert run_record.writes_clause() == "not written: the visit of station 'north-wall'"
    run_record.reset()


def test_ctrl_c_during_a_simulated_capture_end_to_end(camp):
    """SIGINT to a running `fgcd capture` (simulator) once it explores: one line, exit 130, no station left."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "fgcd_cli.cli.app", "capture", "-c", str(camp.path), "-s", "new", "--yes"],
        stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT,
    )
    seen = bytearray()
    exploring = threading.Event()

    def read() -> None:
        while chunk := proc.stderr.read1(256):
            seen.extend(chunk)
            if b"exploration 1/" in seen:
                exploring.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        assert exploring.wait(240), bytes(seen).decode(errors="replace")
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=120)
        reader.join(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    stderr = bytes(seen).decode(errors="replace")
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr
    assert re.fullmatch(r"interrupted \(Ctrl-C\): the sim platform was (stopped mid-motion|not moving); "
                        r"nothing was written", _lines(stderr)[-1]), stderr
    assert "new" not in _stations(camp)


# ----------------------------------------------------------------------------- 3: driver address
@pytest.mark.parametrize("args, option", [
    (["capture", "-s", "new", "--driver", "grbl"], "--port"),
    (["capture", "-s", "new", "--driver", "ur"], "--host"),
    (["relocate", "-s", "s", "--driver", "grbl"], "--port"),
    (["relocate", "-s", "s", "--driver", "ur"], "--host"),
])
@pytest.mark.parametrize("intrinsics", [True, False])
def test_a_hardware_driver_without_its_address_is_bad_input(camp, args, option, intrinsics, capsys):
    # the missing address is the first thing to fix: said before the missing intrinsics
    if intrinsics:
        camp.write_rig("intrinsics", {"camera": {"fx": 600, "fy": 600, "cx": 320, "cy": 240, "width": 640,
                                                 "height": 480}})
    before = _stations(camp)
    assert run(app, [args[0], "-c", str(camp.path), *args[1:], "--yes"]) == 2
    one_line(capsys.readouterr().err, option)
    assert _stations(camp) == before


@pytest.mark.parametrize("driver, option", [("grbl", "--port"), ("ur", "--host")])
def test_handeye_on_hardware_without_its_address_is_bad_input(camp, driver, option, capsys):
    camp.write_rig("intrinsics", {"camera": {"fx": 600, "fy": 600, "cx": 320, "cy": 240, "width": 640, "height": 480}})
    assert run(app, ["calibrate", "hand-eye", "--driver", driver, "-c", str(camp.path), "--yes"]) == 2
    one_line(capsys.readouterr().err, option)


# ----------------------------------------------------------------------------- 4: demo options
@pytest.mark.parametrize("args, mentions", [
    (["--light", "bogus"], ("--light", "bogus", "led:H")),
    (["--scene", "nosuch"], ("nosuch", "relief_panel")),
    (["--changes", "-1"], ("--changes",)),
])
def test_demo_checks_its_options_before_it_starts(tmp_path, monkeypatch, capsys, args, mentions):
    import fgcd_cli.app.demo as demo_mod

    def never(*a, **k):
        raise AssertionError("the demo started with a bad option")

    monkeypatch.setattr(demo_mod, "run_demo", never)
    out = tmp_path / "d"
    assert run(app, ["demo", "-o", str(out), *args]) == 2
    one_line(capsys.readouterr().err, *mentions)
    assert not out.exists()


# ----------------------------------------------------------------------------- 5: relocation progress
def test_relocate_hands_a_progress_callback_to_the_rig(camp, stand_in_rig, monkeypatch, capsys):
    import fgcd_cli.app.relocate as capture_uc

    monkeypatch.setattr(capture_uc, "relocate_and_capture", lambda *a, **k: _result())
    assert run(app, ["relocate", "-c", str(camp.path), "-s", "s", "--yes"]) == 0
    bar = stand_in_rig["on_progress"]
    assert callable(bar)
    bar(1, 4, "adjustment 1: moving")  # the plain (done, total, label) callback the use case calls
    assert run(app, ["relocate", "-c", str(camp.path), "-s", "s", "--yes", "--json"]) == 0
    assert stand_in_rig["on_progress"] is None  # --json: no bar


def test_lines_name_the_bar_step_between_counted_steps():
    from rich.console import Console
    from rich.progress import Progress

    from fgcd_cli.cli.progress import StepBar

    said = []
    with Progress(console=Console(file=io.StringIO()), disable=True) as progress:
        bar = StepBar(progress)
        say = bar.lines(said.append)
        bar(1, 4, "exploring (1/3)")
        say("exploration 1/3: VSE tracking")  # in the middle of a counted step: the bar keeps it
        assert [t.description for t in progress.tasks] == ["exploring (1/3)"]
        bar(4, 4, "adjustment 1: moving")
        say("adjustment 2: waiting for an alignment of the current view")  # after it: the line names the step
        assert [t.description for t in progress.tasks] == ["adjustment 2: waiting for an alignment of the current view"]
        say("  still aligning (10 s; latest estimate: none yet)")  # a detail: the step stays
        assert [t.description for t in progress.tasks] == ["adjustment 2: waiting for an alignment of the current view"]
    assert len(said) == 3


def test_no_terminal_no_bar_and_no_blank_line(capsys):
    from fgcd_cli.cli.progress import step_progress

    with step_progress(enabled=True, heartbeat_s=0.05) as bar:
        bar(0, 0, "a step")
        time.sleep(0.3)  # lasts a heartbeat: named
        bar(1, 2, "another")  # ends at once: not named
    # no live display off a terminal: a plain line per step that lasts, no blank line
    err = capsys.readouterr().err
    assert err.splitlines()[0] == "a step" and "another" not in err and "\n\n" not in err
