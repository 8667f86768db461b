"""The decision at two smoothings of one score: small changes are found, unchanged pairs stay silent."""

import cv2
import numpy as np

from fgcd_cli.changes.config import DetectionConfig
from fgcd_cli.changes.detect import detect_changes
from fgcd_cli.metrics.change_scores import binary_scores

from .conftest import textured_scene

NOISE = 0.004  # sensor noise of each observation (the simulator's read noise is 0.003)


def _observed(image: np.ndarray, seed: int) -> np.ndarray:
    noisy = image + np.random.default_rng(seed).normal(0.0, NOISE, image.shape)
    return np.clip(noisy, 0, 1).astype(np.float32)


def _pair(size: int = 320):
    """A textured surface before and after: a large loss (a disc of 14 px radius turned to plaster)
    and four small stains (29 px discs at half their brightness). Returns reference, current, truth."""
    ref = textured_scene(size)
    cur = ref.copy()
    truth = np.zeros(ref.shape, np.uint8)
    for i, (x, y, radius) in enumerate([(80, 80, 14), (200, 90, 3), (230, 220, 3), (100, 240, 3), (260, 150, 3)]):
        disc = np.zeros(ref.shape, np.uint8)
        cv2.circle(disc, (x, y), radius, 1, -1)
        cur[disc > 0] = 0.95 if i == 0 else 0.5 * cur[disc > 0]
        truth |= disc
    return _observed(ref, 1), _observed(cur, 2), truth > 0


def _found(result, truth) -> int:
    n, labels = cv2.connectedComponents(truth.astype(np.uint8))
    return sum(bool((result.mask & (labels == i)).any()) for i in range(1, n))


def test_small_stains_beside_a_large_loss_are_found_at_the_finer_scale():
    # Each stain is smaller than the main smoothing's correlation area (4 pi 2^2 = 50 px):
    # one sample there, reported only if it is about the pair's most extreme one.
    ref, cur, truth = _pair()
    config = DetectionConfig.from_options(register=False, cues=False)
    with_fine = detect_changes([ref], [cur], config=config)
    main_only = detect_changes([ref], [cur], config=DetectionConfig.from_options(config, fine_smooth_sigma_px=0.0))
    assert _found(with_fine, truth) >= 4  # of 5
    assert _found(main_only, truth) <= 3  # negative control: the main scale alone misses stains here
    assert binary_scores(with_fine.mask, truth).precision > 0.7
    assert with_fine.settings["fine_smooth_sigma_px"] == 1.0
    # Every reported region carries its NFA, below epsilon = 1, counted over both maps.
    assert all(r.log10_nfa is not None and r.log10_nfa < 0 for r in with_fine.regions)


def test_unchanged_noisy_pairs_give_no_region_at_either_scale():
    for seed in range(3):
        ref = textured_scene(320)
        pair = [_observed(ref, 10 + seed)], [_observed(ref * 0.9 + 0.03, 20 + seed)]
        result = detect_changes(*pair, config=DetectionConfig.from_options(register=False))
        assert result.regions == []


def test_the_finer_scan_stays_on_beside_the_edge_check():
    # The edge check (every diff's default) sets aside bands a shift explains; it must not cost the
    # finer scan its small stains (the real test block Db-6's pits are found at that scale alone).
    ref, cur, truth = _pair()
    checked = detect_changes(
        [ref], [cur], config=DetectionConfig.from_options(register=False, cues=False, edge_check_px=2)
    )
    assert checked.settings["fine_smooth_sigma_px"] == 1.0 and checked.fine_score is not None
    assert _found(checked, truth) >= 4  # of 5, as without the edge check


def test_a_decision_made_again_with_the_same_constants_is_the_detections():
    from fgcd_cli.changes.region_decision import decide_again

    ref, cur, truth = _pair()
    config = DetectionConfig.from_options(register=False, cues=False, edge_check_px=2)
    result = detect_changes([ref], [cur], config=config)
    assert np.array_equal(decide_again(result, [ref], config), result.mask)
    # negative control: without the finer scan the small stains go, as in the detection itself
    main_only = DetectionConfig.from_options(config, fine_smooth_sigma_px=0.0)
    assert np.array_equal(decide_again(result, [ref], main_only), detect_changes([ref], [cur], config=main_only).mask)


def test_a_candidate_seen_at_both_scales_is_listed_once():
    from fgcd_cli.changes.significance import Decision, SignificantRegion, merge_decisions

    def decision(candidates):
        return Decision(
            mask=np.zeros((8, 8), bool),
            regions=[],
            candidates=candidates,
            cluster_area_px=50.0,
            n_tests=1.0,
            seed_level=1.0,
            median=1.0,
            seed_index=np.zeros((8, 8), np.int32),
        )

    def candidate(nfa, xy):
        return SignificantRegion(log10_nfa=nfa, p_level=0.01, area_px=3, centroid_xy=xy, peak_score=5.0)

    merged = merge_decisions(
        [
            decision([candidate(0.5, (10.0, 10.0)), candidate(1.5, (40.0, 40.0))]),
            decision([candidate(0.3, (11.0, 10.5)), candidate(2.0, (70.0, 10.0))]),
        ],
        max_candidates=5,
    )
    assert [(c.log10_nfa, c.centroid_xy) for c in merged.candidates] == [
        (0.3, (11.0, 10.5)),
        (1.5, (40.0, 40.0)),
        (2.0, (70.0, 10.0)),
    ]
