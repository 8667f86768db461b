"""GRBL v1.1 serial motion stage (XYZ gantry, optional grblHAL rotary axes A/B/C).

Protocol facts this driver relies on (GRBL ``doc/markdown/interface.md``):
every line gets exactly one ``ok`` or ``error:N``; ``ok`` for a motion means
*queued*, so arrival is waited for by polling ``?`` (at most 5 Hz) until the
report says ``Idle`` at the target; ``ALARM:N`` and the ``Alarm`` state are
safety stops; real-time bytes (``?``, ``!`` feed hold, ``0x85`` jog cancel,
``0x18`` soft reset) are never acknowledged.

A background reader thread owns the port's input: it sorts lines into answers
(``ok``/``error``), status reports, alarms and messages, and drops anything
else (line noise, a boot loader's bytes). Commands wait for their answer with a
timeout; a silent controller becomes :class:`PlatformTimeout`, a vanished port
:class:`PlatformConnectionError`.

The kinematic mapping (:class:`GrblKinematics`) turns a flange pose into stage
axis values and back. A stage with fewer than 6 DoF performs the reachable part
of a motion and names the rest in ``MoveResult.unreachable``.
"""

from __future__ import annotations

import math
import queue
import re
import threading
import time
from dataclasses import dataclass, field

import numpy as np
import serial
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from drivers.platform import (
    Capabilities,
    MotionInterrupted,
    MotionRejected,
    MoveResult,
    PlatformConnectionError,
    PlatformError,
    PlatformTimeout,
    SafetyStop,
)

__all__ = ["GrblKinematics", "GrblConfig", "GrblPlatform", "GrblStatus", "ERROR_TEXT", "ALARM_TEXT"]

#: GRBL 1.1 error codes (``doc/csv/error_codes_en_US.csv``), the ones a person may meet.
ERROR_TEXT = {
    1: "expected command letter",
    2: "bad number format",
    3: "invalid '$' statement",
    4: "negative value",
    5: "homing is not enabled ($22)",
    8: "command needs the controller idle",
    9: "locked by an alarm or a jog (unlock with $X or home with $H)",
    10: "soft limits need homing enabled",
    15: "jog target exceeds the machine travel",
    16: "invalid jog command",
    20: "unsupported or invalid G-code command",
    22: "feed rate not set",
    33: "invalid motion target",
}
#: GRBL 1.1 alarm codes (``doc/csv/alarm_codes_en_US.csv``).
ALARM_TEXT = {
    1: "hard limit triggered",
    2: "soft limit: target outside the machine travel",
    3: "reset while in motion, position may be lost",
    4: "probe fail",
    5: "probe fail",
    6: "homing fail: reset during homing",
    7: "homing fail: safety door opened during homing",
    8: "homing fail: could not clear the limit switch",
    9: "homing fail: limit switch not found",
    10: "homing fail: second switch not found",
}

_STATUS = re.compile(r"^<([A-Za-z]+)(?::(\d+))?\|(.*)>$")
_ROT_AXES = {"rx": 0, "ry": 1, "rz": 2}
_LIN_AXES = ("x", "y", "z")


