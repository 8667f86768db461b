"""A person moves the camera (tripod head, slider) following per-axis instructions.

This is how fgcd serves sites where no robot can go (the manual usage mode the
rACR paper compares against). Each motion is turned into instructions in the
*current flange frame* of the mount, in millimetres and degrees ("slide right
12.5 mm", "tilt down 0.8 deg"), printed, and the person confirms when done.

**The reported pose is the commanded one**: nothing measures where the person
actually put the camera. The relocalization loop therefore sees the residual
of a manual step in its next visual measurement, not in the platform pose.

Flange axes as a person standing behind the camera sees them (OpenCV-like):
x to the right, y down, z forward. A positive rotation about x turns the view
up, about y turns it right, about z rolls it clockwise.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from fgcd_core.platform import Capabilities, MotionInterrupted, MoveResult

__all__ = ["ManualPlatform", "instructions_for"]

_TRANSLATION_WORDS = {0: ("slide right", "slide left"), 1: ("move down", "move up"), 2: ("push forward", "pull back")}
# Right-hand rule with x right, y down, z forward: +rx turns forward towards -y (up),
# +ry turns forward towards +x (right), +rz turns right towards down (clockwise from behind).
_ROTATION_WORDS = {
    0: ("tilt up", "tilt down"),
    1: ("pan right", "pan left"),
    2: ("roll clockwise", "roll anticlockwise"),
}


def instructions_for(T_flange_delta: np.ndarray, *, min_mm: float = 0.05, min_deg: float = 0.02) -> list[str]:
    """Human instructions for a relative motion in the flange frame.

    Parameters
    ----------
    T_flange_delta : (4, 4) ndarray
        Motion expressed in the current flange frame, metres.
    min_mm, min_deg : float
        Components below these are not worth asking a person for.

    Returns
    -------
    list of str
        One instruction per axis, translations first, e.g. ``"slide right 12.5 mm"``.
    """
    T = np.asarray(T_flange_delta, dtype=float)
    lines = []
    for axis, value in enumerate(T[:3, 3] * 1000.0):
        if abs(value) >= min_mm:
            word = _TRANSLATION_WORDS[axis][0 if value > 0 else 1]
            lines.append(f"{word} {abs(value):.1f} mm")
    rotvec_deg = np.degrees(Rotation.from_matrix(T[:3, :3]).as_rotvec())
    for axis, value in enumerate(rotvec_deg):
        if abs(value) >= min_deg:
            word = _ROTATION_WORDS[axis][0 if value > 0 else 1]
            lines.append(f"{word} {abs(value):.2f} deg")
    return lines


class ManualPlatform:
    """A person as the platform.

    Parameters
    ----------
    ask : callable(str) -> str
        Shows a prompt and returns the person's answer (``input`` by default).
    say : callable(str) -> None
        Prints one instruction line (``print`` by default).
    T_base_flange_start : (4, 4) ndarray, optional
        Pose the session starts from (identity: the mount's start defines the base).
    workspace_half_size_m : float
        Half size of the box around the start pose a person is asked to stay in.
    """

    name = "manual"

    def __init__(
        self,
        *,
        ask: Callable[[str], str] = input,
        say: Callable[[str], None] = print,
        T_base_flange_start: np.ndarray | None = None,
        workspace_half_size_m: float = 0.5,
    ) -> None:
        self._ask = ask
        self._say = say
        self._T = np.eye(4) if T_base_flange_start is None else np.array(T_base_flange_start, dtype=float)
        start = self._T[:3, 3]
        self._lo = tuple(float(v) for v in start - workspace_half_size_m)
        self._hi = tuple(float(v) for v in start + workspace_half_size_m)

    def connect(self) -> None:
        """Nothing to open; the person is there."""

    def capabilities(self) -> Capabilities:
        """6 DoF (a person can do any motion), slow."""
        return Capabilities(
            dof=6,
            controllable=("x", "y", "z", "rx", "ry", "rz"),
            workspace_min_m=self._lo,
            workspace_max_m=self._hi,
            max_linear_speed_m_s=0.01,
            max_angular_speed_rad_s=math.radians(5.0),
        )

    def flange_pose(self) -> np.ndarray:
        """The last *commanded* pose (what the person confirmed), 4x4 metres."""
        return self._T.copy()

    def move_to(self, T_base_flange: np.ndarray, *, speed_fraction: float = 1.0) -> MoveResult:
        """Print the instructions and wait until the person confirms (``y``/Enter) or refuses."""
        target = np.asarray(T_base_flange, dtype=float)
        delta = np.linalg.inv(self._T) @ target
        lines = instructions_for(delta)
        if lines:
            self._say("Move the camera mount (directions as seen from behind the camera):")
            for number, line in enumerate(lines, start=1):
                self._say(f"  {number}. {line}")
            answer = self._ask("Done? [Y/n] ").strip().lower()
            if answer not in ("", "y", "yes"):
                raise MotionInterrupted("the manual motion was not confirmed; the pose is unchanged")
        self._T = target.copy()
        return MoveResult(
            T_base_flange_target=target,
            T_base_flange_reached=target.copy(),
            T_base_flange_commanded=target.copy(),
            unreachable=(),
            duration_s=0.0,
        )

    def stop(self) -> None:
        """A person stops by themselves; nothing to send."""

    def home(self) -> None:
        """Ask the person to return the mount to its start position."""
        self._say("Return the camera mount to its start position.")
        self._ask("Done? [Enter] ")
        self._T = np.eye(4)

    def close(self) -> None:
        """Nothing to release."""
