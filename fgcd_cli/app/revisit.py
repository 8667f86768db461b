"""The revisit of a campaign station (``fgcd relocate``): plan it from the options, then run it.

:func:`plan_revisit` checks a :class:`RevisitRequest` against the campaign (its
rig, calibration, reference and scenario); :func:`run_revisit` opens the rig
under the station's lock, continues or starts over an interrupted visit
(:mod:`fgcd_cli.app.visit_journal`), and relocates and writes the visit
(:func:`fgcd_cli.app.relocate.relocate_and_capture`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from fgcd_cli.app.capture import CaptureResult
from fgcd_cli.app.relocate import relocate_and_capture
from fgcd_cli.app.relocate_request import RelocateHooks, RelocateRequest
from fgcd_cli.app.rig import RigHooks, RigRequest
from fgcd_cli.app.rig_options import EffectiveRig, RigOptions, check_campaign_rig, check_record_rig, resolve_rig
from fgcd_cli.app.scenario import SimScenario, check_driver, check_lighting, check_method, check_scenario, check_scene
from fgcd_cli.app.session import revisit_lightings, visit_lightings
from fgcd_cli.app.visit_journal import JournalWriter, ResumeDecision, ResumeMode, decide_resume, return_to
from fgcd_cli.calibration.rig_files import rig_calibration
from fgcd_cli.campaign import schema
from fgcd_cli.campaign.records import station_world
from fgcd_cli.errors import CampaignError, UserInputError, run_record
from fgcd_cli.relocation.acr.baseline import AcrConfig
from fgcd_cli.relocation.acr.pose import AcrModel, AcrPoseConfig
from fgcd_cli.relocation.coarse.config import CoarseConfig
from fgcd_cli.relocation.config import RelocationConfig
from fgcd_cli.relocation.enums import LoopMode, RelocationMethod
from fgcd_cli.relocation.log import AdjustmentRecord
from fgcd_drivers.connect import Driver

__all__ = [
    "RevisitOutcome",
    "RevisitPlan",
    "RevisitRequest",
    "check_relocation_options",
    "plan_revisit",
    "run_revisit",
    "visit_scenario",
]


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
    T_flange_cam: np.ndarray | None  # None: the rig opens with the identity
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
            "station": self.station,
            "visit": self.result.observation_path,
            "converged": reloc.converged,
            "reason": reloc.reason,
            "adjustments": reloc.adjustments,
            "wall_s": reloc.wall_s,
            "session_s": reloc.session_s,
            "residual": reloc.residual.to_dict() if reloc.residual else None,
            "final_truth": reloc.records[-1].truth if reloc.records else None,
            "coarse": None
            if coarse is None
            else {
                "handed_over": coarse.handed_over,
                "reason": coarse.reason,
                "actions": [s.action for s in coarse.steps],
            },
            "resume": None if self.resume is None else self.resume.to_dict(),
        }


def check_relocation_options(
    *, changes: int, eta: float, max_adjustments: int | None, start_offset_mm: float, start_offset_deg: float
) -> None:
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


def visit_scenario(
    campaign, reference, *, light: str, changes: int, start_offset_mm: float, start_offset_deg: float, session_seed: int
) -> SimScenario:
    """The simulated session of a visit: the station's own world (see :func:`station_world`), checked."""
    world = station_world(campaign, reference)
    try:
        check_scene(world["scene"])
    except UserInputError as exc:
        raise CampaignError(
            f"the reference of {reference.path} was captured in a world this simulator lacks: {exc}"
        ) from None
    return check_scenario(
        SimScenario(
            scene=world["scene"],
            seed=world["seed"],
            noise=world["noise"],
            lighting=light,
            changes=changes,
            start_offset_mm=start_offset_mm,
            start_offset_deg=start_offset_deg,
            session_seed=session_seed,
        )
    )


