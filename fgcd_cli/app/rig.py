"""Open a rig (platform + guard + camera + lights + VSE factory) from driver options.

This is the one place where a command chooses between the simulator and real
hardware; algorithms receive only the resulting :class:`RigHandles`. For the
simulator it also returns the evaluation hooks (ground truth), which only
``fgcd_cli.metrics`` reads.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from fgcd_cli.app.scenario import (
    SimScenario,
    check_connection,
    check_driver,
    check_lighting,
    check_scenario,
    check_scene,
)
from fgcd_cli.errors import HardwareError, UserInputError, run_record
from fgcd_cli.relocation.session import recorded_motion
from fgcd_core.camera import PinholeCamera
from fgcd_drivers.connect import DRIVERS, Driver
from fgcd_drivers.lights import Lights, LightsDriver, LightsSpec

__all__ = [
    "DRIVERS",
    "Driver",
    "Lights",
    "OpenedRig",
    "RigHandles",
    "RigHooks",
    "RigRequest",
    "check_connection",
    "check_driver",
    "check_lighting",
    "check_scenario",
    "check_scene",
    "open_rig",
    "open_sim_rig",
    "opened",
    "pinhole_from_intrinsics",
    "undistorted",
    "vse_factory_for",
]


@dataclass
class RigHandles:
    """What the use cases need of a rig (any driver).

    Attributes
    ----------
    guard : fgcd_core.platform.MotionGuard
    camera_source : object with ``grab()`` (stream) and ``grab_still()`` (observation stills)
    intrinsics : PinholeCamera
    T_flange_cam : (4, 4) ndarray
        Hand-eye from calibration (identity with ``--no-handeye``).
    lights : Lights or None
        The rig's switchable lights (None: the day's light only).
    vse_factory : callable() -> VseThread (not started)
    on_event : callable(str) or None
        Progress lines for people.
    on_progress : callable(done, total, label) or None
        Progress of long steps (``total <= 0``: length unknown).
    frame_synthesis_s : callable([thread]) -> float, or None
        The camera's cumulative frame-synthesis time, seconds (a simulator's
        rendering; given a thread's ident, that thread's only), so that session timing leaves it out
        (:class:`fgcd_cli.relocation.session.VseSession`); None for real cameras.
    """

    guard: object
    camera_source: object
    intrinsics: PinholeCamera
    T_flange_cam: np.ndarray
    vse_factory: Callable[[], object]
    lights: Lights | None = None
    on_event: Callable[[str], None] | None = None
    on_progress: Callable[[int, int, str], None] | None = None
    frame_synthesis_s: Callable[..., float] | None = None

    def say(self, text: str) -> None:
        """One progress line for people (no-op without ``on_event``)."""
        if self.on_event:
            self.on_event(text)

    def progress(self, done: int, total: int, label: str) -> None:
        """Progress of a long step (no-op without ``on_progress``)."""
        if self.on_progress:
            self.on_progress(done, total, label)


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
    from fgcd_core.platform import MotionGuard

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
    """The camera's nominal intrinsics as a ``PinholeCamera`` (the one intrinsics type of :mod:`fgcd_core.camera`), or from a dict."""
    return PinholeCamera.from_dict(intr) if isinstance(intr, dict) else intr


def undistorted(camera: PinholeCamera, source):
    """``(ideal camera, source)``: frames remapped to an ideal pinhole when the lens distorts."""
    if not camera.has_distortion:
        return camera, source
    from fgcd_cli.vse.undistort import UndistortedSource, Undistorter

    u = Undistorter(camera)
    return u.ideal, UndistortedSource(source, u)


def vse_factory_for(camera: PinholeCamera, source, *, variant: str = "mono") -> Callable[[], object]:
    """A factory of (not yet started) VSE threads over ``source``."""

    def make():
        from fgcd_cli.vse.engine import VseVariant, make_engine
        from fgcd_cli.vse.thread import VseThread

        if variant not in set(VseVariant):
            raise UserInputError(f"unknown VSE variant '{variant}' ({', '.join(VseVariant)})")
        return VseThread(make_engine(variant, camera), source)

    return make


