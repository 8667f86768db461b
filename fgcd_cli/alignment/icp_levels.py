"""Coarse-to-fine similarity ICP over the pyramid levels (rACR §3.4.2, Eqs. 13 and 15).

Each iteration matches the current points to their nearest reference points
within the level's radius, takes one robust rigid step (sparse ICP, Eq. 13, or
trimmed least squares) and then, from ``scale.from_level`` on, the closed-form
scale step (Eq. 15) with the translation re-solved jointly, bounded per step
and over the run. A level stops on the tolerances of ``convergence`` or when
an iteration no longer moves the points (docs/alignment.md, "Fast alignment").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from fgcd_cli.alignment.fast_config import FastAlignConfig, IcpMetric, RigidStepConfig, RobustKernel, ScaleStepConfig
from fgcd_cli.alignment.reference import ReferenceIndex
from fgcd_cli.alignment.sparse_icp import (
    scale_step_point_to_plane,
    sparse_point_to_plane_step,
    sparse_point_to_point_step,
    trimmed_point_to_plane_step,
)
from fgcd_core.se3 import make_pose
from fgcd_core.sim3 import Sim3

__all__ = ["LevelInputs", "LevelRun", "run_levels", "finest", "LOST_CORRESPONDENCES"]

LOST_CORRESPONDENCES = "lost the correspondences (fewer than 10 within range)"


@dataclass(frozen=True)
class LevelInputs:
    """The current cloud as the ICP levels see it.

    Attributes
    ----------
    cur : (N, 3) ndarray
        Finite current points (map frame).
    weights : (N,) ndarray or None
        Their confidences (positive), or None for equal weights.
    ref : ReferenceIndex
    order : (N,) int ndarray
        Random permutation of the current points; a level of ``n`` points uses ``order[:n]``.
    """

    cur: np.ndarray
    weights: np.ndarray | None
    ref: ReferenceIndex
    order: np.ndarray


class LevelRun(NamedTuple):
    """Outcome of :func:`run_levels`."""

    T: Sim3 | None
    """The similarity, None when the correspondences were lost."""
    converged: bool
    """The last level stopped on its tolerances."""
    iterations: int
    failure: str
    """Why ``T`` is None ("" otherwise)."""


def finest(config: FastAlignConfig) -> range:
    """The last pyramid level alone (warm starts, refits and probes)."""
    n = config.levels.count
    return range(n - 1, n)


@dataclass(frozen=True)
class _Level:
    """One pyramid level of a run: its points, weights and limits."""

    index: int
    x: np.ndarray
    weights: np.ndarray | None
    r_max: float
    tol_T: float
    tol_s: float


@dataclass(frozen=True)
class _RunLimits:
    """What a run may change: the scale (within ``[s_lo, s_hi]``) and which reference points count."""

    estimate_scale: bool
    s_lo: float
    s_hi: float
    ignore_ref: np.ndarray | None


@dataclass(frozen=True)
class _Matches:
    """Valid correspondences of one iteration: reference points, their normals, weights."""

    q: np.ndarray
    normals: np.ndarray
    weights: np.ndarray | None


def run_levels(
    inputs: LevelInputs,
    T: Sim3,
    levels: range,
    config: FastAlignConfig,
    *,
    estimate_scale: bool,
    ignore_ref: np.ndarray | None = None,
) -> LevelRun:
    """Coarse-to-fine ICP over ``levels`` starting from ``T``.

    Parameters
    ----------
    inputs : LevelInputs
    T : Sim3
        Start ``T_ref_cur``.
    levels : range
        Indices into the pyramid of ``config.levels``.
    config : FastAlignConfig
    estimate_scale : bool
        Run the scale step (Eq. 15) from ``config.scale.from_level`` on.
    ignore_ref : (M,) bool ndarray, optional
        Reference points whose correspondences are dropped.

    Returns
    -------
    LevelRun
    """
    R, t, s = T.R, T.t, T.scale
    drift = config.scale.max_drift
    limits = _RunLimits(
        estimate_scale=estimate_scale, s_lo=T.scale / (1 + drift), s_hi=T.scale * (1 + drift), ignore_ref=ignore_ref
    )
    iterations = 0
    converged = False
    for index in levels:
        level = _level(inputs, config, index)
        level_converged = False
        for _ in range(config.levels.iterations[index]):
            iterations += 1
            step = _iteration(inputs.ref, level, (R, t, s), limits, config)
            if step is None:
                return LevelRun(None, False, iterations, LOST_CORRESPONDENCES)
            (R_new, t_new, s_new), r_in, y = step
            done = _stopped(level, (R, t, s), (R_new, t_new, s_new), r_in, y, config)
            R, t, s = R_new, t_new, s_new
            if done:
                level_converged = True
                break
        converged = level_converged
    return LevelRun(Sim3(R, t, s), converged, iterations, "")


def _level(inputs: LevelInputs, config: FastAlignConfig, index: int) -> _Level:
    sel = inputs.order[: config.levels.points[index]]
    last = index == config.levels.count - 1
    tol = config.convergence
    return _Level(
        index=index,
        x=inputs.cur[sel],
        weights=None if inputs.weights is None else inputs.weights[sel],
        r_max=config.levels.radius_rel[index] * inputs.ref.width,
        tol_T=tol.tau_T if last else 10 * tol.tau_T,
        tol_s=tol.tau_sigma if last else 10 * tol.tau_sigma,
    )


def _iteration(ref: ReferenceIndex, level: _Level, pose, limits: _RunLimits, config: FastAlignConfig):
    """One ICP iteration: ``((R, t, s), working inlier distance, points before the step)``, or None if lost."""
    R, t, s = pose
    x = level.x
    y = s * (x @ R.T) + t
    d, idx = ref.nearest(y, max_distance=level.r_max)
    valid = np.isfinite(d)
    if limits.ignore_ref is not None:
        valid[valid] &= ~limits.ignore_ref[idx[valid]]
    if np.count_nonzero(valid) < 10:
        return None
    dv = d[valid]
    r_floor = config.rigid.min_inlier_spacing * ref.spacing
    r_in = float(np.clip(config.rigid.inlier_factor * np.median(dv), r_floor, level.r_max))
    matches = _Matches(
        q=ref.points[idx[valid]],
        normals=ref.normals[idx[valid]],
        weights=None if level.weights is None else level.weights[valid],
    )
    dT, inl = _rigid_step(y[valid], matches, dv, r_in, config.levels.metric[level.index], config.rigid)
    R = dT[:3, :3] @ R
    t = dT[:3, :3] @ t + dT[:3, 3]
    if limits.estimate_scale and level.index >= config.scale.from_level:
        s, t = _scale_step(x[valid] @ R.T, (t, s), matches, inl, r_in, limits, config.scale)
    return (R, t, s), r_in, y


def _rigid_step(
    y: np.ndarray, m: _Matches, dv: np.ndarray, r_in: float, metric: IcpMetric, rigid: RigidStepConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Robust rigid increment ``dT`` (4, 4) of the matched points ``y`` and its inlier mask (Eq. 13)."""
    if metric == IcpMetric.POINT:
        return sparse_point_to_point_step(
            y,
            m.q,
            inlier_distance=r_in,
            p=rigid.sparse_p,
            admm_iterations=rigid.admm_iterations,
            weights=m.weights,
        )
    if rigid.robust == RobustKernel.SPARSE:
        return sparse_point_to_plane_step(
            y,
            m.q,
            m.normals,
            inlier_distance=r_in,
            p=rigid.sparse_p,
            admm_iterations=rigid.admm_iterations,
            weights=m.weights,
        )
    if rigid.robust == RobustKernel.TRIMMED:
        inl = dv < r_in
        w = inl.astype(float) if m.weights is None else inl * m.weights
        return trimmed_point_to_plane_step(y, m.q, m.normals, weights=w), inl
    raise ValueError(f"unknown robust method {rigid.robust!r}")


