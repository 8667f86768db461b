"""The platform motions of the calibration procedures: safe, small, and informative.

Target-free hand-eye needs rotations about at least two non-parallel axes (for
``R_X``) and translations (for the scale); heritage sites allow only small
motions, so the default set stays within a few centimetres and about ten
degrees of the start pose. The first motion is a sideways translation: a
monocular VSE initialises its map from translation parallax, never from a pure
rotation.
"""

from __future__ import annotations

import math

import numpy as np

from fgcd_cli.errors import UserInputError
from fgcd_core.se3 import exp_so3, invert_pose, log_so3, make_pose

__all__ = ["exploration_motions", "target_motions", "interpolate_steps"]


def _T(rot_deg=(0.0, 0.0, 0.0), trans_m=(0.0, 0.0, 0.0)) -> np.ndarray:
    return make_pose(exp_so3(np.radians(np.asarray(rot_deg, dtype=float))), np.asarray(trans_m, dtype=float))


def exploration_motions(
    *,
    translation_m: float = 0.03,
    rotation_deg: float = 8.0,
    rotation_axes: str = "xyz",
) -> list[np.ndarray]:
    """Stops of the target-free procedure, as flange poses relative to the start.

    Parameters
    ----------
    translation_m : float
        Largest translation from the start along each axis, metres (a few cm).
    rotation_deg : float
        Rotation about each flange axis, degrees (keep <= 10-15 on a site).
    rotation_axes : str
        Flange axes the platform can rotate about (at least two of ``xyz``).

    Returns
    -------
    list of (4, 4) ndarray
        ``T_start_flange`` of each stop, starting with the identity. Consecutive
        stops are joined by small steps (:func:`interpolate_steps`).
    """
    if not (0.0 < translation_m <= 0.1):
        raise UserInputError("exploration translation must be in (0, 100] mm")
    if not (0.0 < rotation_deg <= 20.0):
        raise UserInputError("exploration rotation must be in (0, 20] degrees")
    axes = sorted(set(rotation_axes.lower()))
    if len(axes) < 2 or any(a not in "xyz" for a in axes):
        raise UserInputError("target-free calibration needs rotations about at least two of the axes x, y, z")
    t, r = translation_m, rotation_deg
    stops = [
        _T(),
        _T(trans_m=(t, 0, 0)),  # sideways first: the monocular VSE initialises from parallax
        _T(trans_m=(t, t, 0)),
        _T(trans_m=(0, t, -0.5 * t)),
    ]
    unit = {"x": np.array([1.0, 0, 0]), "y": np.array([0, 1.0, 0]), "z": np.array([0, 0, 1.0])}
    for k, axis in enumerate(axes):
        shift = np.roll(np.array([0.5 * t, 0.0, 0.0]), k)
        stops.append(_T(rot_deg=r * unit[axis], trans_m=shift))
        stops.append(_T(rot_deg=-r * unit[axis], trans_m=-shift))
    # Mixed axes (well-conditioned pairs), then back home.
    a0, a1 = unit[axes[0]], unit[axes[1]]
    stops.append(_T(rot_deg=r * 0.7 * (a0 + a1), trans_m=(0, 0, 0.5 * t)))
    stops.append(_T(rot_deg=r * 0.7 * (a0 - a1), trans_m=(-0.5 * t, 0, 0)))
    stops.append(_T())
    return stops


def target_motions(*, rotation_deg: float = 15.0, translation_m: float = 0.04) -> list[np.ndarray]:
    """Stops for hand-eye with a board: larger rotations about all three axes.

    Returns
    -------
    list of (4, 4) ndarray
        ``T_start_flange`` of 13 stops (identity first).
    """
    if not (0.0 < rotation_deg <= 30.0):
        raise UserInputError("target rotation must be in (0, 30] degrees")
    r, t = rotation_deg, translation_m
    return [
        _T(),
        _T((r, 0, 0), (0, t, 0)),
        _T((-r, 0, 0), (0, -t, 0)),
        _T((0, r, 0), (-t, 0, 0)),
        _T((0, -r, 0), (t, 0, 0)),
        _T((0, 0, r), (0, 0, t)),
        _T((0, 0, -r), (0, 0, -t)),
        _T((0.7 * r, 0.7 * r, 0), (0, 0, 0)),
        _T((-0.7 * r, 0.7 * r, 0.5 * r), (t, t, 0)),
        _T((0.7 * r, -0.7 * r, -0.5 * r), (-t, -t, 0)),
        _T((-0.7 * r, -0.7 * r, 0), (0, 0, t)),
        _T((0.5 * r, 0, 0.7 * r), (t, 0, -t)),
        _T((0, 0.5 * r, -0.7 * r), (0, t, t)),
    ]


def interpolate_steps(
    T_from: np.ndarray, T_to: np.ndarray, *, max_step_m: float = 0.005, max_step_deg: float = 1.0
) -> list[np.ndarray]:
    """Intermediate poses from ``T_from`` to ``T_to`` (excluded, included), each step small.

    Small steps keep a visual tracker locked and every step within the motion
    guard's limits.
    """
    delta = invert_pose(T_from) @ T_to
    dist = float(np.linalg.norm(T_to[:3, 3] - T_from[:3, 3]))
    phi = log_so3(delta[:3, :3])
    angle = math.degrees(float(np.linalg.norm(phi)))
    n = max(1, int(math.ceil(max(dist / max_step_m, angle / max_step_deg))))
    out = []
    for k in range(1, n + 1):
        a = k / n
        R = T_from[:3, :3] @ exp_so3(a * phi)
        out.append(make_pose(R, (1 - a) * T_from[:3, 3] + a * T_to[:3, 3]))
    return out
