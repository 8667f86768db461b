"""Open a rig (platform + guard + camera + lights + VSE factory) from driver options.

This is the one place where a command chooses between the simulator and real
hardware; algorithms receive only the resulting :class:`RigHandles`. For the
simulator it also returns the evaluation hooks (ground truth), which only
``fgcd_cli.metrics`` reads.
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Callable, Iterator

import numpy as np

from fgcd_cli.errors import HardwareError, UserInputError, run_record
from fgcd_cli.geometry.camera import PinholeCamera
from fgcd_cli.relocation.capture import RigHandles
from fgcd_cli.relocation.session import recorded_motion

__all__ = [
    "DRIVERS",
    "OpenedRig",
    "SimScenario",
    "check_connection",
    "check_driver",
    "check_lighting",
    "check_scenario",
    "check_scene",
    "open_rig",
    "opened",
    "pinhole_from_intrinsics",
    "vse_factory_for",
]

#: Platform drivers a command can open.
DRIVERS = ("sim", "grbl", "ur", "manual")


@dataclass(frozen=True, kw_only=True)
class SimScenario:
    """How the simulated world of a session differs from the reference one.

    Attributes
    ----------
    scene : str
        Scene name (``fgcd sim scenes``).
    seed : int
        World seed: same seed, same object and same hidden hand-eye.
    lighting : str
        Lighting preset of this session.
    changes : int
        Number of fine-grained changes injected (0 for the reference).
    change_size_mm : (float, float)
        Size range of the injected changes, millimetres.
    change_seed : int
        Seed of the changes.
    start_offset_mm, start_offset_deg : float
        How far from the reference the platform starts (the rig was set up
        again); a random direction drawn from ``session_seed``.
    session_seed : int
        Seed of this session's start offset and noise.
    noise : str
        Platform noise preset.
    """

    scene: str = "stele"
    seed: int = 0
    lighting: str = "front"
    changes: int = 0
    change_seed: int = 1
    change_size_mm: tuple[float, float] = (1.0, 20.0)
    start_offset_mm: float = 0.0
    start_offset_deg: float = 0.0
    session_seed: int = 0
    noise: str = "default"


def check_driver(driver: str) -> str:
    """``driver`` if it is one of :data:`DRIVERS`; UserInputError naming them otherwise."""
    if driver not in DRIVERS:
        raise UserInputError(f"unknown driver '{driver}' (choose from {', '.join(DRIVERS)})")
    return driver


def check_connection(driver: str, *, port: str | None, host: str | None) -> None:
    """Refuse a hardware driver without the address it needs (UserInputError, before anything is opened).

    Rule: the address a driver needs is an option the user forgot, not a
    hardware fault (the same rule as ``fgcd platform``).
    """
    if driver == "grbl" and not port:
        raise UserInputError("the grbl driver needs --port (e.g. --port /dev/ttyUSB0, or port in campaign.toml [rig])")
    if driver == "ur" and not host:
        raise UserInputError("the ur driver needs --host (the controller's address, e.g. --host 192.168.0.10, "
                             "or host in campaign.toml [rig])")


def check_scene(scene: str) -> str:
    """``scene`` if the simulator has it; UserInputError naming the known scenes otherwise."""
    from drivers.sim.scenes import SceneNotFound, scene_spec

    try:
        scene_spec(scene)
    except SceneNotFound:
        from drivers.sim.scenes import list_scenes

        known = ", ".join(s.name for s in list_scenes()) or "none"
        raise UserInputError(f"unknown scene '{scene}' (choose from {known}; `fgcd sim scenes`)") from None
    except (OSError, ValueError) as exc:
        raise UserInputError(f"scene '{scene}' cannot be read: {exc}") from None
    return scene


def check_lighting(name: str, *, option: str = "--light") -> str:
    """The canonical name of a simulator lighting preset; UserInputError naming the valid ones otherwise."""
    from drivers.sim.lights import lighting_preset, list_lighting_presets

    try:
        return lighting_preset(name).name
    except ValueError as exc:
        # the parametrised presets are listed by their pattern, not by an example
        fixed = [n for n, _ in list_lighting_presets() if ":" not in n and n != "front"]
        known = ", ".join(["front", "led:H (H = 1..12)", "sun:az=A,el=E", "sun:day=D,hour=H", *fixed])
        reason = str(exc).split(";")[0]
        raise UserInputError(f"{option}: {reason} (valid: {known}; `fgcd sim lights`)") from None


def check_scenario(scenario: SimScenario) -> SimScenario:
    """``scenario`` with its lighting's canonical name, once every value is valid (UserInputError otherwise)."""
    check_scene(scenario.scene)
    lighting = check_lighting(scenario.lighting)
    if scenario.changes < 0:
        raise UserInputError(f"--changes must be 0 or more, got {scenario.changes}")
    for option, value in (("--start-offset-mm", scenario.start_offset_mm), ("--start-offset-deg", scenario.start_offset_deg)):
        if not math.isfinite(value) or value < 0:
            raise UserInputError(f"{option} must be a finite number >= 0, got {value}")
    lo, hi = scenario.change_size_mm
    if not (0 < lo <= hi and math.isfinite(hi)):
        raise UserInputError(f"change sizes must satisfy 0 < min <= max mm, got {lo}, {hi}")
    return replace(scenario, lighting=lighting)


