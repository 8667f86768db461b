"""The 3D rACR loop (paper 000, Fig. 2): align, adjust (Eq. 3), until the stop rule holds.

Parallel mode moves on the latest trustworthy estimate (latest-value
hand-over) and decides to stop only on an estimate of the view after the last
motion; serial mode aligns the current view before every motion (the paper's
Table 5 baseline). The loop pauses (raises :class:`~fgcd_cli.errors.AlgorithmError`)
on a failing alignment, an estimate beyond any revisit start, or a diverging offset.
"""

from __future__ import annotations

import time

import numpy as np

from fgcd_cli.errors import AlgorithmError
from fgcd_cli.relocation.adjustment import Adjustment, compute_adjustment
from fgcd_cli.relocation.enums import LoopMode
from fgcd_cli.relocation.log import AdjustmentRecord, RelocationResult
from fgcd_cli.relocation.loop.context import LoopContext, LoopState
from fgcd_cli.relocation.racr.aligner import AlignmentEstimate, scaled_pose
from fgcd_cli.relocation.racr.consistency import estimate_spread
from fgcd_cli.relocation.racr.estimates import DegenerateGeometry, align_now, wait_for_estimate
from fgcd_cli.relocation.stop_rule import estimated_afd_px, estimates_agree, offset_vector_mm
from fgcd_cli.vse.types import VseStatus
from fgcd_core.se3 import pose_distance

__all__ = ["racr_loop"]


class _Divergence:
    """Convergence check (paper §3.7: each adjustment shrinks the offset while the hand-eye
    rotation error is below 45 deg). An estimate that keeps growing means the estimates or
    the hand-eye are wrong: stop rather than wander next to the object."""

    def __init__(self):
        self.best: tuple[float, float] | None = None  # smallest estimated remaining offset so far (mm, deg)
        self.growths = 0

    def check(self, adj: Adjustment, ctx: LoopContext) -> None:
        """Raise AlgorithmError after ``divergence_patience`` growths beyond ``factor x best + margin`` in a row."""
        c, best = ctx.config, self.best
        if best is not None and (
            adj.offset_mm > c.divergence_factor * best[0] + c.divergence_margin_mm
            or adj.offset_deg > c.divergence_factor * best[1] + c.divergence_margin_deg
        ):
            self.growths += 1
            if self.growths >= c.divergence_patience:
                raise AlgorithmError(
                    f"relocation is diverging, motion paused: the estimated offset grew to {adj.offset_mm:.1f} mm / "
                    f"{adj.offset_deg:.2f} deg (best {best[0]:.1f} mm / {best[1]:.2f} deg); "
                    "check the hand-eye calibration and the scene (symmetric or flat objects defeat 3D alignment)"
                )
        else:
            self.growths = 0
        if best is None or adj.offset_mm < best[0]:
            self.best = (adj.offset_mm, adj.offset_deg)


def _adjustment(ctx: LoopContext, est: AlignmentEstimate, state) -> tuple[Adjustment, float]:
    """Eq. 3 for the estimate and the VSE's pose, with its estimated AFD (px)."""
    c, reference = ctx.config, ctx.reference
    adj = compute_adjustment(
        T_ref_cur=est.T_ref_cur,
        T_cur_cam=scaled_pose(state.T_map_cam, ctx.scale),
        T_ref_camref=reference.T_ref_camref,
        T_flange_cam=ctx.T_flange_cam,
        max_step_m=c.max_step_m,
        max_step_rad=c.max_step_rad,
    )
    return adj, estimated_afd_px(reference.points, reference.T_ref_camref, adj.T_ref_cam, ctx.camera)


def _stops(ctx: LoopContext, st: LoopState, adj: Adjustment, afd_est_px: float) -> bool:
    """The stop rule (docs/relocation.md, "Stop rules"): ``g <= eta`` or the AFD rule, and the offset within tolerance."""
    c = ctx.config
    return (adj.g <= c.eta or afd_est_px <= c.stop_afd_px) and adj.offset_mm <= st.tol_mm


def _hands_over(ctx: LoopContext, st: LoopState, adj: Adjustment) -> bool:
    """The 3D estimate cannot resolve what remains (its offset within its own 1-sigma uncertainty, which is
    above the tolerance) and the image stage can measure it (``RelocationConfig.image_handover``)."""
    c = ctx.config
    return (
        c.image_handover
        and c.image_refine
        and ctx.can_image
        and st.sigma3d_mm > st.tol_mm
        and adj.offset_mm <= st.sigma3d_mm
    )


