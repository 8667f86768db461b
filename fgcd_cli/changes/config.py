"""Options of the change detector (:func:`fgcd_cli.changes.detect.detect_changes`), grouped by stage.

Each section is a frozen, keyword-only dataclass whose defaults are the shipped
detector's (``docs/change-detection.md``, "Change detection pipeline"). :class:`DetectionConfig` holds one of
each; :meth:`DetectionConfig.from_options` builds one from the flat keyword
options the detector has always accepted (``k_high=...``, ``dense=False``...),
so that every section field keeps its historical keyword name.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from fgcd_cli.errors import UserInputError


class DecisionRule(StrEnum):
    """The rule that decides the change regions (``settings["decision"]``)."""

    HYSTERESIS = "hysteresis"
    """Robust hysteresis threshold on the score (:func:`fgcd_cli.changes.threshold.robust_hysteresis_threshold`)."""
    ACONTRARIO = "acontrario"
    """Number-of-false-alarms test (:func:`fgcd_cli.changes.significance.acontrario_decision`)."""


def _rule(value) -> DecisionRule:
    try:
        return DecisionRule(value)
    except ValueError:
        raise UserInputError(f"unknown decision rule {value!r}: use hysteresis or acontrario") from None


#: ε, the tolerated number of false regions per image under the pair's own no-change model: the one
#: default of every a-contrario decision and of every report that says whether a region is significant
#: (docs/change-detection.md, "Significance of each region (a-contrario)").
EPSILON = 1.0

#: The contrast floor of a reported region (:mod:`fgcd_cli.changes.contrast`). Rule: below half the
#: contrast of the faintest annotated change of the real development groups, taken leaving any one group
#: out, so that a change half as strong as any annotated one is still reported (the figures:
#: docs/change-detection.md, "Change detection pipeline", step 9). The pair's own null model sets the
#: level in units of its noise; a pair cleaner than a real revisit (the simulator's, a camera that did
#: not move) would otherwise report differences of a few percent.
MIN_REGION_CONTRAST = 0.2


@dataclass(frozen=True, kw_only=True)
class RegistrationConfig:
    """Bringing the current stack into the reference frame."""

    register: bool = True
    """Register the current images on the reference (homography, ECC on gradients)."""
    registration_lighting: int = 0
    """Index of the lighting the registration is estimated on (the most diffuse one is best)."""
    dense: bool = True
    """After the homography, estimate the residual parallax as a smooth dense flow
    (:func:`fgcd_cli.changes.dense.refine.refine_dense`) and resample the current images through both at
    once; pixels it cannot align are *not compared* (``ChangeResult.not_compared``) instead of changed."""


@dataclass(frozen=True, kw_only=True)
class ScoreConfig:
    """The fused per-pixel score (:mod:`fgcd_cli.changes.score`)."""

    gain_sigma_px: float = 12.0
    """Scale of the smooth light-gain field removed per lighting, pixels."""
    shift_radius_px: int = 1
    """Residual misregistration absorbed by the difference cue, pixels."""
    structure_weight: float = 0.0
    """Weight in [0, 1] of the gain-invariant local-NCC cue against the colour difference cue."""
    smooth_sigma_px: float = 2.0
    """Gaussian smoothing of the fused score, pixels."""
    fine_smooth_sigma_px: float = 1.0
    """A second, finer smoothing of the same fused score, tested beside the main one with the
    number of tests counted over both (0: off; must be below ``smooth_sigma_px``). A change smaller
    than the main smoothing's correlation area (4 pi sigma^2 px) is one sample there; at the finer
    scale it holds several (``docs/change-detection.md``, "Two scales"). 1 px: the difference cue
    already tolerates ``shift_radius_px`` = 1 px, so a finer smoothing resolves nothing more."""
    robust_gain_rounds: int = 1
    """Re-estimations of the gain field without the pixels the previous score flags as suspect."""
    edge_tolerance_px: int = 0
    """Near strong reference edges (3x3 intensity range above ``edge_contrast`` times its image
    median, grown by ``edge_tolerance_px``) a difference counts only if neither image lies within
    the other's min/max envelope over ``edge_tolerance_px``: a relocation residual of a few mm
    thins, blurs or moves thin structures there by up to ~1-2 px (see
    :func:`fgcd_cli.changes.cues.maps.edge_tolerant_difference`). 0 (default) disables it: it also hides
    small changes on strong texture edges, so it is for pairs known to be relocated only to a few
    mm (campaign diffs use the region-level :class:`EdgeCheckConfig` instead)."""
    edge_contrast: float = 3.0
    """Strong reference edges: 3x3 intensity range above this times its image median."""


@dataclass(frozen=True, kw_only=True)
class RegionConfig:
    """The decision on the score and the cleaning of its regions."""

    decision: DecisionRule = DecisionRule.ACONTRARIO
    """Which rule decides the regions. Either way every region carries its a-contrario significance
    (``ChangeRegion.log10_nfa``) and the strongest regions not reported are kept as candidates."""
    k_high: float = 20.0
    """Hysteresis constants (also the suspect threshold of the robust gain rounds)."""
    k_low: float = 10.0
    epsilon: float = EPSILON
    """A-contrario: tolerated false regions per image under the pair's own null."""
    seed_p: float = 0.005
    """A-contrario: lowest level tested (empirical tail probability)."""
    extent_fraction: float = 0.3
    """A-contrario: extent of a region, as a fraction of its peak excess."""
    edge_fraction: float = 0.2
    """Hysteresis: region trimming (:func:`fgcd_cli.changes.regions.refine_to_local_peak`; 0 disables)."""
    edge_radius_px: int = 6
    min_region_px: int = 30
    """Regions up to this size are dropped."""
    max_hole_px: int = 30
    """Holes up to this size are filled."""
    min_contrast: float = MIN_REGION_CONTRAST
    """Regions whose contrast (:mod:`fgcd_cli.changes.contrast`) stays below this in every lighting are
    not reported (they stay candidates); 0 disables. See :data:`MIN_REGION_CONTRAST`."""
    clip_check: bool = True
    """Regions whose evidence comes from clipped pixels only (a lighting saturates there in one
    observation: a specular highlight) are not reported (they stay candidates); see
    :mod:`fgcd_cli.changes.clip_check`. Count: ``settings["clipped_regions"]``."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "decision", _rule(self.decision))


@dataclass(frozen=True, kw_only=True)
class CueConfig:
    """Relief / colour labels from photometric stereo (:mod:`fgcd_cli.changes.cues.labels`)."""

    cues: bool = True
    """Fit photometric stereo to both stacks and label each region relief, colour or both; needs
    three directional lightings besides the ambient one."""
    ambient_index: int | None = 0
    """Index of the ambient lighting in the stacks (None: all are directional)."""
    light_dirs: np.ndarray | None = field(default=None, compare=False)
    """Kx3 known light directions in the camera frame (calibrated photometric stereo)."""


@dataclass(frozen=True, kw_only=True)
class EdgeCheckConfig:
    """The region-level edge check (:mod:`fgcd_cli.changes.edge_check`)."""

    edge_check_px: int = 0
    """Tolerated edge shift, pixels; 0 disables the check. A region mostly in the reference's
    strong-edge band, explained by a shift of up to ``edge_check_px`` and shaped like a band along
    the edge is set aside (its pixels leave the mask; it stays a candidate). Unlike
    ``ScoreConfig.edge_tolerance_px`` it leaves the pixels of every other region untouched. Counts:
    ``settings["edge_explained_regions"]`` (set aside), ``settings["edge_compact_kept_regions"]`` (kept)."""
    edge_check_band_fraction: float = 0.8
    """Rule 1: fraction of a region's pixels in the strong-edge band."""


