"""``fgcd sim``: the simulator backend from the command line (scenes, lights, renders, contact sheet)."""

from __future__ import annotations

from pathlib import Path

import typer

from fgcd_cli.cli.output import emit, info

app = typer.Typer(
    help="Simulated world: list scenes and lightings, render views with ground truth.", no_args_is_help=True
)


@app.command("scenes")
def scenes(as_json: bool = typer.Option(False, "--json", help="Print one JSON object.")) -> None:
    """List the simulated scenes with their descriptions."""
    from fgcd_cli.app.sim import scenes as sim_scenes

    items, where = sim_scenes()

    def render(console):
        from rich.table import Table

        table = Table(title=f"Simulated scenes ({where})")
        table.add_column("name", style="bold")
        table.add_column("description")
        for it in items:
            table.add_row(it["name"], it["description"])
        console.print(table)

    emit({"scenes": items, "count": len(items)}, as_json=as_json, render=render)


@app.command("lights")
def lights(as_json: bool = typer.Option(False, "--json", help="Print one JSON object.")) -> None:
    """List the lighting presets."""
    from fgcd_cli.app.sim import lightings

    items = lightings()

    def render(console):
        for it in items:
            console.print(f"[bold]{it['name']}[/bold]  {it['description']}")

    emit({"lightings": items}, as_json=as_json, render=render)


@app.command("render")
def render_cmd(
    scene: str = typer.Option(..., "--scene", help="Scene name (fgcd sim scenes)."),
    light: str = typer.Option("front", "--light", help="Lighting preset (fgcd sim lights)."),
    pose: str | None = typer.Option(
        None, "--pose", help="x,y,z,rx,ry,rz in mm and degrees, camera frame, relative to the scene's default camera."
    ),
    out: Path = typer.Option(..., "-o", "--out", help="Output image (PNG)."),
    depth: Path | None = typer.Option(None, "--depth", help="Also write z-depth: .npy (metres) or .png (16-bit mm)."),
    mask: Path | None = typer.Option(None, "--mask", help="Also write the change mask (PNG, 255 = change)."),
    changes: int = typer.Option(0, "--changes", help="Inject this many random changes (1-20 mm)."),
    change_seed: int = typer.Option(1, "--change-seed", help="Seed of the changes."),
    seed: int = typer.Option(0, "--seed", help="Scene seed."),
    gray: bool = typer.Option(False, "--gray", help="Write a grayscale image instead of colour."),
    width: int = typer.Option(640, "--width", help="Image width (px); focal length scales with it."),
    height: int = typer.Option(480, "--height", help="Image height (px)."),
    supersample: int = typer.Option(1, "--supersample", help="Anti-aliasing samples per pixel and axis."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Render one view of a scene (and optionally its depth and change mask)."""
    from fgcd_cli.app.sim import RenderRequest, render_view

    outcome = render_view(
        RenderRequest(
            scene=scene,
            light=light,
            pose=pose,
            out=out,
            depth=depth,
            mask=mask,
            changes=changes,
            change_seed=change_seed,
            seed=seed,
            gray=gray,
            width=width,
            height=height,
            supersample=supersample,
        )
    )
    written = outcome.written

    def show(console):
        console.print(f"rendered [bold]{scene}[/bold] under {outcome.lighting} in {outcome.render_ms:.0f} ms -> {out}")
        for k, v in written.items():
            if k != "image":
                console.print(f"  {k}: {v}")
        if outcome.changes:
            console.print(f"  {outcome.changes} changes, {outcome.change_pixels} changed pixels")

    emit(outcome.record, as_json=as_json, render=show)


@app.command("contact-sheet")
def contact_sheet(
    out: Path = typer.Option(Path("docs/img/scenes_contact_sheet.png"), "-o", "--out", help="Output PNG."),
    lights_: str = typer.Option("front,led:3,night", "--light", help="Comma-separated lighting presets (columns)."),
    width: int = typer.Option(320, "--width", help="Width of each tile (px)."),
    supersample: int = typer.Option(2, "--supersample", help="Anti-aliasing samples per pixel and axis."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Every scene (rows) under several lightings (columns), labelled, in one PNG."""
    from fgcd_cli.app.sim import contact_sheet as render_sheet

    emit(
        render_sheet(out, lights=lights_, width=width, supersample=supersample, say=None if as_json else info),
        as_json=as_json,
    )
