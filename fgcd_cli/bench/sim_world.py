"""The simulated world a bench runs in: ``fgcd bench --world NAME`` (docs/simulator.md, "Appearance").

The world is a property of the whole process (``$FGCD_SIM_WORLD``, read by
:func:`fgcd_drivers.sim.appearance.world_appearance`), so that every renderer a
bench builds, in this process or in the workers it starts, renders the same one.
"""

from __future__ import annotations

import os

from fgcd_drivers.sim.appearance import WORLD_ENV, world_appearance

__all__ = ["select_world", "current_world"]


def select_world(name: str | None) -> str:
    """Make ``name`` the world of this process and its children (None: keep the current one); its name.

    Raises
    ------
    ValueError
        For a name that is not a world.
    """
    if name is not None:
        world_appearance(name)  # validates
        os.environ[WORLD_ENV] = name
    return current_world()


def current_world() -> str:
    """The name of the world this process renders."""
    return world_appearance().name
