"""The capture use case: check a capture's options, open the rig, and write a station's immutable reference.

``plan_capture`` checks every option before anything is created, opened or
moved; ``run_capture`` opens the rig and runs ``capture_reference``: start the
VSE, explore, estimate the map scale, come back to the chosen pose, and write
the reference observation (metric cloud, reference camera pose, keyframes,
images under each lighting).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from fgcd_cli.app.lamp_image import reference_flash
from fgcd_cli.app.rig import RigHandles, RigHooks, RigRequest
from fgcd_cli.app.rig_options import EffectiveRig, RigOptions, check_campaign_rig, check_record_rig, resolve_rig
from fgcd_cli.app.scenario import SimScenario, check_lighting, check_scenario, check_scene
from fgcd_cli.app.session import grab_images, metric_keyframes, start_session
from fgcd_cli.calibration.rig_files import rig_calibration
from fgcd_cli.campaign import schema
from fgcd_cli.campaign.records import campaign_world
from fgcd_cli.errors import AlgorithmError, CampaignError, ImmutableDataError, UserInputError, run_record
from fgcd_cli.relocation.coarse.config import CoarseResult
from fgcd_cli.relocation.log import RelocationResult
from fgcd_cli.relocation.session import ScaleEstimate
from fgcd_cli.vse.types import VseStatus
from fgcd_core.camera import PinholeCamera
from fgcd_drivers.connect import Driver
from fgcd_drivers.lights import LightsSpec

__all__ = [
    "CapturePlan",
    "CaptureRequest",
    "CaptureResult",
    "CaptureOutcome",
    "capture_reference",
    "connection",
    "open_capture",
    "plan_capture",
    "run_capture",
]


@dataclass
class CaptureResult:
    """Summary of a capture or a visit."""

    observation_path: str
    scale: ScaleEstimate
    cloud_points: int
    images: list[str]
    relocation: RelocationResult | None = None
    extra: dict = field(default_factory=dict)
    coarse: CoarseResult | None = None
    """The active coarse stage's outcome, when it ran (far starts only)."""


def capture_reference(
    rig: RigHandles,
    station,
    *,
    lightings: list[str],
    explore_m: float = 0.05,
    metadata: dict | None = None,
    evaluation: Callable[[], dict] | None = None,
) -> CaptureResult:
    """Capture the immutable reference observation of ``station`` at the platform's current pose.

    ``evaluation`` (simulator only, outside the algorithm): called when the reference images are taken,
    the truth of that moment (the camera has explored and come back, with the platform's errors), written
    as the observation's ``evaluation/sim_truth.json``.
    """
    rig.progress(0, 0, "starting the VSE")
    session, vse, scale, T_base_flange_ref = start_session(rig, explore_m=explore_m)
    try:
        session.move_to_flange(T_base_flange_ref, label="back to the reference pose")
        rig.progress(0, 0, "letting the reference cloud mature")
        state = session.tracking_state()
        # a few more frames at the reference pose let the semi-dense cloud mature
        state = session.settle(frames=6)
        if state.status != VseStatus.TRACKING:
            raise AlgorithmError(f"the VSE lost track at the reference pose ({state.message})")
        T_ref_camref = np.array(state.T_map_cam, dtype=float)
        T_ref_camref[:3, 3] *= scale.scale
        cloud = state.cloud
        if len(cloud) < 1000:
            raise AlgorithmError(
                f"the reference cloud has only {len(cloud)} points: scene too weakly textured for rACR"
            )
        points = np.asarray(cloud.points, dtype=float) * scale.scale
        kf_poses, kf_images = metric_keyframes(state, scale.scale)
        images = grab_images(rig, lightings)
        lamp = reference_flash(rig, rig.say)
        images.update(lamp.images)
        truth = evaluation() if evaluation is not None else None
        meta = {
            "lightings": list(images),
            "scale": scale.__dict__,
            "T_flange_cam": np.asarray(rig.T_flange_cam).tolist(),
            "T_base_flange": np.asarray(rig.guard.platform.flange_pose()).tolist(),
            "intrinsics": rig.intrinsics.to_dict(),
            "cloud_points": int(len(points)),
            "keyframes": int(len(kf_poses)),
            "platform_s": session.timing.platform_s,
            **lamp.metadata,
            **(metadata or {}),
        }
        rig.progress(0, 0, "writing the reference")
        with run_record.writing(f"the reference of station '{station.name}'"), station.write_reference(meta) as w:
            for name, img in images.items():
                w.add_image(name, img)
            w.add_cloud(points, colors=np.asarray(cloud.intensities, dtype=np.float32))
            w.add_array(schema.ARRAY_CLOUD_INTENSITIES, np.asarray(cloud.intensities, dtype=np.float32))
            w.add_array(schema.ARRAY_T_REF_CAMREF, T_ref_camref)
            w.add_array(schema.ARRAY_KEYFRAME_POSES, kf_poses)
            w.add_array(schema.ARRAY_KEYFRAME_IMAGES, kf_images.astype(np.float32))
            if truth is not None:
                w.add_json(schema.SIM_TRUTH, truth)
            obs = w.commit()
    finally:
        vse.stop()
    return CaptureResult(str(obs.path), scale, int(len(points)), list(images))


