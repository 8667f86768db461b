"""Ground truth stays in the simulator: algorithm packages never import fgcd_drivers.sim.

The static checks of every import direction are in tests/test_architecture.py;
this file also checks the transitive, run-time form.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ALGORITHM_PACKAGES = ("vse", "calibration", "alignment", "relocation", "changes", "metrics", "archive")


def sim_imports(package_dir: Path) -> list[str]:
    """``file:line`` of every import of ``fgcd_drivers.sim`` under ``package_dir`` (none if it is missing)."""
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
            elif (
                isinstance(node, ast.Call)
                and getattr(node.func, "attr", getattr(node.func, "id", "")) in ("import_module", "__import__")
                and node.args
                and isinstance(node.args[0], ast.Constant)
            ):
                names = [str(node.args[0].value)]
            if any(n == "fgcd_drivers.sim" or n.startswith("fgcd_drivers.sim.") for n in names):
                found.append(f"{path.relative_to(package_dir.parent)}:{node.lineno}")
    return found


@pytest.mark.parametrize("package", ALGORITHM_PACKAGES)
def test_algorithm_package_does_not_import_the_simulator(package):
    offenders = sim_imports(ROOT / "fgcd_cli" / package)
    assert not offenders, (
        f"fgcd_cli/{package} imports fgcd_drivers.sim (ground truth must stay in the simulator): {offenders}"
    )


def test_checker_detects_planted_violations(tmp_path):
    pkg = tmp_path / "relocation"
    pkg.mkdir()
    (pkg / "ok.py").write_text("import numpy as np\nfrom fgcd_core.platform import MotionGuard\nimport drivers\n")
    assert sim_imports(pkg) == []
    assert sim_imports(tmp_path / "missing") == []
    for i, line in enumerate(
        [
            "import fgcd_drivers.sim",
            "from fgcd_drivers.sim.groundtruth import GroundTruth",
            "from fgcd_drivers import sim",
            "import fgcd_drivers.sim.rig as r",
            "import importlib\nimportlib.import_module('fgcd_drivers.sim.rig')",
            "def f():\n    from fgcd_drivers.sim import scenes\n",
        ]
    ):
        bad = tmp_path / f"case{i}" / "alignment"
        bad.mkdir(parents=True)
        (bad / "sub").mkdir()
        (bad / "sub" / "x.py").write_text(line + "\n")
        assert sim_imports(bad), line


def test_algorithm_packages_exist():
    """The static check passes vacuously on a missing folder: make sure the packages are where it looks."""
    for package in ALGORITHM_PACKAGES:
        assert (ROOT / "fgcd_cli" / package / "__init__.py").is_file(), package


def test_importing_the_algorithm_packages_does_not_load_the_simulator():
    """Transitively too: every module of these packages and of ``fgcd_core`` imported, ``fgcd_drivers.sim`` is not loaded."""
    import subprocess
    import sys

    code = (
        "import importlib, pkgutil, sys\n"
        f"for p in {tuple('fgcd_cli.' + p for p in ALGORITHM_PACKAGES) + ('fgcd_core',)!r}:\n"
        "    pkg = importlib.import_module(p)\n"
        "    for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + '.'):\n"
        "        importlib.import_module(m.name)\n"
        "print(sorted(m for m in sys.modules if m == 'fgcd_drivers.sim' or m.startswith('fgcd_drivers.sim.')))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]", f"importing the algorithm packages loads the simulator: {r.stdout.strip()}"
