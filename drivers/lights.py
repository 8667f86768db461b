"""The Lights protocol (beside :class:`fgcd_core.platform.Platform`) and the manual prompt; ``fgcd_drivers.connect.open_lights`` opens a rig's lights.

A *lighting* is named as on the command line (``fgcd capture --lightings
ambient,led:3,led:6``): ``ambient`` means every rig light off (the day's
light only); any other name is a *channel* of the rig (``led:3``, the LED at
3 o'clock around the optical axis, rACR §5.2.2). Switching to a lighting
switches that one channel on and every other channel off.

Drivers: :class:`ManualLights` (a person is asked to switch, here),
:class:`fgcd_drivers.lights_grbl.GrblLights` (GRBL's coolant and spindle outputs),
:class:`fgcd_drivers.lights_serial.SerialLights` (a USB relay / serial light
controller with the line protocol documented there), and the simulator's
``fgcd_drivers.sim.world.SimLights``. Wiring and protocol: ``docs/hardware.md``,
"Lights".
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Protocol, runtime_checkable

from fgcd_core.platform import PlatformConnectionError, PlatformError

__all__ = ["AMBIENT", "Lights", "LightsDriver", "LightsError", "LightsSpec", "ManualLights", "parse_lightings"]

#: The lighting with every rig light off.
AMBIENT = "ambient"


class LightsError(PlatformError):
    """A light could not be switched, or its controller reports another state than asked."""


class LightsDriver(StrEnum):
    """Light drivers (campaign.toml ``[rig.lights] driver``)."""

    SIM = "sim"
    MANUAL = "manual"
    GRBL = "grbl"
    SERIAL = "serial"


@runtime_checkable
class Lights(Protocol):
    """What every light driver offers."""

    name: str

    @property
    def current(self) -> str:
        """The lighting switched to last (``ambient`` at start)."""

    def available(self) -> list[str]:
        """The lightings this rig can switch to (``ambient`` and its channels)."""

    def set(self, lighting: str) -> None:
        """Switch to ``lighting`` and return once the controller reports it (LightsError otherwise)."""

    def close(self) -> None:
        """Switch every light off and release the connection."""


def parse_lightings(text: str) -> list[str]:
    """The comma-separated lighting names of ``text``, stripped, empty items dropped."""
    return [name.strip() for name in text.split(",") if name.strip()]


class ManualLights:
    """A person switches the lights when asked ("switch on the 3 o'clock light, press Enter").

    Parameters
    ----------
    channels : sequence of str
        The rig's light channels (``led:3``...); empty: any name is accepted.
    ask : callable(str) -> str
        Shows a prompt and returns the answer (``input``). End of input (no
        terminal) raises :class:`LightsError`.
    """

    name = "manual"

    def __init__(self, channels=(), *, ask: Callable[[str], str] = input) -> None:
        self._channels = [c for c in channels if c != AMBIENT]
        self._ask = ask
        self._current: str | None = None  # unknown until the person confirms a first switch

    @property
    def current(self) -> str:
        """The lighting the person confirmed last (``unknown`` before the first)."""
        return self._current or "unknown"

    def available(self) -> list[str]:
        """``ambient`` and the configured channels."""
        return [AMBIENT, *self._channels]

    def set(self, lighting: str) -> None:
        """Ask the person to switch, and wait for Enter (``n`` refuses: LightsError)."""
        if self._channels and lighting != AMBIENT and lighting not in self._channels:
            raise LightsError(f"no light '{lighting}' on this rig (lights: {', '.join(self.available())})")
        if lighting == self._current:
            return
        prompt = (
            "Switch every rig light off (ambient light only), then press Enter [Y/n] "
            if lighting == AMBIENT
            else f"Switch on the {_clock_words(lighting)} light only (all others off), then press Enter [Y/n] "
        )
        try:
            answer = self._ask(prompt).strip().lower()
        except EOFError:
            raise LightsError(
                f"no terminal to ask for the light '{lighting}': configure [rig.lights] in "
                "campaign.toml (docs/hardware.md, Lights)"
            ) from None
        if answer not in ("", "y", "yes"):
            raise LightsError(f"the switch to the light '{lighting}' was not confirmed; nothing was captured under it")
        self._current = lighting

    def close(self) -> None:
        """Nothing to release."""


def _clock_words(lighting: str) -> str:
    """``led:3`` -> ``3 o'clock (led:3)``; other names as they are."""
    kind, _, value = lighting.partition(":")
    if kind == "led" and value.split(",")[0].isdigit():
        return f"{value.split(',')[0]} o'clock ({lighting})"
    return f"'{lighting}'"


@dataclass(frozen=True, kw_only=True)
class LightsSpec:
    """How to reach a rig's lights: campaign.toml ``[rig.lights]``.

    Attributes
    ----------
    driver : LightsDriver
    port : str or None
        Serial device of a GRBL board or a serial light controller (a GRBL
        platform on the same port shares its connection).
    baud : int
    channels : dict str -> str
        Lighting name -> output: for GRBL ``flood`` (M8), ``mist`` (M7) or
        ``spindle:S`` (M3 S<S>); for a serial controller the relay number.
    """

    driver: LightsDriver = LightsDriver.MANUAL
    port: str | None = None
    baud: int = 115200
    channels: dict[str, str] = field(default_factory=dict)

    @classmethod
    def from_config(cls, section: dict | None) -> LightsSpec | None:
        """The spec of a ``[rig.lights]`` table (None when there is none); PlatformConnectionError when malformed."""
        if not section:
            return None
        try:
            driver = LightsDriver(str(section.get("driver", LightsDriver.MANUAL)))
        except ValueError:
            raise PlatformConnectionError(
                f"[rig.lights] driver must be one of {', '.join(LightsDriver)}, got '{section.get('driver')}'"
            ) from None
        channels = section.get("channels", {})
        if isinstance(channels, list):  # manual: a list of names is enough
            channels = {str(c): "" for c in channels}
        if not isinstance(channels, dict):
            raise PlatformConnectionError("[rig.lights] channels must be a table: lighting name = output")
        return cls(
            driver=driver,
            port=section.get("port"),
            baud=int(section.get("baud", 115200)),
            channels={str(k): str(v) for k, v in channels.items()},
        )
