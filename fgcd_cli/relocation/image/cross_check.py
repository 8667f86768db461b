"""Independent checks of an image (PnP) estimate before the loop trusts it (docs/relocation.md, "Stop rules").

No single estimator may say "converged" (issue 25). An image estimate is
compared with the 3D geometry of the same view:

* the alignment thread's estimate of a view after the last motion (serial mode:
  one alignment now), within ``k sqrt(sigma_img^2 + sigma_3d^2)``
  (:func:`~fgcd_cli.relocation.stop_rule.estimates_agree`);
* without one (the 3D loop paused, or none came in time), paper 001's camera
  uncertainty of the image estimate: the reference cloud rendered at the
  estimate, registered with what the session observes (its depths set to the
  rendering's on the same pixels: the session's scale is uncertain, so
  the distance to the object is not judged here); the residual's part the geometry constrains is
  the distance between the two, under the bound of both uncertainties: the
  image estimate's and the check's own (the covariance model along the
  directions the view's geometry constrains: a near-plane barely constrains
  its tilts, so a distorted monocular cloud can tilt the registration by more
  than a cloud's 1 % placement error; never less than that).

A large correction is *confirmed* only by a check that could have told it
apart from no correction at all: the check agrees and its bound is below the
correction's size.

The result is a plain dict for the log (``AdjustmentRecord.agreement``):
``agree`` (True, False, or None when no geometric estimate was available),
``distance_mm``, ``bound_mm``, ``check`` ("alignment" or "camera uncertainty")
and a ``note``.
"""

from __future__ import annotations

import math
import time

import numpy as np

from fgcd_cli.relocation.loop.context import LoopContext, LoopState
from fgcd_cli.relocation.racr.estimates import fresh_3d_estimate
from fgcd_cli.relocation.stop_rule import estimates_agree, offset_vector_mm

__all__ = ["ALIGNMENT", "CAMERA_UNCERTAINTY", "geometry_check"]

ALIGNMENT = "alignment"
CAMERA_UNCERTAINTY = "camera uncertainty"


def _alignment_check(
    ctx: LoopContext, st: LoopState, after_frame: int, T_ref_cam_img: np.ndarray, sigma_img_mm: float
) -> dict:
    """The alignment's estimate of the same view against the image estimate."""
    T_3d, note = fresh_3d_estimate(ctx, st, after_frame)
    if T_3d is None:
        return {"agree": None, "note": note, "check": ALIGNMENT}
    T_ref_camref = ctx.reference.T_ref_camref
    d_img = offset_vector_mm(T_ref_cam_img, T_ref_camref)
    d_3d = offset_vector_mm(T_3d, T_ref_camref)
    ok, dist, bound = estimates_agree(d_img, sigma_img_mm, d_3d, st.sigma3d_mm, k=ctx.config.agreement_k)
    return {
        "agree": ok,
        "distance_mm": dist,
        "bound_mm": bound,
        "offset_3d_mm": float(np.linalg.norm(d_3d)),
        "sigma_3d_mm": st.sigma3d_mm,
        "note": "",
        "check": ALIGNMENT,
    }


def _camera_uncertainty_check(ctx: LoopContext, st: LoopState, T_ref_cam_img: np.ndarray, sigma_img_mm: float) -> dict:
    """Paper 001's camera uncertainty of the image estimate (constrained part of the residual motion)."""
    from fgcd_cli.relocation.coarse.camera_uncertainty import camera_uncertainty, in_view
    from fgcd_cli.relocation.coarse.config import CoarseConfig

    out = {"agree": None, "check": CAMERA_UNCERTAINTY}
    if ctx.camera is None:
        return {**out, "note": "no camera model"}
    t0 = time.monotonic()
    state = ctx.session.vse.latest()
    if state.T_map_cam is None or len(state.cloud) == 0:
        return {**out, "note": "no session cloud"}
    T_cur_cam = np.array(state.T_map_cam, dtype=float)
    T_cur_cam[:3, 3] *= ctx.scale
    observed, _ = in_view(np.asarray(state.cloud.points, dtype=float) * ctx.scale, T_cur_cam, ctx.camera)
    observed = _depth_normalised(observed, ctx.reference.points, T_ref_cam_img, ctx.camera)
    config = CoarseConfig()
    unc = camera_uncertainty(observed, ctx.reference.points, T_ref_cam_img, ctx.camera, config=config)
    ctx.session.timing.wait_s += time.monotonic() - t0
    if not math.isfinite(unc.constrained_translation_m) or unc.fitness < config.min_fitness:
        return {
            **out,
            "note": f"camera uncertainty not measurable ({unc.observed} observed points, overlap {unc.fitness:.0%})",
        }
    dist = 1000.0 * unc.constrained_translation_m
    sa = sigma_img_mm if math.isfinite(sigma_img_mm) else 0.0
    # the check's own uncertainty: the covariance model along the directions it constrains, never less
    # than a cloud's placement (vse_sigma_rel x depth); on a near-plane its tilts are barely constrained
    sigma_check = max(st.sigma3d_mm, 1000.0 * unc.check_sigma_m)
    bound = ctx.config.agreement_k * math.hypot(sa, sigma_check)
    return {
        **out,
        "agree": bool(dist <= bound),
        "distance_mm": dist,
        "bound_mm": bound,
        "sigma_3d_mm": sigma_check,
        "weak_directions": unc.weak_directions,
        "note": "",
    }


