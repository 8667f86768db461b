"""The line interpreter of the GRBL emulator: ``$`` system commands, jogging and G-code.

GRBL 1.1 grammar (``doc/markdown/interface.md``): one ``ok`` or ``error:N`` per
line; ``$$ $I $G $X $H $C $J= $N=value``; ``G0/G1/G4/G90/G91/G21`` with ``F``
and axes ``X Y Z`` (optionally ``A B C``). :class:`GrblCommandsMixin` runs on the
state of :class:`fgcd_drivers.testing.grbl_emulator.GrblEmulator`.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass

__all__ = ["BANNER", "GrblCommandsMixin", "Segment", "parse_words"]

BANNER = "Grbl 1.1h ['$' for help]"
_WORD = re.compile(r"([A-Z])([-+]?(?:\d+\.?\d*|\.\d+))")


@dataclass
class Segment:
    """One planned motion (or dwell) of the emulated planner; mm or degrees per axis."""

    start_mm: list[float]
    end_mm: list[float]
    feed_mm_min: float
    jog: bool = False
    dwell_s: float = 0.0
    elapsed_s: float = 0.0

    @property
    def duration_s(self) -> float:
        if self.dwell_s:
            return self.dwell_s
        dist = sum((e - s) ** 2 for s, e in zip(self.start_mm, self.end_mm)) ** 0.5
        return dist / (self.feed_mm_min / 60.0) if dist > 0 else 0.0


def parse_words(text: str) -> list[tuple[str, float]] | str:
    """G-code words ``[(letter, value), ...]`` of a line without spaces, or ``error:1``/``error:2``."""
    pos = 0
    words = []
    for m in _WORD.finditer(text):
        if m.start() != pos:
            return "error:1" if text[pos].isalpha() is False else "error:2"
        words.append((m.group(1), float(m.group(2))))
        pos = m.end()
    if pos != len(text):
        rest = text[pos:]
        return "error:2" if rest[0].isalpha() else "error:1"
    return words


class GrblCommandsMixin:
    """Line commands of :class:`~fgcd_drivers.testing.grbl_emulator.GrblEmulator` (state, locks and
    ``_send``/``_enqueue``/``_enter_alarm``/``_realtime`` live there)."""

    def _execute(self, line: str) -> str | None:
        text = line.upper().replace(" ", "")
        if text.startswith("$"):
            return self._system(text)
        with self._lock:
            if self.state == "Alarm":
                return "error:9"
        return self._gcode(text)

    def _system(self, text: str) -> str | None:
        if text == "$$":
            with self._lock:
                for key in sorted(self.settings):
                    value = self.settings[key]
                    shown = f"{value:.3f}" if isinstance(value, float) else str(int(value))
                    self._send(f"${key}={shown}")
            return "ok"
        if text == "$I":
            self._send("[VER:1.1h.20190825:]")
            self._send("[OPT:V,15,128]")
            return "ok"
        if text == "$G":
            mode = "G90" if self.absolute else "G91"
            coolant = " ".join(w for w, on in (("M7", self.mist), ("M8", self.flood)) if on) or "M9"
            self._send(
                f"[GC:G0 G54 G17 G21 {mode} G94 {self.spindle} {coolant} T0 F{self.feed_mm_min or 0:.0f} "
                f"S{self.spindle_speed:g}]"
            )
            return "ok"
        if text == "$X":
            with self._lock:
                if self.state == "Alarm":
                    self.state = "Idle"
                    self.alarm_code = None
                    self._send("[MSG:Caution: Unlocked]")
            return "ok"
        if text == "$H":
            with self._lock:
                if not self.settings[22]:
                    return "error:5"
                if self.state not in ("Idle", "Alarm"):
                    return "error:8"
                self.state = "Home"
                start = list(self.mpos)
            # Homing: travel to the switches at the seek rate, then pull off to 0.
            dist = max(abs(v) for v in start) if start else 0.0
            time.sleep(min(2.0, dist / (self.settings[25] / 60.0)) * self.time_scale)
            with self._lock:
                if self.state != "Home":
                    return None
                self.mpos = [0.0] * len(self.axes)
                self.state = "Idle"
                self.alarm_code = None
            return "ok"
        if text == "$C":
            with self._lock:
                if self.state not in ("Idle", "Alarm") or self.current or self.queue:
                    return "error:8"
                self.check_mode = not self.check_mode
                if self.check_mode:
                    self._send("[MSG:Enabled]")
                    return "ok"
            # Leaving check mode soft-resets GRBL.
            self._send("[MSG:Disabled]")
            self._send("ok")
            self._realtime(0x18)
            return None
        if text.startswith("$J="):
            return self._jog(text[3:])
        match = re.fullmatch(r"\$(\d+)=([-+]?\d*\.?\d+)", text)
        if match:
            key = int(match.group(1))
            with self._lock:
                if self.state not in ("Idle", "Alarm"):
                    return "error:8"
                if key not in self.settings:
                    return "error:3"
                self.settings[key] = float(match.group(2)) if "." in match.group(2) else int(match.group(2))
            return "ok"
        return "error:3"

    def _jog(self, text: str) -> str:
        words = parse_words(text)
        if isinstance(words, str):
            return words
        with self._lock:
            if self.state not in ("Idle", "Jog"):
                return "error:8"
            target = self._planned_end()
            absolute = self.absolute
            feed = None
            for letter, value in words:
                if letter == "G" and value in (90.0, 91.0):
                    absolute = value == 90.0
                elif letter == "G" and value in (20.0, 21.0, 53.0):
                    continue
                elif letter == "F":
                    feed = value
                elif letter in self.axes:
                    i = self.axes.index(letter)
                    target[i] = value if absolute else target[i] + value
                else:
                    return "error:16"
            if feed is None:
                return "error:22"
            if self.settings[20] and not self._within_travel(target):
                return "error:15"
            if self.check_mode:
                return "ok"
            seg = Segment(self._planned_end(), target, min(feed, self.settings[110]), jog=True)
        return self._enqueue(seg)

    def _gcode(self, text: str) -> str | None:
        words = parse_words(text)
        if isinstance(words, str):
            return words
        words, accessories = _split_accessories(words)
        if accessories:
            reply = self._accessories(accessories)
            if reply != "ok" or not words:
                return reply
        motion = None
        dwell = None
        axis_values: dict[int, float] = {}
        with self._lock:
            absolute = self.absolute
            feed = self.feed_mm_min
            for letter, value in words:
                if letter == "G":
                    if value in (0.0, 1.0):
                        motion = int(value)
                    elif value == 4.0:
                        dwell = 0.0
                    elif value in (90.0, 91.0):
                        absolute = value == 90.0
                    elif value in (17.0, 21.0, 54.0, 94.0):
                        continue
                    else:
                        return "error:20"
                elif letter == "M" and value in (0.0, 2.0, 30.0):
                    continue
                elif letter == "F":
                    feed = value
                elif letter == "P" and dwell is not None:
                    dwell = value
                elif letter in self.axes:
                    axis_values[self.axes.index(letter)] = value
                else:
                    return "error:20"
            self.absolute = absolute
            self.feed_mm_min = feed
            if dwell is not None:
                pass
            elif axis_values:
                motion = 0 if motion is None else motion
                if motion == 1 and not feed:
                    return "error:22"
                start = self._planned_end()
                target = list(start)
                for i, v in axis_values.items():
                    target[i] = v if absolute else target[i] + v
                if self.settings[20] and not self._within_travel(target):
                    if self.check_mode:
                        return "error:15"
                    # GRBL: a soft-limit violation of a G-code motion is an alarm.
                    self._enter_alarm(2)
                    return None
                if self.check_mode:
                    return "ok"
                rate = self.settings[110] if motion == 0 else min(feed, self.settings[110])
                seg = Segment(start, target, rate)
            else:
                return "ok"
        if dwell is not None:
            if self.check_mode:
                return "ok"
            # G4 waits for the planner to empty, then dwells: its ok marks arrival.
            while not self._stop.is_set():
                with self._lock:
                    if self.state == "Alarm":
                        return "error:9"
                    if self.current is None and not self.queue:
                        break
                time.sleep(0.005)
            time.sleep(dwell * self.time_scale)
            return "ok"
        return self._enqueue(seg)

    def _accessories(self, words: list[tuple[str, float]]) -> str:
        """Spindle (M3/M4/M5, S) and coolant (M7/M8/M9) words: applied once the planner is empty (GRBL syncs them)."""
        for letter, value in words:
            if letter == "M" and value not in (3.0, 4.0, 5.0, 7.0, 8.0, 9.0):
                return "error:20"
            if letter == "S" and value < 0:
                return "error:4"
        if self.check_mode:
            return "ok"
        while not self._stop.is_set():
            with self._lock:
                if self.state == "Alarm":
                    return "error:9"
                if self.current is None and not self.queue:
                    for letter, value in words:
                        self._apply_accessory(letter, value)
                    return "ok"
            time.sleep(0.005)
        return "ok"

    def _apply_accessory(self, letter: str, value: float) -> None:
        if letter == "S":
            self.spindle_speed = value
        elif value in (3.0, 4.0, 5.0):
            self.spindle = f"M{value:g}"
        elif value == 7.0:
            self.mist = True
        elif value == 8.0:
            self.flood = True
        elif value == 9.0:
            self.mist = self.flood = False


def _split_accessories(words: list[tuple[str, float]]) -> tuple[list, list]:
    """``(other words, spindle and coolant words)`` of a G-code line."""
    accessory = [
        (letter, v) for letter, v in words if letter == "S" or (letter == "M" and v in (3.0, 4.0, 5.0, 7.0, 8.0, 9.0))
    ]
    return [w for w in words if w not in accessory], accessory
