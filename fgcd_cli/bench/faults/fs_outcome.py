"""The outcome of a real file-system fault (``fgcd bench faults``): a fault outcome with what a small real file system adds."""

from __future__ import annotations

from dataclasses import dataclass

from fgcd_cli.bench.faults.checks import FaultOutcome


@dataclass(kw_only=True)
class FsOutcome(FaultOutcome):
    """A :class:`FaultOutcome` with what a real small file system adds.

    Attributes
    ----------
    leftovers : list of str
        Half-written files left: ``.tmp-*`` in the campaign copy, files left in the child's ``TMPDIR``.
    file_named : bool
        A failure line names a file on the small file system (True for a success).
    skipped : str
        Why the fault could not be injected here (no mount permission); a skipped fault is not ok.
    """

    leftovers: list[str] | None = None
    file_named: bool = True
    skipped: str = ""

    @property
    def ok(self) -> bool:
        """Every check of :class:`FaultOutcome`, no leftover, the file named, and not skipped."""
        return super().ok and not self.leftovers and self.file_named and not self.skipped

    def to_dict(self) -> dict:
        """The JSON row of this fault."""
        return {
            **super().to_dict(),
            "leftovers": list(self.leftovers or [])[:10],
            "file_named": self.file_named,
            **({"skipped": self.skipped} if self.skipped else {}),
        }


def skipped(fault: str, seed: int, reason: str) -> FsOutcome:
    """The outcome of a fault that could not be injected: not ok, with the reason as its detail."""
    return FsOutcome(
        fault=fault,
        seed=seed,
        command="(skipped)",
        code=0,
        expected=(),
        stderr_lines=0,
        traceback=False,
        one_line_expected=False,
        detail=f"skipped: {reason}",
        skipped=reason,
    )
