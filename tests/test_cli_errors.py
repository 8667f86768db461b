"""The CLI boundary: --version, plain `fgcd`, --json errors, prompts without a terminal, Ctrl-C.

Issue 24 items 6 and 9. In-process tests drive ``app.run`` with small typer apps
(the same code path as ``main``); subprocess tests drive the real entry point.
"""

from __future__ import annotations

import io
import json
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import typer

from fgcd_cli import __version__
from fgcd_cli.campaign.store import init_campaign, open_campaign
from fgcd_cli.cli.app import run
from fgcd_cli.errors import run_record

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.timeout(120)


def fgcd(*args, stdin=subprocess.DEVNULL, timeout=60) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "fgcd_cli.cli.app", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        stdin=stdin,
        timeout=timeout,
    )


def _lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]


def one_line(text: str, *mentions: str) -> str:
    lines = _lines(text)
    assert len(lines) == 1, text
    assert "Traceback" not in text
    for word in mentions:
        assert word in lines[0], lines[0]
    return lines[0]


# ----------------------------------------------------------------------------- item 9: version, help
def test_version_prints_the_version():
    r = fgcd("--version")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == f"fgcd {__version__}"
    assert r.stderr == ""


@pytest.mark.parametrize("args", [[], ["campaign"]], ids=["fgcd", "fgcd campaign"])
def test_no_command_prints_help_and_exits_cleanly(args):
    r = fgcd(*args)
    assert r.returncode == 0, r.stderr
    assert "Usage:" in r.stdout and "Commands" in r.stdout
    assert r.stderr == ""


# ----------------------------------------------------------------------------- item 9: --json errors
def test_json_error_is_one_object_on_stdout(tmp_path):
    r = fgcd("campaign", "list", tmp_path / "missing", "--json")
    assert r.returncode == 3
    data = json.loads(r.stdout)
    assert data == {"error": f"error: {tmp_path / 'missing'}: no such directory", "code": 3}
    assert _lines(r.stderr) == [data["error"]]


def test_json_usage_error_is_one_object_on_stdout():
    r = fgcd("campaign", "init", "--json")
    assert r.returncode == 2
    data = json.loads(r.stdout)
    assert data["code"] == 2 and "Missing argument" in data["error"]
    assert len(_lines(r.stderr)) == 1


def test_json_result_then_error_stays_one_object(capsys):
    # A command that printed its JSON result and then fails: no second object on stdout.
    app = typer.Typer()

    @app.command()
    def cmd(as_json: bool = typer.Option(False, "--json")) -> None:
        from fgcd_cli.cli.output import emit
        from fgcd_cli.errors import DataIntegrityError

        emit({"ok": False}, as_json=as_json)
        raise DataIntegrityError("1 damaged file")

    assert run(app, ["--json"]) == 4
    out, err = capsys.readouterr()
    assert json.loads(out) == {"ok": False}
    assert _lines(err) == ["error: 1 damaged file"]


# ----------------------------------------------------------------------------- item 9: no terminal, no --yes
def _confirming_app() -> typer.Typer:
    app = typer.Typer()

    @app.command()
    def cmd() -> None:
        if typer.confirm("Move?"):
            print("moved")

    return app


def test_prompt_without_terminal_says_terminal_or_yes(capsys, monkeypatch):
    monkeypatch.setattr(sys, "stdin", io.StringIO(""))  # not a terminal, end of input
    assert run(_confirming_app(), []) == 2
    _, err = capsys.readouterr()
    lines = _lines(err)
    assert len(lines) == 1 and "needs a terminal" in lines[0] and "--yes" in lines[0], err


def test_platform_move_without_terminal_or_yes_is_refused_before_connecting():
    # /dev/null is no GRBL stage: the refusal must come first, as bad input (exit 2).
    r = fgcd("platform", "move", "--driver", "grbl", "--port", "/dev/null", "--dx", "1")
    assert r.returncode == 2, r.stderr
    lines = _lines(r.stderr)
    assert len(lines) == 1 and "needs a terminal" in lines[0] and "--yes" in lines[0], r.stderr


# ----------------------------------------------------------------------------- item 6: Ctrl-C
def test_ctrl_c_in_a_command_that_says_nothing_gets_a_generic_honest_line(capsys):
    app = typer.Typer()

    @app.command()
    def cmd() -> None:
        raise KeyboardInterrupt

    assert run(app, []) == 130
    out, err = capsys.readouterr()
    assert out == ""
    lines = _lines(err)
    assert len(lines) == 1, err
    assert lines[0].startswith("interrupted (Ctrl-C):")
    assert "motion guard" in lines[0] and "half-written" in lines[0]


