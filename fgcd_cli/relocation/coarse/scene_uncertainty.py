"""Scene uncertainty (paper 001, "Scene Uncertainty Component", Eq. 1-2): where the object is localizable from.

The camera-driven scene map ``U_cd``: for each candidate camera position of the
revisit workspace, ``N_cd`` view directions are predicted, and

    U_cd,i = 1 - (1 / N_cd) sum_j A_j                                  (Eq. 2)

with ``A_j`` = 1 when at least one of the coarse stage's two passive localizers
would succeed from that view. The paper renders each view and runs its
localizer; here each localizer's success is *predicted* from the reference
observation by a stated model (docs/relocation.md, "Scene uncertainty"):

* **image localizer** (SIFT matches to the reference image lifted to 3D by the
  reference cloud, PnP; :func:`fgcd_cli.relocation.coarse.passive.image_estimate`): the
  reference keypoints with a 3D point that the candidate sees (in view, not
  hidden behind the reference surface) under a viewing-angle change SIFT
  tolerates; it succeeds when they are at least the PnP minimum the localizer
  uses and the PnP covariance they predict (reprojection Jacobian, stated pixel
  noise) is within the verification limits;
* **3D localizer** (point-to-plane registration of the session cloud): the
  reference surface the candidate sees; it succeeds when the registration has
  no weak direction under the same covariance model the camera uncertainty
  uses (:func:`fgcd_cli.relocation.coarse.camera_uncertainty.strong_directions`).

Candidate positions form a grid over the plane through the reference camera
centre parallel to its image plane (optionally several depth layers), in the
reference camera frame (x right, y down, z forward, metres). The view directions
are the look at the object's centroid and that look turned by ``spread_deg``
left, right, up and down (the turns the coarse stage's look action makes).
"""

from __future__ import annotations

import io
import json
import math
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from fgcd_cli.relocation.coarse.camera_uncertainty import strong_directions, visible_points
from fgcd_cli.relocation.coarse.config import CoarseConfig
from fgcd_cli.relocation.image.pnp_uncertainty import pnp_jacobian
from fgcd_cli.relocation.image.refine import ImageRefineConfig

__all__ = [
    "SceneModel",
    "SceneUncertaintyConfig",
    "SceneUncertaintyMap",
    "ViewPrediction",
    "build_scene_model",
    "camera_turn",
    "look_at",
    "predict_view",
    "scene_uncertainty_map",
    "view_uncertainty",
]


@dataclass(frozen=True, kw_only=True)
class SceneUncertaintyConfig:
    """Options of the scene uncertainty map. Distances in metres, angles in degrees."""

    extent_m: float = 0.25
    """Half-width of the grid of candidate positions (the revisit workspace around the reference camera)."""
    cells: int = 11
    """Grid positions per axis."""
    depth_layers_m: tuple[float, ...] = (0.0,)
    """Offsets of the grid planes along the reference camera's optical axis."""
    spread_deg: float = 8.0
    """The view directions besides the look at the centroid: turned by this much left, right, up and
    down (N_cd = 5). Default: the farthest turn of the coarse stage's look action (2 x ``look_deg``)."""
    sift_tolerance_deg: float = 30.0
    """Largest viewing-angle change (between the rays from a keypoint to the reference camera and to
    the candidate) under which a SIFT keypoint is counted as matchable. SIFT matching degrades with
    out-of-plane rotation and is reliable to about 30-40 deg of viewpoint change (Lowe 2004, IJCV,
    sec. 7; Morel & Yu 2009, ASIFT, sec. 1-2); the lower end is taken."""
    pixel_sigma_px: float = ImageRefineConfig.max_rms_px
    """Pixel noise of the predicted PnP covariance: the largest inlier RMS the image localizer
    accepts (it refuses a worse fit), so the prediction bounds the fits it returns."""
    min_keypoints: int = ImageRefineConfig.min_inliers
    """PnP minimum of the image localizer (its ``min_inliers``)."""
    min_points: int = 100
    """Fewest visible surface points the 3D check works on (:func:`camera_uncertainty`'s minimum)."""
    max_points: int = 20000
    """The reference cloud is subsampled to this many points (cost)."""
    render_stride_px: int = 4
    """Pixel bin of the z-buffer (as :class:`CoarseConfig`)."""

    def directions(self) -> list[tuple[float, float]]:
        """The ``N_cd`` view-direction offsets ``(yaw, pitch)``, radians."""
        s = math.radians(self.spread_deg)
        return [(0.0, 0.0), (s, 0.0), (-s, 0.0), (0.0, s), (0.0, -s)]


