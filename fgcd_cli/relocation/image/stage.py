"""The image stage of the loop: steps measured on the reference images (see :mod:`.image_refine`).

Each step matches the current image with the reference images, solves the
camera motion by PnP on the reference cloud and moves (through the guard,
clamped to the largest step). No single estimator ends it (issue 25; docs/relocation.md,
"Stop rules"). It stops only when

* the correction moves the reference image by less than ``image_stop_afd_px``
  *and* the camera offset it measures is within the tolerance
  (:func:`~.stop_rule.tolerance_mm`);
* the frames themselves agree: the AFD the matches show is within what a camera
  at the stop rule would show under the matching noise
  (:func:`~.stop_rule.frame_afd_bound_px`);
* the 3D geometry of the same view agrees within both uncertainties
  (:func:`~.cross_check.geometry_check`: the alignment thread's estimate, else paper
  001's camera uncertainty). After a converged 3D loop an unavailable check counts as
  not agreeing; in the fallback (the 3D loop paused) it is reported as not done.

Disagreement takes another step; running out of steps pauses (not converged) with
the reason. A correction beyond the image evidence's own limit is trusted only
when the 3D geometry of the view confirms it; where the alignment is not asked,
one beyond the ordinary limit on ordinary evidence is approached by one
ordinary step, and the next measurement must corroborate it (:mod:`.probe`).

When the loop handed over where the image localizer led the exploration
because its first 3D estimate disputed the localizer's, or its first alignment
found degenerate geometry, or anywhere because two 3D estimates of the run
disagreed (``alignment_set_aside``), the stage runs as in the
fallback: the alignment is not asked (the camera uncertainty is), and weak
evidence before any image motion hands the loop back to the 3D estimate (after
disagreeing estimates: the loop pauses instead, :func:`.loop.relocate`).

After a converged 3D loop (the *refinement*), weak image evidence before any
image motion leaves the camera where the 3D loop stopped, *not converged*: one
estimator said "done" and nothing confirmed it (the record says why; the
residual is the 3D estimate's, with its larger uncertainty). When the 3D loop
paused (the *fallback*) the image estimate is the only one left.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from fgcd_cli.errors import AlgorithmError
from fgcd_cli.relocation.adjustment import clamp_motion
from fgcd_cli.relocation.enums import Agreement, EstimateSource, EstimateStage
from fgcd_cli.relocation.image.cross_check import geometry_check
from fgcd_cli.relocation.image.probe import Prediction, corroborates, predict_after_step
from fgcd_cli.relocation.log import AdjustmentRecord, RelocationResult
from fgcd_cli.relocation.loop.context import LoopContext, LoopState
from fgcd_cli.relocation.stop_rule import Residual, estimated_afd_px, frame_afd_bound_px
from fgcd_core.se3 import camera_motion, flange_motion, invert_pose, pose_distance

__all__ = ["image_stage"]


@dataclass(frozen=True, kw_only=True)
class _Measurement:
    """One image measurement turned into the loop's quantities (mm, deg, px; poses (4, 4))."""

    T_ref_cam: np.ndarray
    M_cmd: np.ndarray
    clamped: bool
    g: float
    offset_mm: float
    offset_deg: float
    afd_px: float
    sigma_mm: float


def _measurement(ctx: LoopContext, ref, last: AdjustmentRecord | None) -> _Measurement:
    """The refinement ``ref`` as a commanded motion; without a solution, the last record's view, standing still."""
    if ref.ok:
        c, reference = ctx.config, ctx.reference
        X = np.asarray(ctx.T_flange_cam, dtype=float)
        T_ref_cam = np.asarray(reference.T_ref_camref, dtype=float) @ invert_pose(ref.M_cam)
        M_flange = flange_motion(X, ref.M_cam)
        M_cmd, clamped = clamp_motion(M_flange, max_step_m=c.max_step_m, max_step_rad=c.max_step_rad)
        off_mm, off_deg = pose_distance(T_ref_cam, reference.T_ref_camref)
        return _Measurement(
            T_ref_cam=T_ref_cam,
            M_cmd=M_cmd,
            clamped=clamped,
            g=float(np.linalg.norm(M_flange - np.eye(4))),
            offset_mm=off_mm,
            offset_deg=off_deg,
            afd_px=estimated_afd_px(reference.points, reference.T_ref_camref, T_ref_cam, ctx.camera),
            sigma_mm=ref.offset_sigma_mm,
        )
    if last is not None:
        return _Measurement(
            T_ref_cam=np.asarray(last.T_ref_cam),
            M_cmd=np.eye(4),
            clamped=False,
            g=last.g,
            offset_mm=last.offset_mm,
            offset_deg=last.offset_deg,
            afd_px=last.afd_est_px,
            sigma_mm=math.nan,
        )
    # nothing is known about the current pose
    return _Measurement(
        T_ref_cam=np.full((4, 4), np.nan),
        M_cmd=np.eye(4),
        clamped=False,
        g=math.nan,
        offset_mm=math.nan,
        offset_deg=math.nan,
        afd_px=math.nan,
        sigma_mm=math.nan,
    )


