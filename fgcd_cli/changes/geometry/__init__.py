"""The reference's geometry in a campaign diff: its depth from the metric cloud, the visit's residual pose
measured against it, and the warp that pose and depth give every pixel (docs/change-detection.md,
"Geometry of a campaign diff")."""
