"""The RTDE watchdog kicker of the UR driver, and the control lock it shares with the commands.

ur_rtde's ``setWatchdog(f)`` makes its control script call URScript
``rtde_set_watchdog("input_int_register_0", f, "stop")``: the controller stops the
program, and the motion, when no input update for that register arrives for
``1/f`` s (URScript manual, ``rtde_set_watchdog``; ur_rtde's ``rtde_control.script``).
Every command updates it; between commands :func:`start_kicker`'s thread sends
``kickWatchdog()``. When the link dies the kicks stop reaching the controller,
which then stops the arm by itself (docs/hardware.md, "Faults in the field").
"""

from __future__ import annotations

import threading
import time
from contextlib import contextmanager

from fgcd_core.platform import PlatformConnectionError

__all__ = ["links_up", "locked", "start_kicker"]


def links_up(c, r) -> bool:
    """True when both ur_rtde interfaces report a live connection (``r`` may be None)."""
    try:
        return bool(c.isConnected()) and (r is None or bool(r.isConnected()))
    except RuntimeError:
        return False


@contextmanager
def locked(lock: threading.Lock, timeout_s: float, what: str):
    """Hold ``lock``, or raise: a kick stuck in ur_rtde's reconnect must not hang a command."""
    if not lock.acquire(timeout=timeout_s):
        raise PlatformConnectionError(f"the UR control interface is stuck (a dropped link?); {what} not sent")
    try:
        yield
    finally:
        lock.release()


def start_kicker(c, lock: threading.Lock, period_s: float) -> threading.Event:
    """Kick ``c``'s watchdog every ``period_s`` in a daemon thread; clear the returned event to end it.

    Rule: never call ur_rtde on a dropped link (its reconnect has no timeout and the
    kick would sit in it): the kicks then stop, and the controller stops the arm.
    """
    kicking = threading.Event()
    kicking.set()

    def loop() -> None:
        while kicking.is_set():
            time.sleep(period_s)
            if not lock.acquire(timeout=period_s):
                continue  # a command holds the interface: it updates the watchdog's register itself
            try:
                if not kicking.is_set() or not links_up(c, None):
                    return
                c.kickWatchdog()
            except RuntimeError:
                return
            finally:
                lock.release()

    threading.Thread(target=loop, name="fgcd-ur-watchdog", daemon=True).start()
    return kicking
