"""``fgcd archive``: a site's whole archive, analysed on Dask (``analyze``) and followed over time (``history``)."""

from __future__ import annotations

from pathlib import Path

import typer

from fgcd_cli.cli.output import emit, info
from fgcd_cli.cli.progress import step_progress
from fgcd_cli.errors import run_record

app = typer.Typer(help="A site's whole archive: batch analysis on Dask, change over time.", no_args_is_help=True)


@app.command("analyze")
def analyze(
    roots: list[Path] = typer.Argument(..., metavar="root", help="Folders holding campaigns (searched recursively)."),
    workers: int = typer.Option(2, "--workers", "-w", help="Worker processes of the embedded Dask LocalCluster."),
    scheduler: str | None = typer.Option(
        None, "--scheduler", help="An existing Dask scheduler, tcp://HOST:PORT (default: embedded)."
    ),
    dry_run: bool = typer.Option(False, "--dry-run", help="List the visits and what would be done; run nothing."),
    force: bool = typer.Option(False, "--force", help="Re-do every visit, up to date or not."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Diff (and AFD) every visit of every station against its reference; up-to-date visits are skipped."""
    from fgcd_cli.app.archive import ArchiveRequest, analyze_archive, plan_archive
    from fgcd_cli.app.archive_task import VisitStatus

    run_record.no_platform()
    request = ArchiveRequest(roots=list(roots), workers=workers, scheduler=scheduler, force=force)
    if dry_run:
        campaigns, planned = plan_archive(request)
        data = {
            "campaigns": campaigns,
            "visits": len(planned),
            "to_do": sum(p.needs_work for p in planned),
            "planned": [p.to_dict() for p in planned],
        }

        def render_plan(console):
            for p in planned:
                state = p.state.value if p.state else f"cannot be read: {p.problem}"
                state += "; --force" if p.forced else ""
                console.print(f"{'analyse' if p.needs_work else 'skip   '}  {p.key.label}  ({state})")
            console.print(f"{data['to_do']} of {data['visits']} visit(s) in {campaigns} campaign(s) to analyse")

        emit(data, as_json=as_json, render=render_plan)
        return

    def report_failure(outcome) -> None:
        if outcome.status == VisitStatus.FAILED and not as_json:
            info(f"failed: {outcome.key.label}: {outcome.reason}")

    with (
        run_record.writing("archive analyses (each visit's products are complete or redone)", whole=False),
        step_progress(enabled=not as_json) as bar,
    ):
        result = analyze_archive(request, on_progress=bar, on_visit=report_failure)
    data = result.to_dict()

    def render(console):
        console.print(
            f"{data['visits']} visit(s) in {data['campaigns']} campaign(s) on {data['workers']} worker(s) "
            f"({data['scheduler']}): {data['done']} done, {data['skipped']} skipped, "
            f"{data['failed']} failed in {data['run_s']:.1f} s"
        )

    emit(data, as_json=as_json, render=render)
    if result.count(VisitStatus.FAILED):
        from fgcd_cli.errors import CampaignError

        raise CampaignError(
            f"{result.count(VisitStatus.FAILED)} visit(s) failed (each named with its reason); the others completed"
        )


@app.command("history")
def history(
    roots: list[Path] = typer.Argument(..., metavar="root", help="Folders holding campaigns (searched recursively)."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Track each change region across visits; write each campaign's site page (<campaign>/site.html)."""
    from fgcd_cli.app.archive_history import HistoryRequest, archive_history, track_growth

    run_record.no_platform()
    sites = archive_history(HistoryRequest(roots=list(roots)))
    data = {"sites": [s.to_dict() for s in sites]}

    def render(console):
        for site in sites:
            console.print(f"[bold]{site.site}[/bold] ({site.campaign})")
            for s in site.stations:
                console.print(
                    f"  {s.station}: {len(s.tracks)} region(s) tracked over {len(s.analysed)} visit(s); "
                    f"new {s.new_area:.1f} {s.unit}, grown {s.grown_area:.1f} {s.unit}"
                    + (f"; not analysed: {len(s.not_analysed)}" if s.not_analysed else "")
                )
                for t in s.tracks:
                    console.print(
                        f"    region {t.id}: {t.status.value}, first seen {t.first_seen}, growth {track_growth(t)}"
                    )
            console.print(f"  site page: {site.page}")

    emit(data, as_json=as_json, render=render)
