"""The coarse stage's passive localizers and their check (paper 001: "how to locate", "whether to trust").

Two independent estimates of the current camera in the reference frame, the
image one (SIFT matches to the reference images lifted to 3D by the reference
cloud, PnP: :func:`image_estimate`) and the 3D alignment of the session cloud;
each checked by its camera uncertainty
(:mod:`fgcd_cli.relocation.coarse.camera_uncertainty`) at the scale
:func:`check_scale` chooses. :func:`localize` gives the best verified one of a
view, else the best unverified one that overlaps the reference.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from fgcd_cli.relocation.coarse.camera_uncertainty import CameraUncertainty, camera_uncertainty, in_view
from fgcd_cli.relocation.coarse.stage_inputs import CoarseInputs
from fgcd_cli.relocation.enums import EstimateSource
from fgcd_core.se3 import invert_pose, pose_distance
from fgcd_core.sim3 import Sim3

__all__ = ["View", "check_scale", "image_estimate", "localize", "residual_m"]


def image_estimate(
    *, reference_images: dict[str, np.ndarray], current_image: np.ndarray, camera, reference
) -> tuple[np.ndarray | None, dict]:
    """The image (PnP) passive localizer: the current camera in ``ref``, or None.

    Parameters
    ----------
    reference_images : dict of name -> (H, W) ndarray
        Undistorted reference images.
    current_image : (H, W) ndarray
        Undistorted current image.
    camera : PinholeCamera
    reference : ReferenceData
        ``points`` (N, 3) metres and ``T_ref_camref`` (4, 4).

    Returns
    -------
    T_ref_cam : (4, 4) ndarray or None
        None when the matches do not make a PnP solution (too few, too few inliers, large residual).
    info : dict
        PnP outcome for the log.

    Unlike the loop's image stage, any motion size is accepted here: the camera
    uncertainty, not the size of the correction, decides whether it is trusted.
    """
    from fgcd_cli.relocation.image.refine import ImageRefineConfig, refine_from_reference_image

    config = replace(
        ImageRefineConfig(),
        max_motion_m=10.0,
        max_motion_deg=180.0,
        strong_max_motion_m=10.0,
        strong_max_motion_deg=180.0,
    )
    T_ref_camref = np.asarray(reference.T_ref_camref, dtype=float)
    pnp = refine_from_reference_image(
        reference_images=reference_images,
        current_image=current_image,
        camera=camera,
        ref_points=reference.points,
        T_ref_camref=T_ref_camref,
        config=config,
    )
    info = {"pnp": pnp.reason, "inliers": pnp.inliers, "sigma_mm": pnp.offset_sigma_mm}
    return (T_ref_camref @ invert_pose(pnp.M_cam) if pnp.ok else None), info


@dataclass(frozen=True, kw_only=True)
class View:
    """What one view gave: the camera in the session's metric frame (4, 4), the log notes, the
    best verified estimate ``(source, T_ref_cam corrected (4, 4), its uncertainty)`` if any, and
    else the best unverified one ``(source, T_ref_cam (4, 4), its uncertainty)`` that overlaps the
    reference (or None)."""

    T_cur_cam: np.ndarray
    notes: dict
    best: tuple[EstimateSource, np.ndarray, CameraUncertainty] | None
    unverified: tuple[EstimateSource, np.ndarray, CameraUncertainty] | None = None
    """When nothing verified: the estimate that overlaps the observation with the smallest residual."""


def _candidates(inp: CoarseInputs, cloud: np.ndarray, T_cur_cam: np.ndarray, last_3d: Sim3):
    """The passive localizers' estimates of the current camera in ``ref``, and their notes for the log."""
    from fgcd_cli.alignment.fast import fast_align
    from fgcd_cli.alignment.initial import global_registration

    candidates: dict[EstimateSource, np.ndarray] = {}
    notes: dict[str, dict] = {}
    fast = fast_align(cloud, inp.ref_index, init=last_3d)
    if not fast.health.ok and not fast.health.degenerate:
        fast = global_registration(cloud, inp.ref_index, around=last_3d)
    candidates[EstimateSource.THREE_D] = fast.T_ref_cur.transform_pose(T_cur_cam)
    notes[EstimateSource.THREE_D] = {
        "alignment": fast.health.reason,
        "scale": float(fast.T_ref_cur.scale),
        "scale_measured": bool(fast.health.scale_measured),
    }
    if inp.reference_images and inp.grab_current is not None:
        T_img, notes[EstimateSource.IMAGE] = image_estimate(
            reference_images=inp.reference_images,
            current_image=inp.grab_current(),
            camera=inp.camera,
            reference=inp.reference,
        )
        if T_img is not None:
            candidates[EstimateSource.IMAGE] = T_img
    return candidates, notes


