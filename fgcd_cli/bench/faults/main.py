"""``fgcd bench faults``: a seeded fault campaign against real fgcd processes (docs/hardware.md, "Faults").

Sixteen fault classes, each injected at a random moment drawn from the run's
seed: mid-move motion faults on the GRBL emulator and the fake UR controller
(:mod:`fgcd_cli.bench.faults.motion`), and campaign faults — SIGINT and SIGKILL
at random moments and during store writes (``fgcd diff``, ``fgcd capture``), a
full disk, two revisits of one station at once, a damaged reference (:mod:`fgcd_cli.bench.faults.campaign_faults`). Each
outcome is judged by :class:`fgcd_cli.bench.faults.checks.FaultOutcome`.

Four more groups hit the field's faults inside whole operations: faults at
seeded instants of a whole ``fgcd capture`` or ``fgcd relocate``
(:mod:`fgcd_cli.bench.faults.whole`), a real small file system filled up
(:mod:`fgcd_cli.bench.faults.real_fs`), a link cut from outside the controller
(:mod:`fgcd_cli.bench.faults.link_cuts`) and SIGKILL while a visit is written
(:mod:`fgcd_cli.bench.faults.power`). Each group module gives ``FAULTS`` (its
classes), ``PER_CLASS_FULL`` (faults per class in the full run) and
``inject(fault, seed, campaign) -> FaultOutcome``.

Summary keys: ``faults_tried``, ``fault_classes``, ``platform_left_moving``,
``campaign_inconsistent``, ``earlier_data_changed``, ``tracebacks`` (the four
must be 0), ``unexpected_exit_codes``, ``stderr_not_one_line``, ``faults_ok``,
and per group ``whole_operation_faults``, ``whole_operation_classes``,
``real_fs_full_faults``, ``link_cut_faults``, ``power_loss_points`` (each counts the faults that reached
their command), ``not_landed`` (rows whose seeded instant never came: the command ended first),
``resume_not_said`` and ``skipped``.
"""

from __future__ import annotations

import importlib
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from fgcd_cli.bench.faults.campaign_faults import CAPTURE_FAULTS, DATA_FAULTS, data_fault, prepare_campaign
from fgcd_cli.bench.faults.checks import FaultOutcome
from fgcd_cli.bench.faults.motion import GRBL_FAULTS, UR_FAULTS, grbl_fault, ur_fault

__all__ = ["FAULT_CLASSES", "GROUPS", "group_of", "run", "run_fault", "summarize"]

#: The groups of fault classes beyond the single-move and campaign ones: summary key -> its modules.
GROUP_MODULES = {
    "whole_operation_faults": ("fgcd_cli.bench.faults.whole", "fgcd_cli.bench.faults.wired"),
    "real_fs_full_faults": ("fgcd_cli.bench.faults.real_fs",),
    "link_cut_faults": ("fgcd_cli.bench.faults.link_cuts",),
    "power_loss_points": ("fgcd_cli.bench.faults.power",),
}
#: Fault class -> the module that injects it.
_MODULE_OF = {
    fault: module
    for names in GROUP_MODULES.values()
    for module in map(importlib.import_module, names)
    for fault in module.FAULTS
}
#: Summary key -> its fault classes.
GROUPS = {
    key: tuple(f for name in names for f in importlib.import_module(name).FAULTS)
    for key, names in GROUP_MODULES.items()
}
FAULT_CLASSES = GRBL_FAULTS + UR_FAULTS + DATA_FAULTS + CAPTURE_FAULTS + tuple(c for g in GROUPS.values() for c in g)


def group_of(fault: str) -> str | None:
    """The summary key of the group ``fault`` belongs to (None: the single-move and campaign classes)."""
    return next((key for key, classes in GROUPS.items() if fault in classes), None)


#: Faults per class: the full run tries 15 x 14 + 3 x 2 = 216 (a simulated capture takes about 90 s: its
#: classes run a fifth as often); the quick one 3 x 14 = 42, without the capture classes.
PER_CLASS_FULL, PER_CLASS_QUICK = 15, 3


def run_fault(fault: str, seed: int, campaign: Path) -> FaultOutcome:
    """Inject one fault of class ``fault`` with ``seed`` and judge it."""
    if fault in GRBL_FAULTS:
        return grbl_fault(fault, seed)
    if fault in UR_FAULTS:
        from fgcd_drivers.testing.fake_ur import FakeURProcess

        with FakeURProcess() as fake:  # fixed ports: one at a time, a fresh controller per fault
            return ur_fault(fault, seed, fake)
    if fault in _MODULE_OF:
        return _MODULE_OF[fault].inject(fault, seed, campaign)
    return data_fault(fault, seed, campaign)


