"""A station lock: a second capture or revisit of the same station fails at once (exit 3), touches nothing."""

from __future__ import annotations

import hashlib
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from fgcd_cli.campaign.lock import StationBusy, station_lock
from fgcd_cli.campaign.store import init_campaign

ROOT = Path(__file__).parents[2]
pytestmark = pytest.mark.timeout(120)


def _tree_digest(path: Path) -> dict[str, str]:
    return {
        str(p.relative_to(path)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(path.rglob("*"))
        if p.is_file()
    }


@pytest.fixture
def camp(tmp_path):
    c = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim", "sim": {"scene": "stele", "seed": 0}})
    c.write_rig("handeye", {"T_flange_cam": np.eye(4).tolist()})
    meta = {"lightings": ["front"], "driver": "sim", "scenario": {"scene": "stele", "seed": 0, "noise": "default"}}
    with c.station_or_create("s1").write_reference(meta) as w:
        w.add_image("front", np.zeros((4, 4), np.uint8))
        w.commit()
    return c


def test_the_second_holder_is_refused_naming_the_first(camp):
    with station_lock(camp.path, "s1", command="relocate"):
        with pytest.raises(StationBusy, match=r"station 's1' is in use by another fgcd \(pid \d+, relocate since"):
            with station_lock(camp.path, "s1", command="capture"):
                pass
        with station_lock(camp.path, "s2", command="capture"):  # another station: free
            pass
    with station_lock(camp.path, "s1", command="capture"):  # released
        pass
    assert StationBusy("x").exit_code == 3


def test_a_lock_left_by_a_killed_process_is_stale_and_does_not_block(camp):
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            (
                "import sys, time; from fgcd_cli.campaign.lock import station_lock\n"
                "with station_lock(sys.argv[1], 's1', command='relocate'):\n"
                "    print('held', flush=True); time.sleep(60)"
            ),
            str(camp.path),
        ],
        stdout=subprocess.PIPE,
        cwd=ROOT,
    )
    try:
        assert holder.stdout.readline().strip() == b"held"
        with pytest.raises(StationBusy, match=f"pid {holder.pid}"):
            with station_lock(camp.path, "s1", command="relocate"):
                pass
        holder.send_signal(signal.SIGKILL)
        holder.wait(timeout=10)
        with station_lock(camp.path, "s1", command="relocate"):  # the kernel released it
            pass
    finally:
        if holder.poll() is None:
            holder.kill()


def test_a_second_relocate_gets_one_line_exit_3_and_changes_nothing(camp):
    before = _tree_digest(camp.path / "stations")
    with station_lock(camp.path, "s1", command="relocate"):  # the first revisit, running
        started = time.monotonic()
        r = subprocess.run(
            [sys.executable, "-m", "fgcd_cli.cli.app", "relocate", "-c", str(camp.path), "-s", "s1", "--yes"],
            capture_output=True,
            text=True,
            cwd=ROOT,
            timeout=120,
            stdin=subprocess.DEVNULL,
        )
        assert r.returncode == 3, r.stderr
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in r.stderr
        assert "station 's1' is in use by another fgcd" in lines[0]
        assert time.monotonic() - started < 60  # refused before any rig is opened
    assert _tree_digest(camp.path / "stations") == before
