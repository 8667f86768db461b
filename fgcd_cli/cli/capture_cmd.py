"""`fgcd capture` and `fgcd relocate`: the field commands."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import typer

from fgcd_cli.campaign import open_campaign
from fgcd_cli.cli.output import emit, info
from fgcd_cli.errors import CampaignError, UserInputError
from fgcd_cli.geometry.camera import PinholeCamera


def _confirm_factory(yes: bool):
    if yes:
        return None

    def confirm(text: str) -> bool:
        return typer.confirm(text, default=False)

    return confirm


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


def sim_scenario_from_campaign(campaign, **overrides):
    """The simulated world recorded in campaign.toml ``[rig.sim]``, with overrides."""
    from fgcd_cli.rigs import SimScenario

    sim = dict(campaign.rig_config.get("sim", {}))
    base = {"scene": sim.get("scene", "stele"), "seed": int(sim.get("seed", 0)), "noise": sim.get("noise", "default")}
    base.update({k: v for k, v in overrides.items() if v is not None})
    return SimScenario(**base)


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


def capture(
    campaign: Path = typer.Option(..., "--campaign", "-c", help="Campaign directory."),
    station: str = typer.Option(..., "--station", "-s", help="Station to capture (created if missing)."),
    driver: str = typer.Option(None, "--driver", help="sim, grbl, ur or manual (default: the campaign's)."),
    scene: str = typer.Option(None, "--scene", help="Simulator scene (sim driver)."),
    seed: int = typer.Option(None, "--seed", help="Simulator world seed (sim driver)."),
    light: str = typer.Option("front", "--light", help="Lighting of the capture (sim)."),
    lightings: str = typer.Option(None, "--lightings", help="Comma-separated lightings for the reference images (default: --light)."),
    port: str = typer.Option(None, "--port", help="Serial port (grbl)."),
    host: str = typer.Option(None, "--host", help="Robot address (ur)."),
    yes: bool = typer.Option(False, "--yes", help="Answer the first-motion confirmation (scripts)."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Capture the reference observation of a station (immutable once written)."""
    from fgcd_cli.metrics.sim_eval import reference_truth
    from fgcd_cli.relocation.capture import capture_reference
    from fgcd_cli.rigs import open_rig

    camp = open_campaign(campaign)
    driver = driver or camp.rig_config.get("driver", "sim")
    st = camp.station_or_create(station)
    if st.has_reference():
        from fgcd_cli.errors import ImmutableDataError

        raise ImmutableDataError(f"station '{station}' already has a reference observation (immutable)")
    T_flange_cam, cam = rig_calibration(camp)
    if T_flange_cam is None:
        raise CampaignError("no hand-eye calibration in the campaign: run `fgcd calibrate hand-eye` first")
    scenario = None
    if driver == "sim":
        sim_cfg = dict(camp.rig_config.get("sim", {}))
        if scene is not None or seed is not None or not sim_cfg:
            sim_cfg.update({"scene": scene or sim_cfg.get("scene", "stele"), "seed": seed if seed is not None else sim_cfg.get("seed", 0)})
            camp.update_config("rig", {"sim": sim_cfg})
        scenario = sim_scenario_from_campaign(camp, lighting=light)
    names = [x.strip() for x in (lightings or light).split(",") if x.strip()]
    rig = open_rig(driver=driver, T_flange_cam=T_flange_cam, intrinsics=cam, scenario=scenario, port=port or camp.rig_config.get("port"), host=host or camp.rig_config.get("host"),
                   confirm=_confirm_factory(yes), on_event=info)
    try:
        result = capture_reference(
            rig.handles, st, lightings=names, metadata={"driver": driver, "scenario": rig.info.get("scenario")},
            evaluation=reference_truth(rig.sim) if rig.sim is not None else None,
        )
    finally:
        rig.close()
    data = {"station": station, "reference": result.observation_path, "cloud_points": result.cloud_points,
            "scale": result.scale.scale, "images": result.images}
    emit(data, as_json=as_json, render=lambda c: c.print(
        f"Reference of [bold]{station}[/bold] written to {result.observation_path} "
        f"({result.cloud_points} cloud points, scale {result.scale.scale:.4f} m/unit, images: {', '.join(result.images)})"))


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
    from fgcd_cli.rigs import open_rig

    camp = open_campaign(campaign)
    driver = driver or camp.rig_config.get("driver", "sim")
    st = camp.station(station)
    ref = st.reference()
    T_flange_cam, cam = rig_calibration(camp)
    if T_flange_cam is None and not no_handeye:
        raise CampaignError("no hand-eye calibration in the campaign: calibrate, or use --no-handeye")
    if no_handeye:
        T_flange_cam = np.eye(4)
    scenario = None
    if driver == "sim":
        scenario = sim_scenario_from_campaign(camp, lighting=light, changes=changes, start_offset_mm=start_offset_mm,
                                              start_offset_deg=start_offset_deg, session_seed=session_seed)
    config = RelocationConfig(mode="serial" if serial else "parallel", eta=eta, max_adjustments=max_adjustments,
                              image_refine=not no_image_refine, image_fallback=not no_image_refine)
    rig = open_rig(driver=driver, T_flange_cam=T_flange_cam, intrinsics=cam, scenario=scenario, port=port or camp.rig_config.get("port"), host=host or camp.rig_config.get("host"),
                   confirm=_confirm_factory(yes), on_event=info)
    evaluator = RelocationEvaluator.from_reference(rig.sim, ref) if rig.sim is not None else None
    try:
        result = relocate_and_capture(
            rig.handles, st, config=config, lightings=visit_lightings(light, ref.metadata.get("lightings", []), controllable=driver == "sim"),
            metadata={"driver": driver, "scenario": rig.info.get("scenario"), "no_handeye": no_handeye},
            evaluate=evaluator.evaluate if evaluator else None, on_record=print_record,
            evaluation=evaluator.summary if evaluator else None,
            coarse=None if no_coarse else CoarseConfig(),
        )
    finally:
        rig.close()
    reloc = result.relocation
    coarse = result.coarse
    data = {
        "station": station, "visit": result.observation_path, "converged": reloc.converged, "reason": reloc.reason,
        "adjustments": reloc.adjustments, "wall_s": reloc.wall_s, "session_s": reloc.session_s,
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
