"""Camera uncertainty of an estimated pose (paper 001, §3.2, geometric variant).

The reference cloud is rendered at the estimated camera pose, the observed
session cloud (in the current camera frame) is registered to the rendering,
and the residual motion says how wrong the estimate is. Directions the geometry
does not constrain (a body of revolution turning about its axis, a plane
sliding along itself) are found from the point-to-plane information and set
apart. The registration is geometric (point-to-plane ICP in Open3D), not the
paper's coloured ICP: a revisit is under another light, and the reference
cloud's intensities are the reference lighting's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fgcd_cli.relocation.coarse.config import CoarseConfig
from fgcd_core.se3 import pose_distance

__all__ = [
    "CameraUncertainty",
    "camera_uncertainty",
    "in_view",
    "render_visible_points",
    "strong_directions",
    "visible_points",
]


@dataclass(frozen=True, kw_only=True)
class CameraUncertainty:
    """Residual motion between the observation and the reference rendered at an estimate.

    Attributes
    ----------
    translation_m, rotation_deg : float
        Size of the residual motion (inf when the registration had too little to work on).
    fitness : float
        Fraction of the observed points with a rendered point within the final radius.
    rmse_m : float
        RMS distance of those correspondences.
    observed, rendered : int
        Point counts that entered the registration.
    T_correction : (4, 4) ndarray
        Residual motion in the estimated camera frame: ``T_ref_cam_true ≈ T_ref_cam_est @ T_correction``.
    """

    translation_m: float
    rotation_deg: float
    fitness: float
    rmse_m: float
    observed: int
    rendered: int
    T_correction: np.ndarray
    weak_directions: int = 0
    """Directions of the residual registration the geometry does not constrain (a body of
    revolution turning about its axis, a plane sliding along itself)."""
    constrained_translation_m: float = math.inf
    constrained_rotation_deg: float = math.inf
    """The size of the residual motion without its part along the weak directions."""
    check_sigma_m: float = math.inf
    """What the check itself may be off by along the directions it constrains, by the covariance model
    (RMS over those directions of ``sigma_rel x depth / sqrt(lambda / N)``, translation part): a
    systematic cloud error moves the registration that far without any error in the estimate."""

    def verified(self, config: CoarseConfig, *, geometric_source: bool = True) -> bool:
        """True when the estimate is within the verification limits on enough overlap.

        An estimate from the geometry itself (the 3D alignment) is verified only where the
        geometry pins every direction: along a weak one, neither the alignment nor the residual
        registration sees an error, so a small residual says nothing there. An image estimate is
        checked on the constrained part: along the weak directions its texture correspondences
        are the evidence, and the registration's slide there is not a measurement
        (docs/relocation.md, "Far starts"; the measurements in docs/lab/2026-11-25-code-comment-measurements.md,
        "Relocation").
        """
        if self.fitness < config.min_fitness:
            return False
        if geometric_source:
            return (
                self.weak_directions == 0
                and self.translation_m <= config.verify_m
                and self.rotation_deg <= config.verify_deg
            )
        return self.constrained_translation_m <= config.verify_m and self.constrained_rotation_deg <= config.verify_deg

    def correction(self, *, geometric_source: bool = True) -> np.ndarray:
        """The residual motion to apply to the estimate: all of it for the geometry's own estimate, none for
        an image estimate.

        The check registers the session's cloud at a scale known to a percent or so (the alignment's,
        :func:`~fgcd_cli.relocation.coarse.passive.check_scale`, or the exploration's few %), whose error shifts
        the registration along the view by that fraction of the depth: 15 mm at 1.5 m for 1 %, against
        2 mm for PnP on a textured slab 92 mm from the reference. The check's constrained part may reject
        an image estimate, but as a correction it would move a good one by the scale's error
        (docs/lab/2026-11-27-coarse-far-starts.md, "Why the statue's far start cannot be verified"). A 3D
        estimate keeps the whole correction: it is verified only where the geometry pins every direction, and there the
        registration is the better measurement of the two.
        """
        if geometric_source:
            return self.T_correction
        return np.eye(4)

    def to_dict(self) -> dict:
        return {
            "translation_mm": self.translation_m * 1e3,
            "rotation_deg": self.rotation_deg,
            "fitness": self.fitness,
            "rmse_mm": self.rmse_m * 1e3,
            "observed": self.observed,
            "rendered": self.rendered,
            "weak_directions": self.weak_directions,
            "constrained_translation_mm": self.constrained_translation_m * 1e3,
            "constrained_rotation_deg": self.constrained_rotation_deg,
            "check_sigma_mm": self.check_sigma_m * 1e3,
        }


def render_visible_points(
    points_ref: np.ndarray, T_ref_cam: np.ndarray, camera, *, stride_px: int = 4, depth_tolerance_rel: float = 0.02
) -> np.ndarray:
    """The reference cloud as a depth camera at ``T_ref_cam`` would see it.

    Parameters
    ----------
    points_ref : (N, 3) ndarray
        Reference cloud, metres, ``ref`` frame.
    T_ref_cam : (4, 4) ndarray
        Camera pose in the ``ref`` frame.
    camera : PinholeCamera
        Intrinsics (``fx fy cx cy width height``).
    stride_px : int
        Pixel bin of the z-buffer; a sparse cloud leaves holes in a full-resolution buffer
        through which hidden points would show.
    depth_tolerance_rel : float
        A point within this fraction of its bin's front-most depth is kept (same surface).

    Returns
    -------
    (M, 3) ndarray
        Visible points in the camera frame, metres.
    """
    _index, Xc = visible_points(
        points_ref, T_ref_cam, camera, stride_px=stride_px, depth_tolerance_rel=depth_tolerance_rel
    )
    return Xc


def visible_points(
    points_ref: np.ndarray, T_ref_cam: np.ndarray, camera, *, stride_px: int = 4, depth_tolerance_rel: float = 0.02
) -> tuple[np.ndarray, np.ndarray]:
    """Which points a camera at ``T_ref_cam`` sees: in view and not hidden (z-buffer of the points themselves).

    Parameters are those of :func:`render_visible_points`.

    Returns
    -------
    index : (M,) int ndarray
        Indices into ``points_ref`` of the visible points.
    Xc : (M, 3) ndarray
        Those points in the camera frame, metres.
    """
    P = np.asarray(points_ref, dtype=float)
    T = np.asarray(T_ref_cam, dtype=float)
    Xc = (P - T[:3, 3]) @ T[:3, :3]
    uv, inside = camera.project(Xc)
    index = np.flatnonzero(inside)
    Xc, uv = Xc[inside], uv[inside]
    if len(Xc) == 0:
        return index, np.zeros((0, 3))
    z = Xc[:, 2]
    s = max(1, int(stride_px))
    cols = int(math.ceil(camera.width / s))
    col = np.clip(uv[:, 0], 0, camera.width - 1) // s
    row = np.clip(uv[:, 1], 0, camera.height - 1) // s
    cell = row.astype(np.int64) * cols + col.astype(np.int64)
    zmin = np.full(int(cell.max()) + 1, np.inf)
    np.minimum.at(zmin, cell, z)
    keep = z <= zmin[cell] * (1.0 + depth_tolerance_rel)
    return index[keep], Xc[keep]


def in_view(points: np.ndarray, T_frame_cam: np.ndarray, camera) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 3) of a frame seen by a camera at ``T_frame_cam``: the ones in front of it and inside
    its image, in the camera frame (M, 3), with their pixels (M, 2)."""
    P = np.asarray(points, dtype=float)
    T = np.asarray(T_frame_cam, dtype=float)
    Xc = (P - T[:3, 3]) @ T[:3, :3]
    uv, inside = camera.project(Xc)
    return Xc[inside], uv[inside]


