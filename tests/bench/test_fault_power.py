"""The power-loss launcher (``python -m fgcd_cli.bench.faults.power_launch``): its write events, counted and cut at a
chosen one, and what a store write killed at seeded events leaves (docs/hardware.md, "Faults in the field")."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from fgcd_cli.bench.faults.checks import ROOT, committed_digests, earlier_changed
from fgcd_cli.bench.faults.power_launch import read_log, write_event_path

#: A tiny writer: two folders, three files, a rename, a file outside the root, a tree removed.
WRITER = """
import os, shutil, sys, time
root = sys.argv[1]
os.makedirs(root + "/out/sub")
for i in range(3):
    with open(f"{root}/out/sub/f{i}.bin", "wb") as fh:
        fh.write(b"x" * 1000)
os.replace(f"{root}/out/sub/f0.bin", f"{root}/out/sub/g0.bin")
open(sys.argv[2], "w").write("outside")
open(f"{root}/out/sub/f1.bin", "rb").read()
time.sleep(float(os.environ.get("WRITER_PAUSE_S", "0")))
shutil.rmtree(f"{root}/out/sub")
"""
#: The writer's events under the root, in order (``shutil.rmtree`` removes through descriptors: its
#: entries are resolved to full paths).
WRITER_EVENTS = [
    "os.mkdir out",
    "os.mkdir out/sub",
    "open out/sub/f0.bin",
    "open out/sub/f1.bin",
    "open out/sub/f2.bin",
    "os.rename out/sub/f0.bin",
    "shutil.rmtree out/sub",
]


def _launch(tmp_path: Path, script: str, args: list[str], **env: str) -> tuple[int, list, object]:
    """Run ``script`` under the launcher with ``FGCD_BENCH_POWER_*`` = ``env``: exit code, events, kill."""
    path = tmp_path / "writer.py"
    path.write_text(textwrap.dedent(script))
    log = tmp_path / "events.log"
    variables = {f"FGCD_BENCH_POWER_{k.upper()}": v for k, v in env.items()}
    proc = subprocess.run(
        [sys.executable, "-m", "fgcd_cli.bench.faults.power_launch", *args],
        cwd=ROOT,
        env={**os.environ, "FGCD_BENCH_POWER_TARGET": str(path), "FGCD_BENCH_POWER_LOG": str(log), **variables},
        capture_output=True,
        timeout=300,
    )
    events, kill = read_log(log)
    return proc.returncode, events, kill


@pytest.fixture
def root(tmp_path):
    (tmp_path / "root").mkdir()
    return tmp_path / "root"


def _names(events, root: Path) -> list[str]:
    return [f"{e.event} {Path(e.path).relative_to(root).as_posix()}" for e in events]


def test_a_counting_run_logs_each_write_under_the_root_in_order(tmp_path, root):
    code, events, kill = _launch(tmp_path, WRITER, [str(root), str(tmp_path / "outside.txt")], under=str(root))
    assert code == 0 and kill is None
    names = _names(events, root)
    assert names[: len(WRITER_EVENTS)] == WRITER_EVENTS
    # then the removal of each entry of the tree (in directory order) and the folder itself
    assert sorted(names[len(WRITER_EVENTS) :]) == sorted(
        ["os.remove out/sub/g0.bin", "os.remove out/sub/f1.bin", "os.remove out/sub/f2.bin", "os.rmdir out/sub"]
    )
    assert [e.n for e in events] == list(range(1, len(events) + 1))


@pytest.mark.parametrize("n", [1, 4, 6])
def test_the_kill_falls_before_the_chosen_event(tmp_path, root, n):
    code, events, kill = _launch(
        tmp_path, WRITER, [str(root), str(tmp_path / "outside.txt")], under=str(root), at=str(n)
    )
    assert code == -signal.SIGKILL
    assert _names(events, root) == WRITER_EVENTS[: n - 1] and kill.n == n
    assert kill.path.startswith("before " + WRITER_EVENTS[n - 1].split()[0])
    made = sorted(p.relative_to(root).as_posix() for p in root.rglob("*"))
    assert ("out/sub/f0.bin" in made) == (n > 3) and ("out/sub/f2.bin" in made) == (n > 5)


def test_events_count_from_the_first_matching_one_and_only_matching_ones(tmp_path, root):
    args = [str(root), str(tmp_path / "outside.txt")]
    _, events, _ = _launch(tmp_path, WRITER, args, under=str(root), **{"from": "f1.bin"})
    assert _names(events, root)[:3] == ["open out/sub/f1.bin", "open out/sub/f2.bin", "os.rename out/sub/f0.bin"]
    _, events, _ = _launch(tmp_path, WRITER, args, under=str(root), only="f2.bin")
    assert _names(events, root) == ["open out/sub/f2.bin", "os.remove out/sub/f2.bin"]
    _, events, _ = _launch(tmp_path, WRITER, args, under=str(root), only="f2.bin", event="os.remove")
    assert _names(events, root) == ["os.remove out/sub/f2.bin"]


def test_a_delayed_kill_lands_after_the_first_event(tmp_path, root):
    os.environ["WRITER_PAUSE_S"] = "120"  # the writer waits there: the delayed kill ends it long before
    try:
        code, events, kill = _launch(
            tmp_path, WRITER, [str(root), str(tmp_path / "outside.txt")], under=str(root), delay_s="0.2"
        )
    finally:
        del os.environ["WRITER_PAUSE_S"]
    assert code == -signal.SIGKILL and kill.path == "after 0.200 s"
    assert _names(events, root) == WRITER_EVENTS[:6] and kill.seconds >= 0.2


def test_only_file_system_changes_are_write_events(tmp_path):
    f = str(tmp_path / "f")
    assert write_event_path("open", (f, "r", os.O_RDONLY)) is None
    assert write_event_path("open", (f, None, os.O_WRONLY | os.O_APPEND)) == f
    assert write_event_path("open", (f, "wb", 0)) == f
    assert write_event_path("open", (3, "wb", 0)) is None  # a descriptor: counted when its file was opened
    assert write_event_path("import", ("os",)) is None
    assert write_event_path("os.remove", ("x", -100)) == os.path.join(os.getcwd(), "x")


#: A visit written through the store (the same writer ``fgcd relocate`` uses), after a committed one.
STORE_WRITER = """
import sys
import numpy as np
from fgcd_cli.campaign.store import open_campaign
station = open_campaign(sys.argv[1]).station("s")
with station.new_visit({"n": 2}) as w:
    w.add_image("led:3", np.full((16, 16), 7, np.uint8))
    w.add_cloud(np.zeros((50, 3)))
    w.add_bytes("relocation.jsonl", b"{}\\n")
    w.commit()
