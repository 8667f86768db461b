"""Levenberg-Marquardt over the hand-eye model with the landmarks eliminated (Schur complement).

Huber IRLS on the norm of each observation's reprojection error; the landmark
blocks are eliminated (:mod:`fgcd_cli.calibration.handeye_schur`), so each step
solves a 6x6 (7x7) system.

Why not :func:`scipy.optimize.least_squares`: with the same model and an
analytic sparse Jacobian ('trf', ``x_scale='jac'``), its sparse trust-region
steps (LSMR, no Schur elimination) reach this solver's hand-eye only with a
tight LSMR tolerance, several times to fifty times slower; with LSMR's default
tolerance it stops short of the minimum by millimetres (measurements in
docs/benchmarks.md, "Calibration").
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fgcd_cli.calibration.handeye_model import HandPoses, Observations, huber_cost, linearise
from fgcd_cli.calibration.handeye_schur import normal_equations, point_sums, reduced_system
from fgcd_core.se3 import exp_se3

__all__ = ["lm_handeye", "Adjusted"]


class Adjusted(NamedTuple):
    """The adjusted hand-eye model.

    Attributes
    ----------
    X : (4, 4) ndarray
        Hand-eye ``T_flange_cam``.
    P : (L, 3) ndarray
        Landmarks, base frame, metres.
    rotation_scale : float
        The platform's rotation scale (1.0 when not estimated).
    S : (p, p) ndarray
        The reduced normal matrix of the hand-eye parameters (undamped, without the
        Huber weights) for the covariance.
    """

    X: np.ndarray
    P: np.ndarray
    rotation_scale: float
    S: np.ndarray


def lm_handeye(hand: HandPoses, K: np.ndarray, X: np.ndarray, P: np.ndarray, obs: Observations, *,
               rotation_scale: float | None = None, iterations: int = 40, huber_px: float = 1.0) -> Adjusted:
    """Levenberg-Marquardt over ``X`` (right perturbation ``X exp(d)``), the landmarks and, if
    ``rotation_scale`` is given (its start value), the platform's rotation scale.

    Returns
    -------
    Adjusted
    """
    with_scale = rotation_scale is not None
    scale = float(rotation_scale) if with_scale else 1.0
    G = point_sums(obs.pt, len(P))
    lam = 1e-3
    r, A, B = linearise(hand, K, X, P, obs, scale, with_scale=with_scale)
    cost = huber_cost(r, huber_px)
    for _ in range(iterations):
        e = np.linalg.norm(r, axis=1)
        w = np.where(e <= huber_px, 1.0, huber_px / np.maximum(e, 1e-12))
        Hxx, gx, Hxp, Hpp, gp = normal_equations(r, A, B, w, G)
        improved = converged = False
        for _try in range(8):
            S, Hpp_inv, HxpHinv = reduced_system(Hxx, Hxp, Hpp, lam)
            bx = gx - np.einsum("mij,mj->i", HxpHinv, gp, optimize=True)
            try:
                dx = np.linalg.solve(S, -bx)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            dp = -np.matmul(Hpp_inv, (gp + np.einsum("mji,j->mi", Hxp, dx))[:, :, None])[:, :, 0]
            X_new = X @ exp_se3(dx[:6])
            s_new = scale + float(dx[6]) if with_scale else scale
            P_new = P + dp
            r_new, A_new, B_new = linearise(hand, K, X_new, P_new, obs, s_new, with_scale=with_scale)
            c_new = huber_cost(r_new, huber_px)
            if c_new < cost:
                X, P, scale, r, A, B = X_new, P_new, s_new, r_new, A_new, B_new
                converged = cost - c_new < 1e-10 * cost or float(np.linalg.norm(dx)) < 1e-10
                cost = c_new
                lam = max(lam / 3.0, 1e-9)
                improved = True
                break
            lam *= 10.0
        if not improved or converged:
            break
    Hxx, _gx, Hxp, Hpp, _gp = normal_equations(r, A, B, np.ones(len(obs.cam)), G)
    S, _, _ = reduced_system(Hxx, Hxp, Hpp, 0.0)
    return Adjusted(X, P, scale, S)
