"""Waiting for the VSE thread: on its condition variable, not by sleeping in a loop."""

from __future__ import annotations

import time
from collections.abc import Callable

__all__ = ["POLL_S", "wait_for_state"]

#: Poll period for a VSE stand-in that has no condition to wait on (test doubles).
POLL_S = 0.005


def wait_for_state(vse, predicate: Callable[[object], bool], timeout_s: float, *, poll_s: float = POLL_S):
    """The VSE's latest state once ``predicate`` holds for it, or ``None`` after ``timeout_s`` seconds.

    A :class:`fgcd_cli.vse.thread.VseThread` is waited on through its own
    condition (``wait_for``), which wakes at every published state; it also
    returns ``None`` early when that thread was stopped. A stand-in without
    ``wait_for`` is polled every ``poll_s``.
    """
    wait_for = getattr(vse, "wait_for", None)
    if wait_for is not None:
        return wait_for(predicate, timeout_s)
    deadline = time.monotonic() + float(timeout_s)
    while True:
        st = vse.latest()
        if predicate(st):
            return st
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return None
        time.sleep(min(poll_s, remaining))
