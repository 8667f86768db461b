"""The revisit use case: drive the camera back to a station's reference pose (rACR) and write a visit.

``relocate_and_capture``: on a revisit, start a new session, explore a little,
re-estimate the scale, align to the reference and drive the camera back with
the rACR loop (after the active coarse stage on a far start, :mod:`fgcd_cli.app.coarse_start`),
then write a visit (images, cloud, relocation log).
"""

from __future__ import annotations

import json
from collections.abc import Callable

import numpy as np

from fgcd_cli.app.capture import CaptureResult
from fgcd_cli.app.coarse_start import CoarseStart, maybe_coarse
from fgcd_cli.app.determinism import deterministic_rig, run_conditions
from fgcd_cli.app.guided_start import start_revisit_session
from fgcd_cli.app.lamp_image import flash_lamp, lamp_alone_now
from fgcd_cli.app.relocate_request import RelocateHooks, RelocateRequest
from fgcd_cli.app.rig import RigHandles
from fgcd_cli.app.session import (
    grab_gray_under,
    grab_images,
    load_reference,
    measurement_lighting,
    reference_images,
)
from fgcd_cli.campaign import schema
from fgcd_cli.errors import AlgorithmError, run_record
from fgcd_cli.relocation.coarse.config import CoarseConfig, CoarseResult
from fgcd_cli.relocation.enums import RelocationMethod
from fgcd_cli.relocation.log import RelocationResult
from fgcd_cli.relocation.loop.context import LoopContext
from fgcd_cli.relocation.loop.parallel import relocate

__all__ = ["relocate_and_capture"]


def relocate_and_capture(
    rig: RigHandles, station, request: RelocateRequest, *, hooks: RelocateHooks | None = None
) -> CaptureResult:
    """Relocate to the station's reference pose with rACR, then write a visit.

    When the first estimate puts the camera farther than ``coarse.trigger_*`` from the
    reference pose, the active coarse stage (:mod:`fgcd_cli.relocation.coarse.stage`, paper 001)
    runs first; ``coarse=None`` leaves it out (the loop then pauses on such a start).
    """
    hooks = hooks or RelocateHooks()
    if request.method != RelocationMethod.RACR:
        from fgcd_cli.app.relocate_acr import acr_relocate_and_capture

        return acr_relocate_and_capture(rig, station, request, hooks=hooks)
    from fgcd_cli.alignment.reference import ReferenceIndex

    reference = load_reference(station)
    if hooks.reference_override is not None:
        reference = hooks.reference_override(reference)
    ref_index = ReferenceIndex(
        reference.points, intensities=reference.intensities, view=(reference.T_ref_camref, rig.intrinsics)
    )
    rig.progress(0, 0, "starting the VSE")
    session, vse, scale, prior_sigma_mm = start_revisit_session(
        deterministic_rig(rig, request.config.deterministic),
        station,
        reference,
        explore_m=request.explore_m,
        legs=request.explore_legs,
        guided=request.guided,
        ref_index=ref_index,
    )
    try:
        measurement = _measurement_images(rig, station, vse)
        start = CoarseStart(
            rig=rig,
            session=session,
            reference=reference,
            ref_index=ref_index,
            station=station,
            scale=scale.scale,
            scale_rel_std=scale.scale_std / scale.scale,
            evaluate=hooks.evaluate,
            measured_images=measurement[0],
            grab_measured=lambda: grab_gray_under(rig, vse, measurement[1]),
        )
        init, coarse_result = _initial_alignment(start, request.coarse)
        result = _run_racr_loop(
            start,
            request,
            hooks,
            vse=vse,
            measurement=measurement,
            init=init,
            coarse_result=coarse_result,
            # the camera stands at the image localizer's reference only when nothing moved it since
            image_prior_sigma_mm=prior_sigma_mm if coarse_result is None else None,
        )
        rig.progress(0, 0, "settling at the reached pose")
        state = session.settle(frames=2)
        points = np.asarray(state.cloud.points, dtype=float) * scale.scale
        lightings = _with_measured(request.lightings, measurement[1])
        images = grab_images(rig, lightings)
        meta = _visit_metadata(rig, request, scale, result, coarse_result, measurement=measurement)
        meta["lightings"] = lightings
        rig.progress(0, 0, "writing the visit")
        log = "".join(
            [json.dumps(e) + "\n" for e in request.earlier_log] + [r.to_json() + "\n" for r in result.records]
        )
        obs = _write_visit(
            station,
            meta,
            images=images,
            points=points,
            state=state,
            log=log.encode("utf-8"),
            coarse_result=coarse_result,
            evaluation=hooks.evaluation,
        )
    finally:
        vse.stop()
    return CaptureResult(str(obs.path), scale, int(len(points)), list(images), relocation=result, coarse=coarse_result)


