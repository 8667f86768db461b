"""Region-level edge check: set aside regions that a small viewpoint difference explains.

A relocation residual of a few millimetres moves, thins or blurs strong edges of
the reference by a pixel or two (parallax at depth edges, occlusion of grazing
walls, resampling). The difference it leaves is a *band along an edge*. A region
is set aside only when all three hold:

1. it lies mostly in the reference's strong-edge band (``band_fraction`` of its
   pixels within ``edge_check_px`` of a strong edge; a thin line the reference saw
   shallow at its sub-pixel phase and the current image deep counts as the reference's,
   :func:`fgcd_cli.changes.cues.maps.edge_band_either_phase`);
2. the two-sided envelope difference over ``edge_check_px``
   (:func:`fgcd_cli.changes.cues.maps.edge_tolerant_difference`) nowhere reaches the
   detection's seed level inside it: each image is explained by the other
   within the tolerated shift;
3. it is not a small compact blob. The envelope of nearby dark strokes hides
   a blob a few pixels wide (a stain or a pit on a carved letter passes rule 2),
   but a shifted edge leaves a band *along* the edge. A region is a blob when it
   is less than ``MIN_ALONG_ACROSS`` times longer along the local edge direction
   than across it (:func:`along_edge_elongation`) and small enough for rule 2
   to be blind to it: at most :func:`max_hidden_blob_px` pixels, the disc a
   stroke widened by the tolerated shift on both sides spans once the
   detection's smoothing has grown it. Larger regions that pass rule 2 are
   fields of shifted edges (a block of lettering), set aside whatever their
   shape. A region touching the border of the compared area has its shape cut
   by that border, so rule 3 does not apply to it.

Set-aside regions are not deleted: the caller keeps them as candidates, shown
to the user (see ``docs/change-detection.md``, "Edge check").
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from fgcd_cli.changes.config import EdgeCheckConfig, ScoreConfig
from fgcd_cli.changes.cues.maps import edge_band_either_phase, edge_tolerant_difference, relative_to_median
from fgcd_cli.changes.images import to_gray
from fgcd_cli.changes.score import PairScore

MIN_ALONG_ACROSS = 2.0
"""Rule 3: a band along an edge is at least twice as long as it is wide (a blob: ~1)."""


@dataclass(frozen=True, kw_only=True)
class EdgeCheck:
    """Outcome of the edge check on the regions of one change mask."""

    explained: np.ndarray
    """HxW bool, pixels of the regions set aside."""
    n_explained: int
    """Number of regions set aside."""
    n_compact_kept: int
    """Regions that passed rules 1-2 but were kept because they are compact (rule 3)."""


def along_edge_elongation(region: np.ndarray, gray: np.ndarray) -> float:
    """How much longer a region is along the local edge direction than across it.

    The edge normal is the dominant eigenvector ``n`` of the reference's gradient
    structure tensor summed over the region; with ``t`` the edge tangent and ``C``
    the 2x2 covariance of the region's pixel coordinates, the elongation is
    ``sqrt(tᵀCt / nᵀCn)``: ~1 for a round blob, L/w for a band of length L and
    width w along the edge.

    Parameters
    ----------
    region : (H, W) bool array, the region's pixels (at least 2).
    gray : (H, W) float32 array, the reference image (any intensity unit).

    Returns
    -------
    float, dimensionless; ``inf`` when the region has no extent across the edge.
    """
    ys, xs = np.nonzero(region)
    if len(xs) < 2:
        return 1.0
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    # Gradients on a one-pixel margin around the region's box (3x3 Sobel support).
    by0, bx0 = max(y0 - 1, 0), max(x0 - 1, 0)
    patch = np.ascontiguousarray(gray[by0 : y1 + 1, bx0 : x1 + 1], np.float32)
    gx = cv2.Sobel(patch, cv2.CV_32F, 1, 0, ksize=3)[ys - by0, xs - bx0].astype(np.float64)
    gy = cv2.Sobel(patch, cv2.CV_32F, 0, 1, ksize=3)[ys - by0, xs - bx0].astype(np.float64)
    tensor = np.array([[gx @ gx, gx @ gy], [gx @ gy, gy @ gy]])
    _, vectors = np.linalg.eigh(tensor)
    normal, tangent = vectors[:, 1], vectors[:, 0]
    coords = np.vstack([xs, ys]).astype(np.float64)
    cov = np.cov(coords)
    across = float(normal @ cov @ normal)
    along = float(tangent @ cov @ tangent)
    if across <= 1e-12:
        return float("inf")
    return float(np.sqrt(along / across))


def max_hidden_blob_px(*, edge_check_px: int, smooth_sigma_px: float) -> float:
    """Largest compact region (pixels) whose pixels a shift of ``edge_check_px`` can all explain.

    Every pixel of such a region lies within ``edge_check_px`` of a dark (or
    bright) stroke of the reference, so the region is at most a stroke
    (~1 px) widened by ``edge_check_px`` on both sides: ``2 * edge_check_px + 1``
    across; the smoothed score spreads it by ``2 * smooth_sigma_px`` on each side.
    A blob straddling two such strokes (letters a stroke width apart) is up to
    twice that diameter; the bound is the area of that disc.
    """
    diameter = 2.0 * ((2 * edge_check_px + 1) + 4.0 * smooth_sigma_px)
    return float(np.pi * diameter**2 / 4.0)


def edge_explained_regions(
    labels: np.ndarray,
    n_regions: int,
    *,
    refs: list[np.ndarray],
    scored: PairScore,
    valid: np.ndarray,
    seed_level: float,
    score: ScoreConfig,
    config: EdgeCheckConfig,
) -> EdgeCheck:
    """Apply rules 1-3 of the module docstring to every region of ``labels``.

    Parameters
    ----------
    labels : (H, W) int32, region ids 1..n_regions (0 elsewhere).
    refs : list of (H, W[, 3]) float32 in [0, 1], the reference images (one per lighting).
    scored : PairScore, the detection's score: its light-normalised, registered current
        images, and its per-lighting medians of the cue, so that the edge-tolerant score
        is in the units of the detection's ``seed_level``.
    valid : (H, W) bool, the compared pixels.
    seed_level : float, the score level at which the detection seeds regions.
    score : ScoreConfig, the detection's shift tolerance (px), score smoothing (px) and
        strong-edge contrast (see :func:`fgcd_cli.changes.cues.maps.edge_band`), applied the same way here.
    config : EdgeCheckConfig, the tolerated edge shift (px) and rule 1's fraction.
    """
    normalized_images, medians = scored.normalized, scored.medians
    shift_radius_px, smooth_sigma_px, edge_contrast = score.shift_radius_px, score.smooth_sigma_px, score.edge_contrast
    edge_check_px, band_fraction = config.edge_check_px, config.edge_check_band_fraction
    check_bands = [
        edge_band_either_phase(ref, normalized, radius_px=edge_check_px, contrast=edge_contrast)
        for ref, normalized in zip(refs, normalized_images)
    ]
    tolerant = [
        relative_to_median(
            edge_tolerant_difference(
                ref, normalized, radius_px=shift_radius_px, edge_radius_px=edge_check_px, band=band
            ),
            valid,
            median=median,
        )
        for ref, normalized, band, median in zip(refs, normalized_images, check_bands, medians)
    ]
    tolerant_score = np.mean(tolerant, axis=0).astype(np.float32)
    if smooth_sigma_px > 0:
        tolerant_score = cv2.GaussianBlur(tolerant_score, (0, 0), smooth_sigma_px)
    in_band = np.logical_or.reduce(check_bands)
    gray = np.mean([to_gray(ref) for ref in refs], axis=0).astype(np.float32)
    # Pixels next to the border of the compared area (or of the frame).
    outside = np.pad(~valid, 1, constant_values=True)
    near_border = ndimage.binary_dilation(outside, structure=np.ones((3, 3), bool))[1:-1, 1:-1]
    blob_px = max_hidden_blob_px(edge_check_px=edge_check_px, smooth_sigma_px=smooth_sigma_px)
    explained = np.zeros(labels.shape, bool)
    n_explained = n_compact = 0
    for region_id in range(1, n_regions + 1):
        pixels = labels == region_id
        if in_band[pixels].mean() < band_fraction or tolerant_score[pixels].max() >= seed_level:
            continue
        if (
            not near_border[pixels].any()
            and pixels.sum() <= blob_px
            and along_edge_elongation(pixels, gray) < MIN_ALONG_ACROSS
        ):
            n_compact += 1
            continue
        explained |= pixels
        n_explained += 1
    return EdgeCheck(explained=explained, n_explained=n_explained, n_compact_kept=n_compact)