# ----------------------------------------------------------------------------- kinematics
@dataclass(frozen=True, kw_only=True)
class GrblKinematics:
    """Mapping between the flange pose in the base frame and the stage's axes.

    The flange position is ``origin_m + sign * mpos_mm / 1000`` per base axis,
    where ``linear_axes[i]`` is the GRBL axis letter that drives base axis i.
    Rotary axes (degrees) rotate the flange about its own axes, stacked in the
    listed order: ``R_base_flange = R_base_flange_zero @ R(axis_1, a_1) @ R(axis_2, a_2) ...``.
    They are assumed to turn about the flange origin (a camera mount centred on
    the rotation axes); an off-centre mount needs its offset in the hand-eye.

    Attributes
    ----------
    linear_axes : tuple of 3 str
        GRBL letters driving base x, y, z, e.g. ``("X", "Y", "Z")``.
    linear_signs : tuple of 3 float
        +1 or -1 per base axis.
    origin_m : tuple of 3 float
        Flange position in the base frame when the machine is at MPos 0, metres.
    rotary_axes : tuple of (str, str)
        ``(flange_axis, letter)`` pairs in stacking order, e.g. ``(("rz", "C"),)``.
    R_base_flange_zero : tuple of 9 float
        Row-major flange orientation with all rotary axes at 0.
    """

    linear_axes: tuple[str, str, str] = ("X", "Y", "Z")
    linear_signs: tuple[float, float, float] = (1.0, 1.0, 1.0)
    origin_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotary_axes: tuple[tuple[str, str], ...] = ()
    R_base_flange_zero: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)

    @property
    def letters(self) -> tuple[str, ...]:
        """All GRBL axis letters used, linear first."""
        return tuple(self.linear_axes) + tuple(letter for _, letter in self.rotary_axes)

    @property
    def controllable(self) -> tuple[str, ...]:
        """Flange axes the stage can move."""
        return _LIN_AXES + tuple(axis for axis in ("rx", "ry", "rz") if axis in dict(self.rotary_axes))

    def _R0(self) -> np.ndarray:
        return np.asarray(self.R_base_flange_zero, dtype=float).reshape(3, 3)

    def _rotation(self, angles_deg) -> np.ndarray:
        R = self._R0()
        for (axis, _), angle in zip(self.rotary_axes, angles_deg):
            rotvec = np.zeros(3)
            rotvec[_ROT_AXES[axis]] = math.radians(angle)
            R = R @ Rotation.from_rotvec(rotvec).as_matrix()
        return R

    def pose_from_axes(self, mpos: dict[str, float]) -> np.ndarray:
        """``T_base_flange`` (4x4, metres) from machine positions (mm, degrees)."""
        T = np.eye(4)
        for i, letter in enumerate(self.linear_axes):
            T[i, 3] = self.origin_m[i] + self.linear_signs[i] * mpos[letter] / 1000.0
        T[:3, :3] = self._rotation([mpos[letter] for _, letter in self.rotary_axes])
        return T

    def axes_from_pose(
        self, T_base_flange: np.ndarray, *, current: dict[str, float], tol_rad: float = 1e-5
    ) -> tuple[dict[str, float], tuple[str, ...]]:
        """Machine targets (mm, degrees) of the reachable part of a pose.

        Returns
        -------
        targets : dict letter -> value
        unreachable : tuple of str
            Flange rotation axes (``rx``, ``ry``, ``rz``, in the flange frame of
            the commanded pose) left with a residual above ``tol_rad``.
        """
        T = np.asarray(T_base_flange, dtype=float)
        targets = {}
        for i, letter in enumerate(self.linear_axes):
            targets[letter] = (T[i, 3] - self.origin_m[i]) * 1000.0 / self.linear_signs[i]
        R_target = T[:3, :3]
        if self.rotary_axes:
            start = np.array([current[letter] for _, letter in self.rotary_axes], dtype=float)

            def residual(angles):
                return Rotation.from_matrix(self._rotation(angles).T @ R_target).as_rotvec()

            # A stack of 1 or 2 rotary axes has no closed form for the nearest
            # reachable orientation; a tiny least-squares problem gives it.
            solution = least_squares(residual, start, x_scale=10.0, xtol=1e-12, ftol=1e-12)
            angles = solution.x
            for (_, letter), angle in zip(self.rotary_axes, angles):
                targets[letter] = float(angle)
        else:
            angles = []
        left = Rotation.from_matrix(self._rotation(angles).T @ R_target).as_rotvec()
        unreachable = tuple(axis for axis, v in zip(("rx", "ry", "rz"), left) if abs(v) > tol_rad)
        return targets, unreachable


