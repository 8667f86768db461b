"""``fgcd bench paper``: paper 000's experiments (§4-5) in the simulator, rACR beside the ACR baseline.

Experiments (each run is one relocation, :mod:`fgcd_cli.bench.paper_runs`):

* **table2**: the 20 cases of ``fgcd bench relocate`` (10 indoor under the LED,
  10 outdoor under the sun), rACR (parallel) and ACR from the same start; AFD per
  case, success (true AFD < 3 px), adjustments, rig time.
* **table5**: the same cases with rACR's serial loop: parallel over serial rig time.
* **fig7**: the indoor scenes with the reference under the LED at 12 o'clock and
  the visit under the LED at 1-12 o'clock, rACR and ACR.
* **table3**: rACR without hand-eye (``X = I``) on the same cases (paper Table 3,
  ``rACR_w/oX``; ACR always takes ``X = I``).
* **revisit**: rACR with the guided exploration (issue 21, item 3), parallel and
  serial, on the same cases.

Resumable: every run's result is written atomically as
``<out>/runs/<experiment>/<case>__<label>.json`` and a re-run skips the runs
whose file exists (the worlds, calibrated once, are reused too). The summary
and ``<out>/paper.md`` (tables) and ``<out>/*.png`` (figures) are rebuilt from
*all* the run files in ``<out>`` at the end of every invocation (so several
invocations, e.g. ``--quick`` then ``--experiment revisit``, add up).
"""

from __future__ import annotations

import json
import math
import statistics
from pathlib import Path

from fgcd_cli.bench.paper_runs import RunSpec, World, ensure_station, ensure_world, run_one
from fgcd_cli.bench.relocate import CASES
from fgcd_cli.campaign.atomic import atomic_write_json
from fgcd_cli.relocation.enums import LoopMode, RelocationMethod

__all__ = ["EXPERIMENTS", "QUICK", "plan", "run", "summarise"]

EXPERIMENTS = ("table2", "table5", "fig7", "table3", "revisit")
#: ``--quick``: a subset sized for <= 30 min on 2 cores (docs/benchmarks.md has the measured time).
QUICK = {"cases": ("indoor-2", "outdoor-1"), "fig7_scenes": ("relief_panel",), "fig7_clock": (3, 6, 9)}
FIG7_REFERENCE = "led:12"
FIG7_OFFSET = (30.0, 3.0)  # mm, deg: the start of the 20 cases' median


def _world(case) -> World:
    return World(name=f"{case.scene}-{case.seed}", scene=case.scene, seed=case.seed,
                 calibration_light=case.reference_light)


def _case_runs(experiments: tuple[str, ...], cases) -> list[RunSpec]:
    """Table 2 (rACR and ACR), Table 5 (rACR serial), Table 3 (rACR without hand-eye) on the relocation cases."""
    runs = []
    racr, par, ser = RelocationMethod.RACR, LoopMode.PARALLEL, LoopMode.SERIAL
    variants = {"table2": [("racr", racr, par, False, False), ("acr", RelocationMethod.ACR, par, False, False)],
                "table5": [("racr-serial", racr, ser, False, False)],
                "table3": [("racr-no-handeye", racr, par, True, False)],
                "revisit": [("racr-guided", racr, par, False, True), ("racr-serial-guided", racr, ser, False, True)]}
    for case in cases:
        for experiment in experiments:
            for label, method, mode, no_x, guided in variants.get(experiment, []):
                runs.append(RunSpec(experiment=experiment, case=case.name, label=label, world=_world(case),
                                    reference_light=case.reference_light, visit_light=case.visit_light,
                                    offset_mm=case.offset_mm, offset_deg=case.offset_deg, method=method, mode=mode,
                                    no_handeye=no_x, guided=guided))
    return runs


def _fig7_runs(scenes: tuple[str, ...], clock: tuple[int, ...]) -> list[RunSpec]:
    """Fig. 7: each indoor scene's world (its first indoor case), reference at 12 o'clock, visit at each hour."""
    runs = []
    for scene in scenes:
        case = next(c for c in CASES if c.scene == scene and c.name.startswith("indoor"))
        for hour in clock:
            for label, method in (("racr", RelocationMethod.RACR), ("acr", RelocationMethod.ACR)):
                runs.append(RunSpec(experiment="fig7", case=f"{scene}-led{hour}", label=label, world=_world(case),
                                    reference_light=FIG7_REFERENCE, visit_light=f"led:{hour}",
                                    offset_mm=FIG7_OFFSET[0], offset_deg=FIG7_OFFSET[1], method=method))
    return runs


def plan(*, quick: bool, experiments: tuple[str, ...] = ("table2", "table5", "fig7"),
         cases: list[str] | None = None) -> list[RunSpec]:
    """Every run of the invocation, in order (worlds grouped, so each is set up once)."""
    chosen = [c for c in CASES if (cases and c.name in cases) or (not cases and (not quick or c.name in QUICK["cases"]))]
    runs = _case_runs(tuple(e for e in experiments if e != "fig7"), chosen)
    if "fig7" in experiments:
        indoor = tuple(dict.fromkeys(c.scene for c in CASES if c.name.startswith("indoor")))
        scenes = QUICK["fig7_scenes"] if quick else indoor
        runs += _fig7_runs(scenes, QUICK["fig7_clock"] if quick else tuple(range(1, 13)))
    return runs


