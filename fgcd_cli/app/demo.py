"""The demo use case (``fgcd demo``): a complete campaign on the simulator, step by step.

calibrate (target-free hand-eye + scale) → capture a reference under one light
→ change the lighting and inject fine-grained changes → relocate from a
displaced start with the rACR loop → diff → report. Every step uses the same
use cases as the field commands.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from fgcd_cli.app.calibrate import calibrate_sim_handeye, calibrate_sim_intrinsics  # the calibration use cases
from fgcd_cli.app.determinism import deterministic_rig
from fgcd_cli.app.sim_scoring import score_visit_changes  # evaluation only
from fgcd_cli.campaign import schema
from fgcd_cli.campaign.store import init_campaign
from fgcd_cli.errors import CampaignError

__all__ = ["DemoConfig", "calibrate_sim_handeye", "calibrate_sim_intrinsics", "demo_output_dir", "run_demo"]

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
    deterministic: bool = False
    """Capture and relocation with their threads stepped in a fixed order: the same seeds, the same demo."""


def demo_output_dir(requested: Path, *, now: datetime | None = None) -> tuple[Path, str]:
    """Where the demo writes, and the one line that says so before any work (issue 48, item 10).

    Rule: a demo never writes into a folder that holds something; a non-empty
    ``requested`` gets a new UTC-timestamped subfolder (``20250102T030405Z``).
    """
    requested = Path(requested)
    if not (requested.exists() and any(requested.iterdir())):
        return requested, f"writing the demo into {requested}"
    out = requested / (now or datetime.now(UTC)).strftime("%Y%m%dT%H%M%SZ")
    return out, f"writing the demo into {out} (a new folder: {requested} is not empty)"


def run_demo(
    out_dir: Path,
    *,
    config: DemoConfig = DemoConfig(),
    say: Callable[[str], None] = print,
    on_record=None,
    on_progress: ProgressCallback | None = None,
) -> dict:
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

    Returns
    -------
    dict
        The summary also written to ``summary.json``: ``out`` (``out_dir``), ``campaign``,
        ``summary`` (that file), ``handeye``, ``reference``, ``relocation``, ``diff``, ``wall_s``.
    """
    out_dir = Path(out_dir)
    camp_dir = out_dir / "campaign"
    if camp_dir.exists():
        raise CampaignError(f"{camp_dir} already exists: choose another --out directory")
    t0 = time.monotonic()
    camp = init_campaign(
        camp_dir,
        site=f"Simulated {config.scene} (fgcd demo)",
        rig={"driver": "sim", "sim": {"scene": config.scene, "seed": config.seed}},
    )
    station = camp.create_station(config.station, description="simulated heritage object")
    run = _DemoRun(config=config, campaign=camp, station=station, say=say, on_record=on_record, on_progress=on_progress)
    summary: dict = {"out": str(out_dir), "campaign": str(camp_dir), "summary": str(out_dir / "summary.json")}
    summary["handeye"] = _calibrate(run)
    summary["reference"] = _capture(run)
    summary["relocation"] = _relocate(run)
    summary["diff"] = _diff(run, camp_dir)
    summary["wall_s"] = round(time.monotonic() - t0, 1)
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2, default=str))
    return summary


@dataclass
class _DemoRun:
    """The demo's state between its steps (the calibration and the revisit's world are set as they run)."""

    config: DemoConfig
    campaign: object
    station: object
    say: Callable[[str], None]
    on_record: Callable | None
    on_progress: ProgressCallback | None
    X: np.ndarray | None = None
    camera: object = None
    visit_scenario: object = None

    def tick(self, label: str) -> None:
        """A step starts (unknown length)."""
        _tick(self.on_progress, 0, 0, label)


def _calibrate(run: _DemoRun) -> dict:
    """Step 1: intrinsics and target-free hand-eye + scale, stored in the campaign rig; their summary."""
    from fgcd_cli.app.scenario import SimScenario

    config = run.config
    run.say("1/5 calibrating hand-eye and map scale (target-free, rACR §3.2)")
    base = SimScenario(scene=config.scene, seed=config.seed, lighting=config.reference_light, session_seed=100)
    run.tick("building the simulated world")
    run.camera = calibrate_sim_intrinsics(run.campaign, base, say=run.say, on_progress=run.on_progress)
    run.tick("hand-eye: starting the VSE")
    he = calibrate_sim_handeye(run.campaign, base, say=run.say, camera=run.camera, on_progress=run.on_progress)
    run.X = np.array(he["T_flange_cam"], dtype=float)
    return {k: he.get(k) for k in ("rms_rotation_deg", "rms_translation_mm", "n_samples") if k in he}


