"""A seeded subset of `fgcd bench faults` in the default run: one fault of most classes, judged like the bench.

Uses the fake UR controller (fixed ports): must not run in parallel with the other UR tests.
"""

from __future__ import annotations

import pytest

from fgcd_cli.bench.faults.main import FAULT_CLASSES, run, summarize

pytestmark = pytest.mark.timeout(600)

#: One fault each of these classes, seed 7 (about 45 s on 2 busy cores); the full bench runs all 14 classes.
SUBSET = (
    "grbl_link_dropped",
    "grbl_hard_limit",
    "ur_emergency_stop",
    "sigkill_during_write",
    "enospc_during_write",
    "two_relocates_at_once",
    "damaged_reference",
)


def test_a_seeded_subset_of_the_fault_campaign_leaves_everything_consistent(tmp_path):
    data = run(seed=7, classes=SUBSET, per_class=1, workdir=tmp_path)
    bad = [row for row in data["faults"] if not row["ok"]]
    assert not bad, bad
    s = data["summary"]
    assert s["faults_tried"] == len(SUBSET) and s["fault_classes"] == len(SUBSET)
    for key in ("platform_left_moving", "campaign_inconsistent", "earlier_data_changed", "tracebacks"):
        assert s[key] == 0, key
    by = {row["fault"]: row for row in data["faults"]}
    assert (
        by["two_relocates_at_once"]["code"] == 3 and "in use by another fgcd" in by["two_relocates_at_once"]["detail"]
    )
    assert (
        by["damaged_reference"]["code"] == 4 and by["damaged_reference"]["damaged"] in by["damaged_reference"]["detail"]
    )


def test_the_judge_counts_what_went_wrong():
    from fgcd_cli.bench.faults.checks import FaultOutcome

    good = FaultOutcome(fault="grbl_alarm", seed=0, command="x", code=7, expected=(7,), stderr_lines=1, traceback=False)
    moving = FaultOutcome(
        fault="grbl_alarm",
        seed=1,
        command="x",
        code=7,
        expected=(7,),
        stderr_lines=1,
        traceback=False,
        platform_left_moving=True,
    )
    chatty = FaultOutcome(fault="ur_frozen", seed=0, command="x", code=7, expected=(7,), stderr_lines=8, traceback=True)
    s = summarize([good, moving, chatty])
    assert (
        s["faults_tried"],
        s["fault_classes"],
        s["platform_left_moving"],
        s["tracebacks"],
        s["stderr_not_one_line"],
        s["faults_ok"],
    ) == (3, 2, 1, 1, 1, 1)
    assert len(FAULT_CLASSES) == len(set(FAULT_CLASSES))  # one class, one name


def test_every_group_class_is_planned_and_counted_in_its_group():
    from fgcd_cli.bench.faults.checks import FaultOutcome
    from fgcd_cli.bench.faults.main import GROUPS, _plan

    quick = _plan(FAULT_CLASSES, quick=True, seed=3, per_class=None, explicit=False)
    for key, classes in GROUPS.items():
        planned = [fault for fault, _ in quick if fault in classes]
        assert len(planned) == (1 if classes else 0), key  # the quick run keeps one fault of each group
    full = _plan(FAULT_CLASSES, quick=False, seed=0, per_class=None, explicit=False)
    assert {fault for fault, _ in full} == set(FAULT_CLASSES)
    rows = [
        FaultOutcome(
            fault=fault,
            seed=k,
            command="x",
            code=0,
            expected=(0,),
            stderr_lines=0,
            traceback=False,
            one_line_expected=False,
        )
        for fault, k in full
    ]
    s = summarize(rows)
    for key, classes in GROUPS.items():
        assert s[key] == sum(fault in classes for fault, _ in full), key


def test_a_fault_whose_instant_never_came_is_not_counted_in_its_group():
    from fgcd_cli.bench.faults.checks import FaultOutcome

    def row(fault: str, landed: bool) -> FaultOutcome:
        return FaultOutcome(
            fault=fault,
            seed=0,
            command="x",
            code=0,
            expected=(0,),
            stderr_lines=0,
            traceback=False,
            one_line_expected=False,
            landed=landed,
        )

    s = summarize([row("relocate_sigint", True), row("relocate_sigterm", False), row("power_loss_journal", False)])
    assert (s["whole_operation_faults"], s["whole_operation_classes"], s["power_loss_points"], s["not_landed"]) == (
        1,
        1,
        0,
        2,
    )
    assert s["faults_ok"] == 3  # judged as usual: a command that ended before the instant must still end well
