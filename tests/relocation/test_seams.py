"""The seams of the renovated relocation package (#20): defaults, enum values, injection, condition waits."""

import threading
import time

import numpy as np
import pytest

from fgcd_cli.relocation.coarse import CoarseConfig, CoarseInputs
from fgcd_cli.relocation.enums import Agreement, CoarseAction, EstimateSource, EstimateStage, LoopMode
from fgcd_cli.relocation.loop import LoopContext, RelocationConfig, relocate
from fgcd_cli.relocation.waiting import wait_for_state
from fgcd_cli.relocation.worker import AlignmentWorker


def test_enum_values_are_the_logged_strings():
    assert [m.value for m in LoopMode] == ["parallel", "serial"]
    assert [s.value for s in EstimateStage] == ["fast", "fine", "image"]
    assert [s.value for s in EstimateSource] == ["image", "3d", ""]
    assert [a.value for a in CoarseAction] == ["move", "descend", "look", "handover", "pause"]
    assert Agreement.NOT_CHECKED.because("no image stage") == "not checked: no image stage"
    assert f"{EstimateSource.THREE_D} estimate" == "3d estimate" and EstimateStage.IMAGE == "image"


def test_an_unknown_mode_is_refused_before_anything_starts():
    from fgcd_cli.errors import AlgorithmError

    with pytest.raises(AlgorithmError, match="unknown relocation mode 'sideways'"):
        relocate(LoopContext(session=None, reference=None, ref_index=None, camera=None, scale=1.0,
                             T_flange_cam=np.eye(4), init=None, config=RelocationConfig(mode="sideways")))


def test_the_contexts_refuse_unknown_inputs_and_inject_their_parts():
    with pytest.raises(TypeError):
        LoopContext(session=None, unknown_option=1)
    with pytest.raises(TypeError):
        CoarseInputs(session=None, unknown_option=1)
    ctx = LoopContext(session=None, reference=None, ref_index=None, camera=None, scale=1.0, T_flange_cam=np.eye(4),
                      init=None, image_refiner=lambda **kw: "measured")
    assert ctx.refiner()() == "measured" and not ctx.can_image
    assert CoarseInputs(session=None, reference=None, ref_index=None, camera=None, scale=1.0, T_flange_cam=np.eye(4),
                        init=None, reference_images=None, grab_current=None).config == CoarseConfig()


class _CondVse:
    """A VSE with a condition (as ``VseThread.wait_for``) publishing a frame every 10 ms."""

    def __init__(self):
        self.frames, self.cond, self.calls = 0, threading.Condition(), 0
        self.stop_ev = threading.Event()
        threading.Thread(target=self._run, daemon=True).start()

    def _run(self):
        while not self.stop_ev.is_set():
            time.sleep(0.01)
            with self.cond:
                self.frames += 1
                self.cond.notify_all()

    def latest(self):
        return self.frames

    def wait_for(self, predicate, timeout):
        self.calls += 1
        with self.cond:
            return self.frames if self.cond.wait_for(lambda: predicate(self.frames), timeout) else None


def test_waits_use_the_vse_condition_and_time_out():
    vse = _CondVse()
    try:
        start = vse.latest()
        assert wait_for_state(vse, lambda n: n >= start + 3, 5.0) >= start + 3 and vse.calls == 1
        assert wait_for_state(vse, lambda n: False, 0.05) is None
    finally:
        vse.stop_ev.set()


def test_the_worker_wakes_its_reader_on_publication():
    from types import SimpleNamespace

    state = SimpleNamespace(status="tracking", cloud=np.zeros((10, 3)), frames_processed=0)
    vse = SimpleNamespace(latest=lambda: state)

    def aligner(*, state, serial=0, **kw):
        time.sleep(0.05)
        return [SimpleNamespace(serial=serial, ok=True, T_ref_cur=None)]

    worker = AlignmentWorker(vse=vse, problem=None, init=None, min_points=1, aligner=aligner).start()
    try:
        t0 = time.monotonic()
        assert worker.wait_until(lambda e: e is not None and e.serial == 1, 10.0)
        assert time.monotonic() - t0 < 5.0 and worker.latest().serial == 1
        assert not worker.wait_until(lambda e: e.serial == 99, 0.05)  # one frame only: no newer estimate
    finally:
        worker.stop()
