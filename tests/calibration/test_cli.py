"""`fgcd calibrate ...` on the command line: bad input gives one line, the simulated camera is the rig's."""

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

from fgcd_cli.campaign import init_campaign

ROOT = Path(__file__).parents[2]


def fgcd(*args, timeout=600):
    return subprocess.run([sys.executable, "-m", "fgcd_cli.cli.app", *map(str, args)], capture_output=True,
                          text=True, cwd=ROOT, timeout=timeout)


def one_line_error(r, code=2, *, mentions: str):
    assert r.returncode == code, (r.returncode, r.stderr)
    assert "Traceback" not in r.stderr
    errors = [line for line in r.stderr.strip().splitlines() if line.startswith("error:")]
    assert len(errors) == 1, r.stderr
    assert mentions in errors[0], errors[0]


def test_intrinsics_needs_exactly_one_source(tmp_path):
    one_line_error(fgcd("calibrate", "intrinsics"), mentions="--images")
    one_line_error(fgcd("calibrate", "intrinsics", "--sim", "--images", tmp_path), mentions="--images")


def test_intrinsics_from_an_empty_folder(tmp_path):
    one_line_error(fgcd("calibrate", "intrinsics", "--images", tmp_path), mentions="no images")


def test_intrinsics_without_a_board_in_view(tmp_path):
    rng = np.random.default_rng(0)
    for i in range(4):
        cv2.imwrite(str(tmp_path / f"noise_{i}.png"), (rng.random((240, 320)) * 255).astype(np.uint8))
    r = fgcd("calibrate", "intrinsics", "--images", tmp_path)
    assert r.returncode != 0 and "Traceback" not in r.stderr
    assert "board was found in only 0 of 4" in r.stderr


def test_handeye_target_mode_has_no_board_in_the_simulator():
    one_line_error(fgcd("calibrate", "hand-eye", "--mode", "target", "--driver", "sim", "--yes"), mentions="board")


def test_handeye_unknown_mode():
    one_line_error(fgcd("calibrate", "hand-eye", "--mode", "magic", "--yes"), mentions="unknown mode")


def test_handeye_rejects_a_zero_rotation_before_moving():
    r = fgcd("calibrate", "hand-eye", "--mode", "target-free", "--driver", "sim", "--rotation-deg", "0", "--yes")
    one_line_error(r, mentions="rotation")
    assert "stop 1/" not in r.stderr + r.stdout
    assert "platform makes small motions" not in r.stderr + r.stdout  # refused before the rig is opened
    r = fgcd("calibrate", "hand-eye", "--mode", "target-free", "--driver", "ur", "--host", "192.0.2.1",
             "--translation-mm", "500", "--yes")
    one_line_error(r, mentions="translation")  # not a connection error: checked before connecting


def test_sim_intrinsics_calibrate_the_camera_of_the_rig_of_that_seed(tmp_path):
    """`--sim --seed N` must calibrate the camera `hand-eye --driver sim --seed N` uses.

    The nominal camera differs from the rig's by 0.5 % in focal length and 6.5 px
    in cy for seed 2; 8 board views calibrate to ~0.1 % and ~1 px, so the
    tolerances (0.25 %, 3 px) separate the two.
    """
    from drivers.sim.rig import SimRigConfig, build_sim_rig

    init_campaign(tmp_path / "c", site="x", rig={"driver": "sim"})
    r = fgcd("calibrate", "intrinsics", "--sim", "--seed", 2, "--sim-views", 8, "-c", tmp_path / "c", "--json")
    assert r.returncode == 0, r.stderr
    cam = json.loads(r.stdout)["camera"]
    stored = json.loads((tmp_path / "c" / "rig" / "intrinsics.json").read_text())["camera"]
    assert stored["fx"] == cam["fx"]
    rig = build_sim_rig(scene="stele", config=SimRigConfig(seed=2))
    try:
        true = rig.ground_truth.intrinsics_true()
    finally:
        rig.close()
    assert abs(cam["fx"] / true.fx - 1) < 0.0025
    assert abs(cam["fy"] / true.fy - 1) < 0.0025
    assert abs(cam["cx"] - true.cx) < 3.0
    assert abs(cam["cy"] - true.cy) < 3.0
