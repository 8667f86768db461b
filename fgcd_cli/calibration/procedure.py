"""Calibration procedures that move the platform: target-free (rACR) and with a board.

Every motion goes through :class:`fgcd_core.platform.MotionGuard`. Samples pair
the platform's *reported* flange pose (what a real rig knows) with what the
camera measured at the same stop: the VSE camera pose (target-free) or the board
pose from ``solvePnP`` (target).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np

from fgcd_cli.calibration.board import BoardSpec
from fgcd_cli.calibration.depth_scale import KeyframeDepths
from fgcd_cli.calibration.errors import CalibrationError
from fgcd_cli.calibration.handeye.linear import solve_handeye_scale
from fgcd_cli.calibration.handeye.result import HandEyeResult
from fgcd_cli.calibration.handeye.target_free import PathViews, refine_target_free
from fgcd_cli.calibration.handeye.tracks import gray_u8
from fgcd_cli.calibration.handeye.with_target import TargetHandEyeResult, solve_handeye_target
from fgcd_cli.calibration.motions import exploration_motions, interpolate_steps, target_motions
from fgcd_cli.vse.types import VseStatus
from fgcd_core.camera import PinholeCamera
from fgcd_core.platform import MotionGuard

__all__ = [
    "TargetFreeRun",
    "TargetRun",
    "TargetFreeRunConfig",
    "TargetRunConfig",
    "run_target_free",
    "run_target",
    "CameraSourceLike",
    "VseEngineLike",
]


class CameraSourceLike(Protocol):
    """What the procedures need from a camera (``fgcd_drivers.cameras.CameraSource``)."""

    def grab(self) -> Any:
        """A frame with ``.image`` and ``.timestamp_s``."""


class VseEngineLike(Protocol):
    """What the target-free procedure needs from a VSE engine (``fgcd_cli.vse.MonocularVSE``)."""

    def process(self, image: np.ndarray, timestamp_s: float) -> Any:
        """A state with ``.status``, ``.message`` and ``.T_map_cam``."""


@dataclass(kw_only=True)
class TargetFreeRun:
    """Outcome of :func:`run_target_free`.

    Attributes
    ----------
    result : HandEyeResult
        Hand-eye and map scale of this VSE session.
    T_base_flange, T_map_cam : list of (4, 4) ndarray
        The samples used (reported flange poses, VSE poses in map units).
    skipped : dict of int to str
        Stops without a usable VSE pose, with the reason.
    frames : int
        Frames given to the VSE.
    engine : object
        The VSE engine, still tracking (the session can continue with it).
    """

    result: HandEyeResult
    T_base_flange: list[np.ndarray]
    T_map_cam: list[np.ndarray]
    skipped: dict[int, str] = field(default_factory=dict)
    frames: int = 0
    engine: Any = None


@dataclass(kw_only=True)
class TargetRun:
    """Outcome of :func:`run_target`: the solvers' result and the samples."""

    result: TargetHandEyeResult
    T_base_flange: list[np.ndarray]
    T_cam_target: list[np.ndarray]
    skipped: dict[int, str] = field(default_factory=dict)


def _rotation_axes(guard: MotionGuard) -> str:
    caps = guard.platform.capabilities()
    return "".join(a for a in "xyz" if f"r{a}" in caps.controllable)


@dataclass(frozen=True, kw_only=True)
class TargetFreeRunConfig:
    """Options of :func:`run_target_free`.

    Attributes
    ----------
    motions : sequence of (4, 4) ndarray, optional
        Stops relative to the start flange pose; default :func:`exploration_motions`.
    translation_m, rotation_deg : float
        Size of the default motions, metres and degrees.
    settle_frames : int
        Frames given to the VSE at each stop before its pose is read.
    max_step_m, max_step_deg : float
        Largest platform step between two frames (keeps the tracker locked).
    refine : bool
        Refine ``X`` by a bundle adjustment over the images of every rest pose of the
        path with the camera poses tied to the reported flange poses, then
        re-estimate the scale (:func:`fgcd_cli.calibration.handeye.target_free.refine_target_free`);
        if the images cannot be matched the linear solution is kept with a note.
    """

    motions: Sequence[np.ndarray] | None = None
    translation_m: float = 0.03
    rotation_deg: float = 8.0
    settle_frames: int = 3
    max_step_m: float = 0.005
    max_step_deg: float = 1.0
    refine: bool = True


