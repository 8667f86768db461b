"""Benchmark of fine-grained change detection (``fgcd bench changes``).

(a) The real FGCD dataset (Feng et al., ICCV 2015; every group under
``../shared/data/fgcd-dataset/<kind>/``: Db-1..5 test blocks, Dp-1 relief, Ds-1
statue): observation 2 is the reference (GT is aligned with it), observation 1
the current one, every lighting both hold. Each pair is detected as the user
runs it (:func:`user_detection`: ``fgcd diff --ref 2-*.png --cur 1-*.png``, its
defaults, no region of interest) and scored inside ``mask.png``, the annotators'
region, which reaches no decision; the same with ``--roi mask.png`` is reported
beside (``roi_*``). Scored
**leave one group out**: the decision's data-chosen constants are selected on
the other groups (best mean auto F1 over a small grid) and the held-out group is
scored with them; the in-sample figures are reported beside, as a reference only.
``lokind_*``: the same with the constants chosen on the other *kinds'* groups only.
Each pair is scored once with the shipped defaults (timed end to end, reading
the files and the FDF included); the decision rules are then applied to that score. Beside it, as references scored
the same way: the former tuned hysteresis rule (k chosen leave one group out),
the detector without its dense parallax refinement, and the ICCV 2015 method's
key ideas (:mod:`fgcd_cli.changes.baseline_iccv`, threshold-free best F1 / AP).
The full run also scores the pair with the score's own constants varied one at a
time (``SCORE_GRID``: light-gain window, smoothing) and reports the threshold-free
figures with those chosen leave one group out too (``logo_*_all_constants``).
(b) Simulated pairs with injected changes under a lighting change and a
relocation residual, plus unchanged pairs (false regions), when the simulator is
available. Evaluation reads ground truth; the detector does not.
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from fgcd_cli.bench.changes.evidence import region_evidence, separation
from fgcd_cli.bench.changes.multilight import run_multilight
from fgcd_cli.bench.changes.overlays import write_overlays
from fgcd_cli.bench.paths import FGCD_DATASET
from fgcd_cli.changes.baseline_iccv import iccv2015_score
from fgcd_cli.changes.config import DecisionRule, DetectionConfig, ScoreConfig
from fgcd_cli.changes.detect import detect_changes
from fgcd_cli.changes.images import to_float_image
from fgcd_cli.changes.region_decision import decide_again
from fgcd_cli.changes.registration import warp_to_reference
from fgcd_cli.metrics.change_scores import binary_scores, region_counts, sweep_scores

DATASET = FGCD_DATASET

# Leave-one-group-out grid of the decision's two data-chosen constants (a-contrario:
# seed_p, extent_fraction; epsilon = 1 is fixed by its meaning, and the finer smoothing by the
# score's shift tolerance, not chosen). The same points without the finer scan are scored as a
# reference, alone and with the scan's use chosen leave one group out as well.
FINE_SIGMA_PX = ScoreConfig().fine_smooth_sigma_px
_POINTS = tuple((seed_p, extent) for seed_p in (0.002, 0.005, 0.01) for extent in (0.2, 0.3, 0.4))
_QUICK_POINTS = tuple((seed_p, extent) for seed_p in (0.005, 0.01) for extent in (0.2, 0.3))
GRID = tuple((DecisionRule.ACONTRARIO, seed_p, extent, FINE_SIGMA_PX) for seed_p, extent in _POINTS)
QUICK_GRID = tuple((DecisionRule.ACONTRARIO, seed_p, extent, FINE_SIGMA_PX) for seed_p, extent in _QUICK_POINTS)
SINGLE_SCALE_GRID = tuple((DecisionRule.ACONTRARIO, seed_p, extent, 0.0) for seed_p, extent in _POINTS)
QUICK_SINGLE_SCALE_GRID = tuple((DecisionRule.ACONTRARIO, seed_p, extent, 0.0) for seed_p, extent in _QUICK_POINTS)
# The former tuned rule (median + k sigma, hysteresis), scored the same way as a reference.
HYSTERESIS_GRID = tuple((DecisionRule.HYSTERESIS, k, 0.0) for k in (14.0, 20.0, 28.0))
# The score's own data-set constants (light-gain window, smoothing; px), varied one at a time
# around the shipped (12, 2) in the full run: the threshold-free figures are then also
# reported with these chosen leave one group out (``logo_*_all_constants``).
SCORE_GRID = ((12.0, 2.0), (6.0, 2.0), (24.0, 2.0), (12.0, 1.0), (12.0, 3.0))


def detector_options(key: tuple) -> dict:
    """The detector options of one grid point (:class:`RegionConfig` fields, and the finer smoothing)."""
    rule, a, b, *fine = key
    if rule == DecisionRule.HYSTERESIS:
        return {"decision": rule, "k_high": a, "k_low": a / 2.0}
    return {"decision": rule, "seed_p": a, "extent_fraction": b, **({"fine_smooth_sigma_px": fine[0]} if fine else {})}


def _decide_at(result, ref_images: list[np.ndarray], key: tuple) -> np.ndarray:
    """The changed pixels of a detection's scores decided with one grid point, edge check included as the
    detection ran it (:func:`fgcd_cli.changes.region_decision.decide_again`)."""
    options = detector_options(key)
    options.setdefault("fine_smooth_sigma_px", 0.0)
    config = DetectionConfig.from_options(edge_check_px=int(result.settings.get("edge_check_px", 0)), **options)
    return decide_again(result, ref_images, config)


def find_groups(dataset: Path) -> list[Path]:
    """Every group folder (``<kind>/<group>`` with GT.png and mask.png), sorted by name."""
    return sorted(
        (p.parent for p in dataset.glob("*/*/GT.png") if (p.parent / "mask.png").is_file()), key=lambda p: p.name
    )


def group_lightings(folder: Path) -> list[int]:
    """Lighting indices present in both observations of a group (Ds-1 has no lighting 3)."""
    ref = {int(p.stem.split("-")[1]) for p in folder.glob("2-*.png")}
    cur = {int(p.stem.split("-")[1]) for p in folder.glob("1-*.png")}
    return sorted(ref & cur)


def user_detection(folder: Path, lightings: list[int], *, roi: bool = False):
    """The detection ``fgcd diff --ref 2-*.png --cur 1-*.png`` makes on a group with a user's defaults.

    ``roi``: as ``--roi mask.png`` (the annotators' region given as a region of interest). Without it the
    annotators' mask reaches no decision: it only chooses the scored pixels (docs/benchmarks.md, "changes").
    """
    from fgcd_cli.app.diff import BareDiffRequest, detect_bare

    request = BareDiffRequest(
        ref=[str(folder / f"2-{k}.png") for k in lightings],
        cur=[str(folder / f"1-{k}.png") for k in lightings],
        output=folder / "never-written",
        roi=folder / "mask.png" if roi else None,
    )
    return detect_bare(request)


def _grid_rows(result, ref_images, truth: np.ndarray, mask: np.ndarray, grid: list[tuple], seconds: float) -> dict:
    """Threshold-free and decided scores of one detection at every grid point, scored inside ``mask``."""
    sweep = sweep_scores(result.score, truth, eval_mask=mask)
    rows = {}
    for key in grid:
        changed = _decide_at(result, ref_images, key)
        auto = binary_scores(changed, truth, eval_mask=mask)
        counts = region_counts(changed, truth, eval_mask=mask)
        rows[key] = {
            "changes_true": counts.changes_true,
            "changes_found": counts.changes_found,
            "false_regions": counts.false_regions,
            "best_f1": sweep.best_f1,
            "ap": sweep.average_precision,
            "auto_f1": auto.f1,
            "auto_precision": auto.precision,
            "auto_recall": auto.recall,
            "changed_fraction_found": float(changed[mask].mean()),
            "seconds": seconds,
        }
    return rows


def _score_group(folder: Path, lightings: list[int], grid: list[tuple], score_grid: tuple = ()) -> dict:
    """Score the user's detection of the pair (no ROI; the ROI beside), decide with every grid point; baselines.

    ``score_grid`` lists further (gain window, smoothing) pairs to score threshold-free.
    """
    truth = cv2.imread(str(folder / "GT.png"), cv2.IMREAD_GRAYSCALE) > 127
    mask = cv2.imread(str(folder / "mask.png"), cv2.IMREAD_GRAYSCALE) > 127
    t0 = time.perf_counter()
    found = user_detection(folder, lightings)  # fgcd diff's own path and defaults, end to end (timed)
    seconds = time.perf_counter() - t0
    result, ref, cur = found.result, found.ref_images, found.cur_images
    rows = _grid_rows(result, ref, truth, mask, grid, seconds)
    t0 = time.perf_counter()
    with_roi = user_detection(folder, lightings, roi=True)
    roi_rows = _grid_rows(with_roi.result, with_roi.ref_images, truth, mask, grid, time.perf_counter() - t0)
    # Baselines on the same pair: without the dense refinement, and the
    # ICCV 2015 method's key ideas (normal-aware correction, low rank + sparse).
    no_dense = detect_changes(ref, cur, config=DetectionConfig.from_options(dense=False, cues=False))
    no_dense_sweep = sweep_scores(no_dense.score, truth, eval_mask=mask)
    registered = [warp_to_reference(to_float_image(c), result.registration.H_cur_ref, truth.shape)[0] for c in cur]
    iccv = iccv2015_score(
        [to_float_image(r) for r in ref],
        registered,
        valid=result.valid,
        ambient_index=0 if len(lightings) > 3 else None,
    )
    iccv_sweep = sweep_scores(iccv, truth, eval_mask=mask)
    variants = {}
    for gain_sigma, smooth_sigma in score_grid:
        if (gain_sigma, smooth_sigma) == SCORE_GRID[0]:
            variants[(gain_sigma, smooth_sigma)] = {"best_f1": rows[grid[0]]["best_f1"], "ap": rows[grid[0]]["ap"]}
            continue
        variant = detect_changes(
            ref,
            cur,
            config=DetectionConfig.from_options(cues=False, gain_sigma_px=gain_sigma, smooth_sigma_px=smooth_sigma),
        )
        variant_sweep = sweep_scores(variant.score, truth, eval_mask=mask)
        variants[(gain_sigma, smooth_sigma)] = {"best_f1": variant_sweep.best_f1, "ap": variant_sweep.average_precision}
    return {
        "group": folder.name,
        "kind": folder.parent.name,
        "lightings": lightings,
        "changed_fraction_true": float(truth[mask].mean()),
        "grid": rows,
        "roi_grid": roi_rows,
        "seconds": seconds,
        "regions": len(result.regions),
        "region_evidence": region_evidence(result, truth, mask),
        "cues": {c: sum(r.cue == c for r in result.regions) for c in ("relief", "colour", "both")},
        "not_compared_fraction": float(result.not_compared[mask].mean()) if result.not_compared is not None else 0.0,
        "no_dense": {"best_f1": no_dense_sweep.best_f1, "ap": no_dense_sweep.average_precision},
        "iccv2015": {"best_f1": iccv_sweep.best_f1, "ap": iccv_sweep.average_precision},
        "score_variants": variants,
    }


def _others(scored: list[dict], held: dict, by: str) -> list[dict]:
    """The groups a held-out group's constants are chosen on: every other group (``by="group"``), or
    every group of another kind (``by="kind"``: the next object may be of a kind never seen)."""
    return [g for g in scored if g is not held and (by == "group" or g["kind"] != held["kind"])]


def leave_one_group_out_score_constants(scored: list[dict], *, by: str = "group") -> dict | None:
    """Best F1 and AP with the score's constants chosen on the other groups (by their mean best F1)."""
    keys = list(scored[0]["score_variants"]) if scored and scored[0]["score_variants"] else []
    if not keys:
        return None
    rows = []
    for held in scored:
        others = _others(scored, held, by)
        chosen = max(
            keys, key=lambda key: (np.mean([g["score_variants"][key]["best_f1"] for g in others]), -keys.index(key))
        )
        rows.append(
            {
                "group": held["group"],
                "gain_sigma_px": chosen[0],
                "smooth_sigma_px": chosen[1],
                **held["score_variants"][chosen],
            }
        )
    return {
        "groups": rows,
        "logo_best_f1_all_constants": float(np.mean([r["best_f1"] for r in rows])),
        "logo_ap_all_constants": float(np.mean([r["ap"] for r in rows])),
        "per_setting": [
            {
                "gain_sigma_px": key[0],
                "smooth_sigma_px": key[1],
                "mean_best_f1": float(np.mean([g["score_variants"][key]["best_f1"] for g in scored])),
                "mean_ap": float(np.mean([g["score_variants"][key]["ap"] for g in scored])),
            }
            for key in keys
        ],
    }


def leave_one_group_out(
    scored: list[dict], grid: list[tuple[float, float]], *, table: str = "grid", by: str = "group"
) -> list[dict]:
    """For each group, the grid point with the best mean auto F1 on the *other* groups, and its held-out scores.

    ``table``: ``"grid"`` (the user's detection, no ROI) or ``"roi_grid"`` (the same with ``--roi mask.png``).
    ``by``: ``"kind"`` chooses on the other kinds' groups only (:func:`_others`).
    """
    out = []
    for held in scored:
        others = _others(scored, held, by)
        chosen = max(grid, key=lambda key: (np.mean([g[table][key]["auto_f1"] for g in others]), -grid.index(key)))
        row = dict(held[table][chosen])
        row.update(
            {
                "group": held["group"],
                "kind": held["kind"],
                "chosen": detector_options(chosen),
                "changed_fraction_true": held["changed_fraction_true"],
            }
        )
        out.append(row)
    return out


def run_real(*, quick: bool, dataset: Path = DATASET, overlay_dir: Path | None = None) -> dict:
    """Part (a): the development groups, leave one group out (quick: every other lighting, a 2x2 grid)."""
    folders = find_groups(dataset)
    if not folders:
        return {"available": False, "reason": f"dataset not found at {dataset.resolve()}"}
    grid = list(QUICK_GRID if quick else GRID)
    single_scale = list(QUICK_SINGLE_SCALE_GRID if quick else SINGLE_SCALE_GRID)
    reference_grid = list(HYSTERESIS_GRID) + single_scale
    scored = []
    for folder in folders:
        lightings = group_lightings(folder)
        if quick:
            lightings = lightings[::2]
        scored.append(_score_group(folder, lightings, grid + reference_grid, () if quick else SCORE_GRID))
    logo = leave_one_group_out(scored, grid)
    logo_roi = leave_one_group_out(scored, grid, table="roi_grid")
    logo_hysteresis = leave_one_group_out(scored, list(HYSTERESIS_GRID))
    logo_single = leave_one_group_out(scored, single_scale)
    logo_scale_chosen = leave_one_group_out(scored, grid + single_scale)
    lokind = leave_one_group_out(scored, grid, by="kind")
    lokind_constants = leave_one_group_out_score_constants(scored, by="kind")
    mean = lambda rows, key: float(np.mean([r[key] for r in rows]))  # noqa: E731
    # The shipped defaults: the grid point chosen on all groups (what the next, unseen object gets).
    deployed = max(grid, key=lambda key: (np.mean([g["grid"][key]["auto_f1"] for g in scored]), -grid.index(key)))
    in_sample = [dict(g["grid"][deployed], group=g["group"]) for g in scored]
    if overlay_dir is not None:
        write_overlays(folders, scored, detector_options(deployed), overlay_dir)
    score_constants = leave_one_group_out_score_constants(scored)
    return {
        "available": True,
        "quick": quick,
        "grid": [list(key) for key in grid],
        "groups": logo,
        "logo_best_f1": mean(logo, "best_f1"),
        "logo_ap": mean(logo, "ap"),
        "logo_auto_f1": mean(logo, "auto_f1"),
        "logo_min_auto_recall": float(min(r["auto_recall"] for r in logo)),
        # What a conservator counts (issue 47, item 6), at the decision chosen on the other groups.
        **_counts("", logo),
        **_counts("roi_", logo_roi),
        # The shipped decision's regions: does the evidence the report shows rank true above false?
        **separation(scored),
        "per_kind": _per_kind(logo),
        # Each kind scored with every constant chosen on the other two kinds (decision; score in full runs).
        "lokind_auto_f1": mean(lokind, "auto_f1"),
        "lokind_best_f1": (
            lokind_constants["logo_best_f1_all_constants"] if lokind_constants else mean(lokind, "best_f1")
        ),
        "lokind_per_kind": _per_kind(lokind),
        # The same with the annotators' mask given as a region of interest (fgcd diff --roi mask.png).
        "roi_logo_best_f1": mean(logo_roi, "best_f1"),
        "roi_logo_ap": mean(logo_roi, "ap"),
        "roi_logo_auto_f1": mean(logo_roi, "auto_f1"),
        "roi_logo_min_auto_recall": float(min(r["auto_recall"] for r in logo_roi)),
        "roi_groups": logo_roi,
        "deployed": detector_options(deployed),
        "in_sample": in_sample,
        # Every grid point on every group (in-sample, a reference: how each rule behaves).
        "logo_hysteresis_auto_f1": mean(logo_hysteresis, "auto_f1"),
        "logo_hysteresis_min_auto_recall": float(min(r["auto_recall"] for r in logo_hysteresis)),
        # References: the decision without the finer scan, and with its use chosen leave one group out.
        "logo_single_scale_auto_f1": mean(logo_single, "auto_f1"),
        "logo_single_scale_min_auto_recall": float(min(r["auto_recall"] for r in logo_single)),
        "logo_scale_chosen_auto_f1": mean(logo_scale_chosen, "auto_f1"),
        "logo_scale_chosen_min_auto_recall": float(min(r["auto_recall"] for r in logo_scale_chosen)),
        "single_scale_groups": logo_single,
        "iccv2015_best_f1": float(np.mean([g["iccv2015"]["best_f1"] for g in scored])),
        "iccv2015_ap": float(np.mean([g["iccv2015"]["ap"] for g in scored])),
        "no_dense_best_f1": float(np.mean([g["no_dense"]["best_f1"] for g in scored])),
        "no_dense_ap": float(np.mean([g["no_dense"]["ap"] for g in scored])),
        **_reference_tables(scored, grid + reference_grid),
        # Full run only: the gain window and smoothing chosen leave one group out too (None in --quick).
        "score_constants": score_constants,
        "logo_best_f1_all_constants": score_constants["logo_best_f1_all_constants"] if score_constants else None,
        "logo_ap_all_constants": score_constants["logo_ap_all_constants"] if score_constants else None,
        "in_sample_auto_f1": mean(in_sample, "auto_f1"),
        "in_sample_best_f1": mean(in_sample, "best_f1"),
        "seconds_per_pair": float(np.median([g["seconds"] for g in scored])),
    }


def _per_kind(rows: list[dict]) -> dict:
    """Per kind of group (Db, Dp, Ds): the mean best F1, AP and auto F1 and the counts, leave one group out."""
    out = {}
    for kind in sorted({r["kind"] for r in rows}):
        of_kind = [r for r in rows if r["kind"] == kind]
        out[kind] = {
            "groups": len(of_kind),
            **{key: float(np.mean([r[key] for r in of_kind])) for key in ("best_f1", "ap", "auto_f1")},
            **_counts("", of_kind),
        }
    return out


def _counts(prefix: str, rows: list[dict]) -> dict:
    """``false_regions_per_pair`` (mean) and ``changes_found_fraction`` (found over true, all groups pooled)."""
    true = sum(r["changes_true"] for r in rows)
    return {
        f"{prefix}false_regions_per_pair": float(np.mean([r["false_regions"] for r in rows])),
        f"{prefix}changes_found_fraction": sum(r["changes_found"] for r in rows) / true if true else float("nan"),
    }


def _reference_tables(scored: list[dict], keys: list) -> dict:
    """Per group the baselines and cues, and per grid point its in-sample scores (a reference: how each rule behaves)."""
    return {
        "baselines": [
            {
                "group": g["group"],
                "iccv2015": g["iccv2015"],
                "no_dense": g["no_dense"],
                "not_compared_fraction": g["not_compared_fraction"],
                "regions": g["regions"],
                "cues": g["cues"],
            }
            for g in scored
        ],
        "per_setting": [
            {
                "setting": detector_options(key),
                "mean_auto_f1": float(np.mean([g["grid"][key]["auto_f1"] for g in scored])),
                "auto_recall": {g["group"]: g["grid"][key]["auto_recall"] for g in scored},
                "auto_precision": {g["group"]: g["grid"][key]["auto_precision"] for g in scored},
            }
            for key in keys
        ],
    }


#: The bench's parts: the real FGCD groups, the simulated pairs, the 24 MP case, the multi-light objects.
PARTS = ("real", "sim", "large", "multilight")


#: The real part's figures the summary carries (the issue's keys first).
REAL_SUMMARY_KEYS = (
    "logo_best_f1",
    "logo_ap",
    "logo_auto_f1",
    "logo_min_auto_recall",
    "lokind_best_f1",
    "lokind_auto_f1",
    "roi_logo_best_f1",
    "roi_logo_ap",
    "roi_logo_auto_f1",
    "roi_logo_min_auto_recall",
    "false_regions_per_pair",
    "changes_found_fraction",
    "roi_false_regions_per_pair",
    "roi_changes_found_fraction",
    "region_strength_auc",
    "region_nfa_auc",
    "in_sample_auto_f1",
    "seconds_per_pair",
    "logo_hysteresis_auto_f1",
    "iccv2015_best_f1",
    "iccv2015_ap",
    "no_dense_best_f1",
    "logo_best_f1_all_constants",
    "logo_ap_all_constants",
    "logo_single_scale_auto_f1",
    "logo_single_scale_min_auto_recall",
    "logo_scale_chosen_auto_f1",
    "logo_scale_chosen_min_auto_recall",
)


def run(*, quick: bool, overlay_dir: Path | None = None, parts: tuple[str, ...] = PARTS) -> dict:
    """Run the change-detection benchmark; returns ``{"summary": {...}, "real": ..., "sim": ...}``.

    ``parts``: which of :data:`PARTS` to run (a part not run reports ``{"available": False}``).
    """
    skipped = {"available": False, "reason": "not run (--part)"}
    real = run_real(quick=quick, overlay_dir=overlay_dir) if "real" in parts else skipped
    summary = {}
    if real.get("available"):
        summary.update({k: real[k] for k in REAL_SUMMARY_KEYS})
    sim = skipped
    try:
        from fgcd_cli.bench.changes.simulated import run_sim
    except ImportError as exc:  # the simulator part needs fgcd_drivers.sim
        sim = {"available": False, "reason": f"simulator part unavailable: {exc}"}
    else:
        if "sim" in parts:
            sim = run_sim(quick=quick)
        if sim.get("available"):
            summary.update(
                {k: sim[k] for k in ("sim_auto_f1", "sim_false_regions_unchanged", "sim_max_false_region_mm2")}
            )
            summary.update({k: v for k, v in sim.items() if k.startswith("sim_heldout_")})
            summary.update({k: v for k, v in sim.items() if k.startswith("sim_relocated_")})
    from fgcd_cli.bench.changes.large import run_large

    large = run_large(quick=quick) if "large" in parts else skipped
    if large.get("available"):
        summary.update({k: large[k] for k in ("seconds_per_pair_24mp", "peak_rss_mb_24mp")})
    multilight = run_multilight(quick=quick) if "multilight" in parts else skipped
    if multilight.get("available"):
        summary.update({k: v for k, v in multilight.items() if k.startswith("multilight_")})
    targets = {
        "multilight_false_regions": 0,
        "logo_best_f1": 0.70,
        "logo_auto_f1": 0.60,
        "logo_min_auto_recall": 0.3,
        "sim_auto_f1": 0.9,
        "seconds_per_pair": 10.0,
        "seconds_per_pair_24mp": 90.0,
        "peak_rss_mb_24mp": 4096.0,
    }
    return {
        "benchmark": "changes",
        "quick": quick,
        "summary": summary,
        "targets": targets,
        "real": real,
        "sim": sim,
        "large": large,
        "multilight": multilight,
        "dataset_citation": "W. Feng et al., Fine-Grained Change Detection of Misaligned Scenes with Varied Illuminations, ICCV 2015",
    }
