"""Active coarse stage: bring a camera that starts far away into rACR's basin (paper 001, AccurateACL).

rACR (paper 000) starts a revisit within a few centimetres of the reference
pose. When the first estimate puts the camera farther away (a robot re-mounted
elsewhere, a stage moved between visits), this stage runs first. It follows
AccurateACL's split, adapted to a platform next to one object:

* **passive localizer** ("how to locate"): two independent estimates of the
  current camera in the reference frame, from 2D-3D correspondences (SIFT
  matches to the reference images lifted to 3D by the reference cloud, PnP:
  the paper's scene-coordinate correspondences) and from the 3D alignment of
  the session cloud (the multi-start registration when the prior fails);
* **camera uncertainty** ("when to stop", and here also "whether to trust"):
  the reference cloud is rendered at an estimated pose, the observed session
  cloud is put in the current camera frame, and the two are registered; the
  residual motion says how wrong the estimate is (paper 001, §3.2). An
  estimate is *verified* when that residual is within 5 cm / 5 deg (the
  paper's lambda_cu) on enough overlap;
* **where to go**: the paper's scene-descent heuristic with the reference
  view as the localizable region (the reference cloud was built from there,
  so it is where the scene is best known): a verified estimate is followed
  along the shortest path, one bounded step at a time, re-localizing after
  each step; without a verified estimate the camera turns a little (the
  paper's turn-around action) to show the localizer another view, and after
  a few unverified views the stage pauses rather than guess.

The residual registration is geometric (point-to-plane ICP in Open3D), not
the paper's coloured ICP: a revisit is under another light, and the
reference cloud's intensities are the reference lighting's.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from drivers.platform import MotionRejected
from fgcd_cli.geometry.se3 import invert_pose, pose_distance
from fgcd_cli.geometry.sim3 import Sim3
from fgcd_cli.relocation.adjustment import clamp_motion

__all__ = [
    "CameraUncertainty",
    "CoarseConfig",
    "CoarseResult",
    "CoarseStep",
    "camera_uncertainty",
    "image_estimate",
    "render_visible_points",
    "run_coarse_stage",
]


@dataclass(frozen=True, kw_only=True)
class CoarseConfig:
    """Options of the active coarse stage.

    Distances in metres, angles in degrees.
    """

    trigger_m: float = 0.10
    trigger_deg: float = 8.0
    """The stage runs when the first estimate is farther than this from the reference pose
    (a revisit start within rACR's usual few centimetres never triggers it)."""
    handover_m: float = 0.04
    handover_deg: float = 4.0
    """A verified estimate within this of the reference pose hands over to the rACR loop: the
    paper's 5 cm / 5 deg less the typical error of a verified estimate (docs/relocation.md,
    "Far starts"), still inside the range the loop starts from routinely."""
    verify_m: float = 0.05
    verify_deg: float = 5.0
    """Camera uncertainty that verifies an estimate (the paper's 5 cm / 5 deg, lambda_cu)."""
    weak_ratio: float = 0.015
    """A direction of the residual registration whose information is below this fraction of the
    strongest (rotations scaled by the median depth) is weak. Measured on the simulator's stupa:
    the orbit about its axis and its couplings at 0.65-1.2 %, the next direction at 20-46 %."""
    min_fitness: float = 0.5
    """Fraction of the observed points that must find a rendered point after the residual
    registration; less means the estimate and the observation barely overlap."""
    step_m: float = 0.08
    step_deg: float = 8.0
    """Largest motion per step; the platform guard applies its own limits too."""
    look_deg: float = 4.0
    """Turn-around action when no estimate is verified."""
    max_steps: int = 10
    max_looks: int = 3
    render_stride_px: int = 4
    """Pixel bin of the z-buffer that renders the reference cloud (its points are sparse)."""
    max_points: int = 6000


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
    """The residual motion without its part along the weak directions."""
    T_correction_constrained: np.ndarray | None = None

    def verified(self, config: CoarseConfig, *, geometric_source: bool = True) -> bool:
        """True when the estimate is within the verification limits on enough overlap.

        An estimate from the geometry itself (the 3D alignment) is verified only where the
        geometry pins every direction: along a weak one, neither the alignment nor the residual
        registration sees an error (measured: a stupa's 3D estimate passed at 8 mm while it was
        69 mm off along the orbit about its axis). An image estimate is checked on the
        constrained part: along the weak directions its texture correspondences are the
        evidence, and the registration's slide there is not a measurement (the same stupa: a
        PnP estimate 5 mm from the truth, which the residual registration slid 64-83 mm).
        """
        if self.fitness < config.min_fitness:
            return False
        if geometric_source:
            return (self.weak_directions == 0 and self.translation_m <= config.verify_m
                    and self.rotation_deg <= config.verify_deg)
        return self.constrained_translation_m <= config.verify_m and self.constrained_rotation_deg <= config.verify_deg

    def correction(self, *, geometric_source: bool = True) -> np.ndarray:
        """The residual motion to apply to the estimate (the constrained part for an image estimate)."""
        if geometric_source or self.T_correction_constrained is None:
            return self.T_correction
        return self.T_correction_constrained

    def to_dict(self) -> dict:
        return {"translation_mm": self.translation_m * 1e3, "rotation_deg": self.rotation_deg,
                "fitness": self.fitness, "rmse_mm": self.rmse_m * 1e3, "observed": self.observed,
                "rendered": self.rendered, "weak_directions": self.weak_directions,
                "constrained_translation_mm": self.constrained_translation_m * 1e3,
                "constrained_rotation_deg": self.constrained_rotation_deg}


def render_visible_points(points_ref: np.ndarray, T_ref_cam: np.ndarray, camera, *, stride_px: int = 4,
                          depth_tolerance_rel: float = 0.02) -> np.ndarray:
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
    Xc, uv = _in_view(points_ref, T_ref_cam, camera)
    if len(Xc) == 0:
        return np.zeros((0, 3))
    z = Xc[:, 2]
    s = max(1, int(stride_px))
    cols = int(math.ceil(camera.width / s))
    col = np.clip(uv[:, 0], 0, camera.width - 1) // s
    row = np.clip(uv[:, 1], 0, camera.height - 1) // s
    cell = row.astype(np.int64) * cols + col.astype(np.int64)
    zmin = np.full(int(cell.max()) + 1, np.inf)
    np.minimum.at(zmin, cell, z)
    keep = z <= zmin[cell] * (1.0 + depth_tolerance_rel)
    return Xc[keep]


def _in_view(points: np.ndarray, T_frame_cam: np.ndarray, camera) -> tuple[np.ndarray, np.ndarray]:
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
        return CameraUncertainty(translation_m=math.inf, rotation_deg=math.inf, fitness=0.0, rmse_m=math.inf,
                                 observed=len(obs), rendered=len(rendered), T_correction=np.eye(4))
    depth = float(np.median(obs[:, 2]))
    src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(obs))
    dst = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(rendered))
    dst.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.05 * depth, max_nn=30))
    dst.orient_normals_towards_camera_location(np.zeros(3))
    T = np.eye(4)
    result = None
    for radius_rel, iterations in ((0.15, 30), (0.05, 30), (0.02, 30)):
        result = o3d.pipelines.registration.registration_icp(
            src, dst, radius_rel * depth, T,
            o3d.pipelines.registration.TransformationEstimationPointToPlane(),
            o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=iterations),
        )
        T = np.asarray(result.transformation)
    # ``T`` maps observed (true camera frame) points onto the rendering (estimated camera frame):
    # T_estcam_truecam, i.e. the true camera in the estimated camera's frame.
    mm, deg = pose_distance(np.eye(4), T)
    weak, T_constrained = _constrained_part(T, obs, rendered, np.asarray(dst.normals), radius=0.02 * depth,
                                            depth=depth, weak_ratio=config.weak_ratio)
    c_mm, c_deg = pose_distance(np.eye(4), T_constrained)
    return CameraUncertainty(translation_m=mm / 1e3, rotation_deg=deg, fitness=float(result.fitness),
                             rmse_m=float(result.inlier_rmse), observed=len(obs), rendered=len(rendered),
                             T_correction=T.copy(), weak_directions=weak, constrained_translation_m=c_mm / 1e3,
                             constrained_rotation_deg=c_deg, T_correction_constrained=T_constrained)


