"""The one Levenberg-Marquardt driver (fgcd_core.lm) and the one Schur-complement solve (fgcd_core.schur).

Known answers: the Schur solve of a random camera-block + point-block system
equals the dense solve of the same damped normal equations; the driver reaches
the known minimum of a curve fit and obeys its stop rules.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from fgcd_core.lm import LMSchedule, huber_cost, huber_rho, huber_weights, levenberg_marquardt
from fgcd_core.schur import Damping, SchurDamping, block_normal_equations, reduced_camera_system, schur_step


def _random_blocks(rng, *, C=4, P=30, k=6, per_point=3):
    obs_pt = np.repeat(np.arange(P), per_point)
    obs_cam = np.concatenate([rng.choice(C, per_point, replace=C < per_point) for _ in range(P)])
    M = len(obs_pt)
    return (
        rng.normal(size=(M, 2)),
        rng.normal(size=(M, 2, k)),
        rng.normal(size=(M, 2, 3)),
        rng.uniform(0.2, 1.0, M),
        obs_cam,
        obs_pt,
        C,
        P,
        k,
    )


def _dense(r, Jc, Jp, w, obs_cam, obs_pt, C, P, k):
    """The full Jacobian ``(2M, C k + 3 P)`` and residual vector."""
    M = len(r)
    J = np.zeros((2 * M, C * k + 3 * P))
    for m in range(M):
        J[2 * m : 2 * m + 2, k * obs_cam[m] : k * obs_cam[m] + k] = Jc[m]
        J[2 * m : 2 * m + 2, C * k + 3 * obs_pt[m] : C * k + 3 * obs_pt[m] + 3] = Jp[m]
    W = np.repeat(w, 2)
    return J.T @ (W[:, None] * J), -J.T @ (W * r.reshape(-1))


@pytest.mark.parametrize("rule", list(Damping))
def test_schur_step_equals_the_dense_solve_of_the_damped_normal_equations(rule):
    rng = np.random.default_rng(0)
    r, Jc, Jp, w, obs_cam, obs_pt, C, P, k = _random_blocks(rng)
    eq = block_normal_equations(r, Jc, Jp, w, obs_cam, obs_pt, n_cameras=C, n_points=P)
    H, b = _dense(r, Jc, Jp, w, obs_cam, obs_pt, C, P, k)
    lam = 0.3
    damping = SchurDamping(rule=rule, camera_floor=1e-3, point_floor=2e-3, point_floor_relative=1e-4)
    Hd = H.copy()
    d = np.diag(H).copy()
    traces = np.array(
        [np.trace(H[C * k + 3 * p : C * k + 3 * p + 3, C * k + 3 * p : C * k + 3 * p + 3]) for p in range(P)]
    )
    extra = np.r_[np.full(C * k, 1e-3), np.repeat(1e-4 * traces + 2e-3, 3)]
    Hd[np.diag_indices_from(H)] = d * (1 + lam) + extra if rule is Damping.MARQUARDT else d + lam + extra
    dense = np.linalg.solve(Hd, b)
    dc, dp = schur_step(eq, lam, damping)
    np.testing.assert_allclose(np.r_[dc.ravel(), dp.ravel()], dense, rtol=0, atol=1e-9 * np.abs(dense).max())


def test_reduced_system_undamped_is_the_marginal_information_of_the_cameras():
    rng = np.random.default_rng(1)
    r, Jc, Jp, w, obs_cam, obs_pt, C, P, k = _random_blocks(rng, C=1, k=7, per_point=4)
    obs_cam[:] = 0
    H, _b = _dense(r, Jc, Jp, w, obs_cam, obs_pt, C, P, k)
    eq = block_normal_equations(r, Jc, Jp, w, obs_cam, obs_pt, n_cameras=C, n_points=P)
    S, *_ = reduced_camera_system(eq, 0.0, SchurDamping(rule=Damping.LEVENBERG))
    # inverse of the camera block of H^-1 = Schur complement (Triggs et al. §6.1)
    np.testing.assert_allclose(np.linalg.inv(np.linalg.inv(H)[:k, :k]), S, rtol=1e-8, atol=1e-8)


def test_fixed_cameras_do_not_move():
    rng = np.random.default_rng(2)
    r, Jc, Jp, w, obs_cam, obs_pt, C, P, k = _random_blocks(rng)
    free = np.array([False, True, True, False])
    Jc[~free[obs_cam]] = 0.0
    eq = block_normal_equations(r, Jc, Jp, w, obs_cam, obs_pt, n_cameras=C, n_points=P)
    dc, _dp = schur_step(eq, 0.1, SchurDamping(), free)
    assert np.all(dc[~free] == 0.0) and np.all(np.abs(dc[free]) > 0)


@dataclass(frozen=True)
class _ExpFit:
    """Fit ``y = a exp(b x)``: a dense problem with the known minimum at the generating (a, b)."""

    x: np.ndarray
    y: np.ndarray

    def residual(self, p):
        return p[0] * np.exp(p[1] * self.x) - self.y

    def cost(self, p):
        return 0.5 * float(np.sum(self.residual(p) ** 2))

    def linearise(self, p):
        e = np.exp(p[1] * self.x)
        J = np.column_stack([e, p[0] * self.x * e])
        return J.T @ J, -J.T @ self.residual(p)

    def step(self, system, lam):
        H, b = system
        return np.linalg.solve(H + lam * np.diag(np.diag(H)), b)

    def apply(self, p, d):
        return p + d

    def step_size(self, d):
        return float(np.linalg.norm(d))


class _Uphill(_ExpFit):
    """Every step points up the cost."""

    def step(self, system, lam):
        return -super().step(system, lam)


def test_driver_reaches_the_known_minimum_from_far_away():
    x = np.linspace(0, 1, 40)
    problem = _ExpFit(x, 2.0 * np.exp(-1.5 * x))
    out = levenberg_marquardt(
        problem, np.array([0.5, 1.0]), LMSchedule(max_iterations=100, relative_decrease=1e-15, min_step=1e-12)
    )
    np.testing.assert_allclose(out.state, [2.0, -1.5], atol=1e-8)
    assert out.cost < 1e-16 and out.converged
    assert out.attempts >= out.iterations >= 2


def test_driver_stop_rules():
    x = np.linspace(0, 1, 40)
    problem = _ExpFit(x, 2.0 * np.exp(-1.5 * x))
    start = np.array([0.5, 1.0])
    capped = levenberg_marquardt(problem, start, LMSchedule(max_iterations=None, max_attempts=3))
    assert capped.attempts == 3 and not capped.converged
    one = levenberg_marquardt(problem, start, LMSchedule(max_iterations=1))
    assert one.iterations == 1 and one.cost < problem.cost(start)
    none = levenberg_marquardt(problem, start, LMSchedule(max_iterations=None, max_attempts=0))
    assert none.attempts == 0 and none.state is start
    # uphill steps are all rejected: lambda grows 1e-3 -> 1e3 > 1e2 in 6 tries (converged), or the rejection limit
    uphill = _Uphill(x, problem.y)
    ceiling = levenberg_marquardt(uphill, start, LMSchedule(max_damping=1e2, increase=10.0))
    assert ceiling.converged and ceiling.iterations == 1 and ceiling.attempts == 6 and ceiling.state is start
    rejected = levenberg_marquardt(uphill, start, LMSchedule(max_damping=np.inf, max_rejections=4))
    assert not rejected.converged and rejected.attempts == 4 and rejected.state is start


def test_huber_is_quadratic_then_linear_and_its_weights_match_its_derivative():
    n = np.array([0.0, 0.5, 1.0, 3.0])
    np.testing.assert_allclose(huber_rho(n, 1.0), [0.0, 0.125, 0.5, 2.5])
    np.testing.assert_allclose(huber_weights(n, 1.0), [1.0, 1.0, 1.0, 1 / 3])
    # IRLS weight = rho'(|r|) / |r|
    eps = 1e-6
    np.testing.assert_allclose(
        huber_weights(n[1:], 1.0) * n[1:],
        (huber_rho(n[1:] + eps, 1.0) - huber_rho(n[1:] - eps, 1.0)) / (2 * eps),
        rtol=1e-6,
    )
    assert huber_cost(n, 1.0) == pytest.approx(3.125)
