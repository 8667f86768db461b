"""Similarity transforms Sim(3): ``x -> scale * R @ x + t``.

The scale is carried explicitly (never hidden in a 4x4 matrix's rotation
block) so that a rigid pose and a similarity cannot be confused. Tangent
vectors are ``(rho (3), phi (3), lambda)`` with ``scale = exp(lambda)``; exp/log
use the matrix exponential of the 4x4 algebra element (exact and short; these
are not in an inner loop).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import expm, logm
from scipy.spatial.transform import Rotation, Slerp

from fgcd_core.se3 import make_pose, project_to_so3, rotation_angle_rad, skew

__all__ = ["Sim3", "umeyama"]


@dataclass(frozen=True)
class Sim3:
    """A similarity ``y = scale * R @ x + t``.

    Attributes
    ----------
    R : (3, 3) ndarray
        Rotation.
    t : (3,) ndarray
        Translation, in the units of the target frame (metres for metric frames).
    scale : float
        Positive scale factor from source units to target units.
    """

    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))
    scale: float = 1.0

    def __post_init__(self) -> None:
        R = np.asarray(self.R, dtype=float).reshape(3, 3)
        t = np.asarray(self.t, dtype=float).reshape(3)
        if not (math.isfinite(float(self.scale)) and float(self.scale) > 0):
            raise ValueError(f"Sim3 scale must be positive and finite, got {self.scale}")
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "scale", float(self.scale))

    # -- constructors
    @classmethod
    def identity(cls) -> Sim3:
        """The identity similarity."""
        return cls()

    @classmethod
    def from_pose(cls, T: np.ndarray, scale: float = 1.0) -> Sim3:
        """Similarity with the rotation and translation of a rigid pose."""
        T = np.asarray(T, dtype=float)
        return cls(T[:3, :3], T[:3, 3], scale)

    @classmethod
    def from_matrix(cls, M: np.ndarray) -> Sim3:
        """From a 4x4 matrix ``[[sR, t], [0, 1]]``."""
        M = np.asarray(M, dtype=float)
        sR = M[:3, :3]
        scale = float(np.cbrt(np.linalg.det(sR)))
        if not scale > 0:
            raise ValueError("matrix is not a proper similarity (non-positive determinant)")
        return cls(project_to_so3(sR / scale), M[:3, 3], scale)

    # -- group operations
    def matrix(self) -> np.ndarray:
        """4x4 matrix ``[[scale*R, t], [0, 1]]``."""
        return make_pose(self.scale * self.R, self.t)

    def rigid(self) -> np.ndarray:
        """The 4x4 rigid part ``[[R, t], [0, 1]]`` (scale dropped)."""
        return make_pose(self.R, self.t)

    def inverse(self) -> Sim3:
        """Inverse similarity."""
        Rinv = self.R.T
        return Sim3(Rinv, -(Rinv @ self.t) / self.scale, 1.0 / self.scale)

    def __matmul__(self, other: Sim3) -> Sim3:
        """Composition: ``(a @ b)(x) == a(b(x))``."""
        return Sim3(self.R @ other.R, self.scale * (self.R @ other.t) + self.t, self.scale * other.scale)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Transform (N, 3) or (3,) points."""
        p = np.asarray(points, dtype=float)
        return self.scale * (p @ self.R.T) + self.t

    def transform_pose(self, T_src_cam: np.ndarray) -> np.ndarray:
        """Carry a camera pose from the source frame into the target frame.

        If ``self`` maps frame ``src`` into frame ``dst``, a camera with pose
        ``T_src_cam`` has pose ``T_dst_cam`` with the same rotation composed and
        its centre mapped: ``R = self.R @ R_cam``, ``t = self(t_cam)``.
        """
        T = np.asarray(T_src_cam, dtype=float)
        return make_pose(self.R @ T[:3, :3], self.apply(T[:3, 3]))

    # -- conversions
    @classmethod
    def from_rotvec(cls, rotvec: np.ndarray, t: np.ndarray, scale: float = 1.0) -> Sim3:
        """From a rotation vector (axis * angle, radians), a translation and a scale."""
        return cls(Rotation.from_rotvec(np.asarray(rotvec, dtype=float).reshape(3)).as_matrix(), t, scale)

    def to_rotvec(self) -> tuple[np.ndarray, np.ndarray, float]:
        """``(rotvec, t, scale)``; inverse of :meth:`from_rotvec`."""
        return Rotation.from_matrix(self.R).as_rotvec(), self.t.copy(), self.scale

    @classmethod
    def from_quat(cls, q_xyzw: np.ndarray, t: np.ndarray, scale: float = 1.0) -> Sim3:
        """From a unit quaternion ``(x, y, z, w)``, a translation and a scale."""
        return cls(Rotation.from_quat(np.asarray(q_xyzw, dtype=float).reshape(4)).as_matrix(), t, scale)

    def to_quat(self) -> tuple[np.ndarray, np.ndarray, float]:
        """``(q_xyzw with w >= 0, t, scale)``; inverse of :meth:`from_quat`."""
        q = Rotation.from_matrix(self.R).as_quat()
        return (-q if q[3] < 0 else q), self.t.copy(), self.scale

    # -- interpolation and distances
    def interpolate(self, other: Sim3, alpha: float) -> Sim3:
        """Similarity a fraction ``alpha`` in [0, 1] of the way to ``other``.

        Rotation by spherical interpolation, translation linearly, scale
        geometrically (like :func:`~fgcd_core.se3.interpolate_pose`).
        """
        a = float(alpha)
        R = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([self.R, other.R])))([a]).as_matrix()[0]
        t = (1.0 - a) * self.t + a * other.t
        scale = math.exp((1.0 - a) * math.log(self.scale) + a * math.log(other.scale))
        return Sim3(R, t, scale)

    def distance(self, other: Sim3) -> tuple[float, float, float]:
        """``(translation mm, rotation deg, scale ratio >= 1)`` between two similarities."""
        mm = float(np.linalg.norm(self.t - other.t) * 1000.0)
        deg = math.degrees(rotation_angle_rad(self.R.T @ other.R))
        ratio = max(self.scale, other.scale) / min(self.scale, other.scale)
        return mm, deg, ratio

    # -- Lie algebra
    @staticmethod
    def exp(xi: np.ndarray) -> Sim3:
        """Similarity of a tangent vector ``(rho (3), phi (3), lambda)``."""
        xi = np.asarray(xi, dtype=float).reshape(7)
        A = np.zeros((4, 4))
        A[:3, :3] = xi[6] * np.eye(3) + skew(xi[3:6])
        A[:3, 3] = xi[:3]
        return Sim3.from_matrix(expm(A))

    def log(self) -> np.ndarray:
        """Tangent vector ``(rho, phi, lambda)``; inverse of :meth:`exp`."""
        A = np.real(logm(self.matrix()))
        lam = float(np.trace(A[:3, :3]) / 3.0)
        W = A[:3, :3] - lam * np.eye(3)
        phi = np.array([W[2, 1] - W[1, 2], W[0, 2] - W[2, 0], W[1, 0] - W[0, 1]]) / 2.0
        return np.concatenate([A[:3, 3], phi, [lam]])

    # -- distances
    def rotation_deg(self) -> float:
        """Rotation angle of the similarity, degrees."""
        return math.degrees(rotation_angle_rad(self.R))

    def to_dict(self) -> dict:
        """JSON-friendly form."""
        return {"R": self.R.tolist(), "t": self.t.tolist(), "scale": self.scale}

    @classmethod
    def from_dict(cls, data: dict) -> Sim3:
        """Inverse of :meth:`to_dict`."""
        return cls(np.array(data["R"]), np.array(data["t"]), float(data["scale"]))