def _constrained_part(T: np.ndarray, observed: np.ndarray, rendered: np.ndarray, normals: np.ndarray, *,
                      radius: float, depth: float, weak_ratio: float) -> tuple[int, np.ndarray]:
    """The residual motion ``T`` without its part along the registration's weak directions.

    Point-to-plane information ``H = sum J^T J`` with ``J = [n, (p x n) / depth]`` over the
    final correspondences (twist ``(t, depth * phi)``: rotations as motions at the scene's
    depth); eigen-directions below ``weak_ratio`` of the strongest are weak. Returns their
    count and ``exp`` of the twist projected onto the others. Written by hand: Open3D's
    information matrix is the point-to-point one, which does not see a surface sliding
    along itself.
    """
    from scipy.spatial import cKDTree

    from fgcd_cli.geometry.se3 import exp_se3, log_se3

    p = observed @ T[:3, :3].T + T[:3, 3]
    dist, idx = cKDTree(rendered).query(p, distance_upper_bound=radius)
    ok = np.isfinite(dist)
    if ok.sum() < 50:
        return 6, np.eye(4)
    n = normals[idx[ok]]
    J = np.hstack([n, np.cross(p[ok], n) / depth])
    evals, evecs = np.linalg.eigh(J.T @ J)
    strong = evals >= weak_ratio * evals.max()
    xi = log_se3(T)
    v = np.concatenate([xi[:3], xi[3:] * depth])
    E = evecs[:, strong]
    v_c = E @ (E.T @ v)
    return int((~strong).sum()), exp_se3(np.concatenate([v_c[:3], v_c[3:] / depth]))


