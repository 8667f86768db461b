"""``fgcd bench soak``: a hundred simulated revisits of one station in one process (issue 50, part 4).

One simulated station, set up by the field commands' own use cases: the
intrinsics (``fgcd calibrate intrinsics --sim``), the target-free hand-eye
(``fgcd calibrate hand-eye --driver sim``: plan, run, store) and the reference
(``fgcd capture``: :func:`fgcd_cli.app.capture.plan_capture` /
:func:`~fgcd_cli.app.capture.run_capture`). Then ``revisits`` consecutive revisits
through ``fgcd relocate``'s use case (:func:`fgcd_cli.app.revisit.plan_revisit` /
:func:`~fgcd_cli.app.revisit.run_revisit`), each with a new session seed and a
displaced start drawn from the run's seed, as a user's revisits; then
``change_revisits`` more with injected changes, each followed by ``fgcd diff``'s
and ``fgcd report``'s use cases. After every revisit the process is sampled
(:mod:`fgcd_cli.bench.soak.sample`) and ``campaign verify`` runs; at the end the
station's history is read back (every visit listed and readable).

The revisits are the quick ones a user makes when the rig stands where it stood:
a start displaced by 5-15 mm and 0.5-1.5 deg (``fgcd relocate --start-offset-mm
--start-offset-deg``), one lighting (the reference's), the default loop. The
simulated camera (640 x 480) and the revisit's exploration (3 legs of 4 cm) are
fixed by the product: no smaller honest setting exists.

Summary keys: ``revisits``, ``rss_growth_mb_per_revisit`` (slope after ``warmup``
revisits), ``rss_peak_mb``, ``python_objects_growth_per_revisit`` (a leak of Python objects, beside the resident set's
growth that the allocator's fragmentation also makes), ``threads_max``, ``fds_max``, ``tmp_files_left`` (target
0), ``visits_verified`` (target ``revisits``), ``history_complete``, ``seconds``.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from fgcd_cli.bench.soak.sample import ResourceSample, TempBaseline, sample_resources, summarize_samples
from fgcd_cli.errors import AlgorithmError, FgcdError, run_record

__all__ = ["FULL", "QUICK", "SoakConfig", "run"]

Say = Callable[[str], None]


@dataclass(frozen=True, kw_only=True)
class SoakConfig:
    """What a soak runs.

    Attributes
    ----------
    revisits : int
        Consecutive revisits without change detection.
    change_revisits : int
        Revisits then, each with injected changes, ``fgcd diff`` and ``fgcd report``.
    warmup : int
        Revisits left out of the RSS slope (libraries, caches and malloc arenas fill up first).
    seed : int
        Seed of the start offsets; revisit ``k`` gets session seed ``1000 * seed + k``.
    scene : str
        Simulated scene of the station.
    light : str
        Lighting of the reference and of every revisit.
    offset_mm, offset_deg : (float, float)
        Range of the displaced start (uniform draws), millimetres and degrees.
    changes : int
        Changes injected into the change revisits' world.
    """

    revisits: int = 100
    change_revisits: int = 20
    warmup: int = 10
    seed: int = 0
    scene: str = "stele"
    light: str = "led:3"
    offset_mm: tuple[float, float] = (5.0, 15.0)
    offset_deg: tuple[float, float] = (0.5, 1.5)
    changes: int = 3


FULL = SoakConfig()
QUICK = SoakConfig(revisits=10, change_revisits=2, warmup=3)
#: The soak's station.
STATION = "soak"


@contextmanager
def private_tempdir(folder: Path) -> Iterator[Path]:
    """The process's temporary folder (``tempfile`` and ``TMPDIR`` for native code) is ``folder`` in the block.

    Rule: the soak counts the temporary files *it* leaves; other processes share the system's
    temporary folder, so its entries would be counted too (docs/benchmarks.md, "Soak (`fgcd bench soak`)").
    """
    folder.mkdir(parents=True, exist_ok=True)
    saved_env, saved = os.environ.get("TMPDIR"), tempfile.tempdir
    os.environ["TMPDIR"], tempfile.tempdir = str(folder), str(folder)
    try:
        yield folder
    finally:
        tempfile.tempdir = saved
        if saved_env is None:
            os.environ.pop("TMPDIR", None)
        else:
            os.environ["TMPDIR"] = saved_env


def set_up_station(campaign: Path, config: SoakConfig, *, say: Say) -> dict:
    """A simulated campaign at ``campaign``: intrinsics, hand-eye and the station's reference; their figures."""
    from fgcd_cli.app.calibrate import (
        HandEyeRequest,
        calibrate_sim_intrinsics,
        plan_handeye,
        run_handeye,
        store_handeye,
    )
    from fgcd_cli.app.capture import CaptureRequest, plan_capture, run_capture
    from fgcd_cli.app.rig import RigHooks, RigRequest, open_rig, opened
    from fgcd_cli.app.rig_options import RigOptions
    from fgcd_cli.app.scenario import SimScenario
    from fgcd_cli.campaign.store import init_campaign

    t0 = time.monotonic()
    camp = init_campaign(campaign, site="soak bench", rig={"driver": "sim", "sim": {"scene": config.scene, "seed": 0}})
    say("calibrating the simulated camera's intrinsics")
    calibrate_sim_intrinsics(camp, SimScenario(scene=config.scene, seed=0), say=say)
    say("target-free hand-eye on the simulated rig")
    plan = plan_handeye(camp, RigOptions(driver="sim"), HandEyeRequest())
    rig = open_rig(
        RigRequest(
            driver="sim", intrinsics=plan.intrinsics.camera if plan.intrinsics else None, scenario=plan.scenario
        ),
        hooks=RigHooks(),
    )
    with opened(rig):
        calibration = run_handeye(rig.handles, plan.request, say=say)
    stored, unusable = store_handeye(camp, plan, calibration)
    if stored is None:  # as `fgcd calibrate hand-eye` (exit 6): no station can be captured with it
        raise AlgorithmError(f"the soak's hand-eye is not usable: {unusable}")
    t1 = time.monotonic()
    say(f"capturing the reference of station '{STATION}' under {config.light}")
    run_record.reset()
    capture_plan = plan_capture(camp, CaptureRequest(station=STATION, light=config.light))
    outcome = run_capture(camp, capture_plan, hooks=RigHooks())
    return {
        "calibration_s": round(t1 - t0, 1),
        "capture_s": round(time.monotonic() - t1, 1),
        "cloud_points": outcome.result.cloud_points,
        "handeye_rms_mm": round(calibration.result.rms_mm, 2),
    }


