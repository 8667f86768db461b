"""The use cases' typed requests keep the defaults of the keyword forms they replace, and the layout is spelled once."""

import inspect

from fgcd_cli.app.capture import CaptureRequest
from fgcd_cli.app.diff import BareDiffRequest, CampaignDiffRequest
from fgcd_cli.app.relocate import RelocateRequest, RevisitRequest
from fgcd_cli.app.rig import RigHooks, RigRequest, open_rig
from fgcd_cli.app.rig_options import RigOptions
from fgcd_cli.campaign import schema
from fgcd_cli.report.html import ReportContext
from fgcd_cli.relocation.coarse import CoarseConfig


def test_rig_request_defaults_are_the_old_open_rig_defaults():
    r = RigRequest(driver="sim")
    assert (r.T_flange_cam, r.intrinsics, r.scenario, r.port, r.baud, r.host, r.camera_index, r.vse_variant) == \
        (None, None, None, None, 115200, None, 0, "mono")
    assert RigHooks() == RigHooks(confirm=None, on_event=None, on_progress=None)
    assert "request" in inspect.signature(open_rig).parameters


def test_relocate_request_defaults():
    r = RelocateRequest(config=None, lightings=["front"])
    assert (r.explore_m, r.explore_legs, r.metadata) == (0.04, 3, None)
    assert r.coarse == CoarseConfig()


def test_cli_requests_keep_the_cli_defaults():
    c = CaptureRequest(station="s")
    assert (c.rig, c.scene, c.seed, c.light) == (RigOptions(), None, None, "front")
    assert RigOptions() == RigOptions(driver=None, port=None, host=None, baud=None, camera=None)
    v = RevisitRequest(station="s")
    # max_adjustments None: the method's own budget (rACR 12 = RelocationConfig's, ACR 30 = AcrConfig's)
    assert (v.light, v.changes, v.start_offset_mm, v.start_offset_deg, v.session_seed, v.eta, v.max_adjustments,
            v.method) == ("led:3", 0, 30.0, 3.0, 1, 1e-4, None, "racr")
    assert not (v.serial or v.no_handeye or v.no_image_refine or v.no_coarse)
    assert v.guided and RelocateRequest(config=None, lightings=["front"]).guided  # the CLI's --guided/--no-guided default
    from fgcd_cli.relocation.acr import AcrConfig
    from fgcd_cli.relocation.config import RelocationConfig

    assert (RelocationConfig().max_adjustments, AcrConfig().max_adjustments) == (12, 30)


def test_diff_requests_and_report_context_defaults():
    b = BareDiffRequest(ref=[], cur=[], output=None)
    assert (b.eval_mask, b.truth, b.mm_per_px, b.register, b.edge_check_px, b.ambient_index) == \
        (None, None, None, True, 0, None)
    c = CampaignDiffRequest(campaign=None, station="s")
    assert (c.visit, c.eval_mask, c.mm_per_px, c.register, c.output, c.edge_check_px) == (None, None, None, True, None, None)
    ctx = ReportContext()
    assert (ctx.relocation_log, ctx.metadata, ctx.title, ctx.subtitle, ctx.max_table_rows, ctx.max_closeups) == \
        (None, None, "Change report", "", 50, 12)


def test_schema_spells_the_layout():
    assert schema.image_relpath("led:3") == "images/led-3.png"
    assert schema.image_relpath_candidates("led:3") == ["images/led-3.png", "images/led:3.png"]
    assert schema.image_name_of("images/led-3.png") == "led-3" and schema.image_name_of("cloud.ply") is None
    assert schema.array_relpath(schema.ARRAY_T_REF_CAMREF) == "arrays/T_ref_camref.npy"
    assert schema.change_relpath(schema.REPORT_HTML) == "report.html"
    assert schema.change_relpath(schema.REGIONS_JSON) == "changes/regions.json"
    assert schema.ObservationKind.REFERENCE == "reference" and schema.ObservationKind.VISIT == "visit"
    assert (schema.CAMPAIGN_FILE, schema.STATION_FILE, schema.MANIFEST, schema.CLOUD_FILE, schema.RELOCATION_LOG) == \
        ("campaign.toml", "station.json", "manifest.json", "cloud.ply", "relocation.jsonl")
    assert schema.rig_record_file("handeye") == "handeye.json"