def test_ctrl_c_says_what_was_and_was_not_written(capsys):
    app = typer.Typer()

    @app.command()
    def cmd() -> None:
        run_record.no_platform()
        with run_record.writing("a.png"):
            pass
        with run_record.writing("the visit"):
            raise KeyboardInterrupt

    assert run(app, []) == 130
    _, err = capsys.readouterr()
    assert _lines(err) == ["interrupted (Ctrl-C): no platform was in use; wrote a.png; not written: the visit"]


def test_ctrl_c_with_json_prints_the_error_object(capsys):
    app = typer.Typer()

    @app.command()
    def cmd(as_json: bool = typer.Option(False, "--json")) -> None:
        run_record.no_platform()
        run_record.no_writes()
        raise KeyboardInterrupt

    assert run(app, ["--json"]) == 130
    out, _ = capsys.readouterr()
    assert json.loads(out) == {
        "error": "interrupted (Ctrl-C): no platform was in use; nothing was written",
        "code": 130,
    }


def test_ctrl_c_at_a_prompt_is_an_interruption(capsys, monkeypatch):
    class CtrlC(io.StringIO):
        def readline(self, *args):
            raise KeyboardInterrupt

    monkeypatch.setattr(sys, "stdin", CtrlC())
    assert run(_confirming_app(), []) == 130
    _, err = capsys.readouterr()
    assert _lines(err)[-1].startswith("interrupted (Ctrl-C):"), err


def test_the_record_starts_empty_for_each_command_line(capsys):
    app = typer.Typer()

    @app.command()
    def cmd(fail: bool = typer.Option(False, "--fail")) -> None:
        if fail:
            raise KeyboardInterrupt
        run_record.wrote("old.txt")

    assert run(app, []) == 0
    assert run(app, ["--fail"]) == 130
    assert "old.txt" not in capsys.readouterr().err


def test_ctrl_c_while_a_person_moves_the_mount_says_stopped_and_nothing_written():
    # The manual driver waits for the person's "Done?": Ctrl-C there, end to end.
    proc = subprocess.Popen(
        [sys.executable, "-m", "fgcd_cli.cli.app", "platform", "move", "--driver", "manual", "--dx", "5", "--yes"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        cwd=ROOT,
    )
    seen = bytearray()
    prompted = threading.Event()

    def read() -> None:
        while chunk := proc.stdout.read1(256):
            seen.extend(chunk)
            if b"Done?" in seen:
                prompted.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        assert prompted.wait(60), bytes(seen)
        time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=30)
        stderr = proc.stderr.read().decode()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, stderr
    assert _lines(stderr) == [
        "interrupted (Ctrl-C): the manual platform was stopped mid-motion; nothing was written"
    ], stderr


def test_ctrl_c_during_a_bare_diff_names_the_incomplete_outputs(capsys, monkeypatch, tmp_path):
    import fgcd_cli.app.diff as usecases
    from fgcd_cli.cli.app import app

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(usecases, "run_bare", interrupted)
    out = tmp_path / "out"
    assert run(app, ["diff", "--ref", "a.png", "--cur", "b.png", "-o", str(out)]) == 130
    lines = _lines(capsys.readouterr().err)
    assert len(lines) == 1 and lines[0].startswith("interrupted (Ctrl-C): no platform was in use; not completed: "), (
        lines
    )
    assert str(out) in lines[0]


def test_record_clauses_for_a_platform_that_was_not_moving():
    from fgcd_cli.errors import RunRecord

    record = RunRecord()
    record.platform_connected("grbl")
    record.no_writes()
    assert (record.platform_clause(), record.writes_clause()) == (
        "the grbl platform was not moving",
        "nothing was written",
    )
    for k in range(5):
        record.wrote(f"f{k}")
    assert record.writes_clause() == "wrote f0, f1, f2 and 2 more"


def test_ctrl_c_during_verify_says_nothing_moved_or_written(capsys, monkeypatch, tmp_path):
    import fgcd_cli.app.campaign as campaign_uc
    from fgcd_cli.cli.app import app

    def interrupted(path):
        raise KeyboardInterrupt

    monkeypatch.setattr(campaign_uc, "verify_campaign_dir", interrupted)
    assert run(app, ["campaign", "verify", str(tmp_path)]) == 130
    assert _lines(capsys.readouterr().err) == ["interrupted (Ctrl-C): no platform was in use; nothing was written"]