def _initial_alignment(start: CoarseStart, coarse: CoarseConfig | None) -> tuple[np.ndarray, CoarseResult | None]:
    """The alignment the rACR loop starts from, and the coarse stage's result when it ran.

    The first camera is near the reference camera; checked by a fast alignment of the
    whole current cloud, with the global multi-start registration as fallback.
    """
    from fgcd_cli.alignment.initial import initial_guess

    rig, scale = start.rig, start.scale
    rig.progress(0, 0, "initial alignment to the reference")
    first = start.session.tracking_state()
    T_cur_cam0 = np.array(first.T_map_cam, dtype=float)
    T_cur_cam0[:3, 3] *= scale
    guess = initial_guess(
        T_ref_camref=start.reference.T_ref_camref,
        T_cur_cam0=T_cur_cam0,
        cur_points=np.asarray(first.cloud.points, dtype=float) * scale,
        reference=start.ref_index,
        scale=1.0,
    )
    init = guess.T_ref_cur
    rig.say(f"initial alignment: {guess.source}" + (f" ({guess.fast.health.reason})" if guess.fast is not None else ""))
    if coarse is None:
        return init, None
    first_trusted = guess.fast is not None and guess.fast.health.ok
    coarse_result, init = maybe_coarse(start, init, coarse, first_trusted=first_trusted)
    return init, coarse_result


def _run_racr_loop(
    start: CoarseStart,
    request: RelocateRequest,
    hooks: RelocateHooks,
    *,
    vse,
    measurement: tuple[dict[str, np.ndarray], str | None],
    init: np.ndarray,
    coarse_result: CoarseResult | None,
    image_prior_sigma_mm: float | None,
) -> RelocationResult:
    """Drive the camera back to the reference pose with the rACR loop, from the initial alignment.

    Parameters
    ----------
    start : CoarseStart
        The rig, session, reference (and its index), station and scale of this revisit.
    request : RelocateRequest
        The loop's configuration (``request.config``).
    hooks : RelocateHooks
        The evaluation (simulated runs) and the per-record callback, passed to the loop.
    vse
        The running VSE, whose images the image stage grabs.
    measurement : (dict, str or None)
        The reference images the image stage compares with, and the rig lamp it
        measures under (None: the day's light), from :func:`_measurement_images`.
    init : ndarray
        The 4x4 alignment (reference from current) the loop starts from.
    coarse_result : CoarseResult or None
        What the coarse stage did, when it ran.
    image_prior_sigma_mm : float or None
        The image localizer's prior on the camera's offset (None once anything moved the camera).

    Returns
    -------
    RelocationResult
        The loop's result and records.

    Raises
    ------
    AlgorithmError
        The loop paused; ``coarse_result`` is attached to it so that what the coarse
        stage did before stays available to the caller.
    """
    rig, station = start.rig, start.station
    ref_images, same_light = measurement
    rig.say(f"relocating ({request.config.loop_name}) to the reference of station '{station.name}'")
    rig.progress(0, 0, "relocating")
    try:
        return relocate(
            LoopContext(
                session=start.session,
                reference=start.reference,
                ref_index=start.ref_index,
                camera=rig.intrinsics,
                scale=start.scale,
                T_flange_cam=rig.T_flange_cam,
                init=init,
                config=request.config,
                evaluate=hooks.evaluate,
                on_record=hooks.on_record,
                reference_images=ref_images,
                grab_current=lambda: grab_gray_under(rig, vse, same_light),
                image_prior_sigma_mm=image_prior_sigma_mm,
                same_light=same_light is not None,
            )
        )
    except AlgorithmError as exc:
        # the loop paused: what the coarse stage did before stays available to the caller
        exc.coarse_result = coarse_result
        raise


