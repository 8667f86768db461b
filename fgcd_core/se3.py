"""Rigid transforms SE(3) as 4x4 float64 matrices.

Convention: ``T_a_b`` maps coordinates from frame b into frame a. Tangent
vectors are ordered ``xi = (rho, phi)``: translation part first (metres), then
rotation vector (radians). No PyPI Lie-group library covers Sim(3) and SE(3)
together on numpy 2 (sophuspy: SE(3) only), so the small exp/log here sit on
top of :mod:`scipy.spatial.transform`.

This module is the bottom layer's: both ``drivers`` and ``fgcd_cli`` import it
(the one implementation; ``fgcd_core`` re-exports its names).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

__all__ = [
    "skew",
    "transform_each",
    "make_pose",
    "invert_pose",
    "is_pose",
    "project_to_so3",
    "exp_so3",
    "log_so3",
    "exp_se3",
    "log_se3",
    "left_jacobian_so3",
    "pose_from_rotvec",
    "pose_to_rotvec",
    "pose_from_quat",
    "pose_to_quat",
    "interpolate_pose",
    "rotation_angle_rad",
    "pose_distance",
    "transform_points",
    "look_at",
    "flange_motion",
    "camera_motion",
]


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix ``[v]x`` of a 3-vector, so ``skew(a) @ b == cross(a, b)``."""
    x, y, z = np.asarray(v, dtype=float).reshape(3)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def make_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """4x4 pose from a (3, 3) rotation and a (3,) translation in metres."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(R, dtype=float)
    T[:3, 3] = np.asarray(t, dtype=float).reshape(3)
    return T


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid (4, 4) pose, exact (uses the rotation's transpose)."""
    T = np.asarray(T, dtype=float)
    R = T[:3, :3]
    return make_pose(R.T, -R.T @ T[:3, 3])


def is_pose(T: np.ndarray, *, atol: float = 1e-6) -> bool:
    """True if ``T`` is a finite 4x4 rigid transform."""
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        return False
    R = T[:3, :3]
    return bool(
        np.allclose(R @ R.T, np.eye(3), atol=atol)
        and abs(np.linalg.det(R) - 1.0) < atol * 10
        and np.allclose(T[3], [0, 0, 0, 1], atol=atol)
    )