def camera_uncertainty(
    observed_cam: np.ndarray,
    points_ref: np.ndarray,
    T_ref_cam_est: np.ndarray,
    camera,
    *,
    config: CoarseConfig = CoarseConfig(),
    seed: int = 0,
) -> CameraUncertainty:
    """Camera uncertainty of an estimated pose (paper 001, §3.2, geometric variant).

    Parameters
    ----------
    observed_cam : (N, 3) ndarray
        What the camera observes, in its own frame, metres (the session cloud, metric).
    points_ref : (M, 3) ndarray
        Reference cloud, ``ref`` frame, metres.
    T_ref_cam_est : (4, 4) ndarray
        The estimate to check.
    camera : PinholeCamera
    config : CoarseConfig
    seed : int
        Subsampling seed.

    Returns
    -------
    CameraUncertainty
        The residual registration, coarse to fine (radii 15, 5, 2 % of the median depth),
        from the identity. Infinite when either side has fewer than 100 points.
    """
    import open3d as o3d

    rendered = render_visible_points(points_ref, T_ref_cam_est, camera, stride_px=config.render_stride_px)
    obs = np.asarray(observed_cam, dtype=float)
    rng = np.random.default_rng(seed)
    if len(obs) > config.max_points:
        obs = obs[rng.choice(len(obs), config.max_points, replace=False)]
    if len(rendered) > 2 * config.max_points:
        rendered = rendered[rng.choice(len(rendered), 2 * config.max_points, replace=False)]
    if len(obs) < 100 or len(rendered) < 100:
        return CameraUncertainty(
            translation_m=math.inf,
            rotation_deg=math.inf,
            fitness=0.0,
            rmse_m=math.inf,
            observed=len(obs),
            rendered=len(rendered),
            T_correction=np.eye(4),
        )
    depth = float(np.median(obs[:, 2]))
    src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(obs))
    dst = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(rendered))
    dst.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.05 * depth, max_nn=30))
    dst.orient_normals_towards_camera_location(np.zeros(3))
    T = np.eye(4)
    result = None
    for radius_rel, iterations in ((0.15, 30), (0.05, 30), (0.02, 30)):
        result = o3d.pipelines.registration.registration_icp(
            src,
            dst,
            radius_rel * depth,
            T,
            o3d.pipelines.registration.TransformationEstimationPointToPlane(),
            o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=iterations),
        )
        T = np.asarray(result.transformation)
    # ``T`` maps observed (true camera frame) points onto the rendering (estimated camera frame):
    # T_estcam_truecam, i.e. the true camera in the estimated camera's frame.
    mm, deg = pose_distance(np.eye(4), T)
    weak, T_constrained, check_sigma_m = _constrained_part(
        T, obs, rendered, np.asarray(dst.normals), radius=0.02 * depth, depth=depth, config=config
    )
    c_mm, c_deg = pose_distance(np.eye(4), T_constrained)
    return CameraUncertainty(
        translation_m=mm / 1e3,
        rotation_deg=deg,
        fitness=float(result.fitness),
        rmse_m=float(result.inlier_rmse),
        observed=len(obs),
        rendered=len(rendered),
        T_correction=T.copy(),
        weak_directions=weak,
        constrained_translation_m=c_mm / 1e3,
        constrained_rotation_deg=c_deg,
        check_sigma_m=check_sigma_m,
    )


