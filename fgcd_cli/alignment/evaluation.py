"""Residuals and health of an alignment result ``T_ref_cur`` (thresholds from :class:`FastAlignConfig`).

Used by the fast alignment for its own result and by the fine alignment for its
geometric check (docs/alignment.md, "Health").
"""

from __future__ import annotations

import math
import time

import numpy as np

from fgcd_cli.alignment.fast_config import FastAlignConfig
from fgcd_cli.alignment.health import HealthEvidence, HealthLimits, assess, residual_stats
from fgcd_cli.alignment.reference import ReferenceIndex, local_roughness
from fgcd_cli.alignment.results import AlignmentHealth, AlignmentResult, ResidualStats
from fgcd_cli.alignment.weak_probe import probe_weak_directions
from fgcd_core.sim3 import Sim3

__all__ = ["evaluate_alignment", "finished_result", "failed_result", "overlap_threshold"]

#: At most this many matched reference points enter the conditioning.
_MAX_MATCHED = 5000


def evaluate_alignment(
    T: Sim3,
    cur: np.ndarray,
    ref: ReferenceIndex,
    *,
    converged: bool,
    scale_ratio: float,
    config: FastAlignConfig = FastAlignConfig(),
) -> tuple[ResidualStats, AlignmentHealth]:
    """Geometric residuals and health of ``T_ref_cur`` for the current cloud.

    Parameters
    ----------
    T : Sim3
        ``T_ref_cur``.
    cur : (N, 3) ndarray
        Current points (map frame).
    ref : ReferenceIndex
    converged : bool
        The iteration that produced ``T`` stopped on its tolerances.
    scale_ratio : float
        ``T``'s scale over the prior's.
    config : FastAlignConfig
        Thresholds (``health``) and the weak-direction probe (``probe``).

    Returns
    -------
    residuals : ResidualStats
        Millimetres.
    health : AlignmentHealth
    """
    h = config.health
    # Inlier threshold: a fraction of the width, or three times the two clouds' combined
    # noise (each cloud's noise estimated on that cloud alone, so a bad fit cannot inflate it).
    noise = math.hypot(local_roughness(cur, samples=500) * T.scale, ref.roughness)
    inlier_thr = max(h.inlier_rel * ref.width, h.inlier_noise_factor * noise, 3 * ref.spacing)
    overlap_thr = overlap_threshold(inlier_thr, ref, config)
    d, idx = ref.nearest(T.apply(cur), max_distance=overlap_thr)
    matched = idx[d < inlier_thr]
    if len(matched) > _MAX_MATCHED:
        matched = matched[:: len(matched) // _MAX_MATCHED + 1]
    smooth_pts, smooth_normals, smooth_tree = ref.smooth_normals()
    matched_smooth = np.unique(smooth_tree.query(ref.points[matched])[1]) if len(matched) else np.zeros(0, int)

    def probe(points: np.ndarray, directions: np.ndarray) -> tuple[float, ...]:
        return probe_weak_directions(T, cur, ref, points=points, directions=directions, config=config)

    evidence = HealthEvidence(
        distances=d,
        matched_points=smooth_pts[matched_smooth],
        matched_normals=smooth_normals[matched_smooth],
        converged=converged,
        scale=scale_ratio,
    )
    limits = HealthLimits(
        inlier_threshold=inlier_thr,
        overlap_threshold=overlap_thr,
        min_inlier_ratio=h.min_inlier_ratio,
        min_overlap=h.min_overlap,
        # Noisy normals lift the smallest eigenvalue of a plane to about (noise / radius)^2.
        min_condition_ratio=max(
            h.min_condition_ratio, h.condition_noise_factor * (ref.roughness / ref.smooth_radius) ** 2
        ),
        scale_bounds=h.scale_bounds,
        probe_return=config.probe.return_fraction,
        probe_directions=config.probe.directions,
    )
    health = assess(evidence, limits, probe=probe if config.probe.enabled else None)
    return residual_stats(d, inlier_threshold=inlier_thr), health


def overlap_threshold(inlier_threshold: float, ref: ReferenceIndex, config: FastAlignConfig) -> float:
    """Distance (m) within which a current point counts as overlapping the reference (the residuals'
    ``count``): a fraction of the width, twice the inlier threshold, or five point spacings."""
    return max(config.health.overlap_rel * ref.width, 2 * inlier_threshold, 5 * ref.spacing)


def finished_result(
    T: Sim3,
    cur: np.ndarray,
    ref: ReferenceIndex,
    config: FastAlignConfig,
    *,
    converged: bool,
    iterations: int,
    t0: float,
    scale_prior: float,
) -> AlignmentResult:
    """:class:`AlignmentResult` of ``T`` with its residuals and health; ``t0`` is the call's start."""
    residuals, health = evaluate_alignment(
        T, cur, ref, converged=converged, scale_ratio=T.scale / scale_prior, config=config
    )
    return AlignmentResult(
        T_ref_cur=T, residuals=residuals, health=health, iterations=iterations, seconds=time.perf_counter() - t0
    )


def failed_result(T: Sim3, reason: str, t0: float, iterations: int = 0) -> AlignmentResult:
    """:class:`AlignmentResult` of a run that produced no similarity (``T`` is its start)."""
    nan = float("nan")
    return AlignmentResult(
        T_ref_cur=T,
        residuals=ResidualStats(count=0, rms_mm=nan, median_mm=nan, inlier_threshold_mm=nan),
        health=AlignmentHealth(
            ok=False,
            reason=reason,
            converged=False,
            overlap=0.0,
            inlier_ratio=0.0,
            condition_ratio=0.0,
            degenerate=False,
        ),
        iterations=iterations,
        seconds=time.perf_counter() - t0,
    )
