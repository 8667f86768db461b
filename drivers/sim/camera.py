"""Simulated camera: renders the world at the true pose of the camera on the platform.

Its true intrinsics (focal lengths, principal point, distortion) may differ from
the nominal ones it advertises; calibration has to find them.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from fgcd_core.camera import CameraIntrinsics
from fgcd_drivers.cameras import CameraError, Frame
from fgcd_drivers.sim.sensor import CameraEffects
from fgcd_drivers.sim.world import SimLights, SimWorld

__all__ = [
    "SimCamera",
    "SimCameraOptions",
    "STILL_SUPERSAMPLE",
    "IntrinsicsErrorLevel",
    "DEFAULT_INTRINSICS",
    "perturbed_intrinsics",
    "DEFAULT_EFFECTS",
]

#: Nominal 640x480 camera with a ~56 deg horizontal field of view.
DEFAULT_INTRINSICS = CameraIntrinsics(fx=600.0, fy=600.0, cx=319.5, cy=239.5, width=640, height=480)

#: A realistic small sensor: vignetting, read and shot noise, gamma.
DEFAULT_EFFECTS = CameraEffects(
    gamma=2.2, vignetting=0.15, read_noise=0.002, shot_noise=0.006, max_exposure=32.0, bit_depth=8
)


class IntrinsicsErrorLevel(StrEnum):
    """How far a simulated camera's true intrinsics are from its nominal ones (:func:`perturbed_intrinsics`)."""

    NONE = "none"
    DEFAULT = "default"
    LARGE = "large"


#: Error scale of each named level (a number given instead scales the default directly).
_LEVEL_SCALE = {IntrinsicsErrorLevel.DEFAULT: 1.0, IntrinsicsErrorLevel.LARGE: 3.0}


def perturbed_intrinsics(nominal: CameraIntrinsics, level: str | float, rng: np.random.Generator) -> CameraIntrinsics:
    """True intrinsics differing from ``nominal``.

    ``level``: ``"none"``, ``"default"`` (focal sigma 1 %, principal point sigma
    4 px, radial distortion k1 about -0.05), ``"large"`` (the default's errors
    times 3: 3 %, 12 px, k1 about -0.15), or a float scaling the default.
    """
    if level == IntrinsicsErrorLevel.NONE or level == 0:
        return nominal
    scale = _LEVEL_SCALE.get(level, level) if isinstance(level, str) else float(level)
    if isinstance(scale, str):
        raise ValueError(f"unknown intrinsics error level {level!r}: use none, default, large or a number")
    f = 1.0 + rng.normal(0, 0.01 * scale)
    return CameraIntrinsics(
        fx=nominal.fx * f,
        fy=nominal.fy * f * (1.0 + rng.normal(0, 0.001 * scale)),
        cx=nominal.cx + rng.normal(0, 4.0 * scale),
        cy=nominal.cy + rng.normal(0, 4.0 * scale),
        width=nominal.width,
        height=nominal.height,
        dist=(-0.05 * scale * abs(1 + rng.normal(0, 0.2)), 0.02 * scale * rng.normal(), 0.0, 0.0, 0.0),
    )


#: Samples per pixel axis of a simulated still (:attr:`SimCameraOptions.still_supersample`).
STILL_SUPERSAMPLE = 2


@dataclass(frozen=True, kw_only=True)
class SimCameraOptions:
    """What a :class:`SimCamera` is, besides the world it looks at.

    Attributes
    ----------
    intrinsics_true : CameraIntrinsics
        What the renderer uses.
    intrinsics_nominal : CameraIntrinsics, optional
        What the camera advertises (default: the true ones).
    effects : CameraEffects
        Sensor noise, vignetting, gamma.
    exposure : ``"auto"`` or float
        Automatic or fixed exposure.
    with_depth, with_rgb : bool
        Also return z-depth (an RGB-D camera) / the colour image.
    frame_period_s : float
        Simulated time each grab takes (advances the clock).
    seed : int
        Noise seed.
    still_supersample : int
        Samples per pixel axis of a still (:meth:`SimCamera.grab_still`): a real
        sensor integrates the light over each pixel's area, a point-sampled render
        does not, and one bright or dark pixel of an edge-on surface then flips
        with a sub-pixel move (``docs/simulator.md``, "Stills"). Stream frames
        stay point-sampled (one ray per pixel) for speed.
    """

    intrinsics_true: CameraIntrinsics = DEFAULT_INTRINSICS
    intrinsics_nominal: CameraIntrinsics | None = None
    effects: CameraEffects = DEFAULT_EFFECTS
    exposure: float | str = "auto"
    with_depth: bool = False
    with_rgb: bool = False
    frame_period_s: float = 0.0
    seed: int = 0
    still_supersample: int = STILL_SUPERSAMPLE


