"""Normal equations of camera-block + point-block problems and their Schur-complement solve.

The one reduced solve of fgcd's bundle adjustments: the VSE windowed bundle
adjustment (``C`` cameras of 6 parameters) and the target-free hand-eye
adjustment (one block of 6 or 7 parameters seen by every observation, ``C = 1``).
Residual ``k`` (2 rows) depends on one camera block ``c_k`` and one point
``p_k``; with the point blocks ``H_pp`` eliminated, the cameras solve the reduced
system ``S = H_cc - H_cp H_pp^-1 H_pc`` (Triggs et al., "Bundle adjustment, a
modern synthesis", §6.1), and each point follows by back-substitution. ``S``
undamped is the inverse marginal covariance of the camera parameters up to the
residual variance.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from scipy.sparse import csr_matrix

__all__ = [
    "Damping",
    "SchurDamping",
    "BlockNormalEquations",
    "block_normal_equations",
    "schur_step",
    "reduced_camera_system",
]


class Damping(StrEnum):
    """How the damping ``lambda`` enters a block's diagonal."""

    #: ``diag(H) (1 + lambda)`` (Marquardt: scale-invariant per parameter)
    MARQUARDT = "marquardt"
    #: ``diag(H) + lambda`` (Levenberg)
    LEVENBERG = "levenberg"


@dataclass(frozen=True, kw_only=True)
class SchurDamping:
    """Damping of the camera and point blocks before the elimination.

    Attributes
    ----------
    rule : Damping
        How ``lambda`` enters the diagonals.
    camera_floor : float
        Added to every camera-block diagonal.
    point_floor : float
        Added to every point-block diagonal.
    point_floor_relative : float
        Plus this times the point block's trace: a point seen from a single
        camera centre (pure rotation) carries no depth information and would
        leave its block singular.
    """

    rule: Damping = Damping.MARQUARDT
    camera_floor: float = 0.0
    point_floor: float = 0.0
    point_floor_relative: float = 0.0


@dataclass(frozen=True, kw_only=True)
class BlockNormalEquations:
    """Weighted Gauss-Newton normal equations ``J^T W J delta = -J^T W r`` split into blocks.

    Attributes
    ----------
    Hcc : (C, k, k) ndarray
        Camera blocks.
    Hpp : (P, 3, 3) ndarray
        Point blocks.
    Hcp : (P, C, k, 3) ndarray
        Camera-point coupling.
    bc : (C, k) ndarray
        Camera part of ``-J^T W r``.
    bp : (P, 3) ndarray
        Point part of ``-J^T W r``.
    """

    Hcc: np.ndarray
    Hpp: np.ndarray
    Hcp: np.ndarray
    bc: np.ndarray
    bp: np.ndarray


def _sum_into(index: np.ndarray, n_rows: int, values: np.ndarray) -> np.ndarray:
    """``out[i] = sum of values[m] with index[m] == i`` (in observation order), shape ``(n_rows,) + values.shape[1:]``."""
    n = len(index)
    G = csr_matrix((np.ones(n), (index, np.arange(n))), shape=(n_rows, n))
    return (G @ values.reshape(n, -1)).reshape((n_rows,) + values.shape[1:])


def block_normal_equations(
    r: np.ndarray,
    Jc: np.ndarray,
    Jp: np.ndarray,
    w: np.ndarray,
    obs_cam: np.ndarray,
    obs_pt: np.ndarray,
    *,
    n_cameras: int,
    n_points: int,
) -> BlockNormalEquations:
    """Accumulate the weighted normal equations of ``M`` residual blocks.

    Parameters
    ----------
    r : (M, 2) ndarray
        Residuals.
    Jc : (M, 2, k) ndarray
        Jacobian of each residual with respect to its camera block (zero rows for fixed cameras).
    Jp : (M, 2, 3) ndarray
        Jacobian with respect to its point.
    w : (M,) ndarray
        Weight of each residual block (Huber IRLS; ones for the covariance).
    obs_cam, obs_pt : (M,) int ndarrays
        Camera and point index of each residual.
    n_cameras, n_points : int
        ``C`` and ``P``.

    Returns
    -------
    BlockNormalEquations
    """
    wJcT = np.transpose(Jc * w[:, None, None], (0, 2, 1))  # (M, k, 2)
    wJpT = np.transpose(Jp * w[:, None, None], (0, 2, 1))  # (M, 3, 2)
    pair = obs_pt * n_cameras + obs_cam
    Hcp = _sum_into(pair, n_points * n_cameras, np.matmul(wJcT, Jp))
    return BlockNormalEquations(
        Hcc=_sum_into(obs_cam, n_cameras, np.matmul(wJcT, Jc)),
        Hpp=_sum_into(obs_pt, n_points, np.matmul(wJpT, Jp)),
        Hcp=Hcp.reshape(n_points, n_cameras, Jc.shape[2], 3),
        bc=_sum_into(obs_cam, n_cameras, -np.matmul(wJcT, r[:, :, None])[:, :, 0]),
        bp=_sum_into(obs_pt, n_points, -np.matmul(wJpT, r[:, :, None])[:, :, 0]),
    )


