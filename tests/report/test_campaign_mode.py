"""`fgcd diff --campaign` and `fgcd report` on a small campaign written with the store API."""

import json
import shutil
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from changes.conftest import textured_scene, translate  # noqa: E402

from fgcd_cli.app.diff import CampaignDiffRequest, run_campaign
from fgcd_cli.app.report import station_history  # noqa: E402
from fgcd_cli.campaign.store import init_campaign, open_campaign
from fgcd_cli.campaign.verify import verify_campaign


def _u8(image):
    return np.round(np.clip(image, 0, 1) * 255).astype(np.uint8)


VISITS = ("20250101T000000Z", "20250601T000000Z")


def _campaign(tmp_path):
    """A station S1 with a reference (two lightings) and two visits, the later one with a 10 px disc changed."""
    camp = init_campaign(tmp_path / "camp", site="test site")
    station = camp.create_station("S1")
    ref = textured_scene(192)
    with station.write_reference({"lightings": ["L1", "L2"]}) as w:
        w.add_image("L1", _u8(ref))
        w.add_image("L2", _u8(ref * 0.6))
        w.commit()
    changed = ref.copy()
    cv2.circle(changed, (50, 140), 10, 0.9, -1)
    for stamp, image in zip(VISITS, (ref, changed)):
        cur = translate(image, 0.8, -1.1)
        log = "".join(
            json.dumps({"iteration": i, "t_wall_s": i, "g": 1.0, "offset_mm": 5 * 0.5**i, "offset_deg": 0.5**i}) + "\n"
            for i in range(5)
        )
        with station.new_visit({"lightings": ["L1", "L2"]}, stamp=stamp) as w:
            w.add_image("L1", _u8(cur))
            w.add_image("L2", _u8(cur * 0.6))
            w.add_bytes("relocation.jsonl", log.encode())
            w.commit()
    return camp


def test_campaign_diff_and_history(tmp_path):
    _campaign(tmp_path)
    data = run_campaign(CampaignDiffRequest(campaign=tmp_path / "camp", station="S1", mm_per_px=0.5))
    assert data["visit"] == "20250601T000000Z" and data["comparable"]
    region = data["regions"][0]
    assert abs(region["centroid_xy"][0] - 50) < 3 and abs(region["centroid_xy"][1] - 140) < 3
    assert region["area_mm2"] == region["area_px"] * 0.25
    visit = open_campaign(tmp_path / "camp").station("S1").visit()
    assert visit.has("changes/regions.json") and visit.has("report.html") and visit.has("afd.json")
    history = station_history(tmp_path / "camp", "S1")
    assert [v["regions"] > 0 for v in history["visits"]] == [False, True]
    assert Path(history["output"]).read_text().count("<img") >= 3


def _fgcd(capsys, *args):
    """``fgcd ARGS`` in this process: (exit code, stdout, stderr)."""
    from fgcd_cli.cli.app import app, run

    code = run(app, list(args))
    out = capsys.readouterr()
    return code, out.out, out.err


def _nothing_is_loaded(monkeypatch):
    """Opening a campaign (the first step that reads data) fails the test: options must be refused before."""
    import fgcd_cli.campaign.store as store

    def load(*_args, **_kwargs):
        raise AssertionError("the campaign was opened before the options were checked")

    monkeypatch.setattr(store, "open_campaign", load)


@pytest.mark.parametrize(
    "option",
    [
        ("--mm-per-px", "-1"),
        ("--mm-per-px", "0"),
        ("--mm-per-px", "nan"),
        ("--mm-per-px", "inf"),
        ("--edge-check", "-2"),
        ("--edge-check", "9"),
    ],
)
def test_campaign_diff_refuses_bad_options_before_reading_anything(tmp_path, capsys, monkeypatch, option):
    camp = _campaign(tmp_path)
    _nothing_is_loaded(monkeypatch)
    code, out, err = _fgcd(capsys, "diff", "-c", str(camp.path), "-s", "S1", *option)
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith(f"error: {option[0]} must be"), err
    assert not (camp.path / "stations/S1/visits" / VISITS[1] / "changes").exists()  # nothing written


