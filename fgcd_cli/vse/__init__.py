"""Visual SLAM engine (VSE): live tracking, keyframes and a semi-dense point cloud.

Engines: :class:`~fgcd_cli.vse.engine.MonocularVSE` (KLT + PnP + windowed bundle adjustment,
semi-dense cloud by multi-view epipolar search, up to scale), :class:`~fgcd_cli.vse.engine.SparseVSE`
(ORB matches, landmark cloud; the paper's rACR-ORB comparison), :class:`~fgcd_cli.vse.engine.RgbdVSE`
(metric, depth from the frames); all three are a :class:`~fgcd_cli.vse.engine.VisualSlamEngine`
with different parts, and :func:`~fgcd_cli.vse.engine.make_engine` picks one by :class:`~fgcd_cli.vse.engine.VseVariant`.
:class:`~fgcd_cli.vse.thread.VseThread` runs one over a camera source with
thread-safe ``latest()``.
"""
