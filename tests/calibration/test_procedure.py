"""The calibration procedures against a fake rig: motions pass the guard, samples are solved; the hand-eye
use case is the target-free procedure."""

from __future__ import annotations

import inspect
import math
from types import SimpleNamespace

import numpy as np
import pytest

from fgcd_cli.app.calibrate import HandEyeCalibration, HandEyeRequest, HandEyeRig, run_handeye
from fgcd_cli.calibration.errors import CalibrationError
from fgcd_cli.calibration.motions import exploration_motions, interpolate_steps, target_motions
from fgcd_cli.calibration.procedure import TargetFreeRunConfig, run_target, run_target_free
from fgcd_cli.calibration.samples import rotation_axis_spread_deg
from fgcd_cli.errors import UserInputError
from fgcd_core.camera import PinholeCamera
from fgcd_core.platform import Capabilities, GuardLimits, MotionGuard, MoveResult
from fgcd_core.se3 import exp_so3, invert_pose, make_pose, pose_distance

CAMERA = PinholeCamera(fx=600, fy=600, cx=319.5, cy=239.5, width=640, height=480)


class IdealPlatform:
    """A 6-DoF platform that reaches every target exactly and counts its motions."""

    name = "ideal"

    def __init__(self, rot_axes=("rx", "ry", "rz")):
        self.T = make_pose(exp_so3([3.0, 0.1, 0.0]), [0.5, 0.0, 0.4])
        self.moves = []
        self.rot_axes = rot_axes

    def connect(self):
        pass

    def capabilities(self):
        return Capabilities(
            dof=3 + len(self.rot_axes),
            controllable=("x", "y", "z") + tuple(self.rot_axes),
            workspace_min_m=(-1.0, -1.0, -1.0),
            workspace_max_m=(1.0, 1.0, 1.0),
            max_linear_speed_m_s=0.1,
            max_angular_speed_rad_s=0.5,
        )

    def flange_pose(self):
        return self.T.copy()

    def move_to(self, T, *, speed_fraction=1.0):
        self.moves.append(pose_distance(self.T, T))
        self.T = np.asarray(T, float).copy()
        return MoveResult(T_base_flange_target=T, T_base_flange_reached=T, T_base_flange_commanded=T)

    def stop(self):
        pass

    def home(self):
        pass

    def close(self):
        pass


class FakeVSE:
    """Reports the true camera pose in a map frame scaled by 1/s, after an initialisation delay."""

    def __init__(self, platform, X, scale, init_frames=5):
        self.platform, self.X, self.scale = platform, X, scale
        self.T_base_map = make_pose(exp_so3([0.2, -0.4, 1.0]), [0.1, 0.2, 0.3])
        self.frames = 0
        self.init_frames = init_frames

    def process(self, image, timestamp_s):
        self.frames += 1
        if self.frames <= self.init_frames:
            return SimpleNamespace(status="initializing", message="need parallax", T_map_cam=None)
        T = invert_pose(self.T_base_map) @ self.platform.T @ self.X
        T[:3, 3] /= self.scale
        return SimpleNamespace(status="tracking", message="ok", T_map_cam=T)


class FakeCamera:
    def __init__(self):
        self.t = 0.0

    def grab(self):
        self.t += 0.1
        return SimpleNamespace(image=np.zeros((4, 4), np.uint8), timestamp_s=self.t)


def test_exploration_motions_are_small_and_rotate_about_several_axes():
    stops = exploration_motions(translation_m=0.03, rotation_deg=8.0)
    np.testing.assert_allclose(stops[0], np.eye(4))
    np.testing.assert_allclose(stops[-1], np.eye(4))
    assert np.linalg.norm(stops[1][:3, 3]) > 0 and np.allclose(stops[1][:3, :3], np.eye(3))
    for T in stops:
        assert np.linalg.norm(T[:3, 3]) <= 0.03 * math.sqrt(2) + 1e-9
        assert pose_distance(np.eye(4), T)[1] <= 8.0 * 1.0 + 1e-6
    assert rotation_axis_spread_deg([T[:3, :3] for T in stops if not np.allclose(T[:3, :3], np.eye(3))]) > 45
    with pytest.raises(UserInputError, match="two of the axes"):
        exploration_motions(rotation_axes="z")
    assert len(target_motions()) == 13


def test_interpolate_steps_respects_limits_and_arrives():
    T0 = make_pose(np.eye(3), [0, 0, 0])
    T1 = make_pose(exp_so3(np.radians([10, -5, 3])), [0.04, 0.01, -0.02])
    steps = interpolate_steps(T0, T1, max_step_m=0.005, max_step_deg=1.0)
    np.testing.assert_allclose(steps[-1], T1, atol=1e-12)
    prev = T0
    for T in steps:
        mm, deg = pose_distance(prev, T)
        assert mm <= 5.0 + 1e-9 and deg <= 1.0 + 1e-9
        prev = T


