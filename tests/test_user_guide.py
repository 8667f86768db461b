"""The user guide's simulator path runs as written, start to end (docs/user-guide.md, section 7).

The commands are read from the guide's marked code block, so the guide and this test cannot
drift apart. The path takes minutes (hand-eye calibration, capture, relocation, diff): the run
is a ``slow`` test (``pytest -m slow tests/test_user_guide.py``); reading the block is not.
"""

from __future__ import annotations

import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
GUIDE = ROOT / "docs" / "user-guide.md"
MARKER = "<!-- user-guide-sim-path"


def guide_commands(text: str) -> list[list[str]]:
    """The commands of the code block that follows the marker comment, as argument lists.

    Parameters
    ----------
    text : str
        The guide's Markdown.

    Returns
    -------
    list of list of str
        One entry per non-empty, non-comment line of the block (shell-quoted words).

    Raises
    ------
    ValueError
        No marker, or no code block right after it.
    """
    lines = text.splitlines()
    try:
        start = next(i for i, line in enumerate(lines) if line.strip().startswith(MARKER))
    except StopIteration:
        raise ValueError(f"{GUIDE.name}: no '{MARKER}' marker") from None
    if start + 1 >= len(lines) or not lines[start + 1].startswith("```"):
        raise ValueError(f"{GUIDE.name}: the marker is not followed by a code block")
    commands = []
    for line in lines[start + 2 :]:
        if line.startswith("```"):
            return commands
        words = shlex.split(line, comments=True)
        if words:
            commands.append(words)
    raise ValueError(f"{GUIDE.name}: the marked code block is not closed")


def test_the_marked_block_is_the_simulator_path():
    commands = guide_commands(GUIDE.read_text(encoding="utf-8"))
    assert all(c[0] == "fgcd" for c in commands)
    steps = [" ".join(c[1:3]) for c in commands]
    for step in (
        "campaign init",
        "calibrate intrinsics",
        "calibrate hand-eye",
        "capture -c",
        "relocate -c",
        "diff -c",
        "report -c",
    ):
        assert any(s.startswith(step) for s in steps), f"the simulator path misses `fgcd {step}`"
    # nothing a newcomer would need hardware for
    flat = [word for c in commands for word in c]
    assert "--host" not in flat and "--port" not in flat


def test_the_reader_refuses_a_guide_without_the_block():
    with pytest.raises(ValueError):
        guide_commands("# guide\n\n```bash\nfgcd demo\n```\n")


@pytest.mark.slow
def test_the_simulator_path_runs_as_written(tmp_path):
    for command in guide_commands(GUIDE.read_text(encoding="utf-8")):
        run = subprocess.run(
            [sys.executable, "-m", "fgcd_cli.cli.app", *command[1:]],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=1800,
            stdin=subprocess.DEVNULL,
        )
        assert run.returncode == 0, f"`{shlex.join(command)}` exited {run.returncode}:\n{run.stderr[-3000:]}"
    visits = list((tmp_path / "sim-stele" / "stations").glob("*/visits/*/report.html"))
    assert visits, "no visit report was written"
    assert list((tmp_path / "sim-stele" / "stations").glob("*/history.html"))


def test_the_timings_say_when_and_where_they_were_measured():
    """'How long things take' states figures as measured, with the date, commit and machine (not estimates)."""
    import re

    text = GUIDE.read_text(encoding="utf-8")
    section = text[text.index("## How long things take") :]
    head = section.split("|", 1)[0]
    assert re.search(r"Measured on \d{4}-\d{2}-\d{2}", head) and re.search(r"`[0-9a-f]{7}`", head), head
    assert "cores" in head
    rows = [line for line in section.splitlines() if line.startswith("| `fgcd") or line.startswith("| the ")]
    assert rows and all(re.search(r"\d+(\.\d+)? (s|min)\b", row) for row in rows), rows
