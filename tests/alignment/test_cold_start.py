"""Cold starts with large scale errors on thick (non-repeated-point) references, and the
scale-minimum self-check that flags a stalled scale.

The scene is the benchmark's noise study in small: half of the reference points are
displaced by N(0, r x width), which makes the inlier ratio useless as a judge of the scale.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fgcd_cli.alignment.cold_start import scale_neighbour
from fgcd_cli.alignment.fast import fast_align
from fgcd_cli.alignment.fast_config import FastAlignConfig
from fgcd_cli.alignment.icp_levels import LevelInputs
from fgcd_cli.alignment.reference import ReferenceIndex
from fgcd_cli.alignment.synthetic import ReliefScene
from fgcd_core.se3 import exp_se3
from fgcd_core.sim3 import Sim3

WIDTH = 0.6
NOISE = 0.002  # current-cloud noise per axis, metres


@pytest.fixture(scope="module")
def study():
    rng = np.random.default_rng(21)
    scene = ReliefScene(seed=3, width=WIDTH, amplitude=0.04)
    pts, _, _ = scene.sample(40000, rng=rng)
    moved = rng.random(len(pts)) < 0.5
    pts[moved] += rng.normal(0.0, 0.04 * WIDTH, (int(moved.sum()), 3))  # r = 4 %
    ref = ReferenceIndex(pts)
    p, _, _ = scene.sample(8000, rng=rng, xlim=(-0.27, 0.2), ylim=(-0.22, 0.27))
    p += rng.normal(0.0, NOISE, p.shape)
    T_true = Sim3(exp_se3(np.array([0.3, -0.2, 0.5, 0.4, -1.0, 2.0]))[:3, :3], np.array([0.3, -0.2, 0.5]), 1.05)
    return ref, p, T_true


def _errors(T_est: Sim3, T_true: Sim3, p_ref: np.ndarray):
    E = T_est @ T_true.inverse()
    point_mm = float(np.mean(np.linalg.norm(E.apply(p_ref) - p_ref, axis=1)) * 1e3)
    return E.rotation_deg(), point_mm, abs(E.scale - 1.0)


def _perturbed(T_true: Sim3, *, rot_deg: float, shift_m, scale: float) -> Sim3:
    """``pert @ T_true`` with the perturbation given in the reference frame (about the origin)."""
    axis = np.array([0.3, 0.8, -0.5]) / np.linalg.norm([0.3, 0.8, -0.5])
    R = exp_se3(np.concatenate([np.zeros(3), np.radians(rot_deg) * axis]))[:3, :3]
    return Sim3(R, np.asarray(shift_m, dtype=float), scale) @ T_true


# Success limits of the benchmark (1 deg, 20 mm, 2 %) are far above what a converged
# alignment reaches here: 2 mm noise over ~8000 points and a reference whose surface
# half is exact leave ~0.1 deg / ~1 mm / ~0.3 %. The limits below leave 3x margin.
@pytest.mark.parametrize(
    "rot_deg, shift_m, scale",
    [
        (10.0, (0.10, -0.08, 0.02), 0.80),  # cold: 20 % scale error with a 13 cm slide along the relief
        (8.0, (0.0, 0.0, 0.0), 1.18),  # looks warm (flat relief): the warm run must hand over to a cold start
    ],
)
def test_large_scale_error_on_thick_reference(study, rot_deg, shift_m, scale):
    ref, p_ref, T_true = study
    cur = T_true.inverse().apply(p_ref)
    init = _perturbed(T_true, rot_deg=rot_deg, shift_m=shift_m, scale=scale)
    result = fast_align(cur, ref, init=init)
    rot, point_mm, scale_err = _errors(result.T_ref_cur, T_true, p_ref)
    assert rot < 0.3
    assert point_mm < 3.0
    assert scale_err < 0.01
    assert result.health.ok, result.health.reason


def test_scale_neighbour_finds_a_better_scale_only_off_the_minimum(study):
    ref, p_ref, T_true = study
    cur = T_true.inverse().apply(p_ref)
    config = FastAlignConfig()
    order = np.random.default_rng(0).permutation(len(cur))
    probe = cur[order[:1000]]
    inputs = LevelInputs(cur=cur, weights=None, ref=ref, order=order)
    better, _ = scale_neighbour(inputs, T_true, probe, config)
    assert better is None  # at the truth no neighbour fits clearly better
    c = T_true.apply(cur.mean(axis=0))
    off = Sim3(np.eye(3), c - 0.93 * c, 0.93) @ T_true  # 7 % too small, about the cloud's centre
    better, _ = scale_neighbour(inputs, off, probe, config)
    assert better is not None
    assert better.scale / off.scale == pytest.approx(1 + config.minimum_check.step)


def test_stalled_scale_is_flagged_although_every_point_is_an_inlier(study):
    ref, p_ref, T_true = study
    cur = T_true.inverse().apply(p_ref)
    # A cold start (12 cm off along the normal) whose scale cannot move: no search, no drift.
    # It ends 8 % off in scale; on this thick reference the inlier ratio stays near 1.
    base = FastAlignConfig()
    stuck = replace(
        base, cold=replace(base.cold, scale_candidates=(1.0,), shift_steps=0), scale=replace(base.scale, max_drift=0.0)
    )
    init = _perturbed(T_true, rot_deg=2.0, shift_m=T_true.R @ np.array([0.0, 0.0, 0.12]), scale=0.92)
    result = fast_align(cur, ref, init=init, config=stuck)
    assert abs(result.T_ref_cur.scale / T_true.scale - 1) > 0.02  # really wrong
    assert result.health.inlier_ratio >= stuck.health.min_inlier_ratio  # the inlier check alone would pass it
    assert not result.health.ok
    assert "residual minimum" in result.health.reason


# A warm start whose joint iteration stalls at a wrong scale. The stall is forced by bounding the
# run's scale drift (2.5 %), the way a warm run on a VSE cloud stopped after moving the scale
# 1.7-4.5 % (docs/alignment.md): it starts 8 % too small, moves 2.5 % and stops ~5.5 % off.
STALL = dict(scale=replace(FastAlignConfig().scale, max_drift=0.025))


def test_warm_run_that_stalls_at_a_wrong_scale_is_redone_cold(study):
    ref, p_ref, T_true = study
    cur = T_true.inverse().apply(p_ref)
    init = _perturbed(T_true, rot_deg=1.0, shift_m=(0.0, 0.0, 0.0), scale=0.92)
    unchecked = replace(
        FastAlignConfig(), warm=replace(FastAlignConfig().warm, check_scale_change=1.0, max_scale_change=1.0), **STALL
    )
    stalled = fast_align(cur, ref, init=init, config=unchecked)
    assert stalled.start == "warm"  # the case: it looks warm...
    assert abs(stalled.T_ref_cur.scale / T_true.scale - 1) > 0.03  # ...stalls well off in scale...
    assert stalled.health.ok  # ...and nothing else flags it (thick reference: inlier ratio ~1)
    result = fast_align(cur, ref, init=init, config=replace(FastAlignConfig(), **STALL))
    assert result.start == "warm -> cold"
    rot, point_mm, scale_err = _errors(result.T_ref_cur, T_true, p_ref)
    assert rot < 0.3  # same limits as the cold starts above
    assert point_mm < 3.0
    assert scale_err < 0.01
    assert result.health.ok, result.health.reason


def test_ordinary_warm_start_runs_no_extra_check(study):
    ref, p_ref, T_true = study
    cur = T_true.inverse().apply(p_ref)
    # The relocation loop's steady state: the previous result, ~1 % and 0.5 deg off.
    init = _perturbed(T_true, rot_deg=0.5, shift_m=(0.003, -0.002, 0.001), scale=1.01)
    result = fast_align(cur, ref, init=init)
    assert result.start == "warm"
    rot, point_mm, scale_err = _errors(result.T_ref_cur, T_true, p_ref)
    assert rot < 0.3 and point_mm < 3.0 and scale_err < 0.01
    assert result.health.ok, result.health.reason
