"""The steps capture and revisit share on a rig: starting a VSE session with its map scale, grabbing images."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from fgcd_cli.app.lamp_image import can_flash, flash_lamp, grab_flash, mean_still
from fgcd_cli.app.rig import RigHandles
from fgcd_cli.campaign import schema
from fgcd_cli.errors import AlgorithmError
from fgcd_cli.relocation.config import ReferenceData
from fgcd_cli.relocation.session import (
    MIN_SCALE_STOPS,
    ScaleEstimate,
    VseSession,
    exploration_pattern,
    retrace_motions,
)
from fgcd_cli.vse.types import VseStatus
from fgcd_core.imaging import to_float01, to_gray_f32
from fgcd_drivers.lights import AMBIENT

__all__ = [
    "MAX_SCALE_RESIDUAL_MM",
    "grab_gray",
    "grab_gray_under",
    "grab_images",
    "load_reference",
    "measurement_lighting",
    "metric_keyframes",
    "reference_images",
    "revisit_lightings",
    "rig_lightings",
    "start_session",
    "visit_lightings",
]


def grab_images(rig: RigHandles, lightings: list[str], *, average: int = 4) -> dict[str, np.ndarray]:
    """Images at the current pose, one per lighting, averaged over a few frames (noise)."""
    images: dict[str, np.ndarray] = {}
    frames = max(1, average)
    for k, name in enumerate(lightings):
        # Rule: "ambient" switches every rig light off, leaving the day's light
        # (docs/hardware.md, "Lights"); the simulated rig's lamps obey the same rule.
        lamp = flash_lamp(name)
        if lamp is not None:
            # a lamp's own image: the difference of a lit and an unlit still (fgcd_cli.app.lamp_image)
            if not can_flash(rig, lamp):
                rig.say(f"no image {name}: this camera cannot lock its exposure or the rig lacks the lamp")
                continue
            rig.progress(k * frames, len(lightings) * frames, "images under each lighting")
            try:
                images[name] = grab_flash(rig, lamp, average=frames).image.astype(np.float32)
            except AlgorithmError as exc:  # the other images (and a relocated visit) are kept
                rig.say(f"{exc}: the observation is stored without {name}")
            continue
        if rig.lights is not None:
            rig.lights.set(name)
        rig.progress(k * frames, len(lightings) * frames, "images under each lighting")
        images[name] = mean_still(rig.camera_source, frames).astype(np.float32)
    return images


#: A session whose scale fit leaves more than this residual (mm) is explored again.
MAX_SCALE_RESIDUAL_MM = 12.0


def start_session(
    rig: RigHandles,
    *,
    explore_m: float,
    attempts: int = 2,
    legs: int = 6,
    motions: list[np.ndarray] | None = None,
    until: Callable[[VseSession, list, list], bool] | None = None,
) -> tuple[VseSession, object, ScaleEstimate, np.ndarray]:
    """Start the VSE, explore and estimate the map scale; explore again once on a bad start.

    ``motions``: the exploration's relative flange motions (a revisit's guided legs,
    :mod:`fgcd_cli.relocation.guided`); None: the usual pattern of ``legs`` legs.
    ``until(session, flange, cams)``: True after a motion ends the exploration there.

    A monocular engine occasionally initialises on a wrong solution (a map whose
    motion opposes the platform's, or a large scale residual); the session then
    resets the engine and explores again rather than building on it.
    """
    vse = rig.vse_factory()
    vse.start()
    session = VseSession(
        guard=rig.guard,
        vse=vse,
        on_event=rig.on_event,
        on_progress=rig.on_progress,
        frame_synthesis_s=rig.frame_synthesis_s,
    )
    T_base_flange_home = rig.guard.platform.flange_pose()
    last_error: AlgorithmError | None = None
    try:
        for attempt in range(1, attempts + 1):
            rig.say("exploring to initialise the VSE and its scale" + (f" (attempt {attempt})" if attempt > 1 else ""))
            try:
                planned = (
                    motions
                    if motions is not None
                    else exploration_pattern(translation_m=explore_m, legs=legs, stops_per_leg=2)
                )
                flange, cams = session.explore(
                    planned, until=None if until is None else (lambda f, c: until(session, f, c))
                )
                flange, cams = _extend_late_start(rig, session, planned, flange, cams)
                if getattr(vse.latest(), "scale_is_metric", False):
                    # a depth camera's map is metric: the platform motions only confirm it
                    check = session.estimate_scale(rig.T_flange_cam, flange, cams)
                    scale = ScaleEstimate(
                        scale=1.0,
                        scale_std=0.0,
                        n_samples=check.n_samples,
                        residual_rms_mm=check.residual_rms_mm,
                        method=f"metric depth (platform check {check.scale:.4f})",
                    )
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


def _extend_late_start(rig: RigHandles, session: VseSession, planned: list, flange: list, cams: list):
    """The tracked stops, with more from retracing the exploration when the VSE started late in it.

    A monocular engine that initialises at the last stops of an exploration tracks, but leaves the
    scale fit fewer than :data:`MIN_SCALE_STOPS` stops; its map is sound, so rather than reset it the
    session goes back over the last stops and forward again (:func:`retrace_motions`), poses the guard
    already allowed, ending where the exploration was planned to end.
    """
    st = session.vse.latest()
    if len(flange) >= MIN_SCALE_STOPS or st.status != VseStatus.TRACKING:
        return flange, cams
    rig.say(f"the VSE started late ({len(flange)} tracked stops): going back over the last stops")
    more_flange, more_cams = session.explore(retrace_motions(planned, MIN_SCALE_STOPS - len(flange) + 1))
    return flange + more_flange, cams + more_cams


def metric_keyframes(state, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """The VSE keyframes' poses with metric translations (``scale`` m per map unit) and their images."""
    poses = []
    for kf in state.keyframes:
        T = np.array(kf.T_map_cam, dtype=float)
        T[:3, 3] *= scale
        poses.append(T)
    images = np.stack([kf.image for kf in state.keyframes]) if state.keyframes else np.zeros((0, 1, 1), np.float32)
    return np.array(poses).reshape(-1, 4, 4), images


def grab_gray(rig: RigHandles, *, average: int = 2) -> np.ndarray:
    """The current undistorted grey image, averaged over a few stills (noise).

    Stills, as the reference's images are (``grab_images``): a measurement compares
    like with like. On the simulator a still integrates each pixel's area and a
    stream frame samples one ray, which differ by aliasing on grain finer than a
    pixel; a real camera's still is its next frame (``fgcd_drivers.cameras``).
    """
    acc = None
    for _ in range(max(1, average)):
        img = to_float01(np.asarray(rig.camera_source.grab_still().image)).astype(np.float64)
        acc = img if acc is None else acc + img
    return (acc / max(1, average)).astype(np.float32)


def rig_lightings(rig: RigHandles) -> list[str] | None:
    """What the rig's lights can switch to (``Lights.available()``), None for a rig without switchable lights."""
    lights = getattr(rig, "lights", None)  # a rig without switchable lights may not carry the attribute
    return None if lights is None else list(lights.available())


def visit_lightings(visit_light: str, reference_lightings: list[str], *, available: list[str] | None) -> list[str]:
    """Images of a visit: under the day's light, and under each reference lighting the rig's lights make again.

    Parameters
    ----------
    visit_light : str
        The visit's own light (``--light``), imaged first.
    reference_lightings : list of str
        The reference's lightings.
    available : list of str or None
        What the rig's lights can switch to (``Lights.available()``); None: no
        switchable lights, the day's light only. A rig that lists no channel
        (a person asked to switch any light) is asked for every reference lighting;
        otherwise a reference lighting the rig cannot make (the reference day's
        sun, sky or night) is not retaken: no rig moves the sun.
    """
    names = [visit_light]
    if available is None:
        return names
    listed = [n for n in available if n != AMBIENT]

    def makes(name: str) -> bool:
        lamp = flash_lamp(name)
        if lamp is not None:
            return lamp in available  # a lamp's own image needs that lamp
        return not listed or name in available

    names += [n for n in reference_lightings if n not in names and makes(n)]
    return names


def revisit_lightings(rig: RigHandles, visit_light: str, reference) -> list[str]:
    """:func:`visit_lightings` of a revisit: the day's light, then those of ``reference`` (an observation) the rig makes."""
    return visit_lightings(visit_light, reference.metadata.get("lightings", []), available=rig_lightings(rig))


def measurement_lighting(rig: RigHandles, reference_lightings: list[str]) -> str | None:
    """The reference lighting the image stage measures under, when the rig's own lamps make it.

    Feature positions on a relief move with the light direction (shadows and
    shading), which biases a pose measured across lightings by a millimetre or
    two; under the reference's own light the image stage compares like with like
    (docs/relocation.md, "Final image stage"). Only a lamp the rig carries can
    be lit again: ``ambient`` and the world's light (sun, sky, night) belong to
    the day of the reference. A reference that holds a lamp's own image
    (``flash:front``, taken where the day's light was part of it) is measured on
    that image first, taken again now (:mod:`fgcd_cli.app.lamp_image`). ``None`` when no
    reference lighting is one of the rig's lamps, or the rig switches none: the
    image stage then measures under the day's light, across lightings.
    """
    if rig.lights is None:
        return None
    for name in reference_lightings:
        lamp = flash_lamp(name)
        if lamp is not None and can_flash(rig, lamp):
            return name
    available = set(rig.lights.available())
    for name in reference_lightings:
        if name != "ambient" and name in available:
            return name
    return None


def grab_gray_under(rig: RigHandles, vse, lighting: str | None) -> np.ndarray:
    """The current grey image under ``lighting`` (the VSE held meanwhile), lights restored after."""
    if lighting is None or rig.lights is None or rig.lights.current == lighting:
        return grab_gray(rig)
    lamp = flash_lamp(lighting)
    if lamp is not None:
        with vse.held():
            return to_gray_f32(grab_flash(rig, lamp).image)
    previous = rig.lights.current
    with vse.held():
        rig.lights.set(lighting)
        try:
            return grab_gray(rig)
        finally:
            rig.lights.set(previous)


def load_reference(station) -> ReferenceData:
    """The reference cloud and camera of a station, as relocation needs them."""
    ref = station.reference()
    return ReferenceData(
        points=ref.array(schema.ARRAY_CLOUD_POINTS),
        intensities=ref.array(schema.ARRAY_CLOUD_INTENSITIES),
        T_ref_camref=ref.array(schema.ARRAY_T_REF_CAMREF),
    )


def reference_images(station) -> dict[str, np.ndarray]:
    """The reference observation's images (undistorted, one per lighting)."""
    ref = station.reference()
    return {name: ref.image(name) for name in ref.image_names()}
