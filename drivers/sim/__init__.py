"""The simulator backend: scenes, renderer, lights, changes, platform, camera, ground truth.

Algorithms never import this package; they see a rig only through
``fgcd_core.platform.Platform`` and ``fgcd_drivers.cameras.CameraSource``. Evaluation
code reads the truth through :class:`fgcd_drivers.sim.groundtruth.GroundTruth`.
Entry point: :func:`fgcd_drivers.sim.rig.build_sim_rig`.
"""
