"""Change regions: connected, cleaned components of a change mask, with their area."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage
from skimage.morphology import remove_small_holes, remove_small_objects

if TYPE_CHECKING:
    from fgcd_cli.changes.significance import Decision


class CueLabel(StrEnum):
    """What changed in a region, from the photometric-stereo cues (:mod:`fgcd_cli.changes.cues.labels`)."""

    RELIEF = "relief"
    """Surface normals changed: pits, flakes, cracks."""
    COLOUR = "colour"
    """Albedo changed: stains, salts, fading."""
    BOTH = "both"


@dataclass(kw_only=True)
class ChangeRegion:
    """One connected change region, in the reference image's frame."""

    id: int
    """1-based, largest region first."""
    area_px: int
    area_mm2: float | None
    """Metric area (mm²) when a per-pixel area map was given; None otherwise."""
    bbox_xywh: tuple[int, int, int, int]
    centroid_xy: tuple[float, float]
    mean_score: float
    max_score: float
    log10_nfa: float | None = None
    """log10 of the region's number of false alarms (a-contrario significance; < 0 is significant at epsilon = 1)."""
    cue: CueLabel | None = None
    """What changed, from the photometric-stereo cues (:class:`CueLabel`), or None when the cues were not computed."""
    brightness_change: float | None = None
    """How much brighter (> 0) or darker (< 0) the region is now, as a fraction (-0.2: 20 % darker):
    :func:`set_brightness_changes`. Swapping reference and current flips its sign. None: not computed."""
    tone: str | None = None
    """``"darker"`` or ``"brighter"`` when every lighting agrees (:func:`set_brightness_changes`),
    ``"mixed"`` when they do not (a relief change shades one way under one light, the other way under
    another); None: not computed."""
    contrast: float | None = None
    """The change's relative size at its strongest lighting and colour channel (0.3: 30 %;
    :mod:`fgcd_cli.changes.contrast`). None: not computed."""
    lightings: tuple[int, ...] | None = None
    """1-based numbers of the lightings that show it (its contrast there at least half its strongest;
    :func:`fgcd_cli.changes.contrast.set_contrasts`). None: not computed."""


def clean_mask(mask: np.ndarray, *, min_region_px: int, max_hole_px: int) -> np.ndarray:
    """Remove regions of at most ``min_region_px`` pixels and fill holes of at most ``max_hole_px``."""
    cleaned = remove_small_objects(mask.astype(bool), max_size=int(min_region_px))
    return remove_small_holes(cleaned, max_size=int(max_hole_px))


def by_evidence(regions: list[ChangeRegion]) -> list[ChangeRegion]:
    """``regions`` strongest first: by peak change score, then by area (ids unchanged).

    Rule (docs/change-detection.md, "Reports"): a person acts on the region with
    the strongest evidence, not the largest; a long thin strip along an edge is
    large and weak (the demo's figures are there).
    """
    return sorted(regions, key=lambda r: evidence_rank(r.max_score, r.area_px, r.id))


def evidence_rank(max_score: float, area_px: int, region_id: int) -> tuple[float, int, int]:
    """The sort key of :func:`by_evidence` (peak score down, then area down, then id), for regions as data."""
    return (-float(max_score), -int(area_px), int(region_id))


def refine_to_local_peak(
    mask: np.ndarray,
    score: np.ndarray,
    *,
    background: float,
    fraction: float = 0.2,
    radius_px: int = 6,
) -> np.ndarray:
    """Trim detected regions to where the score reaches ``fraction`` of its nearby peak.

    A change with a sharp border, seen through the smoothed score, is a plateau
    with Gaussian flanks. The hysteresis growth threshold is set for weak changes,
    so around a strong one it lands far out on the flank's tail: a 100x
    plateau smoothed with sigma = 2 px still exceeds a 2x threshold 4-5 px outside
    the border. Keeping only pixels whose excess over the background is at least
    ``fraction`` of the largest excess within ``radius_px`` (about 3 sigma of the
    smoothing) removes that tail; weak changes, whose whole profile is near the
    threshold, and weak parts of a region far from its strong parts are kept.

    Parameters
    ----------
    mask : ndarray, HxW bool, the thresholded change mask.
    score : ndarray, HxW float, the fused score.
    background : float, score of unchanged pixels (the threshold's median).
    fraction : float in [0, 1), 0 disables the trimming.
    radius_px : int, half size of the window in which the peak is taken.
    """
    if fraction <= 0 or not mask.any():
        return mask
    excess = np.maximum(score.astype(np.float32) - np.float32(background), 0.0)
    peak = ndimage.maximum_filter(np.where(mask, excess, 0.0), size=2 * int(radius_px) + 1)
    return mask & (excess >= fraction * peak)


