"""fgcd_core's shared types: one look-at, one intrinsics type, one board geometry, the same file formats."""

import json
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest

from fgcd_core.board import CharucoSpec
from fgcd_core.camera import CameraIntrinsics, PinholeCamera
from fgcd_core.se3 import look_at, make_pose, rotation_angle_rad

RNG = np.random.default_rng(3)
EYES = [RNG.normal(size=3) for _ in range(20)] + [np.array([0.0, -1.2, 1.1]), np.array([0.0, 0.0, -0.6])]
TARGETS = [RNG.normal(size=3) for _ in range(20)] + [np.array([0.0, 0.0, 1.1]), np.zeros(3)]


def test_look_at_puts_an_opencv_camera_at_the_eye_facing_the_target():
    """Camera z from the eye to the target, x = z x up, y = z x x (against up: down in the image)."""
    # the synthetic reliefs' up (-y): looking along +z is the identity
    np.testing.assert_allclose(look_at((0, 0, 0), (0, 0, 1), up=(0.0, -1.0, 0.0)), np.eye(4), atol=1e-15)
    # the simulator's up (+z): a camera 1 m in front of the origin (-y) looking at it
    facing = make_pose(np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]), [0.0, -1.0, 0.0])
    np.testing.assert_allclose(look_at((0, -1, 0), (0, 0, 0), up=(0.0, 0.0, 1.0)), facing, atol=1e-15)
    # looking along up: the fallback axis takes its place
    down = make_pose(np.array([[0.0, -1, 0], [-1, 0, 0], [0, 0, -1]]), [0.0, 0.0, 1.0])
    np.testing.assert_allclose(
        look_at((0, 0, 1), (0, 0, 0), up=(0.0, 0.0, 1.0), fallback_up=(1.0, 0.0, 0.0)), down, atol=1e-15
    )
    for eye, target in zip(EYES, TARGETS):
        T = look_at(eye, target, up=(0.0, -1.0, 0.0), fallback_up=(0.0, 0.0, 1.0))
        np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-12)
        assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
        z = (target - eye) / np.linalg.norm(target - eye)
        np.testing.assert_allclose(T[:3, 2], z, atol=1e-12)
        np.testing.assert_array_equal(T[:3, 3], eye)


def test_the_simulators_look_at_is_the_core_one_with_z_up():
    from fgcd_drivers.sim.transforms import look_at as sim_look_at

    for eye, target in zip(EYES + [np.array([0.0, 0.0, 1.0])], TARGETS + [np.zeros(3)]):
        assert np.array_equal(
            sim_look_at(eye, target), look_at(eye, target, up=(0.0, 0.0, 1.0), fallback_up=(1.0, 0.0, 0.0))
        )


def test_look_at_needs_up_and_refuses_a_silent_fallback():
    with pytest.raises(TypeError):
        look_at(np.zeros(3), np.ones(3))  # up is required
    with pytest.raises(ValueError):
        look_at((0, 0, 1), (0, 0, 0), up=(0.0, 0.0, 1.0))


def test_guard_rotation_angle_agrees_with_the_old_acos_form():
    """fgcd_core.platform's guard now uses rotation_angle_rad (atan2); the old acos agrees to 1e-7 rad."""
    from fgcd_core.se3 import exp_so3

    for phi in RNG.normal(size=(50, 3)):
        R = exp_so3(phi)
        old = float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))
        assert abs(rotation_angle_rad(R) - old) < 1e-7


