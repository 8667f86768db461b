"""Robust ICP steps: sparse ICP (Bouaziz, Tagliasacchi, Pauly, SGP 2013) in its
point-to-plane form, and the closed-form scale step.

The paper's Eq. (13) is solved with sparse ICP: minimise ``sum_i |z_i|^p``
(``p < 1``) subject to ``z_i = n_i . (y_i - q_i)`` by ADMM, which lets a minority
of correspondences (non-repeated points, outliers, the non-overlapping part)
keep large residuals without pulling the fit. The point-to-plane form is used
because point-to-point ICP slides very slowly along the nearly flat surfaces of
reliefs and murals (tens of iterations more from a few degrees off;
docs/lab/2026-11-25-code-comment-measurements.md, "Alignment"), which the 10 Hz target cannot afford. There
is no maintained PyPI package for sparse ICP and each
ADMM step is a shrink plus a 6x6 linear solve, so it is written here, with the
shrink operator of the authors' reference implementation.
"""

from __future__ import annotations

import numpy as np

from fgcd_core.se3 import exp_se3
from fgcd_core.sim3 import umeyama

__all__ = [
    "shrink",
    "shrink_threshold",
    "sparse_point_to_plane_step",
    "sparse_point_to_point_step",
    "trimmed_point_to_plane_step",
    "scale_step_point_to_plane",
    "gram",
]

#: ADMM penalty in the normalised units used by :func:`sparse_point_to_plane_step`.
DEFAULT_MU = 10.0


def shrink_threshold(mu: float, p: float) -> float:
    """Residual magnitude below which :func:`shrink` returns exactly zero (an inlier)."""
    ba = (2.0 / mu * (1.0 - p)) ** (1.0 / (2.0 - p))
    return ba + p / mu * ba ** (p - 1.0)


def shrink(h: np.ndarray, *, mu: float, p: float) -> np.ndarray:
    """Proximal operator of ``|z|^p`` with penalty ``mu``, for scalars (N,) or row vectors (N, k).

    Entries (rows) shorter than :func:`shrink_threshold` become zero; longer ones
    are scaled by ``beta`` solving ``beta = 1 - p/mu |h|^(p-2) beta^(p-1)`` (three
    fixed-point iterations from the authors' starting value, as in their code).
    """
    h = np.asarray(h, dtype=float)
    ba = (2.0 / mu * (1.0 - p)) ** (1.0 / (2.0 - p))
    ha = ba + p / mu * ba ** (p - 1.0)
    norm = np.abs(h) if h.ndim == 1 else np.linalg.norm(h, axis=1)
    beta = np.zeros_like(norm)
    big = norm > ha
    if np.any(big):
        n = norm[big]
        b = (ba / n + 1.0) / 2.0
        for _ in range(3):
            b = 1.0 - (p / mu) * n ** (p - 2.0) * b ** (p - 1.0)
        beta[big] = b
    return h * beta if h.ndim == 1 else h * beta[:, None]


