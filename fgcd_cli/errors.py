"""The error hierarchy of fgcd. Exit codes are assigned only at the CLI boundary.

Every message is one line a person can act on. ``run_record`` holds what the
running command has done so far, for the line printed when it is interrupted.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, fields
from pathlib import Path


class FgcdError(Exception):
    """Base of every expected failure (bad input, damaged data, hardware trouble)."""

    exit_code = 1


class UserInputError(FgcdError):
    """A command-line value, file or option is wrong."""

    exit_code = 2


class CampaignError(FgcdError):
    """A campaign is missing, malformed or would be damaged by the request."""

    exit_code = 3


class DataIntegrityError(CampaignError):
    """Checksums or manifests do not match what is on disk."""

    exit_code = 4


class ImmutableDataError(CampaignError):
    """A write would overwrite data that is immutable once written (a reference)."""

    exit_code = 5


class AlgorithmError(FgcdError):
    """An algorithm could not produce a trustworthy result (reported, not guessed)."""

    exit_code = 6


class HardwareError(FgcdError):
    """A platform or camera failed; wraps ``fgcd_core.platform.PlatformError``."""

    exit_code = 7


class ConfirmationNeeded(UserInputError):
    """A motion needs a confirmation but there is no terminal to ask on (pass ``--yes``)."""

    @classmethod
    def for_prompt(cls) -> ConfirmationNeeded:
        """The error for a confirmation asked with no terminal on stdin."""
        return cls("confirmation needs a terminal: run the command in a terminal or pass --yes; nothing was moved")


# ----------------------------------------------------------------------------- what a run has done
# Rule: a command that is stopped early (Ctrl-C) says in one line whether a
# platform was moving and what was and was not written. Commands (and the use
# cases they call) describe themselves in ``run_record``; the CLI boundary
# (``cli/app.py``) turns it into that line. A command that says nothing gets a
# generic line that is true of every fgcd command: motions go through the
# MotionGuard, which stops the platform on Ctrl-C, and every file is written
# atomically.


@dataclass
class RunRecord:
    """What the running command has done so far, read when it stops early.

    Attributes
    ----------
    platform_known : bool
        The command said whether it drives a platform.
    platform : str or None
        Name of the platform the command has connected to (None: none).
    moving : bool
        A motion was in progress (set by :meth:`motion`).
    writes_known : bool
        The command said what it writes.
    written : list of str
        Outputs completed so far (paths or short descriptions).
    pending : list of str
        Outputs in progress, as the clause printed if the command stops now
        (``not written: ...`` or ``not completed: ...``).
    kept : list of str
        Files deliberately left if the command stops now, as clauses (a
        revisit's journal for ``--resume``), see :meth:`keep`.
    not_written : str
        What the clause says when nothing was completed or is in progress but
        something is kept (the output the kept file stands in for).
    """

    platform_known: bool = False
    platform: str | None = None
    moving: bool = False
    writes_known: bool = False
    written: list[str] = field(default_factory=list)
    pending: list[str] = field(default_factory=list)
    kept: list[str] = field(default_factory=list)
    not_written: str = "nothing was written"

    def reset(self) -> None:
        """Forget everything (a new command starts)."""
        fresh = RunRecord()
        for f in fields(self):
            setattr(self, f.name, getattr(fresh, f.name))

    def no_platform(self) -> None:
        """The command drives no platform."""
        self.platform_known = True
        self.platform = None

    def platform_connected(self, name: str) -> None:
        """The command is connected to the platform ``name`` (not moving yet)."""
        self.platform_known = True
        self.platform = name

    @contextmanager
    def motion(self) -> Iterator[None]:
        """Mark a motion in progress; Ctrl-C inside the block leaves it marked (it was moving)."""
        self.moving = True
        try:
            yield
        except KeyboardInterrupt:
            raise
        except BaseException:
            self.moving = False
            raise
        self.moving = False

    def no_writes(self) -> None:
        """The command writes nothing (so far)."""
        self.writes_known = True

    def wrote(self, what: str | Path) -> None:
        """An output was completed (a path, or a short description)."""
        self.writes_known = True
        self.written.append(str(what))

    @contextmanager
    def writing(self, what: str | Path, *, whole: bool = True) -> Iterator[None]:
        """Mark an output in progress; it becomes written when the block completes.

        Parameters
        ----------
        what : str or Path
            The output (a path, or a short description).
        whole : bool
            True when the output appears all at once (one atomic file, an
            observation); False for several files written one after the other,
            of which an interruption may leave some.
        """
        self.writes_known = True
        item = (
            f"not written: {what}"
            if whole
            else f"not completed: {what} (some of its files may be there, each one whole)"
        )
        self.pending.append(item)
        yield
        self.pending.remove(item)
        self.written.append(str(what))

    def keep(self, clause: str, *, not_written: str) -> None:
        """A file is left on purpose if the command stops now (``clause`` says what and for what).

        Parameters
        ----------
        clause : str
            E.g. ``the journal ... is kept for `fgcd relocate --resume```.
        not_written : str
            Said first when nothing else was written, e.g. ``no visit was written``.
        """
        self.writes_known = True
        if clause not in self.kept:
            self.kept.append(clause)
        self.not_written = not_written

    def unkeep(self, clause: str) -> None:
        """The kept file is gone (its output was completed)."""
        if clause in self.kept:
            self.kept.remove(clause)

    def platform_clause(self) -> str:
        """Whether a platform was moving, in a few words."""
        if not self.platform_known:
            return "any motion in progress was stopped by the motion guard"
        if self.platform is None:
            return "no platform was in use"
        if self.moving:
            return f"the {self.platform} platform was stopped mid-motion"
        return f"the {self.platform} platform was not moving"

    def writes_clause(self) -> str:
        """What was and was not written, in a few words."""
        if not self.writes_known:
            return "files already complete were kept and none was left half-written"
        clauses = []
        if self.written:
            shown = ", ".join(self.written[:3]) + (
                f" and {len(self.written) - 3} more" if len(self.written) > 3 else ""
            )
            clauses.append(f"wrote {shown}")
        if self.pending:
            clauses += self.pending
        if self.kept:
            clauses = (clauses or [self.not_written]) + self.kept
        return "; ".join(clauses) or "nothing was written"


run_record = RunRecord()


# ----------------------------------------------------------------------------- stop signals
class StopSignal(KeyboardInterrupt):
    """SIGTERM or SIGHUP turned into the path Ctrl-C takes (README, "Errors"; docs/hardware.md, "Faults").

    Rule: a supervisor's SIGTERM or a closed terminal's SIGHUP stops a command
    as Ctrl-C does: every ``except KeyboardInterrupt`` on the way (the motion
    guard, the drivers, the rig) stops the platform first, every write in
    progress is abandoned atomically, and the CLI prints one line naming the
    signal and exits ``128 + signal``.

    Attributes
    ----------
    signum : int
        The signal received.
    name : str
        Its name (``SIGTERM``, ``SIGHUP``).
    """

    def __init__(self, signum: int, name: str) -> None:
        super().__init__(name)
        self.signum = int(signum)
        self.name = name

    @property
    def exit_code(self) -> int:
        """``128 + signal`` (143 for SIGTERM, 129 for SIGHUP), as a shell reports a process ended by it."""
        return 128 + self.signum

    @property
    def prefix(self) -> str:
        """How the one failure line starts: ``terminated (SIGTERM)``, ``hung up (SIGHUP)``."""
        return f"{'hung up' if self.name == 'SIGHUP' else 'terminated'} ({self.name})"


# ----------------------------------------------------------------------------- one line per failure
#: What an exhausted memory is told as (exit 1, an operating-system limit, not a bug).
OUT_OF_MEMORY = (
    "out of memory: the machine (or its limit, `ulimit -v`) gave no more; free memory, or diff fewer "
    "lightings or smaller images at once"
)


def is_out_of_memory(exc: BaseException) -> bool:
    """A MemoryError, or OpenCV's allocation failure (``cv2.error``: "Insufficient memory")."""
    return isinstance(exc, MemoryError) or (type(exc).__name__ == "error" and "Insufficient memory" in str(exc))


def os_error_line(exc: OSError) -> str:
    """The one line of an operating-system error: ``<reason>: <file>`` (README, "Errors": a full disk).

    The file is left out only when the error names none.
    """
    name = getattr(exc, "filename", None)
    reason = exc.strerror or str(exc)
    return f"{reason}: {name}" if name else reason
