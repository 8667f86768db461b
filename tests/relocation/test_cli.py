"""`fgcd capture` / `fgcd relocate` / `fgcd demo`: bad input gives one line and leaves nothing, a capture keeps the
campaign's world and a revisit uses its station's; the full path is a slow test."""

import json
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from fgcd_cli.campaign.store import init_campaign, open_campaign
from fgcd_cli.cli.app import app, run
from fgcd_cli.errors import AlgorithmError, DataIntegrityError

ROOT = Path(__file__).parents[2]


def fgcd(*args, timeout=600):
    """The command in a subprocess; its step lines wait 30 s, so that on a loaded machine a command refused
    within a few seconds still prints its error line alone (``FGCD_STEP_DELAY_S``, fgcd_cli/cli/progress.py)."""
    return subprocess.run(
        [sys.executable, "-m", "fgcd_cli.cli.app", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
        env={**os.environ, "FGCD_STEP_DELAY_S": "30"},
    )


def one_line_error(r, code: int, *mentions: str) -> str:
    """The command failed with ``code`` and one stderr line naming every one of ``mentions``."""
    assert r.returncode == code, (r.returncode, r.stderr)
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    for word in mentions:
        assert word in lines[0], lines[0]
    return lines[0]


def one_line(text: str, *mentions: str) -> str:
    lines = [line for line in text.splitlines() if line.strip()]
    assert len(lines) == 1, text
    assert "Traceback" not in text
    for word in mentions:
        assert word in lines[0], lines[0]
    return lines[0]


@pytest.fixture
def camp(tmp_path):
    """A simulator campaign whose default world is the stele, with a hand-eye."""
    c = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim", "sim": {"scene": "stele", "seed": 0}})
    c.write_rig("handeye", {"T_flange_cam": np.eye(4).tolist()})
    return c


def _fake_reference(station, *, scene: str, seed: int = 0) -> None:
    """A reference as `fgcd capture` records it, without running one."""
    meta = {"lightings": ["front"], "driver": "sim", "scenario": {"scene": scene, "seed": seed, "noise": "default"}}
    with station.write_reference(meta) as w:
        w.add_image("front", np.zeros((4, 4), np.uint8))
        w.commit()


@pytest.fixture
def camp_with_reference(camp):
    """``camp`` with a station 's' holding a (stand-in) reference of the stele."""
    _fake_reference(camp.create_station("s"), scene="stele")
    return camp


def _stations(c) -> list[str]:
    return sorted(p.name for p in (c.path / "stations").iterdir())


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
    from fgcd_cli.campaign.store import open_campaign

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
    r = fgcd(
        "campaign",
        "init",
        tmp_path / "c",
        "--site",
        "x",
        "--driver",
        "grbl",
        "--port",
        "/dev/ttyFGCD-NOPE",
        "--baud",
        "57600",
        "--camera",
        "2",
    )
    assert r.returncode == 0, r.stderr
    from fgcd_cli.campaign.store import open_campaign

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
    assert (opened_rigs[-1].driver, opened_rigs[-1].port, opened_rigs[-1].baud, opened_rigs[-1].camera_index) == (
        "grbl",
        "/dev/ttyFGCD-NOPE",
        57600,
        2,
    )
    # the options win over campaign.toml [rig]
    assert (
        run(
            app,
            [
                command[0],
                "-c",
                str(camp.path),
                *command[1:],
                "-y",
                "--camera",
                "/dev/video7",
                "--baud",
                "250000",
                "--port",
                "/dev/ttyACM3",
            ],
        )
        == 7
    )
    assert (opened_rigs[-1].port, opened_rigs[-1].baud, opened_rigs[-1].camera_index) == (
        "/dev/ttyACM3",
        250000,
        "/dev/video7",
    )


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


# ----------------------------------------------------------------------------- a hardware driver's address
@pytest.mark.parametrize(
    "args, option",
    [
        (["capture", "-s", "new", "--driver", "grbl"], "--port"),
        (["capture", "-s", "new", "--driver", "ur"], "--host"),
        (["relocate", "-s", "s", "--driver", "grbl"], "--port"),
        (["relocate", "-s", "s", "--driver", "ur"], "--host"),
    ],
)
@pytest.mark.parametrize("intrinsics", [True, False])
def test_a_hardware_driver_without_its_address_is_bad_input(camp_with_reference, args, option, intrinsics, capsys):
    # the missing address is the first thing to fix: said before the missing intrinsics
    camp = camp_with_reference
    if intrinsics:
        camp.write_rig(
            "intrinsics", {"camera": {"fx": 600, "fy": 600, "cx": 320, "cy": 240, "width": 640, "height": 480}}
        )
    before = _stations(camp)
    assert run(app, [args[0], "-c", str(camp.path), *args[1:], "--yes"]) == 2
    one_line(capsys.readouterr().err, option)
    assert _stations(camp) == before


# ----------------------------------------------------------------------------- the demo's options
@pytest.mark.parametrize(
    "args, mentions",
    [
        (["--light", "bogus"], ("--light", "bogus", "led:H")),
        (["--scene", "nosuch"], ("nosuch", "relief_panel")),
        (["--changes", "-1"], ("--changes",)),
    ],
)
def test_demo_checks_its_options_before_it_starts(tmp_path, monkeypatch, capsys, args, mentions):
    import fgcd_cli.app.demo as demo_mod

    def never(*a, **k):
        raise AssertionError("the demo started with a bad option")

    monkeypatch.setattr(demo_mod, "run_demo", never)
    out = tmp_path / "d"
    assert run(app, ["demo", "-o", str(out), *args]) == 2
    one_line(capsys.readouterr().err, *mentions)
    assert not out.exists()


# ----------------------------------------------------------------------------- relocation progress
def test_relocate_hands_a_progress_callback_to_the_rig(camp_with_reference, stand_in_rig, stand_in_relocation, capsys):
    camp = camp_with_reference
    assert run(app, ["relocate", "-c", str(camp.path), "-s", "s", "--yes"]) == 0
    bar = stand_in_rig["on_progress"]
    assert callable(bar)
    bar(1, 4, "adjustment 1: moving")  # the plain (done, total, label) callback the use case calls
    assert run(app, ["relocate", "-c", str(camp.path), "-s", "s", "--yes", "--json"]) == 0
    assert stand_in_rig["on_progress"] is None  # --json: no bar


# ----------------------------------------------------------------------------- the campaign's world
def _toml(c) -> bytes:
    return (c.path / "campaign.toml").read_bytes()


def _capture(c, station: str, **options):
    """Call the capture command in-process with every option explicit."""
    from fgcd_cli.cli.capture_cmd import capture

    values = dict(
        driver=None,
        port=None,
        host=None,
        baud=None,
        camera=None,
        scene=None,
        seed=None,
        light="front",
        yes=True,
        as_json=True,
    )
    values.update(options)
    return capture(campaign=c.path, station=station, **values)


@pytest.fixture
def fake_capture(monkeypatch):
    """The rig and the capture use case replaced by fast stand-ins; records the scenario the rig was opened with."""
    import fgcd_cli.app.capture as capture_uc
    import fgcd_cli.app.rig as rigs
    import fgcd_cli.metrics.sim_eval as sim_eval

    seen: dict = {"fail": None}

    def open_rig(request, **kwargs):
        seen["scenario"] = request.scenario
        return SimpleNamespace(
            handles=None,
            close=lambda: None,
            sim=None,
            info={"scenario": request.scenario.__dict__ if request.scenario else None},
        )

    def capture_reference(handles, station, *, lightings, metadata=None, evaluation=None):
        if seen["fail"] is not None:
            raise seen["fail"]
        with station.write_reference({"lightings": lightings, **(metadata or {})}) as w:
            for name in lightings:
                w.add_image(name, np.zeros((4, 4), np.uint8))
            obs = w.commit()
        return SimpleNamespace(
            observation_path=str(obs.path), cloud_points=0, images=list(lightings), scale=SimpleNamespace(scale=1.0)
        )

    monkeypatch.setattr(rigs, "open_rig", open_rig)
    monkeypatch.setattr(capture_uc, "capture_reference", capture_reference)
    monkeypatch.setattr(sim_eval, "reference_truth", lambda sim: None)
    return seen


# ----------------------------------------------------------------------------- a capture's world is its station's
def test_a_capture_with_an_unknown_scene_changes_nothing(camp):
    before = _toml(camp)
    one_line_error(
        fgcd("capture", "-c", camp.path, "-s", "new", "--scene", "nosuch", "--yes"),
        2,
        "nosuch",
        "stele",
        "relief_panel",
    )
    assert _toml(camp) == before
    assert not (camp.path / "stations" / "new").exists()


def test_a_capture_in_another_scene_keeps_the_campaign_world(camp, fake_capture):
    before = _toml(camp)
    _capture(camp, "niche", scene="relief_panel")
    assert _toml(camp) == before  # [rig.sim] still says stele
    assert fake_capture["scenario"].scene == "relief_panel"
    ref = open_campaign(camp.path).station("niche").reference()
    assert ref.metadata["scenario"]["scene"] == "relief_panel"
    _capture(camp, "stele-face")  # no --scene: the campaign's default world
    assert fake_capture["scenario"].scene == "stele"


def test_relocation_uses_the_world_of_the_station_not_the_campaign(camp):
    from fgcd_cli.app.revisit import visit_scenario
    from fgcd_cli.campaign.records import station_world

    _fake_reference(camp.create_station("niche"), scene="relief_panel", seed=3)
    _fake_reference(camp.create_station("stele-face"), scene="stele")
    camp.update_config("rig", {"sim": {"scene": "mural", "seed": 0}})  # e.g. a campaign damaged by the old capture
    niche = open_campaign(camp.path).station("niche").reference()
    assert station_world(camp, niche)["scene"] == "relief_panel" and station_world(camp, niche)["seed"] == 3
    scen = visit_scenario(
        camp,
        open_campaign(camp.path).station("stele-face").reference(),
        light="led:3",
        changes=2,
        start_offset_mm=10,
        start_offset_deg=1,
        session_seed=1,
    )
    assert (scen.scene, scen.lighting, scen.changes) == ("stele", "led:3", 2)


# ----------------------------------------------------------------------------- a failed capture leaves nothing
def test_a_capture_refused_for_missing_calibration_leaves_no_station(tmp_path):
    c = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim"})
    before = _toml(c)
    one_line_error(fgcd("capture", "-c", c.path, "-s", "typo-staton", "--yes"), 3, "hand-eye")
    assert not (c.path / "stations" / "typo-staton").exists()
    assert _toml(c) == before
    r = fgcd("campaign", "add-station", "typo-staton", "-c", c.path)
    assert r.returncode == 0, r.stderr


def test_a_capture_that_fails_on_the_rig_removes_the_station_it_created(camp, fake_capture):
    fake_capture["fail"] = AlgorithmError("the VSE could not start")
    with pytest.raises(AlgorithmError):
        _capture(camp, "new")
    assert not (camp.path / "stations" / "new").exists()
    fake_capture["fail"] = KeyboardInterrupt()
    with pytest.raises(KeyboardInterrupt):
        _capture(camp, "new")
    assert not (camp.path / "stations" / "new").exists()
    # a station that existed before the capture (add-station) is kept
    camp.create_station("planned", description="north face")
    fake_capture["fail"] = AlgorithmError("the VSE could not start")
    with pytest.raises(AlgorithmError):
        _capture(camp, "planned")
    assert json.loads((camp.path / "stations" / "planned" / "station.json").read_text())["description"] == "north face"


def test_a_platform_that_cannot_connect_leaves_no_station(tmp_path):
    c = init_campaign(tmp_path / "c", site="x", rig={"driver": "grbl", "port": "/dev/ttyFGCD-NOPE"})
    c.write_rig("handeye", {"T_flange_cam": np.eye(4).tolist()})
    c.write_rig("intrinsics", {"camera": {"fx": 600, "fy": 600, "cx": 320, "cy": 240, "width": 640, "height": 480}})
    r = fgcd("capture", "-c", c.path, "-s", "s", "--yes")
    assert r.returncode == 7, r.stderr
    assert not (c.path / "stations" / "s").exists()


def test_a_damaged_station_is_named_damaged_not_already_existing(camp):
    sdir = camp.path / "stations" / "broken"
    sdir.mkdir(parents=True)
    (sdir / "station.json").write_text("{not json")
    line = one_line_error(fgcd("capture", "-c", camp.path, "-s", "broken", "--yes"), 4, "station.json", "damaged")
    assert "already exists" not in line
    assert (sdir / "station.json").read_text() == "{not json"  # untouched
    with pytest.raises(DataIntegrityError, match="damaged"):
        camp.station_or_create("broken")


# ----------------------------------------------------------------------------- bad option values, exit 2
@pytest.mark.parametrize(
    "args, mentions",
    [
        (("--light", "bogus"), ("--light", "bogus", "front", "led:H")),
        (("--light", "front,led:13"), ("--light", "1..12")),
        (("--driver", "robot9000"), ("robot9000", "sim, grbl, ur, manual")),
        (("--driver", "ur", "--host", "192.0.2.1", "--scene", "stele"), ("--scene", "--driver sim")),
    ],
)
def test_capture_option_values_are_refused_before_anything_is_written(camp, args, mentions):
    before = _toml(camp)
    one_line_error(fgcd("capture", "-c", camp.path, "-s", "new", *args, "--yes"), 2, *mentions)
    assert _toml(camp) == before
    assert not (camp.path / "stations" / "new").exists()


@pytest.mark.parametrize(
    "args, mentions",
    [
        (("--light", "bogus"), ("--light", "bogus", "front", "led:H")),
        (("--changes", "-3"), ("--changes", "0 or more")),
        (("--start-offset-mm", "-1"), ("--start-offset-mm", ">= 0")),
        (("--max-adjustments", "0"), ("--max-adjustments",)),
        (("--driver", "robot9000"), ("robot9000", "sim, grbl, ur, manual")),
    ],
)
def test_relocate_option_values_are_refused_up_front(camp, args, mentions):
    _fake_reference(camp.create_station("s"), scene="stele")
    one_line_error(fgcd("relocate", "-c", camp.path, "-s", "s", *args, "--yes"), 2, *mentions)
    assert open_campaign(camp.path).station("s").visit_names() == []
