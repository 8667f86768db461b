"""The relocation log: one :class:`AdjustmentRecord` per line of ``relocation.jsonl``, and the run's result."""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from fgcd_cli.relocation.stop_rule import Residual

__all__ = ["AdjustmentRecord", "RelocationResult"]


@dataclass(frozen=True, kw_only=True)
class AdjustmentRecord:
    """One line of ``relocation.jsonl``.

    Poses are nested lists (4 x 4, metres), distances in mm, angles in degrees,
    times in seconds; ``stage`` is an :class:`~fgcd_cli.relocation.enums.EstimateStage` value.
    """

    iteration: int
    t_wall_s: float
    t_session_s: float
    stage: str
    g: float
    offset_mm: float
    offset_deg: float
    T_ref_cam: list
    M_flange_commanded: list
    clamped: bool
    vse_status: str
    vse_points: int
    alignment_ok: bool
    alignment_reason: str
    scale: float
    sigma: float
    afd_est_px: float
    truth: dict | None = None
    image: dict | None = None
    """Image stage only: matches, inliers, RMS, measured AFD, reference image."""
    estimate_serial: int | None = None
    estimate_vse_frame: int | None = None
    """3D stages: the alignment estimate used (its publication number and the VSE frame it saw);
    in parallel mode a motion may reuse an estimate of the view before the previous motion."""
    offset_sigma_mm: float | None = None
    """1-sigma uncertainty of ``offset_mm`` (RMS radius of the camera position's uncertainty):
    PnP residual covariance for the image stage, ``vse_sigma_rel`` x distance for 3D stages."""
    tolerance_mm: float | None = None
    """The stop tolerance on ``offset_mm`` the run used (:func:`~fgcd_cli.relocation.stop_rule.tolerance_mm`)."""
    agreement: dict | None = None
    """Image stage: the 3D estimate of the same view it was compared with, and the verdict."""

    def to_json(self) -> str:
        return json.dumps(self.__dict__, ensure_ascii=False)


@dataclass
class RelocationResult:
    """Outcome of a relocation."""

    converged: bool
    reason: str
    adjustments: int
    records: list[AdjustmentRecord] = field(default_factory=list)
    final_T_ref_cam: np.ndarray | None = None
    wall_s: float = 0.0
    session_s: float = 0.0
    platform_s: float = 0.0
    synthetic_s: float = 0.0
    """Frame-synthesis time left out of ``session_s`` (simulator rendering; 0 on hardware)."""
    residual: Residual | None = None
    """The final remaining offset as the tool estimates it, with its uncertainty."""
    handed_over: bool = False
    """The 3D loop ended because the image stage should take over (``RelocationConfig.image_handover``)."""
    alignment_set_aside: str = ""
    """Why the image stage must not ask the 3D alignment when the loop handed over
    (:func:`fgcd_cli.relocation.racr.stage.racr_loop`): where the image localizer led the exploration, "disputed" (the
    first 3D estimate disagreed with the localizer) or "degenerate" (the first alignment found degenerate
    geometry); anywhere, "inconsistent" (two estimates of the one map-to-reference transform disagreed: the
    estimate follows the camera). The image stage then stops without the alignment's agreement; "" otherwise."""