@dataclass(frozen=True, kw_only=True)
class CoarseStep:
    """One step of the coarse stage (written to the relocation log)."""

    step: int
    t_session_s: float
    action: str  # "move" | "look" | "handover" | "pause"
    source: str  # which passive estimate was used ("3d", "image", or "")
    estimates: dict
    offset_mm: float
    offset_deg: float
    commanded_mm: float
    commanded_deg: float
    truth: dict | None = None

    def to_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class CoarseResult:
    """Outcome of the coarse stage."""

    handed_over: bool
    reason: str
    init: Sim3 | None
    """Alignment of the session's metric frame into ``ref`` for the rACR loop (when handed over)."""
    steps: list[CoarseStep] = field(default_factory=list)


def image_estimate(*, reference_images: dict[str, np.ndarray], current_image: np.ndarray, camera,
                   reference) -> tuple[np.ndarray | None, dict]:
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
    from fgcd_cli.relocation.image_refine import ImageRefineConfig, refine_from_reference_image

    config = replace(ImageRefineConfig(), max_motion_m=10.0, max_motion_deg=180.0,
                     strong_max_motion_m=10.0, strong_max_motion_deg=180.0)
    T_ref_camref = np.asarray(reference.T_ref_camref, dtype=float)
    pnp = refine_from_reference_image(reference_images=reference_images, current_image=current_image, camera=camera,
                                      ref_points=reference.points, T_ref_camref=T_ref_camref, config=config)
    info = {"pnp": pnp.reason, "inliers": pnp.inliers}
    return (T_ref_camref @ invert_pose(pnp.M_cam) if pnp.ok else None), info


