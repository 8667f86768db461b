"""Reference capture and revisit as use cases on a rig (no CLI, no rich).

``capture_reference``: start the VSE, explore, estimate the map scale, come
back to the chosen pose, and write the immutable reference observation (metric
cloud, reference camera pose, keyframes, images under each lighting).

``relocate_and_capture``: on a revisit, start a new session, explore a little,
re-estimate the scale, align to the reference and drive the camera back with
the rACR loop, then write a visit (images, cloud, relocation log).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from fgcd_cli.errors import AlgorithmError, run_record
from fgcd_cli.geometry.camera import PinholeCamera
from fgcd_cli.geometry.sim3 import Sim3
from fgcd_cli.relocation.loop import (
    AdjustmentRecord,
    ReferenceData,
    RelocationConfig,
    RelocationResult,
    run_relocation,
)
from fgcd_cli.relocation.coarse import CoarseConfig, CoarseResult, image_estimate, run_coarse_stage
from fgcd_cli.relocation.session import ScaleEstimate, VseSession, exploration_pattern

__all__ = ["RigHandles", "CaptureResult", "capture_reference", "relocate_and_capture", "grab_images", "load_reference"]


@dataclass
class RigHandles:
    """What the use cases need of a rig (any driver).

    Attributes
    ----------
    guard : drivers.platform.MotionGuard
    camera_source : object with ``grab()``
    intrinsics : PinholeCamera
    T_flange_cam : (4, 4) ndarray
        Hand-eye from calibration (identity with ``--no-handeye``).
    lights : object with ``set(name)`` or None
    vse_factory : callable() -> VseThread (not started)
    on_event : callable(str) or None
        Progress lines for people.
    on_progress : callable(done, total, label) or None
        Progress of long steps (``total <= 0``: length unknown).
    """

    guard: object
    camera_source: object
    intrinsics: PinholeCamera
    T_flange_cam: np.ndarray
    vse_factory: Callable[[], object]
    lights: object | None = None
    on_event: Callable[[str], None] | None = None
    on_progress: Callable[[int, int, str], None] | None = None

    def say(self, text: str) -> None:
        """One progress line for people (no-op without ``on_event``)."""
        if self.on_event:
            self.on_event(text)

    def progress(self, done: int, total: int, label: str) -> None:
        """Progress of a long step (no-op without ``on_progress``)."""
        if self.on_progress:
            self.on_progress(done, total, label)


@dataclass
class CaptureResult:
    """Summary of a capture or a visit."""

    observation_path: str
    scale: ScaleEstimate
    cloud_points: int
    images: list[str]
    relocation: RelocationResult | None = None
    extra: dict = field(default_factory=dict)
    coarse: CoarseResult | None = None
    """The active coarse stage's outcome, when it ran (far starts only)."""


def grab_images(rig: RigHandles, lightings: list[str], *, average: int = 4) -> dict[str, np.ndarray]:
    """Images at the current pose, one per lighting, averaged over a few frames (noise)."""
    images: dict[str, np.ndarray] = {}
    frames = max(1, average)
    for k, name in enumerate(lightings):
        if rig.lights is not None and name != "ambient":
            rig.lights.set(name)
        acc = None
        for i in range(frames):
            rig.progress(k * frames + i, len(lightings) * frames, "images under each lighting")
            frame = rig.camera_source.grab()
            img = frame.rgb if getattr(frame, "rgb", None) is not None else frame.image
            img = np.asarray(img, dtype=np.float64)
            if img.max() > 1.5:
                img = img / 255.0
            acc = img if acc is None else acc + img
        images[name] = (acc / max(1, average)).astype(np.float32)
    return images


#: A session whose scale fit leaves more than this residual (mm) is explored again.
MAX_SCALE_RESIDUAL_MM = 12.0


