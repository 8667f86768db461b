"""`fgcd capture` and `fgcd relocate`: the field commands."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import typer

from fgcd_cli.campaign import open_campaign
from fgcd_cli.cli.output import confirmer, emit, info
from fgcd_cli.errors import CampaignError, UserInputError, run_record
from fgcd_cli.geometry.camera import PinholeCamera

if TYPE_CHECKING:
    from fgcd_cli.rigs import SimScenario


def rig_calibration(campaign) -> tuple[np.ndarray | None, PinholeCamera | None]:
    """Hand-eye and intrinsics stored in the campaign rig (None when absent)."""
    he = campaign.read_rig("handeye")
    intr = campaign.read_rig("intrinsics")
    T = None
    if he is not None:
        if "T_flange_cam" not in he:
            raise CampaignError("rig/handeye.json has no T_flange_cam: calibrate again")
        T = np.array(he["T_flange_cam"], dtype=float)
    cam = None
    if intr is not None:
        data = intr.get("camera", intr)
        try:
            cam = PinholeCamera.from_dict(data)
        except (KeyError, TypeError, ValueError):
            raise CampaignError("rig/intrinsics.json is not a camera model: calibrate again") from None
    return T, cam


def campaign_world(campaign) -> dict:
    """The campaign's default simulated world (``[rig.sim]`` of campaign.toml), never written by a capture."""
    sim = campaign.rig_config.get("sim", {})
    sim = sim if isinstance(sim, dict) else {}
    return {"scene": str(sim.get("scene", "stele")), "seed": _int_or(sim.get("seed"), 0),
            "noise": str(sim.get("noise", "default"))}


def station_world(campaign, reference) -> dict:
    """The simulated world a station's reference was captured in.

    Rule: the world belongs to the station. Its reference records the scene,
    seed and noise it was captured in; the campaign's ``[rig.sim]`` is only the
    default for references that do not say (written before the rule).
    """
    world = campaign_world(campaign)
    recorded = reference.metadata.get("scenario")
    if isinstance(recorded, dict):
        world.update({k: recorded[k] for k in ("scene", "seed", "noise") if recorded.get(k) is not None})
    return world


def _int_or(value, default: int) -> int:
    try:
        return int(value)
    except (TypeError, ValueError):
        return default


def visit_lightings(visit_light: str, reference_lightings: list[str], *, controllable: bool) -> list[str]:
    """Images of a visit: under the day's light, and under the reference's lightings when the rig controls its lights."""
    names = [visit_light]
    if controllable:
        names += [n for n in reference_lightings if n not in names]
    return names


def print_record(rec) -> None:
    """One live line per adjustment."""
    truth = ""
    if rec.truth:
        truth = f"  [dim]true: {rec.truth.get('pose_err_mm', float('nan')):.2f} mm, AFD {rec.truth.get('afd_px', float('nan')):.2f} px[/dim]"
    info(
        f"adjustment {rec.iteration:2d} ({rec.stage})  g = {rec.g:.2e}  remaining {rec.offset_mm:7.2f} mm "
        f"{rec.offset_deg:5.2f} deg  est. AFD {rec.afd_est_px:5.2f} px  cloud {rec.vse_points}{truth}"
    )


@dataclass(frozen=True, kw_only=True)
class CapturePlan:
    """Everything a capture needs, checked before anything is created, opened or moved.

    Attributes
    ----------
    driver : str
        Platform driver (``fgcd_cli.rigs.DRIVERS``).
    lightings : list of str
        Lightings of the reference images (canonical preset names on the simulator).
    scenario : SimScenario or None
        The simulated world of the station (simulator only).
    T_flange_cam : (4, 4) ndarray
        The campaign's hand-eye.
    camera : PinholeCamera or None
        The campaign's intrinsics (required on hardware).
    port, host : str or None
        Address of a GRBL stage / UR arm (option, else campaign.toml ``[rig]``).
    """

    driver: str
    lightings: list[str]
    scenario: SimScenario | None
    T_flange_cam: np.ndarray
    camera: PinholeCamera | None
    port: str | None = None
    host: str | None = None


def check_station_can_take_a_reference(campaign, name: str) -> None:
    """Refuse a damaged station or one that already has its (immutable) reference; writes nothing."""
    from fgcd_cli.errors import ImmutableDataError

    st = campaign.existing_station(name)  # DataIntegrityError when station.json is damaged
    if st is None:
        return
    if st.reference_path.exists():
        raise ImmutableDataError(f"station '{st.name}' already has a reference observation (immutable): "
                                 "create a new station to capture another reference")


