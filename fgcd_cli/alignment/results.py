"""Typed results of the alignment stage.

Every result carries ``T_ref_cur`` (a :class:`~fgcd_core.sim3.Sim3` mapping
the current session's map frame into the reference frame:
``p_ref = T_ref_cur.apply(p_cur)``) and a :class:`AlignmentHealth` that says
whether to trust it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from enum import StrEnum

import numpy as np

from fgcd_core.sim3 import Sim3

__all__ = ["HEALTH_OK", "StartPath", "AlignmentHealth", "ResidualStats", "AlignmentResult", "FineAlignmentResult"]

HEALTH_OK = "ok"
""":attr:`AlignmentHealth.reason` of a result that passed every check (otherwise the failed checks)."""


class StartPath(StrEnum):
    """Which path of :func:`~fgcd_cli.alignment.fast_align` ran (docs/alignment.md, "Fast alignment")."""

    WARM = "warm"
    """The prior fitted: the finest level only."""
    WARM_CHECKED = "warm, checked"
    """A warm run that moved the scale by more than ``warm_check_scale_change`` or did not
    converge, confirmed by the scale-minimum check."""
    WARM_TO_COLD = "warm -> cold"
    """A warm run handed over to the cold-start search."""
    COLD = "cold"
    """Shift and scale search, then all levels."""


@dataclass(frozen=True, kw_only=True)
class ResidualStats:
    """Statistics of point residuals after alignment, millimetres.

    ``count`` residuals were used; ``rms_mm`` and ``median_mm`` are over inliers
    (distance below the inlier threshold), ``inlier_threshold_mm`` states it.
    """

    count: int
    rms_mm: float
    median_mm: float
    inlier_threshold_mm: float


@dataclass(frozen=True, kw_only=True)
class AlignmentHealth:
    """Self-checks of an alignment; ``ok`` is False when the answer must not be trusted.

    Attributes
    ----------
    ok : bool
        All checks passed.
    reason : str
        Human-readable summary (:data:`HEALTH_OK` or what failed).
    converged : bool
        The iteration stopped on its tolerances, not on the iteration limit.
    overlap : float
        Fraction of current points with a reference point within the overlap distance.
    inlier_ratio : float
        Fraction of current points within the inlier threshold.
    condition_ratio : float
        Smallest over largest eigenvalue of the normalised point-to-plane Hessian
        of the 7 similarity parameters (0 for a plane or a sphere).
    degenerate : bool
        ``condition_ratio`` is below the configured limit and (when probed)
        a perturbation along a weak direction was not recovered.
    weak_directions : tuple of str
        Names of the poorly conditioned parameter combinations ("translation",
        "rotation", "scale" mixtures), empty when well conditioned.
    weak_probe : tuple of float
        Per probed weak direction, the fraction of a perturbation the
        alignment left unrecovered (about 0: the direction is pinned after
        all; about 1 or more: it is free). Empty when not probed.
    scale_measured : bool
        Every check but the pose's conditioning passed, and the scale alone is
        conditioned by the same standard (its marginal information,
        :func:`~fgcd_cli.alignment.health.scale_conditioning`): the Sim3 scale is
        a measurement of the two clouds' ratio even when the pose is free along
        a weak direction (an orbit about a stupa's axis, a slide along a cornice).
        Set by :func:`~fgcd_cli.alignment.health.assess` (the fast alignment);
        False where it is not assessed (the fine alignment's composed health).
    """

    ok: bool
    reason: str
    converged: bool
    overlap: float
    inlier_ratio: float
    condition_ratio: float
    degenerate: bool
    weak_directions: tuple[str, ...] = ()
    weak_probe: tuple[float, ...] = ()
    scale_measured: bool = False


@dataclass(frozen=True, kw_only=True)
class AlignmentResult:
    """Result of :func:`~fgcd_cli.alignment.fast_align`.

    Attributes
    ----------
    T_ref_cur : Sim3
        Current map frame -> reference frame.
    residuals : ResidualStats
    health : AlignmentHealth
    iterations : int
        ICP iterations over all resolution levels.
    seconds : float
        Wall-clock time of the call.
    start : StartPath
        Which path ran (its value: ``"warm"``, ``"warm, checked"``, ``"warm -> cold"`` or ``"cold"``).
    """

    T_ref_cur: Sim3
    residuals: ResidualStats
    health: AlignmentHealth
    iterations: int
    seconds: float
    start: StartPath = StartPath.COLD

    def to_dict(self) -> dict:
        """JSON-friendly form."""
        return {
            "T_ref_cur": self.T_ref_cur.to_dict(),
            "residuals": asdict(self.residuals),
            "health": asdict(self.health),
            "iterations": self.iterations,
            "seconds": self.seconds,
            "start": str(self.start),
        }


@dataclass(frozen=True, kw_only=True)
class FineAlignmentResult:
    """Result of :func:`~fgcd_cli.alignment.fine_align`.

    Attributes
    ----------
    T_ref_cur : Sim3
        Refined current map frame -> reference frame.
    keyframe_poses : list of (4, 4) ndarray
        Refined ``T_cur_cam`` of each current keyframe (same order as given).
    residuals : ResidualStats
        Geometric residuals (mm) after refinement.
    photometric_rms_before, photometric_rms_after : float
        RMS of the photometric residuals (grey levels in [0, 1]) before and after.
    health : AlignmentHealth
    iterations : int
        LM iterations over all steps and pyramid levels.
    seconds : float
    """

    T_ref_cur: Sim3
    keyframe_poses: list[np.ndarray]
    residuals: ResidualStats
    photometric_rms_before: float
    photometric_rms_after: float
    health: AlignmentHealth
    iterations: int
    seconds: float
    photometric_residual_count: int = 0
    notes: tuple[str, ...] = field(default=())

    def to_dict(self) -> dict:
        """JSON-friendly form."""
        return {
            "T_ref_cur": self.T_ref_cur.to_dict(),
            "keyframe_poses": [np.asarray(T).tolist() for T in self.keyframe_poses],
            "residuals": asdict(self.residuals),
            "photometric_rms_before": self.photometric_rms_before,
            "photometric_rms_after": self.photometric_rms_after,
            "photometric_residual_count": self.photometric_residual_count,
            "health": asdict(self.health),
            "iterations": self.iterations,
            "seconds": self.seconds,
            "notes": list(self.notes),
        }
