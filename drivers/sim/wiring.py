"""Real light drivers wired to the simulated world: a simulated-platform capture with manual, GRBL or serial lights.

The simulated scene is lit by what the light *controller reports* after each
switch (GRBL's ``$G`` outputs, the relay board's ``STATE``), or by what the
person confirmed (manual prompt): the rendering follows the pins, as a real
scene follows the wiring. The simulated rig carries the hardware's channels as
its lamps; ``ambient`` (every rig light off) renders the world's own light, as
the day's light stays on a real site.
"""

from __future__ import annotations

from fgcd_drivers.lights import Lights
from fgcd_drivers.sim.world import SimLights

__all__ = ["WiredSimLights"]


class WiredSimLights:
    """A real :class:`fgcd_drivers.lights.Lights` driver whose reported state lights the simulated world.

    Parameters
    ----------
    hardware : Lights
        The driver commanded (manual, GRBL, serial).
    world : SimLights
        The simulated rig's lamps in its world; it is made to carry the hardware's channels
        (LightsError for a channel that is not a simulated lamp).
    """

    def __init__(self, hardware: Lights, world: SimLights) -> None:
        self._hardware = hardware
        self._world = world
        self.name = f"{hardware.name} (wired to the simulator)"
        world.mount(hardware.available())

    @property
    def current(self) -> str:
        """The lighting switched to last."""
        return self._hardware.current

    @property
    def lighting(self):
        """The simulated world's lighting (what the camera renders)."""
        return self._world.lighting

    def available(self) -> list[str]:
        """The hardware's lightings."""
        return self._hardware.available()

    def set(self, lighting: str) -> None:
        """Switch the hardware, then light the world as the controller reports."""
        self._hardware.set(lighting)
        reported = getattr(self._hardware, "reported_lighting", None)
        seen = reported() if reported is not None else self._hardware.current
        if seen not in self._world.available():
            # a manual rig without listed channels: the lamp the person switched on is one it carries
            self._world.mount([*self._world.available(), seen])
        self._world.set(seen)

    def close(self) -> None:
        """Close the hardware lights."""
        self._hardware.close()
