"""Experiment (issue 47, item 3): campaign diffs of a ``fgcd bench paper`` run's visits, by the homography and by
the reference depth, scored against the simulator's truth (evaluation only).

Reproduces the figures of docs/change-detection.md, "Geometry of a campaign diff"
(``docs/lab/figures/s57/campaign_geometry_paper_visits.jsonl``). It re-diffs every stored visit of a
run folder in place (``--force``): give it a copy.

    .venv/bin/fgcd bench paper --quick --json --out OUT
    cp -r OUT COPY && .venv/bin/python scripts/experiments/campaign_geometry_visits.py COPY

One JSON line per visit: the true distance of the visit camera from the reference, the pose the diff
measured and its error, the fraction of depth edges, change F1 and false regions with each warp.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from fgcd_cli.app.diff import CampaignDiffRequest, run_campaign
from fgcd_cli.app.sim_scoring import score_visit_changes
from fgcd_cli.bench.paper.plan import plan
from fgcd_cli.bench.paper.runs import VISIT_CHANGES, ensure_world, load_run, station_name, visit_scenario


def _visit_row(spec, run: dict, world) -> dict:
    camp, X, camera = world
    station = camp.station(station_name(spec.reference_light))
    visit = station.visit(run["visit"])
    truth_visit, truth_ref = (
        visit.json("evaluation/sim_truth.json"),
        station.reference().json("evaluation/sim_truth.json"),
    )
    T_true = np.linalg.inv(np.array(truth_visit["T_world_cam"])) @ np.array(truth_ref["T_world_cam"])
    row = {
        "run": f"{spec.experiment}/{spec.case}/{spec.label}",
        "light": f"{spec.reference_light}->{spec.visit_light}",
        "true_t_mm": round(float(np.linalg.norm(T_true[:3, 3]) * 1e3), 2),
    }
    for geometry in (False, True):
        data = run_campaign(
            CampaignDiffRequest(
                campaign=camp.path, station=station.name, visit=run["visit"], geometry=geometry, force=True
            )
        )
        scores = score_visit_changes(
            station.visit(run["visit"]),
            station,
            scenario=visit_scenario(spec),
            X=X,
            camera=camera,
            injected=VISIT_CHANGES["changes"],
        )
        row["geo" if geometry else "H"] = {
            "f1": round(scores.get("f1", 0.0), 3),
            "false": scores.get("false_regions"),
            "regions": len(data.get("regions", [])),
        }
        geo = data["settings"].get("geometry", {}) if geometry else {}
        if "T_cur_ref" in geo:
            T = np.array(geo["T_cur_ref"])
            row.update(
                pnp_mm=geo["residual_pose_mm"],
                pnp_err_mm=round(float(np.linalg.norm(T[:3, 3] - T_true[:3, 3]) * 1e3), 3),
                edge_frac=geo["depth_edge_fraction"],
                inl=geo["pnp_inliers"],
            )
        elif geometry:
            row["pnp"] = geo
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="a copy of a fgcd bench paper --out folder")
    args = parser.parse_args()
    specs = {(s.experiment, s.case, s.label): s for s in plan(quick=False)}
    worlds: dict = {}
    for path in sorted((args.out / "runs").glob("*/*.json")):
        run = load_run(path)
        spec = specs.get((path.parent.name, *path.stem.split("__")))
        if path.parent.name == "s55" or not run or not run.get("visit") or spec is None:
            continue
        if spec.world.name not in worlds:
            worlds[spec.world.name] = ensure_world(spec.world, args.out, say=lambda *_: None)
        print(json.dumps(_visit_row(spec, run, worlds[spec.world.name])), flush=True)


if __name__ == "__main__":
    main()
