"""`fgcd calibrate board|intrinsics|hand-eye`."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import typer
from rich.table import Table

from fgcd_cli.cli import options as opt
from fgcd_cli.cli.output import confirmer, emit, info
from fgcd_cli.errors import run_record

app = typer.Typer(
    help="Calibrate the rig: ChArUco board, camera intrinsics, hand-eye and map scale.", no_args_is_help=True
)

JSON_OPT = typer.Option(False, "--json", help="Print one JSON object instead of text.")


BOARD_FILE = typer.Option(None, "--board", help="Board sidecar JSON written by `fgcd calibrate board`.")
SQX = typer.Option(10, "--squares-x", help="Squares along the board's width.")
SQY = typer.Option(7, "--squares-y", help="Squares along the board's height.")
SQMM = typer.Option(None, "--square-mm", help="Side of one square in mm (measure the print).")
MKMM = typer.Option(None, "--marker-mm", help="Side of one marker in mm (default 72 % of the square).")
DICT = typer.Option("DICT_5X5_100", "--dictionary", help="ArUco dictionary.")


def _board(board_file, squares_x, squares_y, square_mm, marker_mm, dictionary):
    from fgcd_cli.app.intrinsics import BoardOptions

    return BoardOptions(
        board_file=board_file,
        squares_x=squares_x,
        squares_y=squares_y,
        square_mm=square_mm,
        marker_mm=marker_mm,
        dictionary=dictionary,
    )


@app.command("board")
def board_cmd(
    output: Path = typer.Option(..., "--output", "-o", help="Board file to write: .png or .pdf (true size)."),
    squares_x: int = SQX,
    squares_y: int = SQY,
    square_mm: float | None = SQMM,
    marker_mm: float | None = MKMM,
    dictionary: str = DICT,
    dpi: int = typer.Option(300, "--dpi", help="Print resolution."),
    as_json: bool = JSON_OPT,
) -> None:
    """Write a printable ChArUco board and its exact geometry (<output>.json)."""
    from fgcd_cli.app.intrinsics import write_board

    board, sidecar = write_board(_board(None, squares_x, squares_y, square_mm, marker_mm, dictionary), output, dpi=dpi)
    data = {"board_file": str(output), "sidecar": str(output) + ".json", **sidecar}
    emit(
        data,
        as_json=as_json,
        render=lambda c: c.print(
            f"Wrote {output} ({sidecar['page_mm'][0]:.0f} x {sidecar['page_mm'][1]:.0f} mm, "
            f"{board.squares_x}x{board.squares_y} squares of {board.square_m * 1000:.1f} mm) and {output}.json\n"
            + sidecar["instructions"]
        ),
    )


@app.command("intrinsics")
def intrinsics_cmd(
    images: Path | None = typer.Option(None, "--images", help="Folder of board photographs."),
    sim: bool = typer.Option(False, "--sim", help="Use views of a board rendered by the simulator."),
    sim_views: int = typer.Option(20, "--sim-views", help="Number of simulated views."),
    seed: int | None = typer.Option(
        None,
        "--seed",
        help="Simulated rig whose camera is calibrated (--sim): same "
        "seed as `calibrate hand-eye --seed` (default: the campaign's [rig.sim] seed, "
        "else 0).",
    ),
    board_file: Path | None = BOARD_FILE,
    squares_x: int = SQX,
    squares_y: int = SQY,
    square_mm: float | None = SQMM,
    marker_mm: float | None = MKMM,
    dictionary: str = DICT,
    distortion: str = typer.Option("k1k2p1p2", "--distortion", help="none, k1k2, k1k2p1p2 or k1k2p1p2k3."),
    campaign: Path | None = typer.Option(None, "--campaign", "-c", help="Store the result in this campaign's rig."),
    as_json: bool = JSON_OPT,
) -> None:
    """Calibrate the camera from views of a ChArUco board."""
    from fgcd_cli.app.intrinsics import IntrinsicsRequest, plan_intrinsics, run_intrinsics, store_intrinsics
    from fgcd_cli.cli.progress import step_progress

    plan = plan_intrinsics(
        IntrinsicsRequest(
            images=images,
            sim=sim,
            sim_views=sim_views,
            seed=seed,
            distortion=distortion,
            campaign=campaign,
            board=_board(board_file, squares_x, squares_y, square_mm, marker_mm, dictionary),
        )
    )
    with step_progress(enabled=not as_json) as bar:
        result = run_intrinsics(plan, on_progress=bar)
    data = store_intrinsics(plan, result)

    def render(console):
        cam = result.camera
        console.print(
            f"fx {cam.fx:.2f} ± {result.std_px['fx']:.2f}  fy {cam.fy:.2f} ± {result.std_px['fy']:.2f}  "
            f"cx {cam.cx:.2f}  cy {cam.cy:.2f} px   dist {', '.join(f'{d:.4f}' for d in cam.dist)}"
        )
        console.print(
            f"RMS reprojection error {result.rms_px:.3f} px over {result.n_views} views ({result.n_corners} corners), "
            f"coverage {result.coverage_pct:.0f} %, largest tilt {result.max_tilt_deg:.0f} deg"
        )
        table = Table("view", "error px")
        for name, err in result.per_view_error_px.items():
            table.add_row(name, f"{err:.3f}")
        for name, why in result.rejected.items():
            table.add_row(name, f"[red]rejected[/red]: {why}")
        console.print(table)
        for line in result.feedback:
            console.print(f"[yellow]hint:[/yellow] {line}")
        if "stored" in data:
            console.print(f"stored in {data['stored']}")

    emit(data, as_json=as_json, render=render)


def _render_handeye(console, data: dict) -> None:
    from fgcd_cli.app.calibrate import handeye_rotation_deg

    X = np.array(data["T_flange_cam"])
    rv = handeye_rotation_deg(X)
    console.print(
        f"T_flange_cam: t = ({', '.join(f'{v * 1000:.1f}' for v in X[:3, 3])}) mm, "
        f"rotation vector = ({', '.join(f'{v:.2f}' for v in rv)}) deg   \\[{data['method']}]"
    )
    if data.get("scale") is not None:
        console.print(f"map scale s = {data['scale']:.5f} m per VSE unit")
    ref = data.get("refinement") or {}
    if ref:
        views = f"{ref['views']} views, " if ref.get("views") else ""
        console.print(
            f"image refinement: {views}{ref['points']} points, {ref['rms_px']:.2f} px RMS, X +- {ref['std_mm']:.1f} mm / "
            f"{ref['std_deg']:.3f} deg (1 sigma), moved {ref['change_mm']:.1f} mm / {ref['change_deg']:.2f} deg "
            f"from the linear solve; scale from {ref.get('scale_method', '?')}"
        )
        s_rot, s_std = ref.get("platform_rotation_scale"), ref.get("platform_rotation_scale_std")
        if s_rot is not None and s_std is not None and math.isfinite(s_std):
            console.print(f"platform rotations: {s_rot:.5f} x the reported ones (+- {s_std:.5f}), estimated with X")
    console.print(
        f"{data['n_samples']} samples, {data['n_pairs']} motion pairs, residual RMS {data['rms_mm']:.2f} mm / "
        f"{data['rms_deg']:.3f} deg, rotation-axis spread {data['axis_spread_deg']:.0f} deg"
    )
    table = Table("sample", "mean residual mm", "deg")
    for i, (mm, deg) in enumerate(zip(data["sample_residuals_mm"], data["sample_residuals_deg"])):
        table.add_row(str(i), f"{mm:.2f}", f"{deg:.3f}")
    console.print(table)
    if "methods" in data:
        mt = Table("solver", "RMS mm", "RMS deg")
        for name, m in data["methods"].items():
            mt.add_row(
                name + (" (chosen)" if name == data["method"] else ""), f"{m['rms_mm']:.2f}", f"{m['rms_deg']:.3f}"
            )
        console.print(mt)
        console.print(f"solvers agree within {data['agreement_mm']:.2f} mm / {data['agreement_deg']:.3f} deg")
    for note in data.get("notes", []):
        console.print(f"[yellow]note:[/yellow] {note}")
    if "stored" in data:
        console.print(f"stored in {data['stored']}")


def _run_handeye(handles, *, request, say, bar):
    """The hand-eye use case on an opened rig (:class:`fgcd_cli.app.calibrate.HandEyeCalibration`)."""
    from fgcd_cli.app.calibrate import HandEyeMode, run_handeye

    if request.mode == HandEyeMode.TARGET_FREE and say is not None:
        say("target-free hand-eye: the platform makes small motions while the VSE tracks…")
    return run_handeye(handles, request, say=say, on_progress=bar)


@app.command("hand-eye")
def handeye_cmd(
    mode: str = typer.Option("target-free", "--mode", help="target (ChArUco board) or target-free (VSE, rACR)."),
    campaign: Path | None = typer.Option(
        None,
        "--campaign",
        "-c",
        help="Campaign: its rig, its intrinsics; the result is stored in its rig/ (only a hand-eye of that rig).",
    ),
    driver: str | None = opt.DRIVER,
    port: str | None = opt.PORT,
    host: str | None = opt.HOST,
    baud: int | None = opt.BAUD,
    camera: str | None = opt.CAMERA,
    scene: str | None = opt.SCENE,
    seed: int | None = typer.Option(
        None, "--seed", help="Simulated rig seed (default: the campaign's [rig.sim] seed, else 0)."
    ),
    translation_mm: float = typer.Option(30.0, "--translation-mm", help="Exploration translation (target-free)."),
    rotation_deg: float = typer.Option(8.0, "--rotation-deg", help="Rotation about each axis (target: default 15)."),
    board_file: Path | None = BOARD_FILE,
    accept_residual: bool = typer.Option(
        False,
        "--accept-residual",
        help="Store a hand-eye whose residuals are "
        "beyond the limits (docs/calibration.md); refused with exit 6 otherwise.",
    ),
    yes: bool = opt.YES,
    as_json: bool = JSON_OPT,
) -> None:
    """Hand-eye T_flange_cam (and the map scale, target-free) from commanded platform motions."""
    from fgcd_cli.app.calibrate import (
        HandEyeMode,
        HandEyeRequest,
        check_handeye_options,
        plan_handeye,
        store_handeye,
    )
    from fgcd_cli.app.rig import RigHooks, RigRequest, open_rig, opened
    from fgcd_cli.app.rig_options import RigOptions, calibration_campaign
    from fgcd_cli.cli.progress import step_progress
    from fgcd_cli.errors import AlgorithmError

    # no terminal and no --yes: refused first (exit 2), before anything is opened or moved
    confirm = confirmer(yes=yes)
    check_handeye_options(mode=mode, translation_mm=translation_mm, rotation_deg=rotation_deg)
    camp = calibration_campaign(campaign)
    plan = plan_handeye(
        camp,
        RigOptions(driver=driver, port=port, host=host, baud=baud, camera=camera),
        HandEyeRequest(
            mode=HandEyeMode(mode), translation_mm=translation_mm, rotation_deg=rotation_deg, board_file=board_file
        ),
        scene=scene,
        seed=seed,
    )
    if plan.intrinsics is None and not as_json:
        info(
            "warning: no calibrated intrinsics (-c CAMPAIGN): using the simulated camera's nominal ones; a focal "
            "length 1 % off puts the hand-eye centimetres off (docs/calibration.md, §2)"
        )
    rig_of = plan.rig
    run_record.no_writes()
    with step_progress(enabled=not as_json) as bar:
        if bar is not None:
            bar(0, 0, "opening the rig")
            confirm = bar.paused(confirm)
        rig = open_rig(
            RigRequest(
                driver=rig_of.driver,
                intrinsics=plan.intrinsics.camera if plan.intrinsics else None,
                scenario=plan.scenario,
                port=rig_of.port,
                baud=rig_of.baud,
                host=rig_of.host,
                camera_index=rig_of.camera,
            ),
            hooks=RigHooks(confirm=confirm),
        )
        run_record.platform_connected(rig.platform_name or rig_of.driver)
        with opened(rig):
            calibration = _run_handeye(rig.handles, request=plan.request, say=None if as_json else info, bar=bar)
    data = {**calibration.record, "mode": mode, "driver": rig_of.driver, "rig": rig_of.record()}
    if camp is None:
        stored, unusable = store_handeye(None, plan, calibration)
    else:
        with run_record.writing(camp.rig_path("handeye")):
            stored, unusable = store_handeye(camp, plan, calibration, accept_residual=accept_residual)
    if stored is not None:
        data["stored"] = stored
    if unusable is not None:
        data["usable"] = False
        data.setdefault("notes", []).append(f"not usable: {unusable}")
    emit(data, as_json=as_json, render=lambda c: _render_handeye(c, data))
    if unusable is not None and stored is None:
        kept = "nothing stored" if camp is not None else "not stored (no -c)"
        raise AlgorithmError(
            f'{unusable}: {kept}; calibrate again (docs/calibration.md, "When a result is '
            f'refused"), or store it anyway with --accept-residual'
        )
