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