def _start_session(
    rig: RigHandles, *, explore_m: float, attempts: int = 2, legs: int = 6
) -> tuple[VseSession, object, ScaleEstimate, np.ndarray]:
    """Start the VSE, explore and estimate the map scale; explore again once on a bad start.

    A monocular engine occasionally initialises on a wrong solution (a map whose
    motion opposes the platform's, or a large scale residual); the session then
    resets the engine and explores again rather than building on it.
    """
    vse = rig.vse_factory()
    vse.start()
    session = VseSession(guard=rig.guard, vse=vse, on_event=rig.on_event, on_progress=rig.on_progress,
                         frame_synthesis_s=getattr(rig.camera_source, "synthetic_overhead_s", None))
    T_base_flange_home = rig.guard.platform.flange_pose()
    last_error: AlgorithmError | None = None
    try:
        for attempt in range(1, attempts + 1):
            rig.say("exploring to initialise the VSE and its scale" + (f" (attempt {attempt})" if attempt > 1 else ""))
            try:
                flange, cams = session.explore(exploration_pattern(translation_m=explore_m, legs=legs, stops_per_leg=2))
                if getattr(vse.latest(), "scale_is_metric", False):
                    # a depth camera's map is metric: the platform motions only confirm it
                    check = session.estimate_scale(rig.T_flange_cam, flange, cams)
                    scale = ScaleEstimate(scale=1.0, scale_std=0.0, n_samples=check.n_samples,
                                          residual_rms_mm=check.residual_rms_mm,
                                          method=f"metric depth (platform check {check.scale:.4f})")
                else:
                    scale = session.estimate_scale(rig.T_flange_cam, flange, cams)
                if scale.residual_rms_mm > MAX_SCALE_RESIDUAL_MM:
                    raise AlgorithmError(
                        f"the VSE motion disagrees with the platform by {scale.residual_rms_mm:.1f} mm RMS"
                    )
            except AlgorithmError as exc:
                last_error = exc
                rig.say(f"bad VSE start: {exc}; resetting the engine")
                session.move_to_flange(T_base_flange_home)
                vse.reset()
                continue
            rig.say(
                f"map scale {scale.scale:.4f} m/unit (±{scale.scale_std / scale.scale * 100:.2f} %), "
                f"residual {scale.residual_rms_mm:.2f} mm"
            )
            return session, vse, scale, T_base_flange_home
        raise AlgorithmError(f"the VSE could not start after {attempts} explorations: {last_error}")
    except BaseException:
        vse.stop()
        raise


def _metric_keyframes(state, scale: float) -> tuple[np.ndarray, np.ndarray]:
    poses = []
    for kf in state.keyframes:
        T = np.array(kf.T_map_cam, dtype=float)
        T[:3, 3] *= scale
        poses.append(T)
    images = np.stack([kf.image for kf in state.keyframes]) if state.keyframes else np.zeros((0, 1, 1), np.float32)
    return np.array(poses).reshape(-1, 4, 4), images


def capture_reference(
    rig: RigHandles,
    station,
    *,
    lightings: list[str],
    explore_m: float = 0.05,
    metadata: dict | None = None,
    evaluation: dict | None = None,
) -> CaptureResult:
    """Capture the immutable reference observation of ``station`` at the platform's current pose."""
    rig.progress(0, 0, "starting the VSE")
    session, vse, scale, T_base_flange_ref = _start_session(rig, explore_m=explore_m)
    try:
        session.move_to_flange(T_base_flange_ref, label="back to the reference pose")
        rig.progress(0, 0, "letting the reference cloud mature")
        state = session.tracking_state()
        # a few more frames at the reference pose let the semi-dense cloud mature
        state = session.settle(frames=6)
        if state.status != "tracking":
            raise AlgorithmError(f"the VSE lost track at the reference pose ({state.message})")
        T_ref_camref = np.array(state.T_map_cam, dtype=float)
        T_ref_camref[:3, 3] *= scale.scale
        cloud = state.cloud
        if len(cloud) < 1000:
            raise AlgorithmError(f"the reference cloud has only {len(cloud)} points: scene too weakly textured for rACR")
        points = np.asarray(cloud.points, dtype=float) * scale.scale
        kf_poses, kf_images = _metric_keyframes(state, scale.scale)
        images = grab_images(rig, lightings)
        meta = {
            "lightings": lightings,
            "scale": scale.__dict__,
            "T_flange_cam": np.asarray(rig.T_flange_cam).tolist(),
            "T_base_flange": np.asarray(rig.guard.platform.flange_pose()).tolist(),
            "intrinsics": rig.intrinsics.to_dict(),
            "cloud_points": int(len(points)),
            "keyframes": int(len(kf_poses)),
            "platform_s": session.timing.platform_s,
            **(metadata or {}),
        }
        rig.progress(0, 0, "writing the reference")
        with run_record.writing(f"the reference of station '{station.name}'"), station.write_reference(meta) as w:
            for name, img in images.items():
                w.add_image(name, img)
            w.add_cloud(points, colors=np.asarray(cloud.intensities, dtype=np.float32))
            w.add_array("cloud_intensities", np.asarray(cloud.intensities, dtype=np.float32))
            w.add_array("T_ref_camref", T_ref_camref)
            w.add_array("keyframe_poses", kf_poses)
            w.add_array("keyframe_images", kf_images.astype(np.float32))
            if evaluation is not None:
                w.add_json("evaluation/sim_truth.json", evaluation)
            obs = w.commit()
    finally:
        vse.stop()
    return CaptureResult(str(obs.path), scale, int(len(points)), list(images))


