"""Options of the fast alignment (:func:`fgcd_cli.alignment.fast.fast_align`), grouped by stage.

:class:`FastAlignConfig` holds one section per stage (pyramid levels, rigid
step, scale step, convergence, warm start, cold start, scale-minimum check,
health, weak-direction probe), e.g.
``FastAlignConfig(scale=ScaleStepConfig(estimate=False)).scale.estimate``.
The rationale of each default is in ``docs/alignment.md`` ("Fast alignment");
its figures are in ``docs/benchmarks.md``, "Scale-aware point cloud alignment
(`fgcd bench align`)", the measurements behind the defaults in
``docs/lab/2026-11-25-code-comment-measurements.md``, "Alignment".

Distances given as ``*_rel`` are fractions of the reference cloud's width.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

__all__ = [
    "RobustKernel",
    "IcpMetric",
    "SearchScore",
    "PyramidConfig",
    "RigidStepConfig",
    "ScaleStepConfig",
    "ConvergenceConfig",
    "WarmStartConfig",
    "ColdStartConfig",
    "MinimumCheckConfig",
    "HealthConfig",
    "WeakProbeConfig",
    "FastAlignConfig",
]


class RobustKernel(StrEnum):
    """Robust rigid step of the point-to-plane levels."""

    SPARSE = "sparse"
    """Sparse ICP (ADMM on the l_p norm, Eq. 13)."""
    TRIMMED = "trimmed"
    """Trimmed least squares: correspondences beyond the working inlier distance are dropped."""


class IcpMetric(StrEnum):
    """ICP error of a pyramid level."""

    POINT = "point"
    """Point-to-point: the wide basin of the coarse level."""
    PLANE = "plane"
    """Point-to-plane: fast convergence near the optimum."""


class SearchScore(StrEnum):
    """Score of a cold-start candidate (lower is better), see :func:`fgcd_cli.alignment.cold_start.search_score`."""

    MEDIAN = "median"
    """Median nearest-neighbour distance of the probe points."""
    TRUNCATED = "truncated"
    """Mean distance truncated at the overlap distance (points off the reference count fully)."""
    INLIERS = "inliers"
    """Minus the fraction within ``inlier_rel`` of the width (saturates on thick references)."""


def _frozen_set(obj: object, name: str, value: Any) -> None:
    object.__setattr__(obj, name, value)


@dataclass(frozen=True, kw_only=True)
class PyramidConfig:
    """Coarse-to-fine correspondence levels (one entry per level, coarse first)."""

    points: tuple[int, ...] = (1500, 5000, 8000)
    """Current points used at each level (random subset). The last level's count is the
    smallest at which the accuracy stops improving (docs/alignment.md, "Fast alignment")."""
    radius_rel: tuple[float, ...] = (math.inf, 0.2, 0.06)
    """Largest correspondence distance at each level."""
    iterations: tuple[int, ...] = (60, 20, 40)
    metric: tuple[IcpMetric, ...] = (IcpMetric.POINT, IcpMetric.PLANE, IcpMetric.PLANE)
    """ICP error per level: point-to-point (wide basin) or point-to-plane (fast convergence)."""

    def __post_init__(self) -> None:
        _frozen_set(self, "metric", tuple(IcpMetric(m) for m in self.metric))

    @property
    def count(self) -> int:
        """Number of levels."""
        return len(self.points)


@dataclass(frozen=True, kw_only=True)
class RigidStepConfig:
    """Robust rigid step (Eq. 13) and its working inlier distance."""

    robust: RobustKernel = RobustKernel.SPARSE
    """Rigid step of the point-to-plane levels."""
    sparse_p: float = 0.4
    """Exponent ``p`` of the sparse ICP norm."""
    admm_iterations: int = 1
    """ADMM iterations per correspondence update (fresh multipliers make one enough)."""
    inlier_factor: float = 3.0
    """Working inlier distance: this times the median correspondence distance..."""
    min_inlier_spacing: float = 2.0
    """...but never below this many reference point spacings."""

    def __post_init__(self) -> None:
        _frozen_set(self, "robust", RobustKernel(self.robust))


@dataclass(frozen=True, kw_only=True)
class ScaleStepConfig:
    """Closed-form scale step (Eq. 15) and its bounds."""

    estimate: bool = True
    """False keeps the initial scale (the paper's rACR-S ablation)."""
    from_level: int = 1
    """First level at which the scale step runs (the widest level estimates R, t only)."""
    max_step: float = 0.02
    """Largest relative scale change per iteration."""
    max_drift: float = 0.12
    """Largest relative scale change over a run from its starting scale (after the cold-start
    scale search, whose candidates are 10-25 % apart): on noisy VSE clouds the least-squares
    scale otherwise runs away while R, t are still wrong (docs/alignment.md, "Fast alignment")."""
    trim_factor: float = 3.0
    """Correspondences beyond this times the median point-to-plane residual are left out."""
    symmetric: bool = False
    """Measure the scale both ways (current onto reference, reference onto current) and take the
    geometric mean, then re-solve R, t at it (:mod:`~fgcd_cli.alignment.symmetric`): one-way
    scales come out low on VSE clouds. Off here, where a warm call must stay cheap (two more
    finest-level runs and an index of the current cloud); the relocation loop turns it on
    (:attr:`fgcd_cli.relocation.config.RelocationConfig.fast_align`; docs/alignment.md, "Fast alignment")."""


@dataclass(frozen=True, kw_only=True)
class ConvergenceConfig:
    """When an ICP level stops."""

    tau_T: float = 1e-4
    """Stop when ``|dT - I|_F`` of the rigid part (metres/radians) falls below this..."""
    tau_sigma: float = 1e-5
    """...and the scale changes by less than this (ten times both on the coarser levels)."""
    stall_rel: float = 0.005
    """Also converged when an iteration moves the points by less than this fraction of the
    working inlier distance (noise-level jitter)."""


@dataclass(frozen=True, kw_only=True)
class WarmStartConfig:
    """Warm start: the prior already fits, only the finest level runs."""

    rel: float = 0.02
    """Warm start if the median distance of the prior's correspondences is below this fraction of the width."""
    max_scale_change: float = 0.03
    """A warm run that changes the scale by more than this (relative)... (on VSE clouds larger warm
    scale moves include collapses that neither the inlier ratio nor the scale-minimum check
    detects; the cold search corrects them: docs/alignment.md, "Fast alignment")."""
    max_rotation_deg: float = 3.0
    """...or the rotation by more than this is redone as a cold start."""
    check_scale_change: float = 0.02
    """A warm run that changes the scale by more than this (but within ``max_scale_change``),
    or does not converge, must pass the scale-minimum check; if a neighbouring scale fits better
    it is redone as a cold start. Below it (the relocation loop's steady state) nothing extra
    runs. Warm runs that stall at a wrong scale move it by more than this (docs/alignment.md,
    "Fast alignment")."""


@dataclass(frozen=True, kw_only=True)
class ColdStartConfig:
    """Cold start: shift search and scale search before the joint iteration."""

    scale_candidates: tuple[float, ...] = (0.8, 0.9, 1.0, 1.1, 1.25)
    """Relative scales tried with rigid coarse ICP before the scale is estimated."""
    search_score: SearchScore = SearchScore.MEDIAN
    """Score of the candidates."""
    scale_refinements: int = 2
    """Parabolic refinements of the best candidate scale (0: the grid only)."""
    search_iterations: tuple[int, int] = (40, 10)
    """Iteration limits of the two coarse levels during the scale search."""
    shift_steps: int = 2
    """Translations of the prior ``-k..k`` steps along the cloud's two main axes (0: off)."""
    shift_rel: float = 0.06
    """Step of those translations, fraction of the reference width."""
    shift_points: int = 600
    shift_radius_rel: float = 0.1
    shift_iterations: int = 12

    def __post_init__(self) -> None:
        _frozen_set(self, "search_score", SearchScore(self.search_score))


@dataclass(frozen=True, kw_only=True)
class MinimumCheckConfig:
    """The result's scale must sit at the minimum of the robust residual."""

    step: float = 0.04
    """The result's scale times ``1 +- this`` (rigidly refitted) must not fit better (0: no check).
    When one does, the run continues from it once; if the next result fails again, it is flagged
    not ok."""
    margin: float = 0.03
    """...by more than this fraction of the median residual."""
    iterations: int = 8
    """Iteration limit of the rigid refit at each neighbouring scale."""


@dataclass(frozen=True, kw_only=True)
class HealthConfig:
    """Thresholds of the self-checks (:mod:`fgcd_cli.alignment.health`)."""

    points: int = 10000
    """Current points (random subset) used for the health checks."""
    inlier_rel: float = 0.01
    """A current point is an inlier if within this fraction of the width (>= 3 spacings).
    Assumes the current cloud's noise is below about half of it; a mirrored or wrongly
    registered relief leaves about half of its points beyond it."""
    inlier_noise_factor: float = 3.0
    """...or this many times the combined noise of the two clouds, whichever is larger."""
    overlap_rel: float = 0.05
    min_inlier_ratio: float = 0.6
    min_overlap: float = 0.3
    min_condition_ratio: float = 5e-3
    """Smallest accepted condition ratio: between the VSE clouds of a plane or a sphere (below)
    and a relief (above); typical values per scene are in docs/lab/2026-11-25-code-comment-measurements.md,
    "Alignment"."""
    condition_noise_factor: float = 3.0
    """The limit is raised to this times ``(roughness / normal radius)^2`` of the reference: the
    floor that normal noise puts under a plane's smallest eigenvalue."""
    scale_bounds: tuple[float, float] = (1 / 1.5, 1.5)
    """Allowed range of the result's scale relative to the initial scale."""


@dataclass(frozen=True, kw_only=True)
class WeakProbeConfig:
    """Probe of the weak directions (:func:`fgcd_cli.alignment.weak_probe.probe_weak_directions`)."""

    enabled: bool = True
    """Below the condition limit, probe the weak directions before calling the geometry
    degenerate: near-planar objects pinned by a shallow relief, joints or their outline come
    back, planes and spheres do not (docs/alignment.md, "Health")."""
    rel: float = 0.01
    """Size of a probe perturbation: RMS displacement of the matched points, fraction of the
    reference width (at least 3 times the reference roughness)."""
    directions: int = 3
    return_fraction: float = 0.5
    """A direction is pinned if the alignment recovers all but this fraction of the perturbation."""
    points: int = 3000
    iterations: int = 15


@dataclass(frozen=True, kw_only=True)
class FastAlignConfig:
    """Options of :func:`~fgcd_cli.alignment.fast.fast_align`, one section per stage.

    Construct with sections: ``FastAlignConfig(cold=ColdStartConfig(shift_steps=0))``;
    change one option with ``replace(config, cold=replace(config.cold, shift_steps=0))``.
    """

    levels: PyramidConfig = field(default_factory=PyramidConfig)
    rigid: RigidStepConfig = field(default_factory=RigidStepConfig)
    scale: ScaleStepConfig = field(default_factory=ScaleStepConfig)
    convergence: ConvergenceConfig = field(default_factory=ConvergenceConfig)
    warm: WarmStartConfig = field(default_factory=WarmStartConfig)
    cold: ColdStartConfig = field(default_factory=ColdStartConfig)
    minimum_check: MinimumCheckConfig = field(default_factory=MinimumCheckConfig)
    health: HealthConfig = field(default_factory=HealthConfig)
    probe: WeakProbeConfig = field(default_factory=WeakProbeConfig)
    seed: int = 0
    """Seed of the random point subsets (fixed: results are reproducible)."""