def test_one_intrinsics_type_with_both_old_interfaces():
    from fgcd_core.camera import CameraIntrinsics as DriversIntrinsics
    from fgcd_core.camera import PinholeCamera as GeometryPinhole

    assert DriversIntrinsics is CameraIntrinsics is PinholeCamera is GeometryPinhole
    cam = CameraIntrinsics(fx=600.0, fy=601.0, cx=319.5, cy=239.5, width=640, height=480, dist=(-0.05, 0.01, 0, 0, 0))
    for name in (
        "K",
        "dist_array",
        "has_distortion",
        "scaled",
        "to_dict",
        "from_dict",
        "from_K",
        "project",
        "normalized_rays",
        "unproject",
        "backproject_depth",
    ):
        assert hasattr(cam, name), name
    assert np.array_equal(cam.dist_array, np.array([-0.05, 0.01, 0.0, 0.0, 0.0]))
    # the JSON both old types wrote, key for key
    assert json.dumps(cam.to_dict()) == (
        '{"fx": 600.0, "fy": 601.0, "cx": 319.5, "cy": 239.5, "width": 640, "height": 480, '
        '"dist": [-0.05, 0.01, 0.0, 0.0, 0.0]}'
    )
    assert CameraIntrinsics.from_dict(cam.to_dict()) == cam
    assert type(CameraIntrinsics(fx=1, fy=1, cx=0, cy=0, width=4.0, height=3.0).width) is int


def test_board_geometry_is_shared():
    from fgcd_cli.calibration.board import BoardSpec
    from fgcd_drivers.sim.board import SimBoard

    sim, spec = SimBoard(), BoardSpec()
    assert isinstance(sim, CharucoSpec) and isinstance(spec, CharucoSpec)
    base = {f.name for f in fields(CharucoSpec)}
    assert {f.name for f in fields(SimBoard)} == base | {"margin_m"}
    assert {f.name for f in fields(BoardSpec)} == base
    assert (sim.squares_x, sim.squares_y, sim.square_m, sim.marker_m, sim.dictionary, sim.margin_m) == (
        10,
        7,
        0.025,
        0.018,
        "DICT_5X5_100",
        0.01,
    )
    assert np.array_equal(sim.corner_points(), spec.corner_points())
    assert np.array_equal(sim.image(px_per_square=40), spec.image(px_per_square=40))


def test_board_geometry_converts_between_the_two_sides():
    from fgcd_cli.calibration.board import BoardSpec
    from fgcd_drivers.sim.board import SimBoard

    spec = BoardSpec(squares_x=9, squares_y=6, legacy_pattern=True)
    sim = SimBoard(**spec.charuco_fields(), margin_m=0.02)
    assert sim.charuco_fields() == spec.charuco_fields() and sim.margin_m == 0.02
    assert BoardSpec(**sim.charuco_fields()) == spec


def test_board_view_keyword_form_equals_camera_form():
    from fgcd_drivers.sim.board import BoardViewOptions, SimBoard, random_board_poses, render_board_view

    board = SimBoard(squares_x=5, squares_y=4)
    cam = CameraIntrinsics(
        fx=300.0, fy=300.0, cx=159.5, cy=119.5, width=320, height=240, dist=(-0.05, 0.01, 0.0, 0.0, 0.0)
    )
    poses = random_board_poses(board, 2, cam, rng=np.random.default_rng(1))
    assert len(poses) == 2
    image = render_board_view(
        board, poses[0], cam, options=BoardViewOptions(supersample=2), rng=np.random.default_rng(5)
    )
    assert image.dtype == np.uint8 and image.shape == (240, 320) and image.std() > 10
    assert BoardViewOptions() == BoardViewOptions(
        noise_sigma=1.5 / 255.0, blur_sigma_px=0.6, background=0.45, supersample=3
    )
    with pytest.raises(TypeError):  # one call form: the camera and the options objects
        render_board_view(board, poses[0], cam, supersample=2)
    with pytest.raises(TypeError):
        random_board_poses(board, 2, fx=cam.fx, fy=cam.fy, cx=cam.cx, cy=cam.cy, width=cam.width, height=cam.height)


def test_intrinsics_error_levels_keep_their_strings():
    from fgcd_drivers.sim.camera import IntrinsicsErrorLevel

    assert [str(x) for x in IntrinsicsErrorLevel] == ["none", "default", "large"]


def test_fgcd_core_imports_nothing_of_fgcd():
    import subprocess
    import sys

    code = (
        "import sys, fgcd_core.se3, fgcd_core.sim3, fgcd_core.camera, fgcd_core.board, fgcd_core.imaging; "
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('fgcd_cli', 'drivers')))"
    )
    r = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=Path(__file__).resolve().parents[2],
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"
