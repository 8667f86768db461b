"""VseThread.held: no frame is grabbed while the rig measures under another light."""

import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest

from fgcd_cli.vse.thread import VseThread


class _CountingSource:
    def __init__(self):
        self.grabs = 0
        self.lock = threading.Lock()

    def grab(self):
        with self.lock:
            self.grabs += 1
        time.sleep(0.002)
        return SimpleNamespace(image=np.zeros((8, 8), np.uint8), timestamp_s=time.monotonic())


class _Engine:
    def state(self):
        return SimpleNamespace(status="initializing")

    def process(self, image, timestamp_s):
        time.sleep(0.01)  # a frame being processed when the hold is asked finishes first
        return self.state()

    def reset(self):
        pass


def test_no_frame_is_grabbed_while_held_and_grabbing_resumes_after():
    source = _CountingSource()
    thread = VseThread(_Engine(), source).start()
    try:
        time.sleep(0.1)
        with thread.held():
            before = source.grabs
            time.sleep(0.2)  # ~15 frames' time
            during = source.grabs - before
        time.sleep(0.1)
        after = source.grabs - before - during
    finally:
        thread.stop()
    assert before > 0 and during == 0 and after > 0


def test_held_on_a_stopped_thread_does_not_wait():
    thread = VseThread(_Engine(), _CountingSource())
    t0 = time.monotonic()
    with thread.held(timeout_s=5.0):
        pass
    assert time.monotonic() - t0 < 1.0


def test_held_says_when_the_worker_never_pauses():
    class _Stuck(_Engine):
        def process(self, image, timestamp_s):
            time.sleep(2.0)
            return self.state()

    thread = VseThread(_Stuck(), _CountingSource()).start()
    try:
        time.sleep(0.05)
        with pytest.raises(TimeoutError):
            with thread.held(timeout_s=0.2):
                pass
    finally:
        thread.stop()
