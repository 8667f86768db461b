"""The serial link to a GRBL controller: port, reader thread, answers, status and alarms.

A background reader thread owns the port's input: it frames lines (LF ends a
line, CR is dropped), sorts them with :func:`fgcd_drivers.grbl.protocol.classify_line`
into answers (``ok``/``error``), status reports, alarms, the banner, messages
and settings, and counts anything else as noise (line noise, a boot loader's
bytes). Commands are sent one at a time and wait for their answer with a
timeout; a silent controller becomes :class:`PlatformTimeout`, a vanished port
:class:`PlatformConnectionError`.
"""

from __future__ import annotations

import queue
import threading
import time

import serial

from fgcd_core.platform import MotionRejected, PlatformConnectionError, PlatformTimeout, SafetyStop
from fgcd_drivers.grbl.config import GrblConfig
from fgcd_drivers.grbl.protocol import (
    ERROR_LOCKED,
    STATUS_QUERY,
    GrblState,
    GrblStatus,
    LineKind,
    alarm_text,
    classify_line,
    decode_line,
    error_text,
    parse_code,
    parse_setting,
    parse_status,
)

__all__ = ["GrblLink"]

#: A line longer than this without a newline is runaway noise and is dropped.
_MAX_LINE_BYTES = 512


def _default_serial_factory(port: str, baud: int) -> serial.SerialBase:
    return serial.serial_for_url(port, baudrate=baud, timeout=0.05, write_timeout=1.0)


