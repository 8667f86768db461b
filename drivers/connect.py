"""One factory for every platform driver, ``open_platform("grbl", spec=PlatformSpec(port=...))``, and one for the lights, ``open_lights``.

The simulator's platform is built elsewhere (from a rig) and passed in as
``sim_rig``; this module never imports ``fgcd_drivers.sim``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum

from fgcd_core.platform import Platform, PlatformConnectionError
from fgcd_drivers.lights import Lights, LightsDriver, LightsSpec, ManualLights

__all__ = ["DRIVERS", "Driver", "PlatformSpec", "open_lights", "open_platform"]


class Driver(StrEnum):
    """Platform driver names (as typed after ``--driver``)."""

    SIM = "sim"
    GRBL = "grbl"
    UR = "ur"
    MANUAL = "manual"


DRIVERS = tuple(d.value for d in Driver)


@dataclass(frozen=True, kw_only=True)
class PlatformSpec:
    """How to reach a platform: everything :func:`open_platform` needs besides the driver name.

    Attributes
    ----------
    port, baud : str or None, int
        GRBL serial device and baud rate.
    host : str or None
        UR controller address.
    grbl_options, ur_options : dict, optional
        Extra fields of :class:`fgcd_drivers.grbl.GrblConfig` / :class:`fgcd_drivers.ur.URConfig`.
    ask, say : callables, optional
        For the manual driver (``input`` / ``print`` by default).
    sim_rig : Platform, optional
        The simulator's platform object (built from a rig elsewhere).
    connect : bool
        Call ``connect()`` before returning.
    """

    port: str | None = None
    baud: int = 115200
    host: str | None = None
    grbl_options: dict | None = None
    ur_options: dict | None = None
    ask: Callable[[str], str] | None = None
    say: Callable[[str], None] | None = None
    sim_rig: Platform | None = None
    connect: bool = True


def open_platform(driver: str, *, spec: PlatformSpec | None = None) -> Platform:
    """Build (and by default connect) the platform named by ``driver``.

    Parameters
    ----------
    driver : {"sim", "grbl", "ur", "manual"}
    spec : PlatformSpec, optional
        Connection options (default: :class:`PlatformSpec`, which connects).

    Raises
    ------
    PlatformConnectionError
        Unknown driver or missing connection option.
    """
    spec = spec or PlatformSpec()
    platform = _build(driver, spec)
    if spec.connect:
        platform.connect()
    return platform


def _build(driver: str, spec: PlatformSpec) -> Platform:
    if driver == Driver.SIM:
        if spec.sim_rig is None:
            raise PlatformConnectionError("the sim driver needs a simulated rig (sim_rig)")
        return spec.sim_rig
    if driver == Driver.GRBL:
        if not spec.port:
            raise PlatformConnectionError("the grbl driver needs --port (e.g. /dev/ttyUSB0)")
        from fgcd_drivers.grbl.config import GrblConfig
        from fgcd_drivers.grbl.platform import GrblPlatform

        return GrblPlatform(GrblConfig(port=spec.port, baud=spec.baud, **(spec.grbl_options or {})))
    if driver == Driver.UR:
        if not spec.host:
            raise PlatformConnectionError("the ur driver needs --host (the controller's address)")
        from fgcd_drivers.ur import URConfig, URPlatform

        return URPlatform(URConfig(host=spec.host, **(spec.ur_options or {})))
    if driver == Driver.MANUAL:
        from fgcd_drivers.manual import ManualPlatform

        kwargs = {}
        if spec.ask is not None:
            kwargs["ask"] = spec.ask
        if spec.say is not None:
            kwargs["say"] = spec.say
        return ManualPlatform(**kwargs)
    raise PlatformConnectionError(f"unknown platform driver '{driver}' (choose from {', '.join(DRIVERS)})")


def open_lights(spec: LightsSpec, *, platform=None, ask: Callable[[str], str] = input) -> Lights:
    """Open the lights ``spec`` names (``platform``: an open GRBL platform on the same port, shared).

    Raises
    ------
    PlatformConnectionError
        A driver without its port, or a controller that does not answer.
    """
    if spec.driver == LightsDriver.MANUAL:
        return ManualLights(list(spec.channels), ask=ask)
    if spec.driver == LightsDriver.GRBL:
        from fgcd_drivers.lights_grbl import GrblLights

        return GrblLights.open(spec, platform=platform)
    if spec.driver == LightsDriver.SERIAL:
        from fgcd_drivers.lights_serial import SerialLights

        return SerialLights.open(spec)
    raise PlatformConnectionError(f"the '{spec.driver}' lights belong to the simulator's rig")
