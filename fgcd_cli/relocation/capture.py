"""Former home of the capture and revisit use cases, kept importable.

The use cases live in :mod:`fgcd_cli.app.capture` (reference capture),
:mod:`fgcd_cli.app.relocate` (revisit), :mod:`fgcd_cli.app.session` (the steps
they share) and :mod:`fgcd_cli.app.rig` (``RigHandles``); these names are
re-exports until every caller has moved.
"""

from fgcd_cli.app.capture import CaptureResult, capture_reference  # noqa: F401 - re-exports
from fgcd_cli.app.relocate import relocate_and_capture  # noqa: F401
from fgcd_cli.app.rig import RigHandles  # noqa: F401
from fgcd_cli.app.session import (  # noqa: F401
    MAX_SCALE_RESIDUAL_MM,
    grab_gray as _grab_gray,
    grab_gray_under as _grab_gray_under,
    grab_images,
    load_reference,
    measurement_lighting,
    metric_keyframes as _metric_keyframes,
    reference_images as _reference_images,
    start_session as _start_session,
)

__all__ = ["RigHandles", "CaptureResult", "capture_reference", "relocate_and_capture", "grab_images", "load_reference"]
