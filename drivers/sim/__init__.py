"""The simulator backend: scenes, renderer, lights, changes, platform, camera, ground truth.

Algorithms never import this package; they see a rig only through
``drivers.platform.Platform`` and ``drivers.cameras.CameraSource``. Evaluation
code reads the truth through :class:`drivers.sim.groundtruth.GroundTruth`.
Entry point: :func:`drivers.sim.rig.build_sim_rig`.
"""
