"""The exploration pattern of a VSE session."""

import math

import numpy as np
import pytest

from fgcd_cli.geometry.se3 import rotation_angle_rad
from fgcd_cli.relocation.session import exploration_pattern


def _compose(motions):
    T = np.eye(4)
    stops = [T]
    for M in motions:
        T = T @ M
        stops.append(T)
    return stops


@pytest.mark.parametrize("legs", [3, 4, 6])
def test_pattern_returns_to_start_and_splitting_keeps_the_path(legs):
    one = _compose(exploration_pattern(translation_m=0.04, legs=legs))
    two = _compose(exploration_pattern(translation_m=0.04, legs=legs, stops_per_leg=2))
    assert len(two) == 2 * (len(one) - 1) + 1
    np.testing.assert_allclose(one[-1], np.eye(4), atol=1e-12)
    # every original waypoint is still visited, in order, with one stop half-way between
    for k, T in enumerate(one):
        np.testing.assert_allclose(two[2 * k], T, atol=1e-12)
    for k in range(len(one) - 1):
        mid = two[2 * k + 1]
        d_a = np.linalg.norm(mid[:3, 3] - one[k][:3, 3])
        d_b = np.linalg.norm(one[k + 1][:3, 3] - mid[:3, 3])
        assert d_a == pytest.approx(d_b, rel=0.05)


def test_pattern_has_translation_on_every_leg_and_small_tilts():
    for M in exploration_pattern(translation_m=0.04, legs=6):
        assert np.linalg.norm(M[:3, 3]) > 0.02  # a monocular engine needs translation
        assert rotation_angle_rad(M[:3, :3]) < math.radians(5)
