"""What the change detector returns (:class:`ChangeResult`), and the parts of it both detectors build alike."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from fgcd_cli.changes.config import DecisionRule, DetectionConfig
from fgcd_cli.changes.cues.labels import CueMaps
from fgcd_cli.changes.dense.refine import DenseAlignment
from fgcd_cli.changes.regions import ChangeRegion
from fgcd_cli.changes.registration import Registration, RegistrationInit
from fgcd_cli.changes.score import PairScore
from fgcd_cli.changes.significance import Decision, SignificantRegion
from fgcd_cli.changes.threshold import ThresholdInfo

CUES_COMPUTED = "relief and colour (photometric stereo)"
"""``settings["cues"]`` when the cue maps were computed."""


@dataclass(kw_only=True)
class ChangeResult:
    """Everything :func:`fgcd_cli.changes.detect.detect_changes` found, in the reference image's frame."""

    comparable: bool
    """False when the pair cannot be compared honestly (see ``reason``); then the maps are empty."""
    reason: str = ""
    score: np.ndarray
    """HxW float32 fused change score (dimensionless, background median ~1; 0 outside ``valid``)."""
    fine_score: np.ndarray | None = None
    """HxW float32, the same score at the finer smoothing the decision also scans (None when off)."""
    mask: np.ndarray
    """HxW bool, changed pixels after threshold and cleaning."""
    labels: np.ndarray
    """HxW int32, region id per pixel (0 = unchanged)."""
    valid: np.ndarray
    """HxW bool, pixels that were compared (region of interest ∩ seen in the current image)."""
    regions: list[ChangeRegion]
    registration: Registration | None
    threshold: ThresholdInfo | None
    current_registered: list[np.ndarray] = field(default_factory=list)
    """Current images resampled into the reference frame, light-normalized (float32)."""
    settings: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    edge_explained: np.ndarray | None = None
    """HxW bool, pixels of the regions the region-level edge check set aside (``edge_check_px``), or None."""
    candidates: list[SignificantRegion] = field(default_factory=list)
    """The strongest a-contrario regions that were not reported (for "no significant change; strongest candidate ...")."""
    not_compared: np.ndarray | None = None
    """HxW bool, pixels of the evaluation area the dense refinement could not align (left out, not changed)."""
    dense: DenseAlignment | None = None
    """The dense parallax refinement after the homography, when it ran."""
    cue_maps: CueMaps | None = None
    """Relief and colour cue maps (photometric stereo), when they were computed."""
    pair_score: PairScore | None = None
    """The fused score with its light-normalised current images and per-lighting medians: what a decision with
    other constants needs to be made again as the detector makes it, edge check included
    (:func:`fgcd_cli.changes.region_decision.decide_again`)."""

    @property
    def detection_level(self) -> float | None:
        """Score at which the decision starts a region: the a-contrario seed level (the ``seed_p``
        quantile of the pair's null), or the hysteresis rule's high threshold; None without a decision."""
        if self.settings.get("decision") == DecisionRule.ACONTRARIO and self.settings.get("seed_level") is not None:
            return float(self.settings["seed_level"])
        return self.threshold.high if self.threshold is not None else None

    def strength(self, region: ChangeRegion) -> float | None:
        """A region's peak change score in units of :attr:`detection_level` (None without a decision): the
        evidence the report ranks regions by and shows (docs/change-detection.md, "Reports")."""
        level = self.detection_level
        return float(region.max_score) / level if level else None

    @property
    def changed_fraction(self) -> float:
        """Fraction of compared pixels flagged as changed."""
        return float(self.mask[self.valid].mean()) if self.valid.any() else 0.0


def empty_result(
    shape: tuple[int, int], reason: str, registration: Registration | None, settings: dict
) -> ChangeResult:
    """The result of a pair that cannot be compared honestly (``comparable=False``, empty HxW maps)."""
    return ChangeResult(
        comparable=False,
        reason=reason,
        score=np.zeros(shape, np.float32),
        mask=np.zeros(shape, bool),
        labels=np.zeros(shape, np.int32),
        valid=np.zeros(shape, bool),
        regions=[],
        registration=registration,
        threshold=None,
        settings=settings,
    )


