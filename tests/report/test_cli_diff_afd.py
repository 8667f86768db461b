"""`fgcd diff` and `fgcd afd` in bare-image mode, through the console entry point."""

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from fgcd_cli.changes.result import WHY_NOT_REPORTED

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from changes.conftest import textured_scene, translate  # noqa: E402

FGCD = [sys.executable, "-c", "from fgcd_cli.cli.app import main; main()"]


@pytest.fixture(scope="module")
def image_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("imgs")
    ref = textured_scene(256)
    changed = ref.copy()
    cv2.circle(changed, (200, 60), 12, 0.95, -1)
    cur = translate(changed, -1.4, 2.1)
    for name, im in (("ref-1", ref), ("ref-2", ref * 0.7), ("cur-1", cur), ("cur-2", cur * 0.7)):
        cv2.imwrite(str(folder / f"{name}.png"), np.round(im * 65535).astype(np.uint16))  # 16-bit input
    cv2.imwrite(str(folder / "small.png"), (ref[:100] * 255).astype(np.uint8))
    return folder


def run(*args):
    return subprocess.run([*FGCD, *args], capture_output=True, text=True, timeout=300)


def test_diff_writes_all_outputs(image_files, tmp_path):
    out = tmp_path / "out"
    proc = run(
        "diff",
        "--ref",
        str(image_files / "ref-*.png"),
        "--cur",
        str(image_files / "cur-*.png"),
        "-o",
        str(out),
        "--mm-per-px",
        "0.1",
        "--json",
    )
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    assert data["comparable"] and data["settings"]["lightings"] == 2
    assert data["regions"][0]["area_mm2"] == pytest.approx(data["regions"][0]["area_px"] * 0.01)
    cx, cy = data["regions"][0]["centroid_xy"]
    assert abs(cx - 200) < 3 and abs(cy - 60) < 3  # reference frame, not the current one
    for name in (
        "change_score.png",
        "change_score.npy",
        "change_mask.png",
        "overlay.png",
        "regions.json",
        "report.html",
    ):
        assert (out / name).stat().st_size > 0
    assert cv2.imread(str(out / "change_score.png"), cv2.IMREAD_UNCHANGED).dtype == np.uint16
    assert np.load(out / "change_score.npy").shape == (256, 256)


def test_diff_size_mismatch_is_one_line(image_files, tmp_path):
    proc = run(
        "diff", "--ref", str(image_files / "ref-1.png"), "--cur", str(image_files / "small.png"), "-o", str(tmp_path)
    )
    assert proc.returncode == 2
    assert "same size" in proc.stderr and "Traceback" not in proc.stderr
    assert sum(line.startswith("error:") for line in proc.stderr.splitlines()) == 1


def test_diff_missing_file(tmp_path):
    proc = run("diff", "--ref", str(tmp_path / "nope.png"), "--cur", str(tmp_path / "nope.png"), "-o", str(tmp_path))
    assert proc.returncode == 2 and "not found" in proc.stderr


def test_diff_input_errors_are_exactly_one_stderr_line(image_files, tmp_path):
    """No empty line from a progress bar, no "comparing..." before a size mismatch: the error line alone."""
    missing = run(
        "diff",
        "--ref",
        str(tmp_path / "missing.png"),
        "--cur",
        str(image_files / "ref-1.png"),
        "-o",
        str(tmp_path / "o1"),
    )
    assert missing.returncode == 2 and missing.stdout == ""
    assert missing.stderr == f"error: image not found: {tmp_path / 'missing.png'}\n"
    mismatch = run(
        "diff",
        "--ref",
        str(image_files / "ref-1.png"),
        "--cur",
        str(image_files / "small.png"),
        "-o",
        str(tmp_path / "o2"),
    )
    assert mismatch.returncode == 2 and mismatch.stdout == ""
    assert len(mismatch.stderr.splitlines()) == 1 and mismatch.stderr.startswith("error: current image 1 is 256x100 px")
    assert not (tmp_path / "o1").exists() and not (tmp_path / "o2").exists()


