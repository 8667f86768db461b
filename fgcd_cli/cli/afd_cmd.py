"""``fgcd afd``: feature displacement field and average feature displacement between two images."""

from __future__ import annotations

from pathlib import Path

import typer

from fgcd_cli.cli.output import emit
from fgcd_cli.errors import run_record


def afd(
    ref: Path = typer.Argument(..., help="Reference image."),
    cur: Path = typer.Argument(..., help="Current image (same size)."),
    grid: bool = typer.Option(
        False, "--grid", help="Lighting-robust grid variant (phase correlation of gradient patches)."
    ),
    pairs: Path | None = typer.Option(
        None, "--pairs", help="CSV of point pairs x_ref,y_ref,x_cur,y_cur picked by hand."
    ),
    ratio: float = typer.Option(0.75, "--ratio", help="SIFT ratio test."),
    ransac_px: float = typer.Option(3.0, "--ransac-px", help="RANSAC homography inlier threshold (px)."),
    output: Path | None = typer.Option(None, "-o", "--output", help="Write the FDF quiver figure (PNG) here."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """AFD with the authors' protocol (SIFT, ratio test, RANSAC homography inliers, mean displacement in px)."""
    from fgcd_cli.app.afd import AfdRequest, measure_afd, write_fdf_figure

    request = AfdRequest(ref=ref, cur=cur, grid=grid, pairs=pairs, ratio=ratio, ransac_px=ransac_px)
    run_record.no_platform()
    run_record.no_writes()
    measurement = measure_afd(request)
    result, data = measurement.result, measurement.record
    if output is not None:
        with run_record.writing(output):
            write_fdf_figure(measurement, output)
        data["figure"] = str(output)

    def render(console):
        console.print(
            f"AFD [bold]{result.afd_px:.3f} px[/bold] ({result.method}, {result.inliers} of {result.candidates} kept)"
        )
        console.print("settings: " + ", ".join(f"{k}={v}" for k, v in result.settings.items()))
        if output is not None:
            console.print(f"FDF figure: {output}")

    emit(data, as_json=as_json, render=render)
