"""Relocate one simulated station several times with the same seeds; print how much the outcome varies.

    .venv/bin/python scripts/relocation_spread.py --runs 3                  # parallel loop (varies)
    .venv/bin/python scripts/relocation_spread.py --runs 2 --deterministic  # stepped in turn (identical)

The station is the small one of tests/relocation/test_deterministic.py (relief_panel, seed 1, hand-eye
identity, reference under 'front'); each visit starts 20 mm / 2 deg away under 'led:3' with session seed 2,
the 3D loop only (no image stage). Figures: docs/relocation.md, "Reproducibility".
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--deterministic", action="store_true")
    args = parser.parse_args()
    if args.deterministic:
        from fgcd_cli.app.determinism import pin_native_threads

        pin_native_threads()
    from fgcd_cli.app.relocate import relocate_and_capture
    from fgcd_cli.app.relocate_request import RelocateHooks, RelocateRequest
    from fgcd_cli.app.rig import open_sim_rig
    from fgcd_cli.app.scenario import SimScenario
    from fgcd_cli.metrics.sim_eval import RelocationEvaluator
    from fgcd_cli.relocation.config import RelocationConfig

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from tests.relocation.test_deterministic import _simulated_station

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        station = _simulated_station(Path(tmp))
        for i in range(args.runs):
            rig = open_sim_rig(
                SimScenario(
                    scene="relief_panel",
                    seed=1,
                    lighting="led:3",
                    start_offset_mm=20,
                    start_offset_deg=2,
                    session_seed=2,
                ),
                T_flange_cam=None,
                intrinsics=None,
            )
            ev = RelocationEvaluator.from_reference(rig.sim, station.reference())
            t0 = time.monotonic()
            try:
                out = relocate_and_capture(
                    rig.handles,
                    station,
                    RelocateRequest(
                        config=RelocationConfig(
                            deterministic=args.deterministic, image_refine=False, image_fallback=False
                        ),
                        lightings=["led:3"],
                    ),
                    hooks=RelocateHooks(),
                )
                truth = ev.evaluate()
            finally:
                rig.close()
            r = out.relocation
            rows.append(
                {
                    "run": i + 1,
                    "adjustments": r.adjustments,
                    "pose_err_mm": round(truth["pose_err_mm"], 3),
                    "afd_px": round(truth["afd_px"], 3),
                    "session_s": round(r.session_s, 2),
                    "final_T_ref_cam": [round(v, 9) for v in r.final_T_ref_cam.ravel().tolist()],
                    "wall_s": round(time.monotonic() - t0, 1),
                }
            )
            print(json.dumps({k: v for k, v in rows[-1].items() if k != "final_T_ref_cam"}), flush=True)
    errs = [r["pose_err_mm"] for r in rows]
    print(
        json.dumps(
            {
                "deterministic": args.deterministic,
                "runs": len(rows),
                "pose_err_mm_spread": round(max(errs) - min(errs), 3),
                "pose_err_mm_stdev": round(statistics.pstdev(errs), 3),
                "adjustments": sorted({r["adjustments"] for r in rows}),
                "identical_final_poses": len({tuple(r["final_T_ref_cam"]) for r in rows}) == 1,
            }
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