def run_target_free(
    guard: MotionGuard,
    camera_source: CameraSourceLike,
    vse_engine_factory: Callable[[PinholeCamera], VseEngineLike],
    *,
    camera: PinholeCamera,
    config: TargetFreeRunConfig | None = None,
    progress: Callable[[str], None] | None = None,
    on_progress: Callable[[int, int, str], None] | None = None,
) -> TargetFreeRun:
    """Command exploration motions, track them with the VSE, solve ``X`` and ``s``.

    Parameters
    ----------
    guard : MotionGuard
        The platform, behind its safety guard.
    camera_source : CameraSourceLike
        ``grab() -> Frame``.
    vse_engine_factory : callable(PinholeCamera) -> engine
        Builds a fresh monocular VSE (e.g. ``fgcd_cli.vse.MonocularVSE``).
    camera : PinholeCamera
        Calibrated intrinsics.
    config : TargetFreeRunConfig, optional
        Motions, settling, step sizes, refinement.
    progress : callable(str), optional
        Receives one line per stop.
    on_progress : callable(done, total, label), optional
        Receives the frames done along the whole path after each frame, then
        ``(0, 0, label)`` when the image refinement (length unknown) starts.

    Returns
    -------
    TargetFreeRun

    Raises
    ------
    CalibrationError
        The platform cannot rotate about two axes, the VSE failed, or the
        samples are degenerate.
    fgcd_core.platform.PlatformError
        A motion failed or was refused (the platform stays where it stopped).
    """
    config = config or TargetFreeRunConfig()
    say = progress or (lambda _msg: None)
    tick = on_progress or (lambda _done, _total, _label: None)
    motions = _target_free_motions(guard, config)
    session = _TargetFreeSession(guard, camera_source, vse_engine_factory(camera), keep_path=config.refine)
    T_start = np.asarray(guard.platform.flange_pose(), dtype=float)
    targets = [T_start @ np.asarray(T_rel, dtype=float) for T_rel in motions]
    legs = [
        interpolate_steps(a, b, max_step_m=config.max_step_m, max_step_deg=config.max_step_deg) if index else []
        for index, (a, b) in enumerate(zip([T_start] + targets[:-1], targets))
    ]
    settle = max(1, config.settle_frames)
    total_frames = sum(len(steps) for steps in legs) + len(legs) * settle
    for index, steps in enumerate(legs):
        label = f"hand-eye motions (stop {index + 1}/{len(motions)})"
        session.visit(steps, settle, lambda label=label: tick(session.frames, total_frames, label))
        where = f"stop {index + 1}/{len(motions)}"
        if session.record_stop(index):
            say(f"{where}: sample {len(session.hand)} recorded")
        else:
            say(f"{where}: no VSE pose ({session.state.status})")
    if len(session.hand) < 3:
        raise CalibrationError(
            f"the VSE gave a pose at only {len(session.hand)} of {len(motions)} stops: point the camera at a "
            "textured, static surface 0.3-2 m away and try again"
        )
    result = solve_handeye_scale(session.hand, session.eye, pairs="all")
    if config.refine:
        result = _refine(result, session, camera, say, tick)
    return TargetFreeRun(
        result=result,
        T_base_flange=session.hand,
        T_map_cam=session.eye,
        skipped=session.skipped,
        frames=session.frames,
        engine=session.engine,
    )


def _target_free_motions(guard: MotionGuard, config: TargetFreeRunConfig) -> Sequence[np.ndarray]:
    """The configured stops, or the default exploration about the axes the platform can turn."""
    if config.motions is not None:
        return config.motions
    axes = _rotation_axes(guard)
    if len(axes) < 2:
        raise CalibrationError(
            f"platform '{guard.platform.name}' rotates about {len(axes)} axis(es) only: target-free hand-eye "
            "needs rotations about two axes (use a 6-DoF arm, or enter the hand-eye measured by hand)"
        )
    return exploration_motions(translation_m=config.translation_m, rotation_deg=config.rotation_deg, rotation_axes=axes)