class GrblLink:
    """Line-level conversation with one GRBL controller.

    Parameters
    ----------
    config : GrblConfig
        Port, baud rate, reported axis order, answer timeout and polling rate.
    serial_factory : callable, optional
        ``serial_factory(port, baud) -> serial.Serial``; defaults to
        ``serial.serial_for_url`` so URLs (``socket://``) work too.

    Attributes
    ----------
    alarm : int or None
        The last ``ALARM:N`` code; 0 for an ``Alarm`` state reported without a
        code; None when no alarm was seen since opening or unlocking.
    lost : str or None
        Why the link was lost, or None while it is up.
    settings : dict int -> float
        ``$N`` settings read with ``$$``.
    banner : str or None
        The last ``Grbl ...`` banner.
    messages : list of str
        ``[...]`` message lines received.
    noise_lines : int
        Lines that were neither answers nor reports (noise, malformed reports).
    """

    def __init__(self, config: GrblConfig, *, serial_factory=None) -> None:
        self.config = config
        self._serial_factory = serial_factory or _default_serial_factory
        self.serial: serial.SerialBase | None = None
        self._reader: threading.Thread | None = None
        self._answers: queue.Queue[str] = queue.Queue()
        self.last_status: GrblStatus | None = None
        self._status_event = threading.Condition()
        self.banner_event = threading.Event()
        self.alarm: int | None = None
        self.lost: str | None = None
        self._write_lock = threading.Lock()
        self._command_lock = threading.RLock()
        self._closing = False
        self.settings: dict[int, float] = {}
        self.banner: str | None = None
        self.messages: list[str] = []
        self.noise_lines = 0
        self._wco = {letter: 0.0 for letter in config.kinematics.letters}
        self._last_poll = 0.0

    # ------------------------------------------------------------------ port
    def open(self) -> None:
        """Open the port and start the reader thread (state of a previous link forgotten)."""
        self._closing = False
        self.lost = None
        self.banner_event.clear()
        self.alarm = None
        try:
            self.serial = self._serial_factory(self.config.port, self.config.baud)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise PlatformConnectionError(f"cannot open GRBL port {self.config.port}: {exc}") from None
        self._reader = threading.Thread(target=self._read_loop, name="grbl-reader", daemon=True)
        self._reader.start()

    @property
    def is_open(self) -> bool:
        """True between :meth:`open` and :meth:`close`."""
        return self.serial is not None

    def close(self) -> None:
        """Stop the reader thread and release the port."""
        ser = self.serial
        if ser is None:
            return
        self._closing = True
        if self._reader is not None:
            self._reader.join(timeout=1.0)
        try:
            ser.close()
        except (serial.SerialException, OSError):
            pass
        self.serial = None

    # ------------------------------------------------------------------ reader thread
    def _read_loop(self) -> None:
        ser = self.serial
        buffer = bytearray()
        while not self._closing and ser is not None:
            try:
                chunk = ser.read(ser.in_waiting or 1)
            except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                if not self._closing:
                    self.lost = f"serial link to {self.config.port} lost ({exc})"
                    with self._status_event:
                        self._status_event.notify_all()
                return
            for byte in chunk:
                if byte == 0x0A:
                    self._dispatch(bytes(buffer))
                    buffer.clear()
                elif byte != 0x0D:
                    buffer.append(byte)
                    if len(buffer) > _MAX_LINE_BYTES:
                        buffer.clear()
                        self.noise_lines += 1

    def _dispatch(self, raw: bytes) -> None:
        line = decode_line(raw)
        if line is None:
            self.noise_lines += 1
            return
        kind = classify_line(line)
        if kind is LineKind.EMPTY:
            return
        if kind is LineKind.ANSWER:
            self._answers.put(line)
        elif kind is LineKind.STATUS:
            self._take_status(line)
        elif kind is LineKind.ALARM:
            self.alarm = parse_code(line)
            with self._status_event:
                self._status_event.notify_all()
        elif kind is LineKind.BANNER:
            self.banner = line
            self.banner_event.set()
        elif kind is LineKind.MESSAGE:
            self.messages.append(line)
        elif kind is LineKind.SETTING:
            key, value = parse_setting(line)
            self.settings[key] = value
        else:
            self.noise_lines += 1

    def _take_status(self, line: str) -> None:
        status, self._wco = parse_status(line, self.config.report_axes, self._wco, received_at=time.monotonic())
        if status is None:
            self.noise_lines += 1
            return
        with self._status_event:
            self.last_status = status
            if status.state == GrblState.ALARM and self.alarm is None:
                self.alarm = 0
            self._status_event.notify_all()

    # ------------------------------------------------------------------ writing
    def check_lost(self) -> None:
        """Raise PlatformConnectionError when the link is lost or not open."""
        if self.lost is not None:
            raise PlatformConnectionError(self.lost)
        if self.serial is None:
            raise PlatformConnectionError("GRBL stage is not connected")

    def write(self, data: bytes) -> None:
        """Write raw bytes (a line or real-time bytes); a failing port marks the link lost."""
        self.check_lost()
        try:
            with self._write_lock:
                self.serial.write(data)  # type: ignore[union-attr]
                self.serial.flush()  # type: ignore[union-attr]
        except (serial.SerialException, OSError, AttributeError) as exc:
            self.lost = f"serial link to {self.config.port} lost ({exc})"
            raise PlatformConnectionError(self.lost) from None

    def drain_answers(self) -> None:
        """Forget answers not yet taken (late answers of timed-out lines)."""
        while True:
            try:
                self._answers.get_nowait()
            except queue.Empty:
                return

    def alarm_active(self) -> bool:
        """True after an ``ALARM:N`` or an ``Alarm`` state report, until unlocked."""
        return self.alarm not in (None, 0)

    def alarm_text(self) -> str:
        """The safety-stop message for the current alarm."""
        return alarm_text(self.alarm)

    def send_line(self, line: str, *, timeout_s: float | None = None) -> None:
        """Send one line and wait for its ``ok``; ``error:N`` raises MotionRejected.

        Raises
        ------
        MotionRejected
            The controller answered ``error:N``.
        SafetyStop
            An alarm arrived instead of the answer.
        PlatformTimeout
            No answer within the timeout.
        """
        timeout_s = self.config.answer_timeout_s if timeout_s is None else timeout_s
        with self._command_lock:
            self.drain_answers()  # a late answer to a timed-out line must not be taken for this one
            self.write(line.encode("ascii") + b"\n")
            answer = self._wait_answer(line, timeout_s)
            if answer == "ok":
                return
            code = parse_code(answer)
            if code == ERROR_LOCKED and self.alarm is not None:
                raise SafetyStop(self.alarm_text())
            raise MotionRejected(f"GRBL rejected '{line}': error {code} ({error_text(code)})")

    def _wait_answer(self, line: str, timeout_s: float) -> str:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                return self._answers.get(timeout=0.05)
            except queue.Empty:
                self.check_lost()
                # '$' system lines ($X, $H) are how an alarm is left: they still get their answer.
                if self.alarm_active() and not line.startswith("$"):
                    raise SafetyStop(self.alarm_text()) from None
                if time.monotonic() > deadline:
                    raise PlatformTimeout(f"GRBL did not answer '{line}' within {timeout_s:.1f} s") from None

    # ------------------------------------------------------------------ status
    def status(self, *, fresh: bool = True) -> GrblStatus:
        """The latest status report; ``fresh`` polls ``?`` (rate-limited to ``poll_hz``)."""
        self.check_lost()
        if not fresh and self.last_status is not None:
            return self.last_status
        wait = (1.0 / self.config.poll_hz) - (time.monotonic() - self._last_poll)
        if wait > 0:
            time.sleep(wait)
        with self._status_event:
            before = self.last_status
            self._last_poll = time.monotonic()
            self.write(STATUS_QUERY)
            deadline = time.monotonic() + self.config.answer_timeout_s
            period = 1.0 / self.config.poll_hz
            while self.last_status is before:
                self.check_lost()
                now = time.monotonic()
                left = deadline - now
                if left <= 0:
                    raise PlatformTimeout(f"GRBL sent no status report within {self.config.answer_timeout_s:.1f} s")
                if now - self._last_poll >= period:
                    # A report garbled by line noise is lost for good: ask again at the polling rate
                    # (GRBL, interface.md: '?' is real-time, never acknowledged; <= 5 Hz advised).
                    self._last_poll = now
                    self.write(STATUS_QUERY)
                self._status_event.wait(min(left, 0.1))
            return self.last_status  # type: ignore[return-value]
