"""`fgcd demo`: a complete campaign on the simulator, step by step.

calibrate (target-free hand-eye + scale) → capture a reference under one light
→ change the lighting and inject fine-grained changes → relocate from a
displaced start with the rACR loop → diff → report. Every step uses the same
use cases as the field commands.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from fgcd_cli.campaign import init_campaign
from fgcd_cli.errors import CampaignError

__all__ = ["DemoConfig", "count_changes_found", "run_demo"]

ProgressCallback = Callable[[int, int, str], None]
"""``on_progress(done, total, label)``: progress of a long step (``total <= 0``: length unknown).
The demo reports every step through it, so that the CLI can show each one live (no silence)."""


def _tick(on_progress: ProgressCallback | None, done: int, total: int, label: str) -> None:
    if on_progress is not None:
        on_progress(done, total, label)


@dataclass(frozen=True, kw_only=True)
class DemoConfig:
    """Scenario of the demo."""

    scene: str = "relief_panel"
    seed: int = 0
    reference_light: str = "front"
    visit_light: str = "led:3"
    changes: int = 4
    change_size_mm: tuple[float, float] = (15.0, 35.0)
    start_offset_mm: float = 25.0
    start_offset_deg: float = 2.5
    station: str = "niche-figure"
    vse: str = "mono"


def calibrate_sim_intrinsics(campaign, scenario, *, views: int = 16, say: Callable[[str], None],
                             on_progress: ProgressCallback | None = None):
    """ChArUco intrinsics of the simulated rig's camera (board views); stored in the campaign rig."""
    from drivers.sim.board import SimBoard
    from fgcd_cli.calibration import BoardSpec, calibrate_intrinsics
    from fgcd_cli.calibration.rig import save_intrinsics
    from fgcd_cli.rigs import open_sim_rig

    board = BoardSpec(squares_x=9, squares_y=6, square_m=0.025, marker_m=0.018, dictionary="DICT_5X5_100")
    rig = open_sim_rig(scenario, T_flange_cam=None, intrinsics=None)
    try:
        source = rig.sim.board_camera(SimBoard(squares_x=board.squares_x, squares_y=board.squares_y,
                                               square_m=board.square_m, marker_m=board.marker_m,
                                               dictionary=board.dictionary), seed=scenario.seed)
        images = []
        for k in range(views):
            _tick(on_progress, k, views, "rendering board views")
            images.append(source.grab().image)
    finally:
        rig.close()
    _tick(on_progress, 0, 0, "calibrating the intrinsics (ChArUco)")
    result = calibrate_intrinsics(images, board, names=[f"view_{i:02d}" for i in range(views)])
    save_intrinsics(campaign, result)
    say(f"intrinsics: fx {result.camera.fx:.1f} px, RMS {result.rms_px:.3f} px over {result.n_views} views")
    return result.camera


def calibrate_sim_handeye(campaign, scenario, *, say: Callable[[str], None], camera=None,
                          on_progress: ProgressCallback | None = None) -> dict:
    """Target-free hand-eye + scale on the simulated rig; stored in the campaign rig."""
    from fgcd_cli.calibration.procedure import run_target_free
    from fgcd_cli.rigs import open_sim_rig
    from fgcd_cli.vse import MonocularVSE

    rig = open_sim_rig(scenario, T_flange_cam=None, intrinsics=camera, on_event=say, on_progress=on_progress)
    try:
        run = run_target_free(
            rig.handles.guard,
            rig.handles.camera_source,
            lambda cam: MonocularVSE(cam),
            camera=rig.handles.intrinsics,
            progress=say,
            on_progress=on_progress,
        )
    finally:
        rig.close()
    record = run.result.to_dict()
    campaign.write_rig("handeye", record)
    return record


