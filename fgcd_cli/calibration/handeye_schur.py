"""Normal equations of the hand-eye adjustment with the landmarks eliminated (Schur complement).

The parameters of the hand-eye (6, or 7 with the rotation scale) couple with
every landmark; each landmark (3) couples only with them. Eliminating the
landmark blocks leaves a 6x6 (7x7) reduced system
``S = H_xx - sum_j H_xj H_jj^-1 H_jx`` (Triggs et al., "Bundle adjustment, a
modern synthesis", §6.1), whose inverse is the marginal covariance of the
hand-eye parameters up to the residual variance.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix

__all__ = ["point_sums", "normal_equations", "reduced_system"]


def point_sums(obs_pt: np.ndarray, n_points: int) -> csr_matrix:
    """Sparse ``(L, M)`` matrix summing per-observation values into their landmark."""
    return csr_matrix((np.ones(len(obs_pt)), (obs_pt, np.arange(len(obs_pt)))), shape=(n_points, len(obs_pt)))


def normal_equations(r: np.ndarray, A: np.ndarray, B: np.ndarray, w: np.ndarray, G: csr_matrix):
    """Weighted normal equations split into blocks.

    Parameters
    ----------
    r : (M, 2) ndarray
        Residuals, pixels.
    A : (M, 2, p) ndarray
        Jacobian of the residuals with respect to the hand-eye parameters.
    B : (M, 2, 3) ndarray
        Jacobian with respect to each observation's landmark.
    w : (M,) ndarray
        Weight of each observation (Huber IRLS; ones for the covariance).
    G : (L, M) sparse matrix
        :func:`point_sums`.

    Returns
    -------
    Hxx (p, p), gx (p,), Hxp (L, p, 3), Hpp (L, 3, 3), gp (L, 3)
    """
    npar = A.shape[2]
    m, n_obs = G.shape
    Aw = A * w[:, None, None]
    At = np.transpose(Aw, (0, 2, 1))
    Hxx = Aw.reshape(-1, npar).T @ A.reshape(-1, npar)
    gx = Aw.reshape(-1, npar).T @ r.reshape(-1)
    Hxp = (G @ np.matmul(At, B).reshape(n_obs, 3 * npar)).reshape(m, npar, 3)
    Bw = B * w[:, None, None]
    Bt = np.transpose(Bw, (0, 2, 1))
    Hpp = (G @ np.matmul(Bt, B).reshape(n_obs, 9)).reshape(m, 3, 3)
    gp = G @ np.matmul(Bt, r[:, :, None]).reshape(n_obs, 3)
    return Hxx, gx, Hxp, Hpp, gp


def reduced_system(Hxx: np.ndarray, Hxp: np.ndarray, Hpp: np.ndarray, lam: float):
    """The Schur complement ``S`` (damped by ``lam``), the damped landmark block inverses and ``H_xp H_pp^-1``."""
    npar = Hxx.shape[0]
    # a point seen only from one camera centre (a pure rotation) has no depth information:
    # a tiny relative damping keeps its block invertible
    eps = 1e-9 * np.trace(Hpp, axis1=1, axis2=2)[:, None, None] + 1e-12
    Hpp_inv = np.linalg.inv(Hpp + (lam + eps) * np.eye(3))
    HxpHinv = np.matmul(Hxp, Hpp_inv)  # (m, npar, 3)
    S = Hxx + lam * np.eye(npar) - np.einsum("mij,mkj->ik", HxpHinv, Hxp, optimize=True)
    return S, Hpp_inv, HxpHinv