def load_reference(station) -> ReferenceData:
    """The reference cloud and camera of a station, as relocation needs them."""
    ref = station.reference()
    return ReferenceData(
        points=ref.array("cloud_points"),
        intensities=ref.array("cloud_intensities"),
        T_ref_camref=ref.array("T_ref_camref"),
    )


def _reference_images(station) -> dict[str, np.ndarray]:
    """The reference observation's images (undistorted, one per lighting)."""
    ref = station.reference()
    return {name: ref.image(name) for name in ref.image_names()}


def _grab_gray(rig: RigHandles, *, average: int = 2) -> np.ndarray:
    """The current undistorted grey image, averaged over a few frames (noise)."""
    acc = None
    for _ in range(max(1, average)):
        img = np.asarray(rig.camera_source.grab().image, dtype=np.float64)
        if img.max() > 1.5:
            img = img / 255.0
        acc = img if acc is None else acc + img
    return (acc / max(1, average)).astype(np.float32)


def measurement_lighting(rig: RigHandles, reference_lightings: list[str]) -> str | None:
    """The reference lighting the image stage measures under, when the rig can switch to it.

    Feature positions on a relief move with the light direction (shadows and
    shading), which biases a pose measured across lightings by a millimetre or
    two; under the reference's own light the image stage compares like with like
    (docs/relocation.md, "Final image stage"). ``None`` on rigs without switchable
    lights: the image stage then measures under the day's light.
    """
    if rig.lights is None:
        return None
    available = set(rig.lights.available()) if hasattr(rig.lights, "available") else None
    for name in reference_lightings:
        if name != "ambient" and (available is None or name in available):
            return name
    return None


def _grab_gray_under(rig: RigHandles, vse, lighting: str | None) -> np.ndarray:
    """The current grey image under ``lighting`` (the VSE held meanwhile), lights restored after."""
    if lighting is None or rig.lights is None or rig.lights.current == lighting:
        return _grab_gray(rig)
    previous = rig.lights.current
    with vse.held():
        rig.lights.set(lighting)
        try:
            return _grab_gray(rig)
        finally:
            rig.lights.set(previous)


