"""Experiment (issue 19, not adopted): the a-contrario epsilon as a third leave-one-group-out constant.

Reproduces the table of docs/lab/2026-11-25-changes-leave-one-group-out.md, "The a-contrario ε as a
third leave-one-group-out constant" (epsilon chosen leave one group out). Each real group is scored
once with the shipped detector; the decision is then taken over the grid
seed_p x extent_fraction x epsilon and every group is scored with the point
that has the best mean auto F1 on the other six (the bench's own procedure,
fgcd_cli.bench.changes.main.leave_one_group_out, with epsilon added to its grid).
The simulated pairs of `fgcd bench changes` are then decided with a given point.

    .venv/bin/python scripts/experiments/changes_epsilon_grid.py real [--eps 1,10,100]
    .venv/bin/python scripts/experiments/changes_epsilon_grid.py sim SEED_P EXTENT EPSILON
"""

from __future__ import annotations

import argparse
import json

import cv2
import numpy as np

from fgcd_cli.bench.changes.main import DATASET, find_groups, group_lightings
from fgcd_cli.changes.config import DecisionRule, RegionConfig
from fgcd_cli.changes.detect import detect_changes
from fgcd_cli.changes.io import read_image as _read_rgb
from fgcd_cli.changes.region_decision import decide
from fgcd_cli.metrics.change_scores import binary_scores


def real(eps_values: list[float]) -> None:
    grid = [(s, e, eps) for s in (0.002, 0.005, 0.01) for e in (0.2, 0.3, 0.4) for eps in eps_values]
    scores: dict[tuple[str, tuple], tuple[float, float, float]] = {}
    names = []
    for folder in find_groups(DATASET):
        lightings = group_lightings(folder)
        ref = [_read_rgb(folder / f"2-{k}.png") for k in lightings]
        cur = [_read_rgb(folder / f"1-{k}.png") for k in lightings]
        truth = cv2.imread(str(folder / "GT.png"), cv2.IMREAD_GRAYSCALE) > 127
        mask = cv2.imread(str(folder / "mask.png"), cv2.IMREAD_GRAYSCALE) > 127
        result = detect_changes(ref, cur, roi=mask)
        names.append(folder.name)
        for key in grid:
            config = RegionConfig(
                decision=DecisionRule.ACONTRARIO, seed_p=key[0], extent_fraction=key[1], epsilon=key[2]
            )
            changed, _, _ = decide(result.score, result.valid, config=config)
            b = binary_scores(changed, truth, eval_mask=mask)
            scores[(folder.name, key)] = (b.f1, b.precision, b.recall)
    rows = []
    for held in names:
        others = [n for n in names if n != held]
        chosen = max(grid, key=lambda k: (np.mean([scores[(n, k)][0] for n in others]), -grid.index(k)))
        rows.append({"group": held, "chosen": chosen, "f1_p_r": scores[(held, chosen)]})
    deployed = max(grid, key=lambda k: (np.mean([scores[(n, k)][0] for n in names]), -grid.index(k)))
    print(
        json.dumps(
            {
                "groups": rows,
                "logo_auto_f1": float(np.mean([r["f1_p_r"][0] for r in rows])),
                "logo_min_auto_recall": float(min(r["f1_p_r"][2] for r in rows)),
                "deployed": deployed,
            },
            indent=1,
        )
    )


def sim(seed_p: float, extent: float, epsilon: float) -> None:
    from fgcd_cli.bench.changes.simulated import run_sim

    options = {"decision": DecisionRule.ACONTRARIO, "seed_p": seed_p, "extent_fraction": extent, "epsilon": epsilon}
    out = run_sim(quick=False, detector_options=options)
    print(json.dumps({k: v for k, v in out.items() if k.startswith("sim_")}, default=str))


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest="part", required=True)
    p_real = sub.add_parser("real")
    p_real.add_argument("--eps", default="1,10,100")
    p_sim = sub.add_parser("sim")
    for name in ("seed_p", "extent", "epsilon"):
        p_sim.add_argument(name, type=float)
    args = parser.parse_args()
    if args.part == "real":
        real([float(x) for x in args.eps.split(",")])
    else:
        sim(args.seed_p, args.extent, args.epsilon)
