"""Fine-grained change detection between a reference and a current observation.

Everything is expressed in the **reference image's frame**. The entry point is
:func:`fgcd_cli.changes.detect.detect_changes`; its options are a
:class:`fgcd_cli.changes.config.DetectionConfig`.
"""

from fgcd_cli.changes.config import DecisionRule, DetectionConfig
from fgcd_cli.changes.detect import ChangeResult, detect_changes
from fgcd_cli.changes.regions import ChangeRegion, CueLabel, pixel_area_from_depth, pixel_area_from_points

__all__ = [
    "ChangeRegion",
    "ChangeResult",
    "CueLabel",
    "DecisionRule",
    "DetectionConfig",
    "detect_changes",
    "pixel_area_from_depth",
    "pixel_area_from_points",
]
