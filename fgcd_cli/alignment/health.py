"""Self-checks of an alignment: overlap, inliers and geometric conditioning.

A plane leaves in-plane translation and the rotation about its normal free; a
sphere leaves every rotation about its centre free. Such clouds give a
confident-looking ICP answer that is arbitrary along those directions, so the
conditioning of the point-to-plane problem is checked explicitly.

The conditioning uses normals smoothed over several centimetres (fine normals
of a noisy VSE cloud would fake a constraint). That also smooths away what
pins a near-planar object in practice: a shallow relief, mortar joints, the
object's sides and plinth. So a poorly conditioned result is not called
degenerate at once: the caller may *probe* its weak directions (perturb the
result along each and let the alignment run again; see
:func:`fgcd_cli.alignment.weak_probe.probe_weak_directions`). Only if a perturbation
stays where it was put is the geometry degenerate.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from fgcd_cli.alignment.results import HEALTH_OK, AlignmentHealth, ResidualStats

__all__ = [
    "similarity_conditioning",
    "scale_conditioning",
    "residual_stats",
    "HealthEvidence",
    "HealthLimits",
    "assess",
]

_PARAM_NAMES = ("tx", "ty", "tz", "rx", "ry", "rz", "scale")


def similarity_conditioning(points: np.ndarray, normals: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Eigen-decomposition of the normalised point-to-plane Hessian of a similarity.

    Each matched reference point ``q`` with normal ``n`` contributes the row
    ``[n, (q'/L) x n, n . q'/L]`` (``q' = q - centroid``, ``L`` the RMS radius),
    the derivative of its point-to-plane residual with respect to translation
    (in units of ``L``), rotation and log-scale. Normalising by ``L`` makes the
    eigenvalues comparable and independent of units.

    Parameters
    ----------
    points : (N, 3) ndarray
        Matched reference points, metres.
    normals : (N, 3) ndarray
        Their unit normals.

    Returns
    -------
    condition_ratio : float
        Smallest over largest eigenvalue, in [0, 1].
    eigenvalues : (7,) ndarray
        Ascending.
    eigenvectors : (7, 7) ndarray
        Columns, in the order ``(tx, ty, tz, rx, ry, rz, scale)``.
    """
    q = np.asarray(points, dtype=float)
    n = np.asarray(normals, dtype=float)
    if len(q) < 7:
        return 0.0, np.zeros(7), np.eye(7)
    c = q.mean(axis=0)
    L = float(np.sqrt(np.mean(np.sum((q - c) ** 2, axis=1))))
    if L <= 0:
        return 0.0, np.zeros(7), np.eye(7)
    qn = (q - c) / L
    J = np.column_stack([n, np.cross(qn, n), np.sum(n * qn, axis=1)])
    H = np.einsum("ni,nj->ij", J, J, optimize=False) / len(q)
    w, V = np.linalg.eigh(H)
    w = np.clip(w, 0.0, None)
    ratio = float(w[0] / w[-1]) if w[-1] > 0 else 0.0
    return ratio, w, V


def scale_conditioning(eigenvalues: np.ndarray, eigenvectors: np.ndarray) -> float:
    """The scale's own conditioning: its marginal information over the largest eigenvalue, in [0, 1].

    With ``H = V diag(w) V^T`` (:func:`similarity_conditioning`), the scale's variance after the
    other six parameters are estimated with it is ``(H^-1)_ss = sum_k V_sk^2 / w_k``; its
    information ``1 / (H^-1)_ss`` over ``w_max`` is to the scale what the condition ratio is to
    all seven parameters. A plane through the centroid leaves it 0; a body of revolution, free
    to orbit its axis, still measures it.
    """
    w = np.asarray(eigenvalues, dtype=float)
    v = np.asarray(eigenvectors, dtype=float)[_PARAM_NAMES.index("scale")]
    if len(w) == 0 or not w[-1] > 0:
        return 0.0
    coupled = v**2 > 1e-12
    if np.any(coupled & (w <= 0)):
        return 0.0
    variance = float(np.sum(v[coupled] ** 2 / w[coupled]))
    return float(min(1.0, 1.0 / (variance * w[-1]))) if variance > 0 else 1.0


def weak_direction_names(eigenvalues: np.ndarray, eigenvectors: np.ndarray, *, limit: float) -> tuple[str, ...]:
    """Describe the eigenvectors whose eigenvalue is below ``limit`` times the largest."""
    names = []
    for k in range(len(eigenvalues)):
        if eigenvalues[k] >= limit * eigenvalues[-1]:
            break
        v = eigenvectors[:, k]
        parts = [f"{_PARAM_NAMES[i]}:{v[i]:+.2f}" for i in np.argsort(-np.abs(v))[:3] if abs(v[i]) > 0.2]
        names.append(" ".join(parts))
    return tuple(names)


def residual_stats(distances: np.ndarray, *, inlier_threshold: float) -> ResidualStats:
    """Residual statistics in millimetres from point distances in metres."""
    d = np.asarray(distances, dtype=float)
    d = d[np.isfinite(d)]
    inl = d[d < inlier_threshold]
    if len(inl) == 0:
        return ResidualStats(
            count=len(d), rms_mm=float("nan"), median_mm=float("nan"), inlier_threshold_mm=inlier_threshold * 1e3
        )
    return ResidualStats(
        count=len(d),
        rms_mm=float(np.sqrt(np.mean(inl**2)) * 1e3),
        median_mm=float(np.median(inl) * 1e3),
        inlier_threshold_mm=inlier_threshold * 1e3,
    )


