"""What a revisit's relocation is asked to do (``RelocateRequest``) and the hooks a benchmark or the demo adds (``RelocateHooks``)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from fgcd_cli.relocation.acr.baseline import AcrConfig
from fgcd_cli.relocation.coarse.config import CoarseConfig
from fgcd_cli.relocation.config import ReferenceData, RelocationConfig
from fgcd_cli.relocation.enums import RelocationMethod
from fgcd_cli.relocation.log import AdjustmentRecord


@dataclass(frozen=True, kw_only=True)
class RelocateRequest:
    """How to relocate to a station's reference and what the visit records.

    Attributes
    ----------
    config : RelocationConfig
        The rACR loop's options.
    lightings : list of str
        Lightings of the visit's images.
    explore_m : float
        Exploration amplitude of the session start, metres.
    explore_legs : int
        Exploration legs of the session start.
    metadata : dict or None
        Extra entries of the visit's manifest metadata.
    guided : bool
        Explore toward the image localizer's estimate of the reference (:mod:`fgcd_cli.app.guided_start`).
    coarse : CoarseConfig or None
        The active coarse stage's options (paper 001); None leaves it out (the
        loop then pauses on a far start).
    earlier_log : tuple of dict
        Adjustments of an interrupted visit this one continues, written first in its log.
    method : RelocationMethod
        rACR, or the ACR baseline (``acr``, ``acr-h``: :mod:`fgcd_cli.app.relocate_acr`).
    acr : AcrConfig or None
        The ACR loop's options (None: its defaults, the model following ``method``).
    """

    config: RelocationConfig
    lightings: list[str]
    explore_m: float = 0.04
    explore_legs: int = 3
    guided: bool = True
    metadata: dict | None = None
    coarse: CoarseConfig | None = field(default_factory=CoarseConfig)
    earlier_log: tuple[dict, ...] = ()
    method: RelocationMethod = RelocationMethod.RACR
    acr: AcrConfig | None = None


@dataclass(frozen=True, kw_only=True)
class RelocateHooks:
    """Callbacks of a relocation: evaluation (simulator only) and each adjustment as it is made.

    Attributes
    ----------
    evaluate : callable() -> dict, or None
        The simulator's truth at the current pose, logged beside each estimate.
    on_record : callable(AdjustmentRecord), or None
        Each adjustment of the loop.
    evaluation : callable() -> dict, or None
        The truth written into the visit (``evaluation/sim_truth.json``).
    reference_override : callable(ReferenceData) -> ReferenceData, or None
        A benchmark's change of the reference cloud before rACR sees it (paper 000 Fig. 4:
        noise on the reference points); the stored reference is never changed.
    """

    evaluate: Callable[[], dict] | None = None
    on_record: Callable[[AdjustmentRecord], None] | None = None
    evaluation: Callable[[], dict] | None = None
    reference_override: Callable[[ReferenceData], ReferenceData] | None = None
