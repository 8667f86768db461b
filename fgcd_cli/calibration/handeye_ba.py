"""Target-free hand-eye refined on the images of the stops (structure from known motion).

The rACR linear solve (:func:`fgcd_cli.calibration.handeye.solve_handeye_scale`)
works on the camera motions the monocular VSE reports. Over the small motions a
heritage site allows, those poses carry slowly varying errors of several
millimetres and a few tenths of a degree (the rotation/translation ambiguity of a
monocular map of a shallow scene), and ``t_X`` is found from camera
translations divided by rotation angles of ~0.1 rad: the VSE errors reach
``t_X`` amplified about tenfold.

The refinement goes back to the images. The platform's reported flange poses
are metric and accurate to a fraction of a millimetre, so the camera pose at stop
``i`` is ``T_base_flange_i @ X`` and the only unknowns are ``X`` and the scene
points: a bundle adjustment over the stop images with the camera poses tied to
the flange poses (hand-eye calibration by structure from motion; Andreff, Horaud
and Espiau 2001). The map scale does not enter (the flange poses are metric); it
is estimated afterwards from the VSE poses with the refined ``X``
(:func:`fgcd_cli.calibration.handeye.estimate_scale`).

Pipeline: SIFT features per stop image, ratio-test matches between all stop
pairs checked by a RANSAC fundamental matrix, tracks by union-find (a track
seen twice in one image is dropped), linear triangulation with the initial
``X``, then Levenberg-Marquardt (Huber, 1 px) over ``X`` and the points, twice:
observations off by more than ``reject_px`` after the first pass are removed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import cv2
import numpy as np

from fgcd_cli.calibration.errors import CalibrationError
from fgcd_cli.geometry.se3 import exp_se3, exp_so3, invert_pose, log_so3, make_pose, pose_distance

__all__ = ["BAHandEyeResult", "PathViews", "refine_handeye_images", "refine_handeye_tracks", "refine_target_free", "scale_from_depths",
           "KeyframeDepths", "gray_u8", "stop_features"]


@dataclass(frozen=True, kw_only=True)
class BAHandEyeResult:
    """Outcome of :func:`refine_handeye_images`.

    Attributes
    ----------
    T_flange_cam : (4, 4) ndarray
        Refined hand-eye.
    std_mm, std_deg : float
        One-sigma uncertainty of the translation (norm of the per-axis sigmas) and
        rotation of ``X`` from the Gauss-Newton covariance scaled by the residuals.
    rms_px : float
        Reprojection RMS of the kept observations, pixels.
    n_points, n_observations : int
        Scene points and image observations kept.
    per_image_rms_px : (N,) ndarray
        Reprojection RMS per stop image (NaN for an image without observations).
    change_mm, change_deg : float
        How far the refinement moved ``X`` from the initial value.
    notes : list of str
        Warnings.
    points_base : (M, 3) ndarray
        The adjusted scene points in the platform base frame, metres.
    rotation_scale, rotation_scale_std : float
        Ratio of the platform's true rotations to the reported ones, estimated
        with ``X`` (see :class:`_HandPoses`), and its one-sigma; 1.0 / NaN when
        not estimated.
    """

    T_flange_cam: np.ndarray
    std_mm: float
    std_deg: float
    rms_px: float
    n_points: int
    n_observations: int
    per_image_rms_px: np.ndarray
    change_mm: float
    change_deg: float
    notes: list[str] = field(default_factory=list)
    points_base: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    rotation_scale: float = 1.0
    rotation_scale_std: float = float("nan")


def gray_u8(image: np.ndarray) -> np.ndarray:
    """An image as 8-bit grey (float images in [0, 1] or [0, 255])."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img.astype(np.float32) if img.dtype != np.uint8 else img, cv2.COLOR_RGB2GRAY)
    if img.dtype != np.uint8:
        img = img.astype(np.float32)
        if img.size and float(np.nanmax(img)) <= 1.0 + 1e-6:
            img = img * 255.0
        img = np.clip(img, 0, 255).astype(np.uint8)
    return img


def stop_features(images: Sequence[np.ndarray], *, n_features: int = 1500) -> list[tuple[np.ndarray, np.ndarray]]:
    """SIFT keypoints ``(N, 2)`` and descriptors of every stop image.

    The images are equalised locally (CLAHE) first. Why: SIFT drops extrema
    below a fixed contrast, and on dim stone lit by a lamp that moves with the
    camera the raw images keep mostly large blobs of shading whose centres shift
    as the light moves with the camera, which biases ``X``; equalised images keep
    mostly small-scale texture, which does not move with the light
    (docs/calibration.md, "Target-free"; measurements in docs/benchmarks.md,
    "Calibration").
    """
    sift = cv2.SIFT_create(nfeatures=n_features)
    clahe = cv2.createCLAHE(clipLimit=3.0, tileGridSize=(8, 8))
    out = []
    for img in images:
        kp, desc = sift.detectAndCompute(clahe.apply(gray_u8(img)), None)
        xy = np.array([k.pt for k in kp], dtype=float).reshape(-1, 2)
        out.append((xy, desc if desc is not None else np.zeros((0, 128), np.float32)))
    return out