# ----------------------------------------------------------------------------- config
@dataclass(frozen=True, kw_only=True)
class GrblConfig:
    """Connection and motion options of a GRBL stage.

    Attributes
    ----------
    port : str
        Serial device, e.g. ``/dev/ttyUSB0`` (or any pyserial URL).
    baud : int
        115200 for GRBL 1.1.
    kinematics : GrblKinematics
        Flange pose <-> axes mapping.
    answer_timeout_s : float
        Longest wait for the ``ok``/``error`` of one line.
    banner_timeout_s : float
        Longest wait for the banner after a soft reset.
    open_banner_wait_s : float
        Wait for the banner a board prints when opening the port resets it
        (DTR); without one the driver sends a soft reset.
    arrival_margin_s : float
        Extra time allowed beyond the nominal motion time before a move times out.
    homing_timeout_s : float
        Longest ``$H``.
    poll_hz : float
        Status polling rate while waiting for arrival (GRBL advises <= 5 Hz).
    max_linear_speed_m_s : float or None
        Cap on the feed; None uses the stage's ``$110`` max rate.
    max_angular_speed_rad_s : float
        Cap on rotary feed.
    workspace_min_mm, workspace_max_mm : tuple or None
        Machine travel box of the linear axes (MPos, mm); None derives it from
        ``$130..$132`` with GRBL's homing convention ``[-travel, 0]``.
    arrival_tolerance_mm : float
        Distance between reported and commanded MPos counted as arrived.
    report_axes : str
        Axis letters in the order the controller reports them in ``MPos`` and
        numbers them in settings (``$110+i``): GRBL ``XYZ``, grblHAL ``XYZABC``
        or a custom order such as ``XYZC``.
    """

    port: str
    baud: int = 115200
    kinematics: GrblKinematics = field(default_factory=GrblKinematics)
    answer_timeout_s: float = 5.0
    banner_timeout_s: float = 2.5
    open_banner_wait_s: float = 2.0
    arrival_margin_s: float = 5.0
    homing_timeout_s: float = 90.0
    poll_hz: float = 5.0
    max_linear_speed_m_s: float | None = 0.02
    max_angular_speed_rad_s: float = math.radians(30.0)
    workspace_min_mm: tuple[float, float, float] | None = None
    workspace_max_mm: tuple[float, float, float] | None = None
    arrival_tolerance_mm: float = 0.01
    report_axes: str = "XYZABC"


@dataclass(frozen=True, kw_only=True)
class GrblStatus:
    """One parsed status report."""

    state: str
    substate: int | None
    mpos: dict[str, float]
    feed_mm_min: float
    received_at: float


