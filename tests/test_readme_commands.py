"""Every option the README's command table shows exists on that command (the table is what users copy)."""

import re
from pathlib import Path

import pytest
import typer.main

from fgcd_cli.cli.app import app

README = Path(__file__).resolve().parents[1] / "README.md"


def _table_invocations() -> list[list[str]]:
    """Each backticked `fgcd ...` snippet of the command table, as tokens (alternatives a|b expanded)."""
    out = []
    for line in README.read_text().splitlines():
        if not line.startswith("| `fgcd"):
            continue
        cell = line.split(" | ")[0]
        for snippet in re.findall(r"`([^`]+)`", cell):
            tokens = snippet.replace("\\|", "|").split()
            if tokens[0] != "fgcd":
                tokens = out[-1][:2] + tokens  # "/ `show DIR`" continues the previous group
            out.append(tokens)
    return out


def _command(tokens: list[str]):
    """The click command the tokens name (first alternative of a|b), and the tokens after its name."""
    cmd = typer.main.get_command(app)
    rest = tokens[1:]
    while _is_group(cmd) and rest:
        name = rest[0].split("|")[0]
        if name not in cmd.commands:
            break
        cmd, rest = cmd.commands[name], rest[1:]
    return cmd, rest


def _is_group(cmd) -> bool:
    return hasattr(cmd, "commands")  # typer may ship its own click: no isinstance


def _options(cmd) -> set[str]:
    return {opt for p in cmd.params for opt in (*p.opts, *p.secondary_opts)}


INVOCATIONS = _table_invocations()


def test_the_table_was_read():
    assert len(INVOCATIONS) >= 15


@pytest.mark.parametrize("tokens", INVOCATIONS, ids=lambda t: " ".join(t[:3]))
def test_options_in_the_readme_exist(tokens):
    cmd, rest = _command(tokens)
    if _is_group(cmd):
        return  # "calibrate board / intrinsics / hand-eye": names only
    flags = [re.sub(r"[\[\]]", "", t) for t in rest if t.lstrip("[").startswith("-")]
    missing = [f for f in flags if f not in _options(cmd)]
    assert not missing, f"`{' '.join(tokens)}`: {missing} not options of {cmd.name}"


def _doc_invocations() -> list[tuple[str, list[str]]]:
    """`fgcd ...` lines of the code blocks of docs/*.md and README.md."""
    import shlex

    root = README.parent
    out = []
    for md in [*sorted((root / "docs").glob("*.md")), README]:
        in_block = False
        for number, line in enumerate(md.read_text().splitlines(), 1):
            if line.startswith("```"):
                in_block = not in_block
                continue
            match = re.search(r"(?:^|\s|/)(fgcd\s.*)$", line.strip()) if in_block else None
            if match:
                text = match.group(1).split("#")[0]
                try:
                    tokens = shlex.split(text)
                except ValueError:
                    tokens = text.split()
                out.append((f"{md.name}:{number}", tokens))
    return out


DOC_INVOCATIONS = _doc_invocations()


@pytest.mark.parametrize("where,tokens", DOC_INVOCATIONS, ids=[w for w, _ in DOC_INVOCATIONS])
def test_options_in_the_docs_code_blocks_exist(where, tokens):
    cmd, rest = _command(tokens)
    assert not _is_group(cmd), f"{where}: `{' '.join(tokens)}` names no command"
    flags = [re.sub(r"[\[\]]", "", t).split("=")[0] for t in rest if t.lstrip("[").startswith("-")]
    flags = [f for f in flags if not re.fullmatch(r"-[0-9.]+", f)]  # negative numbers are values
    missing = [f for f in flags if f not in _options(cmd)]
    assert not missing, f"{where}: `{' '.join(tokens)}`: {missing} not options of {cmd.name}"


def test_the_readme_cites_the_papers_without_paths_a_clone_lacks():
    """A user who clones has only the repository: the papers are cited by title and identifier."""
    text = README.read_text()
    assert "../shared" not in text
    assert "Fast and robust active camera" in text and "Neurocomputing" in text
    assert "Towards Accurate Active Camera Localization" in text and "arXiv:2012.04263" in text
