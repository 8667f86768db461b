"""The degeneracy check probes its weak directions: shallow relief pins a wall, a plane does not.

Synthetic ground truth: a wall with mortar joints (8 mm deep, the simulator's
brick wall) and the same wall without them, both with 2 mm of noise per axis
(VSE-like). Normals smoothed over centimetres see both as a plane; only the
perturbation test tells the joints pin the in-plane motion.
"""

from __future__ import annotations

import numpy as np

from fgcd_cli.alignment.fast import fast_align
from fgcd_cli.alignment.fast_config import FastAlignConfig, WeakProbeConfig
from fgcd_cli.alignment.reference import ReferenceIndex
from fgcd_cli.alignment.synthetic import look_at
from fgcd_core.camera import PinholeCamera
from fgcd_core.se3 import exp_se3
from fgcd_core.sim3 import Sim3

NOISE = 0.002  # m per axis, both clouds


def _wall(n: int, rng: np.random.Generator, *, joints: bool, xlim=(-0.5, 0.5), ylim=(-0.5, 0.5)) -> np.ndarray:
    """Points (n, 3) of the wall z = 0, with 12 mm wide, 8 mm deep joints every 75 mm / 230 mm if asked."""
    xy = np.column_stack([rng.uniform(*xlim, n), rng.uniform(*ylim, n)])
    z = np.zeros(n)
    if joints:
        bed = np.abs(((xy[:, 1] + 0.0375) % 0.075) - 0.0375) < 0.006
        head = np.abs(((xy[:, 0] + 0.115) % 0.23) - 0.115) < 0.006
        z = np.where(bed | head, 0.008, 0.0)
    return np.column_stack([xy, z]) + rng.normal(0.0, NOISE, (n, 3))


def _align_wall(joints: bool, config: FastAlignConfig = FastAlignConfig()):
    rng = np.random.default_rng(0)
    ref = ReferenceIndex(_wall(40000, rng, joints=joints))
    cur_in_ref = _wall(15000, rng, joints=joints, xlim=(-0.3, 0.25), ylim=(-0.25, 0.3))
    T_true = Sim3(exp_se3(np.r_[0.0, 0.0, 0.0, 0.1, -0.2, 0.05])[:3, :3], np.r_[0.05, -0.02, 0.6], 1.0)
    # Start 14 mm and 1 degree off within the wall's plane: along the weak directions.
    offset = exp_se3(np.r_[0.012, -0.008, 0.0, 0.0, 0.0, np.radians(1.0)])
    init = Sim3(offset[:3, :3], offset[:3, 3], 1.0) @ T_true
    result = fast_align(T_true.inverse().apply(cur_in_ref), ref, init=init, config=config)
    error = result.T_ref_cur @ T_true.inverse()
    rms_mm = float(np.sqrt(np.mean(np.sum((error.apply(cur_in_ref) - cur_in_ref) ** 2, axis=1)))) * 1e3
    return result, rms_mm


def test_mortar_joints_pin_a_wall_that_smoothed_normals_call_flat():
    result, rms_mm = _align_wall(joints=True)
    h = result.health
    # Smoothed normals alone call it degenerate...
    assert h.condition_ratio < FastAlignConfig().health.min_condition_ratio
    assert h.weak_directions
    # ...but every probed perturbation comes back, and the result is where the joints are.
    assert h.weak_probe and max(h.weak_probe) < FastAlignConfig().probe.return_fraction
    assert h.ok and not h.degenerate
    # The start was ~15 mm off (RMS over the points); the noise is 2 mm per axis over 15k points.
    assert rms_mm < 4.0


def test_a_plain_wall_stays_degenerate():
    result, rms_mm = _align_wall(joints=False)
    h = result.health
    assert h.degenerate and not h.ok
    assert h.weak_probe and max(h.weak_probe) > FastAlignConfig().probe.return_fraction
    assert "perturbations along them kept" in h.reason


def test_without_the_probe_the_joints_are_called_degenerate():
    result, _ = _align_wall(joints=True, config=FastAlignConfig(probe=WeakProbeConfig(enabled=False)))
    assert result.health.degenerate and result.health.weak_probe == ()


CAMERA = PinholeCamera(fx=500.0, fy=500.0, cx=319.5, cy=239.5, width=640, height=480)


def _rim_share(points: np.ndarray, T_ref_cam: np.ndarray, where: np.ndarray | None = None) -> float:
    """Share of the cloud's rim points (within ``where``) that count as view rim, not as outline.

    (Random sampling also puts a few per cent of interior points on the "rim"; ``where``
    restricts the count to the true edge.)
    """
    with_view = ReferenceIndex(points, view=(T_ref_cam, CAMERA), remove_outliers=False)
    without = ReferenceIndex(points, remove_outliers=False)
    rim = without.view_rim  # without a view every rim point counts
    if where is not None:
        rim &= where
    assert rim.sum() > 50
    return float(with_view.view_rim[rim].mean())


def test_view_rim_tells_an_outline_from_the_edge_of_the_view_and_a_limb():
    rng = np.random.default_rng(1)
    T_ref_cam = look_at(np.zeros(3), np.array([0.0, 0.0, 1.0]))
    # A disc facing the camera, well inside the image: its rim is the object's outline.
    r = 0.2 * np.sqrt(rng.uniform(0, 1, 20000))
    a = rng.uniform(0, 2 * np.pi, 20000)
    disc = np.column_stack([r * np.cos(a), r * np.sin(a), np.full(20000, 1.0)])
    assert _rim_share(disc, T_ref_cam) < 0.1
    # A wall cut by the image border: its rim is where the view ends.
    uv = rng.uniform([0, 0], [639, 479], (20000, 2))
    wall = np.column_stack([(uv[:, 0] - 319.5) / 500, (uv[:, 1] - 239.5) / 500, np.ones(20000)])
    near_border = np.min(np.column_stack([uv, [639, 479] - uv]), axis=1) < 15
    assert _rim_share(wall, T_ref_cam, near_border) > 0.9
    # The visible half of a ball: its rim is the limb, which moves with the viewpoint.
    v = rng.normal(size=(40000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    centre = np.array([0.0, 0.0, 1.5])
    ball = centre + 0.3 * v
    rays = ball / np.linalg.norm(ball, axis=1, keepdims=True)
    facing = np.sum(v * rays, axis=1)
    visible = facing < 0  # the camera is at the origin
    near_limb = facing[visible] > -0.3
    assert _rim_share(ball[visible], T_ref_cam, near_limb) > 0.8


def test_probe_reports_one_value_per_probed_direction():
    result, _ = _align_wall(joints=True)
    assert len(result.health.weak_probe) == min(len(result.health.weak_directions), FastAlignConfig().probe.directions)
