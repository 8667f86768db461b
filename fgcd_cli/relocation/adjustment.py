"""The hand motion of one rACR adjustment (paper 000, Eq. 3), in fgcd's frames.

Derivation in the project's conventions (``T_a_b`` maps b into a):

* the alignment gives ``T_ref_cur`` (a similarity, scale ``sigma``) from the
  current session's metric frame into the reference frame, and the VSE gives the
  current camera ``T_cur_cam`` (the map pose with its translation multiplied by
  the session scale ``s``); hence the current camera in the reference frame is
  ``T_ref_cam = [R_p R_cam | sigma R_p t_cam + t_p]`` — the paper's
  ``T~_A = T_p [R_A, sigma t_A]``;
* the camera must move by ``M_cam = inv(T_ref_cam) @ T_ref_camref`` expressed in
  its own frame (the reference camera seen from the current camera);
* with the hand-eye ``X = T_flange_cam`` the camera motion ``M_cam`` is produced
  by the flange motion ``M_flange = X @ M_cam @ inv(X)`` expressed in the flange
  frame, since ``T_base_flange @ M_flange @ X = T_base_flange @ X @ M_cam``.

This is the paper's ``M_B = X^-1 T_ref (...)^-1 T_p^-1 X`` with its ``X``
mapping the other way round. The stop criterion is ``g = ||M_flange - I||_F``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fgcd_core.se3 import exp_se3, flange_motion, invert_pose, log_se3, pose_distance, rotation_angle_rad
from fgcd_core.sim3 import Sim3

__all__ = ["Adjustment", "camera_in_reference", "compute_adjustment", "clamp_motion"]


@dataclass(frozen=True, kw_only=True)
class Adjustment:
    """One adjustment's estimate and command.

    Attributes
    ----------
    T_ref_cam : (4, 4) ndarray
        Estimated current camera pose in the reference frame.
    M_cam : (4, 4) ndarray
        Camera motion to the reference pose, in the current camera frame.
    M_flange : (4, 4) ndarray
        The same motion produced at the flange, in the flange frame (the paper's M_B).
    M_flange_commanded : (4, 4) ndarray
        ``M_flange`` after clamping to the maximum step.
    g : float
        ``||M_flange - I||_F`` (mixes metres and radians, as in the paper).
    offset_mm, offset_deg : float
        Remaining camera offset for people.
    clamped : bool
        True if the step limit shortened the motion.
    """

    T_ref_cam: np.ndarray
    M_cam: np.ndarray
    M_flange: np.ndarray
    M_flange_commanded: np.ndarray
    g: float
    offset_mm: float
    offset_deg: float
    clamped: bool


def camera_in_reference(T_ref_cur: Sim3, T_cur_cam: np.ndarray) -> np.ndarray:
    """Current camera pose in the reference frame, shape (4, 4)."""
    return T_ref_cur.transform_pose(T_cur_cam)


def clamp_motion(M: np.ndarray, *, max_step_m: float, max_step_rad: float) -> tuple[np.ndarray, bool]:
    """Shorten a rigid motion along its geodesic so it respects both step limits.

    Parameters
    ----------
    M : (4, 4) ndarray
        Rigid motion.
    max_step_m, max_step_rad : float
        Largest translation (metres) and rotation (radians) allowed.

    Returns
    -------
    M_clamped : (4, 4) ndarray
    clamped : bool
    """
    trans = float(np.linalg.norm(M[:3, 3]))
    rot = rotation_angle_rad(M[:3, :3])
    factor = 1.0
    if trans > max_step_m:
        factor = min(factor, max_step_m / trans)
    if rot > max_step_rad:
        factor = min(factor, max_step_rad / rot)
    if factor >= 1.0:
        return M.copy(), False
    # scale the twist, then shrink again if the curved path overshoots the limits
    xi = log_se3(M)
    for _ in range(20):
        Mc = exp_se3(xi * factor)
        if np.linalg.norm(Mc[:3, 3]) <= max_step_m * (1 + 1e-9) and rotation_angle_rad(Mc[:3, :3]) <= max_step_rad * (
            1 + 1e-9
        ):
            return Mc, True
        factor *= 0.95
    return exp_se3(xi * factor), True


def compute_adjustment(
    *,
    T_ref_cur: Sim3,
    T_cur_cam: np.ndarray,
    T_ref_camref: np.ndarray,
    T_flange_cam: np.ndarray,
    max_step_m: float = math.inf,
    max_step_rad: float = math.inf,
) -> Adjustment:
    """The flange motion that brings the camera to the reference pose.

    Parameters
    ----------
    T_ref_cur : Sim3
        Alignment of the current metric frame into the reference frame.
    T_cur_cam : (4, 4) ndarray
        Current camera pose in the current metric frame (VSE pose times scale ``s``).
    T_ref_camref : (4, 4) ndarray
        The reference camera pose in the reference frame.
    T_flange_cam : (4, 4) ndarray
        Hand-eye transform (identity for the ``--no-handeye`` variant).
    max_step_m, max_step_rad : float
        Step limits; the commanded motion is clamped along its geodesic.
    """
    T_ref_cam = camera_in_reference(T_ref_cur, T_cur_cam)
    M_cam = invert_pose(T_ref_cam) @ np.asarray(T_ref_camref, dtype=float)
    X = np.asarray(T_flange_cam, dtype=float)
    M_flange = flange_motion(X, M_cam)  # paper 000, Eq. 3
    M_cmd, clamped = clamp_motion(M_flange, max_step_m=max_step_m, max_step_rad=max_step_rad)
    g = float(np.linalg.norm(M_flange - np.eye(4)))
    off_mm, off_deg = pose_distance(T_ref_cam, T_ref_camref)
    return Adjustment(
        T_ref_cam=T_ref_cam,
        M_cam=M_cam,
        M_flange=M_flange,
        M_flange_commanded=M_cmd,
        g=g,
        offset_mm=off_mm,
        offset_deg=off_deg,
        clamped=clamped,
    )
