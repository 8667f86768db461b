"""Visual SLAM engine (VSE): live tracking, keyframes and a semi-dense point cloud.

Engines: :class:`MonocularVSE` (KLT + PnP + windowed bundle adjustment,
semi-dense cloud by multi-view epipolar search, up to scale), :class:`SparseVSE`
(ORB matches, landmark cloud; the paper's rACR-ORB comparison), :class:`RgbdVSE`
(metric, depth from the frames); all three are a :class:`VisualSlamEngine`
with different parts, and :func:`make_engine` picks one by :class:`VseVariant`.
:class:`~fgcd_cli.vse.thread.VseThread` runs one over a camera source with
thread-safe ``latest()``.
"""

from fgcd_cli.vse.engine import MonocularVSE, RgbdVSE, SparseVSE, VisualSlamEngine, VseVariant, make_engine
from fgcd_cli.vse.thread import VseThread
from fgcd_cli.vse.types import FrameSource, Keyframe, MapCloud, VseConfig, VseState, VseStatus

__all__ = [
    "MonocularVSE",
    "SparseVSE",
    "RgbdVSE",
    "VisualSlamEngine",
    "VseVariant",
    "make_engine",
    "VseThread",
    "VseConfig",
    "VseState",
    "VseStatus",
    "Keyframe",
    "MapCloud",
    "FrameSource",
]
