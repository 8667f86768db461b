"""Mapping between a flange pose and a GRBL stage's axis values (mm, degrees).

A stage with fewer than 6 DoF performs the reachable part of a motion; the
flange rotation axes it cannot reach are named by :meth:`GrblKinematics.axes_from_pose`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

__all__ = ["GrblKinematics"]

_ROT_AXES = {"rx": 0, "ry": 1, "rz": 2}
_LIN_AXES = ("x", "y", "z")


@dataclass(frozen=True, kw_only=True)
class GrblKinematics:
    """Mapping between the flange pose in the base frame and the stage's axes.

    The flange position is ``origin_m + sign * mpos_mm / 1000`` per base axis,
    where ``linear_axes[i]`` is the GRBL axis letter that drives base axis i.
    Rotary axes (degrees) rotate the flange about its own axes, stacked in the
    listed order: ``R_base_flange = R_base_flange_zero @ R(axis_1, a_1) @ R(axis_2, a_2) ...``.
    They are assumed to turn about the flange origin (a camera mount centred on
    the rotation axes); an off-centre mount needs its offset in the hand-eye.

    Attributes
    ----------
    linear_axes : tuple of 3 str
        GRBL letters driving base x, y, z, e.g. ``("X", "Y", "Z")``.
    linear_signs : tuple of 3 float
        +1 or -1 per base axis.
    origin_m : tuple of 3 float
        Flange position in the base frame when the machine is at MPos 0, metres.
    rotary_axes : tuple of (str, str)
        ``(flange_axis, letter)`` pairs in stacking order, e.g. ``(("rz", "C"),)``.
    R_base_flange_zero : tuple of 9 float
        Row-major flange orientation with all rotary axes at 0.
    """

    linear_axes: tuple[str, str, str] = ("X", "Y", "Z")
    linear_signs: tuple[float, float, float] = (1.0, 1.0, 1.0)
    origin_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotary_axes: tuple[tuple[str, str], ...] = ()
    R_base_flange_zero: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)

    @property
    def letters(self) -> tuple[str, ...]:
        """All GRBL axis letters used, linear first."""
        return tuple(self.linear_axes) + tuple(letter for _, letter in self.rotary_axes)

    @property
    def controllable(self) -> tuple[str, ...]:
        """Flange axes the stage can move."""
        return _LIN_AXES + tuple(axis for axis in ("rx", "ry", "rz") if axis in dict(self.rotary_axes))

    def _R0(self) -> np.ndarray:
        return np.asarray(self.R_base_flange_zero, dtype=float).reshape(3, 3)

    def _rotation(self, angles_deg) -> np.ndarray:
        R = self._R0()
        for (axis, _), angle in zip(self.rotary_axes, angles_deg):
            rotvec = np.zeros(3)
            rotvec[_ROT_AXES[axis]] = math.radians(angle)
            R = R @ Rotation.from_rotvec(rotvec).as_matrix()
        return R

    def pose_from_axes(self, mpos: dict[str, float]) -> np.ndarray:
        """``T_base_flange`` (4x4, metres) from machine positions (mm, degrees)."""
        T = np.eye(4)
        for i, letter in enumerate(self.linear_axes):
            T[i, 3] = self.origin_m[i] + self.linear_signs[i] * mpos[letter] / 1000.0
        T[:3, :3] = self._rotation([mpos[letter] for _, letter in self.rotary_axes])
        return T

    def axes_from_pose(
        self, T_base_flange: np.ndarray, *, current: dict[str, float], tol_rad: float = 1e-5
    ) -> tuple[dict[str, float], tuple[str, ...]]:
        """Machine targets (mm, degrees) of the reachable part of a pose.

        Returns
        -------
        targets : dict letter -> value
        unreachable : tuple of str
            Flange rotation axes (``rx``, ``ry``, ``rz``, in the flange frame of
            the commanded pose) left with a residual above ``tol_rad``.
        """
        T = np.asarray(T_base_flange, dtype=float)
        targets = {}
        for i, letter in enumerate(self.linear_axes):
            targets[letter] = (T[i, 3] - self.origin_m[i]) * 1000.0 / self.linear_signs[i]
        R_target = T[:3, :3]
        if self.rotary_axes:
            start = np.array([current[letter] for _, letter in self.rotary_axes], dtype=float)

            def residual(angles):
                return Rotation.from_matrix(self._rotation(angles).T @ R_target).as_rotvec()

            # A stack of 1 or 2 rotary axes has no closed form for the nearest
            # reachable orientation; a tiny least-squares problem gives it.
            solution = least_squares(residual, start, x_scale=10.0, xtol=1e-12, ftol=1e-12)
            angles = solution.x
            for (_, letter), angle in zip(self.rotary_axes, angles):
                targets[letter] = float(angle)
        else:
            angles = []
        left = Rotation.from_matrix(self._rotation(angles).T @ R_target).as_rotvec()
        unreachable = tuple(axis for axis, v in zip(("rx", "ry", "rz"), left) if abs(v) > tol_rad)
        return targets, unreachable
