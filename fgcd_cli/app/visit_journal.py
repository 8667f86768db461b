"""The journal of a revisit in progress, and ``fgcd relocate --resume``: continue it, or start over cleanly.

A revisit appends one line per adjustment to ``stations/S/visits/.in-progress.jsonl``
(:data:`fgcd_cli.campaign.schema.VISIT_JOURNAL`), each flushed and fsynced: the
adjustment record and the flange pose the platform reported after it. The first
line holds the visit's options; it is written with the first adjustment (a
visit stopped before any leaves no journal, and an earlier one's stays until
then). The journal is removed once the visit is committed; a visit that ends
early after an adjustment (Ctrl-C, a fault, a killed process, a loop that
paused) leaves it, and the Ctrl-C line says so (``run_record.keep``). ``--resume`` then:

* **continues** when the journal is readable and was written with the same
  driver and light: the platform is driven back (through the MotionGuard, in
  steps) to the last pose the journal recorded, the rACR loop runs from there,
  and the visit's relocation log holds the earlier adjustments first;
* **starts over** otherwise (no journal, a damaged one, other options, or a
  journal whose visit was already committed: a stop between the commit and the
  journal's removal), saying why.

Without ``--resume`` a left journal is replaced by the new visit's.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path

import numpy as np

from fgcd_cli.campaign.schema import VISIT_JOURNAL, VISITS_DIR
from fgcd_cli.campaign.verify import committed_visit_of_journal
from fgcd_cli.errors import run_record
from fgcd_core.se3 import interpolate_pose, pose_distance

__all__ = ["JournalWriter", "ResumeDecision", "ResumeMode", "decide_resume", "journal_path", "return_to"]


class ResumeMode(StrEnum):
    """How a revisit started (the ``resume.mode`` of ``fgcd relocate --json``)."""

    NEW = "new"
    CONTINUED = "continued"
    STARTED_OVER = "started over"


@dataclass(frozen=True, kw_only=True)
class ResumeDecision:
    """What a revisit does with a left journal.

    Attributes
    ----------
    mode : ResumeMode
    reason : str
        One line for people.
    records : list of dict
        The adjustments of the interrupted visit (continued only).
    T_base_flange : (4, 4) ndarray or None
        The last pose it recorded, metres (continued only).
    """

    mode: ResumeMode
    reason: str
    records: list[dict] = field(default_factory=list)
    T_base_flange: np.ndarray | None = None

    def to_dict(self) -> dict:
        """``{"mode", "reason", "earlier_adjustments"}``."""
        return {"mode": str(self.mode), "reason": self.reason, "earlier_adjustments": len(self.records)}


def journal_path(station) -> Path:
    """The station's journal file."""
    return Path(station.path) / VISITS_DIR / VISIT_JOURNAL


def _read(path: Path) -> tuple[dict, list[dict], np.ndarray | None]:
    """``(options, records, last pose)`` of a journal; ValueError when it is damaged."""
    lines = path.read_text(encoding="utf-8").splitlines()
    if not lines:
        raise ValueError("empty")
    header = json.loads(lines[0])
    if header.get("kind") != "start":
        raise ValueError("no start line")
    records, pose = [], None
    for number, line in enumerate(lines[1:], start=2):
        try:
            entry = json.loads(line)
        except ValueError:
            if number == len(lines):
                break  # the last line was being written when the process died: the earlier ones hold
            raise
        records.append(entry["record"])
        pose = np.asarray(entry["T_base_flange"], dtype=float).reshape(4, 4)
    return header["options"], records, pose


