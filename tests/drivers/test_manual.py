"""Manual driver: instructions in the flange frame, confirmation, reported pose."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fgcd_core.platform import GuardLimits, MotionGuard, MotionInterrupted, PlatformConnectionError
from fgcd_drivers.connect import PlatformSpec, open_platform
from fgcd_drivers.manual import ManualPlatform, instructions_for


def delta(xyz_mm=(0, 0, 0), rotvec_deg=(0, 0, 0)):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(np.radians(rotvec_deg)).as_matrix()
    T[:3, 3] = np.asarray(xyz_mm) / 1000.0
    return T


def test_rotation_words_follow_the_right_hand_rule():
    forward = np.array([0.0, 0.0, 1.0])
    # +ry sends the forward axis to +x (right); +rx sends it to -y (up, y points down).
    assert (delta(rotvec_deg=(0, 10, 0))[:3, :3] @ forward)[0] > 0
    assert (delta(rotvec_deg=(10, 0, 0))[:3, :3] @ forward)[1] < 0
    assert instructions_for(delta(rotvec_deg=(0, 10, 0))) == ["pan right 10.00 deg"]
    assert instructions_for(delta(rotvec_deg=(10, 0, 0))) == ["tilt up 10.00 deg"]


def test_instructions_name_each_axis_in_mm_and_degrees():
    assert instructions_for(delta((12.5, 0, -3.0), (-0.8, 0, 0))) == [
        "slide right 12.5 mm",
        "pull back 3.0 mm",
        "tilt down 0.80 deg",
    ]
    assert instructions_for(delta((0, 0, 0), (0, 2.0, 0))) == ["pan right 2.00 deg"]
    assert instructions_for(delta((0.01, 0, 0))) == []  # below what a person can do


def test_move_through_guard_prints_flange_frame_steps_and_reports_commanded_pose():
    said, asked = [], []
    start = delta((0, 0, 0), (0, 0, 90))  # mount turned 90 deg about its forward axis
    platform = ManualPlatform(ask=lambda p: asked.append(p) or "y", say=said.append, T_base_flange_start=start)
    guard = MotionGuard(platform, GuardLimits(max_step_m=0.05), confirm=lambda text: True)
    result = guard.move_by(delta((10.0, 0, 0)))
    assert said[1:] == ["  1. slide right 10.0 mm"] and len(asked) == 1
    # In the base frame "right" of the turned mount is +y.
    np.testing.assert_allclose(result.T_base_flange_reached[:3, 3], [0.0, 0.01, 0.0], atol=1e-12)
    np.testing.assert_allclose(platform.flange_pose(), result.T_base_flange_commanded)


def test_refusal_keeps_pose_and_interrupts():
    platform = ManualPlatform(ask=lambda p: "n", say=lambda s: None)
    with pytest.raises(MotionInterrupted, match="not confirmed"):
        platform.move_to(delta((5.0, 0, 0)))
    np.testing.assert_allclose(platform.flange_pose(), np.eye(4))


def test_factory_builds_drivers_and_reports_missing_options():
    manual = open_platform("manual", spec=PlatformSpec(ask=lambda p: "", say=lambda s: None))
    assert manual.name == "manual"
    with pytest.raises(PlatformConnectionError, match="needs --port"):
        open_platform("grbl")
    with pytest.raises(PlatformConnectionError, match="needs --host"):
        open_platform("ur")
    with pytest.raises(PlatformConnectionError, match="unknown platform driver 'kuka'"):
        open_platform("kuka")
    with pytest.raises(PlatformConnectionError, match="sim_rig"):
        open_platform("sim")
    assert open_platform("sim", spec=PlatformSpec(sim_rig=manual, connect=False)) is manual
    assert math.isclose(manual.capabilities().max_linear_speed_m_s, 0.01)
