"""Options and log of the active coarse stage (:mod:`fgcd_cli.relocation.coarse.stage`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from fgcd_cli.relocation.enums import CoarseAction, EstimateSource
from fgcd_core.sim3 import Sim3

__all__ = ["CoarseConfig", "CoarseResult", "CoarseStep"]


@dataclass(frozen=True, kw_only=True)
class CoarseConfig:
    """Options of the active coarse stage.

    Distances in metres, angles in degrees.
    """

    trigger_m: float = 0.10
    trigger_deg: float = 8.0
    """The stage runs when the first estimate is farther than this from the reference pose
    (a revisit start within rACR's usual few centimetres never triggers it)."""
    handover_m: float | None = None
    handover_deg: float | None = None
    """Overrides of the hand-over radius; None: the covariance model (:meth:`handover_limits`)."""
    basin_m: float = 0.05
    basin_deg: float = 5.0
    """Where the rACR loop takes over: the paper's success region (5 cm / 5 deg, lambda_cu)."""
    sigma_rel: float = 0.01
    """Stated covariance model of a verified estimate (docs/relocation.md, "Far starts"): its camera
    position is known to ``sigma_rel`` x the scene depth (1 sigma, RMS radius) and its rotation to
    ``sigma_rel`` radians, because each monocular cloud places its camera only to ~1 % of the depth
    (the loop's ``RelocationConfig.vse_sigma_rel``). The same model sets the weak directions."""
    k_sigma: float = 2.0
    """Multiple of that sigma kept between a hand-over and the basin's edge."""
    verify_m: float = 0.05
    verify_deg: float = 5.0
    """Camera uncertainty that verifies an estimate (the paper's 5 cm / 5 deg, lambda_cu)."""
    weak_ratio: float | None = None
    """Override: a direction whose information is below this fraction of the strongest is weak.
    None: the covariance model of :func:`~fgcd_cli.relocation.coarse.camera_uncertainty.camera_uncertainty`
    (a direction is weak when a systematic cloud error of ``sigma_rel`` x depth could slide the
    registration along it by more than ``verify_m``)."""
    min_fitness: float = 0.5
    """Fraction of the observed points that must find a rendered point after the residual
    registration; less means the estimate and the observation barely overlap."""
    step_m: float = 0.08
    step_deg: float = 8.0
    """Largest motion per step; the platform guard applies its own limits too."""
    look_deg: float = 4.0
    """Turn-around action when no estimate is verified."""
    max_steps: int = 10
    max_looks: int = 3
    max_descents: int = 2
    """Scene-descent steps on an unverified estimate (paper 001's heuristic, docs/relocation.md "Far
    starts"): half the estimated way toward the reference view, at most one step each."""
    render_stride_px: int = 4
    """Pixel bin of the z-buffer that renders the reference cloud (its points are sparse)."""
    max_points: int = 6000

    def handover_limits(self, depth_m: float) -> tuple[float, float]:
        """The hand-over radius (metres, degrees) at a scene depth (metres).

        A verified estimate within ``basin - k_sigma x sigma`` of the reference pose puts the true
        camera inside the basin unless its error exceeds ``k_sigma`` sigma (about 5 % of the time
        for ``k_sigma = 2`` and an isotropic 3-D error of that RMS radius, chi-square). With the
        simulator's depths (1.3-1.75 m) that is 24-15 mm and 3.9 deg.
        """
        depth = depth_m if math.isfinite(depth_m) and depth_m > 0 else 0.0
        m = (
            self.handover_m
            if self.handover_m is not None
            else max(0.0, self.basin_m - self.k_sigma * self.sigma_rel * depth)
        )
        deg = (
            self.handover_deg
            if self.handover_deg is not None
            else max(0.0, self.basin_deg - self.k_sigma * math.degrees(self.sigma_rel))
        )
        return m, deg


@dataclass(frozen=True, kw_only=True)
class CoarseStep:
    """One step of the coarse stage (one line of ``coarse.jsonl``; mm, degrees, seconds)."""

    step: int
    t_session_s: float
    action: CoarseAction | str
    source: EstimateSource | str
    """Which passive estimate was used ("3d", "image", or "")."""
    estimates: dict
    offset_mm: float
    offset_deg: float
    commanded_mm: float
    commanded_deg: float
    truth: dict | None = None
    look: dict | None = None
    """A look: its heading (``yaw_deg``, ``pitch_deg`` from where the stage started), how it was
    chosen, and with the scene uncertainty map the predicted ``uncertainty`` (Eq. 2) of the chosen
    view and of every candidate."""

    def to_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class CoarseResult:
    """Outcome of the coarse stage."""

    handed_over: bool
    reason: str
    init: Sim3 | None
    """Alignment of the session's metric frame into ``ref`` for the rACR loop (when handed over)."""
    steps: list[CoarseStep] = field(default_factory=list)
    end_truth: dict | None = None
    """The evaluator's truth where the stage left the camera, measured after a pause undid its unverified
    motions (evaluation only; None otherwise: the last step's truth is where it left it)."""