def summarize(outcomes: list[FaultOutcome]) -> dict:
    """The summary keys of the bench over ``outcomes``."""
    return {
        "faults_tried": len(outcomes),
        "fault_classes": len({o.fault for o in outcomes}),
        "platform_left_moving": sum(o.platform_left_moving for o in outcomes),
        "campaign_inconsistent": sum(o.campaign_inconsistent for o in outcomes),
        "earlier_data_changed": sum(o.earlier_data_changed for o in outcomes),
        "tracebacks": sum(o.traceback for o in outcomes),
        "unexpected_exit_codes": sum(o.code not in o.expected for o in outcomes),
        "stderr_not_one_line": sum(
            (o.stderr_lines != 1) if o.one_line_expected else (o.stderr_lines > 1) for o in outcomes
        ),
        "faults_ok": sum(o.ok for o in outcomes),
        # a group counts the faults that reached their command; the others are counted apart
        **{key: sum(group_of(o.fault) == key and o.landed for o in outcomes) for key in GROUPS},
        "not_landed": sum(not o.landed for o in outcomes),
        # a resume after a revisit fault that neither succeeded nor said whether it continued (`faults.whole`)
        "resume_not_said": sum(o.resume_failed for o in outcomes),
        # faults that could not be injected on this machine (no tmpfs mount): not ok, counted apart
        "skipped": sum(bool(getattr(o, "skipped", "")) for o in outcomes),
        "whole_operation_classes": len(
            {o.fault for o in outcomes if group_of(o.fault) == "whole_operation_faults" and o.landed}
        ),
    }


def run(
    *,
    quick: bool = False,
    seed: int = 0,
    classes: tuple[str, ...] | None = None,
    per_class: int | None = None,
    workdir: Path | None = None,
    on_progress: Callable[[int, int, str], None] | None = None,
) -> dict:
    """Run the fault campaign; a JSON-able dict with ``summary``, ``by_class`` and one row per fault.

    Parameters
    ----------
    quick : bool
        Three faults per class instead of fifteen, the capture classes left out; one fault of each group of
        :data:`GROUPS` (its class drawn from the seed).
    seed : int
        The run's seed: fault ``k`` of a class uses seed ``1000 * seed + k``.
    classes : tuple of str, optional
        A subset of :data:`FAULT_CLASSES`.
    per_class : int, optional
        Overrides the number of faults per class.
    workdir : Path, optional
        Where the bench campaign lives (a temporary folder by default).
    """
    # the quick form leaves out the whole-capture faults (about 90 s each plus one calibration) unless asked for
    chosen = tuple(classes or (tuple(c for c in FAULT_CLASSES if c not in CAPTURE_FAULTS) if quick else FAULT_CLASSES))
    unknown = [c for c in chosen if c not in FAULT_CLASSES]
    if unknown:
        raise ValueError(f"unknown fault classes {unknown} (known: {', '.join(FAULT_CLASSES)})")
    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="fgcd-faults-") as tmp:
        campaign = prepare_campaign(Path(workdir or tmp))
        outcomes: list[FaultOutcome] = []
        plan = _plan(chosen, quick=quick, seed=seed, per_class=per_class, explicit=classes is not None)
        for fault, k in plan:
            if on_progress is not None:
                on_progress(len(outcomes), len(plan), fault)
            outcomes.append(run_fault(fault, 1000 * seed + k, campaign))
    summary = summarize(outcomes)
    summary["seconds"] = round(time.monotonic() - started, 1)
    by_class = {c: summarize([o for o in outcomes if o.fault == c]) for c in chosen}
    return {
        "bench": "faults",
        "quick": quick,
        "seed": seed,
        "summary": summary,
        "targets": {
            "faults_tried": 200,
            "fault_classes": 10,
            "platform_left_moving": 0,
            "campaign_inconsistent": 0,
            "earlier_data_changed": 0,
            "tracebacks": 0,
            **({} if quick else TARGETS),
        },
        "by_class": by_class,
        "faults": [o.to_dict() for o in outcomes],
    }


#: Targets of the full run for the groups (issue "Faults in the middle of real work").
TARGETS = {
    "whole_operation_faults": 60,
    "whole_operation_classes": 8,
    "real_fs_full_faults": 10,
    "link_cut_faults": 10,
    "power_loss_points": 50,
}


def _plan(
    chosen: tuple[str, ...], *, quick: bool, seed: int, per_class: int | None, explicit: bool
) -> list[tuple[str, int]]:
    """``(fault, k)`` pairs to run: fault ``k`` of its class gets seed ``1000 * seed + k``.

    Classes of a group run ``PER_CLASS_FULL`` of their module each in the full run; the quick run keeps one
    fault per group (its class drawn from ``seed``) unless classes were named.
    """
    count = per_class or (PER_CLASS_QUICK if quick else PER_CLASS_FULL)
    plan = []
    for classes in GROUPS.values():
        picked = [c for c in classes if c in chosen]
        if not picked:
            continue
        if quick and not explicit and per_class is None:
            plan.append((picked[seed % len(picked)], 0))
            continue
        plan += [(c, k) for c in picked for k in range(per_class or _MODULE_OF[c].PER_CLASS_FULL)]
    rest = [c for c in chosen if group_of(c) is None]
    plan = [
        (fault, k)
        for k in range(count)
        for fault in rest
        if fault not in CAPTURE_FAULTS or k < max(1, count // 5) or per_class is not None
    ] + plan
    return plan
