"""The simulated world: a scene, its renderer, the lights and the changes applied so far."""

from __future__ import annotations

from dataclasses import dataclass, field

from fgcd_drivers.lights import AMBIENT, LightsError
from fgcd_drivers.sim.changes import ChangeSpec
from fgcd_drivers.sim.lights import DARK, Lighting, compose, is_rig_lamp, lighting_preset
from fgcd_drivers.sim.render import Renderer
from fgcd_drivers.sim.scene import Scene

__all__ = ["DEFAULT_LAMPS", "SimLights", "SimWorld"]


#: The lamps a simulated rig carries when its campaign names none (``[rig.lights] driver = "sim"``
#: without ``channels``): a ring light at the lens and an LED on an arm at every clock position
#: (rACR §5.2.2).
DEFAULT_LAMPS = ("front", *(f"led:{hour}" for hour in range(1, 13)))


class SimLights:
    """The lamps a simulated rig carries, lighting a world whose own light the rig cannot change.

    A :class:`fgcd_drivers.lights.Lights`: ``set`` switches one carried lamp on
    (every other off) or, with ``ambient``, every lamp off. The world's light
    (the sun, the sky, the night, the room) is the visit's scenario, fixed when
    the rig is built; no ``set`` moves the sun (docs/simulator.md, "Lights a rig
    carries"). ``set`` also takes the world's own name, as the day's light with
    every lamp off, so that an image can be named after the day it was taken in.

    Parameters
    ----------
    lighting : str
        The scenario's light: a rig lamp (``front``, ``led:H``: a dark world,
        that lamp on) or the world's light (``sun-noon``, ``night``...: every
        lamp off).
    lamps : sequence of str, optional
        The lamps the rig carries (default :data:`DEFAULT_LAMPS`; the scenario's
        own lamp is always among them).
    """

    name = "sim"

    def __init__(self, lighting: str = "front", *, lamps=None):
        preset = lighting_preset(lighting)
        if is_rig_lamp(preset):
            self._world, self._on = lighting_preset(DARK), preset
        else:
            self._world, self._on = preset, None
        self._lamps: dict[str, Lighting] = {}
        self.mount(DEFAULT_LAMPS if lamps is None else lamps)
        if self._on is not None:
            self._lamps.setdefault(self._on.name, self._on)

    def mount(self, lamps) -> None:
        """Carry ``lamps`` (preset names of rig lamps) instead; LightsError for a name that is not a rig lamp."""
        carried: dict[str, Lighting] = {}
        for name in lamps:
            if name == AMBIENT:
                continue
            try:
                preset = lighting_preset(name)
            except ValueError:
                raise LightsError(f"the light '{name}' has no simulated counterpart (front, led:H...)") from None
            if not is_rig_lamp(preset):
                raise LightsError(f"'{name}' is the world's light, not a lamp a rig can carry (front, led:H...)")
            carried[preset.name] = preset
        self._lamps = carried
        if self._on is not None and self._on.name not in carried:
            self._on = None

    def set(self, name: str) -> None:
        """Switch the lamp ``name`` on (every other off); ``ambient`` or the world's name: every lamp off.

        Raises
        ------
        LightsError
            ``name`` is not a lamp this rig carries: the sun, the sky or the night
            cannot be switched, and a lamp the rig lacks cannot be lit.
        """
        if name in (AMBIENT, self._world.name):
            self._on = None
            return
        try:
            preset = lighting_preset(name)
        except ValueError:
            raise LightsError(f"unknown light '{name}' (this rig's lamps: {', '.join(self._lamps)})") from None
        if preset.name in (AMBIENT, self._world.name):
            self._on = None
        elif preset.name in self._lamps:
            self._on = self._lamps[preset.name]
        elif is_rig_lamp(preset):
            raise LightsError(f"this rig carries no lamp '{name}' (its lamps: {', '.join(self._lamps)})")
        else:
            raise LightsError(
                f"a rig cannot switch on '{name}': daylight, sky and night are the world's "
                f"(today's: {self._world.name}; this rig's lamps: {', '.join(self._lamps)})"
            )

    @property
    def current(self) -> str:
        """The lamp switched on, or ``ambient`` with every lamp off."""
        return AMBIENT if self._on is None else self._on.name

    @property
    def world(self) -> str:
        """The world's light (the simulator's own, for logs and evaluation; no algorithm reads it)."""
        return self._world.name

    @property
    def lighting(self) -> Lighting:
        """What lights the object now: the world's light plus the lamp switched on."""
        return compose(self._world, self._on)

    def available(self) -> list[str]:
        """``ambient`` and the lamps this rig carries."""
        return [AMBIENT, *self._lamps]

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
