"""The Platform port: the protocol, its errors, and the one motion guard every motion passes.

The port lives in the core so the algorithm packages (relocation, calibration)
speak to a platform without importing any driver; the adapters in ``drivers/``
(sim, GRBL, UR, manual) implement it. Everything crossing it is plain data:
poses are 4x4 float64 homogeneous matrices in metres, ``T_base_flange`` maps
flange coordinates into the platform's base frame.

A platform moves the *flange*; the camera is mounted on it through the hand-eye
transform ``T_flange_cam`` which the driver does not know.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from fgcd_core.se3 import rotation_angle_rad

__all__ = [
    "PlatformError",
    "PlatformConnectionError",
    "PlatformTimeout",
    "SafetyStop",
    "MotionRejected",
    "MotionInterrupted",
    "Capabilities",
    "MoveResult",
    "Platform",
    "GuardLimits",
    "MotionGuard",
    "compose_flange_delta",
    "needed_axes",
    "AXES",
]


# ----------------------------------------------------------------------------- errors
class PlatformError(RuntimeError):
    """Base of every platform failure. The message is one line for a person."""


class PlatformConnectionError(PlatformError):
    """The platform cannot be reached, or the connection was lost."""


class PlatformTimeout(PlatformError):
    """The platform did not answer or did not arrive in time."""


class SafetyStop(PlatformError):
    """The platform is in a safety state (alarm, protective or emergency stop)."""


class MotionRejected(PlatformError):
    """A motion was refused before being sent (guard, workspace, unreachable)."""


class MotionInterrupted(PlatformError):
    """A motion was stopped before arrival (stop request, Ctrl-C); the platform is halted."""


# ----------------------------------------------------------------------------- data
@dataclass(frozen=True, kw_only=True)
class Capabilities:
    """What a platform can do.

    Attributes
    ----------
    dof : int
        Controllable degrees of freedom (3 for an XYZ gantry, 6 for an arm).
    controllable : tuple of str
        Which of ``("x", "y", "z", "rx", "ry", "rz")`` the platform can move.
    workspace_min_m, workspace_max_m : tuple of 3 floats
        Axis-aligned box for the flange origin in the base frame, metres.
    max_linear_speed_m_s : float
        Fastest translation speed the driver will command, m/s.
    max_angular_speed_rad_s : float
        Fastest rotation speed the driver will command, rad/s.
    """

    dof: int
    controllable: tuple[str, ...]
    workspace_min_m: tuple[float, float, float]
    workspace_max_m: tuple[float, float, float]
    max_linear_speed_m_s: float
    max_angular_speed_rad_s: float


@dataclass(frozen=True, kw_only=True)
class MoveResult:
    """Outcome of one motion.

    Attributes
    ----------
    T_base_flange_target : (4, 4) ndarray
        The pose that was asked for.
    T_base_flange_reached : (4, 4) ndarray
        The pose the platform reports after arrival (with its encoder errors).
    T_base_flange_commanded : (4, 4) ndarray
        What was actually sent: equal to the target on a 6-DoF platform, its
        reachable part on a platform with fewer DoF.
    unreachable : tuple of str
        Axes of the requested motion that the platform could not perform.
    duration_s : float
        Time the motion took (simulated seconds on the simulator).
    """

    T_base_flange_target: np.ndarray
    T_base_flange_reached: np.ndarray
    T_base_flange_commanded: np.ndarray
    unreachable: tuple[str, ...] = ()
    duration_s: float = 0.0


@runtime_checkable
class Platform(Protocol):
    """What every motion platform driver offers (sim, GRBL, UR, manual)."""

    name: str

    def connect(self) -> None:
        """Open the connection and check the platform is healthy."""

    def capabilities(self) -> Capabilities:
        """Degrees of freedom, workspace and speed limits."""

    def flange_pose(self) -> np.ndarray:
        """The reported pose ``T_base_flange`` (4x4, metres)."""

    def move_to(self, T_base_flange: np.ndarray, *, speed_fraction: float = 1.0) -> MoveResult:
        """Move the flange to ``T_base_flange`` and return once it has arrived."""

    def stop(self) -> None:
        """Stop any motion now. Must be safe to call from any thread, at any time."""

    def home(self) -> None:
        """Run the platform's homing or go to its home pose."""

    def close(self) -> None:
        """Stop and release the connection."""


