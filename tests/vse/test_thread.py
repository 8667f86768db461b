"""VseThread: latest() never blocks for long, is consistent, reset and stop work; isolation from the simulator."""

import ast
import pathlib
import threading
import time
from dataclasses import dataclass

import numpy as np

from fgcd_cli.vse.engine import MonocularVSE, RgbdVSE
from fgcd_cli.vse.thread import VseThread
from fgcd_cli.vse.types import VseConfig


@dataclass
class _Frame:
    image: np.ndarray
    timestamp_s: float
    depth: np.ndarray | None = None


class _RenderedSource:
    """Camera source replaying an exploration sweep over the synthetic relief (then holding still)."""

    def __init__(self, world, camera, poses, *, depth=False):
        self.frames = []
        for i, T in enumerate(poses):
            img, d = world.render(camera, T)
            self.frames.append(_Frame(img, 0.1 * i, d if depth else None))
        self.i = 0
        self.lock = threading.Lock()

    def grab(self):
        with self.lock:
            f = self.frames[min(self.i, len(self.frames) - 1)]
            self.i += 1
        return _Frame(f.image, 0.1 * (self.i - 1), f.depth)


def test_latest_is_cheap_and_consistent_while_engine_runs(world, small_camera, helpers):
    src = _RenderedSource(world, small_camera, helpers.exploration_poses(24))
    th = VseThread(MonocularVSE(small_camera, config=VseConfig(semidense=True)), src)
    worst = 0.0
    seen = []
    first = None  # (time, frames) at the first processed frame: the engine's start-up is not a frame
    with th:
        deadline = (
            time.monotonic() + 240
        )  # generous: a loaded 2-core machine maps slowly; this test is about consistency
        while time.monotonic() < deadline:
            t0 = time.perf_counter()
            st = th.latest()
            worst = max(worst, time.perf_counter() - t0)
            seen.append(st.frames_processed)
            if first is None and st.frames_processed >= 1:
                first = (time.perf_counter(), st.frames_processed)
            # a snapshot is internally consistent: the cloud only references published keyframes
            if len(st.cloud):
                assert set(np.unique(st.cloud.keyframe_ids)) <= {k.id for k in st.keyframes}
            if st.frames_processed >= 30:
                break
            time.sleep(0.002)
        assert first is not None, th.latest().message
        frame_s = (time.perf_counter() - first[0]) / max(seen[-1] - first[1], 1)
    assert not th.running
    assert seen[-1] >= 30, th.latest().message
    assert all(b >= a for a, b in zip(seen, seen[1:]))  # monotonic
    # reading never waited for a frame: a read that waited would take about one frame's processing time;
    # measured against this run's own time per frame after the first (a loaded machine slows both alike)
    assert worst < 0.5 * frame_s, (worst, frame_s)
    assert th.latest().status == "tracking"


def test_wait_for_reset_and_stop(world, small_camera, helpers):
    src = _RenderedSource(world, small_camera, helpers.exploration_poses(20))
    th = VseThread(MonocularVSE(small_camera, config=VseConfig(semidense=False)), src).start()
    try:
        st = th.wait_for(lambda s: s.status == "tracking" and s.frames_processed >= 6, timeout=60)
        assert st is not None and st.status == "tracking"
        t_reset = st.timestamp_s
        th.reset()
        st2 = th.wait_for(lambda s: s.frames_processed <= 2, timeout=30)
        assert st2 is not None and st2.frames_processed <= 2
        # nothing of the old map survives: every keyframe comes from after the reset
        assert all(k.timestamp_s > t_reset for k in st2.keyframes)
        assert th.wait_for(lambda s: False, timeout=0.2) is None
    finally:
        th.stop()
    assert not th.running


def test_thread_feeds_depth_to_rgbd_engine(world, small_camera, helpers):
    src = _RenderedSource(world, small_camera, helpers.exploration_poses(40)[:6], depth=True)
    th = VseThread(RgbdVSE(small_camera), src).start()
    try:
        st = th.wait_for(lambda s: s.frames_processed >= 4, timeout=60)
    finally:
        th.stop()
    assert st is not None and st.status == "tracking" and st.scale_is_metric


def test_camera_errors_end_in_failed_state(small_camera):
    class Broken:
        def grab(self):
            raise RuntimeError("cable unplugged")

    th = VseThread(MonocularVSE(small_camera), Broken(), max_consecutive_errors=3).start()
    st = th.wait_for(lambda s: s.status == "failed", timeout=10)
    th.stop()
    assert st is not None and "cable unplugged" in st.message


def test_vse_never_imports_the_simulator():
    root = pathlib.Path(__file__).resolve().parents[2] / "fgcd_cli" / "vse"
    for path in root.rglob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            assert not any(n == "fgcd_drivers.sim" or n.startswith("fgcd_drivers.sim.") for n in names), path
