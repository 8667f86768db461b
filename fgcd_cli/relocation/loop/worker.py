"""The alignment thread of the parallel rACR loop (paper 000, Fig. 2).

It aligns the latest VSE state to the reference again and again and publishes
each estimate as the "latest value" under a condition variable: readers take
the latest without waiting, and a reader that needs a newer one waits on the
condition (:meth:`AlignmentWorker.wait_until`) instead of polling.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from fgcd_cli.relocation.racr.aligner import Aligner, AlignmentEstimate, AlignmentProblem, align_once
from fgcd_cli.relocation.waiting import wait_for_state
from fgcd_cli.vse.types import VseStatus
from fgcd_core.sim3 import Sim3

__all__ = ["ALIGNMENT_STEP_S", "AlignmentWorker", "SteppedAlignmentWorker"]

#: Longest wait for a new VSE state before the thread checks whether it is asked to stop, seconds.
VSE_WAIT_S = 0.01

#: A deterministic run's nominal cost of one alignment run (fast, then fine) on the step clock, seconds: the
#: loop's patience rules and the time on the rig count it instead of the wall time the run took.
ALIGNMENT_STEP_S = 1.0


class AlignmentWorker:
    """The alignment thread: aligns the latest VSE state again and again.

    Parameters
    ----------
    vse : VseThreadLike
        Source of the latest state.
    problem : AlignmentProblem
        Reference, camera, scale, fast/fine.
    init : Sim3
        Starting similarity until a trustworthy estimate replaces it.
    min_points : int
        Cloud size needed before aligning.
    aligner : Aligner
        One alignment of a state (default :func:`align_once`).
    """

    def __init__(self, *, vse, problem: AlignmentProblem, init: Sim3, min_points: int, aligner: Aligner = align_once):
        self._vse = vse
        self._problem = problem
        self._init = init
        self._min_points = min_points
        self._aligner = aligner
        self._cond = threading.Condition()
        self._latest: AlignmentEstimate | None = None
        self._last_ok: AlignmentEstimate | None = None  # starting point of the next run
        self._serial = 0
        self._stop = threading.Event()
        self._error: str | None = None
        self._thread = threading.Thread(target=self._run, name="fgcd-alignment", daemon=True)

    def start(self) -> AlignmentWorker:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=120)  # one alignment run at most; never leave it inside native code

    @property
    def error(self) -> str | None:
        return self._error

    def latest(self) -> AlignmentEstimate | None:
        with self._cond:
            return self._latest

    def latest_ok(self) -> AlignmentEstimate | None:
        """The newest trustworthy estimate, if the newest published one is trustworthy."""
        with self._cond:
            return self._latest if self._latest is not None and self._latest.ok else None

    def wait_until(self, predicate: Callable[[AlignmentEstimate | None], bool], timeout_s: float) -> bool:
        """Wait until ``predicate(latest())`` holds or the thread failed; False after ``timeout_s`` seconds."""
        with self._cond:
            return self._cond.wait_for(
                lambda: self._error is not None or predicate(self._latest), timeout=max(0.0, timeout_s)
            )

    def can_align(self, state) -> bool:
        """Whether this thread aligns ``state`` at all: a tracking VSE with at least ``min_points`` cloud points."""
        return state.status == VseStatus.TRACKING and len(state.cloud) >= self._min_points

    def _ready(self, state, last_frame: int) -> bool:
        return self.can_align(state) and state.frames_processed != last_frame

    def _wait_for_vse(self, last_frame: int) -> None:
        """Wait (at most ``VSE_WAIT_S``) for a state worth aligning; a stopped VSE returns at once, so
        the rest of the period is waited on the stop event."""
        t0 = time.monotonic()
        if wait_for_state(self._vse, lambda st: self._ready(st, last_frame), VSE_WAIT_S) is None:
            self._stop.wait(max(0.0, VSE_WAIT_S - (time.monotonic() - t0)))

    def _publish(self, est: AlignmentEstimate) -> None:
        with self._cond:
            self._serial = est.serial
            # a failed estimate is published too (the loop pauses on it) but never
            # replaces the starting point of the next run
            self._latest = est
            self._cond.notify_all()
        if est.ok:
            self._last_ok = est

    def _run(self) -> None:
        last_frame = -1
        try:
            while not self._stop.is_set():
                state = self._vse.latest()
                if not self._ready(state, last_frame):
                    self._wait_for_vse(last_frame)
                    continue
                last_frame = state.frames_processed
                init = self._last_ok.T_ref_cur if self._last_ok is not None else self._init
                for est in self._aligner(state=state, problem=self._problem, init=init, serial=self._serial + 1):
                    self._publish(est)
                    if self._stop.is_set():
                        break
        except Exception as exc:  # noqa: BLE001 - reported to the adjustment thread, which stops
            with self._cond:
                self._error = f"{type(exc).__name__}: {exc}"
                self._cond.notify_all()


class SteppedAlignmentWorker(AlignmentWorker):
    """The alignment "thread" of a deterministic run: no thread, the steps in a fixed order.

    Each tick: the VSE processes a frame (:class:`fgcd_cli.vse.thread.SteppedVse`), then the
    alignment runs to completion on the latest state, then the adjustment reads the result. A
    read (:meth:`latest`, :meth:`latest_ok`) first aligns the VSE's latest state when it is new and
    alignable (the rule of :meth:`AlignmentWorker.can_align`); :meth:`wait_until` steps the VSE one
    frame at a time, aligning after each, until its predicate holds or ``timeout_s`` seconds of the
    VSE's step clock have passed. The same seeds then give the same estimates, in the same order.
    """

    _last_frame = -1  # frames_processed of the state aligned last

    def start(self) -> SteppedAlignmentWorker:
        return self

    def stop(self) -> None:
        self._stop.set()

    def _tick(self) -> None:
        """Align the VSE's latest state to completion, when it is new and alignable."""
        state = self._vse.latest()
        if self._stop.is_set() or self._error is not None or not self._ready(state, self._last_frame):
            return
        self._last_frame = state.frames_processed
        init = self._last_ok.T_ref_cur if self._last_ok is not None else self._init
        try:
            for est in self._aligner(state=state, problem=self._problem, init=init, serial=self._serial + 1):
                self._publish(est)
        except Exception as exc:  # noqa: BLE001 - reported to the adjustment, which stops (as the thread's)
            self._error = f"{type(exc).__name__}: {exc}"
        advance = getattr(self._vse, "advance", None)
        if advance is not None:
            advance(ALIGNMENT_STEP_S)

    def latest(self) -> AlignmentEstimate | None:
        self._tick()
        return self._latest

    def latest_ok(self) -> AlignmentEstimate | None:
        self._tick()
        return self._latest if self._latest is not None and self._latest.ok else None

    def wait_until(self, predicate: Callable[[AlignmentEstimate | None], bool], timeout_s: float) -> bool:
        deadline = self._vse.seconds + max(0.0, timeout_s)
        while True:
            self._tick()
            if self._error is not None or predicate(self._latest):
                return True
            if self._stop.is_set() or self._vse.seconds >= deadline:
                return False
            before = self._vse.seconds
            self._vse.step()
            if self._vse.seconds <= before:  # a VSE that cannot step: nothing will change
                return False
