"""Baseline change score after Feng et al., ICCV 2015, for ``fgcd bench changes``.

W. Feng, F.-P. Tian, Q. Zhang, N. Zhang, L. Wan, J. Sun, "Fine-Grained Change
Detection of Misaligned Scenes with Varied Illuminations", ICCV 2015. The
method compares a reference and a current observation, each a stack of K
images from (almost) one camera pose under K lightings (one ambient, the others
directional), in three steps: dense alignment, lighting correction, and a
low-rank + sparse separation whose sparse part is the change. This module is
the project's re-implementation of its key ideas, kept as a named *baseline*
that the benchmark (``fgcd bench changes``) compares the project's detector
against. It is not the authors' code and does not reproduce their figures.

Implemented
-----------
* **Normal-aware lighting correction.** Under the Lambertian model the ratio of
  the current to the reference intensity of an unchanged pixel under lighting
  ``k`` depends on its surface normal only (``n . l'_k / n . l_k``), not on its
  albedo. The pixels are grouped by their reference normal (spherical k-means on
  the uncalibrated pseudo-normals of
  :func:`fgcd_cli.changes.photometric.stereo.joint_photometric_stereo`, both
  observations in one basis), and each (lighting, normal group) gets one gain,
  the median log ratio of its pixels (robust: changes are a few percent of
  the pixels). Near lights also make the ratio drift across the image; a smooth
  spatial log gain (robust normalised convolution) is fitted in alternation
  with the group gains. The paper estimates a per-pixel correction field
  regularised towards equal corrections for equal normals; the piecewise
  constant (group) x smooth (space) model is a cheap stand-in for it.
* **Low-rank + sparse separation across the lightings.** The reference images
  and the corrected current images are the rows of a ``2K x N`` matrix (one
  column per valid pixel, each image divided by the median level of its
  reference lighting). Unchanged Lambertian pixels make it low rank (rank 3
  for the directional lights, plus the ambient image), a change breaks the
  agreement of a pixel's two halves and lands in a sparse part. The matrix is
  split ``M = L + S`` with ``rank(L) <= rank`` by alternating projections
  (GoDec-like: rank-r truncation of ``M - S``, soft threshold of ``M - L`` at a
  multiple of the robust column scale), instead of the paper's convex
  optimisation.
* **Error maps averaged over the lightings.** The change error of lighting k
  is ``|S_cur_k - S_ref_k|`` (a deviation common to both observations, e.g. a
  cast shadow or a highlight that the rank-r model cannot explain, cancels),
  and the score is their mean over the K lightings, lightly smoothed with a
  Gaussian in place of the paper's smoothness term.

Replaced or left out
--------------------
* **SIFT-flow alignment** (and the paper's joint coarse-to-fine refinement of
  flow, lighting and change) is not implemented: the current images must
  already be registered into the reference frame by the project's registration
  (:func:`fgcd_cli.changes.registration.register_to_reference` and
  :func:`fgcd_cli.changes.registration.warp_to_reference`). Residual
  misalignment is therefore not corrected here.
* The images are compared in grey (channel mean, :func:`fgcd_cli.changes.images.to_gray`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from fgcd_cli.changes.images import to_float_image, to_gray
from fgcd_cli.changes.photometric.stereo import joint_photometric_stereo
from fgcd_cli.errors import UserInputError

_KMEANS_SAMPLES = 50_000  # normals entering the spherical k-means
_KMEANS_ITERATIONS = 12
_MIN_GROUP_PIXELS = 200  # a normal group smaller than this takes the lighting's global gain
_EPS_FRACTION = 0.02  # log-ratio floor, relative to the lighting's median reference level
_SPATIAL_FACTOR = 4  # the spatial gain is fitted on a grid this many times coarser
_CORRECTION_ROUNDS = 2  # alternations of group gains and spatial gain
_LOWRANK_ITERATIONS = 6
_MAD_SAMPLES = 30_000  # residuals entering each row's robust scale
_MAD_TO_SIGMA = 1.4826


@dataclass(kw_only=True)
class ICCV2015Result:
    """Result of :func:`iccv2015_details`.

    Attributes
    ----------
    score : ndarray, HxW float32
        Change score, >= 0, larger = more likely changed (units: fraction of
        the median reference level, averaged over the lightings); 0 outside ``valid``.
    error_maps : ndarray, KxHxW float32
        Per-lighting change error ``|S_cur_k - S_ref_k|`` before averaging and
        smoothing (same units); 0 outside ``valid``.
    normal_groups : ndarray, HxW int32
        Normal group of each pixel, 0..n_normal_bins-1; ``n_normal_bins`` where
        the reference normal is unknown, -1 outside ``valid``.
    group_log_gains : ndarray, K x (n_normal_bins + 1) float64
        Log gain of each (lighting, normal group) removed from the current
        images (natural log, current over reference); the last column is the
        group of unknown normals.
    """

    score: np.ndarray
    error_maps: np.ndarray
    normal_groups: np.ndarray
    group_log_gains: np.ndarray


def _normal_groups(normals: np.ndarray, n_groups: int, seed: int = 0) -> np.ndarray:
    """Spherical k-means of unit normals (M x 3) -> group index per normal (M,) int32."""
    if normals.shape[0] == 0 or n_groups <= 1:
        return np.zeros(normals.shape[0], np.int32)
    rng = np.random.default_rng(seed)
    sample = normals[rng.choice(normals.shape[0], min(_KMEANS_SAMPLES, normals.shape[0]), replace=False)]
    n_groups = min(n_groups, sample.shape[0])
    # k-means++ seeding on 1 - cos distance.
    centres = [sample[rng.integers(sample.shape[0])]]
    distance = 1.0 - sample @ centres[0]
    for _ in range(1, n_groups):
        p = np.maximum(distance, 0.0)
        p = p / p.sum() if p.sum() > 0 else None
        centres.append(sample[rng.choice(sample.shape[0], p=p)])
        distance = np.minimum(distance, 1.0 - sample @ centres[-1])
    centres = np.array(centres)
    for _ in range(_KMEANS_ITERATIONS):
        label = np.argmax(sample @ centres.T, axis=1)
        sums = np.zeros_like(centres)
        np.add.at(sums, label, sample)
        norms = np.linalg.norm(sums, axis=1)
        keep = norms > 0
        centres[keep] = sums[keep] / norms[keep, None]
    return np.argmax(normals @ centres.T, axis=1).astype(np.int32)


def _group_medians(values: np.ndarray, order: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Median of ``values`` within each group; ``order`` sorts the pixels by group, ``starts`` bounds them."""
    sorted_values = values[order]
    out = np.zeros(starts.size - 1)
    for g in range(starts.size - 1):
        chunk = sorted_values[starts[g] : starts[g + 1]]
        if chunk.size >= _MIN_GROUP_PIXELS:
            out[g] = np.median(chunk)
        else:
            out[g] = np.nan
    return out


