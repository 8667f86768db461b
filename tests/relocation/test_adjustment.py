"""The adjustment formula: with perfect alignment and platform, one adjustment reaches the reference."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fgcd_cli.relocation.adjustment import clamp_motion, compute_adjustment
from fgcd_core.se3 import exp_se3, invert_pose, pose_distance, rotation_angle_rad
from fgcd_core.sim3 import Sim3


def random_pose(rng, t_scale=0.1, r_scale=0.3):
    return exp_se3(np.r_[rng.normal(size=3) * t_scale, rng.normal(size=3) * r_scale])


@settings(max_examples=40)
@given(st.integers(0, 2**31 - 1))
def test_one_adjustment_reaches_reference_with_perfect_knowledge(seed):
    rng = np.random.default_rng(seed)
    T_flange_cam = random_pose(rng, 0.1, 0.5)  # hidden hand-eye, known exactly here
    T_base_flange = random_pose(rng, 0.3, 0.5)
    T_world_base = random_pose(rng, 1.0, 1.0)
    # reference frame = world with some unknown similarity to the current session's map
    T_ref_world = Sim3.exp(np.r_[rng.normal(size=6) * 0.3, 0.0])
    s_true = math.exp(rng.normal() * 0.5)  # map units -> metres
    T_cur_world = Sim3.exp(np.r_[rng.normal(size=6) * 0.3, 0.0])  # metric current frame
    T_world_camref = T_world_base @ random_pose(rng, 0.3, 0.5) @ T_flange_cam
    T_ref_camref = T_ref_world.transform_pose(T_world_camref)

    T_world_cam = T_world_base @ T_base_flange @ T_flange_cam
    T_cur_cam = T_cur_world.transform_pose(T_world_cam)
    # VSE reports the map pose up to scale: map = cur / s_true; the loop multiplies back by s
    T_map_cam = T_cur_cam.copy()
    T_map_cam[:3, 3] /= s_true
    T_cur_cam_est = T_map_cam.copy()
    T_cur_cam_est[:3, 3] *= s_true
    T_ref_cur = T_ref_world @ T_cur_world.inverse()

    adj = compute_adjustment(
        T_ref_cur=T_ref_cur, T_cur_cam=T_cur_cam_est, T_ref_camref=T_ref_camref, T_flange_cam=T_flange_cam
    )
    T_base_flange_new = T_base_flange @ adj.M_flange
    T_world_cam_new = T_world_base @ T_base_flange_new @ T_flange_cam
    mm, deg = pose_distance(T_world_cam_new, T_world_camref)
    assert mm < 1e-6 and deg < 1e-6
    # estimate of where the camera was matches the truth
    mm0, deg0 = pose_distance(adj.T_ref_cam, T_ref_world.transform_pose(T_world_cam))
    assert mm0 < 1e-6 and deg0 < 1e-6


def test_g_is_zero_at_reference_and_grows_with_offset():
    T = exp_se3([0.01, 0.0, 0.0, 0.0, 0.0, 0.0])
    at = compute_adjustment(T_ref_cur=Sim3(), T_cur_cam=T, T_ref_camref=T, T_flange_cam=np.eye(4))
    assert at.g < 1e-12 and at.offset_mm < 1e-9
    off = compute_adjustment(T_ref_cur=Sim3(), T_cur_cam=np.eye(4), T_ref_camref=T, T_flange_cam=np.eye(4))
    assert off.g == pytest.approx(0.01, rel=1e-9)
    assert off.offset_mm == pytest.approx(10.0, rel=1e-9)


def test_wrong_handeye_rotation_still_reduces_offset():
    """rACR §3.7: the loop converges while the hand-eye rotation error is below 45 degrees."""
    rng = np.random.default_rng(3)
    X_true = random_pose(rng, 0.08, 0.6)
    X_guess = X_true @ exp_se3([0.02, -0.01, 0.0, 0.0, 0.0, math.radians(30.0)])
    T_base_flange = random_pose(rng, 0.2, 0.3)
    T_ref_camref = T_base_flange @ exp_se3([0.03, 0.02, 0.01, 0.05, 0.02, 0.03]) @ X_true
    first = None
    for _ in range(30):
        T_cam = T_base_flange @ X_true
        adj = compute_adjustment(T_ref_cur=Sim3(), T_cur_cam=T_cam, T_ref_camref=T_ref_camref, T_flange_cam=X_guess)
        first = first or adj.offset_mm
        T_base_flange = T_base_flange @ adj.M_flange
    mm, deg = pose_distance(T_base_flange @ X_true, T_ref_camref)
    assert mm < 0.01 * first and deg < 0.05


def test_clamp_respects_limits_and_direction():
    M = exp_se3([0.08, 0.0, 0.03, 0.0, math.radians(20), 0.0])
    Mc, clamped = clamp_motion(M, max_step_m=0.02, max_step_rad=math.radians(5))
    assert clamped
    assert np.linalg.norm(Mc[:3, 3]) <= 0.02 + 1e-12
    assert rotation_angle_rad(Mc[:3, :3]) <= math.radians(5) + 1e-12
    assert np.dot(Mc[:3, 3], M[:3, 3]) > 0
    same, c2 = clamp_motion(M, max_step_m=1.0, max_step_rad=1.0)
    assert not c2 and np.allclose(same, M)
    _ = invert_pose(Mc)