def extract_regions(
    mask: np.ndarray,
    score: np.ndarray,
    *,
    pixel_area_mm2: np.ndarray | None = None,
) -> tuple[list[ChangeRegion], np.ndarray]:
    """Label 8-connected regions of a (cleaned) change mask.

    Parameters
    ----------
    mask : ndarray, HxW bool
    score : ndarray, HxW float
    pixel_area_mm2 : ndarray, HxW float, optional
        Area of the surface seen by each reference pixel, mm² (NaN where unknown).

    Returns
    -------
    regions : list of ChangeRegion, largest first, ids 1..n
    labels : ndarray, HxW int32, 0 = unchanged, i = region with id i
    """
    raw_labels, count = ndimage.label(mask, structure=np.ones((3, 3), dtype=bool))
    if count == 0:
        return [], np.zeros(mask.shape, np.int32)
    index = np.arange(1, count + 1)
    areas = ndimage.sum_labels(np.ones(mask.shape), raw_labels, index)
    order = np.argsort(-areas, kind="stable")
    relabel = np.zeros(count + 1, np.int32)
    relabel[index[order]] = np.arange(1, count + 1)
    labels = relabel[raw_labels]
    slices = ndimage.find_objects(labels)
    means = ndimage.mean(score, labels, index)
    maxima = ndimage.maximum(score, labels, index)
    centroids = ndimage.center_of_mass(np.ones(mask.shape), labels, index)
    if pixel_area_mm2 is not None:
        area_map = np.nan_to_num(np.asarray(pixel_area_mm2, dtype=np.float64), nan=0.0)
        known = ndimage.sum_labels(np.isfinite(pixel_area_mm2).astype(np.float64), labels, index)
        metric = ndimage.sum_labels(area_map, labels, index)
    regions = []
    for i in range(count):
        sl = slices[i]
        y0, y1, x0, x1 = sl[0].start, sl[0].stop, sl[1].start, sl[1].stop
        area_px = int((labels[sl] == i + 1).sum())
        area_mm2 = None
        if pixel_area_mm2 is not None and known[i] > 0:
            # Extrapolate over pixels without 3D data at the region's mean pixel area.
            area_mm2 = float(metric[i] * area_px / known[i])
        regions.append(
            ChangeRegion(
                id=i + 1,
                area_px=area_px,
                area_mm2=area_mm2,
                bbox_xywh=(int(x0), int(y0), int(x1 - x0), int(y1 - y0)),
                centroid_xy=(float(centroids[i][1]), float(centroids[i][0])),
                mean_score=float(means[i]),
                max_score=float(maxima[i]),
            )
        )
    return regions, labels


def pixel_area_from_points(points_cam: np.ndarray) -> np.ndarray:
    """Surface area seen by each pixel from an organized point map.

    Parameters
    ----------
    points_cam : ndarray, HxWx3 float, metres, 3D point of each pixel (NaN where unknown).

    Returns
    -------
    ndarray, HxW float64, mm² per pixel (NaN where unknown): ``|dP/du x dP/dv|``.
    """
    points = np.asarray(points_cam, dtype=np.float64)
    if points.ndim != 3 or points.shape[2] != 3:
        raise ValueError(f"points_cam must be HxWx3, got {points.shape}")
    dP_dv, dP_du = np.gradient(points, axis=(0, 1))
    area_m2 = np.linalg.norm(np.cross(dP_du, dP_dv), axis=2)
    return area_m2 * 1e6