def check_scale(alignment_scale: float, *, scale_rel_std: float, scale_measured: bool = False) -> float:
    """The factor that brings the session's metric cloud to the reference's scale for the check.

    The check registers shapes: a cloud 3 % too small at 1.5 m reads as a 45 mm slide along the
    view, whatever the estimate. The session's metric scale comes from the exploration's short
    legs (a few % of error, ``scale_rel_std``, which does not count the monocular map's drift since);
    the alignment's Sim3 scale measures the ratio of the two clouds themselves (docs/relocation.md,
    "Far starts"). It is used when it lies within three sigmas of the session's, or, for a monocular
    session (``scale_rel_std`` > 0), whenever the alignment measured it (``scale_measured``: converged,
    overlapping, and the scale well conditioned, :attr:`AlignmentHealth.scale_measured`, even if the
    pose slides along a weak direction); else the alignment is suspect and the session's scale stands
    (1). Pass ``scale_measured`` only for an estimate independent of the alignment: checked at the
    alignment's own scale, the alignment's estimate would be checked against itself.
    """
    s = float(alignment_scale)
    if not (math.isfinite(s) and s > 0):
        return 1.0
    sigma = max(float(scale_rel_std), 0.0)
    return s if abs(math.log(s)) <= 3.0 * sigma or (scale_measured and sigma > 0) else 1.0


def localize(inp: CoarseInputs, step: int, last_3d: Sim3) -> View:
    """Both localizers on the current view, each checked by its camera uncertainty; the best verified one."""
    session, camera, config = inp.session, inp.camera, inp.config
    T_ref_camref = np.asarray(inp.reference.T_ref_camref, dtype=float)
    state = session.tracking_state()
    T_cur_cam = np.array(state.T_map_cam, dtype=float)
    T_cur_cam[:3, 3] *= inp.scale
    cloud = np.asarray(state.cloud.points, dtype=float) * inp.scale
    observed, _ = in_view(cloud, T_cur_cam, camera)
    # the platform waits for the stills and the localizers, not for the simulator's rendering
    with session.standing_still(stills=2):
        candidates, notes = _candidates(inp, cloud, T_cur_cam, last_3d)
        align = notes[EstimateSource.THREE_D]
        best = unverified = None
        for name, T_ref_cam in candidates.items():
            geometric = name == EstimateSource.THREE_D
            notes[name]["check_scale"] = s_check = check_scale(
                align["scale"],
                scale_rel_std=inp.scale_rel_std,
                scale_measured=align["scale_measured"] and not geometric,
            )
            unc = camera_uncertainty(
                observed * s_check, inp.reference.points, T_ref_cam, camera, config=config, seed=step
            )
            notes[name]["uncertainty"] = unc.to_dict()
            notes[name]["offset_mm"], notes[name]["offset_deg"] = pose_distance(T_ref_cam, T_ref_camref)
            # the estimated camera centre in the reference camera frame (the scene uncertainty map's frame)
            notes[name]["position_refcam_m"] = (invert_pose(T_ref_camref) @ T_ref_cam)[:3, 3].tolist()
            if unc.verified(config, geometric_source=geometric) and (
                best is None or unc.constrained_translation_m < best[2].constrained_translation_m
            ):
                best = (name, T_ref_cam @ unc.correction(geometric_source=geometric), unc)
            if unc.fitness >= config.min_fitness and (
                unverified is None or residual_m(unc, name) < residual_m(unverified[2], unverified[0])
            ):
                unverified = (name, T_ref_cam, unc)
    return View(T_cur_cam=T_cur_cam, notes=notes, best=best, unverified=None if best is not None else unverified)


def residual_m(unc: CameraUncertainty, source: EstimateSource) -> float:
    """The residual an estimate is judged on: all of it for the geometry's own, the constrained part for an image
    estimate (:meth:`CameraUncertainty.verified`)."""
    return unc.translation_m if source == EstimateSource.THREE_D else unc.constrained_translation_m
