"""A GRBL 1.1 stage as a :class:`~fgcd_core.platform.Platform`: the motion API over a :class:`GrblLink`.

``ok`` for a motion means *queued* (GRBL ``doc/markdown/interface.md``), so
arrival is waited for by polling ``?`` (at most ``poll_hz``) until the report
says ``Idle`` at the target. The kinematic mapping (:class:`GrblKinematics`)
turns a flange pose into axis values; a stage with fewer than 6 DoF performs
the reachable part of a motion and names the rest in ``MoveResult.unreachable``.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np

from fgcd_core.platform import (
    Capabilities,
    MotionInterrupted,
    MotionRejected,
    MoveResult,
    PlatformConnectionError,
    PlatformError,
    PlatformTimeout,
    SafetyStop,
)
from fgcd_drivers.grbl.config import GrblConfig
from fgcd_drivers.grbl.link import GrblLink
from fgcd_drivers.grbl.protocol import FEED_HOLD_JOG_CANCEL, SOFT_RESET, GrblState, GrblStatus

__all__ = ["GrblPlatform"]

#: Largest share of ``banner_timeout_s`` spent waiting for a banner before the soft reset.
_OPEN_BANNER_SHARE = 0.8

#: States in which a stage accepts a motion and counts as arrived.
_READY = (GrblState.IDLE, GrblState.CHECK)
#: After a motion line's ``ok``, GRBL may still report Idle until its stepper starts the block (the
#: ``?`` report is answered out of band); Idle away from the target within this time of the send,
#: before any moving state was seen, is that start, not a motion cut short.
_START_GRACE_S = 0.5


class GrblPlatform:
    """A GRBL 1.1 stage as a :class:`~fgcd_core.platform.Platform`.

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
        self.link = GrblLink(config, serial_factory=serial_factory)
        self._stop_requested = threading.Event()

    # ------------------------------------------------------------------ link state
    @property
    def settings(self) -> dict[int, float]:
        """``$N`` settings read at connect."""
        return self.link.settings

    @property
    def banner(self) -> str | None:
        """The controller's last banner."""
        return self.link.banner

    @property
    def messages(self) -> list[str]:
        """``[...]`` messages received."""
        return self.link.messages

    @property
    def noise_lines(self) -> int:
        """Received lines that were neither answers nor reports."""
        return self.link.noise_lines

    @property
    def _ser(self):
        """The open serial port (tests drop it under the driver)."""
        return self.link.serial

    # ------------------------------------------------------------------ connection
    def connect(self) -> None:
        """Open the port, wait for the banner (soft reset if none), read settings."""
        link = self.link
        self._open_and_wait_banner()
        time.sleep(0.05)  # let the post-reset messages ([MSG:...]) arrive
        link.drain_answers()
        self._read_settings()
        status = self.status(fresh=True)
        missing = [letter for letter in self.config.kinematics.letters if letter not in status.mpos]
        if missing:
            raise PlatformConnectionError(
                f"the stage reports axes {''.join(status.mpos)}; the configured mapping needs {''.join(missing)}"
            )

    def _open_and_wait_banner(self) -> None:
        """Open the port and wait for the banner, soft reset included, within ``banner_timeout_s`` in all.

        Rule: the time a missing banner states is the time it took, from opening
        the port to giving up (one deadline for both waits, config ``banner_timeout_s``).
        """
        link, total = self.link, self.config.banner_timeout_s
        started = time.monotonic()
        deadline = started + total
        link.open()
        # The wait for a DTR-reset board's own banner leaves the soft reset a share of the time.
        if link.banner_event.wait(min(self.config.open_banner_wait_s, _OPEN_BANNER_SHARE * total)):
            return
        # A pty or a board without DTR reset prints nothing on open: soft reset.
        link.banner_event.clear()
        link.write(SOFT_RESET)
        if link.banner_event.wait(max(0.0, deadline - time.monotonic())):
            return
        link.check_lost()
        self.close()
        raise PlatformTimeout(
            f"no GRBL banner on {self.config.port} within {time.monotonic() - started:.1f} s, soft reset included "
            "(wrong port or baud rate, or the controller is not running GRBL)"
        )

    def reconnect(self) -> None:
        """Close and reopen the port (after a lost link), then re-check the controller."""
        self.close()
        self.connect()

    def close(self) -> None:
        """Stop motion if the link is up and release the port."""
        if not self.link.is_open:
            return
        if self.link.lost is None:
            try:
                self.link.write(FEED_HOLD_JOG_CANCEL)
            except PlatformError:
                pass
        self.link.close()

    def _read_settings(self) -> None:
        self.link.settings.clear()
        self.send_line("$$")
        time.sleep(0.02)

    def send_line(self, line: str, *, timeout_s: float | None = None) -> None:
        """Send one line and wait for its ``ok`` (see :meth:`GrblLink.send_line`)."""
        self.link.send_line(line, timeout_s=timeout_s)

    # ------------------------------------------------------------------ status
    def status(self, *, fresh: bool = True) -> GrblStatus:
        """The latest status report; ``fresh`` polls ``?`` (rate-limited to ``poll_hz``)."""
        return self.link.status(fresh=fresh)

    def state(self) -> str:
        """GRBL machine state (``Idle``, ``Run``, ``Alarm``...)."""
        return self.status(fresh=True).state

    def _in_alarm(self, status: GrblStatus) -> bool:
        return status.state == GrblState.ALARM or self.link.alarm_active()

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
        # $110+i: max rate of the i-th reported axis, mm/min
        max_rate = min(self.settings.get(110 + self.config.report_axes.index(axis), 500.0) for axis in kin.linear_axes)
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
            # $130+i: travel of the i-th reported axis; GRBL's homing convention puts it at [-travel, 0]
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
        if self._in_alarm(status):
            raise SafetyStop(self.link.alarm_text())
        if status.state not in _READY:
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
        reached = kin.pose_from_axes(self.link.last_status.mpos)  # type: ignore[union-attr]
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
            lin_mm = math.sqrt(sum((axes[axis] - start[axis]) ** 2 for axis in kin.linear_axes))
            rot_deg = math.sqrt(sum((axes[axis] - start[axis]) ** 2 for _, axis in kin.rotary_axes))
            if rot_deg > 1e-9:
                max_deg_min = math.degrees(caps.max_angular_speed_rad_s) * 60.0 * fraction
                total = math.hypot(lin_mm, rot_deg)
                feed = min(linear * total / max(lin_mm, 1e-9), max_deg_min * total / rot_deg)
        return max(feed, 1.0)

    @staticmethod
    def _nominal_time_s(start: dict[str, float], axes: dict[str, float], feed: float) -> float:
        dist = math.sqrt(sum((axes[axis] - start[axis]) ** 2 for axis in axes))
        return dist / (feed / 60.0)

    def _wait_arrival(self, axes: dict[str, float], nominal_s: float) -> None:
        sent = time.monotonic()
        deadline = sent + 1.5 * nominal_s + self.config.arrival_margin_s
        moved = False
        while True:
            if self._stop_requested.is_set():
                self._halt_after_stop()
                raise MotionInterrupted("GRBL motion stopped on request before arrival; the stage is halted")
            status = self.status(fresh=True)
            if self._in_alarm(status):
                raise SafetyStop(self.link.alarm_text())
            if status.state in _READY:
                err = max(abs(status.mpos[axis] - v) for axis, v in axes.items())
                if status.state == GrblState.CHECK or err <= self.config.arrival_tolerance_mm:
                    return
                if not moved and time.monotonic() - sent < _START_GRACE_S:
                    continue  # the block has not started yet
                raise MotionRejected(f"GRBL is idle {err:.3f} mm from the target: the motion was cut short")
            moved = moved or status.state not in _READY
            if time.monotonic() > deadline:
                raise PlatformTimeout(
                    f"GRBL did not arrive within {deadline - time.monotonic() + 1.5 * nominal_s:.1f} s "
                    f"(state {status.state}); motion held"
                )

    def _halt_after_stop(self) -> None:
        """After a feed hold: wait until the hold is complete, then flush the planner.

        An ``ALARM:3`` (reset while moving) raised here is reported by the next
        move's SafetyStop.
        """
        link = self.link
        deadline = time.monotonic() + self.config.answer_timeout_s
        try:
            while time.monotonic() < deadline:
                status = self.status(fresh=True)
                held = status.state == GrblState.HOLD and status.substate == 0
                if status.state in (GrblState.IDLE, GrblState.ALARM) or held:
                    break
                if status.state in (GrblState.RUN, GrblState.JOG):
                    # GRBL ignores '!' while idle: a hold sent just before the line started is repeated.
                    link.write(FEED_HOLD_JOG_CANCEL)
            # A soft reset after a completed hold keeps the position and empties the queue.
            link.banner_event.clear()
            link.write(SOFT_RESET)
            link.banner_event.wait(self.config.banner_timeout_s)
            time.sleep(0.05)
            link.drain_answers()
        except PlatformError:
            pass

    def stop(self) -> None:
        """Feed hold and jog cancel now (safe from any thread); the move in progress ends."""
        self._stop_requested.set()
        if self.link.is_open and self.link.lost is None:
            try:
                self.link.write(FEED_HOLD_JOG_CANCEL)
            except PlatformError:
                pass

    def home(self) -> None:
        """Run GRBL's homing cycle ``$H`` (clears an alarm); waits until it completes."""
        try:
            self.send_line("$H", timeout_s=self.config.homing_timeout_s)
        except KeyboardInterrupt:
            self.link.write(SOFT_RESET)
            raise
        self.link.alarm = None

    def unlock(self) -> None:
        """``$X``: leave the alarm state without homing (a person checked the stage)."""
        self.send_line("$X")
        self.link.alarm = None

    def describe(self) -> dict:
        """State, banner and pose for ``fgcd platform check``."""
        status = self.status(fresh=True)
        return {
            "driver": "grbl",
            "port": self.config.port,
            "banner": self.banner,
            "state": status.state,
            "alarm": self.link.alarm,
            "mpos": status.mpos,
            "healthy": status.state in _READY and self.link.alarm in (None, 0),
        }