@dataclass(frozen=True, kw_only=True)
class TilingConfig:
    """The tile-by-tile path for large frames (:func:`fgcd_cli.changes.tiled.pipeline.detect_changes_tiled`)."""

    tile_px: int = 2048
    """Largest tile side, pixels."""
    overlap_px: int | None = None
    """Context read around each tile; None: ``ceil(3 * 4 * gain_sigma_px) + shift_radius_px + 2``."""
    work_px: int = 1600
    """Long side of the working resolution (registration, dense refinement, cue labels)."""
    workers: int = 2
    """Threads over tiles."""
    decision_px: int = 1000
    """Long side at which the a-contrario scan runs."""


_SECTIONS = {
    "registration": RegistrationConfig,
    "score": ScoreConfig,
    "regions": RegionConfig,
    "cue_labels": CueConfig,
    "edge_check": EdgeCheckConfig,
    "tiling": TilingConfig,
}

OPTION_SECTION = {f.name: section for section, cls in _SECTIONS.items() for f in dataclasses.fields(cls)}
"""Flat keyword option -> the :class:`DetectionConfig` section that holds it."""


@dataclass(frozen=True, kw_only=True)
class DetectionConfig:
    """Every option of the change detector, one section per stage (see each section)."""

    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
    score: ScoreConfig = field(default_factory=ScoreConfig)
    regions: RegionConfig = field(default_factory=RegionConfig)
    cue_labels: CueConfig = field(default_factory=CueConfig)
    edge_check: EdgeCheckConfig = field(default_factory=EdgeCheckConfig)
    tiling: TilingConfig = field(default_factory=TilingConfig)

    @classmethod
    def from_options(
        cls, config: DetectionConfig | None = None, /, *, allowed: frozenset[str] | None = None, **options
    ) -> DetectionConfig:
        """``config`` (default: the shipped one) with flat keyword options replacing its fields.

        ``allowed`` restricts the option names (the tiled path accepts fewer); an
        unknown name raises ``TypeError``, as an unknown keyword argument does.
        """
        config = cls() if config is None else config
        grouped: dict[str, dict] = {}
        for name, value in options.items():
            section = OPTION_SECTION.get(name)
            if section is None or (allowed is not None and name not in allowed):
                raise TypeError(f"unexpected keyword argument {name!r}")
            grouped.setdefault(section, {})[name] = value
        return dataclasses.replace(
            config,
            **{section: dataclasses.replace(getattr(config, section), **values) for section, values in grouped.items()},
        )
