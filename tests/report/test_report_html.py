"""The diff report renders in a real browser (headless Chromium) and is self-contained."""

import re
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from changes.conftest import textured_scene, translate  # noqa: E402

from fgcd_cli.changes.detect import detect_changes
from fgcd_cli.metrics.afd import compute_fdf  # noqa: E402
from fgcd_cli.report.html import ReportContext  # noqa: E402
from fgcd_cli.report.products import diff_products  # noqa: E402

CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)


@pytest.fixture(scope="module")
def products():
    ref = textured_scene(256)
    changed = ref.copy()
    cv2.circle(changed, (60, 180), 14, 0.9, -1)
    cur = translate(changed, 1.5, 0.8)
    rgb = lambda g: np.repeat(g[:, :, None], 3, axis=2)  # noqa: E731
    result = detect_changes([rgb(ref)], [rgb(cur)], pixel_area_mm2=np.full((256, 256), 0.04))
    fdf = compute_fdf(ref, cur)
    log = [
        {
            "iteration": i,
            "t_wall_s": i * 0.5,
            "g": 1.0,
            "afd_px_true": 40 * 0.5**i,
            "pose_err_mm_true": 20 * 0.5**i,
            "pose_err_deg_true": 2 * 0.5**i,
        }
        for i in range(8)
    ]
    files = diff_products(
        ref_images=[rgb(ref)],
        cur_images=[rgb(cur)],
        result=result,
        fdf=fdf,
        context=ReportContext(
            relocation_log=log, metadata={"station": "S1", "lightings": ["ambient"]}, title="Test report"
        ),
    )
    return result, files


def test_products_are_complete_and_consistent(products, tmp_path):
    result, files = products
    assert {
        "change_score.png",
        "change_score.npy",
        "change_mask.png",
        "overlay.png",
        "regions.json",
        "report.html",
    } <= set(files)
    path = tmp_path / "score.png"
    path.write_bytes(files["change_score.png"])
    score16 = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert score16.dtype == np.uint16 and score16.shape == (256, 256)
    # The change is the brightest area of the 16-bit score map.
    assert np.unravel_index(
        np.argmax(cv2.GaussianBlur(score16.astype(float), (0, 0), 3)), score16.shape
    ) == pytest.approx((180, 60), abs=8)
    assert result.regions and result.regions[0].area_mm2 == pytest.approx(result.regions[0].area_px * 0.04)


def test_report_is_self_contained(products):
    html = products[1]["report.html"].decode()
    assert "<img" in html
    # Every image is embedded; nothing is fetched from elsewhere.
    assert not re.search(r'(src|href)="(?!data:)', html)
    assert "mm²" in html and "AFD" in html and "Convergence" in html


@pytest.mark.skipif(CHROMIUM is None, reason="headless Chromium not installed (/usr/bin/chromium)")
def test_report_renders_in_chromium(products, tmp_path):
    page = tmp_path / "report.html"
    page.write_bytes(products[1]["report.html"])
    shot = tmp_path / "shot.png"
    cmd = [
        CHROMIUM,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        f"--user-data-dir={tmp_path / 'profile'}",
        f"--screenshot={shot}",
        "--window-size=1280,2000",
        page.as_uri(),
    ]
    subprocess.run(cmd, capture_output=True, timeout=120)
    assert shot.exists(), "Chromium wrote no screenshot"
    image = cv2.imread(str(shot))
    assert image.shape[:2] == (2000, 1280)
    # Not blank: text, photographs and figures give many distinct colours and real contrast.
    assert image.std() > 20
    assert len(np.unique(image.reshape(-1, 3) // 16, axis=0)) > 200
    # The magenta change tint is visible somewhere on the page.
    b, g, r = image[..., 0].astype(int), image[..., 1].astype(int), image[..., 2].astype(int)
    assert np.count_nonzero((r > 180) & (b > 120) & (g < 120)) > 50


def test_report_shows_close_ups_of_the_regions(products):
    result, files = products
    html = files["report.html"].decode()
    assert "Close-ups" in html
    shown = min(len(result.regions), 12)
    assert html.count("<figcaption>Region 1:") == 1 and len(re.findall(r"<figcaption>Region \d+:", html)) == shown


def test_cannot_compare_report_says_why_once(tmp_path):
    ref = np.repeat(textured_scene(128)[:, :, None], 3, axis=2)
    black = np.zeros_like(ref)
    result = detect_changes([ref], [black])
    html = diff_products(ref_images=[ref], cur_images=[black], result=result)["report.html"].decode()
    assert "Not compared:" in html and "black" in html
    assert "cannot compare: cannot compare" not in html and "Not compared:</b> cannot compare" not in html
    assert "Close-ups" not in html