def _smooth_field(residual: np.ndarray, index: np.ndarray, shape: tuple[int, int], sigma_px: float) -> np.ndarray:
    """Robust smooth field of per-pixel residuals (N,) on the valid pixels ``index``; returns (N,).

    Normalised convolution at ``1/_SPATIAL_FACTOR`` resolution; residuals beyond
    3 robust sigmas (changes) get no weight.
    """
    h, w = shape
    scale = _MAD_TO_SIGMA * np.median(np.abs(residual - np.median(residual))) + 1e-6
    weight = (np.abs(residual - np.median(residual)) < 3.0 * scale).astype(np.float32)
    full_v = np.zeros(h * w, np.float32)
    full_w = np.zeros(h * w, np.float32)
    full_v[index] = residual * weight
    full_w[index] = weight
    hs, ws = max(1, h // _SPATIAL_FACTOR), max(1, w // _SPATIAL_FACTOR)
    small_v = cv2.resize(full_v.reshape(h, w), (ws, hs), interpolation=cv2.INTER_AREA)
    small_w = cv2.resize(full_w.reshape(h, w), (ws, hs), interpolation=cv2.INTER_AREA)
    sigma = sigma_px / _SPATIAL_FACTOR
    blur_v = cv2.GaussianBlur(small_v, (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)
    blur_w = cv2.GaussianBlur(small_w, (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)
    field = np.where(blur_w > 1e-3, blur_v / np.maximum(blur_w, 1e-6), 0.0).astype(np.float32)
    return cv2.resize(field, (w, h), interpolation=cv2.INTER_LINEAR).ravel()[index]


def _low_rank_sparse(m: np.ndarray, rank: int, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """Split ``m`` (C x N: one row per image, one column per pixel) into a rank-``rank`` and a sparse part.

    Alternating projections: ``L`` = best rank-r approximation of ``m - S``
    (eigen-decomposition of the C x C Gram matrix, N >> C); ``S`` = soft
    threshold of ``m - L`` at ``threshold`` robust sigmas of each row's
    residual. Returns (L, S), both C x N float32.
    """
    c, n = m.shape
    rank = int(min(max(rank, 1), c))
    rng = np.random.default_rng(0)
    probe = np.sort(rng.choice(n, min(n, _MAD_SAMPLES), replace=False))
    m = np.ascontiguousarray(m, dtype=np.float32)
    s = np.zeros_like(m)
    low = m
    for _ in range(_LOWRANK_ITERATIONS):
        a = m - s
        gram = (a @ a.T).astype(np.float64)
        _, vectors = np.linalg.eigh(gram)
        basis = vectors[:, -rank:]  # C x r: the top left-singular vectors
        projector = (basis @ basis.T).astype(np.float32)
        low = projector @ a
        residual = np.subtract(m, low, out=a)
        sample = residual[:, probe]
        centre = np.median(sample, axis=1, keepdims=True)
        sigma = _MAD_TO_SIGMA * np.median(np.abs(sample - centre), axis=1, keepdims=True) + 1e-6
        tau = (threshold * sigma).astype(np.float32)
        # Soft threshold: the residual minus its clip to [-tau, tau].
        s = residual - np.clip(residual, -tau, tau)
    return low, s


@dataclass(frozen=True, kw_only=True)
class ICCV2015Config:
    """Settings of the ICCV 2015 baseline (:func:`iccv2015_details`)."""

    n_normal_bins: int = 16
    """Number of normal groups of the lighting correction (spherical k-means on the reference
    pseudo-normals), >= 1. 1: one global gain per lighting."""
    rank: int = 3
    """Rank of the no-change part of the ``2K x N`` matrix (reference and corrected current images
    as rows): 3 for Lambertian surfaces under directional lights; an ambient image adds one."""
    spatial_sigma_px: float | None = 40.0
    """Gaussian sigma (pixels) of the smooth spatial log gain fitted together with the group gains
    (near lights); None: group gains only."""
    sparse_threshold: float = 2.0
    """Soft threshold of the sparse part, in robust sigmas (1.4826 MAD) of each column's residual."""
    smooth_sigma_px: float = 2.0
    """Gaussian sigma (pixels) applied to the averaged error map; 0: none."""


def iccv2015_details(
    ref_images: list[np.ndarray],
    cur_images: list[np.ndarray],
    *,
    valid: np.ndarray,
    ambient_index: int | None = 0,
    config: ICCV2015Config | None = None,
) -> ICCV2015Result:
    """ICCV 2015 baseline change score with its intermediate results.

    Parameters
    ----------
    ref_images, cur_images : lists of K ndarrays, HxW or HxWx3, float32 in [0, 1]
        One image per lighting, same lightings in the same order; the current
        images already registered into the reference frame (this baseline does
        no alignment). Integer images are scaled by their dtype's maximum.
    valid : ndarray, HxW bool
        Pixels to score (e.g. the evaluation mask and the registered overlap).
    ambient_index : int or None
        The ambient image, left out of the photometric stereo that gives the
        normals (it still enters the correction, the separation and the
        average); None if all images are directional. At least 3 directional
        images are needed.
    config : ICCV2015Config, optional
        The settings (default: :class:`ICCV2015Config`).

    Returns
    -------
    ICCV2015Result
    """
    config = config or ICCV2015Config()
    refs, curs, valid = _checked_inputs(ref_images, cur_images, valid, config)
    shape = refs[0].shape[:2]
    h, w = shape
    k_count = len(refs)
    index = np.flatnonzero(valid.ravel())
    n_groups = config.n_normal_bins + 1  # the last group: unknown normals
    if index.size < 10 * n_groups:
        return ICCV2015Result(
            score=np.zeros(shape, np.float32),
            error_maps=np.zeros((k_count, h, w), np.float32),
            normal_groups=np.full(shape, -1, np.int32),
            group_log_gains=np.zeros((k_count, n_groups)),
        )

    # 1. Normals of the reference, in the basis shared with the current observation.
    fit_ref, _ = joint_photometric_stereo(refs, curs, valid=valid, ambient_index=ambient_index)
    normals = fit_ref.normals.reshape(-1, 3)[index]
    known = np.all(np.isfinite(normals), axis=1)
    group = np.full(index.size, config.n_normal_bins, np.int32)
    group[known] = _normal_groups(normals[known].astype(np.float64), config.n_normal_bins)

    # 2. Normal-aware lighting correction of the current images (log domain).
    x = np.stack([to_gray(im).ravel()[index] for im in refs])  # K x N
    y = np.stack([to_gray(im).ravel()[index] for im in curs])
    levels = np.maximum(np.median(x, axis=1), 1e-4)  # K
    corrected, gains = _corrected_current(x, y, group, levels, index=index, shape=shape, config=config)

    # 3. Low-rank + sparse separation of [reference | corrected current], one row per pixel.
    m = np.concatenate([x, corrected], axis=0) / np.concatenate([levels, levels])[:, None]  # 2K x N
    _, sparse = _low_rank_sparse(m, config.rank, config.sparse_threshold)
    errors = np.abs(sparse[k_count:] - sparse[:k_count])  # K x N

    # 4. Error maps, averaged over the lightings and smoothed.
    error_maps = np.zeros((k_count, h * w), np.float32)
    error_maps[:, index] = errors
    error_maps = error_maps.reshape(k_count, h, w)
    score = error_maps.mean(axis=0)
    if config.smooth_sigma_px > 0:
        weight = cv2.GaussianBlur(valid.astype(np.float32), (0, 0), config.smooth_sigma_px)
        score = cv2.GaussianBlur(score, (0, 0), config.smooth_sigma_px) / np.maximum(weight, 1e-6)
    score = np.where(valid, score, 0.0).astype(np.float32)
    groups_map = np.full(h * w, -1, np.int32)
    groups_map[index] = group
    return ICCV2015Result(
        score=score, error_maps=error_maps, normal_groups=groups_map.reshape(h, w), group_log_gains=gains
    )


def _checked_inputs(ref_images, cur_images, valid, config: ICCV2015Config):
    """The stacks as float32 [0, 1] and the valid mask as bool; raises UserInputError for bad input."""
    if len(ref_images) != len(cur_images):
        raise UserInputError(f"{len(ref_images)} reference image(s) but {len(cur_images)} current image(s)")
    if config.n_normal_bins < 1:
        raise UserInputError(f"n_normal_bins must be >= 1, got {config.n_normal_bins}")
    if config.rank < 1:
        raise UserInputError(f"rank must be >= 1, got {config.rank}")
    refs = [to_float_image(im, name=f"reference image {i + 1}") for i, im in enumerate(ref_images)]
    curs = [to_float_image(im, name=f"current image {i + 1}") for i, im in enumerate(cur_images)]
    shape = refs[0].shape[:2]
    for im in refs + curs:
        if im.shape[:2] != shape:
            raise UserInputError(f"all images must have one size; got {im.shape[:2]} and {shape}")
    valid = np.asarray(valid, bool)
    if valid.shape != shape:
        raise UserInputError(f"valid mask is {valid.shape}, images are {shape}")
    return refs, curs, valid


def _corrected_current(x, y, group, levels, *, index, shape, config: ICCV2015Config):
    """The current grey levels (K x N) corrected by a log gain per lighting and normal group (and, with
    ``spatial_sigma_px``, a smooth spatial log gain fitted alternately); returns them and the group gains."""
    n_groups = config.n_normal_bins + 1
    order = np.argsort(group, kind="stable")
    starts = np.searchsorted(group[order], np.arange(n_groups + 1))
    k_count = x.shape[0]
    eps = (_EPS_FRACTION * levels)[:, None]
    log_ratio = np.log(y + eps) - np.log(x + eps)
    gains = np.zeros((k_count, n_groups))
    corrected = np.empty_like(y)
    for k in range(k_count):
        field = np.zeros(index.size, np.float32)
        for _ in range(_CORRECTION_ROUNDS if config.spatial_sigma_px else 1):
            g = _group_medians(log_ratio[k] - field, order, starts)
            fallback = float(np.median(log_ratio[k] - field))
            g = np.where(np.isfinite(g), g, fallback)
            if config.spatial_sigma_px:
                field = _smooth_field(log_ratio[k] - g[group], index, shape, config.spatial_sigma_px)
        gains[k] = g
        corrected[k] = (y[k] + eps[k]) * np.exp(-(g[group] + field)) - eps[k]
    return corrected, gains


def iccv2015_score(
    ref_images: list[np.ndarray],
    cur_images: list[np.ndarray],
    *,
    valid: np.ndarray,
    ambient_index: int | None = 0,
    config: ICCV2015Config | None = None,
) -> np.ndarray:
    """Change score of the ICCV 2015 baseline (Feng et al.; see the module docstring).

    Parameters are those of :func:`iccv2015_details`.

    Returns
    -------
    ndarray, HxW float32
        Change score >= 0, larger = more likely changed (fraction of the
        median reference level, averaged over the lightings); 0 outside ``valid``.
    """
    return iccv2015_details(ref_images, cur_images, valid=valid, ambient_index=ambient_index, config=config).score