def _against_prior(ctx: LoopContext, st: LoopState, adj: Adjustment) -> RelocationResult | None:
    """The first 3D estimate against the image localizer's, when the exploration ended at the latter's estimate of
    the reference (``LoopContext.image_prior_sigma_mm``): the camera stands at the reference within the
    localizer's uncertainty. Disagreement beyond ``agreement_k`` times both uncertainties
    (:func:`~fgcd_cli.relocation.stop_rule.estimates_agree`) hands the loop to the image stage before any 3D
    motion, which then stops without the alignment's agreement (docs/relocation.md, "A disputed start").
    Agreement combines the two (:func:`_combined`). None when the 3D estimate stands, or there is nothing to check."""
    c = ctx.config
    if not _at_prior(ctx, st):
        return None
    st.prior_checked = True
    offset_3d = offset_vector_mm(adj.T_ref_cam, ctx.reference.T_ref_camref)
    ok, dist, bound = estimates_agree(offset_3d, st.sigma3d_mm, np.zeros(3), ctx.image_prior_sigma_mm, k=c.agreement_k)
    if ok:
        return _combined(ctx, st, float(np.linalg.norm(offset_3d)))
    out = RelocationResult(
        False,
        f"the first 3D estimate puts the camera {dist:.1f} mm from where the image "
        f"localizer led the exploration (> {bound:.1f} mm, both uncertainties): "
        "handed to the image stage, the 3D alignment disputed",
        st.records[-1].iteration,
    )
    out.handed_over, out.alignment_set_aside = True, "disputed"
    return out


def _combined(ctx: LoopContext, st: LoopState, offset_3d_mm: float) -> RelocationResult | None:
    """Two agreeing estimates of the camera's offset, the 3D one and the localizer's (0, where the exploration
    ended), combine with inverse-variance weights: ``|d| = |d_3d| s_img^2 / (s_img^2 + s_3d^2)``. When that
    leaves the camera within the 3D estimate's own 1-sigma, the 3D estimate is not acted on: the image stage
    takes over as in :func:`_hands_over` (docs/relocation.md, "A disputed start"). None otherwise (an unknown
    localizer uncertainty combines nothing)."""
    s_img, s_3d = float(ctx.image_prior_sigma_mm), st.sigma3d_mm
    if not (np.isfinite(s_img) and np.isfinite(s_3d) and s_3d > st.tol_mm):
        return None
    combined_mm = offset_3d_mm * s_img**2 / (s_img**2 + s_3d**2)
    if combined_mm > s_3d:
        return None
    out = RelocationResult(
        False,
        f"the first 3D estimate ({offset_3d_mm:.1f} ± {s_3d:.1f} mm) agrees with the "
        f"image localizer that led the exploration (0 ± {s_img:.1f} mm); combined, "
        f"{combined_mm:.1f} mm: handed to the image stage",
        st.records[-1].iteration,
    )
    out.handed_over = True
    return out


def _follows_camera(
    ctx: LoopContext, st: LoopState, est: AlignmentEstimate, state, iteration: int, handover: bool
) -> RelocationResult | None:
    """The new estimate against the run's earlier ones, all of one map-to-reference transform
    (:mod:`~fgcd_cli.relocation.racr.consistency`). When two disagree beyond their uncertainties, the alignment's
    estimate moves with the camera and following it walks the camera away: the image stage takes over without
    the alignment (``alignment_set_aside`` "inconsistent"), else the loop pauses (docs/relocation.md,
    "Estimates that follow the camera"). None when they agree."""
    c = ctx.config
    earlier = [e.T_ref_cur for e in st.map_estimates if e.serial != est.serial]
    spread = estimate_spread(
        est.T_ref_cur, earlier, scaled_pose(state.T_map_cam, ctx.scale), sigma_mm=st.sigma3d_mm, k=c.agreement_k
    )
    if spread.agree:
        if all(e.serial != est.serial for e in st.map_estimates):
            st.map_estimates.append(est)
        return None
    text = (
        f"the 3D estimates follow the camera: estimate {iteration} puts it {spread.distance_mm:.1f} mm from "
        f"where an earlier estimate of the same map-to-reference transform puts it (> {spread.bound_mm:.1f} mm, "
        "both uncertainties)"
    )
    if not (handover and c.image_handover and c.image_refine and ctx.can_image):
        raise AlgorithmError(f"{text}; motion paused")
    out = RelocationResult(False, f"{text}: handed to the image stage, the 3D alignment inconsistent", iteration)
    out.handed_over, out.alignment_set_aside = True, "inconsistent"
    return out


def _tracking_or(session, state):
    """The VSE's latest state when it tracks, else ``state``."""
    return session.vse.latest() if session.vse.latest().status == VseStatus.TRACKING else state


