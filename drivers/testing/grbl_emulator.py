"""A GRBL v1.1 controller emulated on a pseudo-terminal, for tests without hardware.

The driver opens :attr:`GrblEmulator.port` (a ``/dev/pts/N`` path) exactly as it
would open ``/dev/ttyUSB0``; a thread serves the master side of the pty with
GRBL's grammar (see GRBL's ``doc/markdown/interface.md``):

* one ``ok`` or ``error:N`` per line; ``ok`` for a motion means *queued*, not
  arrived; a full planner (15 blocks) delays the ``ok`` like the real buffer;
* real-time bytes ``?`` (status report), ``!`` (feed hold), ``~`` (resume),
  ``0x18`` (soft reset), ``0x85`` (jog cancel), never acknowledged;
* ``$$`` settings, ``$I``, ``$G``, ``$X`` unlock, ``$H`` homing, ``$C`` check mode,
  ``$J=`` jogging, ``$N=value`` setting writes; ``G0/G1/G4/G90/G91/G21`` with
  ``F``, axes ``X Y Z`` and optionally ``A B C`` (grblHAL style); spindle and
  coolant ``M3 S…/M4/M5``, ``M7/M8/M9`` (applied once the planner is empty,
  reported by ``$G``, the status ``A:`` field and :meth:`GrblEmulator.outputs`);
* constant-feed motion in real time (scaled by ``time_scale``), soft limits
  (``$20``: ``ALARM:2`` for a G-code motion, ``error:15`` for a jog), alarms with
  ``[MSG:'$H'|'$X' to unlock]``;
* faults on demand: :meth:`inject_alarm`, :meth:`set_silent`,
  :meth:`inject_garbage`, :meth:`unplug` (the pty closed from the board's side:
  the board ends the block it holds) and :meth:`replug` (a new pty, the board's
  state kept).

Machine coordinates follow GRBL's homing convention: after ``$H`` the machine
sits at 0 and travel is ``[-$13x, 0]`` mm on each axis.

pyserial has no loopback that speaks a protocol, and socat would add an
external process; a pty thread is the smallest faithful stand-in, so it is
written by hand here.
"""

from __future__ import annotations

import os
import pty
import select
import threading
import time
import tty
from collections import deque

from fgcd_drivers.testing.grbl_commands import BANNER, GrblCommandsMixin, Segment

__all__ = ["GrblEmulator", "BANNER"]

_PLANNER_BLOCKS = 15


