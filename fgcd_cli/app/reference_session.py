"""The reference capture's VSE session: explored widely enough for the cloud every later visit relies on.

A revisit lifts its image matches to 3D with the reference cloud and checks its
estimates against it; the relocation's uncertainty models assume that cloud's
depths are placed to ``RelocationConfig.vse_sigma_rel`` of the depth. A
monocular cloud triangulated over short legs is not (its depth error grows as
``z^2 / (f b)``, :func:`~fgcd_cli.relocation.session.reference_leg_m`). So the
capture explores once as a revisit would, measures the object's depth, and
when the leg was too short for that depth explores again with the leg the model
asks for, within the platform's workspace (docs/relocation.md, "The reference
cloud"). There is no time pressure at a reference capture; there is at a revisit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fgcd_cli.app.rig import RigHandles
from fgcd_cli.app.session import start_session
from fgcd_cli.errors import AlgorithmError
from fgcd_cli.relocation.config import RelocationConfig
from fgcd_cli.relocation.session import ScaleEstimate, VseSession, exploration_waypoints, reference_leg_m
from fgcd_cli.relocation.stop_rule import reference_depth_m

__all__ = ["MAX_REFERENCE_LEG_M", "ReferenceSession", "start_reference_session"]

#: Longest exploration leg of a reference capture (metres): the legs stay within a hand's breadth of the
#: pose the conservator chose, whatever the model would ask for a distant object.
MAX_REFERENCE_LEG_M = 0.15


@dataclass
class ReferenceSession:
    """A started reference session: the session, its engine, its scale, the pose it started from (the
    reference flange pose, (4, 4)), the exploration leg it used (metres) and why."""

    session: VseSession
    vse: object
    scale: ScaleEstimate
    T_base_flange_home: np.ndarray
    leg_m: float
    note: str


def _inside_workspace(guard, targets: list[np.ndarray]) -> bool:
    """True when every flange target (4, 4) lies in the guard's workspace box (the platform's, intersected
    with the guard's own limits), the rule :meth:`drivers.platform.MotionGuard.check` applies to each motion."""
    caps = guard.platform.capabilities()
    lo = np.array(caps.workspace_min_m, dtype=float)
    hi = np.array(caps.workspace_max_m, dtype=float)
    if guard.limits.workspace_min_m is not None:
        lo = np.maximum(lo, guard.limits.workspace_min_m)
    if guard.limits.workspace_max_m is not None:
        hi = np.minimum(hi, guard.limits.workspace_max_m)
    return all(bool(np.all(T[:3, 3] >= lo - 1e-9) and np.all(T[:3, 3] <= hi + 1e-9)) for T in targets)


def _wanted_leg_m(rig: RigHandles, session: VseSession, scale: ScaleEstimate, *, sigma_rel: float) -> float:
    """The leg the depth model asks for at the object's measured depth (NaN without a cloud)."""
    state = session.tracking_state()
    if state.T_map_cam is None or len(state.cloud) == 0:
        return math.nan
    T_cam = np.array(state.T_map_cam, dtype=float)
    T_cam[:3, 3] *= scale.scale
    depth = reference_depth_m(np.asarray(state.cloud.points, dtype=float) * scale.scale, T_cam)
    return reference_leg_m(depth_m=depth, fx_px=float(rig.intrinsics.fx), sigma_rel=sigma_rel)


def _feasible_leg_m(rig: RigHandles, home: np.ndarray, wanted_m: float, *, floor_m: float) -> float | None:
    """The longest leg up to ``wanted_m`` whose waypoints all lie in the workspace (shortened by 20 % at a
    time); None when none longer than ``floor_m`` does."""
    leg = min(wanted_m, MAX_REFERENCE_LEG_M)
    while leg > floor_m:
        if _inside_workspace(rig.guard, [home @ W for W in exploration_waypoints(translation_m=leg)]):
            return leg
        leg *= 0.8
    return None


def start_reference_session(rig: RigHandles, *, explore_m: float,
                            sigma_rel: float = RelocationConfig().vse_sigma_rel) -> ReferenceSession:
    """Start the reference capture's session (module docstring): explore with ``explore_m`` legs, then once
    more with the leg the depth model asks for when that is more than 10 % longer and fits the workspace.

    Parameters
    ----------
    rig : RigHandles
    explore_m : float
        First exploration leg, metres (a revisit's).
    sigma_rel : float
        Wanted depth precision of the reference cloud, a fraction of the depth.

    Returns
    -------
    ReferenceSession
        The session to capture with; the first one when the wider exploration is not needed, does not
        fit, or fails (its reason in ``note``).
    """
    session, vse, scale, home = start_session(rig, explore_m=explore_m)
    wanted = _wanted_leg_m(rig, session, scale, sigma_rel=sigma_rel)
    if not (math.isfinite(wanted) and wanted > 1.1 * explore_m):
        return ReferenceSession(session, vse, scale, home, explore_m, "the first exploration's legs suffice")
    leg = _feasible_leg_m(rig, home, wanted, floor_m=1.1 * explore_m)
    if leg is None:
        return ReferenceSession(session, vse, scale, home, explore_m,
                                f"a {wanted * 100:.0f} cm leg does not fit the workspace; the reference depths "
                                f"are coarser than {sigma_rel:.0%} of the depth")
    rig.say(f"the object is far for {explore_m * 100:.0f} cm legs: exploring again with {leg * 100:.0f} cm legs "
            f"(depths to {sigma_rel:.0%} need {wanted * 100:.0f} cm)")
    session.move_to_flange(home, label="back to the reference pose")
    vse.stop()
    try:
        session, vse, scale, home2 = start_session(rig, explore_m=leg)
    except AlgorithmError as exc:
        rig.say(f"the wider exploration failed ({exc}); exploring again as at first")
        session, vse, scale, home2 = start_session(rig, explore_m=explore_m)
        return ReferenceSession(session, vse, scale, home2, explore_m, f"the {leg * 100:.0f} cm exploration failed")
    return ReferenceSession(session, vse, scale, home2, leg,
                            f"explored again with {leg * 100:.0f} cm legs for depths to {sigma_rel:.0%}")