def _random_offset(rng: np.random.Generator, mm: float, deg: float) -> np.ndarray:
    from fgcd_core.se3 import exp_se3

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
    from fgcd_core.platform import GuardLimits
    from fgcd_drivers.sim.rig import SimRigConfig, build_sim_rig

    scenario = check_scenario(scenario)
    rig = build_sim_rig(
        scene=scenario.scene,
        config=SimRigConfig(
            lighting=scenario.lighting,
            seed=scenario.seed,
            noise=scenario.noise,
            session_seed=scenario.session_seed,
            with_depth=vse_variant == "rgbd",
        ),
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
    guard = _recorded_guard(
        rig.platform, GuardLimits(max_step_m=0.06, max_step_rad=math.radians(12), speed_fraction=1.0), confirm
    )
    handles = RigHandles(
        guard=guard,
        camera_source=source,
        intrinsics=cam,
        T_flange_cam=hand_eye_or_identity(T_flange_cam),
        vse_factory=vse_factory_for(cam, source, variant=vse_variant),
        lights=rig.lights,
        on_event=on_event,
        on_progress=on_progress,
        frame_synthesis_s=source.synthetic_overhead_s,
    )
    return OpenedRig(handles=handles, close=rig.platform.close, sim=rig, info={"scenario": scenario.__dict__})


def hand_eye_or_identity(T_flange_cam: np.ndarray | None) -> np.ndarray:
    """The hand-eye a rig is opened with: ``T_flange_cam`` (4x4, metres), or the identity without one.

    The one home of "no hand-eye means identity": a rig opened to calibrate it, the ACR
    baseline (which needs none) and ``fgcd relocate --no-handeye`` all reach it through here.
    """
    return np.eye(4) if T_flange_cam is None else np.asarray(T_flange_cam, dtype=float)


@dataclass(frozen=True, kw_only=True)
class RigRequest:
    """Which rig to open, and with which calibration.

    Attributes
    ----------
    driver : str
        Platform driver (:data:`DRIVERS`).
    T_flange_cam : (4, 4) ndarray or None
        Hand-eye (identity when None).
    intrinsics : PinholeCamera or None
        Camera model (required on hardware; the simulator's nominal one when None).
    scenario : SimScenario or None
        The simulated world (simulator only; the default scenario when None).
    port, baud, host, camera_index
        Address of a GRBL stage / UR arm, and the OpenCV camera (hardware only).
    vse_variant : str
        ``mono``, ``sparse`` or ``rgbd``.
    lights : LightsSpec or None
        The rig's light driver (campaign.toml ``[rig.lights]``); None: the
        simulator's own lights, a manual prompt on the manual driver, else none.
        On the simulator a real driver is wired to the simulated scene
        (:class:`fgcd_drivers.sim.wiring.WiredSimLights`).
    """

    driver: str
    T_flange_cam: np.ndarray | None = None
    intrinsics: PinholeCamera | None = None
    scenario: SimScenario | None = None
    port: str | None = None
    baud: int = 115200
    host: str | None = None
    camera_index: int | str = 0
    vse_variant: str = "mono"
    lights: LightsSpec | None = None


@dataclass(frozen=True, kw_only=True)
class RigHooks:
    """The plain callbacks a rig reports through (see :class:`RigHandles`).

    ``ask_light`` asks a person to switch a light (manual lights; ``input`` when None).
    """

    confirm: Callable[[str], bool] | None = None
    ask_light: Callable[[str], str] | None = None
    on_event: Callable[[str], None] | None = None
    on_progress: Callable[[int, int, str], None] | None = None


def open_rig(request: RigRequest, *, hooks: RigHooks | None = None) -> OpenedRig:
    """Open the rig a command asked for (``hooks``: see :class:`RigHandles`)."""
    hooks = hooks or RigHooks()
    if request.driver == Driver.SIM:
        rig = open_sim_rig(
            request.scenario or SimScenario(),
            T_flange_cam=request.T_flange_cam,
            intrinsics=request.intrinsics,
            confirm=hooks.confirm,
            vse_variant=request.vse_variant,
            on_event=hooks.on_event,
            on_progress=hooks.on_progress,
        )
        if request.lights is not None and request.lights.driver != LightsDriver.SIM:
            _wire_sim_lights(rig, request.lights, hooks)
        elif request.lights is not None and request.lights.channels:
            _mount_sim_lamps(rig, request.lights)
        return rig
    return _open_hardware_rig(request, hooks)


def _lights_for(spec: LightsSpec, hooks: RigHooks, platform=None) -> Lights:
    """The light driver of ``spec`` (HardwareError when it cannot be opened)."""
    from fgcd_core.platform import PlatformError
    from fgcd_drivers.connect import open_lights

    try:
        return open_lights(spec, platform=platform, ask=hooks.ask_light or input)
    except (PlatformError, OSError) as exc:
        raise HardwareError(f"cannot open the lights: {exc}") from None


def _mount_sim_lamps(rig: OpenedRig, spec: LightsSpec) -> None:
    """The simulated rig carries the lamps ``[rig.lights]`` lists (driver ``sim``), as a real rig its wired ones."""
    from fgcd_drivers.lights import LightsError

    try:
        rig.handles.lights.mount(list(spec.channels))
    except LightsError as exc:
        rig.close()
        raise HardwareError(f"cannot open the lights: {exc}") from None


def _wire_sim_lights(rig: OpenedRig, spec: LightsSpec, hooks: RigHooks) -> None:
    """A real light driver lighting the simulated scene (docs/hardware.md, Lights); closed with the rig."""
    from fgcd_drivers.sim.wiring import WiredSimLights

    try:
        wired = WiredSimLights(_lights_for(spec, hooks), rig.handles.lights)
    except Exception:
        rig.close()
        raise
    rig.handles.lights = wired
    close_platform = rig.close

    def close() -> None:
        try:
            wired.close()
        finally:
            close_platform()

    rig.close = close


def _open_hardware_rig(request: RigRequest, hooks: RigHooks) -> OpenedRig:
    """A hardware rig: the driver's platform behind a recorded guard, the OpenCV camera undistorted."""
    driver = check_driver(request.driver)
    check_connection(driver, port=request.port, host=request.host)
    if request.intrinsics is None:
        raise UserInputError("no camera intrinsics in the campaign rig: run `fgcd calibrate intrinsics` first")
    from fgcd_core.platform import GuardLimits
    from fgcd_drivers.cameras import OpenCVCamera
    from fgcd_drivers.connect import PlatformSpec, open_platform

    try:
        platform = open_platform(driver, spec=PlatformSpec(port=request.port, baud=request.baud, host=request.host))
        platform.connect()
        try:
            raw_camera = OpenCVCamera(
                request.camera_index, width=request.intrinsics.width, height=request.intrinsics.height
            )
        except BaseException:  # no camera (CameraError, exit 7): the platform is not left connected
            platform.close()
            raise
    except OSError as exc:
        raise HardwareError(f"cannot open the rig: {exc}") from None
    guard = _recorded_guard(platform, GuardLimits(), hooks.confirm)
    intrinsics, camera = undistorted(request.intrinsics, raw_camera)
    spec = request.lights
    if spec is None and driver == Driver.MANUAL:
        spec = LightsSpec(driver=LightsDriver.MANUAL)  # a person is at the rig: asked to switch
    try:
        lights = _lights_for(spec, hooks, platform) if spec is not None else None
    except HardwareError:
        camera.close()
        platform.close()
        raise

    def close() -> None:
        try:
            if lights is not None:
                lights.close()
            camera.close()
        finally:
            platform.close()

    T_flange_cam = request.T_flange_cam
    handles = RigHandles(
        guard=guard,
        camera_source=camera,
        intrinsics=intrinsics,
        T_flange_cam=hand_eye_or_identity(T_flange_cam),
        vse_factory=vse_factory_for(intrinsics, camera, variant=request.vse_variant),
        lights=lights,
        on_event=hooks.on_event,
        on_progress=hooks.on_progress,
    )
    return OpenedRig(handles=handles, close=close)