@dataclass(frozen=True, kw_only=True)
class SceneModel:
    """What the two localizers' success models need from the reference observation.

    Attributes
    ----------
    points : (N, 3) ndarray
        Subsampled reference cloud, ``ref`` frame, metres.
    normals : (N, 3) ndarray
        Their unit normals, oriented towards the reference camera.
    keypoints : (K, 3) ndarray
        Reference SIFT keypoints lifted to 3D, ``ref`` frame, metres.
    keypoint_image : (K,) int ndarray
        Which reference image each keypoint comes from (the localizer matches one image at a time).
    T_ref_camref : (4, 4) ndarray
        Reference camera pose.
    centroid : (3,) ndarray
        Centroid of the surface the reference camera sees, ``ref`` frame, metres.
    """

    points: np.ndarray
    normals: np.ndarray
    keypoints: np.ndarray
    keypoint_image: np.ndarray
    T_ref_camref: np.ndarray
    centroid: np.ndarray


@dataclass(frozen=True, kw_only=True)
class ViewPrediction:
    """Predicted outcome of the two passive localizers from one camera pose.

    Attributes
    ----------
    image_ok, geometry_ok : bool
        Whether the image (PnP) and the 3D localizer are predicted to succeed.
    keypoints : int
        Matchable reference keypoints seen (of the best reference image).
    image_sigma_m, image_sigma_deg : float
        Predicted 1-sigma PnP error (RMS radius of the camera position, of the rotation); inf below
        the PnP minimum.
    surface_points : int
        Visible reference points.
    weak_directions : int
        Directions the visible geometry does not constrain (6 with too few points).
    """

    image_ok: bool
    geometry_ok: bool
    keypoints: int
    image_sigma_m: float
    image_sigma_deg: float
    surface_points: int
    weak_directions: int

    @property
    def ok(self) -> bool:
        return self.image_ok or self.geometry_ok


def build_scene_model(
    *,
    reference_points: np.ndarray,
    T_ref_camref: np.ndarray,
    camera,
    keypoints_per_image: list[np.ndarray],
    config: SceneUncertaintyConfig = SceneUncertaintyConfig(),
    seed: int = 0,
) -> SceneModel:
    """The success models' inputs from the reference observation.

    Parameters
    ----------
    reference_points : (N, 3) ndarray
        Reference cloud, ``ref`` frame, metres.
    T_ref_camref : (4, 4) ndarray
        Reference camera pose.
    camera : PinholeCamera
    keypoints_per_image : list of (K_i, 3) ndarray
        The reference keypoints lifted to 3D, per reference image
        (:func:`fgcd_cli.relocation.image.refine.reference_keypoints_3d`).
    config : SceneUncertaintyConfig
    seed : int
        Subsampling seed.

    Returns
    -------
    SceneModel
    """
    import open3d as o3d

    T = np.asarray(T_ref_camref, dtype=float)
    P = np.asarray(reference_points, dtype=float)
    if len(P) > config.max_points:
        P = P[np.random.default_rng(seed).choice(len(P), config.max_points, replace=False)]
    _idx, seen = visible_points(P, T, camera, stride_px=config.render_stride_px)
    depth = float(np.median(seen[:, 2])) if len(seen) else float(np.median(np.linalg.norm(P - T[:3, 3], axis=1)))
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    # the same normal estimate as the camera uncertainty's rendering (radius 5 % of the depth)
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.05 * depth, max_nn=30))
    cloud.orient_normals_towards_camera_location(T[:3, 3])
    centroid = (seen.mean(axis=0) @ T[:3, :3].T + T[:3, 3]) if len(seen) else P.mean(axis=0)
    kps = [np.asarray(k, dtype=float).reshape(-1, 3) for k in keypoints_per_image]
    return SceneModel(
        points=P,
        normals=np.asarray(cloud.normals),
        keypoints=np.vstack(kps or [np.zeros((0, 3))]),
        keypoint_image=np.concatenate([np.full(len(k), i) for i, k in enumerate(kps)] or [np.zeros(0)]).astype(int),
        T_ref_camref=T,
        centroid=np.asarray(centroid, dtype=float),
    )


