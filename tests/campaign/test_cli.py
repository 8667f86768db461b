"""`fgcd campaign ...` through the real console entry point: one line errors, exit codes, --json."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from fgcd_cli.campaign import init_campaign

ROOT = Path(__file__).parents[2]


def fgcd(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "fgcd_cli.cli.app", *map(str, args)],
        capture_output=True, text=True, cwd=cwd or ROOT,
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
