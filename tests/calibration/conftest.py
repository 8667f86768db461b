"""Synthetic hand-eye data with a known X and map scale s."""

from __future__ import annotations

import numpy as np
import pytest

from fgcd_core.se3 import exp_se3, exp_so3, invert_pose, make_pose


def _perturb(T: np.ndarray, rng: np.random.Generator, sigma_m: float, sigma_rad: float) -> np.ndarray:
    if sigma_m == 0 and sigma_rad == 0:
        return T.copy()
    delta = make_pose(exp_so3(rng.normal(0, sigma_rad, 3)), rng.normal(0, sigma_m, 3))
    return T @ delta


def make_handeye_data(
    *,
    seed: int = 0,
    n: int = 12,
    rot_deg: float = 12.0,
    trans_m: float = 0.04,
    scale: float = 0.37,
    flange_noise_m: float = 0.0,
    flange_noise_rad: float = 0.0,
    cam_noise_m: float = 0.0,
    cam_noise_rad: float = 0.0,
    axes: np.ndarray | None = None,
):
    """Flange poses, VSE camera poses (map units), board poses and the truth.

    Returns a dict with T_base_flange (reported, noisy), T_map_cam (VSE units),
    T_cam_target (board in camera), X (true T_flange_cam), scale (metres per map unit).
    """
    rng = np.random.default_rng(seed)
    X = make_pose(exp_so3(rng.normal(0, 1.0, 3)), rng.uniform(-0.08, 0.08, 3))
    T_base_map = exp_se3(np.concatenate([rng.uniform(-0.5, 0.5, 3), rng.normal(0, 1.0, 3)]))
    T_base_target = exp_se3(np.concatenate([[0.2, 0.1, 0.9], rng.normal(0, 0.3, 3)]))
    T0 = make_pose(exp_so3([np.pi, 0, 0]), [0.3, 0.0, 0.4])
    hand_true, hand_reported, cams, boards = [], [], [], []
    for k in range(n):
        if axes is None:
            axis = rng.normal(size=3)
        else:
            axis = np.asarray(axes[k % len(axes)], dtype=float)
        axis = axis / np.linalg.norm(axis)
        angle = np.deg2rad(rot_deg) * rng.uniform(0.4, 1.0) if k else 0.0
        delta = make_pose(exp_so3(axis * angle), rng.uniform(-trans_m, trans_m, 3) if k else np.zeros(3))
        T_true = T0 @ delta
        hand_true.append(T_true)
        hand_reported.append(_perturb(T_true, rng, flange_noise_m, flange_noise_rad))
        T_base_cam = T_true @ X
        T_map_cam_metric = invert_pose(T_base_map) @ T_base_cam
        T_map_cam_metric = _perturb(T_map_cam_metric, rng, cam_noise_m, cam_noise_rad)
        T_vse = T_map_cam_metric.copy()
        T_vse[:3, 3] /= scale
        cams.append(T_vse)
        boards.append(_perturb(invert_pose(T_base_cam) @ T_base_target, rng, cam_noise_m, cam_noise_rad))
    return {
        "T_base_flange": hand_reported,
        "T_base_flange_true": hand_true,
        "T_map_cam": cams,
        "T_cam_target": boards,
        "X": X,
        "scale": scale,
    }


@pytest.fixture
def handeye_data():
    """Factory of synthetic hand-eye samples with a known X and s."""
    return make_handeye_data
