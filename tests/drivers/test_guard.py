"""MotionGuard: every check, the first-motion confirmation and tripping."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fgcd_core.platform import (
    Capabilities,
    GuardLimits,
    MotionGuard,
    MotionRejected,
    MoveResult,
    Platform,
    PlatformConnectionError,
    SafetyStop,
    needed_axes,
)


def pose(xyz_m=(0.0, 0.0, 0.0), rotvec=(0.0, 0.0, 0.0)) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = xyz_m
    return T


class RecordingPlatform:
    """In-memory platform that arrives exactly; records what it was asked."""

    name = "recording"

    def __init__(self, *, controllable=("x", "y", "z", "rx", "ry", "rz"), fail_with=None):
        self.T = pose((0.1, 0.1, 0.1))
        self.moves: list[np.ndarray] = []
        self.speed_fractions: list[float] = []
        self.stops = 0
        self.controllable = tuple(controllable)
        self.fail_with = fail_with

    def connect(self) -> None:
        pass

    def capabilities(self) -> Capabilities:
        return Capabilities(
            dof=len(self.controllable),
            controllable=self.controllable,
            workspace_min_m=(0.0, 0.0, 0.0),
            workspace_max_m=(0.2, 0.2, 0.2),
            max_linear_speed_m_s=0.1,
            max_angular_speed_rad_s=0.5,
        )

    def flange_pose(self) -> np.ndarray:
        return self.T.copy()

    def move_to(self, T_base_flange, *, speed_fraction=1.0) -> MoveResult:
        if self.fail_with is not None:
            raise self.fail_with
        self.moves.append(np.array(T_base_flange))
        self.speed_fractions.append(speed_fraction)
        self.T = np.array(T_base_flange)
        return MoveResult(T_base_flange_target=self.T, T_base_flange_reached=self.T, T_base_flange_commanded=self.T)

    def stop(self) -> None:
        self.stops += 1

    def home(self) -> None:
        pass

    def close(self) -> None:
        pass


def test_recording_platform_satisfies_protocol():
    assert isinstance(RecordingPlatform(), Platform)


def test_small_move_passes_and_uses_guard_speed():
    platform = RecordingPlatform()
    guard = MotionGuard(platform, GuardLimits(speed_fraction=0.3))
    target = pose((0.11, 0.1, 0.1))
    guard.move_to(target)
    np.testing.assert_allclose(platform.moves[0], target)
    assert platform.speed_fractions == [0.3]


def test_step_limit_refuses_and_nothing_moves():
    platform = RecordingPlatform()
    guard = MotionGuard(platform, GuardLimits(max_step_m=0.01))
    with pytest.raises(MotionRejected, match=r"step 20\.0 mm exceeds the limit 10\.0 mm"):
        guard.move_to(pose((0.12, 0.1, 0.1)))
    assert platform.moves == []


def test_rotation_limit_refuses():
    platform = RecordingPlatform()
    guard = MotionGuard(platform, GuardLimits(max_step_rad=math.radians(5)))
    with pytest.raises(MotionRejected, match=r"rotation 6\.00 deg"):
        guard.move_to(pose((0.1, 0.1, 0.1), (0.0, math.radians(6.0), 0.0)))
    guard.move_to(pose((0.1, 0.1, 0.1), (0.0, math.radians(4.0), 0.0)))
    assert len(platform.moves) == 1


def test_workspace_box_of_platform_and_of_limits_intersect():
    platform = RecordingPlatform()
    platform.T = pose((0.19, 0.1, 0.1))
    guard = MotionGuard(platform, GuardLimits(max_step_m=0.05))
    with pytest.raises(MotionRejected, match="outside the workspace"):
        guard.move_to(pose((0.21, 0.1, 0.1)))
    tight = MotionGuard(platform, GuardLimits(workspace_max_m=(0.15, 0.2, 0.2)))
    with pytest.raises(MotionRejected, match="outside the workspace"):
        tight.move_to(pose((0.18, 0.1, 0.1)))
    assert platform.moves == []


def test_invalid_poses_refused():
    guard = MotionGuard(RecordingPlatform())
    bad = pose((0.1, 0.1, 0.1))
    bad[0, 0] = 2.0
    with pytest.raises(MotionRejected, match="no valid rotation"):
        guard.move_to(bad)
    with pytest.raises(MotionRejected, match="finite 4x4"):
        guard.move_to(np.full((4, 4), np.nan))
    with pytest.raises(MotionRejected, match="finite 4x4"):
        guard.move_to(np.eye(3))


def test_first_motion_confirmation_asked_once_and_decline_refuses():
    asked: list[str] = []
    platform = RecordingPlatform()
    guard = MotionGuard(platform, confirm=lambda text: asked.append(text) or False)
    with pytest.raises(MotionRejected, match="not confirmed"):
        guard.move_to(pose((0.105, 0.1, 0.1)))
    assert platform.moves == [] and "(5.0, 0.0, 0.0) mm" in asked[0]
    guard.confirm = lambda text: asked.append(text) or True
    guard.move_to(pose((0.105, 0.1, 0.1)))
    guard.move_to(pose((0.11, 0.1, 0.1)))
    assert len(asked) == 2 and len(platform.moves) == 2


def test_trip_stops_platform_and_refuses_until_reset():
    platform = RecordingPlatform()
    guard = MotionGuard(platform)
    guard.trip("lost connection")
    assert platform.stops == 1 and guard.tripped == "lost connection"
    with pytest.raises(MotionRejected, match="lost connection"):
        guard.move_to(pose((0.11, 0.1, 0.1)))
    guard.reset()
    guard.move_to(pose((0.11, 0.1, 0.1)))
    assert len(platform.moves) == 1


@pytest.mark.parametrize("failure", [KeyboardInterrupt(), PlatformConnectionError("link down"), SafetyStop("alarm 2")])
def test_failures_during_motion_trip_the_guard(failure):
    platform = RecordingPlatform(fail_with=failure)
    guard = MotionGuard(platform)
    with pytest.raises(type(failure)):
        guard.move_to(pose((0.11, 0.1, 0.1)))
    assert platform.stops == 1 and guard.tripped is not None


def test_move_by_is_in_the_flange_frame():
    platform = RecordingPlatform()
    # Flange turned 90 deg about base z: flange x points along base y.
    platform.T = pose((0.1, 0.1, 0.1), (0.0, 0.0, math.pi / 2))
    guard = MotionGuard(platform, GuardLimits(max_step_rad=math.radians(100)))
    guard.move_by(pose((0.01, 0.0, 0.0)))
    np.testing.assert_allclose(platform.T[:3, 3], [0.1, 0.11, 0.1], atol=1e-12)


def test_partial_motion_refused_only_when_not_allowed():
    platform = RecordingPlatform(controllable=("x", "y", "z"))
    target = pose((0.1, 0.1, 0.1), (0.0, math.radians(2.0), 0.0))
    strict = MotionGuard(platform, GuardLimits(allow_partial_motion=False))
    with pytest.raises(MotionRejected, match="cannot move along ry"):
        strict.move_to(target)
    assert platform.moves == []
    MotionGuard(platform).move_to(target)
    assert len(platform.moves) == 1


def test_needed_axes_names_translation_and_flange_rotation():
    current = pose((0.0, 0.0, 0.0), (0.0, 0.0, math.pi / 2))
    target = current @ pose((0.0, 0.0, 0.002), (math.radians(1.0), 0.0, 0.0))
    # z of the flange is z of the base here; rx is about the flange's x axis.
    assert needed_axes(current, target) == ("z", "rx")
