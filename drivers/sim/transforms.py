"""Pose helpers for the simulator, on top of :mod:`fgcd_core.se3` (the world may not import ``fgcd_cli``).

``make_pose``, ``invert_pose`` and ``exp_so3`` are :mod:`fgcd_core.se3`'s.
``look_at`` fixes the simulator's up direction (+z, the worlds' vertical).
``log_so3`` and ``rot_angle`` keep the simulated platform's own numerics:
``log_so3`` reads the rotation with scipy directly (no SVD projection first),
``rot_angle`` is ``arccos((trace R - 1) / 2)``, whose resolution near 0 is
about 1e-8 rad; the platform's motion timing and its 1e-9 rad "no rotation"
test are computed with them (``drivers/sim/platform.py``).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from fgcd_core.se3 import invert_pose
from fgcd_core.se3 import look_at as _look_at

__all__ = ["invert_pose", "look_at", "rot_angle", "log_so3"]

#: The simulator's worlds are z-up.
WORLD_UP = (0.0, 0.0, 1.0)


def look_at(eye, target, up=WORLD_UP) -> np.ndarray:
    """``T_world_cam`` of an OpenCV camera at ``eye`` looking at ``target``, image up along ``up``.

    Looking straight along ``up``, camera x is taken perpendicular to world x
    (see :func:`fgcd_core.se3.look_at`).
    """
    return _look_at(eye, target, up=up, fallback_up=(1.0, 0.0, 0.0))


def log_so3(R: np.ndarray) -> np.ndarray:
    """Rotation vector (radians) of a rotation matrix, read by scipy without projecting it first."""
    return Rotation.from_matrix(np.asarray(R, dtype=float)).as_rotvec()


def rot_angle(R: np.ndarray) -> float:
    """Rotation angle in radians, ``arccos((trace R - 1) / 2)`` (clipped to [0, pi])."""
    c = (float(np.trace(R[:3, :3])) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))
