"""Calibration procedures that move the platform: target-free (rACR) and with a board.

Every motion goes through :class:`drivers.platform.MotionGuard`. Samples pair
the platform's *reported* flange pose (what a real rig knows) with what the
camera measured at the same stop: the VSE camera pose (target-free) or the board
pose from ``solvePnP`` (target).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable, Protocol, Sequence

import numpy as np

from drivers.platform import MotionGuard
from fgcd_cli.calibration.board import BoardSpec
from fgcd_cli.calibration.errors import CalibrationError
from fgcd_cli.calibration.handeye import HandEyeResult, solve_handeye_scale
from fgcd_cli.calibration.handeye_ba import gray_u8
from fgcd_cli.calibration.handeye_target import TargetHandEyeResult, solve_handeye_target
from fgcd_cli.calibration.motions import exploration_motions, interpolate_steps, target_motions
from fgcd_cli.geometry.camera import PinholeCamera

__all__ = ["TargetFreeRun", "TargetRun", "run_target_free", "run_target", "CameraSourceLike", "VseEngineLike"]


class CameraSourceLike(Protocol):
    """What the procedures need from a camera (``drivers.cameras.CameraSource``)."""

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


def run_target_free(
    guard: MotionGuard,
    camera_source: CameraSourceLike,
    vse_engine_factory: Callable[[PinholeCamera], VseEngineLike],
    *,
    camera: PinholeCamera,
    motions: Sequence[np.ndarray] | None = None,
    translation_m: float = 0.03,
    rotation_deg: float = 8.0,
    settle_frames: int = 3,
    max_step_m: float = 0.005,
    max_step_deg: float = 1.0,
    refine: bool = True,
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
    motions : sequence of (4, 4) ndarray, optional
        Stops relative to the start flange pose; default :func:`exploration_motions`.
    translation_m, rotation_deg : float
        Size of the default motions.
    settle_frames : int
        Frames given to the VSE at each stop before its pose is read.
    max_step_m, max_step_deg : float
        Largest platform step between two frames (keeps the tracker locked).
    refine : bool
        Refine ``X`` by a bundle adjustment over the stop images with the camera
        poses tied to the reported flange poses, then re-estimate the scale
        (:func:`fgcd_cli.calibration.handeye_ba.refine_target_free`); if the images
        cannot be matched the linear solution is kept with a note.
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
    drivers.platform.PlatformError
        A motion failed or was refused (the platform stays where it stopped).
    """
    say = progress or (lambda _msg: None)
    tick = on_progress or (lambda _done, _total, _label: None)
    if motions is None:
        axes = _rotation_axes(guard)
        if len(axes) < 2:
            raise CalibrationError(
                f"platform '{guard.platform.name}' rotates about {len(axes)} axis(es) only: target-free hand-eye "
                "needs rotations about two axes (use a 6-DoF arm, or enter the hand-eye measured by hand)"
            )
        motions = exploration_motions(translation_m=translation_m, rotation_deg=rotation_deg, rotation_axes=axes)
    engine = vse_engine_factory(camera)
    T_start = np.asarray(guard.platform.flange_pose(), dtype=float)
    hand: list[np.ndarray] = []
    eye: list[np.ndarray] = []
    stop_images: list[np.ndarray] = []
    last_image: list[Any] = [None]
    flange_at: dict[float, np.ndarray] = {}  # reported flange pose of every frame, by timestamp
    last_pose: list[Any] = [None]
    # every rest pose along the path with its image (grey, 8 bit), for the image refinement
    path_T: list[np.ndarray] = []
    path_images: list[np.ndarray] = []
    stop_index: list[int] = []
    skipped: dict[int, str] = {}
    frames = 0
    state = None

    def feed() -> Any:
        nonlocal frames
        frame = camera_source.grab()
        frames += 1
        last_image[0] = frame.image
        last_pose[0] = flange_at[float(frame.timestamp_s)] = np.asarray(guard.platform.flange_pose(), dtype=float)
        return engine.process(frame.image, frame.timestamp_s)

    targets = [T_start @ np.asarray(T_rel, dtype=float) for T_rel in motions]
    legs = [interpolate_steps(a, b, max_step_m=max_step_m, max_step_deg=max_step_deg) if index else []
            for index, (a, b) in enumerate(zip([T_start] + targets[:-1], targets))]
    total_frames = sum(len(steps) for steps in legs) + len(legs) * max(1, settle_frames)
    for index, steps in enumerate(legs):
        label = f"hand-eye motions (stop {index + 1}/{len(motions)})"
        for T_step in steps:
            guard.move_to(T_step)
            state = feed()
            tick(frames, total_frames, label)
            if refine:
                path_T.append(last_pose[0])
                path_images.append(gray_u8(last_image[0]))
        for _ in range(max(1, settle_frames)):
            state = feed()
            tick(frames, total_frames, label)
        if state.status == "failed":
            raise CalibrationError(f"the VSE cannot track this scene: {state.message}")
        tracked = state.status == "tracking" and state.T_map_cam is not None
        if tracked:
            hand.append(np.asarray(guard.platform.flange_pose(), dtype=float))
            eye.append(np.asarray(state.T_map_cam, dtype=float))
            stop_images.append(np.asarray(last_image[0]))
        if refine:
            # the last step ended at the stop: the stop's own view replaces it (same rest pose);
            # the refinement needs no VSE pose, so a stop the VSE missed is still a view
            if steps:
                path_T.pop()
                path_images.pop()
            path_T.append(hand[-1] if tracked else last_pose[0])
            path_images.append(gray_u8(last_image[0]))
            if tracked:
                stop_index.append(len(path_T) - 1)
        if tracked:
            say(f"stop {index + 1}/{len(motions)}: sample {len(hand)} recorded")
        else:
            skipped[index] = f"VSE {state.status}: {state.message}"
            say(f"stop {index + 1}/{len(motions)}: no VSE pose ({state.status})")
    if len(hand) < 3:
        raise CalibrationError(
            f"the VSE gave a pose at only {len(hand)} of {len(motions)} stops: point the camera at a textured, "
            "static surface 0.3-2 m away and try again"
        )
    result = solve_handeye_scale(hand, eye, pairs="all")
    if refine:
        from fgcd_cli.calibration.handeye_ba import PathViews, refine_target_free

        tick(0, 0, f"image refinement over {len(path_T)} views")
        path = PathViews(T_base_flange=path_T, images=path_images, stop_index=stop_index)
        try:
            result = refine_target_free(result, hand, eye, stop_images, camera.K, dist=camera.dist,
                                        keyframes=_keyframe_depths(state, flange_at), path=path)
            say(
                f"image refinement: {result.refinement.get('views', len(hand))} views, "
                f"{result.refinement['points']} points, {result.refinement['rms_px']:.2f} px RMS, "
                f"X moved {result.refinement['change_mm']:.1f} mm / {result.refinement['change_deg']:.2f} deg"
            )
        except CalibrationError as exc:
            result = replace(result, notes=list(result.notes) + [f"image refinement skipped: {exc}"])
            say(f"image refinement skipped: {exc}")
    return TargetFreeRun(result=result, T_base_flange=hand, T_map_cam=eye, skipped=skipped, frames=frames, engine=engine)


