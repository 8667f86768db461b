"""Small pose helpers for the simulator (drivers may not import fgcd_cli.geometry)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["make_pose", "invert_pose", "look_at", "pose_from_xyz_rpy", "rot_angle", "exp_so3", "log_so3"]


def make_pose(R: np.ndarray, t) -> np.ndarray:
    """4x4 pose from a 3x3 rotation and a translation (metres)."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, dtype=float).ravel()
    return T


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 pose."""
    R = T[:3, :3]
    return make_pose(R.T, -R.T @ T[:3, 3])


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """``T_world_cam`` of an OpenCV camera at ``eye`` looking at ``target``.

    Camera z points to the target, camera y points "down" (against ``up``).
    """
    eye = np.asarray(eye, dtype=float)
    z = np.asarray(target, dtype=float) - eye
    z /= np.linalg.norm(z)
    up = np.asarray(up, dtype=float)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:  # looking along up: pick any perpendicular
        x = np.cross(z, np.array([1.0, 0.0, 0.0]))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_pose(np.stack([x, y, z], axis=1), eye)


def exp_so3(rotvec) -> np.ndarray:
    return Rotation.from_rotvec(np.asarray(rotvec, dtype=float)).as_matrix()


def log_so3(R: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(np.asarray(R, dtype=float)).as_rotvec()


def rot_angle(R: np.ndarray) -> float:
    """Rotation angle in radians."""
    c = (float(np.trace(R[:3, :3])) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def pose_from_xyz_rpy(xyz_m, rpy_rad) -> np.ndarray:
    """Pose from a translation (m) and a rotation vector... here XYZ Euler angles (rad, extrinsic)."""
    return make_pose(Rotation.from_euler("xyz", np.asarray(rpy_rad, dtype=float)).as_matrix(), xyz_m)
