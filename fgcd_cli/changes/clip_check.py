"""Region-level clip check: set aside regions whose evidence comes from clipped pixels only.

A pixel is *clipped* (:func:`fgcd_cli.changes.images.clipped_pixels`) at either end of the sensor's
range. At the top code in some colour channel its radiance lies somewhere above what the camera
recorded, so a difference there measures the clipping, not the surface. Specular highlights clip (a
bronze's or a glaze's sheen), and they slide over a curved glossy surface when the viewpoint moves by
a millimetre: two observations of an unchanged glossy object differ exactly where a lighting clips in
one of them. At the floor (every channel within the dark noise of black, where that noise alone is
the contrast floor) a difference measures the noise, which the camera's gamma stretches in the dark:
a black void beside a stupa, a deep shadow.

A region is set aside when its score recomputed from *measured* pixels only no longer seeds a
significant region inside it: the detection's own a-contrario decision, made again on that
score (the caller passes it), not a single pixel against the seed level, which the noise of an
unchanged pair alone reaches in a region of a hundred pixels. The decision is made at both of the
detection's smoothings, as the detection made it: a pit a few pixels across is significant at the
finer one only. A lighting measures a pixel when neither observation clips within the difference
cue's shift radius of it (the cue at a pixel takes the best of the ±``shift_radius_px`` shifts,
so a clipped neighbour within that radius enters it). A region no lighting clips in both observations
keeps its score and is never set aside; a stain on white plaster that some lightings clip still shows
in the lightings that do not, and stays; a surface that darkens below the floor in one observation
only is a change.

Set-aside regions are not deleted: the caller keeps them among the unreported candidates
(``docs/change-detection.md``, "Change detection pipeline", step 10).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from fgcd_cli.changes.config import ScoreConfig
from fgcd_cli.changes.cues.maps import edge_tolerant_difference, relative_to_median
from fgcd_cli.changes.score import PairScore

#: Where the smoothed count of measuring lightings is below this (half a lighting), a pixel has no
#: measured evidence: its measured-only score is 0.
MIN_MEASURING_LIGHTINGS = 0.5


@dataclass(frozen=True, kw_only=True)
class ClipCheck:
    """Outcome of the clip check on the regions of one change mask."""

    explained: np.ndarray
    """(H, W) bool, pixels of the regions set aside."""
    region_ids: tuple[int, ...]
    """Ids (in the labels checked) of the regions set aside."""


def _not_measured_kernel(score: ScoreConfig) -> np.ndarray:
    """Square structuring element of the pixels a clipped pixel takes out of the measurement."""
    return cv2.getStructuringElement(cv2.MORPH_RECT, (2 * score.shift_radius_px + 1,) * 2)


def measured_only_score(refs: list[np.ndarray], scored: PairScore, valid: np.ndarray, score: ScoreConfig) -> np.ndarray:
    """The detection's fused score with each lighting counted only where it measures the pixel.

    ``G * (sum_k m_k r_k) / G * (sum_k m_k)``: ``r_k`` the lighting's difference cue over its median
    (as in :func:`fgcd_cli.changes.score.score_pair`), ``m_k`` 1 where neither observation clips within
    ``score.shift_radius_px``, ``G`` the detection's smoothing (normalised convolution).
    Where nothing clips it equals the detection's score (its colour difference cue, with the same edge
    tolerance; the optional local-NCC cue, ``structure_weight``, is not recomputed).

    Parameters
    ----------
    refs : list of K (H, W[, 3]) float32 in [0, 1], the reference images.
    scored : PairScore with ``clipped_ref`` and ``clipped_cur`` set.
    valid : (H, W) bool, the compared pixels.
    score : ScoreConfig, the detection's shift radius and smoothing (px).

    Returns
    -------
    (H, W) float32, dimensionless (the detection score's unit); 0 where no lighting measures.
    """
    numerator, weight = _measured_sums(refs, scored, valid, score)
    return _smoothed_ratio(numerator, weight, score.smooth_sigma_px)


def _measured_sums(refs, scored: PairScore, valid: np.ndarray, score: ScoreConfig) -> tuple[np.ndarray, np.ndarray]:
    """``(sum_k m_k r_k, sum_k m_k)`` of :func:`measured_only_score`, unsmoothed, (H, W) float32 each."""
    grow = _not_measured_kernel(score)
    numerator = np.zeros(valid.shape, np.float32)
    weight = np.zeros(valid.shape, np.float32)
    for ref, normalized, median, clipped_ref, clipped_cur in zip(
        refs, scored.normalized, scored.medians, scored.clipped_ref, scored.clipped_cur
    ):
        measured = 1.0 - cv2.dilate((clipped_ref | clipped_cur).astype(np.uint8), grow).astype(np.float32)
        difference = edge_tolerant_difference(
            ref,
            normalized,
            radius_px=score.shift_radius_px,
            edge_radius_px=score.edge_tolerance_px,
            edge_contrast=score.edge_contrast,
        )
        numerator += measured * relative_to_median(difference, valid, median=median)
        weight += measured
    return numerator, weight


def _smoothed_ratio(numerator: np.ndarray, weight: np.ndarray, sigma_px: float) -> np.ndarray:
    """Normalised convolution ``G * numerator / G * weight`` (0 where under :data:`MIN_MEASURING_LIGHTINGS`)."""
    if sigma_px > 0:
        numerator = cv2.GaussianBlur(numerator, (0, 0), sigma_px)
        weight = cv2.GaussianBlur(weight, (0, 0), sigma_px)
    return np.where(weight >= MIN_MEASURING_LIGHTINGS, numerator / np.maximum(weight, 1e-6), 0.0).astype(np.float32)


def clip_explained_regions(
    labels: np.ndarray,
    n_regions: int,
    *,
    refs: list[np.ndarray],
    scored: PairScore,
    valid: np.ndarray,
    significant: Callable[[np.ndarray, np.ndarray | None, np.ndarray], np.ndarray],
    score: ScoreConfig,
) -> ClipCheck:
    """The regions of ``labels`` that some lighting clips in both observations and in which the
    detection's decision, made again on the measured-only score (:func:`measured_only_score`), seeds
    no significant region.

    Parameters
    ----------
    labels : (H, W) int array, region ids 1..n_regions (0 elsewhere).
    n_regions : int
    refs : list of K (H, W[, 3]) float32 in [0, 1], the reference images.
    scored : PairScore, the detection's score (its clipped pixels, re-lit current images, cue medians).
    valid : (H, W) bool, the compared pixels.
    significant : callable, ``(score, fine_score or None, within) -> (H, W) bool``, the seed pixels of the
        significant regions the detection's decision finds on a score map (and its finer smoothing), at
        least where they reach the (H, W) bool pixels ``within``.
    score : ScoreConfig, the detection's shift radius and smoothing (px).
    """
    explained = np.zeros(labels.shape, bool)
    if scored.clipped_ref is None or scored.clipped_cur is None or n_regions == 0:
        return ClipCheck(explained=explained, region_ids=())
    grow = _not_measured_kernel(score)
    index = np.arange(1, n_regions + 1)
    both = np.zeros(n_regions, bool)
    for clipped_ref, clipped_cur in zip(scored.clipped_ref, scored.clipped_cur):
        if not (clipped_ref.any() and clipped_cur.any()):
            continue
        near_ref = cv2.dilate(clipped_ref.astype(np.uint8), grow)
        near_cur = cv2.dilate(clipped_cur.astype(np.uint8), grow)
        both |= (np.asarray(ndimage.maximum(near_ref, labels, index)) > 0) & (
            np.asarray(ndimage.maximum(near_cur, labels, index)) > 0
        )
    touched = [int(i) for i in index[both]]
    if not touched:
        return ClipCheck(explained=explained, region_ids=())
    # at both of the detection's smoothings, as it decided (a pit a few pixels across is significant at the
    # finer one only)
    numerator, weight = _measured_sums(refs, scored, valid, score)
    two_scales = 0.0 < score.fine_smooth_sigma_px < score.smooth_sigma_px
    seeds = significant(
        _smoothed_ratio(numerator, weight, score.smooth_sigma_px),
        _smoothed_ratio(numerator, weight, score.fine_smooth_sigma_px) if two_scales else None,
        np.isin(labels, touched),
    )
    ids = []
    for region_id in touched:
        pixels = labels == region_id
        if not seeds[pixels].any():
            explained |= pixels
            ids.append(region_id)
    return ClipCheck(explained=explained, region_ids=tuple(ids))
