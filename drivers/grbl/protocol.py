"""GRBL 1.1 serial grammar as pure functions on strings (no I/O).

Facts from GRBL's ``doc/markdown/interface.md``: every line gets exactly one
``ok`` or ``error:N``; status reports are ``<State[:sub]|MPos:...|FS:...>``;
``ALARM:N`` and the ``Alarm`` state are safety stops; ``[...]`` lines are
messages; ``$N=value`` lines are settings; the banner starts with ``Grbl ``.
Real-time bytes (``?``, ``!``, ``0x85``, ``0x18``) are never acknowledged.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from enum import StrEnum

__all__ = [
    "ERROR_TEXT",
    "ALARM_TEXT",
    "ERROR_LOCKED",
    "GrblState",
    "GrblStatus",
    "LineKind",
    "STATUS_QUERY",
    "FEED_HOLD_JOG_CANCEL",
    "SOFT_RESET",
    "decode_line",
    "classify_line",
    "parse_status",
    "parse_setting",
    "parse_code",
    "alarm_text",
    "error_text",
]

#: GRBL 1.1 error codes (``doc/csv/error_codes_en_US.csv``), the ones a person may meet.
ERROR_TEXT = {
    1: "expected command letter",
    2: "bad number format",
    3: "invalid '$' statement",
    4: "negative value",
    5: "homing is not enabled ($22)",
    8: "command needs the controller idle",
    9: "locked by an alarm or a jog (unlock with $X or home with $H)",
    10: "soft limits need homing enabled",
    15: "jog target exceeds the machine travel",
    16: "invalid jog command",
    20: "unsupported or invalid G-code command",
    22: "feed rate not set",
    33: "invalid motion target",
}
#: GRBL 1.1 alarm codes (``doc/csv/alarm_codes_en_US.csv``).
ALARM_TEXT = {
    1: "hard limit triggered",
    2: "soft limit: target outside the machine travel",
    3: "reset while in motion, position may be lost",
    4: "probe fail",
    5: "probe fail",
    6: "homing fail: reset during homing",
    7: "homing fail: safety door opened during homing",
    8: "homing fail: could not clear the limit switch",
    9: "homing fail: limit switch not found",
    10: "homing fail: second switch not found",
}
#: ``error:9``: the controller is locked (by an alarm or a jog).
ERROR_LOCKED = 9

#: Real-time bytes (never acknowledged by GRBL).
STATUS_QUERY = b"?"
FEED_HOLD_JOG_CANCEL = b"!\x85"
SOFT_RESET = b"\x18"

_STATUS = re.compile(r"^<([A-Za-z]+)(?::(\d+))?\|(.*)>$")
_ANSWER = re.compile(r"ok|error:\d+")
_ALARM = re.compile(r"ALARM:\d+")
_SETTING = re.compile(r"\$\d+=[-+]?\d*\.?\d+")


class GrblState(StrEnum):
    """Machine states of a GRBL 1.1 status report (values as GRBL spells them)."""

    IDLE = "Idle"
    RUN = "Run"
    HOLD = "Hold"
    JOG = "Jog"
    ALARM = "Alarm"
    DOOR = "Door"
    CHECK = "Check"
    HOME = "Home"
    SLEEP = "Sleep"


class LineKind(StrEnum):
    """What a received line is."""

    EMPTY = "empty"
    ANSWER = "answer"
    STATUS = "status"
    ALARM = "alarm"
    BANNER = "banner"
    MESSAGE = "message"
    SETTING = "setting"
    NOISE = "noise"


@dataclass(frozen=True, kw_only=True)
class GrblStatus:
    """One parsed status report."""

    state: str
    substate: int | None
    mpos: dict[str, float]
    feed_mm_min: float
    received_at: float


def decode_line(raw: bytes) -> str | None:
    """The stripped ASCII text of one received line, or None when it is not ASCII (noise)."""
    try:
        return raw.decode("ascii").strip()
    except UnicodeDecodeError:
        return None


def classify_line(line: str) -> LineKind:
    """Sort a stripped line into answers, status reports, alarms, banner, messages, settings or noise."""
    if not line:
        return LineKind.EMPTY
    if _ANSWER.fullmatch(line):
        return LineKind.ANSWER
    if line.startswith("<") and line.endswith(">"):
        return LineKind.STATUS
    if _ALARM.fullmatch(line):
        return LineKind.ALARM
    if line.startswith("Grbl "):
        return LineKind.BANNER
    if line.startswith("[") and line.endswith("]"):
        return LineKind.MESSAGE
    if _SETTING.fullmatch(line):
        return LineKind.SETTING
    return LineKind.NOISE


def parse_code(line: str) -> int:
    """The number N of ``error:N`` or ``ALARM:N``."""
    return int(line.split(":")[1])


def parse_setting(line: str) -> tuple[int, float]:
    """``$N=value`` -> ``(N, value)``."""
    key, value = line[1:].split("=")
    return int(key), float(value)


def parse_status(
    line: str, report_axes: str, wco: dict[str, float], *, received_at: float
) -> tuple[GrblStatus | None, dict[str, float]]:
    """Parse a status report.

    Parameters
    ----------
    line : str
        ``<State[:sub]|MPos:x,y,...|FS:feed,speed|WCO:...>``.
    report_axes : str
        Axis letters in the order of the reported coordinates.
    wco : dict letter -> mm
        The last work coordinate offset (a report carries ``WCO`` only now and then).
    received_at : float
        Monotonic arrival time.

    Returns
    -------
    status : GrblStatus or None
        None when the report is malformed or has neither ``MPos`` nor ``WPos``.
    wco : dict letter -> mm
        The offset to keep (updated when the report carries one). With ``$10``
        set to report ``WPos``: MPos = WPos + WCO.
    """
    match = _STATUS.match(line)
    if not match:
        return None, wco
    fields = dict(part.split(":", 1) for part in match.group(3).split("|") if ":" in part)
    letters = report_axes
    try:
        if "WCO" in fields:
            values = [float(v) for v in fields["WCO"].split(",")]
            wco = {letters[i]: v for i, v in enumerate(values)}
        if "MPos" in fields:
            values = [float(v) for v in fields["MPos"].split(",")]
            mpos = {letters[i]: v for i, v in enumerate(values)}
        elif "WPos" in fields:
            values = [float(v) for v in fields["WPos"].split(",")]
            mpos = {letters[i]: v + wco.get(letters[i], 0.0) for i, v in enumerate(values)}
        else:
            return None, wco
        feed = float(fields.get("FS", fields.get("F", "0")).split(",")[0])
    except (ValueError, IndexError):
        return None, wco
    sub = match.group(2)
    status = GrblStatus(
        state=match.group(1),
        substate=int(sub) if sub is not None else None,
        mpos=mpos,
        feed_mm_min=feed,
        received_at=received_at,
    )
    return status, wco


def alarm_text(code: int | None) -> str:
    """The message of a safety stop: ``ALARM:N`` with its meaning, or the bare ``Alarm`` state (code 0/None)."""
    what = ALARM_TEXT.get(code, "alarm state") if code else "alarm state"
    label = f"ALARM:{code}" if code else "Alarm"
    return f"GRBL {label} ({what}); check the stage, then 'fgcd platform home' or unlock ($X)"


def error_text(code: int) -> str:
    """The meaning of ``error:N``."""
    return ERROR_TEXT.get(code, "see the GRBL error table")
