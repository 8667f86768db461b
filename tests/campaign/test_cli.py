"""`fgcd campaign ...` through the real console entry point: one line errors, exit codes, --json."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fgcd_cli.campaign.store import init_campaign

ROOT = Path(__file__).parents[2]


def fgcd(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "fgcd_cli.cli.app", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd or ROOT,
    )


def test_help_lists_commands():
    out = fgcd("--help")
    assert out.returncode == 0
    assert "campaign" in out.stdout


def test_init_list_show_verify_json(tmp_path):
    c = tmp_path / "c"
    r = fgcd("campaign", "init", c, "--site", "Borobudur ꦧꦫꦧꦸꦝꦸꦂ", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["site"] == "Borobudur ꦧꦫꦧꦸꦝꦸꦂ"
    assert fgcd("campaign", "add-station", "relief-12", "-c", c).returncode == 0
    listing = json.loads(fgcd("campaign", "list", c, "--json").stdout)
    assert [s["name"] for s in listing["stations"]] == ["relief-12"]
    shown = json.loads(fgcd("campaign", "show", c, "--json").stdout)
    assert shown["stations"] == ["relief-12"]
    v = fgcd("campaign", "verify", c, "--json")
    assert v.returncode == 0 and json.loads(v.stdout)["ok"] is True


def test_verify_names_damaged_file_and_fails(tmp_path):
    camp = init_campaign(tmp_path / "c", site="x")
    st = camp.create_station("s")
    with st.write_reference() as w:
        w.add_image("front", np.zeros((8, 8), np.uint8))
        ref = w.commit()
    img = ref.path / "images" / "front.png"
    os.chmod(img, 0o644)
    img.write_bytes(img.read_bytes() + b"junk")
    r = fgcd("campaign", "verify", tmp_path / "c")
    assert r.returncode == 4
    assert str(img) in r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_not_a_campaign_is_one_line(tmp_path):
    for args in (["campaign", "list", tmp_path], ["campaign", "verify", tmp_path / "missing"]):
        r = fgcd(*args)
        assert r.returncode == 3
        assert "Traceback" not in r.stderr
        assert len(r.stderr.strip().splitlines()) == 1


def test_bad_option_is_a_usage_error():
    r = fgcd("campaign", "init")
    assert r.returncode == 2
    assert "Traceback" not in r.stderr


# ----------------------------------------------------------------------------- issue 24 item 10
def _campaign_with_observations(root: Path):
    """A campaign with one station: a reference and one visit, each with one image."""
    camp = init_campaign(root, site="x")
    st = camp.create_station("s")
    with st.write_reference() as w:
        w.add_image("front", np.zeros((8, 8), np.uint8))
        ref = w.commit()
    with st.new_visit() as w:
        w.add_image("front", np.ones((8, 8), np.uint8))
        visit = w.commit()
    return camp, st, ref, visit


def _damage(path: Path) -> None:
    """Same size, different bytes: only the checksum can tell."""
    os.chmod(path, 0o644)
    data = path.read_bytes()
    path.write_bytes(data[:-4] + bytes(b ^ 0xFF for b in data[-4:]))


def _verify_json(root: Path):
    r = fgcd("campaign", "verify", root, "--json")
    assert "Traceback" not in r.stderr
    return r, json.loads(r.stdout)


def test_verify_corrupt_campaign_toml_is_damage_and_the_rest_is_still_checked(tmp_path):
    root = tmp_path / "c"
    _, _, ref, _ = _campaign_with_observations(root)
    (root / "campaign.toml").write_text("[campaign\nsite = ")
    _damage(ref.path / "images" / "front.png")
    r, data = _verify_json(root)
    assert r.returncode == 4, r.stderr
    errors = {(p["path"], p["kind"]) for p in data["problems"] if p["severity"] == "error"}
    assert errors == {(str(root / "campaign.toml"), "campaign"), (str(ref.path / "images" / "front.png"), "checksum")}
    assert data["observations"] == 2
    assert len(r.stderr.strip().splitlines()) == 1


def test_verify_missing_campaign_toml_in_a_campaign_is_damage(tmp_path):
    root = tmp_path / "c"
    _campaign_with_observations(root)
    (root / "campaign.toml").unlink()
    r, data = _verify_json(root)
    assert r.returncode == 4, r.stderr
    assert [(p["path"], p["kind"]) for p in data["problems"]] == [(str(root / "campaign.toml"), "missing")]
    assert data["observations"] == 2


def test_verify_campaign_toml_from_a_newer_fgcd_is_not_damage(tmp_path):
    root = tmp_path / "c"
    _campaign_with_observations(root)
    text = (root / "campaign.toml").read_text().replace("format_version = 1", "format_version = 99")
    (root / "campaign.toml").write_text(text)
    r = fgcd("campaign", "verify", root)
    assert r.returncode == 3 and "not supported" in r.stderr, r.stderr


def test_verify_broken_station_json_still_checks_that_stations_observations(tmp_path):
    root = tmp_path / "c"
    _, st, _, visit = _campaign_with_observations(root)
    (st.path / "station.json").write_text("{ broken")
    _damage(visit.path / "images" / "front.png")
    r, data = _verify_json(root)
    assert r.returncode == 4, r.stderr
    assert [(p["path"], p["kind"]) for p in data["problems"]] == [
        (str(st.path / "station.json"), "station"),
        (str(visit.path / "images" / "front.png"), "checksum"),
    ]
    assert data["observations"] == 2  # the intact reference and the visit were both read


@pytest.mark.parametrize(
    "content",
    ['["reference"]', '"s"', '{"observations": "reference"}', None],
    ids=["array", "string", "bad-index", "missing"],
)
def test_verify_names_a_malformed_or_missing_station_json(tmp_path, content):
    root = tmp_path / "c"
    _, st, _, _ = _campaign_with_observations(root)
    if content is None:
        (st.path / "station.json").unlink()
    else:
        (st.path / "station.json").write_text(content)
    r, data = _verify_json(root)
    assert r.returncode == 4, r.stderr
    assert [p["path"] for p in data["problems"] if p["severity"] == "error"] == [str(st.path / "station.json")]
    assert data["observations"] == 2


# ----------------------------------------------------------------------------- issue 48 item 9: the summary counts
def _summary(root: Path) -> tuple[int, str]:
    r = fgcd("campaign", "verify", root)
    assert "Traceback" not in r.stderr
    return r.returncode, " ".join(r.stdout.split()).rsplit(" — ", 1)[-1]


def test_verify_counts_notes_and_warnings_as_such_in_singular_and_plural(tmp_path):
    # Before: "OK: 2 observations, 2 files checked, 1 problems" for one interrupted revisit (no problem at all).
    root = tmp_path / "c"
    _, st, _, _ = _campaign_with_observations(root)
    assert _summary(root) == (0, "OK: 2 observations, 2 files checked")
    (st.path / "visits" / ".in-progress.jsonl").write_text('{"kind": "start", "options": {}}\n')
    code, out = _summary(root)
    assert code == 0 and out.endswith("OK, 1 note: 2 observations, 2 files checked"), out
    assert "note interrupted-visit:" in fgcd("campaign", "verify", root).stdout
    (st.path / "visits" / ".tmp-visit-1").mkdir()
    (st.path / ".tmp-x").write_text("")
    assert _summary(root)[1].endswith("OK, 2 warnings, 1 note: 2 observations, 2 files checked")


def test_verify_counts_damage_in_singular_and_plural(tmp_path):
    root = tmp_path / "c"
    _, _, ref, visit = _campaign_with_observations(root)
    _damage(ref.path / "images" / "front.png")
    r = fgcd("campaign", "verify", root)
    assert r.returncode == 4
    assert "DAMAGED, 1 problem: 2 observations, 2 files checked" in " ".join(r.stdout.split())
    assert r.stderr.startswith("error: 1 damaged or missing file, first: ")
    _damage(visit.path / "images" / "front.png")
    r = fgcd("campaign", "verify", root, "--json")
    data = json.loads(r.stdout)
    assert (data["errors"], data["warnings"], data["notes"]) == (2, 0, 0)
    assert "error: 2 damaged or missing files, first: " in r.stderr


def test_init_stores_the_rigs_camera_and_baud_rate(tmp_path):
    """`campaign init` writes the whole rig into campaign.toml [rig] (issue 48, item 4)."""
    import tomllib

    r = fgcd(
        "campaign",
        "init",
        tmp_path / "g",
        "--site",
        "x",
        "-d",
        "grbl",
        "--port",
        "/dev/ttyUSB1",
        "--baud",
        "57600",
        "--camera",
        "/dev/video2",
    )
    assert r.returncode == 0, r.stderr
    rig = tomllib.loads((tmp_path / "g" / "campaign.toml").read_text())["rig"]
    assert rig == {"driver": "grbl", "port": "/dev/ttyUSB1", "baud": 57600, "camera": "/dev/video2"}
    r = fgcd("campaign", "init", tmp_path / "u", "--site", "x", "--driver", "ur", "--host", "10.0.0.5")
    rig = tomllib.loads((tmp_path / "u" / "campaign.toml").read_text())["rig"]
    assert rig == {"driver": "ur", "host": "10.0.0.5", "camera": 0}  # the defaults written out
    r = fgcd("campaign", "init", tmp_path / "bad", "--site", "x", "--driver", "grbl", "--baud", "0")
    assert r.returncode == 2 and "--baud" in r.stderr and not (tmp_path / "bad").exists()
