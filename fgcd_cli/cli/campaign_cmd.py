"""`fgcd campaign init|list|show|verify|add-station`."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.markup import escape
from rich.table import Table

from fgcd_cli.app import campaign as campaign_uc
from fgcd_cli.cli.output import emit
from fgcd_cli.errors import DataIntegrityError, run_record

app = typer.Typer(
    help="Create, inspect and verify campaigns (a site, its stations and observations).", no_args_is_help=True
)

JSON_OPT = typer.Option(False, "--json", help="Print one JSON object instead of text.")


def _reads_only() -> None:
    """Tell the interruption line that this command moves and writes nothing."""
    run_record.no_platform()
    run_record.no_writes()


@app.command("init")
def init_cmd(
    directory: Path = typer.Argument(..., help="Campaign directory to create."),
    site: str = typer.Option(..., "--site", help="Site name, e.g. 'Dunhuang cave 45'."),
    description: str = typer.Option("", "--description", help="Free text."),
    driver: str = typer.Option(
        "sim", "--driver", "-d", help="The campaign's rig: sim, grbl, ur or manual (campaign.toml [rig] driver)."
    ),
    port: str = typer.Option(None, "--port", help="GRBL serial device, e.g. /dev/ttyUSB0 ([rig] port)."),
    host: str = typer.Option(None, "--host", help="UR controller address, e.g. 192.168.0.10 ([rig] host)."),
    baud: int = typer.Option(None, "--baud", help="GRBL baud rate ([rig] baud; grbl: 115200 when not given)."),
    camera: str = typer.Option(
        None,
        "--camera",
        help="OpenCV camera: an index or a device path such as "
        "/dev/video2 ([rig] camera; grbl, ur, manual: 0 when not given).",
    ),
    as_json: bool = JSON_OPT,
) -> None:
    """Create a new campaign directory: one site, one rig (every command that drives it reads campaign.toml [rig])."""
    request = campaign_uc.CampaignInit(
        directory=directory,
        site=site,
        description=description,
        driver=driver,
        port=port,
        host=host,
        baud=baud,
        camera=camera,
    )
    run_record.no_platform()
    with run_record.writing(f"the campaign in {directory}"):
        data = campaign_uc.create_campaign(request)
    emit(
        data,
        as_json=as_json,
        render=lambda c: c.print(f"Created campaign [bold]{data['site']}[/bold] in {data['campaign']}"),
    )


@app.command("add-station")
def add_station_cmd(
    name: str = typer.Argument(..., help="Station (viewpoint) name."),
    campaign: Path = typer.Option(..., "--campaign", "-c", help="Campaign directory."),
    description: str = typer.Option(
        "", "--description", help="Free text: what the station looks at, where the camera stands."
    ),
    as_json: bool = JSON_OPT,
) -> None:
    """Add a station (a viewpoint to monitor) to a campaign."""
    run_record.no_platform()
    with run_record.writing(f"station '{name}'"):
        data = campaign_uc.add_station(campaign, name, description=description)
    emit(data, as_json=as_json, render=lambda c: c.print(f"Added station [bold]{data['station']}[/bold]"))


@app.command("list")
def list_cmd(
    campaign: Path = typer.Argument(..., help="Campaign directory."),
    as_json: bool = JSON_OPT,
) -> None:
    """List the stations of a campaign with their reference and visits."""
    _reads_only()
    listed = campaign_uc.campaign_stations(campaign)
    stations = listed.stations

    def render(c) -> None:
        t = Table(title=f"{listed.site} — {listed.path}")
        t.add_column("station")
        t.add_column("reference")
        t.add_column("visits", justify="right")
        t.add_column("latest visit")
        for s in stations:
            t.add_row(
                s["name"],
                "yes" if s["reference"] else "—",
                str(len(s["visits"])),
                s["visits"][-1] if s["visits"] else "—",
            )
        c.print(t)

    emit(listed.to_dict(), as_json=as_json, render=render)


@app.command("show")
def show_cmd(
    campaign: Path = typer.Argument(..., help="Campaign directory."),
    station: str = typer.Option(None, "--station", "-s", help="Show one station in detail."),
    as_json: bool = JSON_OPT,
) -> None:
    """Show a campaign's configuration, or one station's observations."""
    _reads_only()
    if station is None:
        camp = campaign_uc.campaign_overview(campaign)
        data = camp.to_dict()

        def render(c) -> None:
            c.print(f"[bold]{camp.site}[/bold]  ({camp.path})")
            for sec, vals in camp.config.items():
                c.print(f"[{sec}]")
                for k, v in vals.items():
                    c.print(f"  {k} = {v}")
            c.print(f"stations: {', '.join(data['stations']) or '—'}")
            c.print(f"rig records: {', '.join(data['rig_records']) or '—'}")

        emit(data, as_json=as_json, render=render)
        return
    data = campaign_uc.station_observations(campaign, station)
    rows = data["observations"]

    def render(c) -> None:
        t = Table(title=f"station {data['station']['name']}")
        for col in ("observation", "kind", "created", "files", "images"):
            t.add_column(col)
        for r in rows:
            t.add_row(r["name"], r["kind"], str(r["created"]), str(r["files"]), ", ".join(r["images"]))
        c.print(t)

    emit(data, as_json=as_json, render=render)


@app.command("verify")
def verify_cmd(
    campaign: Path = typer.Argument(..., help="Campaign directory."),
    as_json: bool = JSON_OPT,
) -> None:
    """Check every manifest and checksum; name each damaged file and exit 4 if any (3: not a campaign)."""
    _reads_only()
    report = campaign_uc.verify(campaign)

    def render(c) -> None:
        for p in report.problems:
            colour = {"error": "red", "warning": "yellow"}.get(p.severity, "cyan")
            c.print(f"[{colour}]{p.severity}[/{colour}] {p.kind}: {escape(p.path)} — {escape(p.detail)}")
        status, colour = ("OK", "green") if report.ok else ("DAMAGED", "red")
        c.print(f"[{colour}]{status}[/{colour}]{escape(report.summary().removeprefix(status))}")

    emit(report.to_dict(), as_json=as_json, render=render)
    damage = campaign_uc.damage_line(report)
    if damage is not None:
        raise DataIntegrityError(damage)