def relocate_and_capture(
    rig: RigHandles,
    station,
    *,
    config: RelocationConfig,
    lightings: list[str],
    explore_m: float = 0.04,
    explore_legs: int = 3,
    metadata: dict | None = None,
    evaluate: Callable[[], dict] | None = None,
    on_record: Callable[[AdjustmentRecord], None] | None = None,
    evaluation: Callable[[], dict] | None = None,
    coarse: CoarseConfig | None = CoarseConfig(),
) -> CaptureResult:
    """Relocate to the station's reference pose with rACR, then write a visit.

    When the first estimate puts the camera farther than ``coarse.trigger_*`` from the
    reference pose, the active coarse stage (:mod:`fgcd_cli.relocation.coarse`, paper 001)
    runs first; ``coarse=None`` leaves it out (the loop then pauses on such a start).
    """
    from fgcd_cli.alignment import ReferenceIndex

    reference = load_reference(station)
    ref_index = ReferenceIndex(reference.points, intensities=reference.intensities,
                               view=(reference.T_ref_camref, rig.intrinsics))
    rig.progress(0, 0, "starting the VSE")
    session, vse, scale, _ = _start_session(rig, explore_m=explore_m, legs=explore_legs)
    try:
        rig.progress(0, 0, "initial alignment to the reference")
        first = session.tracking_state()
        T_cur_cam0 = np.array(first.T_map_cam, dtype=float)
        T_cur_cam0[:3, 3] *= scale.scale
        from fgcd_cli.alignment import initial_guess

        # the first camera is near the reference camera; checked by a fast alignment of the
        # whole current cloud, with the global multi-start registration as fallback
        guess = initial_guess(T_ref_camref=reference.T_ref_camref, T_cur_cam0=T_cur_cam0,
                              cur_points=np.asarray(first.cloud.points, dtype=float) * scale.scale,
                              reference=ref_index, scale=1.0)
        init = guess.T_ref_cur
        rig.say(f"initial alignment: {guess.source}"
                + (f" ({guess.fast.health.reason})" if guess.fast is not None else ""))
        coarse_result = None
        if coarse is not None:
            first_trusted = guess.fast is not None and guess.fast.health.ok
            coarse_result, init = _maybe_coarse(rig, session, reference, ref_index, station, scale.scale, init,
                                                coarse, evaluate, first_trusted=first_trusted)
        reference_images = _reference_images(station)
        same_light = measurement_lighting(rig, list(reference_images))
        if same_light is not None:
            # like with like: the image stage compares with the reference image of that light only
            reference_images = {same_light: reference_images[same_light]}
            rig.say(f"the image stage measures under the reference's light ({same_light})")
        rig.say(f"relocating ({config.mode}) to the reference of station '{station.name}'")
        rig.progress(0, 0, "relocating")
        try:
            result = run_relocation(
                session=session,
                reference=reference,
                ref_index=ref_index,
                camera=rig.intrinsics,
                scale=scale.scale,
                T_flange_cam=rig.T_flange_cam,
                init=init,
                config=config,
                evaluate=evaluate,
                on_record=on_record,
                reference_images=reference_images,
                grab_current=lambda: _grab_gray_under(rig, vse, same_light),
            )
        except AlgorithmError as exc:
            # the loop paused: what the coarse stage did before stays available to the caller
            exc.coarse_result = coarse_result
            raise
        rig.progress(0, 0, "settling at the reached pose")
        state = session.settle(frames=2)
        points = np.asarray(state.cloud.points, dtype=float) * scale.scale
        images = grab_images(rig, lightings)
        meta = {
            "lightings": lightings,
            "scale": scale.__dict__,
            "relocation": {
                "converged": result.converged,
                "reason": result.reason,
                "adjustments": result.adjustments,
                "wall_s": result.wall_s,
                "session_s": result.session_s,
                "platform_s": result.platform_s,
                "synthetic_s": result.synthetic_s,
                "mode": config.mode,
                "residual": result.residual.to_dict() if result.residual else None,
            },
            "coarse": None if coarse_result is None else {
                "handed_over": coarse_result.handed_over, "reason": coarse_result.reason,
                "steps": len(coarse_result.steps),
            },
            "T_flange_cam": np.asarray(rig.T_flange_cam).tolist(),
            "T_base_flange": np.asarray(rig.guard.platform.flange_pose()).tolist(),
            "intrinsics": rig.intrinsics.to_dict(),
            **(metadata or {}),
        }
        rig.progress(0, 0, "writing the visit")
        stamp_writer = station.new_visit(meta)
        with run_record.writing(f"the visit of station '{station.name}'"), stamp_writer as w:
            for name, img in images.items():
                w.add_image(name, img)
            w.add_cloud(points, colors=np.asarray(state.cloud.intensities, dtype=np.float32))
            w.add_bytes(
                "relocation.jsonl", "".join(r.to_json() + "\n" for r in result.records).encode("utf-8")
            )
            if coarse_result is not None and coarse_result.steps:
                w.add_bytes("coarse.jsonl", "".join(json.dumps(st.to_dict(), default=float) + "\n"
                                                    for st in coarse_result.steps).encode("utf-8"))
            if evaluation is not None:
                w.add_json("evaluation/sim_truth.json", evaluation())
            obs = w.commit()
    finally:
        vse.stop()
    return CaptureResult(str(obs.path), scale, int(len(points)), list(images), relocation=result,
                         coarse=coarse_result)


