"""Calibration: camera intrinsics (ChArUco), hand-eye ``T_flange_cam`` and the monocular map scale.

Public API::

    solve_handeye_scale(T_base_flange, T_map_cam, *, pairs="all") -> HandEyeResult
    estimate_scale(T_flange_cam, T_base_flange, T_map_cam) -> ScaleResult
    solve_handeye_target(T_base_flange, T_cam_target, *, methods=...) -> TargetHandEyeResult
    calibrate_intrinsics(images, board: BoardSpec, *, distortion_model=...) -> IntrinsicsResult
"""

from fgcd_cli.calibration.board import BoardSpec, write_printable_board
from fgcd_cli.calibration.errors import CalibrationError
from fgcd_cli.calibration.handeye.linear import HandEyeResult, ScaleResult, estimate_scale, solve_handeye_scale
from fgcd_cli.calibration.handeye.with_target import TargetHandEyeResult, solve_handeye_target
from fgcd_cli.calibration.intrinsics import IntrinsicsResult, calibrate_intrinsics

__all__ = [
    "BoardSpec",
    "IntrinsicsResult",
    "calibrate_intrinsics",
    "write_printable_board",
    "CalibrationError",
    "HandEyeResult",
    "ScaleResult",
    "TargetHandEyeResult",
    "estimate_scale",
    "solve_handeye_scale",
    "solve_handeye_target",
]
