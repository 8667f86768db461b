"""Assemble a simulated rig: world, platform, camera, lights, clock and ground truth."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgcd_core.camera import CameraIntrinsics
from fgcd_core.se3 import exp_so3, invert_pose, make_pose
from fgcd_drivers.sim.camera import (
    DEFAULT_EFFECTS,
    DEFAULT_INTRINSICS,
    STILL_SUPERSAMPLE,
    SimCamera,
    SimCameraOptions,
    perturbed_intrinsics,
)
from fgcd_drivers.sim.groundtruth import GroundTruth
from fgcd_drivers.sim.platform import PlatformErrorModel, SimClock, SimPlatform, SimPlatformConfig
from fgcd_drivers.sim.render import Renderer
from fgcd_drivers.sim.scenes import load_scene
from fgcd_drivers.sim.sensor import CameraEffects
from fgcd_drivers.sim.world import SimLights, SimWorld

__all__ = ["SimRig", "SimRigConfig", "build_sim_rig", "random_hand_eye"]


@dataclass
class SimRig:
    """A simulated rig. Algorithms may use only ``platform``, ``camera`` and ``lights``."""

    platform: SimPlatform
    camera: SimCamera
    lights: SimLights
    clock: SimClock
    ground_truth: GroundTruth
    world: SimWorld

    def close(self) -> None:
        self.camera.close()
        self.platform.close()

    def board_camera(self, board, *, seed: int = 0, supersample: int = 2):
        """The rig's camera looking at a hand-held ChArUco board (intrinsics calibration views)."""
        from fgcd_drivers.sim.board import SimBoardCamera

        return SimBoardCamera(
            board, seed=seed, supersample=supersample, intrinsics_true=self.ground_truth.intrinsics_true()
        )

    def inject_changes(self, *, n: int, seed: int, kinds=None, size_mm: tuple[float, float] = (1.0, 20.0)) -> list:
        """Add ``n`` random changes on the object where the reference camera sees it (returns them)."""
        from fgcd_drivers.sim.change_placement import random_changes
        from fgcd_drivers.sim.changes import KINDS

        chs = random_changes(self.world.scene, n=n, seed=seed, kinds=kinds or KINDS, size_mm=size_mm)
        self.world.apply_changes(chs)
        return chs

    def displace_base(self, T_cam_delta: np.ndarray) -> None:
        """The rig was set up again: move the platform base so that the camera, at the current
        flange pose, ends up displaced by ``T_cam_delta`` (a pose expressed in the camera frame)."""
        gt = self.ground_truth
        T_world_cam = gt.T_world_cam_true()
        T_base_flange = self.platform.true_flange_pose()
        new = (
            T_world_cam
            @ np.asarray(T_cam_delta, float)
            @ invert_pose(gt.T_flange_cam_true())
            @ invert_pose(T_base_flange)
        )
        gt._set_T_world_base(new)


def random_hand_eye(rng: np.random.Generator) -> np.ndarray:
    """A realistic hidden ``T_flange_cam``: camera 5-15 cm from the flange, rotated 5-30 degrees."""
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    t = direction * rng.uniform(0.05, 0.15)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    return make_pose(exp_so3(axis * np.radians(rng.uniform(5.0, 30.0))), t)


