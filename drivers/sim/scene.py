"""The :class:`Scene` container: textured mesh parts, a default camera pose and a lamp."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fgcd_drivers.sim.meshes import MeshPart

__all__ = ["Scene", "SceneInfo", "OBJECT_LABEL"]

#: Label of the monitored object in the label buffer; backgrounds use other labels.
OBJECT_LABEL = 1


@dataclass(frozen=True, kw_only=True)
class SceneInfo:
    """Name and one-line description of a scene."""

    name: str
    description: str


@dataclass(kw_only=True)
class Scene:
    """A simulated world: the heritage object and its surroundings, at real scale.

    Attributes
    ----------
    name, description : str
    seed : int
        Seed the scene was generated from.
    parts : list of MeshPart
        Textured surfaces; the monitored object has label ``OBJECT_LABEL`` (1).
    default_T_world_cam : (4, 4) ndarray
        A sensible reference viewpoint (0.4-2 m from the object, looking at it).
    lamp_position : (3,) ndarray
        Where the scene's artificial lamp stands (``night`` lighting), metres.
    up : (3,) ndarray
        World up (z).
    spec : dict
        The spec the scene was built from.
    """

    name: str
    description: str
    seed: int
    parts: list[MeshPart]
    default_T_world_cam: np.ndarray
    lamp_position: np.ndarray = field(default_factory=lambda: np.array([-1.5, -1.5, 0.3]))
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    spec: dict = field(default_factory=dict)

    @property
    def n_triangles(self) -> int:
        return int(sum(len(p.triangles) for p in self.parts))

    def part_names(self) -> dict[int, str]:
        """Label -> part name."""
        return {p.label: p.name for p in self.parts}

    def bounds(self, label: int | None = OBJECT_LABEL) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds (min, max) of the parts with ``label`` (all if None)."""
        vs = [p.vertices for p in self.parts if label is None or p.label == label]
        v = np.concatenate(vs) if vs else np.concatenate([p.vertices for p in self.parts])
        return v.min(axis=0), v.max(axis=0)

    @property
    def info(self) -> SceneInfo:
        return SceneInfo(name=self.name, description=self.description)
