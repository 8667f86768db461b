"""Bundle adjustment and motion-only pose refinement (pinhole, Huber loss).

The solver is fgcd's one Levenberg-Marquardt (:mod:`fgcd_core.lm`) with the one
Schur-complement solve (:mod:`fgcd_core.schur`), not ``scipy.optimize.least_squares``:
a windowed bundle adjustment has few cameras (<= ~20) and many points, so the
reduced camera system is small and dense and, with analytic Jacobians, a solve
takes tens of milliseconds where ``least_squares(jac_sparsity=...)`` takes
seconds (docs/vse.md, "Design and why").

Poses are optimised as ``T_cam_map`` (map-to-camera) with a left perturbation
``T <- exp_se3(delta) @ T``, ``delta = (rho, phi)``. Observations are
undistorted pixels (ideal pinhole with ``fx, fy, cx, cy``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from fgcd_core.camera import MIN_DEPTH_M, pinhole_pixels
from fgcd_core.lm import LMSchedule, huber_cost, huber_weights, levenberg_marquardt
from fgcd_core.schur import BlockNormalEquations, Damping, SchurDamping, block_normal_equations, schur_step
from fgcd_core.se3 import exp_se3, transform_each

__all__ = [
    "BundleResult",
    "BundleAdjustConfig",
    "OutlierRejectionConfig",
    "bundle_adjust",
    "bundle_adjust_rejecting_outliers",
    "outlier_threshold_px",
    "refine_pose",
    "projection_residuals",
]


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
    T_cam_map: np.ndarray,
    points: np.ndarray,
    obs_cam: np.ndarray,
    obs_pt: np.ndarray,
    obs_uv: np.ndarray,
    K: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Residuals ``projected - observed`` (M, 2) in pixels and camera-frame points (M, 3)."""
    Xc = transform_each(T_cam_map[obs_cam], points[obs_pt])
    r = pinhole_pixels(K, Xc) - obs_uv
    r[Xc[:, 2] <= MIN_DEPTH_M] = 1e3  # behind the camera: a residual far in the Huber tail
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


class _BAState(NamedTuple):
    """Poses, points, and the residuals and camera-frame points at them."""

    T: np.ndarray
    X: np.ndarray
    r: np.ndarray
    Xc: np.ndarray


@dataclass(frozen=True, kw_only=True)
class _BundleProblem:
    """The bundle adjustment as a :class:`fgcd_core.lm.LeastSquaresProblem` (Huber IRLS, Schur solve)."""

    obs_cam: np.ndarray
    obs_pt: np.ndarray
    obs_uv: np.ndarray
    K: np.ndarray
    free: np.ndarray
    huber_px: float

    def state(self, T: np.ndarray, X: np.ndarray) -> _BAState:
        r, Xc = projection_residuals(T, X, self.obs_cam, self.obs_pt, self.obs_uv, self.K)
        return _BAState(T, X, r, Xc)

    def cost(self, s: _BAState) -> float:
        return huber_cost(np.linalg.norm(s.r, axis=1), self.huber_px)

    def linearise(self, s: _BAState) -> BlockNormalEquations:
        Jc, Jp = _jacobians(s.Xc, s.T[self.obs_cam, :3, :3], self.K)
        Jc[~self.free[self.obs_cam]] = 0.0
        w = huber_weights(np.linalg.norm(s.r, axis=1), self.huber_px)
        return block_normal_equations(s.r, Jc, Jp, w, self.obs_cam, self.obs_pt, n_cameras=len(s.T), n_points=len(s.X))

    def step(self, eq: BlockNormalEquations, lam: float):
        return schur_step(eq, lam, _DAMPING, self.free)

    def apply(self, s: _BAState, step) -> _BAState:
        dc, dp = step
        T_new = s.T.copy()
        for c in np.flatnonzero(self.free):
            T_new[c] = exp_se3(dc[c]) @ s.T[c]
        return self.state(T_new, s.X + dp)

    def step_size(self, step) -> float:
        return float(np.linalg.norm(step[0]))


