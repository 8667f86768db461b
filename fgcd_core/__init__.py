"""The bottom layer both sides of fgcd import: ``drivers`` (the world) and ``fgcd_cli`` (the brain).

``se3``: rigid poses. ``sim3``: similarities and Umeyama. ``camera``: the one
pinhole intrinsics type. ``board``: the ChArUco board's geometry. ``imaging``:
grey conversion on declared dtypes, CLAHE, SIFT. This package imports only
numpy, scipy and OpenCV; never ``fgcd_cli`` nor ``drivers``.
"""