def _damped_diagonal(H: np.ndarray, lam: float, extra: np.ndarray | float, rule: Damping) -> np.ndarray:
    """``H`` (N, d, d) with its diagonals damped by ``rule`` and raised by ``extra``."""
    out = H.copy()
    idx = np.arange(H.shape[1])
    diag = H[:, idx, idx]
    if rule is Damping.MARQUARDT:
        out[:, idx, idx] = diag * (1.0 + lam) + extra
    else:
        out[:, idx, idx] = diag + (lam + extra)
    return out


def reduced_camera_system(
    eq: BlockNormalEquations, lam: float, damping: SchurDamping, free: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The damped reduced system of the cameras.

    Parameters
    ----------
    eq : BlockNormalEquations
        The normal equations.
    lam : float
        Damping (0: the undamped system, e.g. for a covariance).
    damping : SchurDamping
        How ``lam`` and the floors enter.
    free : (C,) bool ndarray, optional
        Cameras that move; the others get an identity block and a zero right-hand side.

    Returns
    -------
    S : (C k, C k) ndarray
        Reduced matrix ``H_cc - H_cp H_pp^-1 H_pc`` (damped).
    rhs : (C k,) ndarray
        Reduced right-hand side ``b_c - H_cp H_pp^-1 b_p``.
    Hpp_inv : (P, 3, 3) ndarray
        Damped point block inverses.
    E : (P, C, k, 3) ndarray
        ``H_cp H_pp^-1``.
    """
    C, k = eq.bc.shape
    Hcc_d = _damped_diagonal(eq.Hcc, lam, damping.camera_floor, damping.rule)
    point_extra = damping.point_floor_relative * np.trace(eq.Hpp, axis1=1, axis2=2)[:, None] + damping.point_floor
    Hpp_inv = np.linalg.inv(_damped_diagonal(eq.Hpp, lam, point_extra, damping.rule))
    if free is not None:
        Hcc_d[~free] = np.eye(k)
    E = np.matmul(eq.Hcp, Hpp_inv[:, None])
    S = np.zeros((C, k, C, k))
    S[np.arange(C), :, np.arange(C), :] = Hcc_d
    S -= np.einsum("pcij,pdkj->cidk", E, eq.Hcp, optimize=True)
    rhs = eq.bc - np.einsum("pcij,pj->ci", E, eq.bp, optimize=True)
    if free is not None:
        rhs[~free] = 0.0
    return S.reshape(C * k, C * k), rhs.reshape(-1), Hpp_inv, E


def schur_step(
    eq: BlockNormalEquations, lam: float, damping: SchurDamping, free: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray] | None:
    """Camera and point steps of the damped normal equations, points eliminated.

    Parameters
    ----------
    eq, lam, damping, free
        As :func:`reduced_camera_system`.

    Returns
    -------
    dc : (C, k) ndarray
        Camera steps (zero for fixed cameras).
    dp : (P, 3) ndarray
        Point steps.
    None
        When a damped point block is singular.
    """
    C, k = eq.bc.shape
    try:
        S, rhs, Hpp_inv, _E = reduced_camera_system(eq, lam, damping, free)
    except np.linalg.LinAlgError:
        return None
    try:
        dc = np.linalg.solve(S, rhs).reshape(C, k)
    except np.linalg.LinAlgError:
        dc = np.linalg.lstsq(S, rhs, rcond=None)[0].reshape(C, k)
    if free is not None:
        dc[~free] = 0.0
    dp = np.matmul(Hpp_inv, (eq.bp - np.einsum("pcji,cj->pi", eq.Hcp, dc, optimize=True))[:, :, None])[:, :, 0]
    return dc, dp
