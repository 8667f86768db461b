"""Target-free hand-eye + scale (rACR) and the target-based solvers, on synthetic poses with a known X and s."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fgcd_cli.calibration.errors import CalibrationError
from fgcd_cli.calibration.handeye.linear import estimate_scale, solve_handeye_scale
from fgcd_cli.calibration.handeye.result import HandEyeResult, ScaleResult
from fgcd_cli.calibration.handeye.with_target import solve_handeye_target
from fgcd_cli.calibration.samples import rotation_axis_spread_deg
from fgcd_cli.errors import UserInputError
from fgcd_core.se3 import camera_motion, exp_so3, flange_motion, invert_pose, log_so3, make_pose, pose_distance

# Default noise of the noisy cases: platform 0.2 mm / 0.02 deg, VSE 0.3 mm / 0.05 deg per pose.
NOISE = dict(
    flange_noise_m=2e-4, flange_noise_rad=math.radians(0.02), cam_noise_m=3e-4, cam_noise_rad=math.radians(0.05)
)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_convention_hand_motion_times_x_equals_x_times_camera_motion(handeye_data, seed):
    # Our convention: M_B X = X M_A with M_B in the flange frame and M_A the metric camera motion.
    d = handeye_data(seed=seed)
    X, s = d["X"], d["scale"]
    for i, j in [(0, 3), (2, 7), (5, 1)]:
        MB = invert_pose(d["T_base_flange"][i]) @ d["T_base_flange"][j]
        MA = invert_pose(d["T_map_cam"][i]) @ d["T_map_cam"][j]
        MA[:3, 3] *= s
        np.testing.assert_allclose(MB @ X, X @ MA, atol=1e-12)
        np.testing.assert_allclose(flange_motion(X, MA), MB, atol=1e-12)  # paper 000, Eq. 3
        np.testing.assert_allclose(camera_motion(X, MB), MA, atol=1e-12)


def test_axis_projection_scale_formula_in_our_convention(handeye_data):
    # The corrected Eq. 8 in fgcd's naming: k_B^T (R_B - I) = 0 gives s = k_B.t_B / k_B.(R_X t_VSE).
    d = handeye_data(seed=3)
    X, s = d["X"], d["scale"]
    for i, j in [(0, 4), (1, 9)]:
        MB = invert_pose(d["T_base_flange"][i]) @ d["T_base_flange"][j]
        MA = invert_pose(d["T_map_cam"][i]) @ d["T_map_cam"][j]
        phi = log_so3(MB[:3, :3])
        k = phi / np.linalg.norm(phi)
        s_pair = (k @ MB[:3, 3]) / (k @ (X[:3, :3] @ MA[:3, 3]))
        assert s_pair == pytest.approx(s, rel=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
@pytest.mark.parametrize("pairs", ["all", "consecutive", "first"])
def test_noise_free_recovers_x_and_scale_exactly(handeye_data, seed, pairs):
    d = handeye_data(seed=seed, scale=0.05 + seed)
    r = solve_handeye_scale(d["T_base_flange"], d["T_map_cam"], pairs=pairs)
    mm, deg = pose_distance(r.T_flange_cam, d["X"])
    assert mm < 1e-6 and deg < 1e-6
    assert r.scale == pytest.approx(d["scale"], rel=1e-9)
    assert r.rms_mm < 1e-6 and r.rms_deg < 1e-6
    assert r.n_samples == 12


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noisy_poses_give_errors_at_the_noise_level(handeye_data, seed):
    # Translation error ~ sigma_cam / sin(rotation) ~ 0.3 mm / sin(8 deg) ~ 2 mm per pair, averaged over
    # 66 pairs of 12 samples; rotation error ~ 0.05 deg / sqrt(N). Bounds at several sigma.
    d = handeye_data(seed=seed, **NOISE)
    r = solve_handeye_scale(d["T_base_flange"], d["T_map_cam"])
    mm, deg = pose_distance(r.T_flange_cam, d["X"])
    assert mm < 5.0
    assert deg < 0.3
    assert abs(r.scale / d["scale"] - 1) < 0.02
    # Residuals reflect the injected noise: neither zero nor large.
    assert 0.05 < r.rms_mm < 5.0


def test_scale_only_with_translations(handeye_data):
    d = handeye_data(seed=4, rot_deg=0.0, **NOISE)
    r = estimate_scale(d["X"], d["T_base_flange"], d["T_map_cam"])
    # 0.3 mm camera noise over ~4 cm translations: relative error ~ 1 % per pair, averaged over 11 pairs.
    assert abs(r.scale / d["scale"] - 1) < 0.02
    assert r.scale_std / d["scale"] < 0.02
    assert abs(r.scale - d["scale"]) < 5 * r.scale_std + 1e-12
    assert isinstance(r, ScaleResult) and r.n_pairs == 11


def test_scale_only_noise_free_exact(handeye_data):
    d = handeye_data(seed=5, rot_deg=10.0)
    r = estimate_scale(d["X"], d["T_base_flange"][:3], d["T_map_cam"][:3])
    assert r.scale == pytest.approx(d["scale"], rel=1e-9)
    assert np.max(r.residuals_mm) < 1e-6


def test_scale_result_round_trip(handeye_data):
    d = handeye_data(seed=5, **NOISE)
    r = estimate_scale(d["X"], d["T_base_flange"], d["T_map_cam"])
    back = ScaleResult.from_dict(r.to_dict())
    assert back.scale == r.scale and np.allclose(back.residuals_mm, r.residuals_mm)


def test_result_round_trip_and_worst_sample(handeye_data):
    d = handeye_data(seed=6, **NOISE)
    # Corrupt one VSE pose by 3 cm: the per-sample residuals must point at it.
    d["T_map_cam"][7] = d["T_map_cam"][7] @ make_pose(np.eye(3), [0.03 / d["scale"], 0, 0])
    r = solve_handeye_scale(d["T_base_flange"], d["T_map_cam"])
    assert r.worst_sample == 7
    back = HandEyeResult.from_dict(r.to_dict())
    np.testing.assert_allclose(back.T_flange_cam, r.T_flange_cam)
    assert back.scale == r.scale and back.pairs == r.pairs and back.method == "racr-linear"


# ----------------------------------------------------------------------------- degenerate input
def test_too_few_samples(handeye_data):
    d = handeye_data(n=2)
    with pytest.raises(CalibrationError, match="too few samples"):
        solve_handeye_scale(d["T_base_flange"], d["T_map_cam"])
    with pytest.raises(CalibrationError, match="too few samples"):
        solve_handeye_target(d["T_base_flange"], d["T_cam_target"])


def test_parallel_rotation_axes_refused(handeye_data):
    d = handeye_data(axes=np.array([[0.0, 0.0, 1.0]]))
    with pytest.raises(CalibrationError, match="same axis"):
        solve_handeye_scale(d["T_base_flange"], d["T_map_cam"])
    with pytest.raises(CalibrationError, match="same axis"):
        solve_handeye_target(d["T_base_flange"], d["T_cam_target"])


def test_two_orthogonal_axes_suffice(handeye_data):
    d = handeye_data(axes=np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]))
    r = solve_handeye_scale(d["T_base_flange"], d["T_map_cam"])
    assert pose_distance(r.T_flange_cam, d["X"])[0] < 1e-6
    # Pairs mixing the two axes rotate about axes in between, so the spread is below 90 deg.
    assert r.axis_spread_deg > 30


def test_pure_translations_refused(handeye_data):
    d = handeye_data(rot_deg=0.0)
    with pytest.raises(CalibrationError, match="only translated"):
        solve_handeye_scale(d["T_base_flange"], d["T_map_cam"])


def test_nan_pose_refused(handeye_data):
    d = handeye_data()
    d["T_map_cam"][4] = d["T_map_cam"][4].copy()
    d["T_map_cam"][4][0, 3] = np.nan
    with pytest.raises(UserInputError, match="sample 4 contains NaN"):
        solve_handeye_scale(d["T_base_flange"], d["T_map_cam"])
    with pytest.raises(UserInputError, match="NaN"):
        estimate_scale(d["X"], d["T_base_flange"], d["T_map_cam"])


def test_mismatched_lengths_refused(handeye_data):
    d = handeye_data()
    with pytest.raises(UserInputError, match="one of each per sample"):
        solve_handeye_scale(d["T_base_flange"], d["T_map_cam"][:-1])


def test_static_vse_refused(handeye_data):
    d = handeye_data()
    frozen = [d["T_map_cam"][0]] * len(d["T_map_cam"])
    with pytest.raises(CalibrationError):
        solve_handeye_scale(d["T_base_flange"], frozen)
    with pytest.raises(CalibrationError, match="unobservable"):
        estimate_scale(d["X"], d["T_base_flange"], frozen)


def test_axis_spread_measure():
    z = exp_so3([0, 0, 0.2])
    x = exp_so3([0.2, 0, 0])
    tilted = exp_so3(0.2 * np.array([np.sin(np.radians(30)), 0, np.cos(np.radians(30))]))
    assert rotation_axis_spread_deg([z, z]) == pytest.approx(0.0, abs=1e-6)
    assert rotation_axis_spread_deg([z, x]) == pytest.approx(90.0, abs=1e-6)
    assert rotation_axis_spread_deg([z, tilted]) == pytest.approx(30.0, abs=1e-6)


# ----------------------------------------------------------------------------- with a target
def test_target_solvers_agree_noise_free(handeye_data):
    d = handeye_data(seed=1, rot_deg=30)
    r = solve_handeye_target(d["T_base_flange"], d["T_cam_target"])
    assert set(r.per_method) | set(r.failed) == {"TSAI", "PARK", "HORAUD", "ANDREFF", "DANIILIDIS"}
    assert len(r.per_method) >= 4
    for res in r.per_method.values():
        mm, deg = pose_distance(res.T_flange_cam, d["X"])
        assert mm < 1e-6 and deg < 1e-6
    assert r.agreement_mm < 1e-6
    T_base_target_true = d["T_base_flange"][0] @ d["X"] @ d["T_cam_target"][0]
    np.testing.assert_allclose(r.T_base_target, T_base_target_true, atol=1e-9)


def test_target_solvers_noisy(handeye_data):
    d = handeye_data(seed=2, rot_deg=30, **NOISE)
    r = solve_handeye_target(d["T_base_flange"], d["T_cam_target"])
    mm, deg = pose_distance(r.T_flange_cam, d["X"])
    assert mm < 5.0 and deg < 0.3
    assert r.best.scale is None
    assert 0.05 < float(np.sqrt(np.mean(r.best.sample_residuals_mm**2))) < 5.0
    assert r.to_dict()["methods"][r.best.method]["rms_mm"] == pytest.approx(r.best.rms_mm)


def test_target_unknown_method(handeye_data):
    d = handeye_data()
    with pytest.raises(UserInputError, match="unknown hand-eye method"):
        solve_handeye_target(d["T_base_flange"], d["T_cam_target"], methods=("NOPE",))


def test_estimate_scale_regression_directions_under_independent_vse_noise(handeye_data):
    """Independent VSE pose noise: regressing the VSE translations on the metric motions
    (``regress="vse"``) is unbiased; the default fit of the metric residuals is biased low."""
    from fgcd_cli.calibration.handeye.linear import estimate_scale

    errors = {"vse": [], "platform": []}
    for seed in range(60):
        d = handeye_data(seed=seed, n=12, rot_deg=8, trans_m=0.03, cam_noise_m=0.003, cam_noise_rad=np.radians(0.2))
        for regress, errs in errors.items():
            res = estimate_scale(d["X"], d["T_base_flange"], d["T_map_cam"], pairs="all", regress=regress)
            errs.append(res.scale / d["scale"] - 1)
            assert abs(errs[-1]) < 4 * res.scale_std / res.scale + 0.01  # the reported sigma is of the right size
    # one session scatters ~3 %; the mean of 60 has a standard error of ~0.4 %
    assert abs(np.mean(errors["vse"])) < 0.012
    assert np.mean(errors["platform"]) < -0.02  # errors in the regressor: ~-3 % here
    with pytest.raises(UserInputError, match="unknown regression"):
        estimate_scale(d["X"], d["T_base_flange"], d["T_map_cam"], regress="both")


def test_hand_eye_report_shows_the_image_refinement(handeye_data):
    from dataclasses import replace

    from rich.console import Console

    from fgcd_cli.cli.calibrate_cmd import _render_handeye

    d = handeye_data(seed=2)
    res = solve_handeye_scale(d["T_base_flange"], d["T_map_cam"])
    res = replace(
        res,
        method="racr-linear+image-ba",
        refinement={
            "points": 543,
            "rms_px": 0.25,
            "std_mm": 0.7,
            "std_deg": 0.024,
            "change_mm": 9.8,
            "change_deg": 0.29,
            "scale_method": "map depths (scale_from_depths)",
        },
    )
    console = Console(record=True, width=200)
    _render_handeye(console, res.to_dict())
    text = console.export_text()
    assert "image refinement: 543 points, 0.25 px RMS" in text and "map depths" in text
    assert "[racr-linear+image-ba]" in text  # the method is shown, not taken for rich markup