def test_run_target_free_recovers_x_and_scale_through_the_guard():
    platform = IdealPlatform()
    X = make_pose(exp_so3([0.1, -0.3, 0.2]), [0.03, -0.05, 0.08])
    camera = FakeCamera()
    guard = MotionGuard(platform, GuardLimits(max_step_m=0.006, max_step_rad=math.radians(1.2)))
    start = platform.flange_pose()
    run = run_target_free(guard, camera, lambda cam: FakeVSE(platform, X, 0.42), camera=CAMERA)
    assert pose_distance(run.result.T_flange_cam, X)[0] < 1e-6
    assert run.result.scale == pytest.approx(0.42, rel=1e-9)
    assert run.skipped and 0 in run.skipped  # the VSE was still initialising at the first stop
    assert max(m for m, _ in platform.moves) <= 5.0 + 1e-9
    np.testing.assert_allclose(platform.flange_pose(), start, atol=1e-12)  # back home at the end


def test_run_target_free_refuses_a_platform_that_cannot_rotate():
    platform = IdealPlatform(rot_axes=("rz",))
    guard = MotionGuard(platform)
    with pytest.raises(CalibrationError, match="rotates about 1 axis"):
        run_target_free(guard, FakeCamera(), lambda cam: FakeVSE(platform, np.eye(4), 1.0), camera=CAMERA)
    assert platform.moves == []


def test_run_target_free_reports_a_vse_that_never_tracks():
    platform = IdealPlatform()
    guard = MotionGuard(platform)
    with pytest.raises(CalibrationError, match="VSE gave a pose at only 0"):
        run_target_free(
            guard, FakeCamera(), lambda cam: FakeVSE(platform, np.eye(4), 1.0, init_frames=10**6), camera=CAMERA
        )


def test_results_are_stored_in_the_campaign_rig_with_history(tmp_path, handeye_data):
    from fgcd_cli.calibration.handeye.linear import solve_handeye_scale
    from fgcd_cli.calibration.rig_files import load_camera, load_handeye, save_handeye
    from fgcd_cli.campaign.store import init_campaign
    from fgcd_cli.errors import CampaignError

    camp = init_campaign(tmp_path / "c", site="test")
    with pytest.raises(CampaignError, match="not calibrated"):
        load_camera(camp)
    assert load_handeye(camp) is None
    d = handeye_data(seed=1)
    first = solve_handeye_scale(d["T_base_flange"], d["T_map_cam"])
    save_handeye(camp, first)
    second = solve_handeye_scale(d["T_base_flange"][:8], d["T_map_cam"][:8])
    save_handeye(camp, second)
    loaded = load_handeye(camp)
    assert loaded.n_samples == 8 and np.allclose(loaded.T_flange_cam, second.T_flange_cam)
    assert len(list((camp.path / "rig" / "history").glob("handeye-*.json"))) >= 1


def test_one_reader_gives_the_full_result_and_what_a_revisit_needs(tmp_path, handeye_data):
    from fgcd_cli.calibration.handeye.linear import solve_handeye_scale
    from fgcd_cli.calibration.rig_files import load_handeye, rig_calibration, save_handeye
    from fgcd_cli.campaign.store import init_campaign
    from fgcd_cli.errors import CampaignError

    camp = init_campaign(tmp_path / "c", site="test")
    assert rig_calibration(camp) == (None, None)
    d = handeye_data(seed=1)
    save_handeye(camp, solve_handeye_scale(d["T_base_flange"], d["T_map_cam"]))
    T_flange_cam, camera = rig_calibration(camp)
    assert camera is None and np.array_equal(T_flange_cam, load_handeye(camp).T_flange_cam)
    # a record a person wrote by hand: the bare camera model is accepted as the intrinsics
    camp.write_rig("intrinsics", {"fx": 600, "fy": 600, "cx": 320, "cy": 240, "width": 640, "height": 480})
    assert rig_calibration(camp)[1].fx == 600
    camp.write_rig("handeye", {"method": "by hand"})
    for read in (rig_calibration, load_handeye):
        with pytest.raises(CampaignError, match=r"handeye.json has no T_flange_cam"):
            read(camp)
    camp.write_rig("handeye", {"T_flange_cam": np.eye(3).tolist()})
    with pytest.raises(CampaignError, match=r"not a 4 x 4 matrix"):
        rig_calibration(camp)


def test_calibration_package_never_imports_the_simulator():
    from pathlib import Path

    import fgcd_cli.calibration as pkg

    for path in Path(pkg.__file__).parent.rglob("*.py"):
        text = path.read_text(encoding="utf-8")
        assert "fgcd_drivers.sim" not in text, f"{path.name} imports the simulator"