def _yaw(angle_rad: float) -> np.ndarray:
    """Rotation about the camera's vertical (y) axis through its centre, (4, 4)."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    M = np.eye(4)
    M[:3, :3] = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
    return M


def _sim3_from_camera(T_ref_cam: np.ndarray, T_cur_cam: np.ndarray) -> Sim3:
    """The rigid ``T_ref_cur`` that puts the session camera at ``T_ref_cam``."""
    M = np.asarray(T_ref_cam, dtype=float) @ invert_pose(np.asarray(T_cur_cam, dtype=float))
    return Sim3(M[:3, :3].copy(), M[:3, 3].copy(), 1.0)


def run_coarse_stage(
    *,
    session,
    reference,
    ref_index,
    camera,
    scale: float,
    T_flange_cam: np.ndarray,
    init: Sim3,
    reference_images: dict[str, np.ndarray] | None,
    grab_current: Callable[[], np.ndarray] | None,
    config: CoarseConfig = CoarseConfig(),
    evaluate: Callable[[], dict] | None = None,
    say: Callable[[str], None] = lambda _m: None,
) -> CoarseResult:
    """Move the camera from far away into the rACR loop's basin.

    Parameters
    ----------
    session : VseSession
        Running session (exploration done); every motion goes through its guard.
    reference : ReferenceData
        ``points`` (N, 3) metres and ``T_ref_camref`` (4, 4).
    ref_index : ReferenceIndex
        Search structure over the reference cloud.
    camera : PinholeCamera
        Undistorted intrinsics.
    scale : float
        Metres per map unit of this session.
    T_flange_cam : (4, 4) ndarray
        Hand-eye.
    init : Sim3
        First alignment ``T_ref_cur`` (the one that triggered the stage).
    reference_images, grab_current :
        For the image (PnP) localizer; without them only the 3D one runs.
    evaluate : callable, optional
        Simulation only: truth for the log (evaluation code).

    Returns
    -------
    CoarseResult
        ``handed_over`` with the verified ``init`` for the rACR loop, or the reason it paused.
    """
    from fgcd_cli.alignment import fast_align, global_registration

    X = np.asarray(T_flange_cam, dtype=float)
    T_ref_camref = np.asarray(reference.T_ref_camref, dtype=float)
    steps: list[CoarseStep] = []
    last_3d = init
    looks = 0
    heading = 0.0  # look-around rotation from where the stage started, radians
    for step in range(1, config.max_steps + 1):
        state = session.tracking_state()
        T_cur_cam = np.array(state.T_map_cam, dtype=float)
        T_cur_cam[:3, 3] *= scale
        cloud = np.asarray(state.cloud.points, dtype=float) * scale
        observed, _ = _in_view(cloud, T_cur_cam, camera)
        t0 = time.monotonic()
        candidates: dict[str, np.ndarray] = {}
        notes: dict[str, dict] = {}
        fast = fast_align(cloud, ref_index, init=last_3d)
        if not fast.health.ok and not fast.health.degenerate:
            fast = global_registration(cloud, ref_index, around=last_3d)
        candidates["3d"] = fast.T_ref_cur.transform_pose(T_cur_cam)
        notes["3d"] = {"alignment": fast.health.reason}
        if reference_images and grab_current is not None:
            T_img, notes["image"] = image_estimate(reference_images=reference_images, current_image=grab_current(),
                                                   camera=camera, reference=reference)
            if T_img is not None:
                candidates["image"] = T_img
        best: tuple[str, np.ndarray, CameraUncertainty] | None = None
        for name, T_ref_cam in candidates.items():
            unc = camera_uncertainty(observed, reference.points, T_ref_cam, camera, config=config, seed=step)
            notes[name]["uncertainty"] = unc.to_dict()
            off_mm, off_deg = pose_distance(T_ref_cam, T_ref_camref)
            notes[name]["offset_mm"], notes[name]["offset_deg"] = off_mm, off_deg
            geometric = name == "3d"
            if unc.verified(config, geometric_source=geometric) and (
                    best is None or unc.constrained_translation_m < best[2].constrained_translation_m):
                best = (name, T_ref_cam @ unc.correction(geometric_source=geometric), unc)
        session.timing.wait_s += time.monotonic() - t0
        truth = evaluate() if evaluate is not None else None
        t_s = session.timing.total_s
        if best is None:
            if looks >= config.max_looks:
                steps.append(CoarseStep(step=step, t_session_s=t_s, action="pause", source="", estimates=notes,
                                        offset_mm=math.nan, offset_deg=math.nan, commanded_mm=0.0,
                                        commanded_deg=0.0, truth=truth))
                reason = (f"coarse stage: no estimate verified in {looks + 1} views (camera uncertainty above "
                          f"{config.verify_m * 1e3:.0f} mm / {config.verify_deg:.0f} deg); bring the camera nearer "
                          "the reference pose")
                try:  # back to the heading the stage started from: the loop starts where it would have
                    if heading:
                        session.move_by(X @ _yaw(-heading) @ invert_pose(X))
                except MotionRejected:
                    pass
                return CoarseResult(False, reason, None, steps)
            # turn-around: headings +a, -a, +2a, -2a ... about the camera's vertical axis through its
            # centre, relative to where the stage started (a pure rotation: no translation towards
            # anything unverified)
            target = math.radians(config.look_deg) * (1 + looks // 2) * (1.0 if looks % 2 == 0 else -1.0)
            try:
                session.move_by(X @ _yaw(target - heading) @ invert_pose(X))
            except MotionRejected as exc:
                return CoarseResult(False, f"coarse stage: a look-around motion is refused by the platform "
                                    f"guard ({exc})", None, steps)
            steps.append(CoarseStep(step=step, t_session_s=t_s, action="look", source="", estimates=notes,
                                    offset_mm=math.nan, offset_deg=math.nan, commanded_mm=0.0,
                                    commanded_deg=math.degrees(abs(target - heading)), truth=truth))
            heading = target
            looks += 1
            say(f"coarse step {step}: no verified estimate; looking {math.degrees(target):+.0f} deg from the start")
            continue
        name, T_ref_cam, unc = best
        last_3d = _sim3_from_camera(T_ref_cam, T_cur_cam)
        off_mm, off_deg = pose_distance(T_ref_cam, T_ref_camref)
        if off_mm <= config.handover_m * 1e3 and off_deg <= config.handover_deg:
            steps.append(CoarseStep(step=step, t_session_s=t_s, action="handover", source=name, estimates=notes,
                                    offset_mm=off_mm, offset_deg=off_deg, commanded_mm=0.0, commanded_deg=0.0,
                                    truth=truth))
            say(f"coarse step {step}: verified ({name}) {off_mm:.0f} mm / {off_deg:.1f} deg from the reference; "
                "handing over to rACR")
            return CoarseResult(True, f"verified {name} estimate within {config.handover_m * 1e3:.0f} mm / "
                                f"{config.handover_deg:.0f} deg", last_3d, steps)
        M_cam = invert_pose(T_ref_cam) @ T_ref_camref
        M_flange, _ = clamp_motion(X @ M_cam @ invert_pose(X), max_step_m=config.step_m,
                                   max_step_rad=math.radians(config.step_deg))
        cmd_mm, cmd_deg = pose_distance(np.eye(4), M_flange)
        steps.append(CoarseStep(step=step, t_session_s=t_s, action="move", source=name, estimates=notes,
                                offset_mm=off_mm, offset_deg=off_deg, commanded_mm=cmd_mm, commanded_deg=cmd_deg,
                                truth=truth))
        say(f"coarse step {step}: verified ({name}, uncertainty {unc.constrained_translation_m * 1e3:.0f} mm / "
            f"{unc.constrained_rotation_deg:.1f} deg"
            + (f", {unc.weak_directions} weak directions" if unc.weak_directions else "")
            + f") {off_mm:.0f} mm / {off_deg:.1f} deg away; moving {cmd_mm:.0f} mm")
        try:
            session.move_by(M_flange)
        except MotionRejected as exc:
            return CoarseResult(False, f"coarse stage: the way to the reference is refused by the platform "
                                f"guard ({exc})", None, steps)
        session.settle(frames=session.settle_frames + 1)
    return CoarseResult(False, f"coarse stage: not within {config.handover_m * 1e3:.0f} mm / "
                        f"{config.handover_deg:.0f} deg of the reference after {config.max_steps} steps", None, steps)
