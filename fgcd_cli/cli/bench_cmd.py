"""``fgcd bench NAME``: benchmarks; each prints a JSON-able dict with a ``summary``."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import typer
from rich.console import Console

from fgcd_cli.cli.determinism import DETERMINISTIC, deterministic_setup
from fgcd_cli.cli.output import emit as _emit_plain
from fgcd_cli.cli.output import info

app = typer.Typer(help="Benchmarks reproducing the papers' measurements.", no_args_is_help=True)


@app.callback()
def _world(
    world: str = typer.Option(
        None,
        "--world",
        help="Simulated world: calibrated (the default: grain and a specular lobe, checked against real "
        "photographs) or smooth (Lambert, the appearance before issue 45).",
    ),
) -> None:
    """Benchmarks reproducing the papers' measurements."""
    from fgcd_cli.bench.sim_world import select_world
    from fgcd_cli.errors import UserInputError

    try:
        select_world(world)
    except ValueError as exc:
        raise UserInputError(str(exc)) from None


def emit(data: dict, *, as_json: bool, render: Callable[[Console], None] | None = None) -> None:
    """Print a bench's result, recording the simulated world it ran in (``settings.world``)."""
    from fgcd_cli.bench.sim_world import current_world

    if isinstance(data, dict):
        data.setdefault("settings", {})["world"] = current_world()
    _emit_plain(data, as_json=as_json, render=render)


