"""A simulated rig whose platform is a real driver: GRBL on its pty emulator, or UR on the fake controller.

Bench-only test harness of ``fgcd bench faults`` (docs/hardware.md, "Testing
without hardware"). The simulated world stays the camera and the scene; every
guarded motion goes, through the MotionGuard, to the real driver
(:class:`fgcd_drivers.grbl.GrblPlatform`, :class:`fgcd_drivers.ur.URPlatform`),
and the simulated camera is rendered at the pose the *driver reports*
(read back from the emulator, never the commanded one).

Frames: the driver's base frame and the simulated platform's base frame are
tied at connect time, the driver's pose then standing for the simulated home
(:class:`FrameMap`). A GRBL stage is an XYZ stage: its rig is the 3-DoF
simulated rig (``SimRigConfig(dof=3)``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fgcd_core.se3 import invert_pose

__all__ = [
    "ENV_LOG",
    "ENV_TARGET",
    "FrameMap",
    "WiredPlatform",
    "inner_workspace",
    "install_wired_rig",
    "open_driver",
    "parse_target",
]

#: ``grbl:/dev/pts/N`` or ``ur:127.0.0.1``: the driver the launcher wires in.
ENV_TARGET = "FGCD_BENCH_WIRED"
#: A file the wired platform appends one JSON line to before each motion (index, phase), for the injector.
ENV_LOG = "FGCD_BENCH_WIRED_LOG"
#: Linear speed cap of the wired drivers, m/s: the simulated stage's pace order (6.7 mm/s) rather than an
#: industrial arm's, so that a 5 mm sub-step lasts long enough to be hit while it moves (docs/hardware.md,
#: "Faults in the field").
WIRED_SPEED_M_S = 0.02


@dataclass(frozen=True)
class FrameMap:
    """The fixed transform between the driver's base frame and the simulated platform's base frame.

    ``T_sim_driver`` takes a pose in the driver's base frame to the simulated base frame:
    ``T_sim_flange = T_sim_driver @ T_driver_flange``.
    """

    T_sim_driver: np.ndarray

    @classmethod
    def at_connect(cls, T_sim_home: np.ndarray, T_driver_home: np.ndarray) -> FrameMap:
        """The map that makes the driver's pose at connect the simulated home pose."""
        return cls(np.asarray(T_sim_home, float) @ invert_pose(np.asarray(T_driver_home, float)))

    def to_sim(self, T_driver_flange: np.ndarray) -> np.ndarray:
        """A driver-frame flange pose in the simulated base frame."""
        return self.T_sim_driver @ np.asarray(T_driver_flange, float)

    def to_driver(self, T_sim_flange: np.ndarray) -> np.ndarray:
        """A simulated-frame flange pose in the driver's base frame."""
        return invert_pose(self.T_sim_driver) @ np.asarray(T_sim_flange, float)


def inner_workspace(caps, T_driver_home: np.ndarray, T_sim_home: np.ndarray, sim_min, sim_max):
    """``(lo, hi)``: a box around the simulated home whose every point the driver can reach.

    Rule: the base frames are rotated against each other, so the driver's travel
    box seen from the simulated frame is a rotated box; the cube of half-size
    ``r / sqrt(3)`` (``r``: the home's distance to the nearest face of the driver's
    box) fits inside it whatever the rotation. It is intersected with the
    simulated platform's own box.
    """
    p = np.asarray(T_driver_home, float)[:3, 3]
    r = float(min(np.min(p - np.asarray(caps.workspace_min_m)), np.min(np.asarray(caps.workspace_max_m) - p)))
    half = max(r, 0.0) / math.sqrt(3.0)
    h = np.asarray(T_sim_home, float)[:3, 3]
    lo = np.maximum(h - half, np.asarray(sim_min, float))
    hi = np.minimum(h + half, np.asarray(sim_max, float))
    return lo, hi


def _phase() -> str:
    """Which stage of the operation asked for the motion: ``exploration`` (VseSession.explore) or ``adjustment``."""
    frame = sys._getframe(2)
    while frame is not None:
        if frame.f_code.co_name == "explore":
            return "exploration"
        if frame.f_code.co_name == "capture_reference":
            return "capture"
        frame = frame.f_back
    return "adjustment"