def _recording(confirm: Callable[[str], bool] | None) -> Callable[[str], bool] | None:
    """``confirm`` asked with the run record saying the platform is not moving (nothing moves before the answer)."""
    if confirm is None:
        return None

    def ask(text: str) -> bool:
        was = run_record.moving
        run_record.moving = False
        answer = confirm(text)  # Ctrl-C here: not moving, as recorded
        run_record.moving = was
        return answer

    return ask


def _recorded_guard(platform, limits, confirm):
    """A MotionGuard whose motions mark ``run_record`` (the Ctrl-C line says whether the platform was moving)."""
    from drivers.platform import MotionGuard

    class RecordedMotionGuard(MotionGuard):
        def move_to(self, T_base_flange_target):  # noqa: D102 - MotionGuard.move_to, recorded
            with recorded_motion():
                return super().move_to(T_base_flange_target)

    return RecordedMotionGuard(platform, limits, confirm=_recording(confirm))


@dataclass
class OpenedRig:
    """A rig ready for the use cases, plus what to close and (sim only) evaluation hooks."""

    handles: RigHandles
    close: Callable[[], None]
    sim: object | None = None  # the SimRig, for evaluation code only
    info: dict = field(default_factory=dict)

    @property
    def platform_name(self) -> str | None:
        """Name of the rig's platform (``sim``, ``grbl``, ``ur``, ``manual``), None when unknown."""
        platform = getattr(getattr(self.handles, "guard", None), "platform", None)
        return getattr(platform, "name", None)

    def stop(self, reason: str = "interrupted by the user (Ctrl-C)") -> None:
        """Stop the platform and refuse further motion (trips the guard)."""
        guard = getattr(self.handles, "guard", None)
        if guard is not None and hasattr(guard, "trip"):
            guard.trip(reason)


@contextmanager
def opened(rig: OpenedRig) -> Iterator[OpenedRig]:
    """``rig`` for a block: on Ctrl-C the platform is stopped first, and the rig is always closed.

    A Ctrl-C between two motions (while the VSE settles, an alignment runs)
    does not pass through the guard: the block stops the platform itself.
    """
    try:
        yield rig
    except KeyboardInterrupt:
        stop = getattr(rig, "stop", None)  # any object with close() (stand-ins in tests)
        if stop is not None:
            stop()
        raise
    finally:
        rig.close()


def pinhole_from_intrinsics(intr) -> PinholeCamera:
    """``PinholeCamera`` from ``drivers.cameras.CameraIntrinsics`` (or a dict)."""
    if isinstance(intr, dict):
        return PinholeCamera.from_dict(intr)
    return PinholeCamera(
        fx=float(intr.fx),
        fy=float(intr.fy),
        cx=float(intr.cx),
        cy=float(intr.cy),
        width=int(intr.width),
        height=int(intr.height),
        dist=tuple(float(d) for d in intr.dist),
    )


def undistorted(camera: PinholeCamera, source):
    """``(ideal camera, source)``: frames remapped to an ideal pinhole when the lens distorts."""
    if not camera.has_distortion:
        return camera, source
    from fgcd_cli.vse.undistort import Undistorter, UndistortedSource

    u = Undistorter(camera)
    return u.ideal, UndistortedSource(source, u)


def vse_factory_for(camera: PinholeCamera, source, *, variant: str = "mono") -> Callable[[], object]:
    """A factory of (not yet started) VSE threads over ``source``."""

    def make():
        from fgcd_cli.vse import MonocularVSE, RgbdVSE, SparseVSE
        from fgcd_cli.vse.thread import VseThread

        engines = {"mono": MonocularVSE, "sparse": SparseVSE, "rgbd": RgbdVSE}
        if variant not in engines:
            raise UserInputError(f"unknown VSE variant '{variant}' (mono, sparse, rgbd)")
        return VseThread(engines[variant](camera), source)

    return make


def _random_offset(rng: np.random.Generator, mm: float, deg: float) -> np.ndarray:
    from fgcd_cli.geometry.se3 import exp_se3

    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    a = rng.normal(size=3)
    a /= np.linalg.norm(a)
    return exp_se3(np.r_[d * mm / 1000.0, a * math.radians(deg)])


