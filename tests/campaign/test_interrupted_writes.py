"""Writes cut at the worst moment (found by `fgcd bench faults`): a station being created, a derived product
being replaced. `fgcd campaign verify` must pass afterwards."""

from __future__ import annotations

import numpy as np
import pytest

import fgcd_cli.campaign.observation as observation_mod
import fgcd_cli.campaign.store as store_mod
from fgcd_cli.campaign.store import init_campaign, open_campaign
from fgcd_cli.campaign.verify import verify_campaign_dir


@pytest.fixture
def camp(tmp_path):
    return init_campaign(tmp_path / "c", site="x", rig={"driver": "sim"})


def test_ctrl_c_while_a_new_station_is_created_leaves_no_station(camp, monkeypatch):
    real = store_mod.atomic_write_json

    def interrupted(path, data, **kwargs):
        tmp = path.parent / ".tmp-station.json.cut"
        tmp.write_text("{")  # the temporary file exists when the signal lands; atomic_write removes its own
        tmp.unlink()
        raise KeyboardInterrupt

    monkeypatch.setattr(store_mod, "atomic_write_json", interrupted)
    with pytest.raises(KeyboardInterrupt):
        with camp.station_for_writing("new"):
            pass
    monkeypatch.setattr(store_mod, "atomic_write_json", real)
    assert not (camp.path / "stations" / "new").exists()
    assert verify_campaign_dir(camp.path).ok


def test_a_kill_between_a_derived_file_and_its_manifest_leaves_a_consistent_visit(camp, monkeypatch):
    st = camp.station_or_create("s")
    with st.new_visit({}) as w:
        w.add_image("front", np.zeros((4, 4), np.uint8))
        w.commit()
    visit = open_campaign(camp.path).station("s").visits()[-1]
    visit.add_derived("changes/overlay.png", b"first")

    from fgcd_cli.campaign.atomic import sha256_bytes

    real = observation_mod.atomic_write_json
    new = sha256_bytes(b"second, longer")

    def killed_before_listing_the_new_file(path, data, **kwargs):
        if data.get("files", {}).get("changes/overlay.png", {}).get("sha256") == new:
            raise KeyboardInterrupt  # the new file is in place, the manifest that lists it is not
        return real(path, data, **kwargs)

    monkeypatch.setattr(observation_mod, "atomic_write_json", killed_before_listing_the_new_file)
    with pytest.raises(KeyboardInterrupt):
        visit.add_derived("changes/overlay.png", b"second, longer")
    report = verify_campaign_dir(camp.path)
    assert report.ok, report.to_dict()  # the old entry went first: the old file is merely unlisted (a warning)
    assert any(p.kind == "unlisted" for p in report.problems)


def test_a_visit_committed_by_a_killed_process_is_indexed_by_the_next_write(camp):
    import json

    st = camp.station_or_create("s")
    for _ in range(2):
        with st.new_visit({}) as w:
            w.add_image("front", np.zeros((4, 4), np.uint8))
            w.commit()
    sfile = camp.path / "stations" / "s" / "station.json"
    info = json.loads(sfile.read_text())
    lost = info["observations"].pop()  # killed between the visit's rename and its index update
    sfile.write_text(json.dumps(info))
    assert any(p.kind == "unindexed" for p in verify_campaign_dir(camp.path).problems)
    with open_campaign(camp.path).station("s").new_visit({}) as w:
        w.add_image("front", np.zeros((4, 4), np.uint8))
        w.commit()
    index = json.loads(sfile.read_text())["observations"]
    assert lost in index and len(index) == 3 and index.index(lost) == 1  # in its place, before the new one
    assert not any(p.kind == "unindexed" for p in verify_campaign_dir(camp.path).problems)


def test_a_read_only_folder_is_refused_by_name_before_any_work(tmp_path):
    import errno
    import subprocess

    from fgcd_cli.campaign.atomic import check_writable

    check_writable(tmp_path)  # writable: nothing said
    folder = tmp_path / "ro"
    folder.mkdir()
    mounted = (
        subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=1m,ro", "tmpfs", str(folder)], capture_output=True
        ).returncode
        == 0
    )
    if not mounted:
        pytest.skip("mounting a read-only tmpfs is not permitted here (needs root)")
    try:
        with pytest.raises(OSError) as info:
            check_writable(folder)
        assert info.value.errno == errno.EROFS and info.value.filename == str(folder)
    finally:
        subprocess.run(["umount", str(folder)], check=False)
