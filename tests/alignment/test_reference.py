"""ReferenceIndex: statistics and the density filter for stray points."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from fgcd_cli.alignment.reference import ReferenceIndex
from fgcd_cli.alignment.synthetic import ReliefScene


def test_density_filter_drops_sparse_strays_and_keeps_the_surface():
    rng = np.random.default_rng(0)
    scene = ReliefScene(seed=1)
    surface, _, _ = scene.sample(20000, rng=rng)
    # 20 % stray points spread through the volume in front of the relief (non-repeated points).
    strays = rng.uniform([-0.25, -0.25, -0.15], [0.25, 0.25, 0.05], size=(5000, 3))
    ref = ReferenceIndex(np.vstack([surface, strays]))
    kept_surface = ref.kept[:20000].mean()
    # Strays within a few 8th-neighbour distances (~6 mm) of the surface borrow its density
    # and may stay (they are nearly repeated points); those 2 cm or more away must go.
    far = cKDTree(surface).query(strays)[0] > 0.02
    assert kept_surface > 0.98
    assert ref.kept[20000:][far].mean() < 0.05
    # The robust width is the relief's side (0.5 m), not inflated by strays.
    assert abs(ref.width - 0.5) < 0.03


def test_clean_cloud_is_kept_whole_and_statistics_match():
    rng = np.random.default_rng(1)
    pts = rng.uniform(-0.5, 0.5, size=(20000, 3)) * [1.0, 1.0, 0.0]
    ref = ReferenceIndex(pts)
    assert ref.kept.mean() > 0.99
    # Uniform square of side 1 m: RMS radius sqrt(2/12), width ~ 0.98 (1st-99th percentile).
    assert abs(ref.rms_radius - np.sqrt(2 / 12)) < 0.01
    assert abs(ref.width - 0.98) < 0.02
    # Mean nearest-neighbour spacing of a Poisson process of density n: 0.5/sqrt(n); median a bit less.
    assert 0.3 / np.sqrt(20000) < ref.spacing < 0.5 / np.sqrt(20000)
