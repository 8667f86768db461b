"""The up-to-date record of an archived analysis (archive/freshness.py) on a campaign written with the store API."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fgcd_cli.archive import freshness as fr
from fgcd_cli.archive.freshness import (
    ANALYSIS_RELPATH,
    AnalysisOptions,
    Freshness,
    analysis_inputs,
    analysis_record,
    freshness,
    verify_inputs,
)
from fgcd_cli.campaign import schema
from fgcd_cli.campaign.store import init_campaign
from fgcd_cli.errors import DataIntegrityError


@pytest.fixture
def analysed(tmp_path):
    """A station whose one visit carries products and a matching analysis record (no diff run: the record's rules)."""
    camp = init_campaign(tmp_path / "c", site="s")
    st = camp.create_station("S")
    rng = np.random.default_rng(0)
    with st.write_reference({"lightings": ["a"], "intrinsics": {"fx": 100.0}}) as w:
        w.add_image("a", rng.integers(0, 255, (16, 16, 3), dtype=np.uint8))
        w.commit()
    with st.new_visit(stamp="20240101T000000000Z") as w:
        w.add_image("a", rng.integers(0, 255, (16, 16, 3), dtype=np.uint8))
        w.commit()
    visit = st.visit()
    visit.add_derived(schema.change_relpath(schema.REGIONS_JSON), b'{"regions": []}')
    visit.add_derived(schema.REPORT_HTML, b"<html></html>")
    inputs = analysis_inputs(st.reference(), visit)
    visit.add_derived(
        ANALYSIS_RELPATH,
        json.dumps(analysis_record(visit, inputs=inputs, options=AnalysisOptions(), seconds=1.0)).encode(),
    )
    return st


def test_up_to_date_until_the_version_the_options_an_input_or_a_product_changes(analysed, monkeypatch):
    st = analysed
    ref, visit = st.reference(), st.visit()
    assert freshness(ref, visit, AnalysisOptions()) == Freshness.UP_TO_DATE
    assert freshness(ref, visit, AnalysisOptions(edge_check_px=0)) == Freshness.OPTIONS_CHANGED
    monkeypatch.setattr(fr, "DETECTOR_VERSION", "next")
    assert freshness(ref, visit, AnalysisOptions()) == Freshness.DETECTOR_CHANGED
    monkeypatch.undo()
    (visit.path / schema.REPORT_HTML).write_bytes(
        b"<html>edited</html>"
    )  # another size: the product is not the one recorded
    assert freshness(ref, visit, AnalysisOptions()) == Freshness.PRODUCTS_MISSING
    (visit.path / ANALYSIS_RELPATH).unlink()
    assert freshness(ref, visit, AnalysisOptions()) == Freshness.NOT_ANALYSED


def test_a_record_older_than_an_option_keeps_its_meaning(analysed):
    """A record written before ``eval_mask_sha256`` existed is read with that option's default (up to date)."""
    st = analysed
    visit = st.visit()
    record = json.loads((visit.path / ANALYSIS_RELPATH).read_text())
    record["options"].pop("eval_mask_sha256")
    visit.add_derived(ANALYSIS_RELPATH, json.dumps(record).encode())
    visit = st.visit()
    assert freshness(st.reference(), visit, AnalysisOptions()) == Freshness.UP_TO_DATE
    assert fr.stored_options(visit) == AnalysisOptions()
    assert freshness(st.reference(), visit, AnalysisOptions(eval_mask_sha256="ab")) == Freshness.OPTIONS_CHANGED


def test_a_changed_input_checksum_is_seen_and_damaged_bytes_are_refused(analysed):
    st = analysed
    ref, visit = st.reference(), st.visit()
    inputs = analysis_inputs(ref, visit)
    assert set(inputs) == {"reference/images/a.png", "visit/images/a.png", "reference/manifest.json#intrinsics"}
    verify_inputs(ref, visit, inputs)
    visit.manifest["files"]["images/a.png"]["sha256"] = "0" * 64  # as if the visit's image had been replaced
    assert freshness(ref, visit, AnalysisOptions()) == Freshness.INPUTS_CHANGED
    with pytest.raises(DataIntegrityError, match="images/a.png: damaged"):
        verify_inputs(ref, visit, analysis_inputs(ref, visit))
