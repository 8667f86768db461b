"""Real small file systems: a tmpfs really full, a read-only campaign folder; the store on them names the file.

Every test here mounts a size-limited tmpfs (root and mount permission); where
that is not allowed it is skipped with the reason, never passed.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np
import pytest

from fgcd_cli.bench.faults.tmpfs import MountUnavailable, fill_to, free_bytes, remount_readonly, small_fs
from fgcd_cli.campaign.lock import station_lock
from fgcd_cli.campaign.store import init_campaign

pytestmark = pytest.mark.timeout(600)

META = {"lightings": ["front"], "driver": "sim", "scenario": {"scene": "stele", "seed": 0, "noise": "default"}}


@pytest.fixture
def tmpfs(tmp_path):
    """A 4 MiB tmpfs (skipped, saying why, where it cannot be mounted)."""
    try:
        with small_fs(4 << 20, parent=tmp_path) as point:
            yield point
    except MountUnavailable as exc:
        pytest.skip(f"real-file-system faults need a tmpfs: {exc}")


def _campaign(point: Path):
    camp = init_campaign(point / "c", site="x", rig={"driver": "sim", "sim": {"scene": "stele", "seed": 0}})
    with camp.station_or_create("s1").write_reference(META) as w:
        w.add_image("front", np.zeros((4, 4), np.uint8))
        w.commit()
    return camp


def test_the_filler_leaves_the_drawn_bytes_free_to_a_page(tmpfs):
    page = os.statvfs(tmpfs).f_frsize
    for leave in np.random.default_rng(0).integers(0, 2 << 20, size=3):
        (tmpfs / ".filler").unlink(missing_ok=True)
        free = fill_to(tmpfs, int(leave))
        assert int(leave) - page < free <= int(leave)
    assert fill_to(tmpfs, 0) == 0 == free_bytes(tmpfs)


def test_a_mount_is_undone_when_its_block_fails(tmp_path):
    try:
        with pytest.raises(RuntimeError):
            with small_fs(1 << 20, parent=tmp_path) as point:
                raise RuntimeError("the fault's own failure")
    except MountUnavailable as exc:
        pytest.skip(f"real-file-system faults need a tmpfs: {exc}")
    assert not point.exists()
    assert str(point) not in Path("/proc/mounts").read_text()


def test_an_observation_on_a_full_disk_names_its_file_and_leaves_nothing(tmpfs):
    camp = _campaign(tmpfs)
    image = np.random.default_rng(1).integers(0, 255, size=(600, 600, 3), dtype=np.uint8)  # ~1 MB of PNG
    fill_to(tmpfs, 200_000)
    with pytest.raises(OSError) as caught:
        with camp.station_or_create("s2").write_reference(META) as w:
            w.add_image("front", image)
            w.commit()
    assert caught.value.errno == errno.ENOSPC
    assert caught.value.filename == str(camp.path / "stations" / "s2" / "reference" / "images" / "front.png")
    assert not list(camp.path.rglob(".tmp-*"))
    assert not (camp.path / "stations" / "s2" / "reference").exists()


def test_a_station_that_cannot_be_written_leaves_no_folder(tmpfs):
    camp = _campaign(tmpfs)
    fill_to(tmpfs, 0)
    with pytest.raises(OSError) as caught:
        camp.station_or_create("s3")
    assert caught.value.errno == errno.ENOSPC
    assert caught.value.filename == str(camp.path / "stations" / "s3" / "station.json")
    assert not (camp.path / "stations" / "s3").exists()
    (tmpfs / ".filler").unlink()
    assert camp.station_or_create("s3").name == "s3"  # once there is room, the station is created


def test_a_read_only_campaign_refuses_the_lock_naming_its_file(tmpfs):
    camp = _campaign(tmpfs)
    remount_readonly(tmpfs)
    with pytest.raises(OSError) as caught:
        with station_lock(camp.path, "s1", command="relocate"):
            pass
    assert caught.value.errno == errno.EROFS
    assert caught.value.filename.startswith(str(camp.path / ".locks"))


@pytest.mark.slow
@pytest.mark.parametrize(
    ("fault", "seed"), [("fs_full_diff", 0), ("fs_full_diff", 1), ("readonly_campaign", 5), ("fs_full_archive", 1)]
)
def test_fgcd_on_a_real_small_file_system_ends_cleanly(tmp_path, fault, seed):
    """The real command on a full (or read-only) tmpfs: documented code, one line naming the file, nothing left."""
    from fgcd_cli.bench.faults.campaign_faults import prepare_campaign
    from fgcd_cli.bench.faults.real_fs import inject

    outcome = inject(fault, seed, prepare_campaign(tmp_path))
    if outcome.skipped:
        pytest.skip(outcome.skipped)
    row = outcome.to_dict()
    assert outcome.ok, f"{row['detail']} (stray stderr lines: {row.get('stray_lines')}, left: {row['leftovers']})"
