"""Universal Robots arm through the ``ur_rtde`` client (RTDE, dashboard, control script).

Behaviours of ``ur_rtde`` 1.6.5 this driver guards against (``docs/hardware.md``,
"Universal Robots arm"):

* the interface constructors and ``reconnect()`` have no timeout and hold the
  GIL: a peer that accepts TCP but never answers freezes the interpreter. So a
  pure-Python **pre-flight** (:func:`preflight`) first opens RTDE with a short
  timeout, sends the protocol-version request and requires an answer, and
  checks the dashboard greeting;
* after a dropped link the getters keep returning the last, **stale** values:
  every pose read checks ``isConnected()`` first, and that the controller's
  timestamp still advances (a hung controller keeps the link "connected");
* ``moveL`` returns ``False`` (no exception) under a protective stop, and a
  blocking ``moveL`` cannot be interrupted by Ctrl-C. Moves are therefore sent
  asynchronously and the driver polls arrival, safety bits and the connection
  itself, so Ctrl-C or :meth:`stop` can ``stopL`` the arm at once;
* a ``moveL`` whose client is gone (the network is down, nothing reaches the
  controller, not even the dashboard's ``stop``) runs to its end. So at connect
  the driver arms ur_rtde's watchdog (``setWatchdog``: the control script calls
  URScript ``rtde_set_watchdog("input_int_register_0", f, "stop")``) and a
  thread kicks it (``kickWatchdog``) every :attr:`URConfig.watchdog_kick_s`:
  when the kicks stop arriving the controller stops the program, and the arm,
  by itself within :attr:`URConfig.link_stop_s` (docs/hardware.md, "Faults in
  the field").

All poses are of the **flange**: at connect the driver sets the TCP offset to
zero (``setTcp``), so ``actual_TCP_pose`` is the flange pose. Poses travel as
``[x, y, z, rx, ry, rz]`` (metres, rotation vector) and are converted with
scipy's ``Rotation.from_rotvec`` / ``as_rotvec``, never Euler angles.
"""

from __future__ import annotations

import math
import socket
import threading
import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from fgcd_core.platform import (
    Capabilities,
    MotionInterrupted,
    MotionRejected,
    MoveResult,
    PlatformConnectionError,
    PlatformTimeout,
    SafetyStop,
)
from fgcd_drivers.ur_preflight import preflight
from fgcd_drivers.ur_state import RECEIVE_VARIABLES, ROBOT_MODE_RUNNING, pose_to_vector, safety_problem, vector_to_pose
from fgcd_drivers.ur_watchdog import links_up as _links_up
from fgcd_drivers.ur_watchdog import locked, start_kicker

#: Interfaces of hung controllers, kept alive so that no ur_rtde call (not even a
#: destructor's disconnect, which can block without a timeout) touches them again.
_ABANDONED: list = []

__all__ = [
    "URConfig",
    "URPlatform",
    "abandoned_interface_count",
]

# ur_rtde's accepted ranges for moveL (rtde_control_interface.h).
_UR_TOOL_SPEED_MAX = 3.0
_UR_TOOL_ACC_MAX = 150.0


def abandoned_interface_count() -> int:
    """How many hung or dropped controllers' ur_rtde interface pairs this process abandoned so far.

    Their native threads may reconnect forever, so a normal interpreter exit would wait for
    them: a command that abandoned one (the count grew) ends its process with ``os._exit``.
    """
    return len(_ABANDONED)