def pixel_area_from_depth(depth_m: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Surface area seen by each pixel from a z-depth map and pinhole intrinsics.

    Parameters
    ----------
    depth_m : ndarray, HxW float, z-depth in metres (NaN or <= 0 where unknown).
    K : ndarray, 3x3 camera matrix (pixels).

    Returns
    -------
    ndarray, HxW float64, mm² per pixel (NaN where unknown).
    """
    depth = np.asarray(depth_m, dtype=np.float64).copy()
    depth[~(depth > 0)] = np.nan
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    x = (u - K[0, 2]) / K[0, 0] * depth
    y = (v - K[1, 2]) / K[1, 1] * depth
    return pixel_area_from_points(np.stack([x, y, depth], axis=2))


def regions_with_significance(mask, score, significance: Decision, pixel_area_mm2):
    """Regions of the final mask (as :func:`fgcd_cli.changes.regions.extract_regions`: numbered by
    decreasing area), each with the log10 NFA of the most significant a-contrario seed it holds.

    The per-region sums run over the list of mask pixels rather than whole-frame arrays
    (a change mask covers a few percent of a large frame).
    """
    raw_labels, count = ndimage.label(mask, structure=np.ones((3, 3), dtype=bool))
    if count == 0:
        return [], np.zeros(mask.shape, np.int32)
    pixels = np.flatnonzero(raw_labels)
    raw = raw_labels.ravel()[pixels]
    areas = np.bincount(raw, minlength=count + 1)[1:].astype(np.float64)
    order = np.argsort(-areas, kind="stable")
    relabel = np.zeros(count + 1, np.int32)
    relabel[order + 1] = np.arange(1, count + 1)
    labels = relabel[raw_labels]
    del raw_labels
    ids = relabel[raw]
    counts = np.bincount(ids, minlength=count + 1)[1:]
    ys, xs = np.divmod(pixels, mask.shape[1])
    values = score.ravel()[pixels]
    means = np.bincount(ids, weights=values, minlength=count + 1)[1:] / counts.astype(np.float64)
    cy = np.bincount(ids, weights=ys.astype(np.float64), minlength=count + 1)[1:] / counts
    cx = np.bincount(ids, weights=xs.astype(np.float64), minlength=count + 1)[1:] / counts
    by_id = np.argsort(ids, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    maxima = np.maximum.reduceat(values[by_id], starts)
    y_lo, y_hi = np.minimum.reduceat(ys[by_id], starts), np.maximum.reduceat(ys[by_id], starts)
    x_lo, x_hi = np.minimum.reduceat(xs[by_id], starts), np.maximum.reduceat(xs[by_id], starts)
    area_mm2 = [None] * count
    if pixel_area_mm2 is not None:
        area_map = np.asarray(pixel_area_mm2).ravel()[pixels]
        known = np.bincount(ids, weights=np.isfinite(area_map).astype(np.float64), minlength=count + 1)[1:]
        metric = np.bincount(ids, weights=np.nan_to_num(area_map.astype(np.float64), nan=0.0), minlength=count + 1)[1:]
        # Extrapolate over pixels without 3D data at the region's mean pixel area.
        area_mm2 = [float(metric[i] * counts[i] / known[i]) if known[i] > 0 else None for i in range(count)]
    nfa = [None] * count
    if significance.seed_index is not None:
        seeds = significance.seed_index.ravel()[pixels]
        for region_id, seed in set(zip(ids[seeds > 0].tolist(), seeds[seeds > 0].tolist())):
            value = significance.regions[seed - 1].log10_nfa
            nfa[region_id - 1] = value if nfa[region_id - 1] is None else min(nfa[region_id - 1], value)
    regions = [
        ChangeRegion(
            id=i + 1,
            area_px=int(counts[i]),
            area_mm2=area_mm2[i],
            bbox_xywh=(int(x_lo[i]), int(y_lo[i]), int(x_hi[i] - x_lo[i] + 1), int(y_hi[i] - y_lo[i] + 1)),
            centroid_xy=(float(cx[i]), float(cy[i])),
            mean_score=float(means[i]),
            max_score=float(maxima[i]),
            log10_nfa=None if nfa[i] is None else float(nfa[i]),
        )
        for i in range(count)
    ]
    return regions, labels


def set_brightness_changes(
    regions: list[ChangeRegion], labels: np.ndarray, refs: list[np.ndarray], normalized: list[np.ndarray]
) -> None:
    """Set each region's ``brightness_change``: the geometric mean over lightings of its light ratio, less 1.

    Per lighting ``k`` the ratio is ``sum(cur_k) / sum(ref_k)`` over the region's pixels (grey, the
    current image re-lit to the reference by the local gain), so a stain reads below 0 and a
    whitening or a loss showing a paler layer above 0; the geometric mean makes the swapped pair's
    value ``1 / (1 + b) - 1``, of the opposite sign (docs/change-detection.md, "Reports").

    Parameters
    ----------
    regions : list of ChangeRegion, ids 1..n matching ``labels``.
    labels : (H, W) int32, region ids (0 elsewhere).
    refs, normalized : lists of K (H, W[, 3]) float32 in [0, 1], the reference images and the
        re-lit current images in the reference frame.
    """
    if not regions:
        return
    from fgcd_cli.changes.images import to_gray

    index = np.array([r.id for r in regions])
    log_ratios = []
    for ref, cur in zip(refs, normalized):
        sum_ref = ndimage.sum_labels(to_gray(ref).astype(np.float64), labels, index)
        sum_cur = ndimage.sum_labels(np.clip(to_gray(cur), 0.0, None).astype(np.float64), labels, index)
        log_ratios.append(np.log((sum_cur + 1e-6) / (sum_ref + 1e-6)))
    log_ratios = np.array(log_ratios)
    mean = log_ratios.mean(axis=0)
    change = np.expm1(mean)
    # The tone is stated when the lightings agree: the mean log ratio at least two of its standard
    # errors from 0 (one lighting: its sign).
    k = len(log_ratios)
    standard_error = log_ratios.std(axis=0, ddof=1) / np.sqrt(k) if k > 1 else np.zeros_like(mean)
    for region, value, m, se in zip(regions, change, mean, standard_error):
        region.brightness_change = float(value)
        region.tone = "mixed" if abs(m) <= 2.0 * se else ("darker" if m < 0 else "brighter")