def _revisit_request(config: SoakConfig, k: int, rng: np.random.Generator, *, changes: int):
    """Revisit ``k``'s options, as ``fgcd relocate -s soak --session-seed S --start-offset-mm ... --yes`` gives them."""
    from fgcd_cli.app.revisit import RevisitRequest

    return RevisitRequest(
        station=STATION,
        light=config.light,
        changes=changes,
        start_offset_mm=float(rng.uniform(*config.offset_mm)),
        start_offset_deg=float(rng.uniform(*config.offset_deg)),
        session_seed=1000 * config.seed + k,
    )


def _verify_visit(campaign: Path, visit: str) -> str:
    """``campaign verify``'s errors, those naming ``visit`` first ('' when the campaign verifies)."""
    from fgcd_cli.campaign.verify import verify_campaign_dir

    report = verify_campaign_dir(campaign)
    errors = [p for p in report.problems if p.severity == "error"]
    errors.sort(key=lambda p: visit not in p.path if visit else True)
    return "; ".join(f"{p.path}: {p.kind} {p.detail}" for p in errors)


def _visit_truth(outcome) -> dict:
    """The simulator's truth at the pose a revisit reached (``evaluation/sim_truth.json``; evaluation only)."""
    from fgcd_cli.campaign import schema
    from fgcd_cli.campaign.observation import load_observation

    try:
        return load_observation(Path(outcome.result.observation_path), "visit").json(schema.SIM_TRUTH)
    except (FgcdError, OSError, ValueError):
        return {}


