"""The calibration's config dataclasses, enums and the hand-eye use case keep the former defaults and values."""

from __future__ import annotations

import inspect
import json
import math

import numpy as np
import pytest

from fgcd_drivers.platform import GuardLimits, MotionGuard
from fgcd_cli.app.calibrate import HandEyeCalibration, HandEyeMode, HandEyeRequest, HandEyeRig, run_handeye
from fgcd_cli.calibration.handeye import HandEyeMethod, Regress
from fgcd_cli.calibration.handeye_target import OPENCV_METHODS, TargetSolver
from fgcd_cli.calibration.intrinsics import DISTORTION_MODELS, DistortionModel
from fgcd_cli.calibration.procedure import TargetFreeRunConfig, run_target, run_target_free
from fgcd_cli.calibration.target_free import ScaleMethod
from fgcd_cli.calibration.tracks import pair_list
from fgcd_core.se3 import exp_so3, make_pose


def test_the_hand_eye_request_moves_as_far_as_the_procedure():
    assert HandEyeRequest().translation_mm / 1000 == TargetFreeRunConfig().translation_m


def test_enums_keep_the_strings_of_logs_and_json():
    assert [str(m) for m in HandEyeMethod] == ["racr-linear", "racr-linear+image-ba"]
    assert [str(m) for m in Regress] == ["platform", "vse"]
    assert [str(m) for m in HandEyeMode] == ["target", "target-free"]
    assert list(OPENCV_METHODS) == [str(s) for s in TargetSolver] == ["TSAI", "PARK", "HORAUD", "ANDREFF", "DANIILIDIS"]
    assert list(DISTORTION_MODELS) == [str(m) for m in DistortionModel] == ["none", "k1k2", "k1k2p1p2", "k1k2p1p2k3"]
    assert str(ScaleMethod.DEPTHS) == "map depths (scale_from_depths)"
    assert str(ScaleMethod.MOTIONS) == "camera motions (estimate_scale, regress=vse)"
    assert json.dumps({"m": HandEyeMethod.RACR_LINEAR}) == '{"m": "racr-linear"}'


def test_match_pairs_window_and_anchors():
    assert pair_list(4) == [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    assert pair_list(6, 1, anchors=(0, 3, 5, 9)) == [(0, 1), (0, 3), (0, 5), (1, 2), (2, 3), (3, 4), (3, 5), (4, 5)]


def test_procedures_take_their_options_as_one_config():
    for func in (run_target_free, run_target):
        params = inspect.signature(func).parameters
        assert "config" in params and not any(p.kind is p.VAR_KEYWORD for p in params.values())
    with pytest.raises(TypeError):
        TargetFreeRunConfig(nonsense=1)


def _fake_rig():
    """The ideal platform and VSE stand-ins of ``test_procedure.py`` (loaded by path: tests are no package)."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("_procedure_fakes", Path(__file__).with_name("test_procedure.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_hand_eye_use_case_is_the_target_free_procedure():
    fakes = _fake_rig()
    X = make_pose(exp_so3([0.1, -0.3, 0.2]), [0.03, -0.05, 0.08])
    outcomes = []
    for use_case in (True, False):
        platform = fakes.IdealPlatform()
        guard = MotionGuard(platform, GuardLimits(max_step_m=0.006, max_step_rad=math.radians(1.2)))
        says, ticks = [], []
        factory = lambda cam: fakes.FakeVSE(platform, X, 0.42)  # noqa: E731
        if use_case:
            calibration = run_handeye(HandEyeRig(guard=guard, camera_source=fakes.FakeCamera(), intrinsics=fakes.CAMERA),
                                      HandEyeRequest(), say=says.append,
                                      on_progress=lambda *a: ticks.append(a), vse_factory=factory)
            assert isinstance(calibration, HandEyeCalibration)
            assert calibration.record["skipped_stops"] == {"0": "VSE initializing: need parallax"}
            run = calibration.run
        else:
            run = run_target_free(guard, fakes.FakeCamera(), factory, camera=fakes.CAMERA, progress=says.append,
                                  on_progress=lambda *a: ticks.append(a))
        outcomes.append((np.asarray(run.result.T_flange_cam), run.result.scale, says, ticks, run.frames))
    (X_a, s_a, say_a, tick_a, f_a), (X_b, s_b, say_b, tick_b, f_b) = outcomes
    assert np.array_equal(X_a, X_b) and s_a == s_b and say_a == say_b and tick_a == tick_b and f_a == f_b
