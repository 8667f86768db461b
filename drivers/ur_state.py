"""What a UR controller's RTDE state says, in the driver's words: the variables asked for, robot mode and
safety bits, and flange poses as ``[x, y, z, rx, ry, rz]`` (metres, rotation vector; scipy's
``Rotation.from_rotvec`` / ``as_rotvec``, never Euler angles). Used by :mod:`fgcd_drivers.ur`.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from fgcd_core.platform import PlatformConnectionError

__all__ = ["RECEIVE_VARIABLES", "ROBOT_MODE_RUNNING", "pose_to_vector", "safety_problem", "vector_to_pose"]

#: Variables the receive interface asks for (less traffic than the default set).
RECEIVE_VARIABLES = [
    "timestamp",
    "actual_TCP_pose",
    "actual_TCP_speed",
    "robot_mode",
    "safety_mode",
    "safety_status_bits",
    "runtime_state",
    "robot_status_bits",
]
#: ``robot_mode`` of an arm that runs (RTDE).
ROBOT_MODE_RUNNING = 7
_SAFETY_BITS = {
    2: "protective stop",
    3: "recovery mode",
    4: "safeguard stop",
    5: "system emergency stop",
    6: "robot emergency stop",
    7: "emergency stop",
    8: "safety violation",
    9: "safety fault",
    10: "stopped due to safety",
}


def pose_to_vector(T: np.ndarray) -> list[float]:
    """``[x, y, z, rx, ry, rz]`` (metres, rotation vector) of a 4x4 pose."""
    T = np.asarray(T, dtype=float)
    return [float(v) for v in T[:3, 3]] + [float(v) for v in Rotation.from_matrix(T[:3, :3]).as_rotvec()]


def vector_to_pose(vector) -> np.ndarray:
    """4x4 pose from ``[x, y, z, rx, ry, rz]`` (metres, rotation vector)."""
    v = np.asarray(vector, dtype=float)
    if v.shape != (6,) or not np.all(np.isfinite(v)):
        raise PlatformConnectionError(f"the robot reported an invalid pose {list(v)}")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(v[3:]).as_matrix()
    T[:3, 3] = v[:3]
    return T


def safety_problem(bits: int) -> str | None:
    """Words for the raised safety-status bits, or None when the robot is normal."""
    raised = [text for bit, text in _SAFETY_BITS.items() if bits & (1 << bit)]
    return ", ".join(raised) if raised else None