# ----------------------------------------------------------------------------- helpers
def compose_flange_delta(T_base_flange: np.ndarray, T_flange_delta: np.ndarray) -> np.ndarray:
    """Target of a relative motion expressed in the current flange frame."""
    return np.asarray(T_base_flange, dtype=float) @ np.asarray(T_flange_delta, dtype=float)


def _check_pose(T: np.ndarray, what: str) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise MotionRejected(f"{what} is not a finite 4x4 pose")
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise MotionRejected(f"{what} has no valid rotation")
    return T


# ----------------------------------------------------------------------------- guard
@dataclass(frozen=True, kw_only=True)
class GuardLimits:
    """Limits every motion is checked against before it is sent.

    Attributes
    ----------
    max_step_m : float
        Largest translation of one motion, metres.
    max_step_rad : float
        Largest rotation of one motion, radians.
    speed_fraction : float
        Fraction (0, 1] of the platform's maximum speeds used for motions.
    workspace_min_m, workspace_max_m : tuple of 3 floats or None
        Extra workspace box (intersected with the platform's own), metres.
    allow_partial_motion : bool
        If True (default) a platform with fewer DoF performs the reachable part
        of a motion and reports the rest in ``MoveResult.unreachable``; if False
        such a motion is refused before anything moves.
    """

    max_step_m: float = 0.05
    max_step_rad: float = math.radians(10.0)
    speed_fraction: float = 0.5
    workspace_min_m: tuple[float, float, float] | None = None
    workspace_max_m: tuple[float, float, float] | None = None
    allow_partial_motion: bool = True


#: Axis names of a flange motion, in the order of ``Capabilities.controllable``.
AXES = ("x", "y", "z", "rx", "ry", "rz")


def needed_axes(
    T_base_flange_current: np.ndarray,
    T_base_flange_target: np.ndarray,
    *,
    tol_m: float = 1e-6,
    tol_rad: float = 1e-6,
) -> tuple[str, ...]:
    """Axes a motion uses: base-frame translation axes, flange-frame rotation axes.

    Parameters
    ----------
    T_base_flange_current, T_base_flange_target : (4, 4) ndarray
        Poses in metres.
    tol_m, tol_rad : float
        Components smaller than these are not counted.

    Returns
    -------
    tuple of str
        Subset of ``("x", "y", "z", "rx", "ry", "rz")``.
    """
    from scipy.spatial.transform import Rotation

    current = np.asarray(T_base_flange_current, dtype=float)
    target = np.asarray(T_base_flange_target, dtype=float)
    dp = target[:3, 3] - current[:3, 3]
    rotvec = Rotation.from_matrix(current[:3, :3].T @ target[:3, :3]).as_rotvec()
    used = [a for a, v in zip(AXES[:3], dp) if abs(v) > tol_m]
    used += [a for a, v in zip(AXES[3:], rotvec) if abs(v) > tol_rad]
    return tuple(used)