def sensitivity_of(evals: np.ndarray, n: int) -> np.ndarray:
    """RMS residual per unit motion along each eigen-direction of a point-to-plane information ``J^T J``
    (eigenvalues ``evals`` (6,)) over ``n`` correspondences: ``sqrt(lambda / n)``."""
    return np.sqrt(np.clip(evals, 0.0, None) / max(n, 1))


def _constrained_part(
    T: np.ndarray,
    observed: np.ndarray,
    rendered: np.ndarray,
    normals: np.ndarray,
    *,
    radius: float,
    depth: float,
    config: CoarseConfig,
) -> tuple[int, np.ndarray, float]:
    """The residual motion ``T`` without its part along the registration's weak directions
    (:func:`strong_directions` on the ``N`` final correspondences). Returns the weak count, ``exp`` of
    the twist projected onto the others, and the check's own uncertainty on that part (metres): along
    each kept direction the model's bound ``sigma_rel x depth / sqrt(lambda / N)``, their translation
    parts summed in quadrature.
    """
    from scipy.spatial import cKDTree

    from fgcd_core.se3 import exp_se3, log_se3

    p = observed @ T[:3, :3].T + T[:3, 3]
    dist, idx = cKDTree(rendered).query(p, distance_upper_bound=radius)
    ok = np.isfinite(dist)
    if ok.sum() < 50:
        return 6, np.eye(4), math.inf
    strong, evecs, sensitivity = strong_directions(p[ok], normals[idx[ok]], depth=depth, config=config)
    xi = log_se3(T)
    v = np.concatenate([xi[:3], xi[3:] * depth])
    E = evecs[:, strong]
    v_c = E @ (E.T @ v)
    bound = config.sigma_rel * depth / np.maximum(sensitivity[strong], 1e-12)
    check_sigma = float(np.sqrt(np.sum((bound * np.linalg.norm(E[:3], axis=0)) ** 2)))
    return int((~strong).sum()), exp_se3(np.concatenate([v_c[:3], v_c[3:] / depth])), check_sigma


