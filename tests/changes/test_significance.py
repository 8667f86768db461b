"""The a-contrario decision on synthetic score maps with known changes (scikit-image style ground truth)."""

import numpy as np
import pytest
from scipy import ndimage

from fgcd_cli.changes.marginal import empirical_neglog_survival, halfnormal_neglog_survival
from fgcd_cli.changes.significance import acontrario_decision


def _background(shape=(300, 300), *, seed=0, sigma=2.0):
    """Half-normal noise with median ~1, smoothed like the detector's fused score."""
    rng = np.random.default_rng(seed)
    noise = np.abs(rng.standard_normal(shape)) / 0.6745
    smooth = ndimage.gaussian_filter(noise, sigma)
    return (smooth / np.median(smooth)).astype(np.float32)


def _disc(shape, centre, radius):
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
    return (yy - centre[1]) ** 2 + (xx - centre[0]) ** 2 <= radius**2


def _strong_and_medium_change():
    """A strong (+6) and a weaker (+3) disc on smoothed noise, and the decision on them."""
    score = _background(seed=3)
    strong = _disc(score.shape, (80, 80), 10)
    medium = _disc(score.shape, (200, 220), 7)
    score[strong] += 6.0
    score[medium] += 3.0
    score = ndimage.gaussian_filter(score, 1.0)
    return strong, medium, acontrario_decision(score, np.ones(score.shape, bool), min_cluster_area_px=4 * np.pi * 4)


def test_pure_noise_gives_no_region_in_most_images():
    # epsilon = 1 means at most ~1 false region expected per image under the model;
    # over 10 noise images the model is conservative (half-normal floor), so nearly none.
    found = [
        len(
            acontrario_decision(
                _background(seed=s), np.ones((300, 300), bool), min_cluster_area_px=4 * np.pi * 4
            ).regions
        )
        for s in range(10)
    ]
    assert sum(found) <= 2


def test_compact_changes_are_found_with_their_extent_and_weak_ones_stay_candidates():
    strong, medium, decision = _strong_and_medium_change()
    assert len(decision.regions) >= 1
    assert all(r.log10_nfa < 0 for r in decision.regions)
    overlap = (decision.mask & strong).sum() / strong.sum()
    assert overlap > 0.6  # the extent covers most of the strong change ...
    spill = (decision.mask & ~ndimage.binary_dilation(strong | medium, iterations=4)).sum()
    assert spill < 0.2 * (strong | medium).sum()  # ... and does not spill far beyond it
    if decision.candidates:
        assert min(c.log10_nfa for c in decision.candidates) >= max(r.log10_nfa for r in decision.regions)


@pytest.mark.xfail(
    strict=True,
    reason="known weakness (issue 19): the seed level is an empirical quantile, so a strong "
    "change covering most of the top seed_p pixels pushes a weaker one below it",
)
def test_a_weaker_change_beside_a_strong_one_is_at_least_a_candidate():
    strong, medium, decision = _strong_and_medium_change()
    found_medium = (decision.mask & medium).any()
    first = decision.candidates[0] if decision.candidates else None
    assert found_medium or (
        first is not None and medium[int(round(first.centroid_xy[1])), int(round(first.centroid_xy[0]))]
    )
    # Every candidate left over is less significant than every reported region.
    if decision.candidates:
        assert min(c.log10_nfa for c in decision.candidates) >= max(r.log10_nfa for r in decision.regions)


@pytest.mark.xfail(
    strict=True,
    reason="known weakness (issue 19): dozens of similar changes inflate the empirical "
    "null's tail and the cluster area; the a-contrario rule is not the default decision yet",
)
def test_many_similar_small_changes_are_not_hidden_by_each_other():
    # Dozens of pits of similar strength: an empirical null alone would call each one
    # "common"; clustering of exceedances at the independent-sample scale keeps them.
    score = _background(seed=5, shape=(400, 400))
    truth = np.zeros(score.shape, bool)
    rng = np.random.default_rng(1)
    for _ in range(30):
        truth |= _disc(score.shape, tuple(rng.integers(20, 380, 2)), 4)
    score[truth] += 5.0
    decision = acontrario_decision(score, np.ones(score.shape, bool), min_cluster_area_px=4 * np.pi * 4)
    labels, count = ndimage.label(truth)
    hit = len(set(np.unique(labels[decision.mask])) - {0})
    assert hit >= 0.8 * count


def test_survival_functions():
    score = np.arange(100, dtype=np.float32).reshape(10, 10)
    neglogp = empirical_neglog_survival(score, np.ones_like(score, bool))
    assert neglogp[0, 0] == pytest.approx(0.0, abs=0.01)
    assert neglogp[9, 9] == pytest.approx(-np.log(1.5 / 100), rel=1e-3)  # (n - rank + 0.5) / n, rank 99 of 100
    # Half-normal with median 1: P(S >= 1) = 0.5.
    assert float(halfnormal_neglog_survival(np.array([1.0]))[0]) == pytest.approx(np.log(2.0), rel=1e-3)


def test_level_components_are_the_whole_frame_components_of_every_level():
    # The scan labels each level inside the lowest level's components; the rounds reuse that list.
    # It must hold exactly the 8-connected components of labelling the whole frame at each level.
    from fgcd_cli.changes.significance import level_components

    score = _background(seed=5)
    score[_disc(score.shape, (150, 150), 12)] += 4.0
    neglogp = score.astype(np.float32)
    valid = np.ones(score.shape, bool)
    valid[:, :20] = False
    levels = np.quantile(neglogp[valid], [0.95, 0.98, 0.995]).astype(np.float64)
    per_level = level_components(neglogp, valid, levels)
    for lam, components in zip(levels, per_level):
        labels, count = ndimage.label((neglogp >= lam) & valid, structure=np.ones((3, 3), bool))
        expected = sorted(np.bincount(labels.ravel())[1:].tolist())
        assert sorted(int(c[0]) for c in components) == expected
        rebuilt = np.zeros(score.shape, bool)
        for _, _, window, pixels in components:
            rebuilt[window] |= pixels
        assert np.array_equal(rebuilt, labels > 0)
        assert len(components) == count > 0
