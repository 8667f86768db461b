"""Rigid transforms SE(3): re-exported from :mod:`fgcd_core.se3`, where they live."""

from fgcd_core.se3 import *  # noqa: F401,F403
from fgcd_core.se3 import (  # noqa: F401
    __all__,
    exp_se3,
    exp_so3,
    interpolate_pose,
    invert_pose,
    is_pose,
    left_jacobian_so3,
    log_se3,
    log_so3,
    look_at,
    make_pose,
    pose_distance,
    pose_from_quat,
    pose_from_rotvec,
    pose_to_quat,
    pose_to_rotvec,
    project_to_so3,
    rotation_angle_rad,
    skew,
    transform_points,
)