@dataclass(frozen=True, kw_only=True)
class CapturePlan:
    """Everything a capture needs, checked before anything is created, opened or moved.

    Attributes
    ----------
    driver : str
        Platform driver (``fgcd_cli.app.scenario.DRIVERS``).
    lightings : list of str
        Lightings of the reference images (canonical preset names on the simulator).
    scenario : SimScenario or None
        The simulated world of the station (simulator only).
    T_flange_cam : (4, 4) ndarray
        The campaign's hand-eye.
    camera : PinholeCamera or None
        The campaign's intrinsics (required on hardware).
    rig : EffectiveRig
        Driver, address, baud rate and camera (option, else campaign.toml ``[rig]``, else the default).
    station : str
        The station to capture.
    """

    driver: str
    lightings: list[str]
    scenario: SimScenario | None
    T_flange_cam: np.ndarray
    camera: PinholeCamera | None
    rig: EffectiveRig | None = None
    station: str = ""
    lights: LightsSpec | None = None

    def rig_request(self) -> RigRequest:
        """The rig this capture opens."""
        rig = self.rig or EffectiveRig(driver=self.driver)
        return RigRequest(
            driver=self.driver,
            T_flange_cam=self.T_flange_cam,
            intrinsics=self.camera,
            scenario=self.scenario,
            port=rig.port,
            baud=rig.baud,
            host=rig.host,
            camera_index=rig.camera,
            lights=self.lights,
        )


def rig_lights(campaign, lightings: list[str]) -> LightsSpec | None:
    """The campaign's ``[rig.lights]`` (None when absent), checked to have every lighting asked for.

    Raises
    ------
    CampaignError
        ``[rig.lights]`` is malformed, or a lighting is not one of its channels.
    """
    from fgcd_core.platform import PlatformError
    from fgcd_drivers.lights import AMBIENT, LightsDriver

    try:
        spec = LightsSpec.from_config(campaign.rig_config.get("lights"))
    except PlatformError as exc:
        raise CampaignError(f"campaign.toml {exc}") from None
    if spec is None or not spec.channels:
        return spec
    missing = [n for n in lightings if n != AMBIENT and n not in spec.channels]
    if spec.driver == LightsDriver.SIM:
        # the simulator's world lights (sun, sky, night) are the day's, not channels of the rig
        missing = [n for n in missing if not _is_world_light(n)]
    if missing:
        raise CampaignError(
            f"campaign.toml [rig.lights] wires no light {', '.join(missing)} (channels: {', '.join(spec.channels)})"
        )
    return spec


