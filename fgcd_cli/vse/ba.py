"""Bundle adjustment and motion-only pose refinement (pinhole, Huber loss).

Written by hand rather than with ``scipy.optimize.least_squares``: a windowed
bundle adjustment has few cameras (<= ~20) and many points, so a
Levenberg-Marquardt with the Schur complement on a small dense camera system
and analytic Jacobians runs in tens of milliseconds where the finite-difference
``least_squares(jac_sparsity=...)`` takes seconds (docs/vse.md, "Design and why").

Poses are optimised as ``T_cam_map`` (map-to-camera) with a left perturbation
``T <- exp_se3(delta) @ T``, ``delta = (rho, phi)``. Observations are
undistorted pixels (ideal pinhole with ``fx, fy, cx, cy``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from fgcd_core.se3 import exp_se3

__all__ = ["BundleResult", "BundleAdjustConfig", "OutlierRejectionConfig", "bundle_adjust",
           "bundle_adjust_rejecting_outliers", "outlier_threshold_px", "refine_pose", "projection_residuals"]


@dataclass(frozen=True, kw_only=True)
class BundleResult:
    """Result of :func:`bundle_adjust`.

    Attributes
    ----------
    T_cam_map : (C, 4, 4) ndarray
        Optimised map-to-camera poses.
    points : (P, 3) ndarray
        Optimised map points.
    residual_px : (M,) ndarray
        Reprojection error of every observation after optimisation, pixels.
    rms_px : float
        Root-mean-square reprojection error over the inliers (``residual_px < huber_px * 3``).
    iterations : int
        Levenberg-Marquardt iterations performed.
    """

    T_cam_map: np.ndarray
    points: np.ndarray
    residual_px: np.ndarray
    rms_px: float
    iterations: int


def projection_residuals(
    T_cam_map: np.ndarray, points: np.ndarray, obs_cam: np.ndarray, obs_pt: np.ndarray, obs_uv: np.ndarray, K: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Residuals ``projected - observed`` (M, 2) in pixels and camera-frame points (M, 3)."""
    R = T_cam_map[obs_cam, :3, :3]
    t = T_cam_map[obs_cam, :3, 3]
    Xc = np.einsum("mij,mj->mi", R, points[obs_pt]) + t
    z = Xc[:, 2]
    zs = np.where(z > 1e-9, z, 1e-9)
    u = K[0, 0] * Xc[:, 0] / zs + K[0, 2]
    v = K[1, 1] * Xc[:, 1] / zs + K[1, 2]
    r = np.column_stack([u, v]) - obs_uv
    r[z <= 1e-9] = 1e3
    return r, Xc


