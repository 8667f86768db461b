"""Fast scale-aware alignment (rACR §3.4.2, Eqs. 12–15).

Alternates a robust rigid step (sparse ICP, Eq. 13) with the closed-form scale
step (Eq. 15) until the change of the rigid part is below ``tau_T`` and the
change of the scale below ``tau_sigma``. Two measures keep it from collapsing
(similarity ICP shrinks the scale when started without a prior):

* the scale starts from a prior (the given ``init``, or the ratio of RMS radii),
  and the first, widest correspondence level estimates only R and t;
* coarse-to-fine: few points with unbounded correspondences first, then more
  points with shrinking correspondence radii.

The scale step is Eq. (15) with the translation re-solved jointly (weighted
centroids), over the correspondences that sparse ICP kept as inliers and within
``trim_factor`` times the median residual, weighted by the caller's per-point
confidence: Umeyama-type scale estimates are biased low when the source cloud is
noisy, and trimming/weighting keep that bias at the noise-variance level.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from fgcd_cli.alignment.cold_start import scale_neighbour, scale_search, shift_search
from fgcd_cli.alignment.evaluation import evaluate_alignment, failed_result, finished_result
from fgcd_cli.alignment.fast_config import FastAlignConfig
from fgcd_cli.alignment.icp_levels import LevelInputs, LevelRun, finest, run_levels
from fgcd_cli.alignment.reference import ReferenceIndex
from fgcd_cli.alignment.results import AlignmentResult, StartPath
from fgcd_cli.alignment.weak_probe import probe_weak_directions
from fgcd_core.sim3 import Sim3

__all__ = [
    "MIN_CURRENT_POINTS",
    "fast_align",
    "initial_scale",
    "as_reference",
    "evaluate_alignment",
    "probe_weak_directions",
]

#: Current points (the first of the random order) that score starts and test warmth.
_PROBE_POINTS = 1000
#: Fewest valid current points a fast alignment attempts (a similarity has 7 parameters; fewer than
#: 10 points leave no residual to judge the fit by).
MIN_CURRENT_POINTS = 10


def as_reference(ref_points: np.ndarray | ReferenceIndex) -> ReferenceIndex:
    """Wrap an (M, 3) array into a :class:`ReferenceIndex` (reuse one across calls instead)."""
    return ref_points if isinstance(ref_points, ReferenceIndex) else ReferenceIndex(ref_points)


def initial_scale(cur_points: np.ndarray, ref: ReferenceIndex) -> Sim3:
    """Similarity prior without pose knowledge: centroids and the ratio of RMS radii.

    Valid when the two clouds cover the same part of the scene; the relocation
    loop normally has a better prior (:func:`~fgcd_cli.alignment.initial_guess`).
    """
    c = cur_points.mean(axis=0)
    rms = float(np.sqrt(np.mean(np.sum((cur_points - c) ** 2, axis=1))))
    scale = ref.rms_radius / rms if rms > 0 else 1.0
    return Sim3(np.eye(3), ref.centroid - scale * c, scale)


def fast_align(
    cur_points: np.ndarray,
    ref_points: np.ndarray | ReferenceIndex,
    *,
    init: Sim3 | None = None,
    cur_weights: np.ndarray | None = None,
    config: FastAlignConfig = FastAlignConfig(),
) -> AlignmentResult:
    """Similarity ``T_ref_cur`` registering the current cloud to the reference cloud.

    A warm start (the prior already fits) runs the finest level only; otherwise, or
    when the warm run walks far from its prior or stalls at a wrong scale, the cold
    start searches shifts and scales first (docs/alignment.md, "Fast alignment").

    Parameters
    ----------
    cur_points : (N, 3) ndarray
        Current session's cloud in its map frame (metric up to the session scale error).
    ref_points : (M, 3) ndarray or ReferenceIndex
        Reference cloud, metres; pass a :class:`ReferenceIndex` built once to
        avoid rebuilding the KD-tree on every call.
    init : Sim3, optional
        Prior ``T_ref_cur`` (e.g. from :func:`~fgcd_cli.alignment.initial_guess` or the
        previous alignment); without it, centroids and RMS radii give the prior.
    cur_weights : (N,) ndarray, optional
        Confidence of each current point (e.g. inverse depth variance).
    config : FastAlignConfig

    Returns
    -------
    AlignmentResult
        Never raises on bad geometry: check ``result.health.ok``.
    """
    t0 = time.perf_counter()
    cur, weights = _valid_points(cur_points, cur_weights)
    ref = as_reference(ref_points)
    T = initial_scale(cur, ref) if init is None else init
    if len(cur) < MIN_CURRENT_POINTS:
        return failed_result(T, f"fewer than {MIN_CURRENT_POINTS} valid current points", t0)
    order = np.random.default_rng(config.seed).permutation(len(cur))
    run = _Run(
        inputs=LevelInputs(cur=cur, weights=weights, ref=ref, order=order),
        probe=cur[order[:_PROBE_POINTS]],
        config=config,
        t0=t0,
        scale_prior=T.scale,
    )
    # Warm start (the loop re-aligns from its previous result): skip the coarse
    # level and the scale search when the prior already fits.
    d0, _ = ref.nearest(T.apply(run.probe))
    if not np.median(d0) < config.warm.rel * ref.width:
        result = _cold_start(run, T, StartPath.COLD)
    else:
        result = _warm_start(run, T) or _cold_start(run, T, StartPath.WARM_TO_COLD)
    if config.scale.symmetric and config.scale.estimate and result.health.ok:
        from fgcd_cli.alignment.symmetric import symmetric_scale

        result = symmetric_scale(cur, ref, result, config, cur_weights=weights)
    return result


def _valid_points(cur_points: np.ndarray, cur_weights: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    """The finite current points (N, 3) with a positive finite weight, and those weights (or None)."""
    cur = np.asarray(cur_points, dtype=float)
    if cur.ndim != 2 or cur.shape[1] != 3:
        raise ValueError(f"current points must be (N, 3), got {cur.shape}")
    finite = np.all(np.isfinite(cur), axis=1)
    weights = None if cur_weights is None else np.asarray(cur_weights, dtype=float).reshape(-1)
    if weights is not None:
        if len(weights) != len(cur):
            raise ValueError("cur_weights must have one value per current point")
        finite &= np.isfinite(weights) & (weights > 0)
        weights = weights[finite]
    return cur[finite], weights


@dataclass
class _Run:
    """One :func:`fast_align` call: its inputs, probe points, clock and iteration count."""

    inputs: LevelInputs
    probe: np.ndarray
    config: FastAlignConfig
    t0: float
    scale_prior: float
    iterations: int = 0

    def levels(self, T: Sim3, levels: range, *, estimate_scale: bool) -> LevelRun:
        out = run_levels(self.inputs, T, levels, self.config, estimate_scale=estimate_scale)
        self.iterations += out.iterations
        return out

    def neighbour(self, T: Sim3) -> Sim3 | None:
        better, its = scale_neighbour(self.inputs, T, self.probe, self.config)
        self.iterations += its
        return better

    def finish(self, T: Sim3, converged: bool, path: StartPath) -> AlignmentResult:
        inputs = self.inputs
        health_points = inputs.cur[inputs.order[: self.config.health.points]]
        result = finished_result(
            T,
            health_points,
            inputs.ref,
            self.config,
            converged=converged,
            iterations=self.iterations,
            t0=self.t0,
            scale_prior=self.scale_prior,
        )
        return replace(result, start=path)

    def failed(self, T: Sim3, reason: str) -> AlignmentResult:
        return failed_result(T, reason, self.t0, self.iterations)


def _warm_start(run: _Run, T: Sim3) -> AlignmentResult | None:
    """The finest level from the prior; None when the start must be redone as a cold one.

    A nearly flat surface hides a large scale or rotation error from the warm test: the
    warm run then walks far from its prior (beyond the ``warm`` limits). A warm run whose
    scale moved by more than ``warm.check_scale_change``, or that did not converge, is
    checked against its neighbouring scales, because the joint iteration can stall at a
    wrong scale with a fine inlier ratio (docs/alignment.md, "Fast alignment"). The loop's
    steady state moves the scale far less: no cost there.
    """
    config = run.config
    out = run.levels(T, finest(config), estimate_scale=config.scale.estimate)
    if out.T is None or not _close(out.T, T, config):
        return None
    moved = abs(math.log(out.T.scale / T.scale))
    path = StartPath.WARM
    if (
        (not out.converged or moved > config.warm.check_scale_change)
        and config.scale.estimate
        and config.minimum_check.step > 0
    ):
        if run.neighbour(out.T) is not None:
            return None
        path = StartPath.WARM_CHECKED
    return run.finish(out.T, out.converged, path)


def _close(T_new: Sim3, T_old: Sim3, config: FastAlignConfig) -> bool:
    """A warm run stayed near its prior (scale and rotation within the warm limits)."""
    dR = T_new.R @ T_old.R.T
    angle = math.degrees(math.acos(float(np.clip((np.trace(dR) - 1) / 2, -1.0, 1.0))))
    return (
        abs(math.log(T_new.scale / T_old.scale)) <= config.warm.max_scale_change
        and angle <= config.warm.max_rotation_deg
    )


def _cold_start(run: _Run, T: Sim3, path: StartPath) -> AlignmentResult:
    """Shift and scale search (:mod:`~fgcd_cli.alignment.cold_start`), all levels, then the scale-minimum check."""
    config = run.config
    n_levels = config.levels.count
    first = 0
    if config.scale.estimate and len(config.cold.scale_candidates) > 1:
        T = shift_search(run.inputs, T, run.probe, config)
        best, its = scale_search(run.inputs, T, run.probe, config)
        run.iterations += its
        if best is not None:
            T = best
            first = 1 if n_levels > 1 else 0
    out = run.levels(T, range(first, n_levels), estimate_scale=config.scale.estimate)
    if out.T is None:
        return run.failed(T, out.failure)
    T_out, converged, problem = out.T, out.converged, ""
    if config.scale.estimate and config.minimum_check.step > 0:
        checked = _minimum_check(run, T_out, converged)
        if isinstance(checked, AlignmentResult):
            return checked
        T_out, converged, problem = checked
    result = run.finish(T_out, converged, path)
    if problem:
        health = replace(
            result.health,
            ok=False,
            scale_measured=False,
            reason=problem if result.health.ok else f"{result.health.reason}; {problem}",
        )
        result = replace(result, health=health, seconds=time.perf_counter() - run.t0)
    return result


def _minimum_check(run: _Run, T: Sim3, converged: bool) -> tuple[Sim3, bool, str] | AlignmentResult:
    """The scale must sit at the minimum of the robust residual (cold starts).

    A neighbouring scale that fits clearly better means the joint iteration stalled (on a
    thick reference the inlier ratio cannot tell): the finest level runs again from it,
    once. Returns ``(T, converged, problem)`` (``problem`` "" when the scale passed), or the
    failed result when that rerun lost its correspondences.
    """
    for attempt in range(2):
        better = run.neighbour(T)
        if better is None:
            break
        if attempt == 1:
            return (
                T,
                converged,
                (f"scale is not at the residual minimum (a {better.scale / T.scale - 1:+.0%} change fits better)"),
            )
        out = run.levels(better, finest(run.config), estimate_scale=True)
        if out.T is None:
            return run.failed(better, out.failure)
        T, converged = out.T, out.converged
    return T, converged, ""