#: Marquardt damping of both blocks plus a tiny absolute floor (a point seen in two nearly
#: parallel rays keeps an invertible block).
_DAMPING = SchurDamping(rule=Damping.MARQUARDT, camera_floor=1e-9, point_floor=1e-9)
#: lambda / 5 after a success, x 10 after a failure, converged below a 1e-6 relative decrease
_SCHEDULE = LMSchedule(
    initial_damping=1e-3, decrease=5.0, min_damping=1e-7, increase=10.0, max_damping=1e6, relative_decrease=1e-6
)


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
        Options (default: :class:`BundleAdjustConfig`).

    Returns
    -------
    BundleResult
    """
    cfg = BundleAdjustConfig() if config is None else config
    T = np.array(T_cam_map, dtype=float)
    X = np.array(points, dtype=float)
    if fixed_cams is None:
        fixed_cams = np.zeros(len(T), dtype=bool)
        fixed_cams[0] = True
    problem = _BundleProblem(
        obs_cam=np.asarray(obs_cam, dtype=np.int64),
        obs_pt=np.asarray(obs_pt, dtype=np.int64),
        obs_uv=np.asarray(obs_uv, dtype=float),
        K=K,
        free=~np.asarray(fixed_cams, dtype=bool),
        huber_px=cfg.huber_px,
    )
    out = levenberg_marquardt(problem, problem.state(T, X), replace(_SCHEDULE, max_iterations=cfg.iterations))
    res = np.linalg.norm(out.state.r, axis=1)
    inl = res < 3 * cfg.huber_px
    rms = float(np.sqrt(np.mean(res[inl] ** 2))) if np.any(inl) else float("inf")
    return BundleResult(
        T_cam_map=out.state.T, points=out.state.X, residual_px=res, rms_px=rms, iterations=out.iterations
    )


def outlier_threshold_px(
    residual_px: np.ndarray, *, sigmas: float = 4.0, min_px: float = 0.5, max_px: float = 6.0
) -> float:
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
        Options (default: :class:`OutlierRejectionConfig`).

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
    cfg = OutlierRejectionConfig() if config is None else config
    solve = BundleAdjustConfig(iterations=cfg.iterations, huber_px=cfg.huber_px)
    obs_cam, obs_pt, obs_uv = np.asarray(obs_cam), np.asarray(obs_pt), np.asarray(obs_uv, dtype=float)
    X_in = np.asarray(points, dtype=float)
    bad = np.zeros(len(obs_cam), bool)
    res, new = None, bad
    for _ in range(cfg.max_rounds):
        res = bundle_adjust(
            T_cam_map, X_in, obs_cam[~bad], obs_pt[~bad], obs_uv[~bad], K, fixed_cams=fixed_cams, config=solve
        )
        seen = np.bincount(obs_pt[~bad], minlength=len(X_in)) > 0
        X = np.where(seen[:, None], res.points, X_in)
        r = np.linalg.norm(projection_residuals(res.T_cam_map, X, obs_cam, obs_pt, obs_uv, K)[0], axis=1)
        res = replace(res, points=X, residual_px=r)
        # judged afresh each round: a first solution pulled by the outliers misjudges some inliers
        thr = outlier_threshold_px(
            r[~bad], sigmas=cfg.outlier_sigmas, min_px=cfg.outlier_min_px, max_px=cfg.outlier_max_px
        )
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
        w = huber_weights(np.linalg.norm(r, axis=1), huber_px)
        Jc, _ = _jacobians(Xc, np.repeat(T[None, :3, :3], n, axis=0), K)
        H = np.einsum("mki,mkj->ij", Jc * w[:, None, None], Jc) + 1e-9 * np.eye(6)
        b = -np.einsum("mki,mk->i", Jc * w[:, None, None], r)
        d = np.linalg.solve(H, b)
        T = exp_se3(d) @ T
        if np.linalg.norm(d) < 1e-10:
            break
    r, _ = projection_residuals(T[None], points, cam, pt, uv, K)
    return T, np.linalg.norm(r, axis=1)