class GrblEmulator(GrblCommandsMixin):
    """GRBL 1.1 on a pseudo-terminal.

    Parameters
    ----------
    axes : str
        Axis letters, ``"XYZ"`` or with rotary axes e.g. ``"XYZABC"``.
    start_mm : sequence of float, optional
        Initial machine position (mm for XYZ, degrees for ABC). Default: all
        axes at -10 (inside the travel).
    homing_enabled : bool
        ``$22``: with homing on, GRBL starts in ``Alarm`` until ``$H`` or ``$X``.
    soft_limits : bool
        ``$20``.
    max_travel_mm : float
        ``$130..$135`` for every axis.
    max_rate_mm_min : float
        ``$110..$115`` for every axis; G0 moves at this rate.
    time_scale : float
        Motions take ``duration * time_scale`` wall-clock seconds (tests use < 1).
    banner_on_open : bool
        Real boards reset when the port opens (DTR) and print the banner; a pty
        cannot see the open, so by default the banner only follows a soft reset.
    """

    def __init__(
        self,
        *,
        axes: str = "XYZ",
        start_mm=None,
        homing_enabled: bool = False,
        soft_limits: bool = True,
        max_travel_mm: float = 300.0,
        max_rate_mm_min: float = 3000.0,
        time_scale: float = 1.0,
    ) -> None:
        self.axes = axes
        self.settings: dict[int, float] = {
            0: 10,
            1: 25,
            2: 0,
            3: 0,
            4: 0,
            5: 0,
            6: 0,
            10: 1,
            11: 0.010,
            12: 0.002,
            13: 0,
            20: int(soft_limits),
            21: 0,
            22: int(homing_enabled),
            23: 0,
            24: 25.0,
            25: 500.0,
            26: 250,
            27: 1.0,
            30: 1000,
            31: 0,
            32: 0,
        }
        for i in range(len(axes)):
            self.settings[100 + i] = 250.0
            self.settings[110 + i] = max_rate_mm_min
            self.settings[120 + i] = 10.0
            self.settings[130 + i] = max_travel_mm
        self.time_scale = float(time_scale)
        self.garble_status = 0  # status reports still to garble (garble_status_reports)
        self.mpos = list(start_mm) if start_mm is not None else [-10.0] * len(axes)
        self.wco = [0.0] * len(axes)
        self.state = "Alarm" if homing_enabled else "Idle"
        self.alarm_code: int | None = None
        self.check_mode = False
        self.absolute = True
        self.feed_mm_min: float | None = None
        self.queue: deque[Segment] = deque()
        self.current: Segment | None = None
        self.hold = False
        self.spindle = "M5"  # M3 (CW) / M4 (CCW) / M5 (off); PWM duty spindle_speed / $30
        self.spindle_speed = 0.0
        self.flood = False  # M8
        self.mist = False  # M7
        self.silent = False
        self.lines_received: list[str] = []
        self.realtime_received: list[int] = []
        self.silent_realtime_received: list[int] = []  # real-time bytes that arrived while silent
        self._reports = 0
        self._lock = threading.RLock()
        self._space = threading.Condition(self._lock)
        self._stop = threading.Event()
        self._pending_lines: deque[str] = deque()
        self._line_ready = threading.Condition(threading.Lock())
        self._master, self._slave = pty.openpty()
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)
        self._threads = [
            threading.Thread(target=self._read_loop, name="grbl-emu-read", daemon=True),
            threading.Thread(target=self._exec_loop, name="grbl-emu-exec", daemon=True),
            threading.Thread(target=self._motion_loop, name="grbl-emu-motion", daemon=True),
        ]
        for t in self._threads:
            t.start()

    # ------------------------------------------------------------------ life cycle
    def close(self) -> None:
        """Stop the threads and close the pty."""
        self._stop.set()
        with self._line_ready:
            self._line_ready.notify_all()
        with self._space:
            self._space.notify_all()
        for t in self._threads:
            t.join(timeout=1.0)
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> GrblEmulator:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ faults
    def inject_alarm(self, code: int = 1) -> None:
        """A hard limit (1) or other alarm: motion stops at once, queue cleared."""
        with self._lock:
            self._enter_alarm(code)

    def set_silent(self, silent: bool = True) -> None:
        """Stop answering anything (a hung controller or a dead link)."""
        self.silent = silent

    def inject_garbage(self, data: bytes) -> None:
        """Write noise on the line (EMI, baud mismatch, a boot loader)."""
        self._write_raw(data)

    def garble_status_reports(self, count: int = 1) -> None:
        """The next ``count`` status reports are cut by line noise (a torn, unparseable report each)."""
        with self._lock:
            self.garble_status = int(count)

    def unplug(self) -> None:
        """The USB cable is pulled: the pty hangs up under the driver.

        The board keeps executing what its planner holds (a real GRBL is not
        reset by a pulled cable), then stays idle: :meth:`moving` tells.
        """
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass
        self._master = self._slave = -1

    def replug(self) -> str:
        """The cable is plugged back in: a new pty (a new ``/dev/pts`` path, as a re-enumerated USB port).

        The board's state is kept (position, alarm, a block still running): a pty carries
        no DTR, so nothing resets it; the driver's connect sends its soft reset. Returns the new port.
        """
        if self._master >= 0:
            self.unplug()  # still plugged: the old pty is pulled first
        master, slave = pty.openpty()
        tty.setraw(slave)
        self._master, self._slave = master, slave
        self.port = os.ttyname(slave)
        reader = threading.Thread(target=self._read_loop, name="grbl-emu-read", daemon=True)
        self._threads.append(reader)
        reader.start()
        return self.port

    def outputs(self) -> dict[str, float | bool]:
        """The accessory pins as the board drives them: spindle enable and PWM duty (0..1), flood, mist."""
        with self._lock:
            on = self.spindle != "M5"
            duty = min(1.0, self.spindle_speed / max(float(self.settings[30]), 1e-9)) if on else 0.0
            return {"spindle": on, "spindle_pwm": duty, "flood": self.flood, "mist": self.mist}

    def moving(self) -> bool:
        """True while the board executes a motion (not held, not in alarm)."""
        with self._lock:
            return (self.current is not None or bool(self.queue)) and not self.hold and self.state != "Alarm"

    def block_left_s(self) -> float:
        """Wall-clock seconds until the board has executed what it holds (the running block and the queue)."""
        with self._lock:
            if self.hold or self.state == "Alarm":
                return 0.0
            left = sum(seg.duration_s for seg in self.queue)
            if self.current is not None:
                left += max(0.0, self.current.duration_s - self.current.elapsed_s)
            return left * self.time_scale

    def position(self) -> list[float]:
        """Current machine position (thread-safe copy)."""
        with self._lock:
            return list(self.mpos)

    # ------------------------------------------------------------------ I/O
    def _write_raw(self, data: bytes) -> None:
        if self._master < 0:
            return
        try:
            os.write(self._master, data)
        except OSError:
            pass

    def _send(self, line: str) -> None:
        if not self.silent:
            self._write_raw(line.encode("ascii") + b"\r\n")

    def _read_loop(self) -> None:
        buffer = bytearray()
        master = self._master  # this pty's: after an unplug a replugged one gets its own reader
        while not self._stop.is_set() and master == self._master:
            try:
                ready, _, _ = select.select([master], [], [], 0.05)
                if not ready:
                    continue
                chunk = os.read(master, 1024)
            except (OSError, ValueError):
                return
            if not chunk:
                return
            for byte in chunk:
                if self.silent:
                    # a hung controller: bytes still arrive on the line (recorded for
                    # the tests) but nothing is executed or answered
                    if byte in (0x3F, 0x21, 0x7E, 0x18, 0x85):
                        self.silent_realtime_received.append(byte)
                    continue
                if byte in (0x3F, 0x21, 0x7E, 0x18, 0x85, 0x90, 0x91, 0x92, 0x93):
                    self.realtime_received.append(byte)
                    self._realtime(byte)
                elif byte in (0x0A, 0x0D):
                    line = buffer.decode("ascii", errors="replace").strip()
                    buffer.clear()
                    if line:
                        with self._line_ready:
                            self._pending_lines.append(line)
                            self._line_ready.notify()
                elif byte >= 0x80:
                    continue  # unsupported extended real-time command: ignored like GRBL
                else:
                    buffer.append(byte)

    def _exec_loop(self) -> None:
        while not self._stop.is_set():
            with self._line_ready:
                while not self._pending_lines and not self._stop.is_set():
                    self._line_ready.wait(0.1)
                if self._stop.is_set():
                    return
                line = self._pending_lines.popleft()
            self.lines_received.append(line)
            reply = self._execute(line)
            if reply is not None:
                self._send(reply)

    # ------------------------------------------------------------------ real-time
    def _realtime(self, byte: int) -> None:
        with self._lock:
            if byte == 0x3F:  # '?'
                if self.garble_status > 0:  # the report is lost to line noise
                    self.garble_status -= 1
                    self._write_raw(b"<Run|MP\xff\xfe")
                else:
                    self._send(self._status())
            elif byte == 0x21:  # '!' feed hold
                if self.current is not None or self.queue:
                    self.hold = True
                    self.state = "Hold:0"
            elif byte == 0x7E:  # '~' resume
                if self.hold:
                    self.hold = False
                    self.state = "Run" if (self.current or self.queue) else "Idle"
            elif byte == 0x85:  # jog cancel
                if self.state == "Jog" or (self.current is not None and self.current.jog):
                    self.current = None
                    self.queue = deque(s for s in self.queue if not s.jog)
                    self.state = "Idle"
            elif byte == 0x18:  # soft reset
                moving = self.current is not None and not self.hold
                self.current = None
                self.queue.clear()
                self.hold = False
                self._outputs_off()  # a reset switches spindle and coolant off
                with self._line_ready:
                    self._pending_lines.clear()
                self._space.notify_all()
                if moving:
                    # Reset during motion loses position: GRBL raises ALARM:3.
                    self._send("ALARM:3")
                    self.state = "Alarm"
                    self.alarm_code = 3
                elif self.state != "Alarm":
                    self.state = "Idle"
                if self.check_mode:
                    self.check_mode = False
                self._send("")
                self._send(BANNER)
                if self.state == "Alarm":
                    self._send("[MSG:'$H'|'$X' to unlock]")

    def _status(self) -> str:
        self._reports += 1
        pos = ",".join(f"{v:.3f}" for v in self.mpos)
        feed = 0.0
        if self.current is not None and not self.hold and not self.current.dwell_s:
            feed = self.current.feed_mm_min
        state = "Check" if self.check_mode and self.state == "Idle" else self.state
        speed = self.spindle_speed if self.spindle != "M5" else 0.0
        text = f"<{state}|MPos:{pos}|FS:{feed:.0f},{speed:.0f}"
        accessories = (
            ("S" if self.spindle == "M3" else "C" if self.spindle == "M4" else "")
            + ("F" if self.flood else "")
            + ("M" if self.mist else "")
        )
        if accessories:
            text += f"|A:{accessories}"
        if self._reports % 10 == 1:
            text += "|WCO:" + ",".join(f"{v:.3f}" for v in self.wco)
        return text + ">"

    # ------------------------------------------------------------------ motion
    def _motion_loop(self) -> None:
        last = time.monotonic()
        while not self._stop.is_set():
            time.sleep(0.005)
            now = time.monotonic()
            dt = (now - last) / max(self.time_scale, 1e-6)
            last = now
            with self._lock:
                if self.hold:
                    if self.state == "Hold:0":
                        pass
                    continue
                if self.current is None and self.queue:
                    self.current = self.queue.popleft()
                    self._space.notify_all()
                    if self.state not in ("Alarm",):
                        self.state = "Jog" if self.current.jog else "Run"
                seg = self.current
                if seg is None:
                    continue
                seg.elapsed_s += dt
                duration = seg.duration_s
                frac = 1.0 if duration <= 0 else min(1.0, seg.elapsed_s / duration)
                if not seg.dwell_s:
                    self.mpos = [s + (e - s) * frac for s, e in zip(seg.start_mm, seg.end_mm)]
                if frac >= 1.0:
                    self.current = None
                    if not self.queue and self.state in ("Run", "Jog"):
                        self.state = "Idle"
                    self._space.notify_all()

    def _outputs_off(self) -> None:
        self.spindle, self.spindle_speed, self.flood, self.mist = "M5", 0.0, False, False

    def _enter_alarm(self, code: int) -> None:
        self.current = None
        self.queue.clear()
        self.hold = False
        self._outputs_off()
        self.state = "Alarm"
        self.alarm_code = code
        self._space.notify_all()
        self._send(f"ALARM:{code}")

    def _planned_end(self) -> list[float]:
        if self.queue:
            return list(self.queue[-1].end_mm)
        if self.current is not None:
            return list(self.current.end_mm)
        return list(self.mpos)

    def _within_travel(self, target: list[float]) -> bool:
        for i, v in enumerate(target):
            if self.axes[i] not in "XYZ":
                continue  # rotary axes: no soft limits, as on most grblHAL builds
            travel = self.settings[130 + i]
            if v > 1e-6 or v < -travel - 1e-6:
                return False
        return True

    def _enqueue(self, seg: Segment) -> str | None:
        with self._space:
            while len(self.queue) >= _PLANNER_BLOCKS and not self._stop.is_set():
                self._space.wait(0.05)
            if self.state == "Alarm":
                return "error:9"
            self.queue.append(seg)
        return "ok"
