"""``fgcd report``: a station's history across visits, as a self-contained HTML page."""

from __future__ import annotations

from pathlib import Path

import typer

from fgcd_cli.cli.output import emit, info
from fgcd_cli.errors import run_record


def report(
    campaign: Path = typer.Option(..., "--campaign", "-c", help="Campaign folder."),
    station: str = typer.Option(..., "--station", "-s", help="Station name."),
    output: Path | None = typer.Option(None, "-o", "--output", help="HTML file (default: <station>/history.html)."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Station history: every visit compared with the reference (visits not yet compared are compared now).

    Exit status 0; 4 when a recorded visit is damaged or missing: the report of
    the other visits is still written, and it and the output name the damaged ones.
    """
    from fgcd_cli.app.report import station_history

    run_record.no_platform()
    # Visits not yet compared get their change maps first, one file at a time.
    with run_record.writing(f"the history report of station '{station}'", whole=False):
        data = station_history(campaign, station, output=output, progress=None if as_json else info)

    def render(console):
        damaged = f", {len(data['damaged'])} damaged or missing" if data["damaged"] else ""
        console.print(f"station {station}: {len(data['visits'])} visit(s){damaged}")
        for v in data["visits"]:
            status = (
                f"{v['regions']} region(s), {v['changed_px']} px" if v["comparable"] else f"not compared: {v['reason']}"
            )
            console.print(f"  {v['name']}: {status}")
        for v in data["damaged"]:
            console.print(f"  {v['name']}: [red]damaged[/red]: {v['reason']}")
        console.print(f"report: {data['output']}")

    emit(data, as_json=as_json, render=render)
    if data["damaged"]:
        from fgcd_cli.errors import DataIntegrityError

        names = ", ".join(v["name"] for v in data["damaged"])
        raise DataIntegrityError(
            f"station '{station}': {len(data['damaged'])} recorded visit(s) damaged or missing "
            f"({names}); the report covers the other {len(data['visits'])}; "
            "run `fgcd campaign verify`"
        )