def _load(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None  # missing or torn (never: atomic writes): run it


def run(*, quick: bool, out: Path, experiments: tuple[str, ...] = ("table2", "table5", "fig7"),
        cases: list[str] | None = None, say=lambda _m: None, on_progress=None) -> dict:
    """Run (or resume) the experiments; returns ``{"summary", "targets", "paper", "runs", "out"}``."""
    from fgcd_cli.bench.paper_report import write_report

    out = Path(out)
    runs = plan(quick=quick, experiments=experiments, cases=cases)
    results, worlds = [], {}
    for i, spec in enumerate(runs):
        if on_progress is not None:
            on_progress(i, len(runs), f"{spec.experiment} {spec.case} {spec.label}")
        done = _load(spec.path(out))
        if done is None:
            done = _run_spec(spec, out, worlds, say)
            atomic_write_json(spec.path(out), done)
        results.append(done)
    if on_progress is not None:
        on_progress(len(runs), len(runs), "done")
    # the folder is the record: the summary and the report cover every run in it (earlier invocations too)
    results = [r for r in (_load(p) for p in sorted((out / "runs").glob("*/*.json"))) if r is not None]
    summary = summarise(results)
    data = {"summary": summary, "targets": TARGETS, "paper": PAPER, "runs": results, "out": str(out)}
    write_report(data, out)
    return data


def _run_spec(spec: RunSpec, out: Path, worlds: dict, say) -> dict:
    """One run, with its world and station set up first (once per invocation, or reused from disk)."""
    from fgcd_cli.errors import FgcdError

    try:
        if spec.world.name not in worlds:
            worlds[spec.world.name] = ensure_world(spec.world, out, say=say)
        camp, X, camera = worlds[spec.world.name]
        station = ensure_station(camp, spec.world, spec.reference_light, X, camera, say=say)
    except FgcdError as exc:
        say(f"{spec.world.name}: set-up failed: {exc}")
        return {"experiment": spec.experiment, "case": spec.case, "label": spec.label, "method": str(spec.method),
                "error": f"setup: {exc}", "success": False, "afd_px": None}
    return run_one(spec, camp, station, X, camera, say=say)


# ----------------------------------------------------------------------------- summary
#: The paper's published figures (paper 000, Tables 2, 3, 5) beside ours.
PAPER = {"racr_success": "20/20", "racr_mean_afd_px": 1.46, "racr_mean_iterations": 5.3, "racr_mean_rig_s": 61.1,
         "acr_success": "6/20", "acr_mean_afd_px": 20.1, "acr_mean_iterations": 18.6, "acr_mean_rig_s": 316.7,
         "parallel_rig_s": 59.5, "serial_rig_s": 84.6}
#: Issue 21's targets.
TARGETS = {"racr_success_rate": 1.0, "racr_mean_afd_px": 0.5, "racr_mean_rig_s": 30.0, "led_sweep_success_rate": 1.0}


def _mean(values) -> float:
    xs = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    return float(statistics.fmean(xs)) if xs else math.nan


def _rows(results: list[dict], experiment: str, label: str) -> list[dict]:
    return [r for r in results if r.get("experiment") == experiment and r.get("label") == label]


def _method_summary(rows: list[dict], prefix: str) -> dict:
    ok = [r for r in rows if "error" not in r]
    return {
        f"{prefix}_runs": len(rows),
        f"{prefix}_success_rate": sum(bool(r.get("success")) for r in rows) / len(rows) if rows else math.nan,
        f"{prefix}_mean_afd_px": _mean(r.get("afd_px") for r in rows),
        f"{prefix}_mean_iterations": _mean(r.get("adjustments") for r in ok),
        f"{prefix}_mean_rig_s": _mean(r.get("session_s") for r in ok),
        f"{prefix}_mean_platform_s": _mean(r.get("platform_s") for r in ok),
        # AFD hides a sideways shift that a small turn compensates: the true camera-position error beside it
        f"{prefix}_mean_pose_err_mm": _mean(r.get("pose_err_mm") for r in rows),
        f"{prefix}_max_pose_err_mm": max((float(r["pose_err_mm"]) for r in rows if r.get("pose_err_mm") is not None),
                                          default=math.nan),
    }


def summarise(results: list[dict]) -> dict:
    """The issue's summary keys from the run files (means over the runs that exist)."""
    summary = {}
    summary.update(_method_summary(_rows(results, "table2", "racr"), "racr"))
    summary.update(_method_summary(_rows(results, "table2", "acr"), "acr"))
    serial = _rows(results, "table5", "racr-serial")
    parallel = [r for r in _rows(results, "table2", "racr") if r["case"] in {s["case"] for s in serial}]
    summary.update(_method_summary(serial, "racr_serial"))
    par_s = _mean(r.get("session_s") for r in parallel if "error" not in r)
    ser_s = summary["racr_serial_mean_rig_s"]
    summary["parallel_over_serial_speedup"] = ser_s / par_s if par_s > 0 else math.nan
    summary.update(_method_summary(_rows(results, "table3", "racr-no-handeye"), "racr_no_handeye"))
    summary.update(_method_summary(_rows(results, "revisit", "racr-guided"), "racr_guided"))
    summary.update(_method_summary(_rows(results, "revisit", "racr-serial-guided"), "racr_serial_guided"))
    sweep = _rows(results, "fig7", "racr")
    summary["led_sweep_runs"] = len(sweep)
    summary["led_sweep_success_rate"] = (sum(bool(r.get("success")) for r in sweep) / len(sweep)) if sweep else math.nan
    acr_sweep = _rows(results, "fig7", "acr")
    summary["acr_led_sweep_success_rate"] = (sum(bool(r.get("success")) for r in acr_sweep) / len(acr_sweep)
                                             if acr_sweep else math.nan)
    return summary