# ----------------------------------------------------------------------------- issue 48 item 3: hardware, --verbose
def _manual_campaign(root: Path) -> Path:
    import numpy as np

    from fgcd_cli.campaign.store import init_campaign
    from fgcd_core.camera import PinholeCamera

    camp = init_campaign(root / "c", site="x", rig={"driver": "manual"})
    camp.write_rig("intrinsics", PinholeCamera(fx=500.0, fy=500.0, cx=319.5, cy=239.5, width=640, height=480).to_dict())
    camp.write_rig("handeye", {"T_flange_cam": np.eye(4).tolist()})
    return camp.path


@pytest.mark.parametrize("verbose", [[], ["--verbose"], ["-v"]], ids=["plain", "--verbose after", "-v after"])
def test_a_missing_camera_is_hardware_in_one_line(tmp_path, monkeypatch, capsys, verbose):
    # Before: exit 70 "internal error: CameraError: ..." (and `--verbose` after the subcommand a usage error).
    import fgcd_drivers.cameras as cameras
    from fgcd_cli.cli.app import app

    exists = cameras.os.path.exists
    monkeypatch.setattr(cameras.os.path, "exists", lambda p: False if str(p) == "/dev/video0" else exists(p))
    monkeypatch.setattr(sys, "stdin", io.StringIO(""))
    code = run(
        app, ["capture", "-c", str(_manual_campaign(tmp_path)), "-s", "m1", "--driver", "manual", "--yes", *verbose]
    )
    err = capsys.readouterr().err
    assert code == 7, err
    assert _lines(err)[-1:] == [
        "camera error: no camera at /dev/video0 (camera 0): connect it, or choose another with --camera"
    ], err
    assert "Traceback" not in err and len(_lines(err)) <= 2  # a progress line may come first


def test_camera_errors_are_hardware_exit_7(capsys):
    from fgcd_drivers.cameras import CameraError

    app = typer.Typer()

    @app.command()
    def cmd() -> None:
        raise CameraError("camera 0 opened but delivers no frames")

    assert run(app, []) == 7
    assert _lines(capsys.readouterr().err) == ["camera error: camera 0 opened but delivers no frames"]


@pytest.mark.parametrize(
    "error, line",
    [
        (MemoryError(), "error: out of memory"),
        (
            OSError(28, "No space left on device", "/c/stations/s1/visits/.tmp-x/cloud.ply"),
            "error: No space left on device: /c/stations/s1/visits/.tmp-x/cloud.ply",
        ),
        (OSError(30, "Read-only file system"), "error: Read-only file system"),
    ],
)
def test_memory_and_disk_exhaustion_are_one_line_exit_1(capsys, error, line):
    app = typer.Typer()

    @app.command()
    def cmd() -> None:
        raise error

    assert run(app, []) == 1
    lines = _lines(capsys.readouterr().err)
    assert len(lines) == 1 and lines[0].startswith(line) and not lines[0].endswith(": ")


def _verbose_app() -> typer.Typer:
    from fgcd_cli.cli.output import state

    app = typer.Typer()

    @app.callback()
    def root(verbose: bool = typer.Option(False, "--verbose", "-v")) -> None:
        state.verbose = verbose

    @app.command()
    def bug(site: str = typer.Option("", "--site")) -> None:
        print(f"site={site} verbose={state.verbose}")
        raise ValueError("a bug")

    @app.command()
    def own(value: str = typer.Option("", "--value", "-v")) -> None:
        print(f"value={value} verbose={state.verbose}")

    return app


def test_verbose_after_the_subcommand_is_the_roots(capsys):
    app = _verbose_app()
    assert run(app, ["bug"]) == 70
    out, err = capsys.readouterr()
    assert "verbose=False" in out and "run the same command again with --verbose" in _lines(err)[0]
    for flag in ("--verbose", "-v"):
        with pytest.raises(ValueError, match="a bug"):  # --verbose: a bug propagates with its traceback
            run(app, ["bug", "--site", "x", flag])
        assert "site=x verbose=True" in capsys.readouterr().out


def test_verbose_is_not_taken_from_a_command_or_value_that_owns_it(capsys):
    app = _verbose_app()
    assert run(app, ["own", "-v", "3"]) == 0
    assert capsys.readouterr().out.strip() == "value=3 verbose=False"
    assert run(app, ["bug", "--site", "-v"]) == 70  # the value of --site
    assert "site=-v verbose=False" in capsys.readouterr().out
    assert run(app, ["own", "--", "-v"]) == 2  # after --: an argument, not an option


