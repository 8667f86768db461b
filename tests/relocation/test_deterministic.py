"""The deterministic rACR loop: the VSE, the alignment and the adjustment stepped in a fixed order in one thread,
so the same seeds give the same run whatever the machine's speed (docs/relocation.md, "Reproducibility").

The fast tests use exact stand-ins (a stepped VSE over a fake engine that sees the platform's true pose, an
alignment with seeded noise and an unseeded sleep); the slow test relocates a small simulated station twice.
"""

from __future__ import annotations

import json
import random
import threading
import time
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import pytest

from fgcd_cli.relocation.config import ReferenceData, RelocationConfig
from fgcd_cli.relocation.loop.context import LoopContext
from fgcd_cli.relocation.loop.parallel import relocate
from fgcd_cli.relocation.loop.worker import ALIGNMENT_STEP_S
from fgcd_cli.relocation.racr.aligner import AlignmentEstimate
from fgcd_cli.relocation.session import VseSession
from fgcd_cli.vse.thread import SteppedVse
from fgcd_core.platform import Capabilities, GuardLimits, MotionGuard, MoveResult
from fgcd_core.se3 import exp_se3, invert_pose, log_se3
from fgcd_core.sim3 import Sim3


class Platform:
    """A 6-DoF platform whose motions err by a seeded proportional error."""

    name = "test"

    def __init__(self, T0, events):
        self.true = np.array(T0, dtype=float)
        self.reported = np.array(T0, dtype=float)
        self.rng = np.random.default_rng(3)
        self.events = events

    def capabilities(self):
        return Capabilities(
            dof=6,
            controllable=("x", "y", "z", "rx", "ry", "rz"),
            workspace_min_m=(-5, -5, -5),
            workspace_max_m=(5, 5, 5),
            max_linear_speed_m_s=0.1,
            max_angular_speed_rad_s=1.0,
        )

    def flange_pose(self):
        return self.reported.copy()

    def move_to(self, T, *, speed_fraction=1.0):
        M = invert_pose(self.reported) @ T
        self.true = self.true @ exp_se3(log_se3(M) * (1.0 + 0.05 * self.rng.uniform(-1, 1, 6)))
        self.reported = np.array(T, dtype=float)
        self.events.append(("move",))
        return MoveResult(
            T_base_flange_target=T,
            T_base_flange_reached=T,
            T_base_flange_commanded=T,
            duration_s=float(np.linalg.norm(M[:3, 3])) * 150.0,
        )

    def connect(self):
        pass

    def stop(self):
        pass

    def home(self):
        pass

    def close(self):
        pass


@dataclass(frozen=True)
class Cloud:
    n: int

    def __len__(self):
        return self.n

    @property
    def points(self):
        return np.zeros((self.n, 3))


@dataclass(frozen=True)
class State:
    status: str
    T_map_cam: np.ndarray | None
    frames_processed: int
    cloud: Cloud
    keyframes: tuple = ()
    message: str = ""


class Source:
    """A camera whose "image" is the true camera pose in the map frame (scaled by 1/s)."""

    def __init__(self, platform, X, T_map_base, s, events):
        self.platform, self.X, self.T_map_base, self.s, self.events = platform, X, T_map_base, s, events
        self.n = 0

    def grab(self):
        self.n += 1
        self.events.append(("frame", self.n))
        T = self.T_map_base @ self.platform.true @ self.X
        T[:3, 3] /= self.s
        return SimpleNamespace(image=T, timestamp_s=self.n / 30.0)


class Engine:
    def __init__(self):
        self.frames = 0

    def state(self):
        return State("initializing", None, self.frames, Cloud(0))

    def process(self, image, timestamp_s):
        self.frames += 1
        return State("tracking", image, self.frames, Cloud(1000))

    def reset(self):
        self.frames = 0