def _pair_matches(f_a, f_b, *, ratio: float, ransac_px: float) -> np.ndarray:
    """Index pairs ``(k_a, k_b)`` of ratio-test matches consistent with one fundamental matrix."""
    (xy_a, d_a), (xy_b, d_b) = f_a, f_b
    if len(xy_a) < 8 or len(xy_b) < 8:
        return np.zeros((0, 2), int)
    # approximate nearest neighbours (kd-trees): ~10x faster than brute force on 1500 x 1500 SIFT descriptors
    matcher = cv2.FlannBasedMatcher({"algorithm": 1, "trees": 4}, {"checks": 64})
    knn = matcher.knnMatch(np.asarray(d_a, np.float32), np.asarray(d_b, np.float32), k=2)
    good = [(m[0].queryIdx, m[0].trainIdx) for m in knn if len(m) == 2 and m[0].distance < ratio * m[1].distance]
    if len(good) < 20:
        return np.zeros((0, 2), int)
    idx = np.array(good, dtype=int)
    # one-to-one: drop keypoints of b matched twice
    _, first, counts = np.unique(idx[:, 1], return_index=True, return_counts=True)
    idx = idx[first[counts == 1]]
    if len(idx) < 20:
        return np.zeros((0, 2), int)
    _F, mask = cv2.findFundamentalMat(xy_a[idx[:, 0]], xy_b[idx[:, 1]], cv2.FM_RANSAC, ransac_px, 0.999)
    if mask is None:
        return np.zeros((0, 2), int)
    return idx[mask.ravel().astype(bool)]


def _tracks(features, pair_list, matches) -> list[list[tuple[int, int]]]:
    """Union-find over (image, keypoint) nodes; tracks seen twice in one image are dropped."""
    offsets = np.cumsum([0] + [len(f[0]) for f in features])
    parent = np.arange(offsets[-1])

    def find(a: int) -> int:
        root = a
        while parent[root] != root:
            root = parent[root]
        while parent[a] != root:
            parent[a], a = root, parent[a]
        return root

    for (i, j), m in zip(pair_list, matches):
        for ka, kb in m:
            ra, rb = find(offsets[i] + ka), find(offsets[j] + kb)
            if ra != rb:
                parent[rb] = ra
    groups: dict[int, list[tuple[int, int]]] = {}
    for img in range(len(features)):
        for k in range(len(features[img][0])):
            node = offsets[img] + k
            groups.setdefault(find(node), []).append((img, k))
    out = []
    for members in groups.values():
        if len(members) < 2:
            continue
        imgs = [m[0] for m in members]
        if len(set(imgs)) != len(imgs):
            continue
        out.append(members)
    return out


def _triangulate(P_list: list[np.ndarray], uv: list[np.ndarray]) -> np.ndarray:
    """Linear (DLT) triangulation of one point from several views."""
    rows = []
    for P, (u, v) in zip(P_list, uv):
        rows.append(u * P[2] - P[0])
        rows.append(v * P[2] - P[1])
    _, _, vt = np.linalg.svd(np.asarray(rows))
    Xh = vt[-1]
    return Xh[:3] / Xh[3] if abs(Xh[3]) > 1e-12 else np.full(3, np.nan)