def _at_prior(ctx: LoopContext, st: LoopState) -> bool:
    """The camera stands where the image localizer led the exploration and nothing has checked that yet
    (``LoopContext.image_prior_sigma_mm``), and the image stage may take over there."""
    c = ctx.config
    return (
        not st.prior_checked
        and ctx.image_prior_sigma_mm is not None
        and c.image_handover
        and c.image_refine
        and ctx.can_image
    )


def _degenerate_at_prior(st: LoopState, iteration: int, exc: DegenerateGeometry) -> RelocationResult:
    """The first alignment found degenerate geometry where the localizer led: the image stage takes over at
    once, without the alignment (docs/relocation.md, "A disputed start"), instead of waiting for
    ``degenerate_patience`` estimates in a row; weak image evidence there hands the loop back."""
    st.prior_checked = True
    out = RelocationResult(
        False,
        f"the first alignment found {exc.detail or 'degenerate geometry'} where the image "
        "localizer led the exploration: handed to the image stage, the 3D alignment "
        "degenerate",
        max(iteration - 1, 0),
    )
    out.handed_over, out.alignment_set_aside = True, "degenerate"
    return out


def _estimate(
    ctx: LoopContext,
    st: LoopState,
    iteration: int,
    last_serial: int,
    current_init,
    *,
    degenerate_patience: int | None = None,
):
    """The estimate this adjustment uses, and the VSE state to combine it with."""
    session = ctx.session
    state = session.tracking_state()
    if ctx.config.mode == LoopMode.PARALLEL:
        # Latest-value hand-over (paper Fig. 2): T_ref_cur maps the session's map frame, which
        # does not move with the camera, so the latest trustworthy estimate and the VSE's
        # current pose give the next motion without waiting for an alignment of the new view.
        # Only the decision to stop waits for an estimate computed after the last motion.
        latest = st.worker.latest_ok() if iteration > 1 else None
        if latest is not None and latest.serial >= last_serial:
            est = latest
        else:
            ctx.say(f"adjustment {iteration}: waiting for an alignment of the current view")
            est = wait_for_estimate(ctx, st.worker, last_serial, degenerate_patience=degenerate_patience)
        return est, _tracking_or(session, state)
    t0 = time.monotonic()
    ctx.say(f"adjustment {iteration}: aligning the current cloud to the reference")
    return align_now(ctx, state, current_init, last_serial + 1, t0=t0), state


def _confirmed(ctx: LoopContext, st: LoopState, iteration: int, est: AlignmentEstimate, state, handover: bool):
    """Parallel mode, about to stop (or hand over) on an estimate of the view before the last motion: confirm it
    first."""
    adj, afd = _adjustment(ctx, est, state)
    while (
        ctx.config.mode == LoopMode.PARALLEL
        and est.vse_frame < st.moved_at_frame
        and (_stops(ctx, st, adj, afd) or (handover and _hands_over(ctx, st, adj)))
    ):
        ctx.say(f"adjustment {iteration}: confirming the stop on an alignment of the current view")
        est = wait_for_estimate(ctx, st.worker, est.serial)
        state = _tracking_or(ctx.session, state)
        adj, afd = _adjustment(ctx, est, state)
    return est, state, adj, afd


def _record(
    ctx: LoopContext, st: LoopState, iteration: int, est: AlignmentEstimate, state, adj: Adjustment, afd: float
) -> AdjustmentRecord:
    return AdjustmentRecord(
        iteration=iteration,
        t_wall_s=st.elapsed_s(),
        t_session_s=ctx.session.timing.total_s,
        stage=est.stage,
        g=adj.g,
        offset_mm=adj.offset_mm,
        offset_deg=adj.offset_deg,
        T_ref_cam=adj.T_ref_cam.tolist(),
        M_flange_commanded=adj.M_flange_commanded.tolist(),
        clamped=adj.clamped,
        vse_status=state.status,
        vse_points=len(state.cloud),
        alignment_ok=est.ok,
        alignment_reason=est.reason,
        scale=ctx.scale,
        sigma=est.T_ref_cur.scale,
        afd_est_px=afd,
        truth=ctx.truth(),
        estimate_serial=est.serial,
        estimate_vse_frame=est.vse_frame,
        offset_sigma_mm=st.sigma3d_mm,
        tolerance_mm=st.tol_mm,
    )


