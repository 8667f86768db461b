"""Power loss while a visit is written (``fgcd bench faults``, group ``power_loss_points``; docs/hardware.md, "Faults").

Each point is a real ``fgcd relocate`` of the bench station ``real``
(:func:`fgcd_cli.bench.faults.station.prepare_real_station`) run through
:mod:`fgcd_cli.bench.faults.power_launch`, which SIGKILLs it at a seeded instant:

* ``power_loss_visit_write``: before the N-th file-system event of the visit's
  write (its temporary folder, images, cloud, logs, manifest, the rename, the
  station index, the journal's removal), N drawn over ``[1, count]``; or, for
  a third of the points, a seeded delay after the write's first event, which
  lands inside the writes themselves (the bytes of an image);
* ``power_loss_journal``: before the N-th line write of the revisit journal
  (its start line, one line per adjustment) or, for a quarter of the points,
  before its removal after the visit's commit.

``count`` comes from a counting run (the same launcher, never killed) made once
per bench campaign (its log holds every event under ``stations/``; each class
keeps its own) and kept in ``<campaign>/.bench-power.json``. A visit-write
point runs ``fgcd relocate --resume`` (the killed point before it left its
journal: the revisit continues from its last pose, the cheapest honest revisit;
with no journal it starts over), with a 5 mm / 0.5 degree displaced start; a
journal point runs a new ``fgcd relocate`` (so its journal starts from line 1).

After each kill: the earlier observations are byte-identical
(:func:`fgcd_cli.bench.faults.checks.committed_digests`); ``fgcd campaign
verify`` reports nothing new outside the station's write (its ``.tmp-*``
entries, the journal, the new visit), no new error, and names every leftover
on disk; the store temporaries it calls safe to delete are then deleted, as
an operator would. Every fifth point of a class is followed by a plain
``fgcd relocate`` that must succeed (exit 0): a new revisit after the power loss.
"""

from __future__ import annotations

import json
import shutil
import signal
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fgcd_cli.bench.faults.checks import FaultOutcome, committed_digests, earlier_changed, run_fgcd
from fgcd_cli.bench.faults.power_launch import read_log
from fgcd_cli.bench.faults.station import prepare_real_station
from fgcd_cli.campaign import schema
from fgcd_cli.campaign.atomic import TMP_PREFIX
from fgcd_cli.campaign.verify import verify_campaign_dir

__all__ = ["FAULTS", "PER_CLASS_FULL", "event_counts", "inject", "judge_verify", "leftovers"]

FAULTS: tuple[str, ...] = ("power_loss_visit_write", "power_loss_journal")
#: 28 + 28 points in the full run, for the group's ``power_loss_points`` target of 50 landed (issue "Faults in
#: the middle"): a journal point drawn at the counting run's last line does not land when the revisit
#: converges in fewer adjustments (docs/benchmarks.md, "Fault groups").
PER_CLASS_FULL = 28
#: The cheapest honest revisit: a displaced start of 5 mm and 0.5 degree (the default is 30 mm, 3 degrees).
RELOCATE_OPTIONS = ("--start-offset-mm", "5", "--start-offset-deg", "0.5", "--yes", "--json")
#: A new revisit after the power loss is checked after every REVISIT_EVERY-th point of a class.
REVISIT_EVERY = 5
#: Share of the visit-write points killed at a delay rather than at an event (instants inside one write).
JITTERED_SHARE = 1 / 3
#: Share of the journal points killed before the journal's removal (after the visit's commit).
REMOVAL_SHARE = 1 / 4
_COUNTS = ".bench-power.json"
_TIMEOUT_S = 1800.0


@dataclass(frozen=True, kw_only=True)
class _Instant:
    """Where a point's power cut falls: the launcher's environment, and its description."""

    env: dict
    text: str


def _launch_env(campaign: Path, log: Path, fault: str) -> dict:
    """The launcher's environment common to a counting run and a point of ``fault``."""
    env = {"FGCD_BENCH_POWER_UNDER": str(campaign / schema.STATIONS_DIR), "FGCD_BENCH_POWER_LOG": str(log)}
    if fault == "power_loss_journal":
        env["FGCD_BENCH_POWER_ONLY"] = schema.VISIT_JOURNAL
    else:
        env["FGCD_BENCH_POWER_FROM"] = f"/{schema.VISITS_DIR}/{TMP_PREFIX}"
    return env


