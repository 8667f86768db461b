"""A serial light controller (the protocol of :mod:`fgcd_drivers.lights_serial`) emulated on a pseudo-terminal.

The driver opens :attr:`LightControllerEmulator.port` as it would open
``/dev/ttyACM0``. :attr:`relays_on` is what the relay board drives; faults on
demand: :meth:`set_silent` (a hung controller).
"""

from __future__ import annotations

import os
import pty
import select
import threading
import tty

__all__ = ["LightControllerEmulator"]


class LightControllerEmulator:
    """``n_relays`` relays behind the light line protocol on a pty."""

    def __init__(self, *, n_relays: int = 8) -> None:
        self.n_relays = n_relays
        self.relays_on: set[int] = set()
        self.lines_received: list[str] = []
        self.silent = False
        self._stop = threading.Event()
        self._master, self._slave = pty.openpty()
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)
        self._thread = threading.Thread(target=self._serve, name="lights-emu", daemon=True)
        self._thread.start()

    def set_silent(self, silent: bool = True) -> None:
        """Stop answering (the controller hangs)."""
        self.silent = silent

    def close(self) -> None:
        """Stop serving and close the pty."""
        self._stop.set()
        self._thread.join(timeout=1.0)
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> LightControllerEmulator:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _serve(self) -> None:
        buffer = bytearray()
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self._master], [], [], 0.05)
                if not ready:
                    continue
                chunk = os.read(self._master, 256)
            except (OSError, ValueError):
                return
            buffer.extend(chunk)
            while b"\n" in buffer:
                raw, _, rest = bytes(buffer).partition(b"\n")
                buffer[:] = rest
                line = raw.decode("ascii", errors="replace").strip()
                if not line:
                    continue
                self.lines_received.append(line)
                if not self.silent:
                    os.write(self._master, (self.answer(line) + "\n").encode("ascii"))

    def answer(self, line: str) -> str:
        """The controller's answer to one command line (and its effect on the relays)."""
        words = line.upper().split()
        if words == ["ID"]:
            return f"LIGHTS {self.n_relays}"
        if words == ["STATE"]:
            return "STATE " + (",".join(str(k) for k in sorted(self.relays_on)) or "-")
        if words == ["ALL", "OFF"]:
            self.relays_on.clear()
            return "OK"
        if len(words) == 2 and words[0] in ("ON", "OFF") and words[1].isdigit():
            k = int(words[1])
            if not 1 <= k <= self.n_relays:
                return f"ERR no relay {k}"
            (self.relays_on.add if words[0] == "ON" else self.relays_on.discard)(k)
            return "OK"
        return "ERR unknown command"
