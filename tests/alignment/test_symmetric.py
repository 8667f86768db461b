"""The two-way scale (fgcd_cli.alignment.symmetric) against synthetic ground truth.

Two noisy samplings of the same relief (the reference the whole panel, the current a
part of it), related by a known similarity: a one-way alignment's scale comes out low,
the two-way one closer to the truth.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from fgcd_cli.alignment.fast import fast_align
from fgcd_cli.alignment.fast_config import FastAlignConfig, ScaleStepConfig
from fgcd_cli.alignment.reference import ReferenceIndex
from fgcd_cli.alignment.symmetric import symmetric_scale
from fgcd_cli.alignment.synthetic import ReliefScene
from fgcd_core.se3 import exp_se3
from fgcd_core.sim3 import Sim3

#: Depth noise of both clouds (m), as a VSE's roughness on the simulated relief panel (2.4-2.7 mm).
NOISE_M = 0.003


def _pair(seed: int):
    """Reference cloud, current cloud (current frame) and the true ``T_ref_cur`` (scale 1.02)."""
    rng = np.random.default_rng(seed)
    scene = ReliefScene(seed=seed)
    ref, _, _ = scene.sample(40000, rng=rng)
    cur, _, _ = scene.sample(15000, rng=rng, xlim=(-0.15, 0.2), ylim=(-0.2, 0.1))
    ref[:, 2] += rng.normal(size=len(ref)) * NOISE_M
    cur[:, 2] += rng.normal(size=len(cur)) * NOISE_M
    T = exp_se3(np.array([0.01, -0.02, 0.005, 0.02, -0.01, 0.03]))
    truth = Sim3(T[:3, :3], T[:3, 3], 1.02)
    return ReferenceIndex(ref), truth.inverse().apply(cur), truth


@pytest.mark.parametrize("seed", [0, 2])
def test_two_way_scale_is_closer_to_the_truth_than_one_way(seed):
    # Seeds 0 and 2 shrink the one-way scale by 0.65 % and 0.28 % (measured); the two-way scale
    # landed within 0.15 % of the truth on 4 of 4 seeds (docs/lab/2026-12-07-symmetric-scale.md).
    ref, cur, truth = _pair(seed)
    init = Sim3(truth.R, truth.t, truth.scale * 1.01)
    one_way = fast_align(cur, ref, init=init, config=FastAlignConfig(scale=ScaleStepConfig(symmetric=False)))
    two_way = fast_align(cur, ref, init=init, config=FastAlignConfig(scale=ScaleStepConfig(symmetric=True)))
    assert one_way.health.ok and two_way.health.ok
    err_one = abs(math.log(one_way.T_ref_cur.scale / truth.scale))
    err_two = abs(math.log(two_way.T_ref_cur.scale / truth.scale))
    assert one_way.T_ref_cur.scale < truth.scale  # the shrink this corrects
    assert err_two < 0.6 * err_one
    assert err_two < 0.002
    # the points land closer too (mean distance to their true place)
    dist = [np.linalg.norm(r.T_ref_cur.apply(cur) - truth.apply(cur), axis=1).mean() for r in (one_way, two_way)]
    assert dist[1] < dist[0]


def test_forward_kept_when_the_reference_does_not_cover_the_current_cloud():
    # The current cloud 1 m beside the reference: no reference point near it, nothing to measure backwards.
    ref, cur, truth = _pair(0)
    forward = fast_align(cur, ref, init=truth, config=FastAlignConfig(scale=ScaleStepConfig(symmetric=False)))
    far = Sim3(truth.R, truth.t + np.array([1.0, 0.0, 0.0]), truth.scale)
    moved = replace(forward, T_ref_cur=far)
    assert symmetric_scale(cur, ref, moved, FastAlignConfig()) is moved
