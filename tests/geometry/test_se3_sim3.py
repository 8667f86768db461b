"""Group laws and round trips of SE(3) and Sim(3), property-based."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from fgcd_core.se3 import (
    exp_se3,
    interpolate_pose,
    invert_pose,
    is_pose,
    log_se3,
    pose_distance,
    pose_from_quat,
    pose_from_rotvec,
    pose_to_quat,
    pose_to_rotvec,
    transform_points,
)
from fgcd_core.sim3 import Sim3, umeyama

finite = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)
# rotation angles below pi (log is ambiguous at exactly pi)
twist = arrays(np.float64, 6, elements=finite).map(
    lambda x: np.r_[x[:3], x[3:] * 2.5 / max(1.0, np.linalg.norm(x[3:]))]
)
sim_tangent = st.tuples(twist, st.floats(-1.0, 1.0)).map(lambda p: np.r_[p[0], p[1]])


@given(twist)
def test_exp_log_se3_round_trip(xi):
    T = exp_se3(xi)
    assert is_pose(T)
    np.testing.assert_allclose(log_se3(T), xi, atol=1e-8)


@given(twist, twist, twist)
def test_se3_associative_and_inverse(a, b, c):
    A, B, C = exp_se3(a), exp_se3(b), exp_se3(c)
    np.testing.assert_allclose((A @ B) @ C, A @ (B @ C), atol=1e-9)
    np.testing.assert_allclose(A @ invert_pose(A), np.eye(4), atol=1e-9)
    np.testing.assert_allclose(invert_pose(A @ B), invert_pose(B) @ invert_pose(A), atol=1e-9)


@given(twist)
def test_rotvec_and_quaternion_round_trips(xi):
    T = exp_se3(xi)
    rv, t = pose_to_rotvec(T)
    np.testing.assert_allclose(pose_from_rotvec(rv, t), T, atol=1e-9)
    q, t = pose_to_quat(T)
    assert q[3] >= 0
    np.testing.assert_allclose(np.linalg.norm(q), 1.0, atol=1e-12)
    np.testing.assert_allclose(pose_from_quat(q, t), T, atol=1e-9)


@given(twist, twist, st.floats(0.0, 1.0))
def test_interpolation_endpoints_and_monotone_distance(a, b, alpha):
    A, B = exp_se3(a), exp_se3(b)
    np.testing.assert_allclose(interpolate_pose(A, B, 0.0), A, atol=1e-9)
    np.testing.assert_allclose(interpolate_pose(A, B, 1.0), B, atol=1e-9)
    M = interpolate_pose(A, B, alpha)
    dt_total, dr_total = pose_distance(A, B)
    dt, dr = pose_distance(A, M)
    assert dt <= dt_total * alpha + 1e-6
    assert dr <= dr_total * alpha + 1e-6


def test_pose_distance_units():
    A = np.eye(4)
    B = pose_from_rotvec([0, 0, math.radians(3.0)], [0.001, 0.002, 0.0])
    mm, deg = pose_distance(A, B)
    assert math.isclose(mm, math.hypot(1.0, 2.0), rel_tol=1e-12)
    assert math.isclose(deg, 3.0, rel_tol=1e-9)


@given(sim_tangent)
def test_sim3_exp_log_round_trip(xi):
    S = Sim3.exp(xi)
    np.testing.assert_allclose(S.log(), xi, atol=1e-7)
    np.testing.assert_allclose(S.scale, math.exp(xi[6]), rtol=1e-9)


@given(sim_tangent, sim_tangent, arrays(np.float64, (5, 3), elements=finite))
def test_sim3_group_laws(a, b, pts):
    A, B = Sim3.exp(a), Sim3.exp(b)
    np.testing.assert_allclose((A @ B).apply(pts), A.apply(B.apply(pts)), atol=1e-9)
    np.testing.assert_allclose((A @ A.inverse()).matrix(), np.eye(4), atol=1e-9)
    np.testing.assert_allclose(Sim3.from_matrix(A.matrix()).matrix(), A.matrix(), atol=1e-9)
    np.testing.assert_allclose(A.matrix() @ B.matrix(), (A @ B).matrix(), atol=1e-9)


@settings(max_examples=30)
@given(sim_tangent, st.integers(0, 2**31 - 1))
def test_umeyama_recovers_similarity(xi, seed):
    rng = np.random.default_rng(seed)
    S = Sim3.exp(xi)
    src = rng.normal(size=(40, 3))
    est = umeyama(src, S.apply(src))
    np.testing.assert_allclose(est.matrix(), S.matrix(), atol=1e-8)
    rigid = umeyama(src, Sim3(S.R, S.t, 1.0).apply(src), with_scale=False)
    assert rigid.scale == 1.0
    np.testing.assert_allclose(rigid.R, S.R, atol=1e-8)


def test_umeyama_never_returns_a_reflection():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(50, 3))
    mirrored = src * np.array([-1.0, 1.0, 1.0])
    est = umeyama(src, mirrored)
    assert np.linalg.det(est.R) > 0


def test_transform_pose_moves_camera_centre_with_scale():
    S = Sim3(np.eye(3), np.array([1.0, 0.0, 0.0]), 2.0)
    T = pose_from_rotvec([0.1, 0.2, 0.3], [0.5, 0.0, 0.0])
    T2 = S.transform_pose(T)
    np.testing.assert_allclose(T2[:3, 3], [2.0, 0.0, 0.0])
    np.testing.assert_allclose(T2[:3, :3], T[:3, :3])
    np.testing.assert_allclose(transform_points(T2, np.zeros((1, 3)))[0], T2[:3, 3])


@given(sim_tangent)
def test_sim3_rotvec_quaternion_and_matrix_round_trips(xi):
    S = Sim3.exp(xi)
    rv, t, s = S.to_rotvec()
    np.testing.assert_allclose(Sim3.from_rotvec(rv, t, s).matrix(), S.matrix(), atol=1e-9)
    q, t, s = S.to_quat()
    assert q[3] >= 0 and math.isclose(np.linalg.norm(q), 1.0, rel_tol=1e-12)
    np.testing.assert_allclose(Sim3.from_quat(q, t, s).matrix(), S.matrix(), atol=1e-9)
    np.testing.assert_allclose(Sim3.from_matrix(S.matrix()).matrix(), S.matrix(), atol=1e-9)


@given(sim_tangent, sim_tangent, st.floats(0.0, 1.0))
def test_sim3_interpolation_endpoints_and_monotone_distance(a, b, alpha):
    A, B = Sim3.exp(a), Sim3.exp(b)
    np.testing.assert_allclose(A.interpolate(B, 0.0).matrix(), A.matrix(), atol=1e-9)
    np.testing.assert_allclose(A.interpolate(B, 1.0).matrix(), B.matrix(), atol=1e-9)
    M = A.interpolate(B, alpha)
    mm_total, deg_total, ratio_total = A.distance(B)
    mm, deg, ratio = A.distance(M)
    assert mm <= mm_total * alpha + 1e-6
    assert deg <= deg_total * alpha + 1e-6
    assert math.log(ratio) <= math.log(ratio_total) * alpha + 1e-9
    # scale is interpolated geometrically: exactly the log-linear blend
    assert math.isclose(math.log(M.scale), (1 - alpha) * math.log(A.scale) + alpha * math.log(B.scale), abs_tol=1e-12)


def test_sim3_distance_units():
    A = Sim3.identity()
    B = Sim3.from_rotvec([0.0, 0.0, math.radians(3.0)], [0.001, 0.002, 0.0], 0.5)
    mm, deg, ratio = A.distance(B)
    assert math.isclose(mm, math.hypot(1.0, 2.0), rel_tol=1e-12)
    assert math.isclose(deg, 3.0, rel_tol=1e-9)
    assert math.isclose(ratio, 2.0, rel_tol=1e-12)