def camera_turn(yaw_rad: float, pitch_rad: float) -> np.ndarray:
    """A turn of the camera about its own centre, (4, 4): yaw about its vertical (y) axis, then pitch
    about its horizontal (x) axis."""
    cy, sy, cp, sp = math.cos(yaw_rad), math.sin(yaw_rad), math.cos(pitch_rad), math.sin(pitch_rad)
    M = np.eye(4)
    M[:3, :3] = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]]) @ np.array(
        [[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]]
    )
    return M


def look_at(centre: np.ndarray, target: np.ndarray, down: np.ndarray) -> np.ndarray:
    """Camera pose (4, 4) at ``centre`` (3,) whose optical axis points at ``target`` (3,), its image's
    y axis as near ``down`` (3,) as that allows (x right, y down, z forward)."""
    z = np.asarray(target, dtype=float) - np.asarray(centre, dtype=float)
    z /= np.linalg.norm(z)
    x = np.cross(np.asarray(down, dtype=float), z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = centre
    return T


def _pnp_sigma(Xc: np.ndarray, camera, pixel_sigma_px: float) -> tuple[float, float]:
    """Predicted 1-sigma PnP error from 2D-3D points ``Xc`` (K, 3) in the camera frame, metres.

    Gauss-Newton covariance ``sigma^2 (J^T J)^-1`` of the pose at the camera itself (``rvec = tvec = 0``,
    where the translation's uncertainty is the camera centre's) with ``J`` the localizer's own
    reprojection Jacobian (:func:`~fgcd_cli.relocation.image.pnp_uncertainty.pnp_jacobian`). Returns the RMS
    radius of the position error (metres) and of the rotation error (degrees); inf when the system is
    singular.
    """
    _proj, J = pnp_jacobian(Xc, np.zeros(3), np.zeros(3), camera.K)
    H = J.T @ J
    if np.linalg.cond(H) > 1e12:
        return math.inf, math.inf
    cov = pixel_sigma_px**2 * np.linalg.inv(H)
    return (
        float(math.sqrt(max(0.0, float(np.trace(cov[3:, 3:]))))),
        math.degrees(math.sqrt(max(0.0, float(np.trace(cov[:3, :3]))))),
    )


def predict_view(
    model: SceneModel,
    T_ref_cam: np.ndarray,
    camera,
    *,
    config: SceneUncertaintyConfig = SceneUncertaintyConfig(),
    coarse: CoarseConfig = CoarseConfig(),
) -> ViewPrediction:
    """Whether each passive localizer is predicted to succeed from a camera at ``T_ref_cam`` (4, 4).

    The reference cloud and keypoints are rendered into one z-buffer (a keypoint behind the
    surface is hidden). Image localizer: the keypoints seen under a viewing-angle change within
    ``config.sift_tolerance_deg``, counted per reference image; success when the best image has
    ``config.min_keypoints`` and their predicted PnP error is within ``coarse.verify_m`` /
    ``coarse.verify_deg``. 3D localizer: success when at least ``config.min_points`` surface points
    are seen and the point-to-plane registration on them has no weak direction
    (:func:`~fgcd_cli.relocation.coarse.camera_uncertainty.strong_directions`, the camera uncertainty's model).
    """
    T = np.asarray(T_ref_cam, dtype=float)
    n = len(model.points)
    idx, Xc = visible_points(np.vstack([model.points, model.keypoints]), T, camera, stride_px=config.render_stride_px)
    surf = idx < n
    weak = 6
    if surf.sum() >= config.min_points:
        strong, _, _ = strong_directions(
            Xc[surf], model.normals[idx[surf]] @ T[:3, :3], depth=float(np.median(Xc[surf, 2])), config=coarse
        )
        weak = int((~strong).sum())
    k = idx[~surf] - n
    K = model.keypoints[k]
    to_ref = model.T_ref_camref[:3, 3] - K
    to_cam = T[:3, 3] - K
    cos = np.einsum("ij,ij->i", to_ref, to_cam) / (np.linalg.norm(to_ref, axis=1) * np.linalg.norm(to_cam, axis=1))
    matchable = cos >= math.cos(math.radians(config.sift_tolerance_deg))
    counts = np.bincount(model.keypoint_image[k][matchable], minlength=1)
    best = int(np.argmax(counts))
    sigma_m = sigma_deg = math.inf
    if counts[best] >= config.min_keypoints:
        sel = matchable & (model.keypoint_image[k] == best)
        sigma_m, sigma_deg = _pnp_sigma(Xc[~surf][sel], camera, config.pixel_sigma_px)
    return ViewPrediction(
        image_ok=bool(sigma_m <= coarse.verify_m and sigma_deg <= coarse.verify_deg),
        geometry_ok=weak == 0,
        keypoints=int(counts[best]),
        image_sigma_m=sigma_m,
        image_sigma_deg=sigma_deg,
        surface_points=int(surf.sum()),
        weak_directions=weak,
    )


def view_uncertainty(
    model: SceneModel,
    T_ref_cam: np.ndarray,
    camera,
    *,
    config: SceneUncertaintyConfig = SceneUncertaintyConfig(),
    coarse: CoarseConfig = CoarseConfig(),
) -> tuple[float, float, float]:
    """Eq. 2 at one camera pose (4, 4): over the ``N_cd`` directions ``config.directions()`` turned from it.

    Returns
    -------
    U : float
        1 - fraction of the directions where at least one localizer succeeds, in [0, 1].
    image_fraction, geometry_fraction : float
        Fraction where the image (PnP), the 3D localizer succeeds.
    """
    preds = [
        predict_view(model, T_ref_cam @ camera_turn(yaw, pitch), camera, config=config, coarse=coarse)
        for yaw, pitch in config.directions()
    ]
    n = len(preds)
    return (
        1.0 - sum(p.ok for p in preds) / n,
        sum(p.image_ok for p in preds) / n,
        sum(p.geometry_ok for p in preds) / n,
    )


@dataclass(frozen=True, kw_only=True)
class SceneUncertaintyMap:
    """The camera-driven scene map ``U_cd`` (paper 001, Eq. 2) of one reference observation.

    Attributes
    ----------
    x_m, y_m, z_m : (nx,), (ny,), (nz,) ndarray
        Grid axes: candidate camera centres in the reference camera frame (x right, y down,
        z forward), metres.
    uncertainty : (nz, ny, nx) ndarray
        ``U`` per position, in [0, 1] (1: no direction localizes).
    successes, image_successes, geometry_successes : (nz, ny, nx) int ndarray
        Directions (of ``n_directions``) where either, the image, the 3D localizer succeeds.
    n_directions : int
        ``N_cd``.
    config : SceneUncertaintyConfig
    model : SceneModel
        The inputs of the success models (to predict other views, e.g. the coarse stage's looks).
    seconds : float
        Time it took to compute.
    """

    x_m: np.ndarray
    y_m: np.ndarray
    z_m: np.ndarray
    uncertainty: np.ndarray
    successes: np.ndarray
    image_successes: np.ndarray
    geometry_successes: np.ndarray
    n_directions: int
    config: SceneUncertaintyConfig = field(default_factory=SceneUncertaintyConfig)
    model: SceneModel | None = None
    seconds: float = math.nan

    def to_npz(self) -> bytes:
        """The map as ``.npz`` bytes (arrays, the options as JSON)."""
        arrays = {
            k: np.asarray(getattr(self, k))
            for k in ("x_m", "y_m", "z_m", "uncertainty", "successes", "image_successes", "geometry_successes")
        }
        arrays.update(
            n_directions=np.array(self.n_directions),
            seconds=np.array(self.seconds),
            config=np.array(json.dumps(asdict(self.config))),
        )
        if self.model is not None:
            arrays.update({f"model_{k}": np.asarray(v) for k, v in self.model.__dict__.items()})
        buf = io.BytesIO()
        np.savez_compressed(buf, **arrays)
        return buf.getvalue()

    @classmethod
    def from_npz(cls, data: bytes) -> SceneUncertaintyMap:
        """The map written by :meth:`to_npz`."""
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            options = json.loads(str(z["config"]))
            options["depth_layers_m"] = tuple(options["depth_layers_m"])
            model = None
            if "model_points" in z:
                model = SceneModel(**{k: z[f"model_{k}"] for k in SceneModel.__dataclass_fields__})
            return cls(
                x_m=z["x_m"],
                y_m=z["y_m"],
                z_m=z["z_m"],
                uncertainty=z["uncertainty"],
                successes=z["successes"],
                image_successes=z["image_successes"],
                geometry_successes=z["geometry_successes"],
                n_directions=int(z["n_directions"]),
                config=SceneUncertaintyConfig(**options),
                model=model,
                seconds=float(z["seconds"]),
            )


def scene_uncertainty_map(
    model: SceneModel,
    camera,
    *,
    config: SceneUncertaintyConfig = SceneUncertaintyConfig(),
    coarse: CoarseConfig = CoarseConfig(),
) -> SceneUncertaintyMap:
    """The camera-driven scene map ``U_cd`` (Eq. 2) over the workspace grid.

    Parameters
    ----------
    model : SceneModel
    camera : PinholeCamera
    config : SceneUncertaintyConfig
        Grid (``extent_m``, ``cells``, ``depth_layers_m``), directions and the success models' options.
    coarse : CoarseConfig
        ``verify_m`` / ``verify_deg`` and the covariance model (``sigma_rel``) of the coarse stage.

    Returns
    -------
    SceneUncertaintyMap
        Per position, ``N_cd`` = 5 directions: the look at the object's centroid and that look
        turned by ``config.spread_deg`` (:meth:`SceneUncertaintyConfig.directions`).
    """
    t0 = time.monotonic()
    T0 = model.T_ref_camref
    axis = np.linspace(-config.extent_m, config.extent_m, config.cells)
    z_m = np.asarray(config.depth_layers_m, dtype=float)
    shape = (len(z_m), len(axis), len(axis))
    counts = {k: np.zeros(shape, dtype=int) for k in ("any", "image", "geometry")}
    n_dir = len(config.directions())
    for (iz, iy, ix), _ in np.ndenumerate(counts["any"]):
        centre = T0[:3, :3] @ np.array([axis[ix], axis[iy], z_m[iz]]) + T0[:3, 3]
        T = look_at(centre, model.centroid, T0[:3, 1])
        u, f_img, f_geo = view_uncertainty(model, T, camera, config=config, coarse=coarse)
        counts["any"][iz, iy, ix] = round((1.0 - u) * n_dir)
        counts["image"][iz, iy, ix] = round(f_img * n_dir)
        counts["geometry"][iz, iy, ix] = round(f_geo * n_dir)
    return SceneUncertaintyMap(
        x_m=axis,
        y_m=axis.copy(),
        z_m=z_m,
        uncertainty=1.0 - counts["any"] / n_dir,
        successes=counts["any"],
        image_successes=counts["image"],
        geometry_successes=counts["geometry"],
        n_directions=n_dir,
        config=config,
        model=model,
        seconds=time.monotonic() - t0,
    )
