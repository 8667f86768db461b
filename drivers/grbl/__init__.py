"""GRBL v1.1 serial motion stage (XYZ gantry, optional grblHAL rotary axes A/B/C).

Modules: :mod:`~fgcd_drivers.grbl.protocol` (the serial grammar as pure functions),
:mod:`~fgcd_drivers.grbl.link` (port, reader thread, answers, status, alarms),
:mod:`~fgcd_drivers.grbl.kinematics` (flange pose <-> axis values),
:mod:`~fgcd_drivers.grbl.config` (options) and :mod:`~fgcd_drivers.grbl.platform`
(:class:`GrblPlatform`, the Platform protocol's motion API). See ``docs/hardware.md``, "GRBL serial stage".
"""
