"""The fused change score of a registered pair: light normalisation, per-lighting cues, fusion over lightings."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from fgcd_cli.changes.config import RegionConfig, ScoreConfig
from fgcd_cli.changes.cues.maps import edge_band, edge_tolerant_difference, local_ncc_dissimilarity, relative_to_median
from fgcd_cli.changes.illumination import normalize_local_gain
from fgcd_cli.changes.images import clipped_pixels, to_gray
from fgcd_cli.changes.threshold import robust_hysteresis_threshold


@dataclass(kw_only=True)
class ScoreOptions:
    """How the per-pixel score is formed (see :func:`fgcd_cli.changes.detect.detect_changes` for each)."""

    gain_sigma_px: float = 12.0
    shift_radius_px: int = 1
    structure_weight: float = 0.0
    smooth_sigma_px: float = 2.0
    fine_smooth_sigma_px: float = 0.0
    robust_gain_rounds: int = 1
    edge_tolerance_px: int = 0
    edge_contrast: float = 3.0
    suspect_k_high: float = 20.0
    """Hysteresis constants that flag the pixels left out of the gain re-estimation."""
    suspect_k_low: float = 10.0

    @classmethod
    def from_config(cls, score: ScoreConfig, *, suspect: RegionConfig) -> ScoreOptions:
        """The score options of a detector configuration (the suspect threshold is the decision's hysteresis)."""
        return cls(
            gain_sigma_px=score.gain_sigma_px,
            shift_radius_px=score.shift_radius_px,
            structure_weight=score.structure_weight,
            smooth_sigma_px=score.smooth_sigma_px,
            fine_smooth_sigma_px=score.fine_smooth_sigma_px,
            robust_gain_rounds=score.robust_gain_rounds,
            edge_tolerance_px=score.edge_tolerance_px,
            edge_contrast=score.edge_contrast,
            suspect_k_high=suspect.k_high,
            suspect_k_low=suspect.k_low,
        )


@dataclass(kw_only=True)
class PairScore:
    """Result of :func:`score_pair`."""

    score: np.ndarray
    """HxW float32 fused score (dimensionless, background median ~1; 0 outside ``valid``)."""
    normalized: list[np.ndarray]
    """Current images re-lit to the reference by the local gain (float32, reference frame)."""
    medians: list[float]
    """Per-lighting median of the difference cue over the compared pixels (its unit)."""
    robust_rounds: int
    edge_band_fraction: float | None = None
    fine_score: np.ndarray | None = None
    """HxW float32, the same fused score at ``fine_smooth_sigma_px`` (None when off)."""
    clipped_ref: np.ndarray | None = None
    """(K, H, W) bool: per lighting, the pixels clipped in the reference
    (:func:`fgcd_cli.changes.images.clipped_pixels`)."""
    clipped_cur: np.ndarray | None = None
    """(K, H, W) bool: the same in the registered current image, before any re-lighting."""


def _fuse(refs, warped, *, valid, bands, options: ScoreOptions, gain_weight):
    """One pass: normalise each lighting, difference cue per lighting, fuse (mean of cue / its median)."""
    differences, structures, normalized_images = [], [], []
    for ref, current, band in zip(refs, warped, bands):
        normalized = normalize_local_gain(ref, current, sigma_px=options.gain_sigma_px, weight=gain_weight)
        normalized_images.append(normalized)
        differences.append(
            edge_tolerant_difference(
                ref, normalized, radius_px=options.shift_radius_px, edge_radius_px=options.edge_tolerance_px, band=band
            )
        )
        if options.structure_weight > 0:
            structures.append(local_ncc_dissimilarity(to_gray(ref), to_gray(normalized)))
    # Each cue is divided by its median (dimensionless) so lightings of different
    # brightness weigh the same; averaging over lightings suppresses cast-shadow
    # and specular differences that only one light produces.
    medians = [float(np.median(d[valid])) if valid.any() else 0.0 for d in differences]
    fused = np.mean([relative_to_median(d, valid, median=m) for d, m in zip(differences, medians)], axis=0)
    if structures:
        structure = np.mean([relative_to_median(s, valid) for s in structures], axis=0)
        fused = (1.0 - options.structure_weight) * fused + options.structure_weight * structure
    fused, fine = smooth_at_two_scales(
        fused.astype(np.float32), smooth_sigma_px=options.smooth_sigma_px, fine_sigma_px=options.fine_smooth_sigma_px
    )
    if fine is not None:
        fine[~valid] = 0.0
    return np.where(valid, fused, 0.0).astype(np.float32), fine, normalized_images, medians


def smooth_at_two_scales(
    fused: np.ndarray, *, smooth_sigma_px: float, fine_sigma_px: float
) -> tuple[np.ndarray, np.ndarray | None]:
    """The fused score smoothed at ``smooth_sigma_px`` and, when ``0 < fine_sigma_px < smooth_sigma_px``,
    at the finer scale.

    Parameters
    ----------
    fused : ndarray, HxW float32, the unsmoothed fused score.

    Returns
    -------
    (main, fine or None), HxW float32 each; ``main`` is the same whether the fine scale is on or off.
    """
    fine = None
    if 0.0 < fine_sigma_px < smooth_sigma_px:
        fine = cv2.GaussianBlur(fused, (0, 0), fine_sigma_px)
    main = cv2.GaussianBlur(fused, (0, 0), smooth_sigma_px) if smooth_sigma_px > 0 else fused
    return main, fine


def score_pair(
    refs: list[np.ndarray], warped: list[np.ndarray], *, valid: np.ndarray, seen_all: np.ndarray, options: ScoreOptions
) -> PairScore:
    """Fused change score of a reference stack and a current stack resampled into its frame.

    Parameters
    ----------
    refs, warped : lists of K ndarrays, HxW or HxWx3 float32 in [0, 1]
        Reference images and current images in the reference frame, one per lighting.
    valid : ndarray, HxW bool
        Compared pixels (they define the medians).
    seen_all : ndarray, HxW bool
        Pixels that carry data in every current image (weights of the gain fit).
    options : ScoreOptions

    Returns
    -------
    PairScore
    """
    bands = [
        edge_band(ref, radius_px=options.edge_tolerance_px, contrast=options.edge_contrast)
        if options.edge_tolerance_px > 0
        else None
        for ref in refs
    ]
    band_fraction = float(np.mean([b[valid].mean() for b in bands])) if options.edge_tolerance_px > 0 else None
    score, fine, normalized, medians = _fuse(refs, warped, valid=valid, bands=bands, options=options, gain_weight=None)
    # The light-gain field is estimated from unchanged pixels only: a first pass
    # flags what is suspect (above the growing threshold, fused over all
    # lightings), the gain is re-estimated without it, and so on until the
    # suspect set settles. Without this, a change drags the local gain and
    # leaves a halo as wide as the gain window around itself.
    gain_weight = seen_all.astype(np.float32)
    rounds = 0
    for _ in range(options.robust_gain_rounds):
        _, first = robust_hysteresis_threshold(score, valid, k_high=options.suspect_k_high, k_low=options.suspect_k_low)
        suspect = (score > first.low) & valid
        if suspect.mean() > 0.5 * valid.mean():
            break  # more suspect than trusted pixels: nothing sensible to re-estimate from
        suspect = cv2.dilate(suspect.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        new_weight = (seen_all & ~suspect).astype(np.float32)
        if rounds and np.array_equal(new_weight, gain_weight):
            break
        gain_weight = new_weight
        score, fine, normalized, medians = _fuse(
            refs, warped, valid=valid, bands=bands, options=options, gain_weight=gain_weight
        )
        rounds += 1
    return PairScore(
        score=score,
        normalized=normalized,
        medians=medians,
        robust_rounds=rounds,
        edge_band_fraction=band_fraction,
        fine_score=fine,
        clipped_ref=np.array([clipped_pixels(ref) for ref in refs]),
        clipped_cur=np.array([clipped_pixels(current) for current in warped]),
    )