class WiredPlatform:
    """The simulated platform's seat in a rig, taken by a real driver.

    Parameters
    ----------
    sim : fgcd_drivers.sim.platform.SimPlatform
        The simulated platform (its home, workspace and clock; its own motions are never used).
    driver : Platform
        The real driver (not yet connected).
    log : Path or None
        Where each motion is announced (:data:`ENV_LOG`).
    """

    def __init__(self, sim, driver, *, log: Path | None = None) -> None:
        self.sim = sim
        self.driver = driver
        self.name = sim.name  # the campaign's rig is the simulator's: its records say sim
        self.clock = sim.clock
        self.map: FrameMap | None = None
        self._home_driver: np.ndarray | None = None
        self._last = sim.true_flange_pose()
        self._log = log
        self._moves = 0
        self._lock = threading.Lock()

    # ------------------------------------------------------------------ Platform
    def connect(self) -> None:
        """Connect the driver and tie its frame to the simulated home."""
        self.driver.connect()
        self._home_driver = np.asarray(self.driver.flange_pose(), float)
        self.map = FrameMap.at_connect(self.sim.T_base_flange_home, self._home_driver)
        self._last = self.map.to_sim(self._home_driver)

    def capabilities(self):
        """The driver's capabilities, its workspace seen from the simulated frame (:func:`inner_workspace`)."""
        caps = self.driver.capabilities()
        own = self.sim.capabilities()
        lo, hi = inner_workspace(
            caps, self._home_driver, self.sim.T_base_flange_home, own.workspace_min_m, own.workspace_max_m
        )
        return dataclasses.replace(
            caps, workspace_min_m=tuple(float(v) for v in lo), workspace_max_m=tuple(float(v) for v in hi)
        )

    def flange_pose(self) -> np.ndarray:
        """The driver's reported pose, in the simulated frame."""
        T = self.map.to_sim(self.driver.flange_pose())
        self._last = T
        return T.copy()

    def move_to(self, T_base_flange: np.ndarray, *, speed_fraction: float = 1.0):
        """Send the motion to the driver; the result's poses in the simulated frame."""
        self._announce()
        result = self.driver.move_to(self.map.to_driver(T_base_flange), speed_fraction=speed_fraction)
        self._last = self.map.to_sim(result.T_base_flange_reached)
        self.clock.advance(max(0.0, float(result.duration_s)))
        return dataclasses.replace(
            result,
            T_base_flange_target=np.asarray(T_base_flange, float),
            T_base_flange_reached=self._last.copy(),
            T_base_flange_commanded=self.map.to_sim(result.T_base_flange_commanded),
        )

    def stop(self) -> None:
        """The driver's stop."""
        self.driver.stop()

    def home(self) -> None:
        """The driver's homing."""
        self.driver.home()

    def close(self) -> None:
        """Close the driver."""
        self.driver.close()

    # ------------------------------------------------------------------ the camera's pose
    @property
    def T_base_flange_home(self) -> np.ndarray:
        """The simulated home pose."""
        return self.sim.T_base_flange_home

    def true_flange_pose(self) -> np.ndarray:
        """Where the simulated camera is rendered: the driver's latest reported pose, in the simulated frame.

        Before connect, the simulated home. A driver that cannot report (the
        link is gone) leaves the camera where it was last reported.
        """
        from fgcd_core.platform import PlatformError

        if self.map is None:
            return self._last.copy()
        try:
            with self._lock:
                T = self.map.to_sim(self._reported())
        except (PlatformError, RuntimeError, OSError):
            return self._last.copy()
        self._last = T
        return T.copy()

    def _reported(self) -> np.ndarray:
        """The driver's latest report without a new poll where it has one (GRBL's last status)."""
        status = getattr(self.driver, "status", None)
        if status is not None:
            return self.driver.config.kinematics.pose_from_axes(status(fresh=False).mpos)
        return self.driver.flange_pose()

    def _announce(self) -> None:
        """One JSON line per motion in the log: its index and the operation's stage."""
        self._moves += 1
        if self._log is None:
            return
        entry = {"k": self._moves, "phase": _phase(), "t": time.monotonic()}
        with open(self._log, "a", encoding="utf-8") as handle:
            handle.write(json.dumps(entry) + "\n")


def parse_target(text: str) -> tuple[str, str]:
    """``("grbl", "/dev/pts/5")`` from ``grbl:/dev/pts/5``; ValueError when malformed."""
    kind, _, address = text.partition(":")
    if kind not in ("grbl", "ur") or not address:
        raise ValueError(f"{ENV_TARGET} must be grbl:PORT or ur:HOST, got {text!r}")
    return kind, address


def open_driver(kind: str, address: str):
    """The real driver (not connected): GRBL on ``address`` (a pty) or UR at ``address``."""
    if kind == "grbl":
        from fgcd_drivers.grbl.config import GrblConfig
        from fgcd_drivers.grbl.platform import GrblPlatform

        return GrblPlatform(GrblConfig(port=address, max_linear_speed_m_s=WIRED_SPEED_M_S))
    from fgcd_drivers.ur import URConfig, URPlatform

    return URPlatform(URConfig(host=address, max_linear_speed_m_s=WIRED_SPEED_M_S))


def install_wired_rig(kind: str, address: str, *, log: Path | None = None) -> None:
    """Make every simulated rig this process builds a wired one (GRBL: 3-DoF)."""
    from fgcd_drivers.sim import rig as sim_rig

    build = sim_rig.build_sim_rig

    def build_wired(*, scene: str, config=None):
        config = config or sim_rig.SimRigConfig()
        if kind == "grbl":
            config = dataclasses.replace(config, dof=3)
        rig = build(scene=scene, config=config)
        wired = WiredPlatform(rig.platform, open_driver(kind, address), log=log)
        rig.platform = wired
        rig.ground_truth._platform = wired  # the camera renders at the wired platform's reported pose
        return rig

    sim_rig.build_sim_rig = build_wired


def install_from_environment() -> None:
    """:func:`install_wired_rig` from :data:`ENV_TARGET` and :data:`ENV_LOG`."""
    kind, address = parse_target(os.environ[ENV_TARGET])
    log = os.environ.get(ENV_LOG)
    install_wired_rig(kind, address, log=Path(log) if log else None)
