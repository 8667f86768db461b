"""The fine alignment's dense least-squares steps on a subset of parameters, with an optional gauge penalty.

The fine alignment (Eqs. 16-18, docs/alignment.md, "Fine-grained alignment")
builds its normal equations with analytic Jacobians in the caller's ``evaluate``;
this module states them as a :class:`fgcd_core.lm.LeastSquaresProblem` with
Marquardt damping on the ``free`` parameters and runs fgcd's one
Levenberg-Marquardt driver (:func:`fgcd_core.lm.levenberg_marquardt`) on it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from fgcd_core.lm import LMSchedule, levenberg_marquardt

__all__ = ["minimise_subset"]

#: Every step tried counts against ``iterations``; lambda / 3 after a success, x 8 after a
#: failure; converged below a 1e-5 relative decrease or once lambda exceeds 1e6
_SCHEDULE = LMSchedule(
    initial_damping=1e-3,
    decrease=3.0,
    min_damping=1e-7,
    increase=8.0,
    max_damping=1e6,
    max_iterations=None,
    relative_decrease=1e-5,
)
#: Weight of the gauge penalty ``C^T C`` relative to the largest diagonal of the free block
_GAUGE_WEIGHT = 1e3

Evaluate = Callable[[Any, bool], tuple[float, np.ndarray | None, np.ndarray | None]]


@dataclass(frozen=True, kw_only=True)
class _SubsetProblem:
    """Dense normal equations from ``evaluate``, solved on ``free`` with Marquardt damping."""

    evaluate: Evaluate
    move: Callable[[Any, np.ndarray], Any]
    free: np.ndarray
    gauge: np.ndarray | None

    def cost(self, state) -> float:
        return self.evaluate(state, False)[0]

    def linearise(self, state) -> tuple[np.ndarray, np.ndarray, int]:
        _cost, H, b = self.evaluate(state, True)
        Hf = H[np.ix_(self.free, self.free)]
        if self.gauge is not None:
            Cf = self.gauge[:, self.free]
            Hf = Hf + _GAUGE_WEIGHT * max(float(np.max(np.diag(Hf))), 1e-12) * (Cf.T @ Cf)
        return Hf, b[self.free], len(b)

    def step(self, system, lam: float) -> np.ndarray | None:
        Hf, bf, n = system
        diag = np.diag(Hf).copy()
        diag[diag <= 0] = 1e-12
        try:
            step = np.linalg.solve(Hf + lam * np.diag(diag) + 1e-15 * np.eye(len(bf)), bf)
        except np.linalg.LinAlgError:
            return None
        delta = np.zeros(n)
        delta[self.free] = step
        return delta

    def apply(self, state, delta: np.ndarray):
        return self.move(state, delta)

    def step_size(self, delta: np.ndarray) -> float:
        return float(np.linalg.norm(delta))


def minimise_subset(
    evaluate: Evaluate,
    apply: Callable[[Any, np.ndarray], Any],
    state,
    *,
    iterations: int,
    free: np.ndarray,
    gauge: np.ndarray | None = None,
) -> tuple[Any, int, bool]:
    """Levenberg-Marquardt on the ``free`` parameters; returns ``(state, steps tried, converged)``.

    Parameters
    ----------
    evaluate : callable(state, jac) -> (cost, H, b)
        Cost, and with ``jac`` the Gauss-Newton matrix ``H`` (P, P) and ``b = -J^T r`` (P,).
    apply : callable(state, delta) -> state
        The state moved by ``delta`` (P,).
    state
        Start.
    iterations : int
        Largest number of steps tried.
    free : (F,) int ndarray
        Indices of the parameters that move.
    gauge : (C, P) ndarray, optional
        Adds the constraint ``C delta = 0`` as a stiff penalty.

    Converged: a relative cost decrease below 1e-5, or a damping above 1e6. A
    singular damped system counts as a rejected step (more damping).
    """
    problem = _SubsetProblem(evaluate=evaluate, move=apply, free=np.asarray(free), gauge=gauge)
    out = levenberg_marquardt(problem, state, replace(_SCHEDULE, max_attempts=iterations))
    return out.state, out.attempts, out.converged
