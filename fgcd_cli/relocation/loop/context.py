"""What the stages of one relocation share: its inputs (:class:`LoopContext`) and its running state (:class:`LoopState`).

The aligner and the image refiner are values of the context, so a test (or
another rig) substitutes them by passing others.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from fgcd_cli.relocation.config import ReferenceData, RelocationConfig
from fgcd_cli.relocation.log import AdjustmentRecord
from fgcd_cli.relocation.protocols import CameraModel, ImageRefiner
from fgcd_cli.relocation.racr.aligner import Aligner, AlignmentProblem, align_once
from fgcd_cli.relocation.session import VseSession
from fgcd_cli.relocation.stop_rule import reference_depth_m, tolerance_mm
from fgcd_core.sim3 import Sim3

if TYPE_CHECKING:
    from fgcd_cli.relocation.loop.worker import AlignmentWorker

__all__ = ["LoopContext", "LoopState", "say"]


def say(session, text: str) -> None:
    """A progress line through the session's plain callback (the CLI renders it)."""
    if getattr(session, "on_event", None):
        session.on_event(text)


@dataclass(frozen=True, kw_only=True)
class LoopContext:
    """The inputs of :func:`fgcd_cli.relocation.loop.parallel.relocate`.

    Attributes
    ----------
    session : VseSession
        A running VSE session (exploration done, scale known).
    reference : ReferenceData
        Reference cloud and camera.
    ref_index : fgcd_cli.alignment.ReferenceIndex or None
        Search structure over the reference cloud, built once.
    camera : CameraModel or None
        Intrinsics of the current camera.
    scale : float
        Metres per VSE map unit of this session.
    T_flange_cam : (4, 4) ndarray
        Hand-eye (identity for the ``--no-handeye`` variant).
    init : Sim3
        Starting similarity ``T_ref_cur``.
    config : RelocationConfig
    evaluate : callable() -> dict, optional
        Evaluation hook (simulation only, outside the algorithm): true errors written
        into each log record.
    on_record : callable(AdjustmentRecord), optional
        Called with each record (live display, log file).
    reference_images : dict of name -> (H, W) ndarray, optional
        Undistorted reference images, for the image stage.
    grab_current : callable() -> (H, W) ndarray, optional
        The current undistorted grey image, for the image stage.
    aligner : Aligner
        One fast (then fine) alignment of a VSE state (default
        :func:`~fgcd_cli.relocation.racr.aligner.align_once`).
    image_refiner : ImageRefiner, optional
        The image measurement (default
        :func:`~fgcd_cli.relocation.image.refine.refine_from_reference_image`).
    same_light : bool
        Whether the current image is taken under the reference images' light.
    image_prior_sigma_mm : float or None
        Set when the exploration ended where the image localizer put the reference pose
        (:mod:`fgcd_cli.app.guided_start`): the localizer's 1-sigma (RMS radius, mm) of that
        estimate. The camera then stands at the reference as far as the localizer knows, and
        the first 3D estimate is checked against it (docs/relocation.md, "A disputed start").
    """

    session: VseSession
    reference: ReferenceData
    ref_index: object
    camera: CameraModel | None
    scale: float
    T_flange_cam: np.ndarray
    init: Sim3
    config: RelocationConfig = RelocationConfig()
    evaluate: Callable[[], dict] | None = None
    on_record: Callable[[AdjustmentRecord], None] | None = None
    reference_images: dict[str, np.ndarray] | None = None
    grab_current: Callable[[], np.ndarray] | None = None
    aligner: Aligner = align_once
    image_refiner: ImageRefiner | None = None
    image_prior_sigma_mm: float | None = None
    same_light: bool = False
    """The current image is taken under the light of the reference images (a lamp the rig carries): the
    image stage's matches then share a smaller common error (``refine.SAME_LIGHT_COMMON_PX``)."""

    @property
    def can_image(self) -> bool:
        """The image stage has what it needs: reference images and a way to grab the current one."""
        return bool(self.reference_images) and self.grab_current is not None

    def problem(self) -> AlignmentProblem:
        """The fixed part of every alignment of this run."""
        return AlignmentProblem(
            reference=self.reference,
            ref_index=self.ref_index,
            camera=self.camera,
            scale=self.scale,
            fine=self.config.fine,
            fast_config=self.config.fast_align,
            fine_config=self.config.fine_align,
        )

    def refiner(self, *, unresolved_mm: float = 0.0) -> ImageRefiner:
        """The image refiner: the injected one, else the default (imported on first use: OpenCV's SIFT).

        ``unresolved_mm``: the offset the 3D estimate cannot tell from none (``agreement_k`` times its
        1-sigma). The default refiner trusts corrections up to it on ordinary evidence: the image stage
        exists to measure what the 3D loop cannot resolve, so its ordinary limit
        (``ImageRefineConfig.max_motion_m``) never stops short of that (docs/relocation.md, "Stop rules").
        """
        if self.image_refiner is not None:
            return self.image_refiner
        from functools import partial

        from fgcd_cli.relocation.image.refine import (
            CROSS_LIGHT_COMMON_PX,
            SAME_LIGHT_COMMON_PX,
            ImageRefineConfig,
            refine_from_reference_image,
        )

        base = ImageRefineConfig(common_error_px=SAME_LIGHT_COMMON_PX if self.same_light else CROSS_LIGHT_COMMON_PX)
        limit_m = max(base.max_motion_m, unresolved_mm / 1000.0) if math.isfinite(unresolved_mm) else base.max_motion_m
        return partial(refine_from_reference_image, config=replace(base, max_motion_m=limit_m))

    def say(self, text: str) -> None:
        """A progress line (see :func:`say`)."""
        say(self.session, text)

    def truth(self) -> dict | None:
        """The evaluation hook's truth for a log record (None without one)."""
        return self.evaluate() if self.evaluate else None


