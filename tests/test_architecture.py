"""Every forbidden import direction, checked on the source of every module (docs/architecture.md).

Layers: ``fgcd_core`` (bottom: numpy/scipy/OpenCV only) <- ``fgcd_drivers`` (the folder ``drivers/``, the
world) <- ``fgcd_cli`` (the brain). The algorithm packages stay free of the
simulator, the use cases, reports, benchmarks and the CLI, and those under ``fgcd_cli``
of every driver (the robot port is ``fgcd_core.platform``); only ``fgcd_cli.cli``
speaks typer, and nothing imports the CLI but the CLI; the CLI itself imports of fgcd
only the use cases, the benchmarks and the errors (it is only a face).

Imports are read with :mod:`ast` (top-level and function-local ``import`` /
``from ... import`` with relative imports resolved, and ``importlib.import_module``
/ ``__import__`` of a literal name), so a lazy import counts like any other.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TOP_PACKAGES = ("fgcd_core", "fgcd_drivers", "fgcd_cli")
#: The folder of each top-level package: the design card's ``drivers/`` installs as ``fgcd_drivers`` (setup.py).
FOLDER = {"fgcd_core": "fgcd_core", "fgcd_drivers": "drivers", "fgcd_cli": "fgcd_cli"}
ALGORITHM_PACKAGES = (
    "fgcd_core",
    "fgcd_cli.vse",
    "fgcd_cli.alignment",
    "fgcd_cli.calibration",
    "fgcd_cli.relocation",
    "fgcd_cli.changes",
    "fgcd_cli.metrics",
    "fgcd_cli.archive",
)
#: What no algorithm package may import: the simulator's truth, use cases, outputs, benchmarks, the CLI and its libraries.
ALGORITHM_FORBIDDEN = (
    "fgcd_drivers.sim",
    "fgcd_cli.cli",
    "fgcd_cli.app",
    "fgcd_cli.report",
    "fgcd_cli.bench",
    "typer",
    "rich",
)


def module_name(path: Path, root: Path) -> str:
    """Dotted module name of ``path`` under ``root`` (a package's ``__init__`` is the package)."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    parts[0] = {folder: package for package, folder in FOLDER.items()}.get(parts[0], parts[0])
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def imported_names(path: Path, root: Path) -> list[tuple[int, str]]:
    """``(line, dotted name)`` of everything ``path`` imports; ``from a import b`` gives ``a`` and ``a.b``."""
    name = module_name(path, root)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            found += [(node.lineno, module)] + [(node.lineno, f"{module}.{a.name}") for a in node.names]
        elif (
            isinstance(node, ast.Call)
            and getattr(node.func, "attr", getattr(node.func, "id", "")) in ("import_module", "__import__")
            and node.args
            and isinstance(node.args[0], ast.Constant)
        ):
            found.append((node.lineno, str(node.args[0].value)))
    return found


def _matches(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


def offenders(
    root: Path, importers: tuple[str, ...], forbidden: tuple[str, ...], exempt: tuple[str, ...] = ()
) -> list[str]:
    """``file:line -> name`` of every module under ``importers`` (minus ``exempt``) importing a ``forbidden`` name."""
    out = []
    for top in TOP_PACKAGES:
        for path in sorted((root / FOLDER[top]).rglob("*.py")):
            mod = module_name(path, root)
            if not _matches(mod, importers) or _matches(mod, exempt):
                continue
            for line, name in imported_names(path, root):
                if _matches(name, forbidden):
                    out.append(f"{path.relative_to(root)}:{line} -> {name}")
    return sorted(set(out))


def test_core_imports_neither_the_brain_nor_the_world():
    assert not offenders(ROOT, ("fgcd_core",), ("fgcd_cli", "fgcd_drivers"))


def test_drivers_never_import_fgcd_cli():
    assert not offenders(ROOT, ("fgcd_drivers",), ("fgcd_cli",))


def test_nothing_imports_the_folder_name_drivers():
    """``drivers`` is importable only from the repository root; installed, the package is ``fgcd_drivers``."""
    assert not offenders(ROOT, TOP_PACKAGES, ("drivers",))


_KNOWN_VIOLATIONS: dict[str, str] = {}


@pytest.mark.parametrize(
    "package",
    [
        pytest.param(p, marks=pytest.mark.xfail(strict=True, reason=_KNOWN_VIOLATIONS[p]))
        if p in _KNOWN_VIOLATIONS
        else p
        for p in ALGORITHM_PACKAGES
    ],
)
def test_algorithm_package_stays_below_the_simulator_use_cases_and_cli(package):
    found = offenders(ROOT, (package,), ALGORITHM_FORBIDDEN)
    assert not found, f"{package} imports what an algorithm package may not: {found}"


#: The algorithm packages under ``fgcd_cli``: they drive a platform through the port in ``fgcd_core.platform``
#: (``Platform``, its errors, ``MotionGuard``) and get their rig from a use case, so they import no driver at all.
ALGORITHM_CLI_PACKAGES = tuple(p for p in ALGORITHM_PACKAGES if p.startswith("fgcd_cli."))


@pytest.mark.parametrize("package", ALGORITHM_CLI_PACKAGES)
def test_algorithm_package_imports_no_driver(package):
    found = offenders(ROOT, (package,), ("fgcd_drivers",))
    assert not found, f"{package} imports a driver (the port is fgcd_core.platform): {found}"


def test_driver_checker_sees_every_import_form(tmp_path):
    pkg = tmp_path / "fgcd_cli" / "relocation"
    (pkg / "sub").mkdir(parents=True)
    for p in (tmp_path / "fgcd_cli", pkg, pkg / "sub"):
        (p / "__init__.py").write_text("")
    (tmp_path / "drivers").mkdir()
    (tmp_path / "fgcd_core").mkdir()
    cases = {
        "import fgcd_drivers": "fgcd_drivers",
        "import fgcd_drivers.grbl.platform as g": "fgcd_drivers.grbl.platform",
        "from fgcd_drivers import connect": "fgcd_drivers.connect",
        "from fgcd_drivers.sim import build_sim_rig": "fgcd_drivers.sim",
        "def f():\n    from fgcd_drivers.ur import URPlatform\n": "fgcd_drivers.ur",
        "class A:\n    def f(self):\n        import fgcd_drivers.manual\n": "fgcd_drivers.manual",
        "import importlib\nimportlib.import_module('fgcd_drivers.connect')": "fgcd_drivers.connect",
        "__import__('fgcd_drivers.cameras')": "fgcd_drivers.cameras",
    }
    for i, (line, expected) in enumerate(cases.items()):
        f = pkg / "sub" / f"case{i}.py"
        f.write_text(line + "\n")
        found = offenders(tmp_path, ALGORITHM_CLI_PACKAGES, ("fgcd_drivers",))
        assert any(o.endswith(f"-> {expected}") for o in found), (line, found)
        f.unlink()
    (pkg / "ok.py").write_text(
        "import numpy\nfrom fgcd_core.platform import MotionGuard\nfrom fgcd_core import platform\n"
        "from . import sub\ndef f():\n    from fgcd_core.platform import MotionRejected\n"
    )
    assert offenders(tmp_path, ALGORITHM_CLI_PACKAGES, ("fgcd_drivers",)) == []


def test_only_the_cli_speaks_typer():
    assert not offenders(ROOT, TOP_PACKAGES, ("typer",), exempt=("fgcd_cli.cli",))


def test_nothing_but_the_cli_imports_the_cli():
    """``fgcd_cli.bench`` and ``fgcd_cli.app`` may import anything else; nothing imports ``fgcd_cli.cli``."""
    assert not offenders(ROOT, TOP_PACKAGES, ("fgcd_cli.cli",), exempt=("fgcd_cli.cli",))


#: What the CLI may import of fgcd: itself, the use cases, the benchmarks, the errors (the command's one line and
#: exit code) and the package's version; the rest of fgcd only through a use case (the CLI is only a face).
CLI_MAY_IMPORT = ("fgcd_cli.cli", "fgcd_cli.app", "fgcd_cli.bench", "fgcd_cli.errors", "fgcd_cli.__version__")


def outsiders(root: Path, importers: tuple[str, ...], allowed: tuple[str, ...]) -> list[str]:
    """``file:line -> name`` of every fgcd name (of ``TOP_PACKAGES``) a module under ``importers`` imports that is
    not ``allowed``; the packages on the way to an allowed name (``fgcd_cli`` of ``fgcd_cli.app``) are allowed."""
    on_the_way = {".".join(p.split(".")[:k]) for p in allowed for k in range(1, p.count(".") + 1)}
    out = []
    for top in TOP_PACKAGES:
        for path in sorted((root / FOLDER[top]).rglob("*.py")):
            if not _matches(module_name(path, root), importers):
                continue
            for line, name in imported_names(path, root):
                if _matches(name, TOP_PACKAGES) and not _matches(name, allowed) and name not in on_the_way:
                    out.append(f"{path.relative_to(root)}:{line} -> {name}")
    return sorted(set(out))


def test_the_cli_is_only_a_face():
    """``fgcd_cli.cli`` builds a request, calls a use case (``fgcd_cli.app``) or a bench, and renders its result."""
    found = outsiders(ROOT, ("fgcd_cli.cli",), CLI_MAY_IMPORT)
    assert not found, f"the CLI imports what only a use case may: {found}"


def test_cli_checker_sees_every_import_form(tmp_path):
    pkg = tmp_path / "fgcd_cli" / "cli"
    (pkg / "sub").mkdir(parents=True)
    for p in (tmp_path / "fgcd_cli", pkg, pkg / "sub"):
        (p / "__init__.py").write_text("")
    (tmp_path / "drivers").mkdir()
    (tmp_path / "fgcd_core").mkdir()
    cases = {
        "import fgcd_drivers.connect": "fgcd_drivers.connect",
        "from fgcd_core.platform import MotionGuard": "fgcd_core.platform",
        "from fgcd_drivers import sim": "fgcd_drivers.sim",
        "from fgcd_core.se3 import log_so3": "fgcd_core.se3",
        "import fgcd_cli.campaign": "fgcd_cli.campaign",
        "from fgcd_cli import report": "fgcd_cli.report",
        "from fgcd_cli.relocation.enums import LoopMode": "fgcd_cli.relocation.enums",
        "import importlib\nimportlib.import_module('fgcd_cli.metrics.afd')": "fgcd_cli.metrics.afd",
        "def f():\n    from ...calibration import board\n": "fgcd_cli.calibration",
        "def f():\n    from ... import changes\n": "fgcd_cli.changes",
    }
    for i, (line, expected) in enumerate(cases.items()):
        f = pkg / "sub" / f"case{i}.py"
        f.write_text(line + "\n")
        found = outsiders(tmp_path, ("fgcd_cli.cli",), CLI_MAY_IMPORT)
        assert any(expected in o for o in found), (line, found)
        f.unlink()
    (pkg / "ok.py").write_text(
        "import typer\nfrom rich.table import Table\nimport numpy\nfrom fgcd_cli import __version__\n"
        "from fgcd_cli.app.platform import MoveRequest\nfrom fgcd_cli.bench.relocate import LOOP_MODES\n"
        "from fgcd_cli.errors import UserInputError\nfrom . import sub\nfrom .. import app\n"
        "def f():\n    from fgcd_cli.cli.output import emit\n    import fgcd_cli.app.sim\n"
    )
    assert outsiders(tmp_path, ("fgcd_cli.cli",), CLI_MAY_IMPORT) == []


def test_every_listed_package_exists():
    """The checks pass vacuously on a missing folder: make sure they look where the code is."""
    for package in ALGORITHM_PACKAGES + TOP_PACKAGES + ("fgcd_cli.cli",):
        top, _, rest = package.partition(".")
        assert (ROOT / FOLDER[top] / rest.replace(".", "/") / "__init__.py").is_file(), package


def test_checker_sees_every_import_form(tmp_path):
    pkg = tmp_path / "fgcd_cli" / "alignment"
    (pkg / "sub").mkdir(parents=True)
    for p in (tmp_path / "fgcd_cli", pkg, pkg / "sub"):
        (p / "__init__.py").write_text("")
    (tmp_path / "drivers").mkdir()
    (tmp_path / "fgcd_core").mkdir()
    cases = {
        "import fgcd_drivers.sim": "fgcd_drivers.sim",
        "from fgcd_drivers.sim.groundtruth import GroundTruth": "fgcd_drivers.sim.groundtruth",
        "from fgcd_drivers import sim": "fgcd_drivers.sim",
        "import typer": "typer",
        "from rich.console import Console": "rich.console",
        "import importlib\nimportlib.import_module('fgcd_cli.cli.app')": "fgcd_cli.cli.app",
        "def f():\n    from ...report import html\n": "fgcd_cli.report",
        "from ... import bench": "fgcd_cli.bench",
    }
    for i, (line, expected) in enumerate(cases.items()):
        f = pkg / "sub" / f"case{i}.py"
        f.write_text(line + "\n")
        found = offenders(tmp_path, ("fgcd_cli.alignment",), ALGORITHM_FORBIDDEN)
        assert any(expected in o for o in found), (line, found)
        f.unlink()
    (pkg / "ok.py").write_text("import numpy\nfrom fgcd_core.platform import MotionGuard\nfrom . import sub\n")
    assert offenders(tmp_path, ("fgcd_cli.alignment",), ALGORITHM_FORBIDDEN) == []


#: The code rules of docs/architecture.md ("Code rules the layers keep").
MAX_FUNCTION_LINES = 80
MAX_MODULE_LINES = 500
MAX_PARAMETERS = 8


def _parameters(node: ast.FunctionDef | ast.AsyncFunctionDef) -> list[str]:
    """Every parameter but ``self`` / ``cls``, ``*args`` and ``**kwargs`` included."""
    a = node.args
    names = [x.arg for x in a.posonlyargs + a.args + a.kwonlyargs if x.arg not in ("self", "cls")]
    return names + [f"*{v.arg}" for v in (a.vararg,) if v] + [f"**{v.arg}" for v in (a.kwarg,) if v]


def _body_lines(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Lines of a function's body: its signature and docstring excluded (the formatter puts a parameter a line)."""
    body = node.body
    if len(body) > 1 and isinstance(body[0], ast.Expr) and isinstance(getattr(body[0], "value", None), ast.Constant):
        body = body[1:]
    return body[-1].end_lineno - body[0].lineno + 1


def size_offenders(root: Path) -> list[str]:
    """Modules over the line limit, functions over the line or parameter limit (typer commands in ``fgcd_cli.cli``
    exempt from the parameter limit: their options are the command line's)."""
    out = []
    for top in TOP_PACKAGES:
        for path in sorted((root / FOLDER[top]).rglob("*.py")):
            rel = path.relative_to(root)
            source = path.read_text(encoding="utf-8")
            if len(source.splitlines()) > MAX_MODULE_LINES:
                out.append(f"{rel}: {len(source.splitlines())} lines")
            cli = _matches(module_name(path, root), ("fgcd_cli.cli",))
            for node in ast.walk(ast.parse(source, filename=str(path))):
                if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    continue
                length = _body_lines(node)
                if length > MAX_FUNCTION_LINES:
                    out.append(f"{rel}:{node.lineno} {node.name}: {length} lines")
                if not cli and len(_parameters(node)) > MAX_PARAMETERS:
                    out.append(f"{rel}:{node.lineno} {node.name}: {len(_parameters(node))} parameters")
    return out


def test_modules_and_functions_keep_their_size_and_parameter_limits():
    assert not size_offenders(ROOT)


def test_size_checker_sees_each_rule(tmp_path):
    pkg = tmp_path / "fgcd_core"
    pkg.mkdir()
    for top in ("drivers", "fgcd_cli"):
        (tmp_path / top).mkdir()
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_FUNCTION_LINES + 1))
    (pkg / "long.py").write_text(f"def long():\n{body}\n")
    params = ", ".join(f"p{i}" for i in range(MAX_PARAMETERS)) + ", **extra"
    (pkg / "wide.py").write_text(f"class A:\n    def wide(self, {params}):\n        pass\n")
    (pkg / "big.py").write_text("x = 1\n" * (MAX_MODULE_LINES + 1))
    (pkg / "ok.py").write_text(f"def fine(self, {', '.join(f'p{i}' for i in range(MAX_PARAMETERS))}):\n    pass\n")
    found = size_offenders(tmp_path)
    assert any("long.py:1 long" in f for f in found)
    assert any(f"wide.py:2 wide: {MAX_PARAMETERS + 1} parameters" in f for f in found)
    assert any(f"big.py: {MAX_MODULE_LINES + 1} lines" in f for f in found)
    assert not any("ok.py" in f for f in found)


#: The only ``**`` parameters: pass-through of write options, a station's free-form record,
#: the one builder of a detector config from flat option names (the CLI's options), and the
#: fault bench's stand-ins for ``os.fdopen`` and ``open`` (they must accept what those accept).
ALLOWED_KEYWORD_CATCH_ALLS = {
    "fgcd_cli/campaign/atomic.py": {"atomic_write_text", "atomic_write_json"},
    "fgcd_cli/campaign/store.py": {"create_station", "station_or_create", "station_for_writing"},
    "fgcd_cli/changes/config.py": {"from_options"},
    "fgcd_cli/bench/faults/launch.py": {"fdopen", "open_budgeted"},
}


def test_options_travel_in_config_objects_not_keyword_catch_alls():
    """One call form per function: no ``**overrides`` beside a config dataclass or a typed request."""
    found = []
    for top in TOP_PACKAGES:
        for path in sorted((ROOT / FOLDER[top]).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if (
                    isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
                    and node.args.kwarg is not None
                    and node.name not in ALLOWED_KEYWORD_CATCH_ALLS.get(rel, ())
                ):
                    found.append(f"{rel}:{node.lineno} {node.name}(**{node.args.kwarg.arg})")
    assert not found


#: Paper 000's Eq. 3 written out: ``X @ M @ invert_pose(X)`` (or its inverse ``invert_pose(X) @ M @ X``).
EQ3_WRITTEN_OUT = r"\bX\b[^#\n]*@[^#\n]*@\s*invert_pose\(\s*(self\.)?X\s*\)|invert_pose\(\s*(self\.)?X\s*\)\s*@[^#\n]*@\s*(self\.)?X\b"


def test_eq3_is_written_out_in_one_function_only():
    """The camera motion as a flange motion has one home: ``fgcd_core.se3.flange_motion`` / ``camera_motion``."""
    import re

    pattern = re.compile(EQ3_WRITTEN_OUT)
    homes = set()
    for path in sorted(
        p for folder in ("fgcd_cli", "fgcd_core", "drivers", "scripts") for p in (ROOT / folder).rglob("*.py")
    ):
        for line in path.read_text(encoding="utf-8").splitlines():
            if pattern.search(line):
                homes.add(path.relative_to(ROOT).as_posix())
    assert homes == {"fgcd_core/se3.py"}
    assert pattern.search("M_flange = X @ M_cam @ invert_pose(X)")  # the checker sees the inline form
    assert pattern.search("step = invert_pose(self.X) @ M_cmd @ self.X")


# --- the module graph: no circle, no re-export, one meaning per module name -------------------------------------


def module_paths(root: Path) -> dict[str, Path]:
    """Dotted name -> file of every module of the three top packages."""
    return {module_name(p, root): p for top in TOP_PACKAGES for p in sorted((root / FOLDER[top]).rglob("*.py"))}


def import_graph(root: Path) -> dict[str, set[str]]:
    """Module -> the modules it imports (any form, ``TYPE_CHECKING`` blocks and function-local imports included)."""
    paths = module_paths(root)
    graph: dict[str, set[str]] = {m: set() for m in paths}
    for mod, path in paths.items():
        for _, name in imported_names(path, root):
            parts = name.split(".")
            while parts and ".".join(parts) not in paths:
                parts.pop()
            target = ".".join(parts)
            # a package's __init__ imported on the way to its submodule is not an edge back to it
            if target and target != mod and not mod.startswith(target + "."):
                graph[mod].add(target)
    return graph


def import_circles(root: Path) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm, iterative)."""
    graph = import_graph(root)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    circles = []
    for start in graph:
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    circles.append(sorted(component))
    return circles


def test_no_import_circle():
    assert not import_circles(ROOT)


def test_circle_checker_sees_a_type_checking_circle(tmp_path):
    pkg = tmp_path / "fgcd_cli"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from fgcd_cli.b import f\n")
    (pkg / "b.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from fgcd_cli.a import g\n")
    (pkg / "c.py").write_text("from fgcd_cli import a\n")
    for top in ("fgcd_core", "drivers"):
        (tmp_path / top).mkdir()
    assert import_circles(tmp_path) == [["fgcd_cli.a", "fgcd_cli.b"]]


#: Names a module may import from another without defining them: pyplot configured once for the reports.
REEXPORT_ALLOWED = {("fgcd_cli.report.mpl", "plt"), ("fgcd_cli.report.mpl", "matplotlib")}


def top_level_names(path: Path) -> set[str]:
    """Functions, classes and assigned names a module defines at top level (inside ``if`` / ``try`` too)."""
    names: set[str] = set()
    stack = list(ast.parse(path.read_text(encoding="utf-8")).body)
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
            for target in node.targets if isinstance(node, ast.Assign) else [node.target]:
                names |= {n.id for n in ast.walk(target) if isinstance(n, ast.Name)}
        elif isinstance(node, (ast.If, ast.Try, ast.With)):
            stack.extend(ast.iter_child_nodes(node))
    return names


def re_exports(
    root: Path, scanned: tuple[str, ...] = ("fgcd_core", "fgcd_cli", "drivers", "tests", "scripts")
) -> list[str]:
    """``file:line name from module`` of every import of a name its module does not define (a re-export)."""
    paths = module_paths(root)
    defined = {m: top_level_names(p) for m, p in paths.items()}
    out = []
    for folder in scanned:
        for path in sorted((root / folder).rglob("*.py")) if (root / folder).exists() else ():
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if not (isinstance(node, ast.ImportFrom) and node.level == 0 and node.module in defined):
                    continue
                for alias in node.names:
                    name = alias.name
                    if (
                        name in defined[node.module]
                        or f"{node.module}.{name}" in paths
                        or (node.module, name) in REEXPORT_ALLOWED
                    ):
                        continue
                    out.append(f"{path.relative_to(root)}:{node.lineno} {name} from {node.module}")
    return out


def test_each_name_is_imported_from_the_module_that_defines_it():
    """No re-export shim and no package facade: each public name has one import path."""
    assert not re_exports(ROOT)


def test_re_export_checker_sees_a_facade_and_a_shim(tmp_path):
    pkg = tmp_path / "fgcd_cli"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("from fgcd_cli.sub.impl import thing\n")
    (pkg / "sub" / "impl.py").write_text("def thing():\n    pass\n")
    (pkg / "shim.py").write_text("from fgcd_cli.sub.impl import thing  # noqa: F401\n")
    (pkg / "user.py").write_text(
        "from fgcd_cli.sub import thing, impl\nfrom fgcd_cli.shim import thing as t\n"
        "from fgcd_cli.sub.impl import thing as fine\n"
    )
    found = re_exports(tmp_path, scanned=("fgcd_cli",))
    assert found == ["fgcd_cli/user.py:1 thing from fgcd_cli.sub", "fgcd_cli/user.py:2 thing from fgcd_cli.shim"]


#: Module names a package may use for its own part of a shared role (docs/architecture.md, "Names").
ROLE_NAMES = {
    "config": "the options of its package",
    "errors": "the errors of its package",
    "result": "what its package returns",
    "main": "the entry (run) of a bench with parts",
    "stage": "the steps of one relocation stage",
    "refine": "the refinement of its package's estimate",
}
#: One concept at different layers (core, an algorithm package, the simulator, a driver, a use case, the CLI, a bench).
LAYER_TWINS = {
    "afd": "FDF/AFD",
    "board": "the ChArUco board",
    "calibrate": "hand-eye calibration",
    "camera": "the camera",
    "determinism": "deterministic runs",
    "intrinsics": "camera intrinsics",
    "lights": "the rig's lights",
    "platform": "the motion platform",
    "relocate": "a revisit's relocation",
    "render": "the simulator's renderer",
    "report": "a report",
    "rig": "a rig",
    "scene_uncertainty": "paper 001's scene uncertainty",
    "session": "a VSE session on a rig",
}


def layer_of(module: str) -> str:
    """The layer a module sits in: core, sim, a driver, app, cli, bench, or its algorithm package."""
    for prefix, layer in (
        ("fgcd_core", "core"),
        ("fgcd_drivers.sim", "sim"),
        ("fgcd_drivers", "drivers"),
        ("fgcd_cli.app", "app"),
        ("fgcd_cli.cli", "cli"),
        ("fgcd_cli.bench", "bench"),
    ):
        if _matches(module, (prefix,)):
            return layer
    return ".".join(module.split(".")[:2])


def test_a_module_name_names_one_thing():
    by_name: dict[str, list[str]] = {}
    for mod, path in module_paths(ROOT).items():
        if path.name != "__init__.py":
            by_name.setdefault(path.stem, []).append(mod)
    repeated = {name: mods for name, mods in by_name.items() if len(mods) > 1}
    unexplained = sorted(set(repeated) - set(ROLE_NAMES) - set(LAYER_TWINS))
    assert not unexplained, f"module names used twice for different things: {[repeated[n] for n in unexplained]}"
    for name in set(repeated) & set(LAYER_TWINS):
        layers = [layer_of(m) for m in repeated[name]]
        assert len(set(layers)) == len(layers), f"{name}: twins in one layer: {repeated[name]}"
    assert set(LAYER_TWINS) <= set(repeated), "a twin no longer repeated leaves the table"