@app.command("changes")
def changes(
    quick: bool = typer.Option(False, "--quick", help="Fewer lightings and pairs."),
    overlays: Path | None = typer.Option(None, "--overlays", help="Write sample overlays (PNG) into this folder."),
    part: list[str] | None = typer.Option(
        None, "--part", help="Run only this part: real, sim, large, multilight (repeatable; default: all)."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Fine-grained change detection: real FGCD groups (leave one group out), simulated pairs, real multi-light objects."""
    from fgcd_cli.bench.changes.main import PARTS, run
    from fgcd_cli.errors import UserInputError

    unknown = sorted(set(part or ()) - set(PARTS))
    if unknown:
        raise UserInputError(f"unknown --part {', '.join(unknown)}: choose from {', '.join(PARTS)}")
    if not as_json:
        info("running the change-detection benchmark…")
    data = run(quick=quick, overlay_dir=overlays, parts=tuple(part) if part else PARTS)

    def render(console):
        real = data["real"]
        if real.get("available"):
            console.print("leave one group out (constants chosen on the other groups):")
            for g in real["groups"]:
                console.print(
                    f"{g['group']}: best F1 {g['best_f1']:.3f}  AP {g['ap']:.3f}  auto F1 {g['auto_f1']:.3f} "
                    f"(P {g['auto_precision']:.2f} R {g['auto_recall']:.2f})  {g['chosen']}  {g['seconds']:.1f} s"
                )
        else:
            console.print(f"real dataset: {real.get('reason')}")
        if data["sim"] and not data["sim"].get("available"):
            console.print(f"simulated part: {data['sim'].get('reason')}")
        for key, value in data["summary"].items():
            target = data["targets"].get(key)
            bound = "≤" if key.startswith(("seconds", "peak")) or "false_regions" in key else "≥"  # upper bounds
            shown = f"  (target {bound} {target})" if target is not None else ""
            console.print(f"[bold]{key}[/bold] = {value:.3f}" + shown)

    emit(data, as_json=as_json, render=render)


@app.command("render")
def render(
    quick: bool = typer.Option(False, "--quick", help="Three scenes, three frames each."),
    supersample: int = typer.Option(1, "--supersample", help="Anti-aliasing samples per pixel and axis."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Simulator renderer: time per shaded 640x480 frame for each scene (target <= 200 ms)."""
    from fgcd_cli.bench.render import run

    if not as_json:
        info("timing the simulator renderer…")
    data = run(quick=quick, supersample=supersample)

    def show(console):
        for s in data["scenes"]:
            console.print(
                f"{s['scene']:<14} {s['ms_median']:7.1f} ms/frame (CPU {s['cpu_ms_median']:.0f} ms)  "
                f"({s['triangles']} triangles, "
                f"built in {s['build_s']:.1f} s)"
            )
        sm = data["summary"]
        console.print(
            f"[bold]ms_per_frame_median[/bold] = {sm['ms_per_frame_median']:.1f} (target ≤ {sm['target_ms']:.0f}); "
            f"load average {data['machine']['load_avg_1min']:.1f} on {data['machine']['cpu_count']} cores"
        )

    emit(data, as_json=as_json, render=show)


@app.command("lighting")
def lighting(
    quick: bool = typer.Option(
        False, "--quick", help="One real group per kind, one multi-light object, one scene each."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Registration across lightings (paper 000, Table 1): real photographs beside their simulated counterparts."""
    from fgcd_cli.bench.lighting.main import run

    if not as_json:
        info("registering across lightings: real photographs, then simulated scenes of the same kinds…")
    data = run(quick=quick, say=(lambda text: None) if as_json else info)

    def show(console):
        if not data["real_available"]:
            console.print("real photographs: none found beside the repository (../shared/data); simulated side only")
        console.print("kind: real / simulated — failed, beyond 3 px, median corner error")
        for kind, k in data["kinds"].items():
            console.print(
                f"{kind:<18} real {k.get('real_fail_rate', float('nan')):.2f} {k.get('real_over3_rate', float('nan')):.2f} "
                f"{k.get('real_median_corner_px', float('nan')):.2f} px ({k.get('real_pairs', 0)} pairs)  "
                f"sim {k.get('sim_fail_rate', float('nan')):.2f} {k.get('sim_over3_rate', float('nan')):.2f} "
                f"{k.get('sim_median_corner_px', float('nan')):.2f} px ({k.get('sim_pairs', 0)} pairs)  "
                f"{'met' if k.get('met') else 'not met'}"
            )
        for key, value in data["summary"].items():
            console.print(
                f"[bold]{key}[/bold] = {value:.3f}" if isinstance(value, float) else f"[bold]{key}[/bold] = {value}"
            )

    emit(data, as_json=as_json, render=show)


@app.command("calibrate")
def calibrate(
    quick: bool = typer.Option(False, "--quick", help="Two rigs, 12 intrinsics views each."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Calibration on simulated rigs: intrinsics, hand-eye (board and target-free) and map scale."""
    from fgcd_cli.bench.calibrate import run

    if not as_json:
        info("running the calibration benchmark (simulated rigs, a minute or more per rig)…")
    data = run(quick=quick)

    def show(console):
        for r in data["rigs"]:
            f = r["target_free"]
            free = (
                f"target-free {f['trans_err_mm']:.1f} mm / {f['rot_err_deg']:.2f} deg, scale {f['scale_err_pct']:.2f} %"
                if "error" not in f
                else f"target-free failed: {f['error']}"
            )
            console.print(
                f"rig {r['seed']} ({r['noise']}): intrinsics {r['intrinsics']['err_pct']:.3f} %, "
                f"board {r['target']['trans_err_mm']:.1f} mm / {r['target']['rot_err_deg']:.2f} deg, {free}"
            )
        for key, value in data["summary"].items():
            target = data["targets"].get(key)
            console.print(f"[bold]{key}[/bold] = {value:.3f}" + (f"  (target ≤ {target})" if target else ""))

    emit(data, as_json=as_json, render=show)


@app.command("align")
def align(
    quick: bool = typer.Option(False, "--quick", help="One current VSE session and fewer trials."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Scale-aware point cloud alignment (rACR §3.4) on VSE clouds from simulated sessions."""
    from fgcd_cli.bench.align import run

    if not as_json:
        info("running the alignment benchmark (VSE sessions in the simulator, synthetic noise study)…")
    data = run(quick=quick)

    def show(console):
        for key, value in data["summary"].items():
            target = data["targets"].get(key)
            console.print(f"[bold]{key}[/bold] = {value:.3f}" + (f"  (target {target})" if target else ""))

    emit(data, as_json=as_json, render=show)


@app.command("vse")
def vse(
    quick: bool = typer.Option(False, "--quick", help="Three textured scenes, half the exploration, no hard scenes."),
    variant: str = typer.Option("both", "--variant", help="mono, sparse or both (side by side)."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Visual SLAM engine: ATE, cloud accuracy and density, tracking speed on simulated explorations."""
    from fgcd_cli.bench.vse import run
    from fgcd_cli.errors import UserInputError

    if variant not in ("mono", "sparse", "both"):
        raise UserInputError(f"--variant must be mono, sparse or both, not {variant!r}")
    if not as_json:
        info("running the VSE benchmark (renders every frame on the CPU; a few minutes)…")
    data = run(quick=quick, variant=variant)

    def show(console):
        for r in data["scenes"]:
            ate = "—" if r["ate_mm"] is None else f"{r['ate_mm']:.2f}"
            cl = "—" if r["cloud_median_error_pct_depth"] is None else f"{r['cloud_median_error_pct_depth']:.2f}"
            console.print(
                f"{r['scene']:<13} {r['variant']:<6} {r['status']:<12} ATE {ate:>6} mm  cloud {cl:>5} % "
                f"of depth  {r['cloud_points']:>6} pts  {r['track_fps']:.0f} fps track "
                f"({r['overall_fps']:.0f} with mapping)"
            )
        for key, value in data["summary"].items():
            target = data["targets"].get(key)
            console.print(f"[bold]{key}[/bold] = {value}" + (f"  (target {target})" if target else ""))

    emit(data, as_json=as_json, render=show)


@app.command("relocate")
def relocate(
    quick: bool = typer.Option(False, "--quick", help="A 3-case subset (CI-sized)."),
    no_serial: bool = typer.Option(False, "--no-serial", help="Skip the serial comparison."),
    case: list[str] | None = typer.Option(None, "--case", help="Run only these cases (repeatable)."),
    deterministic: bool = DETERMINISTIC,
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """The rACR loop on simulated indoor/outdoor cases: success (true AFD < 3 px), AFD, adjustments, time."""
    deterministic_setup(deterministic)
    from fgcd_cli.bench.relocate import LOOP_MODES, run

    data = run(quick=quick, serial=not no_serial, say=info, cases=case, deterministic=deterministic)

    def show(console):
        for r in data["cases"]:
            for mode in LOOP_MODES:
                if mode in r:
                    m = r[mode]
                    if "error" in m:
                        console.print(
                            f"{r['case']:<11} {mode:<8} [red]error[/red]: {m['error']} (AFD {m.get('afd_px', float('nan')):.2f} px)"
                        )
                    else:
                        console.print(
                            f"{r['case']:<11} {mode:<8} AFD {m['afd_px']:6.2f} px  {m['pose_err_mm']:6.2f} mm  "
                            f"{m['adjustments']} adj  {m['session_s']:6.1f} s rig  {m['wall_s']:6.1f} s wall"
                        )
            if "error" in r:
                console.print(f"{r['case']:<11} [red]{r['error']}[/red]")
        for k, v in data["summary"].items():
            t = data["targets"].get(k)
            console.print(f"[bold]{k}[/bold] = {v:.3f}" + (f"  (target {t})" if t is not None else ""))

    emit(data, as_json=as_json, render=show)


@app.command("paper")
def paper(
    quick: bool = typer.Option(False, "--quick", help="One or two cases per experiment (<= 30 min)."),
    out: Path = typer.Option(
        Path("fgcd-bench-paper"),
        "--out",
        help="Folder of the worlds, per-run JSON, tables (paper.md) and figures; a re-run resumes it.",
    ),
    experiment: list[str] | None = typer.Option(
        None,
        "--experiment",
        help="table2, table5, fig7, table3, table4, fig4, fig6, fig12, s55, revisit (repeatable; default all).",
    ),
    case: list[str] | None = typer.Option(None, "--case", help="Only these relocation cases (repeatable)."),
    deterministic: bool = DETERMINISTIC,
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Paper 000's experiments in the simulator: rACR beside the ACR baseline (Tables 2-5, Figs. 4, 6, 7, 12, §5.5)."""
    deterministic_setup(deterministic)
    from fgcd_cli.bench.paper.main import run
    from fgcd_cli.bench.paper.plan import EXPERIMENTS, TABLE4_CASES
    from fgcd_cli.bench.relocate import CASES
    from fgcd_cli.cli.progress import step_progress
    from fgcd_cli.errors import UserInputError

    unknown = [e for e in experiment or [] if e not in EXPERIMENTS]
    if unknown:
        raise UserInputError(f"--experiment: unknown {', '.join(unknown)} (valid: {', '.join(EXPERIMENTS)})")
    unknown = [c for c in case or [] if c not in {c.name for c in [*CASES, *TABLE4_CASES]}]
    if unknown:
        raise UserInputError(
            f"--case: unknown {', '.join(unknown)} (see `fgcd bench relocate`; Table 4: W1-3, R1-3, V1-3)"
        )
    with step_progress(enabled=True) as bar:
        say = bar.lines(info) if bar is not None else info
        data = run(
            quick=quick,
            out=out,
            experiments=tuple(experiment) if experiment else EXPERIMENTS,
            cases=case,
            say=say,
            on_progress=bar,
            deterministic=deterministic,
        )

    def show(console):
        console.print((Path(data["out"]) / "paper.md").read_text())
        for k, v in data["summary"].items():
            t = data["targets"].get(k)
            console.print(f"[bold]{k}[/bold] = {v:.3f}" + (f"  (target {t})" if t is not None else ""))

    emit(data, as_json=as_json, render=show)


@app.command("coarse")
def coarse(
    quick: bool = typer.Option(False, "--quick", help="A 2-case subset."),
    no_baseline: bool = typer.Option(False, "--no-baseline", help="Skip the runs without the coarse stage."),
    case: list[str] | None = typer.Option(None, "--case", help="Run only these cases (repeatable)."),
    deterministic: bool = DETERMINISTIC,
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """The active coarse stage (paper 001) from far starts: hand-over within 5 cm / 5 deg, then rACR."""
    deterministic_setup(deterministic)
    from fgcd_cli.bench.coarse import run

    data = run(quick=quick, baseline=not no_baseline, say=info, cases=case, deterministic=deterministic)

    def show(console):
        for r in data["cases"]:
            for label in ("coarse", "baseline"):
                m = r.get(label)
                if m is None:
                    continue
                if "error" in m:
                    console.print(
                        f"{r['case']:<6} {label:<8} [red]error[/red]: {m['error']} "
                        f"(AFD {m.get('afd_px', float('nan')):.2f} px)"
                    )
                    continue
                c = m.get("coarse") or {}
                stage = (
                    f"coarse {c.get('steps')} steps, end {c.get('end_err_mm') or float('nan'):.0f} mm / "
                    f"{c.get('end_err_deg') or float('nan'):.1f} deg"
                    if c
                    else "no coarse stage"
                )
                console.print(
                    f"{r['case']:<6} {label:<8} AFD {m['afd_px']:6.2f} px  {m['adjustments']} adj  "
                    f"{m['session_s']:6.1f} s rig  {stage}"
                )
            if "error" in r:
                console.print(f"{r['case']:<6} [red]{r['error']}[/red]")
        for k, v in data["summary"].items():
            t = data["targets"].get(k)
            console.print(f"[bold]{k}[/bold] = {v:.3f}" + (f"  (target {t})" if t is not None else ""))

    emit(data, as_json=as_json, render=show)


@app.command("archive")
def archive(
    quick: bool = typer.Option(False, "--quick", help="2 campaigns x 2 stations x 3 visits (else 3 x 3 x 4)."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Archive analysis on Dask: visits per minute with 1 and 2 workers, scheduler overhead, re-run when unchanged."""
    from fgcd_cli.bench.archive.main import run

    if not as_json:
        info("building a synthetic archive and analysing it on Dask…")
    data = run(quick=quick)

    def show(console):
        for name, r in data["runs"].items():
            console.print(
                f"{name:<16} {r['visits']} visits on {r['workers']} worker(s): {r['done']} done, "
                f"{r['skipped']} skipped in {r['run_s']:.1f} s (+{r['cluster_start_s']:.1f} s start-up)"
            )
        for key, value in data["summary"].items():
            console.print(f"[bold]{key}[/bold] = {value:.3f}")

    emit(data, as_json=as_json, render=show)


@app.command("faults")
def faults(
    quick: bool = typer.Option(
        False,
        "--quick",
        help="3 faults per single-move and campaign class instead of 15, "
        "without the whole-capture classes, and one fault of each group (whole operations, "
        "real disk full, link cuts, power loss).",
    ),
    seed: int = typer.Option(0, "--seed", help="Seed of the fault moments and kinds."),
    fault: list[str] | None = typer.Option(None, "--fault", help="Only these fault classes (repeatable)."),
    per_class: int | None = typer.Option(
        None,
        "--per-class",
        min=1,
        help="Faults per class (default: the run's, 15 or 3; each group's own in the full run).",
    ),
    workdir: Path | None = typer.Option(
        None,
        "--workdir",
        help="Keep the bench campaign here and reuse it (its calibration and captured stations) on the next run.",
    ),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Injected field faults against real fgcd processes and emulated controllers (docs/hardware.md, Faults)."""
    from fgcd_cli.bench.faults.main import FAULT_CLASSES, run
    from fgcd_cli.errors import UserInputError

    unknown = [f for f in fault or [] if f not in FAULT_CLASSES]
    if unknown:
        raise UserInputError(f"--fault: unknown class {', '.join(unknown)} (valid: {', '.join(FAULT_CLASSES)})")
    if not as_json:
        info("injecting faults…")
    data = run(
        quick=quick,
        seed=seed,
        classes=tuple(fault) if fault else None,
        per_class=per_class,
        workdir=workdir,
        on_progress=None if as_json else (lambda done, total, label: info(f"{done + 1}/{total} {label}")),
    )

    def show(console):
        for name, s in data["by_class"].items():
            console.print(f"{name:<24} {s['faults_ok']}/{s['faults_tried']} ok")
        for row in data["faults"]:
            if not row["ok"]:
                console.print(f"[red]{row['fault']} seed {row['seed']}[/red]: exit {row['code']} {row['detail']}")
        for k, v in data["summary"].items():
            t = data["targets"].get(k)
            console.print(
                f"[bold]{k}[/bold] = {v}"
                + (f"  (target {'≥' if k.startswith(('faults', 'fault_')) else '='} {t})" if t is not None else "")
            )

    emit(data, as_json=as_json, render=show)


@app.command("soak")
def soak(
    quick: bool = typer.Option(False, "--quick", help="10 revisits, then 2 with change detection (else 100 + 20)."),
    revisits: int | None = typer.Option(
        None,
        "--revisits",
        help="Consecutive revisits before the ones with change detection (default 100; 10 with --quick).",
    ),
    change_revisits: int | None = typer.Option(
        None,
        "--change-revisits",
        help="Revisits with injected changes, diff and report after those (default 20; 2 with --quick).",
    ),
    out: Path | None = typer.Option(
        None,
        "--out",
        help="Keep the campaign and samples.jsonl (one line per "
        "revisit, as it ends) in this folder; by default a temporary one, removed.",
    ),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Many simulated revisits of one station in one process: memory, threads, files and temporaries per revisit."""
    from fgcd_cli.bench.soak.main import run
    from fgcd_cli.errors import UserInputError

    for option, value in (("--revisits", revisits), ("--change-revisits", change_revisits)):
        if value is not None and value < 0:
            raise UserInputError(f"{option} must be 0 or more, got {value}")
    if out is not None and out.exists() and any(out.iterdir()):
        raise UserInputError(f"--out {out} is not empty: give a new or empty folder")
    data = run(
        quick=quick,
        revisits=revisits,
        change_revisits=change_revisits,
        out=out,
        say=(lambda _m: None) if as_json else info,
    )

    def show(console):
        for key, value in data["summary"].items():
            target = data["targets"].get(key)
            console.print(f"[bold]{key}[/bold] = {value}" + (f"  (target {target})" if target is not None else ""))
        for s in data["samples"]:
            if s["detail"]:
                console.print(f"[red]revisit {s['index']}[/red]: {s['detail']}")

    emit(data, as_json=as_json, render=show)
