"""A simulated motion platform with realistic execution errors, on a simulated clock.

The platform keeps a hidden *true* flange pose and reports what its encoders
say. A commanded pose ``T_base_flange_cmd`` is reached as

* translation: ``home + M (cmd - home) + backlash + noise`` where ``M = I + S``
  holds per-axis scale errors and small axis misalignments (proportional error,
  fixed per platform instance), backlash is a per-axis offset of
  ``-/+ backlash/2`` depending on the direction of the axis' last motion, and
  noise is fresh Gaussian repeatability error;
* rotation: ``R_home exp((1 + s_rot) log(R_home^T R_cmd) + noise)``.

The reported pose is the commanded pose plus encoder noise (the controller
believes it arrived). Motions take ``max(distance / v_lin, angle / v_ang)`` of
simulated time (default 1.5 s per cm as the rACR paper's platform) plus a
settling time; with ``realtime_factor`` set they also take that time (divided
by the factor) in real time, during which the true pose moves and ``stop()``
halts the motion. Faults can be injected: timeout, emergency stop, disconnect.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from fgcd_core.platform import (
    Capabilities,
    MotionRejected,
    MoveResult,
    PlatformConnectionError,
    PlatformTimeout,
    SafetyStop,
)
from fgcd_core.se3 import exp_so3, make_pose
from fgcd_drivers.sim.transforms import log_so3, rot_angle

__all__ = ["SimClock", "PlatformErrorModel", "SimPlatform", "SimPlatformConfig", "SimFault", "ERROR_PRESETS", "FAULTS"]


class SimFault(StrEnum):
    """Faults :meth:`SimPlatform.inject_fault` can make a motion fail with."""

    TIMEOUT = "timeout"
    ESTOP = "estop"
    DISCONNECT = "disconnect"


FAULTS = tuple(f.value for f in SimFault)


class SimClock:
    """Simulated time in seconds; advances only when told (motions, frames)."""

    def __init__(self, start_s: float = 0.0):
        self._t = float(start_s)
        self._lock = threading.Lock()

    def now(self) -> float:
        with self._lock:
            return self._t

    def advance(self, dt_s: float) -> float:
        if dt_s < 0:
            raise ValueError("time cannot go backwards")
        with self._lock:
            self._t += float(dt_s)
            return self._t


@dataclass(frozen=True, kw_only=True)
class PlatformErrorModel:
    """Execution error statistics (1-sigma values unless stated).

    Attributes
    ----------
    scale_error : float
        Std of the per-axis proportional (scale) error, fraction (1e-3 = 0.1 %).
    axis_misalignment_rad : float
        Std of the off-diagonal coupling terms between axes, radians.
    rotation_scale_error : float
        Std of the proportional error of rotations, fraction.
    noise_m : float
        Repeatability noise per motion and axis, metres.
    noise_rad : float
        Rotation repeatability noise per motion and axis, radians.
    backlash_m : float
        Backlash per axis (full width), metres.
    encoder_noise_m, encoder_noise_rad : float
        Noise of the reported pose.
    """

    scale_error: float = 1e-3
    axis_misalignment_rad: float = 2e-4
    rotation_scale_error: float = 1e-3
    noise_m: float = 1e-4
    noise_rad: float = math.radians(0.01)
    backlash_m: float = 2e-5
    encoder_noise_m: float = 1e-5
    encoder_noise_rad: float = math.radians(0.001)


ERROR_PRESETS = {
    "none": PlatformErrorModel(
        scale_error=0,
        axis_misalignment_rad=0,
        rotation_scale_error=0,
        noise_m=0,
        noise_rad=0,
        backlash_m=0,
        encoder_noise_m=0,
        encoder_noise_rad=0,
    ),
    "default": PlatformErrorModel(),
    "precise": PlatformErrorModel(
        scale_error=2e-4,
        axis_misalignment_rad=5e-5,
        rotation_scale_error=2e-4,
        noise_m=2e-5,
        noise_rad=math.radians(0.002),
        backlash_m=5e-6,
        encoder_noise_m=2e-6,
        encoder_noise_rad=math.radians(0.0005),
    ),
    "sloppy": PlatformErrorModel(
        scale_error=1e-2,
        axis_misalignment_rad=3e-3,
        rotation_scale_error=1e-2,
        noise_m=1e-3,
        noise_rad=math.radians(0.1),
        backlash_m=5e-4,
        encoder_noise_m=1e-4,
        encoder_noise_rad=math.radians(0.01),
    ),
}


@dataclass(frozen=True, kw_only=True)
class SimPlatformConfig:
    """Motion model and limits of a :class:`SimPlatform`.

    Attributes
    ----------
    workspace_min_m, workspace_max_m : array-like of 3 or None
        Box for the flange origin in the base frame (default: home +- 0.25 m).
    seconds_per_m : float
        Translation time model (150 s/m = 1.5 s per cm, rACR's platform).
    rotation_deg_per_s : float
    settle_s : float
        Added to every motion.
    dof : 6 or 3 (an XYZ gantry keeps its orientation).
    realtime_factor : float or None
        If set, motions also take ``duration / realtime_factor`` of wall time.
    timeout_s : float
        A motion longer than this (simulated) raises PlatformTimeout.
    name : str
        The platform's driver name.
    """

    workspace_min_m: np.ndarray | tuple[float, float, float] | None = None
    workspace_max_m: np.ndarray | tuple[float, float, float] | None = None
    seconds_per_m: float = 150.0
    rotation_deg_per_s: float = 5.0
    settle_s: float = 0.2
    dof: int = 6
    realtime_factor: float | None = None
    timeout_s: float = 600.0
    name: str = "sim"


class SimPlatform:
    """Simulated 6-DoF (or 3-DoF gantry) platform implementing ``fgcd_core.platform.Platform``.

    Parameters
    ----------
    T_base_flange_home : (4, 4) home pose of the flange in the base frame.
    errors : PlatformErrorModel or preset name (``none default precise sloppy``).
    seed : int
        Draws the fixed kinematic errors (and the noise unless ``session_seed`` is given).
    session_seed : int, optional
        Seeds the per-motion noise separately (same platform, another session).
    clock : SimClock, optional (a new one by default).
    config : SimPlatformConfig, optional
        Motion model and limits (default: :class:`SimPlatformConfig`).
    """

    def __init__(
        self,
        *,
        T_base_flange_home: np.ndarray | None = None,
        errors: PlatformErrorModel | str = "default",
        seed: int = 0,
        clock: SimClock | None = None,
        session_seed: int | None = None,
        config: SimPlatformConfig | None = None,
    ):
        config = config or SimPlatformConfig()
        if config.dof not in (3, 6):
            raise ValueError("dof must be 3 or 6")
        self.config = config
        self.name = config.name
        self.errors = ERROR_PRESETS[errors] if isinstance(errors, str) else errors
        self.clock = clock or SimClock()
        self._rng = np.random.default_rng([seed, 0x51A7])
        self._home = np.eye(4) if T_base_flange_home is None else np.asarray(T_base_flange_home, float).copy()
        h = self._home[:3, 3]
        self._ws_min = np.asarray(config.workspace_min_m if config.workspace_min_m is not None else h - 0.25, float)
        self._ws_max = np.asarray(config.workspace_max_m if config.workspace_max_m is not None else h + 0.25, float)
        self.seconds_per_m = float(config.seconds_per_m)
        self.rotation_rad_per_s = math.radians(config.rotation_deg_per_s)
        self.settle_s = float(config.settle_s)
        self.dof = config.dof
        self.realtime_factor = config.realtime_factor
        self.timeout_s = float(config.timeout_s)
        e = self.errors
        # fixed per instance: proportional error and misalignment (the stage's kinematic calibration error)
        self._M = np.eye(3) + np.diag(self._rng.normal(0, e.scale_error, 3))
        off = self._rng.normal(0, e.axis_misalignment_rad, (3, 3))
        self._M += off - np.diag(np.diag(off))
        self._rot_scale = 1.0 + self._rng.normal(0, e.rotation_scale_error)
        if session_seed is not None:
            self._rng = np.random.default_rng([seed, 0x5E55, session_seed])
        self._last_dir = np.zeros(3)  # sign of each axis' last motion (backlash state)
        self._cmd = self._home.copy()
        self._true = self._execute(self._home, np.zeros(3), noise=False)
        self._motion: tuple[np.ndarray, np.ndarray, float, float] | None = None  # start, end, t0, duration
        self._connected = False
        self._estop = False
        self._pending_faults: list[tuple[str, int]] = []
        self._stop_flag = threading.Event()
        self._lock = threading.RLock()
        self.move_count = 0

    # ------------------------------------------------------------------ protocol
    def connect(self) -> None:
        with self._lock:
            self._connected = True

    def capabilities(self) -> Capabilities:
        axes = ("x", "y", "z", "rx", "ry", "rz") if self.dof == 6 else ("x", "y", "z")
        return Capabilities(
            dof=self.dof,
            controllable=axes,
            workspace_min_m=tuple(float(v) for v in self._ws_min),
            workspace_max_m=tuple(float(v) for v in self._ws_max),
            max_linear_speed_m_s=1.0 / self.seconds_per_m,
            max_angular_speed_rad_s=self.rotation_rad_per_s,
        )

    def flange_pose(self) -> np.ndarray:
        """Reported pose: the commanded pose as the encoders read it (with encoder noise)."""
        with self._lock:
            self._check_link()
            e = self.errors
            T = self._cmd.copy()
            T[:3, 3] += self._rng.normal(0, e.encoder_noise_m, 3)
            T[:3, :3] = T[:3, :3] @ exp_so3(self._rng.normal(0, e.encoder_noise_rad, 3))
            return T

    def move_to(self, T_base_flange: np.ndarray, *, speed_fraction: float = 1.0) -> MoveResult:
        T_target = np.asarray(T_base_flange, dtype=float)
        if T_target.shape != (4, 4) or not np.all(np.isfinite(T_target)):
            raise MotionRejected("target pose is not a finite 4x4 matrix")
        if not (0.0 < speed_fraction <= 1.0):
            raise MotionRejected("speed fraction must be in (0, 1]")
        with self._lock:
            self._check_link()
            if self._estop:
                raise SafetyStop("emergency stop is active on the simulated platform (clear_faults() to reset)")
            fault = self._take_fault()
            T_cmd = T_target.copy()
            unreachable: tuple[str, ...] = ()
            if self.dof == 3:
                if rot_angle(self._cmd[:3, :3].T @ T_target[:3, :3]) > 1e-9:
                    unreachable = ("rx", "ry", "rz")
                T_cmd[:3, :3] = self._cmd[:3, :3]
            p = T_cmd[:3, 3]
            if np.any(p < self._ws_min - 1e-9) or np.any(p > self._ws_max + 1e-9):
                raise MotionRejected(
                    "target " + ", ".join(f"{v * 1000:.1f}" for v in p) + " mm is outside the simulated workspace"
                )
            dist = float(np.linalg.norm(T_cmd[:3, 3] - self._cmd[:3, 3]))
            ang = rot_angle(self._cmd[:3, :3].T @ T_cmd[:3, :3])
            duration = max(dist * self.seconds_per_m, ang / self.rotation_rad_per_s) / speed_fraction + self.settle_s
            if fault == SimFault.DISCONNECT:
                self._connected = False
                raise PlatformConnectionError("connection to the simulated platform lost")
            if fault == SimFault.ESTOP:
                # pressed half way: the platform stops there, half the motion's time has passed
                self._estop = True
                self._run_motion(T_cmd, duration, partial=0.5)
                raise SafetyStop("emergency stop pressed during the motion (simulated)")
            if fault == SimFault.TIMEOUT or duration > self.timeout_s:
                # the host waits timeout_s: a too-long motion gets as far as it can in that time,
                # an injected timeout (stalled axis) stops half way; either way timeout_s have passed
                part = 0.5 if fault == SimFault.TIMEOUT else self.timeout_s / duration
                self._run_motion(T_cmd, duration, partial=part)
                stalled = self.timeout_s - part * duration
                if stalled > 0:
                    self.clock.advance(stalled)
                raise PlatformTimeout(f"simulated platform did not arrive within {self.timeout_s:.0f} s")
            stopped_at = self._run_motion(T_cmd, duration)
            self.move_count += 1
            reached = self.flange_pose()
            return MoveResult(
                T_base_flange_target=T_target,
                T_base_flange_reached=reached,
                T_base_flange_commanded=T_cmd if stopped_at is None else self._cmd.copy(),
                unreachable=unreachable,
                duration_s=duration if stopped_at is None else stopped_at,
            )

    def stop(self) -> None:
        self._stop_flag.set()

    def home(self) -> None:
        self.move_to(self._home)

    def close(self) -> None:
        with self._lock:
            self._connected = False

    # ------------------------------------------------------------------ faults
    def inject_fault(self, kind: str, *, after_moves: int = 0) -> None:
        """Make the motion after ``after_moves`` successful motions fail with ``kind``."""
        if kind not in FAULTS:
            raise ValueError(f"unknown fault {kind!r}; known: {', '.join(FAULTS)}")
        kind = SimFault(kind)
        with self._lock:
            self._pending_faults.append((kind, self.move_count + after_moves))

    def clear_faults(self) -> None:
        """Release the emergency stop and forget pending faults (a person reset the rig)."""
        with self._lock:
            self._estop = False
            self._pending_faults.clear()

    def _take_fault(self) -> SimFault | None:
        for i, (kind, at) in enumerate(self._pending_faults):
            if self.move_count >= at:
                del self._pending_faults[i]
                return kind
        return None

    def _check_link(self) -> None:
        if not self._connected:
            raise PlatformConnectionError("simulated platform is not connected (call connect())")

    # ------------------------------------------------------------------ truth (for the rig / ground truth only)
    @property
    def T_base_flange_home(self) -> np.ndarray:
        return self._home.copy()

    def true_flange_pose(self) -> np.ndarray:
        """The hidden true ``T_base_flange`` (interpolated while a real-time motion runs)."""
        with self._lock:
            if self._motion is None:
                return self._true.copy()
            start, end, t0, dur = self._motion
            a = min(1.0, max(0.0, (self.clock.now() - t0) / max(dur, 1e-9)))
            return _interp(start, end, a)

    def commanded_pose(self) -> np.ndarray:
        return self._cmd.copy()

    # ------------------------------------------------------------------ internals
    def _execute(self, T_cmd: np.ndarray, direction: np.ndarray, *, noise: bool = True) -> np.ndarray:
        e = self.errors
        h = self._home[:3, 3]
        t = h + self._M @ (T_cmd[:3, 3] - h)
        t = t - 0.5 * e.backlash_m * direction
        phi = log_so3(self._home[:3, :3].T @ T_cmd[:3, :3]) * self._rot_scale
        if noise:
            t = t + self._rng.normal(0, e.noise_m, 3)
            phi = phi + self._rng.normal(0, e.noise_rad, 3)
        return make_pose(self._home[:3, :3] @ exp_so3(phi), t)

    def _run_motion(self, T_cmd: np.ndarray, duration: float, *, partial: float | None = None) -> float | None:
        """Move the true state; returns the elapsed time if stopped early, else None."""
        delta = T_cmd[:3, 3] - self._cmd[:3, 3]
        direction = np.where(np.abs(delta) > 1e-9, np.sign(delta), self._last_dir)
        start = self._true.copy()
        end = self._execute(T_cmd, direction)
        self._stop_flag.clear()
        elapsed = duration
        stopped = False
        if self.realtime_factor:
            t0 = self.clock.now()
            self._motion = (start, end, t0, duration)
            steps = max(1, int(math.ceil(duration / 0.05)))
            for k in range(steps):
                if self._stop_flag.is_set():
                    elapsed = k * duration / steps
                    stopped = True
                    break
                if partial is not None and (k + 1) / steps > partial:
                    elapsed = partial * duration
                    self.clock.advance(max(0.0, elapsed - k * duration / steps))
                    break
                self._lock.release()
                try:
                    time.sleep(duration / steps / self.realtime_factor)
                finally:
                    self._lock.acquire()
                self.clock.advance(duration / steps)
            self._motion = None
            remaining = 0.0
        else:
            if partial is not None:
                elapsed = partial * duration
            remaining = elapsed
        if stopped or partial is not None:
            a = elapsed / max(duration, 1e-9)
            self._true = _interp(start, end, a)
            self._cmd = _interp(self._cmd, T_cmd, a)
        else:
            self._true = end
            self._cmd = T_cmd.copy()
        self._last_dir = direction
        if remaining:
            self.clock.advance(remaining)
        return elapsed if stopped else None


def _interp(T0: np.ndarray, T1: np.ndarray, a: float) -> np.ndarray:
    phi = log_so3(T0[:3, :3].T @ T1[:3, :3])
    return make_pose(T0[:3, :3] @ exp_so3(a * phi), (1 - a) * T0[:3, 3] + a * T1[:3, 3])
