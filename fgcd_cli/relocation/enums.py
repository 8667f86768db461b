"""Modes, stages, sources and verdicts of relocation, as string enums.

Every value is the exact string the relocation log (``relocation.jsonl``,
``coarse.jsonl``), the visit manifest and the benchmarks have always carried:
``report/``, ``cli/`` and ``bench/`` read them as plain strings, and a
``StrEnum`` member compares equal to, formats as and serialises to its value.
"""

from __future__ import annotations

from enum import StrEnum

__all__ = ["Agreement", "CoarseAction", "EstimateStage", "EstimateSource", "LoopMode", "RelocationMethod"]


class LoopMode(StrEnum):
    """How the rACR loop runs (paper 000, Fig. 2 and its Table 5 baseline)."""

    PARALLEL = "parallel"
    """VSE, alignment and adjustment threads with latest-value hand-over."""
    SERIAL = "serial"
    """The same steps one after the other."""


class RelocationMethod(StrEnum):
    """Which relocation method a revisit runs (``fgcd relocate --method``)."""

    RACR = "racr"
    """rACR (paper 000): 3D alignment of VSE clouds, then the image stage."""
    ACR = "acr"
    """The ACR baseline (Tian et al.): 5-point relative pose, bisection on the scale (:mod:`.acr`)."""
    ACR_H = "acr-h"
    """ACR with the homography-guided step (the paper's H-CR)."""


class EstimateStage(StrEnum):
    """Which stage produced an estimate (``AdjustmentRecord.stage``)."""

    FAST = "fast"
    """Sparse ICP with closed-form scale (:func:`fgcd_cli.alignment.fast_align`)."""
    FINE = "fine"
    """Geometric + photometric refinement (:func:`fgcd_cli.alignment.fine_align`)."""
    IMAGE = "image"
    """PnP on the reference images (:mod:`fgcd_cli.relocation.image.refine`)."""


class EstimateSource(StrEnum):
    """Which estimator a residual or a coarse step rests on."""

    IMAGE = "image"
    """PnP on the reference images."""
    THREE_D = "3d"
    """Alignment of the session cloud to the reference cloud."""
    NONE = ""
    """No estimate (a coarse look-around or pause)."""


class Agreement(StrEnum):
    """How the other estimator compared (``Residual.agreement``); a note may follow ``NOT_CHECKED``."""

    AGREE = "agree"
    DISAGREE = "disagree"
    NOT_CHECKED = "not checked"

    def because(self, note: str) -> str:
        """``"not checked: <note>"``: the verdict with why."""
        return f"{self.value}: {note}"


class CoarseAction(StrEnum):
    """What one step of the active coarse stage did (``CoarseStep.action``)."""

    MOVE = "move"
    DESCEND = "descend"
    LOOK = "look"
    HANDOVER = "handover"
    PAUSE = "pause"
