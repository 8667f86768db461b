"""Target-free hand-eye and monocular map scale (rACR paper 000, §3.2).

Unknowns: the hand-eye ``X = T_flange_cam`` and the map scale ``s`` of a
monocular VSE session (metres per map unit: a metric camera translation is
``t_A = s * t_VSE``). Data: flange poses ``T_base_flange`` reported by the
platform and camera poses ``T_map_cam`` from the VSE at the same stops.

Derivation in fgcd's convention (checked numerically in the tests). For a pair
``(i, j)`` the flange motion ``M_B = inv(T_base_flange_i) T_base_flange_j`` and
the metric camera motion ``M_A = inv(T_cam_i) T_cam_j`` are one rigid motion
seen from two frames, so ``M_B X = X M_A``:

- rotation: ``R_B R_X = R_X R_A``, i.e. the rotation vectors satisfy
  ``log(R_B) = R_X log(R_A)`` (the axes are carried by ``R_X``);
- translation: ``R_B t_X + t_B = R_X (s t_VSE) + t_X``, i.e. the linear system
  ``(R_B - I) t_X - s R_X t_VSE = -t_B`` in the four unknowns ``(t_X, s)``.

(The paper's Eq. 8 is printed inverted and uses the opposite naming of A and B;
the system above is the one verified against a known ``X`` and ``s``.) Pure
translations (``R_B = I``) observe ``s`` but not ``t_X``; ``R_X`` needs rotations
about at least two non-parallel axes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from enum import StrEnum

import numpy as np
from scipy.spatial.transform import Rotation

from fgcd_cli.calibration.errors import CalibrationError
from fgcd_cli.calibration.handeye.result import HandEyeResult, ScaleResult
from fgcd_cli.calibration.samples import (
    check_rotation_diversity,
    motion_pairs,
    relative_motions,
    rotation_axis_spread_deg,
    validate_poses,
)
from fgcd_cli.errors import UserInputError
from fgcd_core.se3 import log_so3, make_pose, pose_distance

__all__ = [
    "HandEyeMethod",
    "Regress",
    "solve_handeye_scale",
    "estimate_scale",
    "pair_residuals",
    "per_sample_residuals",
    "rotation_from_axes",
]


class HandEyeMethod(StrEnum):
    """Target-free solvers (the ``method`` of a :class:`HandEyeResult`; with a target it is the OpenCV solver's name)."""

    RACR_LINEAR = "racr-linear"
    RACR_LINEAR_IMAGE_BA = "racr-linear+image-ba"


class Regress(StrEnum):
    """Which side of ``s u = b`` carries the noise in :func:`estimate_scale`."""

    PLATFORM = "platform"
    VSE = "vse"


#: A VSE session that translated less than this (in its own units, relative to the
#: hand's metric motion) cannot observe the scale.
_MIN_RELATIVE_CONDITION = 1e-6


# ----------------------------------------------------------------------------- residuals
def pair_residuals(
    T_flange_cam: np.ndarray,
    hand_motions: Sequence[np.ndarray],
    eye_motions_metric: Sequence[np.ndarray],
) -> tuple[np.ndarray, np.ndarray]:
    """Per-pair disagreement of ``M_B X`` and ``X M_A``.

    Parameters
    ----------
    T_flange_cam : (4, 4) ndarray
        Hand-eye ``X``.
    hand_motions, eye_motions_metric : sequences of (4, 4) ndarray
        Flange motions ``M_B`` and metric camera motions ``M_A`` (same length P).

    Returns
    -------
    residuals_mm, residuals_deg : (P,) ndarray
        Translation (mm) and rotation (degrees) difference of the two sides.
    """
    X = np.asarray(T_flange_cam, dtype=float)
    res = [pose_distance(MB @ X, X @ MA) for MB, MA in zip(hand_motions, eye_motions_metric)]
    if not res:
        return np.zeros(0), np.zeros(0)
    arr = np.asarray(res, dtype=float)
    return arr[:, 0], arr[:, 1]


def per_sample_residuals(n_samples: int, pairs: Sequence[tuple[int, int]], values: np.ndarray) -> np.ndarray:
    """Mean of the pair residuals involving each sample, shape (N,) (NaN if unused)."""
    total = np.zeros(n_samples)
    count = np.zeros(n_samples)
    for (i, j), v in zip(pairs, values):
        total[[i, j]] += v
        count[[i, j]] += 1
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def _scaled_motion(M: np.ndarray, scale: float) -> np.ndarray:
    return make_pose(M[:3, :3], scale * M[:3, 3])


def _check_lengths(a: Sequence, b: Sequence, what_a: str, what_b: str, minimum: int) -> None:
    if len(a) != len(b):
        raise UserInputError(f"{len(a)} {what_a} but {len(b)} {what_b}: need one of each per sample")
    if len(a) < minimum:
        raise CalibrationError(f"too few samples: {len(a)} given, at least {minimum} needed (12-20 is a good target)")


# ----------------------------------------------------------------------------- solvers
def rotation_from_axes(R_hand: Sequence[np.ndarray], R_eye: Sequence[np.ndarray]) -> np.ndarray:
    """Hand-eye rotation from paired motion rotations.

    ``R_B = R_X R_A R_X^T`` means ``log(R_B) = R_X log(R_A)``: ``R_X`` is the
    rotation best aligning the eye rotation vectors onto the hand ones
    (least squares, Wahba's problem; solved by :func:`scipy.spatial.transform.Rotation.align_vectors`).
    Larger rotations weigh more because their rotation vectors are longer.

    Parameters
    ----------
    R_hand, R_eye : sequences of (3, 3) ndarray
        Rotations of flange motions ``R_B`` and camera motions ``R_A``.

    Returns
    -------
    (3, 3) ndarray
        ``R_X``.
    """
    beta = np.array([log_so3(R) for R in R_hand])
    alpha = np.array([log_so3(R) for R in R_eye])
    rot, _ = Rotation.align_vectors(beta, alpha)
    return rot.as_matrix()


def solve_handeye_scale(
    T_base_flange: Sequence[np.ndarray],
    T_map_cam: Sequence[np.ndarray],
    *,
    pairs: str | Sequence[tuple[int, int]] = "all",
) -> HandEyeResult:
    """Hand-eye ``X`` and map scale ``s`` from flange poses and VSE camera poses.

    First ``R_X`` from the rotation axes of all rotating motion pairs, then
    ``(t_X, s)`` jointly by linear least squares over all pairs (translations
    included) from ``(R_B - I) t_X - s R_X t_VSE = -t_B``.

    Parameters
    ----------
    T_base_flange : sequence of N (4, 4) ndarray
        Flange poses reported by the platform at each stop, metres.
    T_map_cam : sequence of N (4, 4) ndarray
        VSE camera poses at the same stops, in map units.
    pairs : {"all", "consecutive", "first"} or sequence of (int, int)
        Which motion pairs to use.

    Returns
    -------
    HandEyeResult
        With ``scale`` set (metres per map unit) and per-pair residuals.

    Raises
    ------
    UserInputError
        Mismatched lengths or invalid (NaN, non-rigid) poses.
    CalibrationError
        Too few samples, pure translations, parallel rotation axes, or a VSE
        that did not translate (scale unobservable).
    """
    _check_lengths(T_base_flange, T_map_cam, "flange poses", "camera poses", 3)
    hand = validate_poses(T_base_flange, "flange pose")
    eye = validate_poses(T_map_cam, "VSE camera pose")
    index_pairs = motion_pairs(len(hand), pairs)
    MB = relative_motions(hand, index_pairs)
    MA = relative_motions(eye, index_pairs)
    rotating = check_rotation_diversity([M[:3, :3] for M in MB])

    R_X = rotation_from_axes(
        [M[:3, :3] for m, M in zip(rotating, MB) if m], [M[:3, :3] for m, M in zip(rotating, MA) if m]
    )

    # Linear least squares in (t_X, s): (R_B - I) t_X - s R_X t_VSE = -t_B.
    rows = [np.column_stack([B[:3, :3] - np.eye(3), -(R_X @ A[:3, 3])]) for B, A in zip(MB, MA)]
    A_mat = np.vstack(rows)
    b_vec = np.concatenate([-B[:3, 3] for B in MB])
    _check_linear_system(A_mat)
    sol, *_ = np.linalg.lstsq(A_mat, b_vec, rcond=None)
    t_X, scale = sol[:3], float(sol[3])
    if not scale > 0:
        raise CalibrationError(
            f"the map scale came out non-positive ({scale:.3g}): the VSE camera poses do not follow "
            "the platform motion (wrong pose order, tracking lost, or camera poses inverted)"
        )
    X = make_pose(R_X, t_X)
    res_mm, res_deg = pair_residuals(X, MB, [_scaled_motion(A, scale) for A in MA])
    notes = _quality_notes(MB, MA, rotating)
    return HandEyeResult(
        T_flange_cam=X,
        scale=scale,
        method=str(HandEyeMethod.RACR_LINEAR),
        n_samples=len(hand),
        n_pairs=len(index_pairs),
        pairs=index_pairs,
        residuals_mm=res_mm,
        residuals_deg=res_deg,
        sample_residuals_mm=per_sample_residuals(len(hand), index_pairs, res_mm),
        sample_residuals_deg=per_sample_residuals(len(hand), index_pairs, res_deg),
        axis_spread_deg=rotation_axis_spread_deg([M[:3, :3] for m, M in zip(rotating, MB) if m]),
        max_rotation_deg=max(math.degrees(float(np.linalg.norm(log_so3(M[:3, :3])))) for M in MB),
        notes=notes,
    )


def _check_linear_system(A_mat: np.ndarray) -> None:
    """Refuse a (t_X, s) system that does not determine all four unknowns."""
    norms = np.linalg.norm(A_mat, axis=0)
    if norms[3] <= 1e-12 * max(1.0, norms[:3].max()):
        raise CalibrationError(
            "the VSE camera did not translate between samples: the map scale is unobservable "
            "(check that the VSE is tracking and the platform really moved)"
        )
    if np.any(norms[:3] <= 1e-12):
        raise CalibrationError("the hand-eye translation is unobservable: add rotations about other axes")
    sv = np.linalg.svd(A_mat / norms, compute_uv=False)
    if sv[-1] / sv[0] < _MIN_RELATIVE_CONDITION:
        raise CalibrationError(
            "the hand-eye translation and map scale are not separable from these motions: "
            "add rotations about other axes and translations"
        )


def _quality_notes(MB: Sequence[np.ndarray], MA: Sequence[np.ndarray], rotating: np.ndarray) -> list[str]:
    """Warnings: the rotation angle is frame-independent, hand and eye must agree on it."""
    notes = []
    diffs = [
        abs(np.linalg.norm(log_so3(B[:3, :3])) - np.linalg.norm(log_so3(A[:3, :3])))
        for B, A, r in zip(MB, MA, rotating)
        if r
    ]
    if diffs and math.degrees(float(np.median(diffs))) > 1.0:
        notes.append(
            f"camera and platform disagree on rotation angles (median {math.degrees(float(np.median(diffs))):.2f} deg): "
            "check the VSE tracking and that flange poses (not TCP poses) are used"
        )
    max_rot = max(math.degrees(float(np.linalg.norm(log_so3(B[:3, :3])))) for B in MB)
    if max_rot < 5.0:
        notes.append(f"rotations are small (largest {max_rot:.1f} deg): the hand-eye rotation will be noisy")
    return notes


def estimate_scale(
    T_flange_cam: np.ndarray,
    T_base_flange: Sequence[np.ndarray],
    T_map_cam: Sequence[np.ndarray],
    *,
    pairs: str | Sequence[tuple[int, int]] = "first",
    regress: str = "platform",
) -> ScaleResult:
    """Map scale of a VSE session when the hand-eye is known.

    Called at the start of every capture/relocate session after a few
    commanded motions; translations suffice. From ``M_B X = X M_A``:
    ``s R_X t_VSE = (R_B - I) t_X + t_B`` for every pair, i.e. ``s u = b`` with
    ``u = R_X t_VSE`` (VSE, map units) and ``b`` the metric camera motion known
    from the platform and ``X``.

    ``regress="platform"`` (the default) fits ``s`` to minimise the metric
    residuals: ``s = sum(u . b) / sum(u . u)``. With independent VSE pose noise
    this is biased low (noise in the regressor, attenuation bias).
    ``regress="vse"`` fits ``1/s`` instead, ``s = sum(b . b) / sum(u . b)``,
    unbiased for such noise (``tests/calibration/test_handeye.py``). Neither is
    unbiased for the monocular VSE's structured pose errors, which is why the
    target-free calibration takes the scale from the map depths
    (:func:`fgcd_cli.calibration.depth_scale.scale_from_depths`;
    docs/calibration.md, "Target-free").

    Parameters
    ----------
    T_flange_cam : (4, 4) ndarray
        Known hand-eye, metres.
    T_base_flange : sequence of N (4, 4) ndarray
        Reported flange poses, metres.
    T_map_cam : sequence of N (4, 4) ndarray
        VSE camera poses, map units.
    pairs : {"first", "all", "consecutive"} or sequence of (int, int)
        Motion pairs (default: each sample against the first).
    regress : {"platform", "vse"}
        Which side carries the noise in the fit (see above).

    Returns
    -------
    ScaleResult

    Raises
    ------
    UserInputError
        Mismatched lengths or invalid poses.
    CalibrationError
        Fewer than 2 samples or no camera translation.
    """
    _check_lengths(T_base_flange, T_map_cam, "flange poses", "camera poses", 2)
    X = validate_poses([T_flange_cam], "hand-eye")[0]
    hand = validate_poses(T_base_flange, "flange pose")
    eye = validate_poses(T_map_cam, "VSE camera pose")
    index_pairs = motion_pairs(len(hand), pairs)
    MB = relative_motions(hand, index_pairs)
    MA = relative_motions(eye, index_pairs)
    R_X, t_X = X[:3, :3], X[:3, 3]
    u = np.concatenate([R_X @ A[:3, 3] for A in MA])
    b = np.concatenate([(B[:3, :3] - np.eye(3)) @ t_X + B[:3, 3] for B in MB])
    uu = float(u @ u)
    hand_travel = float(np.linalg.norm(b))
    if uu <= 1e-24 or hand_travel <= 1e-9:
        raise CalibrationError(
            "the camera did not translate between samples: the map scale is unobservable "
            "(move the platform a few centimetres and check that the VSE is tracking)"
        )
    if regress not in tuple(Regress):
        raise UserInputError(f"unknown regression '{regress}' (platform or vse)")
    # pairs of N samples share their samples' errors: N - 1 of them are independent
    shared = math.sqrt(max(1.0, len(index_pairs) / max(len(hand) - 1, 1)))
    scale, scale_std = _fit_scale(u, b, Regress(regress), shared)
    res_mm, res_deg = pair_residuals(X, MB, [_scaled_motion(A, scale) for A in MA])
    return ScaleResult(
        scale=scale, scale_std=scale_std, n_pairs=len(index_pairs), residuals_mm=res_mm, rotation_residuals_deg=res_deg
    )


def _fit_scale(u: np.ndarray, b: np.ndarray, regress: Regress, shared: float) -> tuple[float, float]:
    """``s`` of ``s u = b`` by least squares on the side ``regress`` names, and its one-sigma.

    ``u`` are the VSE translations rotated into the flange (map units), ``b`` the
    metric camera motions (metres); ``shared`` inflates the sigma for pairs sharing samples.
    """
    uu = float(u @ u)
    ub = float(u @ b)
    if not ub > 0:
        raise CalibrationError(
            f"the map scale came out non-positive ({ub:.3g}): the VSE camera motion opposes the platform motion"
        )
    dof = max(len(u) - 1, 1)
    if regress == Regress.PLATFORM:
        scale = ub / uu
        r = scale * u - b  # metres
        return scale, float(math.sqrt(float(r @ r) / dof / uu)) * shared
    bb = float(b @ b)
    scale = bb / ub
    r = u - b / scale  # map units
    return scale, float(math.sqrt(float(r @ r) / dof / bb)) * scale**2 * shared
