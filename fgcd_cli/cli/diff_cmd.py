"""``fgcd diff``: fine-grained change detection between a reference and a current observation."""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path

import typer

from fgcd_cli.cli.output import emit, info
from fgcd_cli.errors import run_record

HELP = "Find fine-grained changes between reference and current images; write maps, regions and a report."


def _render(data: dict):
    from fgcd_cli.app.diff_summary import (
        clipped_line,
        faint_line,
        no_change_lines,
        region_line,
        result_epsilon,
        set_aside_line,
        strongest_first,
        warp_line,
    )

    def render(console):
        if not data["comparable"]:
            reason = data["reason"].removeprefix("cannot compare: ")
            console.print(f"[yellow]cannot compare[/yellow]: {reason}")
        else:
            n = len(data["regions"])
            epsilon = result_epsilon(data)
            if n == 0:
                for line in no_change_lines(data.get("candidates") or [], epsilon=epsilon):
                    console.print(line, markup=False)
            else:
                console.print(
                    f"[bold]{n}[/bold] changed region(s), {data['changed_fraction'] * 100:.2f} % of the compared area; "
                    "strongest first"
                )
            for r in strongest_first(data["regions"])[:10]:
                console.print("  " + region_line(r, epsilon=epsilon))
            set_aside = int((data.get("settings") or {}).get("edge_explained_regions") or 0)
            if set_aside:
                console.print(set_aside_line(n, set_aside), markup=False)
            for line in (faint_line(data), clipped_line(data)):
                if line:
                    console.print(line, markup=False)
            for w in data.get("warnings", []):
                console.print(f"[yellow]warning[/yellow]: {w}")
        if "afd" in data:
            console.print(
                f"AFD {data['afd']['afd_px']:.2f} px ({data['afd']['method']}, {data['afd']['inliers']} vectors)"
            )
        if warp_line(data):
            console.print(warp_line(data), markup=False)
        if data.get("relocation_check"):
            console.print(f"relocation check: {data['relocation_check']}", markup=False)
        if data.get("scores"):
            s = data["scores"]
            console.print(
                f"against ground truth: {s['changes_found']} of {s['changes_true']} change(s) found, "
                f"{s['false_regions']} false region(s); pixels F1 {s['f1']:.3f} (P {s['precision']:.3f}, "
                f"R {s['recall']:.3f}), best F1 {s['best_f1']:.3f}, AP {s['average_precision']:.3f}"
            )
        console.print(f"outputs: {data['output']}")

    return render


@contextmanager
def diff_progress(*, enabled: bool):
    """``(say, tile_progress)`` of a diff: where its lines go, and the tile bar of large frames.

    On a terminal: lines through :func:`info`, and a rich bar that starts at the
    first tile, never before, so a command that fails earlier (bad input, a
    damaged file) prints its one error line and nothing else (a started bar
    leaves an empty line on stderr when it stops). Off a terminal: plain step
    lines with the heartbeat of :func:`fgcd_cli.cli.progress.step_progress`, so
    a long comparison (a 24 MP frame: about a minute) is never silent in a log.
    ``enabled`` False (``--json``): ``(None, None)``.
    """
    from fgcd_cli.cli.output import err_console
    from fgcd_cli.cli.progress import step_progress

    if not enabled:
        yield None, None
        return
    if not err_console.is_terminal:
        with step_progress(enabled=True) as steps:
            yield steps.lines(info), steps
        return
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    bar = None
    task = None

    def update(done: int, total: int, label: str) -> None:
        nonlocal bar, task
        if bar is None:
            bar = Progress(
                TextColumn("{task.description}"),
                BarColumn(),
                TextColumn("{task.completed}/{task.total}"),
                TimeElapsedColumn(),
                transient=True,
                console=Console(stderr=True),
            )
            bar.start()
            task = bar.add_task(label, total=total)
        bar.update(task, completed=done, total=total, description=label)

    try:
        yield info, update
    finally:
        if bar is not None:
            bar.stop()


