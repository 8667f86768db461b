"""The scale measured both ways: current onto reference, and reference onto current.

The closed-form scale step (Eq. 15) comes out low on VSE clouds: on 9 simulated
relief-panel revisits the forward scale was below the truth every time (0.9942–0.9984),
by 2–5 times what the clouds' roughness predicts as errors in the variables, and
Deming's regression on the same correspondences corrects only a third of it
(docs/lab/2026-12-07-symmetric-scale.md). Nearest-neighbour correspondences on a
curved relief pull the matched offsets toward the local mean, whichever cloud is
the source. Aligning the reference onto the current cloud shrinks the inverse scale
the same way, so the geometric mean of the forward scale and the inverted backward
one cancels the shrink when the two clouds sample the surface alike (two sessions
of the same VSE). R and t are then re-solved at that scale.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from fgcd_cli.alignment.fast_config import FastAlignConfig
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
#: Largest relative change the backward scale may make to the forward one; larger means the
#: backward run went elsewhere (the measured shrink is 0.2–0.7 %).
_MAX_CORRECTION = 0.02


def symmetric_scale(
    cur: np.ndarray, ref: ReferenceIndex, forward: AlignmentResult, config: FastAlignConfig
) -> AlignmentResult:
    """The forward alignment with its scale replaced by the two-way geometric mean.

    Parameters
    ----------
    cur : (N, 3) ndarray
        The current points the forward alignment used (current metric frame).
    ref : ReferenceIndex
        The reference.
    forward : AlignmentResult
        ``fast_align(cur, ref)``, healthy.
    config : FastAlignConfig
        The forward's options (its ``scale.symmetric`` is ignored here).

    Returns
    -------
    AlignmentResult
        The re-solved alignment at the symmetric scale, or ``forward`` unchanged when the backward
        alignment is not trustworthy (too few reference points near the current cloud, unhealthy,
        or a correction above ``_MAX_CORRECTION``).
    """
    from fgcd_cli.alignment.fast import fast_align

    t0 = time.perf_counter()
    T = forward.T_ref_cur
    one_way = replace(config, scale=replace(config.scale, symmetric=False))
    cur_index = ReferenceIndex(cur)
    radius = _NEAR_THRESHOLDS * max(forward.residuals.inlier_threshold_mm * 1e-3, 3.0 * ref.spacing)
    d, _ = cur_index.nearest(T.inverse().apply(ref.points), max_distance=radius / T.scale)
    near = ref.points[np.isfinite(d)]
    if len(near) < _MIN_BACKWARD_POINTS:
        return forward
    backward = fast_align(near, cur_index, init=T.inverse(), config=one_way)
    if not backward.health.ok:
        return forward
    s = math.sqrt(T.scale / backward.T_ref_cur.scale)
    if abs(math.log(s / T.scale)) > _MAX_CORRECTION:
        return forward
    # the same centroid of the current cloud, at the new scale
    c = cur.mean(axis=0)
    start = Sim3(T.R, T.apply(c) - s * (T.R @ c), s)
    held = replace(config, scale=replace(config.scale, estimate=False, symmetric=False))
    out = fast_align(cur, ref, init=start, config=held)
    if not out.health.ok:
        return forward
    return replace(
        out,
        iterations=forward.iterations + backward.iterations + out.iterations,
        seconds=forward.seconds + (time.perf_counter() - t0),
        start=forward.start,
    )