def _scale_step(
    a: np.ndarray,
    ts: tuple[np.ndarray, float],
    m: _Matches,
    inl: np.ndarray,
    r_in: float,
    limits: _RunLimits,
    cfg: ScaleStepConfig,
) -> tuple[float, np.ndarray]:
    """Closed-form scale with the translation re-solved (Eq. 15), over the trimmed inliers.

    ``a`` (K, 3) are the rotated current points; returns ``(s, t)``, unchanged when fewer
    than 10 correspondences remain or the estimate is not a positive number.
    """
    t, s = ts
    e = np.abs(np.sum(m.normals * (s * a + t - m.q), axis=1))
    med = float(np.median(e[inl])) if np.any(inl) else r_in
    use = inl & (e < cfg.trim_factor * max(med, 1e-12))
    if np.count_nonzero(use) < 10:
        return s, t
    w = use.astype(float) if m.weights is None else use * m.weights
    s_new, t_new = scale_step_point_to_plane(a, m.q, m.normals, w)
    if not (s_new > 0 and math.isfinite(s_new)):
        return s, t
    # The least-squares scale is biased low while the correspondences are poor: bounding
    # each step stops a collapse from running away before R, t have caught up.
    s_clip = float(np.clip(s_new, max(s * (1 - cfg.max_step), limits.s_lo), min(s * (1 + cfg.max_step), limits.s_hi)))
    if s_clip != s_new:
        t_new = t_new + (s_new - s_clip) * (a.T @ w) / w.sum()
    return s_clip, t_new


def _stopped(level: _Level, old, new, r_in: float, y: np.ndarray, config: FastAlignConfig) -> bool:
    """The level converged: the step is below the tolerances, or the points no longer move."""
    R_old, t_old, s_old = old
    R, t, s = new
    dT = make_pose(R, t) @ np.linalg.inv(make_pose(R_old, t_old))
    if np.linalg.norm(dT - np.eye(4)) <= level.tol_T and abs(s - s_old) <= level.tol_s:
        return True
    # On noisy clouds the estimate can jitter above tau_T for ever: accept when the
    # points move by a negligible fraction of the working inlier distance.
    moved = float(np.sqrt(np.mean(np.sum((s * (level.x @ R.T) + t - y) ** 2, axis=1))))
    return moved < config.convergence.stall_rel * r_in