def _relocate_args(campaign: Path, station: str, seed: int, *, resume: bool) -> list[str]:
    return [
        "relocate",
        "-c",
        str(campaign),
        "-s",
        station,
        "--session-seed",
        str(seed % 1000 + 1),
        *RELOCATE_OPTIONS,
        *(["--resume"] if resume else []),
    ]


def event_counts(campaign: Path, station: str) -> dict:
    """Events of a visit's write and of its journal, from one counting run (kept in the campaign).

    Returns
    -------
    dict
        ``{fault: {"events": n, "seconds": s}}``: the events the launcher counts for that class's
        filter, and the seconds from the first to the last.

    Raises
    ------
    RuntimeError
        The counting run's revisit failed (no count to draw the instants from).
    """
    path = Path(campaign) / _COUNTS
    if path.is_file():
        return json.loads(path.read_text(encoding="utf-8"))
    with tempfile.TemporaryDirectory(prefix="fgcd-power-") as tmp:
        log = Path(tmp) / "events.log"  # every event under stations/: each class's filter is applied below
        run = run_fgcd(
            _relocate_args(campaign, station, 0, resume=False),
            timeout_s=_TIMEOUT_S,
            launcher=["fgcd_cli.bench.faults.power_launch"],
            env={"FGCD_BENCH_POWER_UNDER": str(campaign / schema.STATIONS_DIR), "FGCD_BENCH_POWER_LOG": str(log)},
        )
        events, _ = read_log(log)
    write_start = f"/{schema.VISITS_DIR}/{TMP_PREFIX}"
    first = next((i for i, e in enumerate(events) if write_start in e.path), None)
    journal = [e for e in events if schema.VISIT_JOURNAL in e.path]
    if run.code != 0 or first is None or not journal:
        raise RuntimeError(f"the power-loss counting run failed ({run.code}): {(run.lines or ['?'])[-1]}")
    counts = {
        "power_loss_visit_write": {
            "events": len(events) - first,
            "seconds": events[-1].seconds - events[first].seconds,
        },
        "power_loss_journal": {"events": len(journal), "seconds": journal[-1].seconds - journal[0].seconds},
        "relocate_seconds": round(run.seconds, 1),
    }
    path.write_text(json.dumps(counts) + "\n", encoding="utf-8")
    return counts


def _instant(fault: str, seed: int, count: dict) -> _Instant:
    """The seeded instant of one point (every draw from ``np.random.default_rng(seed)``).

    A journal point falls before one of its line writes, or (a quarter of them) before its removal after the
    commit: a revisit may make fewer adjustments than the counting run, and its removal is always last.
    """
    rng = np.random.default_rng(seed)
    draw = rng.random()
    if fault == "power_loss_journal":
        if draw < REMOVAL_SHARE:
            return _Instant(
                env={"FGCD_BENCH_POWER_EVENT": "os.remove", "FGCD_BENCH_POWER_AT": "1"},
                text="before the journal's removal",
            )
        lines = max(count["events"] - 1, 1)
        n = int(rng.integers(1, lines + 1))
        return _Instant(
            env={"FGCD_BENCH_POWER_EVENT": "open", "FGCD_BENCH_POWER_AT": str(n)},
            text=f"before journal line write {n} of {lines}",
        )
    if draw < JITTERED_SHARE:
        delay = float(rng.uniform(0.0, 1.1 * max(count["seconds"], 0.1)))
        return _Instant(
            env={"FGCD_BENCH_POWER_DELAY_S": f"{delay:.4f}"}, text=f"{delay:.3f} s after the write's first event"
        )
    n = int(rng.integers(1, count["events"] + 1))
    return _Instant(env={"FGCD_BENCH_POWER_AT": str(n)}, text=f"before event {n} of {count['events']}")


def leftovers(station_path: Path) -> set[str]:
    """What an interrupted write of the station leaves on disk: store temporaries, the journal, unindexed visits."""
    visits = station_path / schema.VISITS_DIR
    out = {
        str(p)
        for parent in (station_path, visits)
        if parent.is_dir()
        for p in parent.iterdir()
        if p.name.startswith(TMP_PREFIX)
    }
    if (visits / schema.VISIT_JOURNAL).exists():
        out.add(str(visits / schema.VISIT_JOURNAL))
    try:
        index = set(json.loads((station_path / schema.STATION_FILE).read_text(encoding="utf-8"))["observations"])
    except (OSError, ValueError, KeyError, TypeError):
        index = set()
    if visits.is_dir():
        out |= {
            str(p)
            for p in visits.iterdir()
            if p.is_dir() and not p.name.startswith(".") and f"{schema.VISITS_DIR}/{p.name}" not in index
        }
    return out


