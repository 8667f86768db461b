"""Calibration: camera intrinsics (ChArUco), hand-eye ``T_flange_cam`` and the monocular map scale.

Entry functions::

    handeye.linear.solve_handeye_scale(T_base_flange, T_map_cam, *, pairs="all") -> HandEyeResult
    handeye.linear.estimate_scale(T_flange_cam, T_base_flange, T_map_cam) -> ScaleResult
    handeye.with_target.solve_handeye_target(T_base_flange, T_cam_target, *, methods=...) -> TargetHandEyeResult
    intrinsics.calibrate_intrinsics(images, board: BoardSpec, *, distortion_model=...) -> IntrinsicsResult
"""
