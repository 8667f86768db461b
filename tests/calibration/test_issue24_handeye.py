"""Issue 24, items 7 and 11 for `calibrate hand-eye` and `capture`: one message for missing intrinsics,
progress reported through a plain callback for every long step."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from fgcd_drivers.platform import GuardLimits, MotionGuard
from fgcd_cli.calibration.procedure import run_target_free
from fgcd_cli.campaign import init_campaign
from fgcd_core.se3 import exp_so3, make_pose

ROOT = Path(__file__).parents[2]


def fgcd(*args, timeout=120):
    return subprocess.run([sys.executable, "-m", "fgcd_cli.cli.app", *map(str, args)], capture_output=True,
                          text=True, cwd=ROOT, timeout=timeout, stdin=subprocess.DEVNULL)


# ----------------------------------------------------------------------------- item 11
@pytest.mark.parametrize("rig", [("--driver", "ur", "--host", "192.0.2.1"), ("--driver", "grbl", "--port", "/dev/null")])
def test_handeye_on_hardware_without_intrinsics_is_one_message(tmp_path, rig):
    for campaign in ((), ("-c", init_campaign(tmp_path / rig[1], site="x").path)):
        r = fgcd("calibrate", "hand-eye", "--mode", "target-free", *rig, *campaign, "--yes")
        assert r.returncode == 2, r.stderr
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1, r.stderr  # no "warning: using nominal intrinsics" before the failure
        assert lines[0].startswith("error:") and "intrinsics" in lines[0] and "warning" not in lines[0]


def test_handeye_with_an_unknown_scene_is_refused_naming_the_scenes():
    r = fgcd("calibrate", "hand-eye", "--driver", "sim", "--scene", "nosuch", "--yes")
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "nosuch" in lines[0] and "stele" in lines[0], r.stderr


# ----------------------------------------------------------------------------- item 7: plain progress callbacks
def _procedure_fakes():
    """The fake rig of ``test_procedure.py`` (tests are not a package: loaded by path)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("_procedure_fakes", Path(__file__).with_name("test_procedure.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_target_free_reports_its_progress_through_a_plain_callback():
    fakes = _procedure_fakes()
    CAMERA, FakeCamera, FakeVSE, IdealPlatform = fakes.CAMERA, fakes.FakeCamera, fakes.FakeVSE, fakes.IdealPlatform

    platform = IdealPlatform()
    X = make_pose(exp_so3([0.1, -0.3, 0.2]), [0.03, -0.05, 0.08])
    guard = MotionGuard(platform, GuardLimits(max_step_m=0.006, max_step_rad=math.radians(1.2)))
    calls = []
    run_target_free(guard, FakeCamera(), lambda cam: FakeVSE(platform, X, 0.42), camera=CAMERA,
                    on_progress=lambda done, total, label: calls.append((done, total, label)))
    path = [c for c in calls if c[1] > 0]
    assert path, calls
    totals = {t for _, t, _ in path}
    assert len(totals) == 1  # one bar over the whole path
    dones = [d for d, _, _ in path]
    assert dones == sorted(dones) and dones[-1] == totals.pop()
    assert path[0][2].startswith("hand-eye motions (stop 1/") and "stop 13/13" in path[-1][2]
    assert calls[-1][1] == 0 and "refinement" in calls[-1][2]  # the refinement: length unknown


class _Guard:
    def __init__(self):
        self.platform = SimpleNamespace(flange_pose=lambda: np.eye(4))

    def move_by(self, step):
        return SimpleNamespace(duration_s=0.1)


class _Vse:
    def __init__(self):
        self.frames = 0

    def latest(self):
        self.frames += 1
        return SimpleNamespace(frames_processed=self.frames, status="tracking", T_map_cam=np.eye(4))


def test_session_exploration_reports_every_substep():
    from fgcd_cli.relocation.session import VseSession, exploration_pattern

    calls = []
    session = VseSession(guard=_Guard(), vse=_Vse(), on_progress=lambda d, t, label: calls.append((d, t, label)))
    motions = exploration_pattern(translation_m=0.02, legs=3)
    session.explore(motions)
    total = sum(session.substeps(M) for M in motions)
    assert [d for d, _, _ in calls] == list(range(1, total + 1))
    assert {t for _, t, _ in calls} == {total}
    assert calls[0][2] == f"exploring (1/{len(motions)})" and calls[-1][2] == f"exploring ({len(motions)}/{len(motions)})"


def test_the_cli_bar_keeps_one_step_per_label_and_hides_for_questions():
    from rich.console import Console
    from rich.progress import Progress

    from fgcd_cli.cli.progress import StepBar, step_progress

    with step_progress(enabled=False) as bar:
        assert bar is None  # --json: no bar
    with Progress(console=Console(file=open("/dev/null", "w"))) as progress:
        bar = StepBar(progress)
        bar(1, 10, "exploring (1/5)")
        bar(4, 10, "exploring (2/5)")
        assert len(progress.tasks) == 1 and progress.tasks[0].completed == 4
        bar(0, 0, "writing the reference")
        assert len(progress.tasks) == 1 and progress.tasks[0].total is None
        assert bar.paused(lambda text: text == "move?")("move?") is True
        assert bar.paused(None) is None