def diff(
    ref: list[str] | None = typer.Option(
        None, "--ref", help="Reference image(s): repeat, comma-separate or quote a glob; one per lighting."
    ),
    cur: list[str] | None = typer.Option(None, "--cur", help="Current image(s), same lightings in the same order."),
    output: Path | None = typer.Option(None, "-o", "--output", help="Output folder (bare-image mode)."),
    campaign: Path | None = typer.Option(None, "--campaign", "-c", help="Campaign folder (campaign mode)."),
    station: str | None = typer.Option(None, "--station", "-s", help="Station name (campaign mode)."),
    visit: str | None = typer.Option(None, "--visit", help="Visit name (default: latest)."),
    roi: Path | None = typer.Option(
        None,
        "--roi",
        "--eval-mask",
        help="Region of interest: compare only where this mask (reference frame) is "
        "non-zero, e.g. the object without its background. Default: the whole frame.",
    ),
    truth: Path | None = typer.Option(
        None,
        "--truth",
        help="Ground-truth change mask (reference frame; bare or campaign mode): print the changes found, "
        "the false regions and P/R/F1/AP.",
    ),
    score_mask: Path | None = typer.Option(
        None,
        "--score-mask",
        help="With --truth: score only inside this mask (an evaluator's region; the "
        "detector never sees it). Default: the region of interest, else the whole frame.",
    ),
    mm_per_px: float | None = typer.Option(
        None, "--mm-per-px", help="Known scale on the object (mm per pixel) for areas in mm²."
    ),
    no_register: bool = typer.Option(False, "--no-register", help="Images are already aligned: skip registration."),
    no_geometry: bool = typer.Option(
        False,
        "--no-geometry",
        help="Campaign mode: warp the visit by the image registration alone, not by the reference's depth "
        "and the residual pose measured against it.",
    ),
    edge_check: int | None = typer.Option(
        None,
        "--edge-check",
        help="Set aside regions along strong reference edges that a shift of up to this many px "
        "explains (shown in cyan); 0 = off. Default: 2.",
    ),
    min_contrast: float | None = typer.Option(
        None,
        "--min-contrast",
        help="Report only regions whose change reaches this fraction of the surface's brightness under "
        "some lighting (0.2 = 20 %); fainter ones stay candidates. 0 = report all. Default: 0.2.",
    ),
    ambient_index: int | None = typer.Option(
        None,
        "--ambient-index",
        help="Bare images: 0-based index of the ambient-light image (left out of the "
        "photometric stereo that labels regions relief/colour). Campaigns know it from the lighting names.",
    ),
    force: bool = typer.Option(
        False,
        "--force",
        help="Campaign mode: replace the visit's stored diff even when it was made with other "
        "options (without it such a diff is kept and the command refused, exit 5).",
    ),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Find fine-grained changes; writes change_score.png/.npy, change_mask.png, overlay.png, regions.json, report.html.

    Exit status 0 when the images were compared (with or without changes); 6 when
    they cannot be compared honestly (black, textureless, not overlapping): the
    report and regions.json are still written and say why; 2 for bad input
    (every option is checked before anything is read); 5 when the visit already
    holds a diff made with other options and --force is not given.
    """
    from fgcd_cli.app import diff as diff_uc
    from fgcd_cli.errors import UserInputError

    if campaign is not None or station is not None:
        if ref or cur:
            raise UserInputError("give either --campaign/--station or --ref/--cur, not both")
        if campaign is None or station is None:
            raise UserInputError("campaign mode needs both --campaign and --station")
        if score_mask is not None and truth is None:
            raise UserInputError("--score-mask says where --truth is scored: give --truth too")
        request = diff_uc.CampaignDiffRequest(
            campaign=campaign,
            station=station,
            visit=visit,
            roi=roi,
            mm_per_px=mm_per_px,
            register=not no_register,
            output=output,
            edge_check_px=edge_check,
            min_contrast=min_contrast,
            geometry=not no_geometry,
            force=force,
            truth=truth,
            score_mask=score_mask,
        )
        run_record.no_platform()
        where = output or f"visit {visit or '(latest)'} of station '{station}'"
        with (
            run_record.writing(f"the change maps and report in {where}", whole=False),
            diff_progress(enabled=not as_json) as (say, _),
        ):
            data = diff_uc.run_campaign(request, progress=say)
    else:
        if not ref or not cur:
            raise UserInputError("give --ref and --cur images (or --campaign and --station)")
        if output is None:
            raise UserInputError("give an output folder with -o DIR")
        if force:
            raise UserInputError("--force is for campaign mode (a visit's stored diff); bare mode writes to -o DIR")
        if no_geometry:
            raise UserInputError("--no-geometry is for campaign mode: bare images carry no reference depth")
        if score_mask is not None and truth is None:
            raise UserInputError("--score-mask says where --truth is scored: give --truth too")
        request = diff_uc.BareDiffRequest(
            ref=ref,
            cur=cur,
            output=output,
            roi=roi,
            truth=truth,
            score_mask=score_mask,
            mm_per_px=mm_per_px,
            register=not no_register,
            edge_check_px=edge_check,
            min_contrast=min_contrast,
            ambient_index=ambient_index,
        )
        run_record.no_platform()
        with (
            run_record.writing(f"the change maps and report in {output}", whole=False),
            diff_progress(enabled=not as_json) as (say, tile_progress),
        ):
            data = diff_uc.run_bare(request, progress=say, tile_progress=tile_progress)
    emit(data, as_json=as_json, render=_render(data))
    if not data["comparable"]:
        from fgcd_cli.errors import AlgorithmError

        raise typer.Exit(AlgorithmError.exit_code)