def _image_lightings(text: str, *, sim: bool) -> list[str]:
    """The comma-separated lightings of the reference images, checked (simulator: known presets)."""
    from fgcd_cli.rigs import check_lighting

    names = [x.strip() for x in text.split(",") if x.strip()]
    if not names:
        raise UserInputError("--lightings names no lighting")
    if sim:
        names = [check_lighting(n, option="--lightings") for n in names]
    if len(set(names)) != len(names):
        raise UserInputError(f"--lightings names a lighting twice: {text}")
    return names


def plan_capture(campaign, *, station: str, driver: str | None, scene: str | None, seed: int | None, light: str,
                 lightings: str | None, port: str | None = None, host: str | None = None) -> CapturePlan:
    """Check every option of a capture, in the order a person fixes them; nothing is written.

    Station (name, damage, existing reference) -> driver -> world (scene)
    -> the driver's address -> lights -> calibration. The simulated world is the station's: ``--scene``
    and ``--seed`` override the campaign's default ``[rig.sim]`` for this
    station only, and are recorded in its reference.
    """
    from fgcd_cli.rigs import SimScenario, check_driver, check_scenario, check_scene

    check_station_can_take_a_reference(campaign, station)
    driver = check_driver(driver or campaign.rig_config.get("driver", "sim"))
    scenario = None
    if driver == "sim":
        world = campaign_world(campaign)
        if scene is None:
            try:
                check_scene(world["scene"])
            except UserInputError as exc:
                raise CampaignError(f"campaign.toml [rig.sim] names a world this simulator lacks: {exc}; "
                                    "give --scene") from None
        scenario = check_scenario(SimScenario(scene=scene or world["scene"], seed=world["seed"] if seed is None else seed,
                                              noise=world["noise"], lighting=light))
    elif scene is not None or seed is not None:
        raise UserInputError(f"--scene and --seed choose a simulated world: they need --driver sim, not {driver}")
    port, host = connection(campaign, driver, port=port, host=host)
    names = _image_lightings(lightings or light, sim=driver == "sim")
    T_flange_cam, cam = rig_calibration(campaign)
    if T_flange_cam is None:
        raise CampaignError("no hand-eye calibration in the campaign: run `fgcd calibrate hand-eye` first")
    if driver != "sim" and cam is None:
        raise CampaignError("no camera intrinsics in the campaign: run `fgcd calibrate intrinsics -c CAMPAIGN` first")
    return CapturePlan(driver=driver, lightings=names, scenario=scenario, T_flange_cam=T_flange_cam, camera=cam,
                       port=port, host=host)