@dataclass(frozen=True, kw_only=True)
class HealthEvidence:
    """What an alignment result is judged on.

    Attributes
    ----------
    distances : (N,) ndarray
        Distance of every current point to its nearest reference point after
        alignment, metres (``inf`` when none within the search radius).
    matched_points, matched_normals : (K, 3) ndarray
        Reference points (and unit normals) matched by inliers, for the conditioning.
    converged : bool
        The iteration stopped on its tolerances.
    scale : float
        Result scale relative to the prior.
    """

    distances: np.ndarray
    matched_points: np.ndarray
    matched_normals: np.ndarray
    converged: bool
    scale: float


@dataclass(frozen=True, kw_only=True)
class HealthLimits:
    """Thresholds of :func:`assess`.

    Attributes
    ----------
    inlier_threshold, overlap_threshold : float
        Distances (m) within which a current point is an inlier / overlaps.
    min_inlier_ratio, min_overlap : float
        Smallest accepted fractions of current points.
    min_condition_ratio : float
        Smallest accepted :func:`similarity_conditioning` ratio.
    scale_bounds : (2,) tuple of float
        Allowed range of the relative scale.
    probe_return : float
        A probed direction is free when more than this fraction of its perturbation stays.
    probe_directions : int
        At most this many weak directions are probed.
    """

    inlier_threshold: float
    overlap_threshold: float
    min_inlier_ratio: float
    min_overlap: float
    min_condition_ratio: float
    scale_bounds: tuple[float, float]
    probe_return: float = 0.5
    probe_directions: int = 3


def assess(
    evidence: HealthEvidence,
    limits: HealthLimits,
    *,
    probe: Callable[[np.ndarray, np.ndarray], tuple[float, ...]] | None = None,
) -> AlignmentHealth:
    """Combine the checks into one :class:`AlignmentHealth`.

    Parameters
    ----------
    evidence : HealthEvidence
    limits : HealthLimits
    probe : callable(points, directions) -> tuple of float, optional
        Called when the conditioning is below the limit, with the matched
        points (K, 3) and the weakest eigenvectors (7, D) (at most
        ``limits.probe_directions``, weakest first, in the parameter order of
        :func:`similarity_conditioning`); returns, per direction, the
        fraction of a perturbation along it that the alignment left
        unrecovered. The geometry is degenerate only if one of them exceeds
        ``limits.probe_return``.
    """
    d = np.asarray(evidence.distances, dtype=float)
    n = max(1, len(d))
    overlap = float(np.count_nonzero(d < limits.overlap_threshold) / n)
    inlier_ratio = float(np.count_nonzero(d < limits.inlier_threshold) / n)
    ratio, w, V = similarity_conditioning(evidence.matched_points, evidence.matched_normals)
    weak = weak_direction_names(w, V, limit=limits.min_condition_ratio) if ratio < limits.min_condition_ratio else ()
    remaining: tuple[float, ...] = ()
    if weak and probe is not None and len(evidence.matched_points) >= 7:
        remaining = tuple(
            float(r)
            for r in probe(
                np.asarray(evidence.matched_points, dtype=float), V[:, : min(len(weak), limits.probe_directions)]
            )
        )
        degenerate = not remaining or max(remaining) > limits.probe_return
    else:
        degenerate = bool(weak)
    problems = _problems(
        evidence,
        limits,
        overlap=overlap,
        inlier_ratio=inlier_ratio,
        degenerate=(ratio, weak, remaining) if degenerate else None,
    )
    scale_measured = (
        not _problems(evidence, limits, overlap=overlap, inlier_ratio=inlier_ratio, degenerate=None)
        and scale_conditioning(w, V) >= limits.min_condition_ratio
    )
    return AlignmentHealth(
        ok=not problems,
        reason=HEALTH_OK if not problems else "; ".join(problems),
        converged=evidence.converged,
        overlap=overlap,
        inlier_ratio=inlier_ratio,
        condition_ratio=ratio,
        degenerate=degenerate,
        weak_directions=weak,
        weak_probe=remaining,
        scale_measured=scale_measured,
    )


def _problems(
    evidence: HealthEvidence, limits: HealthLimits, *, overlap: float, inlier_ratio: float, degenerate: tuple | None
) -> list[str]:
    """The failed checks, in the order of :attr:`AlignmentHealth.reason`."""
    problems = []
    if not evidence.converged:
        problems.append("did not converge")
    if overlap < limits.min_overlap:
        problems.append(f"overlap {overlap:.0%} < {limits.min_overlap:.0%}")
    if inlier_ratio < limits.min_inlier_ratio:
        problems.append(f"inlier ratio {inlier_ratio:.0%} < {limits.min_inlier_ratio:.0%}")
    if degenerate is not None:
        ratio, weak, remaining = degenerate
        probed = f"; perturbations along them kept {', '.join(f'{r:.0%}' for r in remaining)}" if remaining else ""
        problems.append(
            f"degenerate geometry (condition {ratio:.1e} < {limits.min_condition_ratio:.0e}; "
            f"weak: {'; '.join(weak)}{probed})"
        )
    lo, hi = limits.scale_bounds
    if not (lo <= evidence.scale <= hi):
        problems.append(f"scale changed by a factor {evidence.scale:.3f}, outside [{lo:.3f}, {hi:.3f}]")
    return problems