def change_ids_in_reference(sim_rig, T_world_camref: np.ndarray, camera_used) -> np.ndarray:
    """Which injected change each pixel of the stored reference image shows (HxW int32, 0 = none).

    Evaluation only. Like :func:`fgcd_cli.metrics.sim_eval.change_truth_in_reference`, but
    keeping each change's identity (1 + its index among the injected changes), remapped
    like the stored images with a nearest-neighbour lookup so that identities never mix.
    """
    gt = sim_rig.ground_truth
    ids = gt.change_ids(np.asarray(T_world_camref, dtype=float), gt.intrinsics_true())
    if camera_used is not None and camera_used.has_distortion:
        from fgcd_cli.vse.undistort import Undistorter

        ids = Undistorter(camera_used).depth(ids.astype(np.float32))
    return np.rint(ids).astype(np.int32)


def count_changes_found(found: np.ndarray, truth_ids: np.ndarray, *, injected: int) -> dict:
    """How many injected changes a change mask found, counted by change, not by blob.

    A change seen as several pieces (a crack broken by the relief, a stain cut by a
    shadow) is still one change, found when any of its pixels is found.

    Parameters
    ----------
    found : ndarray, HxW bool; the tool's change mask (reference image).
    truth_ids : ndarray, HxW int; 0 where no change, else the change's identity (1-based).
    injected : int, keyword-only; changes injected into the world (some may be out of view).

    Returns
    -------
    dict with ``injected_changes``, ``true_changes`` (injected changes in view of the
    reference image) and ``true_changes_found``.
    """
    found = np.asarray(found, dtype=bool)
    ids = np.asarray(truth_ids)
    in_view = set(np.unique(ids[ids > 0]).tolist())
    hit = set(np.unique(ids[found & (ids > 0)]).tolist())
    return {"injected_changes": int(injected), "true_changes": len(in_view), "true_changes_found": len(hit)}


def _evaluate_changes(visit, station, *, scenario, X: np.ndarray, camera, injected: int) -> dict:
    """Score the visit's change mask against the simulator's truth (the tool never saw it)."""
    import cv2

    from fgcd_cli.metrics.sim_eval import score_change_detection
    from fgcd_cli.rigs import open_sim_rig

    found = cv2.imdecode(np.frombuffer(visit.bytes("changes/change_mask.png"), np.uint8), cv2.IMREAD_UNCHANGED) > 0
    truth_ref = station.reference().json("evaluation/sim_truth.json")
    rig = open_sim_rig(scenario, T_flange_cam=X, intrinsics=camera)
    try:
        ids = change_ids_in_reference(rig.sim, np.array(truth_ref["T_world_cam"]), camera)
    finally:
        rig.close()
    # pixel scores and false regions from the shared scorer; changes counted by identity
    return {**score_change_detection(found, ids > 0), **count_changes_found(found, ids, injected=injected)}