def _run(mode: str) -> tuple[list, object]:
    """One deterministic relocation with the stand-ins; the events in order and the result."""
    events: list = []
    rng = np.random.default_rng(5)
    X = exp_se3([0.05, -0.02, 0.1, 0.2, -0.1, 0.3])
    T0 = exp_se3([0.3, 0.1, 0.4, 0.1, 0.2, 0.0])
    T_map_base, s = exp_se3(rng.normal(size=6) * 0.3), 0.37
    T_ref_base = exp_se3(rng.normal(size=6) * 0.3)
    T_ref_camref = T_ref_base @ T0 @ exp_se3([0.02, -0.015, 0.01, 0.03, -0.02, 0.05]) @ X
    T_ref_cur = Sim3.from_pose(T_ref_base @ invert_pose(T_map_base))
    noise = np.random.default_rng(11)  # the alignment's noise, seeded as a visit's

    def aligner(*, state, problem, init, serial=0):
        events.append(("align", state.frames_processed))
        time.sleep(random.random() * 0.003)  # the machine's speed: unseeded on purpose
        T = T_ref_cur.matrix() @ exp_se3(noise.normal(0, 2e-4, 6))
        return [
            AlignmentEstimate(
                T_ref_cur=Sim3.from_matrix(T),
                stage="fast",
                ok=True,
                reason="noisy",
                vse_frame=state.frames_processed,
                seconds=0.0,
                serial=serial,
            )
        ]

    platform = Platform(T0, events)
    vse = SteppedVse(Engine(), Source(platform, X, T_map_base, s, events)).start()
    session = VseSession(
        guard=MotionGuard(platform, GuardLimits(max_step_m=0.1, max_step_rad=0.5)),
        vse=vse,
        substep_m=0.01,
        substep_rad=0.05,
    )
    ref = ReferenceData(points=np.zeros((10, 3)), intensities=np.zeros(10), T_ref_camref=T_ref_camref)
    result = relocate(
        LoopContext(
            session=session,
            reference=ref,
            ref_index=None,
            camera=None,
            scale=s,
            T_flange_cam=X,
            init=Sim3(),
            aligner=aligner,
            config=RelocationConfig(mode=mode, deterministic=True, eta=5e-3, tolerance_mm=0.5, max_adjustments=10),
        )
    )
    return events, result


def _records(result) -> list[dict]:
    return [{k: v for k, v in json.loads(r.to_json()).items() if k != "t_wall_s"} for r in result.records]


@pytest.mark.parametrize("mode", ["parallel", "serial"])
def test_a_deterministic_run_steps_frame_then_alignment_then_adjustment(mode):
    threads_before = set(threading.enumerate())
    events, result = _run(mode)
    # no thread beside the caller (a thread of an earlier test may end meanwhile: compare sets, not counts)
    assert not set(threading.enumerate()) - threads_before
    assert result.converged and result.adjustments >= 2
    aligns = [i for i, e in enumerate(events) if e[0] == "align"]
    assert aligns
    for i in aligns:  # each alignment runs on the frame processed just before it, to completion
        last_frame = max(e[1] for e in events[:i] if e[0] == "frame")
        assert events[i][1] == last_frame
    moves = [i for i, e in enumerate(events) if e[0] == "move"]
    # the adjustment moves on an alignment of the view after the previous motion: between two motions
    # an alignment, after the frame that motion's settling processed
    for a, b in zip(moves, moves[1:]):
        if any(e[0] == "frame" for e in events[a:b]) and b - a > 2:
            assert any(e[0] == "align" for e in events[a:b]), events[a:b]


@pytest.mark.parametrize("mode", ["parallel", "serial"])
def test_two_deterministic_runs_are_identical(mode):
    events_a, a = _run(mode)
    events_b, b = _run(mode)
    assert events_a == events_b
    assert _records(a) == _records(b)  # t_session_s included: the time on the rig counts the steps
    np.testing.assert_array_equal(a.final_T_ref_cam, b.final_T_ref_cam)
    assert a.session_s == b.session_s


def test_the_step_clock_counts_frames_and_alignments():
    events, result = _run("serial")
    frames = sum(1 for e in events if e[0] == "frame")
    aligns = sum(1 for e in events if e[0] == "align")
    assert result.session_s == pytest.approx(result.platform_s + frames / 30.0 + aligns * ALIGNMENT_STEP_S)