def _check_within_revisit_range(ctx: LoopContext, adj: Adjustment) -> None:
    """Pause on an estimate farther than ``max_offset_m`` / ``max_offset_deg`` from the reference pose."""
    c = ctx.config
    if adj.offset_mm > c.max_offset_m * 1e3 or adj.offset_deg > c.max_offset_deg:
        raise AlgorithmError(
            f"the alignment puts the camera {adj.offset_mm:.0f} mm / {adj.offset_deg:.1f} deg from the reference, "
            f"beyond the {c.max_offset_m * 1e3:.0f} mm / {c.max_offset_deg:.0f} deg a revisit starts "
            "within; motion paused (a wrong alignment, or a start far from the reference)"
        )


def _stop_result(
    ctx: LoopContext, st: LoopState, iteration: int, adj: Adjustment, afd: float
) -> RelocationResult | None:
    """Converged when the paper's ``g <= eta`` or the image-space AFD rule holds, in both cases with the
    estimated offset within the tolerance (docs/relocation.md, "Stop rules"); None otherwise."""
    c = ctx.config
    within = adj.offset_mm <= st.tol_mm
    if adj.g <= c.eta and within:
        return RelocationResult(True, f"g = {adj.g:.2e} <= eta = {c.eta:.0e}", iteration)
    if afd <= c.stop_afd_px and within:
        return RelocationResult(
            True,
            f"estimated AFD {afd:.2f} px <= {c.stop_afd_px} px and offset "
            f"{adj.offset_mm:.2f} mm <= {st.tol_mm:.2f} mm (g = {adj.g:.2e})",
            iteration,
        )
    return None


def _move(ctx: LoopContext, st: LoopState, iteration: int, adj: Adjustment) -> None:
    session = ctx.session
    mm_cmd, deg_cmd = pose_distance(np.eye(4), adj.M_flange_commanded)
    ctx.say(f"adjustment {iteration}: moving {mm_cmd:.1f} mm / {deg_cmd:.2f} deg")
    session.move_by(
        adj.M_flange_commanded,
        progress=(0, session.substeps(adj.M_flange_commanded), f"adjustment {iteration}: moving"),
    )
    st.moved_at_frame = session.vse.latest().frames_processed


def racr_loop(ctx: LoopContext, st: LoopState, *, handover: bool = True) -> RelocationResult:
    """The 3D rACR loop: align, adjust, until converged; raises AlgorithmError when it pauses.

    It stops when the paper's rule (``g <= eta``) or the image-space rule (estimated AFD
    ``<= stop_afd_px``) holds *and* the estimated remaining offset is within the tolerance
    (:func:`~fgcd_cli.relocation.stop_rule.tolerance_mm`): a stage never stops while its own
    estimate says more remains. With ``handover``, it ends earlier, *not* converged and with
    ``handed_over`` set, when the image stage should take over (:func:`_hands_over`). Called
    again (after an image stage that could not take over), it continues the numbering and the
    estimates of ``st``. Every record goes to ``st.records``.
    """
    last = st.records[-1] if st.records else None
    current_init = st.last_T_ref_cur if st.last_T_ref_cur is not None else ctx.init
    last_serial = max([int(r.estimate_serial) for r in st.records if r.estimate_serial is not None], default=0)
    divergence = _Divergence()
    for iteration in range((last.iteration + 1) if last is not None else 1, ctx.config.max_adjustments + 1):
        at_prior = handover and _at_prior(ctx, st)
        try:
            est, state = _estimate(
                ctx, st, iteration, last_serial, current_init, degenerate_patience=1 if at_prior else None
            )
        except DegenerateGeometry as exc:
            if not at_prior:
                raise
            return _degenerate_at_prior(st, iteration, exc)
        est, state, adj, afd = _confirmed(ctx, st, iteration, est, state, handover)
        last_serial, current_init = est.serial, est.T_ref_cur
        st.last_T_ref_cur = est.T_ref_cur
        st.add(ctx, _record(ctx, st, iteration, est, state, adj, afd))
        _check_within_revisit_range(ctx, adj)
        prior = _against_prior(ctx, st, adj) if handover else None
        if prior is not None:
            return prior
        drift = _follows_camera(ctx, st, est, state, iteration, handover)
        if drift is not None:
            return drift
        divergence.check(adj, ctx)
        result = _stop_result(ctx, st, iteration, adj, afd)
        if result is not None:
            return result
        if handover and _hands_over(ctx, st, adj):
            out = RelocationResult(
                False,
                f"3D estimate {adj.offset_mm:.1f} mm within its own uncertainty "
                f"(± {st.sigma3d_mm:.1f} mm): handed to the image stage",
                iteration,
            )
            out.handed_over = True
            return out
        _move(ctx, st, iteration, adj)
    n = ctx.config.max_adjustments
    return RelocationResult(False, f"not converged after {n} adjustments", n)
