"""The revisit use case: drive the camera back to a station's reference pose (rACR) and write a visit.

``relocate_and_capture``: on a revisit, start a new session, explore a little,
re-estimate the scale, align to the reference and drive the camera back with
the rACR loop (after the active coarse stage on a far start, :mod:`fgcd_cli.app.coarse_start`),
then write a visit (images, cloud, relocation log).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from fgcd_cli.app.capture import CaptureResult
from fgcd_cli.app.coarse_start import CoarseStart, maybe_coarse
from fgcd_cli.app.determinism import deterministic_rig, run_conditions
from fgcd_cli.app.guided_start import start_revisit_session
from fgcd_cli.app.rig import RigHandles, RigHooks, RigRequest
from fgcd_cli.app.rig_options import EffectiveRig, RigOptions, check_campaign_rig, check_record_rig, resolve_rig
from fgcd_cli.app.scenario import (Driver, SimScenario, check_driver, check_lighting, check_method, check_scenario,
                                   check_scene)
from fgcd_cli.app.visit_journal import JournalWriter, ResumeDecision, ResumeMode, decide_resume, return_to
from fgcd_cli.app.session import (
    grab_gray_under,
    grab_images,
    load_reference,
    measurement_lighting,
    reference_images,
)
from fgcd_cli.campaign import schema
from fgcd_cli.campaign.records import rig_calibration, station_world
from fgcd_cli.errors import AlgorithmError, CampaignError, UserInputError, run_record
from fgcd_cli.relocation.coarse_config import CoarseConfig, CoarseResult
from fgcd_cli.relocation.config import ReferenceData, RelocationConfig
from fgcd_cli.relocation.acr import AcrConfig
from fgcd_cli.relocation.acr_pose import AcrModel, AcrPoseConfig
from fgcd_cli.relocation.enums import LoopMode, RelocationMethod
from fgcd_cli.relocation.log import AdjustmentRecord, RelocationResult
from fgcd_cli.relocation.loop import LoopContext, relocate

__all__ = ["RelocateHooks", "RelocateRequest", "RevisitOutcome", "RevisitPlan", "RevisitRequest", "check_method",
           "check_relocation_options",
           "load_reference", "plan_revisit", "reference_images", "relocate_and_capture", "run_revisit", "visit_lightings",
           "visit_scenario"]


@dataclass(frozen=True, kw_only=True)
class RelocateRequest:
    """How to relocate to a station's reference and what the visit records.

    Attributes
    ----------
    config : RelocationConfig
        The rACR loop's options.
    lightings : list of str
        Lightings of the visit's images.
    explore_m : float
        Exploration amplitude of the session start, metres.
    explore_legs : int
        Exploration legs of the session start.
    metadata : dict or None
        Extra entries of the visit's manifest metadata.
    guided : bool
        Explore toward the image localizer's estimate of the reference (:mod:`fgcd_cli.app.guided_start`).
    coarse : CoarseConfig or None
        The active coarse stage's options (paper 001); None leaves it out (the
        loop then pauses on a far start).
    earlier_log : tuple of dict
        Adjustments of an interrupted visit this one continues, written first in its log.
    method : RelocationMethod
        rACR, or the ACR baseline (``acr``, ``acr-h``: :mod:`fgcd_cli.app.relocate_acr`).
    acr : AcrConfig or None
        The ACR loop's options (None: its defaults, the model following ``method``).
    """

    config: RelocationConfig
    lightings: list[str]
    explore_m: float = 0.04
    explore_legs: int = 3
    guided: bool = True
    metadata: dict | None = None
    coarse: CoarseConfig | None = field(default_factory=CoarseConfig)
    earlier_log: tuple[dict, ...] = ()
    method: RelocationMethod = RelocationMethod.RACR
    acr: AcrConfig | None = None


@dataclass(frozen=True, kw_only=True)
class RelocateHooks:
    """Callbacks of a relocation: evaluation (simulator only) and each adjustment as it is made.

    Attributes
    ----------
    evaluate : callable() -> dict, or None
        The simulator's truth at the current pose, logged beside each estimate.
    on_record : callable(AdjustmentRecord), or None
        Each adjustment of the loop.
    evaluation : callable() -> dict, or None
        The truth written into the visit (``evaluation/sim_truth.json``).
    reference_override : callable(ReferenceData) -> ReferenceData, or None
        A benchmark's change of the reference cloud before rACR sees it (paper 000 Fig. 4:
        noise on the reference points); the stored reference is never changed.
    """

    evaluate: Callable[[], dict] | None = None
    on_record: Callable[[AdjustmentRecord], None] | None = None
    evaluation: Callable[[], dict] | None = None
    reference_override: Callable[[ReferenceData], ReferenceData] | None = None


def relocate_and_capture(rig: RigHandles, station, request: RelocateRequest, *,
                         hooks: RelocateHooks | None = None) -> CaptureResult:
    """Relocate to the station's reference pose with rACR, then write a visit.

    When the first estimate puts the camera farther than ``coarse.trigger_*`` from the
    reference pose, the active coarse stage (:mod:`fgcd_cli.relocation.coarse`, paper 001)
    runs first; ``coarse=None`` leaves it out (the loop then pauses on such a start).
    """
    hooks = hooks or RelocateHooks()
    if request.method != RelocationMethod.RACR:
        from fgcd_cli.app.relocate_acr import acr_relocate_and_capture

        return acr_relocate_and_capture(rig, station, request, hooks=hooks)
    from fgcd_cli.alignment import ReferenceIndex

    reference = load_reference(station)
    if hooks.reference_override is not None:
        reference = hooks.reference_override(reference)
    ref_index = ReferenceIndex(reference.points, intensities=reference.intensities,
                               view=(reference.T_ref_camref, rig.intrinsics))
    rig.progress(0, 0, "starting the VSE")
    session, vse, scale, prior_sigma_mm = start_revisit_session(
        deterministic_rig(rig, request.config.deterministic), station, reference, explore_m=request.explore_m,
        legs=request.explore_legs, guided=request.guided, ref_index=ref_index)
    try:
        start = CoarseStart(rig=rig, session=session, reference=reference, ref_index=ref_index, station=station,
                            scale=scale.scale, scale_rel_std=scale.scale_std / scale.scale,
                            evaluate=hooks.evaluate)
        init, coarse_result = _initial_alignment(start, request.coarse)
        ref_images, same_light = _measurement_images(rig, station)
        rig.say(f"relocating ({request.config.loop_name}) to the reference of station '{station.name}'")
        rig.progress(0, 0, "relocating")
        try:
            result = relocate(LoopContext(
                session=session, reference=reference, ref_index=ref_index, camera=rig.intrinsics,
                scale=scale.scale, T_flange_cam=rig.T_flange_cam, init=init, config=request.config,
                evaluate=hooks.evaluate, on_record=hooks.on_record, reference_images=ref_images,
                grab_current=lambda: grab_gray_under(rig, vse, same_light),
                # the camera stands at the image localizer's reference only when nothing moved it since
                image_prior_sigma_mm=prior_sigma_mm if coarse_result is None else None,
            ))
        except AlgorithmError as exc:
            # the loop paused: what the coarse stage did before stays available to the caller
            exc.coarse_result = coarse_result
            raise
        rig.progress(0, 0, "settling at the reached pose")
        state = session.settle(frames=2)
        points = np.asarray(state.cloud.points, dtype=float) * scale.scale
        images = grab_images(rig, request.lightings)
        meta = _visit_metadata(rig, request, scale, result, coarse_result)
        rig.progress(0, 0, "writing the visit")
        log = "".join([json.dumps(e) + "\n" for e in request.earlier_log] + [r.to_json() + "\n" for r in result.records])
        obs = _write_visit(station, meta, images=images, points=points, state=state, log=log.encode("utf-8"),
                           coarse_result=coarse_result, evaluation=hooks.evaluation)
    finally:
        vse.stop()
    return CaptureResult(str(obs.path), scale, int(len(points)), list(images), relocation=result,
                         coarse=coarse_result)


def _initial_alignment(start: CoarseStart, coarse: CoarseConfig | None) -> tuple[np.ndarray, CoarseResult | None]:
    """The alignment the rACR loop starts from, and the coarse stage's result when it ran.

    The first camera is near the reference camera; checked by a fast alignment of the
    whole current cloud, with the global multi-start registration as fallback.
    """
    from fgcd_cli.alignment import initial_guess

    rig, scale = start.rig, start.scale
    rig.progress(0, 0, "initial alignment to the reference")
    first = start.session.tracking_state()
    T_cur_cam0 = np.array(first.T_map_cam, dtype=float)
    T_cur_cam0[:3, 3] *= scale
    guess = initial_guess(T_ref_camref=start.reference.T_ref_camref, T_cur_cam0=T_cur_cam0,
                          cur_points=np.asarray(first.cloud.points, dtype=float) * scale,
                          reference=start.ref_index, scale=1.0)
    init = guess.T_ref_cur
    rig.say(f"initial alignment: {guess.source}"
            + (f" ({guess.fast.health.reason})" if guess.fast is not None else ""))
    if coarse is None:
        return init, None
    first_trusted = guess.fast is not None and guess.fast.health.ok
    coarse_result, init = maybe_coarse(start, init, coarse, first_trusted=first_trusted)
    return init, coarse_result


def _measurement_images(rig: RigHandles, station) -> tuple[dict[str, np.ndarray], str | None]:
    """The reference images the image stage compares with, and the light it measures under (None: the day's)."""
    ref_images = reference_images(station)
    same_light = measurement_lighting(rig, list(ref_images))
    if same_light is not None:
        # like with like: the image stage compares with the reference image of that light only
        ref_images = {same_light: ref_images[same_light]}
        rig.say(f"the image stage measures under the reference's light ({same_light})")
    return ref_images, same_light


def _visit_metadata(rig: RigHandles, request: RelocateRequest, scale, result: RelocationResult,
                    coarse_result: CoarseResult | None) -> dict:
    """The visit manifest's metadata: lightings, scale, the relocation's outcome and the rig's calibration."""
    return {
        "lightings": request.lightings,
        "scale": scale.__dict__,
        "relocation": {
            "converged": result.converged,
            "reason": result.reason,
            "adjustments": result.adjustments,
            "wall_s": result.wall_s,
            "session_s": result.session_s,
            "platform_s": result.platform_s,
            "synthetic_s": result.synthetic_s,
            "mode": request.config.mode, "run": run_conditions(request.config, request.metadata),
            "residual": result.residual.to_dict() if result.residual else None,
        },
        "coarse": None if coarse_result is None else {
            "handed_over": coarse_result.handed_over, "reason": coarse_result.reason,
            "steps": len(coarse_result.steps),
        },
        "T_flange_cam": np.asarray(rig.T_flange_cam).tolist(),
        "T_base_flange": np.asarray(rig.guard.platform.flange_pose()).tolist(),
        "intrinsics": rig.intrinsics.to_dict(),
        **(request.metadata or {}),
    }


def _write_visit(station, meta: dict, *, images: dict[str, np.ndarray], points: np.ndarray, state,
                 log: bytes, coarse_result: CoarseResult | None,
                 evaluation: Callable[[], dict] | None):
    """Write the visit (images, cloud, relocation and coarse logs, truth) and return the committed observation."""
    stamp_writer = station.new_visit(meta)
    with run_record.writing(f"the visit of station '{station.name}'"), stamp_writer as w:
        for name, img in images.items():
            w.add_image(name, img)
        w.add_cloud(points, colors=np.asarray(state.cloud.intensities, dtype=np.float32))
        w.add_bytes(schema.RELOCATION_LOG, log)
        if coarse_result is not None and coarse_result.steps:
            w.add_bytes(schema.COARSE_LOG, "".join(json.dumps(st.to_dict(), default=float) + "\n"
                                                   for st in coarse_result.steps).encode("utf-8"))
        if evaluation is not None:
            w.add_json(schema.SIM_TRUTH, evaluation())
        return w.commit()


# ----------------------------------------------------------------------------- the revisit of a campaign station
@dataclass(frozen=True, kw_only=True)
class RevisitRequest:
    """The options of a revisit, as given (``fgcd relocate``); :func:`plan_revisit` checks them.

    Attributes
    ----------
    station : str
    rig : RigOptions
        Driver, port, host, baud, camera as given (None: campaign.toml ``[rig]``, else the default;
        :func:`fgcd_cli.app.rig_options.resolve_rig`).
    light : str
        Lighting of the visit (simulator).
    changes : int
        Fine-grained changes injected (simulator).
    start_offset_mm, start_offset_deg : float
        Displaced start (simulator), millimetres and degrees.
    session_seed : int
        Seed of the visit's start and noise (simulator).
    serial, deterministic : bool
        The single-thread loop (rACR Table 5); the loop's threads stepped in a fixed order (same seeds, same visit).
    no_handeye : bool
        X = I instead of the calibration (rACR Table 3).
    no_image_refine : bool
        Skip the image stage and its fallback (pure rACR).
    no_coarse : bool
        Leave out the active coarse stage.
    eta : float
        Stop when ``||M_B - I|| <= eta``.
    max_adjustments : int or None
        None: the method's own budget (12 for rACR, 30 for ACR).
    method : str
        ``racr``, ``acr`` or ``acr-h`` (:class:`RelocationMethod`).
    guided : bool
        rACR: explore toward the image localizer's estimate of the reference.
    resume : bool
        Continue an interrupted visit from its journal, or start over cleanly
        (:mod:`fgcd_cli.app.visit_journal`).
    """

    station: str
    rig: RigOptions = RigOptions()
    light: str = "led:3"
    changes: int = 0
    start_offset_mm: float = 30.0
    start_offset_deg: float = 3.0
    session_seed: int = 1
    serial: bool = False
    deterministic: bool = False
    no_handeye: bool = False
    no_image_refine: bool = False
    no_coarse: bool = False
    eta: float = 1e-4
    max_adjustments: int | None = None
    resume: bool = False
    method: str = RelocationMethod.RACR
    guided: bool = True


@dataclass(frozen=True, kw_only=True)
class RevisitPlan:
    """Everything a revisit needs, checked before the rig is opened."""

    request: RevisitRequest
    driver: str
    station: object
    reference: object
    scenario: SimScenario | None
    T_flange_cam: np.ndarray
    camera: object
    config: RelocationConfig
    rig: EffectiveRig | None = None  # driver, address, baud, camera (fgcd_cli.app.rig_options.resolve_rig)
    lights: object | None = None  # fgcd_drivers.lights.LightsSpec of campaign.toml [rig.lights]
    method: RelocationMethod = RelocationMethod.RACR
    acr: AcrConfig | None = None


@dataclass(frozen=True, kw_only=True)
class RevisitOutcome:
    """What a revisit did and wrote (``fgcd relocate``'s result)."""

    station: str
    result: CaptureResult
    resume: ResumeDecision | None = None

    @property
    def converged(self) -> bool:
        """True when the rACR loop met its stop rule."""
        return self.result.relocation.converged

    def to_dict(self) -> dict:
        """The JSON object ``fgcd relocate --json`` prints."""
        reloc, coarse = self.result.relocation, self.result.coarse
        return {
            "station": self.station, "visit": self.result.observation_path, "converged": reloc.converged,
            "reason": reloc.reason, "adjustments": reloc.adjustments, "wall_s": reloc.wall_s,
            "session_s": reloc.session_s, "residual": reloc.residual.to_dict() if reloc.residual else None,
            "final_truth": reloc.records[-1].truth if reloc.records else None,
            "coarse": None if coarse is None else {"handed_over": coarse.handed_over, "reason": coarse.reason,
                                                   "actions": [s.action for s in coarse.steps]},
            "resume": None if self.resume is None else self.resume.to_dict(),
        }


def check_relocation_options(*, changes: int, eta: float, max_adjustments: int | None, start_offset_mm: float,
                             start_offset_deg: float) -> None:
    """Refuse out-of-range relocation options up front (UserInputError naming the valid range)."""
    if changes < 0:
        raise UserInputError(f"--changes must be 0 or more, got {changes}")
    if not (math.isfinite(eta) and eta > 0):
        raise UserInputError(f"--eta must be a number > 0, got {eta}")
    if max_adjustments is not None and max_adjustments < 1:
        raise UserInputError(f"--max-adjustments must be 1 or more, got {max_adjustments}")
    for option, value in (("--start-offset-mm", start_offset_mm), ("--start-offset-deg", start_offset_deg)):
        if not (math.isfinite(value) and value >= 0):
            raise UserInputError(f"{option} must be a number >= 0, got {value}")


def visit_scenario(campaign, reference, *, light: str, changes: int, start_offset_mm: float, start_offset_deg: float,
                   session_seed: int) -> SimScenario:
    """The simulated session of a visit: the station's own world (see :func:`station_world`), checked."""
    world = station_world(campaign, reference)
    try:
        check_scene(world["scene"])
    except UserInputError as exc:
        raise CampaignError(f"the reference of {reference.path} was captured in a world this simulator lacks: {exc}") \
            from None
    return check_scenario(SimScenario(scene=world["scene"], seed=world["seed"], noise=world["noise"], lighting=light,
                                      changes=changes, start_offset_mm=start_offset_mm,
                                      start_offset_deg=start_offset_deg, session_seed=session_seed))


def visit_lightings(visit_light: str, reference_lightings: list[str], *, controllable: bool) -> list[str]:
    """Images of a visit: under the day's light, and under the reference's lightings when the rig controls its lights."""
    names = [visit_light]
    if controllable:
        names += [n for n in reference_lightings if n not in names]
    return names


def plan_revisit(campaign_path, request: RevisitRequest) -> RevisitPlan:
    """Check every option of a revisit, then the campaign; nothing is written or opened.

    Order: option values (exit 2), then the campaign (exit 3): driver, values, campaign,
    the campaign's driver, light, connection, station and reference, world, calibration.
    """
    from fgcd_cli.app.capture import rig_lights
    from fgcd_cli.campaign import open_campaign

    r = request
    if r.rig.driver is not None:
        check_driver(r.rig.driver)
    method = check_method(r.method)
    check_relocation_options(changes=r.changes, eta=r.eta, max_adjustments=r.max_adjustments,
                             start_offset_mm=r.start_offset_mm, start_offset_deg=r.start_offset_deg)
    camp = open_campaign(campaign_path)
    rig = resolve_rig(camp, r.rig)  # the driver, then its address
    driver = rig.driver
    light = check_lighting(r.light) if driver == Driver.SIM else r.light
    check_campaign_rig(camp, rig, what="a visit")
    st = camp.station(r.station)
    ref = st.reference()
    for relpath in ref.files():  # Rule: a damaged reference is refused before anything is opened or moved
        ref.bytes(relpath)  # DataIntegrityError (exit 4) naming the damaged file
    scenario = None
    if driver == Driver.SIM:
        scenario = visit_scenario(camp, ref, light=light, changes=r.changes, start_offset_mm=r.start_offset_mm,
                                  start_offset_deg=r.start_offset_deg, session_seed=r.session_seed)
    T_flange_cam, cam = rig_calibration(camp)
    if T_flange_cam is None and not r.no_handeye and method == RelocationMethod.RACR:
        raise CampaignError("no hand-eye calibration in the campaign: calibrate, or use --no-handeye")
    if r.no_handeye or T_flange_cam is None:  # ACR needs none: it takes the identity
        T_flange_cam = np.eye(4)
    else:
        check_record_rig(camp.read_rig(schema.RIG_HANDEYE), rig, name=schema.RIG_HANDEYE,
                         command="fgcd calibrate hand-eye")
    config = RelocationConfig(mode=LoopMode.SERIAL if r.serial else LoopMode.PARALLEL, deterministic=r.deterministic,
                              eta=r.eta, max_adjustments=r.max_adjustments or RelocationConfig().max_adjustments,
                              image_refine=not r.no_image_refine, image_fallback=not r.no_image_refine)
    acr = AcrConfig(pose=AcrPoseConfig(model=AcrModel(str(method))), max_adjustments=r.max_adjustments
                    or AcrConfig().max_adjustments) if method != RelocationMethod.RACR else None
    lights = rig_lights(camp, visit_lightings(light, ref.metadata.get("lightings", []), controllable=True))
    return RevisitPlan(request=replace(r, light=light), driver=driver, station=st, reference=ref, scenario=scenario,
                       T_flange_cam=T_flange_cam, camera=cam, config=config, rig=rig, lights=lights,
                       method=method, acr=acr)


def run_revisit(plan: RevisitPlan, *, hooks: RigHooks = RigHooks(),
                on_record: Callable[[AdjustmentRecord], None] | None = None) -> RevisitOutcome:
    """Open the plan's rig, relocate to the station's reference and write the visit (under the station's lock)."""
    from fgcd_cli.campaign.lock import station_lock

    with station_lock(plan.station.path.parents[1], plan.request.station, command="relocate"):
        return _revisit_locked(plan, hooks=hooks, on_record=on_record)


def _revisit_locked(plan: RevisitPlan, *, hooks: RigHooks,
                    on_record: Callable[[AdjustmentRecord], None] | None) -> RevisitOutcome:
    """:func:`run_revisit` under the station's lock."""
    from fgcd_cli.app import rig as rig_uc
    from fgcd_cli.metrics.sim_eval import RelocationEvaluator

    r = plan.request
    options = {"driver": plan.driver, "light": r.light}
    decision = decide_resume(plan.station, resume=r.resume, options=options)
    run_record.no_writes()
    where = plan.rig or EffectiveRig(driver=plan.driver)
    rig = rig_uc.open_rig(RigRequest(driver=plan.driver, T_flange_cam=plan.T_flange_cam, intrinsics=plan.camera,
                                     scenario=plan.scenario, port=where.port, baud=where.baud, host=where.host,
                                     camera_index=where.camera, lights=plan.lights),
                          hooks=hooks)
    run_record.platform_connected(getattr(rig, "platform_name", None) or plan.driver)
    with rig_uc.opened(rig):
        say = getattr(rig.handles, "say", None) or (lambda text: None)  # stand-in rigs may lack it
        say(decision.reason)
        journal = JournalWriter(plan.station, options=options, decision=decision)
        if decision.mode == ResumeMode.CONTINUED:
            say(f"back to where the interrupted visit stopped "
                f"({return_to(rig.handles.guard, decision.T_base_flange)} guarded steps)")
        evaluator = RelocationEvaluator.from_reference(rig.sim, plan.reference) if rig.sim is not None else None
        request = RelocateRequest(
            config=plan.config,
            lightings=visit_lightings(r.light, plan.reference.metadata.get("lightings", []),
                                      controllable=getattr(rig.handles, "lights", None) is not None),
            metadata={"driver": plan.driver, "scenario": rig.info.get("scenario"), "no_handeye": r.no_handeye,
                      "resume": decision.to_dict()},
            coarse=None if r.no_coarse else CoarseConfig(),
            earlier_log=tuple(decision.records),
            method=plan.method,
            acr=plan.acr,
            guided=r.guided,
        )

        def record(rec: AdjustmentRecord) -> None:
            journal.record(rec, rig.handles.guard.platform.flange_pose())
            if on_record is not None:
                on_record(rec)

        result = relocate_and_capture(rig.handles, plan.station, request=request, hooks=RelocateHooks(
            evaluate=evaluator.evaluate if evaluator else None, on_record=record,
            evaluation=evaluator.summary if evaluator else None))
        journal.remove()
    return RevisitOutcome(station=r.station, result=result, resume=decision)
