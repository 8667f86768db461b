"""A VSE session: the exploration pattern, its sub-stepped motions, the time it counts."""

import math
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest

from fgcd_cli.errors import run_record
from fgcd_cli.relocation.session import VseSession, exploration_pattern
from fgcd_core.se3 import exp_se3, rotation_angle_rad


def _compose(motions):
    T = np.eye(4)
    stops = [T]
    for M in motions:
        T = T @ M
        stops.append(T)
    return stops


@pytest.mark.parametrize("legs", [3, 4, 6])
def test_pattern_returns_to_start_and_splitting_keeps_the_path(legs):
    one = _compose(exploration_pattern(translation_m=0.04, legs=legs))
    two = _compose(exploration_pattern(translation_m=0.04, legs=legs, stops_per_leg=2))
    assert len(two) == 2 * (len(one) - 1) + 1
    np.testing.assert_allclose(one[-1], np.eye(4), atol=1e-12)
    # every original waypoint is still visited, in order, with one stop half-way between
    for k, T in enumerate(one):
        np.testing.assert_allclose(two[2 * k], T, atol=1e-12)
    for k in range(len(one) - 1):
        mid = two[2 * k + 1]
        d_a = np.linalg.norm(mid[:3, 3] - one[k][:3, 3])
        d_b = np.linalg.norm(one[k + 1][:3, 3] - mid[:3, 3])
        assert d_a == pytest.approx(d_b, rel=0.05)


def test_pattern_has_translation_on_every_leg_and_small_tilts():
    for M in exploration_pattern(translation_m=0.04, legs=6):
        assert np.linalg.norm(M[:3, 3]) > 0.02  # a monocular engine needs translation
        assert rotation_angle_rad(M[:3, :3]) < math.radians(5)


class _SlowSynthesisVse:
    """A VSE thread stand-in whose every frame takes ``render_s`` of synthesis plus ``process_s`` of work."""

    def __init__(self, render_s: float, process_s: float):
        self.synthesis = 0.0
        self.frames = 0
        self._stop = threading.Event()

        def run():
            while not self._stop.is_set():
                time.sleep(render_s)
                self.synthesis += render_s
                time.sleep(process_s)
                self.frames += 1

        self._thread = threading.Thread(target=run, daemon=True)
        self._thread.start()

    def latest(self):
        from types import SimpleNamespace

        return SimpleNamespace(frames_processed=self.frames)

    def stop(self):
        self._stop.set()
        self._thread.join()


def test_frame_waits_count_without_the_synthesis_of_the_frames():
    """Rig-time model: a streaming camera costs the VSE's work (at least 1/fps a frame), not the rendering."""
    from fgcd_cli.relocation.session import VseSession

    render_s, process_s, frames = 0.06, 0.01, 5
    vse = _SlowSynthesisVse(render_s, process_s)
    try:
        plain = VseSession(guard=None, vse=vse)
        plain.settle(frames=frames)
        modelled = VseSession(guard=None, vse=vse, frame_synthesis_s=lambda: vse.synthesis, camera_fps=30.0)
        modelled.settle(frames=frames)
    finally:
        vse.stop()
    # without the model every frame costs render + process (the first one partly)
    assert plain.timing.wait_s >= (frames - 1) * (render_s + process_s)
    assert plain.timing.synthetic_s == 0.0
    # with it, the rendering is set aside and each frame costs the 1/30 s floor (> process_s here)
    assert modelled.timing.wait_s >= frames / 30.0 - 1e-9
    assert modelled.timing.wait_s < 0.5 * plain.timing.wait_s  # rendering is 6/7 of a frame here
    assert modelled.timing.synthetic_s >= (frames - 1) * render_s - frames / 30.0
    assert modelled.timing.with_synthesis_s == pytest.approx(modelled.timing.wait_s + modelled.timing.synthetic_s)


def test_an_exploration_the_vse_never_tracks_fails_with_the_vses_own_reason():
    """Fewer than three tracked stops: the scale cannot be fitted, and the error says what the VSE last said."""
    from types import SimpleNamespace

    from fgcd_cli.errors import AlgorithmError
    from fgcd_cli.relocation.session import VseSession

    said = "initialising: median parallax 0.12 deg < 0.5 deg"
    vse = SimpleNamespace(latest=lambda: SimpleNamespace(status="initializing", message=said, frames_processed=0))
    session = VseSession(guard=None, vse=vse)
    with pytest.raises(AlgorithmError, match="only 2 tracked exploration waypoints.*median parallax 0.12 deg"):
        session.estimate_scale(np.eye(4), [np.eye(4)] * 2, [np.eye(4)] * 2)


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
        return SimpleNamespace(frames_processed=self.frames, status="tracking", T_map_cam=np.eye(4))

    def stop(self):
        pass