def _jacobians(Xc: np.ndarray, R: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of the projection w.r.t. the pose twist (M, 2, 6) and the point (M, 2, 3)."""
    fx, fy = K[0, 0], K[1, 1]
    x, y, z = Xc[:, 0], Xc[:, 1], np.maximum(Xc[:, 2], 1e-9)
    M = len(Xc)
    Jproj = np.zeros((M, 2, 3))
    Jproj[:, 0, 0] = fx / z
    Jproj[:, 0, 2] = -fx * x / z**2
    Jproj[:, 1, 1] = fy / z
    Jproj[:, 1, 2] = -fy * y / z**2
    # d(Xc)/d(rho) = I, d(Xc)/d(phi) = -[Xc]x
    dX = np.zeros((M, 3, 6))
    dX[:, 0, 0] = dX[:, 1, 1] = dX[:, 2, 2] = 1.0
    dX[:, 0, 4], dX[:, 0, 5] = z, -y
    dX[:, 1, 3], dX[:, 1, 5] = -z, x
    dX[:, 2, 3], dX[:, 2, 4] = y, -x
    Jc = Jproj @ dX
    Jp = Jproj @ R
    return Jc, Jp


def _huber_weights(r: np.ndarray, delta: float) -> np.ndarray:
    n = np.linalg.norm(r, axis=1)
    return np.where(n <= delta, 1.0, delta / np.maximum(n, 1e-12))


def _robust_cost(r: np.ndarray, delta: float) -> float:
    n = np.linalg.norm(r, axis=1)
    return float(np.sum(np.where(n <= delta, 0.5 * n**2, delta * (n - 0.5 * delta))))


@dataclass(frozen=True, kw_only=True)
class BundleAdjustConfig:
    """Options of :func:`bundle_adjust`.

    Attributes
    ----------
    iterations : int
        Maximum Levenberg-Marquardt iterations.
    huber_px : float
        Huber threshold of the robust loss, pixels.
    """

    iterations: int = 10
    huber_px: float = 1.5


@dataclass(frozen=True, kw_only=True)
class OutlierRejectionConfig:
    """Options of :func:`bundle_adjust_rejecting_outliers`.

    Attributes
    ----------
    iterations, huber_px
        As :class:`BundleAdjustConfig`, for each solve.
    outlier_sigmas, outlier_min_px, outlier_max_px
        The threshold of :func:`outlier_threshold_px` (``sigmas``, ``min_px``, ``max_px``).
    max_rounds : int
        Solves at most (1: one solve and a fixed-threshold test).
    """

    iterations: int = 10
    huber_px: float = 1.0
    outlier_sigmas: float = 4.0
    outlier_min_px: float = 0.5
    outlier_max_px: float = 6.0
    max_rounds: int = 4


def _with_overrides(config, default_type, overrides: dict):
    """``config`` (or the defaults) with the keyword options of the former call form applied."""
    base = default_type() if config is None else config
    return replace(base, **overrides) if overrides else base


def _normal_equations(Jc: np.ndarray, Jp: np.ndarray, w: np.ndarray, r: np.ndarray, obs_cam: np.ndarray,
                      obs_pt: np.ndarray, C: int, P: int):
    """Weighted Gauss-Newton blocks ``(Hcc (C,6,6), Hpp (P,3,3), Hcp (P,C,6,3), bc (C,6), bp (P,3))``."""
    wJc = Jc * w[:, None, None]
    wJp = Jp * w[:, None, None]
    Hcc = np.zeros((C, 6, 6))
    np.add.at(Hcc, obs_cam, np.einsum("mki,mkj->mij", wJc, Jc))
    Hpp = np.zeros((P, 3, 3))
    np.add.at(Hpp, obs_pt, np.einsum("mki,mkj->mij", wJp, Jp))
    Hcp = np.zeros((P, C, 6, 3))
    np.add.at(Hcp, (obs_pt, obs_cam), np.einsum("mki,mkj->mij", wJc, Jp))
    bc = np.zeros((C, 6))
    np.add.at(bc, obs_cam, -np.einsum("mki,mk->mi", wJc, r))
    bp = np.zeros((P, 3))
    np.add.at(bp, obs_pt, -np.einsum("mki,mk->mi", wJp, r))
    return Hcc, Hpp, Hcp, bc, bp


def _damped_step(blocks: tuple, free: np.ndarray, lam: float) -> tuple[np.ndarray, np.ndarray]:
    """Camera (C, 6) and point (P, 3) steps of the damped system, points eliminated (Schur complement)."""
    Hcc, Hpp, Hcp, bc, bp = blocks
    C = len(Hcc)
    Hcc_d = Hcc.copy()
    idx = np.arange(6)
    Hcc_d[:, idx, idx] = Hcc_d[:, idx, idx] * (1.0 + lam) + 1e-9
    Hcc_d[~free] = np.eye(6)
    Hpp_d = Hpp.copy()
    idx3 = np.arange(3)
    Hpp_d[:, idx3, idx3] = Hpp_d[:, idx3, idx3] * (1.0 + lam) + 1e-9
    Hpp_inv = np.linalg.inv(Hpp_d)
    E = np.einsum("pcij,pjk->pcik", Hcp, Hpp_inv)  # (P, C, 6, 3)
    S = np.zeros((C, 6, C, 6))
    S[np.arange(C), :, np.arange(C), :] = Hcc_d
    S -= np.einsum("pcij,pdkj->cidk", E, Hcp)
    rhs = bc - np.einsum("pcij,pj->ci", E, bp)
    S2 = S.reshape(6 * C, 6 * C)
    rhs[~free] = 0.0
    try:
        dc = np.linalg.solve(S2, rhs.reshape(-1)).reshape(C, 6)
    except np.linalg.LinAlgError:
        dc = np.linalg.lstsq(S2, rhs.reshape(-1), rcond=None)[0].reshape(C, 6)
    dc[~free] = 0.0
    dp = np.einsum("pij,pj->pi", Hpp_inv, bp - np.einsum("pcji,cj->pi", Hcp, dc))
    return dc, dp


def bundle_adjust(
    T_cam_map: np.ndarray,
    points: np.ndarray,
    obs_cam: np.ndarray,
    obs_pt: np.ndarray,
    obs_uv: np.ndarray,
    K: np.ndarray,
    *,
    fixed_cams: np.ndarray | None = None,
    config: BundleAdjustConfig | None = None,
    **overrides,
) -> BundleResult:
    """Levenberg-Marquardt bundle adjustment with a Schur complement.

    Parameters
    ----------
    T_cam_map : (C, 4, 4) ndarray
        Initial map-to-camera poses.
    points : (P, 3) ndarray
        Initial map points.
    obs_cam, obs_pt : (M,) int ndarrays
        Camera and point index of each observation.
    obs_uv : (M, 2) ndarray
        Observed undistorted pixels.
    K : (3, 3) ndarray
        Pinhole intrinsics.
    fixed_cams : (C,) bool ndarray, optional
        Cameras held fixed (gauge); by default the first one.
    config : BundleAdjustConfig, optional
        Options; ``iterations=``, ``huber_px=`` may also be given as keywords.

    Returns
    -------
    BundleResult
    """
    cfg = _with_overrides(config, BundleAdjustConfig, overrides)
    huber_px = cfg.huber_px
    T = np.array(T_cam_map, dtype=float)
    X = np.array(points, dtype=float)
    C, P = len(T), len(X)
    obs_cam = np.asarray(obs_cam, dtype=np.int64)
    obs_pt = np.asarray(obs_pt, dtype=np.int64)
    obs_uv = np.asarray(obs_uv, dtype=float)
    if fixed_cams is None:
        fixed_cams = np.zeros(C, dtype=bool)
        fixed_cams[0] = True
    free = ~np.asarray(fixed_cams, dtype=bool)
    lam = 1e-3
    r, Xc = projection_residuals(T, X, obs_cam, obs_pt, obs_uv, K)
    cost = _robust_cost(r, huber_px)
    it = 0
    for it in range(1, cfg.iterations + 1):
        Jc, Jp = _jacobians(Xc, T[obs_cam, :3, :3], K)
        Jc[~free[obs_cam]] = 0.0
        blocks = _normal_equations(Jc, Jp, _huber_weights(r, huber_px), r, obs_cam, obs_pt, C, P)
        while True:
            dc, dp = _damped_step(blocks, free, lam)
            T_new = T.copy()
            for c in np.flatnonzero(free):
                T_new[c] = exp_se3(dc[c]) @ T[c]
            X_new = X + dp
            r_new, Xc_new = projection_residuals(T_new, X_new, obs_cam, obs_pt, obs_uv, K)
            cost_new = _robust_cost(r_new, huber_px)
            if cost_new < cost:
                T, X, r, Xc = T_new, X_new, r_new, Xc_new
                converged = (cost - cost_new) < 1e-6 * cost
                cost = cost_new
                lam = max(lam / 5.0, 1e-7)
                break
            lam *= 10.0
            if lam > 1e6:
                converged = True
                break
        if converged:
            break
    res = np.linalg.norm(r, axis=1)
    inl = res < 3 * huber_px
    rms = float(np.sqrt(np.mean(res[inl] ** 2))) if np.any(inl) else float("inf")
    return BundleResult(T_cam_map=T, points=X, residual_px=res, rms_px=rms, iterations=it)


def outlier_threshold_px(residual_px: np.ndarray, *, sigmas: float = 4.0, min_px: float = 0.5,
                         max_px: float = 6.0) -> float:
    """Reprojection error above which an observation is an outlier, from the residuals' own scale.

    The per-axis noise scale of 2-D residuals is their median norm / 1.1774
    (Rayleigh distribution); the threshold is ``sigmas`` times it (4 sigma is
    exceeded with probability 3e-4 under the Gaussian), clipped to
    ``[min_px, max_px]``.
    """
    r = np.asarray(residual_px, dtype=float)
    sigma = float(np.median(r)) / 1.1774 if len(r) else 0.0
    return float(np.clip(sigmas * sigma, min_px, max_px))


def bundle_adjust_rejecting_outliers(
    T_cam_map: np.ndarray,
    points: np.ndarray,
    obs_cam: np.ndarray,
    obs_pt: np.ndarray,
    obs_uv: np.ndarray,
    K: np.ndarray,
    *,
    fixed_cams: np.ndarray | None = None,
    config: OutlierRejectionConfig | None = None,
    **overrides,
) -> tuple[BundleResult, np.ndarray]:
    """Bundle adjustment that rejects the observations beyond the residuals' own noise level.

    A fixed pixel threshold is not enough for KLT tracks (noise ~0.05 px): a
    track that slides along an occluding contour (a corner on the stele's
    outline over the background) is fitted within ~1 px by a wrong landmark
    depth and a shifted pose, and the Huber loss alone leaves it its pull
    (docs/vse.md, "The stele's 6-leg drift"). Each round solves from the input
    values without the observations judged outliers by the previous round, and
    judges all observations afresh (a first solution pulled by the outliers
    misjudges some inliers), until the set no longer changes or ``max_rounds``.
    Points whose every observation is rejected keep their input position.

    Parameters
    ----------
    T_cam_map, points, obs_cam, obs_pt, obs_uv, K, fixed_cams
        As :func:`bundle_adjust`.
    config : OutlierRejectionConfig, optional
        Options; its fields may also be given as keywords (``iterations=``,
        ``huber_px=``, ``outlier_sigmas=``, ``outlier_min_px=``,
        ``outlier_max_px=``, ``max_rounds=``).

    Returns
    -------
    result : BundleResult
        The last solution; ``residual_px`` holds the residual of every
        observation at it, rejected ones included.
    outlier : (M,) bool ndarray
        The observations beyond the threshold at that solution (when the
        rounds converged, exactly those it was computed without; with
        ``max_rounds=1``, the single solve and fixed-threshold test).
    """
    cfg = _with_overrides(config, OutlierRejectionConfig, overrides)
    solve = BundleAdjustConfig(iterations=cfg.iterations, huber_px=cfg.huber_px)
    obs_cam, obs_pt, obs_uv = np.asarray(obs_cam), np.asarray(obs_pt), np.asarray(obs_uv, dtype=float)
    X_in = np.asarray(points, dtype=float)
    bad = np.zeros(len(obs_cam), bool)
    res, new = None, bad
    for _ in range(cfg.max_rounds):
        res = bundle_adjust(T_cam_map, X_in, obs_cam[~bad], obs_pt[~bad], obs_uv[~bad], K, fixed_cams=fixed_cams,
                            config=solve)
        seen = np.bincount(obs_pt[~bad], minlength=len(X_in)) > 0
        X = np.where(seen[:, None], res.points, X_in)
        r = np.linalg.norm(projection_residuals(res.T_cam_map, X, obs_cam, obs_pt, obs_uv, K)[0], axis=1)
        res = replace(res, points=X, residual_px=r)
        # judged afresh each round: a first solution pulled by the outliers misjudges some inliers
        thr = outlier_threshold_px(r[~bad], sigmas=cfg.outlier_sigmas, min_px=cfg.outlier_min_px,
                                   max_px=cfg.outlier_max_px)
        new = r > thr
        if np.array_equal(new, bad) or (~new).sum() < 10:
            break
        bad = new
    return res, new


def refine_pose(
    T_cam_map: np.ndarray,
    points: np.ndarray,
    uv: np.ndarray,
    K: np.ndarray,
    *,
    iterations: int = 10,
    huber_px: float = 1.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Motion-only Gauss-Newton refinement of one pose against fixed points.

    Parameters
    ----------
    T_cam_map : (4, 4) ndarray
        Initial map-to-camera pose.
    points : (N, 3) ndarray
        Map points.
    uv : (N, 2) ndarray
        Their observed undistorted pixels.
    K : (3, 3) ndarray
        Pinhole intrinsics.

    Returns
    -------
    T_cam_map : (4, 4) ndarray
        Refined pose.
    residual_px : (N,) ndarray
        Reprojection errors at the refined pose.
    """
    T = np.array(T_cam_map, dtype=float)
    n = len(points)
    cam = np.zeros(n, dtype=np.int64)
    pt = np.arange(n)
    for _ in range(iterations):
        r, Xc = projection_residuals(T[None], points, cam, pt, uv, K)
        w = _huber_weights(r, huber_px)
        Jc, _ = _jacobians(Xc, np.repeat(T[None, :3, :3], n, axis=0), K)
        H = np.einsum("mki,mkj->ij", Jc * w[:, None, None], Jc) + 1e-9 * np.eye(6)
        b = -np.einsum("mki,mk->i", Jc * w[:, None, None], r)
        d = np.linalg.solve(H, b)
        T = exp_se3(d) @ T
        if np.linalg.norm(d) < 1e-10:
            break
    r, _ = projection_residuals(T[None], points, cam, pt, uv, K)
    return T, np.linalg.norm(r, axis=1)