def _keyframe_depths(state: Any, flange_at: dict[float, np.ndarray]) -> list:
    """The VSE keyframes with their cloud points and the flange pose of their frame."""
    from fgcd_cli.calibration.handeye_ba import KeyframeDepths

    cloud = getattr(state, "cloud", None)
    if cloud is None or len(getattr(cloud, "points", ())) == 0:
        return []
    out = []
    for kf in getattr(state, "keyframes", ()):
        T_flange = flange_at.get(float(kf.timestamp_s))
        sel = np.asarray(cloud.keyframe_ids) == kf.id
        if T_flange is None or not np.any(sel):
            continue
        out.append(KeyframeDepths(T_base_flange=T_flange, T_map_cam=np.asarray(kf.T_map_cam, dtype=float),
                                  pixels=np.asarray(cloud.pixels)[sel], points_map=np.asarray(cloud.points)[sel]))
    return out


def run_target(
    guard: MotionGuard,
    camera_source: CameraSourceLike,
    board: BoardSpec,
    *,
    camera: PinholeCamera,
    motions: Sequence[np.ndarray] | None = None,
    rotation_deg: float = 15.0,
    translation_m: float = 0.04,
    methods: Sequence[str] = ("TSAI", "PARK", "HORAUD", "ANDREFF", "DANIILIDIS"),
    min_corners: int = 12,
    progress: Callable[[str], None] | None = None,
    on_progress: Callable[[int, int, str], None] | None = None,
) -> TargetRun:
    """Visit stops looking at a fixed ChArUco board and solve ``AX = XB``.

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
    motions : sequence of (4, 4) ndarray, optional
        Stops relative to the start flange pose; default :func:`target_motions`.
    rotation_deg, translation_m : float
        Size of the default motions.
    methods : sequence of str
        Solvers to compare.
    min_corners : int
        Views with fewer board corners are skipped.
    progress : callable(str), optional
        Receives one line per stop.
    on_progress : callable(done, total, label), optional
        Receives the stops done before each stop's motion, and at the end.

    Returns
    -------
    TargetRun
    """
    say = progress or (lambda _msg: None)
    motions = list(motions) if motions is not None else target_motions(rotation_deg=rotation_deg, translation_m=translation_m)
    T_start = np.asarray(guard.platform.flange_pose(), dtype=float)
    step_m = guard.limits.max_step_m * 0.95
    step_deg = np.degrees(guard.limits.max_step_rad) * 0.95
    hand: list[np.ndarray] = []
    boards: list[np.ndarray] = []
    skipped: dict[int, str] = {}
    tick = on_progress or (lambda _done, _total, _label: None)
    T_prev = T_start
    for index, T_rel in enumerate(motions):
        tick(index, len(motions), f"hand-eye with the board (stop {index + 1}/{len(motions)})")
        T_target = T_start @ np.asarray(T_rel, dtype=float)
        if index:
            for T_step in interpolate_steps(T_prev, T_target, max_step_m=step_m, max_step_deg=step_deg):
                guard.move_to(T_step)
        T_prev = T_target
        frame = camera_source.grab()
        det = board.detect(frame.image)
        T_cam_target = board.estimate_pose(det, camera.K, camera.dist) if det.n_corners >= min_corners else None
        if T_cam_target is None:
            skipped[index] = f"board not seen ({det.n_corners} corners)"
            say(f"stop {index + 1}/{len(motions)}: board not seen ({det.n_corners} corners)")
            continue
        hand.append(np.asarray(guard.platform.flange_pose(), dtype=float))
        boards.append(T_cam_target)
        say(f"stop {index + 1}/{len(motions)}: {det.n_corners} corners")
    tick(len(motions), len(motions), "back to the start pose")
    # Return to the start pose (the same small steps).
    for T_step in interpolate_steps(T_prev, T_start, max_step_m=step_m, max_step_deg=step_deg):
        guard.move_to(T_step)
    if len(hand) < 3:
        raise CalibrationError(
            f"the board was seen at only {len(hand)} of {len(motions)} stops: place it 0.3-0.8 m in front of the "
            "camera, fully visible from the start pose, or reduce --rotation-deg"
        )
    result = solve_handeye_target(hand, boards, methods=methods)
    return TargetRun(result=result, T_base_flange=hand, T_cam_target=boards, skipped=skipped)