def detection_settings(config: DetectionConfig, *, lightings: int, shading: bool) -> dict:
    """The options a result records in ``settings`` (keys in the order reports print them)."""
    score, regions = config.score, config.regions
    return {
        "lightings": lightings,
        "gain_sigma_px": score.gain_sigma_px,
        "shift_radius_px": score.shift_radius_px,
        "structure_weight": score.structure_weight,
        "smooth_sigma_px": score.smooth_sigma_px,
        "fine_smooth_sigma_px": score.fine_smooth_sigma_px,
        "k_high": regions.k_high,
        "k_low": regions.k_low,
        "min_region_px": regions.min_region_px,
        "max_hole_px": regions.max_hole_px,
        "registration_lighting": config.registration.registration_lighting,
        "robust_gain_rounds_max": score.robust_gain_rounds,
        "edge_fraction": regions.edge_fraction,
        "edge_radius_px": regions.edge_radius_px,
        "edge_tolerance_px": score.edge_tolerance_px,
        "edge_contrast": score.edge_contrast,
        "edge_check_px": config.edge_check.edge_check_px,
        "shading_normalization": shading,
        "decision": regions.decision.value,
        "epsilon": regions.epsilon,
        "seed_p": regions.seed_p,
        "extent_fraction": regions.extent_fraction,
        "dense": config.registration.dense,
    }


def result_warnings(mask: np.ndarray, valid: np.ndarray, registration: Registration, *, register: bool) -> list[str]:
    """Warnings a conservator should read with the map (too much flagged, registration without features)."""
    warnings = []
    fraction = float(mask[valid].mean())
    if fraction > 0.25:
        warnings.append(
            f"{fraction * 100:.0f} % of the compared area flagged: lighting or viewpoint may differ too much for a fine-grained comparison"
        )
    if registration.init == RegistrationInit.IDENTITY and register:
        warnings.append("features did not match; registration started from the identity (gradient ECC only)")
    return warnings


#: Why a candidate was not reported, as the report and ``regions.json`` say it (docs/change-detection.md,
#: "Change detection pipeline", steps 5-10).
WHY_NOT_REPORTED = {
    "not_significant": "not significant (NFA of 1 or more)",
    "set_aside": "set aside along an edge, or under the smallest region",
    "faint": "fainter than the contrast floor",
    "clipped": "clipped: a highlight, or too dark to measure",
}


def unreported_candidates(
    significance: Decision, mask: np.ndarray, *, count: int = 5, first: tuple[SignificantRegion, ...] = ()
) -> list[SignificantRegion]:
    """The ``count`` most significant a-contrario regions whose centroid is not in the final mask.

    ``first`` (the regions the contrast floor set aside, which the report says are listed) all come
    first, whatever ``count``; a-contrario regions whose centroid lies in one of them are not repeated.
    """

    def inside(candidate: SignificantRegion, pixels: np.ndarray) -> bool:
        return bool(pixels[int(round(candidate.centroid_xy[1])), int(round(candidate.centroid_xy[0]))])

    unreported = sorted(
        (
            dataclasses.replace(c, why=WHY_NOT_REPORTED["set_aside" if significant else "not_significant"])
            for cs, significant in ((significance.candidates, False), (significance.regions, True))
            for c in cs
            if not inside(c, mask)
        ),
        key=lambda c: c.log10_nfa,
    )
    if not first:
        return unreported[:count]
    rest = [c for c in unreported if not any(_near(c, f) for f in first)]
    return list(first) + rest[: max(0, count - len(first))]


def _near(candidate: SignificantRegion, region: SignificantRegion) -> bool:
    """The same place: centres closer than the larger region's radius (an area-equivalent disc)."""
    dx = candidate.centroid_xy[0] - region.centroid_xy[0]
    dy = candidate.centroid_xy[1] - region.centroid_xy[1]
    return dx * dx + dy * dy <= max(candidate.area_px, region.area_px) / np.pi
