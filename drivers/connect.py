"""One factory for every platform driver: ``open_platform("grbl", port=...)``.

The simulator's platform is built elsewhere (from a rig) and passed in as
``sim_rig``; this module never imports ``drivers.sim``.
"""

from __future__ import annotations

from typing import Callable

from drivers.platform import Platform, PlatformConnectionError

__all__ = ["DRIVERS", "open_platform"]

DRIVERS = ("sim", "grbl", "ur", "manual")


def open_platform(
    driver: str,
    *,
    port: str | None = None,
    baud: int = 115200,
    host: str | None = None,
    grbl_options: dict | None = None,
    ur_options: dict | None = None,
    ask: Callable[[str], str] | None = None,
    say: Callable[[str], None] | None = None,
    sim_rig: Platform | None = None,
    connect: bool = True,
) -> Platform:
    """Build (and by default connect) the platform named by ``driver``.

    Parameters
    ----------
    driver : {"sim", "grbl", "ur", "manual"}
    port, baud : GRBL serial device and baud rate.
    host : UR controller address.
    grbl_options, ur_options : dict, optional
        Extra fields of :class:`drivers.grbl.GrblConfig` / :class:`drivers.ur.URConfig`.
    ask, say : callables for the manual driver (``input`` / ``print`` by default).
    sim_rig : Platform, optional
        The simulator's platform object (built from a rig elsewhere).
    connect : bool
        Call ``connect()`` before returning.

    Raises
    ------
    PlatformConnectionError
        Unknown driver or missing connection option.
    """
    if driver == "sim":
        if sim_rig is None:
            raise PlatformConnectionError("the sim driver needs a simulated rig (sim_rig)")
        platform = sim_rig
    elif driver == "grbl":
        if not port:
            raise PlatformConnectionError("the grbl driver needs --port (e.g. /dev/ttyUSB0)")
        from drivers.grbl import GrblConfig, GrblPlatform

        platform = GrblPlatform(GrblConfig(port=port, baud=baud, **(grbl_options or {})))
    elif driver == "ur":
        if not host:
            raise PlatformConnectionError("the ur driver needs --host (the controller's address)")
        from drivers.ur import URConfig, URPlatform

        platform = URPlatform(URConfig(host=host, **(ur_options or {})))
    elif driver == "manual":
        from drivers.manual import ManualPlatform

        kwargs = {}
        if ask is not None:
            kwargs["ask"] = ask
        if say is not None:
            kwargs["say"] = say
        platform = ManualPlatform(**kwargs)
    else:
        raise PlatformConnectionError(f"unknown platform driver '{driver}' (choose from {', '.join(DRIVERS)})")
    if connect:
        platform.connect()
    return platform
