"""A revisit's exploration toward the reference (issue 21, "a faster revisit").

The exploration exists to give the monocular VSE a baseline (translation with
parallax) and the scale fit tracked stops (docs/relocation.md, "What a session
does"). It need not lead away from the reference. When the image localizer
estimates the reference pose before any motion, the legs go *toward* it:

    start → R + a − b → R        (R: the estimated reference flange pose)

with ``a`` perpendicular to the way there and to the optical axis, ``|a|`` half
the exploration amplitude, and ``b`` a step back along the
optical axis, away from the object, of :data:`BACK_FRACTION` of the amplitude
from the nearer of the start and ``R`` (when the way there leads toward the
object, a step back from ``R`` alone would cancel it and leave the stops level
with the start, the initialiser's first view).
The step back is what lets a monocular VSE start on a flat object: before a
plane facing the camera, a sideways translation moves the image as a small
rotation does (the homography ``K (R + t nᵀ/d) K⁻¹`` differs from ``K R K⁻¹`` by
a shift only), so the initialiser's rotation-only test
(:func:`fgcd_cli.vse.twoview.rotation_only_residual_px`) sees no parallax when
the way there is sideways too; a move along the axis scales the image, which
no rotation does (1 cm at 1.2 m moves the image corners ~2.5 px, ten times
the test's 0.2 px). The stops never come closer to the object than R. The
exploration ends where the rACR loop would have driven the camera anyway, and
the loop only refines. Rotation toward the reference is spread over the legs.

Two legs, not three: the map and the scale fit need translations with parallax
from the start, in two directions (the start's view is the initialiser's first
frame and the fit's origin). The first stop lies ``|d + a − b|`` from the start
and R lies ``|d|`` from it, across ``|a − b|``; a third stop on the other side
of R (``R − a − b``) adds one more displacement of the same size at the price
of a 2|a| leg and a return (docs/relocation.md, "A guided exploration").

Every waypoint is checked against the guard's workspace before the first
motion (:func:`within_workspace`); a plan that leaves it is not used (the usual
pattern is). The guard still checks every sub-step.
"""

from __future__ import annotations

import numpy as np

from fgcd_core.se3 import exp_se3, invert_pose, log_se3

__all__ = ["BACK_FRACTION", "guided_waypoints", "motions_between", "within_workspace"]

#: The sideways stops' step back along the optical axis, as a fraction of the exploration amplitude
#: (1 cm of a 4 cm exploration: the module docstring gives the model).
BACK_FRACTION = 0.25


def _sideways(d: np.ndarray, optical_axis: np.ndarray, camera_x: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to the way there ``d`` and to the optical axis (the camera's x when ``d`` is along it)."""
    a = np.cross(d, optical_axis)
    n = float(np.linalg.norm(a))
    if n < 1e-6 * max(1e-12, float(np.linalg.norm(d))) or n < 1e-9:
        return camera_x / np.linalg.norm(camera_x)
    return a / n


def guided_waypoints(M_flange_ref: np.ndarray, T_flange_cam: np.ndarray, *, explore_m: float) -> list[np.ndarray]:
    """Flange waypoints relative to the start flange (the first is the identity), ending at the estimated reference.

    Parameters
    ----------
    M_flange_ref : (4, 4) ndarray
        The estimated reference flange pose in the start flange's frame (the flange motion to the
        reference: ``X · M_cam · X⁻¹``, :mod:`fgcd_cli.relocation.adjustment`), metres.
    T_flange_cam : (4, 4) ndarray
        Hand-eye: the optical axis and the camera's x axis in the flange frame.
    explore_m : float
        Exploration amplitude, metres: the first stop lies half of it sideways of the way there.

    Returns
    -------
    list of (4, 4) ndarray
        ``[I, R + a − b, R]``: poses in the start flange's frame.
    """
    M = np.asarray(M_flange_ref, dtype=float)
    X = np.asarray(T_flange_cam, dtype=float)
    d = M[:3, 3]
    a = 0.5 * explore_m * _sideways(d, X[:3, 2], X[:3, 0])
    axis = X[:3, 2] / np.linalg.norm(X[:3, 2])  # the optical axis, toward the object
    # The stops' depth along the axis: a step back of BACK_FRACTION from the nearer of the start
    # and R (module docstring): behind R, and behind the start, the initialiser's first view,
    # even when the way there leads toward the object and would cancel a step back from R alone.
    d_axial = float(np.dot(d, axis))
    back = (min(d_axial, 0.0) - BACK_FRACTION * explore_m - d_axial) * axis
    xi = log_se3(M)
    # rotation toward the reference spread over the legs: half of it, then all of it
    T_side = exp_se3(np.r_[np.zeros(3), xi[3:] * 0.5])
    T_side[:3, 3] = d + a + back
    return [np.eye(4), T_side, M.copy()]


def motions_between(waypoints: list[np.ndarray], *, stops_per_leg: int = 2) -> list[np.ndarray]:
    """Relative flange motions from waypoint to waypoint, each leg cut into ``stops_per_leg`` equal motions."""
    n = max(1, int(stops_per_leg))
    legs = [invert_pose(a) @ b for a, b in zip(waypoints[:-1], waypoints[1:])]
    return [exp_se3(log_se3(L) / n) for L in legs for _ in range(n)]


def within_workspace(
    T_base_flange_start: np.ndarray, motions: list[np.ndarray], lo_m: np.ndarray, hi_m: np.ndarray
) -> bool:
    """True when every stop of ``motions`` from ``T_base_flange_start`` lies in the box ``[lo_m, hi_m]`` (metres).

    The path between two stops is a screw motion of a few centimetres; the guard checks each of its
    sub-steps again when it moves.
    """
    T = np.asarray(T_base_flange_start, dtype=float)
    lo, hi = np.asarray(lo_m, dtype=float), np.asarray(hi_m, dtype=float)
    for M in motions:
        T = T @ M
        if np.any(T[:3, 3] < lo - 1e-9) or np.any(T[:3, 3] > hi + 1e-9):
            return False
    return True
