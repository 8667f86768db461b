"""A serial light controller that fails on demand, for ``fgcd bench faults`` (class ``relocate_light_stuck``).

:class:`FaultyLightController` is the pty emulator of
:mod:`fgcd_drivers.testing.light_controller_emulator` (the protocol of
``drivers/lights_serial.py``, docs/hardware.md "Serial light controller") with
the faults a relay board has in the field, switched on at a chosen instant by
:meth:`FaultyLightController.fail`:

* ``stuck``: the relays stop following (a welded relay, a board whose relay
  supply dropped): commands still answer ``OK``, ``STATE`` reports what the
  relays really do;
* ``wrong``: ``STATE`` reports every relay on (a confused firmware);
* ``refuses``: every command answers ``ERR``;
* ``silent``: no answer at all (a hung controller).

:attr:`FaultyLightController.revealed` says whether, since the fault, the
controller gave fgcd an answer that shows it (a ``STATE`` that differs from
what was commanded, an ``ERR``, a silence): fgcd must then stop with exit 7.
"""

from __future__ import annotations

import threading

from fgcd_drivers.testing.light_controller_emulator import LightControllerEmulator

__all__ = ["LIGHT_FAULT_MODES", "FaultyLightController", "lights_section"]

#: The fault modes of :meth:`FaultyLightController.fail`.
LIGHT_FAULT_MODES = ("stuck", "wrong", "refuses", "silent")


def lights_section(port: str, channels: dict[str, int]) -> str:
    """The ``[rig.lights]`` table of a campaign.toml wiring ``channels`` to a serial controller on ``port``."""
    wired = ", ".join(f'"{name}" = "{relay}"' for name, relay in channels.items())
    return f'\n[rig.lights]\ndriver = "serial"\nport = "{port}"\nchannels = {{ {wired} }}\n'


class FaultyLightController(LightControllerEmulator):
    """The light controller emulator with field faults switched on by :meth:`fail`."""

    def __init__(self, *, n_relays: int = 8) -> None:
        self.mode: str | None = None
        self.revealed = False
        self.commanded: set[int] = set()
        self._lines_at_fault = 0
        self._fault_lock = threading.Lock()
        super().__init__(n_relays=n_relays)

    def fail(self, mode: str) -> None:
        """From now on, fail as ``mode`` (one of :data:`LIGHT_FAULT_MODES`)."""
        if mode not in LIGHT_FAULT_MODES:
            raise ValueError(f"unknown light fault '{mode}' (known: {', '.join(LIGHT_FAULT_MODES)})")
        with self._fault_lock:
            self.mode = mode
            self._lines_at_fault = len(self.lines_received)
            if mode == "silent":
                self.set_silent(True)

    @property
    def commands_since_fault(self) -> int:
        """Command lines received since :meth:`fail` (0 before it)."""
        return len(self.lines_received) - self._lines_at_fault if self.mode else 0

    def answer(self, line: str) -> str:
        """The answer of a healthy controller, or of the failed one (and whether it shows the fault)."""
        words = line.upper().split()
        with self._fault_lock:
            mode = self.mode
        if mode == "refuses":
            self.revealed = True
            return "ERR relay board fault"
        follows = mode != "stuck"
        if words == ["ALL", "OFF"]:
            self.commanded.clear()
            if follows:
                self.relays_on.clear()
            return "OK"
        if len(words) == 2 and words[0] in ("ON", "OFF") and words[1].isdigit() and 1 <= int(words[1]) <= self.n_relays:
            k = int(words[1])
            (self.commanded.add if words[0] == "ON" else self.commanded.discard)(k)
            if follows:
                (self.relays_on.add if words[0] == "ON" else self.relays_on.discard)(k)
            return "OK"
        if words == ["STATE"] and mode == "wrong":
            self.revealed = True
            return "STATE " + ",".join(str(k) for k in range(1, self.n_relays + 1))
        if words == ["STATE"] and mode == "stuck" and self.relays_on != self.commanded:
            self.revealed = True
        return super().answer(line)

    @property
    def showed_fault(self) -> bool:
        """fgcd was shown the fault before it closed the lights.

        ``stuck``/``wrong``: a ``STATE`` answer that differs from what was commanded. ``refuses``/``silent``:
        a command answered ``ERR`` or left unanswered, the driver's last ``ALL OFF`` (its best-effort
        close, which ignores the failure) not counted.
        """
        if self.mode in ("stuck", "wrong"):
            return self.revealed
        since = self.lines_received[self._lines_at_fault :] if self.mode else []
        if since and since[-1].upper().split() == ["ALL", "OFF"]:
            since = since[:-1]
        return bool(since)
