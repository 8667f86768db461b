"""Fine-grained scale-aware alignment (rACR §3.4.3, Eqs. 10, 11, 16–18).

Minimises ``alpha * E_g + (1 - alpha) * E_p`` from the fast alignment's result:

* ``E_p`` (Eq. 10): each selected reference point is projected into every
  *current* keyframe where it is visible (nearest point per image cell, the
  paper's occlusion rule) and the keyframes' intensities are compared with each
  other, never with reference images, so lighting changes between the sessions
  do not enter. For the squared loss ``sum_{u,v} (I_u - I_v)^2 = 2K sum_u (I_u - I_mean)^2``,
  so the residuals are taken against the per-point mean (K instead of K^2/2
  residuals per point), with Huber weights (IRLS).
* ``E_g`` (Eq. 9): each current point's offset from its matched reference point,
  split into the part along the reference normal and the tangential part, each
  with its own robust scale (:class:`~fgcd_cli.alignment.fine_problem.GeometricMatches`).

Step 1 (Eq. 16) refines the current keyframe poses with ``E_p`` and the
similarity fixed; steps 2–3 (Eqs. 17–18) refine the similarity: here R, t and
the scale jointly in one Levenberg–Marquardt problem (the paper alternates R, t
and the scale; the joint 7-parameter step converges in fewer iterations and
the ``-S`` ablation simply drops the scale column). Hand-written LM
(:mod:`~fgcd_cli.alignment.dense_steps`) with analytic Jacobians ``dI/du . du/dX . dX/dparams``
(:mod:`~fgcd_cli.alignment.fine_problem`): ``scipy.optimize.least_squares`` with the
same Jacobian is far slower here (docs/lab/2026-11-25-code-comment-measurements.md, "Alignment") and numeric
Jacobians do not move on bilinearly interpolated images. A blur schedule (sigma 3 then 1 pixel)
widens the basin before the final precise level.

Units: the two terms are normalised by their robust residual scales
(grey levels, metres) and their residual counts, so ``alpha`` weighs
dimensionless mean costs.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from fgcd_cli.alignment.dense_steps import minimise_subset
from fgcd_cli.alignment.evaluation import evaluate_alignment
from fgcd_cli.alignment.fast_config import FastAlignConfig
from fgcd_cli.alignment.fine_config import FineAlignConfig
from fgcd_cli.alignment.fine_problem import Block, FineProblem, GeometricMatches, PhotometricObservations
from fgcd_cli.alignment.photometric import prepare_keyframe, sample, visible_nearest
from fgcd_cli.alignment.reference import ReferenceIndex
from fgcd_cli.alignment.results import HEALTH_OK, AlignmentHealth, FineAlignmentResult, ResidualStats
from fgcd_core.camera import PinholeCamera
from fgcd_core.se3 import exp_se3
from fgcd_core.sim3 import Sim3

__all__ = ["fine_align"]


def _select_points(ref: ReferenceIndex, S: Sim3, poses, camera, images, config, rng):
    """Reference points visible (nearest in their cell) in >= 2 keyframes, textured there."""
    candidates = np.arange(len(ref))
    contrast = ref.contrast
    if contrast is not None:
        candidates = candidates[contrast >= np.percentile(contrast, 30)]
    q = S.apply(ref.points[candidates])
    vis = np.zeros((len(poses), len(candidates)), dtype=bool)
    grad = np.zeros((len(poses), len(candidates)))
    for u, T in enumerate(poses):
        X = (q - T[:3, 3]) @ T[:3, :3]
        uv, in_view = camera.project(X)
        px, py = uv[:, 0], uv[:, 1]
        inside = in_view & (px >= 2) & (px <= camera.width - 3) & (py >= 2) & (py <= camera.height - 3)
        v = visible_nearest(
            np.nan_to_num(uv),
            X[:, 2],
            inside,
            width=camera.width,
            height=camera.height,
            cell_px=config.occlusion_cell_px,
            depth_tol=config.occlusion_depth_tol,
        )
        if np.any(v):
            vals, _ = sample(images[u], uv[v])
            grad[u, v] = np.hypot(vals[:, 1], vals[:, 2])
        vis[u] = v
    seen = vis.sum(axis=0) >= 2
    score = np.where(vis, grad, 0.0).max(axis=0)
    good = np.flatnonzero(seen & (score > 0))
    if len(good) > config.max_photometric_points:
        # Prefer textured points: keep the better-textured half, then a random subset.
        good = good[score[good] >= np.median(score[good])]
        if len(good) > config.max_photometric_points:
            good = rng.choice(good, config.max_photometric_points, replace=False)
    sel = candidates[good]
    pt_list, kf_list = [], []
    for k, g in enumerate(good):
        us = np.flatnonzero(vis[:, g])
        pt_list.append(np.full(len(us), k))
        kf_list.append(us)
    if not pt_list:
        return sel, np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    return sel, np.concatenate(pt_list), np.concatenate(kf_list)


def _undistorted(camera: PinholeCamera, keyframes):
    if not camera.has_distortion:
        return camera, [img for _, img in keyframes]
    pinhole = PinholeCamera(
        fx=camera.fx, fy=camera.fy, cx=camera.cx, cy=camera.cy, width=camera.width, height=camera.height
    )
    return pinhole, [cv2.undistort(np.asarray(img), camera.K, np.array(camera.dist)) for _, img in keyframes]


def fine_align(
    *,
    ref_points: np.ndarray | ReferenceIndex,
    ref_intensities: np.ndarray | None = None,
    cur_keyframes: list[tuple[np.ndarray, np.ndarray]],
    camera: PinholeCamera,
    init: Sim3,
    cur_points: np.ndarray | None = None,
    config: FineAlignConfig = FineAlignConfig(),
) -> FineAlignmentResult:
    """Refine ``T_ref_cur`` and the current keyframe poses with geometry and photometry.

    Parameters
    ----------
    ref_points : (M, 3) ndarray or ReferenceIndex
        Reference cloud (metres, ``ref`` frame); pass the loop's ReferenceIndex to reuse it.
    ref_intensities : (M,) ndarray, optional
        Grey values of the reference points; only used to skip textureless points
        (ignored when ``ref_points`` is a ReferenceIndex, which carries its own).
    cur_keyframes : list of (T_cur_cam (4, 4), image (H, W))
        Current keyframes: pose in the current map frame (metric units of
        ``cur_points``) and grey image (uint8 or float32 in [0, 1]).
    camera : PinholeCamera
        Intrinsics of the keyframe images (distortion is removed first if present).
    init : Sim3
        ``T_ref_cur`` from :func:`~fgcd_cli.alignment.fast_align` (or a previous fine run).
    cur_points : (N, 3) ndarray, optional
        Current cloud for ``E_g``; without it only ``E_p`` constrains the similarity.
    config : FineAlignConfig

    Returns
    -------
    FineAlignmentResult
        Refined similarity and keyframe poses; ``health.ok`` False if the result
        moved implausibly far from ``init`` or the geometry check fails.
    """
    t0 = time.perf_counter()
    ctx = _inputs(ref_points, ref_intensities, cur_keyframes, camera, init, config)
    geo = None
    if cur_points is not None and config.alpha > 0:
        geo = _geometric_matches(ctx, cur_points)
    state = _FineState(S=ctx.S0, poses=[T.copy() for T in ctx.poses0])
    for level, blur in enumerate(config.blur_sigmas):
        _refine_level(state, ctx, geo, level, blur)
    if state.obs is not None:
        state.rms_after = state.obs.rms(state.S, state.poses)
    T = state.S.inverse()
    residuals, health = _health(state, T, ctx, cur_points)
    return FineAlignmentResult(
        T_ref_cur=T,
        keyframe_poses=state.poses,
        residuals=residuals,
        photometric_rms_before=state.rms_before,
        photometric_rms_after=state.rms_after,
        health=health,
        iterations=state.iterations,
        seconds=time.perf_counter() - t0,
        photometric_residual_count=state.n_res,
        notes=tuple(state.notes),
    )


@dataclass(frozen=True, kw_only=True)
class _FineInputs:
    """The checked inputs of one :func:`fine_align` call."""

    ref: ReferenceIndex
    camera: PinholeCamera
    raw_images: list[np.ndarray]
    init: Sim3
    S0: Sim3
    poses0: list[np.ndarray]
    rng: np.random.Generator
    config: FineAlignConfig


@dataclass
class _FineState:
    """What the blur levels refine and record."""

    S: Sim3
    poses: list[np.ndarray]
    iterations: int = 0
    converged: bool = True
    notes: list[str] = field(default_factory=list)
    obs: PhotometricObservations | None = None
    rms_before: float = float("nan")
    rms_after: float = float("nan")
    n_res: int = 0


def _inputs(
    ref_points, ref_intensities, cur_keyframes, camera: PinholeCamera, init: Sim3, config: FineAlignConfig
) -> _FineInputs:
    """Check and prepare the inputs: the last keyframes, undistorted; the reference index."""
    if len(cur_keyframes) < 2:
        raise ValueError("fine alignment needs at least 2 current keyframes")
    keyframes = list(cur_keyframes)[-config.max_keyframes :]
    ref = (
        ref_points
        if isinstance(ref_points, ReferenceIndex)
        else ReferenceIndex(np.asarray(ref_points, dtype=float), intensities=ref_intensities)
    )
    cam, raw_images = _undistorted(camera, keyframes)
    for img in raw_images:
        if np.asarray(img).shape[:2] != (cam.height, cam.width):
            raise ValueError(f"keyframe image is {np.asarray(img).shape[:2]}, camera is {(cam.height, cam.width)}")
    return _FineInputs(
        ref=ref,
        camera=cam,
        raw_images=raw_images,
        init=init,
        S0=init.inverse(),
        poses0=[np.array(T, dtype=float) for T, _ in keyframes],
        rng=np.random.default_rng(config.seed),
        config=config,
    )


def _geometric_matches(ctx: _FineInputs, cur_points: np.ndarray) -> GeometricMatches | None:
    """Current points (at most ``max_geometric_points``) matched to the reference at ``init``.

    Matches beyond three times the median distance (at least 3 reference spacings) are
    dropped; the robust scales are the MADs of the normal and tangential offsets at the
    start, floored at a quarter spacing (normal) and the normal scale (tangential).
    None with fewer than 10 matches.
    """
    ref, config = ctx.ref, ctx.config
    cur = np.asarray(cur_points, dtype=float)
    cur = cur[np.all(np.isfinite(cur), axis=1)]
    if len(cur) > config.max_geometric_points:
        cur = cur[ctx.rng.choice(len(cur), config.max_geometric_points, replace=False)]
    d, idx = ref.nearest(ctx.init.apply(cur))
    keep = np.isfinite(d)
    if np.count_nonzero(keep) < 10:
        return None
    thr = max(3.0 * float(np.median(d[keep])), 3 * ref.spacing)
    keep &= d < thr
    x, q, n = cur[keep], ref.points[idx[keep]], ref.normals[idx[keep]]
    n0 = n @ ctx.S0.R.T
    d0 = x - ctx.S0.apply(q)
    rg = np.sum(n0 * d0, axis=1)
    sigma_g = max(1.4826 * float(np.median(np.abs(rg))), ref.spacing / 4)
    rt0 = (d0 - n0 * rg[:, None]).reshape(-1)
    sigma_t = max(1.4826 * float(np.median(np.abs(rt0))), sigma_g)
    return GeometricMatches(x=x, q=q, n=n, sigma_g=sigma_g, sigma_t=sigma_t)


def _refine_level(state: _FineState, ctx: _FineInputs, geo: GeometricMatches | None, level: int, blur: float) -> None:
    """One blur level: keyframe poses with ``E_p`` (Eq. 16), then the similarity (Eqs. 17-18)."""
    config = ctx.config
    images = [prepare_keyframe(img, blur_sigma=blur) for img in ctx.raw_images]
    sel, pt, kf = _select_points(ctx.ref, state.S, state.poses, ctx.camera, images, config, ctx.rng)
    if len(pt) < 50:
        state.notes.append(f"level {level}: only {len(pt)} photometric observations")
        state.converged = False
        return
    obs = PhotometricObservations(
        camera=ctx.camera, images=images, ref_pts=ctx.ref.points[sel], pt=pt, kf=kf, n_kf=len(state.poses)
    )
    r0, ok0, _ = obs.residuals(state.S, state.poses, block=None)
    sigma_p = max(1.4826 * float(np.median(np.abs(r0[ok0]))) if ok0.any() else 0.0, config.min_photometric_sigma)
    problem = FineProblem(obs, geo, alpha=config.alpha, sigma_p=sigma_p)
    state.obs = obs
    if level == len(config.blur_sigmas) - 1:
        state.rms_before = obs.rms(ctx.S0, ctx.poses0)
        state.n_res = int(np.count_nonzero(ok0))
    if config.refine_keyframes:
        S = state.S
        K = len(state.poses)
        # Moving all keyframes together is (nearly) a change of the similarity,
        # observed by E_p only through parallax: fix that gauge (zero mean
        # correction) and leave it to the similarity step, where E_g sees it.
        state.poses, it, _ = minimise_subset(
            lambda poses, jac: problem.cost(S, poses, block=Block.KEYFRAMES if jac else None, with_geometry=False),
            lambda poses, delta: [T @ exp_se3(delta[6 * u : 6 * u + 6]) for u, T in enumerate(poses)],
            state.poses,
            iterations=config.keyframe_iterations,
            free=np.arange(6 * K),
            gauge=np.tile(np.eye(6), (1, K)) / K,
        )
        state.iterations += it
    poses = state.poses
    free_sim = np.arange(7) if config.estimate_scale else np.arange(6)
    state.S, it, _ = minimise_subset(
        lambda S, jac: problem.cost(S, poses, block=Block.SIMILARITY if jac else None, with_geometry=True),
        lambda S, delta: Sim3.exp(delta) @ S,
        state.S,
        iterations=config.similarity_iterations,
        free=free_sim,
    )
    state.iterations += it


def _health(state: _FineState, T: Sim3, ctx: _FineInputs, cur_points: np.ndarray | None):
    """Geometric checks as in the fast alignment, plus plausibility of the change from ``init``."""
    config, ref, init = ctx.config, ctx.ref, ctx.init
    change = T @ init.inverse()
    shift = float(np.linalg.norm(change.apply(ref.centroid) - ref.centroid))
    problems = []
    if change.rotation_deg() > config.max_rotation_change_deg:
        problems.append(f"moved {change.rotation_deg():.1f} deg from the fast result")
    if abs(math.log(change.scale)) > config.max_scale_change:
        problems.append(f"scale changed by {100 * (change.scale - 1):+.1f} % from the fast result")
    if shift > config.max_translation_change_rel * ref.width:
        problems.append(f"moved {shift * 1e3:.0f} mm from the fast result")
    if not (state.rms_after <= state.rms_before * 1.001):
        problems.append("photometric error did not decrease")
    if cur_points is not None:
        cur_all = np.asarray(cur_points, dtype=float)
        cur_all = cur_all[np.all(np.isfinite(cur_all), axis=1)]
        residuals, geo_health = evaluate_alignment(
            T, cur_all, ref, converged=state.converged, scale_ratio=T.scale / init.scale, config=FastAlignConfig()
        )
    else:
        nan = float("nan")
        residuals = ResidualStats(count=0, rms_mm=nan, median_mm=nan, inlier_threshold_mm=nan)
        geo_health = AlignmentHealth(
            ok=True,
            reason=HEALTH_OK,
            converged=state.converged,
            overlap=nan,
            inlier_ratio=nan,
            condition_ratio=nan,
            degenerate=False,
        )
    if not geo_health.ok:
        problems.append(geo_health.reason)
    if not state.converged:
        problems.append("; ".join(state.notes) or "did not converge")
    health = AlignmentHealth(
        ok=not problems,
        reason=HEALTH_OK if not problems else "; ".join(dict.fromkeys(problems)),
        converged=state.converged,
        overlap=geo_health.overlap,
        inlier_ratio=geo_health.inlier_ratio,
        condition_ratio=geo_health.condition_ratio,
        degenerate=geo_health.degenerate,
        weak_directions=geo_health.weak_directions,
    )
    return residuals, health
