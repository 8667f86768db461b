"""The simulated world: a scene, its renderer, the lights and the changes applied so far."""

from __future__ import annotations

from dataclasses import dataclass, field

from fgcd_drivers.sim.changes import ChangeSpec
from fgcd_drivers.sim.lights import Lighting, lighting_preset, list_lighting_presets
from fgcd_drivers.sim.render import Renderer
from fgcd_drivers.sim.scene import Scene

__all__ = ["SimWorld", "SimLights"]


class SimLights:
    """Switchable lighting of a rig (what a rig with controllable lights offers).

    ``set(name)`` takes any preset of :func:`fgcd_drivers.sim.lights.lighting_preset`
    (a :class:`fgcd_drivers.lights.Lights`).
    """

    name = "sim"

    def __init__(self, name: str = "front"):
        self._lighting = lighting_preset(name)

    def set(self, name: str) -> None:
        self._lighting = lighting_preset(name)

    @property
    def current(self) -> str:
        return self._lighting.name

    @property
    def lighting(self) -> Lighting:
        return self._lighting

    @staticmethod
    def available() -> list[str]:
        return [n for n, _ in list_lighting_presets()]

    def close(self) -> None:
        """Nothing to release."""


@dataclass
class SimWorld:
    """Scene + renderer + the changes currently present on the object."""

    scene: Scene
    renderer: Renderer
    changes: list[ChangeSpec] = field(default_factory=list)

    def apply_changes(self, changes) -> None:
        """Add changes (they persist until :meth:`clear_changes`)."""
        self.changes = list(self.changes) + list(changes)

    def clear_changes(self) -> None:
        self.changes = []