def run_demo(out_dir: Path, *, config: DemoConfig = DemoConfig(), say: Callable[[str], None] = print,
             on_record=None, on_progress: ProgressCallback | None = None) -> dict:
    """Run the whole simulated campaign into ``out_dir``; returns a summary.

    Parameters
    ----------
    out_dir : Path
        Created; receives ``campaign/`` and ``summary.json``.
    config : DemoConfig, keyword-only
    say : callable(str), keyword-only
        One line per milestone.
    on_record : callable(AdjustmentRecord), keyword-only, optional
        Each relocation adjustment, as it is made.
    on_progress : callable(done, total, label), keyword-only, optional
        Every step, as it runs (``total <= 0``: length unknown); no step is left
        without one, so a live display is never silent.
    """
    from fgcd_cli.metrics.sim_eval import RelocationEvaluator, reference_truth
    from fgcd_cli.relocation.capture import capture_reference, relocate_and_capture
    from fgcd_cli.relocation.loop import RelocationConfig
    from fgcd_cli.report.usecases import run_campaign
    from fgcd_cli.rigs import SimScenario, open_sim_rig

    out_dir = Path(out_dir)
    camp_dir = out_dir / "campaign"
    if camp_dir.exists():
        raise CampaignError(f"{camp_dir} already exists: choose another --out directory")
    t0 = time.monotonic()
    camp = init_campaign(camp_dir, site=f"Simulated {config.scene} (fgcd demo)",
                         rig={"driver": "sim", "sim": {"scene": config.scene, "seed": config.seed}})
    station = camp.create_station(config.station, description="simulated heritage object")
    summary: dict = {"campaign": str(camp_dir)}

    say("1/5 calibrating hand-eye and map scale (target-free, rACR §3.2)")
    base = SimScenario(scene=config.scene, seed=config.seed, lighting=config.reference_light, session_seed=100)
    _tick(on_progress, 0, 0, "building the simulated world")
    cam = calibrate_sim_intrinsics(camp, base, say=say, on_progress=on_progress)
    _tick(on_progress, 0, 0, "hand-eye: starting the VSE")
    he = calibrate_sim_handeye(camp, base, say=say, camera=cam, on_progress=on_progress)
    X = np.array(he["T_flange_cam"], dtype=float)
    summary["handeye"] = {k: he.get(k) for k in ("rms_rotation_deg", "rms_translation_mm", "n_samples") if k in he}

    say(f"2/5 capturing the reference under '{config.reference_light}'")
    _tick(on_progress, 0, 0, "opening the simulated rig")
    rig = open_sim_rig(SimScenario(scene=config.scene, seed=config.seed, lighting=config.reference_light, session_seed=0),
                       T_flange_cam=X, intrinsics=cam, on_event=say, on_progress=on_progress,
                       vse_variant=config.vse)
    _tick(on_progress, 0, 0, "capturing the reference")
    try:
        cap = capture_reference(rig.handles, station, lightings=[config.reference_light],
                                metadata={"driver": "sim", "scenario": rig.info["scenario"]},
                                evaluation=reference_truth(rig.sim))
    finally:
        rig.close()
    summary["reference"] = {"path": cap.observation_path, "cloud_points": cap.cloud_points, "scale": cap.scale.scale}

    say(f"3/5 revisit: light '{config.visit_light}', {config.changes} injected changes, start displaced by "
        f"{config.start_offset_mm:.0f} mm / {config.start_offset_deg:.1f} deg")
    _tick(on_progress, 0, 0, "changing the light, injecting the changes")
    scen = SimScenario(scene=config.scene, seed=config.seed, lighting=config.visit_light, changes=config.changes,
                       change_seed=7, change_size_mm=config.change_size_mm, start_offset_mm=config.start_offset_mm, start_offset_deg=config.start_offset_deg,
                       session_seed=1)
    rig = open_sim_rig(scen, T_flange_cam=X, intrinsics=cam, on_event=say, on_progress=on_progress,
                       vse_variant=config.vse)
    evaluator = RelocationEvaluator.from_reference(rig.sim, station.reference())
    say("4/5 relocating (parallel rACR loop)")
    _tick(on_progress, 0, 0, "relocating (parallel rACR loop)")
    try:
        vis = relocate_and_capture(rig.handles, station, config=RelocationConfig(), lightings=[config.visit_light, config.reference_light],
                                   metadata={"driver": "sim", "scenario": rig.info["scenario"]},
                                   evaluate=evaluator.evaluate, on_record=on_record, evaluation=evaluator.summary)
    finally:
        rig.close()
    reloc = vis.relocation
    summary["relocation"] = {
        "converged": reloc.converged, "reason": reloc.reason, "adjustments": reloc.adjustments,
        "session_s": round(reloc.session_s, 1), "wall_s": round(reloc.wall_s, 1),
        "final_truth": reloc.records[-1].truth if reloc.records else None, "visit": vis.observation_path,
    }

    say("5/5 change detection and report")
    _tick(on_progress, 0, 0, "change detection and report")
    diff = run_campaign(camp_dir, config.station)
    visit = station.visit()
    summary["diff"] = {
        "regions": len(diff.get("regions", [])),
        "set_aside_regions": (diff.get("settings") or {}).get("edge_explained_regions", 0),
        "changed_fraction": diff.get("changed_fraction"),
        "comparable": diff.get("comparable"),
        "report": str(visit.path / "report.html"),
    }
    if visit.has("changes/change_mask.png"):
        _tick(on_progress, 0, 0, "scoring against the simulator's truth")
        summary["diff"]["evaluation"] = _evaluate_changes(visit, station, scenario=scen, X=X, camera=cam,
                                                           injected=config.changes)
    summary["wall_s"] = round(time.monotonic() - t0, 1)
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2, default=str))
    return summary
