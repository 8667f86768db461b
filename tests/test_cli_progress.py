"""cli/progress.py: the step bar, and off a terminal a plain line per step and a heartbeat during a long step
(stderr only)."""

from __future__ import annotations

import io
import subprocess
import sys
import textwrap
import time

SLOW_STEP = textwrap.dedent("""
    import sys, time
    from fgcd_cli.cli.output import info
    from fgcd_cli.cli.progress import step_progress

    with step_progress(enabled=True, heartbeat_s=float(sys.argv[1])) as bar:
        bar(0, 0, "a slow step")
        time.sleep(float(sys.argv[2]))          # one long step, nothing said
        for i in range(1, 4):
            bar(i, 3, f"counted ({i}/3)")       # one step: one line
        for _ in range(int(sys.argv[3])):       # lines of the use case: not silent, no heartbeat needed
            info("a line of the use case")
            time.sleep(0.05)
    print("result")
""")


def _run(heartbeat_s: float, sleep_s: float, said: int = 0) -> tuple[list[tuple[float, str]], str]:
    """The script through pipes: each stderr line with the time it arrived, and stdout."""
    proc = subprocess.Popen(
        [sys.executable, "-c", SLOW_STEP, str(heartbeat_s), str(sleep_s), str(said)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    lines = []
    t0 = time.monotonic()
    for line in proc.stderr:
        lines.append((time.monotonic() - t0, line.rstrip("\n")))
    out = proc.stdout.read()
    assert proc.wait(timeout=60) == 0, lines
    return lines, out


def test_off_a_terminal_each_step_is_a_line_and_a_long_step_beats():
    lines, out = _run(heartbeat_s=0.2, sleep_s=1.6)
    texts = [t for _, t in lines]
    assert out == "result\n"  # stdout untouched: a --json result stays one object
    assert texts[0] == "a slow step"
    beats = [t for t in texts if t.startswith("  ... a slow step")]
    # 1.6 s of silence at a 0.2 s interval: a beat every interval or so (not one at the end only)
    assert 3 <= len(beats) <= 9, texts
    assert beats[-1].endswith(" s")
    # the counted step ends at once: not named (a step is named once it lasts a heartbeat here)
    assert not any(t.startswith("counted") for t in texts), texts
    assert "" not in texts  # no blank line left behind by a live display


def test_the_heartbeat_stays_quiet_while_something_else_prints():
    lines, _ = _run(heartbeat_s=0.3, sleep_s=0.0, said=12)
    texts = [t for _, t in lines]
    assert texts.count("a line of the use case") == 12
    assert not any(t.startswith("  ... counted") for t in texts), texts


def test_a_heartbeat_interval_is_a_named_constant_overridable_for_tests():
    from fgcd_cli.cli import progress

    assert progress.HEARTBEAT_S < 10.0  # the rule: no silence over 10 s in a log, with room for a loaded machine
    r = subprocess.run(
        [sys.executable, "-c", "from fgcd_cli.cli import progress; print(progress.HEARTBEAT_S)"],
        env={**__import__("os").environ, "FGCD_HEARTBEAT_S": "0.5"},
        capture_output=True,
        text=True,
    )
    assert r.stdout.strip() == "0.5"


def test_the_longest_silence_of_a_command_in_a_pipe_is_the_heartbeat():
    """scripts/longest_silence.py on a command with a 1.5 s silent step, heartbeat at 0.25 s: the longest
    silence is about the heartbeat, not the step (measured, not a speed assertion: generous bounds)."""
    import json
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "scripts" / "longest_silence.py"
    r = subprocess.run(
        [sys.executable, str(script), "--", sys.executable, "-c", SLOW_STEP, "0.25", "1.5", "0"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    report = json.loads(r.stdout.strip().splitlines()[-1])
    assert report["exit"] == 0 and report["lines"] >= 5
    assert report["longest_silence_s"] < 1.2, r.stdout  # the step alone would leave 1.5 s


def test_a_step_that_ends_at_once_is_not_named_so_a_quick_error_stays_one_line():
    """Off a terminal the step lines wait PLAIN_STEP_DELAY_S: a command refused at once prints its error only."""
    script = textwrap.dedent("""
        import sys
        from fgcd_cli.cli.progress import step_progress
        with step_progress(enabled=True) as bar:
            bar(0, 0, "opening the rig")
        print("error: refused", file=sys.stderr)
    """)
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert r.stderr.splitlines() == ["error: refused"]


def test_lines_name_the_bar_step_between_counted_steps():
    from rich.console import Console
    from rich.progress import Progress

    from fgcd_cli.cli.progress import StepBar

    said = []
    with Progress(console=Console(file=io.StringIO()), disable=True) as progress:
        bar = StepBar(progress)
        say = bar.lines(said.append)
        bar(1, 4, "exploring (1/3)")
        say("exploration 1/3: VSE tracking")  # in the middle of a counted step: the bar keeps it
        assert [t.description for t in progress.tasks] == ["exploring (1/3)"]
        bar(4, 4, "adjustment 1: moving")
        say("adjustment 2: waiting for an alignment of the current view")  # after it: the line names the step
        assert [t.description for t in progress.tasks] == ["adjustment 2: waiting for an alignment of the current view"]
        say("  still aligning (10 s; latest estimate: none yet)")  # a detail: the step stays
        assert [t.description for t in progress.tasks] == ["adjustment 2: waiting for an alignment of the current view"]
    assert len(said) == 3


def test_no_terminal_no_bar_and_no_blank_line(capsys):
    from fgcd_cli.cli.progress import step_progress

    with step_progress(enabled=True, heartbeat_s=0.05) as bar:
        bar(0, 0, "a step")
        time.sleep(0.3)  # lasts a heartbeat: named
        bar(1, 2, "another")  # ends at once: not named
    # no live display off a terminal: a plain line per step that lasts, no blank line
    err = capsys.readouterr().err
    assert err.splitlines()[0] == "a step" and "another" not in err and "\n\n" not in err


def test_the_cli_bar_keeps_one_step_per_label_and_hides_for_questions():
    from rich.console import Console
    from rich.progress import Progress

    from fgcd_cli.cli.progress import StepBar, step_progress

    with step_progress(enabled=False) as bar:
        assert bar is None  # --json: no bar
    with Progress(console=Console(file=io.StringIO())) as progress:
        bar = StepBar(progress)
        bar(1, 10, "exploring (1/5)")
        bar(4, 10, "exploring (2/5)")
        assert len(progress.tasks) == 1 and progress.tasks[0].completed == 4
        bar(0, 0, "writing the reference")
        assert len(progress.tasks) == 1 and progress.tasks[0].total is None
        assert bar.paused(lambda text: text == "move?")("move?") is True
        assert bar.paused(None) is None
