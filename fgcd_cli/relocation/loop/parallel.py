"""The rACR relocation loop: VSE thread, alignment thread, adjustment thread (paper 000, Fig. 2).

* the VSE thread (``fgcd_cli.vse.thread.VseThread``) keeps the latest camera pose
  and cloud of the current session;
* the alignment thread (:class:`~fgcd_cli.relocation.loop.worker.AlignmentWorker`) aligns
  the latest cloud to the reference, fast then fine, again and again, and publishes
  its latest similarity ``T_ref_cur``;
* the adjustment thread (the caller of :func:`relocate`) combines the latest pose
  and the latest similarity into a hand motion (Eq. 3, see
  :mod:`fgcd_cli.relocation.adjustment`), sends it through the motion guard, and
  stops by the stop rule (:mod:`fgcd_cli.relocation.stop_rule`).

Hand-over between threads is "latest value" under a lock: nobody waits for
anybody except the adjustment thread, which needs one estimate newer than its
previous motion and waits for it on the alignment thread's condition variable. ``mode="serial"`` runs the same steps one after the other
(the paper's Table 5 baseline), with the VSE thread still running beside them. ``deterministic=True``
steps all three in a fixed order in one thread (docs/relocation.md, "Reproducibility"). A failing VSE or alignment pauses motion
instead of guessing; the image stage (:mod:`fgcd_cli.relocation.image.stage`)
takes over once the 3D estimate can no longer resolve the remaining offset
(``RelocationConfig.image_handover``), refines a converged result, or falls back
when the 3D loop paused.

This module composes the stages.
"""

from __future__ import annotations

import time

import numpy as np

from fgcd_cli.errors import AlgorithmError
from fgcd_cli.relocation.config import HEARTBEAT_S, RelocationConfig
from fgcd_cli.relocation.enums import Agreement, EstimateSource, LoopMode
from fgcd_cli.relocation.image.stage import image_stage
from fgcd_cli.relocation.log import AdjustmentRecord, RelocationResult
from fgcd_cli.relocation.loop.context import LoopContext, LoopState
from fgcd_cli.relocation.loop.worker import AlignmentWorker, SteppedAlignmentWorker
from fgcd_cli.relocation.racr.aligner import AlignmentProblem, align_once
from fgcd_cli.relocation.racr.stage import racr_loop
from fgcd_cli.relocation.stop_rule import (
    Residual,
    reference_depth_m,
)

__all__ = [
    "HEARTBEAT_S",
    "AlignmentProblem",
    "AlignmentWorker",
    "AdjustmentRecord",
    "RelocationResult",
    "align_once",
    "reference_depth_m",
    "relocate",
]


def _check_mode(config: RelocationConfig) -> LoopMode:
    try:
        return LoopMode(config.mode)
    except ValueError:
        raise AlgorithmError(f"unknown relocation mode {config.mode!r}") from None


def _start_worker(ctx: LoopContext) -> AlignmentWorker:
    """The alignment thread; deterministic runs step it in turn with the VSE (no thread)."""
    kind = SteppedAlignmentWorker if ctx.config.deterministic else AlignmentWorker
    return kind(
        vse=ctx.session.vse, problem=ctx.problem(), init=ctx.init, min_points=ctx.config.min_points, aligner=ctx.aligner
    ).start()


def _run_stages(ctx: LoopContext, st: LoopState) -> RelocationResult:
    """The 3D loop, then the image refinement (converged) or the image fallback (paused)."""
    config = ctx.config
    try:
        result = racr_loop(ctx, st)
        if result.handed_over:
            taken = image_stage(ctx, st, result, fallback=False, handed_over=True)
            if taken is not None:
                return taken
            if result.alignment_set_aside == "inconsistent":  # a 3D loop that follows the camera cannot go on
                raise AlgorithmError(f"{result.reason}; the image stage could not take over")
            # the image evidence could not take over where the 3D estimate stopped resolving the offset:
            # the 3D loop goes on to its own stop rule (then the usual refinement)
            ctx.say("the image stage could not take over: the 3D loop goes on")
            result = racr_loop(ctx, st, handover=False)
    except AlgorithmError as paused:
        # The 3D loop paused (degenerate geometry, too few inliers, divergence). Without
        # the fallback, or when it finds no strong evidence either, the pause stands.
        if not (config.image_fallback and ctx.can_image):
            raise
        result = RelocationResult(False, str(paused), len(st.records))
    if st.worker is not None and not result.converged:
        st.worker.stop()  # the 3D estimates are not used any more: free the CPU for matching
        st.worker = None
    if result.converged and config.image_refine and ctx.can_image:
        return image_stage(ctx, st, result, fallback=False)
    if not result.converged and config.image_fallback and ctx.can_image:
        return image_stage(ctx, st, result, fallback=True)
    if result.converged and st.records:
        last = st.records[-1]
        result.residual = Residual(
            offset_mm=last.offset_mm,
            sigma_mm=st.sigma3d_mm,
            tolerance_mm=st.tol_mm,
            source=EstimateSource.THREE_D,
            agreement=Agreement.NOT_CHECKED.because("no image stage"),
        )
        result.reason = f"{result.reason}; {result.residual.text()}"
    return result


def relocate(ctx: LoopContext) -> RelocationResult:
    """Drive the camera to the reference pose.

    Parameters
    ----------
    ctx : LoopContext
        The session, the reference, the options and the injected aligner and image refiner.

    Returns
    -------
    RelocationResult
        Converged or not, with the log records, the final estimated camera pose, the
        times (wall, session on the rig, platform, frame synthesis) and the residual.

    Raises
    ------
    AlgorithmError
        The loop paused and no image evidence took over.
    """
    t_start = time.monotonic()
    mode = _check_mode(ctx.config)
    st = LoopState.for_context(ctx, t_start=t_start)
    if mode == LoopMode.PARALLEL:
        st.worker = _start_worker(ctx)
    try:
        result = _run_stages(ctx, st)
    finally:
        if st.worker is not None:
            st.worker.stop()
    records, timing = st.records, ctx.session.timing
    result.records = records
    result.final_T_ref_cam = np.array(records[-1].T_ref_cam) if records else None
    result.wall_s = time.monotonic() - t_start
    result.session_s = timing.total_s
    result.platform_s = timing.platform_s
    result.synthetic_s = timing.synthetic_s
    return result