"""


def _store_campaign(tmp_path: Path):
    from fgcd_cli.campaign.store import init_campaign

    camp = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim"})
    st = camp.station_or_create("s")
    for writer in (st.write_reference({}), st.new_visit({"n": 1})):
        with writer as w:
            w.add_image("led:3", np.zeros((16, 16), np.uint8))
            w.commit()
    return camp.path, st.path


def test_a_store_write_killed_at_seeded_events_leaves_only_named_leftovers(tmp_path):
    from fgcd_cli.bench.faults.power import judge_verify, leftovers

    campaign, station = _store_campaign(tmp_path / "count")
    where = {"under": str(campaign / "stations"), "from": "/visits/.tmp-"}  # from the visit's temporary folder
    _, events, _ = _launch(tmp_path, STORE_WRITER, [str(campaign)], **where)
    assert events[0].event == "os.mkdir" and events[-1].event == "os.rename"  # station.json's atomic write last
    rng = np.random.default_rng(5)
    for n in sorted(set(rng.integers(1, len(events) + 1, size=4)) | {len(events)}):
        campaign, station = _store_campaign(tmp_path / f"kill-{n}")
        before = committed_digests(campaign)
        where["under"] = str(campaign / "stations")
        code, _, kill = _launch(tmp_path, STORE_WRITER, [str(campaign)], **where, at=str(n))
        assert code == -signal.SIGKILL and kill.n == n
        assert earlier_changed(before, committed_digests(campaign)) == []
        wrong, new = judge_verify(campaign, station, set())
        assert wrong == [], (n, events[n - 1], wrong)
        # before the rename of the visit folder, its temporary folder is named; after it, nothing is left but
        # (before the index update) the unindexed visit
        assert bool(leftovers(station)) == bool(new), (n, new)


@pytest.mark.slow
def test_power_loss_points_of_a_real_revisit_leave_the_campaign_consistent(tmp_path):
    # one point of each class on a fresh bench campaign (a calibration, a capture, a counting revisit, two
    # killed revisits), then the fifth point of a class: killed, and followed by a new revisit that succeeds
    from fgcd_cli.bench.faults.main import run
    from fgcd_cli.bench.faults.power import FAULTS, inject

    data = run(classes=FAULTS, per_class=1, seed=0, workdir=tmp_path)
    summary = data["summary"]
    assert summary["power_loss_points"] == 2 and summary["faults_ok"] == 2, data["faults"]
    for key in ("platform_left_moving", "campaign_inconsistent", "earlier_data_changed", "tracebacks"):
        assert summary[key] == 0, data["faults"]
    fifth = inject(FAULTS[0], 4, tmp_path / "campaign")
    assert fifth.ok and fifth.extra["revisit_after"] == 0, fifth.to_dict()
