"""Degenerate inputs of `fgcd diff` and `fgcd afd`: one clear line or an honest "cannot compare", never a traceback."""

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from changes.conftest import textured_scene, translate  # noqa: E402

FGCD = [sys.executable, "-c", "from fgcd_cli.cli.app import main; main()"]
CANNOT_COMPARE = 6  # AlgorithmError's exit status


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("degenerate")
    wall = cv2.resize(textured_scene(512), (512, 256))
    ref = wall[:, :256].copy()
    images = {
        "ref": ref,
        "cur": translate(ref, 1.5, -0.8),
        "small": ref[:120, :200],
        "black": np.zeros_like(ref),
        "flat": np.full_like(ref, 0.5),
        "elsewhere": wall[:, 256:].copy(),  # another part of the wall: no overlap with ref
    }
    for name, image in images.items():
        cv2.imwrite(str(folder / f"{name}.png"), np.round(image * 255).astype(np.uint8))
    for name in ("ref", "cur"):
        cv2.imwrite(str(folder / f"{name}16.png"), np.round(images[name] * 65535).astype(np.uint16))
    (folder / "notimage.png").write_text("not an image")
    return folder


def run(*args):
    return subprocess.run([*FGCD, *map(str, args)], capture_output=True, text=True, timeout=300)


def one_error_line(proc) -> str:
    assert "Traceback" not in proc.stderr
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, proc.stderr
    return errors[0]


@pytest.mark.parametrize(
    "cur, expected_code, words",
    [
        ("small.png", 2, "equal sizes"),
        ("missing.png", 2, "not found"),
        ("notimage.png", 2, "cannot read image"),
        ("black.png", CANNOT_COMPARE, "black"),
        ("flat.png", CANNOT_COMPARE, "no texture"),
        ("elsewhere.png", CANNOT_COMPARE, "need 12"),
    ],
)
def test_afd_refuses_in_one_line(files, cur, expected_code, words):
    proc = run("afd", files / "ref.png", files / cur)
    assert proc.returncode == expected_code, proc.stderr
    assert words in one_error_line(proc)


def test_afd_grid_refuses_images_that_do_not_overlap(files):
    proc = run("afd", files / "ref.png", files / "elsewhere.png", "--grid")
    assert proc.returncode == CANNOT_COMPARE
    assert "agree on one motion" in one_error_line(proc)


def test_afd_16_bit_equals_8_bit(files):
    values = []
    for suffix in ("", "16"):
        proc = run("afd", files / f"ref{suffix}.png", files / f"cur{suffix}.png", "--json")
        assert proc.returncode == 0, proc.stderr
        values.append(json.loads(proc.stdout)["afd_px"])
    assert values[0] == pytest.approx(np.hypot(1.5, 0.8), abs=0.15)
    assert values[1] == pytest.approx(values[0], abs=0.02)


@pytest.mark.parametrize(
    "cur, words",
    [
        ("small.png", "same size"),
        ("missing.png", "not found"),
        ("notimage.png", "cannot read image"),
    ],
)
def test_diff_bad_input_is_one_line(files, tmp_path, cur, words):
    proc = run("diff", "--ref", files / "ref.png", "--cur", files / cur, "-o", tmp_path / "out")
    assert proc.returncode == 2
    assert words in one_error_line(proc)


@pytest.mark.parametrize(
    "cur, words",
    [
        ("black.png", "black"),
        ("flat.png", "no texture"),
        ("elsewhere.png", "registration failed"),
    ],
)
def test_diff_cannot_compare_is_honest(files, tmp_path, cur, words):
    out = tmp_path / "out"
    proc = run("diff", "--ref", files / "ref.png", "--cur", files / cur, "-o", out, "--json")
    assert proc.returncode == CANNOT_COMPARE, proc.stderr
    assert "Traceback" not in proc.stderr
    data = json.loads(proc.stdout)
    assert data["comparable"] is False and words in data["reason"]
    assert data["regions"] == [] and "afd" not in data  # no made-up displacement either
    # The products still say why, for the record.
    assert json.loads((out / "regions.json").read_text())["comparable"] is False
    report = (out / "report.html").read_text()
    assert "Not compared:" in report and words in report
    human = run("diff", "--ref", files / "ref.png", "--cur", files / cur, "-o", out)
    assert human.returncode == CANNOT_COMPARE
    assert "cannot compare: cannot compare" not in human.stdout and words in human.stdout


def test_diff_16_bit_input(files, tmp_path):
    proc = run("diff", "--ref", files / "ref16.png", "--cur", files / "cur16.png", "-o", tmp_path / "out", "--json")
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    assert data["comparable"] and data["regions"] == []
