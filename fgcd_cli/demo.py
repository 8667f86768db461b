"""Former home of the demo use case, kept importable: it is :mod:`fgcd_cli.app.demo` (``fgcd demo``)."""

from fgcd_cli.app.demo import (  # noqa: F401 - re-exports
    DemoConfig,
    calibrate_sim_handeye,
    calibrate_sim_intrinsics,
    change_ids_in_reference,
    count_changes_found,
    run_demo,
)

__all__ = ["DemoConfig", "count_changes_found", "run_demo"]
