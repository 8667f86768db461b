"""Pinhole camera: projection round trips, distortion, depth back-projection."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fgcd_core.camera import PinholeCamera

CAM = PinholeCamera(fx=520.0, fy=515.0, cx=319.5, cy=239.5, width=640, height=480)
DIST = PinholeCamera(
    fx=520.0, fy=515.0, cx=319.5, cy=239.5, width=640, height=480, dist=(-0.12, 0.05, 0.001, -0.0008, 0.0)
)


@settings(max_examples=50)
@given(st.integers(0, 2**31 - 1), st.sampled_from([CAM, DIST]))
def test_project_unproject_round_trip(seed, cam):
    rng = np.random.default_rng(seed)
    z = rng.uniform(0.4, 3.0, 200)
    xy = rng.uniform(-0.5, 0.5, (200, 2)) * z[:, None]
    P = np.column_stack([xy, z])
    uv, ok = cam.project(P)
    back = cam.unproject(uv[ok], z[ok])
    np.testing.assert_allclose(back, P[ok], atol=1e-6 * 3.0)


def test_principal_point_and_behind_camera():
    uv, ok = CAM.project(np.array([[0.0, 0.0, 2.0], [0.0, 0.0, -1.0], [10.0, 0.0, 1.0]]))
    np.testing.assert_allclose(uv[0], [319.5, 239.5])
    assert ok.tolist() == [True, False, False]
    assert np.all(np.isnan(uv[1]))


def test_distortion_moves_corner_pixels_inwards_for_barrel():
    P = np.array([[0.5, 0.35, 1.0]])
    uv_ideal, _ = CAM.project(P)
    uv_dist, _ = DIST.project(P)
    centre = np.array([DIST.cx, DIST.cy])
    assert np.linalg.norm(uv_dist - centre) < np.linalg.norm(uv_ideal - centre)


def test_backproject_plane_depth():
    depth = np.full((480, 640), 1.5)
    depth[:10] = 0.0
    pts, pix = CAM.backproject_depth(depth, stride=4)
    assert np.allclose(pts[:, 2], 1.5)
    assert pix[:, 1].min() >= 10
    uv, ok = CAM.project(pts)
    np.testing.assert_allclose(uv, pix, atol=1e-9)


def test_scaled_intrinsics_follow_pixel_centres():
    half = CAM.scaled(0.5)
    assert (half.width, half.height) == (320, 240)
    # a point at pixel (u, v) in full resolution sits at ((u+0.5)/2-0.5) at half resolution
    P = np.array([[0.1, -0.05, 1.0]])
    uv_full, _ = CAM.project(P)
    uv_half, _ = half.project(P)
    np.testing.assert_allclose(uv_half, (uv_full + 0.5) * 0.5 - 0.5, atol=1e-9)


def test_invalid_camera_rejected():
    with pytest.raises(ValueError):
        PinholeCamera(fx=0, fy=1, cx=0, cy=0, width=10, height=10)
    with pytest.raises(ValueError):
        CAM.backproject_depth(np.ones((10, 10)))


def test_dict_round_trip():
    assert PinholeCamera.from_dict(DIST.to_dict()) == DIST