@dataclass(frozen=True, kw_only=True)
class URConfig:
    """Connection and motion limits of a UR arm.

    Attributes
    ----------
    host : str
        Controller address (``127.0.0.1`` for the fake controller or URSim).
    preflight_timeout_s : float
        Timeout of the pure-Python pre-flight.
    max_linear_speed_m_s, max_linear_acc_m_s2 : float
        Caps on moveL speed and acceleration (within ur_rtde's accepted ranges).
    max_angular_speed_rad_s : float
        Cap used by the guard and to time rotations.
    workspace_min_m, workspace_max_m : tuple of 3 float
        Box for the flange origin in the base frame.
    arrival_tolerance_m, arrival_tolerance_rad : float
        Distance from the target counted as arrived.
    arrival_margin_s : float
        Extra time beyond the nominal motion time before a move times out.
    poll_s : float
        Polling period while waiting for arrival.
    stale_after_s : float
        A state whose controller timestamp has not advanced for this long is
        stale (the controller streams at 125 or 500 Hz): the link is treated as lost.
    stop_timeout_s : float
        ``stop()`` returns after at most this long: ur_rtde can block inside
        ``stopL`` without a timeout while it tries to reconnect to a controller
        that is gone, and a stop must never hang the tool (the controller stops
        the arm by itself when its connection drops).
    watchdog_min_hz : float
        The RTDE watchdog's minimum input frequency: the controller stops the
        program (and the motion) when no kick reached it for ``1 / watchdog_min_hz``
        seconds. 0 leaves it unset (a move then runs to its end when the link dies).
        1 Hz: a fgcd process stalled for under a second on a busy laptop is not stopped.
    watchdog_kick_s : float
        Period of the kicks (ten per watchdog period by default).
    """

    host: str
    preflight_timeout_s: float = 2.0
    max_linear_speed_m_s: float = 0.1
    max_linear_acc_m_s2: float = 0.5
    max_angular_speed_rad_s: float = math.radians(30.0)
    workspace_min_m: tuple[float, float, float] = (-0.8, -0.8, -0.1)
    workspace_max_m: tuple[float, float, float] = (0.8, 0.8, 0.9)
    arrival_tolerance_m: float = 2e-4
    arrival_tolerance_rad: float = math.radians(0.05)
    arrival_margin_s: float = 5.0
    poll_s: float = 0.02
    stale_after_s: float = 0.5
    stop_timeout_s: float = 2.0
    watchdog_min_hz: float = 1.0
    watchdog_kick_s: float = 0.1

    @property
    def link_stop_s(self) -> float | None:
        """The stated bound: after the link dies the arm stops by itself within this many seconds (its
        braking aside): the watchdog period plus one kick period (the last kick may have left that much
        earlier). None when no watchdog is set."""
        return 1.0 / self.watchdog_min_hz + self.watchdog_kick_s if self.watchdog_min_hz > 0 else None


