"""A revisit's exploration toward the reference (``fgcd relocate --guided``; :mod:`fgcd_cli.relocation.guided`).

Before any motion the image localizer (SIFT + PnP on the reference images and
cloud, the coarse stage's passive localizer) estimates the reference pose. When
it does, near enough for a revisit start, and the planned stops stay in the
guard's workspace, the exploration's legs go toward it; otherwise the usual
pattern runs. The localizer's computation counts as rig time.
"""

from __future__ import annotations

import time

import numpy as np

from fgcd_cli.app.rig import RigHandles
from fgcd_cli.app.session import grab_gray, reference_images, start_session
from fgcd_cli.relocation.coarse.config import CoarseConfig
from fgcd_cli.relocation.coarse.passive import image_estimate
from fgcd_cli.relocation.guided import guided_waypoints, motions_between, within_workspace
from fgcd_core.se3 import flange_motion, invert_pose, pose_distance

__all__ = ["GuidedPlan", "guided_exploration", "start_revisit_session", "workspace_bounds"]


class GuidedPlan:
    """The exploration chosen: ``motions`` (None: the usual pattern), why, the seconds the choice took,
    whether the image estimate put the start beyond the coarse stage's trigger (``far``), and the image
    estimate's 1-sigma (RMS radius, mm; NaN when the localizer gave none)."""

    def __init__(
        self,
        motions: list[np.ndarray] | None,
        reason: str,
        seconds: float,
        *,
        far: bool = False,
        sigma_mm: float = float("nan"),
    ):
        self.motions, self.reason, self.seconds, self.far = motions, reason, seconds, far
        self.sigma_mm = sigma_mm


def workspace_bounds(guard) -> tuple[np.ndarray, np.ndarray]:
    """The box every flange position must stay in: the platform's workspace within the guard's limits, metres."""
    caps = guard.platform.capabilities()
    lo, hi = np.array(caps.workspace_min_m, dtype=float), np.array(caps.workspace_max_m, dtype=float)
    if guard.limits.workspace_min_m is not None:
        lo = np.maximum(lo, guard.limits.workspace_min_m)
    if guard.limits.workspace_max_m is not None:
        hi = np.minimum(hi, guard.limits.workspace_max_m)
    return lo, hi


def guided_exploration(
    rig: RigHandles, station, reference, *, explore_m: float, near: CoarseConfig = CoarseConfig()
) -> GuidedPlan:
    """Plan the exploration toward the image localizer's estimate of the reference pose.

    ``near``: an estimate beyond its trigger (100 mm / 8 deg) is a far start, the
    coarse stage's case; the usual pattern runs and the coarse stage decides.
    """
    image = grab_gray(rig)
    t0 = time.monotonic()
    T_img, info = image_estimate(
        reference_images=reference_images(station), current_image=image, camera=rig.intrinsics, reference=reference
    )
    seconds = time.monotonic() - t0
    if T_img is None:
        return GuidedPlan(None, f"no image estimate ({info.get('pnp')}): the usual exploration", seconds)
    X = np.asarray(rig.T_flange_cam, dtype=float)
    M_cam = invert_pose(T_img) @ np.asarray(reference.T_ref_camref, dtype=float)
    M_flange = flange_motion(X, M_cam)
    mm, deg = pose_distance(np.eye(4), M_flange)
    if mm > near.trigger_m * 1e3 or deg > near.trigger_deg:
        return GuidedPlan(
            None,
            f"image estimate {mm:.0f} mm / {deg:.1f} deg away (a far start): the usual exploration",
            seconds,
            far=True,
        )
    motions = motions_between(guided_waypoints(M_flange, X, explore_m=explore_m), stops_per_leg=2)
    lo, hi = workspace_bounds(rig.guard)
    if not within_workspace(rig.guard.platform.flange_pose(), motions, lo, hi):
        return GuidedPlan(None, "the guided legs would leave the workspace: the usual exploration", seconds)
    return GuidedPlan(
        motions,
        f"exploring toward the image estimate of the reference ({mm:.0f} mm / {deg:.1f} deg)",
        seconds,
        sigma_mm=float(info.get("sigma_mm", float("nan"))),
    )


#: Tracked stops after which the usual exploration may end early: the scale fit needs 3, and two
#: legs of 2 stops leave the monocular map the baseline of two non-parallel translations.
EARLY_STOP_STOPS = 4


def alignment_trusted(rig: RigHandles, reference, ref_index, session, flange: list, cams: list) -> bool:
    """True when the session's scale fits and a fast alignment of its cloud to the reference is trustworthy.

    Asked once, at the usual exploration's fourth tracked stop: its last leg only returns to the
    start, which a trustworthy alignment makes useless (the loop drives to the reference from
    wherever the camera is). The check's computation counts as rig time.
    """
    from fgcd_cli.alignment.initial import initial_guess
    from fgcd_cli.app.session import MAX_SCALE_RESIDUAL_MM
    from fgcd_cli.errors import AlgorithmError

    if len(flange) != EARLY_STOP_STOPS:
        return False
    t0 = time.monotonic()
    try:
        scale = session.estimate_scale(rig.T_flange_cam, flange, cams)
        if scale.residual_rms_mm > MAX_SCALE_RESIDUAL_MM:
            return False
        state = session.vse.latest()
        T_cur_cam0 = np.array(state.T_map_cam, dtype=float)
        T_cur_cam0[:3, 3] *= scale.scale
        guess = initial_guess(
            T_ref_camref=reference.T_ref_camref,
            T_cur_cam0=T_cur_cam0,
            cur_points=np.asarray(state.cloud.points, dtype=float) * scale.scale,
            reference=ref_index,
            scale=1.0,
            global_fallback=False,
        )
        return guess.fast is not None and bool(guess.fast.health.ok)
    except AlgorithmError:
        return False
    finally:
        session.timing.wait_s += time.monotonic() - t0


def start_revisit_session(
    rig: RigHandles, station, reference, *, explore_m: float, legs: int, guided: bool, ref_index=None
):
    """A revisit's VSE session: ``(session, vse, scale, prior_sigma_mm)``.

    ``guided``: explored toward the image localizer's estimate of the reference when it has one;
    otherwise the usual pattern, ended early once the alignment is trustworthy (:func:`alignment_trusted`),
    except on a far start: there the whole pattern runs, as the active coarse stage expects its map.
    ``prior_sigma_mm``: when the exploration ended at the image estimate of the reference, that estimate's
    1-sigma (mm; NaN when unknown), the prior the loop checks its first 3D estimate against
    (``LoopContext.image_prior_sigma_mm``); None otherwise.
    """
    plan = guided_exploration(rig, station, reference, explore_m=explore_m) if guided else None
    until = None
    if plan is not None:
        rig.say(plan.reason)
        if plan.motions is None and not plan.far and ref_index is not None:

            def until(session, flange, cams):
                return alignment_trusted(rig, reference, ref_index, session, flange, cams)

    session, vse, scale, _ = start_session(
        rig, explore_m=explore_m, legs=legs, motions=plan.motions if plan is not None else None, until=until
    )
    if plan is not None:
        session.timing.wait_s += plan.seconds  # the platform stood still while the localizer ran
    prior_sigma_mm = plan.sigma_mm if plan is not None and plan.motions is not None else None
    return session, vse, scale, prior_sigma_mm
