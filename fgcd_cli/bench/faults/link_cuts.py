"""Link cuts of ``fgcd bench faults``: a link that really drops, cut from outside the controller.

Four classes (docs/hardware.md, "Faults in the field"): the network to the fake
UR controller cut mid-``fgcd platform move`` or down when fgcd connects
(:mod:`fgcd_cli.bench.faults.link_ur`: a network namespace, else a TCP proxy), and the
GRBL emulator's serial line closed from the board's side mid-move, then plugged
back with or without an alarm raised meanwhile (:mod:`fgcd_cli.bench.faults.link_grbl`).
Each is judged on the command (exit 7, one line, within its stated time), the
controller's own motion state after its stated bound, and a clean reconnect
once the link is back (nothing unlocked by connecting).
"""

from __future__ import annotations

from pathlib import Path

from fgcd_cli.bench.faults.checks import FaultOutcome
from fgcd_cli.bench.faults.link_grbl import GRBL_LINK_FAULTS, grbl_link_fault
from fgcd_cli.bench.faults.link_ur import UR_LINK_FAULTS, ur_link_fault

__all__ = ["FAULTS", "PER_CLASS_FULL", "inject"]

FAULTS: tuple[str, ...] = UR_LINK_FAULTS + GRBL_LINK_FAULTS
#: 4 classes x 3 = 12 faults in the full run (target: 10 link cuts); a UR one takes about 20 s, a GRBL one 10 s.
PER_CLASS_FULL = 3


def inject(fault: str, seed: int, campaign: Path) -> FaultOutcome:
    """Run one link cut of class ``fault`` with ``seed`` (the campaign is not used: these hit the platform only)."""
    if fault in UR_LINK_FAULTS:
        return ur_link_fault(fault, seed)
    if fault in GRBL_LINK_FAULTS:
        return grbl_link_fault(fault, seed)
    raise ValueError(f"unknown fault '{fault}'")
