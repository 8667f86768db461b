"""What every injected fault is judged by: the fgcd process's exit and stderr, the campaign's consistency,
and the checksums of the observations written before the fault (``fgcd bench faults``).
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from fgcd_cli.bench.paths import REPO_ROOT
from fgcd_cli.campaign.schema import MANIFEST, STATION_FILE, STATIONS_DIR
from fgcd_cli.campaign.verify import verify_campaign_dir

__all__ = [
    "FaultOutcome",
    "FgcdRun",
    "committed_digests",
    "campaign_problems",
    "run_fgcd",
    "run_fgcd_lines",
    "wait_until",
]

#: How the CLI's one failure line starts (``fgcd_cli/cli/app.py``, Failure prefixes).
FAILURE_PREFIXES = (
    "error:",
    "platform error:",
    "interrupted (Ctrl-C):",
    "internal error:",
    "usage error:",
    "terminated (SIGTERM):",
    "hung up (SIGHUP):",
    "camera error:",
    "aborted:",
)

ROOT = REPO_ROOT  # the fgcd children run from the repository root, like the tests


@dataclass(frozen=True, kw_only=True)
class FgcdRun:
    """One fgcd child process: exit code (negative: killed by that signal), stderr, seconds."""

    code: int
    stderr: str
    seconds: float

    @property
    def lines(self) -> list[str]:
        """Non-empty stderr lines."""
        return [line for line in self.stderr.splitlines() if line.strip()]

    @property
    def error_lines(self) -> list[str]:
        """The stderr lines that report how the command failed (progress lines are not counted).

        The CLI's failure line starts with one of the prefixes of ``cli/app.py`` (``error:``,
        ``platform error:``, ``interrupted (Ctrl-C):``...); any other line carrying ``Error``
        or ``error`` also counts (a library's message reaching the terminal).
        """
        return [
            line
            for line in self.lines
            if line.startswith(FAILURE_PREFIXES) or "Error" in line or "error" in line.split(":")[0]
        ]

    @property
    def failure_lines(self) -> int:
        """How many lines report the failure; one more when the last stderr line is not one of them."""
        errors = self.error_lines
        return len(errors) + (1 if errors and self.lines[-1] != errors[-1] else 0)

    @property
    def traceback(self) -> bool:
        """A Python traceback reached the user."""
        return "Traceback (most recent call last)" in self.stderr


@dataclass(kw_only=True)
class FaultOutcome:
    """The judged outcome of one injected fault.

    Attributes
    ----------
    fault : str
        The fault class.
    seed : int
    command : str
        The fgcd command line the fault hit (without the paths).
    code : int
        Its exit code (negative: killed by that signal, SIGKILL faults).
    expected : tuple of int
        The documented codes for this fault (README, "Errors"; docs/hardware.md, "Faults").
    stderr_lines : int
        Lines reporting the failure (:attr:`FgcdRun.failure_lines`): 1 for a failure, 0 for a success;
        progress lines above them are not counted.
    traceback : bool
    platform_left_moving : bool
        The emulator's own state says it still moves after the command ended.
    campaign_inconsistent : bool
        ``fgcd campaign verify`` found an error other than the one damaged file the fault made.
    earlier_data_changed : bool
        A file of an observation committed before the fault changed or vanished.
    detail : str
        The stderr line, or what went wrong.
    one_line_expected : bool
        The run must end with exactly one failure line (not a success, not a SIGKILL).
    resume_failed : bool
        The ``fgcd relocate --resume`` run after the fault neither succeeded nor said whether it continued
        the visit or started over (docs/hardware.md, "Faults in the field"); False when none was run.
    extra : dict
        The fault's details (its moment, the resume's mode and exit code...).
    landed : bool
        The fault reached the command: False when its seeded instant never came (the command ended first,
        or the write had fewer events). Such a row is judged as usual but not counted as a fault of its
        group (:func:`fgcd_cli.bench.faults.main.summarize`, ``not_landed``).
    """

    fault: str
    seed: int
    command: str
    code: int
    expected: tuple[int, ...]
    stderr_lines: int
    traceback: bool
    platform_left_moving: bool = False
    campaign_inconsistent: bool = False
    earlier_data_changed: bool = False
    detail: str = ""
    one_line_expected: bool = True
    resume_failed: bool = False
    extra: dict = field(default_factory=dict)
    landed: bool = True

    @property
    def ok(self) -> bool:
        """Every check passed: documented code, one stderr line (none for SIGKILL), nothing left moving or damaged."""
        lines_ok = self.stderr_lines == 1 if self.one_line_expected else self.stderr_lines <= 1
        return (
            self.code in self.expected
            and lines_ok
            and not self.traceback
            and not self.platform_left_moving
            and not self.campaign_inconsistent
            and not self.earlier_data_changed
            and not self.resume_failed
        )

    def to_dict(self) -> dict:
        """The JSON row of this fault."""
        return {
            "fault": self.fault,
            "seed": self.seed,
            "command": self.command,
            "code": self.code,
            "expected": list(self.expected),
            "stderr_lines": self.stderr_lines,
            "traceback": self.traceback,
            "platform_left_moving": self.platform_left_moving,
            "campaign_inconsistent": self.campaign_inconsistent,
            "earlier_data_changed": self.earlier_data_changed,
            "resume_failed": self.resume_failed,
            "ok": self.ok,
            "landed": self.landed,
            "detail": self.detail[:300],
            **self.extra,
        }


def run_fgcd(
    args: list[str],
    *,
    inject: Callable[[subprocess.Popen], None] | None = None,
    timeout_s: float = 300.0,
    launcher: list[str] | None = None,
    env: dict | None = None,
) -> FgcdRun:
    """Run ``fgcd ARGS`` as a child; ``inject(process)`` runs in a thread meanwhile (the fault).

    ``launcher`` replaces ``python -m fgcd_cli.cli.app`` (the ENOSPC launcher).
    """
    command = [sys.executable, "-m", *(launcher or ["fgcd_cli.bench.faults.child"]), *args]  # a terminal's signals
    started = time.monotonic()
    proc = subprocess.Popen(
        command,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        cwd=ROOT,
        env={**os.environ, **(env or {})},
    )
    thread = None
    if inject is not None:
        thread = threading.Thread(target=inject, args=(proc,), daemon=True)
        thread.start()
    try:
        _, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()  # by its own pid: a hung child is a failed fault, never left behind
        _, err = proc.communicate()
        err += b"\n[bench] the command did not end in time and was killed"
    if thread is not None:
        thread.join(timeout=30)
    return FgcdRun(
        code=proc.returncode, stderr=err.decode("utf-8", errors="replace"), seconds=time.monotonic() - started
    )


def run_fgcd_lines(
    args: list[str],
    *,
    on_line: Callable[[str, subprocess.Popen], None],
    timeout_s: float = 300.0,
    env: dict | None = None,
) -> FgcdRun:
    """Run ``fgcd ARGS`` as a child, handing each stderr line to ``on_line(line, process)`` as it comes.

    The streaming form of :func:`run_fgcd` (whole-operation faults act on the
    child's progress lines): ``on_line`` runs on the reader thread, so it must
    not block for long (start a timer or a thread for a delayed fault). Stdout
    is read on its own thread (a full pipe must never stall the child).
    """
    # the terminal's signal defaults, whatever the bench's own (`faults.child`: a bench run in the background)
    command = [sys.executable, "-m", "fgcd_cli.bench.faults.child", *args]
    started = time.monotonic()
    proc = subprocess.Popen(
        command,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        cwd=ROOT,
        env={**os.environ, **(env or {})},
    )
    lines: list[str] = []

    def read_stderr() -> None:
        for raw in iter(proc.stderr.readline, b""):
            line = raw.decode("utf-8", errors="replace").rstrip("\n")
            lines.append(line)
            on_line(line, proc)

    readers = [
        threading.Thread(target=read_stderr, daemon=True),
        threading.Thread(target=proc.stdout.read, daemon=True),
    ]
    for reader in readers:
        reader.start()
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()  # by its own pid: a hung child is a failed fault, never left behind
        proc.wait()
        lines.append("[bench] the command did not end in time and was killed")
    for reader in readers:
        reader.join(timeout=30)
    return FgcdRun(code=proc.returncode, stderr="\n".join(lines), seconds=time.monotonic() - started)


def send_signal(proc: subprocess.Popen, sig: int) -> None:
    """``sig`` to the child by its pid, if it still runs."""
    if proc.poll() is None:
        try:
            os.kill(proc.pid, sig)
        except ProcessLookupError:
            pass


def wait_until(condition: Callable[[], bool], *, timeout_s: float, proc: subprocess.Popen | None = None) -> bool:
    """Poll ``condition`` every 10 ms until true, the timeout, or (when given) the child's end."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        if proc is not None and proc.poll() is not None:
            return condition()
        time.sleep(0.01)
    return False


def committed_digests(campaign: Path) -> dict[str, str]:
    """sha256 of every captured file under ``stations/``, and of each manifest's captured entries.

    Left out: write leftovers, lock and journal files (dot names), and a diff's
    derived products (listed ``derived`` in a manifest, or unlisted), which every
    ``fgcd diff`` may recompute (docs/user-guide.md, the campaign folder); a manifest counts by its
    captured entries and metadata, which no command may change.
    """
    out = {}
    root = Path(campaign) / STATIONS_DIR
    for manifest in sorted(root.rglob(MANIFEST)):
        rel_obs = manifest.parent.relative_to(root)
        if any(part.startswith(".") for part in rel_obs.parts):
            continue
        data = json.loads(manifest.read_text(encoding="utf-8"))
        captured = {k: v for k, v in data.get("files", {}).items() if not v.get("derived", False)}
        out[f"{rel_obs.as_posix()}/{MANIFEST}#captured"] = hashlib.sha256(
            json.dumps([captured, data.get("metadata")], sort_keys=True).encode()
        ).hexdigest()
        for relpath in captured:
            path = manifest.parent / relpath
            out[f"{rel_obs.as_posix()}/{relpath}"] = (
                hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else "missing"
            )
    for station_file in sorted(root.glob(f"*/{STATION_FILE}")):
        out.update(_station_record_digests(station_file, station_file.relative_to(root).as_posix()))
    return out


def _station_record_digests(station_file: Path, rel: str) -> dict[str, str]:
    """A ``station.json`` as earlier data: its fields, and each observation it indexes.

    Rule (docs/user-guide.md, the campaign folder): a committed observation appends itself to the
    station's index, so a new entry is new data, not a change; an entry that
    vanishes, or any other field that changes, is earlier data changed.
    Unreadable JSON counts by its bytes (any change to it is flagged).
    """
    raw = station_file.read_bytes()
    try:
        info = json.loads(raw)
    except (json.JSONDecodeError, UnicodeDecodeError):
        return {rel: hashlib.sha256(raw).hexdigest()}
    if not isinstance(info, dict) or not isinstance(info.get("observations", []), list):
        return {rel: hashlib.sha256(raw).hexdigest()}
    fields = {k: v for k, v in info.items() if k != "observations"}
    out = {f"{rel}#fields": hashlib.sha256(json.dumps(fields, sort_keys=True).encode()).hexdigest()}
    out.update({f"{rel}#indexes/{obs}": "indexed" for obs in info.get("observations", [])})
    return out


def earlier_changed(before: dict[str, str], after: dict[str, str]) -> list[str]:
    """Files of ``before`` that changed or vanished (new files are not earlier data)."""
    return [rel for rel, digest in before.items() if after.get(rel) != digest]


def campaign_problems(campaign: Path, *, allowed: set[str] = frozenset()) -> list[str]:
    """``fgcd campaign verify``'s errors (warnings such as write leftovers are not errors), minus ``allowed`` paths."""
    report = verify_campaign_dir(Path(campaign))
    return [
        f"{p.path}: {p.kind}"
        for p in report.problems
        if getattr(p, "severity", "error") == "error" and str(p.path) not in allowed
    ]


SIGNALS = {"SIGINT": signal.SIGINT, "SIGKILL": signal.SIGKILL, "SIGTERM": signal.SIGTERM, "SIGHUP": signal.SIGHUP}


def fresh_station(campaign: Path, base: str) -> str:
    """A station name of the campaign not taken yet: ``base``, else ``base-r2``, ``base-r3``, ...

    A capture fault needs a new station; a bench campaign reused across runs
    (``--workdir``) already holds the stations of earlier runs with the same seeds.
    """
    root = Path(campaign) / STATIONS_DIR
    name, n = base, 1
    while (root / name).exists():
        n += 1
        name = f"{base}-r{n}"
    return name
