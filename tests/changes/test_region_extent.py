"""Regions keep the extent of the change: no gain halo, no smoothing tail."""

import cv2
import numpy as np
import pytest

from fgcd_cli.changes.config import DetectionConfig
from fgcd_cli.changes.detect import detect_changes
from fgcd_cli.changes.illumination import normalize_local_gain
from fgcd_cli.changes.regions import refine_to_local_peak
from fgcd_cli.metrics.change_scores import binary_scores

from .conftest import textured_scene


def _dark_spot_pair(radius: int = 10, level: float = 0.05):
    ref = textured_scene()
    truth = np.zeros(ref.shape, bool)
    cv2.circle(truth.view(np.uint8), (128, 128), radius, 1, -1)
    cur = ref.copy()
    cur[truth] = level  # a dark stain or hole: far below the surroundings
    # Both observations carry their own sensor noise: a noise-free pair has a zero median
    # score, against which every rounding difference (the gain's) is extreme.
    rng = np.random.default_rng(0)
    ref, cur = (np.clip(image + rng.normal(0.0, 0.002, image.shape), 0, 1).astype(np.float32) for image in (ref, cur))
    return ref, cur, truth


def test_weighted_gain_ignores_the_change():
    ref, cur, truth = _dark_spot_pair()
    ring = cv2.dilate(truth.astype(np.uint8), np.ones((21, 21), np.uint8)).astype(bool) & ~truth
    plain = normalize_local_gain(ref, cur, sigma_px=12.0)
    # The dark spot lowers the local mean of the current image: its unchanged
    # surroundings are brightened (the halo the weights remove).
    assert np.median(plain[ring] / ref[ring]) > 1.1
    suspect = cv2.dilate(truth.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    robust = normalize_local_gain(ref, cur, sigma_px=12.0, weight=(~suspect).astype(np.float32))
    assert abs(np.median(robust[ring] / ref[ring]) - 1.0) < 0.02


def test_weighted_gain_still_removes_a_smooth_light_ramp():
    ref = textured_scene()
    ramp = np.linspace(0.7, 1.2, ref.shape[1], dtype=np.float32)[None, :]
    cur = np.clip(ref * ramp, 0, 1)
    weight = np.ones(ref.shape, np.float32)
    weight[100:160, 100:160] = 0  # a large excluded block: filled from the wider window
    out = normalize_local_gain(ref, cur, sigma_px=12.0, weight=weight)
    inner = (slice(30, -30), slice(30, -30))
    assert np.median(np.abs(out[inner] - ref[inner])) < 0.01


@pytest.mark.parametrize("decision", ["acontrario", "hysteresis"])
def test_strong_change_region_matches_its_footprint(decision):
    ref, cur, truth = _dark_spot_pair()
    result = detect_changes([ref], [cur], config=DetectionConfig.from_options(register=False, decision=decision))
    scores = binary_scores(result.mask, truth)
    assert scores.recall > 0.9
    # The 10 px disc may come out up to 1.5 px wider in radius (the score is smoothed
    # with sigma = 2 px): precision above (10 / 11.5)^2 = 0.756.
    assert scores.precision > (10 / 11.5) ** 2, f"region {result.mask.sum()} px for a {truth.sum()} px change"
    if decision == "hysteresis":
        # Without the two fixes the same change comes out about twice too large.
        loose = detect_changes(
            [ref],
            [cur],
            config=DetectionConfig.from_options(
                register=False, decision=decision, robust_gain_rounds=0, edge_fraction=0.0
            ),
        )
        assert loose.mask.sum() > 1.5 * result.mask.sum()


def test_trimming_keeps_weak_regions_and_cuts_the_tail_of_strong_ones():
    score = np.ones((80, 160), np.float32)
    strong = np.zeros_like(score, bool)
    strong[30:50, 20:40] = True
    weak = np.zeros_like(score, bool)
    weak[30:50, 110:130] = True
    score[strong] = 100.0
    score[weak] = 4.0
    score = cv2.GaussianBlur(score, (0, 0), 2.0)
    mask = score > 2.0  # a low growth threshold: far out on the strong change's flank
    assert mask[:, :80].sum() > 1.5 * strong.sum()
    trimmed = refine_to_local_peak(mask, score, background=1.0, fraction=0.2, radius_px=6)
    # At 20 % of a sigma-2 step's plateau the border lies 0.84 sigma = 1.7 px outside:
    # the trimmed region covers the change and stays within 2 px of it.
    near = lambda m, r: cv2.dilate(m.astype(np.uint8), np.ones((2 * r + 1, 2 * r + 1), np.uint8)).astype(bool)  # noqa: E731
    assert (trimmed & strong).sum() == strong.sum()
    assert not (trimmed[:, :80] & ~near(strong, 2)[:, :80]).any()
    assert (mask[:, :80] & ~near(strong, 3)[:, :80]).any()
    np.testing.assert_array_equal(trimmed[:, 80:], mask[:, 80:])
    np.testing.assert_array_equal(refine_to_local_peak(mask, score, background=1.0, fraction=0.0), mask)