@dataclass
class MotionGuard:
    """The single gate every motion of fgcd passes.

    It checks workspace, step size and speed, asks for a confirmation before
    the first motion of a session, refuses motions a platform cannot perform
    (when ``limits.allow_partial_motion`` is False), and can be tripped after
    which it refuses every motion until reset. It trips itself when a motion
    ends in Ctrl-C (``KeyboardInterrupt``), a lost connection, a safety stop or
    an interrupted motion.

    Parameters
    ----------
    platform : Platform
        The driver motions go to.
    limits : GuardLimits
        Step, speed and workspace limits.
    confirm : callable(str) -> bool, optional
        Asked once before the first motion with a description of it; ``None``
        means the caller has already confirmed (``--yes``).
    """

    platform: Platform
    limits: GuardLimits = field(default_factory=GuardLimits)
    confirm: Callable[[str], bool] | None = None
    _confirmed: bool = field(default=False, init=False)
    _tripped: str | None = field(default=None, init=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, init=False)

    # -- state
    @property
    def tripped(self) -> str | None:
        """Reason the guard was tripped, or None."""
        return self._tripped

    def trip(self, reason: str) -> None:
        """Stop the platform and refuse further motion (thread-safe)."""
        self._tripped = reason
        try:
            self.platform.stop()
        except (PlatformError, OSError):
            pass

    def reset(self) -> None:
        """Allow motions again after a trip (a person decided it is safe)."""
        self._tripped = None

    # -- checks
    def check(self, T_base_flange_target: np.ndarray) -> None:
        """Raise MotionRejected if the motion to the target is not allowed."""
        if self._tripped is not None:
            raise MotionRejected(f"motion refused: platform stopped ({self._tripped})")
        target = _check_pose(T_base_flange_target, "target pose")
        current = _check_pose(self.platform.flange_pose(), "reported flange pose")
        step_m = float(np.linalg.norm(target[:3, 3] - current[:3, 3]))
        step_rad = rotation_angle_rad(current[:3, :3].T @ target[:3, :3])
        if step_m > self.limits.max_step_m + 1e-12:
            raise MotionRejected(
                f"motion refused: step {step_m * 1000:.1f} mm exceeds the limit {self.limits.max_step_m * 1000:.1f} mm"
            )
        if step_rad > self.limits.max_step_rad + 1e-12:
            raise MotionRejected(
                f"motion refused: rotation {math.degrees(step_rad):.2f} deg exceeds the limit "
                f"{math.degrees(self.limits.max_step_rad):.2f} deg"
            )
        caps = self.platform.capabilities()
        lo = np.array(caps.workspace_min_m, dtype=float)
        hi = np.array(caps.workspace_max_m, dtype=float)
        if self.limits.workspace_min_m is not None:
            lo = np.maximum(lo, self.limits.workspace_min_m)
        if self.limits.workspace_max_m is not None:
            hi = np.minimum(hi, self.limits.workspace_max_m)
        p = target[:3, 3]
        if np.any(p < lo - 1e-9) or np.any(p > hi + 1e-9):
            raise MotionRejected(
                "motion refused: target "
                + ", ".join(f"{v * 1000:.1f}" for v in p)
                + " mm is outside the workspace ["
                + ", ".join(f"{v * 1000:.0f}" for v in lo)
                + "] .. ["
                + ", ".join(f"{v * 1000:.0f}" for v in hi)
                + "] mm"
            )
        if not (0.0 < self.limits.speed_fraction <= 1.0):
            raise MotionRejected("motion refused: speed fraction must be in (0, 1]")
        if not self.limits.allow_partial_motion:
            missing = [a for a in needed_axes(current, target) if a not in caps.controllable]
            if missing:
                raise MotionRejected(
                    f"motion refused: '{self.platform.name}' cannot move along "
                    + ", ".join(missing)
                    + f" (it controls {', '.join(caps.controllable)})"
                )

    # -- motions
    def move_to(self, T_base_flange_target: np.ndarray) -> MoveResult:
        """Check, confirm once, then move and wait for arrival."""
        with self._lock:
            self.check(T_base_flange_target)
            if not self._confirmed:
                if self.confirm is not None:
                    current = self.platform.flange_pose()
                    dp = (np.asarray(T_base_flange_target)[:3, 3] - current[:3, 3]) * 1000
                    text = (
                        f"First motion of this session on '{self.platform.name}': "
                        f"move flange by ({dp[0]:.1f}, {dp[1]:.1f}, {dp[2]:.1f}) mm. Proceed?"
                    )
                    if not self.confirm(text):
                        raise MotionRejected("motion refused: the first motion was not confirmed")
                self._confirmed = True
            try:
                return self.platform.move_to(
                    np.asarray(T_base_flange_target, dtype=float),
                    speed_fraction=self.limits.speed_fraction,
                )
            except KeyboardInterrupt:
                # Ctrl-C: halt the platform before the interrupt propagates.
                self.trip("interrupted by the user (Ctrl-C)")
                raise
            except (PlatformConnectionError, SafetyStop, MotionInterrupted) as exc:
                # A lost connection or a safety state stops the loop until a person resets.
                self.trip(str(exc))
                raise

    def move_by(self, T_flange_delta: np.ndarray) -> MoveResult:
        """Relative motion expressed in the current flange frame."""
        delta = _check_pose(T_flange_delta, "relative motion")
        return self.move_to(compose_flange_delta(self.platform.flange_pose(), delta))
