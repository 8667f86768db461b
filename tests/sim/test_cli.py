"""`fgcd sim scenes|render`: the catalogue, renders with depth and mask, one-line errors on bad input."""

from __future__ import annotations

import json
import sys

import cv2
import numpy as np
import pytest


class Result:
    def __init__(self, returncode, stdout, stderr):
        self.returncode, self.stdout, self.stderr = returncode, stdout, stderr


@pytest.fixture
def fgcd(capfd, monkeypatch):
    """Run the console entry point in-process (same error handling as the installed ``fgcd``)."""
    from fgcd_cli.cli.app import main

    def run(*args):
        monkeypatch.setattr(sys, "argv", ["fgcd", *map(str, args)])
        capfd.readouterr()
        try:
            main()
            code = 0
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        out, err = capfd.readouterr()
        return Result(code, out, err)

    return run


def one_line_error(r, code, *words):
    assert r.returncode == code, (r.returncode, r.stderr)
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    for w in words:
        assert w in lines[0], lines[0]


def test_scenes_lists_the_catalogue_with_descriptions(fgcd):
    r = fgcd("sim", "scenes", "--json")
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    names = [s["name"] for s in data["scenes"]]
    assert data["count"] == len(names) >= 9
    for required in ("stele", "stupa", "relief_panel", "mural", "statue", "plaster", "bricks", "plane", "sphere"):
        assert required in names
    assert all(len(s["description"]) > 20 for s in data["scenes"])


def test_render_writes_image_depth_and_mask(fgcd, tmp_path):
    out, d_npy, mask = tmp_path / "a" / "img.png", tmp_path / "d.npy", tmp_path / "m.png"
    r = fgcd(
        "sim",
        "render",
        "--scene",
        "plane",
        "--light",
        "led:3",
        "--width",
        "96",
        "--height",
        "72",
        "--pose",
        "10,0,0,0,0,2",
        "-o",
        out,
        "--depth",
        d_npy,
        "--mask",
        mask,
        "--changes",
        "3",
        "--json",
    )
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    img = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert img.shape == (72, 96, 3) and 20 < img.mean() < 235
    depth = np.load(d_npy)
    assert depth.shape == (72, 96) and np.all(depth > 0.4) and depth.max() < 3.0  # the plane fills the view
    m = cv2.imread(str(mask), cv2.IMREAD_UNCHANGED)
    assert set(np.unique(m)) <= {0, 255}
    assert (m == 255).sum() == data["change_pixels"] > 0 and len(data["changes"]) == 3
    # the same view as 16-bit millimetres
    d_png = tmp_path / "d.png"
    r = fgcd(
        "sim",
        "render",
        "--scene",
        "plane",
        "--light",
        "led:3",
        "--width",
        "96",
        "--height",
        "72",
        "--pose",
        "10,0,0,0,0,2",
        "-o",
        tmp_path / "b.png",
        "--depth",
        d_png,
    )
    assert r.returncode == 0, r.stderr
    d16 = cv2.imread(str(d_png), cv2.IMREAD_UNCHANGED)
    assert d16.dtype == np.uint16
    np.testing.assert_allclose(d16, np.round(depth * 1000), atol=1)


@pytest.mark.parametrize(
    "args, words",
    [
        (["--scene", "atlantis"], ["unknown scene", "atlantis", "stele"]),
        (["--scene", "plane", "--light", "disco"], ["unknown lighting", "disco"]),
        (["--scene", "plane", "--pose", "1,2,3"], ["--pose", "six numbers"]),
        (["--scene", "plane", "--pose", "1,2,3,a,b,c"], ["--pose"]),
        (["--scene", "plane", "--pose", "0,0,nan,0,0,0"], ["--pose", "finite"]),
        (["--scene", "plane", "--depth", "d.txt"], ["--depth", ".npy"]),
    ],
)
def test_bad_input_is_one_line(fgcd, tmp_path, args, words):
    r = fgcd("sim", "render", *args, "-o", tmp_path / "x.png")
    one_line_error(r, 2, *words)
    assert not (tmp_path / "x.png").exists()


def test_unwritable_outputs_are_one_line_before_rendering(fgcd, tmp_path):
    afile = tmp_path / "file"
    afile.write_text("not a folder")
    (tmp_path / "dir.png").mkdir()
    one_line_error(
        fgcd("sim", "render", "--scene", "plane", "-o", afile / "x.png"), 2, "cannot write image", "not a directory"
    )
    one_line_error(
        fgcd("sim", "render", "--scene", "plane", "-o", tmp_path / "dir.png"), 2, "cannot write image", "is a directory"
    )
    one_line_error(
        fgcd("sim", "render", "--scene", "plane", "-o", tmp_path / "ok.png", "--mask", afile / "m.png"),
        2,
        "cannot write mask",
    )
    one_line_error(
        fgcd("sim", "render", "--scene", "plane", "-o", tmp_path / "ok.png", "--depth", afile / "d.npy"),
        2,
        "cannot write depth",
    )
    one_line_error(fgcd("sim", "render", "--scene", "plane", "-o", tmp_path / "x.jpg"), 2, ".png")
    assert not (tmp_path / "ok.png").exists()  # refused before rendering anything
