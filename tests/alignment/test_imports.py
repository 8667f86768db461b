"""The alignment package must not reach into the simulator (ground truth stays there)."""

from __future__ import annotations

import ast
from pathlib import Path

import fgcd_cli.alignment

PACKAGE = Path(fgcd_cli.alignment.__file__).parent


def test_alignment_does_not_import_simulator_or_cli():
    offenders = []
    for path in PACKAGE.rglob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            for name in names:
                if name.startswith(("fgcd_drivers.sim", "fgcd_cli.cli", "typer", "rich")):
                    offenders.append(f"{path.name}: {name}")
    assert not offenders
