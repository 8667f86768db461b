"""Real light drivers wired to the simulated world: a simulated-platform capture with manual, GRBL or serial lights.

The simulated scene is lit by what the light *controller reports* after each
switch (GRBL's ``$G`` outputs, the relay board's ``STATE``), or by what the
person confirmed (manual prompt): the rendering follows the pins, as a real
scene follows the wiring. ``ambient`` (every rig light off) renders the
session's own light, as the day's light stays on a real site.
"""

from __future__ import annotations

from fgcd_drivers.lights import AMBIENT, Lights, LightsError
from fgcd_drivers.sim.lights import lighting_preset
from fgcd_drivers.sim.world import SimLights

__all__ = ["WiredSimLights"]


class WiredSimLights:
    """A real :class:`fgcd_drivers.lights.Lights` driver whose reported state lights the simulated world.

    Parameters
    ----------
    hardware : Lights
        The driver commanded (manual, GRBL, serial).
    world : SimLights
        The simulated scene's lighting (its current preset is the day's light).
    """

    def __init__(self, hardware: Lights, world: SimLights) -> None:
        self._hardware = hardware
        self._world = world
        self._day = world.current
        self.name = f"{hardware.name} (wired to the simulator)"
        for channel in hardware.available():
            if channel != AMBIENT:
                try:
                    lighting_preset(channel)
                except ValueError:
                    raise LightsError(f"the light '{channel}' has no simulated counterpart (led:H, front...)") from None

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
        self._world.set(self._day if seen == AMBIENT else seen)

    def close(self) -> None:
        """Close the hardware lights."""
        self._hardware.close()