def _frames(ctx: LoopContext, ref) -> dict:
    """What the frames themselves say: the matches' mean displacement against the bound a camera at the
    stop rule would show (:func:`~.stop_rule.frame_afd_bound_px`)."""
    c = ctx.config
    bound = frame_afd_bound_px(stop_afd_px=c.image_stop_afd_px, rms_px=ref.rms_px, inliers=ref.inliers, k=c.agreement_k)
    measured = float(ref.measured_afd_px)
    return {"measured_afd_px": measured, "bound_px": bound, "agree": bool(math.isfinite(bound) and measured <= bound)}


class _ImageStage:
    """One run of the image stage; :meth:`run` returns the result or raises (fallback that found nothing)."""

    def __init__(
        self, ctx: LoopContext, st: LoopState, result: RelocationResult, *, fallback: bool, handed_over: bool = False
    ):
        c = ctx.config
        self.ctx, self.st, self.result, self.fallback = ctx, st, result, fallback
        self.handed_over = handed_over
        self.handed_back = False  # declined before any motion after a hand-over: the 3D loop goes on
        # the 3D alignment paused, or was set aside where the image localizer led: it is not asked to confirm
        self.set_aside = result.alignment_set_aside
        self.without_alignment = fallback or bool(self.set_aside)
        self.last = st.records[-1] if st.records else None
        self.first_iteration = self.last.iteration if self.last is not None else 0
        self.label = (
            "image fallback" if fallback else f"image stage (3D {self.set_aside})" if self.set_aside else "image stage"
        )
        self.steps = c.image_fallback_steps if self.without_alignment else c.image_refine_steps
        self.reason = result.reason
        self.residual: Residual | None = None
        self.converged = False
        self.moved = False  # an image motion was made since the last estimate that reached the tolerance
        self.after_frame = st.moved_at_frame
        self.pending: Prediction | None = None  # after a step toward an unverified correction (:mod:`.probe`)

    def _refine(self, step: int):
        ctx, session = self.ctx, self.ctx.session
        ctx.say(
            f"{self.label} {step + 1}/{self.steps}: matching the current image with "
            f"{len(ctx.reference_images)} reference image(s)"
        )
        # the platform waits for the stills and the matching; the simulator's rendering is not the rig's
        with session.standing_still(stills=2):
            return ctx.refiner(unresolved_mm=ctx.config.agreement_k * self.st.sigma3d_mm)(
                reference_images=ctx.reference_images,
                current_image=ctx.grab_current(),
                camera=ctx.camera,
                ref_points=ctx.reference.points,
                T_ref_camref=ctx.reference.T_ref_camref,
            )

    def _record(
        self, step: int, state, ref, m: _Measurement, agreement: dict | None, frames: dict | None
    ) -> AdjustmentRecord:
        ctx, last = self.ctx, self.last
        info = {
            "matches": ref.matches,
            "inliers": ref.inliers,
            "rms_px": ref.rms_px,
            "measured_afd_px": ref.measured_afd_px,
            "reference_image": ref.reference_image,
            "matcher": ref.matcher,
            "fallback": self.fallback,
            "frames": frames,
        }
        return AdjustmentRecord(
            iteration=self.first_iteration + step + 1,
            t_wall_s=self.st.elapsed_s(),
            t_session_s=ctx.session.timing.total_s,
            stage=EstimateStage.IMAGE,
            g=m.g,
            offset_mm=m.offset_mm,
            offset_deg=m.offset_deg,
            T_ref_cam=np.asarray(m.T_ref_cam).tolist(),
            M_flange_commanded=np.asarray(m.M_cmd).tolist(),
            clamped=m.clamped,
            vse_status=state.status,
            vse_points=len(state.cloud),
            alignment_ok=ref.ok,
            alignment_reason=ref.reason,
            scale=ctx.scale,
            sigma=last.sigma if last is not None else math.nan,
            afd_est_px=m.afd_px,
            truth=ctx.truth(),
            image=info,
            offset_sigma_mm=m.sigma_mm if ref.ok else (last.offset_sigma_mm if last is not None else None),
            tolerance_mm=self.st.tol_mm,
            agreement=agreement,
        )

    def _confirmed_if_large(self, ref):
        """A correction refused only for its size (``oversize``) is trusted when it is within the loop's
        revisit range and the 3D geometry of the view confirms it (:mod:`.cross_check`); else as refused."""
        ctx, c = self.ctx, self.ctx.config
        if ref.ok or not ref.oversize or ref.M_cam is None:
            return ref, None
        mm, deg = pose_distance(np.eye(4), ref.M_cam)
        if mm > c.max_offset_m * 1e3 or deg > c.max_offset_deg:
            return replace(
                ref,
                reason=f"{ref.reason}, and beyond the {c.max_offset_m * 1e3:.0f} mm / "
                f"{c.max_offset_deg:.0f} deg revisit range",
            ), None
        T_ref_cam = np.asarray(ctx.reference.T_ref_camref, dtype=float) @ invert_pose(ref.M_cam)
        check = geometry_check(
            ctx, self.st, self.after_frame, T_ref_cam, ref.offset_sigma_mm, use_alignment=not self.without_alignment
        )
        if check["agree"] and check["bound_mm"] >= mm:  # the check could not tell it from no correction at all
            return replace(
                ref,
                reason=f"{ref.reason}; not confirmed by the 3D geometry (its {check['check']} "
                f"bound {check['bound_mm']:.0f} mm does not resolve a {mm:.0f} mm "
                "correction)",
            ), check
        if check["agree"]:
            ctx.say(
                f"{self.label}: a {mm:.0f} mm correction confirmed by the {check['check']} "
                f"({check['distance_mm']:.1f} mm <= {check['bound_mm']:.1f} mm)"
            )
            return replace(ref, ok=True, reason=f"ok: {mm:.0f} mm confirmed by the {check['check']}"), check
        why = (
            f"{check['check']} {check['distance_mm']:.1f} mm > {check['bound_mm']:.1f} mm"
            if check["agree"] is False
            else check["note"]
        )
        return replace(ref, reason=f"{ref.reason}; not confirmed by the 3D geometry ({why})"), check

    def _checks(self, ref, m: _Measurement) -> tuple[bool, dict | None, dict | None]:
        """Whether every estimator lets the stage stop here: the image estimate, the frames, the 3D geometry."""
        st, c = self.st, self.ctx.config
        if not (ref.ok and m.afd_px <= c.image_stop_afd_px and m.offset_mm <= st.tol_mm):
            return False, None, None
        frames = _frames(self.ctx, ref)
        if not frames["agree"]:
            return False, frames, None
        geometry = geometry_check(
            self.ctx, st, self.after_frame, m.T_ref_cam, m.sigma_mm, use_alignment=not self.without_alignment
        )
        # after a converged 3D loop an unavailable check is no confirmation; without the alignment (paused or
        # set aside) there is no other estimator
        done = geometry["agree"] is True or (geometry["agree"] is None and self.without_alignment)
        return done, frames, geometry

    def _step(self, step: int) -> bool:
        """One measurement, and a motion unless it ends the stage; True when the stage ends."""
        ctx = self.ctx
        state = ctx.session.settle(frames=2)
        ref = self._corroborated(self._refine(step))
        if self._may_probe(step, ref):
            return self._probe(step, state, ref)
        ref, large = self._confirmed_if_large(ref)
        m = _measurement(ctx, ref, self.last)
        done, frames, geometry = self._checks(ref, m)
        self.st.add(ctx, self._record(step, state, ref, m, geometry or large, frames))
        if not ref.ok:
            self._declined(ref)
            return True
        if done:
            self._stopped(m, geometry)
            return True
        self._note_why_not(step, m, frames, geometry)
        ctx.say(f"{self.label} {step + 1}/{self.steps}: moving {m.offset_mm:.1f} mm / {m.offset_deg:.2f} deg")
        ctx.session.move_by(m.M_cmd, progress=(0, ctx.session.substeps(m.M_cmd), f"{self.label} {step + 1}: moving"))
        self.moved = True
        self.after_frame = ctx.session.vse.latest().frames_processed
        return False

    def _may_probe(self, step: int, ref) -> bool:
        """A correction refused only for its size on ordinary evidence, where nothing else can vouch for it (the
        alignment is not asked), within the revisit range, with a step left to measure again."""
        c = self.ctx.config
        if not (
            ref.unverified
            and ref.M_cam is not None
            and ref.step_M_cam is not None
            and self.without_alignment
            and step + 1 < self.steps
        ):
            return False
        mm, deg = pose_distance(np.eye(4), ref.M_cam)
        return mm <= c.max_offset_m * 1e3 and deg <= c.max_offset_deg

    def _probe(self, step: int, state, ref) -> bool:
        """One ordinary step toward the unverified correction; the next measurement must corroborate it
        (:mod:`.probe`). Returns False (the stage goes on)."""
        ctx, c = self.ctx, self.ctx.config
        X = np.asarray(ctx.T_flange_cam, dtype=float)
        M_cmd, _ = clamp_motion(flange_motion(X, ref.step_M_cam), max_step_m=c.max_step_m, max_step_rad=c.max_step_rad)
        step_cam = camera_motion(X, M_cmd)
        self.pending = predict_after_step(ctx.reference.T_ref_camref, ref.M_cam, step_cam, sigma_mm=ref.offset_sigma_mm)
        m = replace(_measurement(ctx, replace(ref, ok=True), self.last), M_cmd=M_cmd, clamped=True)
        self.st.add(ctx, self._record(step, state, ref, m, None, None))
        mm, deg = pose_distance(np.eye(4), step_cam)
        self.reason = f"{self.result.reason}; {self.label}: {ref.reason}; approached by {mm:.1f} mm"
        ctx.say(
            f"{self.label} {step + 1}/{self.steps}: {m.offset_mm:.0f} mm on ordinary evidence ({ref.inliers} "
            f"inliers): moving {mm:.1f} mm / {deg:.2f} deg toward it, the next measurement must corroborate it"
        )
        ctx.session.move_by(M_cmd, progress=(0, ctx.session.substeps(M_cmd), f"{self.label} {step + 1}: moving"))
        self.moved = True
        self.after_frame = ctx.session.vse.latest().frames_processed
        return False

    def _corroborated(self, ref):
        """After a step toward an unverified correction: the new measurement must put the camera where the last
        one predicted (:func:`~.probe.corroborates`), else it is refused."""
        prediction, self.pending = self.pending, None
        if prediction is None or ref.M_cam is None:
            return ref
        ok, dist, bound = corroborates(
            prediction,
            self.ctx.reference.T_ref_camref,
            ref.M_cam,
            sigma_mm=ref.offset_sigma_mm,
            k=self.ctx.config.agreement_k,
        )
        if ok:
            self.ctx.say(
                f"{self.label}: the step corroborated the image estimate ({dist:.1f} mm from its "
                f"prediction, <= {bound:.1f} mm)"
            )
            return ref
        return replace(
            ref,
            ok=False,
            unverified=False,
            oversize=False,
            reason=f"after the step the image estimate lies {dist:.1f} mm from where the last one put the "
            f"camera (> {bound:.1f} mm, both uncertainties): it does not follow the motion",
        )

    def _declined(self, ref) -> None:
        """No trustworthy image solution: the stage ends. Before any image motion the camera stays where the 3D
        loop stopped, with the 3D residual, but *not converged*: nothing confirmed the 3D estimate."""
        self.reason = f"{self.result.reason}; {self.label}: {ref.reason}"
        if self.handed_over and not self.moved:
            self.handed_back = True
            return
        if not self.fallback and not self.moved and self.last is not None:
            self.residual = Residual(
                offset_mm=self.last.offset_mm,
                sigma_mm=self.st.sigma3d_mm,
                tolerance_mm=self.st.tol_mm,
                source=EstimateSource.THREE_D,
                agreement=Agreement.NOT_CHECKED.because(f"{self.label} declined"),
            )
            self.reason = (
                f"{self.reason}; the 3D estimate alone says done, with an uncertainty "
                f"(± {self.st.sigma3d_mm:.1f} mm) above the tolerance, and nothing confirmed it"
            )

    def _stopped(self, m: _Measurement, geometry: dict | None) -> None:
        """The image stop rule holds, the frames agree, and the 3D geometry agrees (or, in the fallback,
        cannot be measured)."""
        c = self.ctx.config
        if geometry is not None and geometry["agree"]:
            verdict = (
                Agreement.AGREE if geometry["check"] == "alignment" else Agreement.AGREE.because(geometry["check"])
            )
        else:
            verdict = Agreement.NOT_CHECKED.because(
                geometry["note"]
                if geometry
                else "the 3D loop paused"
                if self.fallback
                else f"the 3D alignment {self.set_aside}"
            )
        self.converged = True
        self.residual = Residual(
            offset_mm=m.offset_mm,
            sigma_mm=m.sigma_mm,
            tolerance_mm=self.st.tol_mm,
            source=EstimateSource.IMAGE,
            agreement=verdict,
        )
        self.reason = (
            f"{self.result.reason}; {self.label}: correction {m.afd_px:.2f} px <= {c.image_stop_afd_px} px "
            f"and {m.offset_mm:.2f} mm <= {self.st.tol_mm:.2f} mm"
        )

    def _note_why_not(self, step: int, m: _Measurement, frames: dict | None, geometry: dict | None) -> None:
        c, tol, head = self.ctx.config, self.st.tol_mm, f"{self.result.reason}; {self.label}"
        if geometry is not None and geometry["agree"] is False:  # the 3D geometry of the same view disagrees
            self.reason = (
                f"{head}: the 3D and image estimates disagree by {geometry['distance_mm']:.1f} mm "
                f"(> {geometry['bound_mm']:.1f} mm, {geometry['check']})"
            )
        elif geometry is not None:
            self.reason = f"{head}: the image estimate says done, but no 3D estimate confirms it ({geometry['note']})"
        elif frames is not None:
            self.reason = (
                f"{head}: the image estimate says {m.afd_px:.2f} px, but the frames show "
                f"{frames['measured_afd_px']:.2f} px (> {frames['bound_px']:.2f} px)"
            )
        else:
            self.reason = (
                f"{head}: after {step + 1} step(s) it still measures "
                f"{m.offset_mm:.2f} ± {m.sigma_mm:.2f} mm / {m.afd_px:.2f} px (tolerance {tol:.2f} mm, "
                f"{c.image_stop_afd_px} px)"
            )

    def _paused(self) -> RelocationResult:
        """Out of steps, or the image evidence failed after an image motion: the remaining offset is not
        known to be within the tolerance. Never "converged" on that; a fallback raises."""
        records = self.st.records
        if self.fallback:
            raise AlgorithmError(f"motion paused: {self.reason}")
        out = RelocationResult(False, f"motion paused: {self.reason}", records[-1].iteration if records else 0)
        last_rec = records[-1] if records else None
        if self.residual is not None:  # declined before any image motion: the 3D loop's residual
            out.residual = self.residual
            out.reason = f"{out.reason}; {self.residual.text()}"
        elif last_rec is not None and last_rec.alignment_ok:
            out.residual = Residual(
                offset_mm=last_rec.offset_mm,
                sigma_mm=float(last_rec.offset_sigma_mm or math.nan),
                tolerance_mm=self.st.tol_mm,
                source=EstimateSource.IMAGE,
                agreement=Agreement.NOT_CHECKED,
            )
        return out

    def run(self) -> RelocationResult | None:
        for step in range(self.steps):
            if self._step(step):
                break
        if self.handed_back:
            return None
        if self.converged:
            out = RelocationResult(True, f"{self.reason}; {self.residual.text()}", self.st.records[-1].iteration)
            out.residual = self.residual
            return out
        return self._paused()


def image_stage(
    ctx: LoopContext, st: LoopState, result: RelocationResult, *, fallback: bool, handed_over: bool = False
) -> RelocationResult | None:
    """Image-based steps from the reference images after the 3D loop (module docstring).

    Parameters
    ----------
    ctx, st :
        The run's inputs and shared state; records are appended to ``st.records``.
    result : RelocationResult
        The 3D loop's outcome (converged, handed over, or the pause it ended on).
    fallback : bool
        True when the 3D loop paused (the image estimate is the only one left).
    handed_over : bool
        The 3D loop handed over before its own stop rule held (``RelocationConfig.image_handover``):
        weak image evidence before any image motion returns None, and the 3D loop goes on.

    Raises
    ------
    AlgorithmError
        A fallback that found no strong evidence or ran out of steps: the pause stands.
    """
    return _ImageStage(ctx, st, result, fallback=fallback, handed_over=handed_over).run()
