"""Fast scale-aware alignment (rACR §3.4.2, Eqs. 12–15).

Alternates a robust rigid step (sparse ICP, Eq. 13) with the closed-form scale
step (Eq. 15) until the change of the rigid part is below ``tau_T`` and the
change of the scale below ``tau_sigma``. Two measures keep it from collapsing
(similarity ICP shrinks the scale when started without a prior):

* the scale starts from a prior (the given ``init``, or the ratio of RMS radii),
  and the first, widest correspondence level estimates only R and t;
* coarse-to-fine: few points with unbounded correspondences first, then more
  points with shrinking correspondence radii.

The scale step is Eq. (15) with the translation re-solved jointly (weighted
centroids), over the correspondences that sparse ICP kept as inliers and within
``trim_factor`` times the median residual, weighted by the caller's per-point
confidence: Umeyama-type scale estimates are biased low when the source cloud is
noisy, and trimming/weighting keep that bias at the noise-variance level.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from fgcd_cli.alignment.health import assess, residual_stats
from fgcd_cli.alignment.reference import ReferenceIndex, local_roughness
from fgcd_cli.alignment.results import AlignmentHealth, AlignmentResult, ResidualStats
from fgcd_cli.alignment.sparse_icp import (
    scale_step_point_to_plane,
    sparse_point_to_plane_step,
    sparse_point_to_point_step,
    trimmed_point_to_plane_step,
)
from fgcd_cli.geometry import Sim3, exp_se3, make_pose

__all__ = ["FastAlignConfig", "fast_align", "initial_scale", "as_reference", "evaluate_alignment",
           "probe_weak_directions"]


@dataclass(frozen=True, kw_only=True)
class FastAlignConfig:
    """Options of :func:`fast_align`.

    Distances given as ``*_rel`` are fractions of the reference cloud's width.
    """

    tau_T: float = 1e-4
    """Stop when ``|dT - I|_F`` of the rigid part (metres/radians) falls below this..."""
    tau_sigma: float = 1e-5
    """...and the scale changes by less than this."""
    estimate_scale: bool = True
    """False keeps the initial scale (the paper's rACR-S ablation)."""
    robust: str = "sparse"
    """Rigid step: ``"sparse"`` (sparse ICP, ADMM) or ``"trimmed"`` (trimmed least squares)."""
    sparse_p: float = 0.4
    admm_iterations: int = 1
    """ADMM iterations per correspondence update (one is enough with fresh multipliers; measured as robust as 3)."""
    level_points: tuple[int, ...] = (1500, 5000, 8000)
    """Current points used at each resolution level (random subset). 8000 points at the
    last level give the same accuracy as 20000 (errors are noise-averaged already) at
    twice the rate."""
    health_points: int = 10000
    """Current points (random subset) used for the health checks."""
    level_radius_rel: tuple[float, ...] = (math.inf, 0.2, 0.06)
    """Largest correspondence distance at each level."""
    level_iterations: tuple[int, ...] = (60, 20, 40)
    level_metric: tuple[str, ...] = ("point", "plane", "plane")
    """ICP error per level: ``"point"`` (wide basin) or ``"plane"`` (fast convergence)."""
    scale_from_level: int = 1
    """First level at which the scale step runs (the widest level estimates R, t only)."""
    max_scale_step: float = 0.02
    """Largest relative scale change per iteration."""
    max_scale_drift: float = 0.12
    """Largest relative scale change over a run from its starting scale (after the cold-start
    scale search, whose candidates are 10-25 % apart). Noisy VSE clouds let the least-squares
    scale run away (measured: +40 %) while R, t are still wrong."""
    inlier_factor: float = 3.0
    """Working inlier distance: this times the median correspondence distance."""
    min_inlier_spacing: float = 2.0
    """...but never below this many reference point spacings."""
    trim_factor: float = 3.0
    inlier_rel: float = 0.01
    """Health: a current point is an inlier if within this fraction of the width (>= 3 spacings).
    Assumes the current cloud's noise is below about half of it; a mirrored or
    wrongly registered relief leaves about half of its points beyond it."""
    inlier_noise_factor: float = 3.0
    """...or this many times the combined noise of the two clouds, whichever is larger."""
    overlap_rel: float = 0.05
    min_inlier_ratio: float = 0.6
    min_overlap: float = 0.3
    min_condition_ratio: float = 5e-3
    """Measured: VSE plane 2e-3-6e-3, VSE sphere 4e-4-1e-3; relief of 1 cm on 0.5 m 9e-3, relief panel 0.1."""
    condition_noise_factor: float = 3.0
    """The limit is raised to this times ``(roughness / normal radius)^2`` of the reference: the
    floor that normal noise puts under a plane's smallest eigenvalue."""
    weak_probe: bool = True
    """Below the limit, probe the weak directions before calling the geometry degenerate
    (:func:`probe_weak_directions`). Measured on relocation sessions (VSE clouds, 640 x 480):
    the stele, mural, stupa and brick wall sit at 1e-3-5e-3 with smoothed normals, yet
    perturbations along their three weakest directions come back to within 5-30 % and the
    results are 0.3-0.8 px from the truth; on the plane and sphere scenes they stay (77-230 %)
    and the results are 1-42 px off."""
    weak_probe_rel: float = 0.01
    """Size of a probe perturbation: RMS displacement of the matched points, fraction of the
    reference width (at least 3 times the reference roughness)."""
    weak_probe_directions: int = 3
    weak_probe_return: float = 0.5
    """A direction is pinned if the alignment recovers all but this fraction of the perturbation."""
    weak_probe_points: int = 3000
    weak_probe_iterations: int = 15
    scale_bounds: tuple[float, float] = (1 / 1.5, 1.5)
    """Health: allowed range of the result's scale relative to the initial scale."""
    stall_rel: float = 0.005
    """Also converged when an iteration moves the points by less than this fraction of the
    working inlier distance (noise-level jitter)."""
    warm_rel: float = 0.02
    """Warm start if the median distance of the prior's correspondences is below this fraction of the width."""
    warm_max_scale_change: float = 0.03
    """A warm run that changes the scale by more than this (relative)... Measured on VSE clouds: warm
    runs that moved the scale by 3-5 % included collapses to 15 % off that neither the inlier ratio
    nor the scale-minimum check detects (the cold search corrects them). Was 5 %."""
    warm_max_rotation_deg: float = 3.0
    """...or the rotation by more than this is redone as a cold start."""
    warm_check_scale_change: float = 0.02
    """A warm run that changes the scale by more than this (but within ``warm_max_scale_change``),
    or does not converge, must pass the scale-minimum check; if a neighbouring scale fits better
    it is redone as a cold start. Below it (the relocation loop's steady state) nothing extra runs.
    Measured on VSE clouds: warm runs that stalled 4-10 % off in scale had moved it by 1.7-4.5 %, some
    without converging."""
    scale_candidates: tuple[float, ...] = (0.8, 0.9, 1.0, 1.1, 1.25)
    """Cold start only: relative scales tried with rigid coarse ICP before the scale is estimated."""
    search_score: str = "median"
    """Score of the scale candidates (see :func:`_search_score`)."""
    scale_refinements: int = 2
    """Parabolic refinements of the best candidate scale (0: the grid only)."""
    search_iterations: tuple[int, int] = (40, 10)
    minimum_check_step: float = 0.04
    """Cold starts: the result's scale times ``1 +- this`` (rigidly refitted) must not fit better
    (0: no check). When one does, the run continues from it once; if the next result fails
    again, it is flagged not ok."""
    minimum_check_margin: float = 0.03
    """...by more than this fraction of the median residual."""
    minimum_check_iterations: int = 8
    shift_steps: int = 2
    """Cold start: translations of the prior ``-k..k`` steps along the cloud's two main axes (0: off)."""
    shift_rel: float = 0.06
    """Step of those translations, fraction of the reference width."""
    shift_points: int = 600
    shift_radius_rel: float = 0.1
    shift_iterations: int = 12
    """Iteration limits of the two coarse levels during that scale search."""
    seed: int = 0


def as_reference(ref_points: np.ndarray | ReferenceIndex) -> ReferenceIndex:
    """Wrap an (M, 3) array into a :class:`ReferenceIndex` (reuse one across calls instead)."""
    return ref_points if isinstance(ref_points, ReferenceIndex) else ReferenceIndex(ref_points)


def initial_scale(cur_points: np.ndarray, ref: ReferenceIndex) -> Sim3:
    """Similarity prior without pose knowledge: centroids and the ratio of RMS radii.

    Valid when the two clouds cover the same part of the scene; the relocation
    loop normally has a better prior (:func:`~fgcd_cli.alignment.initial_guess`).
    """
    c = cur_points.mean(axis=0)
    rms = float(np.sqrt(np.mean(np.sum((cur_points - c) ** 2, axis=1))))
    scale = ref.rms_radius / rms if rms > 0 else 1.0
    return Sim3(np.eye(3), ref.centroid - scale * c, scale)


def fast_align(
    cur_points: np.ndarray,
    ref_points: np.ndarray | ReferenceIndex,
    *,
    init: Sim3 | None = None,
    cur_weights: np.ndarray | None = None,
    config: FastAlignConfig = FastAlignConfig(),
) -> AlignmentResult:
    """Similarity ``T_ref_cur`` registering the current cloud to the reference cloud.

    Parameters
    ----------
    cur_points : (N, 3) ndarray
        Current session's cloud in its map frame (metric up to the session scale error).
    ref_points : (M, 3) ndarray or ReferenceIndex
        Reference cloud, metres; pass a :class:`ReferenceIndex` built once to
        avoid rebuilding the KD-tree on every call.
    init : Sim3, optional
        Prior ``T_ref_cur`` (e.g. from :func:`~fgcd_cli.alignment.initial_guess` or the
        previous alignment); without it, centroids and RMS radii give the prior.
    cur_weights : (N,) ndarray, optional
        Confidence of each current point (e.g. inverse depth variance).
    config : FastAlignConfig

    Returns
    -------
    AlignmentResult
        Never raises on bad geometry: check ``result.health.ok``.
    """
    t0 = time.perf_counter()
    cur = np.asarray(cur_points, dtype=float)
    if cur.ndim != 2 or cur.shape[1] != 3:
        raise ValueError(f"current points must be (N, 3), got {cur.shape}")
    finite = np.all(np.isfinite(cur), axis=1)
    weights_all = None if cur_weights is None else np.asarray(cur_weights, dtype=float).reshape(-1)
    if weights_all is not None:
        if len(weights_all) != len(cur):
            raise ValueError("cur_weights must have one value per current point")
        finite &= np.isfinite(weights_all) & (weights_all > 0)
    cur = cur[finite]
    if weights_all is not None:
        weights_all = weights_all[finite]
    ref = as_reference(ref_points)
    T = initial_scale(cur, ref) if init is None else init
    if len(cur) < 10:
        return _failed(T, "fewer than 10 valid current points", t0)

    rng = np.random.default_rng(config.seed)
    order = rng.permutation(len(cur))
    s_prior = T.scale
    normals = ref.normals
    n_levels = len(config.level_points)
    # Warm start (the loop re-aligns from its previous result): skip the coarse
    # level and the scale search when the prior already fits.
    probe = cur[order[:1000]]
    d0, _ = ref.nearest(T.apply(probe))
    warm = bool(np.median(d0) < config.warm_rel * ref.width)
    iterations = 0
    if warm:
        T_out, converged, its, failure = _run_levels(cur, weights_all, ref, normals, order, T,
                                                      range(n_levels - 1, n_levels), config,
                                                      estimate_scale=config.estimate_scale)
        iterations += its
        # A nearly flat surface hides a large scale or rotation error from the warm test
        # (measured: 20 % scale error at a median distance of 0.8 % of the width): the
        # warm run then walks far from its prior, and the start is redone as a cold one.
        if T_out is not None and _close(T_out, T, config):
            moved = abs(math.log(T_out.scale / T.scale))
            path = "warm"
            if (not converged or moved > config.warm_check_scale_change) and config.estimate_scale \
                    and config.minimum_check_step > 0:
                # Rule: a warm start whose scale moved by more than the check threshold is
                # checked against its neighbouring scales, because the joint iteration can
                # stall at a wrong scale with a fine inlier ratio (docs/alignment.md, "Fast
                # alignment"). The loop's steady state moves the scale far less: no cost there.
                better, its = _scale_neighbour(cur, weights_all, ref, normals, order, T_out, probe, config)
                iterations += its
                path = "warm, checked" if better is None else "warm -> cold"
            if path != "warm -> cold":
                result = _finish(T_out, cur[order[: config.health_points]], ref, config, converged, iterations,
                                 t0, scale_prior=s_prior)
                return replace(result, start=path)
        path = "warm -> cold"
    else:
        path = "cold"
    first = 0
    if config.estimate_scale and len(config.scale_candidates) > 1:
        # Cold start: a scale prior that is off by 10-20 % sends similarity ICP
        # astray, so try a few scales with rigid ICP on the coarse levels (scale
        # changed about the mapped centroid) and keep the best-fitting one.
        c_cur = cur.mean(axis=0)
        search = replace(config, level_iterations=tuple(
            min(n, m) for n, m in zip(config.level_iterations, config.search_iterations + config.level_iterations[2:])
        ))
        levels = range(0, min(2, n_levels))
        T = _shift_search(cur, weights_all, ref, normals, order, T, probe, config)
        tried = []  # (log scale, score, T)
        for factor in config.scale_candidates:
            s_c = T.scale * factor
            start = Sim3(T.R, T.apply(c_cur) - s_c * (T.R @ c_cur), s_c)
            out = _run_levels(cur, weights_all, ref, normals, order, start, levels, search, estimate_scale=False)
            iterations += out[2]
            if out[0] is not None:
                tried.append((math.log(s_c), _search_score(out[0], probe, ref, config), out[0]))
        # Refine the best scale by parabolic interpolation of the score in log-scale:
        # the grid is coarse, and from a grid point the joint scale step creeps along
        # nearly flat surfaces and stalls short of the optimum (docs/alignment.md,
        # "Fast alignment").
        for _ in range(config.scale_refinements):
            if len(tried) < 3:
                break
            tried.sort(key=lambda e: e[0])
            i = min(range(len(tried)), key=lambda k: tried[k][1])
            if i == 0 or i == len(tried) - 1:
                break  # the optimum is outside the bracket: keep the best end point
            (x0, f0, _), (x1, f1, T1), (x2, f2, _) = tried[i - 1], tried[i], tried[i + 1]
            denom = (x1 - x0) * (f1 - f2) - (x1 - x2) * (f1 - f0)
            if denom >= 0:
                break  # not convex: no interior minimum
            x = x1 - 0.5 * ((x1 - x0) ** 2 * (f1 - f2) - (x1 - x2) ** 2 * (f1 - f0)) / denom
            x = float(np.clip(x, x0 + 0.1 * (x1 - x0), x2 - 0.1 * (x2 - x1)))
            if abs(x - x1) < 2e-3:
                break
            s_c = math.exp(x)
            c_ref = T1.apply(c_cur)
            start = Sim3(T1.R, c_ref - s_c * (T1.R @ c_cur), s_c)
            out = _run_levels(cur, weights_all, ref, normals, order, start, levels[1:], search, estimate_scale=False)
            iterations += out[2]
            if out[0] is None:
                break
            tried.append((x, _search_score(out[0], probe, ref, config), out[0]))
        if tried:
            T = min(tried, key=lambda e: e[1])[2]
            first = 1 if n_levels > 1 else 0
    T_out, converged, its, failure = _run_levels(cur, weights_all, ref, normals, order, T, range(first, n_levels),
                                                  config, estimate_scale=config.estimate_scale)
    iterations += its
    if T_out is None:
        return _failed(T, failure, t0, iterations)
    problem = ""
    if config.estimate_scale and config.minimum_check_step > 0:
        # Cold starts (warm runs are checked above only when they moved the scale by more
        # than warm_check_scale_change): the scale must sit at the minimum of the robust
        # residual; a neighbour that fits clearly better means the joint iteration stalled
        # (on a thick reference the inlier ratio cannot tell).
        for attempt in range(2):
            better, its = _scale_neighbour(cur, weights_all, ref, normals, order, T_out, probe, config)
            iterations += its
            if better is None:
                break
            if attempt == 1:
                problem = (f"scale is not at the residual minimum (a {better.scale / T_out.scale - 1:+.0%} "
                           "change fits better)")
                break
            out = _run_levels(cur, weights_all, ref, normals, order, better, range(n_levels - 1, n_levels),
                              config, estimate_scale=True)
            iterations += out[2]
            if out[0] is None:
                return _failed(better, out[3], t0, iterations)
            T_out, converged = out[0], out[1]
    result = replace(_finish(T_out, cur[order[: config.health_points]], ref, config, converged, iterations, t0,
                             scale_prior=s_prior), start=path)
    if problem:
        health = replace(result.health, ok=False,
                         reason=problem if result.health.ok else f"{result.health.reason}; {problem}")
        result = replace(result, health=health, seconds=time.perf_counter() - t0)
    return result


def _scale_neighbour(cur, weights_all, ref: ReferenceIndex, normals, order, T: Sim3, probe, config: FastAlignConfig):
    """A scale ``1 +- minimum_check_step`` times ``T``'s (rigidly refitted) that fits clearly better, or None."""
    n_levels = len(config.level_points)
    short = replace(config, level_iterations=config.level_iterations[:-1] + (config.minimum_check_iterations,))
    c_cur = probe.mean(axis=0)
    c_ref = T.apply(c_cur)
    check = replace(config, search_score="median")
    f0 = _search_score(T, probe, ref, check)
    iterations = 0
    best = None
    for factor in (1 - config.minimum_check_step, 1 + config.minimum_check_step):
        s_c = T.scale * factor
        start = Sim3(T.R, c_ref - s_c * (T.R @ c_cur), s_c)
        out = _run_levels(cur, weights_all, ref, normals, order, start, range(n_levels - 1, n_levels), short,
                          estimate_scale=False)
        iterations += out[2]
        if out[0] is None:
            continue
        f = _search_score(out[0], probe, ref, check)
        if f < (1 - config.minimum_check_margin) * f0 and (best is None or f < best[0]):
            best = (f, out[0])
    return (None if best is None else best[1]), iterations


def _shift_search(cur, weights_all, ref: ReferenceIndex, normals, order, T: Sim3, probe, config: FastAlignConfig) -> Sim3:
    """Cold start: try translations of the prior across the cloud's main plane; keep the best.

    Local ICP does not slide the current cloud 10-15 cm along a nearly flat relief
    (it stops in a local minimum that a smaller scale fits better: the collapse the
    scale search then picks). Each start runs a short rigid point-to-plane ICP on few
    points; the best by :func:`_search_score` is kept (the unshifted prior included).
    """
    if config.shift_steps <= 0:
        return T
    y = T.apply(probe)
    c = y.mean(axis=0)
    axes = np.linalg.svd(y - c, full_matrices=False)[2][:2]
    step = config.shift_rel * ref.width
    quick = replace(config, level_points=(config.shift_points,), level_radius_rel=(config.shift_radius_rel,),
                    level_iterations=(config.shift_iterations,), level_metric=("plane",), scale_from_level=1)
    best = None
    k = config.shift_steps
    for i in range(-k, k + 1):
        for j in range(-k, k + 1):
            start = Sim3(T.R, T.t + step * (i * axes[0] + j * axes[1]), T.scale)
            out = _run_levels(cur, weights_all, ref, normals, order, start, range(1), quick, estimate_scale=False)
            if out[0] is None:
                continue
            score = _search_score(out[0], probe, ref, config)
            if best is None or score < best[0]:
                best = (score, start)
    return T if best is None else best[1]


def _close(T_new: Sim3, T_old: Sim3, config: FastAlignConfig) -> bool:
    """A warm run stayed near its prior (scale and rotation within the warm limits)."""
    dR = T_new.R @ T_old.R.T
    angle = math.degrees(math.acos(float(np.clip((np.trace(dR) - 1) / 2, -1.0, 1.0))))
    return abs(math.log(T_new.scale / T_old.scale)) <= config.warm_max_scale_change and angle <= config.warm_max_rotation_deg


def _search_score(T: Sim3, probe: np.ndarray, ref: ReferenceIndex, config: FastAlignConfig) -> float:
    """Cold-start score of a candidate (lower is better): a robust residual of the probe points.

    ``"median"``: median nearest-neighbour distance. ``"truncated"``: mean distance truncated
    at the overlap distance (points off the reference count fully). ``"inliers"``: minus the
    fraction within ``inlier_rel`` of the width (the old score; it saturates on thick references).
    """
    d, _ = ref.nearest(T.apply(probe))
    if config.search_score == "inliers":
        return -float(np.mean(d < config.inlier_rel * ref.width))
    if config.search_score == "truncated":
        return float(np.mean(np.minimum(d, config.overlap_rel * ref.width)))
    return float(np.median(d))


def _run_levels(cur, weights_all, ref: ReferenceIndex, normals, order, T: Sim3, levels, config: FastAlignConfig,
                *, estimate_scale: bool, ignore_ref: np.ndarray | None = None):
    """Coarse-to-fine ICP over ``levels``; returns ``(T or None, converged, iterations, failure reason)``.

    ``ignore_ref`` (M,) bool marks reference points whose correspondences are dropped.
    """
    R, t, s = T.R, T.t, T.scale
    s_lo, s_hi = T.scale / (1 + config.max_scale_drift), T.scale * (1 + config.max_scale_drift)
    iterations = 0
    converged = False
    r_floor = config.min_inlier_spacing * ref.spacing
    n_levels = len(config.level_points)
    for level in levels:
        sel = order[: config.level_points[level]]
        x = cur[sel]
        w_pts = None if weights_all is None else weights_all[sel]
        r_max = config.level_radius_rel[level] * ref.width
        last = level == n_levels - 1
        tol_T = config.tau_T if last else 10 * config.tau_T
        tol_s = config.tau_sigma if last else 10 * config.tau_sigma
        level_converged = False
        for _ in range(config.level_iterations[level]):
            iterations += 1
            y = s * (x @ R.T) + t
            d, idx = ref.nearest(y, max_distance=r_max)
            valid = np.isfinite(d)
            if ignore_ref is not None:
                valid[valid] &= ~ignore_ref[idx[valid]]
            if np.count_nonzero(valid) < 10:
                return None, False, iterations, "lost the correspondences (fewer than 10 within range)"
            dv = d[valid]
            r_in = float(np.clip(config.inlier_factor * np.median(dv), r_floor, r_max))
            q = ref.points[idx[valid]]
            nq = normals[idx[valid]]
            wv = None if w_pts is None else w_pts[valid]
            R_old, t_old, s_old = R, t, s
            if config.level_metric[level] == "point":
                dT, inl = sparse_point_to_point_step(
                    y[valid], q, inlier_distance=r_in, p=config.sparse_p,
                    admm_iterations=config.admm_iterations, weights=wv,
                )
            elif config.robust == "sparse":
                dT, inl = sparse_point_to_plane_step(
                    y[valid], q, nq, inlier_distance=r_in, p=config.sparse_p,
                    admm_iterations=config.admm_iterations, weights=wv,
                )
            elif config.robust == "trimmed":
                # Trimmed least squares: drop correspondences beyond the working inlier distance.
                inl = dv < r_in
                w = inl.astype(float) if wv is None else inl * wv
                dT = trimmed_point_to_plane_step(y[valid], q, nq, weights=w)
            else:
                raise ValueError(f"unknown robust method {config.robust!r}")
            R = dT[:3, :3] @ R
            t = dT[:3, :3] @ t + dT[:3, 3]
            if estimate_scale and level >= config.scale_from_level:
                a = x[valid] @ R.T
                e = np.abs(np.sum(nq * (s * a + t - q), axis=1))
                med = float(np.median(e[inl])) if np.any(inl) else r_in
                use = inl & (e < config.trim_factor * max(med, 1e-12))
                if np.count_nonzero(use) >= 10:
                    w = use.astype(float) if wv is None else use * wv
                    s_new, t_new = scale_step_point_to_plane(a, q, nq, w)
                    if s_new > 0 and math.isfinite(s_new):
                        # Least-squares scale is attenuated (biased low) while the
                        # correspondences are poor; bounding each step stops a collapse
                        # from running away before R, t have caught up.
                        s_clip = float(np.clip(s_new, max(s * (1 - config.max_scale_step), s_lo),
                                               min(s * (1 + config.max_scale_step), s_hi)))
                        if s_clip != s_new:
                            t_new = t_new + (s_new - s_clip) * (a.T @ w) / w.sum()
                        s, t = s_clip, t_new
            dT = make_pose(R, t) @ np.linalg.inv(make_pose(R_old, t_old))
            if np.linalg.norm(dT - np.eye(4)) <= tol_T and abs(s - s_old) <= tol_s:
                level_converged = True
                break
            # On noisy clouds the estimate can jitter above tau_T for ever: accept when the
            # points move by a negligible fraction of the working inlier distance.
            moved = float(np.sqrt(np.mean(np.sum((s * (x @ R.T) + t - y) ** 2, axis=1))))
            if moved < config.stall_rel * r_in:
                level_converged = True
                break
        converged = level_converged
    return Sim3(R, t, s), converged, iterations, ""


def _finish(
    T: Sim3, cur, ref: ReferenceIndex, config: FastAlignConfig, converged, iterations, t0, *, scale_prior: float
) -> AlignmentResult:
    residuals, health = evaluate_alignment(
        T, cur, ref, converged=converged, scale_ratio=T.scale / scale_prior, config=config
    )
    return AlignmentResult(
        T_ref_cur=T, residuals=residuals, health=health, iterations=iterations, seconds=time.perf_counter() - t0
    )


def evaluate_alignment(
    T: Sim3,
    cur: np.ndarray,
    ref: ReferenceIndex,
    *,
    converged: bool,
    scale_ratio: float,
    config: FastAlignConfig = FastAlignConfig(),
) -> tuple[ResidualStats, AlignmentHealth]:
    """Geometric residuals and health of ``T_ref_cur`` for the current cloud (thresholds from ``config``)."""
    # Inlier threshold: a fraction of the width, or three times the two clouds' combined
    # noise (measured on each cloud by itself, so it cannot be inflated by a bad fit).
    noise = math.hypot(local_roughness(cur, samples=500) * T.scale, ref.roughness)
    inlier_thr = max(config.inlier_rel * ref.width, config.inlier_noise_factor * noise, 3 * ref.spacing)
    overlap_thr = max(config.overlap_rel * ref.width, 2 * inlier_thr, 5 * ref.spacing)
    d, idx = ref.nearest(T.apply(cur), max_distance=overlap_thr)
    inl = d < inlier_thr
    matched = idx[inl]
    if len(matched) > 5000:
        matched = matched[:: len(matched) // 5000 + 1]
    smooth_pts, smooth_normals, smooth_tree = ref.smooth_normals()
    matched_smooth = np.unique(smooth_tree.query(ref.points[matched])[1]) if len(matched) else np.zeros(0, int)

    def probe(points: np.ndarray, directions: np.ndarray) -> tuple[float, ...]:
        return probe_weak_directions(T, cur, ref, points=points, directions=directions, config=config)
    health = assess(
        distances=d,
        matched_points=smooth_pts[matched_smooth],
        matched_normals=smooth_normals[matched_smooth],
        converged=converged,
        inlier_threshold=inlier_thr,
        overlap_threshold=overlap_thr,
        min_inlier_ratio=config.min_inlier_ratio,
        min_overlap=config.min_overlap,
        # Noisy normals lift the smallest eigenvalue of a plane to about (noise / radius)^2.
        min_condition_ratio=max(config.min_condition_ratio,
                                config.condition_noise_factor * (ref.roughness / ref.smooth_radius) ** 2),
        scale=scale_ratio,
        scale_bounds=config.scale_bounds,
        probe=probe if config.weak_probe else None,
        probe_return=config.weak_probe_return,
        probe_directions=config.weak_probe_directions,
    )
    return residual_stats(d, inlier_threshold=inlier_thr), health


def _perturbation(direction: np.ndarray, centre: np.ndarray, radius: float) -> Sim3:
    """Similarity (reference frame) of a 7-vector in the normalised parameters of
    :func:`~fgcd_cli.alignment.health.similarity_conditioning`: translation ``radius * v[:3]``,
    rotation ``v[3:6]`` and log-scale ``v[6]`` about ``centre``."""
    R = exp_se3(np.r_[0.0, 0.0, 0.0, direction[3:6]])[:3, :3]
    s = math.exp(float(direction[6]))
    return Sim3(R, centre + radius * direction[:3] - s * (R @ centre), s)


def probe_weak_directions(
    T: Sim3,
    cur_points: np.ndarray,
    ref: ReferenceIndex,
    *,
    points: np.ndarray,
    directions: np.ndarray,
    config: FastAlignConfig = FastAlignConfig(),
) -> tuple[float, ...]:
    """How much of a perturbation along each weak direction the alignment recovers.

    The result ``T`` is moved along each direction (alternating signs) by a
    similarity that displaces ``points`` by ``weak_probe_rel`` of the reference
    width (RMS; at least 3 times its roughness), and the last ICP level runs
    again from there (``weak_probe_points`` points, ``weak_probe_iterations``
    iterations). A direction pinned by the data (a relief, joints, the object's
    sides) pulls the estimate back; a free one (in-plane on a plane, rotation
    on a sphere) leaves it where it was put. This is a finite-size test of the
    actual point-to-plane problem, which the linearised conditioning with
    smoothed normals cannot see. (Written here: no registration library offers
    a degeneracy test of this kind.)

    Parameters
    ----------
    T : Sim3
        The alignment result ``T_ref_cur``.
    cur_points : (N, 3) ndarray
        Current cloud (its map frame).
    ref : ReferenceIndex
    points : (K, 3) ndarray
        Reference points matched by the result (metres), defining the
        normalisation of ``directions``.
    directions : (7, D) ndarray
        Unit vectors in the parameters ``(tx, ty, tz, rx, ry, rz, log s)`` of
        :func:`~fgcd_cli.alignment.health.similarity_conditioning`
        (translation in units of the RMS radius of ``points`` about their centroid).

    Returns
    -------
    tuple of float
        Per direction, the RMS displacement of ``points`` between the rerun's
        result and ``T``, over the perturbation's (0: fully recovered).
    """
    q = np.asarray(points, dtype=float)
    c = q.mean(axis=0)
    L = float(np.sqrt(np.mean(np.sum((q - c) ** 2, axis=1))))
    if L <= 0 or directions.size == 0:
        return ()
    if len(q) > 2000:
        q = q[:: len(q) // 2000 + 1]
    size = max(config.weak_probe_rel * ref.width, 3.0 * ref.roughness)
    n_levels = len(config.level_points)
    probe_config = replace(
        config,
        level_points=config.level_points[:-1] + (config.weak_probe_points,),
        level_iterations=config.level_iterations[:-1] + (config.weak_probe_iterations,),
    )
    order = np.random.default_rng(config.seed + 1).permutation(len(cur_points))
    out = []
    for k in range(directions.shape[1]):
        v = directions[:, k]
        unit = _perturbation(v, c, L)
        disp = float(np.sqrt(np.mean(np.sum((unit.apply(q) - q) ** 2, axis=1))))
        if disp <= 0:
            out.append(0.0)
            continue
        amount = (size / disp) * (1.0 if k % 2 == 0 else -1.0)
        start = _perturbation(v * amount, c, L) @ T
        # Correspondences on the reference cloud's rim where the view ended are left out:
        # there point-to-plane residuals of a curved cloud pull a perturbation back, although
        # the rim is only where the camera stopped seeing (a sphere's rotations came back
        # 75 % with them). The object's own outline stays: it pins a stele's height.
        T_back, _conv, _its, failure = _run_levels(cur_points, None, ref, ref.normals, order, start,
                                                  range(n_levels - 1, n_levels), probe_config,
                                                  estimate_scale=config.estimate_scale, ignore_ref=ref.view_rim)
        if T_back is None:
            out.append(math.inf)
            continue
        correction = T_back @ T.inverse()
        out.append(float(np.sqrt(np.mean(np.sum((correction.apply(q) - q) ** 2, axis=1)))) / size)
    return tuple(out)


def _failed(T: Sim3, reason: str, t0: float, iterations: int = 0) -> AlignmentResult:
    nan = float("nan")
    return AlignmentResult(
        T_ref_cur=T,
        residuals=ResidualStats(count=0, rms_mm=nan, median_mm=nan, inlier_threshold_mm=nan),
        health=AlignmentHealth(
            ok=False, reason=reason, converged=False, overlap=0.0, inlier_ratio=0.0,
            condition_ratio=0.0, degenerate=False,
        ),
        iterations=iterations,
        seconds=time.perf_counter() - t0,
    )