class SimCamera:
    """A camera in the simulated world (implements ``fgcd_drivers.cameras.CameraSource``).

    Parameters
    ----------
    world : SimWorld
    pose_fn : callable returning the true ``T_world_cam`` now.
    lights : SimLights
    options : SimCameraOptions, optional
        Intrinsics, sensor, outputs and seed (default: :class:`SimCameraOptions`).
    clock : object with ``now()``/``advance()``; timestamps come from it.
    """

    def __init__(
        self,
        *,
        world: SimWorld,
        pose_fn: Callable[[], np.ndarray],
        lights: SimLights,
        options: SimCameraOptions | None = None,
        clock=None,
    ):
        o = options or SimCameraOptions()
        self.options = o
        self.world = world
        self._pose_fn = pose_fn
        self.lights = lights
        self._intr_true = o.intrinsics_true
        self._intr_nominal = o.intrinsics_nominal or o.intrinsics_true
        self.effects = o.effects
        self.exposure = o.exposure
        self.with_depth = o.with_depth
        self.with_rgb = o.with_rgb
        self.clock = clock
        self.frame_period_s = float(o.frame_period_s)
        self._rng = np.random.default_rng([o.seed, 0xCA3])
        self.last_exposure: float | None = None
        self._still_exposure: float | None = None
        self._closed = False
        self._still_renderer = None
        # rendering time, for the rig-time model: finished renders' seconds and the start of those in
        # progress, by thread (the VSE thread and a caller grabbing images may render at once)
        self._render_lock = threading.Lock()
        self._render_total_s: dict[int, float] = {}
        self._render_started: dict[int, float] = {}

    @property
    def intrinsics_nominal(self) -> CameraIntrinsics:
        return self._intr_nominal

    def grab(self) -> Frame:
        return self._render_frame(self.world.renderer)

    def grab_still(self) -> Frame:
        """One still: the pixel area integrated over ``still_supersample``² samples (box filter)."""
        s = int(self.options.still_supersample)
        renderer = self.world.renderer
        if s > 1 and renderer.supersample != s:
            if self._still_renderer is None:
                self._still_renderer = renderer.with_supersample(s)
            renderer = self._still_renderer
        frame = self._render_frame(renderer)
        self._still_exposure = frame.exposure
        return frame

    @contextmanager
    def exposure_locked(self):
        """Every frame keeps the exposure of the last still until the block ends (automatic again after).

        The stream frames the VSE grabs do not move the lock: it is the last *still*'s exposure.
        """
        if self._still_exposure is None:
            self.grab_still()
        previous = self.exposure
        self.exposure = float(self._still_exposure)
        try:
            yield
        finally:
            self.exposure = previous

    def _render_frame(self, renderer) -> Frame:
        if self._closed:
            raise CameraError("simulated camera is closed")
        T = self._pose_fn()
        want = ("gray", "rgb") if self.with_rgb else ("gray",)
        me = threading.get_ident()
        start = time.monotonic()
        with self._render_lock:
            self._render_started[me] = start
        try:
            res = renderer.render(
                T,
                self._intr_true,
                self.lights.lighting,
                changes=self.world.changes,
                exposure=self.exposure,
                effects=self.effects,
                rng=self._rng,
                want=want,
            )
        finally:
            with self._render_lock:
                self._render_total_s[me] = self._render_total_s.get(me, 0.0) + time.monotonic() - start
                self._render_started.pop(me, None)
        self.last_exposure = res.exposure
        ts = 0.0
        if self.clock is not None:
            ts = self.clock.now()
            if self.frame_period_s:
                self.clock.advance(self.frame_period_s)
        return Frame(res.gray, ts, res.depth if self.with_depth else None, res.rgb, exposure=float(res.exposure))

    def synthetic_overhead_s(self, thread: int | None = None) -> float:
        """Wall seconds spent so far synthesising frames and stills (the renders in progress included).

        A real camera streams frames while the software works, and its still is its
        next frame; this camera renders each image on demand in the grabbing thread,
        which a rig's time budget must not count (docs/relocation.md, "Time"; render
        times in docs/benchmarks.md, "Simulator renderer (`fgcd bench render`)").
        ``thread`` (a ``threading.get_ident()``): only the renders made in that thread,
        for a caller timing its own stills while the VSE thread renders its stream.
        ``time.monotonic`` seconds, comparable between calls.
        """
        with self._render_lock:
            now = time.monotonic()
            if thread is None:
                done = sum(self._render_total_s.values())
                return done + sum(now - t for t in self._render_started.values())
            started = self._render_started.get(thread)
            return self._render_total_s.get(thread, 0.0) + (now - started if started is not None else 0.0)

    def close(self) -> None:
        self._closed = True
