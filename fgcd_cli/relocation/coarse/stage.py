"""Active coarse stage: bring a camera that starts far away into rACR's basin (paper 001, AccurateACL).

rACR (paper 000) starts a revisit within a few centimetres of the reference
pose. When the first estimate puts the camera farther away (a robot re-mounted
elsewhere, a stage moved between visits), this stage runs first. It follows
AccurateACL's split, adapted to a platform next to one object:

* **passive localizer** ("how to locate"): two independent estimates of the
  current camera in the reference frame, from 2D-3D correspondences (SIFT
  matches to the reference images lifted to 3D by the reference cloud, PnP:
  the paper's scene-coordinate correspondences) and from the 3D alignment of
  the session cloud (the multi-start registration when the prior fails);
* **camera uncertainty** ("when to stop", and here also "whether to trust"):
  the reference cloud is rendered at an estimated pose, the observed session
  cloud is put in the current camera frame, and the two are registered; the
  residual motion says how wrong the estimate is (paper 001, §3.2;
  :mod:`fgcd_cli.relocation.coarse.camera_uncertainty`). An estimate is *verified* when that
  residual is within 5 cm / 5 deg (the paper's lambda_cu) on enough overlap;
* **where to go**: the paper's scene-descent heuristic with the reference
  view as the localizable region (the reference cloud was built from there,
  so it is where the scene is best known): a verified estimate is followed
  along the shortest path, one bounded step at a time, re-localizing after
  each step; without a verified estimate the camera descends half the way an
  unverified (but overlapping) estimate points to, at most twice (the
  paper's scene descent, which assumes the estimate roughly right), or else
  turns a little (the paper's turn-around action) to show the localizer
  another view; after a few unverified views the stage pauses rather than
  guess. Only a verified estimate ever hands over. Which turn: the one whose
  predicted view has the lowest scene uncertainty (paper 001, Eq. 2;
  :mod:`fgcd_cli.relocation.coarse.scene_uncertainty`) seen from the best unverified
  estimate of where the camera is; without one, a fixed order.
"""

from __future__ import annotations

import math
import time

import numpy as np
from scipy.spatial.transform import Rotation

from fgcd_cli.relocation.adjustment import clamp_motion
from fgcd_cli.relocation.coarse.config import CoarseConfig, CoarseResult, CoarseStep
from fgcd_cli.relocation.coarse.passive import View, localize, residual_m
from fgcd_cli.relocation.coarse.scene_uncertainty import SceneUncertaintyMap, camera_turn, view_uncertainty
from fgcd_cli.relocation.coarse.stage_inputs import CoarseInputs
from fgcd_cli.relocation.enums import CoarseAction, EstimateSource
from fgcd_cli.relocation.stop_rule import reference_depth_m
from fgcd_core.platform import MotionRejected
from fgcd_core.se3 import flange_motion, invert_pose, pose_distance
from fgcd_core.sim3 import Sim3

__all__ = ["run_coarse"]


def _sim3_from_camera(T_ref_cam: np.ndarray, T_cur_cam: np.ndarray) -> Sim3:
    """The rigid ``T_ref_cur`` that puts the session camera at ``T_ref_cam``."""
    M = np.asarray(T_ref_cam, dtype=float) @ invert_pose(np.asarray(T_cur_cam, dtype=float))
    return Sim3(M[:3, :3].copy(), M[:3, 3].copy(), 1.0)


def _why_not_verified(notes: dict, config: CoarseConfig) -> str:
    """One phrase per localizer of the last view: why its estimate did not verify."""
    parts = []
    for name in (EstimateSource.THREE_D, EstimateSource.IMAGE):
        note = notes.get(name) or {}
        unc = note.get("uncertainty")
        if unc is None:
            parts.append(f"{name}: no estimate ({note.get('pnp') or note.get('alignment') or 'not run'})")
        elif unc["fitness"] < config.min_fitness:
            parts.append(f"{name}: overlap {unc['fitness']:.0%} < {config.min_fitness:.0%}")
        elif name == EstimateSource.THREE_D and unc["weak_directions"]:
            parts.append(
                f"3d: residual {unc['translation_mm']:.0f} mm / {unc['rotation_deg']:.1f} deg, but "
                f"{unc['weak_directions']} direction(s) the geometry cannot check"
            )
        else:
            parts.append(
                f"{name}: camera uncertainty {unc['constrained_translation_mm']:.0f} mm / "
                f"{unc['constrained_rotation_deg']:.1f} deg above {config.verify_m * 1e3:.0f} mm / "
                f"{config.verify_deg:.0f} deg"
            )
    return "; ".join(parts)


