"""A VSE session on a rig: start the engine, move slowly, settle, estimate the map scale.

Shared by capture and relocate. The engine runs in its own thread over the
camera; motions go through the :class:`fgcd_core.platform.MotionGuard` in small
sub-steps so that the VSE keeps tracking (the rACR platform moves slowly too),
and after each sub-step the session waits for fresh frames before it trusts a
pose.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from fgcd_cli.errors import AlgorithmError, run_record
from fgcd_cli.relocation.waiting import wait_for_state
from fgcd_cli.vse.types import VseStatus
from fgcd_core.platform import MotionGuard
from fgcd_core.se3 import exp_se3, invert_pose, log_se3, rotation_angle_rad

__all__ = [
    "MIN_SCALE_STOPS",
    "SessionTiming",
    "ScaleEstimate",
    "VseSession",
    "exploration_pattern",
    "recorded_motion",
    "retrace_motions",
]

#: Tracked exploration stops the scale fit needs (rACR scale, docs/relocation.md "What a session does"):
#: two give one baseline and no residual to judge the fit by.
MIN_SCALE_STOPS = 3


@contextmanager
def recorded_motion() -> Iterator[None]:
    """Mark a motion in progress in ``run_record`` (the line printed on Ctrl-C says the platform was moving).

    Nested marks are one motion: a motion cut into guarded sub-steps is in
    progress from its first sub-step to its last, and the inner marks of
    its sub-steps leave the outer one standing.
    """
    if run_record.moving:
        yield
        return
    with run_record.motion():
        yield


class VseThreadLike(Protocol):
    """What the session needs of :class:`fgcd_cli.vse.thread.VseThread`.

    A thread that also has ``wait_for(predicate, timeout)`` (the real one) is waited on
    through its condition; a stand-in without it is polled (:func:`.waiting.wait_for_state`).
    """

    def latest(self): ...  # noqa: D102

    def stop(self) -> None: ...  # noqa: D102


@dataclass
class SessionTiming:
    """Where the time of a session went.

    Attributes
    ----------
    platform_s : float
        Time the platform spent moving (simulated seconds on the simulator).
    wait_s : float
        Wall time spent waiting for VSE frames and estimates while not moving.
    moves : int
        Motions sent (sub-steps counted).
    """

    platform_s: float = 0.0
    wait_s: float = 0.0
    moves: int = 0
    synthetic_s: float = 0.0
    """Wall time of frame waits that the camera spent synthesising the frames (the
    simulator's rendering), left out of ``wait_s``: a real camera streams frames
    while the VSE works. 0 on hardware."""

    step_clock: Callable[[], float] | None = None
    """A deterministic run's clock (:attr:`fgcd_cli.vse.thread.SteppedVse.seconds`, one frame period per
    frame step): its waits then count that, not the wall clock (docs/relocation.md, "Reproducibility")."""

    def count_wait(self, wall_s: float, rendered_s: float | None, *, floor_s: float = 0.0) -> None:
        """Count a wait of ``wall_s`` seconds while the platform stood still.

        ``rendered_s``: the simulator's rendering within it (None on hardware: all of it counts).
        The rendering is left out, as a real camera streams frames and its still is its next
        frame, but the wait counts at least ``floor_s`` (the frames' periods) and never more
        than the wall time (docs/relocation.md, "Time"). The one home of that rule.
        """
        if rendered_s is None:
            self.wait_s += wall_s
            return
        rendered = min(wall_s, max(0.0, rendered_s))
        counted = min(wall_s, max(wall_s - rendered, floor_s))
        self.wait_s += counted
        self.synthetic_s += wall_s - counted

    @property
    def total_s(self) -> float:
        """Platform time plus waiting time: the session's duration on a real rig (a deterministic run:
        platform time plus the frames' steps, so that it depends on the steps only)."""
        return self.platform_s + (self.step_clock() if self.step_clock is not None else self.wait_s)

    @property
    def with_synthesis_s(self) -> float:
        """``total_s`` with the frame synthesis counted too (what the simulator's wall clock saw)."""
        return self.total_s + self.synthetic_s


@dataclass(frozen=True, kw_only=True)
class ScaleEstimate:
    """The map scale of a session (metres per VSE unit)."""

    scale: float
    scale_std: float
    n_samples: int
    residual_rms_mm: float
    method: str


def exploration_waypoints(
    *, translation_m: float = 0.02, rotation_rad: float = math.radians(3.0), legs: int = 6
) -> list[np.ndarray]:
    """Flange poses of the exploration relative to its start (the first is the identity).

    Translations along the three flange axes with small tilts, returning to the
    start after six legs; translation is what initialises a monocular engine
    (pure rotation cannot) and observes the scale.
    """
    d, r = translation_m, rotation_rad
    twists = [
        np.zeros(6),
        np.array([d, 0, 0, 0, r, 0]),
        np.array([d, d, 0, -r, r, 0]),
        np.array([0, d, d / 2, -r, 0, 0]),
        np.array([-d, 0, d / 2, 0, -r, 0]),
        np.array([0, -d, 0, r, 0, 0]),
        np.zeros(6),
    ]
    return [exp_se3(w) for w in twists[: legs + 1]]


def exploration_pattern(
    *, translation_m: float = 0.02, rotation_rad: float = math.radians(3.0), legs: int = 6, stops_per_leg: int = 1
) -> list[np.ndarray]:
    """The exploration as relative flange motions, applied one after the other.

    ``legs=6`` is the full pattern of :func:`exploration_waypoints` (capture:
    the reference cloud sees the object from several sides); fewer legs take
    the first waypoints and return straight to the start (relocation: the
    hand-eye is known, translations suffice for the scale). ``stops_per_leg``
    cuts every leg into that many equal motions along its geodesic: the same
    path, more recorded stops for the scale (a monocular engine that
    initialises late in the first leg still leaves enough tracked stops).
    """
    poses = exploration_waypoints(translation_m=translation_m, rotation_rad=rotation_rad)
    if legs < 6:
        poses = poses[: max(2, legs)] + [poses[-1]]
    legs_rel = [invert_pose(a) @ b for a, b in zip(poses[:-1], poses[1:])]
    n = max(1, int(stops_per_leg))
    return [exp_se3(log_se3(M) / n) for M in legs_rel for _ in range(n)]


def retrace_motions(motions: Sequence[np.ndarray], stops: int) -> list[np.ndarray]:
    """Back over an exploration's last ``stops`` motions, then forward again to where it ended.

    The extension of an exploration whose VSE started late (few tracked stops): every stop is one
    the guard already allowed, and the exploration still ends where it was planned to.

    Parameters
    ----------
    motions : sequence of (4, 4) ndarray
        The exploration's relative flange motions, in the order they ran.
    stops : int
        How many of its last motions to retrace (clipped to ``len(motions)``).

    Returns
    -------
    list of (4, 4) ndarray
        ``2 * stops`` relative flange motions.
    """
    last = [np.asarray(M, dtype=float) for M in motions[len(motions) - min(max(0, stops), len(motions)) :]]
    return [invert_pose(M) for M in reversed(last)] + last


@dataclass
class VseSession:
    """One VSE session on a rig.

    Parameters
    ----------
    guard : fgcd_core.platform.MotionGuard
        Every motion passes here.
    vse : VseThreadLike
        A started VSE thread over the rig's camera.
    substep_m, substep_rad : float
        Largest sub-step of a motion; the VSE sees every sub-step.
    settle_frames : int
        Fresh frames to wait for after a motion before trusting the pose.
    frame_timeout_s : float
        Wall time after which a silent VSE is an error.
    on_event : callable(str), optional
        Progress lines for people.
    on_progress : callable(done, total, label), optional
        Progress of long steps (exploration, motions in sub-steps), reported
        after each sub-step; ``total <= 0`` means the length is unknown.
    frame_synthesis_s : callable([thread]) -> float, optional
        Cumulative seconds the camera has spent synthesising frames (the
        simulator's ``synthetic_overhead_s``; given a thread's ident, that thread's only). When given, frame waits count
        without that time, and at least one ``1 / camera_fps`` per frame: the
        rig-time model of a streaming camera (see :class:`SessionTiming`).
    camera_fps : float
        Frame rate of the modelled streaming camera.
    """

    guard: MotionGuard
    vse: VseThreadLike
    substep_m: float = 0.005
    substep_rad: float = math.radians(1.0)
    settle_frames: int = 2
    frame_timeout_s: float = 60.0
    on_event: Callable[[str], None] | None = None
    frame_synthesis_s: Callable[..., float] | None = None
    camera_fps: float = 30.0
    on_progress: Callable[[int, int, str], None] | None = None
    timing: SessionTiming = field(default_factory=SessionTiming)

    def __post_init__(self) -> None:
        if getattr(self.vse, "stepped", False):  # a deterministic run: the VSE's steps are the clock
            self.timing.step_clock = lambda: self.vse.seconds

    def now(self) -> float:
        """The session's clock for its waits: ``time.monotonic()``, or a deterministic run's step clock."""
        return self.timing.step_clock() if self.timing.step_clock is not None else time.monotonic()

    # -- VSE access
    def settle(self, *, frames: int | None = None):
        """Wait until the VSE has processed ``frames`` new frames; return its state."""
        need = self.settle_frames if frames is None else frames
        synth0 = self.frame_synthesis_s() if self.frame_synthesis_s is not None else 0.0
        t0 = time.monotonic()
        start = self.vse.latest().frames_processed
        st = wait_for_state(self.vse, lambda s: s.frames_processed >= start + need, self.frame_timeout_s)
        if st is None:
            raise AlgorithmError(f"the VSE processed no new frame in {self.frame_timeout_s:.0f} s")
        self._count_frame_wait(time.monotonic() - t0, synth0, need)
        return st

    def _count_frame_wait(self, wall_s: float, synth0: float, frames: int) -> None:
        """Add a frame wait to the timing, without the camera's frame synthesis (if known)."""
        rendered = None if self.frame_synthesis_s is None else self.frame_synthesis_s() - synth0
        self.timing.count_wait(wall_s, rendered, floor_s=frames / self.camera_fps)

    @contextmanager
    def standing_still(self, *, stills: int = 0) -> Iterator[None]:
        """Time a block in which the platform stands still while this thread grabs stills and computes.

        Rig time is the block's wall time without the simulator's rendering of this thread's
        stills (the VSE thread's stream frames, rendered meanwhile, are not the block's),
        at least ``stills`` frame periods (:meth:`SessionTiming.count_wait`).
        """
        me = threading.get_ident()
        own = None if self.frame_synthesis_s is None else (lambda: self.frame_synthesis_s(me))
        synth0 = own() if own is not None else 0.0
        t0 = time.monotonic()
        try:
            yield
        finally:
            rendered = None if own is None else own() - synth0
            self.timing.count_wait(time.monotonic() - t0, rendered, floor_s=stills / self.camera_fps)

    def tracking_state(self, *, timeout_s: float = 60.0):
        """Wait for a settled state in which the VSE tracks; raise if it fails."""
        t0 = self.now()
        while True:
            st = self.settle()
            if st.status == VseStatus.TRACKING and st.T_map_cam is not None:
                return st
            if st.status == VseStatus.FAILED:
                raise AlgorithmError(f"the VSE cannot track this scene: {st.message}")
            if self.now() - t0 > timeout_s:
                raise AlgorithmError(f"the VSE is not tracking ({st.status}: {st.message})")

    # -- motion
    def substeps(self, M_flange: np.ndarray) -> int:
        """Number of sub-steps :meth:`move_by` cuts the motion ``M_flange`` into."""
        M_flange = np.asarray(M_flange, dtype=float)
        trans = float(np.linalg.norm(M_flange[:3, 3]))
        rot = rotation_angle_rad(M_flange[:3, :3])
        return max(1, int(math.ceil(max(trans / self.substep_m, rot / self.substep_rad))))

    def progress(self, done: int, total: int, label: str) -> None:
        """Report the progress of a long step (no-op without ``on_progress``)."""
        if self.on_progress is not None:
            self.on_progress(done, total, label)

    def move_by(self, M_flange: np.ndarray, *, progress: tuple[int, int, str] | None = None) -> float:
        """Move by ``M_flange`` (flange frame) in sub-steps; returns the platform time spent.

        ``progress = (done, total, label)``: the sub-steps already done of a
        longer step and its total; each sub-step of this motion is reported.
        """
        n = self.substeps(M_flange)
        step = exp_se3(log_se3(np.asarray(M_flange, dtype=float)) / n)
        done, total, label = progress if progress is not None else (0, n, "")
        spent = 0.0
        # the whole sub-stepped motion is one motion in progress for the Ctrl-C line
        with recorded_motion():
            for i in range(n):
                result = self.guard.move_by(step)
                spent += float(getattr(result, "duration_s", 0.0))
                self.timing.moves += 1
                self.settle(frames=1)
                if progress is not None:
                    self.progress(done + i + 1, total, label)
        self.timing.platform_s += spent
        return spent

    def move_to_flange(self, T_base_flange_target: np.ndarray, *, label: str | None = None) -> float:
        """Move the flange to an absolute pose in sub-steps (reported under ``label`` when given)."""
        current = self.guard.platform.flange_pose()
        M = invert_pose(current) @ np.asarray(T_base_flange_target, dtype=float)
        return self.move_by(M, progress=None if label is None else (0, self.substeps(M), label))

    # -- exploration and scale
    def explore(
        self, motions: Sequence[np.ndarray], *, until: Callable[[list, list], bool] | None = None
    ) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Run an exploration; return the flange and VSE poses at each tracked waypoint.

        ``until(flange, cams)``, asked after each motion: True ends the exploration there.
        """
        flange, cams = [], []
        counts = [self.substeps(M) for M in motions]
        total = sum(counts)
        for i, M in enumerate(motions):
            self.move_by(M, progress=(sum(counts[:i]), total, f"exploring ({i + 1}/{len(motions)})"))
            st = self.settle(frames=self.settle_frames + 1)
            if st.status == VseStatus.FAILED:
                raise AlgorithmError(f"the VSE cannot track this scene: {st.message}")
            if st.status == VseStatus.TRACKING and st.T_map_cam is not None:
                flange.append(self.guard.platform.flange_pose())
                cams.append(np.asarray(st.T_map_cam, dtype=float))
            if self.on_event:
                said = f" ({st.message})" if st.status != VseStatus.TRACKING and getattr(st, "message", "") else ""
                self.on_event(f"exploration {i + 1}/{len(motions)}: VSE {st.status}{said}")
            if until is not None and i + 1 < len(motions) and until(flange, cams):
                if self.on_event:
                    self.on_event(
                        f"exploration ended after {i + 1}/{len(motions)} motions: the alignment is trustworthy"
                    )
                break
        return flange, cams

    def estimate_scale(
        self, T_flange_cam: np.ndarray, flange: list[np.ndarray], cams: list[np.ndarray]
    ) -> ScaleEstimate:
        """Metric scale of the map from the recorded waypoints and a known hand-eye."""
        from fgcd_cli.calibration.handeye.linear import estimate_scale

        if len(flange) < MIN_SCALE_STOPS:
            st = self.vse.latest()  # its last word says why (too little texture, parallax, lost...)
            said = f" ({getattr(st.status, 'value', st.status)}: {st.message})" if getattr(st, "message", "") else ""
            raise AlgorithmError(
                f"only {len(flange)} tracked exploration waypoints: the VSE could not follow the motion{said}"
            )
        res = estimate_scale(T_flange_cam, flange, cams, pairs="all")
        return ScaleEstimate(
            scale=float(res.scale),
            scale_std=float(res.scale_std),
            n_samples=len(flange),
            residual_rms_mm=float(res.rms_mm),
            method="rACR scale (hand-eye known)",
        )
