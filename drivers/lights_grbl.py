"""Lights on a GRBL board's accessory outputs: flood coolant (M8), mist coolant (M7), spindle (M3 S…/M5).

GRBL 1.1 has three switchable outputs besides the motors (``doc/markdown/commands.md``):
flood coolant ``M8`` and mist coolant ``M7`` (``M9`` switches both off; M7
needs the ``ENABLE_M7`` build option), and the spindle enable + PWM pin
(``M3 S<speed>`` on, ``M5`` off; the PWM duty is ``S / $30``). Each drives an
LED channel through a MOSFET or relay board (wiring: ``docs/hardware.md``,
"Lights"). M-codes are executed in order with the motions, so a switch never
happens mid-move; ``G4 P0.01`` then waits until it is done, and the ``$G``
parser state (``[GC:... M3 M8 ... S1000]``) is read back to check every output.
"""

from __future__ import annotations

import re
import time

from fgcd_core.platform import PlatformConnectionError, PlatformError
from fgcd_drivers.lights import AMBIENT, LightsError, LightsSpec

__all__ = ["GrblLights", "GrblOutput", "output_command"]

_GC = re.compile(r"^\[GC:(.*)\]$")


class GrblOutput:
    """GRBL output names of ``[rig.lights] channels`` (``spindle:S`` carries the PWM speed)."""

    FLOOD = "flood"
    MIST = "mist"
    SPINDLE = "spindle"


def output_command(output: str) -> tuple[str, str]:
    """``(G-code that switches the output on, modal word $G then reports)`` for an output name.

    ``flood`` -> ``("M8", "M8")``, ``mist`` -> ``("M7", "M7")``, ``spindle:1000`` ->
    ``("M3 S1000", "M3")``; LightsError for anything else.
    """
    kind, _, value = output.partition(":")
    if kind == GrblOutput.FLOOD and not value:
        return "M8", "M8"
    if kind == GrblOutput.MIST and not value:
        return "M7", "M7"
    if kind == GrblOutput.SPINDLE:
        try:
            speed = float(value or "1000")
        except ValueError:
            speed = -1.0
        if speed > 0:
            return f"M3 S{speed:g}", "M3"
    raise LightsError(f"unknown GRBL light output '{output}' (flood, mist or spindle:S)")


class GrblLights:
    """LED channels on a GRBL board's outputs.

    Parameters
    ----------
    platform : fgcd_drivers.grbl.GrblPlatform
        An open GRBL connection (the stage's own, or one opened for the lights).
    channels : dict str -> str
        Lighting name -> output (``flood``, ``mist``, ``spindle:S``), one output per lighting.
    owns_platform : bool
        Close the connection on :meth:`close` (it was opened for the lights only).
    """

    name = "grbl"

    def __init__(self, platform, channels: dict[str, str], *, owns_platform: bool = False) -> None:
        self._platform = platform
        self._commands = {name: output_command(out) for name, out in channels.items() if name != AMBIENT}
        words = [w for _, w in self._commands.values()]
        if len(set(words)) != len(words):
            raise LightsError("two GRBL light channels use the same output; each LED channel needs its own")
        self._owns = owns_platform
        self._current = AMBIENT

    @classmethod
    def open(cls, spec: LightsSpec, *, platform=None) -> GrblLights:
        """The lights of ``spec``: on ``platform`` when it is the GRBL stage on the same port, else a connection of their own."""
        if getattr(platform, "name", None) == "grbl" and (spec.port is None or spec.port == platform.config.port):
            return cls(platform, spec.channels)
        if not spec.port:
            raise PlatformConnectionError("[rig.lights] driver 'grbl' needs a port (the GRBL board's serial device)")
        from fgcd_drivers.grbl.config import GrblConfig
        from fgcd_drivers.grbl.platform import GrblPlatform

        board = GrblPlatform(GrblConfig(port=spec.port, baud=spec.baud))
        board.connect()
        lights = cls(board, spec.channels, owns_platform=True)
        lights.set(AMBIENT)
        return lights

    @property
    def current(self) -> str:
        """The lighting switched to last."""
        return self._current

    def available(self) -> list[str]:
        """``ambient`` and the wired channels."""
        return [AMBIENT, *self._commands]

    def set(self, lighting: str) -> None:
        """All outputs off (``M5``, ``M9``), the lighting's output on, wait, and check ``$G``."""
        if lighting != AMBIENT and lighting not in self._commands:
            raise LightsError(f"no light '{lighting}' wired to the GRBL board (lights: {', '.join(self.available())})")
        on = self._commands.get(lighting)
        try:
            self._platform.send_line("M5")
            self._platform.send_line("M9")
            if on is not None:
                self._platform.send_line(on[0])
            self._platform.send_line("G4 P0.01")  # its ok comes once the switch is done
        except PlatformError as exc:
            raise LightsError(f"cannot switch the GRBL light '{lighting}': {exc}") from None
        reported = self.reported_outputs()
        expected = {on[1]} if on is not None else set()
        if reported != expected:
            raise LightsError(
                f"GRBL reports outputs {sorted(reported) or 'off'} after switching to '{lighting}' "
                f"(expected {sorted(expected) or 'off'})"
            )
        self._current = lighting

    def reported_outputs(self) -> set[str]:
        """The outputs GRBL's parser state reports on: a subset of ``{"M3", "M4", "M7", "M8"}``."""
        before = len(self._platform.messages)
        self._platform.send_line("$G")
        deadline = time.monotonic() + 0.5
        while time.monotonic() < deadline:
            for line in reversed(self._platform.messages[before:]):
                match = _GC.match(line)
                if match:
                    return {w for w in match.group(1).split() if w in ("M3", "M4", "M7", "M8")}
            time.sleep(0.01)
        raise LightsError("GRBL did not report its parser state ($G): cannot check the lights")

    def reported_lighting(self) -> str:
        """The lighting whose output GRBL reports on (``ambient`` when none; LightsError when several)."""
        outputs = self.reported_outputs()
        names = [name for name, (_, word) in self._commands.items() if word in outputs]
        if len(names) > 1:
            raise LightsError(f"GRBL reports several lights on: {', '.join(names)}")
        return names[0] if names else AMBIENT

    def close(self) -> None:
        """Switch every light off (best effort) and close a connection of our own."""
        try:
            self._platform.send_line("M5")
            self._platform.send_line("M9")
        except PlatformError:
            pass
        if self._owns:
            self._platform.close()
