"""The scale measured both ways: current onto reference, and reference onto current.

The closed-form scale step (Eq. 15) comes out low on VSE clouds, more than errors in
the variables explain (docs/alignment.md, "Fast alignment"): nearest-neighbour
correspondences on a curved relief pull the matched offsets toward the local mean,
whichever cloud is the source. Aligning the reference onto the current cloud shrinks the inverse scale
the same way, so the geometric mean of the forward scale and the inverted backward
one cancels the shrink when the two clouds sample the surface alike (two sessions
of the same VSE). R and t are then re-solved at that scale.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from fgcd_cli.alignment.evaluation import overlap_threshold
from fgcd_cli.alignment.fast_config import FastAlignConfig
from fgcd_cli.alignment.health import residual_stats
from fgcd_cli.alignment.icp_levels import LevelInputs, finest, run_levels
from fgcd_cli.alignment.reference import ReferenceIndex
from fgcd_cli.alignment.results import AlignmentResult
from fgcd_core.sim3 import Sim3

__all__ = ["symmetric_scale"]

#: Fewest reference points near the current cloud the backward alignment needs (as the forward's
#: MIN_CURRENT_POINTS, with margin: the backward scale is only a correction).
_MIN_BACKWARD_POINTS = 200
#: The backward alignment's reference points: those within this many forward inlier thresholds of
#: the current cloud (the part of the reference the current cloud covers).
_NEAR_THRESHOLDS = 2.0
#: Points of the current cloud the backward run aligns onto.
_BACKWARD_POINTS = 10000
#: Largest relative change the backward scale may make to the forward one; larger means the
#: backward run went elsewhere (the shrink it corrects is a fraction of this: docs/alignment.md).
_MAX_CORRECTION = 0.02


def symmetric_scale(
    cur: np.ndarray,
    ref: ReferenceIndex,
    forward: AlignmentResult,
    config: FastAlignConfig,
    *,
    cur_weights: np.ndarray | None = None,
) -> AlignmentResult:
    """The forward alignment with its scale replaced by the two-way geometric mean.

    The two extra runs are the finest ICP level from the forward result (as a warm start),
    without the health check: the geometry's verdict is the forward's. The held run's own
    probes could not judge it anyway (with the scale held, a weak direction that contains the
    scale never comes back).

    Parameters
    ----------
    cur : (N, 3) ndarray
        The finite current points the forward alignment used (current metric frame).
    ref : ReferenceIndex
        The reference.
    forward : AlignmentResult
        ``fast_align(cur, ref)``, healthy.
    config : FastAlignConfig
        The forward's options.
    cur_weights : (N,) ndarray, optional
        The forward's per-point confidences (the held re-solve uses them as the forward did).

    Returns
    -------
    AlignmentResult
        ``forward`` at the two-way scale with R, t re-solved (its residuals recomputed), or ``forward``
        unchanged when the backward run cannot be trusted: too few reference points near the current
        cloud, a run that lost its correspondences or did not converge, or a correction above
        ``_MAX_CORRECTION``.
    """
    t0 = time.perf_counter()
    T = forward.T_ref_cur
    rng = np.random.default_rng(config.seed)
    # The backward run's reference: the current cloud, thinned to the finest level's point count (its
    # normals and rim cost in proportion; the forward's finest level uses as many current points).
    thin = cur if len(cur) <= _BACKWARD_POINTS else cur[rng.choice(len(cur), _BACKWARD_POINTS, replace=False)]
    cur_index = ReferenceIndex(thin)
    inlier_m = forward.residuals.inlier_threshold_mm * 1e-3
    radius = _NEAR_THRESHOLDS * max(inlier_m, 3.0 * ref.spacing)
    d, idx = cur_index.nearest(T.inverse().apply(ref.points), max_distance=radius / T.scale)
    # Reference points beyond the current cloud's rim match its rim points and pull the two rims
    # together, which shrinks the backward scale: only points matched inside the rim count.
    found = np.isfinite(d)
    found[found] &= ~cur_index.view_rim[idx[found]]
    near = ref.points[found]
    if len(near) < _MIN_BACKWARD_POINTS:
        return forward
    backward = run_levels(
        LevelInputs(cur=near, weights=None, ref=cur_index, order=rng.permutation(len(near))),
        T.inverse(),
        finest(config),
        config,
        estimate_scale=True,
    )
    if backward.T is None or not backward.converged:
        return forward
    s = math.sqrt(T.scale / backward.T.scale)
    if abs(math.log(s / T.scale)) > _MAX_CORRECTION:
        return forward
    # the same centroid of the current cloud, at the new scale; then R, t again at that scale
    c = cur.mean(axis=0)
    start = Sim3(T.R, T.apply(c) - s * (T.R @ c), s)
    held = run_levels(
        LevelInputs(cur=cur, weights=cur_weights, ref=ref, order=rng.permutation(len(cur))),
        start,
        finest(config),
        config,
        estimate_scale=False,
    )
    if held.T is None or not held.converged:
        return forward
    distances, _ = ref.nearest(held.T.apply(cur), max_distance=overlap_threshold(inlier_m, ref, config))
    return replace(
        forward,
        T_ref_cur=held.T,
        residuals=residual_stats(distances, inlier_threshold=inlier_m),
        iterations=forward.iterations + backward.iterations + held.iterations,
        seconds=forward.seconds + (time.perf_counter() - t0),
    )
