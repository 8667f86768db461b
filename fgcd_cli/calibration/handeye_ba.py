"""The target-free image refinement under its former module name (re-exports).

Split into :mod:`~fgcd_cli.calibration.tracks` (features, matches, tracks,
triangulation), :mod:`~fgcd_cli.calibration.handeye_model` (the residual model),
:mod:`~fgcd_cli.calibration.handeye_refine` (the adjustment),
:mod:`~fgcd_cli.calibration.depth_scale` (the map scale from the keyframe depths)
and :mod:`~fgcd_cli.calibration.target_free` (the refined target-free result).
"""

from fgcd_cli.calibration.depth_scale import KeyframeDepths, scale_from_depths
from fgcd_cli.calibration.handeye_refine import BAHandEyeResult, refine_handeye_images, refine_handeye_tracks
from fgcd_cli.calibration.target_free import PathViews, refine_target_free
from fgcd_cli.calibration.tracks import gray_u8, stop_features

__all__ = ["BAHandEyeResult", "PathViews", "refine_handeye_images", "refine_handeye_tracks", "refine_target_free",
           "scale_from_depths", "KeyframeDepths", "gray_u8", "stop_features"]