class _CoarseRun:
    """The stage's state between steps: the last verified alignment, the looks made and the heading."""

    def __init__(self, inp: CoarseInputs):
        self.inp = inp
        self.X = np.asarray(inp.T_flange_cam, dtype=float)
        self.T_ref_camref = np.asarray(inp.reference.T_ref_camref, dtype=float)
        self.steps: list[CoarseStep] = []
        self.last_3d = inp.init
        self.looks = 0
        self.descents = 0
        self.heading = (0.0, 0.0)  # look-around turn (yaw, pitch) from where the stage started, radians
        # the flange motion made on no verified estimate (looks, descents) since the stage started or last
        # moved on a verified one: what a pause undoes
        self.M_unverified = np.eye(4)
        self.seen_headings = [self.heading]
        self.scene: SceneUncertaintyMap | None = None
        self.scene_asked = False
        self.t_s = 0.0  # the session's time on the rig when the current view was localized
        depth = reference_depth_m(inp.reference.points, self.T_ref_camref)
        self.handover_m, self.handover_deg = inp.config.handover_limits(depth)

    def _log(
        self,
        step: int,
        action: CoarseAction,
        source: EstimateSource,
        view: View,
        truth,
        *,
        offset=(math.nan, math.nan),
        commanded=(0.0, 0.0),
        look: dict | None = None,
    ) -> None:
        self.steps.append(
            CoarseStep(
                step=step,
                t_session_s=self.t_s,
                action=action,
                source=source,
                estimates=view.notes,
                offset_mm=offset[0],
                offset_deg=offset[1],
                commanded_mm=commanded[0],
                commanded_deg=commanded[1],
                truth=truth,
                look=look,
            )
        )

    def _pause(self, step: int, view: View, truth) -> CoarseResult:
        """No estimate verified in the views allowed: undo every motion made on no verified estimate and give up.

        Rule: looks and descents move on nothing verified (a descent follows an unverified estimate, paper 001);
        when nothing confirmed them the camera goes back to where the stage started (or last moved on a
        verified estimate), so the loop starts from the best pose known, not from wherever the search ended.
        """
        c = self.inp.config
        self._log(step, CoarseAction.PAUSE, EstimateSource.NONE, view, truth)
        reason = (
            f"coarse stage: no estimate verified in {self.looks + 1} views ({_why_not_verified(view.notes, c)}); "
            "bring the camera nearer the reference pose"
        )
        undo = invert_pose(self.M_unverified)
        if pose_distance(np.eye(4), undo)[0] > 1e-6 or pose_distance(np.eye(4), undo)[1] > 1e-6:
            try:
                self.inp.session.move_by(undo)
                self.M_unverified = np.eye(4)
                reason += "; its unverified motions undone (the camera is back where it started or last moved on a verified estimate)"
            except MotionRejected as exc:
                reason += f"; the way back is refused by the platform guard ({exc})"
        end_truth = self.inp.evaluate() if self.inp.evaluate is not None else None
        return CoarseResult(False, reason, None, self.steps, end_truth=end_truth)

    def _scene_map(self) -> SceneUncertaintyMap | None:
        """The scene uncertainty map, asked for once (its computation is waited for on the rig)."""
        if not self.scene_asked and self.inp.scene is not None:
            self.scene_asked = True
            t0 = time.monotonic()
            self.scene = self.inp.scene()
            self.inp.session.timing.wait_s += time.monotonic() - t0
        return self.scene

    def _choose_look(self, view: View) -> tuple[tuple[float, float], dict]:
        """The next look's heading ``(yaw, pitch)`` (radians, from where the stage started) and its log note.

        Candidates not yet seen: the fixed order's yaw headings +a, -a, +2a, ... (``max_looks`` of
        them) and a pitch of +a and -a. Seen from the best unverified estimate, the one whose
        predicted view has the lowest scene uncertainty (Eq. 2 over the map's directions turned from
        that view); ties, no estimate or no map: the first of the fixed order.
        """
        c = self.inp.config
        a = math.radians(c.look_deg)
        fixed = [(a * (1 + k // 2) * (1.0 if k % 2 == 0 else -1.0), 0.0) for k in range(c.max_looks)]
        candidates = [h for h in fixed + [(0.0, a), (0.0, -a)] if h not in self.seen_headings]
        chosen = candidates[0]
        note = {"chosen_by": "fixed order"}
        scene = self._scene_map() if view.unverified is not None else None
        if scene is not None and scene.model is not None:
            R_back = invert_pose(camera_turn(*self.heading))
            scored = [
                (
                    view_uncertainty(
                        scene.model,
                        view.unverified[1] @ R_back @ camera_turn(*h),
                        self.inp.camera,
                        config=scene.config,
                        coarse=c,
                    ),
                    h,
                )
                for h in candidates
            ]
            (u, f_img, f_geo), chosen = min(scored, key=lambda r: r[0][0])  # min keeps the first of a tie
            note = {
                "chosen_by": "scene uncertainty",
                "uncertainty": u,
                "image_fraction": f_img,
                "geometry_fraction": f_geo,
                "candidates": [
                    {"yaw_deg": math.degrees(h[0]), "pitch_deg": math.degrees(h[1]), "uncertainty": r[0]}
                    for r, h in scored
                ],
            }
        return chosen, {"yaw_deg": math.degrees(chosen[0]), "pitch_deg": math.degrees(chosen[1]), **note}

    def _look(self, step: int, view: View, truth) -> CoarseResult | None:
        """The turn-around action: a turn about the camera's centre (:meth:`_choose_look`), relative to
        where the stage started (a pure rotation: no translation towards anything unverified).
        A result when the stage ends here."""
        inp = self.inp
        if self.looks >= inp.config.max_looks:
            return self._pause(step, view, truth)
        target, note = self._choose_look(view)
        M_cam = invert_pose(camera_turn(*self.heading)) @ camera_turn(*target)
        try:
            inp.session.move_by(flange_motion(self.X, M_cam))
            self.M_unverified = self.M_unverified @ flange_motion(self.X, M_cam)
        except MotionRejected as exc:
            return CoarseResult(
                False, f"coarse stage: a look-around motion is refused by the platform guard ({exc})", None, self.steps
            )
        self._log(
            step,
            CoarseAction.LOOK,
            EstimateSource.NONE,
            view,
            truth,
            commanded=(0.0, pose_distance(np.eye(4), M_cam)[1]),
            look=note,
        )
        self.heading = target
        self.seen_headings.append(target)
        self.looks += 1
        where = f"{note['yaw_deg']:+.0f} deg" + (f", pitch {note['pitch_deg']:+.0f} deg" if target[1] else "")
        why = f" (scene uncertainty {note['uncertainty']:.2f})" if "uncertainty" in note else ""
        inp.say(f"coarse step {step}: no verified estimate; looking {where} from the start{why}")
        return None

    def _descend(self, step: int, view: View, truth) -> CoarseResult | None:
        """Paper 001's scene descent on an unverified estimate: it is assumed roughly right and the camera moves
        toward the localizable region (the reference view), half the estimated way, at most one step. With the
        true offset ``c`` and the estimate ``e``, the offset after the move is ``c - e/2``, shorter than ``c``
        whenever ``|e| / 4 < |c| cos(angle(c, e))``: a direction within 75 deg of the truth at the right
        distance, within 60 deg at twice it. Nothing is verified by it; the next view is localized afresh.
        A result when the stage ends here."""
        inp, c = self.inp, self.inp.config
        name, T_ref_cam, unc = view.unverified
        off_mm, off_deg = pose_distance(T_ref_cam, self.T_ref_camref)
        M_cam = invert_pose(T_ref_cam) @ self.T_ref_camref
        M_half = np.eye(4)  # half the translation, half the rotation angle about the same axis
        M_half[:3, :3] = Rotation.from_rotvec(0.5 * Rotation.from_matrix(M_cam[:3, :3]).as_rotvec()).as_matrix()
        M_half[:3, 3] = 0.5 * M_cam[:3, 3]
        M_flange, _ = clamp_motion(
            flange_motion(self.X, M_half), max_step_m=c.step_m, max_step_rad=math.radians(c.step_deg)
        )
        cmd_mm, cmd_deg = pose_distance(np.eye(4), M_flange)
        inp.say(
            f"coarse step {step}: no verified estimate; descending {cmd_mm:.0f} mm toward the reference on the "
            f"{name} estimate ({off_mm:.0f} mm / {off_deg:.1f} deg away, residual "
            f"{residual_m(unc, name) * 1e3:.0f} mm)"
        )
        try:
            inp.session.move_by(M_flange)
            self.M_unverified = self.M_unverified @ M_flange
        except MotionRejected as exc:
            return CoarseResult(
                False, f"coarse stage: a descent motion is refused by the platform guard ({exc})", None, self.steps
            )
        self._log(step, CoarseAction.DESCEND, name, view, truth, offset=(off_mm, off_deg), commanded=(cmd_mm, cmd_deg))
        self.descents += 1
        inp.session.settle(frames=inp.session.settle_frames + 1)
        return None

    def _advance(self, step: int, view: View, truth) -> CoarseResult | None:
        """Hand over when the verified estimate is near enough; else one bounded step toward the reference."""
        inp, c = self.inp, self.inp.config
        name, T_ref_cam, unc = view.best
        self.last_3d = _sim3_from_camera(T_ref_cam, view.T_cur_cam)
        off_mm, off_deg = pose_distance(T_ref_cam, self.T_ref_camref)
        if off_mm <= self.handover_m * 1e3 and off_deg <= self.handover_deg:
            self._log(step, CoarseAction.HANDOVER, name, view, truth, offset=(off_mm, off_deg))
            inp.say(
                f"coarse step {step}: verified ({name}) {off_mm:.0f} mm / {off_deg:.1f} deg from the reference; "
                "handing over to rACR"
            )
            return CoarseResult(
                True,
                f"verified {name} estimate within {self.handover_m * 1e3:.0f} mm / {self.handover_deg:.1f} deg",
                self.last_3d,
                self.steps,
            )
        M_cam = invert_pose(T_ref_cam) @ self.T_ref_camref
        M_flange, _ = clamp_motion(
            flange_motion(self.X, M_cam), max_step_m=c.step_m, max_step_rad=math.radians(c.step_deg)
        )
        cmd_mm, cmd_deg = pose_distance(np.eye(4), M_flange)
        self._log(step, CoarseAction.MOVE, name, view, truth, offset=(off_mm, off_deg), commanded=(cmd_mm, cmd_deg))
        inp.say(
            f"coarse step {step}: verified ({name}, uncertainty {unc.constrained_translation_m * 1e3:.0f} mm / "
            f"{unc.constrained_rotation_deg:.1f} deg"
            + (f", {unc.weak_directions} weak directions" if unc.weak_directions else "")
            + f") {off_mm:.0f} mm / {off_deg:.1f} deg away; moving {cmd_mm:.0f} mm"
        )
        try:
            inp.session.move_by(M_flange)
            self.M_unverified = np.eye(4)  # moved on a verified estimate: the pose to come back to
        except MotionRejected as exc:
            return CoarseResult(
                False,
                f"coarse stage: the way to the reference is refused by the platform guard ({exc})",
                None,
                self.steps,
            )
        inp.session.settle(frames=inp.session.settle_frames + 1)
        return None

    def run(self) -> CoarseResult:
        inp, c = self.inp, self.inp.config
        for step in range(1, c.max_steps + 1):
            view = localize(inp, step, self.last_3d)
            truth = inp.evaluate() if inp.evaluate is not None else None
            self.t_s = inp.session.timing.total_s
            if view.best is not None:
                done = self._advance(step, view, truth)
            elif view.unverified is not None and self.descents < c.max_descents:
                done = self._descend(step, view, truth)
            else:
                done = self._look(step, view, truth)
            if done is not None:
                return done
        return CoarseResult(
            False,
            f"coarse stage: not within {self.handover_m * 1e3:.0f} mm / "
            f"{self.handover_deg:.1f} deg of the reference after {c.max_steps} steps",
            None,
            self.steps,
        )


def run_coarse(inp: CoarseInputs) -> CoarseResult:
    """Move the camera from far away into the rACR loop's basin.

    Returns
    -------
    CoarseResult
        ``handed_over`` with the verified ``init`` for the rACR loop, or the reason it paused.
    """
    return _CoarseRun(inp).run()
