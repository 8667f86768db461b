"""``fgcd afd``: feature displacement field and average feature displacement between two images."""

from __future__ import annotations

from pathlib import Path

import typer

from fgcd_cli.cli.output import emit
from fgcd_cli.errors import run_record


def afd(
    ref: Path = typer.Argument(..., help="Reference image."),
    cur: Path = typer.Argument(..., help="Current image (same size)."),
    grid: bool = typer.Option(False, "--grid", help="Lighting-robust grid variant (phase correlation of gradient patches)."),
    pairs: Path | None = typer.Option(None, "--pairs", help="CSV of point pairs x_ref,y_ref,x_cur,y_cur picked by hand."),
    ratio: float = typer.Option(0.75, "--ratio", help="SIFT ratio test."),
    ransac_px: float = typer.Option(3.0, "--ransac-px", help="RANSAC homography inlier threshold (px)."),
    output: Path | None = typer.Option(None, "-o", "--output", help="Write the FDF quiver figure (PNG) here."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """AFD with the authors' protocol (SIFT, ratio test, RANSAC homography inliers, mean displacement in px)."""
    from fgcd_cli.campaign.atomic import atomic_write_bytes
    from fgcd_cli.changes.io import read_image
    from fgcd_cli.errors import UserInputError
    from fgcd_cli.metrics.afd import FdfConfig, compute_fdf, read_pairs_csv
    from fgcd_cli.report.figures import fdf_quiver_png

    if grid and pairs is not None:
        raise UserInputError("give either --grid or --pairs, not both")
    run_record.no_platform()
    run_record.no_writes()
    ref_image, cur_image = read_image(ref), read_image(cur)
    if pairs is not None:
        result = compute_fdf(ref_image, cur_image, config=FdfConfig(method="pairs"), pairs=read_pairs_csv(pairs))
    else:
        result = compute_fdf(ref_image, cur_image,
                             config=FdfConfig(method="grid" if grid else "sift", ratio=ratio, ransac_px=ransac_px))
    data = result.as_dict()
    data["reference"], data["current"] = str(ref), str(cur)
    if output is not None:
        with run_record.writing(output):
            atomic_write_bytes(output, fdf_quiver_png(ref_image, result.points_ref, result.points_cur,
                                                      afd_px=result.afd_px, inliers=result.inliers, method=result.method))
        data["figure"] = str(output)

    def render(console):
        console.print(f"AFD [bold]{result.afd_px:.3f} px[/bold] ({result.method}, {result.inliers} of {result.candidates} kept)")
        console.print("settings: " + ", ".join(f"{k}={v}" for k, v in result.settings.items()))
        if output is not None:
            console.print(f"FDF figure: {output}")

    emit(data, as_json=as_json, render=render)
