"""GRBL v1.1 serial motion stage (XYZ gantry, optional grblHAL rotary axes A/B/C).

Modules: :mod:`~drivers.grbl.protocol` (the serial grammar as pure functions),
:mod:`~drivers.grbl.link` (port, reader thread, answers, status, alarms),
:mod:`~drivers.grbl.kinematics` (flange pose <-> axis values),
:mod:`~drivers.grbl.config` (options) and :mod:`~drivers.grbl.platform`
(:class:`GrblPlatform`, the Platform protocol's motion API). See ``docs/hardware.md``.
"""

from __future__ import annotations

from drivers.grbl.config import GrblConfig
from drivers.grbl.kinematics import GrblKinematics
from drivers.grbl.link import GrblLink
from drivers.grbl.platform import GrblPlatform
from drivers.grbl.protocol import ALARM_TEXT, ERROR_TEXT, GrblState, GrblStatus

__all__ = [
    "GrblKinematics", "GrblConfig", "GrblPlatform", "GrblStatus", "ERROR_TEXT", "ALARM_TEXT",
    "GrblLink", "GrblState",
]