def gram(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A.T @ B`` for tall, narrow matrices, without BLAS.

    OpenBLAS's threaded GEMM on these shapes slows down by orders of magnitude when
    the machine's cores are busy (docs/lab/2026-11-25-code-comment-measurements.md, "Alignment"); ``einsum``
    without BLAS takes a steady few milliseconds.
    """
    return np.einsum("ni,nj->ij", A, B, optimize=False)


def _solve_increment(yc: np.ndarray, n: np.ndarray, target: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted least squares for the se(3) increment ``(rho, phi)`` of ``n.(y + rho + phi x y) = target``."""
    J = np.column_stack([n, np.cross(yc, n)])
    r = target - np.sum(n * yc, axis=1)
    Jw = J * w[:, None]
    H = gram(Jw, J) + 1e-9 * np.eye(6)
    return np.linalg.solve(H, r @ Jw)


def sparse_point_to_plane_step(
    y: np.ndarray,
    q: np.ndarray,
    n: np.ndarray,
    *,
    inlier_distance: float,
    p: float = 0.4,
    mu: float = DEFAULT_MU,
    admm_iterations: int = 3,
    weights: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """ADMM iterations of point-to-plane sparse ICP for fixed correspondences.

    Parameters
    ----------
    y : (N, 3) ndarray
        Current points already mapped into the reference frame, metres.
    q, n : (N, 3) ndarray
        Corresponding reference points and their unit normals.
    inlier_distance : float
        Metres; the ADMM units are chosen so that :func:`shrink_threshold` equals
        this distance, i.e. residuals below it count as inliers.
    p : float
        Sparsity exponent in (0, 1].
    admm_iterations : int
        ADMM iterations, each one linearised 6-DoF solve.
    weights : (N,) ndarray, optional
        Per-point confidence (e.g. inverse depth variance).

    Returns
    -------
    dT : (4, 4) ndarray
        Rigid increment to apply on the left: ``y_new = dT (y)``.
    inlier : (N,) bool ndarray
        Correspondences whose sparse residual ``z`` is zero.
    """
    unit = inlier_distance / shrink_threshold(mu, p)
    c = y.mean(axis=0)
    yc = (y - c) / unit
    qc = (q - c) / unit
    w = np.ones(len(y)) if weights is None else np.asarray(weights, dtype=float)
    lam = np.zeros(len(y))
    z = np.zeros(len(y))
    T = np.eye(4)
    for _ in range(admm_iterations):
        delta = np.sum(n * (yc - qc), axis=1)
        z = shrink(delta + lam / mu, mu=mu, p=p)
        target = np.sum(n * qc, axis=1) + z - lam / mu
        dT = exp_se3(_solve_increment(yc, n, target, w))
        yc = yc @ dT[:3, :3].T + dT[:3, 3]
        T = dT @ T
        delta = np.sum(n * (yc - qc), axis=1)
        lam = lam + mu * (delta - z)
    # back to metres and to the uncentred frame: y -> c + unit * T((y - c) / unit)
    out = np.eye(4)
    out[:3, :3] = T[:3, :3]
    out[:3, 3] = c + unit * T[:3, 3] - T[:3, :3] @ c
    return out, z == 0.0


def sparse_point_to_point_step(
    y: np.ndarray,
    q: np.ndarray,
    *,
    inlier_distance: float,
    p: float = 0.4,
    mu: float = DEFAULT_MU,
    admm_iterations: int = 3,
    weights: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """ADMM iterations of point-to-point sparse ICP (the authors' original form).

    Slower to converge than :func:`sparse_point_to_plane_step` on smooth
    surfaces but with a wider basin; used on the coarsest level. Arguments and
    returns as there (``z`` is a 3-vector per correspondence).
    """
    unit = inlier_distance / shrink_threshold(mu, p)
    c = y.mean(axis=0)
    yc = (y - c) / unit
    qc = (q - c) / unit
    lam = np.zeros_like(yc)
    z = np.zeros_like(yc)
    T = np.eye(4)
    for _ in range(admm_iterations):
        z = shrink(yc - qc + lam / mu, mu=mu, p=p)
        fit = umeyama(yc, qc + z - lam / mu, with_scale=False, weights=weights)
        yc = yc @ fit.R.T + fit.t
        T = fit.rigid() @ T
        lam = lam + mu * (yc - qc - z)
    out = np.eye(4)
    out[:3, :3] = T[:3, :3]
    out[:3, 3] = c + unit * T[:3, 3] - T[:3, :3] @ c
    return out, ~np.any(z != 0.0, axis=1)


def trimmed_point_to_plane_step(y: np.ndarray, q: np.ndarray, n: np.ndarray, *, weights: np.ndarray) -> np.ndarray:
    """One weighted point-to-plane Gauss-Newton step (weights 0 drop outliers); returns the left increment."""
    c = y.mean(axis=0)
    dT = exp_se3(_solve_increment(y - c, n, np.sum(n * (q - c), axis=1), weights))
    out = dT.copy()
    out[:3, 3] = c + dT[:3, 3] - dT[:3, :3] @ c
    return out


def scale_step_point_to_plane(a: np.ndarray, q: np.ndarray, n: np.ndarray, w: np.ndarray) -> tuple[float, np.ndarray]:
    """Closed-form scale step (Eq. 15 in point-to-plane form) with the rotation fixed.

    Minimises ``sum_i w_i (n_i . (s a_i + t - q_i))^2`` over the scale ``s`` and
    translation ``t`` (linear least squares in 4 unknowns; the rotation is
    already applied: ``a_i = R x_i``).

    Returns
    -------
    scale : float
    t : (3,) ndarray
    """
    ca = (w @ a) / w.sum()
    ac = a - ca
    J = np.column_stack([np.sum(n * ac, axis=1), n])
    r = np.sum(n * q, axis=1)
    Jw = J * w[:, None]
    sol = np.linalg.solve(gram(Jw, J) + 1e-12 * np.eye(4), r @ Jw)
    s = float(sol[0])
    # y = s (a - ca) + t'  ->  t = t' - s ca
    return s, sol[1:] - s * ca
