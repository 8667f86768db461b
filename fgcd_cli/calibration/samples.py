"""Calibration samples: validation, motion pairs and the degeneracy checks.

A *sample* is one platform stop: the reported flange pose ``T_base_flange`` and
what the camera saw there (a board pose, or the VSE camera pose). A *motion
pair* ``(i, j)`` is the relative motion between two samples, expressed in the
frame of sample ``i``:

- hand (flange) motion ``M_B = inv(T_base_flange_i) @ T_base_flange_j``,
- eye (camera) motion ``M_A = inv(T_x_cam_i) @ T_x_cam_j`` for any fixed frame x.

With ``X = T_flange_cam`` both are the same physical motion, hence
``M_B @ X = X @ M_A`` (``R_B R_X = R_X R_A`` and ``R_B t_X + t_B = R_X t_A + t_X``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from itertools import combinations

import numpy as np

from fgcd_cli.calibration.errors import CalibrationError
from fgcd_cli.errors import UserInputError
from fgcd_core.se3 import invert_pose, is_pose, log_so3

__all__ = [
    "validate_poses",
    "motion_pairs",
    "relative_motions",
    "rotation_axis_spread_deg",
    "check_rotation_diversity",
    "MIN_PAIR_ROTATION_DEG",
    "MIN_AXIS_SPREAD_DEG",
]

#: Motion pairs rotating less than this carry no usable rotation-axis information.
MIN_PAIR_ROTATION_DEG = 2.0
#: Smallest angle between rotation axes for R_X to be well determined.
MIN_AXIS_SPREAD_DEG = 15.0


def validate_poses(poses: Sequence[np.ndarray], what: str) -> list[np.ndarray]:
    """Check a list of 4x4 rigid poses and return them as float arrays.

    Raises
    ------
    UserInputError
        If any pose is not a finite 4x4 rigid transform; the message names the sample.
    """
    out = []
    for index, T in enumerate(poses):
        T = np.asarray(T, dtype=float)
        if T.shape != (4, 4):
            raise UserInputError(f"{what} sample {index} has shape {T.shape}, expected a 4x4 pose")
        if not np.all(np.isfinite(T)):
            raise UserInputError(f"{what} sample {index} contains NaN or infinite values")
        if not is_pose(T, atol=1e-5):
            raise UserInputError(f"{what} sample {index} is not a rigid transform (rotation not orthonormal)")
        out.append(T)
    return out


def motion_pairs(n_samples: int, pairs: str | Sequence[tuple[int, int]] = "all") -> list[tuple[int, int]]:
    """Index pairs ``(i, j)`` of the motions used by a solver.

    Parameters
    ----------
    n_samples : int
        Number of samples.
    pairs : {"all", "consecutive"} or sequence of (int, int)
        ``"all"``: every ``i < j`` (over-determined, robust to one bad sample);
        ``"consecutive"``: ``(i, i+1)``; ``"first"``: ``(0, j)``; or an explicit list.
    """
    if isinstance(pairs, str):
        if pairs == "all":
            return list(combinations(range(n_samples), 2))
        if pairs == "consecutive":
            return [(i, i + 1) for i in range(n_samples - 1)]
        if pairs == "first":
            return [(0, j) for j in range(1, n_samples)]
        raise UserInputError(f"unknown pair selection '{pairs}' (use all, consecutive or first)")
    out = []
    for i, j in pairs:
        if not (0 <= i < n_samples and 0 <= j < n_samples) or i == j:
            raise UserInputError(f"motion pair ({i}, {j}) is not a pair of distinct samples 0..{n_samples - 1}")
        out.append((int(i), int(j)))
    return out


def relative_motions(poses: Sequence[np.ndarray], pairs: Sequence[tuple[int, int]]) -> list[np.ndarray]:
    """``inv(T_i) @ T_j`` for every pair: the motion from i to j in the frame of i."""
    return [invert_pose(poses[i]) @ poses[j] for i, j in pairs]


def rotation_axis_spread_deg(rotations: Sequence[np.ndarray]) -> float:
    """How far apart the rotation axes of a set of motions are, in degrees.

    For two unit axes at angle ``theta`` the singular values of the stacked axes
    are ``sqrt(1 +- cos theta)``; their ratio is ``tan(theta / 2)``. The value
    returned is ``2 atan(sigma_2 / sigma_1)`` over all axes (sign-free, since an
    axis and its opposite are the same line): 0 for parallel axes, 90 for two
    orthogonal ones.
    """
    axes = []
    for R in rotations:
        phi = log_so3(R)
        angle = float(np.linalg.norm(phi))
        if angle > 1e-9:
            axes.append(phi / angle)
    if len(axes) < 2:
        return 0.0
    # The scatter matrix sum(a a^T) is sign-free; its two largest eigenvalues are sigma_1^2, sigma_2^2.
    A = np.asarray(axes)
    eig = np.sort(np.linalg.eigvalsh(A.T @ A))[::-1]
    return math.degrees(2.0 * math.atan(math.sqrt(max(eig[1], 0.0) / eig[0])))


def check_rotation_diversity(
    R_hand_motions: Sequence[np.ndarray],
    *,
    min_rotation_deg: float = MIN_PAIR_ROTATION_DEG,
    min_axis_spread_deg: float = MIN_AXIS_SPREAD_DEG,
) -> np.ndarray:
    """Refuse motion sets from which the hand-eye rotation cannot be found.

    Parameters
    ----------
    R_hand_motions : sequence of (3, 3) ndarray
        Rotation parts of the flange motions ``M_B``.

    Returns
    -------
    rotating : (P,) bool ndarray
        Which motions rotate enough to carry axis information.

    Raises
    ------
    CalibrationError
        Pure translations only, a single rotating motion, or parallel rotation axes.
    """
    angles = np.array([math.degrees(float(np.linalg.norm(log_so3(R)))) for R in R_hand_motions])
    rotating = angles >= min_rotation_deg
    if not np.any(rotating):
        raise CalibrationError(
            "degenerate motions: the platform only translated (largest rotation "
            f"{angles.max(initial=0.0):.2f} deg); the hand-eye rotation needs rotations of at least "
            f"{min_rotation_deg:.0f} deg about two or more non-parallel axes"
        )
    spread = rotation_axis_spread_deg([R for R, r in zip(R_hand_motions, rotating) if r])
    if spread < min_axis_spread_deg:
        raise CalibrationError(
            f"degenerate motions: all rotations are about (nearly) the same axis (spread {spread:.1f} deg); "
            f"rotate about at least two axes at least {min_axis_spread_deg:.0f} deg apart"
        )
    return rotating