def judge_verify(campaign: Path, station_path: Path, before: set[tuple]) -> tuple[list[str], list]:
    """``fgcd campaign verify`` after a kill: what is wrong with its report (empty: right), and its new problems.

    Right: no new problem outside the station's write, none an error, and every leftover on disk named.
    """
    report = verify_campaign_dir(campaign)
    new = [p for p in report.problems if (p.path, p.kind, p.detail) not in before]
    scope = (str(station_path / schema.VISITS_DIR) + "/", str(station_path / TMP_PREFIX))
    wrong = [f"{p.path}: {p.kind} ({p.severity}) outside the write" for p in new if not p.path.startswith(scope)]
    wrong += [f"{p.path}: {p.kind} is an error ({p.detail})" for p in new if p.severity == "error"]
    named = {p.path for p in report.problems}
    wrong += [
        f"{path}: left on disk, not named by campaign verify"
        for path in sorted(leftovers(station_path))
        if path not in named
    ]
    return wrong, new


def _clean(problems: list) -> None:
    """Delete the store temporaries verify calls safe to delete (what the operator does; the journal stays)."""
    for p in problems:
        path = Path(p.path)
        if p.kind == "incomplete-write" and path.name.startswith(TMP_PREFIX):
            shutil.rmtree(path) if path.is_dir() else path.unlink(missing_ok=True)


def _revisit_after(campaign: Path, station: str, seed: int) -> tuple[int, str]:
    """A plain new ``fgcd relocate`` of the station: its exit code and last line."""
    run = run_fgcd(_relocate_args(campaign, station, seed + 7919, resume=False), timeout_s=_TIMEOUT_S)
    return run.code, (run.error_lines or run.lines or [""])[-1]


def inject(fault: str, seed: int, campaign: Path) -> FaultOutcome:
    """One power-loss point of class ``fault`` with ``seed`` on the bench campaign, judged."""
    if fault not in FAULTS:
        raise ValueError(f"unknown fault '{fault}'")
    campaign = Path(campaign)
    station = prepare_real_station(campaign)
    station_path = campaign / schema.STATIONS_DIR / station
    instant = _instant(fault, seed, event_counts(campaign, station)[fault])
    before = committed_digests(campaign)
    problems_before = {(p.path, p.kind, p.detail) for p in verify_campaign_dir(campaign).problems}
    with tempfile.TemporaryDirectory(prefix="fgcd-power-") as tmp:
        log = Path(tmp) / "events.log"
        run = run_fgcd(
            _relocate_args(campaign, station, seed, resume=fault == "power_loss_visit_write"),
            launcher=["fgcd_cli.bench.faults.power_launch"],
            timeout_s=_TIMEOUT_S,
            env={**_launch_env(campaign, log, fault), **instant.env},
        )
        events, kill = read_log(log)
    changed = earlier_changed(before, committed_digests(campaign))
    wrong, new = judge_verify(campaign, station_path, problems_before)
    extra = {
        "instant": instant.text,
        "killed": kill.path[:160] if kill else None,
        "events_done": len(events),
        "seconds": round(run.seconds, 1),
        "left": sorted({f"{p.kind}:{Path(p.path).name[:24]}" for p in new}),
    }
    _clean(new)
    revisit_failed = False
    if seed % REVISIT_EVERY == REVISIT_EVERY - 1:
        code, line = _revisit_after(campaign, station, seed)
        extra["revisit_after"] = code
        revisit_failed = code != 0
        if revisit_failed:
            extra["revisit_line"] = line[:200]
    killed = run.code == -signal.SIGKILL
    # the plan's kill, or (its instant never came: the write ended first) a revisit that succeeded
    expected = () if revisit_failed else (-signal.SIGKILL,) if kill is not None else (0,)
    return FaultOutcome(
        fault=fault,
        seed=seed,
        command=f"relocate -s {station} ({instant.text})",
        code=run.code,
        expected=expected,
        stderr_lines=run.failure_lines,
        traceback=run.traceback,
        campaign_inconsistent=bool(wrong),
        earlier_data_changed=bool(changed),
        one_line_expected=run.code != 0 and not killed,
        detail="; ".join(
            wrong + changed + ([f"the new revisit failed: {extra['revisit_line']}"] if revisit_failed else [])
        )
        or (run.error_lines or run.lines or [""])[-1],
        extra=extra,
        landed=kill is not None,
    )