def _capture(run: _DemoRun) -> dict:
    """Step 2: the reference under the reference light; its summary."""
    from fgcd_cli.app import capture as capture_uc
    from fgcd_cli.app import rig as rig_uc
    from fgcd_cli.app.scenario import SimScenario
    from fgcd_cli.app.scene_uncertainty import station_scene_uncertainty
    from fgcd_cli.metrics.sim_eval import reference_truth

    config = run.config
    run.say(f"2/5 capturing the reference under '{config.reference_light}'")
    run.tick("opening the simulated rig")
    rig = rig_uc.open_sim_rig(
        SimScenario(scene=config.scene, seed=config.seed, lighting=config.reference_light, session_seed=0),
        T_flange_cam=run.X,
        intrinsics=run.camera,
        on_event=run.say,
        on_progress=run.on_progress,
        vse_variant=config.vse,
    )
    run.tick("capturing the reference")
    try:
        cap = capture_uc.capture_reference(
            deterministic_rig(rig.handles, config.deterministic),
            run.station,
            lightings=[config.reference_light],
            metadata={"driver": "sim", "scenario": rig.info["scenario"]},
            evaluation=lambda: reference_truth(rig.sim),
        )
    finally:
        rig.close()
    run.tick("scene uncertainty of the reference")
    station_scene_uncertainty(run.station, run.camera, say=run.say)
    return {"path": cap.observation_path, "cloud_points": cap.cloud_points, "scale": cap.scale.scale}


def _relocate(run: _DemoRun) -> dict:
    """Steps 3 and 4: the revisit's world (other light, injected changes, displaced start), relocation; its summary."""
    from fgcd_cli.app import relocate as relocate_uc
    from fgcd_cli.app import rig as rig_uc
    from fgcd_cli.app.scenario import SimScenario
    from fgcd_cli.app.session import revisit_lightings
    from fgcd_cli.metrics.sim_eval import RelocationEvaluator
    from fgcd_cli.relocation.config import RelocationConfig

    config = run.config
    run.say(
        f"3/5 revisit: light '{config.visit_light}', {config.changes} injected changes, start displaced by "
        f"{config.start_offset_mm:.0f} mm / {config.start_offset_deg:.1f} deg"
    )
    run.tick("changing the light, injecting the changes")
    run.visit_scenario = SimScenario(
        scene=config.scene,
        seed=config.seed,
        lighting=config.visit_light,
        changes=config.changes,
        change_seed=7,
        change_size_mm=config.change_size_mm,
        start_offset_mm=config.start_offset_mm,
        start_offset_deg=config.start_offset_deg,
        session_seed=1,
    )
    rig = rig_uc.open_sim_rig(
        run.visit_scenario,
        T_flange_cam=run.X,
        intrinsics=run.camera,
        on_event=run.say,
        on_progress=run.on_progress,
        vse_variant=config.vse,
    )
    evaluator = RelocationEvaluator.from_reference(rig.sim, run.station.reference())
    loop = "deterministic rACR loop, threads stepped in turn" if config.deterministic else "parallel rACR loop"
    run.say(f"4/5 relocating ({loop})")
    run.tick(f"relocating ({loop})")
    try:
        vis = relocate_uc.relocate_and_capture(
            rig.handles,
            run.station,
            request=relocate_uc.RelocateRequest(
                config=RelocationConfig(deterministic=config.deterministic),
                lightings=revisit_lightings(rig.handles, config.visit_light, run.station.reference()),
                metadata={"driver": "sim", "scenario": rig.info["scenario"]},
            ),
            hooks=relocate_uc.RelocateHooks(
                evaluate=evaluator.evaluate, on_record=run.on_record, evaluation=evaluator.summary
            ),
        )
    finally:
        rig.close()
    reloc = vis.relocation
    return {
        "converged": reloc.converged,
        "reason": reloc.reason,
        "adjustments": reloc.adjustments,
        "session_s": round(reloc.session_s, 1),
        "wall_s": round(reloc.wall_s, 1),
        "final_truth": reloc.records[-1].truth if reloc.records else None,
        "visit": vis.observation_path,
    }


def _diff(run: _DemoRun, camp_dir: Path) -> dict:
    """Step 5: change detection and report, scored against the simulator's truth; their summary."""
    from fgcd_cli.app import diff as diff_uc

    config = run.config
    run.say("5/5 change detection and report")
    run.tick("change detection and report")
    diff = diff_uc.run_campaign(diff_uc.CampaignDiffRequest(campaign=camp_dir, station=config.station))
    visit = run.station.visit()
    summary = {
        "regions": len(diff.get("regions", [])),
        "set_aside_regions": (diff.get("settings") or {}).get("edge_explained_regions", 0),
        "changed_fraction": diff.get("changed_fraction"),
        "comparable": diff.get("comparable"),
        "report": str(visit.path / schema.REPORT_HTML),
    }
    mask_file = schema.change_relpath(schema.CHANGE_MASK_PNG)
    if visit.has(mask_file):
        run.tick("scoring against the simulator's truth")
        summary["evaluation"] = score_visit_changes(
            visit, run.station, scenario=run.visit_scenario, X=run.X, camera=run.camera, injected=config.changes
        )
    return summary