class URPlatform:
    """A UR arm as a :class:`~fgcd_core.platform.Platform` (6 DoF, flange frame)."""

    name = "ur"

    def __init__(self, config: URConfig) -> None:
        self.config = config
        self._rtde_c = None
        self._rtde_r = None
        self._control_lock = threading.Lock()
        self._stop_requested = threading.Event()
        self.greeting: str | None = None
        self._last_timestamp: float | None = None
        self._last_fresh = 0.0
        self._kicking = threading.Event()  # set while the watchdog kicker of the current interfaces runs

    # ------------------------------------------------------------------ connection
    def connect(self) -> None:
        """Pre-flight, construct the ur_rtde interfaces, zero the TCP, check safety."""
        self.greeting = preflight(self.config.host, timeout_s=self.config.preflight_timeout_s)
        import rtde_control
        import rtde_receive

        try:
            self._rtde_r = rtde_receive.RTDEReceiveInterface(self.config.host, -1.0, RECEIVE_VARIABLES)
            self._rtde_c = rtde_control.RTDEControlInterface(self.config.host)
        except RuntimeError as exc:
            self._rtde_c = self._rtde_r = None
            raise PlatformConnectionError(f"ur_rtde could not connect to {self.config.host}: {exc}") from None
        self._last_timestamp, self._last_fresh = None, time.monotonic()
        with self._locked("setTcp"):
            accepted = self._rtde_c.setTcp([0.0] * 6)
        if not accepted:
            # ur_rtde refuses every command under a protective or emergency stop: say so (connecting
            # never releases one; a person does, on the pendant: docs/hardware.md, faults).
            self.check_safety()
            raise PlatformConnectionError("the UR controller refused setTcp (is the control script running?)")
        self._arm_watchdog()
        time.sleep(0.05)  # let a state package with the new TCP arrive

    def _locked(self, what: str):
        """The control lock, held within ``stop_timeout_s`` or PlatformConnectionError."""
        return locked(self._control_lock, self.config.stop_timeout_s, what)

    def _arm_watchdog(self) -> None:
        """Set the controller's RTDE watchdog and start kicking it (see the module docstring)."""
        if self.config.watchdog_min_hz <= 0:
            return
        with self._locked("setWatchdog"):
            if not self._rtde_c.setWatchdog(float(self.config.watchdog_min_hz)):
                raise PlatformConnectionError("the UR controller refused setWatchdog (is the control script running?)")
        self._kicking = start_kicker(self._rtde_c, self._control_lock, self.config.watchdog_kick_s)

    def reconnect(self) -> None:
        """Drop the old interfaces and connect afresh (pre-flight first).

        ur_rtde's own ``reconnect()`` has no timeout and can fail after a
        dropped link; new interfaces do not depend on the old link's state.
        """
        self.close()
        self.connect()

    def close(self) -> None:
        """Stop, end the control script and disconnect.

        Commands are only sent while the link and the script are up: on a
        broken link ur_rtde would try to reconnect inside ``stopL`` with no timeout.
        """
        c, r = self._rtde_c, self._rtde_r
        self._rtde_c = self._rtde_r = None
        self._kicking.clear()  # the kicker ends at its next period (stopScript removes the watchdog)
        if c is not None and (self._hung(r) or not _links_up(c, r)):
            # A hung controller or a dropped link: ur_rtde's stopL/disconnect block with
            # no timeout on the first, and race its own native reconnect thread on the
            # second (a crash inside the library). Never touch these interfaces again;
            # keep them referenced so their destructors do not run either.
            _ABANDONED.append((c, r))
            return
        if self._control_lock.acquire(timeout=self.config.stop_timeout_s):
            self._control_lock.release()  # a kick in flight has ended; no other one starts
        try:
            healthy = c is not None and c.isConnected() and c.isProgramRunning()
        except RuntimeError:
            healthy = False
        steps = [lambda: c.stopL(self.config.max_linear_acc_m_s2), lambda: c.stopScript()] if healthy else []
        steps += [lambda: c is not None and c.disconnect(), lambda: r is not None and r.disconnect()]
        for action in steps:
            try:
                action()
            except RuntimeError:
                pass

    # ------------------------------------------------------------------ state
    def _hung(self, r) -> bool:
        """True when the receive stream stopped advancing (the controller hangs)."""
        if r is None:
            return False
        try:
            stamp = float(r.getTimestamp())
        except RuntimeError:
            return False
        if stamp != self._last_timestamp:
            self._last_timestamp, self._last_fresh = stamp, time.monotonic()
            return False
        return time.monotonic() - self._last_fresh > self.config.stale_after_s

    def _receive(self):
        r = self._rtde_r
        if r is None or self._rtde_c is None:
            raise PlatformConnectionError("the UR arm is not connected")
        if not r.isConnected() or not self._rtde_c.isConnected():
            raise PlatformConnectionError(
                f"lost the connection to the UR controller at {self.config.host} (the last pose is stale)"
            )
        # A hung controller or a half-open link keeps isConnected() True while the
        # getters repeat the last package: the controller's own clock must advance.
        stamp = float(r.getTimestamp())
        now = time.monotonic()
        if stamp != self._last_timestamp:
            self._last_timestamp, self._last_fresh = stamp, now
        elif now - self._last_fresh > self.config.stale_after_s:
            raise PlatformConnectionError(
                f"the UR controller at {self.config.host} sent no fresh state for "
                f"{now - self._last_fresh:.1f} s (the last pose is stale)"
            )
        return r

    def check_safety(self) -> None:
        """Raise SafetyStop unless the arm is running with no safety bit raised."""
        r = self._receive()
        problem = safety_problem(int(r.getSafetyStatusBits()))
        if problem:
            raise SafetyStop(
                f"UR safety status: {problem}; clear it on the teach pendant (or the dashboard) before moving"
            )
        mode = int(r.getRobotMode())
        if mode != ROBOT_MODE_RUNNING:
            raise SafetyStop(f"UR robot mode is {mode}, not running (7): power on and release the brakes")

    def flange_pose(self) -> np.ndarray:
        """``T_base_flange`` (4x4, metres) from a live state package."""
        return vector_to_pose(self._receive().getActualTCPPose())

    def capabilities(self) -> Capabilities:
        """6 DoF with the configured workspace and speed caps."""
        return Capabilities(
            dof=6,
            controllable=("x", "y", "z", "rx", "ry", "rz"),
            workspace_min_m=tuple(self.config.workspace_min_m),
            workspace_max_m=tuple(self.config.workspace_max_m),
            max_linear_speed_m_s=self.config.max_linear_speed_m_s,
            max_angular_speed_rad_s=self.config.max_angular_speed_rad_s,
        )

    def describe(self) -> dict:
        """State and pose for ``fgcd platform check``."""
        r = self._receive()
        bits = int(r.getSafetyStatusBits())
        mode = int(r.getRobotMode())
        return {
            "driver": "ur",
            "host": self.config.host,
            "greeting": self.greeting,
            "robot_mode": mode,
            "safety_status_bits": bits,
            "safety_problem": safety_problem(bits),
            "program_running": bool(self._rtde_c.isProgramRunning()),
            "healthy": mode == ROBOT_MODE_RUNNING and safety_problem(bits) is None,
        }

    # ------------------------------------------------------------------ motion
    def move_to(self, T_base_flange: np.ndarray, *, speed_fraction: float = 1.0) -> MoveResult:
        """moveL to ``T_base_flange`` (asynchronous send, polled arrival).

        Raises
        ------
        SafetyStop
            A safety bit was raised before or during the move.
        PlatformConnectionError
            The link dropped (stale data is never used).
        MotionInterrupted
            :meth:`stop` was called; the arm was stopped with stopL.
        PlatformTimeout
            No arrival in time; the arm was stopped.
        """
        started = time.monotonic()
        target = np.asarray(T_base_flange, dtype=float)
        self._stop_requested.clear()
        self.check_safety()
        start = self.flange_pose()
        fraction = min(max(float(speed_fraction), 1e-3), 1.0)
        speed = min(self.config.max_linear_speed_m_s * fraction, _UR_TOOL_SPEED_MAX)
        acc = min(self.config.max_linear_acc_m_s2, _UR_TOOL_ACC_MAX)
        dist = float(np.linalg.norm(target[:3, 3] - start[:3, 3]))
        angle = float(np.linalg.norm(Rotation.from_matrix(start[:3, :3].T @ target[:3, :3]).as_rotvec()))
        nominal = max(dist / speed, angle / (self.config.max_angular_speed_rad_s * fraction)) + speed / acc
        try:
            with self._locked("moveL"):
                accepted = self._rtde_c.moveL(pose_to_vector(target), speed, acc, True)
            if not accepted:
                self.check_safety()  # a protective stop is the usual reason
                if not self._rtde_c.isProgramRunning():
                    raise PlatformConnectionError(
                        "the UR control script is not running (connection lost, its watchdog stopped it after a "
                        "link loss, or it was stopped on the pendant); reconnect"
                    )
                raise MotionRejected("the UR controller refused the move (moveL returned False)")
            self._wait_arrival(target, nominal)
        except KeyboardInterrupt:
            self.stop()
            raise
        except (PlatformTimeout, SafetyStop, PlatformConnectionError, MotionInterrupted):
            self.stop()
            raise
        except MotionRejected:
            raise
        except RuntimeError as exc:  # ur_rtde: lost link or a failed command
            self.stop()
            raise PlatformConnectionError(f"UR move failed: {exc}") from None
        self.check_safety()
        reached = self.flange_pose()
        return MoveResult(
            T_base_flange_target=target,
            T_base_flange_reached=reached,
            T_base_flange_commanded=target,
            unreachable=(),
            duration_s=time.monotonic() - started,
        )

    def _wait_arrival(self, target: np.ndarray, nominal_s: float) -> None:
        deadline = time.monotonic() + 1.5 * nominal_s + self.config.arrival_margin_s
        while True:
            if self._stop_requested.is_set():
                raise MotionInterrupted("UR motion stopped on request before arrival; the arm is stopped")
            self.check_safety()
            r = self._receive()
            pose = vector_to_pose(r.getActualTCPPose())
            speed = float(np.linalg.norm(r.getActualTCPSpeed()[:3]))
            err_m = float(np.linalg.norm(pose[:3, 3] - target[:3, 3]))
            err_rad = float(np.linalg.norm(Rotation.from_matrix(pose[:3, :3].T @ target[:3, :3]).as_rotvec()))
            if (
                err_m <= self.config.arrival_tolerance_m
                and err_rad <= self.config.arrival_tolerance_rad
                and speed < 1e-3
            ):
                return
            if time.monotonic() > deadline:
                raise PlatformTimeout(
                    f"the UR arm did not arrive in time ({err_m * 1000:.1f} mm from the target); it was stopped"
                )
            time.sleep(self.config.poll_s)

    def stop(self) -> None:
        """Stop the arm now (safe from any thread); the move in progress ends.

        Over RTDE with ``stopL`` while the link and the control script are up;
        otherwise (the link dropped, a hung stream, ``stopL`` not sent in time)
        through the dashboard server's ``stop`` command on a fresh connection, which
        stops the running program and with it the motion (UR dashboard server
        protocol; docs/hardware.md, faults).
        """
        self._stop_requested.set()
        c = self._rtde_c
        sent = threading.Event()
        if c is not None and not self._hung(self._rtde_r):

            def send_stop() -> None:
                # A watchdog kick in flight must not interleave with stopL's handshake; a moveL
                # holding the lock (a send, milliseconds) is not waited for past a short while.
                held = self._control_lock.acquire(timeout=min(0.5, self.config.stop_timeout_s / 2))
                try:
                    if c.isConnected() and c.isProgramRunning():
                        c.stopL(self.config.max_linear_acc_m_s2 * 2.0)
                        sent.set()
                except RuntimeError:
                    pass
                finally:
                    if held:
                        self._control_lock.release()

            # In a daemon thread: ur_rtde may block in its reconnect loop (see URConfig.stop_timeout_s).
            sender = threading.Thread(target=send_stop, name="fgcd-ur-stop", daemon=True)
            sender.start()
            sender.join(self.config.stop_timeout_s)
        if not sent.is_set():
            try:
                self._dashboard_command("stop")
            except PlatformConnectionError:
                pass  # nothing reaches the controller: the caller's error says the link is lost

    def home(self) -> None:
        """A UR arm has no homing cycle: its home is a taught pose, reached by moves."""
        raise MotionRejected(
            "a UR arm has no homing cycle; move it to a taught pose with 'fgcd platform move' or the pendant"
        )

    def unlock_protective_stop(self) -> str:
        """Ask the dashboard to release a protective stop (a person checked the cause)."""
        return self._dashboard_command("unlock protective stop")

    def _dashboard_command(self, text: str) -> str:
        """One dashboard-server command on a fresh connection (plain socket, with a timeout); its answer."""
        try:
            with socket.create_connection((self.config.host, 29999), timeout=self.config.preflight_timeout_s) as sock:
                sock.settimeout(self.config.preflight_timeout_s)
                sock.recv(256)
                sock.sendall(text.encode() + b"\n")
                return sock.recv(256).decode(errors="replace").strip()
        except OSError as exc:
            raise PlatformConnectionError(f"dashboard at {self.config.host} unreachable: {exc}") from None
