"""`fgcd relocate`: drive the camera back to a station's reference pose and record a visit (parse, call
:mod:`fgcd_cli.app.revisit`, render)."""

from __future__ import annotations

from pathlib import Path

import typer

from fgcd_cli.cli import options as opt
from fgcd_cli.cli.determinism import DETERMINISTIC, deterministic_setup
from fgcd_cli.cli.output import ask_line, confirmer, emit, info


def print_record(rec) -> None:
    """One live line per adjustment."""
    truth = ""
    if rec.truth:
        truth = f"  [dim]true: {rec.truth.get('pose_err_mm', float('nan')):.2f} mm, AFD {rec.truth.get('afd_px', float('nan')):.2f} px[/dim]"
    if rec.image and "step_mm" in rec.image:  # ACR: no metric estimate of the remaining offset
        info(
            f"adjustment {rec.iteration:2d} ({rec.stage})  step {rec.image['step_mm']:6.2f} mm  turn "
            f"{rec.offset_deg:5.2f} deg  measured AFD {rec.afd_est_px:5.2f} px  inliers {rec.image['inliers']}{truth}"
        )
        return
    info(
        f"adjustment {rec.iteration:2d} ({rec.stage})  g = {rec.g:.2e}  remaining {rec.offset_mm:7.2f} mm "
        f"{rec.offset_deg:5.2f} deg  est. AFD {rec.afd_est_px:5.2f} px  cloud {rec.vse_points}{truth}"
    )


def relocate(
    campaign: Path = opt.CAMPAIGN,
    station: str = typer.Option(..., "--station", "-s", help="Station to relocate to."),
    driver: str | None = opt.DRIVER,
    port: str | None = opt.PORT,
    host: str | None = opt.HOST,
    baud: int | None = opt.BAUD,
    camera: str | None = opt.CAMERA,
    light: str = opt.light_option(
        "led:3",
        "Lighting of this visit (sim: `fgcd sim lights`; hardware: the name "
        "of the day's light; the reference's lightings are taken as well).",
    ),
    changes: int = typer.Option(0, "--changes", help="Fine-grained changes to inject (sim)."),
    start_offset_mm: float = typer.Option(30.0, "--start-offset-mm", help="Displaced start, mm (sim)."),
    start_offset_deg: float = typer.Option(3.0, "--start-offset-deg", help="Displaced start, degrees (sim)."),
    session_seed: int = typer.Option(1, "--session-seed", help="Seed of the visit's start and noise (sim)."),
    serial: bool = typer.Option(False, "--serial", help="Single-thread variant (rACR Table 5)."),
    deterministic: bool = DETERMINISTIC,
    no_handeye: bool = typer.Option(
        False, "--no-handeye", help="Guess X = I instead of the calibration (rACR Table 3)."
    ),
    no_image_refine: bool = typer.Option(
        False, "--no-image-refine", help="Skip the image stage and its fallback (pure rACR: 3D alignment only)."
    ),
    no_coarse: bool = typer.Option(
        False,
        "--no-coarse",
        help="Leave out the active coarse stage (paper 001) that first brings a far start "
        "(beyond 10 cm / 8 deg) near the reference; the loop then pauses on such a start.",
    ),
    eta: float = typer.Option(1e-4, "--eta", help="Stop when ||M_B - I|| <= eta."),
    max_adjustments: int | None = typer.Option(
        None, "--max-adjustments", help="Adjustment budget (default: 12 for racr, 30 for acr)."
    ),
    method: str = typer.Option(
        "racr",
        "--method",
        help="racr (3D alignment, paper 000), or the baselines acr "
        "(Tian et al.: 5-point pose, bisection on the scale, hand-eye "
        "taken as identity) and acr-h (its homography-guided step).",
    ),
    guided: bool = typer.Option(
        True,
        "--guided/--no-guided",
        help="rACR: explore toward the image localizer's "
        "estimate of the reference pose (default), or the fixed 3-leg pattern.",
    ),
    resume: bool = typer.Option(
        False,
        "--resume",
        help="Continue the station's interrupted visit from its journal (or start over cleanly), and say which.",
    ),
    yes: bool = opt.YES,
    as_json: bool = opt.JSON,
) -> None:
    """Drive the camera back to a station's reference pose (rACR, or the ACR baseline) and record a visit."""
    deterministic_setup(deterministic)  # before the heavy libraries load
    from fgcd_cli.app.revisit import RevisitRequest, plan_revisit, run_revisit
    from fgcd_cli.app.rig import RigHooks
    from fgcd_cli.app.rig_options import RigOptions
    from fgcd_cli.cli.progress import step_progress

    # no terminal and no --yes: refused first (exit 2); option values (exit 2), then the campaign (exit 3)
    confirm = confirmer(yes=yes)
    plan = plan_revisit(
        campaign,
        RevisitRequest(
            station=station,
            rig=RigOptions(driver=driver, port=port, host=host, baud=baud, camera=camera),
            light=light,
            changes=changes,
            start_offset_mm=start_offset_mm,
            start_offset_deg=start_offset_deg,
            session_seed=session_seed,
            serial=serial,
            deterministic=deterministic,
            no_handeye=no_handeye,
            no_image_refine=no_image_refine,
            no_coarse=no_coarse,
            eta=eta,
            max_adjustments=max_adjustments,
            resume=resume,
            method=method,
            guided=guided,
        ),
    )
    # The steps report through plain callbacks: a live bar on stderr (not with --json), lines above it.
    with step_progress(enabled=not as_json) as bar:
        say, ask = info, ask_line
        if bar is not None:
            bar(0, 0, "opening the rig")
            confirm, say, ask = bar.paused(confirm), bar.lines(info), bar.paused(ask_line)
        outcome = run_revisit(
            plan, hooks=RigHooks(confirm=confirm, ask_light=ask, on_event=say, on_progress=bar), on_record=print_record
        )
    result = outcome.result
    reloc = result.relocation
    emit(
        outcome.to_dict(),
        as_json=as_json,
        render=lambda c: c.print(
            f"{'[green]converged[/green]' if reloc.converged else '[red]not converged[/red]'}: {reloc.reason}; "
            f"{reloc.adjustments} adjustments, {reloc.session_s:.1f} s on the rig ({reloc.wall_s:.1f} s wall). "
            f"Visit written to {result.observation_path}"
        ),
    )
    if not reloc.converged:
        raise typer.Exit(6)
