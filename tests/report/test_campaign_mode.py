"""`fgcd diff --campaign` and `fgcd report` on a small campaign written with the store API."""

import json
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from changes.conftest import textured_scene, translate  # noqa: E402

from fgcd_cli.campaign import init_campaign, open_campaign  # noqa: E402
from fgcd_cli.app.diff import CampaignDiffRequest, run_campaign
from fgcd_cli.app.report import station_history  # noqa: E402


def _u8(image):
    return np.round(np.clip(image, 0, 1) * 255).astype(np.uint8)


def test_campaign_diff_and_history(tmp_path):
    camp = init_campaign(tmp_path / "camp", site="test site")
    station = camp.create_station("S1")
    ref = textured_scene(192)
    with station.write_reference({"lightings": ["L1", "L2"]}) as w:
        w.add_image("L1", _u8(ref))
        w.add_image("L2", _u8(ref * 0.6))
        w.commit()
    changed = ref.copy()
    cv2.circle(changed, (50, 140), 10, 0.9, -1)
    for stamp, image in (("20250101T000000Z", ref), ("20250601T000000Z", changed)):
        cur = translate(image, 0.8, -1.1)
        log = "".join(json.dumps({"iteration": i, "t_wall_s": i, "g": 1.0, "offset_mm": 5 * 0.5**i, "offset_deg": 0.5**i}) + "\n"
                      for i in range(5))
        with station.new_visit({"lightings": ["L1", "L2"]}, stamp=stamp) as w:
            w.add_image("L1", _u8(cur))
            w.add_image("L2", _u8(cur * 0.6))
            w.add_bytes("relocation.jsonl", log.encode())
            w.commit()
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
