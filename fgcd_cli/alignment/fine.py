"""Fine-grained scale-aware alignment (rACR §3.4.3, Eqs. 10, 11, 16–18).

Minimises ``alpha * E_g + (1 - alpha) * E_p`` from the fast alignment's result:

* ``E_p`` (Eq. 10): each selected reference point is projected into every
  *current* keyframe where it is visible (nearest point per image cell, the
  paper's occlusion rule) and the keyframes' intensities are compared with each
  other, never with reference images, so lighting changes between the sessions
  do not enter. For the squared loss ``sum_{u,v} (I_u - I_v)^2 = 2K sum_u (I_u - I_mean)^2``,
  so the residuals are taken against the per-point mean (K instead of K^2/2
  residuals per point), with Huber weights (IRLS).
* ``E_g`` (Eq. 9) in point-to-plane form against the reference normals.

Step 1 (Eq. 16) refines the current keyframe poses with ``E_p`` and the
similarity fixed; steps 2–3 (Eqs. 17–18) refine the similarity: here R, t and
the scale jointly in one Levenberg–Marquardt problem (the paper alternates R, t
and the scale; the joint 7-parameter step converges in fewer iterations and
the ``-S`` ablation simply drops the scale column). Hand-written LM with analytic
Jacobians ``dI/du . du/dX . dX/dparams``: ``scipy.optimize.least_squares`` with
the same Jacobian is ~50x slower here and numeric Jacobians do not move on
bilinearly interpolated images. A blur schedule (sigma 3 then 1 pixel) widens
the basin before the final precise level.

Units: the two terms are normalised by their robust residual scales
(grey levels, metres) and their residual counts, so ``alpha`` weighs
dimensionless mean costs.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import sparse

from fgcd_cli.alignment.fast import FastAlignConfig, as_reference, evaluate_alignment
from fgcd_cli.alignment.photometric import (
    KeyframeImage,
    prepare_keyframe,
    project_with_jacobian,
    sample,
    visible_nearest,
)
from fgcd_cli.alignment.reference import ReferenceIndex
from fgcd_cli.alignment.sparse_icp import gram
from fgcd_cli.alignment.results import AlignmentHealth, FineAlignmentResult, ResidualStats
from fgcd_cli.geometry import PinholeCamera, Sim3, exp_se3

__all__ = ["FineAlignConfig", "fine_align"]

_HUBER_K = 1.345


@dataclass(frozen=True, kw_only=True)
class FineAlignConfig:
    """Options of :func:`fine_align`."""

    alpha: float = 0.2
    """Weight of the geometric term (the paper's alpha)."""
    refine_keyframes: bool = True
    """False skips Eq. (16) (the paper's rACR-P ablation)."""
    estimate_scale: bool = False
    """Refine the scale here too (the paper's Eq. 18). Off by default: the scale
    then stays the fast stage's (Eq. 14, from ``E_g``). ``E_p`` sees the scale,
    and the shift along the viewing direction that goes with it on a nearly flat
    object, only through the parallax between the current keyframes, i.e.
    through the monocular trajectory, whose scale disagrees with its own cloud
    by 1-2 % (bas-relief ambiguity of small motions). Measured on the stele
    (``docs/alignment.md``): Eq. 18 moved the camera 17-29 mm along the optical
    axis and the true AFD from 0.5 to 1.4-2.5 px; with the scale kept, 0.44 px."""
    blur_sigmas: tuple[float, ...] = (3.0, 1.0)
    """Gaussian blur (pixels) of each level, coarse to fine."""
    keyframe_iterations: int = 5
    similarity_iterations: int = 5
    max_photometric_points: int = 2000
    max_geometric_points: int = 3000
    min_photometric_sigma: float = 0.004
    """Floor of the robust photometric residual scale (grey levels in [0, 1])."""
    occlusion_cell_px: int = 4
    occlusion_depth_tol: float = 0.01
    max_keyframes: int = 8
    """Only the last ``max_keyframes`` keyframes are used."""
    max_rotation_change_deg: float = 3.0
    """Health: larger changes from ``init`` are not trusted."""
    max_scale_change: float = 0.05
    max_translation_change_rel: float = 0.05
    """Fraction of the reference width."""
    seed: int = 0


def _huber_weights(r: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """IRLS weights and Huber costs of residuals ``r`` scaled by ``sigma``."""
    a = np.abs(r) / sigma
    w = np.where(a <= _HUBER_K, 1.0, _HUBER_K / np.maximum(a, 1e-12))
    cost = np.where(a <= _HUBER_K, 0.5 * a * a, _HUBER_K * (a - 0.5 * _HUBER_K))
    return w, cost


class _Problem:
    """Residuals and Jacobians of the fine alignment at one blur level."""

    def __init__(self, *, camera, images, ref_pts, pt, kf, n_kf, geo, alpha, sigma_p, sigma_g, sigma_t, n_p, n_g):
        self.camera = camera
        self.images: list[KeyframeImage] = images
        self.ref_pts = ref_pts  # (M, 3) selected reference points, ref frame
        self.pt = pt  # (O,) point index per observation
        self.kf = kf  # (O,) keyframe index per observation
        self.n_kf = n_kf
        self.geo = geo  # None or (x_cur (G,3), q_ref (G,3), n_ref (G,3))
        self.alpha = alpha
        self.sigma_p = sigma_p
        self.sigma_g = sigma_g
        self.sigma_t = sigma_t
        self.n_p = max(1, n_p)
        self.n_g = max(1, n_g)
        self.by_kf = [np.flatnonzero(kf == u) for u in range(n_kf)]

    def photometric(self, S: Sim3, poses: list[np.ndarray], *, block: str | None):
        """Residuals (O,), validity (O,) and, if ``block`` is "keyframes" or "similarity", the Jacobian."""
        O = len(self.pt)
        q = S.apply(self.ref_pts)[self.pt]  # current map frame
        I = np.zeros(O)
        ok = np.zeros(O, dtype=bool)
        dIdX = np.zeros((O, 3))
        X = np.zeros((O, 3))
        for u, idx in enumerate(self.by_kf):
            if len(idx) == 0:
                continue
            R_u, t_u = poses[u][:3, :3], poses[u][:3, 3]
            Xu = (q[idx] - t_u) @ R_u
            uv, J, front = project_with_jacobian(self.camera, Xu)
            vals, inside = sample(self.images[u], np.nan_to_num(uv))
            I[idx] = vals[:, 0]
            ok[idx] = front & inside
            dIdX[idx] = np.einsum("ni,nij->nj", vals[:, 1:3], J)
            X[idx] = Xu
        cnt = np.bincount(self.pt, weights=ok.astype(float), minlength=len(self.ref_pts))
        ok &= cnt[self.pt] >= 2
        cnt = np.bincount(self.pt, weights=ok.astype(float), minlength=len(self.ref_pts))
        mean = np.bincount(self.pt, weights=I * ok, minlength=len(self.ref_pts)) / np.maximum(cnt, 1)
        r = np.where(ok, I - mean[self.pt], 0.0)
        if block is None:
            return r, ok, None
        if block == "keyframes":
            # Right perturbation T_u <- T_u exp(delta): dX = -rho + X x phi.
            Jb = np.concatenate([-dIdX, np.cross(dIdX, X)], axis=1)
            cols = 6 * self.n_kf
            JI = sparse.csr_matrix(
                (Jb.ravel(), ((6 * self.kf)[:, None] + np.arange(6)).ravel(), np.arange(0, 6 * O + 1, 6)),
                shape=(O, cols),
            ).toarray()
        else:
            # Left perturbation S <- exp(xi) S: dq = rho + phi x q + lambda q; dX = R_u^T dq.
            a = np.zeros((O, 3))
            for u, idx in enumerate(self.by_kf):
                a[idx] = dIdX[idx] @ poses[u][:3, :3].T
            JI = np.concatenate([a, np.cross(q, a), np.sum(a * q, axis=1, keepdims=True)], axis=1)
        JI[~ok] = 0.0
        w_avg = np.where(ok, 1.0 / np.maximum(cnt[self.pt], 1), 0.0)
        A = sparse.csr_matrix((w_avg, (self.pt, np.arange(O))), shape=(len(self.ref_pts), O))
        J = JI - (A @ JI)[self.pt]
        J[~ok] = 0.0
        return r, ok, J

    def geometric(self, S: Sim3, *, jac: bool):
        """Residuals of the current points against their matched reference points.

        Returns ``(r_n, r_t, J_n, J_t)``: ``r_n`` (G,) the offset along the
        reference normal (point-to-plane), ``r_t`` (G, 3) the offset within the
        tangent plane. The paper's ``E_g`` (Eq. 9) is point-to-point, i.e. both
        parts with one weight; point-to-plane alone cannot tell the scale from a
        shift along the normal on a nearly flat object (a stele: 1.5 % of scale
        became 26 mm along the optical axis), while the normal part is far less
        noisy than the tangential one. So both are kept, each with its own
        robust scale (an anisotropic, GICP-like point-to-point).
        """
        x, q_ref, n_ref = self.geo
        Sq = S.apply(q_ref)
        n_c = n_ref @ S.R.T
        d = x - Sq
        r_n = np.sum(n_c * d, axis=1)
        r_t = d - n_c * r_n[:, None]
        if not jac:
            return r_n, r_t, None, None
        J_n = np.concatenate([-n_c, -np.cross(Sq, n_c), -np.sum(n_c * Sq, axis=1, keepdims=True)], axis=1)
        # d(Sq)/dxi for the left perturbation S <- exp(xi) S: [I, -[Sq]x, Sq]; d = x - Sq.
        G = len(Sq)
        J_d = np.zeros((G, 3, 7))
        J_d[:, :, 0:3] = -np.eye(3)
        skew = np.zeros((G, 3, 3))
        skew[:, 0, 1], skew[:, 0, 2] = -Sq[:, 2], Sq[:, 1]
        skew[:, 1, 0], skew[:, 1, 2] = Sq[:, 2], -Sq[:, 0]
        skew[:, 2, 0], skew[:, 2, 1] = -Sq[:, 1], Sq[:, 0]
        J_d[:, :, 3:6] = skew
        J_d[:, :, 6] = -Sq
        P_t = np.eye(3)[None] - n_c[:, :, None] * n_c[:, None, :]
        J_t = np.einsum("gij,gjk->gik", P_t, J_d)
        return r_n, r_t, J_n, J_t

    def cost(self, S, poses, *, block: str | None, with_geometry: bool):
        """Total normalised robust cost; with ``block`` also the weighted normal equations."""
        r, ok, J = self.photometric(S, poses, block=block)
        w, c = _huber_weights(r, self.sigma_p)
        w = np.where(ok, w, 0.0)
        total = (1 - self.alpha) * float(np.sum(c[ok])) / self.n_p if with_geometry else float(np.sum(c[ok])) / self.n_p
        H = b = None
        if J is not None:
            scale_p = ((1 - self.alpha) if with_geometry else 1.0) / (self.n_p * self.sigma_p**2)
            Jw = J * (w * scale_p)[:, None]
            H = gram(Jw, J)
            b = -(r @ Jw)
        if with_geometry and self.geo is not None:
            rn, rt, Jn, Jt = self.geometric(S, jac=J is not None)
            wn, cn = _huber_weights(rn, self.sigma_g)
            rt = rt.reshape(-1)
            wt, ct = _huber_weights(rt, self.sigma_t)
            total += self.alpha * (float(np.sum(cn)) + float(np.sum(ct))) / self.n_g
            if Jn is not None:
                scale_n = self.alpha / (self.n_g * self.sigma_g**2)
                Jnw = Jn * (wn * scale_n)[:, None]
                Jt = Jt.reshape(-1, 7)
                scale_t = self.alpha / (self.n_g * self.sigma_t**2)
                Jtw = Jt * (wt * scale_t)[:, None]
                H = H + gram(Jnw, Jn) + gram(Jtw, Jt)
                b = b - rn @ Jnw - rt @ Jtw
        return total, H, b


def _lm(
    evaluate, apply, state, *, iterations: int, free: np.ndarray, gauge: np.ndarray | None = None
) -> tuple[object, int, bool]:
    """Levenberg–Marquardt on the ``free`` parameters; returns (state, iterations, converged).

    ``gauge`` (rows C) adds the constraint ``C delta = 0`` as a stiff penalty.
    """
    cost, H, b = evaluate(state, True)
    lam = 1e-3
    done = 0
    converged = False
    for _ in range(iterations):
        done += 1
        Hf = H[np.ix_(free, free)]
        bf = b[free]
        if gauge is not None:
            Cf = gauge[:, free]
            Hf = Hf + 1e3 * max(float(np.max(np.diag(Hf))), 1e-12) * (Cf.T @ Cf)
        diag = np.diag(Hf).copy()
        diag[diag <= 0] = 1e-12
        try:
            step = np.linalg.solve(Hf + lam * np.diag(diag) + 1e-15 * np.eye(len(bf)), bf)
        except np.linalg.LinAlgError:
            break
        delta = np.zeros(len(b))
        delta[free] = step
        candidate = apply(state, delta)
        new_cost, _, _ = evaluate(candidate, False)
        if new_cost < cost:
            gain = (cost - new_cost) / max(cost, 1e-30)
            state = candidate
            cost, H, b = evaluate(state, True)
            lam = max(lam / 3.0, 1e-7)
            if gain < 1e-5:
                converged = True
                break
        else:
            lam *= 8.0
            if lam > 1e6:
                converged = True
                break
    return state, done, converged


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
        inside = in_view & (uv[:, 0] >= 2) & (uv[:, 0] <= camera.width - 3) & (uv[:, 1] >= 2) & (uv[:, 1] <= camera.height - 3)
        v = visible_nearest(np.nan_to_num(uv), X[:, 2], inside, width=camera.width, height=camera.height,
                            cell_px=config.occlusion_cell_px, depth_tol=config.occlusion_depth_tol)
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
    pinhole = PinholeCamera(fx=camera.fx, fy=camera.fy, cx=camera.cx, cy=camera.cy,
                            width=camera.width, height=camera.height)
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
    if len(cur_keyframes) < 2:
        raise ValueError("fine alignment needs at least 2 current keyframes")
    keyframes = list(cur_keyframes)[-config.max_keyframes :]
    ref = ref_points if isinstance(ref_points, ReferenceIndex) else ReferenceIndex(
        np.asarray(ref_points, dtype=float), intensities=ref_intensities
    )
    cam, raw_images = _undistorted(camera, keyframes)
    for img in raw_images:
        if np.asarray(img).shape[:2] != (cam.height, cam.width):
            raise ValueError(f"keyframe image is {np.asarray(img).shape[:2]}, camera is {(cam.height, cam.width)}")
    rng = np.random.default_rng(config.seed)
    poses0 = [np.array(T, dtype=float) for T, _ in keyframes]
    S0 = init.inverse()
    S, poses = S0, [T.copy() for T in poses0]
    K = len(poses)
    notes: list[str] = []

    geo_all = None
    sigma_g = max(ref.spacing, 1e-6)
    sigma_t = sigma_g
    if cur_points is not None and config.alpha > 0:
        cur = np.asarray(cur_points, dtype=float)
        cur = cur[np.all(np.isfinite(cur), axis=1)]
        if len(cur) > config.max_geometric_points:
            cur = cur[rng.choice(len(cur), config.max_geometric_points, replace=False)]
        d, idx = ref.nearest(init.apply(cur))
        keep = np.isfinite(d)
        if np.count_nonzero(keep) >= 10:
            thr = max(3.0 * float(np.median(d[keep])), 3 * ref.spacing)
            keep &= d < thr
            geo_all = (cur[keep], ref.points[idx[keep]], ref.normals[idx[keep]])
            n0 = geo_all[2] @ S0.R.T
            d0 = geo_all[0] - S0.apply(geo_all[1])
            rg = np.sum(n0 * d0, axis=1)
            sigma_g = max(1.4826 * float(np.median(np.abs(rg))), ref.spacing / 4)
            rt0 = (d0 - n0 * rg[:, None]).reshape(-1)
            sigma_t = max(1.4826 * float(np.median(np.abs(rt0))), sigma_g)
    free_sim = np.arange(7) if config.estimate_scale else np.arange(6)
    iterations = 0
    converged = True
    rms_before = rms_after = float("nan")
    n_res = 0
    problem = None
    for level, blur in enumerate(config.blur_sigmas):
        images = [prepare_keyframe(img, blur_sigma=blur) for img in raw_images]
        sel, pt, kf = _select_points(ref, S, poses, cam, images, config, rng)
        if len(pt) < 50:
            notes.append(f"level {level}: only {len(pt)} photometric observations")
            converged = False
            continue
        n_g = 0 if geo_all is None else len(geo_all[0])
        probe = _Problem(camera=cam, images=images, ref_pts=ref.points[sel], pt=pt, kf=kf, n_kf=K, geo=geo_all,
                         alpha=config.alpha, sigma_p=1.0, sigma_g=sigma_g, sigma_t=sigma_t, n_p=len(pt), n_g=n_g)
        r0, ok0, _ = probe.photometric(S, poses, block=None)
        sigma_p = max(1.4826 * float(np.median(np.abs(r0[ok0]))) if ok0.any() else 0.0, config.min_photometric_sigma)
        problem = _Problem(camera=cam, images=images, ref_pts=ref.points[sel], pt=pt, kf=kf, n_kf=K, geo=geo_all,
                           alpha=config.alpha, sigma_p=sigma_p, sigma_g=sigma_g, sigma_t=sigma_t, n_p=len(pt), n_g=n_g)
        if level == len(config.blur_sigmas) - 1:
            rms_before = _photometric_rms(problem, S0, poses0)
            n_res = int(np.count_nonzero(ok0))
        if config.refine_keyframes:
            def eval_kf(state, jac, _p=problem):
                return _p.cost(S, state, block="keyframes" if jac else None, with_geometry=False)

            def apply_kf(state, delta):
                return [T @ exp_se3(delta[6 * u : 6 * u + 6]) for u, T in enumerate(state)]

            # Moving all keyframes together is (nearly) a change of the similarity,
            # observed by E_p only through parallax: fix that gauge (zero mean
            # correction) and leave it to the similarity step, where E_g sees it.
            gauge = np.tile(np.eye(6), (1, K)) / K
            poses, it, conv = _lm(eval_kf, apply_kf, poses, iterations=config.keyframe_iterations,
                                  free=np.arange(6 * K), gauge=gauge)
            iterations += it

        def eval_sim(state, jac, _p=problem):
            return _p.cost(state, poses, block="similarity" if jac else None, with_geometry=True)

        def apply_sim(state, delta):
            return Sim3.exp(delta) @ state

        S, it, conv = _lm(eval_sim, apply_sim, S, iterations=config.similarity_iterations, free=free_sim)
        iterations += it
    if problem is not None:
        rms_after = _photometric_rms(problem, S, poses)
    T = S.inverse()

    # Health: geometric checks as in the fast alignment, plus plausibility of the change.
    change = T @ init.inverse()
    shift = float(np.linalg.norm(change.apply(ref.centroid) - ref.centroid))
    problems = []
    if change.rotation_deg() > config.max_rotation_change_deg:
        problems.append(f"moved {change.rotation_deg():.1f} deg from the fast result")
    if abs(math.log(change.scale)) > config.max_scale_change:
        problems.append(f"scale changed by {100 * (change.scale - 1):+.1f} % from the fast result")
    if shift > config.max_translation_change_rel * ref.width:
        problems.append(f"moved {shift * 1e3:.0f} mm from the fast result")
    if not (rms_after <= rms_before * 1.001):
        problems.append("photometric error did not decrease")
    if cur_points is not None:
        cur_all = np.asarray(cur_points, dtype=float)
        cur_all = cur_all[np.all(np.isfinite(cur_all), axis=1)]
        residuals, geo_health = evaluate_alignment(
            T, cur_all, ref, converged=converged, scale_ratio=T.scale / init.scale, config=FastAlignConfig()
        )
    else:
        nan = float("nan")
        residuals = ResidualStats(count=0, rms_mm=nan, median_mm=nan, inlier_threshold_mm=nan)
        geo_health = AlignmentHealth(ok=True, reason="ok", converged=converged, overlap=float("nan"),
                                     inlier_ratio=float("nan"), condition_ratio=float("nan"), degenerate=False)
    if not geo_health.ok:
        problems.append(geo_health.reason)
    if not converged:
        problems.append("; ".join(notes) or "did not converge")
    health = AlignmentHealth(
        ok=not problems,
        reason="ok" if not problems else "; ".join(dict.fromkeys(problems)),
        converged=converged,
        overlap=geo_health.overlap,
        inlier_ratio=geo_health.inlier_ratio,
        condition_ratio=geo_health.condition_ratio,
        degenerate=geo_health.degenerate,
        weak_directions=geo_health.weak_directions,
    )
    return FineAlignmentResult(
        T_ref_cur=T,
        keyframe_poses=poses,
        residuals=residuals,
        photometric_rms_before=rms_before,
        photometric_rms_after=rms_after,
        health=health,
        iterations=iterations,
        seconds=time.perf_counter() - t0,
        photometric_residual_count=n_res,
        notes=tuple(notes),
    )


def _photometric_rms(problem: _Problem, S: Sim3, poses) -> float:
    r, ok, _ = problem.photometric(S, poses, block=None)
    return float(np.sqrt(np.mean(r[ok] ** 2))) if ok.any() else float("nan")
