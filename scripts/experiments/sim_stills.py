"""Experiment (simulator realism): false change regions of an unchanged niche against the stills' samples per pixel.

Reproduces the table in docs/lab/2026-11-22-render.md, "Simulated stills". The demo's
scene (``relief_panel``, a niche whose side walls are seen edge-on, 1-2 px
wide) is rendered at its default view and again 0.4 mm / 0.013 deg away (the
demo's relocation residual) in a random direction, under the same light, with
the sensor's noise, and nothing changed; ``detect_changes`` with the campaign
diff's region-level edge check counts the regions it reports (all false).

    .venv/bin/python scripts/experiments/sim_stills.py [--samples 1,2,3] [--trials 8]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from fgcd_cli.app.diff_options import EDGE_CHECK_PX
from fgcd_cli.changes.config import DetectionConfig
from fgcd_cli.changes.detect import detect_changes
from fgcd_cli.changes.regions import pixel_area_from_depth
from fgcd_core.camera import CameraIntrinsics
from fgcd_core.se3 import exp_se3
from fgcd_drivers.sim.render import Renderer
from fgcd_drivers.sim.scenes import load_scene
from fgcd_drivers.sim.sensor import CameraEffects

INTRINSICS = CameraIntrinsics(fx=600.0, fy=600.0, cx=319.5, cy=239.5, width=640, height=480)
EFFECTS = CameraEffects(read_noise=0.003, shot_noise=0.004, vignetting=0.2)


def trials(samples: int, n: int) -> dict:
    scene = load_scene("relief_panel")
    renderer = Renderer(scene, supersample=samples)
    T_ref = np.asarray(scene.default_T_world_cam, float)
    geometry = renderer.render(T_ref, INTRINSICS, None, want=("depth", "labels"))
    area = pixel_area_from_depth(np.where(geometry.depth > 0, geometry.depth, np.nan), INTRINSICS.K)
    config = DetectionConfig.from_options(edge_check_px=EDGE_CHECK_PX)
    rows = []
    for seed in range(n):
        rng = np.random.default_rng(seed)
        t0 = time.perf_counter()
        ref = [renderer.render(T_ref, INTRINSICS, "front", effects=EFFECTS, exposure=4.0, rng=rng, want=("rgb",)).rgb]
        render_s = time.perf_counter() - t0
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        xi = np.r_[direction * 0.4e-3, rng.normal(size=3) / np.sqrt(3) * np.deg2rad(0.013)]
        cur = [
            renderer.render(
                T_ref @ exp_se3(xi), INTRINSICS, "front", effects=EFFECTS, exposure=4.0, rng=rng, want=("rgb",)
            ).rgb
        ]
        result = detect_changes(ref, cur, roi=geometry.labels == 1, pixel_area_mm2=area, config=config)
        rows.append(
            {
                "seed": seed,
                "false_regions": len(result.regions),
                "set_aside": int(result.settings.get("edge_explained_regions", 0)),
                "render_s": render_s,
            }
        )
    return {
        "samples_per_axis": samples,
        "trials": rows,
        "false_regions_total": sum(r["false_regions"] for r in rows),
        "pairs_with_false_regions": sum(r["false_regions"] > 0 for r in rows),
        "render_s_median": float(np.median([r["render_s"] for r in rows])),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", default="1,2,3")
    parser.add_argument("--trials", type=int, default=8)
    args = parser.parse_args()
    for s in (int(v) for v in args.samples.split(",")):
        out = trials(s, args.trials)
        print(json.dumps({k: v for k, v in out.items() if k != "trials"}), flush=True)


if __name__ == "__main__":
    main()
