"""Levenberg–Marquardt on a subset of parameters, with an optional gauge penalty.

Used by the fine alignment with analytic Jacobians (Eqs. 16-18); the normal
equations come from the caller's ``evaluate`` (docs/alignment.md, "Fine-grained alignment").
"""

from __future__ import annotations

from typing import Callable, TypeVar

import numpy as np

__all__ = ["levenberg_marquardt"]

State = TypeVar("State")


def levenberg_marquardt(
    evaluate: Callable[[State, bool], tuple[float, np.ndarray | None, np.ndarray | None]],
    apply: Callable[[State, np.ndarray], State],
    state: State,
    *,
    iterations: int,
    free: np.ndarray,
    gauge: np.ndarray | None = None,
) -> tuple[State, int, bool]:
    """Levenberg–Marquardt on the ``free`` parameters; returns ``(state, iterations, converged)``.

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

    Converged: a relative cost decrease below 1e-5, or a damping above 1e6.
    """
    cost, H, b = evaluate(state, True)
    lam = 1e-3
    done = 0
    converged = False
    for _ in range(iterations):
        done += 1
        Hf = H[np.ix_(free, free)]
        bf = b[free]
        if gauge is not None:
            Cf = gauge[:, free]
            Hf = Hf + 1e3 * max(float(np.max(np.diag(Hf))), 1e-12) * (Cf.T @ Cf)
        diag = np.diag(Hf).copy()
        diag[diag <= 0] = 1e-12
        try:
            step = np.linalg.solve(Hf + lam * np.diag(diag) + 1e-15 * np.eye(len(bf)), bf)
        except np.linalg.LinAlgError:
            break
        delta = np.zeros(len(b))
        delta[free] = step
        candidate = apply(state, delta)
        new_cost, _, _ = evaluate(candidate, False)
        if new_cost < cost:
            gain = (cost - new_cost) / max(cost, 1e-30)
            state = candidate
            cost, H, b = evaluate(state, True)
            lam = max(lam / 3.0, 1e-7)
            if gain < 1e-5:
                converged = True
                break
        else:
            lam *= 8.0
            if lam > 1e6:
                converged = True
                break
    return state, done, converged
