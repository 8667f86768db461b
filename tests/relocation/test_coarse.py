"""Active coarse stage (paper 001): camera uncertainty against synthetic ground truth, and the stage's choices.

The scene is a relief: a 1.2 m x 0.9 m panel at 1.5 m with bumps of 3-6 cm
(non-planar, so a depth registration is well posed), sampled densely as the
reference cloud. The observation is the same relief seen from the true camera,
with 1.5 mm of noise per axis and its own sampling (a VSE cloud, not a copy).
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from fgcd_cli.geometry import PinholeCamera, exp_se3
from fgcd_cli.geometry.se3 import invert_pose, pose_distance
from fgcd_cli.relocation.coarse import CoarseConfig, camera_uncertainty, render_visible_points

CAMERA = PinholeCamera(fx=600.0, fy=600.0, cx=320.0, cy=240.0, width=640, height=480)


def _relief(n: int, rng: np.random.Generator) -> np.ndarray:
    x = rng.uniform(-0.6, 0.6, n)
    y = rng.uniform(-0.45, 0.45, n)
    z = (1.5 + 0.04 * np.sin(x / 0.09) * np.cos(y / 0.07) + 0.06 * np.exp(-((x - 0.2) ** 2 + (y + 0.1) ** 2) / 0.02)
         - 0.03 * np.exp(-((x + 0.3) ** 2 + (y - 0.15) ** 2) / 0.01))
    return np.column_stack([x, y, z])


def _observed(T_ref_cam_true: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    pts = _relief(60000, rng)
    seen = render_visible_points(pts, T_ref_cam_true, CAMERA, stride_px=2)
    return seen + rng.normal(0.0, 0.0015, seen.shape)


@pytest.fixture(scope="module")
def reference_points() -> np.ndarray:
    return _relief(120000, np.random.default_rng(1))


def test_rendering_keeps_only_the_visible_front_surface():
    rng = np.random.default_rng(0)
    n = 20000  # ~3.7 points per 4-px bin: a hidden point shows only through the ~2.5 % empty bins
    front = np.column_stack([rng.uniform(-0.3, 0.3, n), rng.uniform(-0.2, 0.2, n), np.full(n, 1.0)])
    behind = front.copy()
    behind[:, 2] = 2.0  # hidden behind the front sheet
    outside = np.array([[5.0, 0.0, 1.0], [0.0, 0.0, -1.0]])  # beyond the image, behind the camera
    seen = render_visible_points(np.vstack([front, behind, outside]), np.eye(4), CAMERA, stride_px=4)
    assert np.sum(seen[:, 2] < 1.05) > 0.99 * n
    assert np.sum(seen[:, 2] > 1.05) < 0.05 * n
    assert np.all(seen[:, 2] > 0)


@pytest.mark.parametrize("error", [(0.03, 0.0, 0.0, 0.0, 0.0, 2.0), (-0.015, 0.02, 0.01, 1.5, -1.0, 0.5)])
def test_camera_uncertainty_measures_a_small_pose_error_and_corrects_it(reference_points, error):
    rng = np.random.default_rng(2)
    T_true = exp_se3(np.r_[0.02, -0.03, 0.05, np.radians([2.0, -3.0, 1.0])])
    obs = _observed(T_true, rng)
    dt, rot = np.r_[error[:3]], np.radians(error[3:])
    T_est = T_true @ exp_se3(np.r_[dt, rot])
    unc = camera_uncertainty(obs, reference_points, T_est, CAMERA)
    true_mm, true_deg = pose_distance(T_est, T_true)
    # The residual is the pose error (within a few mm and a few tenths of a degree: noise 1.5 mm, 5k points).
    assert abs(unc.translation_m * 1e3 - true_mm) < 5.0
    assert abs(unc.rotation_deg - true_deg) < 0.5
    assert unc.verified(CoarseConfig())
    err_mm, err_deg = pose_distance(T_est @ unc.T_correction, T_true)
    assert err_mm < 4.0 and err_deg < 0.3


def test_a_far_wrong_estimate_is_not_verified(reference_points):
    rng = np.random.default_rng(3)
    T_true = np.eye(4)
    obs = _observed(T_true, rng)
    T_est = exp_se3(np.r_[0.25, 0.0, -0.1, 0.0, np.radians(15.0), 0.0])
    unc = camera_uncertainty(obs, reference_points, T_est, CAMERA)
    assert not unc.verified(CoarseConfig())


def test_too_little_observation_gives_infinite_uncertainty(reference_points):
    unc = camera_uncertainty(np.zeros((20, 3)) + [0, 0, 1.5], reference_points, np.eye(4), CAMERA)
    assert math.isinf(unc.translation_m) and not unc.verified(CoarseConfig())
