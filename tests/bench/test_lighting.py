"""`fgcd bench lighting`: the Table 1 protocol's parts against synthetic ground truth."""

import cv2
import numpy as np
import pytest

from fgcd_cli.bench.lighting.cross_light import (
    MIN_INLIERS,
    Matcher,
    consensus_homography,
    corner_error_px,
    match_pair,
    summarise,
)
from fgcd_cli.bench.lighting.photographs import known_motion, resampled
from fgcd_cli.bench.lighting.renders import multilight_lightings
from fgcd_cli.bench.lighting.sphere import binned_by_normal, gain_fit_error


def _shift(dx, dy):
    return np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])


def test_the_corner_error_of_a_shift_is_its_length():
    assert corner_error_px(_shift(0, 0), _shift(0, 0), (480, 640)) == 0.0
    assert corner_error_px(_shift(3.0, 4.0), _shift(0, 0), (480, 640)) == pytest.approx(5.0)
    # a rotation about the centre moves each corner by r * angle: the mean over the 4 corners
    H = known_motion((481, 641), (0.0, 0.0, 1.0))
    r = np.hypot(320, 240)
    assert corner_error_px(H, _shift(0, 0), (481, 641)) == pytest.approx(r * np.radians(1.0), rel=1e-3)


def test_the_consensus_is_the_median_and_ignores_one_stray_registration():
    Hs = [_shift(1.0, 0.0), _shift(1.1, 0.0), _shift(0.9, 0.0), _shift(25.0, 9.0)]
    np.testing.assert_allclose(consensus_homography([2.0 * H for H in Hs]), _shift(1.05, 0.0))
    assert consensus_homography([]) is None


def _texture(seed=0, shape=(240, 320)):
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.random(shape).astype(np.float32), (0, 0), 2.0)
    img = (img - img.min()) / (img.max() - img.min())
    return np.clip(img * 255, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("matcher", list(Matcher))
def test_a_known_sub_pixel_motion_is_registered_to_tenths_of_a_pixel(matcher):
    ref = _texture(shape=(480, 640))
    H = known_motion(ref.shape, (0.6, 0.4, 0.1))
    m = match_pair(ref, resampled(ref, H), matcher)
    assert not m.failed and m.inliers >= MIN_INLIERS
    # SIFT locates to a few hundredths of a pixel; the grid's phase-correlation peaks to about a tenth, and the
    # corners extrapolate the fit beyond the outermost cells (hence three tenths)
    assert corner_error_px(m.H_cur_ref, H, ref.shape) < (0.3 if matcher == Matcher.GRID else 0.1)


@pytest.mark.parametrize("matcher", list(Matcher))
def test_a_blank_image_fails_to_register(matcher):
    blank = np.full((240, 320), 128, np.uint8)
    assert match_pair(blank, blank, matcher).failed


def test_summary_counts_failures_as_beyond_every_threshold():
    rows = [
        {"failed": False, "corner_px": 0.5, "matches": 100, "inliers": 80},
        {"failed": False, "corner_px": 2.0, "matches": 100, "inliers": 60},
        {"failed": False, "corner_px": 4.0, "matches": 50, "inliers": 20},
        {"failed": True, "corner_px": float("nan"), "matches": 10, "inliers": 3},
    ]
    s = summarise(rows)
    assert s["fail_rate"] == 0.25 and s["over1_rate"] == 0.75 and s["over3_rate"] == 0.5
    assert s["median_corner_px"] == 2.0  # over the registered pairs only


def test_multilight_directions_light_the_side_they_name():
    """lights.txt: x right, y up, z toward the viewer; in the OpenCV camera frame (y down, z forward) (x, -y, -z)."""
    T = np.eye(4)
    (up_right,) = multilight_lightings(np.array([[0.6, 0.6, 0.53]]), T)
    d = np.asarray(up_right.lights[0].direction)
    assert d[0] > 0 and d[1] < 0 and d[2] < 0  # right, up (camera y is down), toward the camera
    assert np.linalg.norm(d) == pytest.approx(1.0)


def _lambert_sphere(L, gamma=1.0, size=201):
    """A synthetic orthographic sphere: grey levels of max(0, n.L)^(1/gamma), its normals and its inside."""
    yy, xx = np.mgrid[0:size, 0:size]
    c, r = (size - 1) / 2.0, size / 2.2
    nx, ny = (xx - c) / r, (yy - c) / r
    inside = nx**2 + ny**2 < 0.9**2
    nz = np.sqrt(np.clip(1 - nx**2 - ny**2, 0, 1))
    normals = np.dstack([nx, ny, nz])
    return np.clip(normals @ np.asarray(L, float), 0, None) ** (1 / gamma) * 200.0, normals, inside


def test_the_sphere_error_is_zero_for_the_same_shading_at_another_exposure_and_grows_with_gamma():
    L = np.array([0.3, -0.2, 0.93]) / np.linalg.norm([0.3, -0.2, 0.93])
    real, normals, inside = _lambert_sphere(L)
    real_bins = binned_by_normal(real, normals, inside)
    same = binned_by_normal(0.5 * real, normals, inside)  # another exposure: the gain absorbs it
    assert gain_fit_error(real_bins, same) == pytest.approx(0.0, abs=1e-12)
    errors = [
        gain_fit_error(real_bins, binned_by_normal(_lambert_sphere(L, g)[0], normals, inside)) for g in (1.4, 2.2)
    ]
    assert 0.02 < errors[0] < errors[1]  # a camera curve is not an exposure: it shows, and more for 2.2


def test_lamp_pairs_hold_each_side_lights_own_image_and_leave_out_empty_ones():
    from fgcd_cli.bench.lighting.photographs import lamp_pairs
    from fgcd_core.flash import CAMERA_RESPONSE_GAMMA

    rng = np.random.default_rng(2)
    albedo = rng.uniform(0.3, 0.9, (64, 80))
    env = 0.3 * albedo
    side = 0.2 * albedo * np.linspace(0.2, 1.0, 80)[None, :]

    def still(linear):
        return (np.round(np.clip(linear, 0, 1) ** (1 / CAMERA_RESPONSE_GAMMA) * 255)).astype(np.uint8)

    # lighting 3 is darker than the environment's everywhere: it adds no light, and is left out
    obs = {1: still(env), 2: still(env + side), 3: still(0.5 * env)}
    pairs = lamp_pairs(obs, obs, [1, 2, 3])
    assert [label for label, _, _ in pairs] == ["2-2-2-1/1-2-1-1"]
    recovered = pairs[0][1].astype(np.float64) ** CAMERA_RESPONSE_GAMMA
    ratio = recovered / side
    # 8-bit rounding of the two stills: a few % of the side light's 0.012-0.18 linear
    assert np.median(np.abs(ratio / np.median(ratio) - 1)) < 0.05