def test_a_stepped_vse_waits_on_its_own_clock():
    events: list = []
    platform = Platform(np.eye(4), events)
    vse = SteppedVse(Engine(), Source(platform, np.eye(4), np.eye(4), 1.0, events))
    assert vse.wait_for(lambda st: st.frames_processed >= 3, timeout=10.0).frames_processed == 3
    assert vse.seconds == pytest.approx(3 / 30.0)
    assert vse.wait_for(lambda st: False, timeout=1.0) is None  # 1 s of its clock: 30 frames, no wall time
    assert vse.latest().frames_processed == 33
    vse.stop()
    assert vse.wait_for(lambda st: st.frames_processed > 33, timeout=5.0) is None  # stopped: at once


def _simulated_station(tmp_path):
    """A small simulated station with a reference (the cheapest capture the use cases allow)."""
    from fgcd_cli.app import capture as capture_uc
    from fgcd_cli.app.determinism import deterministic_rig
    from fgcd_cli.app.rig import open_sim_rig
    from fgcd_cli.app.scenario import SimScenario
    from fgcd_cli.campaign.store import init_campaign
    from fgcd_cli.metrics.sim_eval import reference_truth

    camp = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim"})
    station = camp.create_station("s")
    rig = open_sim_rig(SimScenario(scene="relief_panel", seed=1, lighting="front"), T_flange_cam=None, intrinsics=None)
    try:
        capture_uc.capture_reference(
            deterministic_rig(rig.handles),
            station,
            lightings=["front"],
            metadata={"driver": "sim", "scenario": rig.info["scenario"]},
            evaluation=lambda: reference_truth(rig.sim),
        )
    finally:
        rig.close()
    return station


def _relocate_once(station):
    from fgcd_cli.app.relocate import relocate_and_capture
    from fgcd_cli.app.relocate_request import RelocateHooks, RelocateRequest
    from fgcd_cli.app.rig import open_sim_rig
    from fgcd_cli.app.scenario import SimScenario

    scenario = SimScenario(
        scene="relief_panel", seed=1, lighting="led:3", start_offset_mm=20, start_offset_deg=2, session_seed=2
    )
    rig = open_sim_rig(scenario, T_flange_cam=None, intrinsics=None)
    try:
        out = relocate_and_capture(
            rig.handles,
            station,
            RelocateRequest(
                config=RelocationConfig(deterministic=True, image_refine=False, image_fallback=False),
                lightings=["led:3"],
                metadata={"driver": "sim", "scenario": rig.info["scenario"]},
            ),
            hooks=RelocateHooks(),
        )
    finally:
        rig.close()
    return out


@pytest.mark.slow
def test_two_deterministic_relocations_of_a_simulated_station_are_identical(tmp_path):
    from fgcd_cli.app.determinism import pin_native_threads
    from fgcd_cli.campaign import schema

    pin_native_threads()
    station = _simulated_station(tmp_path)
    a, b = _relocate_once(station), _relocate_once(station)
    np.testing.assert_array_equal(a.relocation.final_T_ref_cam, b.relocation.final_T_ref_cam)
    assert _records(a.relocation) == _records(b.relocation)
    va, vb = station.visits()[-2:]
    logs = [
        [
            {k: v for k, v in json.loads(line).items() if k != "t_wall_s"}
            for line in v.bytes(schema.RELOCATION_LOG).decode().splitlines()
        ]
        for v in (va, vb)
    ]
    assert logs[0] == logs[1] and logs[0]
    run = va.metadata["relocation"]["run"]
    assert run["deterministic"] is True and run["seeds"]["session_seed"] == 2 and "numpy" in run["versions"]
    assert a.relocation.session_s == b.relocation.session_s


def test_the_loop_line_says_when_a_run_is_deterministic():
    """A deterministic demo printed 'relocating (parallel)': the loop's name says both."""
    from fgcd_cli.relocation.config import RelocationConfig
    from fgcd_cli.relocation.enums import LoopMode

    assert RelocationConfig().loop_name == "parallel"
    assert RelocationConfig(mode=LoopMode.SERIAL, deterministic=True).loop_name == "serial, deterministic"
