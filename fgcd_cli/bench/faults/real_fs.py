"""Real resource exhaustion for ``fgcd bench faults``: a small real file system that is really full, a read-only
campaign, a memory limit (docs/hardware.md, "Faults in the field").

Each fault mounts a fresh size-limited ``tmpfs`` (:mod:`fgcd_cli.bench.faults.tmpfs`),
copies onto it the part of the bench campaign the command needs, fills it with
a filler file so that a seeded random number of bytes stays free (``statvfs``),
and runs the real command on the copy:

* ``fs_full_capture``: ``fgcd capture`` of a new station;
* ``fs_full_relocate``: ``fgcd relocate -s real`` (the station captured once by
  :func:`fgcd_cli.bench.faults.station.prepare_real_station` on the normal disk);
* ``fs_full_diff``: ``fgcd diff -c C -s s1``;
* ``fs_full_archive``: ``fgcd archive analyze --force`` over the copy;
* ``readonly_campaign``: the tmpfs remounted read-only (root ignores permission
  bits) under a seeded one of those four commands;
* ``memory_limit_diff``: a 24 MP bare-image ``fgcd diff`` under ``RLIMIT_AS``
  (:mod:`fgcd_cli.bench.faults.memory_limit`).

Odd seeds also point the child's ``HOME``, ``TMPDIR`` and ``XDG_STATE_HOME``
into the small file system, so that what fgcd writes outside the store (the
native-stderr log, temporary files, the visit journal is in the store) fills it
too. Expected (README, "Errors"): exit 0 when it fit, else exit 1 with one line
``No space left on device: <file>`` (``Read-only file system: <file>``) naming a
file on the small file system; ``fgcd archive analyze`` exits 3 when a visit
failed. After each: no write leftover (``.tmp-*``) anywhere in the copy, nothing
left in its ``TMPDIR``, ``campaign verify`` clean and the observations committed
before byte-identical (:func:`fgcd_cli.bench.faults.checks.committed_digests`).
Where a tmpfs cannot be mounted the fault is reported skipped with the reason,
never passed.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fgcd_cli.bench.faults.checks import (
    FaultOutcome,
    FgcdRun,
    campaign_problems,
    committed_digests,
    earlier_changed,
    run_fgcd,
)
from fgcd_cli.bench.faults.fs_outcome import FsOutcome, skipped
from fgcd_cli.bench.faults.tmpfs import MountUnavailable, fill_to, free_bytes, remount_readonly, small_fs, tree_bytes
from fgcd_cli.campaign import schema

__all__ = ["FAULTS", "PER_CLASS_FULL", "FsOutcome", "inject"]

#: The quick run keeps one class of the group, ``FAULTS[seed % 6]``: the cheapest (a diff, ~40 s) comes first.
FAULTS: tuple[str, ...] = (
    "fs_full_diff",
    "fs_full_archive",
    "readonly_campaign",
    "fs_full_capture",
    "fs_full_relocate",
    "memory_limit_diff",
)
#: Two faults per class: 12 in the full run (a capture or a revisit takes minutes on 2 busy cores).
PER_CLASS_FULL = 2

#: Documented exit codes (README, "Errors"): success, an operating-system error, a visit of an archive failed.
EXIT_OK, EXIT_OS, EXIT_CAMPAIGN = 0, 1, 3
#: The strerror texts the failure line must carry.
NO_SPACE, READ_ONLY = "No space left on device", "Read-only file system"
#: Bytes that may stay free before each command, drawn uniformly below this: a little more than what the
#: command writes on the bench campaign (a capture's reference with its keyframes and cloud ~32 MB, a visit
#: 1.6-2.6 MB, a diff's maps and report ~2.5 MB), so that most faults fill up and some fit.
FREE_UP_TO = {"capture": 40_000_000, "relocate": 3_000_000, "diff": 3_000_000, "archive": 3_000_000}
#: Room on the small file system beyond the copy and the bytes left free, before filling.
MARGIN = 16 << 20


@dataclass(frozen=True, kw_only=True)
class _Command:
    """One fgcd command run on the small file system: the stations its copy needs, codes it may end with."""

    name: str
    stations: tuple[str, ...]
    codes: tuple[int, ...]
    timeout_s: float


COMMANDS = {
    "capture": _Command(name="capture", stations=(), codes=(EXIT_OK, EXIT_OS), timeout_s=1800),
    "relocate": _Command(name="relocate", stations=("real",), codes=(EXIT_OK, EXIT_OS), timeout_s=1800),
    "diff": _Command(name="diff", stations=("s1",), codes=(EXIT_OK, EXIT_OS), timeout_s=900),
    # archive analyze: a visit whose task failed is one line of its summary and exit 3 (docs/archive.md, "One task per visit")
    "archive": _Command(name="archive", stations=("s1",), codes=(EXIT_OK, EXIT_OS, EXIT_CAMPAIGN), timeout_s=1200),
}


def _copy_campaign(campaign: Path, dest: Path, stations: tuple[str, ...]) -> Path:
    """``campaign`` copied to ``dest`` with only ``stations`` (hidden files and locks left out); the copy."""
    root = Path(campaign)

    def ignore(folder: str, names: list[str]) -> set[str]:
        out = {n for n in names if n.startswith(".")}
        if Path(folder) == root / schema.STATIONS_DIR:
            out |= {n for n in names if n not in stations}
        return out

    shutil.copytree(root, dest, symlinks=True, ignore=ignore)
    (dest / schema.STATIONS_DIR).mkdir(exist_ok=True)
    return dest


def _source_bytes(campaign: Path, stations: tuple[str, ...]) -> int:
    """Bytes of what :func:`_copy_campaign` copies (the rig records and ``stations``)."""
    root = Path(campaign)
    return tree_bytes(root / "rig") + sum(tree_bytes(root / schema.STATIONS_DIR / s) for s in stations)


def _args(command: str, copy: Path, seed: int) -> list[str]:
    """The command line of ``command`` on the campaign copy ``copy``."""
    if command == "capture":
        from fgcd_cli.bench.faults.station import REAL_STATION_LIGHTS

        return ["capture", "-c", str(copy), "-s", f"fs-{seed}", "--light", REAL_STATION_LIGHTS, "--yes", "--json"]
    if command == "relocate":
        return ["relocate", "-c", str(copy), "-s", "real", "--yes", "--json"]
    if command == "diff":
        return ["diff", "-c", str(copy), "-s", "s1", "--json"]
    # without --json: each failed visit is a stderr line naming its reason (docs/archive.md, "One task per visit")
    return ["archive", "analyze", str(copy.parent), "--workers", "1", "--force"]


def _outside_env(point: Path) -> dict[str, str]:
    """``HOME``, ``TMPDIR`` and ``XDG_STATE_HOME`` of the child in folders of the small file system."""
    env = {"HOME": point / "home", "TMPDIR": point / "tmp", "XDG_STATE_HOME": point / "state"}
    for folder in env.values():
        folder.mkdir()
    return {k: str(v) for k, v in env.items()}


#: What Dask keeps in ``TMPDIR`` on purpose across runs (``distributed.diskutils``: the shared scratch folder's
#: locks, a few bytes, never one per run); the per-worker folders in it are removed and are counted.
DASK_KEEPS = frozenset({"dask-scratch-space", "dask-scratch-space/global.lock", "dask-scratch-space/purge.lock"})
#: The per-visit failure lines of ``fgcd archive analyze`` (docs/archive.md, "One task per visit"): one per failed visit, then its line.
VISIT_FAILED = "failed: "


def _leftovers(copy: Path, env: dict[str, str]) -> list[str]:
    """Write leftovers in the copy (``.tmp-*``, anywhere) and whatever the child left in its ``TMPDIR``."""
    left = [p.relative_to(copy).as_posix() for p in copy.rglob(".tmp-*")]
    if "TMPDIR" in env:
        kept = (p.relative_to(env["TMPDIR"]).as_posix() for p in Path(env["TMPDIR"]).rglob("*"))
        left += [f"$TMPDIR/{rel}" for rel in kept if rel not in DASK_KEEPS]
    return sorted(left)


def stray_lines(run: FgcdRun, point: Path) -> list[str]:
    """stderr lines that are neither the failure line nor progress: a library's warning reaching the terminal.

    Rule (README, "Errors"): a failing command prints one line. :attr:`FgcdRun.failure_lines` counts the lines
    carrying ``error``; a library's warning about the small file system (``mkdir -p failed for path ...``,
    ``Matplotlib created a temporary cache directory ...``) carries none, and is caught here by what it names.
    """
    errors = set(run.error_lines)
    return [
        line
        for line in run.lines
        if line not in errors
        and not line.startswith(VISIT_FAILED)
        and (str(point) in line or "Errno" in line or "arning" in line)
    ]


@dataclass(frozen=True, kw_only=True)
class _Judged:
    """What a fault is judged on besides the run: the copy, the mount, the digests before, the error text."""

    copy: Path
    point: Path
    before: dict[str, str]
    env: dict[str, str]
    strerror: str
    leftovers_checked: bool = True


def judge(
    fault: str, seed: int, command: str, run: FgcdRun, codes: tuple[int, ...], ctx: _Judged, extra: dict
) -> FsOutcome:
    """Judge one fault on its run, the campaign copy and what the small file system holds (before unmounting)."""
    changed = earlier_changed(ctx.before, committed_digests(ctx.copy))
    problems = campaign_problems(ctx.copy)
    leftovers = _leftovers(ctx.copy, ctx.env) if ctx.leftovers_checked else []
    lines = run.error_lines or run.lines or [""]
    # the failure line names the file: the errno's text, then a path on the small file system (README, "Errors")
    named = run.code == EXIT_OK or any(ctx.strerror in line and str(ctx.point) in line for line in run.lines)
    visits_failed = [line for line in run.error_lines if line.startswith(VISIT_FAILED)]
    stray = stray_lines(run, ctx.point)
    detail = "; ".join(problems + changed + [f"left {p}" for p in leftovers[:3]] + stray[:2]) or lines[-1]
    if not named:
        detail = f"the failure does not name a file on the small file system: {lines[-1]}"
    return FsOutcome(
        fault=fault,
        seed=seed,
        command=command,
        code=run.code,
        expected=codes,
        stderr_lines=run.failure_lines - len(visits_failed) + len(stray),
        traceback=run.traceback,
        campaign_inconsistent=bool(problems),
        earlier_data_changed=bool(changed),
        one_line_expected=run.code != EXIT_OK,
        detail=detail,
        leftovers=leftovers,
        file_named=named,
        extra={
            **extra,
            "seconds": round(run.seconds, 1),
            "stray_lines": stray[:5],
            "visit_failures": visits_failed[:3],
        },
    )


def _full_fault(fault: str, seed: int, campaign: Path) -> FsOutcome:
    """One ``fs_full_*`` fault: the command on a campaign copy on a tmpfs with a seeded number of bytes free."""
    rng = np.random.default_rng(seed)
    name = fault.removeprefix("fs_full_")
    spec = COMMANDS[name]
    leave = int(rng.integers(0, FREE_UP_TO[name]))
    outside = seed % 2 == 1  # odd seeds: HOME, TMPDIR and the state folder fill up too
    _prepare_source(name, campaign)
    size = _source_bytes(campaign, spec.stations) + FREE_UP_TO[name] + MARGIN
    with small_fs(size, parent=Path(campaign).parent) as point:
        copy = _copy_campaign(campaign, point / "site" / "campaign", spec.stations)
        env = _outside_env(point) if outside else {}
        before = committed_digests(copy)
        free = fill_to(point, leave)
        run = run_fgcd(_args(name, copy, seed), env=env, timeout_s=spec.timeout_s)
        return judge(
            fault,
            seed,
            f"{name} (disk full{', HOME/TMPDIR too' if outside else ''})",
            run,
            spec.codes,
            _Judged(copy=copy, point=point, before=before, env=env, strerror=NO_SPACE),
            {"free_bytes": free, "free_after": free_bytes(point), "outside_env": outside},
        )


def _readonly_fault(seed: int, campaign: Path) -> FsOutcome:
    """A seeded command on a campaign copy on a tmpfs remounted read-only: exit 1 naming a file, nothing changed."""
    rng = np.random.default_rng(seed)
    name = str(rng.choice(sorted(COMMANDS)))
    spec = COMMANDS[name]
    outside = seed % 2 == 1  # odd seeds: HOME, TMPDIR and the state folder are read-only too
    _prepare_source(name, campaign)
    codes = (EXIT_OS, EXIT_CAMPAIGN) if name == "archive" else (EXIT_OS,)
    with small_fs(_source_bytes(campaign, spec.stations) + MARGIN, parent=Path(campaign).parent) as point:
        copy = _copy_campaign(campaign, point / "site" / "campaign", spec.stations)
        env = _outside_env(point) if outside else {}
        before = committed_digests(copy)
        remount_readonly(point)
        run = run_fgcd(_args(name, copy, seed), env=env, timeout_s=spec.timeout_s)
        return judge(
            "readonly_campaign",
            seed,
            f"{name} (read-only campaign{', HOME/TMPDIR too' if outside else ''})",
            run,
            codes,
            _Judged(copy=copy, point=point, before=before, env=env, strerror=READ_ONLY),
            {"outside_env": outside},
        )


def _prepare_source(command: str, campaign: Path) -> None:
    """What the command needs in the bench campaign before it is copied: the hand-eye, the real station."""
    if command == "capture":
        from fgcd_cli.bench.faults.campaign_faults import calibrate_campaign

        calibrate_campaign(campaign)
    elif command == "relocate":
        from fgcd_cli.bench.faults.station import prepare_real_station

        prepare_real_station(campaign)


def inject(fault: str, seed: int, campaign: Path) -> FaultOutcome:
    """Run one fault of this group (skipped, saying why, where a tmpfs cannot be mounted)."""
    if fault not in FAULTS:
        raise ValueError(f"unknown fault '{fault}'")
    try:
        if fault == "memory_limit_diff":
            from fgcd_cli.bench.faults.memory_limit import memory_fault

            return memory_fault(seed, campaign)
        if fault == "readonly_campaign":
            return _readonly_fault(seed, campaign)
        return _full_fault(fault, seed, campaign)
    except MountUnavailable as exc:
        return skipped(fault, seed, str(exc))
    except RuntimeError as exc:  # the bench campaign's calibration or real station could not be made
        return skipped(fault, seed, f"not injected: {exc}")
