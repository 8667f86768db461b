"""`fgcd demo`: the complete simulated campaign."""

from __future__ import annotations

from pathlib import Path

import typer

from fgcd_cli.cli.capture_cmd import print_record
from fgcd_cli.cli.output import emit, info


def demo(
    out: Path = typer.Option(Path("runs/demo"), "--out", "-o", help="Directory for the campaign and the summary."),
    scene: str = typer.Option("stele", "--scene", help="Simulator scene."),
    visit_light: str = typer.Option("led:3", "--visit-light", help="Lighting of the revisit (e.g. led:3, sun-evening)."),
    changes: int = typer.Option(4, "--changes", help="Fine-grained changes injected before the revisit."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Run a complete simulated campaign: calibrate, capture, relocate under other light, diff, report."""
    from fgcd_cli.demo import DemoConfig, run_demo

    if out.exists() and any(out.iterdir()):
        from datetime import datetime, timezone

        out = out / datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    summary = run_demo(out, config=DemoConfig(scene=scene, visit_light=visit_light, changes=changes), say=info,
                       on_record=print_record)

    def render(c) -> None:
        r = summary["relocation"]
        truth = r.get("final_truth") or {}
        c.print(f"[bold]Demo campaign[/bold] in {summary['campaign']}")
        c.print(f"  reference: {summary['reference']['cloud_points']} cloud points")
        c.print(f"  relocation: {'converged' if r['converged'] else 'NOT converged'} in {r['adjustments']} adjustments, "
                f"{r['session_s']} s on the rig; true error {truth.get('pose_err_mm', float('nan')):.2f} mm, "
                f"AFD {truth.get('afd_px', float('nan')):.2f} px")
        d = summary.get("diff", {})
        c.print(f"  changes: {d.get('regions', d.get('n_regions', '?'))} regions; report: {d.get('report', '?')}")
        c.print(f"  summary: {out / 'summary.json'}")

    emit(summary, as_json=as_json, render=render)
