"""Benchmark of fine-grained change detection (``fgcd bench changes``).

(a) The real FGCD dataset (Feng et al., ICCV 2015; groups Db-1..Db-5 in
``../shared/data/fgcd-dataset``): observation 2 is the reference (GT is aligned
with it), observation 1 the current one, all 7 lightings; scores inside
``mask.png``. (b) Simulated pairs with injected changes under a lighting change
and a relocation residual, plus unchanged pairs (false regions), when the
simulator is available. Evaluation reads ground truth; the detector does not.
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from fgcd_cli.changes import detect_changes
from fgcd_cli.metrics.change_scores import binary_scores, sweep_scores

DATASET = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "fgcd-dataset" / "Db"
GROUPS = ("Db-1", "Db-2", "Db-3", "Db-4", "Db-5")


def _read_rgb(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise FileNotFoundError(path)
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def run_real(*, quick: bool, dataset: Path = DATASET, overlay_dir: Path | None = None) -> dict:
    """Part (a): per-group and mean scores on the real dataset (quick: lightings 1, 3, 5 only)."""
    if not dataset.is_dir():
        return {"available": False, "reason": f"dataset not found at {dataset.resolve()}"}
    lightings = (1, 3, 5) if quick else tuple(range(1, 8))
    groups = []
    for group in GROUPS:
        folder = dataset / group
        ref = [_read_rgb(folder / f"2-{k}.png") for k in lightings]
        cur = [_read_rgb(folder / f"1-{k}.png") for k in lightings]
        truth = cv2.imread(str(folder / "GT.png"), cv2.IMREAD_GRAYSCALE) > 127
        mask = cv2.imread(str(folder / "mask.png"), cv2.IMREAD_GRAYSCALE) > 127
        t0 = time.perf_counter()
        result = detect_changes(ref, cur, eval_mask=mask)
        seconds = time.perf_counter() - t0
        auto = binary_scores(result.mask, truth, eval_mask=mask)
        sweep = sweep_scores(result.score, truth, eval_mask=mask)
        groups.append({
            "group": group,
            "best_f1": sweep.best_f1,
            "ap": sweep.average_precision,
            "auto_f1": auto.f1,
            "auto_precision": auto.precision,
            "auto_recall": auto.recall,
            "auto_iou": auto.iou,
            "changed_fraction_true": float(truth[mask].mean()),
            "changed_fraction_found": result.changed_fraction,
            "regions": len(result.regions),
            "ecc_correlation": result.registration.ecc_correlation if result.registration else None,
            "seconds": seconds,
        })
        if overlay_dir is not None:
            from fgcd_cli.report.figures import change_overlay, png_bytes

            overlay = change_overlay(ref[0], result.labels, result.regions, valid=result.valid)
            # Ground truth outline in green for the benchmark figure.
            contours, _ = cv2.findContours((truth & mask).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            cv2.drawContours(overlay, contours, -1, (0, 255, 0), 1)
            overlay_dir.mkdir(parents=True, exist_ok=True)
            (overlay_dir / f"changes_{group}.png").write_bytes(png_bytes(cv2.resize(overlay, (352, 349), interpolation=cv2.INTER_AREA)))
    mean = lambda key: float(np.mean([g[key] for g in groups]))  # noqa: E731
    return {
        "available": True,
        "lightings": list(lightings),
        "groups": groups,
        "fgcd_best_f1": mean("best_f1"),
        "fgcd_ap": mean("ap"),
        "fgcd_auto_f1": mean("auto_f1"),
        "fgcd_auto_precision": mean("auto_precision"),
        "fgcd_auto_recall": mean("auto_recall"),
    }


def run(*, quick: bool, overlay_dir: Path | None = None) -> dict:
    """Run the change-detection benchmark; returns ``{"summary": {...}, "real": ..., "sim": ...}``."""
    real = run_real(quick=quick, overlay_dir=overlay_dir)
    summary = {}
    if real.get("available"):
        summary.update({k: real[k] for k in ("fgcd_best_f1", "fgcd_ap", "fgcd_auto_f1")})
    sim = None
    try:
        from fgcd_cli.bench.changes_sim import run_sim
    except ImportError as exc:  # the simulator part needs drivers.sim
        sim = {"available": False, "reason": f"simulator part unavailable: {exc}"}
    else:
        sim = run_sim(quick=quick)
        if sim.get("available"):
            summary.update({k: sim[k] for k in ("sim_auto_f1", "sim_false_regions_unchanged", "sim_max_false_region_mm2")})
            summary.update({k: v for k, v in sim.items() if k.startswith("sim_relocated_")})
    targets = {"fgcd_best_f1": 0.65, "fgcd_auto_f1": 0.55, "sim_auto_f1": 0.8}
    return {
        "benchmark": "changes",
        "quick": quick,
        "summary": summary,
        "targets": targets,
        "real": real,
        "sim": sim,
        "dataset_citation": "W. Feng et al., Fine-Grained Change Detection of Misaligned Scenes with Varied Illuminations, ICCV 2015",
    }