class _TargetFreeSession:
    """The samples of a target-free run as the platform moves: stops, VSE poses, and every rest pose's view.

    Every rest pose along the path is kept with its image (grey, 8 bit) for the image
    refinement when ``keep_path``; a stop the VSE missed is still a view (the
    refinement needs no VSE pose).
    """

    def __init__(self, guard: MotionGuard, camera_source: CameraSourceLike, engine: Any, *, keep_path: bool):
        self.guard, self.camera_source, self.engine, self.keep_path = guard, camera_source, engine, keep_path
        self.frames = 0
        self.state: Any = None
        self.last_image: Any = None
        self.last_pose: Any = None
        self.flange_at: dict[float, np.ndarray] = {}  # reported flange pose of every frame, by timestamp
        self.hand: list[np.ndarray] = []
        self.eye: list[np.ndarray] = []
        self.stop_images: list[np.ndarray] = []
        self.path_T: list[np.ndarray] = []
        self.path_images: list[np.ndarray] = []
        self.stop_index: list[int] = []
        self.skipped: dict[int, str] = {}

    def feed(self) -> None:
        """One frame to the VSE, with the flange pose reported when it was grabbed."""
        frame = self.camera_source.grab()
        self.frames += 1
        self.last_image = frame.image
        self.last_pose = self.flange_at[float(frame.timestamp_s)] = np.asarray(
            self.guard.platform.flange_pose(), dtype=float
        )
        self.state = self.engine.process(frame.image, frame.timestamp_s)

    def visit(self, steps: Sequence[np.ndarray], settle: int, tick: Callable[[], None]) -> None:
        """Step to the next stop (a frame after each step) and let the VSE settle there."""
        for T_step in steps:
            self.guard.move_to(T_step)
            self.feed()
            tick()
            if self.keep_path:
                self.path_T.append(self.last_pose)
                self.path_images.append(gray_u8(self.last_image))
        for _ in range(settle):
            self.feed()
            tick()
        if steps and self.keep_path:
            # the last step ended at the stop: the stop's own view replaces it (same rest pose)
            self.path_T.pop()
            self.path_images.pop()

    def record_stop(self, index: int) -> bool:
        """The stop's sample if the VSE tracks; whether it did (the reason is kept in ``skipped`` if not)."""
        state = self.state
        if state.status == VseStatus.FAILED:
            raise CalibrationError(f"the VSE cannot track this scene: {state.message}")
        tracked = state.status == VseStatus.TRACKING and state.T_map_cam is not None
        if tracked:
            self.hand.append(np.asarray(self.guard.platform.flange_pose(), dtype=float))
            self.eye.append(np.asarray(state.T_map_cam, dtype=float))
            self.stop_images.append(np.asarray(self.last_image))
        if self.keep_path:
            self.path_T.append(self.hand[-1] if tracked else self.last_pose)
            self.path_images.append(gray_u8(self.last_image))
            if tracked:
                self.stop_index.append(len(self.path_T) - 1)
        if not tracked:
            self.skipped[index] = f"VSE {state.status}: {state.message}"
        return tracked

    def keyframe_depths(self) -> list[KeyframeDepths]:
        """The VSE keyframes with their cloud points and the flange pose of their frame."""
        cloud = getattr(self.state, "cloud", None)
        if cloud is None or len(getattr(cloud, "points", ())) == 0:
            return []
        out = []
        for kf in getattr(self.state, "keyframes", ()):
            T_flange = self.flange_at.get(float(kf.timestamp_s))
            sel = np.asarray(cloud.keyframe_ids) == kf.id
            if T_flange is None or not np.any(sel):
                continue
            out.append(
                KeyframeDepths(
                    T_base_flange=T_flange,
                    T_map_cam=np.asarray(kf.T_map_cam, dtype=float),
                    pixels=np.asarray(cloud.pixels)[sel],
                    points_map=np.asarray(cloud.points)[sel],
                )
            )
        return out


def _refine(result: HandEyeResult, session: _TargetFreeSession, camera: PinholeCamera, say, tick) -> HandEyeResult:
    """The image refinement of the linear result; the linear result with a note if the images cannot be matched."""
    tick(0, 0, f"image refinement over {len(session.path_T)} views")
    path = PathViews(T_base_flange=session.path_T, images=session.path_images, stop_index=session.stop_index)
    try:
        result = refine_target_free(
            result,
            session.hand,
            session.eye,
            session.stop_images,
            camera,
            keyframes=session.keyframe_depths(),
            path=path,
        )
        ref = result.refinement
        say(
            f"image refinement: {ref.get('views', len(session.hand))} views, {ref['points']} points, "
            f"{ref['rms_px']:.2f} px RMS, X moved {ref['change_mm']:.1f} mm / {ref['change_deg']:.2f} deg"
        )
    except CalibrationError as exc:
        result = replace(result, notes=list(result.notes) + [f"image refinement skipped: {exc}"])
        say(f"image refinement skipped: {exc}")
    return result


