"""SE(3)/Sim(3), rotations and the pinhole camera model (re-exported from :mod:`fgcd_core`)."""

from fgcd_cli.geometry.camera import PinholeCamera
from fgcd_cli.geometry.se3 import (
    exp_se3,
    interpolate_pose,
    invert_pose,
    log_se3,
    make_pose,
    pose_distance,
    pose_from_quat,
    pose_from_rotvec,
    pose_to_quat,
    pose_to_rotvec,
    transform_points,
)
from fgcd_cli.geometry.sim3 import Sim3, umeyama

__all__ = [
    "PinholeCamera",
    "Sim3",
    "umeyama",
    "exp_se3",
    "log_se3",
    "make_pose",
    "invert_pose",
    "interpolate_pose",
    "pose_distance",
    "pose_from_quat",
    "pose_from_rotvec",
    "pose_to_quat",
    "pose_to_rotvec",
    "transform_points",
]
