"""Lights on a USB relay / serial light controller speaking fgcd's light line protocol.

The protocol (ASCII lines ending in ``\\n``, one answer line per command; a
microcontroller sketch of a dozen lines implements it, see ``docs/hardware.md``,
"Lights"):

=============  ===========================  ==========================================
command        answer                       meaning
=============  ===========================  ==========================================
``ID``         ``LIGHTS <n>``               the controller has relays 1..n
``ON <k>``     ``OK``                       relay k on (others unchanged)
``OFF <k>``    ``OK``                       relay k off
``ALL OFF``    ``OK``                       every relay off
``STATE``      ``STATE <k>,<k>`` / ``STATE -``  the relays that are on
(anything)     ``ERR <reason>``             refused, nothing changed
=============  ===========================  ==========================================

A switch is ``ALL OFF``, ``ON k``, then ``STATE`` read back and compared.
"""

from __future__ import annotations

import serial

from fgcd_core.platform import PlatformConnectionError
from fgcd_drivers.lights import AMBIENT, LightsError, LightsSpec

__all__ = ["SerialLights", "parse_state"]


def parse_state(line: str) -> set[int]:
    """The relays a ``STATE ...`` answer reports on; LightsError on anything else."""
    kind, _, rest = line.partition(" ")
    if kind != "STATE":
        raise LightsError(f"the light controller answered '{line}' to STATE")
    if rest.strip() in ("", "-"):
        return set()
    try:
        return {int(v) for v in rest.split(",")}
    except ValueError:
        raise LightsError(f"the light controller answered '{line}' to STATE") from None


class SerialLights:
    """Relay channels of a serial light controller.

    Parameters
    ----------
    port : serial.SerialBase
        The open port (a read timeout set).
    channels : dict str -> str
        Lighting name -> relay number (``"1"``...).
    """

    name = "serial"

    def __init__(self, port, channels: dict[str, str]) -> None:
        self._port = port
        try:
            self._relays = {name: int(k) for name, k in channels.items() if name != AMBIENT}
        except ValueError:
            raise LightsError("[rig.lights] channels of a serial controller are relay numbers") from None
        self._current = AMBIENT

    @classmethod
    def open(cls, spec: LightsSpec, *, timeout_s: float = 1.0) -> SerialLights:
        """Open ``spec.port``, check the controller (``ID``) has every configured relay, switch all off."""
        if not spec.port:
            raise PlatformConnectionError("[rig.lights] driver 'serial' needs a port")
        try:
            port = serial.serial_for_url(spec.port, baudrate=spec.baud, timeout=timeout_s)
        except (serial.SerialException, OSError) as exc:
            raise PlatformConnectionError(f"cannot open the light controller on {spec.port}: {exc}") from None
        lights = cls(port, spec.channels)
        try:
            answer = lights._ask("ID")
            kind, _, count = answer.partition(" ")
            if kind != "LIGHTS" or not count.isdigit():
                raise PlatformConnectionError(f"{spec.port} answered '{answer}' to ID: not a light controller")
            missing = [n for n, k in lights._relays.items() if not 1 <= k <= int(count)]
            if missing:
                raise PlatformConnectionError(
                    f"the light controller has relays 1..{count}; [rig.lights] wires {', '.join(missing)} beyond them"
                )
            lights.set(AMBIENT)
        except (LightsError, PlatformConnectionError):
            port.close()
            raise
        return lights

    def _ask(self, command: str) -> str:
        """Send one command line and return its answer line (LightsError on silence or ``ERR``)."""
        try:
            self._port.reset_input_buffer()
            self._port.write(command.encode("ascii") + b"\n")
            raw = self._port.readline()
        except (serial.SerialException, OSError) as exc:
            raise LightsError(f"the light controller connection failed: {exc}") from None
        answer = raw.decode("ascii", errors="replace").strip()
        if not raw.endswith(b"\n"):
            raise LightsError(f"the light controller did not answer '{command}'")
        if answer.startswith("ERR"):
            raise LightsError(f"the light controller refused '{command}': {answer[3:].strip()}")
        return answer

    @property
    def current(self) -> str:
        """The lighting switched to last."""
        return self._current

    def available(self) -> list[str]:
        """``ambient`` and the wired relays' lightings."""
        return [AMBIENT, *self._relays]

    def set(self, lighting: str) -> None:
        """``ALL OFF``, ``ON k``, then check ``STATE``."""
        if lighting != AMBIENT and lighting not in self._relays:
            raise LightsError(f"no light '{lighting}' on the light controller (lights: {', '.join(self.available())})")
        self._ask("ALL OFF")
        relay = self._relays.get(lighting)
        if relay is not None:
            self._ask(f"ON {relay}")
        reported = parse_state(self._ask("STATE"))
        expected = {relay} if relay is not None else set()
        if reported != expected:
            raise LightsError(
                f"the light controller reports relays {sorted(reported) or 'off'} after switching "
                f"to '{lighting}' (expected {sorted(expected) or 'off'})"
            )
        self._current = lighting

    def reported_lighting(self) -> str:
        """The lighting whose relay the controller reports on (``ambient`` when none)."""
        on = parse_state(self._ask("STATE"))
        names = [n for n, k in self._relays.items() if k in on]
        if len(names) > 1:
            raise LightsError(f"the light controller reports several lights on: {', '.join(names)}")
        return names[0] if names else AMBIENT

    def close(self) -> None:
        """Every relay off (best effort), port closed."""
        try:
            self._ask("ALL OFF")
        except LightsError:
            pass
        self._port.close()