def _measurement_images(rig: RigHandles, station, vse) -> tuple[dict[str, np.ndarray], str | None]:
    """The reference images the image stage compares with, and the light it measures under (None: the day's)."""
    ref_images = reference_images(station)
    same_light = measurement_lighting(rig, list(ref_images))
    alone = None if same_light is None else lamp_alone_now(rig, vse, station.reference().metadata, same_light, rig.say)
    if alone is not None:
        # a dark world's lamp image is the lamp alone: compared with the lamp's own image taken now
        return {alone: ref_images[same_light]}, alone
    if same_light is not None:
        # like with like: the image stage compares with the reference image of that light only
        ref_images = {same_light: ref_images[same_light]}
        if flash_lamp(same_light) is not None:
            rig.say(
                f"the image stage measures on the lamp's own image ({same_light}): "
                "the same on every visit, whatever the day's light"
            )
        else:
            rig.say(f"the image stage measures under the reference's light ({same_light}), lit by the rig's own lamp")
    else:
        rig.say(
            f"the image stage measures across lightings: no lamp of this rig makes the reference's light "
            f"({', '.join(ref_images) or 'none'})"
        )
    return ref_images, same_light


def _with_measured(lightings: list[str], measured: str | None) -> list[str]:
    """The visit's lightings with the lamp image the image stage measured on (a dark world's lamp alone,
    :func:`~fgcd_cli.app.lamp_image.lamp_alone_now`), so that the change map can compare it too."""
    if measured is None or flash_lamp(measured) is None or measured in lightings:
        return list(lightings)
    return [*lightings, measured]


def _visit_metadata(
    rig: RigHandles,
    request: RelocateRequest,
    scale,
    result: RelocationResult,
    coarse_result: CoarseResult | None,
    *,
    measurement: tuple[dict[str, np.ndarray], str | None],
) -> dict:
    """The visit manifest's metadata: lightings, scale, the relocation's outcome (with the light its image
    stage measured under, ``measurement`` from :func:`_measurement_images`) and the rig's calibration."""
    return {
        "lightings": request.lightings,
        "scale": scale.__dict__,
        "relocation": {
            "converged": result.converged,
            "reason": result.reason,
            "adjustments": result.adjustments,
            "wall_s": result.wall_s,
            "session_s": result.session_s,
            "platform_s": result.platform_s,
            "synthetic_s": result.synthetic_s,
            "mode": request.config.mode,
            "run": run_conditions(request.config, request.metadata),
            "residual": result.residual.to_dict() if result.residual else None,
            "image_stage": {
                "measured_under": measurement[1] or "the day's light",
                "compared_with": list(measurement[0]),
            },
        },
        "coarse": None
        if coarse_result is None
        else {
            "handed_over": coarse_result.handed_over,
            "reason": coarse_result.reason,
            "steps": len(coarse_result.steps),
        },
        "T_flange_cam": np.asarray(rig.T_flange_cam).tolist(),
        "T_base_flange": np.asarray(rig.guard.platform.flange_pose()).tolist(),
        "intrinsics": rig.intrinsics.to_dict(),
        **(request.metadata or {}),
    }


def _write_visit(
    station,
    meta: dict,
    *,
    images: dict[str, np.ndarray],
    points: np.ndarray,
    state,
    log: bytes,
    coarse_result: CoarseResult | None,
    evaluation: Callable[[], dict] | None,
):
    """Write the visit (images, cloud, relocation and coarse logs, truth) and return the committed observation."""
    stamp_writer = station.new_visit(meta)
    with run_record.writing(f"the visit of station '{station.name}'"), stamp_writer as w:
        for name, img in images.items():
            w.add_image(name, img)
        w.add_cloud(points, colors=np.asarray(state.cloud.intensities, dtype=np.float32))
        w.add_bytes(schema.RELOCATION_LOG, log)
        if coarse_result is not None and coarse_result.steps:
            w.add_bytes(
                schema.COARSE_LOG,
                "".join(json.dumps(st.to_dict(), default=float) + "\n" for st in coarse_result.steps).encode("utf-8"),
            )
        if evaluation is not None:
            w.add_json(schema.SIM_TRUTH, evaluation())
        return w.commit()