def one_revisit(campaign: Path, request, *, diff_and_report: bool) -> dict:
    """One revisit through ``fgcd relocate``'s use case (then ``fgcd diff``'s and ``fgcd report``'s).

    Returns ``converged``, ``visit`` (folder name), ``detail`` ('' or the failure), ``report_visits``.
    """
    from fgcd_cli.app.diff import CampaignDiffRequest, run_campaign
    from fgcd_cli.app.report import station_history
    from fgcd_cli.app.revisit import plan_revisit, run_revisit
    from fgcd_cli.app.rig import RigHooks

    run_record.reset()  # a new command starts (as the CLI boundary does)
    try:
        outcome = run_revisit(plan_revisit(campaign, request), hooks=RigHooks())
    except FgcdError as exc:  # the revisit failed (the CLI's exit 3/4/6): a finding, the soak goes on
        return {"converged": False, "visit": "", "detail": f"{type(exc).__name__}: {exc}", "report_visits": None}
    visit = Path(outcome.result.observation_path).name
    truth = _visit_truth(outcome)
    out = {
        "converged": outcome.converged,
        "visit": visit,
        "detail": "" if outcome.converged else f"not converged: {outcome.result.relocation.reason}",
        "report_visits": None,
        "afd_px": float(truth.get("afd_px", float("nan"))),
    }
    if diff_and_report:
        run_record.reset()
        run_campaign(CampaignDiffRequest(campaign=campaign, station=STATION, visit=visit))
        run_record.reset()
        history = station_history(campaign, STATION)
        out["report_visits"] = len(history["visits"])
        if history["damaged"]:
            out["detail"] = f"report: damaged {[d['name'] for d in history['damaged']]}"
    return out


def read_history(campaign: Path, visits: list[str]) -> dict:
    """The station's history read back: every visit listed (``station.json``, the tracks) and readable."""
    from fgcd_cli.app.archive_history import station_tracks
    from fgcd_cli.campaign.store import open_campaign

    st = open_campaign(campaign).station(STATION)
    listed = st.visit_names()
    unreadable = []
    for name in listed:
        try:
            obs = st.visit(name)
            for relpath in obs.files():
                obs.bytes(relpath)  # DataIntegrityError on a damaged file
        except FgcdError as exc:
            unreadable.append(f"{name}: {exc}")
    tracks = station_tracks(campaign, STATION)
    tracked = set(tracks.analysed) | set(tracks.not_analysed)
    missing = sorted(set(visits) - set(listed))
    complete = not missing and not unreadable and not st.missing_visit_names() and tracked == set(listed)
    return {
        "listed": len(listed),
        "written": len(visits),
        "missing": missing,
        "unreadable": unreadable,
        "tracked": len(tracked),
        "analysed": len(tracks.analysed),
        "complete": complete,
    }


