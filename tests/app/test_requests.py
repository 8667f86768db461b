"""The use cases take typed requests, and the campaign's layout is spelled once."""

import inspect

from fgcd_cli.app.rig import open_rig
from fgcd_cli.campaign import schema


def test_open_rig_takes_a_typed_request():
    assert "request" in inspect.signature(open_rig).parameters


def test_schema_spells_the_layout():
    assert schema.image_relpath("led:3") == "images/led-3.png"
    assert schema.image_relpath_candidates("led:3") == ["images/led-3.png", "images/led:3.png"]
    assert schema.image_name_of("images/led-3.png") == "led-3" and schema.image_name_of("cloud.ply") is None
    assert schema.array_relpath(schema.ARRAY_T_REF_CAMREF) == "arrays/T_ref_camref.npy"
    assert schema.change_relpath(schema.REPORT_HTML) == "report.html"
    assert schema.change_relpath(schema.REGIONS_JSON) == "changes/regions.json"
    assert schema.ObservationKind.REFERENCE == "reference" and schema.ObservationKind.VISIT == "visit"
    assert (schema.CAMPAIGN_FILE, schema.STATION_FILE, schema.MANIFEST, schema.CLOUD_FILE, schema.RELOCATION_LOG) == (
        "campaign.toml",
        "station.json",
        "manifest.json",
        "cloud.ply",
        "relocation.jsonl",
    )
    assert schema.rig_record_file("handeye") == "handeye.json"
