"""A regular (non-editable) install ships what the simulator needs: scenes listed and rendered from a wheel."""

import json
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """fgcd built as a wheel and unpacked into a folder of its own (dependencies from this environment)."""
    tmp = tmp_path_factory.mktemp("wheel")
    before = {p.name for p in ROOT.iterdir()}
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            str(ROOT),
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(tmp / "dist"),
        ],
        check=True,
        cwd=tmp,
        capture_output=True,
        timeout=300,
    )
    left = sorted({p.name for p in ROOT.iterdir()} - before)
    assert not left, f"the build wrote into the source tree: {left}"  # setup.py builds out of tree
    wheel = next((tmp / "dist").glob("fgcd-*.whl"))
    tops = {name.split("/")[0] for name in zipfile.ZipFile(wheel).namelist() if "/" in name}
    assert "fgcd_drivers" in tops and "drivers" not in tops, tops  # fgcd's own name in site-packages
    target = tmp / "site"
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(target), str(wheel)],
        check=True,
        cwd=tmp,
        capture_output=True,
        timeout=300,
    )
    return target


def _run_installed(target: Path, code: str) -> subprocess.CompletedProcess:
    """Run ``code`` seeing the installed wheel and this environment's dependencies, not the repository.

    ``-S`` skips site processing, so the editable install's path hook (a ``.pth``
    file) is not loaded; the working directory is outside the repository.
    """
    deps = sysconfig.get_paths()["purelib"]
    env = {"PYTHONPATH": f"{target}:{deps}", "PATH": "/usr/bin:/bin", "HOME": str(target)}
    return subprocess.run(
        [sys.executable, "-S", "-c", code], cwd=target, env=env, capture_output=True, text=True, timeout=600
    )


def test_wheel_lists_the_scenes_and_renders_a_frame(installed):
    listing = _run_installed(
        installed,
        (
            "import json; import fgcd_cli, fgcd_core, fgcd_drivers.sim.scenes as s; "
            "print(json.dumps({'module': fgcd_cli.__file__, 'core': fgcd_core.__file__, "
            "'scenes': [i.name for i in s.list_scenes()]}))"
        ),
    )
    assert listing.returncode == 0, listing.stderr
    data = json.loads(listing.stdout)
    assert data["module"].startswith(str(installed)), data["module"]  # the wheel's copy, not the repository's
    assert data["core"].startswith(str(installed)), data["core"]  # the bottom layer ships too
    shipped = sorted(p.stem for p in (ROOT / "drivers" / "sim" / "scene_specs").glob("*.toml"))
    assert data["scenes"] == shipped and "stele" in shipped

    cli = _run_installed(
        installed,
        "import sys; sys.argv = ['fgcd', 'sim', 'scenes', '--json']; from fgcd_cli.cli.app import main; main()",
    )
    assert cli.returncode == 0, cli.stderr
    assert sorted(s["name"] for s in json.loads(cli.stdout)["scenes"]) == shipped

    render = _run_installed(
        installed,
        (
            "import numpy as np; from fgcd_core.camera import CameraIntrinsics; "
            "from fgcd_drivers.sim.render import Renderer; from fgcd_drivers.sim.scenes import load_scene; "
            "scene = load_scene('stele'); intr = CameraIntrinsics(fx=120., fy=120., cx=39.5, cy=29.5, width=80, height=60); "
            "rgb = Renderer(scene).render(np.asarray(scene.default_T_world_cam), intr, 'front', want=('rgb',)).rgb; "
            "print(rgb.shape, float(rgb.std()))"
        ),
    )
    assert render.returncode == 0, render.stderr
    shape, spread = render.stdout.strip().rsplit(" ", 1)
    assert shape == "(60, 80, 3)" and float(spread) > 0.01  # an image of the object, not a blank frame