def test_campaign_diff_scores_against_a_given_truth_and_counts_regions(tmp_path, capsys):
    camp = _campaign(tmp_path)
    truth = np.zeros((192, 192), np.uint8)
    cv2.circle(truth, (50, 140), 10, 255, -1)  # the disc the later visit changed
    cv2.circle(truth, (150, 40), 8, 255, -1)  # and a change the detector cannot have seen
    cv2.imwrite(str(tmp_path / "truth.png"), truth)
    code, out, err = _fgcd(capsys, "diff", "-c", str(camp.path), "-s", "S1", "--truth", str(tmp_path / "truth.png"))
    assert code == 0, err
    assert "1 of 2 change(s) found, 0 false region(s)" in out
    code, out, err = _fgcd(
        capsys, "diff", "-c", str(camp.path), "-s", "S1", "--truth", str(tmp_path / "truth.png"), "--json", "--force"
    )
    scores = json.loads(out)["scores"]
    assert (scores["changes_true"], scores["changes_found"], scores["false_regions"]) == (2, 1, 0)
    assert 0.4 < scores["recall"] < 0.75  # the disc's pixels of the two discs' (314 of 515)
    # a truth of another size is refused before anything is written
    cv2.imwrite(str(tmp_path / "small.png"), truth[:100])
    stored = (camp.path / "stations/S1/visits" / VISITS[1] / "changes" / "regions.json").read_bytes()
    code, out, err = _fgcd(
        capsys, "diff", "-c", str(camp.path), "-s", "S1", "--truth", str(tmp_path / "small.png"), "--force"
    )
    assert code == 2 and err.count("\n") == 1 and "--truth" in err
    assert (camp.path / "stations/S1/visits" / VISITS[1] / "changes" / "regions.json").read_bytes() == stored


def test_diff_requests_check_their_options_for_every_caller(tmp_path):
    """The bench and the archive build the same requests: the check is theirs too."""
    from fgcd_cli.app.diff import BareDiffRequest
    from fgcd_cli.errors import UserInputError

    for bad in (-1.0, 0.0, float("nan"), float("-inf")):
        with pytest.raises(UserInputError, match="--mm-per-px"):
            CampaignDiffRequest(campaign=tmp_path, station="S1", mm_per_px=bad)
        with pytest.raises(UserInputError, match="--mm-per-px"):
            BareDiffRequest(ref=["a.png"], cur=["b.png"], output=tmp_path, mm_per_px=bad)
    with pytest.raises(UserInputError, match="--roi: file not found"):
        CampaignDiffRequest(campaign=tmp_path, station="S1", roi=tmp_path / "mask.png")
    with pytest.raises(UserInputError, match="--ambient-index"):
        BareDiffRequest(ref=["a.png"], cur=["b.png"], output=tmp_path, ambient_index=-1)


def test_rediff_with_other_options_keeps_the_stored_diff_unless_forced(tmp_path, capsys):
    camp = _campaign(tmp_path)
    first = run_campaign(CampaignDiffRequest(campaign=camp.path, station="S1"))
    visit = camp.path / "stations/S1/visits" / VISITS[1]
    stored = (visit / "changes/regions.json").read_bytes()
    record = json.loads((visit / "changes/analysis.json").read_text())
    assert record["options"]["mm_per_px"] is None and record["options"]["edge_check_px"] is None
    code, out, err = _fgcd(capsys, "diff", "-c", str(camp.path), "-s", "S1", "--mm-per-px", "0.5")
    assert code == 5 and out == "" and err.count("\n") == 1
    assert (
        "already has a diff made with no --mm-per-px, --edge-check 2" in err
        and "--mm-per-px 0.5" in err
        and "--force" in err
    )
    assert (visit / "changes/regions.json").read_bytes() == stored
    again = run_campaign(CampaignDiffRequest(campaign=camp.path, station="S1", edge_check_px=2))  # the same diff
    assert again["regions"] == first["regions"] and not any("replaced" in w for w in again["warnings"])
    forced = run_campaign(CampaignDiffRequest(campaign=camp.path, station="S1", mm_per_px=0.5, force=True))
    assert forced["regions"][0]["area_mm2"] == forced["regions"][0]["area_px"] * 0.25
    assert json.loads((visit / "changes/analysis.json").read_text())["options"]["mm_per_px"] == 0.5
    assert verify_campaign(open_campaign(camp.path)).ok


def test_rediff_over_a_diff_without_a_record_says_it_replaced_it(tmp_path):
    camp = _campaign(tmp_path)
    visit = open_campaign(camp.path).station("S1").visit()
    visit.add_derived(
        "changes/regions.json", b'{"regions": [], "metadata": {"metric scale": "-1.0 mm per px (given)"}}'
    )
    assert [p.kind for p in verify_campaign(open_campaign(camp.path)).problems] == ["scale"]
    data = run_campaign(CampaignDiffRequest(campaign=camp.path, station="S1"))
    assert any("replaced the stored diff of visit 20250601T000000Z" in w for w in data["warnings"])
    assert verify_campaign(open_campaign(camp.path)).ok