def _is_world_light(name: str) -> bool:
    """True when ``name`` is one of the simulator's world lights (the sun, the sky, the night), not a rig lamp."""
    from fgcd_drivers.sim.lights import is_rig_lamp, lighting_preset

    try:
        return not is_rig_lamp(lighting_preset(name))
    except ValueError:
        return False


def check_station_can_take_a_reference(campaign, name: str) -> None:
    """Refuse a damaged station or one that already has its (immutable) reference; writes nothing."""
    st = campaign.existing_station(name)  # DataIntegrityError when station.json is damaged
    if st is None:
        return
    if st.reference_path.exists():
        raise ImmutableDataError(
            f"station '{st.name}' already has a reference observation (immutable): "
            "create a new station to capture another reference"
        )


def _image_lightings(text: str, *, sim: bool) -> list[str]:
    """The comma-separated lightings of the reference images (``--light``), checked (simulator: known presets)."""
    names = [x.strip() for x in text.split(",") if x.strip()]
    if not names:
        raise UserInputError("--light names no lighting")
    if sim:
        names = [check_lighting(n, option="--light") for n in names]
    if len(set(names)) != len(names):
        raise UserInputError(f"--light names a lighting twice: {text}")
    return names


@dataclass(frozen=True, kw_only=True)
class CaptureRequest:
    """The options of a capture, as given (``fgcd capture``); :func:`plan_capture` checks them.

    Attributes
    ----------
    station : str
        Station to capture (created if missing).
    rig : RigOptions
        Driver, port, host, baud, camera as given (None: campaign.toml ``[rig]``, else the default;
        :func:`fgcd_cli.app.rig_options.resolve_rig`).
    scene, seed : str, int or None
        The station's simulated world (None: the campaign's ``[rig.sim]``).
    light : str
        Comma-separated lightings of the reference images, e.g. ``ambient,led:3,led:9``; on the
        simulator the first also lights the capture session.
    """

    station: str
    rig: RigOptions = RigOptions()
    scene: str | None = None
    seed: int | None = None
    light: str = "front"


def plan_capture(campaign, request: CaptureRequest) -> CapturePlan:
    """Check every option of a capture, in the order a person fixes them; nothing is written.

    Station (name, damage, existing reference) -> the rig (driver, address; :func:`resolve_rig`) -> world (scene)
    -> the campaign's rig -> lights (and ``[rig.lights]``) -> calibration. The simulated world is the station's:
    ``--scene`` and ``--seed`` override the campaign's default ``[rig.sim]`` for this
    station only, and are recorded in its reference.
    """
    r = request
    check_station_can_take_a_reference(campaign, r.station)
    rig = resolve_rig(campaign, r.rig)
    driver = rig.driver
    names = _image_lightings(r.light, sim=driver == Driver.SIM)
    scenario = None
    if driver == Driver.SIM:
        world = campaign_world(campaign)
        if r.scene is None:
            try:
                check_scene(world["scene"])
            except UserInputError as exc:
                raise CampaignError(
                    f"campaign.toml [rig.sim] names a world this simulator lacks: {exc}; give --scene"
                ) from None
        scenario = check_scenario(
            SimScenario(
                scene=r.scene or world["scene"],
                seed=world["seed"] if r.seed is None else r.seed,
                noise=world["noise"],
                lighting=names[0],
            )
        )
    elif r.scene is not None or r.seed is not None:
        raise UserInputError(f"--scene and --seed choose a simulated world: they need --driver sim, not {driver}")
    check_campaign_rig(campaign, rig, what="a reference")
    lights = rig_lights(campaign, names)
    T_flange_cam, cam = rig_calibration(campaign)
    if T_flange_cam is None:
        raise CampaignError("no hand-eye calibration in the campaign: run `fgcd calibrate hand-eye` first")
    check_record_rig(
        campaign.read_rig(schema.RIG_HANDEYE), rig, name=schema.RIG_HANDEYE, command="fgcd calibrate hand-eye"
    )
    if driver != Driver.SIM and cam is None:
        raise CampaignError("no camera intrinsics in the campaign: run `fgcd calibrate intrinsics -c CAMPAIGN` first")
    return CapturePlan(
        driver=driver,
        lightings=names,
        scenario=scenario,
        T_flange_cam=T_flange_cam,
        camera=cam,
        rig=rig,
        station=r.station,
        lights=lights,
    )