def _depth_normalised(
    observed: np.ndarray,
    ref_points: np.ndarray,
    T_ref_cam: np.ndarray,
    camera,
    *,
    stride_px: int = 4,
    min_pixels: int = 100,
) -> np.ndarray:
    """The observed cloud (N, 3), camera frame, metres, scaled about the camera so that its depths match the
    reference rendering's at ``T_ref_cam`` *on the same pixels* (median ratio over the pixel bins both cover).

    A monocular session's scale is known only to what its exploration measured (the alignment's own scale
    absorbs the rest, docs/relocation.md "What a session does"); a scale error moves every observed point
    along its ray, which on a flat object is the same as a shift along the view. So this check does not
    judge the distance to the object (the image estimate and the frames do). The ratio is taken pixel by
    pixel because the session cloud covers only what its exploration saw: medians over different parts of
    a leaning slab differ by more than the scale error itself. Fewer than ``min_pixels`` shared bins: the
    ratio of the medians.
    """
    from fgcd_cli.relocation.coarse.camera_uncertainty import render_visible_points

    rendered = render_visible_points(ref_points, T_ref_cam, camera, stride_px=stride_px)
    if len(observed) == 0 or len(rendered) == 0:
        return observed
    uv_ren, in_ren = camera.project(rendered)
    uv_obs, in_obs = camera.project(observed)
    cols = int(math.ceil(camera.width / stride_px)) + 1
    rows = int(math.ceil(camera.height / stride_px)) + 1

    def cell(uv: np.ndarray) -> np.ndarray:
        bins = (uv[:, 1] // stride_px).astype(np.int64) * cols + (uv[:, 0] // stride_px).astype(np.int64)
        return np.clip(bins, 0, rows * cols - 1)

    z_ren = np.full(rows * cols, np.nan)
    z_ren[cell(uv_ren[in_ren])] = rendered[in_ren, 2]
    ratio = z_ren[cell(uv_obs[in_obs])] / observed[in_obs, 2]
    ratio = ratio[np.isfinite(ratio) & (ratio > 0)]
    if len(ratio) >= min_pixels:
        return observed * float(np.median(ratio))
    z_obs, z_r = float(np.median(observed[:, 2])), float(np.median(rendered[:, 2]))
    return observed * (z_r / z_obs) if z_obs > 0 and z_r > 0 else observed


def geometry_check(
    ctx: LoopContext,
    st: LoopState,
    after_frame: int,
    T_ref_cam_img: np.ndarray,
    sigma_img_mm: float,
    *,
    use_alignment: bool = True,
) -> dict:
    """Compare an image estimate of the current camera with the 3D geometry of the same view.

    Parameters
    ----------
    ctx, st :
        The run's inputs and shared state.
    after_frame : int
        VSE frame count after the last motion: the 3D estimate must be of a later view.
    T_ref_cam_img : (4, 4) ndarray
        The image estimate of the current camera, ``ref`` frame, metres.
    sigma_img_mm : float
        Its RMS-radius uncertainty, mm.
    use_alignment : bool
        False when the 3D loop paused or its alignment was set aside (it is what failed): the camera
        uncertainty only.

    Returns
    -------
    dict
        See the module docstring; the alignment's verdict when it has one, else the camera uncertainty's.
    """
    first = (
        _alignment_check(ctx, st, after_frame, T_ref_cam_img, sigma_img_mm)
        if use_alignment
        else {"agree": None, "note": "the 3D alignment not asked (paused or set aside)", "check": ALIGNMENT}
    )
    if first["agree"] is not None:
        return first
    second = _camera_uncertainty_check(ctx, st, T_ref_cam_img, sigma_img_mm)
    if second["agree"] is None:
        second["note"] = f"{first['note']}; {second['note']}"
    return second