@pytest.mark.parametrize("where", ["in a sub-step", "between sub-steps"])
def test_a_sub_stepped_motion_is_in_progress_until_its_last_sub_step(where):
    run_record.reset()
    M = exp_se3(np.r_[0.02, 0, 0, 0, 0, 0])  # 20 mm: 4 sub-steps
    VseSession(guard=_Guard(), vse=_Vse()).move_by(M)
    assert run_record.moving is False  # a finished motion
    guard, vse = (_Guard(interrupt_at=2), _Vse()) if where == "in a sub-step" else (_Guard(), _Vse(interrupt_after=4))
    with pytest.raises(KeyboardInterrupt):
        VseSession(guard=guard, vse=vse).move_by(M)
    assert run_record.moving is True
    run_record.reset()


def test_session_exploration_reports_every_substep():
    calls = []
    session = VseSession(guard=_Guard(), vse=_Vse(), on_progress=lambda d, t, label: calls.append((d, t, label)))
    motions = exploration_pattern(translation_m=0.02, legs=3)
    session.explore(motions)
    total = sum(session.substeps(M) for M in motions)
    assert [d for d, _, _ in calls] == list(range(1, total + 1))
    assert {t for _, t, _ in calls} == {total}
    assert (
        calls[0][2] == f"exploring (1/{len(motions)})" and calls[-1][2] == f"exploring ({len(motions)}/{len(motions)})"
    )


class _PerThreadSynthesis:
    """A camera's synthesis clock by thread, as ``SimCamera.synthetic_overhead_s``."""

    def __init__(self):
        self.by_thread: dict[int, float] = {}
        self.lock = threading.Lock()

    def render(self, seconds: float) -> None:
        # the time actually spent, as SimCamera measures its renders (a loaded machine oversleeps)
        t0 = time.monotonic()
        time.sleep(seconds)
        spent = time.monotonic() - t0
        with self.lock:
            me = threading.get_ident()
            self.by_thread[me] = self.by_thread.get(me, 0.0) + spent

    def __call__(self, thread: int | None = None) -> float:
        with self.lock:
            return sum(self.by_thread.values()) if thread is None else self.by_thread.get(thread, 0.0)


def test_a_stand_still_block_counts_its_work_but_not_the_rendering_of_its_own_stills():
    """Rig-time model: a real camera's still is its next frame; the VSE thread's stream is not the block's."""
    from fgcd_cli.relocation.session import VseSession

    synth = _PerThreadSynthesis()
    session = VseSession(guard=None, vse=None, frame_synthesis_s=synth, camera_fps=30.0)
    stop = threading.Event()

    def stream():  # the VSE thread renders its frames meanwhile
        while not stop.is_set():
            synth.render(0.02)

    streaming = threading.Thread(target=stream, daemon=True)
    streaming.start()
    still_s, work_s = 0.3, 0.1
    me = threading.get_ident()
    t0 = time.monotonic()
    try:
        with session.standing_still(stills=2):
            synth.render(still_s)  # two stills rendered in this thread
            time.sleep(work_s)  # the matching
    finally:
        wall = time.monotonic() - t0
        stop.set()
        streaming.join()
    rendered_here = synth(me)
    assert rendered_here >= still_s
    # the stills' rendering is set aside, the work counts; the stream's rendering is not subtracted
    assert session.timing.synthetic_s == pytest.approx(rendered_here, abs=1e-9)
    assert session.timing.wait_s == pytest.approx(wall - rendered_here, abs=0.01)
    assert session.timing.wait_s >= work_s
    # without a synthesis clock (a real camera) the whole block counts
    real = VseSession(guard=None, vse=None)
    with real.standing_still(stills=2):
        time.sleep(work_s)
    assert real.timing.wait_s >= work_s and real.timing.synthetic_s == 0.0
    # a block faster than its stills' frame periods counts those periods
    fast = VseSession(guard=None, vse=None, frame_synthesis_s=synth, camera_fps=30.0)
    with fast.standing_still(stills=2):
        synth.render(0.1)
    assert fast.timing.wait_s == pytest.approx(2 / 30.0, abs=1e-6)
