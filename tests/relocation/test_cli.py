"""`fgcd capture` / `fgcd relocate` / `fgcd demo`: bad input gives one line; the full path is a slow test."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fgcd_cli.campaign import init_campaign

ROOT = Path(__file__).parents[2]


def fgcd(*args, timeout=600):
    return subprocess.run([sys.executable, "-m", "fgcd_cli.cli.app", *map(str, args)], capture_output=True,
                          text=True, cwd=ROOT, timeout=timeout)


def one_line_error(r, code):
    assert r.returncode == code, (r.returncode, r.stderr)
    assert "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_capture_without_handeye_is_refused(tmp_path):
    init_campaign(tmp_path / "c", site="x", rig={"driver": "sim"})
    one_line_error(fgcd("capture", "-c", tmp_path / "c", "-s", "s", "--yes"), 3)


def test_relocate_without_reference_is_refused(tmp_path):
    camp = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim"})
    camp.create_station("s")
    camp.write_rig("handeye", {"T_flange_cam": np.eye(4).tolist()})
    one_line_error(fgcd("relocate", "-c", tmp_path / "c", "-s", "s", "--yes"), 3)


def test_capture_refuses_an_existing_reference(tmp_path):
    camp = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim"})
    st = camp.create_station("s")
    camp.write_rig("handeye", {"T_flange_cam": np.eye(4).tolist()})
    with st.write_reference() as w:
        w.add_image("front", np.zeros((4, 4), np.uint8))
        w.commit()
    one_line_error(fgcd("capture", "-c", tmp_path / "c", "-s", "s", "--yes"), 5)


def test_unknown_driver_and_demo_vse_are_refused(tmp_path):
    camp = init_campaign(tmp_path / "c", site="x")
    camp.write_rig("handeye", {"T_flange_cam": np.eye(4).tolist()})
    one_line_error(fgcd("capture", "-c", tmp_path / "c", "-s", "s", "--driver", "robot9000", "--yes"), 2)
    one_line_error(fgcd("demo", "-o", tmp_path / "d", "--vse", "lidar"), 2)


@pytest.mark.slow
def test_demo_runs_end_to_end(tmp_path):
    r = fgcd("demo", "-o", tmp_path / "demo", "--json", timeout=1800)
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["reference"]["cloud_points"] > 1000
    assert summary["relocation"]["adjustments"] >= 1
    truth = summary["relocation"]["final_truth"]
    # started 25 mm / 2.5 deg away, i.e. ~31 px of true AFD: the loop must bring it well inside that
    assert truth["afd_px"] < 10.0
    assert (tmp_path / "demo" / "campaign").is_dir()
    v = fgcd("campaign", "verify", tmp_path / "demo" / "campaign")
    assert v.returncode == 0, v.stdout + v.stderr


def test_connection_options_come_from_the_rig_section(tmp_path):
    r = fgcd("campaign", "init", tmp_path / "c", "--site", "x", "--driver", "grbl", "--port", "/dev/ttyFGCD-NOPE")
    assert r.returncode == 0, r.stderr
    from fgcd_cli.campaign import open_campaign

    camp = open_campaign(tmp_path / "c")
    camp.write_rig("handeye", {"T_flange_cam": np.eye(4).tolist()})
    camp.write_rig("intrinsics", {"camera": {"fx": 600, "fy": 600, "cx": 320, "cy": 240, "width": 640, "height": 480}})
    r = fgcd("capture", "-c", tmp_path / "c", "-s", "s", "--yes")
    one_line_error(r, 7)
    assert "/dev/ttyFGCD-NOPE" in r.stderr


# ----------------------------------------------------------------------------- the campaign's rig (issue 48, items 1, 4)
CAMERA = {"fx": 600, "fy": 600, "cx": 320, "cy": 240, "width": 640, "height": 480}


def _grbl_campaign(tmp_path, *, handeye_driver="grbl"):
    """A GRBL campaign made by `campaign init` (baud 57600, camera 2), calibrated, with a station 's' and its reference."""
    r = fgcd("campaign", "init", tmp_path / "c", "--site", "x", "--driver", "grbl", "--port", "/dev/ttyFGCD-NOPE",
             "--baud", "57600", "--camera", "2")
    assert r.returncode == 0, r.stderr
    from fgcd_cli.campaign import open_campaign

    camp = open_campaign(tmp_path / "c")
    camp.write_rig("handeye", {"T_flange_cam": np.eye(4).tolist(), "driver": handeye_driver})
    camp.write_rig("intrinsics", {"camera": CAMERA})
    with camp.create_station("s").write_reference({"lightings": ["front"], "driver": "grbl"}) as w:
        w.add_image("front", np.zeros((4, 4), np.uint8))
        w.commit()
    return camp


@pytest.fixture
def opened_rigs(monkeypatch):
    """``open_rig`` replaced by a stand-in that records the request and fails like an absent stage (exit 7)."""
    import fgcd_cli.app.rig as rigs
    from fgcd_cli.errors import HardwareError

    seen = []

    def open_rig(request, *, hooks=None):
        seen.append(request)
        raise HardwareError("stand-in rig: not opened")

    monkeypatch.setattr(rigs, "open_rig", open_rig)
    return seen


@pytest.mark.parametrize("command", [["capture", "-s", "new"], ["relocate", "-s", "s"]])
def test_capture_and_relocate_open_the_camera_and_baud_rate_of_the_campaign(tmp_path, opened_rigs, command):
    from fgcd_cli.cli.app import app, run

    camp = _grbl_campaign(tmp_path)
    assert run(app, [command[0], "-c", str(camp.path), *command[1:], "--yes"]) == 7
    assert (opened_rigs[-1].driver, opened_rigs[-1].port, opened_rigs[-1].baud, opened_rigs[-1].camera_index) == \
        ("grbl", "/dev/ttyFGCD-NOPE", 57600, 2)
    # the options win over campaign.toml [rig]
    assert run(app, [command[0], "-c", str(camp.path), *command[1:], "-y", "--camera", "/dev/video7", "--baud",
                     "250000", "--port", "/dev/ttyACM3"]) == 7
    assert (opened_rigs[-1].port, opened_rigs[-1].baud, opened_rigs[-1].camera_index) == \
        ("/dev/ttyACM3", 250000, "/dev/video7")


@pytest.mark.parametrize("command", [["capture", "-s", "new"], ["relocate", "-s", "s"]])
def test_a_handeye_made_on_another_rig_is_not_used(tmp_path, opened_rigs, capsys, command):
    """A rig/handeye.json the simulator made (the old `calibrate hand-eye` default) in a GRBL campaign: exit 3."""
    from fgcd_cli.cli.app import app, run

    camp = _grbl_campaign(tmp_path, handeye_driver="sim")
    assert run(app, [command[0], "-c", str(camp.path), *command[1:], "--yes"]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "handeye.json was made on the sim rig" in err[0], err
    assert not opened_rigs  # refused before anything is opened


@pytest.mark.parametrize("command", [["capture", "-s", "new"], ["relocate", "-s", "s"]])
def test_capture_and_relocate_refuse_another_driver_than_the_campaigns(tmp_path, opened_rigs, capsys, command):
    from fgcd_cli.cli.app import app, run

    camp = _grbl_campaign(tmp_path)
    assert run(app, [command[0], "-c", str(camp.path), *command[1:], "--driver", "sim", "--yes"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "grbl rig" in err[0] and "--driver sim" in err[0], err
    assert not opened_rigs and not (camp.path / "stations" / "new").exists()