def test_run_target_free_gives_the_refinement_every_rest_pose_of_the_path(monkeypatch):
    """The image refinement sees the stops and every step between them, each once, with the
    pose reported when its frame was taken; the stops are marked in the path."""
    import fgcd_cli.calibration.procedure as procedure

    seen = {}

    def spy(linear, T_base_flange, T_map_cam, images, K, **kwargs):
        seen.update(hand=T_base_flange, images=images, path=kwargs["path"])
        from dataclasses import replace

        return replace(linear, refinement={"points": 0, "rms_px": 0.0, "change_mm": 0.0, "change_deg": 0.0})

    monkeypatch.setattr(procedure, "refine_target_free", spy)
    platform = IdealPlatform()
    X = make_pose(exp_so3([0.1, -0.3, 0.2]), [0.03, -0.05, 0.08])
    guard = MotionGuard(platform, GuardLimits(max_step_m=0.006, max_step_rad=math.radians(1.2)))
    run_target_free(guard, FakeCamera(), lambda cam: FakeVSE(platform, X, 0.42), camera=CAMERA)
    path = seen["path"]
    # one view per platform motion, plus the start (the first stop, reached without moving, which
    # the VSE missed: still a view of the refinement, not a stop sample)
    assert len(path.T_base_flange) == len(path.images) == len(platform.moves) + 1
    assert len(path.stop_index) == len(seen["hand"]) == len(seen["images"])
    for k, i in enumerate(path.stop_index):
        np.testing.assert_allclose(path.T_base_flange[i], seen["hand"][k], atol=1e-12)
    # consecutive views are distinct rest poses a step apart
    steps = [
        max(pose_distance(a, b)[0] / 5.0, pose_distance(a, b)[1])
        for a, b in zip(path.T_base_flange[:-1], path.T_base_flange[1:])
    ]
    assert min(steps) > 0.01 and max(steps) <= 1.0 + 1e-9  # distinct poses, each <= 5 mm / 1 deg on
    assert 0 not in path.stop_index
    assert all(img.dtype == np.uint8 and img.ndim == 2 for img in path.images)


def test_target_free_reports_its_progress_through_a_plain_callback():
    platform = IdealPlatform()
    X = make_pose(exp_so3([0.1, -0.3, 0.2]), [0.03, -0.05, 0.08])
    guard = MotionGuard(platform, GuardLimits(max_step_m=0.006, max_step_rad=math.radians(1.2)))
    calls = []
    run_target_free(
        guard,
        FakeCamera(),
        lambda cam: FakeVSE(platform, X, 0.42),
        camera=CAMERA,
        on_progress=lambda done, total, label: calls.append((done, total, label)),
    )
    path = [c for c in calls if c[1] > 0]
    assert path, calls
    totals = {t for _, t, _ in path}
    assert len(totals) == 1  # one bar over the whole path
    dones = [d for d, _, _ in path]
    assert dones == sorted(dones) and dones[-1] == totals.pop()
    assert path[0][2].startswith("hand-eye motions (stop 1/") and "stop 13/13" in path[-1][2]
    assert calls[-1][1] == 0 and "refinement" in calls[-1][2]  # the refinement: length unknown


def test_procedures_take_their_options_as_one_config():
    for func in (run_target_free, run_target):
        params = inspect.signature(func).parameters
        assert "config" in params and not any(p.kind is p.VAR_KEYWORD for p in params.values())
    with pytest.raises(TypeError):
        TargetFreeRunConfig(nonsense=1)


def test_the_hand_eye_request_moves_as_far_as_the_procedure():
    assert HandEyeRequest().translation_mm / 1000 == TargetFreeRunConfig().translation_m


def test_the_hand_eye_use_case_is_the_target_free_procedure():
    X = make_pose(exp_so3([0.1, -0.3, 0.2]), [0.03, -0.05, 0.08])
    outcomes = []
    for use_case in (True, False):
        platform = IdealPlatform()
        guard = MotionGuard(platform, GuardLimits(max_step_m=0.006, max_step_rad=math.radians(1.2)))
        says, ticks = [], []

        def factory(cam, platform=platform):
            return FakeVSE(platform, X, 0.42)

        if use_case:
            calibration = run_handeye(
                HandEyeRig(guard=guard, camera_source=FakeCamera(), intrinsics=CAMERA),
                HandEyeRequest(),
                say=says.append,
                on_progress=lambda *a, ticks=ticks: ticks.append(a),
                vse_factory=factory,
            )
            assert isinstance(calibration, HandEyeCalibration)
            assert calibration.record["skipped_stops"] == {"0": "VSE initializing: need parallax"}
            run = calibration.run
        else:
            run = run_target_free(
                guard,
                FakeCamera(),
                factory,
                camera=CAMERA,
                progress=says.append,
                on_progress=lambda *a, ticks=ticks: ticks.append(a),
            )
        outcomes.append((np.asarray(run.result.T_flange_cam), run.result.scale, says, ticks, run.frames))
    (X_a, s_a, say_a, tick_a, f_a), (X_b, s_b, say_b, tick_b, f_b) = outcomes
    assert np.array_equal(X_a, X_b) and s_a == s_b and say_a == say_b and tick_a == tick_b and f_a == f_b