def open_sim_rig(
    scenario: SimScenario,
    *,
    T_flange_cam: np.ndarray | None,
    intrinsics: PinholeCamera | None,
    confirm: Callable[[str], bool] | None = None,
    vse_variant: str = "mono",
    on_event: Callable[[str], None] | None = None,
    on_progress: Callable[[int, int, str], None] | None = None,
) -> OpenedRig:
    """A simulated rig for one session of a scenario (``on_progress``: see :class:`RigHandles`)."""
    from drivers.platform import GuardLimits
    from drivers.sim.rig import build_sim_rig

    scenario = check_scenario(scenario)
    rig = build_sim_rig(
        scene=scenario.scene,
        lighting=scenario.lighting,
        seed=scenario.seed,
        noise=scenario.noise,
        session_seed=scenario.session_seed,
        with_depth=vse_variant == "rgbd",
    )
    if scenario.changes > 0:
        rig.inject_changes(n=scenario.changes, seed=scenario.change_seed, size_mm=tuple(scenario.change_size_mm))
    if scenario.start_offset_mm > 0 or scenario.start_offset_deg > 0:
        rng = np.random.default_rng(10_000 + scenario.session_seed)
        rig.displace_base(_random_offset(rng, scenario.start_offset_mm, scenario.start_offset_deg))
    rig.platform.connect()
    cam, source = undistorted(intrinsics or pinhole_from_intrinsics(rig.camera.intrinsics_nominal), rig.camera)
    # The simulated platform's speed model is already the rACR paper's slow stage
    # (1.5 s per cm, ~6.7 mm/s): run it at that speed, not at the guard's default
    # half speed meant for fast industrial arms, so simulated times compare with the paper's.
    guard = _recorded_guard(rig.platform, GuardLimits(max_step_m=0.06, max_step_rad=math.radians(12),
                                                      speed_fraction=1.0), confirm)
    handles = RigHandles(
        guard=guard,
        camera_source=source,
        intrinsics=cam,
        T_flange_cam=np.eye(4) if T_flange_cam is None else np.asarray(T_flange_cam, dtype=float),
        vse_factory=vse_factory_for(cam, source, variant=vse_variant),
        lights=rig.lights,
        on_event=on_event,
        on_progress=on_progress,
    )
    return OpenedRig(handles=handles, close=rig.platform.close, sim=rig, info={"scenario": scenario.__dict__})


def open_rig(
    *,
    driver: str,
    T_flange_cam: np.ndarray | None,
    intrinsics: PinholeCamera | None,
    scenario: SimScenario | None = None,
    port: str | None = None,
    baud: int = 115200,
    host: str | None = None,
    camera_index: int | str = 0,
    confirm: Callable[[str], bool] | None = None,
    vse_variant: str = "mono",
    on_event: Callable[[str], None] | None = None,
    on_progress: Callable[[int, int, str], None] | None = None,
) -> OpenedRig:
    """Open the rig a command asked for (``on_event``, ``on_progress``: see :class:`RigHandles`)."""
    if driver == "sim":
        return open_sim_rig(
            scenario or SimScenario(),
            T_flange_cam=T_flange_cam,
            intrinsics=intrinsics,
            confirm=confirm,
            vse_variant=vse_variant,
            on_event=on_event,
            on_progress=on_progress,
        )
    check_driver(driver)
    check_connection(driver, port=port, host=host)
    if intrinsics is None:
        raise UserInputError("no camera intrinsics in the campaign rig: run `fgcd calibrate intrinsics` first")
    from drivers.cameras import OpenCVCamera
    from drivers.connect import open_platform
    from drivers.platform import GuardLimits

    try:
        platform = open_platform(driver, port=port, baud=baud, host=host)
        platform.connect()
        raw_camera = OpenCVCamera(camera_index, width=intrinsics.width, height=intrinsics.height)
    except OSError as exc:
        raise HardwareError(f"cannot open the rig: {exc}") from None
    guard = _recorded_guard(platform, GuardLimits(), confirm)
    intrinsics, camera = undistorted(intrinsics, raw_camera)

    def close() -> None:
        try:
            camera.close()
        finally:
            platform.close()

    handles = RigHandles(
        guard=guard,
        camera_source=camera,
        intrinsics=intrinsics,
        T_flange_cam=np.eye(4) if T_flange_cam is None else np.asarray(T_flange_cam, dtype=float),
        vse_factory=vse_factory_for(intrinsics, camera, variant=vse_variant),
        lights=None,
        on_event=on_event,
        on_progress=on_progress,
    )
    return OpenedRig(handles=handles, close=close)
