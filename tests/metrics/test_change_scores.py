import numpy as np
import pytest

from fgcd_cli.metrics.change_scores import binary_scores, precision_recall_curve, sweep_scores


def test_binary_scores_by_hand():
    truth = np.zeros((4, 4), bool)
    truth[0, :] = True  # 4 positives
    pred = np.zeros((4, 4), bool)
    pred[0, :2] = True
    pred[1, 0] = True  # 2 TP, 1 FP, 2 FN
    s = binary_scores(pred, truth)
    assert (s.true_positive, s.false_positive, s.false_negative) == (2, 1, 2)
    assert s.precision == pytest.approx(2 / 3)
    assert s.recall == pytest.approx(0.5)
    assert s.f1 == pytest.approx(4 / 7)
    assert s.iou == pytest.approx(2 / 5)


def test_evaluation_mask_excludes_pixels():
    truth = np.zeros((4, 4), bool)
    pred = np.zeros((4, 4), bool)
    pred[3, 3] = True
    mask = np.ones((4, 4), bool)
    mask[3, 3] = False
    assert binary_scores(pred, truth, eval_mask=mask).f1 == 1.0
    assert binary_scores(pred, truth).f1 == 0.0


def test_perfect_score_map_has_ap_and_best_f1_one():
    rng = np.random.default_rng(1)
    truth = rng.random((50, 50)) < 0.02
    score = truth + 0.1 * rng.random((50, 50))
    s = sweep_scores(score, truth)
    assert s.best_f1 == pytest.approx(1.0)
    assert s.average_precision == pytest.approx(1.0)


def test_random_score_ap_is_prevalence():
    rng = np.random.default_rng(2)
    truth = rng.random((300, 300)) < 0.03
    s = sweep_scores(rng.random((300, 300)), truth)
    # AP of an uninformed ranking is the prevalence; its std over 2700 positives is < 0.005.
    assert s.average_precision == pytest.approx(truth.mean(), abs=0.01)


def test_best_f1_matches_exhaustive_sweep():
    rng = np.random.default_rng(3)
    truth = rng.random((40, 40)) < 0.1
    score = np.round(truth * 0.5 + rng.random((40, 40)), 2)  # with ties
    best = max(binary_scores(score >= t, truth).f1 for t in np.unique(score))
    assert sweep_scores(score, truth).best_f1 == pytest.approx(best)
    precision, recall, thresholds = precision_recall_curve(score, truth)
    assert np.all(np.diff(thresholds) < 0) and np.all(np.diff(recall) >= 0)


def test_region_counts_count_changes_found_and_false_regions():
    from fgcd_cli.metrics.change_scores import region_counts

    truth = np.zeros((40, 40), bool)
    truth[2:6, 2:6] = True  # change A: found
    truth[20:24, 20:24] = True  # change B: missed
    truth[30:32, 30:32] = True  # change C: outside the evaluation mask
    predicted = np.zeros_like(truth)
    predicted[4:9, 4:9] = True  # overlaps A
    predicted[10:12, 30:35] = True  # false
    predicted[14, 14] = True  # false, one pixel
    predicted[30:32, 30:32] = True  # on C, outside the mask: neither found nor false
    mask = np.ones_like(truth)
    mask[28:, 28:] = False
    counts = region_counts(predicted, truth, eval_mask=mask)
    assert (counts.changes_true, counts.changes_found, counts.regions, counts.false_regions) == (2, 1, 3, 2)
    # diagonal neighbours are one region (8-connected)
    diagonal = np.zeros_like(truth)
    diagonal[1, 1] = diagonal[2, 2] = True
    assert region_counts(diagonal, np.zeros_like(truth)).false_regions == 1


def test_evidence_separation_is_the_probability_a_true_region_ranks_above_a_false_one():
    from fgcd_cli.metrics.change_scores import evidence_separation

    assert evidence_separation([5.0, 6.0], [1.0, 2.0, 3.0]) == 1.0
    assert evidence_separation([1.0, 2.0], [5.0, 6.0]) == 0.0
    # by hand: true 2 beats false 1, ties false 2 (half), loses to false 3; true 4 beats all three
    assert evidence_separation([2.0, 4.0], [1.0, 2.0, 3.0]) == pytest.approx((1 + 0.5 + 0 + 3) / 6)
    assert np.isnan(evidence_separation([], [1.0]))