def _revisits(
    campaign: Path, config: SoakConfig, baseline: TempBaseline, *, say: Say, on_sample: Callable[[ResourceSample], None]
) -> list[ResourceSample]:
    """Every revisit of the soak, sampled after each (``on_sample``: as each is taken)."""
    rng = np.random.default_rng(config.seed)
    samples = []
    total = config.revisits + config.change_revisits
    for k in range(1, total + 1):
        changes = k > config.revisits
        t0 = time.monotonic()
        done = one_revisit(
            campaign,
            _revisit_request(config, k, rng, changes=config.changes if changes else 0),
            diff_and_report=changes,
        )
        seconds = time.monotonic() - t0
        problems = _verify_visit(campaign, done["visit"])
        detail = "; ".join(d for d in (done["detail"], problems) if d)
        sample = sample_resources(
            index=k,
            phase="changes" if changes else "quick",
            seconds=seconds,
            baseline=baseline,
            outcome={
                "verified": bool(done["visit"]) and not problems,
                "converged": done["converged"],
                "visit": done["visit"],
                "detail": detail,
                "afd_px": done.get("afd_px", float("nan")),
            },
        )
        samples.append(sample)
        on_sample(sample)
        say(
            f"revisit {k}/{total} ({sample.phase}): {seconds:.0f} s, RSS {sample.rss_mb:.0f} MB, "
            f"{sample.threads_native} threads, {sample.fds} fds, {sample.tmp_left} tmp left"
            + (f" [{detail}]" if detail else "")
        )
    return samples


def run(
    *,
    quick: bool = False,
    revisits: int | None = None,
    change_revisits: int | None = None,
    out: Path | None = None,
    say: Say = lambda _m: None,
) -> dict:
    """Run the soak; its JSON-able result (``summary``, ``targets``, ``samples``, ``history``, ``setup``).

    Parameters
    ----------
    quick : bool
        :data:`QUICK` (10 + 2 revisits) instead of :data:`FULL` (100 + 20).
    revisits, change_revisits : int, optional
        Override the configuration's counts.
    out : Path, optional
        Folder kept after the run (the campaign, ``samples.jsonl`` as each sample is taken); by default a
        temporary folder, removed at the end.
    say : callable(str)
        One line per step and revisit.
    """
    config = QUICK if quick else FULL
    config = SoakConfig(
        **{
            **asdict(config),
            **{k: v for k, v in (("revisits", revisits), ("change_revisits", change_revisits)) if v is not None},
        }
    )
    work = Path(out) if out is not None else Path(tempfile.mkdtemp(prefix="fgcd-bench-soak-"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        return _run_in(work, config, say=say)
    finally:
        if out is None:
            shutil.rmtree(work, ignore_errors=True)


def _run_in(work: Path, config: SoakConfig, *, say: Say) -> dict:
    """:func:`run` in the folder ``work``."""
    t0 = time.monotonic()
    campaign = work / "campaign"
    log = work / "samples.jsonl"
    with private_tempdir(work / "tmp"):
        setup = set_up_station(campaign, config, say=say)
        baseline = TempBaseline.take(campaign)
        first = sample_resources(index=0, phase="setup", seconds=time.monotonic() - t0, baseline=baseline)
        log.write_text(json.dumps(first.to_dict()) + "\n")

        def on_sample(sample: ResourceSample) -> None:
            with log.open("a") as f:
                f.write(json.dumps(sample.to_dict()) + "\n")

        samples = _revisits(campaign, config, baseline, say=say, on_sample=on_sample)
        history = read_history(campaign, [s.visit for s in samples if s.visit])
        left = baseline.left()
    resources = summarize_samples([first, *samples], warmup=config.warmup)
    summary = {
        "revisits": len(samples),
        "change_revisits": sum(s.phase == "changes" for s in samples),
        "warmup_revisits": config.warmup,
        **resources,
        "tmp_files_left": len(left),
        "visits_verified": sum(s.verified for s in samples),
        "converged": sum(s.converged for s in samples),
        "history_complete": history["complete"],
        "seconds_per_revisit_median": round(
            float(np.median([s.seconds for s in samples if s.phase == "quick"] or [0.0])), 1
        ),
        "seconds": round(time.monotonic() - t0, 1),
    }
    return {
        "summary": summary,
        "targets": {"tmp_files_left": 0, "visits_verified": len(samples), "history_complete": True},
        "config": asdict(config),
        "setup": setup,
        "history": history,
        "tmp_left": left[:20],
        "samples": [first.to_dict(), *(s.to_dict() for s in samples)],
        "load_avg_1min": os.getloadavg()[0],
    }
