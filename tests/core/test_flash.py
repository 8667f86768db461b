"""The lamp's own image from a lit and an unlit still, against synthetic linear light."""

import numpy as np
import pytest

from fgcd_core.flash import CAMERA_RESPONSE_GAMMA, lamp_only_image

GAMMA = CAMERA_RESPONSE_GAMMA


def _still(linear: np.ndarray) -> np.ndarray:
    """An 8-bit still of linear light (clipped at 1, gamma-encoded, rounded)."""
    return np.round(np.clip(linear, 0, 1) ** (1 / GAMMA) * 255) / 255


@pytest.fixture(scope="module")
def lamp_and_days():
    rng = np.random.default_rng(0)
    albedo = rng.uniform(0.3, 0.9, (120, 160))
    lamp = 0.15 * albedo  # the lamp at the lens: the albedo, the same on every visit
    yy, xx = np.mgrid[0:120, 0:160]
    # two days: a low sun from the left, then from the right (shading that swaps sides)
    morning = 0.5 * albedo * (0.4 + 0.6 * xx / 159)
    evening = 0.5 * albedo * (1.0 - 0.6 * xx / 159)
    return lamp, morning, evening


def test_recovers_the_lamp_whatever_the_day(lamp_and_days):
    lamp, morning, evening = lamp_and_days
    got = [lamp_only_image(_still(day + lamp), _still(day)) for day in (morning, evening)]
    for g in got:
        recovered = g.image.astype(np.float64) ** GAMMA
        ratio = recovered / lamp
        # 8-bit rounding of both stills: at most 2 x 0.5/255 encoded, i.e. a linear error of
        # gamma * v**(gamma - 1) * 1/255 with v <= 0.9: about 0.0075 of 0.045..0.135 of lamp
        assert np.median(np.abs(ratio / np.median(ratio) - 1)) < 0.05
        assert g.clipped_fraction == 0.0
    # the two days' lamp images agree to the rounding; the days themselves differ (linear) by up to 60 %
    a, b = (g.image.astype(np.float64) ** GAMMA for g in got)
    assert np.median(np.abs(a / b - 1)) < 0.05
    assert np.median(np.abs((_still(morning) / _still(evening)) ** GAMMA - 1)) > 0.3


def test_states_the_lamps_share_and_clipped_pixels(lamp_and_days):
    lamp, morning, _ = lamp_and_days
    lit = morning + lamp
    lit[:10] = 2.0  # a clipped band: no lamp value known there
    got = lamp_only_image(_still(lit), _still(morning))
    expected_share = np.median((lamp / (morning + lamp))[10:])
    assert abs(got.lamp_share - expected_share) < 0.02
    assert abs(got.clipped_fraction - 10 / 120) < 1e-9
    assert np.all(got.image[:10] == 0)
    assert got.image.max() <= 1.0


def test_colour_stills_and_refusals(lamp_and_days):
    lamp, morning, _ = lamp_and_days
    colour = lambda im: np.stack([im, 0.8 * im, 0.6 * im], axis=2)  # noqa: E731
    got = lamp_only_image(_still(colour(morning + lamp)), _still(colour(morning)))
    assert got.image.shape == (120, 160, 3)
    with pytest.raises(ValueError, match="adds no light"):
        lamp_only_image(_still(morning), _still(morning))
    with pytest.raises(ValueError, match="one shape"):
        lamp_only_image(np.zeros((4, 4)), np.zeros((4, 5)))
