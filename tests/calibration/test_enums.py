"""The calibration's methods, modes, solvers, distortion models and scale sources: the strings of logs and JSON."""

import json

from fgcd_cli.app.calibrate import HandEyeMode
from fgcd_cli.calibration.handeye.linear import HandEyeMethod, Regress
from fgcd_cli.calibration.handeye.target_free import ScaleMethod
from fgcd_cli.calibration.handeye.with_target import OPENCV_METHODS, TargetSolver
from fgcd_cli.calibration.intrinsics import DISTORTION_MODELS, DistortionModel


def test_enums_keep_the_strings_of_logs_and_json():
    assert [str(m) for m in HandEyeMethod] == ["racr-linear", "racr-linear+image-ba"]
    assert [str(m) for m in Regress] == ["platform", "vse"]
    assert [str(m) for m in HandEyeMode] == ["target", "target-free"]
    assert list(OPENCV_METHODS) == [str(s) for s in TargetSolver] == ["TSAI", "PARK", "HORAUD", "ANDREFF", "DANIILIDIS"]
    assert list(DISTORTION_MODELS) == [str(m) for m in DistortionModel] == ["none", "k1k2", "k1k2p1p2", "k1k2p1p2k3"]
    assert str(ScaleMethod.DEPTHS) == "map depths (scale_from_depths)"
    assert str(ScaleMethod.MOTIONS) == "camera motions (estimate_scale, regress=vse)"
    assert json.dumps({"m": HandEyeMethod.RACR_LINEAR}) == '{"m": "racr-linear"}'
