"""The residual model of the target-free hand-eye refinement (structure from known motion).

The platform's reported flange poses are metric and accurate to a fraction of a
millimetre, so the camera pose of view ``i`` is ``T_base_flange_i @ X`` and the
unknowns are ``X = T_flange_cam``, the scene points (landmarks, base frame,
metres) and, when the platform turned, the scale of its rotations
(:class:`HandPoses`). A residual is the reprojection error of one observation,
pixels (hand-eye by structure from motion: Andreff, Horaud and Espiau 2001;
docs/calibration.md, "Target-free").

Parameterisation: ``X`` is perturbed on the right, ``X exp(d)`` with
``d = (rho, phi)`` (translation first, :func:`fgcd_core.se3.exp_se3`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fgcd_cli.calibration.errors import CalibrationError
from fgcd_cli.calibration.handeye.tracks import triangulate_dlt
from fgcd_core.camera import MIN_DEPTH_M, pinhole_pixels
from fgcd_core.se3 import exp_so3, invert_pose, log_so3, make_pose, transform_each

__all__ = ["HandPoses", "Observations", "residuals", "linearise", "initial_landmarks", "INIT_MAX_PX"]

#: A triangulated track whose initial reprojection error exceeds this (pixels) is left out.
INIT_MAX_PX = 8.0


class HandPoses:
    """Reported flange poses, optionally with the platform's rotations scaled by ``s``.

    With ``s`` the flange orientation of view ``i`` is ``R_0 exp(s log(R_0^T R_i))``
    (rotations about the first view's orientation scaled by ``s``; positions as
    reported): a rotary stage or arm whose rotations are a fraction of a percent
    longer or shorter than it reports. The images measure the camera's rotations
    far better than that; left unmodelled, a rotation scale error of about a
    tenth of a percent biases ``t_X`` by millimetres (docs/calibration.md,
    "Target-free").

    Attributes
    ----------
    T : (N, 4, 4) ndarray
        Reported flange poses, metres.
    R0 : (3, 3) ndarray
        Orientation of the first view.
    phi : (N, 3) ndarray
        Rotation vector of each view relative to the first, radians.
    """

    def __init__(self, T_base_flange: np.ndarray):
        self.T = np.asarray(T_base_flange, dtype=float)
        R0 = self.T[0, :3, :3]
        self.R0 = R0
        self.phi = np.stack([log_so3(R0.T @ T[:3, :3]) for T in self.T])  # (N, 3) rad

    def inv(self, scale: float) -> np.ndarray:
        """``inv(T_base_flange)`` of every view with the rotations scaled by ``scale``, ``(N, 4, 4)``."""
        if scale == 1.0:
            return np.stack([invert_pose(T) for T in self.T])
        out = np.empty_like(self.T)
        for i, T in enumerate(self.T):
            R = self.R0 @ exp_so3(scale * self.phi[i])
            out[i] = invert_pose(make_pose(R, T[:3, 3]))
        return out


@dataclass(frozen=True)
class Observations:
    """Image observations of the landmarks.

    Attributes
    ----------
    cam : (M,) int ndarray
        View of each observation.
    pt : (M,) int ndarray
        Landmark of each observation.
    uv : (M, 2) ndarray
        Undistorted pixel of each observation.
    """

    cam: np.ndarray
    pt: np.ndarray
    uv: np.ndarray

    def subset(self, keep: np.ndarray, remap: np.ndarray) -> Observations:
        """The observations ``keep`` (bool mask), with landmark indices renumbered by ``remap``."""
        return Observations(self.cam[keep], remap[self.pt[keep]], self.uv[keep])


def residuals(inv_hand: np.ndarray, K: np.ndarray, X: np.ndarray, P: np.ndarray, obs: Observations) -> np.ndarray:
    """Reprojection residuals ``(M, 2)``, pixels, with camera poses ``inv(X) @ inv(T_base_flange)``."""
    T_cam_base = np.einsum("ij,mjk->mik", invert_pose(X), inv_hand)
    return pinhole_pixels(K, transform_each(T_cam_base[obs.cam], P[obs.pt])) - obs.uv


def linearise(
    hand: HandPoses, K: np.ndarray, X: np.ndarray, P: np.ndarray, obs: Observations, scale: float, *, with_scale: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals and their Jacobians at ``(X, P, scale)``.

    Returns
    -------
    r : (M, 2) ndarray
        Reprojection residuals, pixels.
    A : (M, 2, 6) or (M, 2, 7) ndarray
        Jacobian with respect to the right perturbation ``d`` of ``X`` (and the rotation scale).
    B : (M, 2, 3) ndarray
        Jacobian with respect to each observation's landmark.
    """
    oc, op, ouv = obs.cam, obs.pt, obs.uv
    fx, fy = K[0, 0], K[1, 1]
    Xi = invert_pose(X)
    T_cam_base = np.einsum("ij,mjk->mik", Xi, hand.inv(scale))
    R = T_cam_base[oc, :3, :3]
    pc = transform_each(T_cam_base[oc], P[op])
    r = pinhole_pixels(K, pc) - ouv
    z = np.where(np.abs(pc[:, 2]) < MIN_DEPTH_M, MIN_DEPTH_M, pc[:, 2])
    Jp = np.zeros((len(oc), 2, 3))
    Jp[:, 0, 0] = fx / z
    Jp[:, 0, 2] = -fx * pc[:, 0] / z**2
    Jp[:, 1, 1] = fy / z
    Jp[:, 1, 2] = -fy * pc[:, 1] / z**2
    # camera-frame point q = exp(-d) inv(X) p_flange: dq/drho = -I, dq/dphi = [q]x
    qx = np.zeros((len(oc), 3, 3))
    qx[:, 0, 1], qx[:, 0, 2] = -pc[:, 2], pc[:, 1]
    qx[:, 1, 0], qx[:, 1, 2] = pc[:, 2], -pc[:, 0]
    qx[:, 2, 0], qx[:, 2, 1] = -pc[:, 1], pc[:, 0]
    A = np.concatenate([-Jp, np.einsum("mij,mjk->mik", Jp, qx)], axis=2)  # (M, 2, 6)
    if with_scale:
        # ds turns flange i by phi_i ds about its own origin (right perturbation, flange frame);
        # seen from the camera that is the twist Ad(inv(X)) (0, phi_i) ds
        Rx, tx = X[:3, :3], X[:3, 3]
        ang = hand.phi @ Rx  # rows: R_X^T phi_i
        lin = -np.cross(tx @ Rx, ang)  # rows: -[R_X^T t_X]x R_X^T phi_i
        twist = np.concatenate([lin, ang], axis=1)[oc]  # (M, 6)
        A = np.concatenate([A, np.einsum("mij,mj->mi", A, twist)[:, :, None]], axis=2)
    B = np.einsum("mij,mjk->mik", Jp, R)  # (M, 2, 3)
    return r, A, B


