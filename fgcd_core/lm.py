"""The one damped least-squares driver (Levenberg-Marquardt) and the Huber IRLS weights.

Every iterative least-squares solver in fgcd runs through :func:`levenberg_marquardt`:
the VSE bundle adjustment (``fgcd_cli/vse/ba.py``), the target-free hand-eye
adjustment (``fgcd_cli/calibration/handeye/schur_lm.py``) and the fine alignment
(``fgcd_cli/alignment/dense_steps.py``). A problem supplies its linearisation, its damped
step (dense, or the Schur-complement solve of :mod:`fgcd_core.schur`), how a step
moves the state and the cost; the driver owns the accept / reject rule, the
damping schedule and the stop rules (Nocedal & Wright, *Numerical
Optimization*, §10.3; Triggs et al., "Bundle adjustment, a modern synthesis",
§4.3). Each solver keeps its own :class:`LMSchedule` (docs/architecture.md,
"Modules").

Hand-written rather than :func:`scipy.optimize.least_squares`: measured on the
hand-eye problem, its sparse trust-region steps were 10-50x slower or stopped
short of the minimum (docs/lab/2026-11-25-code-comment-measurements.md, "Calibration").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

import numpy as np

__all__ = [
    "LMSchedule",
    "LMOutcome",
    "LeastSquaresProblem",
    "levenberg_marquardt",
    "huber_weights",
    "huber_rho",
    "huber_cost",
]

State = TypeVar("State")


@dataclass(frozen=True, kw_only=True)
class LMSchedule:
    """Damping schedule and stop rules of :func:`levenberg_marquardt`.

    Attributes
    ----------
    initial_damping : float
        Damping ``lambda`` of the first step.
    decrease : float
        After an accepted step ``lambda <- max(lambda / decrease, min_damping)``.
    min_damping : float
        Floor of ``lambda``.
    increase : float
        After a rejected step ``lambda <- lambda * increase``.
    max_damping : float
        Converged (no descent direction left at this damping) once ``lambda`` exceeds it;
        ``math.inf`` disables the rule.
    max_iterations : int or None
        Largest number of linearisations; ``None``: no limit.
    max_attempts : int or None
        Largest number of steps tried in all (accepted or not); ``None``: no limit.
    max_rejections : int or None
        Stop after this many consecutive rejected steps at one linearisation; ``None``: no limit.
    relative_decrease : float
        Converged when an accepted step lowers the cost by less than this fraction.
    min_step : float
        Converged when an accepted step's size (``problem.step_size``) is below this.
    """

    initial_damping: float = 1e-3
    decrease: float = 3.0
    min_damping: float = 1e-7
    increase: float = 10.0
    max_damping: float = 1e6
    max_iterations: int | None = 10
    max_attempts: int | None = None
    max_rejections: int | None = None
    relative_decrease: float = 1e-6
    min_step: float = 0.0


class LeastSquaresProblem(Protocol[State]):
    """What :func:`levenberg_marquardt` needs of a problem (states are immutable values)."""

    def cost(self, state: State) -> float:
        """The (robust) cost at ``state``."""

    def linearise(self, state: State) -> Any:
        """The normal equations (or whatever :meth:`step` solves) at ``state``."""

    def step(self, system: Any, damping: float) -> Any | None:
        """The damped step from ``system``, or ``None`` when the damped system is singular."""

    def apply(self, state: State, step: Any) -> State:
        """``state`` moved by ``step``."""

    def step_size(self, step: Any) -> float:
        """The size the ``min_step`` rule compares."""


@dataclass(frozen=True, kw_only=True)
class LMOutcome(Generic[State]):
    """Result of :func:`levenberg_marquardt`.

    Attributes
    ----------
    state
        The last accepted state (the start if none was).
    cost : float
        Its cost.
    iterations : int
        Linearisations made.
    attempts : int
        Steps tried (accepted or rejected).
    converged : bool
        A stop rule of convergence fired (relative decrease, step size or damping ceiling),
        rather than an iteration, attempt or rejection limit.
    """

    state: Any
    cost: float
    iterations: int
    attempts: int
    converged: bool


def _reached(count: int, limit: int | None) -> bool:
    return limit is not None and count >= limit


def levenberg_marquardt(problem: LeastSquaresProblem[State], state: State, schedule: LMSchedule) -> LMOutcome:
    """Minimise ``problem``'s cost from ``state`` by damped Gauss-Newton steps.

    At each linearisation, steps are tried with growing damping until one lowers
    the cost (accepted, damping lowered) or a stop rule fires.

    Parameters
    ----------
    problem : LeastSquaresProblem
        Cost, linearisation, damped step and update.
    state
        Start.
    schedule : LMSchedule
        Damping schedule and stop rules.

    Returns
    -------
    LMOutcome
    """
    s = schedule
    cost = problem.cost(state)
    lam = s.initial_damping
    iterations = attempts = 0
    converged = stop = False
    while not (stop or _reached(iterations, s.max_iterations) or _reached(attempts, s.max_attempts)):
        iterations += 1
        system = problem.linearise(state)
        rejections = 0
        while True:
            attempts += 1
            step = problem.step(system, lam)
            candidate = None if step is None else problem.apply(state, step)
            new_cost = math.inf if candidate is None else problem.cost(candidate)
            if new_cost < cost:
                converged = cost - new_cost < s.relative_decrease * cost or problem.step_size(step) < s.min_step
                state, cost = candidate, new_cost
                lam = max(lam / s.decrease, s.min_damping)
                stop = converged or _reached(attempts, s.max_attempts)
                break
            lam *= s.increase
            rejections += 1
            if lam > s.max_damping:
                converged = stop = True
                break
            if _reached(rejections, s.max_rejections) or _reached(attempts, s.max_attempts):
                stop = True
                break
    return LMOutcome(state=state, cost=cost, iterations=iterations, attempts=attempts, converged=converged)


def huber_weights(norms: np.ndarray, delta: float) -> np.ndarray:
    """IRLS weights of the Huber loss on residual norms: 1 up to ``delta``, ``delta / |r|`` beyond.

    Parameters
    ----------
    norms : (M,) ndarray
        Norm of each residual block (pixels for reprojection errors).
    delta : float
        Huber threshold, same unit.

    Returns
    -------
    (M,) ndarray
    """
    return np.where(norms <= delta, 1.0, delta / np.maximum(norms, 1e-12))


def huber_rho(norms: np.ndarray, delta: float) -> np.ndarray:
    """Huber loss of each residual norm: ``|r|^2 / 2`` up to ``delta``, ``delta (|r| - delta / 2)`` beyond.

    Parameters
    ----------
    norms : (M,) ndarray
        Norm of each residual block.
    delta : float
        Huber threshold, same unit.

    Returns
    -------
    (M,) ndarray
    """
    return np.where(norms <= delta, 0.5 * norms**2, delta * (norms - 0.5 * delta))


def huber_cost(norms: np.ndarray, delta: float) -> float:
    """Huber cost ``sum rho(|r|)`` of :func:`huber_rho`."""
    return float(np.sum(huber_rho(norms, delta)))
