"""relocation/waiting.py: waits on the VSE's condition, with a timeout."""

import threading
import time

from fgcd_cli.relocation.waiting import wait_for_state


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