def plan_revisit(campaign_path, request: RevisitRequest) -> RevisitPlan:
    """Check every option of a revisit, then the campaign; nothing is written or opened.

    Order: option values (exit 2), then the campaign (exit 3): driver, values, campaign,
    the campaign's driver, light, connection, station and reference, world, calibration.
    """
    from fgcd_cli.app.capture import rig_lights
    from fgcd_cli.campaign.store import open_campaign

    r = request
    if r.rig.driver is not None:
        check_driver(r.rig.driver)
    method = check_method(r.method)
    check_relocation_options(
        changes=r.changes,
        eta=r.eta,
        max_adjustments=r.max_adjustments,
        start_offset_mm=r.start_offset_mm,
        start_offset_deg=r.start_offset_deg,
    )
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
        scenario = visit_scenario(
            camp,
            ref,
            light=light,
            changes=r.changes,
            start_offset_mm=r.start_offset_mm,
            start_offset_deg=r.start_offset_deg,
            session_seed=r.session_seed,
        )
    T_flange_cam, cam = rig_calibration(camp)
    if T_flange_cam is None and not r.no_handeye and method == RelocationMethod.RACR:
        raise CampaignError("no hand-eye calibration in the campaign: calibrate, or use --no-handeye")
    if (
        r.no_handeye or T_flange_cam is None
    ):  # ACR needs none; the rig opens with the identity (rig.hand_eye_or_identity)
        T_flange_cam = None
    else:
        check_record_rig(
            camp.read_rig(schema.RIG_HANDEYE), rig, name=schema.RIG_HANDEYE, command="fgcd calibrate hand-eye"
        )
    config = RelocationConfig(
        mode=LoopMode.SERIAL if r.serial else LoopMode.PARALLEL,
        deterministic=r.deterministic,
        eta=r.eta,
        max_adjustments=r.max_adjustments or RelocationConfig().max_adjustments,
        image_refine=not r.no_image_refine,
        image_fallback=not r.no_image_refine,
    )
    acr = (
        AcrConfig(
            pose=AcrPoseConfig(model=AcrModel(str(method))),
            max_adjustments=r.max_adjustments or AcrConfig().max_adjustments,
        )
        if method != RelocationMethod.RACR
        else None
    )
    # every reference lighting a wired rig is asked for must be one of its channels (sim: the world's light is not)
    lights = rig_lights(camp, visit_lightings(light, ref.metadata.get("lightings", []), available=[]))
    return RevisitPlan(
        request=replace(r, light=light),
        driver=driver,
        station=st,
        reference=ref,
        scenario=scenario,
        T_flange_cam=T_flange_cam,
        camera=cam,
        config=config,
        rig=rig,
        lights=lights,
        method=method,
        acr=acr,
    )


def run_revisit(
    plan: RevisitPlan, *, hooks: RigHooks = RigHooks(), on_record: Callable[[AdjustmentRecord], None] | None = None
) -> RevisitOutcome:
    """Open the plan's rig, relocate to the station's reference and write the visit (under the station's lock)."""
    from fgcd_cli.campaign.lock import station_lock

    with station_lock(plan.station.path.parents[1], plan.request.station, command="relocate"):
        return _revisit_locked(plan, hooks=hooks, on_record=on_record)


def _revisit_locked(
    plan: RevisitPlan, *, hooks: RigHooks, on_record: Callable[[AdjustmentRecord], None] | None
) -> RevisitOutcome:
    """:func:`run_revisit` under the station's lock."""
    from fgcd_cli.app import rig as rig_uc
    from fgcd_cli.metrics.sim_eval import RelocationEvaluator

    r = plan.request
    options = {"driver": plan.driver, "light": r.light}
    decision = decide_resume(plan.station, resume=r.resume, options=options)
    run_record.no_writes()
    where = plan.rig or EffectiveRig(driver=plan.driver)
    rig = rig_uc.open_rig(
        RigRequest(
            driver=plan.driver,
            T_flange_cam=plan.T_flange_cam,
            intrinsics=plan.camera,
            scenario=plan.scenario,
            port=where.port,
            baud=where.baud,
            host=where.host,
            camera_index=where.camera,
            lights=plan.lights,
        ),
        hooks=hooks,
    )
    run_record.platform_connected(getattr(rig, "platform_name", None) or plan.driver)
    with rig_uc.opened(rig):
        say = getattr(rig.handles, "say", None) or (lambda text: None)  # stand-in rigs may lack it
        say(decision.reason)
        journal = JournalWriter(plan.station, options=options, decision=decision)
        if decision.mode == ResumeMode.CONTINUED:
            say(
                f"back to where the interrupted visit stopped "
                f"({return_to(rig.handles.guard, decision.T_base_flange)} guarded steps)"
            )
        evaluator = RelocationEvaluator.from_reference(rig.sim, plan.reference) if rig.sim is not None else None
        request = RelocateRequest(
            config=plan.config,
            lightings=revisit_lightings(rig.handles, r.light, plan.reference),
            metadata={
                "driver": plan.driver,
                "scenario": rig.info.get("scenario"),
                "no_handeye": r.no_handeye,
                "resume": decision.to_dict(),
            },
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

        result = relocate_and_capture(
            rig.handles,
            plan.station,
            request=request,
            hooks=RelocateHooks(
                evaluate=evaluator.evaluate if evaluator else None,
                on_record=record,
                evaluation=evaluator.summary if evaluator else None,
            ),
        )
        journal.remove()
    return RevisitOutcome(station=r.station, result=result, resume=decision)
