"""Change-detection scores against a ground-truth mask, inside an optional evaluation mask."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(kw_only=True)
class BinaryScores:
    """Pixel counts and rates of a binary change mask against ground truth."""

    precision: float
    recall: float
    f1: float
    iou: float
    true_positive: int
    false_positive: int
    false_negative: int


@dataclass(kw_only=True)
class SweepScores:
    """Threshold-free scores of a continuous change map."""

    best_f1: float
    """F1 at the best threshold of a sweep (oracle, optimistic)."""
    best_threshold: float
    average_precision: float
    """Area under the precision-recall curve (step-wise, every distinct score a threshold)."""


def _select(array: np.ndarray, eval_mask: np.ndarray | None) -> np.ndarray:
    array = np.asarray(array)
    if eval_mask is None:
        return array.ravel()
    eval_mask = np.asarray(eval_mask).astype(bool)
    if eval_mask.shape != array.shape:
        raise ValueError(f"evaluation mask shape {eval_mask.shape} differs from {array.shape}")
    return array[eval_mask]


def binary_scores(predicted: np.ndarray, truth: np.ndarray, *, eval_mask: np.ndarray | None = None) -> BinaryScores:
    """Precision, recall, F1 and IoU of a predicted mask (HxW bool) against ground truth (HxW bool).

    Empty prediction and empty truth give precision = recall = F1 = IoU = 1 (nothing
    to find, nothing found); any other empty denominator gives 0.
    """
    if np.shape(predicted) != np.shape(truth):
        raise ValueError(f"prediction shape {np.shape(predicted)} differs from truth {np.shape(truth)}")
    p = _select(predicted, eval_mask).astype(bool)
    t = _select(truth, eval_mask).astype(bool)
    tp = int(np.count_nonzero(p & t))
    fp = int(np.count_nonzero(p & ~t))
    fn = int(np.count_nonzero(~p & t))
    if tp + fp + fn == 0:
        return BinaryScores(
            precision=1.0, recall=1.0, f1=1.0, iou=1.0, true_positive=0, false_positive=0, false_negative=0
        )
    precision = tp / (tp + fp) if tp + fp else 0.0
    recall = tp / (tp + fn) if tp + fn else 0.0
    f1 = 2 * tp / (2 * tp + fp + fn)
    iou = tp / (tp + fp + fn)
    return BinaryScores(
        precision=precision, recall=recall, f1=f1, iou=iou, true_positive=tp, false_positive=fp, false_negative=fn
    )


def precision_recall_curve(score: np.ndarray, truth: np.ndarray, *, eval_mask: np.ndarray | None = None):
    """Precision and recall for every distinct threshold ``score >= t``.

    Returns (precision, recall, thresholds), 1-D arrays ordered by decreasing threshold.
    """
    s = _select(score, eval_mask).astype(np.float64)
    t = _select(truth, eval_mask).astype(bool)
    order = np.argsort(-s, kind="mergesort")
    s_sorted = s[order]
    t_sorted = t[order]
    tp = np.cumsum(t_sorted)
    fp = np.cumsum(~t_sorted)
    # Keep the last index of each run of equal scores: ties share one threshold.
    last = np.r_[np.nonzero(np.diff(s_sorted))[0], s_sorted.size - 1]
    tp, fp, thresholds = tp[last], fp[last], s_sorted[last]
    positives = max(int(t.sum()), 1)
    precision = tp / np.maximum(tp + fp, 1)
    recall = tp / positives
    return precision, recall, thresholds


def sweep_scores(score: np.ndarray, truth: np.ndarray, *, eval_mask: np.ndarray | None = None) -> SweepScores:
    """Best F1 over all thresholds and average precision of a continuous change map.

    Average precision is ``sum_k (R_k - R_{k-1}) P_k`` (scikit-learn's definition).
    """
    precision, recall, thresholds = precision_recall_curve(score, truth, eval_mask=eval_mask)
    if not np.any(_select(truth, eval_mask)):
        return SweepScores(best_f1=float("nan"), best_threshold=float("nan"), average_precision=float("nan"))
    with np.errstate(invalid="ignore", divide="ignore"):
        f1 = np.where(precision + recall > 0, 2 * precision * recall / (precision + recall), 0.0)
    best = int(np.argmax(f1))
    ap = float(np.sum(np.diff(np.r_[0.0, recall]) * precision))
    return SweepScores(best_f1=float(f1[best]), best_threshold=float(thresholds[best]), average_precision=ap)


@dataclass(frozen=True, kw_only=True)
class RegionCounts:
    """What a conservator counts on a change map: changes found and false regions.

    Attributes
    ----------
    changes_true : int
        Ground-truth changes: connected components (8-connected) of the truth inside the evaluation mask.
    changes_found : int
        Those a predicted region overlaps by at least one pixel.
    regions : int
        Predicted regions: connected components of the prediction inside the evaluation mask.
    false_regions : int
        Predicted regions overlapping no ground-truth pixel.
    """

    changes_true: int
    changes_found: int
    regions: int
    false_regions: int


def region_counts(predicted: np.ndarray, truth: np.ndarray, *, eval_mask: np.ndarray | None = None) -> RegionCounts:
    """Count changes found and false regions of a predicted mask (HxW bool) against ground truth (HxW bool).

    Both masks are cut to ``eval_mask`` first; components are 8-connected (``scipy.ndimage.label``).
    """
    from scipy import ndimage

    if np.shape(predicted) != np.shape(truth):
        raise ValueError(f"prediction shape {np.shape(predicted)} differs from truth {np.shape(truth)}")
    inside = np.ones(np.shape(truth), bool) if eval_mask is None else np.asarray(eval_mask).astype(bool)
    p = np.asarray(predicted).astype(bool) & inside
    t = np.asarray(truth).astype(bool) & inside
    eight = np.ones((3, 3), bool)
    t_labels, n_true = ndimage.label(t, structure=eight)
    p_labels, n_regions = ndimage.label(p, structure=eight)
    found = np.unique(t_labels[p & t])
    hit_regions = np.unique(p_labels[p & t])
    return RegionCounts(
        changes_true=int(n_true),
        changes_found=int(np.count_nonzero(found)),
        regions=int(n_regions),
        false_regions=int(n_regions - np.count_nonzero(hit_regions)),
    )


def evidence_separation(true_values, false_values) -> float:
    """How well an evidence measure ranks true regions above false ones: the probability that a true
    region's value exceeds a false one's, ties counted half (the ROC area, Mann-Whitney U over
    ``n_true * n_false``; ``scipy.stats.mannwhitneyu``). 0.5 is no separation, 1 a perfect one.

    Parameters
    ----------
    true_values, false_values : sequences of float, the measure on the regions that overlap a true
        change and on those that do not.

    Returns
    -------
    float in [0, 1], NaN when either sequence is empty.
    """
    from scipy.stats import mannwhitneyu

    t, f = np.asarray(true_values, float), np.asarray(false_values, float)
    if t.size == 0 or f.size == 0:
        return float("nan")
    return float(mannwhitneyu(t, f).statistic / (t.size * f.size))


def truth_report(
    predicted: np.ndarray, score: np.ndarray, truth: np.ndarray, *, eval_mask: np.ndarray | None = None
) -> dict:
    """A change map against ground truth, as ``fgcd diff --truth`` prints it: pixels and regions.

    Parameters
    ----------
    predicted : (H, W) bool, the changed pixels.
    score : (H, W) float, the change score (swept for the threshold-free figures).
    truth : (H, W) bool, the true changes.
    eval_mask : (H, W) bool or None, where they are scored (None: everywhere).

    Returns
    -------
    dict
        ``precision``, ``recall``, ``f1``, ``iou`` (pixels, at the tool's decision), ``best_f1`` and
        ``average_precision`` (the score swept), ``changes_true``, ``changes_found`` and
        ``false_regions`` (:func:`region_counts`).
    """
    b = binary_scores(predicted, truth, eval_mask=eval_mask)
    s = sweep_scores(score, truth, eval_mask=eval_mask)
    c = region_counts(predicted, truth, eval_mask=eval_mask)
    return {
        "precision": b.precision,
        "recall": b.recall,
        "f1": b.f1,
        "iou": b.iou,
        "best_f1": s.best_f1,
        "average_precision": s.average_precision,
        "changes_true": c.changes_true,
        "changes_found": c.changes_found,
        "false_regions": c.false_regions,
    }
