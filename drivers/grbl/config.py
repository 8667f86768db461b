"""Connection and motion options of a GRBL stage."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from fgcd_drivers.grbl.kinematics import GrblKinematics

__all__ = ["GrblConfig"]


@dataclass(frozen=True, kw_only=True)
class GrblConfig:
    """Connection and motion options of a GRBL stage.

    Attributes
    ----------
    port : str
        Serial device, e.g. ``/dev/ttyUSB0`` (or any pyserial URL).
    baud : int
        115200 for GRBL 1.1.
    kinematics : GrblKinematics
        Flange pose <-> axes mapping.
    answer_timeout_s : float
        Longest wait for the ``ok``/``error`` of one line.
    banner_timeout_s : float
        Longest wait for the banner in all, from opening the port, the soft
        reset included (the time a missing banner's error states).
    open_banner_wait_s : float
        Part of that wait spent on the banner a board prints when opening the
        port resets it (DTR), at most 80 % of ``banner_timeout_s``; without a
        banner by then the driver sends a soft reset and waits the rest.
    arrival_margin_s : float
        Extra time allowed beyond the nominal motion time before a move times out.
    homing_timeout_s : float
        Longest ``$H``.
    poll_hz : float
        Status polling rate while waiting for arrival (GRBL advises <= 5 Hz).
    max_linear_speed_m_s : float or None
        Cap on the feed; None uses the stage's ``$110`` max rate.
    max_angular_speed_rad_s : float
        Cap on rotary feed.
    workspace_min_mm, workspace_max_mm : tuple or None
        Machine travel box of the linear axes (MPos, mm); None derives it from
        ``$130..$132`` with GRBL's homing convention ``[-travel, 0]``.
    arrival_tolerance_mm : float
        Distance between reported and commanded MPos counted as arrived.
    report_axes : str
        Axis letters in the order the controller reports them in ``MPos`` and
        numbers them in settings (``$110+i``): GRBL ``XYZ``, grblHAL ``XYZABC``
        or a custom order such as ``XYZC``.
    """

    port: str
    baud: int = 115200
    kinematics: GrblKinematics = field(default_factory=GrblKinematics)
    answer_timeout_s: float = 5.0
    banner_timeout_s: float = 2.5
    open_banner_wait_s: float = 2.0
    arrival_margin_s: float = 5.0
    homing_timeout_s: float = 90.0
    poll_hz: float = 5.0
    max_linear_speed_m_s: float | None = 0.02
    max_angular_speed_rad_s: float = math.radians(30.0)
    workspace_min_mm: tuple[float, float, float] | None = None
    workspace_max_mm: tuple[float, float, float] | None = None
    arrival_tolerance_mm: float = 0.01
    report_axes: str = "XYZABC"