def test_diff_names_empty_and_damaged_image_files(image_files, tmp_path):
    """A 0-byte file is empty, a cut-short PNG or JPEG is damaged (OpenCV would decode the JPEG with grey rows)."""
    png = (image_files / "ref-1.png").read_bytes()
    ok, jpg = cv2.imencode(".jpg", (textured_scene(64) * 255).astype(np.uint8))
    cases = {
        "empty.png": (b"", "empty file (0 bytes)"),
        "cut.png": (png[: len(png) // 2], "damaged or truncated PNG file"),
        "cut.jpg": (jpg.tobytes()[: len(jpg) // 2], "damaged or truncated JPEG file"),
        "notes.png": (b"field notes, not an image", "not an image format OpenCV knows"),
    }
    for name, (data, said) in cases.items():
        (tmp_path / name).write_bytes(data)
        proc = run(
            "diff", "--ref", str(tmp_path / name), "--cur", str(image_files / "ref-1.png"), "-o", str(tmp_path / "o")
        )
        assert proc.returncode == 2, name
        assert proc.stderr.splitlines() == [proc.stderr.strip()] and said in proc.stderr, (name, proc.stderr)


def test_afd_json_and_figure(image_files, tmp_path):
    fig = tmp_path / "q.png"
    proc = run("afd", str(image_files / "ref-1.png"), str(image_files / "cur-1.png"), "-o", str(fig), "--json")
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    assert data["afd_px"] == pytest.approx(np.hypot(1.4, 2.1), abs=0.15)
    assert data["settings"]["ratio"] == 0.75 and data["inliers"] > 20
    assert cv2.imread(str(fig)) is not None


def test_diff_edge_check_option(tmp_path):
    """The edge check (default 2 px) sets the half-pixel-shifted groove aside (and says so); --edge-check 0
    reports it; a bad value is one clear line."""
    from changes.test_edge_tolerance import _niche_scene, _revisit

    ref, _ = _niche_scene(0)
    cur, _ = _niche_scene(2)
    cv2.imwrite(str(tmp_path / "ref.png"), np.round(ref * 65535).astype(np.uint16))
    cv2.imwrite(str(tmp_path / "cur.png"), np.round(_revisit(cur) * 65535).astype(np.uint16))
    args = ("diff", "--ref", str(tmp_path / "ref.png"), "--cur", str(tmp_path / "cur.png"), "--json")
    # the bands are faint: the contrast floor alone sets them aside, and says so
    floored = run(*args, "-o", str(tmp_path / "floored"), "--edge-check", "0")
    assert floored.returncode == 0, floored.stderr
    assert json.loads(floored.stdout)["settings"]["low_contrast_regions"] > 0
    plain = run(*args, "-o", str(tmp_path / "plain"), "--edge-check", "0", "--min-contrast", "0")
    assert plain.returncode == 0, plain.stderr
    assert len(json.loads(plain.stdout)["regions"]) > 0
    checked = run(*args, "-o", str(tmp_path / "checked"))  # the default
    assert checked.returncode == 0, checked.stderr
    data = json.loads(checked.stdout)
    assert data["regions"] == [] and data["settings"]["edge_explained_regions"] >= 1 and data["set_aside_px"] > 0
    assert "set aside" in (tmp_path / "checked" / "report.html").read_text()
    bad = run(*args, "-o", str(tmp_path / "bad"), "--edge-check", "99")
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
    assert "--edge-check" in bad.stderr.strip().splitlines()[-1]
    bad = run(*args, "-o", str(tmp_path / "bad"), "--min-contrast", "1.5")
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
    assert "--min-contrast" in bad.stderr.strip().splitlines()[-1]


def test_large_frames_take_the_tiled_path_with_the_same_change(image_files, tmp_path, monkeypatch):
    # A frame above LARGE_FRAME_PX goes through detect_changes_tiled; lowered here so the
    # 256 px pair takes that path: the same change is found at the same place.
    from fgcd_cli.app import diff as usecases

    monkeypatch.setattr(usecases, "LARGE_FRAME_PX", 10_000)
    calls = []
    data = usecases.run_bare(
        usecases.BareDiffRequest(
            ref=[str(image_files / "ref-*.png")], cur=[str(image_files / "cur-*.png")], output=tmp_path / "out"
        ),
        tile_progress=lambda done, total, label: calls.append((done, total)),
    )
    assert data["comparable"] and "work_scale" in data["settings"]
    cx, cy = data["regions"][0]["centroid_xy"]
    assert abs(cx - 200) < 3 and abs(cy - 60) < 3
    assert calls and calls[-1][0] == calls[-1][1]  # progress reached its total
    assert (tmp_path / "out" / "report.html").stat().st_size > 0


def test_a_diff_in_a_pipe_names_its_step_and_beats(image_files, tmp_path):
    """Off a terminal the diff's lines name a step and the heartbeat repeats it (shortened here to 0.05 s), so a
    long comparison (a 24 MP frame: about a minute) is never silent in a log; stdout keeps only the result."""
    import os

    proc = subprocess.run(
        [
            *FGCD,
            "diff",
            "--ref",
            str(image_files / "ref-*.png"),
            "--cur",
            str(image_files / "cur-*.png"),
            "-o",
            str(tmp_path / "out"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "FGCD_HEARTBEAT_S": "0.05"},
    )
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.splitlines()
    assert lines[0].startswith("comparing 2 lighting(s)"), lines
    assert any(line.startswith("  ... comparing 2 lighting(s)") for line in lines), lines
    assert "comparing" not in proc.stdout and "changed region" in proc.stdout


def test_diff_says_how_many_highlights_it_set_aside(tmp_path):
    """A glossy highlight that clips in both 8-bit visits and slides: not reported, and both the summary
    line and the report say so."""
    from changes.test_clip_check import _highlight_pair

    refs, curs = _highlight_pair()
    for k, (ref, cur) in enumerate(zip(refs, curs), start=1):
        cv2.imwrite(str(tmp_path / f"ref-{k}.png"), np.round(ref * 255).astype(np.uint8))
        cv2.imwrite(str(tmp_path / f"cur-{k}.png"), np.round(cur * 255).astype(np.uint8))
    out = tmp_path / "out"
    proc = run("diff", "--ref", str(tmp_path / "ref-*.png"), "--cur", str(tmp_path / "cur-*.png"), "-o", str(out))
    assert proc.returncode == 0, proc.stderr
    assert "explained by clipped pixels" in proc.stdout
    data = json.loads((out / "regions.json").read_text())
    assert data["settings"]["clipped_regions"] >= 1
    assert all(np.hypot(r["centroid_xy"][0] - 92, r["centroid_xy"][1] - 96) > 12 for r in data["regions"])
    report = (out / "report.html").read_text()
    assert "explained by clipped pixels" in report and WHY_NOT_REPORTED["clipped"] in report
    assert data["candidates"][0]["why"] == WHY_NOT_REPORTED["clipped"]
