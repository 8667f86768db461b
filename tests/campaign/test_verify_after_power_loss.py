"""`fgcd campaign verify` after a process killed while it wrote a visit: each leftover named precisely, a
leftover never an error, damage never silent (docs/hardware.md, "Faults in the field")."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from fgcd_cli.campaign.schema import RELOCATION_LOG, VISIT_JOURNAL, VISITS_DIR
from fgcd_cli.campaign.store import init_campaign, open_campaign
from fgcd_cli.campaign.verify import verify_campaign_dir

RECORDS = [{"iteration": 1, "residual": 0.01}, {"iteration": 2, "residual": 0.001}]


@pytest.fixture
def station(tmp_path):
    camp = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim"})
    st = camp.station_or_create("s")
    with st.write_reference({}) as w:
        w.add_image("led:3", np.zeros((4, 4), np.uint8))
        w.commit()
    return open_campaign(camp.path).station("s")


def _problems(station) -> list[tuple[str, str, str]]:
    report = verify_campaign_dir(station.campaign.path)
    return [(p.path.removeprefix(str(station.path) + "/"), p.kind, p.severity) for p in report.problems]


def _journal(station, text: str) -> None:
    (station.path / VISITS_DIR).mkdir(exist_ok=True)
    (station.path / VISITS_DIR / VISIT_JOURNAL).write_text(text)


def _lines(*entries) -> str:
    return "".join(json.dumps(e) + "\n" for e in entries)


START = {"kind": "start", "options": {"driver": "sim", "light": "led:3"}}
ENTRIES = [{"record": r, "T_base_flange": np.eye(4).tolist()} for r in RECORDS]


def test_the_temporary_folder_of_a_visit_being_written_is_a_warning_naming_the_visit(station):
    with station.new_visit({}, stamp="20261201T000000000Z") as w:
        w.add_image("led:3", np.zeros((4, 4), np.uint8))
        shutil.copytree(w.tmp_path, station.path / VISITS_DIR / ".tmp-20261201T000000000Z-dead0001")
    report = verify_campaign_dir(station.campaign.path)
    assert report.ok
    [problem] = report.problems
    assert (problem.kind, problem.severity) == ("incomplete-write", "warning")
    assert "visit 20261201T000000000Z" in problem.detail and "1 file" in problem.detail
    assert "without its manifest" in problem.detail and "safe to delete" in problem.detail


def test_a_station_record_cut_before_its_rename_names_the_intact_file(station):
    (station.path / ".tmp-station.json.k1ll3d00").write_text('{"name": "s", "obs')
    report = verify_campaign_dir(station.campaign.path)
    assert report.ok and [(p.kind, p.severity) for p in report.problems] == [("incomplete-write", "warning")]
    assert "station.json in place is intact" in report.problems[0].detail


def test_an_intact_journal_is_a_note_and_a_cut_last_line_a_warning(station):
    _journal(station, _lines(START, *ENTRIES))
    assert _problems(station) == [(f"{VISITS_DIR}/{VISIT_JOURNAL}", "interrupted-visit", "note")]
    _journal(station, _lines(START, ENTRIES[0]) + json.dumps(ENTRIES[1])[:17])
    assert _problems(station) == [(f"{VISITS_DIR}/{VISIT_JOURNAL}", "incomplete-write", "warning")]
    detail = verify_campaign_dir(station.campaign.path).problems[0].detail
    assert "line 3" in detail and "1 adjustment before it hold" in detail


@pytest.mark.parametrize("text", ["", json.dumps(START)[:9]])
def test_a_journal_killed_at_its_first_line_is_a_leftover(station, text):
    _journal(station, text)
    assert _problems(station) == [(f"{VISITS_DIR}/{VISIT_JOURNAL}", "incomplete-write", "warning")]


@pytest.mark.parametrize(
    "text", [_lines(START) + "garbage\n" + _lines(ENTRIES[0]), _lines(ENTRIES[0]), _lines(START) + "not json\n"]
)
def test_a_journal_damaged_otherwise_is_an_error(station, text):
    # every line is written whole and fsynced: a bad middle line, a missing start line or a bad whole
    # last line is no interrupted write's doing
    _journal(station, text)
    report = verify_campaign_dir(station.campaign.path)
    assert not report.ok and [(p.kind, p.severity) for p in report.problems] == [("journal", "error")]


def test_a_journal_that_outlived_its_committed_visit_is_a_leftover_naming_the_visit(station):
    with station.new_visit({}, stamp="20261201T000000000Z") as w:
        w.add_bytes(RELOCATION_LOG, _lines(*RECORDS).encode())
        w.commit()
    _journal(station, _lines(START, *ENTRIES))
    [problem] = verify_campaign_dir(station.campaign.path).problems
    assert (problem.kind, problem.severity) == ("incomplete-write", "warning")
    assert "committed as visits/20261201T000000000Z" in problem.detail
    _journal(station, _lines(START, ENTRIES[0]))  # fewer adjustments than the visit: a revisit of its own
    assert _problems(station) == [(f"{VISITS_DIR}/{VISIT_JOURNAL}", "interrupted-visit", "note")]


def test_a_derived_product_without_its_manifest_entry_is_named_as_such(station):
    with station.new_visit({}, stamp="20261201T000000000Z") as w:
        w.add_image("led:3", np.zeros((4, 4), np.uint8))
        w.commit()
    visit = station.path / VISITS_DIR / "20261201T000000000Z"
    (visit / "report.html").write_text("<html>")
    (visit / "notes.txt").write_text("mine")
    report = verify_campaign_dir(station.campaign.path)
    assert report.ok
    details = {p.path.rsplit("/", 1)[-1]: p for p in report.problems}
    assert details["report.html"].kind == "unlisted" and "derived product" in details["report.html"].detail
    assert details["notes.txt"].detail == "file not in the manifest"


def test_a_visit_committed_but_not_indexed_says_why(station):
    with station.new_visit({}, stamp="20261201T000000000Z") as w:
        w.add_image("led:3", np.zeros((4, 4), np.uint8))
        w.commit()
    info = json.loads((station.path / "station.json").read_text())
    info["observations"].remove(f"{VISITS_DIR}/20261201T000000000Z")
    (station.path / "station.json").write_text(json.dumps(info))
    [problem] = verify_campaign_dir(station.campaign.path).problems
    assert (problem.kind, problem.severity) == ("unindexed", "warning") and "interrupted" in problem.detail