def decide_resume(station, *, resume: bool, options: dict) -> ResumeDecision:
    """Continue the interrupted visit of ``station`` or start over, and why (see the module docstring)."""
    path = journal_path(station)
    if not resume:
        left = " (an interrupted visit's journal is replaced; --resume would continue it)" if path.exists() else ""
        return ResumeDecision(mode=ResumeMode.NEW, reason="a new visit" + left)
    if not path.exists():
        return ResumeDecision(
            mode=ResumeMode.STARTED_OVER, reason=f"no interrupted visit of station '{station.name}': starting a new one"
        )
    try:
        earlier, records, pose = _read(path)
    except (OSError, ValueError, KeyError, TypeError):
        return ResumeDecision(
            mode=ResumeMode.STARTED_OVER, reason="the interrupted visit's journal is damaged: starting over"
        )
    changed = [k for k in sorted(options) if earlier.get(k) != options[k]]
    if changed:
        return ResumeDecision(
            mode=ResumeMode.STARTED_OVER,
            reason=f"the interrupted visit used another {', '.join(changed)}: starting over",
        )
    if pose is None:
        return ResumeDecision(
            mode=ResumeMode.STARTED_OVER, reason="the interrupted visit made no adjustment yet: starting over"
        )
    committed = committed_visit_of_journal(station, records)
    if committed is not None:  # continuing would record the same revisit a second time
        return ResumeDecision(
            mode=ResumeMode.STARTED_OVER,
            reason=f"the journal's visit was already written (visits/{committed}): starting a new one",
        )
    return ResumeDecision(
        mode=ResumeMode.CONTINUED,
        records=records,
        T_base_flange=pose,
        reason=f"continuing the interrupted visit after its {len(records)} "
        f"adjustment{'' if len(records) == 1 else 's'}",
    )


class JournalWriter:
    """Appends a revisit's adjustments to the station's journal (flushed and fsynced line by line)."""

    def __init__(self, station, *, options: dict, decision: ResumeDecision) -> None:
        self.path = journal_path(station)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._options = options
        self.adjustments = len(decision.records) if decision.mode == ResumeMode.CONTINUED else 0
        self._kept_clause = f"the journal {self.path} is kept for `fgcd relocate --resume`"
        if self.adjustments:
            self._keep()

    def _keep(self) -> None:
        run_record.keep(self._kept_clause, not_written="no visit was written")

    def _append(self, entry: dict, *, truncate: bool = False) -> None:
        flags = os.O_WRONLY | os.O_CREAT | (os.O_TRUNC if truncate else os.O_APPEND)
        data = memoryview((json.dumps(entry, default=float) + "\n").encode("utf-8"))
        fd = os.open(self.path, flags, 0o644)
        try:
            while data:  # os.write may write less than asked (a nearly full disk): the rest follows or raises
                data = data[os.write(fd, data) :]
            os.fsync(fd)
        finally:
            os.close(fd)

    def record(self, record, T_base_flange: np.ndarray) -> None:
        """One adjustment and the flange pose the platform reported after it (the first: after the start line)."""
        if self.adjustments == 0:
            self._append({"kind": "start", "options": self._options}, truncate=True)
        self._append(
            {"record": json.loads(record.to_json()), "T_base_flange": np.asarray(T_base_flange, dtype=float).tolist()}
        )
        if self.adjustments == 0:
            self._keep()
        self.adjustments += 1

    def remove(self) -> None:
        """The visit is committed: the journal goes."""
        try:
            self.path.unlink()
        except FileNotFoundError:
            pass
        run_record.unkeep(self._kept_clause)


def return_to(guard, T_base_flange: np.ndarray, *, step_fraction: float = 0.9) -> int:
    """Drive the platform to ``T_base_flange`` through ``guard`` in steps within its limits; the number of steps.

    Each step is at most ``step_fraction`` of the guard's largest translation
    and rotation (:class:`fgcd_core.platform.GuardLimits`), so every one passes it.
    """
    target = np.asarray(T_base_flange, dtype=float)
    start = np.asarray(guard.platform.flange_pose(), dtype=float)
    mm, deg = pose_distance(start, target)
    limits = guard.limits
    steps = max(
        math.ceil(mm / (limits.max_step_m * 1000.0 * step_fraction)),
        math.ceil(math.radians(deg) / (limits.max_step_rad * step_fraction)),
        0,
    )
    for k in range(1, steps + 1):
        guard.move_to(interpolate_pose(start, target, k / steps))
    return steps