def _maybe_coarse(rig, session, reference, ref_index, station, scale: float, init, config: CoarseConfig,
                  evaluate, *, first_trusted: bool = True) -> tuple[CoarseResult | None, object]:
    """Run the active coarse stage when the first estimate is far from the reference pose.

    An untrustworthy first alignment (a degenerate fit can claim the camera is near when it is
    not: a stupa's frieze slides along itself) is checked against the image localizer too;
    the stage runs when either puts the camera far away.

    Returns the stage's result (None when it did not run) and the alignment the rACR loop
    starts from: the stage's verified one, or the first one when the stage could not verify
    any (the loop then pauses on the far estimate and its image fallback tries, as before).
    """
    from fgcd_cli.geometry.se3 import pose_distance
    from fgcd_cli.relocation.adjustment import camera_in_reference

    state = session.tracking_state()
    T_cur_cam = np.array(state.T_map_cam, dtype=float)
    T_cur_cam[:3, 3] *= scale
    off_mm, off_deg = pose_distance(camera_in_reference(init, T_cur_cam), reference.T_ref_camref)
    source = "first estimate"
    near = off_mm <= config.trigger_m * 1e3 and off_deg <= config.trigger_deg
    if not near or not first_trusted:
        # A second opinion: a far 3D estimate may be a confidently wrong fit (a statue's at 1.19 m
        # from a start 20 mm away), a near one from an untrustworthy fit may be a slide (a stupa's).
        # When the image localizer puts the camera near, the loop and its image fallback take it
        # from there (measured, that statue: the stage found nothing to verify in 4 views on its
        # distorted session cloud and cost 50 s before the fallback relocated anyway).
        rig.progress(0, 0, "locating the camera in the reference images")
        t0 = time.monotonic()
        T_img, _info = image_estimate(reference_images=_reference_images(station), current_image=_grab_gray(rig),
                                      camera=rig.intrinsics, reference=reference)
        session.timing.wait_s += time.monotonic() - t0  # the platform waits for it
        if T_img is not None:
            img_mm, img_deg = pose_distance(T_img, reference.T_ref_camref)
            img_near = img_mm <= config.trigger_m * 1e3 and img_deg <= config.trigger_deg
            if near and not img_near:
                off_mm, off_deg, near = img_mm, img_deg, False
                source = "image estimate (the 3D one is untrustworthy)"
            elif not near and img_near:
                rig.say(f"first estimate {off_mm:.0f} mm / {off_deg:.1f} deg from the reference, but the image "
                        f"localizer says {img_mm:.0f} mm / {img_deg:.1f} deg: no coarse stage")
                near = True
    if near:
        return None, init
    rig.say(f"{source} {off_mm:.0f} mm / {off_deg:.1f} deg from the reference: active coarse stage")
    rig.progress(0, 0, "active coarse stage")
    result = run_coarse_stage(session=session, reference=reference, ref_index=ref_index, camera=rig.intrinsics,
                              scale=scale, T_flange_cam=rig.T_flange_cam, init=init,
                              reference_images=_reference_images(station), grab_current=lambda: _grab_gray(rig),
                              config=config, evaluate=evaluate, say=rig.say)
    if not result.handed_over:
        rig.say(f"{result.reason}; the rACR loop starts from the first estimate")
        return result, init
    return result, result.init