# ----------------------------------------------------------------------------- driver
class GrblPlatform:
    """A GRBL 1.1 stage as a :class:`~drivers.platform.Platform`.

    Parameters
    ----------
    config : GrblConfig
        Port, kinematics and timeouts.
    serial_factory : callable, optional
        ``serial_factory(port, baud) -> serial.Serial``; defaults to
        ``serial.serial_for_url`` so URLs (``socket://``) work too.
    """

    name = "grbl"

    def __init__(self, config: GrblConfig, *, serial_factory=None) -> None:
        self.config = config
        self._serial_factory = serial_factory or (
            lambda port, baud: serial.serial_for_url(port, baudrate=baud, timeout=0.05, write_timeout=1.0)
        )
        self._ser: serial.SerialBase | None = None
        self._reader: threading.Thread | None = None
        self._answers: queue.Queue[str] = queue.Queue()
        self._status: GrblStatus | None = None
        self._status_event = threading.Condition()
        self._banner = threading.Event()
        self._alarm: int | None = None
        self._lost: str | None = None
        self._stop_requested = threading.Event()
        self._write_lock = threading.Lock()
        self._command_lock = threading.RLock()
        self._closing = False
        self.settings: dict[int, float] = {}
        self.banner: str | None = None
        self.messages: list[str] = []
        self.noise_lines = 0
        self._wco = {letter: 0.0 for letter in config.kinematics.letters}
        self._last_poll = 0.0

    # ------------------------------------------------------------------ connection
    def connect(self) -> None:
        """Open the port, wait for the banner (soft reset if none), read settings."""
        self._open()
        if not self._banner.wait(self.config.open_banner_wait_s):
            # A pty or a board without DTR reset prints nothing on open: soft reset.
            self._banner.clear()
            self._write(b"\x18")
            if not self._banner.wait(self.config.banner_timeout_s):
                self._check_lost()
                self.close()
                raise PlatformTimeout(
                    f"no GRBL banner on {self.config.port} within {self.config.banner_timeout_s:.1f} s "
                    "(wrong port or baud rate, or the controller is not running GRBL)"
                )
        time.sleep(0.05)  # let the post-reset messages ([MSG:...]) arrive
        self._drain_answers()
        self._read_settings()
        status = self.status(fresh=True)
        missing = [letter for letter in self.config.kinematics.letters if letter not in status.mpos]
        if missing:
            raise PlatformConnectionError(
                f"the stage reports axes {''.join(status.mpos)}; the configured mapping needs {''.join(missing)}"
            )

    def _open(self) -> None:
        self._closing = False
        self._lost = None
        self._banner.clear()
        self._alarm = None
        try:
            self._ser = self._serial_factory(self.config.port, self.config.baud)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise PlatformConnectionError(f"cannot open GRBL port {self.config.port}: {exc}") from None
        self._reader = threading.Thread(target=self._read_loop, name="grbl-reader", daemon=True)
        self._reader.start()

    def reconnect(self) -> None:
        """Close and reopen the port (after a lost link), then re-check the controller."""
        self.close()
        self.connect()

    def close(self) -> None:
        """Stop motion if the link is up and release the port."""
        ser = self._ser
        if ser is None:
            return
        if self._lost is None:
            try:
                self._write(b"!\x85")
            except PlatformError:
                pass
        self._closing = True
        if self._reader is not None:
            self._reader.join(timeout=1.0)
        try:
            ser.close()
        except (serial.SerialException, OSError):
            pass
        self._ser = None

    # ------------------------------------------------------------------ reader thread
    def _read_loop(self) -> None:
        ser = self._ser
        buffer = bytearray()
        while not self._closing and ser is not None:
            try:
                chunk = ser.read(ser.in_waiting or 1)
            except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                if not self._closing:
                    self._lost = f"serial link to {self.config.port} lost ({exc})"
                    with self._status_event:
                        self._status_event.notify_all()
                return
            for byte in chunk:
                if byte == 0x0A:
                    self._dispatch(bytes(buffer))
                    buffer.clear()
                elif byte != 0x0D:
                    buffer.append(byte)
                    if len(buffer) > 512:  # runaway noise without newlines
                        buffer.clear()
                        self.noise_lines += 1

    def _dispatch(self, raw: bytes) -> None:
        try:
            line = raw.decode("ascii").strip()
        except UnicodeDecodeError:
            self.noise_lines += 1
            return
        if not line:
            return
        if line == "ok" or re.fullmatch(r"error:\d+", line):
            self._answers.put(line)
        elif line.startswith("<") and line.endswith(">"):
            status = self._parse_status(line)
            if status is None:
                self.noise_lines += 1
                return
            with self._status_event:
                self._status = status
                if status.state == "Alarm" and self._alarm is None:
                    self._alarm = 0
                self._status_event.notify_all()
        elif re.fullmatch(r"ALARM:\d+", line):
            self._alarm = int(line.split(":")[1])
            with self._status_event:
                self._status_event.notify_all()
        elif line.startswith("Grbl "):
            self.banner = line
            self._banner.set()
        elif line.startswith("[") and line.endswith("]"):
            self.messages.append(line)
        elif re.fullmatch(r"\$\d+=[-+]?\d*\.?\d+", line):
            key, value = line[1:].split("=")
            self.settings[int(key)] = float(value)
        else:
            self.noise_lines += 1

    def _parse_status(self, line: str) -> GrblStatus | None:
        match = _STATUS.match(line)
        if not match:
            return None
        fields = dict(part.split(":", 1) for part in match.group(3).split("|") if ":" in part)
        letters = self.config.report_axes
        try:
            if "WCO" in fields:
                wco = [float(v) for v in fields["WCO"].split(",")]
                self._wco = {letters[i]: v for i, v in enumerate(wco)}
            if "MPos" in fields:
                values = [float(v) for v in fields["MPos"].split(",")]
                mpos = {letters[i]: v for i, v in enumerate(values)}
            elif "WPos" in fields:  # $10 set to report WPos: MPos = WPos + WCO
                values = [float(v) for v in fields["WPos"].split(",")]
                mpos = {letters[i]: v + self._wco.get(letters[i], 0.0) for i, v in enumerate(values)}
            else:
                return None
            feed = float(fields.get("FS", fields.get("F", "0")).split(",")[0])
        except (ValueError, IndexError):
            return None
        sub = match.group(2)
        return GrblStatus(
            state=match.group(1),
            substate=int(sub) if sub is not None else None,
            mpos=mpos,
            feed_mm_min=feed,
            received_at=time.monotonic(),
        )

    # ------------------------------------------------------------------ low level
    def _check_lost(self) -> None:
        if self._lost is not None:
            raise PlatformConnectionError(self._lost)
        if self._ser is None:
            raise PlatformConnectionError("GRBL stage is not connected")

    def _write(self, data: bytes) -> None:
        self._check_lost()
        try:
            with self._write_lock:
                self._ser.write(data)  # type: ignore[union-attr]
                self._ser.flush()  # type: ignore[union-attr]
        except (serial.SerialException, OSError, AttributeError) as exc:
            self._lost = f"serial link to {self.config.port} lost ({exc})"
            raise PlatformConnectionError(self._lost) from None

    def _drain_answers(self) -> None:
        while True:
            try:
                self._answers.get_nowait()
            except queue.Empty:
                return

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
            self._drain_answers()  # a late answer to a timed-out line must not be taken for this one
            self._write(line.encode("ascii") + b"\n")
            deadline = time.monotonic() + timeout_s
            while True:
                try:
                    answer = self._answers.get(timeout=0.05)
                except queue.Empty:
                    self._check_lost()
                    if self._alarm not in (None, 0) and not line.startswith("$"):
                        raise SafetyStop(self._alarm_text()) from None
                    if time.monotonic() > deadline:
                        raise PlatformTimeout(
                            f"GRBL did not answer '{line}' within {timeout_s:.1f} s"
                        ) from None
                    continue
                if answer == "ok":
                    return
                code = int(answer.split(":")[1])
                if code == 9 and self._alarm is not None:
                    raise SafetyStop(self._alarm_text())
                raise MotionRejected(
                    f"GRBL rejected '{line}': error {code} ({ERROR_TEXT.get(code, 'see the GRBL error table')})"
                )

    def _alarm_text(self) -> str:
        code = self._alarm
        what = ALARM_TEXT.get(code, "alarm state") if code else "alarm state"
        label = f"ALARM:{code}" if code else "Alarm"
        return f"GRBL {label} ({what}); check the stage, then 'fgcd platform home' or unlock ($X)"

    def _read_settings(self) -> None:
        self.settings.clear()
        self.send_line("$$")
        time.sleep(0.02)

    # ------------------------------------------------------------------ status
    def status(self, *, fresh: bool = True) -> GrblStatus:
        """The latest status report; ``fresh`` polls ``?`` (rate-limited to ``poll_hz``)."""
        self._check_lost()
        if not fresh and self._status is not None:
            return self._status
        wait = (1.0 / self.config.poll_hz) - (time.monotonic() - self._last_poll)
        if wait > 0:
            time.sleep(wait)
        with self._status_event:
            before = self._status
            self._last_poll = time.monotonic()
            self._write(b"?")
            deadline = time.monotonic() + self.config.answer_timeout_s
            while self._status is before:
                self._check_lost()
                left = deadline - time.monotonic()
                if left <= 0:
                    raise PlatformTimeout(
                        f"GRBL sent no status report within {self.config.answer_timeout_s:.1f} s"
                    )
                self._status_event.wait(min(left, 0.1))
            return self._status  # type: ignore[return-value]

    def state(self) -> str:
        """GRBL machine state (``Idle``, ``Run``, ``Alarm``...)."""
        return self.status(fresh=True).state

    # ------------------------------------------------------------------ Platform
    def capabilities(self) -> Capabilities:
        """DoF from the mapping; workspace from the travel settings or the config."""
        kin = self.config.kinematics
        lo_mm, hi_mm = self._travel_box_mm()
        corners = []
        for use_hi in range(8):
            mpos = {letter: 0.0 for letter in kin.letters}
            for i, letter in enumerate(kin.linear_axes):
                mpos[letter] = hi_mm[i] if (use_hi >> i) & 1 else lo_mm[i]
            corners.append(kin.pose_from_axes(mpos)[:3, 3])
        corners = np.array(corners)
        max_rate = min(self.settings.get(110 + self.config.report_axes.index(l), 500.0) for l in kin.linear_axes)
        linear = max_rate / 60.0 / 1000.0
        if self.config.max_linear_speed_m_s is not None:
            linear = min(linear, self.config.max_linear_speed_m_s)
        return Capabilities(
            dof=len(kin.controllable),
            controllable=kin.controllable,
            workspace_min_m=tuple(float(v) for v in corners.min(axis=0)),
            workspace_max_m=tuple(float(v) for v in corners.max(axis=0)),
            max_linear_speed_m_s=float(linear),
            max_angular_speed_rad_s=float(self.config.max_angular_speed_rad_s if kin.rotary_axes else 0.0),
        )

    def _travel_box_mm(self) -> tuple[list[float], list[float]]:
        if self.config.workspace_min_mm is not None and self.config.workspace_max_mm is not None:
            return list(self.config.workspace_min_mm), list(self.config.workspace_max_mm)
        lo, hi = [], []
        for letter in self.config.kinematics.linear_axes:
            travel = self.settings.get(130 + self.config.report_axes.index(letter), 0.0)
            lo.append(-travel)
            hi.append(0.0)
        return lo, hi

    def flange_pose(self) -> np.ndarray:
        """``T_base_flange`` from a fresh status report (4x4, metres)."""
        return self.config.kinematics.pose_from_axes(self.status(fresh=True).mpos)

    def move_to(self, T_base_flange: np.ndarray, *, speed_fraction: float = 1.0) -> MoveResult:
        """Move to the reachable part of ``T_base_flange`` and wait for arrival.

        Raises
        ------
        SafetyStop
            The stage is or goes into alarm.
        MotionRejected
            The controller rejected the command.
        MotionInterrupted
            :meth:`stop` was called or Ctrl-C pressed; the stage is halted.
        PlatformTimeout, PlatformConnectionError
            Silence or a lost link; the stage was told to hold where possible.
        """
        started = time.monotonic()
        kin = self.config.kinematics
        target = np.asarray(T_base_flange, dtype=float)
        self._stop_requested.clear()
        status = self.status(fresh=True)
        if status.state == "Alarm" or self._alarm not in (None, 0):
            raise SafetyStop(self._alarm_text())
        if status.state not in ("Idle", "Check"):
            raise MotionRejected(f"GRBL is busy ({status.state}); wait for Idle before moving")
        axes, unreachable = kin.axes_from_pose(target, current=status.mpos)
        commanded = kin.pose_from_axes({**status.mpos, **axes})
        feed = self._feed_mm_min(status.mpos, axes, speed_fraction)
        words = " ".join(f"{letter}{axes[letter]:.4f}" for letter in kin.letters)
        try:
            self.send_line(f"G90 G1 {words} F{feed:.1f}")
            self._wait_arrival(axes, self._nominal_time_s(status.mpos, axes, feed))
        except KeyboardInterrupt:
            self.stop()
            self._halt_after_stop()
            raise
        except (PlatformTimeout, PlatformConnectionError):
            self.stop()
            raise
        reached = kin.pose_from_axes(self._status.mpos)  # type: ignore[union-attr]
        return MoveResult(
            T_base_flange_target=target,
            T_base_flange_reached=reached,
            T_base_flange_commanded=commanded,
            unreachable=unreachable,
            duration_s=time.monotonic() - started,
        )

    def _feed_mm_min(self, start: dict[str, float], axes: dict[str, float], fraction: float) -> float:
        kin = self.config.kinematics
        caps = self.capabilities()
        fraction = min(max(float(fraction), 1e-3), 1.0)
        linear = caps.max_linear_speed_m_s * 1000.0 * 60.0 * fraction
        feed = linear
        if kin.rotary_axes:
            # GRBL's F is a rate along the combined axis vector; keep rotation within its cap too.
            lin_mm = math.sqrt(sum((axes[l] - start[l]) ** 2 for l in kin.linear_axes))
            rot_deg = math.sqrt(sum((axes[l] - start[l]) ** 2 for _, l in kin.rotary_axes))
            if rot_deg > 1e-9:
                max_deg_min = math.degrees(caps.max_angular_speed_rad_s) * 60.0 * fraction
                total = math.hypot(lin_mm, rot_deg)
                feed = min(linear * total / max(lin_mm, 1e-9), max_deg_min * total / rot_deg)
        return max(feed, 1.0)

    @staticmethod
    def _nominal_time_s(start: dict[str, float], axes: dict[str, float], feed: float) -> float:
        dist = math.sqrt(sum((axes[l] - start[l]) ** 2 for l in axes))
        return dist / (feed / 60.0)

    def _wait_arrival(self, axes: dict[str, float], nominal_s: float) -> None:
        deadline = time.monotonic() + 1.5 * nominal_s + self.config.arrival_margin_s
        while True:
            if self._stop_requested.is_set():
                self._halt_after_stop()
                raise MotionInterrupted("GRBL motion stopped on request before arrival; the stage is halted")
            status = self.status(fresh=True)
            if status.state == "Alarm" or self._alarm not in (None, 0):
                raise SafetyStop(self._alarm_text())
            if status.state in ("Idle", "Check"):
                err = max(abs(status.mpos[l] - v) for l, v in axes.items())
                if status.state == "Check" or err <= self.config.arrival_tolerance_mm:
                    return
                raise MotionRejected(
                    f"GRBL is idle {err:.3f} mm from the target: the motion was cut short"
                )
            if time.monotonic() > deadline:
                raise PlatformTimeout(
                    f"GRBL did not arrive within {deadline - time.monotonic() + 1.5 * nominal_s:.1f} s "
                    f"(state {status.state}); motion held"
                )

    def _halt_after_stop(self) -> None:
        """After a feed hold: wait until the hold is complete, then flush the planner."""
        deadline = time.monotonic() + self.config.answer_timeout_s
        try:
            while time.monotonic() < deadline:
                status = self.status(fresh=True)
                if status.state in ("Idle", "Alarm") or (status.state == "Hold" and status.substate == 0):
                    break
                if status.state in ("Run", "Jog"):
                    # GRBL ignores '!' while idle: a hold sent just before the line started is repeated.
                    self._write(b"!\x85")
            # A soft reset after a completed hold keeps the position and empties the queue.
            self._banner.clear()
            self._write(b"\x18")
            self._banner.wait(self.config.banner_timeout_s)
            time.sleep(0.05)
            self._drain_answers()
            if self._alarm == 3:
                pass  # reported by the next move's SafetyStop
        except PlatformError:
            pass

    def stop(self) -> None:
        """Feed hold and jog cancel now (safe from any thread); the move in progress ends."""
        self._stop_requested.set()
        if self._ser is not None and self._lost is None:
            try:
                self._write(b"!\x85")
            except PlatformError:
                pass

    def home(self) -> None:
        """Run GRBL's homing cycle ``$H`` (clears an alarm); waits until it completes."""
        try:
            self.send_line("$H", timeout_s=self.config.homing_timeout_s)
        except KeyboardInterrupt:
            self._write(b"\x18")
            raise
        self._alarm = None

    def unlock(self) -> None:
        """``$X``: leave the alarm state without homing (a person checked the stage)."""
        self.send_line("$X")
        self._alarm = None

    def describe(self) -> dict:
        """State, banner and pose for ``fgcd platform check``."""
        status = self.status(fresh=True)
        return {
            "driver": "grbl",
            "port": self.config.port,
            "banner": self.banner,
            "state": status.state,
            "alarm": self._alarm,
            "mpos": status.mpos,
            "healthy": status.state in ("Idle", "Check") and self._alarm in (None, 0),
        }
