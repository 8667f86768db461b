"""The decision made again under a kept null (:mod:`fgcd_cli.changes.rescan`), on synthetic score maps."""

import numpy as np
import pytest
from scipy import ndimage

from fgcd_cli.changes.config import RegionConfig
from fgcd_cli.changes.region_decision import two_scale_decision
from fgcd_cli.changes.rescan import seeds_under_nulls
from fgcd_cli.changes.significance import AcontrarioConfig, acontrario_decision


def _scores(seed: int):
    """Smoothed half-normal noise (median ~1) with three discs of +6, +4 and +1.5 (the last below the
    decision's reach), at the detector's two smoothings (2 px and 1 px)."""
    rng = np.random.default_rng(seed)
    raw = np.abs(rng.standard_normal((400, 400))) / 0.6745
    yy, xx = np.mgrid[0:400, 0:400]
    discs = [((70, 60), 9, 6.0), ((210, 180), 8, 4.0), ((150, 300), 5, 1.5)]
    for (x, y), r, add in discs:
        raw[(yy - y) ** 2 + (xx - x) ** 2 <= r * r] += add
    coarse = ndimage.gaussian_filter(raw, 2.0)
    fine = ndimage.gaussian_filter(raw, 1.0)
    return (coarse / np.median(coarse)).astype(np.float32), (fine / np.median(fine)).astype(np.float32)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_same_maps_under_their_own_nulls_give_the_decisions_seeds(seed):
    coarse, fine = _scores(seed)
    valid = np.ones(coarse.shape, bool)
    decision = two_scale_decision(
        coarse, valid, config=RegionConfig(), smooth_sigma_px=2.0, fine_score=fine, fine_sigma_px=1.0
    )
    assert len(decision.nulls) == 2 and len(decision.regions) >= 1
    seeds = seeds_under_nulls([coarse, fine], valid, decision.nulls, within=valid)
    np.testing.assert_array_equal(seeds, decision.seed_index > 0)


def test_only_the_components_that_reach_the_asked_pixels_are_scanned():
    coarse, _ = _scores(0)
    valid = np.ones(coarse.shape, bool)
    decision = acontrario_decision(coarse, valid, min_cluster_area_px=4 * np.pi * 4)
    everywhere = seeds_under_nulls([coarse], valid, decision.nulls, within=valid)
    np.testing.assert_array_equal(everywhere, decision.seed_index > 0)
    asked = np.zeros(valid.shape, bool)
    asked[300:320, 140:160] = True  # the sub-threshold disc, nowhere near the strong one
    assert not seeds_under_nulls([coarse], valid, decision.nulls, within=asked).any()
    asked[55:66, 65:76] = True  # and inside the strong disc
    np.testing.assert_array_equal(seeds_under_nulls([coarse], valid, decision.nulls, within=asked), everywhere)


def test_evidence_taken_away_leaves_no_seed_under_the_pairs_null():
    coarse, _ = _scores(1)
    valid = np.ones(coarse.shape, bool)
    decision = acontrario_decision(coarse, valid, min_cluster_area_px=4 * np.pi * 4)
    region = ndimage.binary_dilation(decision.mask, iterations=3) & (
        np.hypot(*np.mgrid[0:400, 0:400] - np.array([60, 70])[:, None, None]) < 20
    )
    assert region.any()
    flattened = coarse.copy()
    flattened[region] = np.float32(np.median(coarse))  # the evidence there is gone
    assert not seeds_under_nulls([flattened], valid, decision.nulls, within=region).any()


def test_maps_and_nulls_must_pair_up():
    coarse, fine = _scores(0)
    valid = np.ones(coarse.shape, bool)
    decision = acontrario_decision(coarse, valid)
    with pytest.raises(ValueError, match="2 score maps for 1 kept nulls"):
        seeds_under_nulls([coarse, fine], valid, decision.nulls, within=valid)


def test_a_decision_keeps_the_null_it_decided_under():
    coarse, _ = _scores(2)
    valid = np.ones(coarse.shape, bool)
    decision = acontrario_decision(coarse, valid, min_cluster_area_px=4 * np.pi * 4)
    (null,) = decision.nulls
    assert null.area == decision.cluster_area_px and null.n_tests == decision.n_tests
    assert null.levels[0] == pytest.approx(-np.log(0.005)) and np.all(np.diff(null.sorted_background) >= 0)
    assert null.epsilon == AcontrarioConfig().epsilon
