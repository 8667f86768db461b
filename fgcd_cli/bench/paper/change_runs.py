"""Paper 000 §5.5 in the simulator: change detection after rACR against after ACR.

Each Table 2 run wrote a visit of a world with three injected fine-grained
changes. Here that visit is compared with its reference by the campaign diff
(``fgcd diff -c ... -s ... --visit ...``, the same use case) and its change map
is scored against the simulator's truth (evaluation only). A relocation that
stopped off the reference leaves parallax and misregistration that the
detector reports as change or hides changes behind: F1 after each method says
what the relocation is worth to the conservator.
"""

from __future__ import annotations

from pathlib import Path

from fgcd_cli.bench.paper.runs import VISIT_CHANGES, RunSpec, ensure_world, load_run, station_name, visit_scenario
from fgcd_cli.campaign.atomic import atomic_write_json

__all__ = ["score_visits"]


def _score(spec: RunSpec, run: dict, out: Path, worlds: dict, say) -> dict:
    """Diff one run's visit and score its change map."""
    from fgcd_cli.app.diff import CampaignDiffRequest, run_campaign
    from fgcd_cli.app.sim_scoring import score_visit_changes

    if spec.world.name not in worlds:
        worlds[spec.world.name] = ensure_world(spec.world, out, say=say)
    camp, X, camera = worlds[spec.world.name]
    station = camp.station(station_name(spec.reference_light))
    diff = run_campaign(CampaignDiffRequest(campaign=camp.path, station=station.name, visit=run["visit"]))
    w = spec.world
    row = {
        "experiment": "s55",
        "case": spec.case,
        "label": spec.label,
        "method": run.get("method"),
        "scene": w.scene,
        "afd_px": run.get("afd_px"),
        "pose_err_mm": run.get("pose_err_mm"),
        "relocation_success": run.get("success"),
        "comparable": diff.get("comparable"),
        "regions": len(diff.get("regions", [])),
    }
    if diff.get("comparable", True):
        row.update(
            score_visit_changes(
                station.visit(run["visit"]),
                station,
                scenario=visit_scenario(spec),
                X=X,
                camera=camera,
                injected=VISIT_CHANGES["changes"],
            )
        )
    else:
        row["f1"] = 0.0  # the diff refused the pair: nothing detected is nothing found
    say(f"s55 {spec.case} {spec.label}: change F1 {row.get('f1', float('nan')):.2f} after AFD {row['afd_px']:.2f} px")
    return row


def score_visits(specs: list[RunSpec], out: Path, *, worlds: dict, say) -> list[dict]:
    """Score the visit of every run of ``specs`` that wrote one; resumable like the runs.

    Returns the rows, written as ``<out>/runs/s55/<case>__<label>.json``.
    """
    rows = []
    for spec in specs:
        run = load_run(spec.path(out))
        if run is None or "error" in run or not run.get("visit"):
            continue
        path = out / "runs" / "s55" / f"{spec.case}__{spec.label}.json"
        row = load_run(path)
        if row is None:
            row = _score(spec, run, out, worlds, say)
            atomic_write_json(path, row)
        rows.append(row)
    return rows