def test_diff_with_the_latest_recorded_visit_missing_names_it(tmp_path, capsys):
    camp = _campaign(tmp_path)
    shutil.rmtree(camp.path / "stations/S1/visits" / VISITS[1])
    code, out, err = _fgcd(capsys, "diff", "-c", str(camp.path), "-s", "S1")
    assert code == 4 and out == "" and err.count("\n") == 1
    assert f"latest recorded visit {VISITS[1]} is missing" in err and f"--visit {VISITS[0]}" in err
    assert not (camp.path / "stations/S1/visits" / VISITS[0] / "changes").exists()  # the older one was not diffed


@pytest.mark.parametrize("damage", ["manifest", "folder"])
def test_history_reports_the_good_visits_and_names_the_damaged_one(tmp_path, capsys, damage):
    camp = _campaign(tmp_path)
    older = camp.path / "stations/S1/visits" / VISITS[0]
    if damage == "manifest":
        (older / "manifest.json").write_text("{ not json")
    else:
        shutil.rmtree(older)
    code, out, err = _fgcd(capsys, "report", "-c", str(camp.path), "-s", "S1", "--json")
    assert code == 4 and err.count("\n") == 1
    assert f"1 recorded visit(s) damaged or missing ({VISITS[0]}); the report covers the other 1" in err
    data = json.loads(out)
    assert [v["name"] for v in data["visits"]] == [VISITS[1]] and data["visits"][0]["regions"] > 0
    assert [d["name"] for d in data["damaged"]] == [VISITS[0]]
    assert ("not valid JSON" if damage == "manifest" else "folder") in data["damaged"][0]["reason"]
    page = Path(data["output"]).read_text()
    assert "Damaged or missing visit(s), not compared: " + VISITS[0] in page and '<td class="l">damaged: ' in page


def _campaign_with_a_cloud(tmp_path, T_cur_ref):
    """A station whose reference holds a metric cloud of a tilted plane and a raised block (exact geometry,
    tests/changes/plane_scene.py); its visit is seen from ``T_cur_ref`` with one painted disc."""
    from changes.plane_scene import H, K, W, scene  # noqa: PLC0415

    ref, cur, depth = scene(T_cur_ref, block=True, paint=(100, 280))
    v, u = np.mgrid[0:H:3, 0:W:3]
    z = depth[v, u]
    points = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=-1).reshape(-1, 3)
    camp = init_campaign(tmp_path / "camp", site="test site")
    station = camp.create_station("S1")
    intrinsics = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "width": W, "height": H}
    with station.write_reference({"lightings": ["L1"], "intrinsics": intrinsics}) as w:
        w.add_image("L1", _u8(ref))
        w.add_cloud(points)
        w.add_array("T_ref_camref", np.eye(4))
        w.commit()
    with station.new_visit({"lightings": ["L1"]}, stamp=VISITS[0]) as w:
        w.add_image("L1", _u8(cur))
        w.commit()
    return camp


def test_campaign_diff_measures_the_visit_pose_against_the_reference_depth(tmp_path, capsys):
    from changes.plane_scene import make_pose  # noqa: PLC0415

    camp = _campaign_with_a_cloud(tmp_path, make_pose((40.0, 10.0, 5.0), (0.1, -0.2, 0.05)))
    code, out, err = _fgcd(capsys, "diff", "-c", str(camp.path), "-s", "S1", "--json")
    assert code == 0, err
    geo = json.loads(out)["settings"]["geometry"]
    # |t| = 41.5 mm; SIFT on the plane and block fixes it to a fraction of a millimetre (test_geometry.py)
    assert geo["warp"] == "reference depth and residual pose"
    assert abs(geo["residual_pose_mm"] - np.linalg.norm([40.0, 10.0, 5.0])) < 0.5
    assert geo["depth_edge_fraction"] > 0  # the block's outline: a parallax jump of ~1.3 px
    assert len(json.loads(out)["regions"]) == 1
    # the same visit without the geometry: a different diff, refused over the stored one unless forced
    code, out, err = _fgcd(capsys, "diff", "-c", str(camp.path), "-s", "S1", "--no-geometry")
    assert code == 5 and "--no-geometry" in err
    code, out, err = _fgcd(capsys, "diff", "-c", str(camp.path), "-s", "S1", "--no-geometry", "--force", "--json")
    assert code == 0 and "geometry" not in json.loads(out)["settings"]


def test_bare_diff_refuses_no_geometry(tmp_path, capsys):
    image = tmp_path / "a.png"
    cv2.imwrite(str(image), np.zeros((8, 8), np.uint8))
    code, out, err = _fgcd(
        capsys, "diff", "--ref", str(image), "--cur", str(image), "-o", str(tmp_path / "o"), "--no-geometry"
    )
    assert code == 2 and "--no-geometry is for campaign mode" in err and "Traceback" not in err
