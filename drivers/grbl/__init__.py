"""GRBL v1.1 serial motion stage (XYZ gantry, optional grblHAL rotary axes A/B/C).

Modules: :mod:`~fgcd_drivers.grbl.protocol` (the serial grammar as pure functions),
:mod:`~fgcd_drivers.grbl.link` (port, reader thread, answers, status, alarms),
:mod:`~fgcd_drivers.grbl.kinematics` (flange pose <-> axis values),
:mod:`~fgcd_drivers.grbl.config` (options) and :mod:`~fgcd_drivers.grbl.platform`
(:class:`GrblPlatform`, the Platform protocol's motion API). See ``docs/hardware.md``.
"""

from __future__ import annotations

from fgcd_drivers.grbl.config import GrblConfig
from fgcd_drivers.grbl.kinematics import GrblKinematics
from fgcd_drivers.grbl.link import GrblLink
from fgcd_drivers.grbl.platform import GrblPlatform
from fgcd_drivers.grbl.protocol import ALARM_TEXT, ERROR_TEXT, GrblState, GrblStatus

__all__ = [
    "GrblKinematics", "GrblConfig", "GrblPlatform", "GrblStatus", "ERROR_TEXT", "ALARM_TEXT",
    "GrblLink", "GrblState",
]
