"""`fgcd demo`: the complete simulated campaign."""

from __future__ import annotations

from pathlib import Path

import typer

from fgcd_cli.cli.determinism import DETERMINISTIC, deterministic_setup
from fgcd_cli.cli.output import emit, info
from fgcd_cli.cli.relocate_cmd import print_record


def summary_lines(summary: dict, *, summary_path: Path) -> list[str]:
    """The demo's closing summary as rich-markup lines (one per topic).

    The truth line counts injected changes, as the revisit line announced them
    (``count_changes_found``): "3 of 4 injected changes found".
    """
    r = summary["relocation"]
    truth = r.get("final_truth") or {}
    lines = [
        f"[bold]Demo campaign[/bold] in {summary['campaign']}",
        f"  reference: {summary['reference']['cloud_points']} cloud points",
        f"  relocation: {'converged' if r['converged'] else 'NOT converged'} in {r['adjustments']} adjustments, "
        f"{r['session_s']} s on the rig; simulator truth: {truth.get('pose_err_mm', float('nan')):.2f} mm, "
        f"AFD {truth.get('afd_px', float('nan')):.2f} px",
    ]
    d = summary.get("diff", {})
    aside = d.get("set_aside_regions")
    aside_text = f" ({aside} more along edges set aside, cyan in the report)" if aside else ""
    lines.append(f"  changes: {d.get('regions', '?')} regions found{aside_text}; report: {d.get('report', '?')}")
    ev = d.get("evaluation")
    if ev:
        injected = ev.get("injected_changes", ev["true_changes"])
        hidden = injected - ev["true_changes"]
        view = f" ({hidden} out of the reference's view)" if hidden > 0 else ""
        lines.append(
            f"  [dim]simulator truth: {ev['true_changes_found']} of {injected} injected changes found{view}, "
            f"{ev['false_regions']} false regions, pixel F1 {ev['f1']:.2f}[/dim]"
        )
    lines.append(f"  summary: {summary_path}")
    return lines


def demo(
    out: Path = typer.Option(Path("runs/demo"), "--out", "-o", help="Directory for the campaign and the summary."),
    scene: str = typer.Option("relief_panel", "--scene", help="Simulator scene (fgcd sim scenes)."),
    visit_light: str = typer.Option(
        "led:3", "--light", help="Lighting of the revisit (e.g. led:3, sun-evening; `fgcd sim lights`)."
    ),
    changes: int = typer.Option(4, "--changes", help="Fine-grained changes injected before the revisit."),
    vse: str = typer.Option(
        "mono", "--vse", help="VSE of capture and relocation: mono (rACR, monocular) or rgbd (depth camera)."
    ),
    deterministic: bool = DETERMINISTIC,
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Run a complete simulated campaign: calibrate, capture, relocate under other light, diff, report."""
    deterministic_setup(deterministic)  # before the heavy libraries load
    from fgcd_cli.app import demo as demo_uc
    from fgcd_cli.app.scenario import check_lighting, check_scene
    from fgcd_cli.cli.progress import step_progress
    from fgcd_cli.errors import UserInputError

    # every option with a closed set of values, before anything is created or calibrated
    if vse not in ("mono", "rgbd"):
        raise UserInputError(f"unknown --vse '{vse}' (mono or rgbd)")
    check_scene(scene)
    visit_light = check_lighting(visit_light, option="--light")
    if changes < 0:
        raise UserInputError(f"--changes must be 0 or more, got {changes}")

    out, where = demo_uc.demo_output_dir(out)
    info(where)  # before any work: a non-empty --out gets a new subfolder, named now, not at the end
    # Every step of the demo reports through on_progress: a live bar with its elapsed time, or off a
    # terminal a plain line per step and a heartbeat (stderr, also with --json), so no step runs silently.
    with step_progress(enabled=True) as bar:
        summary = demo_uc.run_demo(
            out,
            config=demo_uc.DemoConfig(
                scene=scene, visit_light=visit_light, changes=changes, vse=vse, deterministic=deterministic
            ),
            say=info,
            on_record=print_record,
            on_progress=bar,
        )

    def render(c) -> None:
        for line in summary_lines(summary, summary_path=out / "summary.json"):
            c.print(line)

    emit(summary, as_json=as_json, render=render)