def initial_landmarks(
    T_base_flange: Sequence[np.ndarray],
    tracks: Sequence[Sequence[tuple[int, Sequence[float]]]],
    K: np.ndarray,
    X0: np.ndarray,
) -> tuple[np.ndarray, Observations]:
    """Landmarks triangulated (DLT) with the initial hand-eye ``X0``, and their observations.

    A track is left out when its point is at infinity, behind a camera, or
    reprojects more than :data:`INIT_MAX_PX` from one of its observations.

    Returns
    -------
    P : (L, 3) ndarray
        Landmarks in the base frame, metres.
    obs : Observations

    Raises
    ------
    CalibrationError
        A track refers to a view that does not exist.
    """
    n = len(T_base_flange)
    cams0 = np.stack([invert_pose(np.asarray(T, dtype=float) @ X0) for T in T_base_flange])
    Pmats = [K @ T[:3, :] for T in cams0]
    pts, obs_cam, obs_pt, obs_uv = [], [], [], []
    for members in tracks:
        if len(members) < 2:
            continue
        uv = [np.asarray(m[1], dtype=float) for m in members]
        cam_idx = np.array([int(m[0]) for m in members])
        if np.any(cam_idx < 0) or np.any(cam_idx >= n):
            raise CalibrationError(f"a feature track refers to stop {cam_idx.max()} of {n}")
        P = triangulate_dlt([Pmats[i] for i in cam_idx], uv)
        if not np.all(np.isfinite(P)):
            continue
        pc = transform_each(cams0[cam_idx], np.repeat(P[None], len(members), axis=0))
        proj, z = pinhole_pixels(K, pc), pc[:, 2]
        if np.any(z <= 0) or np.max(np.linalg.norm(proj - np.asarray(uv), axis=1)) > INIT_MAX_PX:
            continue
        j = len(pts)
        pts.append(P)
        obs_cam.extend(cam_idx.tolist())
        obs_pt.extend([j] * len(members))
        obs_uv.extend(uv)
    obs = Observations(
        np.asarray(obs_cam, dtype=int), np.asarray(obs_pt, dtype=int), np.asarray(obs_uv, dtype=float).reshape(-1, 2)
    )
    return np.asarray(pts, dtype=float).reshape(-1, 3), obs