@dataclass(frozen=True, kw_only=True)
class TargetRunConfig:
    """Options of :func:`run_target`.

    Attributes
    ----------
    motions : sequence of (4, 4) ndarray, optional
        Stops relative to the start flange pose; default :func:`target_motions`.
    rotation_deg, translation_m : float
        Size of the default motions, degrees and metres.
    methods : tuple of str
        Solvers to compare (:data:`fgcd_cli.calibration.handeye.with_target.OPENCV_METHODS`).
    min_corners : int
        Views with fewer board corners are skipped.
    """

    motions: Sequence[np.ndarray] | None = None
    rotation_deg: float = 15.0
    translation_m: float = 0.04
    methods: Sequence[str] = ("TSAI", "PARK", "HORAUD", "ANDREFF", "DANIILIDIS")
    min_corners: int = 12


def run_target(
    guard: MotionGuard,
    camera_source: CameraSourceLike,
    board: BoardSpec,
    *,
    camera: PinholeCamera,
    config: TargetRunConfig | None = None,
    progress: Callable[[str], None] | None = None,
    on_progress: Callable[[int, int, str], None] | None = None,
) -> TargetRun:
    """Visit stops looking at a fixed ChArUco board and solve ``AX = XB``.

    The platform moves in steps within 95 % of the guard's limits and returns to
    the start pose at the end.

    Parameters
    ----------
    guard : MotionGuard
        The platform behind its safety guard.
    camera_source : CameraSourceLike
        ``grab() -> Frame``.
    board : BoardSpec
        The board as printed, fixed in the scene, visible from the start pose.
    camera : PinholeCamera
        Calibrated intrinsics.
    config : TargetRunConfig, optional
        Motions, solvers, corner threshold.
    progress : callable(str), optional
        Receives one line per stop.
    on_progress : callable(done, total, label), optional
        Receives the stops done before each stop's motion, and at the end.

    Returns
    -------
    TargetRun
    """
    config = config or TargetRunConfig()
    say = progress or (lambda _msg: None)
    tick = on_progress or (lambda _done, _total, _label: None)
    motions = (
        list(config.motions)
        if config.motions is not None
        else target_motions(rotation_deg=config.rotation_deg, translation_m=config.translation_m)
    )
    T_start = np.asarray(guard.platform.flange_pose(), dtype=float)
    steps = {"max_step_m": guard.limits.max_step_m * 0.95, "max_step_deg": np.degrees(guard.limits.max_step_rad) * 0.95}
    run = TargetRun(result=None, T_base_flange=[], T_cam_target=[])
    T_prev = T_start
    for index, T_rel in enumerate(motions):
        tick(index, len(motions), f"hand-eye with the board (stop {index + 1}/{len(motions)})")
        T_target = T_start @ np.asarray(T_rel, dtype=float)
        if index:
            for T_step in interpolate_steps(T_prev, T_target, **steps):
                guard.move_to(T_step)
        T_prev = T_target
        _board_sample(
            run,
            guard,
            camera_source.grab(),
            board,
            camera,
            config.min_corners,
            index,
            lambda text, index=index: say(f"stop {index + 1}/{len(motions)}: {text}"),
        )
    tick(len(motions), len(motions), "back to the start pose")
    # Return to the start pose (the same small steps).
    for T_step in interpolate_steps(T_prev, T_start, **steps):
        guard.move_to(T_step)
    if len(run.T_base_flange) < 3:
        raise CalibrationError(
            f"the board was seen at only {len(run.T_base_flange)} of {len(motions)} stops: place it 0.3-0.8 m in "
            "front of the camera, fully visible from the start pose, or reduce --rotation-deg"
        )
    run.result = solve_handeye_target(run.T_base_flange, run.T_cam_target, methods=config.methods)
    return run


def _board_sample(
    run: TargetRun,
    guard: MotionGuard,
    frame: Any,
    board: BoardSpec,
    camera: PinholeCamera,
    min_corners: int,
    index: int,
    say: Callable[[str], None],
) -> None:
    """The stop's sample (flange pose, board pose) when the board is seen with enough corners, else a skip."""
    det = board.detect(frame.image)
    T_cam_target = board.estimate_pose(det, camera.K, camera.dist) if det.n_corners >= min_corners else None
    if T_cam_target is None:
        run.skipped[index] = f"board not seen ({det.n_corners} corners)"
        say(f"board not seen ({det.n_corners} corners)")
        return
    run.T_base_flange.append(np.asarray(guard.platform.flange_pose(), dtype=float))
    run.T_cam_target.append(T_cam_target)
    say(f"{det.n_corners} corners")