def _project(T_cam_base: np.ndarray, K: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels ``(M, 2)`` and depths of base-frame points ``P`` seen by cameras ``T_cam_base`` (M, 4, 4)."""
    pc = np.einsum("mij,mj->mi", T_cam_base[:, :3, :3], P) + T_cam_base[:, :3, 3]
    z = pc[:, 2]
    zs = np.where(np.abs(z) < 1e-9, 1e-9, z)
    u = K[0, 0] * pc[:, 0] / zs + K[0, 2]
    v = K[1, 1] * pc[:, 1] / zs + K[1, 2]
    return np.column_stack([u, v]), z


def refine_handeye_images(
    T_base_flange: Sequence[np.ndarray],
    images: Sequence[np.ndarray],
    K: np.ndarray,
    T_flange_cam_init: np.ndarray,
    *,
    ratio: float = 0.8,
    ransac_px: float = 1.0,
    reject_px: float = 2.0,
    min_points: int = 60,
    max_points: int = 3000,
    n_features: int = 1500,
    dist: Sequence[float] | None = None,
    match_window: int | None = None,
    anchors: Sequence[int] | None = None,
    estimate_rotation_scale: bool = True,
) -> BAHandEyeResult:
    """Refine the hand-eye on the stop images with the camera poses tied to the flange poses.

    Parameters
    ----------
    T_base_flange : sequence of N (4, 4) ndarray
        Reported flange poses at the stops, metres.
    images : sequence of N images
        The camera image at each stop, **undistorted** (ideal pinhole ``K``).
    K : (3, 3) ndarray
        Intrinsic matrix of the undistorted images.
    T_flange_cam_init : (4, 4) ndarray
        Initial hand-eye (the linear solve); must be within a few degrees and
        centimetres for the triangulation to start.
    ratio, ransac_px : float
        SIFT ratio test and fundamental-matrix RANSAC threshold (pixels).
    reject_px : float
        Observations with a larger reprojection error after the first pass are dropped.
    min_points : int
        Fewer scene points seen from two stops or more raise.
    max_points : int
        Keep at most this many points (the longest tracks) to bound the run time.
    n_features : int
        SIFT features per image.
    dist : sequence of float, optional
        OpenCV distortion coefficients if the images are *not* undistorted; the
        keypoints are then undistorted before the adjustment.
    match_window : int, optional
        None: match every pair of images (a dozen stops). Else the images are a
        sequence along the platform's path, and image ``i`` is matched with
        ``i+1 .. i+match_window`` and, if it is one of ``anchors``, with every
        other anchor.
    anchors : sequence of int, optional
        Indices of the images matched with each other in any case (the stops).
    estimate_rotation_scale : bool
        See :func:`refine_handeye_tracks`.

    Returns
    -------
    BAHandEyeResult

    Raises
    ------
    CalibrationError
        Too few matched points between the stop images (low texture, too large motions).
    """
    if len(T_base_flange) != len(images):
        raise CalibrationError(f"{len(T_base_flange)} flange poses but {len(images)} stop images")
    n = len(images)
    features = stop_features(images, n_features=n_features)
    if dist is not None and np.any(np.asarray(dist, dtype=float) != 0):
        K_ = np.asarray(K, dtype=float)
        features = [
            (cv2.undistortPoints(xy.reshape(-1, 1, 2), K_, np.asarray(dist, dtype=float), P=K_).reshape(-1, 2)
             if len(xy) else xy, desc)
            for xy, desc in features
        ]
    if match_window is None:
        pair_list = [(i, j) for i in range(n) for j in range(i + 1, n)]
    else:
        pairs = {(i, j) for i in range(n) for j in range(i + 1, min(n, i + 1 + int(match_window)))}
        stops = sorted({int(a) for a in (anchors or ()) if 0 <= int(a) < n})
        pairs |= {(a, b) for k, a in enumerate(stops) for b in stops[k + 1:]}
        pair_list = sorted(pairs)
    matches = [_pair_matches(features[i], features[j], ratio=ratio, ransac_px=ransac_px) for i, j in pair_list]
    tracks = _tracks(features, pair_list, matches)
    tracks.sort(key=len, reverse=True)
    tracks = [[(img, features[img][0][k]) for img, k in members] for members in tracks[:max_points]]
    return refine_handeye_tracks(T_base_flange, tracks, K, T_flange_cam_init, reject_px=reject_px,
                                 min_points=min_points, estimate_rotation_scale=estimate_rotation_scale)


def refine_handeye_tracks(
    T_base_flange: Sequence[np.ndarray],
    tracks: Sequence[Sequence[tuple[int, Sequence[float]]]],
    K: np.ndarray,
    T_flange_cam_init: np.ndarray,
    *,
    reject_px: float = 2.0,
    min_points: int = 60,
    estimate_rotation_scale: bool = True,
) -> BAHandEyeResult:
    """Bundle adjustment of ``X`` and the scene points from feature tracks across the stops.

    Parameters
    ----------
    T_base_flange : sequence of N (4, 4) ndarray
        Reported flange poses, metres.
    tracks : sequence of tracks
        Each track lists ``(stop_index, (u, v))`` observations of one scene point
        (undistorted pixels), at least two stops.
    K : (3, 3) ndarray
        Pinhole intrinsics of the undistorted images.
    T_flange_cam_init : (4, 4) ndarray
        Initial hand-eye.
    reject_px, min_points : see :func:`refine_handeye_images`.
    estimate_rotation_scale : bool
        Also estimate the scale of the platform's reported rotations (when it
        turned by more than 2 degrees).
    """
    n = len(T_base_flange)
    hand = [np.asarray(T, dtype=float) for T in T_base_flange]
    K = np.asarray(K, dtype=float)
    X0 = np.asarray(T_flange_cam_init, dtype=float)

    def cams_for(X: np.ndarray) -> np.ndarray:
        return np.stack([invert_pose(T @ X) for T in hand])

    cams0 = cams_for(X0)
    Pmats = [K @ T[:3, :] for T in cams0]
    pts, obs_cam, obs_pt, obs_uv = [], [], [], []
    for members in tracks:
        if len(members) < 2:
            continue
        uv = [np.asarray(m[1], dtype=float) for m in members]
        cam_idx = np.array([int(m[0]) for m in members])
        if np.any(cam_idx < 0) or np.any(cam_idx >= n):
            raise CalibrationError(f"a feature track refers to stop {cam_idx.max()} of {n}")
        P = _triangulate([Pmats[i] for i in cam_idx], uv)
        if not np.all(np.isfinite(P)):
            continue
        proj, z = _project(cams0[cam_idx], K, np.repeat(P[None], len(members), axis=0))
        if np.any(z <= 0) or np.max(np.linalg.norm(proj - np.asarray(uv), axis=1)) > 8.0:
            continue
        j = len(pts)
        pts.append(P)
        obs_cam.extend(cam_idx.tolist())
        obs_pt.extend([j] * len(members))
        obs_uv.extend(uv)
    if len(pts) < min_points:
        raise CalibrationError(
            f"only {len(pts)} scene points were matched between the stop images (need {min_points}): "
            "the scene has too little texture or the stops are too far apart"
        )
    pts0 = np.asarray(pts)
    obs_cam = np.asarray(obs_cam)
    obs_pt = np.asarray(obs_pt)
    obs_uv = np.asarray(obs_uv)

    poses = _HandPoses(np.stack(hand))
    # the rotation scale is observable only if the platform turned (the procedures turn by ~8 degrees)
    s0 = 1.0 if estimate_rotation_scale and np.max(np.linalg.norm(poses.phi, axis=1)) > math.radians(2.0) else None
    X, P, s_rot, _ = _lm_handeye(poses, K, X0, pts0, obs_cam, obs_pt, obs_uv, rotation_scale=s0)
    r = _residuals(poses.inv(s_rot), K, X, P, obs_cam, obs_pt, obs_uv)
    keep = np.linalg.norm(r, axis=1) < reject_px
    # points left with fewer than two observations go too
    counts = np.bincount(obs_pt[keep], minlength=len(pts0))
    keep &= counts[obs_pt] >= 2
    used = np.flatnonzero(counts >= 2)
    if len(used) < min_points:
        raise CalibrationError(f"only {len(used)} scene points are consistent across the stop images (need {min_points})")
    remap = -np.ones(len(pts0), int)
    remap[used] = np.arange(len(used))
    oc, op, ouv = obs_cam[keep], remap[obs_pt[keep]], obs_uv[keep]
    X, P, s_rot, S = _lm_handeye(poses, K, X, P[used], oc, op, ouv, rotation_scale=None if s0 is None else s_rot)
    r = _residuals(poses.inv(s_rot), K, X, P, oc, op, ouv)
    rms = float(np.sqrt(np.mean(np.sum(r**2, axis=1))))
    per_image = np.array([
        float(np.sqrt(np.mean(np.sum(r[oc == i] ** 2, axis=1)))) if np.any(oc == i) else float("nan") for i in range(n)
    ])
    # covariance of the hand-eye (and rotation scale): inverse Schur complement times the residual variance
    dof = max(r.size - len(S) - 3 * len(used), 1)
    sigma2 = float(np.sum(r**2)) / dof
    try:
        d = np.sqrt(np.clip(np.diag(np.linalg.inv(S)) * sigma2, 0, None))
        std_mm = float(np.linalg.norm(d[:3])) * 1000.0
        std_deg = math.degrees(float(np.linalg.norm(d[3:6])))
        s_std = float(d[6]) if len(d) > 6 else float("nan")
    except np.linalg.LinAlgError:  # pragma: no cover - singular: X not observable from these stops
        std_mm = std_deg = s_std = float("inf")
    change_mm, change_deg = pose_distance(X, X0)
    notes = []
    if s0 is not None and abs(s_rot - 1.0) > max(3.0 * s_std, 3e-4):
        notes.append(
            f"the platform's rotations are {abs(s_rot - 1) * 100:.2f} % {'longer' if s_rot > 1 else 'shorter'} than "
            f"it reports (+-{s_std * 100:.2f} %, from the images): the hand-eye accounts for it, but the platform's "
            "own calibration is off"
        )
    if rms > 0.6:  # 0.22-0.26 px in the simulator with a good platform; 0.99 px with the 'sloppy' one
        notes.append(
            f"image refinement: reprojection RMS {rms:.2f} px is high: the platform did not reach the poses it "
            "reports (check its calibration and repeatability), or blur, a moving scene or wrong intrinsics"
        )
    return BAHandEyeResult(
        T_flange_cam=X, std_mm=std_mm, std_deg=std_deg, rms_px=rms, n_points=len(used), n_observations=len(oc),
        per_image_rms_px=per_image, change_mm=change_mm, change_deg=change_deg, notes=notes, points_base=P,
        rotation_scale=s_rot, rotation_scale_std=s_std,
    )


def _residuals(inv_hand, K, X, P, oc, op, ouv) -> np.ndarray:
    """Reprojection residuals ``(M, 2)`` with camera poses ``inv(X) @ inv(T_base_flange)``."""
    T_cam_base = np.einsum("ij,mjk->mik", invert_pose(X), inv_hand)
    proj, _ = _project(T_cam_base[oc], K, P[op])
    return proj - ouv


class _HandPoses:
    """Reported flange poses, optionally with the platform's rotations scaled by ``s``.

    With ``s`` the flange orientation of view ``i`` is ``R_0 exp(s log(R_0^T R_i))``
    (rotations about the first view's orientation scaled by ``s``; positions as
    reported): a rotary stage or arm whose rotations are a fraction of a percent
    longer or shorter than it reports. The images measure the camera's rotations
    far better than that; left unmodelled, a rotation scale error of about a
    tenth of a percent biases ``t_X`` by millimetres (docs/calibration.md,
    "Target-free").
    """

    def __init__(self, T_base_flange: np.ndarray):
        self.T = np.asarray(T_base_flange, dtype=float)
        R0 = self.T[0, :3, :3]
        self.R0 = R0
        self.phi = np.stack([log_so3(R0.T @ T[:3, :3]) for T in self.T])  # (N, 3) rad

    def inv(self, scale: float) -> np.ndarray:
        """``inv(T_base_flange)`` of every view, ``(N, 4, 4)``."""
        if scale == 1.0:
            return np.stack([invert_pose(T) for T in self.T])
        out = np.empty_like(self.T)
        for i, T in enumerate(self.T):
            R = self.R0 @ exp_so3(scale * self.phi[i])
            out[i] = invert_pose(make_pose(R, T[:3, 3]))
        return out


def _lm_handeye(hand: _HandPoses, K, X, P, oc, op, ouv, *, rotation_scale: float | None = None,
                iterations: int = 40, huber_px: float = 1.0):
    """Levenberg-Marquardt over ``X`` (right perturbation ``X exp(d)``), the points and, if
    ``rotation_scale`` is given (its start value), the platform's rotation scale; Huber IRLS.

    The point blocks are eliminated (Schur complement), so each step solves a 6x6
    (7x7) system. Returns ``(X, P, s, S)`` with ``s`` the rotation scale (1.0 when
    not estimated) and ``S`` the reduced normal matrix of the parameters
    (undamped, unweighted by the Huber kernel) for the covariance.
    """
    m = len(P)
    fx, fy = K[0, 0], K[1, 1]
    with_scale = rotation_scale is not None
    npar = 7 if with_scale else 6
    scale = float(rotation_scale) if with_scale else 1.0

    def linearise(X, P, scale):
        Xi = invert_pose(X)
        T_cam_base = np.einsum("ij,mjk->mik", Xi, hand.inv(scale))
        R = T_cam_base[oc, :3, :3]
        pc = np.einsum("mij,mj->mi", R, P[op]) + T_cam_base[oc, :3, 3]
        z = pc[:, 2]
        z = np.where(np.abs(z) < 1e-9, 1e-9, z)
        r = np.column_stack([fx * pc[:, 0] / z + K[0, 2], fy * pc[:, 1] / z + K[1, 2]]) - ouv
        Jp = np.zeros((len(oc), 2, 3))
        Jp[:, 0, 0] = fx / z
        Jp[:, 0, 2] = -fx * pc[:, 0] / z**2
        Jp[:, 1, 1] = fy / z
        Jp[:, 1, 2] = -fy * pc[:, 1] / z**2
        # camera-frame point q = exp(-d) inv(X) p_flange: dq/drho = -I, dq/dphi = [q]x
        qx = np.zeros((len(oc), 3, 3))
        qx[:, 0, 1], qx[:, 0, 2] = -pc[:, 2], pc[:, 1]
        qx[:, 1, 0], qx[:, 1, 2] = pc[:, 2], -pc[:, 0]
        qx[:, 2, 0], qx[:, 2, 1] = -pc[:, 1], pc[:, 0]
        A = np.concatenate([-Jp, np.einsum("mij,mjk->mik", Jp, qx)], axis=2)  # (M, 2, 6)
        if with_scale:
            # ds turns flange i by phi_i ds about its own origin (right perturbation, flange frame);
            # seen from the camera that is the twist Ad(inv(X)) (0, phi_i) ds
            Rx, tx = X[:3, :3], X[:3, 3]
            ang = hand.phi @ Rx  # rows: R_X^T phi_i
            lin = -np.cross(tx @ Rx, ang)  # rows: -[R_X^T t_X]x R_X^T phi_i
            twist = np.concatenate([lin, ang], axis=1)[oc]  # (M, 6)
            A = np.concatenate([A, np.einsum("mij,mj->mi", A, twist)[:, :, None]], axis=2)
        B = np.einsum("mij,mjk->mik", Jp, R)  # (M, 2, 3)
        return r, A, B

    def robust_cost(r):
        e = np.linalg.norm(r, axis=1)
        return float(np.sum(np.where(e <= huber_px, 0.5 * e**2, huber_px * (e - 0.5 * huber_px))))

    from scipy.sparse import csr_matrix

    # sums over the observations of each point as one sparse product
    G = csr_matrix((np.ones(len(op)), (op, np.arange(len(op)))), shape=(m, len(op)))

    def normal_equations(r, A, B, w):
        Aw = A * w[:, None, None]
        At = np.transpose(Aw, (0, 2, 1))
        Hxx = Aw.reshape(-1, npar).T @ A.reshape(-1, npar)
        gx = Aw.reshape(-1, npar).T @ r.reshape(-1)
        Hxp = (G @ np.matmul(At, B).reshape(len(op), 3 * npar)).reshape(m, npar, 3)
        Bw = B * w[:, None, None]
        Bt = np.transpose(Bw, (0, 2, 1))
        Hpp = (G @ np.matmul(Bt, B).reshape(len(op), 9)).reshape(m, 3, 3)
        gp = G @ np.matmul(Bt, r[:, :, None]).reshape(len(op), 3)
        return Hxx, gx, Hxp, Hpp, gp

    def reduced(Hxx, Hxp, Hpp, lam):
        # a point seen only from one camera centre (a pure rotation) has no depth information:
        # a tiny relative damping keeps its block invertible
        eps = 1e-9 * np.trace(Hpp, axis1=1, axis2=2)[:, None, None] + 1e-12
        Hpp_inv = np.linalg.inv(Hpp + (lam + eps) * np.eye(3))
        HxpHinv = np.matmul(Hxp, Hpp_inv)  # (m, npar, 3)
        S = Hxx + lam * np.eye(npar) - np.einsum("mij,mkj->ik", HxpHinv, Hxp, optimize=True)
        return S, Hpp_inv, HxpHinv

    lam = 1e-3
    r, A, B = linearise(X, P, scale)
    cost = robust_cost(r)
    for _ in range(iterations):
        e = np.linalg.norm(r, axis=1)
        w = np.where(e <= huber_px, 1.0, huber_px / np.maximum(e, 1e-12))
        Hxx, gx, Hxp, Hpp, gp = normal_equations(r, A, B, w)
        improved = False
        for _try in range(8):
            S, Hpp_inv, HxpHinv = reduced(Hxx, Hxp, Hpp, lam)
            bx = gx - np.einsum("mij,mj->i", HxpHinv, gp, optimize=True)
            try:
                dx = np.linalg.solve(S, -bx)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            dp = -np.matmul(Hpp_inv, (gp + np.einsum("mji,j->mi", Hxp, dx))[:, :, None])[:, :, 0]
            X_new = X @ exp_se3(dx[:6])
            s_new = scale + float(dx[6]) if with_scale else scale
            P_new = P + dp
            r_new, A_new, B_new = linearise(X_new, P_new, s_new)
            c_new = robust_cost(r_new)
            if c_new < cost:
                X, P, scale, r, A, B = X_new, P_new, s_new, r_new, A_new, B_new
                step = float(np.linalg.norm(dx))
                converged = cost - c_new < 1e-10 * cost or step < 1e-10
                cost = c_new
                lam = max(lam / 3.0, 1e-9)
                improved = True
                break
            lam *= 10.0
        if not improved or converged:
            break
    Hxx, _gx, Hxp, Hpp, _gp = normal_equations(r, A, B, np.ones(len(oc)))
    S, _, _ = reduced(Hxx, Hxp, Hpp, 0.0)
    return X, P, scale, S


def refine_target_free(
    linear,
    T_base_flange: Sequence[np.ndarray],
    T_map_cam: Sequence[np.ndarray],
    images: Sequence[np.ndarray],
    K: np.ndarray,
    *,
    dist: Sequence[float] | None = None,
    n_features: int = 1500,
    keyframes: Sequence[KeyframeDepths] | None = None,
    path: PathViews | None = None,
    match_window: int = 2,
):
    """The target-free result with ``X`` refined on the stop images and the scale re-estimated.

    Parameters
    ----------
    linear : HandEyeResult
        The rACR linear solution (:func:`fgcd_cli.calibration.handeye.solve_handeye_scale`)
        of the same samples; its ``X`` starts the refinement.
    T_base_flange, T_map_cam : sequences of N (4, 4) ndarray
        The samples (reported flange poses, VSE camera poses in map units).
    images : sequence of N images
        Camera image at each stop.
    K, dist :
        Intrinsics of the images (``dist`` None or zeros for undistorted images).
    n_features : int
        SIFT features per image.
    keyframes : sequence of KeyframeDepths, optional
        The VSE's keyframes with their cloud; when given (and matched), the scale
        is the ratio of metric to map depths (:func:`scale_from_depths`).
    path : PathViews, optional
        All the views along the platform's path (stops included); when given, the
        adjustment runs over them (each matched with the next ``match_window``
        views, the stops with each other) instead of over the stops alone.
    match_window : int
        See ``path``.

    Returns
    -------
    HandEyeResult
        Method ``"racr-linear+image-ba"``; ``scale`` from the map depths when
        ``keyframes`` are given, else from the VSE's camera motions with the refined
        ``X`` (:func:`fgcd_cli.calibration.handeye.estimate_scale`); residuals
        recomputed; ``refinement`` says what was done.

    Raises
    ------
    CalibrationError
        The images could not be matched (the caller keeps the linear result).
    """
    from dataclasses import replace

    from fgcd_cli.calibration.handeye import estimate_scale, pair_residuals, per_sample_residuals
    from fgcd_cli.calibration.samples import relative_motions

    if path is not None and len(path.images) > len(images):
        if len(path.stop_index) != len(images) or len(path.T_base_flange) != len(path.images):
            raise CalibrationError("the path views do not match the stop samples")
        ba = refine_handeye_images(path.T_base_flange, path.images, K, linear.T_flange_cam, dist=dist,
                                   n_features=n_features, match_window=match_window, anchors=path.stop_index)
        views, stop_rms = len(path.images), np.asarray(ba.per_image_rms_px)[list(path.stop_index)]
    else:
        ba = refine_handeye_images(T_base_flange, images, K, linear.T_flange_cam, dist=dist, n_features=n_features)
        views, stop_rms = len(images), np.asarray(ba.per_image_rms_px)
    # the VSE side carries the noise: fit 1/s (unbiased for independent pose noise, see estimate_scale)
    sc = estimate_scale(ba.T_flange_cam, T_base_flange, T_map_cam, pairs=linear.pairs, regress="vse")
    scale, scale_method, depth_info = sc.scale, "camera motions (estimate_scale, regress=vse)", {}
    if keyframes:
        try:
            d_scale, d_spread, d_n = scale_from_depths(ba.points_base, ba.T_flange_cam, keyframes, K)
            scale, scale_method = d_scale, "map depths (scale_from_depths)"
            depth_info = {"scale_depth_spread": d_spread, "scale_depth_matches": d_n}
        except CalibrationError as exc:
            depth_info = {"scale_depth_error": str(exc)}
    MB = relative_motions(list(T_base_flange), linear.pairs)
    MA = relative_motions(list(T_map_cam), linear.pairs)
    MA_metric = [np.block([[A[:3, :3], scale * A[:3, 3:4]], [A[3:4, :]]]) for A in MA]
    res_mm, res_deg = pair_residuals(ba.T_flange_cam, MB, MA_metric)
    refinement = {
        "method": "bundle adjustment of X over the images of the platform's rest poses, camera poses = "
                  "T_base_flange @ X",
        "views": views,
        "points": ba.n_points,
        "observations": ba.n_observations,
        "rms_px": ba.rms_px,
        "per_image_rms_px": stop_rms.tolist(),
        "std_mm": ba.std_mm,
        "std_deg": ba.std_deg,
        "platform_rotation_scale": ba.rotation_scale,
        "platform_rotation_scale_std": ba.rotation_scale_std,
        "change_mm": ba.change_mm,
        "change_deg": ba.change_deg,
        "linear_T_flange_cam": np.asarray(linear.T_flange_cam).tolist(),
        "linear_scale": linear.scale,
        "scale_method": scale_method,
        "scale_from_motions": sc.scale,
        "scale_std": sc.scale_std,
        **depth_info,
    }
    notes = list(linear.notes) + list(ba.notes)
    n = linear.n_samples
    return replace(
        linear,
        T_flange_cam=ba.T_flange_cam,
        scale=scale,
        method="racr-linear+image-ba",
        residuals_mm=res_mm,
        residuals_deg=res_deg,
        sample_residuals_mm=per_sample_residuals(n, linear.pairs, res_mm),
        sample_residuals_deg=per_sample_residuals(n, linear.pairs, res_deg),
        notes=notes,
        refinement=refinement,
    )


@dataclass(frozen=True, kw_only=True)
class PathViews:
    """Every pose the platform came to rest at during a procedure, in order, with its image.

    The steps between the stops (a few millimetres and a degree apart) are views
    with a reported flange pose like the stops: the bundle adjustment needs no
    VSE pose for them. Each step brings the platform's repeatability error anew,
    and with ~10x more views than stops the adjustment averages it down
    (docs/calibration.md §3).

    Attributes
    ----------
    T_base_flange : list of (4, 4) ndarray
        Reported flange pose of each view, metres.
    images : list of images
        The camera image at each view (undistorted like the stop images).
    stop_index : list of int
        For each stop sample (in the order of the samples), its index in this path.
    """

    T_base_flange: list
    images: list
    stop_index: list


@dataclass(frozen=True, kw_only=True)
class KeyframeDepths:
    """What :func:`scale_from_depths` needs of one VSE keyframe.

    Attributes
    ----------
    T_base_flange : (4, 4) ndarray
        Reported flange pose when the keyframe's image was taken.
    T_map_cam : (4, 4) ndarray
        The keyframe's pose in the map (map units).
    pixels : (P, 2) ndarray
        Pixels of the keyframe's cloud points (``MapCloud.pixels``).
    points_map : (P, 3) ndarray
        Those points in the map frame (``MapCloud.points``).
    """

    T_base_flange: np.ndarray
    T_map_cam: np.ndarray
    pixels: np.ndarray
    points_map: np.ndarray


def scale_from_depths(
    points_base: np.ndarray,
    T_flange_cam: np.ndarray,
    keyframes: Sequence[KeyframeDepths],
    K: np.ndarray,
    *,
    max_px: float = 1.5,
    min_matches: int = 100,
) -> tuple[float, float, int]:
    """Map scale as the ratio of metric to map depths of the same pixels of the VSE keyframes.

    The metric depths come from the image refinement's scene points (base frame)
    seen from the keyframe's metric camera pose ``T_base_flange @ X``; the map
    depths from the VSE's own cloud points measured in that keyframe. The camera
    *positions* the VSE reports carry errors of millimetres (a few % of the small
    motions); the depths of its map are consistent to a few tenths of a percent
    across keyframes, so they are what fixes the scale.

    Returns
    -------
    scale, spread, n : float, float, int
        Median ratio (metres per map unit), robust relative spread of the per-keyframe
        medians (1.4826 MAD / median), and the number of matched pixels.

    Raises
    ------
    CalibrationError
        Fewer than ``min_matches`` pixels matched.
    """
    from scipy.spatial import cKDTree

    P = np.asarray(points_base, dtype=float)
    X = np.asarray(T_flange_cam, dtype=float)
    per_kf, ratios = [], []
    for kf in keyframes:
        if len(kf.pixels) == 0 or len(P) == 0:
            continue
        T_cam_base = invert_pose(np.asarray(kf.T_base_flange, dtype=float) @ X)
        uv, z_metric = _project(np.repeat(T_cam_base[None], len(P), axis=0), K, P)
        T_cam_map = invert_pose(np.asarray(kf.T_map_cam, dtype=float))
        z_map = (np.asarray(kf.points_map, dtype=float) @ T_cam_map[:3, :3].T + T_cam_map[:3, 3])[:, 2]
        dist, nn = cKDTree(np.asarray(kf.pixels, dtype=float)).query(uv, distance_upper_bound=max_px)
        ok = np.isfinite(dist) & (z_metric > 0)
        if not np.any(ok):
            continue
        zm = z_map[nn[ok]]
        good = zm > 0
        r = z_metric[ok][good] / zm[good]
        if len(r) >= 10:
            per_kf.append(float(np.median(r)))
            ratios.append(r)
    n = int(sum(len(r) for r in ratios))
    if n < min_matches:
        raise CalibrationError(f"only {n} pixels of the VSE keyframes matched the refined scene points")
    allr = np.concatenate(ratios)
    scale = float(np.median(allr))
    med = np.asarray(per_kf)
    spread = float(1.4826 * np.median(np.abs(med - np.median(med))) / scale) if len(med) > 1 else float("nan")
    return scale, spread, n
