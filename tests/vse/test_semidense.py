"""Semi-dense depths: per-keyframe depth on a rendered relief, cross-keyframe fusion against synthetic ground
truth."""

from __future__ import annotations

import numpy as np
import pytest

from fgcd_cli.vse.semidense import KeyframeDepthConfig, fuse_across_keyframes, keyframe_depth
from fgcd_core.se3 import make_pose

K = np.array([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]])
Z = 1.5  # fronto-parallel plane: the true inverse depth is 1/Z in both (parallel) cameras


def _case(rng, n=4000, baseline_m=0.03):
    """Reference pixels and the other keyframe's pixels of the same plane points (shifted < 0.5 px)."""
    # one pixel per 3x3 cell as the semi-dense selection does: no other point within 0.75 px but the partner
    gu, gv = np.meshgrid(np.arange(20, 620, 3.0), np.arange(20, 460, 3.0))
    px = np.column_stack([gu.ravel(), gv.ravel()])[rng.choice(gu.size, n, replace=False)]
    T_ref_other = make_pose(np.eye(3), np.array([baseline_m, 0.0, 0.0]))  # other camera 3 cm to the right
    # a reference pixel seen from the other camera, moved by a sub-pixel offset (the other keyframe's own grid)
    shift = rng.uniform(-0.3, 0.3, (n, 2))
    opx = px - np.array([K[0, 0] * baseline_m / Z, 0.0]) + shift
    return px, opx, T_ref_other


def test_fusion_of_two_keyframes_halves_the_variance():
    rng = np.random.default_rng(0)
    px, opx, T = _case(rng)
    n = len(px)
    sig = np.full(n, 0.01 / Z)  # 1 % of depth, in inverse depth
    rho = 1 / Z + rng.normal(0, 1, n) * sig
    orho = 1 / Z + rng.normal(0, 1, n) * sig
    fused, fsig, nf = fuse_across_keyframes(K, (px, rho, sig), [(opx, orho, sig, T)])
    # every point has its partner within 0.3*sqrt(2) < 0.75 px; the 2-sigma gate on the difference
    # (sigma*sqrt(2), the combined sigma) keeps P(|N(0,1)| <= 2) = 95.4 % of the pairs
    frac = nf.mean()
    assert abs(frac - 0.954) < 0.02
    on = nf == 1
    np.testing.assert_allclose(fsig[on], sig[on] / np.sqrt(2), rtol=1e-9)
    np.testing.assert_array_equal(fused[~on], rho[~on])
    # the fused error shrinks by sqrt(2); the gate trims the tails a little, so it is a bit smaller.
    # Standard error of an RMS over ~3800 points: 1/sqrt(2*3800) = 1.1 %; 8 % tolerance.
    rms = np.sqrt(np.mean((fused[on] - 1 / Z) ** 2))
    assert 0.85 * sig[0] / np.sqrt(2) < rms < 1.08 * sig[0] / np.sqrt(2)


def test_fusion_weights_by_inverse_variance_and_rejects_outliers():
    rng = np.random.default_rng(1)
    px, opx, T = _case(rng, n=2000)
    n = len(px)
    sig = np.full(n, 0.004 / Z)
    osig = 2 * sig
    rho = np.full(n, 1 / Z)
    orho = np.full(n, 1 / Z + 0.5 * sig[0])  # small disagreement: within the gate
    bad = rng.random(n) < 0.2
    orho[bad] = 1 / Z * 1.2  # gross errors (20 % of depth) are never fused
    fused, fsig, nf = fuse_across_keyframes(K, (px, rho, sig), [(opx, orho, osig, T)])
    assert np.all(nf[bad] == 0) and np.all(nf[~bad] == 1)
    np.testing.assert_array_equal(fused[bad], rho[bad])
    # inverse-variance mean: weights 1 and 1/4 -> 1/Z + 0.5 sigma / 5
    np.testing.assert_allclose(fused[~bad], 1 / Z + 0.1 * sig[0], rtol=1e-12)
    np.testing.assert_allclose(fsig[~bad], sig[0] / np.sqrt(1.25), rtol=1e-12)


def test_points_without_a_partner_are_unchanged():
    rng = np.random.default_rng(2)
    px, opx, T = _case(rng, n=500)
    sig = np.full(len(px), 0.002)
    rho = np.full(len(px), 1 / Z)
    # the other keyframe's points are 2 px away from any reference projection
    fused, fsig, nf = fuse_across_keyframes(K, (px, rho, sig), [(opx + 2.0, rho.copy(), sig, T)])
    assert np.all(nf == 0)
    np.testing.assert_array_equal(fused, rho)
    np.testing.assert_array_equal(fsig, sig)
    # and nothing to fuse with at all
    f2, s2, n2 = fuse_across_keyframes(K, (px, rho, sig), [])
    np.testing.assert_array_equal(f2, rho)
    assert np.all(n2 == 0)


def test_keyframe_depth_takes_its_options_as_one_config(world, small_camera, helpers):
    T0, T1 = helpers.look_pose([0, 0, 0]), helpers.look_pose([0.012, 0.0, 0.0])
    i0, _ = world.render(small_camera, T0)
    i1, _ = world.render(small_camera, T1)
    nbs = [(i1, np.linalg.inv(T1) @ T0)]
    b = keyframe_depth(
        i0, nbs, small_camera.K, (1 / 0.8, 1 / 0.45), config=KeyframeDepthConfig(max_points=2000, min_views=1)
    )
    assert len(b.inv_depth) > 100 and len(b.pixels) <= 2000
    with pytest.raises(TypeError):
        keyframe_depth(i0, nbs, small_camera.K, (1 / 0.8, 1 / 0.45), max_points=2000)
