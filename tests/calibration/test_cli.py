"""`fgcd calibrate ...` on the command line: bad input gives one line, the simulated camera is the rig's."""

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from fgcd_cli.campaign.store import init_campaign

ROOT = Path(__file__).parents[2]


def fgcd(*args, timeout=600):
    return subprocess.run(
        [sys.executable, "-m", "fgcd_cli.cli.app", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
    )


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


@pytest.mark.parametrize(
    "rig", [("--driver", "ur", "--host", "192.0.2.1"), ("--driver", "grbl", "--port", "/dev/null")]
)
def test_handeye_on_hardware_without_intrinsics_is_one_message(tmp_path, rig):
    for campaign in ((), ("-c", init_campaign(tmp_path / rig[1], site="x").path)):
        r = fgcd("calibrate", "hand-eye", "--mode", "target-free", *rig, *campaign, "--yes", timeout=120)
        assert r.returncode == 2, r.stderr
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1, r.stderr  # no "warning: using nominal intrinsics" before the failure
        assert lines[0].startswith("error:") and "intrinsics" in lines[0] and "warning" not in lines[0]


def test_handeye_with_an_unknown_scene_is_refused_naming_the_scenes():
    r = fgcd("calibrate", "hand-eye", "--driver", "sim", "--scene", "nosuch", "--yes", timeout=120)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "nosuch" in lines[0] and "stele" in lines[0], r.stderr


def test_handeye_rejects_a_zero_rotation_before_moving():
    r = fgcd("calibrate", "hand-eye", "--mode", "target-free", "--driver", "sim", "--rotation-deg", "0", "--yes")
    one_line_error(r, mentions="rotation")
    assert "stop 1/" not in r.stderr + r.stdout
    assert "platform makes small motions" not in r.stderr + r.stdout  # refused before the rig is opened
    r = fgcd(
        "calibrate",
        "hand-eye",
        "--mode",
        "target-free",
        "--driver",
        "ur",
        "--host",
        "192.0.2.1",
        "--translation-mm",
        "500",
        "--yes",
    )
    one_line_error(r, mentions="translation")  # not a connection error: checked before connecting


def test_sim_intrinsics_calibrate_the_camera_of_the_rig_of_that_seed(tmp_path):
    """`--sim --seed N` must calibrate the camera `hand-eye --driver sim --seed N` uses.

    The nominal camera differs from the rig's by 0.5 % in focal length and 6.5 px
    in cy for seed 2; 8 board views calibrate to ~0.1 % and ~1 px, so the
    tolerances (0.25 %, 3 px) separate the two.
    """
    from fgcd_drivers.sim.rig import SimRigConfig, build_sim_rig

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


# ----------------------------------------------------------------------------- the campaign's rig (issue 48, item 1)
INTRINSICS = {
    "camera": {"fx": 600.0, "fy": 600.0, "cx": 320.0, "cy": 240.0, "width": 640, "height": 480},
    "distortion_model": "none",
    "rms_px": 0.2,
    "n_views": 20,
}


def _ur_campaign(tmp_path):
    """A UR campaign (an address nothing listens on: refused at once) with calibrated intrinsics."""
    r = fgcd("campaign", "init", tmp_path / "urc", "--site", "UR site", "--driver", "ur", "--host", "127.0.0.77")
    assert r.returncode == 0, r.stderr
    from fgcd_cli.campaign.store import open_campaign

    camp = open_campaign(tmp_path / "urc")
    camp.write_rig("intrinsics", INTRINSICS)
    return camp


def _rig_files(camp):
    return sorted(p.relative_to(camp.path).as_posix() for p in (camp.path / "rig").rglob("*"))


def test_handeye_drives_the_campaigns_robot_not_the_simulator(tmp_path):
    """No --driver: the campaign's ur at its host; unreachable, so exit 7 at once (not 210 s of simulator)."""
    camp = _ur_campaign(tmp_path)
    before = _rig_files(camp)
    r = fgcd("calibrate", "hand-eye", "-c", camp.path, "--yes", timeout=60)
    assert r.returncode == 7, (r.returncode, r.stderr)
    assert "Traceback" not in r.stderr
    assert "127.0.0.77" in r.stderr.strip().splitlines()[-1]
    assert _rig_files(camp) == before  # no handeye.json


def test_handeye_made_on_another_rig_is_never_stored_in_the_campaign(tmp_path):
    """--driver sim on a UR campaign: refused before anything is opened (exit 2, one line, nothing written)."""
    camp = _ur_campaign(tmp_path)
    before = _rig_files(camp)
    r = fgcd("calibrate", "hand-eye", "-c", camp.path, "--driver", "sim", "--yes", timeout=60)
    one_line_error(r, mentions="ur rig")
    assert "--driver sim" in r.stderr
    assert "platform makes small motions" not in r.stderr
    assert _rig_files(camp) == before


def _fake_calibration(rms_mm: float):
    from fgcd_cli.app.calibrate import HandEyeCalibration
    from fgcd_cli.calibration.handeye.result import HandEyeResult

    result = HandEyeResult(
        T_flange_cam=np.eye(4),
        scale=1.6,
        method="racr-linear",
        n_samples=12,
        n_pairs=2,
        pairs=[(0, 1), (1, 2)],
        residuals_mm=np.array([rms_mm, rms_mm]),
        residuals_deg=np.array([0.2, 0.2]),
        sample_residuals_mm=np.full(3, rms_mm),
        sample_residuals_deg=np.full(3, 0.2),
        axis_spread_deg=80.0,
        max_rotation_deg=8.0,
    )
    return HandEyeCalibration(result=result, record=result.to_dict(), run=None)


@pytest.fixture
def handeye_of(monkeypatch):
    """`calibrate hand-eye` in process, its procedure replaced by one giving a residual of ``rms_mm``."""
    from types import SimpleNamespace

    import fgcd_cli.app.calibrate as calibrate_uc
    import fgcd_cli.app.rig as rig_uc

    def run(rms_mm):
        monkeypatch.setattr(calibrate_uc, "run_handeye", lambda *a, **k: _fake_calibration(rms_mm))
        monkeypatch.setattr(
            rig_uc,
            "open_rig",
            lambda request, hooks=None: rig_uc.OpenedRig(handles=SimpleNamespace(guard=None), close=lambda: None),
        )

    return run


@pytest.mark.parametrize("rms_mm, code", [(24.4, 6), (5.3, 0)])
def test_handeye_beyond_the_residual_limit_is_refused_and_not_stored(tmp_path, handeye_of, capsys, rms_mm, code):
    from fgcd_cli.cli.app import app, run

    camp = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim"})
    handeye_of(rms_mm)
    assert run(app, ["calibrate", "hand-eye", "-c", str(camp.path), "--yes", "--json"]) == code
    out, err = capsys.readouterr()
    if code == 6:
        assert err.strip().splitlines()[-1].startswith("error:") and "24.4 mm" in err and "12 mm" in err, err
        assert json.loads(out)["usable"] is False
        assert camp.read_rig("handeye") is None
    else:
        record = camp.read_rig("handeye")
        assert record["rig"] == {"driver": "sim"} and record["driver"] == "sim"


def test_handeye_beyond_the_limit_is_stored_only_when_accepted(tmp_path, handeye_of, capsys):
    from fgcd_cli.cli.app import app, run

    camp = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim"})
    handeye_of(24.4)
    assert run(app, ["calibrate", "hand-eye", "-c", str(camp.path), "-y", "--accept-residual"]) == 0
    assert "24.4 mm" in camp.read_rig("handeye")["residual_accepted"]


def test_sim_intrinsics_are_not_silent_in_a_pipe():
    """Rendering and calibrating run under the progress: off a terminal they are named and beat (no 10 s
    silence in a log; here the heartbeat is shortened to 0.3 s), and stdout keeps only the result."""
    import os

    r = subprocess.run(
        [sys.executable, "-m", "fgcd_cli.cli.app", "calibrate", "intrinsics", "--sim", "--sim-views", "8"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
        env={**os.environ, "FGCD_HEARTBEAT_S": "0.3"},
    )
    assert r.returncode == 0, r.stderr
    lines = r.stderr.splitlines()
    assert lines and lines[0] == "rendering board views", lines
    assert any(line.startswith("  ... rendering board views") for line in lines)
    assert "RMS reprojection error" in r.stdout and "rendering" not in r.stdout


@pytest.mark.parametrize("rms_mm, warned", [(24.4, True), (5.3, False)])
def test_the_simulated_campaigns_hand_eye_states_a_residual_beyond_the_limit(tmp_path, monkeypatch, rms_mm, warned):
    """The demo's and the benches' hand-eye is kept (their own simulated campaign) but said to be unusable."""
    from types import SimpleNamespace

    import fgcd_cli.app.calibrate as calibrate_uc
    import fgcd_cli.app.rig as rig_uc
    from fgcd_cli.app.scenario import SimScenario

    monkeypatch.setattr(calibrate_uc, "run_handeye", lambda *a, **k: _fake_calibration(rms_mm))
    monkeypatch.setattr(rig_uc, "open_sim_rig", lambda *a, **k: SimpleNamespace(handles=None, close=lambda: None))
    camp = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim"})
    said = []
    record = calibrate_uc.calibrate_sim_handeye(camp, SimScenario(), say=said.append, camera=None)
    assert any(s.startswith("warning:") and "24.4 mm" in s for s in said) == warned, said
    assert ("residual_accepted" in record) == warned
    assert camp.read_rig("handeye") is not None


@pytest.mark.parametrize("driver, option", [("grbl", "--port"), ("ur", "--host")])
def test_handeye_on_hardware_without_its_address_is_bad_input(tmp_path, driver, option, capsys):
    from fgcd_cli.cli.app import app, run

    camp = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim", "sim": {"scene": "stele", "seed": 0}})
    camp.write_rig("handeye", {"T_flange_cam": np.eye(4).tolist()})
    camp.write_rig("intrinsics", {"camera": {"fx": 600, "fy": 600, "cx": 320, "cy": 240, "width": 640, "height": 480}})
    assert run(app, ["calibrate", "hand-eye", "--driver", driver, "-c", str(camp.path), "--yes"]) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err and option in lines[0], err
