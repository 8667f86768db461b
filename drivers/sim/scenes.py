"""Scene catalogue: small TOML specs (``drivers/sim/scene_specs/``) built deterministically.

A spec names a builder (``drivers/sim/scene_builders.py``, ``scene_builders_arch.py``), its parameters, the
default camera (eye and target, metres, world frame z up) and the lamp used at
night. ``load_scene(name, seed=...)`` returns the same :class:`Scene` for the
same spec and seed (results are cached, scenes are treated as read-only).

The spec folder is ``$FGCD_SCENES_DIR`` if set, else the ``scene_specs`` data
folder shipped inside this package, found through :mod:`importlib.resources` so
that a wheel install finds it as an editable one does.
"""

from __future__ import annotations

import os
import tomllib
from functools import lru_cache
from importlib import resources
from pathlib import Path

import numpy as np

from fgcd_drivers.sim.scene import OBJECT_LABEL, Scene, SceneInfo
from fgcd_drivers.sim.scene_builders import BUILDERS as _BASE_BUILDERS
from fgcd_drivers.sim.scene_builders_arch import ARCH_BUILDERS
from fgcd_drivers.sim.scene_builders_lab import LAB_BUILDERS
from fgcd_drivers.sim.scene_builders_rock import ROCK_BUILDERS
from fgcd_drivers.sim.transforms import look_at

BUILDERS = {**_BASE_BUILDERS, **ARCH_BUILDERS, **LAB_BUILDERS, **ROCK_BUILDERS}

__all__ = [
    "scenes_dir",
    "list_scenes",
    "load_scene",
    "scene_spec",
    "SceneNotFound",
    "Scene",
    "SceneInfo",
    "OBJECT_LABEL",
]


class SceneNotFound(ValueError):
    """No scene spec of that name."""


def scenes_dir() -> Path:
    env = os.environ.get("FGCD_SCENES_DIR")
    if env:
        return Path(env)
    # setuptools installs package data as plain files (wheels are not zip-imported),
    # so the resource folder is a directory on disk.
    return Path(str(resources.files("fgcd_drivers.sim").joinpath("scene_specs")))


def _spec_files() -> dict[str, Path]:
    d = scenes_dir()
    if not d.is_dir():
        return {}
    return {p.stem: p for p in sorted(d.glob("*.toml"))}


def scene_spec(name: str) -> dict:
    """The parsed spec of scene ``name``."""
    files = _spec_files()
    if name not in files:
        known = ", ".join(files) or "none"
        raise SceneNotFound(f"unknown scene {name!r}; known: {known} (specs in {scenes_dir()})")
    with open(files[name], "rb") as fh:
        spec = tomllib.load(fh)
    for key in ("description", "builder", "camera"):
        if key not in spec:
            raise ValueError(f"scene spec {files[name]} lacks '{key}'")
    if spec["builder"] not in BUILDERS:
        raise ValueError(f"scene spec {files[name]} names unknown builder {spec['builder']!r}")
    return spec


def list_scenes() -> list[SceneInfo]:
    """Every scene with a spec, sorted by name."""
    out = []
    for name in _spec_files():
        spec = scene_spec(name)
        out.append(SceneInfo(name=name, description=str(spec["description"])))
    return out


@lru_cache(maxsize=4)
def _load(name: str, seed: int, mtime: float) -> Scene:
    spec = scene_spec(name)
    rng = np.random.default_rng([seed, sum(name.encode())])
    built = BUILDERS[spec["builder"]](dict(spec.get("params", {})), rng)
    cam = spec["camera"]
    T = look_at(cam["eye"], cam["target"])
    lamp = np.asarray(spec.get("lamp", {}).get("position", (-1.5, -1.5, 0.3)), float)
    return Scene(
        name=name,
        description=str(spec["description"]),
        seed=seed,
        parts=built["parts"],
        default_T_world_cam=T,
        lamp_position=lamp,
        spec=spec,
    )


def load_scene(name: str, *, seed: int = 0) -> Scene:
    """Build (or reuse) scene ``name`` for ``seed``."""
    files = _spec_files()
    if name not in files:
        scene_spec(name)  # raises SceneNotFound with the list
    return _load(name, int(seed), files[name].stat().st_mtime)
