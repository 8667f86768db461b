"""Options and log of the active coarse stage (:mod:`fgcd_cli.relocation.coarse`)."""

from __future__ import annotations

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
    handover_m: float = 0.04
    handover_deg: float = 4.0
    """A verified estimate within this of the reference pose hands over to the rACR loop: the
    paper's 5 cm / 5 deg less the typical error of a verified estimate (docs/relocation.md,
    "Far starts"), still inside the range the loop starts from routinely."""
    verify_m: float = 0.05
    verify_deg: float = 5.0
    """Camera uncertainty that verifies an estimate (the paper's 5 cm / 5 deg, lambda_cu)."""
    weak_ratio: float = 0.015
    """A direction of the residual registration whose information is below this fraction of the
    strongest (rotations scaled by the median depth) is weak. The limit sits between the
    directions a body of revolution leaves free (its orbit about the axis and their couplings,
    around 1 %) and the next constrained one (tens of percent) (docs/benchmarks.md)."""
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
    render_stride_px: int = 4
    """Pixel bin of the z-buffer that renders the reference cloud (its points are sparse)."""
    max_points: int = 6000


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