def project_to_so3(M: np.ndarray) -> np.ndarray:
    """Closest rotation (Frobenius norm) to a 3x3 matrix, via SVD."""
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=float))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def exp_so3(phi: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (radians)."""
    return Rotation.from_rotvec(np.asarray(phi, dtype=float).reshape(3)).as_matrix()


def log_so3(R: np.ndarray) -> np.ndarray:
    """Rotation vector (radians) of a rotation matrix."""
    return Rotation.from_matrix(project_to_so3(R)).as_rotvec()


def left_jacobian_so3(phi: np.ndarray) -> np.ndarray:
    """Left Jacobian ``J(phi)`` of SO(3): ``t = J(phi) @ rho`` in ``exp_se3``."""
    phi = np.asarray(phi, dtype=float).reshape(3)
    theta = float(np.linalg.norm(phi))
    K = skew(phi)
    if theta < 1e-6:
        return np.eye(3) + 0.5 * K + K @ K / 6.0
    a = (1.0 - math.cos(theta)) / theta**2
    b = (theta - math.sin(theta)) / theta**3
    return np.eye(3) + a * K + b * K @ K


def exp_se3(xi: np.ndarray) -> np.ndarray:
    """Pose from a twist ``xi = (rho, phi)`` of shape (6,)."""
    xi = np.asarray(xi, dtype=float).reshape(6)
    rho, phi = xi[:3], xi[3:]
    return make_pose(exp_so3(phi), left_jacobian_so3(phi) @ rho)


def log_se3(T: np.ndarray) -> np.ndarray:
    """Twist ``(rho, phi)`` of shape (6,) of a pose; inverse of :func:`exp_se3`."""
    T = np.asarray(T, dtype=float)
    phi = log_so3(T[:3, :3])
    rho = np.linalg.solve(left_jacobian_so3(phi), T[:3, 3])
    return np.concatenate([rho, phi])


def pose_from_rotvec(rotvec: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Pose from a rotation vector (radians) and translation (metres), as UR poses."""
    return make_pose(exp_so3(rotvec), t)


def pose_to_rotvec(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(rotvec (3,), t (3,))`` of a pose."""
    T = np.asarray(T, dtype=float)
    return log_so3(T[:3, :3]), T[:3, 3].copy()


def pose_from_quat(q_xyzw: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Pose from a unit quaternion in scalar-last order ``(x, y, z, w)``."""
    return make_pose(Rotation.from_quat(np.asarray(q_xyzw, dtype=float)).as_matrix(), t)


def pose_to_quat(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(q_xyzw (4,), t (3,))`` of a pose, with ``w >= 0``."""
    T = np.asarray(T, dtype=float)
    q = Rotation.from_matrix(project_to_so3(T[:3, :3])).as_quat()
    if q[3] < 0:
        q = -q
    return q, T[:3, 3].copy()


def interpolate_pose(T0: np.ndarray, T1: np.ndarray, alpha: float) -> np.ndarray:
    """Pose a fraction ``alpha`` in [0, 1] of the way from ``T0`` to ``T1``.

    Rotation by spherical interpolation, translation linearly (the path a
    platform takes when it moves position and orientation independently).
    """
    T0 = np.asarray(T0, dtype=float)
    T1 = np.asarray(T1, dtype=float)
    rots = Rotation.from_matrix(np.stack([project_to_so3(T0[:3, :3]), project_to_so3(T1[:3, :3])]))
    R = Slerp([0.0, 1.0], rots)([float(alpha)]).as_matrix()[0]
    return make_pose(R, (1.0 - alpha) * T0[:3, 3] + alpha * T1[:3, 3])


def rotation_angle_rad(R: np.ndarray) -> float:
    """Angle of a rotation matrix in radians, in [0, pi]."""
    # atan2 of sine and cosine parts: accurate near 0 and pi, unlike acos alone.
    R = np.asarray(R, dtype=float)[:3, :3]
    c = (float(np.trace(R)) - 1.0) / 2.0
    s = 0.5 * float(np.linalg.norm([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]))
    return math.atan2(s, c)


def pose_distance(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """Distance between two poses of the same thing, for people.

    Returns
    -------
    translation_mm : float
        Distance between the two origins, millimetres.
    rotation_deg : float
        Angle of the relative rotation, degrees.
    """
    T_a = np.asarray(T_a, dtype=float)
    T_b = np.asarray(T_b, dtype=float)
    trans_mm = float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]) * 1000.0)
    rot_deg = math.degrees(rotation_angle_rad(T_a[:3, :3].T @ T_b[:3, :3]))
    return trans_mm, rot_deg


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a (4, 4) transform to (N, 3) points."""
    T = np.asarray(T, dtype=float)
    points = np.asarray(points, dtype=float)
    return points @ T[:3, :3].T + T[:3, 3]


def transform_each(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply transform ``T[m]`` (M, 4, 4) to point ``points[m]`` (M, 3); returns (M, 3)."""
    return np.einsum("mij,mj->mi", T[:, :3, :3], points) + T[:, :3, 3]


def look_at(
    eye: np.ndarray,
    target: np.ndarray,
    *,
    up: np.ndarray,
    fallback_up: np.ndarray | None = None,
) -> np.ndarray:
    """``T_world_cam`` of an OpenCV camera at ``eye`` looking at ``target``.

    Camera z points from ``eye`` to ``target``; camera x is ``z x up`` (so
    camera y, ``z x x``, points against ``up``: "down" in the image).

    Parameters
    ----------
    eye, target : (3,) array_like
        Camera centre and the point it looks at, world frame, metres.
    up : (3,) array_like
        World direction that appears upwards in the image. Required: the
        simulator's worlds use ``+z``, the synthetic relief scenes ``-y``.
    fallback_up : (3,) array_like, optional
        ``up`` to use instead when the view direction is parallel to ``up``
        (``|z x up| < 1e-9``). Without it that case raises ``ValueError``.

    Returns
    -------
    (4, 4) ndarray
        Rigid pose ``T_world_cam``.
    """
    eye = np.asarray(eye, dtype=float)
    z = np.asarray(target, dtype=float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=float))
    if np.linalg.norm(x) < 1e-9:
        if fallback_up is None:
            raise ValueError("look_at: the view direction is parallel to up; give fallback_up")
        x = np.cross(z, np.asarray(fallback_up, dtype=float))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_pose(np.column_stack([x, y, z]), eye)


def flange_motion(T_flange_cam: np.ndarray, M_cam: np.ndarray) -> np.ndarray:
    """The flange motion that moves the camera by ``M_cam``: ``M_flange = X M_cam X⁻¹`` (paper 000, Eq. 3).

    Parameters
    ----------
    T_flange_cam : (4, 4) ndarray
        Hand-eye transform ``X``: the camera in the flange frame, metres (identity: no hand-eye).
    M_cam : (4, 4) ndarray
        The camera's motion, expressed in its own frame before the motion, metres.

    Returns
    -------
    (4, 4) ndarray
        The same rigid motion as the flange must make it, in the flange frame before the motion.
    """
    X = np.asarray(T_flange_cam, dtype=float)
    return X @ np.asarray(M_cam, dtype=float) @ invert_pose(X)


def camera_motion(T_flange_cam: np.ndarray, M_flange: np.ndarray) -> np.ndarray:
    """The camera motion a flange motion makes: ``M_cam = X⁻¹ M_flange X``, the inverse of :func:`flange_motion`.

    Shapes and units as :func:`flange_motion`.
    """
    X = np.asarray(T_flange_cam, dtype=float)
    return invert_pose(X) @ np.asarray(M_flange, dtype=float) @ X
