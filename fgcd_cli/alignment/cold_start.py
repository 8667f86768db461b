"""Cold start of the fast alignment: shift search, scale search and the scale-minimum check.

A scale prior that is off by 10-20 % sends similarity ICP astray, and local ICP
does not slide a cloud 10-15 cm along a nearly flat relief; so a cold start
first tries translations of the prior across the cloud's main plane, then a
grid of scales with rigid coarse ICP (refined by parabolic interpolation of the
score in log-scale), and every result's scale is checked against its
neighbours (docs/alignment.md, "Fast alignment").
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from fgcd_cli.alignment.fast_config import FastAlignConfig, IcpMetric, PyramidConfig, SearchScore
from fgcd_cli.alignment.icp_levels import LevelInputs, finest, run_levels
from fgcd_cli.alignment.reference import ReferenceIndex
from fgcd_core.sim3 import Sim3

__all__ = ["search_score", "shift_search", "scale_search", "scale_neighbour"]


def search_score(
    T: Sim3, probe: np.ndarray, ref: ReferenceIndex, config: FastAlignConfig, score: SearchScore | None = None
) -> float:
    """Cold-start score of a candidate (lower is better): a robust residual of the probe points.

    ``score`` (default ``config.cold.search_score``), see :class:`SearchScore`: the median
    nearest-neighbour distance, the mean distance truncated at the overlap distance, or
    minus the fraction within ``inlier_rel`` of the width.
    """
    score = config.cold.search_score if score is None else score
    d, _ = ref.nearest(T.apply(probe))
    if score == SearchScore.INLIERS:
        return -float(np.mean(d < config.health.inlier_rel * ref.width))
    if score == SearchScore.TRUNCATED:
        return float(np.mean(np.minimum(d, config.health.overlap_rel * ref.width)))
    return float(np.median(d))


def shift_search(inputs: LevelInputs, T: Sim3, probe: np.ndarray, config: FastAlignConfig) -> Sim3:
    """Try translations of the prior across the cloud's main plane; keep the best.

    Local ICP does not slide the current cloud 10-15 cm along a nearly flat relief
    (it stops in a local minimum that a smaller scale fits better: the collapse the
    scale search then picks). Each start runs a short rigid point-to-plane ICP on few
    points; the best by :func:`search_score` is kept (the unshifted prior included).
    """
    cold = config.cold
    if cold.shift_steps <= 0:
        return T
    y = T.apply(probe)
    c = y.mean(axis=0)
    axes = np.linalg.svd(y - c, full_matrices=False)[2][:2]
    step = cold.shift_rel * inputs.ref.width
    quick = replace(
        config,
        levels=PyramidConfig(
            points=(cold.shift_points,),
            radius_rel=(cold.shift_radius_rel,),
            iterations=(cold.shift_iterations,),
            metric=(IcpMetric.PLANE,),
        ),
        scale=replace(config.scale, from_level=1),
    )
    best = None
    k = cold.shift_steps
    for i in range(-k, k + 1):
        for j in range(-k, k + 1):
            start = Sim3(T.R, T.t + step * (i * axes[0] + j * axes[1]), T.scale)
            out = run_levels(inputs, start, range(1), quick, estimate_scale=False)
            if out.T is None:
                continue
            score = search_score(out.T, probe, inputs.ref, config)
            if best is None or score < best[0]:
                best = (score, start)
    return T if best is None else best[1]


def scale_search(inputs: LevelInputs, T: Sim3, probe: np.ndarray, config: FastAlignConfig) -> tuple[Sim3 | None, int]:
    """Best-fitting start over the candidate scales (rigid ICP on the coarse levels).

    The scales ``config.cold.scale_candidates`` (relative to ``T``'s, changed about the
    current cloud's centroid) each run the two coarse levels rigidly; the best by
    :func:`search_score` is refined by parabolic interpolation of the score in log-scale:
    the grid is coarse, and from a grid point the joint scale step creeps along nearly
    flat surfaces and stalls short of the optimum (docs/alignment.md, "Fast alignment").

    Returns
    -------
    T : Sim3 or None
        The best candidate's result, None when every candidate lost its correspondences.
    iterations : int
    """
    c_cur = inputs.cur.mean(axis=0)
    search = _search_config(config)
    levels = range(0, min(2, config.levels.count))
    iterations = 0
    tried = []  # (log scale, score, T)
    for factor in config.cold.scale_candidates:
        s_c = T.scale * factor
        start = Sim3(T.R, T.apply(c_cur) - s_c * (T.R @ c_cur), s_c)
        out = run_levels(inputs, start, levels, search, estimate_scale=False)
        iterations += out.iterations
        if out.T is not None:
            tried.append((math.log(s_c), search_score(out.T, probe, inputs.ref, config), out.T))
    for _ in range(config.cold.scale_refinements):
        if len(tried) < 3:
            break
        x = _parabolic_minimum(tried)
        if x is None:
            break
        T1 = min(tried, key=lambda e: e[1])[2]
        s_c = math.exp(x)
        start = Sim3(T1.R, T1.apply(c_cur) - s_c * (T1.R @ c_cur), s_c)
        out = run_levels(inputs, start, levels[1:], search, estimate_scale=False)
        iterations += out.iterations
        if out.T is None:
            break
        tried.append((x, search_score(out.T, probe, inputs.ref, config), out.T))
    best = min(tried, key=lambda e: e[1])[2] if tried else None
    return best, iterations


def _search_config(config: FastAlignConfig) -> FastAlignConfig:
    """``config`` with the coarse levels' iterations limited to ``cold.search_iterations``."""
    its = config.levels.iterations
    limits = config.cold.search_iterations + its[2:]
    return replace(config, levels=replace(config.levels, iterations=tuple(min(n, m) for n, m in zip(its, limits))))


def _parabolic_minimum(tried: list) -> float | None:
    """Log-scale of the vertex of the parabola through the best candidate and its neighbours.

    ``tried`` (sorted here by log-scale) holds ``(log scale, score, T)``. None when the best
    is at an end of the bracket, the three are not convex, or the step is below 2e-3.
    The vertex is kept 10 % of each interval away from the outer points.
    """
    tried.sort(key=lambda e: e[0])
    i = min(range(len(tried)), key=lambda k: tried[k][1])
    if i == 0 or i == len(tried) - 1:
        return None  # the optimum is outside the bracket: keep the best end point
    (x0, f0, _), (x1, f1, _), (x2, f2, _) = tried[i - 1], tried[i], tried[i + 1]
    denom = (x1 - x0) * (f1 - f2) - (x1 - x2) * (f1 - f0)
    if denom >= 0:
        return None  # not convex: no interior minimum
    x = x1 - 0.5 * ((x1 - x0) ** 2 * (f1 - f2) - (x1 - x2) ** 2 * (f1 - f0)) / denom
    x = float(np.clip(x, x0 + 0.1 * (x1 - x0), x2 - 0.1 * (x2 - x1)))
    if abs(x - x1) < 2e-3:
        return None
    return x


def scale_neighbour(
    inputs: LevelInputs, T: Sim3, probe: np.ndarray, config: FastAlignConfig
) -> tuple[Sim3 | None, int]:
    """A scale ``1 +- minimum_check.step`` times ``T``'s (rigidly refitted) that fits clearly better.

    Each neighbouring scale (about the probe points' centroid) runs the finest level
    rigidly for ``minimum_check.iterations``; it fits clearly better when its median
    residual is below ``1 - minimum_check.margin`` times ``T``'s.

    Returns
    -------
    better : Sim3 or None
    iterations : int
    """
    check = config.minimum_check
    levels = config.levels
    short = replace(config, levels=replace(levels, iterations=levels.iterations[:-1] + (check.iterations,)))
    c_cur = probe.mean(axis=0)
    c_ref = T.apply(c_cur)
    f0 = search_score(T, probe, inputs.ref, config, SearchScore.MEDIAN)
    iterations = 0
    best = None
    for factor in (1 - check.step, 1 + check.step):
        s_c = T.scale * factor
        start = Sim3(T.R, c_ref - s_c * (T.R @ c_cur), s_c)
        out = run_levels(inputs, start, finest(config), short, estimate_scale=False)
        iterations += out.iterations
        if out.T is None:
            continue
        f = search_score(out.T, probe, inputs.ref, config, SearchScore.MEDIAN)
        if f < (1 - check.margin) * f0 and (best is None or f < best[0]):
            best = (f, out.T)
    return (None if best is None else best[1]), iterations
