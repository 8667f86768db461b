"""The options of a rig checked before anything is opened: driver, connection, simulated world and lighting.

Every check raises UserInputError naming the valid values; nothing is created,
opened or moved by them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from fgcd_cli.errors import UserInputError
from fgcd_drivers.connect import DRIVERS

__all__ = [
    "check_method",
    "SimScenario",
    "check_connection",
    "check_driver",
    "check_lighting",
    "check_scenario",
    "check_scene",
]


@dataclass(frozen=True, kw_only=True)
class SimScenario:
    """How the simulated world of a session differs from the reference one.

    Attributes
    ----------
    scene : str
        Scene name (``fgcd sim scenes``).
    seed : int
        World seed: same seed, same object and same hidden hand-eye.
    lighting : str
        Lighting preset of this session.
    changes : int
        Number of fine-grained changes injected (0 for the reference).
    change_size_mm : (float, float)
        Size range of the injected changes, millimetres.
    change_seed : int
        Seed of the changes.
    start_offset_mm, start_offset_deg : float
        How far from the reference the platform starts (the rig was set up
        again); a random direction drawn from ``session_seed``.
    session_seed : int
        Seed of this session's start offset and noise.
    noise : str
        Platform noise preset.
    """

    scene: str = "stele"
    seed: int = 0
    lighting: str = "front"
    changes: int = 0
    change_seed: int = 1
    change_size_mm: tuple[float, float] = (1.0, 20.0)
    start_offset_mm: float = 0.0
    start_offset_deg: float = 0.0
    session_seed: int = 0
    noise: str = "default"


def check_driver(driver: str) -> str:
    """``driver`` if it is one of :data:`DRIVERS`; UserInputError naming them otherwise."""
    if driver not in DRIVERS:
        raise UserInputError(f"unknown driver '{driver}' (choose from {', '.join(DRIVERS)})")
    return driver


def check_connection(driver: str, *, port: str | None, host: str | None) -> None:
    """Refuse a hardware driver without the address it needs (UserInputError, before anything is opened).

    Rule: the address a driver needs is an option the user forgot, not a
    hardware fault (the same rule as ``fgcd platform``).
    """
    if driver == "grbl" and not port:
        raise UserInputError("the grbl driver needs --port (e.g. --port /dev/ttyUSB0, or port in campaign.toml [rig])")
    if driver == "ur" and not host:
        raise UserInputError(
            "the ur driver needs --host (the controller's address, e.g. --host 192.168.0.10, "
            "or host in campaign.toml [rig])"
        )


def check_scene(scene: str) -> str:
    """``scene`` if the simulator has it; UserInputError naming the known scenes otherwise."""
    from fgcd_drivers.sim.scenes import SceneNotFound, scene_spec

    try:
        scene_spec(scene)
    except SceneNotFound:
        from fgcd_drivers.sim.scenes import list_scenes

        known = ", ".join(s.name for s in list_scenes()) or "none"
        raise UserInputError(f"unknown scene '{scene}' (choose from {known}; `fgcd sim scenes`)") from None
    except (OSError, ValueError) as exc:
        raise UserInputError(f"scene '{scene}' cannot be read: {exc}") from None
    return scene


def check_lighting(name: str, *, option: str = "--light") -> str:
    """The canonical name of a simulator lighting preset; UserInputError naming the valid ones otherwise."""
    from fgcd_drivers.sim.lights import lighting_preset, list_lighting_presets

    try:
        return lighting_preset(name).name
    except ValueError as exc:
        # the parametrised presets are listed by their pattern, not by an example
        fixed = [n for n, _ in list_lighting_presets() if ":" not in n and n != "front"]
        known = ", ".join(["front", "led:H (H = 1..12)", "sun:az=A,el=E", "sun:day=D,hour=H", *fixed])
        reason = str(exc).split(";")[0]
        raise UserInputError(f"{option}: {reason} (valid: {known}; `fgcd sim lights`)") from None


def check_scenario(scenario: SimScenario) -> SimScenario:
    """``scenario`` with its lighting's canonical name, once every value is valid (UserInputError otherwise)."""
    check_scene(scenario.scene)
    lighting = check_lighting(scenario.lighting)
    if scenario.changes < 0:
        raise UserInputError(f"--changes must be 0 or more, got {scenario.changes}")
    for option, value in (
        ("--start-offset-mm", scenario.start_offset_mm),
        ("--start-offset-deg", scenario.start_offset_deg),
    ):
        if not math.isfinite(value) or value < 0:
            raise UserInputError(f"{option} must be a finite number >= 0, got {value}")
    lo, hi = scenario.change_size_mm
    if not (0 < lo <= hi and math.isfinite(hi)):
        raise UserInputError(f"change sizes must satisfy 0 < min <= max mm, got {lo}, {hi}")
    return replace(scenario, lighting=lighting)


def check_method(method: str):
    """The relocation method named by ``--method`` (UserInputError naming the valid ones)."""
    from fgcd_cli.relocation.enums import RelocationMethod

    try:
        return RelocationMethod(method)
    except ValueError:
        raise UserInputError(f"--method must be one of {', '.join(RelocationMethod)}, got {method!r}") from None
