"""`fgcd capture`: the reference of a station (parse, call :mod:`fgcd_cli.app.capture`, render)."""

from __future__ import annotations

from pathlib import Path

import typer

from fgcd_cli.cli import options as opt
from fgcd_cli.cli.output import ask_line, confirmer, emit, info


def capture(
    campaign: Path = opt.CAMPAIGN,
    station: str = typer.Option(..., "--station", "-s", help="Station to capture (created if missing)."),
    driver: str | None = opt.DRIVER,
    port: str | None = opt.PORT,
    host: str | None = opt.HOST,
    baud: int | None = opt.BAUD,
    camera: str | None = opt.CAMERA,
    scene: str | None = opt.SCENE,
    seed: int = typer.Option(
        None,
        "--seed",
        help="Simulator world seed of this station (default: the campaign's; "
        "the seed the hand-eye was calibrated with).",
    ),
    light: str = opt.light_option(
        "front",
        "Lightings of the reference images, comma-separated, e.g. "
        "ambient,led:3,led:9 (`fgcd sim lights`; the first lights the simulated capture; "
        "hardware: channels of [rig.lights]).",
    ),
    yes: bool = opt.YES,
    as_json: bool = opt.JSON,
) -> None:
    """Capture the reference observation of a station (immutable once written).

    Every option is checked before anything is written; a capture that fails
    leaves no station behind, and never changes campaign.toml.
    """
    from fgcd_cli.app.capture import CaptureRequest, open_capture, run_capture
    from fgcd_cli.app.rig import RigHooks
    from fgcd_cli.app.rig_options import RigOptions
    from fgcd_cli.cli.progress import step_progress

    # Rule: a motion that needs confirming without a terminal is refused before anything is created.
    confirm = confirmer(yes=yes)
    rig = RigOptions(driver=driver, port=port, host=host, baud=baud, camera=camera)
    camp, plan = open_capture(campaign, CaptureRequest(station=station, rig=rig, scene=scene, seed=seed, light=light))
    with step_progress(enabled=not as_json) as progress:
        say, ask = info, ask_line
        if progress is not None:
            progress(0, 0, "opening the rig")
            confirm, say, ask = progress.paused(confirm), progress.lines(info), progress.paused(ask_line)
        outcome = run_capture(
            camp, plan, hooks=RigHooks(confirm=confirm, ask_light=ask, on_event=say, on_progress=progress)
        )
    result = outcome.result
    emit(
        outcome.to_dict(),
        as_json=as_json,
        render=lambda c: c.print(
            f"Reference of [bold]{station}[/bold] written to {result.observation_path} "
            f"({result.cloud_points} cloud points, scale {result.scale.scale:.4f} m/unit, images: {', '.join(result.images)})"
        ),
    )