@dataclass(frozen=True, kw_only=True)
class SimRigConfig:
    """Options of :func:`build_sim_rig` besides the scene.

    Attributes
    ----------
    lighting : initial lighting preset.
    seed : the world: hand-eye, base placement, the platform's kinematic errors, true intrinsics.
    session_seed : this session's random draws: platform repeatability noise, sensor noise.
    scene_seed : seed of the scene generation.
    noise : platform error preset (``none default precise sloppy``) or a PlatformErrorModel.
    T_flange_cam : hand-eye; random (5-15 cm, 5-30 deg) if None.
    intrinsics_error : ``none``, ``default``, ``large`` or a scale factor.
    intrinsics_nominal : what the camera advertises.
    effects : sensor effects (default: vignetting + noise + gamma); ``noise="none"``
        also makes the sensor noiseless unless effects are given.
    supersample : renderer anti-aliasing samples per axis (stream frames).
    still_supersample : samples per pixel axis of the camera's stills (``SimCameraOptions``).
    with_depth, with_rgb : extra frame outputs.
    exposure : ``"auto"`` or a fixed value.
    dof : 6 or 3.
    realtime_factor : see SimPlatformConfig.
    workspace_half_m : half-size of the platform workspace box around home.
    """

    lighting: str = "front"
    seed: int = 0
    session_seed: int = 0
    scene_seed: int = 0
    noise: str | PlatformErrorModel = "default"
    T_flange_cam: np.ndarray | None = None
    intrinsics_error: str | float = "default"
    intrinsics_nominal: CameraIntrinsics = DEFAULT_INTRINSICS
    effects: CameraEffects | None = None
    supersample: int = 1
    still_supersample: int = STILL_SUPERSAMPLE
    with_depth: bool = False
    with_rgb: bool = False
    exposure: float | str = "auto"
    dof: int = 6
    realtime_factor: float | None = None
    workspace_half_m: float = 0.25


def build_sim_rig(*, scene: str, config: SimRigConfig | None = None) -> SimRig:
    """Build a rig in scene ``scene``.

    The platform base is placed so that the flange's home pose puts the camera at
    the scene's default camera pose (``scene.default_T_world_cam``); the base
    frame itself is rotated arbitrarily (seeded) so nothing can rely on it being
    aligned with the world.

    Parameters
    ----------
    scene : scene name (``fgcd_drivers.sim.scenes.list_scenes``).
    config : SimRigConfig, optional
        The rig's options (default: :class:`SimRigConfig`).
    """
    c = config or SimRigConfig()
    rng = np.random.default_rng([c.seed, 0x816])
    sc = load_scene(scene, seed=c.scene_seed)
    world = SimWorld(scene=sc, renderer=Renderer(sc, supersample=c.supersample))
    X = random_hand_eye(rng) if c.T_flange_cam is None else np.asarray(c.T_flange_cam, float)
    clock = SimClock()
    # home flange pose in the base frame: a plausible arm pose (flange ~0.6 m out, 0.4 m up)
    T_base_flange_home = make_pose(exp_so3(rng.normal(0, 0.3, 3)), [0.6, 0.0, 0.4] + rng.normal(0, 0.05, 3))
    T_world_base = sc.default_T_world_cam @ invert_pose(X) @ invert_pose(T_base_flange_home)
    h = T_base_flange_home[:3, 3]
    motion = SimPlatformConfig(
        workspace_min_m=h - c.workspace_half_m,
        workspace_max_m=h + c.workspace_half_m,
        dof=c.dof,
        realtime_factor=c.realtime_factor,
    )
    platform = SimPlatform(
        T_base_flange_home=T_base_flange_home,
        errors=c.noise,
        seed=int(rng.integers(1 << 31)),
        session_seed=c.session_seed,
        clock=clock,
        config=motion,
    )
    intr_true = perturbed_intrinsics(c.intrinsics_nominal, c.intrinsics_error, rng)
    effects = c.effects
    if effects is None:
        effects = (
            DEFAULT_EFFECTS
            if c.noise != "none"
            else CameraEffects(gamma=DEFAULT_EFFECTS.gamma, vignetting=DEFAULT_EFFECTS.vignetting)
        )
    lights = SimLights(c.lighting)

    gt = GroundTruth(
        world=world, platform=platform, T_world_base=T_world_base, T_flange_cam=X, intrinsics_true=intr_true
    )
    camera_seed = int(rng.integers(1 << 31))
    options = SimCameraOptions(
        intrinsics_true=intr_true,
        intrinsics_nominal=c.intrinsics_nominal,
        effects=effects,
        exposure=c.exposure,
        with_depth=c.with_depth,
        with_rgb=c.with_rgb,
        seed=camera_seed + 7919 * c.session_seed,
        still_supersample=c.still_supersample,
    )
    camera = SimCamera(world=world, pose_fn=gt.T_world_cam_true, lights=lights, clock=clock, options=options)
    platform.connect()
    return SimRig(platform=platform, camera=camera, lights=lights, clock=clock, ground_truth=gt, world=world)