def strong_directions(
    points_cam: np.ndarray, normals_cam: np.ndarray, *, depth: float, config: CoarseConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which directions of a point-to-plane registration the geometry constrains (the covariance model).

    Parameters
    ----------
    points_cam : (N, 3) ndarray
        Surface points in the camera frame, metres.
    normals_cam : (N, 3) ndarray
        Their unit normals, camera frame.
    depth : float
        Scene depth, metres (rotations are weighed as motions at this depth).
    config : CoarseConfig
        ``sigma_rel``, ``verify_m`` and the ``weak_ratio`` override.

    Returns
    -------
    strong : (6,) bool ndarray
        Per eigen-direction (ascending eigenvalue), True when constrained.
    directions : (6, 6) ndarray
        The eigen-directions as columns, twist ``(t, depth * phi)``.
    sensitivity : (6,) ndarray
        RMS residual per unit motion along each, ``sqrt(lambda / N)`` (metres per metre).

    Point-to-plane information ``H = sum J^T J`` with ``J = [n, (p x n) / depth]`` (twist
    ``(t, depth * phi)``). Covariance model (docs/relocation.md, "Far starts"): the residuals are
    not independent noise but a systematic cloud error of up to ``b = sigma_rel x depth`` (each
    monocular cloud is placed to ~1 % of the depth). Such an error shifts the solution along an
    eigen-direction of ``H`` by at most ``b / sqrt(lambda / N)`` (Cauchy-Schwarz on
    ``H^-1 J^T r``), so the direction is weak when that exceeds ``verify_m``: the check cannot see
    an error along it. ``config.weak_ratio``, when set, replaces the model by a fraction of the
    strongest direction. Written by hand: Open3D's information matrix is the point-to-point one,
    which does not see a surface sliding along itself.
    """
    p = np.asarray(points_cam, dtype=float)
    n = np.asarray(normals_cam, dtype=float)
    J = np.hstack([n, np.cross(p, n) / depth])
    evals, evecs = np.linalg.eigh(J.T @ J)
    sensitivity = sensitivity_of(evals, len(J))
    if config.weak_ratio is not None:
        strong = evals >= config.weak_ratio * evals.max()
    else:
        strong = config.sigma_rel * depth <= config.verify_m * sensitivity
    return strong, evecs, sensitivity
