"""The revisit with the ACR baseline (``fgcd relocate --method acr|acr-h``): one reference image, no VSE.

The same visit as rACR's (:mod:`fgcd_cli.app.relocate`): images under the
visit's lightings, ``relocation.jsonl`` with one :class:`AdjustmentRecord` per
adjustment, the simulator's truth in ``evaluation/``. What differs is the
method (:mod:`fgcd_cli.relocation.acr.baseline`): no exploration, no map, no cloud in
the visit, the hand-eye taken as the identity. Every motion goes through the
rig's :class:`fgcd_core.platform.MotionGuard`, cut into the guard's largest steps.

Rig time follows the rACR session's model (docs/relocation.md, "Time"): the
platform's own motion time, plus the computation while the platform stands
still, plus the frames waited for (the simulator's rendering left out, at least
1/30 s a frame).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from fgcd_cli.app.capture import CaptureResult
from fgcd_cli.app.rig import RigHandles
from fgcd_cli.app.session import grab_gray, grab_images
from fgcd_cli.campaign import schema
from fgcd_cli.errors import CampaignError, run_record
from fgcd_cli.relocation.acr.baseline import AcrConfig, AcrRig, acr_relocate
from fgcd_cli.relocation.acr.pose import AcrModel
from fgcd_cli.relocation.log import RelocationResult
from fgcd_cli.relocation.session import ScaleEstimate, SessionTiming, recorded_motion
from fgcd_core.se3 import exp_se3, log_se3, rotation_angle_rad

if TYPE_CHECKING:
    from fgcd_cli.app.relocate_request import RelocateHooks, RelocateRequest

__all__ = ["acr_relocate_and_capture", "acr_reference_image"]

#: Frame rate of the modelled streaming camera (as :class:`fgcd_cli.relocation.session.VseSession`).
CAMERA_FPS = 30.0


def acr_reference_image(station) -> tuple[str, np.ndarray]:
    """ACR's one reference image: the reference observation's first lighting (its capture light)."""
    ref = station.reference()
    names = [n for n in ref.metadata.get("lightings", []) if n in set(ref.image_names())] or list(ref.image_names())
    if not names:
        raise CampaignError(f"the reference of station '{station.name}' has no image for ACR")
    return names[0], ref.image(names[0])


def _grab_timed(rig: RigHandles, timing: SessionTiming, *, frames: int = 2) -> np.ndarray:
    """The current grey image (``frames`` averaged); the wait counts as rig time without the rendering."""
    synth = rig.frame_synthesis_s
    synth0 = synth() if synth is not None else 0.0
    t0 = time.monotonic()
    image = grab_gray(rig, average=frames)
    timing.count_wait(time.monotonic() - t0, None if synth is None else synth() - synth0, floor_s=frames / CAMERA_FPS)
    return image


def _guarded_move(rig: RigHandles, M_flange: np.ndarray, timing: SessionTiming) -> None:
    """Move the flange by ``M_flange`` (flange frame) through the guard, in steps within its limits."""
    limits = rig.guard.limits
    M = np.asarray(M_flange, dtype=float)
    n = max(
        1,
        math.ceil(
            max(
                float(np.linalg.norm(M[:3, 3])) / limits.max_step_m, rotation_angle_rad(M[:3, :3]) / limits.max_step_rad
            )
            - 1e-9
        ),
    )
    step = exp_se3(log_se3(M) / n)
    with recorded_motion():
        for _ in range(n):
            result = rig.guard.move_by(step)
            timing.platform_s += float(getattr(result, "duration_s", 0.0))
            timing.moves += 1


def _visit_metadata(request: RelocateRequest, result: RelocationResult, reference_name: str) -> dict:
    return {
        "lightings": request.lightings,
        "scale": None,
        "relocation": {
            "method": str(request.method),
            "converged": result.converged,
            "reason": result.reason,
            "adjustments": result.adjustments,
            "wall_s": result.wall_s,
            "session_s": result.session_s,
            "platform_s": result.platform_s,
            "synthetic_s": result.synthetic_s,
            "reference_image": reference_name,
            "residual": None,
        },
        "coarse": None,
        **(request.metadata or {}),
    }


def acr_relocate_and_capture(
    rig: RigHandles, station, request: RelocateRequest, *, hooks: RelocateHooks
) -> CaptureResult:
    """Relocate to the station's reference image with ACR, then write a visit (images, log, truth).

    Raises
    ------
    AlgorithmError
        ACR found no trustworthy relative pose: motion paused, nothing written.
    """
    name, reference_image = acr_reference_image(station)
    timing = SessionTiming()
    acr_rig = AcrRig(
        grab=lambda: _grab_timed(rig, timing),
        move=lambda M: _guarded_move(rig, M, timing),
        timing=timing,
        say=rig.say,
        evaluate=hooks.evaluate,
        on_record=hooks.on_record,
    )
    config = request.acr or AcrConfig()
    # the two-view model follows the method (acr: essential matrix; acr-h: homography)
    config = replace(config, pose=replace(config.pose, model=AcrModel(str(request.method))))
    handeye = "the calibrated hand-eye" if config.use_handeye else "hand-eye taken as the identity"
    rig.say(f"relocating ({request.method}) to the reference image '{name}' of station '{station.name}' ({handeye})")
    rig.progress(0, 0, "relocating")
    result = acr_relocate(
        acr_rig,
        reference_image,
        rig.intrinsics.K,
        config=config,
        T_flange_cam=rig.T_flange_cam if config.use_handeye else None,
    )
    images = grab_images(rig, request.lightings)
    meta = _visit_metadata(request, result, name)
    rig.progress(0, 0, "writing the visit")
    log = "".join([json.dumps(e) + "\n" for e in request.earlier_log] + [r.to_json() + "\n" for r in result.records])
    with run_record.writing(f"the visit of station '{station.name}'"), station.new_visit(meta) as w:
        for image_name, img in images.items():
            w.add_image(image_name, img)
        w.add_bytes(schema.RELOCATION_LOG, log.encode("utf-8"))
        if hooks.evaluation is not None:
            w.add_json(schema.SIM_TRUTH, hooks.evaluation())
        obs = w.commit()
    scale = ScaleEstimate(
        scale=math.nan, scale_std=math.nan, n_samples=0, residual_rms_mm=math.nan, method="none: ACR builds no map"
    )
    return CaptureResult(str(obs.path), scale, 0, list(images), relocation=result)