def umeyama(src: np.ndarray, dst: np.ndarray, *, with_scale: bool = True, weights: np.ndarray | None = None) -> Sim3:
    """Least-squares similarity mapping ``src`` onto ``dst`` (Umeyama 1991).

    Parameters
    ----------
    src, dst : (N, 3) ndarray
        Corresponding points, N >= 3 and not collinear.
    with_scale : bool
        Estimate the scale; otherwise return a rigid transform (scale 1).
    weights : (N,) ndarray, optional
        Non-negative weights per correspondence.

    Returns
    -------
    Sim3
        ``T`` minimising ``sum w_i |dst_i - T(src_i)|^2``.
    """
    src = np.asarray(src, dtype=float)
    dst = np.asarray(dst, dtype=float)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or src.shape[0] < 3:
        raise ValueError("umeyama needs two (N, 3) arrays with N >= 3")
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=float)
    w = w / w.sum()
    mu_s = w @ src
    mu_d = w @ dst
    xs = src - mu_s
    xd = dst - mu_d
    cov = (xd * w[:, None]).T @ xs
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    var_s = float(w @ np.sum(xs**2, axis=1))
    if with_scale:
        if var_s <= 0:
            raise ValueError("umeyama: source points have no spread")
        scale = float(np.sum(D * np.diag(S)) / var_s)
    else:
        scale = 1.0
    t = mu_d - scale * R @ mu_s
    return Sim3(R, t, scale)
