"""Issue 24, items 1, 2, 8: a capture never rewrites the campaign's world, a failed one leaves nothing,
bad option values are refused up front in one line naming the valid values."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fgcd_cli.campaign import init_campaign, open_campaign
from fgcd_cli.errors import AlgorithmError, DataIntegrityError

ROOT = Path(__file__).parents[2]


def fgcd(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "fgcd_cli.cli.app", *map(str, args)], capture_output=True,
                          text=True, cwd=ROOT, timeout=timeout, stdin=subprocess.DEVNULL)


def one_line_error(r, code: int, *mentions: str) -> str:
    assert r.returncode == code, (r.returncode, r.stderr)
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    for word in mentions:
        assert word in lines[0], lines[0]
    return lines[0]


@pytest.fixture
def camp(tmp_path):
    """A simulator campaign whose default world is the stele, with a hand-eye."""
    c = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim", "sim": {"scene": "stele", "seed": 0}})
    c.write_rig("handeye", {"T_flange_cam": np.eye(4).tolist()})
    return c


def _toml(c) -> bytes:
    return (c.path / "campaign.toml").read_bytes()


def _fake_reference(station, *, scene: str, seed: int = 0) -> None:
    """A reference as `fgcd capture` records it, without running one."""
    meta = {"lightings": ["front"], "driver": "sim", "scenario": {"scene": scene, "seed": seed, "noise": "default"}}
    with station.write_reference(meta) as w:
        w.add_image("front", np.zeros((4, 4), np.uint8))
        w.commit()


def _capture(c, station: str, **options):
    """Call the capture command in-process with every option explicit."""
    from fgcd_cli.cli.capture_cmd import capture

    values = dict(driver=None, port=None, host=None, baud=None, camera=None, scene=None, seed=None, light="front",
                  yes=True, as_json=True)
    values.update(options)
    return capture(campaign=c.path, station=station, **values)


@pytest.fixture
def fake_capture(monkeypatch):
    """The rig and the capture use case replaced by fast stand-ins; records the scenario the rig was opened with."""
    from types import SimpleNamespace

    import fgcd_cli.app.capture as capture_uc
    import fgcd_cli.app.rig as rigs
    import fgcd_cli.metrics.sim_eval as sim_eval

    seen: dict = {"fail": None}

    def open_rig(request, **kwargs):
        seen["scenario"] = request.scenario
        return SimpleNamespace(handles=None, close=lambda: None, sim=None,
                               info={"scenario": request.scenario.__dict__ if request.scenario else None})

    def capture_reference(handles, station, *, lightings, metadata=None, evaluation=None):
        if seen["fail"] is not None:
            raise seen["fail"]
        with station.write_reference({"lightings": lightings, **(metadata or {})}) as w:
            for name in lightings:
                w.add_image(name, np.zeros((4, 4), np.uint8))
            obs = w.commit()
        return SimpleNamespace(observation_path=str(obs.path), cloud_points=0, images=list(lightings),
                               scale=SimpleNamespace(scale=1.0))

    monkeypatch.setattr(rigs, "open_rig", open_rig)
    monkeypatch.setattr(capture_uc, "capture_reference", capture_reference)
    monkeypatch.setattr(sim_eval, "reference_truth", lambda sim: None)
    return seen


# ----------------------------------------------------------------------------- item 1: the world is the station's
def test_a_capture_with_an_unknown_scene_changes_nothing(camp):
    before = _toml(camp)
    one_line_error(fgcd("capture", "-c", camp.path, "-s", "new", "--scene", "nosuch", "--yes"), 2,
                   "nosuch", "stele", "relief_panel")
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
    from fgcd_cli.cli.capture_cmd import station_world, visit_scenario

    _fake_reference(camp.create_station("niche"), scene="relief_panel", seed=3)
    _fake_reference(camp.create_station("stele-face"), scene="stele")
    camp.update_config("rig", {"sim": {"scene": "mural", "seed": 0}})  # e.g. a campaign damaged by the old capture
    niche = open_campaign(camp.path).station("niche").reference()
    assert station_world(camp, niche)["scene"] == "relief_panel" and station_world(camp, niche)["seed"] == 3
    scen = visit_scenario(camp, open_campaign(camp.path).station("stele-face").reference(), light="led:3", changes=2,
                          start_offset_mm=10, start_offset_deg=1, session_seed=1)
    assert (scen.scene, scen.lighting, scen.changes) == ("stele", "led:3", 2)


# ----------------------------------------------------------------------------- item 2: a failed capture leaves nothing
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


# ----------------------------------------------------------------------------- item 8: bad option values, exit 2
@pytest.mark.parametrize("args, mentions", [
    (("--light", "bogus"), ("--light", "bogus", "front", "led:H")),
    (("--light", "front,led:13"), ("--light", "1..12")),
    (("--driver", "robot9000"), ("robot9000", "sim, grbl, ur, manual")),
    (("--driver", "ur", "--host", "192.0.2.1", "--scene", "stele"), ("--scene", "--driver sim")),
])
def test_capture_option_values_are_refused_before_anything_is_written(camp, args, mentions):
    before = _toml(camp)
    one_line_error(fgcd("capture", "-c", camp.path, "-s", "new", *args, "--yes"), 2, *mentions)
    assert _toml(camp) == before
    assert not (camp.path / "stations" / "new").exists()


@pytest.mark.parametrize("args, mentions", [
    (("--light", "bogus"), ("--light", "bogus", "front", "led:H")),
    (("--changes", "-3"), ("--changes", "0 or more")),
    (("--start-offset-mm", "-1"), ("--start-offset-mm", ">= 0")),
    (("--max-adjustments", "0"), ("--max-adjustments",)),
    (("--driver", "robot9000"), ("robot9000", "sim, grbl, ur, manual")),
])
def test_relocate_option_values_are_refused_up_front(camp, args, mentions):
    _fake_reference(camp.create_station("s"), scene="stele")
    one_line_error(fgcd("relocate", "-c", camp.path, "-s", "s", *args, "--yes"), 2, *mentions)
    assert open_campaign(camp.path).station("s").visit_names() == []
