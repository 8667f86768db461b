"""Ground truth stays in the simulator: algorithm packages never import drivers.sim."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ALGORITHM_PACKAGES = ("vse", "calibration", "alignment", "relocation", "changes")


def sim_imports(package_dir: Path) -> list[str]:
    """``file:line`` of every import of ``drivers.sim`` under ``package_dir`` (none if it is missing)."""
    found = []
    if not package_dir.is_dir():
        return found
    for path in sorted(package_dir.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", "")) in (
                    "import_module", "__import__") and node.args and isinstance(node.args[0], ast.Constant):
                names = [str(node.args[0].value)]
            if any(n == "drivers.sim" or n.startswith("drivers.sim.") for n in names):
                found.append(f"{path.relative_to(package_dir.parent)}:{node.lineno}")
    return found


@pytest.mark.parametrize("package", ALGORITHM_PACKAGES)
def test_algorithm_package_does_not_import_the_simulator(package):
    offenders = sim_imports(ROOT / "fgcd_cli" / package)
    assert not offenders, f"fgcd_cli/{package} imports drivers.sim (ground truth must stay in the simulator): {offenders}"


def test_checker_detects_planted_violations(tmp_path):
    pkg = tmp_path / "relocation"
    pkg.mkdir()
    (pkg / "ok.py").write_text("import numpy as np\nfrom drivers.platform import MotionGuard\nimport drivers\n")
    assert sim_imports(pkg) == []
    assert sim_imports(tmp_path / "missing") == []
    for i, line in enumerate([
        "import drivers.sim",
        "from drivers.sim.groundtruth import GroundTruth",
        "from drivers import sim",
        "import drivers.sim.rig as r",
        "import importlib\nimportlib.import_module('drivers.sim.rig')",
        "def f():\n    from drivers.sim import scenes\n",
    ]):
        bad = tmp_path / f"case{i}" / "alignment"
        bad.mkdir(parents=True)
        (bad / "sub").mkdir()
        (bad / "sub" / "x.py").write_text(line + "\n")
        assert sim_imports(bad), line
