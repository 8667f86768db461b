"""``fgcd report``: a station's history across visits, as a self-contained HTML page."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from fgcd_cli.cli.output import emit, info
from fgcd_cli.errors import run_record


def report(
    campaign: Path = typer.Option(..., "--campaign", "-c", help="Campaign folder."),
    station: str = typer.Option(..., "--station", "-s", help="Station name."),
    output: Optional[Path] = typer.Option(None, "-o", "--output", help="HTML file (default: <station>/history.html)."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Station history: every visit compared with the reference (visits not yet compared are compared now)."""
    from fgcd_cli.app.report import station_history

    run_record.no_platform()
    # Visits not yet compared get their change maps first, one file at a time.
    with run_record.writing(f"the history report of station '{station}'", whole=False):
        data = station_history(campaign, station, output=output, progress=None if as_json else info)

    def render(console):
        console.print(f"station {station}: {len(data['visits'])} visit(s)")
        for v in data["visits"]:
            status = f"{v['regions']} region(s), {v['changed_px']} px" if v["comparable"] else f"not compared: {v['reason']}"
            console.print(f"  {v['name']}: {status}")
        console.print(f"report: {data['output']}")

    emit(data, as_json=as_json, render=render)
