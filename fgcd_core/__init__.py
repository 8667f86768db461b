"""The bottom layer both sides of fgcd import: ``drivers`` (the world) and ``fgcd_cli`` (the brain).

``se3``: rigid poses. ``sim3``: similarities and Umeyama. ``camera``: the one
pinhole intrinsics type and the one ideal projection. ``board``: the ChArUco
board's geometry. ``imaging``: grey conversion on declared dtypes, CLAHE, SIFT.
``lm``: the one Levenberg-Marquardt driver and the Huber weights. ``schur``: the
one Schur-complement solve of camera-block + point-block normal equations.
``platform``: the robot port (the Platform protocol, its errors, capabilities,
results) and ``MotionGuard``, the one gate every motion passes; the adapters in
``drivers`` implement it. This package imports only numpy, scipy and OpenCV;
never ``fgcd_cli`` nor ``drivers``.
"""


from fgcd_core.camera import PinholeCamera
from fgcd_core.se3 import (
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
from fgcd_core.sim3 import Sim3, umeyama

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
