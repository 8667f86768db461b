"""What the fault benches count as earlier data (``fgcd_cli.bench.faults.checks.committed_digests``)."""

from __future__ import annotations

import json

import numpy as np

from fgcd_cli.bench.faults.checks import committed_digests, earlier_changed
from fgcd_cli.campaign.store import init_campaign, open_campaign


def _campaign(tmp_path):
    camp = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim"})
    with camp.station_or_create("s").write_reference({}) as w:
        w.add_image("led:3", np.zeros((16, 16), np.uint8))
        w.commit()
    return camp.path


def _add_visit(campaign) -> None:
    with open_campaign(campaign).station("s").new_visit({"n": 1}) as w:
        w.add_image("led:3", np.full((16, 16), 7, np.uint8))
        w.commit()


def test_a_committed_visit_appending_itself_to_the_station_index_is_new_data(tmp_path):
    campaign = _campaign(tmp_path)
    before = committed_digests(campaign)
    _add_visit(campaign)
    after = committed_digests(campaign)
    assert earlier_changed(before, after) == []
    assert len(after) > len(before)  # the visit and its index entry are counted from now on


def test_a_vanished_index_entry_or_an_edited_station_field_is_earlier_data_changed(tmp_path):
    campaign = _campaign(tmp_path)
    _add_visit(campaign)
    station_file = campaign / "stations" / "s" / "station.json"
    before = committed_digests(campaign)
    info = json.loads(station_file.read_text(encoding="utf-8"))
    dropped = {**info, "observations": info["observations"][:1]}
    station_file.write_text(json.dumps(dropped), encoding="utf-8")
    assert earlier_changed(before, committed_digests(campaign)) == [f"s/station.json#indexes/{info['observations'][1]}"]
    station_file.write_text(json.dumps({**info, "site": "elsewhere"}), encoding="utf-8")
    assert earlier_changed(before, committed_digests(campaign)) == ["s/station.json#fields"]
    station_file.write_bytes(b"{not json")
    assert earlier_changed(before, committed_digests(campaign)) == ["s/station.json#fields"] + [
        f"s/station.json#indexes/{obs}" for obs in info["observations"]
    ]


def test_a_capture_fault_takes_a_station_name_no_earlier_run_left(tmp_path):
    from fgcd_cli.bench.faults.checks import fresh_station

    campaign = _campaign(tmp_path)
    assert fresh_station(campaign, "t-1") == "t-1"
    assert fresh_station(campaign, "s") == "s-r2"
    (campaign / "stations" / "s-r2").mkdir()
    assert fresh_station(campaign, "s") == "s-r3"


def test_the_full_disk_launcher_reaches_an_observations_own_files(tmp_path):
    """The simulated ENOSPC hits the files an observation writes itself (``open``), not only atomic writes."""
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent(f"""
        from pathlib import Path
        from fgcd_cli.bench.faults.launch import install_enospc
        install_enospc(1000, {str(tmp_path)!r})
        from fgcd_cli.campaign.observation import ObservationKind, ObservationWriter
        writer = ObservationWriter(Path({str(tmp_path / "obs")!r}), ObservationKind.VISIT, {{}})
        writer.add_bytes("small.bin", b"0" * 600)
        try:
            writer.add_bytes("large.bin", b"0" * 5000)
        except OSError as exc:
            print(exc.errno, exc.filename)
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["28", str(tmp_path / "obs" / "large.bin")]