def capture(
    campaign: Path = typer.Option(..., "--campaign", "-c", help="Campaign directory."),
    station: str = typer.Option(..., "--station", "-s", help="Station to capture (created if missing)."),
    driver: str = typer.Option(None, "--driver", help="sim, grbl, ur or manual (default: the campaign's)."),
    scene: str = typer.Option(None, "--scene", help="Simulator scene of this station (default: the campaign's "
                                                     "[rig.sim] scene; `fgcd sim scenes`)."),
    seed: int = typer.Option(None, "--seed", help="Simulator world seed of this station (default: the campaign's; "
                                                   "the seed the hand-eye was calibrated with)."),
    light: str = typer.Option("front", "--light", help="Lighting of the capture (sim; `fgcd sim lights`)."),
    lightings: str = typer.Option(None, "--lightings", help="Comma-separated lightings for the reference images (default: --light)."),
    port: str = typer.Option(None, "--port", help="Serial port (grbl)."),
    host: str = typer.Option(None, "--host", help="Robot address (ur)."),
    yes: bool = typer.Option(False, "--yes", help="Answer the first-motion confirmation (scripts)."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Capture the reference observation of a station (immutable once written).

    Every option is checked before anything is written; a capture that fails
    leaves no station behind, and never changes campaign.toml.
    """
    from fgcd_cli.cli.progress import step_progress
    from fgcd_cli.metrics.sim_eval import reference_truth
    from fgcd_cli.relocation.capture import capture_reference
    from fgcd_cli.rigs import open_rig, opened

    # Rule: a motion that needs confirming without a terminal is refused before anything is created.
    confirm = confirmer(yes=yes)
    camp = open_campaign(campaign)
    plan = plan_capture(camp, station=station, driver=driver, scene=scene, seed=seed, light=light, lightings=lightings,
                        port=port, host=host)
    run_record.no_writes()
    with step_progress(enabled=not as_json) as progress, camp.station_for_writing(station) as st:
        say = info
        if progress is not None:
            progress(0, 0, "opening the rig")
            confirm, say = progress.paused(confirm), progress.lines(info)
        rig = open_rig(driver=plan.driver, T_flange_cam=plan.T_flange_cam, intrinsics=plan.camera,
                       scenario=plan.scenario, port=plan.port, host=plan.host, confirm=confirm, on_event=say,
                       on_progress=progress)
        run_record.platform_connected(getattr(rig, "platform_name", None) or plan.driver)
        with opened(rig):
            result = capture_reference(
                rig.handles, st, lightings=plan.lightings,
                metadata={"driver": plan.driver, "scenario": rig.info.get("scenario")},
                evaluation=reference_truth(rig.sim) if rig.sim is not None else None,
            )
    data = {"station": station, "reference": result.observation_path, "cloud_points": result.cloud_points,
            "scale": result.scale.scale, "images": result.images,
            "scene": plan.scenario.scene if plan.scenario is not None else None}
    emit(data, as_json=as_json, render=lambda c: c.print(
        f"Reference of [bold]{station}[/bold] written to {result.observation_path} "
        f"({result.cloud_points} cloud points, scale {result.scale.scale:.4f} m/unit, images: {', '.join(result.images)})"))


def connection(campaign, driver: str, *, port: str | None, host: str | None) -> tuple[str | None, str | None]:
    """``(port, host)`` of a hardware driver (options first, then campaign.toml [rig]); UserInputError when missing.

    Checked before anything is created or opened, like ``fgcd platform``.
    """
    from fgcd_cli.rigs import check_connection

    port = port or campaign.rig_config.get("port")
    host = host or campaign.rig_config.get("host")
    check_connection(driver, port=port, host=host)
    return port, host


def check_relocation_options(*, changes: int, eta: float, max_adjustments: int, start_offset_mm: float,
                             start_offset_deg: float) -> None:
    """Refuse out-of-range relocation options up front (UserInputError naming the valid range)."""
    if changes < 0:
        raise UserInputError(f"--changes must be 0 or more, got {changes}")
    if not (math.isfinite(eta) and eta > 0):
        raise UserInputError(f"--eta must be a number > 0, got {eta}")
    if max_adjustments < 1:
        raise UserInputError(f"--max-adjustments must be 1 or more, got {max_adjustments}")
    for option, value in (("--start-offset-mm", start_offset_mm), ("--start-offset-deg", start_offset_deg)):
        if not (math.isfinite(value) and value >= 0):
            raise UserInputError(f"{option} must be a number >= 0, got {value}")


def visit_scenario(campaign, reference, *, light: str, changes: int, start_offset_mm: float, start_offset_deg: float,
                   session_seed: int):
    """The simulated session of a visit: the station's own world (see :func:`station_world`), checked."""
    from fgcd_cli.rigs import SimScenario, check_scenario, check_scene

    world = station_world(campaign, reference)
    try:
        check_scene(world["scene"])
    except UserInputError as exc:
        raise CampaignError(f"the reference of {reference.path} was captured in a world this simulator lacks: {exc}") \
            from None
    return check_scenario(SimScenario(scene=world["scene"], seed=world["seed"], noise=world["noise"], lighting=light,
                                      changes=changes, start_offset_mm=start_offset_mm,
                                      start_offset_deg=start_offset_deg, session_seed=session_seed))


def relocate(
    campaign: Path = typer.Option(..., "--campaign", "-c", help="Campaign directory."),
    station: str = typer.Option(..., "--station", "-s", help="Station to relocate to."),
    driver: str = typer.Option(None, "--driver", help="sim, grbl, ur or manual (default: the campaign's)."),
    light: str = typer.Option("led:3", "--light", help="Lighting of this visit (sim)."),
    changes: int = typer.Option(0, "--changes", help="Fine-grained changes to inject (sim)."),
    start_offset_mm: float = typer.Option(30.0, "--start-offset-mm", help="Displaced start, mm (sim)."),
    start_offset_deg: float = typer.Option(3.0, "--start-offset-deg", help="Displaced start, degrees (sim)."),
    session_seed: int = typer.Option(1, "--session-seed", help="Seed of the visit's start and noise (sim)."),
    serial: bool = typer.Option(False, "--serial", help="Single-thread variant (rACR Table 5)."),
    no_handeye: bool = typer.Option(False, "--no-handeye", help="Guess X = I instead of the calibration (rACR Table 3)."),
    no_image_refine: bool = typer.Option(False, "--no-image-refine",
                                         help="Skip the image stage and its fallback (pure rACR: 3D alignment only)."),
    no_coarse: bool = typer.Option(False, "--no-coarse",
                                   help="Leave out the active coarse stage (paper 001) that first brings a far start "
                                        "(beyond 10 cm / 8 deg) near the reference; the loop then pauses on such a start."),
    eta: float = typer.Option(1e-4, "--eta", help="Stop when ||M_B - I|| <= eta."),
    max_adjustments: int = typer.Option(12, "--max-adjustments"),
    port: str = typer.Option(None, "--port"),
    host: str = typer.Option(None, "--host"),
    yes: bool = typer.Option(False, "--yes", help="Answer the first-motion confirmation (scripts)."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Drive the camera back to a station's reference pose (rACR) and record a visit."""
    from fgcd_cli.metrics.sim_eval import RelocationEvaluator
    from fgcd_cli.relocation.capture import relocate_and_capture
    from fgcd_cli.relocation.coarse import CoarseConfig
    from fgcd_cli.relocation.loop import RelocationConfig
    from fgcd_cli.cli.progress import step_progress
    from fgcd_cli.rigs import check_driver, check_lighting, open_rig, opened

    # no terminal and no --yes: refused first (exit 2); option values (exit 2), then the campaign (exit 3)
    confirm = confirmer(yes=yes)
    driver = check_driver(driver) if driver is not None else None
    check_relocation_options(changes=changes, eta=eta, max_adjustments=max_adjustments,
                             start_offset_mm=start_offset_mm, start_offset_deg=start_offset_deg)
    camp = open_campaign(campaign)
    driver = check_driver(driver or camp.rig_config.get("driver", "sim"))
    if driver == "sim":
        light = check_lighting(light)
    port, host = connection(camp, driver, port=port, host=host)
    st = camp.station(station)
    ref = st.reference()
    scenario = None
    if driver == "sim":
        scenario = visit_scenario(camp, ref, light=light, changes=changes, start_offset_mm=start_offset_mm,
                                  start_offset_deg=start_offset_deg, session_seed=session_seed)
    T_flange_cam, cam = rig_calibration(camp)
    if T_flange_cam is None and not no_handeye:
        raise CampaignError("no hand-eye calibration in the campaign: calibrate, or use --no-handeye")
    if no_handeye:
        T_flange_cam = np.eye(4)
    config = RelocationConfig(mode="serial" if serial else "parallel", eta=eta, max_adjustments=max_adjustments,
                              image_refine=not no_image_refine, image_fallback=not no_image_refine)
    run_record.no_writes()
    # The steps report through plain callbacks: a live bar on stderr (not with --json), lines above it.
    with step_progress(enabled=not as_json) as bar:
        say = info
        if bar is not None:
            bar(0, 0, "opening the rig")
            confirm, say = bar.paused(confirm), bar.lines(info)
        rig = open_rig(driver=driver, T_flange_cam=T_flange_cam, intrinsics=cam, scenario=scenario, port=port,
                       host=host, confirm=confirm, on_event=say, on_progress=bar)
        run_record.platform_connected(getattr(rig, "platform_name", None) or driver)
        with opened(rig):
            evaluator = RelocationEvaluator.from_reference(rig.sim, ref) if rig.sim is not None else None
            result = relocate_and_capture(
                rig.handles, st, config=config,
                lightings=visit_lightings(light, ref.metadata.get("lightings", []), controllable=driver == "sim"),
                metadata={"driver": driver, "scenario": rig.info.get("scenario"), "no_handeye": no_handeye},
                evaluate=evaluator.evaluate if evaluator else None, on_record=print_record,
                evaluation=evaluator.summary if evaluator else None,
                coarse=None if no_coarse else CoarseConfig(),
            )
    reloc = result.relocation
    coarse = result.coarse
    data = {
        "station": station, "visit": result.observation_path, "converged": reloc.converged, "reason": reloc.reason,
        "adjustments": reloc.adjustments, "wall_s": reloc.wall_s, "session_s": reloc.session_s,
        "residual": reloc.residual.to_dict() if reloc.residual else None,
        "final_truth": reloc.records[-1].truth if reloc.records else None,
        "coarse": None if coarse is None else {"handed_over": coarse.handed_over, "reason": coarse.reason,
                                               "actions": [s.action for s in coarse.steps]},
    }
    emit(data, as_json=as_json, render=lambda c: c.print(
        f"{'[green]converged[/green]' if reloc.converged else '[red]not converged[/red]'}: {reloc.reason}; "
        f"{reloc.adjustments} adjustments, {reloc.session_s:.1f} s on the rig ({reloc.wall_s:.1f} s wall). "
        f"Visit written to {result.observation_path}"))
    if not reloc.converged:
        raise typer.Exit(6)
