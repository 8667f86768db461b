"""Levenberg-Marquardt over the hand-eye model with the landmarks eliminated (Schur complement).

The problem of :func:`lm_handeye` runs on fgcd's one damped least-squares driver
(:mod:`fgcd_core.lm`) and its one Schur-complement solve (:mod:`fgcd_core.schur`):
a single camera block (the hand-eye's 6 parameters, 7 with the rotation scale)
that every observation sees, and one 3-vector block per landmark, so each step
solves a 6x6 (7x7) reduced system. Huber IRLS on the norm of each observation's
reprojection error.

Why not :func:`scipy.optimize.least_squares`: with the same model and an
analytic sparse Jacobian ('trf', ``x_scale='jac'``), its sparse trust-region
steps (LSMR, no Schur elimination) reach this solver's hand-eye only with a
tight LSMR tolerance, several times to fifty times slower; with LSMR's default
tolerance it stops short of the minimum by millimetres (measurements in
docs/lab/2026-11-25-code-comment-measurements.md, "Calibration", solver).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from fgcd_cli.calibration.handeye.model import HandPoses, Observations, linearise
from fgcd_core.lm import LMSchedule, huber_cost, huber_weights, levenberg_marquardt
from fgcd_core.schur import (
    BlockNormalEquations,
    Damping,
    SchurDamping,
    block_normal_equations,
    reduced_camera_system,
    schur_step,
)
from fgcd_core.se3 import exp_se3

__all__ = ["lm_handeye", "Adjusted"]

#: Levenberg damping (``+ lambda I``); the landmark blocks get a tiny relative floor, as a
#: point seen only from one camera centre (a pure rotation) has no depth information
_DAMPING = SchurDamping(rule=Damping.LEVENBERG, point_floor=1e-12, point_floor_relative=1e-9)
#: lambda / 3 after a success, x 10 after a failure, at most 8 tries per linearisation
_SCHEDULE = LMSchedule(
    initial_damping=1e-3,
    decrease=3.0,
    min_damping=1e-9,
    increase=10.0,
    max_damping=np.inf,
    max_rejections=8,
    relative_decrease=1e-10,
    min_step=1e-10,
)


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


class _HandEyeState(NamedTuple):
    """Hand-eye, landmarks, rotation scale, and the residuals and Jacobians there."""

    X: np.ndarray
    P: np.ndarray
    scale: float
    r: np.ndarray
    A: np.ndarray
    B: np.ndarray


@dataclass(frozen=True, kw_only=True)
class _HandEyeProblem:
    """The hand-eye adjustment as a :class:`fgcd_core.lm.LeastSquaresProblem`; the hand-eye is camera block 0."""

    hand: HandPoses
    K: np.ndarray
    obs: Observations
    with_scale: bool
    huber_px: float

    def state(self, X: np.ndarray, P: np.ndarray, scale: float) -> _HandEyeState:
        r, A, B = linearise(self.hand, self.K, X, P, self.obs, scale, with_scale=self.with_scale)
        return _HandEyeState(X, P, scale, r, A, B)

    def normal_equations(self, s: _HandEyeState, w: np.ndarray) -> BlockNormalEquations:
        return block_normal_equations(
            s.r, s.A, s.B, w, np.zeros(len(w), dtype=np.int64), self.obs.pt, n_cameras=1, n_points=len(s.P)
        )

    def cost(self, s: _HandEyeState) -> float:
        return huber_cost(np.linalg.norm(s.r, axis=1), self.huber_px)

    def linearise(self, s: _HandEyeState) -> BlockNormalEquations:
        return self.normal_equations(s, huber_weights(np.linalg.norm(s.r, axis=1), self.huber_px))

    def step(self, eq: BlockNormalEquations, lam: float):
        return schur_step(eq, lam, _DAMPING)

    def apply(self, s: _HandEyeState, step) -> _HandEyeState:
        dx = step[0][0]
        scale = s.scale + float(dx[6]) if self.with_scale else s.scale
        return self.state(s.X @ exp_se3(dx[:6]), s.P + step[1], scale)

    def step_size(self, step) -> float:
        return float(np.linalg.norm(step[0]))


def lm_handeye(
    hand: HandPoses,
    K: np.ndarray,
    X: np.ndarray,
    P: np.ndarray,
    obs: Observations,
    *,
    rotation_scale: float | None = None,
    iterations: int = 40,
    huber_px: float = 1.0,
) -> Adjusted:
    """Levenberg-Marquardt over ``X`` (right perturbation ``X exp(d)``), the landmarks and, if
    ``rotation_scale`` is given (its start value), the platform's rotation scale.

    Returns
    -------
    Adjusted
    """
    with_scale = rotation_scale is not None
    problem = _HandEyeProblem(hand=hand, K=K, obs=obs, with_scale=with_scale, huber_px=huber_px)
    start = problem.state(X, P, float(rotation_scale) if with_scale else 1.0)
    s = levenberg_marquardt(problem, start, replace(_SCHEDULE, max_iterations=iterations)).state
    S, _rhs, _Hpp_inv, _E = reduced_camera_system(problem.normal_equations(s, np.ones(len(obs.cam))), 0.0, _DAMPING)
    return Adjusted(s.X, s.P, s.scale, S)