@dataclass
class LoopState:
    """What the stages of one run share while it goes.

    Attributes
    ----------
    tol_mm : float
        Stop tolerance on the remaining offset (:func:`~fgcd_cli.relocation.stop_rule.tolerance_mm`).
    sigma3d_mm : float
        1-sigma uncertainty of a 3D estimate of the camera position, mm (``vse_sigma_rel`` x depth).
    t_start : float
        ``time.monotonic()`` at the start of the run.
    records : list of AdjustmentRecord
        The log so far.
    last_T_ref_cur : Sim3 or None
        The 3D loop's latest trustworthy estimate.
    moved_at_frame : int
        VSE frame count when the 3D loop's last motion ended (-1 before any).
    worker : AlignmentWorker or None
        The alignment thread (parallel mode, while it runs).
    prior_checked : bool
        The first 3D estimate was compared with the image localizer's (once per run).
    map_estimates : list of AlignmentEstimate
        The 3D loop's trustworthy estimates so far that agree with each other (one per serial;
        :func:`~fgcd_cli.relocation.racr.consistency.estimate_spread`).
    """

    tol_mm: float
    sigma3d_mm: float
    t_start: float = field(default_factory=time.monotonic)
    records: list[AdjustmentRecord] = field(default_factory=list)
    last_T_ref_cur: Sim3 | None = None
    moved_at_frame: int = -1
    worker: AlignmentWorker | None = None
    prior_checked: bool = False
    map_estimates: list = field(default_factory=list)

    @classmethod
    def for_context(cls, ctx: LoopContext, *, t_start: float) -> LoopState:
        """Tolerance and 3D uncertainty from the reference (docs/relocation.md, "Stop rules")."""
        config, reference = ctx.config, ctx.reference
        tol = (
            config.tolerance_mm
            if config.tolerance_mm is not None
            else tolerance_mm(reference.points, reference.T_ref_camref, ctx.camera, stop_afd_px=config.stop_afd_px)
        )
        depth = reference_depth_m(reference.points, reference.T_ref_camref)
        sigma3d = 1000.0 * config.vse_sigma_rel * depth if math.isfinite(depth) else math.inf
        return cls(tol_mm=tol, sigma3d_mm=sigma3d, t_start=t_start)

    def add(self, ctx: LoopContext, record: AdjustmentRecord) -> None:
        """Log a record and hand it to ``ctx.on_record``."""
        self.records.append(record)
        if ctx.on_record:
            ctx.on_record(record)

    def elapsed_s(self) -> float:
        """Wall time since the start of the run."""
        return time.monotonic() - self.t_start