# ----------------------------------------------------------------------------- SIGTERM, SIGHUP
@pytest.mark.parametrize(
    "name, code, prefix", [("SIGTERM", 143, "terminated (SIGTERM)"), ("SIGHUP", 129, "hung up (SIGHUP)")]
)
def test_a_stop_signal_mid_move_stops_the_platform_in_one_line(name, code, prefix):
    # A supervisor's SIGTERM or a closed terminal's SIGHUP takes Ctrl-C's path (README, "Errors"): the
    # GRBL emulator's own state says the platform no longer moves once the command has ended.
    from fgcd_cli.bench.faults.checks import run_fgcd, send_signal, wait_until
    from fgcd_drivers.testing.grbl_emulator import GrblEmulator

    emu = GrblEmulator(time_scale=1.0)
    sent = {}

    def inject(proc) -> None:
        # 60 mm at the driver's 20 mm/s: 3 s of motion, signalled once the motion line has reached the board
        if wait_until(lambda: any(" G1 " in f" {line} " for line in emu.lines_received), timeout_s=90, proc=proc):
            sent["moving"] = emu.moving()
            send_signal(proc, getattr(signal, name))

    try:
        # bench.faults.child: a terminal's signal defaults, even when the tests run in the background (nohup, CI)
        run = run_fgcd(
            [
                "platform",
                "move",
                "--driver",
                "grbl",
                "--port",
                emu.port,
                "--yes",
                "--dx",
                "-60",
                "--speed-fraction",
                "1",
                "--max-step-mm",
                "80",
            ],
            inject=inject,
            timeout_s=110,
            launcher=["fgcd_cli.bench.faults.child"],
        )
        assert sent.get("moving"), run.stderr
        assert not emu.moving(), "the platform still moves after the command ended"
    finally:
        emu.close()
    assert run.code == code, run.stderr
    assert run.lines == [f"{prefix}: the grbl platform was stopped mid-motion; nothing was written"], run.stderr


def test_a_stop_signal_in_process_is_one_line_and_restores_the_handlers(capsys):
    import os

    app = typer.Typer()

    @app.command()
    def wait() -> None:
        run_record.no_platform()
        run_record.no_writes()
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # the handler raises before this ends

    before = signal.getsignal(signal.SIGTERM)
    assert run(app, []) == 143
    assert _lines(capsys.readouterr().err) == ["terminated (SIGTERM): no platform was in use; nothing was written"]
    assert signal.getsignal(signal.SIGTERM) is before


def test_a_stop_signal_ignored_at_start_stays_ignored(capsys):
    # `nohup fgcd relocate ... &`: the person chose that a closed terminal does not stop the command
    import os

    app = typer.Typer()

    @app.command()
    def hang_up() -> None:
        run_record.no_platform()
        os.kill(os.getpid(), signal.SIGHUP)
        time.sleep(0.2)

    before = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        assert run(app, []) == 0
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGHUP, before)
    assert capsys.readouterr().err == ""


# ----------------------------------------------------------------------------- capture, relocate, hand-eye: the
# first-motion question and Ctrl-C on a rig
@pytest.fixture
def camp(tmp_path):
    """A simulator campaign (stele) with a hand-eye and a station 's' holding a (stand-in) reference."""
    c = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim", "sim": {"scene": "stele", "seed": 0}})
    c.write_rig("handeye", {"T_flange_cam": np.eye(4).tolist()})
    meta = {"lightings": ["front"], "driver": "sim", "scenario": {"scene": "stele", "seed": 0, "noise": "default"}}
    with c.create_station("s").write_reference(meta) as w:
        w.add_image("front", np.zeros((4, 4), np.uint8))
        w.commit()
    return c


def _stations(c) -> list[str]:
    return sorted(p.name for p in (c.path / "stations").iterdir())


@pytest.mark.timeout(300)
@pytest.mark.parametrize("command", ["capture", "relocate", "hand-eye"])
def test_a_motion_command_without_a_terminal_or_yes_is_refused_before_anything_is_created(camp, command):
    before = _stations(camp)
    args = {
        "capture": ["capture", "-c", camp.path, "-s", "new"],
        "relocate": ["relocate", "-c", camp.path, "-s", "s"],
        "hand-eye": ["calibrate", "hand-eye", "--driver", "sim", "-c", camp.path],
    }[command]
    r = fgcd(*args, "--json", timeout=120)
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    line = one_line(r.stderr, "needs a terminal", "--yes")
    assert line.startswith("error:"), line
    assert json.loads(r.stdout) == {"error": line, "code": 2}  # stdout: one object, no prompt
    assert _stations(camp) == before
    assert not list(camp.path.glob("stations/s/visits/*"))
    assert open_campaign(camp.path).read_rig("handeye")["T_flange_cam"] == np.eye(4).tolist()


