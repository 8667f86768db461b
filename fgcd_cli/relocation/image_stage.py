"""The image stage of the loop: steps measured on the reference images (see :mod:`.image_refine`).

Each step matches the current image with the reference images, solves the
camera motion by PnP on the reference cloud and moves (through the guard,
clamped to the largest step). It stops only when the correction moves the
reference image by less than ``image_stop_afd_px`` *and* the camera offset it
measures is within the tolerance (:func:`~.stop_rule.tolerance_mm`); and, after
a converged 3D loop, only when a 3D estimate of the same view agrees with it
within their uncertainties (:func:`~.stop_rule.estimates_agree`).
Disagreement takes another step; running out of steps pauses (not converged)
with the reason (docs/relocation.md, "Final image stage").

After a converged 3D loop (the *refinement*), weak image evidence before any
image motion leaves the rACR result as it is (the record says why; the
residual is the 3D estimate's, with its larger uncertainty). When the 3D loop
paused (the *fallback*) the image estimate is the only one left.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from fgcd_cli.errors import AlgorithmError
from fgcd_cli.relocation.adjustment import clamp_motion
from fgcd_cli.relocation.context import LoopContext, LoopState
from fgcd_cli.relocation.enums import Agreement, EstimateSource, EstimateStage
from fgcd_cli.relocation.estimates import fresh_3d_estimate
from fgcd_cli.relocation.log import AdjustmentRecord, RelocationResult
from fgcd_cli.relocation.stop_rule import Residual, estimated_afd_px, estimates_agree, offset_vector_mm
from fgcd_core.se3 import invert_pose, pose_distance

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
        M_flange = X @ ref.M_cam @ invert_pose(X)
        M_cmd, clamped = clamp_motion(M_flange, max_step_m=c.max_step_m, max_step_rad=c.max_step_rad)
        off_mm, off_deg = pose_distance(T_ref_cam, reference.T_ref_camref)
        return _Measurement(T_ref_cam=T_ref_cam, M_cmd=M_cmd, clamped=clamped,
                            g=float(np.linalg.norm(M_flange - np.eye(4))), offset_mm=off_mm, offset_deg=off_deg,
                            afd_px=estimated_afd_px(reference.points, reference.T_ref_camref, T_ref_cam, ctx.camera),
                            sigma_mm=ref.offset_sigma_mm)
    if last is not None:
        return _Measurement(T_ref_cam=np.asarray(last.T_ref_cam), M_cmd=np.eye(4), clamped=False, g=last.g,
                            offset_mm=last.offset_mm, offset_deg=last.offset_deg, afd_px=last.afd_est_px,
                            sigma_mm=math.nan)
    # nothing is known about the current pose
    return _Measurement(T_ref_cam=np.full((4, 4), np.nan), M_cmd=np.eye(4), clamped=False, g=math.nan,
                        offset_mm=math.nan, offset_deg=math.nan, afd_px=math.nan, sigma_mm=math.nan)


def _agreement(ctx: LoopContext, st: LoopState, after_frame: int, T_ref_cam_img: np.ndarray,
               sigma_img_mm: float) -> dict:
    """Compare the image estimate with a 3D estimate of the same view (:func:`~.stop_rule.estimates_agree`).

    Returns a dict for the log: ``agree`` (True, False, or None when no 3D estimate
    of this view was available), the distance and bound in mm, the 3D offset, a note.
    """
    T_3d, note = fresh_3d_estimate(ctx, st, after_frame)
    if T_3d is None:
        return {"agree": None, "note": note}
    T_ref_camref = ctx.reference.T_ref_camref
    d_img = offset_vector_mm(T_ref_cam_img, T_ref_camref)
    d_3d = offset_vector_mm(T_3d, T_ref_camref)
    ok, dist, bound = estimates_agree(d_img, sigma_img_mm, d_3d, st.sigma3d_mm, k=ctx.config.agreement_k)
    return {"agree": ok, "distance_mm": dist, "bound_mm": bound, "offset_3d_mm": float(np.linalg.norm(d_3d)),
            "sigma_3d_mm": st.sigma3d_mm, "note": ""}


class _ImageStage:
    """One run of the image stage; :meth:`run` returns the result or raises (fallback that found nothing)."""

    def __init__(self, ctx: LoopContext, st: LoopState, result: RelocationResult, *, fallback: bool):
        c = ctx.config
        self.ctx, self.st, self.result, self.fallback = ctx, st, result, fallback
        self.last = st.records[-1] if st.records else None
        self.first_iteration = self.last.iteration if self.last is not None else 0
        self.label = "image fallback" if fallback else "image stage"
        self.steps = c.image_fallback_steps if fallback else c.image_refine_steps
        self.reason = result.reason
        self.residual: Residual | None = None
        self.moved = False  # an image motion was made since the last estimate that reached the tolerance
        self.after_frame = st.moved_at_frame

    def _refine(self, step: int):
        ctx, session = self.ctx, self.ctx.session
        ctx.say(f"{self.label} {step + 1}/{self.steps}: matching the current image with "
                f"{len(ctx.reference_images)} reference image(s)")
        t0 = time.monotonic()
        ref = ctx.refiner()(reference_images=ctx.reference_images, current_image=ctx.grab_current(),
                            camera=ctx.camera, ref_points=ctx.reference.points,
                            T_ref_camref=ctx.reference.T_ref_camref)
        session.timing.wait_s += time.monotonic() - t0
        return ref

    def _record(self, step: int, state, ref, m: _Measurement, agreement: dict | None) -> AdjustmentRecord:
        ctx, last = self.ctx, self.last
        info = {"matches": ref.matches, "inliers": ref.inliers, "rms_px": ref.rms_px,
                "measured_afd_px": ref.measured_afd_px, "reference_image": ref.reference_image,
                "matcher": ref.matcher, "fallback": self.fallback}
        return AdjustmentRecord(
            iteration=self.first_iteration + step + 1, t_wall_s=self.st.elapsed_s(),
            t_session_s=ctx.session.timing.total_s, stage=EstimateStage.IMAGE, g=m.g, offset_mm=m.offset_mm,
            offset_deg=m.offset_deg, T_ref_cam=np.asarray(m.T_ref_cam).tolist(),
            M_flange_commanded=np.asarray(m.M_cmd).tolist(), clamped=m.clamped, vse_status=state.status,
            vse_points=len(state.cloud), alignment_ok=ref.ok, alignment_reason=ref.reason, scale=ctx.scale,
            sigma=last.sigma if last is not None else math.nan, afd_est_px=m.afd_px, truth=ctx.truth(), image=info,
            offset_sigma_mm=m.sigma_mm if ref.ok else (last.offset_sigma_mm if last is not None else None),
            tolerance_mm=self.st.tol_mm, agreement=agreement,
        )

    def _step(self, step: int) -> bool:
        """One measurement, and a motion unless it ends the stage; True when the stage ends."""
        ctx, st, c = self.ctx, self.st, self.ctx.config
        state = ctx.session.settle(frames=2)
        ref = self._refine(step)
        m = _measurement(ctx, ref, self.last)
        within = ref.ok and m.afd_px <= c.image_stop_afd_px and m.offset_mm <= st.tol_mm
        agreement = None
        if within and not self.fallback:
            agreement = _agreement(ctx, st, self.after_frame, m.T_ref_cam, m.sigma_mm)
        st.add(ctx, self._record(step, state, ref, m, agreement))
        if not ref.ok:
            self._declined(ref)
            return True
        if within and (agreement is None or agreement["agree"] is not False):
            self._stopped(m, agreement)
            return True
        self._note_why_not(step, m, agreement, within)
        ctx.say(f"{self.label} {step + 1}/{self.steps}: moving {m.offset_mm:.1f} mm / {m.offset_deg:.2f} deg")
        ctx.session.move_by(m.M_cmd, progress=(0, ctx.session.substeps(m.M_cmd),
                                               f"{self.label} {step + 1}: moving"))
        self.moved = True
        self.after_frame = ctx.session.vse.latest().frames_processed
        return False

    def _declined(self, ref) -> None:
        """No trustworthy image solution: the stage ends; a converged 3D result stands if nothing moved yet."""
        self.reason = f"{self.result.reason}; {self.label}: {ref.reason}"
        if not self.fallback and not self.moved and self.last is not None:
            # weak evidence before any image motion: the converged 3D result stands
            self.residual = Residual(offset_mm=self.last.offset_mm, sigma_mm=self.st.sigma3d_mm,
                                     tolerance_mm=self.st.tol_mm, source=EstimateSource.THREE_D,
                                     agreement=Agreement.NOT_CHECKED.because(f"{self.label} declined"))

    def _stopped(self, m: _Measurement, agreement: dict | None) -> None:
        """The image stop rule holds and no 3D estimate contradicts it."""
        c = self.ctx.config
        if self.fallback:
            verdict = Agreement.NOT_CHECKED.because("the 3D loop paused")
        elif agreement is None:
            verdict = Agreement.NOT_CHECKED
        else:
            verdict = Agreement.AGREE if agreement["agree"] else Agreement.NOT_CHECKED.because(agreement["note"])
        self.residual = Residual(offset_mm=m.offset_mm, sigma_mm=m.sigma_mm, tolerance_mm=self.st.tol_mm,
                                 source=EstimateSource.IMAGE, agreement=verdict)
        self.reason = (f"{self.result.reason}; {self.label}: correction {m.afd_px:.2f} px <= {c.image_stop_afd_px} px "
                       f"and {m.offset_mm:.2f} mm <= {self.st.tol_mm:.2f} mm")

    def _note_why_not(self, step: int, m: _Measurement, agreement: dict | None, within: bool) -> None:
        c, tol = self.ctx.config, self.st.tol_mm
        if within:  # the image says done, the 3D estimate of the same view disagrees: measure again
            self.reason = (f"{self.result.reason}; {self.label}: the 3D and image estimates disagree by "
                           f"{agreement['distance_mm']:.1f} mm (> {agreement['bound_mm']:.1f} mm)")
        else:
            self.reason = (f"{self.result.reason}; {self.label}: after {step + 1} step(s) it still measures "
                           f"{m.offset_mm:.2f} ± {m.sigma_mm:.2f} mm / {m.afd_px:.2f} px (tolerance {tol:.2f} mm, "
                           f"{c.image_stop_afd_px} px)")

    def _paused(self) -> RelocationResult:
        """Out of steps, or the image evidence failed after an image motion: the remaining offset is not
        known to be within the tolerance. Never "converged" on that; a fallback raises."""
        records = self.st.records
        if self.fallback:
            raise AlgorithmError(f"motion paused: {self.reason}")
        out = RelocationResult(False, f"motion paused: {self.reason}", records[-1].iteration if records else 0)
        last_rec = records[-1] if records else None
        if last_rec is not None and last_rec.alignment_ok:
            out.residual = Residual(offset_mm=last_rec.offset_mm,
                                    sigma_mm=float(last_rec.offset_sigma_mm or math.nan),
                                    tolerance_mm=self.st.tol_mm, source=EstimateSource.IMAGE,
                                    agreement=Agreement.NOT_CHECKED)
        return out

    def run(self) -> RelocationResult:
        for step in range(self.steps):
            if self._step(step):
                break
        if self.residual is not None:
            out = RelocationResult(True, f"{self.reason}; {self.residual.text()}", self.st.records[-1].iteration)
            out.residual = self.residual
            return out
        return self._paused()


def image_stage(ctx: LoopContext, st: LoopState, result: RelocationResult, *, fallback: bool) -> RelocationResult:
    """Image-based steps from the reference images after the 3D loop (module docstring).

    Parameters
    ----------
    ctx, st :
        The run's inputs and shared state; records are appended to ``st.records``.
    result : RelocationResult
        The 3D loop's outcome (converged, or the pause it ended on).
    fallback : bool
        True when the 3D loop paused (the image estimate is the only one left).

    Raises
    ------
    AlgorithmError
        A fallback that found no strong evidence or ran out of steps: the pause stands.
    """
    return _ImageStage(ctx, st, result, fallback=fallback).run()
