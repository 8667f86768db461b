"""`fgcd bench coarse`: the active coarse stage (paper 001) on far starts.

Each case: a world (scene + seed), a target-free hand-eye calibration and a
reference capture as in ``fgcd bench relocate``, then two revisits of the
same reference under another light from the same kind of far start (15-23 cm,
8-20 deg, beyond rACR's usual few centimetres): one with the coarse stage,
one without (the rACR loop alone, which pauses on an estimate that far and
lets its image fallback try). Summary keys:

* ``coarse_success_rate``: the stage handed over with the camera truly within
  5 cm / 5 deg of the reference (the paper's success criterion);
* ``success_rate`` / ``baseline_success_rate``: true AFD < 3 px at the end of
  the whole relocation, with / without the stage;
* ``confident_wrong_runs``: runs that said "converged" while truly more than
  1 px (AFD) or 5 mm away (truth, evaluation only);
* ``handover_rate``: the stage handed over to the rACR loop, over the cases
  where it ran (``coarse_ran``);
* ``mean_coarse_steps``, ``mean_afd_px``, ``mean_sim_time_s`` (rig-time model
  of ``fgcd bench relocate``).
"""

from __future__ import annotations

import math
import statistics
import tempfile
from pathlib import Path

from fgcd_cli.bench.relocate import Case, _run_case, confident_wrong, handover_summary
from fgcd_cli.relocation.enums import LoopMode

__all__ = ["CASES", "run"]

CASES: list[Case] = [
    # Far starts, measured at the camera. The simulated platform's workspace is its home +- 250 mm
    # and a far start displaces the base: beyond ~230 mm the reference pose leaves the workspace.
    Case("far-1", "mural", 8, "front", "led:2", 200, 15),
    Case("far-2", "relief_panel", 1, "front", "led:9", 220, 10),
    Case("far-3", "stupa", 3, "front", "led:6", 150, 20),
    Case("far-4", "stele", 10, "sun-morning", "sun-evening", 180, 12),
    Case("far-5", "statue", 4, "front", "led:1", 160, 15),
    Case("far-6", "bricks", 5, "front", "led:4", 230, 8),
    # scene kinds the stage was never tuned on (issue 25): an overhang seen from below, a lettered slab
    Case("far-7", "cornice", 21, "front", "led:5", 170, 10),
    Case("far-8", "lettered_slab", 22, "sun-noon", "sun-afternoon", 160, 12),
]
QUICK = ["far-1", "far-2"]


def _summarise(results: list[dict], label: str) -> dict:
    rows = [r[label] for r in results if label in r]
    ok = [r for r in rows if "error" not in r]
    mean = lambda xs: float(statistics.fmean(xs)) if xs else float("nan")  # noqa: E731
    return {
        "success_rate": sum(bool(r.get("success")) for r in rows) / max(1, len(results)),
        "converged_runs": sum(bool(r.get("converged")) for r in rows),
        "confident_wrong_runs": sum(confident_wrong(r) for r in rows),
        "mean_afd_px": mean([r["afd_px"] for r in rows if math.isfinite(r.get("afd_px", float("nan")))]),
        "mean_iterations": mean([r["adjustments"] for r in ok]),
        "mean_sim_time_s": mean([r["session_s"] for r in ok]),
    }


def _coarse_ok(row: dict) -> bool:
    c = row.get("coarse") or {}
    mm, deg = c.get("end_err_mm"), c.get("end_err_deg")
    return bool(c.get("handed_over")) and mm is not None and deg is not None and mm <= 50.0 and deg <= 5.0


def run(
    *,
    quick: bool,
    baseline: bool = True,
    say=lambda _m: None,
    cases: list[str] | None = None,
    deterministic: bool = False,
) -> dict:
    """Run the benchmark; returns ``{"summary": ..., "cases": [...]}`` (``deterministic``: threads stepped in turn)."""
    from fgcd_cli.relocation.coarse.config import CoarseConfig

    chosen = [c for c in CASES if (cases and c.name in cases) or (not cases and (not quick or c.name in QUICK))]
    runs = [("coarse", LoopMode.PARALLEL, CoarseConfig())] + (
        [("baseline", LoopMode.PARALLEL, None)] if baseline else []
    )
    results = []
    with tempfile.TemporaryDirectory(prefix="fgcd-bench-coarse-") as tmp:
        for case in chosen:
            say(f"case {case.name}: {case.scene}, start {case.offset_mm:.0f} mm / {case.offset_deg:.0f} deg away")
            results.append(_run_case(case, Path(tmp), modes=[], runs=runs, say=say, deterministic=deterministic))
    with_stage = _summarise(results, "coarse")
    rows = [r["coarse"] for r in results if "coarse" in r]
    ran = [r for r in rows if r.get("coarse")]
    summary = {
        "cases": len(results),
        "coarse_success_rate": sum(_coarse_ok(r) for r in rows) / max(1, len(results)),
        **handover_summary(rows),
        "mean_coarse_steps": (statistics.fmean([r["coarse"]["steps"] for r in ran]) if ran else float("nan")),
        **with_stage,
    }
    if baseline:
        summary.update({f"baseline_{k}": v for k, v in _summarise(results, "baseline").items()})
    return {
        "summary": summary,
        "targets": {"coarse_success_rate": 0.9, "success_rate": 0.9, "confident_wrong_runs": 0},
        "cases": results,
    }
