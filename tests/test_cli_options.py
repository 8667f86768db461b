"""The conventions of `fgcd_cli/cli/options.py` over every command: one spelling per concept, plain help."""

from __future__ import annotations

import re

import pytest
import typer.main

from fgcd_cli.cli.app import app


def _commands(group, path=("fgcd",)):
    for name, command in sorted(getattr(group, "commands", {}).items()):
        if getattr(command, "commands", None):
            yield from _commands(command, (*path, name))
        else:
            yield " ".join((*path, name)), command


COMMANDS = dict(_commands(typer.main.get_command(app)))


def _help(path: str) -> str:
    from typer.testing import CliRunner

    result = CliRunner().invoke(app, [*path.split()[1:], "--help"], env={"COLUMNS": "400", "NO_COLOR": "1"})
    assert result.exit_code == 0, result.output
    return result.output


def _options(command) -> dict[str, object]:
    return {name: p for p in command.params for name in (*p.opts, *p.secondary_opts)}


def test_capture_help_prints_bracketed_words_as_written():
    out = _help("fgcd capture")
    assert "[rig.lights]" in out and "[rig] driver" in out and "[rig.sim] scene" in out


@pytest.mark.parametrize("path", sorted(COMMANDS))
def test_help_has_no_bool_placeholder_and_keeps_every_bracket(path):
    out = " ".join(_help(path).split())
    assert "<bool>" not in out
    for param in COMMANDS[path].params:
        for token in re.findall(r"\[[A-Za-z][^\]\[]*\]", param.help or ""):
            assert token in out, (path, param.name, token)


@pytest.mark.parametrize("path", sorted(COMMANDS))
def test_every_option_has_help(path):
    missing = [p.opts[0] for p in COMMANDS[path].params if p.param_type_name == "option" and not p.help]
    assert not missing, (path, missing)


def test_one_name_per_concept():
    names = {path: _options(c) for path, c in COMMANDS.items()}
    for path, opts in names.items():
        assert not {"--lightings", "--visit-light", "--lights"} & set(opts), path  # the lighting option is --light
        if "--yes" in opts:
            assert "-y" in opts and opts["-y"] is opts["--yes"], path
    rig_commands = ["fgcd calibrate hand-eye", "fgcd capture", "fgcd relocate"]
    platform = ["fgcd platform check", "fgcd platform move", "fgcd platform home"]
    for option in ("--driver", "--port", "--host", "--baud", "--camera", "--yes"):
        helps = {names[p][option].help for p in rig_commands + platform if option in names[p]}
        assert len(helps) == 1, (option, helps)  # the shared definition
    for path in rig_commands + platform:
        assert names[path]["--driver"].default is None and "-d" in names[path]  # the campaign's, else sim
        assert names[path]["--campaign"] is names[path]["-c"]
    for path in ("fgcd calibrate hand-eye", "fgcd capture"):  # relocate: the station's own world
        assert names[path]["--scene"].default is None  # the campaign's [rig.sim] scene, else stele
