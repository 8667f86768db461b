"""Run a VSE engine continuously over a camera source in its own thread.

The worker grabs a frame, processes it and publishes the resulting immutable
:class:`~fgcd_cli.vse.types.VseState` by swapping one reference under a lock;
readers (:meth:`VseThread.latest`) only take that lock for the swap, so they
never wait for a frame to be processed.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from contextlib import contextmanager

from fgcd_cli.vse.types import FrameSource, VseState, VseStatus

__all__ = ["SteppedVse", "VseThread"]


class VseThread:
    """A VSE engine running over a camera source.

    Parameters
    ----------
    engine : VisualSlamEngine
        The engine (``process(image, timestamp_s[, depth=...])``, ``state()``, ``reset()``); a
        ``metric`` one (RGB-D) is given each frame's ``depth``.
    source : FrameSource
        Anything with ``grab() -> frame`` (``frame.image``, ``frame.timestamp_s``,
        optional ``frame.depth``), e.g. a ``fgcd_drivers.cameras`` camera.
    idle_s : float
        Pause between frames (0: as fast as the engine goes).
    max_consecutive_errors : int
        Camera errors in a row after which the thread stops and reports ``failed``.
    """

    def __init__(self, engine, source: FrameSource, *, idle_s: float = 0.0, max_consecutive_errors: int = 20):
        self.engine = engine
        self.source = source
        self.idle_s = float(idle_s)
        self.max_consecutive_errors = int(max_consecutive_errors)
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._latest: VseState = engine.state()
        self._stop = threading.Event()
        self._reset_requested = threading.Event()
        self._hold = threading.Event()
        self._holding = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: str | None = None

    # ------------------------------------------------------------------ control
    def start(self) -> VseThread:
        """Start the worker (idempotent)."""
        if self._thread is not None and self._thread.is_alive():
            return self
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="vse", daemon=True)
        self._thread.start()
        return self

    @contextmanager
    def held(self, *, timeout_s: float = 30.0):
        """Keep the worker from grabbing frames while the caller uses the camera.

        For a measurement under another light (the rig switches its lights, grabs,
        switches back): the engine must not see those frames, whose brightness
        change it would take for motion. Returns once the worker waits between
        frames (a frame it is processing finishes first); a stopped worker is not
        waited for. Raises TimeoutError when it does not reach that point in
        ``timeout_s``.
        """
        self._hold.set()
        try:
            if self.running and not self._holding.wait(timeout_s):
                raise TimeoutError(f"the VSE did not pause within {timeout_s:.0f} s")
            yield self
        finally:
            self._hold.clear()

    def stop(self, timeout: float = 60.0) -> None:
        """Ask the worker to stop and wait for it (at most ``timeout`` seconds).

        The wait is long on purpose: a keyframe's mapping can take seconds on a
        busy machine, and a thread still inside OpenCV/Open3D when the
        interpreter exits aborts the process.
        """
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        with self._cond:
            self._cond.notify_all()

    @property
    def running(self) -> bool:
        """True while the worker thread is alive."""
        return self._thread is not None and self._thread.is_alive()

    def reset(self) -> None:
        """Ask the engine to forget its map before the next frame (non-blocking)."""
        self._reset_requested.set()
        if not self.running:
            self._do_reset()

    def latest(self) -> VseState:
        """The latest published state (never waits for a frame to be processed)."""
        with self._lock:
            return self._latest

    def wait_for(self, predicate: Callable[[VseState], bool], timeout: float) -> VseState | None:
        """Block until ``predicate(latest())`` holds; the state, or ``None`` after ``timeout`` seconds."""
        deadline = time.monotonic() + float(timeout)
        with self._cond:
            while True:
                if predicate(self._latest):
                    return self._latest
                remaining = deadline - time.monotonic()
                if remaining <= 0 or (self._thread is not None and not self._thread.is_alive() and self._stop.is_set()):
                    return None
                self._cond.wait(min(remaining, 0.1))

    def __enter__(self) -> VseThread:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # ------------------------------------------------------------------ worker
    def _publish(self, state: VseState) -> None:
        with self._cond:
            self._latest = state
            self._cond.notify_all()

    def _do_reset(self) -> None:
        self._reset_requested.clear()
        self.engine.reset()
        self._publish(self.engine.state())

    def _run(self) -> None:
        errors = 0
        while not self._stop.is_set():
            if self._hold.is_set():
                self._holding.set()
                while self._hold.is_set() and not self._stop.is_set():
                    time.sleep(0.005)
                self._holding.clear()
                continue
            if self._reset_requested.is_set():
                self._do_reset()
            try:
                frame = self.source.grab()
            except Exception as exc:  # camera trouble: report, retry a few times, then stop
                errors += 1
                self.error = f"camera error: {exc}"
                if errors >= self.max_consecutive_errors:
                    self._publish(_failed(self._latest, f"failed: camera stopped delivering frames ({exc})"))
                    return
                time.sleep(0.05)
                continue
            errors = 0
            if self._stop.is_set():
                break
            try:
                depth = getattr(frame, "depth", None)
                if getattr(self.engine, "metric", False):
                    state = self.engine.process(frame.image, frame.timestamp_s, depth=depth)
                else:
                    state = self.engine.process(frame.image, frame.timestamp_s)
            except Exception as exc:  # an engine bug must not kill the caller silently
                self.error = f"engine error: {type(exc).__name__}: {exc}"
                self._publish(_failed(self._latest, f"failed: {self.error}"))
                return
            self._publish(state)
            if self.idle_s > 0:
                self._stop.wait(self.idle_s)


def _failed(prev: VseState, message: str) -> VseState:
    from dataclasses import replace

    return replace(prev, status=VseStatus.FAILED, message=message)


class SteppedVse:
    """The VSE of a deterministic run: frames are processed in the caller's thread, when it waits for them.

    Same interface as :class:`VseThread` (``start``, ``stop``, ``latest``, ``wait_for``, ``held``,
    ``reset``). No thread runs beside the caller: :meth:`wait_for` grabs and processes one frame at a
    time until its predicate holds, so how many frames the engine sees, and in what order with the
    motions and the alignments, depends only on the steps, never on the machine's speed
    (docs/relocation.md, "Reproducibility"). Its clock (:attr:`seconds`) is the steps' too: one
    ``frame_period_s`` per frame, and ``wait_for``'s timeout is counted on it.
    """

    stepped = True

    def __init__(
        self, engine, source: FrameSource, *, frame_period_s: float = 1.0 / 30.0, max_consecutive_errors: int = 20
    ):
        self.engine = engine
        self.source = source
        self.frame_period_s = float(frame_period_s)
        self.max_consecutive_errors = int(max_consecutive_errors)
        self._latest: VseState = engine.state()
        self._steps = 0
        self._advanced_s = 0.0
        self._errors = 0
        self._stopped = False
        self._dead = False  # the camera or the engine failed: no further frame
        self.error: str | None = None

    @classmethod
    def like(cls, thread: VseThread) -> SteppedVse:
        """The stepped twin of a (not started) :class:`VseThread`: its engine and its source."""
        return cls(thread.engine, thread.source, max_consecutive_errors=thread.max_consecutive_errors)

    @property
    def seconds(self) -> float:
        """The steps' clock: ``frame_period_s`` per frame step so far (resets included), plus what
        :meth:`advance` added (the nominal cost of the other threads' steps)."""
        return self._steps * self.frame_period_s + self._advanced_s

    def advance(self, seconds: float) -> None:
        """Count a step of another thread on this clock (an alignment run: its nominal cost)."""
        self._advanced_s += max(0.0, float(seconds))

    @property
    def running(self) -> bool:
        """False: nothing runs beside the caller."""
        return False

    def start(self) -> SteppedVse:
        self._stopped = False
        return self

    def stop(self, timeout: float = 60.0) -> None:
        self._stopped = True

    @contextmanager
    def held(self, *, timeout_s: float = 30.0):
        """Nothing to hold: frames are only grabbed inside :meth:`wait_for`."""
        yield self

    def reset(self) -> None:
        """Forget the map now."""
        self.engine.reset()
        self._latest = self.engine.state()

    def latest(self) -> VseState:
        return self._latest

    def step(self) -> VseState:
        """Grab and process one frame (a failed camera or engine: the failed state, no frame)."""
        self._steps += 1
        if self._dead or self._stopped:
            return self._latest
        try:
            frame = self.source.grab()
        except Exception as exc:  # camera trouble: as VseThread, a few retries then failed
            self._errors += 1
            self.error = f"camera error: {exc}"
            if self._errors >= self.max_consecutive_errors:
                self._dead = True
                self._latest = _failed(self._latest, f"failed: camera stopped delivering frames ({exc})")
            return self._latest
        self._errors = 0
        try:
            if getattr(self.engine, "metric", False):
                self._latest = self.engine.process(frame.image, frame.timestamp_s, depth=getattr(frame, "depth", None))
            else:
                self._latest = self.engine.process(frame.image, frame.timestamp_s)
        except Exception as exc:  # an engine bug must not kill the caller silently
            self._dead = True
            self.error = f"engine error: {type(exc).__name__}: {exc}"
            self._latest = _failed(self._latest, f"failed: {self.error}")
        return self._latest

    def wait_for(self, predicate: Callable[[VseState], bool], timeout: float) -> VseState | None:
        """Process frames until ``predicate(latest())`` holds; ``None`` after ``timeout`` seconds of the steps'
        clock, or at once when no frame can come (stopped, failed)."""
        deadline = self.seconds + float(timeout)
        while True:
            if predicate(self._latest):
                return self._latest
            if self._dead or self._stopped or self.seconds >= deadline:
                return None
            self.step()

    def __enter__(self) -> SteppedVse:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