def open_capture(campaign_dir, request: CaptureRequest):
    """Open the campaign in ``campaign_dir`` and plan its capture (``fgcd capture``); nothing is written.

    Parameters
    ----------
    campaign_dir : path-like
        The campaign folder (CampaignError when it is not one).
    request : CaptureRequest

    Returns
    -------
    tuple of (Campaign, CapturePlan)
        The opened campaign and :func:`plan_capture`'s plan, both for :func:`run_capture`.
    """
    from fgcd_cli.campaign.store import open_campaign

    campaign = open_campaign(campaign_dir)
    return campaign, plan_capture(campaign, request)


@dataclass(frozen=True, kw_only=True)
class CaptureOutcome:
    """What a capture wrote (``fgcd capture``'s result)."""

    station: str
    result: CaptureResult
    scene: str | None

    def to_dict(self) -> dict:
        """The JSON object ``fgcd capture --json`` prints."""
        r = self.result
        return {
            "station": self.station,
            "reference": r.observation_path,
            "cloud_points": r.cloud_points,
            "scale": r.scale.scale,
            "images": r.images,
            "scene": self.scene,
        }


def run_capture(campaign, plan: CapturePlan, *, hooks: RigHooks = RigHooks()) -> CaptureOutcome:
    """Open the plan's rig and capture the reference of ``plan.station`` (created if missing).

    Rule: a capture that fails leaves no station behind, and never changes campaign.toml; it holds
    the station's lock (:mod:`fgcd_cli.campaign.lock`) throughout.
    """
    from fgcd_cli.app import rig as rig_uc
    from fgcd_cli.app.scene_uncertainty import station_scene_uncertainty
    from fgcd_cli.campaign.lock import station_lock
    from fgcd_cli.metrics.sim_eval import reference_truth

    run_record.no_writes()
    with station_lock(campaign.path, plan.station, command="capture"), campaign.station_for_writing(plan.station) as st:
        check_station_can_take_a_reference(campaign, plan.station)  # again, under the lock
        rig = rig_uc.open_rig(plan.rig_request(), hooks=hooks)
        run_record.platform_connected(getattr(rig, "platform_name", None) or plan.driver)
        with rig_uc.opened(rig):
            result = capture_reference(
                rig.handles,
                st,
                lightings=plan.lightings,
                metadata={
                    "driver": plan.driver,
                    "rig": (plan.rig or EffectiveRig(driver=plan.driver)).record(),
                    "scenario": rig.info.get("scenario"),
                },
                evaluation=(lambda: reference_truth(rig.sim)) if rig.sim is not None else None,
            )
        # the platform is released; the reference's scene uncertainty map (paper 001), for the report and the
        # coarse stage's looks: guidance only, a reference that cannot give one says why and is kept
        camera = plan.camera if plan.camera is not None else (rig.handles.intrinsics if rig.handles else None)
        if camera is not None:
            station_scene_uncertainty(st, camera, say=hooks.on_event or (lambda _m: None))
    return CaptureOutcome(
        station=plan.station, result=result, scene=plan.scenario.scene if plan.scenario is not None else None
    )


def connection(campaign, driver: str, *, port: str | None, host: str | None) -> tuple[str | None, str | None]:
    """``(port, host)`` of a hardware driver (options first, then campaign.toml [rig]); UserInputError when missing.

    Checked before anything is created or opened, like ``fgcd platform``
    (:func:`fgcd_cli.app.rig_options.resolve_rig` resolves the whole rig).
    """
    rig = resolve_rig(campaign, RigOptions(driver=driver, port=port, host=host))
    return rig.port, rig.host
