"""Simulated platform: error statistics, speed model, workspace, faults, protocol."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fgcd_core.platform import (
    GuardLimits,
    MotionGuard,
    MotionRejected,
    Platform,
    PlatformConnectionError,
    PlatformTimeout,
    SafetyStop,
)
from fgcd_core.se3 import exp_so3, make_pose
from fgcd_drivers.sim.platform import PlatformErrorModel, SimPlatform, SimPlatformConfig
from fgcd_drivers.sim.transforms import rot_angle

ZERO = dict(
    scale_error=0,
    axis_misalignment_rad=0,
    rotation_scale_error=0,
    noise_m=0,
    noise_rad=0,
    backlash_m=0,
    encoder_noise_m=0,
    encoder_noise_rad=0,
)


def _platform(seed=0, **errors):
    e = PlatformErrorModel(**{**ZERO, **errors})
    p = SimPlatform(T_base_flange_home=make_pose(np.eye(3), [0.5, 0.0, 0.4]), errors=e, seed=seed)
    p.connect()
    return p


def _target(p, dt, rotvec=(0, 0, 0)):
    T = p.T_base_flange_home
    return make_pose(T[:3, :3] @ exp_so3(rotvec), T[:3, 3] + np.asarray(dt))


def test_implements_protocol_and_passes_the_guard():
    p = _platform()
    assert isinstance(p, Platform)
    guard = MotionGuard(platform=p, limits=GuardLimits(max_step_m=0.02))
    res = guard.move_by(make_pose(np.eye(3), [0.01, 0, 0]))
    np.testing.assert_allclose(res.T_base_flange_reached[:3, 3], [0.51, 0, 0.4], atol=1e-12)
    with pytest.raises(MotionRejected):
        guard.move_by(make_pose(np.eye(3), [0.05, 0, 0]))


def test_error_free_platform_is_exact():
    p = _platform()
    T = _target(p, [0.03, -0.02, 0.01], rotvec=[0.05, -0.02, 0.1])
    res = p.move_to(T)
    np.testing.assert_allclose(p.true_flange_pose(), T, atol=1e-12)
    np.testing.assert_allclose(res.T_base_flange_reached, T, atol=1e-12)


def test_repeatability_noise_has_configured_std():
    sigma, sigma_r = 1e-4, math.radians(0.01)
    p = _platform(seed=3, noise_m=sigma, noise_rad=sigma_r)
    rng = np.random.default_rng(0)
    dt, dr = [], []
    for _ in range(300):
        T = _target(p, rng.uniform(-0.05, 0.05, 3), rng.normal(0, 0.05, 3))
        p.move_to(T)
        Tt = p.true_flange_pose()
        dt.append(Tt[:3, 3] - T[:3, 3])
        dr.append(rot_angle(T[:3, :3].T @ Tt[:3, :3]))
    dt = np.array(dt)
    # 900 samples: relative std error ~ 1/sqrt(2 * 900) = 2.4 %; allow 12 %
    assert np.std(dt) == pytest.approx(sigma, rel=0.12)
    assert abs(np.mean(dt)) < 4 * sigma / math.sqrt(dt.size)
    # rotation error angle of an isotropic 3D Gaussian: mean = 2 sqrt(2/pi) sigma
    assert np.mean(dr) == pytest.approx(2 * math.sqrt(2 / math.pi) * sigma_r, rel=0.12)


def test_proportional_error_grows_with_distance_from_home():
    p = _platform(seed=5, scale_error=5e-3)
    for d in (0.01, 0.05, 0.1):
        p.move_to(_target(p, [d, 0, 0]))
        err = p.true_flange_pose()[0, 3] - (0.5 + d)
        ratios = err / d
        if d == 0.01:
            first = ratios
        assert ratios == pytest.approx(first, rel=1e-9)
    assert 1e-5 < abs(first) < 0.03  # a scale error drawn with std 0.5 %


def test_backlash_depends_on_approach_direction():
    b = 5e-5
    p = _platform(backlash_m=b)
    p.move_to(_target(p, [0.02, 0, 0]))
    p.move_to(_target(p, [0.01, 0, 0]))  # approach x = 0.51 from above
    x_down = p.true_flange_pose()[0, 3]
    p.move_to(_target(p, [0.0, 0, 0]))
    p.move_to(_target(p, [0.01, 0, 0]))  # approach from below
    x_up = p.true_flange_pose()[0, 3]
    assert x_down - x_up == pytest.approx(b, abs=1e-12)
    # the encoder does not see it
    np.testing.assert_allclose(p.flange_pose()[:3, 3], [0.51, 0, 0.4], atol=1e-12)


def test_encoder_noise_on_reported_pose_only():
    p = _platform(encoder_noise_m=1e-5)
    p.move_to(_target(p, [0.01, 0, 0]))
    reads = np.array([p.flange_pose()[:3, 3] for _ in range(400)])
    assert np.std(reads - [0.51, 0, 0.4]) == pytest.approx(1e-5, rel=0.15)
    np.testing.assert_allclose(p.true_flange_pose()[:3, 3], [0.51, 0, 0.4], atol=1e-12)


def test_speed_model_and_simulated_clock():
    p = _platform()
    t0 = p.clock.now()
    res = p.move_to(_target(p, [0.02, 0, 0]))
    assert res.duration_s == pytest.approx(2 * 1.5 + p.settle_s)
    assert p.clock.now() - t0 == pytest.approx(res.duration_s)
    res = p.move_to(_target(p, [0.02, 0, 0], rotvec=[0, 0, math.radians(10)]))
    assert res.duration_s == pytest.approx(10 / 5.0 + p.settle_s)


def test_workspace_limits():
    p = _platform()
    with pytest.raises(MotionRejected):
        p.move_to(_target(p, [0.3, 0, 0]))


def test_faults_raise_the_right_errors():
    p = _platform()
    p.inject_fault("timeout")
    with pytest.raises(PlatformTimeout):
        p.move_to(_target(p, [0.01, 0, 0]))
    # the motion stopped half way
    assert 0.5 < p.true_flange_pose()[0, 3] < 0.51
    p.move_to(_target(p, [0.01, 0, 0]))  # works again

    p.inject_fault("estop", after_moves=1)
    p.move_to(_target(p, [0.0, 0, 0]))
    with pytest.raises(SafetyStop):
        p.move_to(_target(p, [0.01, 0, 0]))
    with pytest.raises(SafetyStop):  # latched until a person clears it
        p.move_to(_target(p, [0.01, 0, 0]))
    p.clear_faults()
    p.move_to(_target(p, [0.01, 0, 0]))

    p.inject_fault("disconnect")
    with pytest.raises(PlatformConnectionError):
        p.move_to(_target(p, [0.0, 0, 0]))
    with pytest.raises(PlatformConnectionError):
        p.flange_pose()
    p.connect()
    p.flange_pose()


def test_three_dof_gantry_reports_unreachable_rotation():
    p = SimPlatform(T_base_flange_home=np.eye(4), errors="none", config=SimPlatformConfig(dof=3))
    p.connect()
    res = p.move_to(make_pose(exp_so3([0, 0, 0.1]), [0.01, 0, 0]))
    assert res.unreachable == ("rx", "ry", "rz")
    np.testing.assert_allclose(p.true_flange_pose()[:3, :3], np.eye(3), atol=1e-12)


def test_determinism_under_seed():
    def run(seed):
        p = SimPlatform(T_base_flange_home=np.eye(4), errors="sloppy", seed=seed)
        p.connect()
        for d in (0.01, -0.02, 0.03):
            p.move_to(make_pose(np.eye(3), [d, d / 2, 0]))
        return p.true_flange_pose()

    np.testing.assert_array_equal(run(7), run(7))
    assert not np.allclose(run(7), run(8))


def test_faults_take_the_time_they_would_on_the_rig():
    p = _platform()
    full = 1.5 + p.settle_s  # 1 cm
    p.inject_fault("estop")
    t0 = p.clock.now()
    with pytest.raises(SafetyStop):
        p.move_to(_target(p, [0.01, 0, 0]))
    assert p.clock.now() - t0 == pytest.approx(0.5 * full)  # stopped half way, after half the motion's time
    assert p.true_flange_pose()[0, 3] == pytest.approx(0.505, abs=1e-9)
    p.clear_faults()
    p.move_to(_target(p, [0.0, 0, 0]))
    p.inject_fault("timeout")
    t0 = p.clock.now()
    with pytest.raises(PlatformTimeout):
        p.move_to(_target(p, [0.01, 0, 0]))
    assert p.clock.now() - t0 == pytest.approx(p.timeout_s)  # the host waited the whole timeout
    # a motion longer than the timeout gets as far as its speed allows in that time
    q = SimPlatform(
        T_base_flange_home=make_pose(np.eye(3), [0.5, 0.0, 0.4]), errors="none", config=SimPlatformConfig(timeout_s=3.0)
    )
    q.connect()
    t0 = q.clock.now()
    with pytest.raises(PlatformTimeout):
        q.move_to(_target(q, [0.04, 0, 0]))  # 6 s + settle at 1.5 s/cm
    assert q.clock.now() - t0 == pytest.approx(3.0)
    assert q.true_flange_pose()[0, 3] - 0.5 == pytest.approx(0.04 * 3.0 / (6.0 + q.settle_s), rel=1e-9)


def test_realtime_factor_runs_the_clock_faster_than_wall_time_and_stop_halts():
    import threading
    import time

    p = SimPlatform(
        T_base_flange_home=make_pose(np.eye(3), [0.5, 0.0, 0.4]),
        errors="none",
        config=SimPlatformConfig(realtime_factor=20.0),
    )
    p.connect()
    w0, t0 = time.perf_counter(), p.clock.now()
    res = p.move_to(_target(p, [0.01, 0, 0]))  # 1.7 s simulated
    wall = time.perf_counter() - w0
    assert p.clock.now() - t0 == pytest.approx(1.5 + p.settle_s)
    assert res.duration_s == pytest.approx(1.5 + p.settle_s)
    assert 1.7 / 20 * 0.9 < wall < 1.7 / 20 + 1.0  # ~85 ms of wall time, slack for a busy machine
    # a 4 cm motion (6.2 s simulated, ~0.3 s wall) stopped from another thread after ~0.1 s of wall time
    threading.Timer(0.1, p.stop).start()
    res = p.move_to(_target(p, [0.05, 0, 0]))
    x = p.true_flange_pose()[0, 3]
    assert 0.51 < x < 0.55 - 1e-3
    assert res.duration_s < 6.2
    np.testing.assert_allclose(res.T_base_flange_commanded[:3, 3], p.true_flange_pose()[:3, 3], atol=1e-12)


def test_a_sim_platform_takes_its_config_and_refuses_four_axes():
    from fgcd_drivers.sim.platform import SimFault

    p = SimPlatform(config=SimPlatformConfig(dof=3, timeout_s=3.0))
    assert (p.dof, p.timeout_s, p.rotation_rad_per_s) == (3, 3.0, math.radians(5.0))
    with pytest.raises(ValueError):
        SimPlatform(config=SimPlatformConfig(dof=4))
    assert [f.value for f in SimFault] == ["timeout", "estop", "disconnect"]
