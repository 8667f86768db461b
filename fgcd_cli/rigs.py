"""Former home of rig opening, kept importable: the use case is :mod:`fgcd_cli.app.rig`.

Callers should import from ``fgcd_cli.app.rig`` (and ``fgcd_cli.app.scenario`` for
the option checks); these names are re-exports until every caller has moved.
"""

from fgcd_cli.app.rig import (  # noqa: F401 - re-exports
    OpenedRig,
    RigHandles,
    RigHooks,
    RigRequest,
    _recorded_guard,
    _recording,
    open_rig,
    open_sim_rig,
    opened,
    pinhole_from_intrinsics,
    undistorted,
    vse_factory_for,
)
from fgcd_cli.app.scenario import (  # noqa: F401 - re-exports
    DRIVERS,
    Driver,
    SimScenario,
    check_connection,
    check_driver,
    check_lighting,
    check_scenario,
    check_scene,
)

__all__ = [
    "DRIVERS",
    "OpenedRig",
    "SimScenario",
    "check_connection",
    "check_driver",
    "check_lighting",
    "check_scenario",
    "check_scene",
    "open_rig",
    "opened",
    "pinhole_from_intrinsics",
    "vse_factory_for",
]