def test_the_first_motion_question_is_asked_on_stderr(camp, stand_in_rig, stand_in_relocation, monkeypatch, capsys):
    import fgcd_cli.cli.output as output
    from fgcd_cli.cli.app import app

    monkeypatch.setattr(output, "stdin_is_terminal", lambda: True)
    monkeypatch.setattr(sys, "stdin", io.StringIO("y\n"))
    assert run(app, ["relocate", "-c", str(camp.path), "-s", "s", "--json"]) == 0
    out, err = capsys.readouterr()
    assert stand_in_rig["answer"] is True
    assert "Proceed?" in err and "Proceed?" not in out
    assert json.loads(out)["converged"] is True  # stdout is the one JSON object


def test_ctrl_c_during_a_relocation_names_the_platform_and_the_unwritten_visit(camp, stand_in_rig, monkeypatch, capsys):
    import fgcd_cli.app.revisit as capture_uc
    from fgcd_cli.cli.app import app

    def interrupted(rig, station, **kwargs):
        with run_record.motion():
            raise KeyboardInterrupt

    monkeypatch.setattr(capture_uc, "relocate_and_capture", interrupted)
    assert run(app, ["relocate", "-c", str(camp.path), "-s", "s", "--yes"]) == 130
    assert (
        _lines(capsys.readouterr().err)[-1]
        == "interrupted (Ctrl-C): the sim platform was stopped mid-motion; nothing was written"
    )
    assert stand_in_rig["tripped"] and stand_in_rig["closed"]  # the platform was told to stop, the rig closed


def test_ctrl_c_during_a_capture_says_nothing_written_and_leaves_no_station(camp, stand_in_rig, monkeypatch, capsys):
    import fgcd_cli.app.capture as capture_uc
    from fgcd_cli.cli.app import app

    def interrupted(rig, station, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(capture_uc, "capture_reference", interrupted)
    assert run(app, ["capture", "-c", str(camp.path), "-s", "new", "--yes"]) == 130
    assert (
        _lines(capsys.readouterr().err)[-1]
        == "interrupted (Ctrl-C): the sim platform was not moving; nothing was written"
    )
    assert "new" not in _stations(camp)


def test_ctrl_c_during_a_handeye_run_names_the_platform_and_keeps_the_old_calibration(
    camp, stand_in_rig, monkeypatch, capsys
):
    import fgcd_cli.cli.calibrate_cmd as calibrate_cmd
    from fgcd_cli.cli.app import app

    def interrupted(handles, **kwargs):
        assert handles.guard.platform.name == "sim"
        with run_record.motion():
            raise KeyboardInterrupt

    monkeypatch.setattr(calibrate_cmd, "_run_handeye", interrupted)
    assert run(app, ["calibrate", "hand-eye", "--driver", "sim", "-c", str(camp.path), "--yes"]) == 130
    assert (
        _lines(capsys.readouterr().err)[-1]
        == "interrupted (Ctrl-C): the sim platform was stopped mid-motion; nothing was written"
    )
    assert stand_in_rig["tripped"] and stand_in_rig["closed"]
    assert open_campaign(camp.path).read_rig("handeye")["T_flange_cam"] == np.eye(4).tolist()


@pytest.mark.timeout(300)
def test_ctrl_c_during_a_simulated_capture_is_one_line_and_leaves_no_station(camp):
    """SIGINT to a running `fgcd capture` (simulator) once it explores: one line, exit 130, no station left."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "fgcd_cli.cli.app", "capture", "-c", str(camp.path), "-s", "new", "--yes"],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        cwd=ROOT,
    )
    seen = bytearray()
    exploring = threading.Event()

    def read() -> None:
        while chunk := proc.stderr.read1(256):
            seen.extend(chunk)
            if b"exploration 1/" in seen:
                exploring.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        assert exploring.wait(240), bytes(seen).decode(errors="replace")
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=120)
        reader.join(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    stderr = bytes(seen).decode(errors="replace")
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr
    assert re.fullmatch(
        r"interrupted \(Ctrl-C\): the sim platform was (stopped mid-motion|not moving); "
        r"nothing was written",
        _lines(stderr)[-1],
    ), stderr
    assert "new" not in _stations(camp)
