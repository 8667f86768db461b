"""Inputs of the rACR loop: the reference it drives to and its options."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fgcd_cli.alignment.fast_config import FastAlignConfig, ScaleStepConfig
from fgcd_cli.alignment.fine_config import FineAlignConfig
from fgcd_cli.relocation.enums import LoopMode

__all__ = ["HEARTBEAT_S", "ReferenceData", "RelocationConfig"]

#: Longest silence (s) while the loop waits for an alignment: a progress line at least this often.
HEARTBEAT_S = 5.0


@dataclass(frozen=True, kw_only=True)
class ReferenceData:
    """What relocation needs of a reference observation (all in the ref frame, metres).

    Attributes
    ----------
    points : (N, 3) ndarray
        Reference metric cloud.
    intensities : (N,) ndarray
        Grey value of each point in [0, 1].
    T_ref_camref : (4, 4) ndarray
        The reference camera pose.
    """

    points: np.ndarray
    intensities: np.ndarray
    T_ref_camref: np.ndarray


@dataclass(frozen=True, kw_only=True)
class RelocationConfig:
    """Options of the loop.

    Attributes
    ----------
    mode : LoopMode
        ``"parallel"``: three threads with latest-value hand-over; ``"serial"``:
        everything in turn. A plain string is accepted and checked when the loop starts.
    deterministic : bool
        Step the threads in a fixed order instead of running them side by side
        (:class:`~fgcd_cli.vse.thread.SteppedVse`,
        :class:`~fgcd_cli.relocation.loop.worker.SteppedAlignmentWorker`): the same seeds give the
        same run, and the time on the rig counts the steps, not the wall clock
        (docs/relocation.md, "Reproducibility"). Either mode may be deterministic.
    eta : float
        Stop when ``g = ||M_B - I||_F <= eta`` (paper: 1e-4).
    max_adjustments : int
        Give up after this many adjustments.
    max_step_m, max_step_rad : float
        Largest motion of one adjustment (also enforced by the guard).
    fine : bool
        Run the fine-grained stage after the fast one (``-F`` ablation when False).
    min_points : int
        Current cloud size needed before aligning.
    estimate_timeout_s : float
        Longest wait for a fresh alignment before pausing with an error.
    stop_afd_px : float
        Also stop when the remaining motion, as estimated, would move the
        reference image by less than this many pixels on average (the
        estimated AFD). ``g <= eta`` is the paper's rule; with monocular
        estimates whose noise is above ``eta`` this image-space rule is what
        ends a relocation, at the accuracy the paper scores (AFD in pixels).
    heartbeat_s : float
        Longest silence while the loop waits for an alignment: a progress line at
        least this often.
    """

    mode: LoopMode | str = LoopMode.PARALLEL
    deterministic: bool = False
    eta: float = 1e-4
    max_adjustments: int = 12
    max_step_m: float = 0.05
    max_step_rad: float = math.radians(10.0)
    fine: bool = True
    min_points: int = 500
    estimate_timeout_s: float = 120.0
    stop_afd_px: float = 0.5
    divergence_factor: float = 1.5
    divergence_margin_mm: float = 10.0
    divergence_margin_deg: float = 1.0
    divergence_patience: int = 2
    """Pause with an error when the estimated offset exceeds ``factor x best + margin``
    this many adjustments in a row (the loop should shrink it every time)."""
    max_offset_m: float = 0.25
    max_offset_deg: float = 20.0
    """Pause (and let the image fallback try) when an estimate puts the camera farther than this
    from the reference pose: rACR starts a revisit within a few centimetres (the exploration moves
    4 cm), so such an estimate is a confidently wrong alignment, or a start that needs the active
    coarse stage first (docs/relocation.md, "Far starts"). Trusting it would move the camera
    the wrong way until the divergence rule fires."""
    image_refine: bool = True
    """After the 3D loop converges, refine from the reference images
    (:mod:`fgcd_cli.relocation.image.refine`) when the evidence is strong."""
    image_handover: bool = True
    """Hand the loop to the image stage as soon as the 3D estimate's offset is within its own 1-sigma
    uncertainty (``vse_sigma_rel`` of the depth): a motion that size is mostly the estimate's error,
    and the image stage measures the same offset far more precisely. When the image evidence is
    weak at that point, the 3D loop goes on to its own stop rule (docs/relocation.md, "Stop rules")."""
    image_refine_steps: int = 4
    image_stop_afd_px: float = 0.5
    """The image stage stops when its correction moves the reference image by less than this.
    The same 0.5 px as ``stop_afd_px``: the image measurement itself is only good to about
    0.3 px across lightings, so a lower bar makes the stage chase its own noise, each step
    costing seconds and millimetres of motion for no gain (docs/lab/2026-11-25-code-comment-measurements.md,
    "Relocation")."""
    image_fallback: bool = True
    """When the 3D alignment stays untrustworthy (degenerate geometry such as a
    flat wall, too few inliers, divergence), try the image stage before pausing:
    it needs no alignment of the current cloud, only the reference images and
    cloud. It acts only on strong evidence; otherwise the loop pauses as before."""
    image_fallback_steps: int = 6
    untrusted_patience: int = 6
    untrusted_min_wait_s: float = 20.0
    """Pause early (instead of waiting ``estimate_timeout_s``) after this many
    consecutive untrustworthy estimates, once at least this long was waited."""
    degenerate_patience: int = 3
    """Pause at once after this many consecutive estimates flagged as degenerate
    geometry (plane, sphere, body of revolution): a property of the scene, which
    waiting does not cure, unlike too few inliers in a young map."""
    tolerance_mm: float | None = None
    """Largest remaining camera offset (mm) any stage may stop on. ``None``: the model of
    :func:`fgcd_cli.relocation.stop_rule.tolerance_mm` (the sideways camera shift that moves
    the object's image by ``stop_afd_px`` at the reference camera's distance;
    docs/relocation.md, "Stop rules")."""
    vse_sigma_rel: float = 0.01
    """1-sigma uncertainty of a 3D (cloud-alignment) estimate of the camera position, as a
    fraction of the camera distance: two monocular sessions place their cameras relative to
    their clouds to about 1 % of the depth (docs/relocation.md, "Final image stage")."""
    agreement_k: float = 2.0
    """Two estimates agree when their camera positions differ by at most ``k`` times the
    RMS radius of their combined uncertainty
    (:func:`fgcd_cli.relocation.stop_rule.estimates_agree`)."""
    agreement_wait_s: float = 30.0
    """Longest wait for a 3D estimate of the view after the last image motion, to check
    agreement; without one, the check is reported as not done."""
    heartbeat_s: float = HEARTBEAT_S
    fast_align: FastAlignConfig = FastAlignConfig(scale=ScaleStepConfig(symmetric=True))
    """Options of every fast alignment of the loop (the paper's ``rACR-S`` ablation keeps the scale). The
    scale is measured both ways: the loop's last estimates set the final pose, and the one-way scale is
    low on VSE clouds (docs/alignment.md, "Fast alignment")."""
    fine_align: FineAlignConfig = FineAlignConfig()
    """Options of every fine alignment of the loop (the paper's alpha, and ``rACR-P``)."""

    @property
    def loop_name(self) -> str:
        """How the loop runs, as a log line says it: ``parallel``, ``serial``, ``parallel, deterministic``."""
        return f"{self.mode}, deterministic" if self.deterministic else str(self.mode)
