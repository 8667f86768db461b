"""FDF (feature displacement field) and AFD (average feature displacement) between two images.

The authors' protocol (rACR, paper 000; ``docs/change-detection.md``, "FDF / AFD"): SIFT on
both grayscale images, ratio-test matching, RANSAC homography, keep the inliers;
FDF is the field of inlier displacement vectors, AFD their mean length in pixels
of the input image. AFD depends on every one of these settings, so each value
carries them. Under strong lighting change the authors picked 20-100 point pairs
on a regular grid: :func:`compute_fdf` with ``method="grid"`` does it automatically
(phase correlation of gradient-orientation patches), ``method="pairs"`` takes pairs
given by a person.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path

import cv2
import numpy as np

from fgcd_cli.changes.images import image_health, to_float_image, to_gray
from fgcd_cli.changes.registration import (
    MIN_GRADIENT_CORRELATION,
    ecc_gradient,
    match_sift,
    ransac_homography,
    warp_to_reference,
)
from fgcd_cli.errors import AlgorithmError, UserInputError
from fgcd_cli.metrics.orientation_correlation import orientation_field, phase_correlate_orientation


@dataclass(kw_only=True)
class FdfResult:
    """A feature displacement field and its average length."""

    points_ref: np.ndarray
    """Nx2 float64, pixel coordinates (x, y) in the reference image."""
    points_cur: np.ndarray
    """Nx2 float64, the same features in the current image."""
    afd_px: float
    """Mean displacement length, pixels of the input image (NaN when N = 0)."""
    inliers: int
    """Number of displacement vectors kept (N)."""
    candidates: int
    """Matches (or grid cells, or pairs) before outlier rejection."""
    method: str
    settings: dict = field(default_factory=dict)
    image_size: tuple[int, int] = (0, 0)
    """(width, height) of the reference image, pixels."""

    @property
    def displacements(self) -> np.ndarray:
        """Nx2 float64, ``points_cur - points_ref`` (pixels)."""
        return self.points_cur - self.points_ref

    def as_dict(self) -> dict:
        """Plain summary for JSON (no point arrays)."""
        lengths = np.linalg.norm(self.displacements, axis=1) if self.inliers else np.zeros(0)
        return {
            "afd_px": self.afd_px,
            "median_px": float(np.median(lengths)) if lengths.size else float("nan"),
            "max_px": float(lengths.max()) if lengths.size else float("nan"),
            "inliers": self.inliers,
            "candidates": self.candidates,
            "method": self.method,
            "image_size": list(self.image_size),
            "settings": self.settings,
        }


def _prepare(image: np.ndarray, name: str) -> np.ndarray:
    return to_gray(to_float_image(image, name=name))


def _result(points_ref, points_cur, *, candidates, method, settings, shape) -> FdfResult:
    lengths = np.linalg.norm(points_cur - points_ref, axis=1)
    return FdfResult(
        points_ref=points_ref,
        points_cur=points_cur,
        afd_px=float(lengths.mean()) if lengths.size else float("nan"),
        inliers=int(len(points_ref)),
        candidates=int(candidates),
        method=method,
        settings=settings,
        image_size=(int(shape[1]), int(shape[0])),
    )


#: The whole-image shift the grid's start falls back on is measured at this fraction of the resolution: a
#: quarter turns a 40-60 px motion into 10-15 px, well inside a whole-image window.
COARSE_SHIFT_SCALE = 0.25


def _coarse_shift(ref_gray: np.ndarray, cur_gray: np.ndarray) -> np.ndarray:
    """The whole image's shift, (3, 3): phase correlation of the two orientation fields at
    :data:`COARSE_SHIFT_SCALE` of the resolution, Hann-windowed, scaled back to pixels.

    Why: ECC from no motion converges only within a few pixels at its coarsest level, so a start
    2-3 degrees off (40-60 px) is refused; the shift of the edges' layout across the whole image
    reaches it whatever the light (docs/lab/2026-12-06-stele-across-suns-per-surface.md).
    """
    size = (
        max(16, round(ref_gray.shape[1] * COARSE_SHIFT_SCALE)),
        max(16, round(ref_gray.shape[0] * COARSE_SHIFT_SCALE)),
    )
    a = orientation_field(cv2.resize(np.asarray(ref_gray, np.float32), size, interpolation=cv2.INTER_AREA))
    b = orientation_field(cv2.resize(np.asarray(cur_gray, np.float32), size, interpolation=cv2.INTER_AREA))
    window = cv2.createHanningWindow(size, cv2.CV_32F)
    (dx, dy), _ = phase_correlate_orientation(a, b, window)
    return np.array([[1.0, 0.0, dx / COARSE_SHIFT_SCALE], [0.0, 1.0, dy / COARSE_SHIFT_SCALE], [0.0, 0.0, 1.0]])


def _grid_start(ref_gray: np.ndarray, cur_gray: np.ndarray) -> tuple[np.ndarray, float]:
    """The whole-image motion the cells start from, (3, 3), and its correlation: ECC on gradient magnitude
    from no motion, else from the whole image's shift (:func:`_coarse_shift`); the identity and NaN when
    both diverge or correlate below ``changes.registration.MIN_GRADIENT_CORRELATION``, the bar ``fgcd
    diff``'s registration trusts.

    Why: a patch correlated from no motion reaches only a fraction of its own size; the whole image's
    gradients bring every cell within reach of a motion several patches wide (the image stage's
    fallback after a far start; measured: docs/change-detection.md, "FDF / AFD").
    """
    starts = (lambda: np.eye(3), lambda: _coarse_shift(ref_gray, cur_gray))  # the shift only when needed
    for start in starts:
        try:
            H, correlation = ecc_gradient(ref_gray, cur_gray, start())
        except cv2.error:
            continue
        if np.isfinite(correlation) and correlation >= MIN_GRADIENT_CORRELATION:
            return H, correlation
    return np.eye(3), float("nan")


def _grid_fdf(ref_gray, cur_gray, *, grid_cells: int, patch_px: int, min_response: float, ransac_px: float):
    """Phase correlation of gradient-orientation patches on a regular grid, from the whole image's motion.

    Hand-written loop over cells (OpenCV has no block-wise phase correlation). The
    doubled-angle gradients (:mod:`fgcd_cli.metrics.orientation_correlation`) make the
    patches insensitive to light gain and to an edge's polarity (a groove lit from the
    other side); the Hann window suppresses the patch borders. The current
    image's gradients are first warped into the reference's pixels by the
    whole-image motion (:func:`_grid_start`), so each cell measures only what is
    left of it; each cell's match is mapped back through that motion.
    """
    h, w = ref_gray.shape
    patch = int(min(patch_px, h // 2, w // 2))
    patch -= patch % 2
    H_start, _ = _grid_start(ref_gray, cur_gray)
    field_ref = orientation_field(ref_gray)
    field_cur = orientation_field(cur_gray)
    real_cur, covered = warp_to_reference(np.ascontiguousarray(field_cur.real), H_start, ref_gray.shape)
    imag_cur, _ = warp_to_reference(np.ascontiguousarray(field_cur.imag), H_start, ref_gray.shape)
    window = cv2.createHanningWindow((patch, patch), cv2.CV_32F)
    xs = np.linspace(patch / 2, w - patch / 2, grid_cells)
    ys = np.linspace(patch / 2, h - patch / 2, grid_cells)
    points_ref, points_cur = [], []
    half = patch // 2
    for cy in ys:
        for cx in xs:
            x0, y0 = int(round(cx)) - half, int(round(cy)) - half
            a = field_ref[y0 : y0 + patch, x0 : x0 + patch]
            if np.abs(a).std() < 1e-4 or covered[y0 : y0 + patch, x0 : x0 + patch].mean() < 0.9:
                continue
            centre = np.array([x0 + half - 0.5, y0 + half - 0.5])
            # Windowed phase correlation is biased towards zero shift; re-centre the
            # current patch on the estimate and correlate again until the residual vanishes.
            shift = np.zeros(2)
            response = 0.0
            for _ in range(4):
                at = tuple(centre + shift)
                b = cv2.getRectSubPix(real_cur, (patch, patch), at) + 1j * cv2.getRectSubPix(
                    imag_cur, (patch, patch), at
                )
                if np.abs(b).std() < 1e-4:
                    response = 0.0
                    break
                (dx, dy), response = phase_correlate_orientation(a, b, window)
                shift += (dx, dy)
                if np.hypot(dx, dy) < 0.01:
                    break
            if response < min_response:
                continue
            # phaseCorrelate returns the shift of b relative to a: content at p in a is at p + d in b.
            points_ref.append(centre)
            points_cur.append(centre + shift)
    candidates = len(points_ref)
    if candidates == 0:
        return np.zeros((0, 2)), np.zeros((0, 2)), 0
    points_ref = np.array(points_ref)
    points_cur = _apply_homography(H_start, np.array(points_cur))
    if candidates >= 8:
        # Keep only the cells that agree on one homography (the caller refuses too few).
        _, inliers = ransac_homography(points_ref, points_cur, ransac_px=ransac_px)
        points_ref, points_cur = points_ref[inliers], points_cur[inliers]
    return points_ref, points_cur, candidates


def _apply_homography(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``H`` applied to pixel points ``(x, y)``, (N, 2) -> (N, 2)."""
    p = np.column_stack([points, np.ones(len(points))]) @ np.asarray(H, float).T
    return p[:, :2] / p[:, 2:3]


class FdfMethod(StrEnum):
    """How the displacement field is measured (``FdfResult.method``)."""

    SIFT = "sift"
    """The authors' protocol: SIFT, ratio test, RANSAC homography."""
    GRID = "grid"
    """Phase correlation of gradient-orientation patches on a regular grid, started from the whole image's
    ECC motion on gradient magnitude; RANSAC homography over the cells."""
    PAIRS = "pairs"
    """Point pairs given by a person, as they are."""


@dataclass(frozen=True, kw_only=True)
class FdfConfig:
    """Settings of :func:`compute_fdf` (AFD depends on every one of them, so each result records them)."""

    method: FdfMethod = FdfMethod.SIFT
    ratio: float = 0.75
    """Lowe ratio test threshold (SIFT)."""
    ransac_px: float = 3.0
    """RANSAC homography inlier threshold, pixels."""
    max_features: int = 4000
    """SIFT keypoints per image."""
    min_inliers: int = 12
    """Fewest SIFT inliers for a trustworthy AFD (3x the homography's minimal set). With fewer,
    RANSAC has fitted chance matches (``docs/lab/2026-11-25-code-comment-measurements.md``, "Change detection").
    The grid variant needs 8 agreeing cells and at least half of the correlated ones."""
    grid_cells: int = 8
    """Grid variant: cells per side."""
    patch_px: int = 96
    """Grid variant: patch size, pixels."""
    min_response: float = 0.1
    """Grid variant: minimal phase-correlation peak."""

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "method", FdfMethod(self.method))
        except ValueError:
            raise UserInputError(f"unknown FDF method {self.method!r} (use sift, grid or pairs)") from None


def compute_fdf(
    ref_gray: np.ndarray,
    cur_gray: np.ndarray,
    *,
    pairs: tuple[np.ndarray, np.ndarray] | None = None,
    config: FdfConfig | None = None,
) -> FdfResult:
    """Feature displacement field and AFD from the reference to the current image.

    Parameters
    ----------
    ref_gray, cur_gray : ndarray, HxW (or HxWx3, converted to grey), uint8/uint16/float in [0, 1]
        The two images must have the same size (AFD is in pixels of that size).
    pairs : (Nx2, Nx2) arrays, required for ``method="pairs"``
        Reference and current pixel coordinates (x, y).
    config : FdfConfig, optional
        The method and its settings (default: SIFT, :class:`FdfConfig`).

    Returns
    -------
    FdfResult with its settings recorded. Raises :class:`AlgorithmError` when no
    displacement could be measured, :class:`UserInputError` for bad input.
    """
    ref = _prepare(ref_gray, "reference image")
    cur = _prepare(cur_gray, "current image")
    if ref.shape != cur.shape:
        raise UserInputError(
            f"reference is {ref.shape[1]}x{ref.shape[0]} px, current {cur.shape[1]}x{cur.shape[0]} px: AFD needs equal sizes"
        )
    config = config or FdfConfig()
    method = config.method
    if method in (FdfMethod.SIFT, FdfMethod.GRID):
        for label, image in (("reference", ref), ("current", cur)):
            problem = image_health(image)
            if problem:
                raise AlgorithmError(
                    f"cannot measure AFD: {label} {problem} "
                    "(neither SIFT nor the grid variant can; point pairs picked by hand can: --pairs)"
                )
    if config.method == FdfMethod.SIFT:
        return _sift_fdf(ref, cur, config)
    if config.method == FdfMethod.GRID:
        return _grid_result(ref, cur, config)
    return _pairs_fdf(ref, pairs)


def _sift_fdf(ref: np.ndarray, cur: np.ndarray, config: FdfConfig) -> FdfResult:
    """The authors' protocol: SIFT matches, RANSAC homography, its inliers."""
    settings = {
        "detector": "SIFT (OpenCV)",
        "ratio": config.ratio,
        "model": "homography",
        "ransac_px": config.ransac_px,
        "max_features": config.max_features,
    }
    points_ref, points_cur = match_sift(ref, cur, ratio=config.ratio, max_features=config.max_features)
    _, inliers = ransac_homography(points_ref, points_cur, ransac_px=config.ransac_px)
    if inliers.sum() < config.min_inliers:
        raise AlgorithmError(
            f"AFD: only {int(inliers.sum())} SIFT inliers out of {len(points_ref)} matches (need {config.min_inliers}); "
            "try the lighting-robust grid variant (--grid) or give point pairs (--pairs)"
        )
    return _result(
        points_ref[inliers],
        points_cur[inliers],
        candidates=len(points_ref),
        method=FdfMethod.SIFT.value,
        settings=settings,
        shape=ref.shape,
    )


def _grid_result(ref: np.ndarray, cur: np.ndarray, config: FdfConfig) -> FdfResult:
    """The grid variant: correlated cells that agree on one homography (8 at least, half of the correlated)."""
    settings = {
        "detector": "phase correlation of gradient-orientation patches",
        "grid_cells": config.grid_cells,
        "patch_px": config.patch_px,
        "min_response": config.min_response,
        "model": "homography",
        "ransac_px": config.ransac_px,
    }
    points_ref, points_cur, candidates = _grid_fdf(
        ref,
        cur,
        grid_cells=config.grid_cells,
        patch_px=config.patch_px,
        min_response=config.min_response,
        ransac_px=config.ransac_px,
    )
    if len(points_ref) < 8 or len(points_ref) < 0.5 * candidates:
        raise AlgorithmError(
            f"AFD (grid): only {len(points_ref)} of {candidates} correlated cells ({config.grid_cells**2} in the grid) "
            "agree on one motion; no reliable displacement (do the images overlap?)"
        )
    return _result(
        points_ref, points_cur, candidates=candidates, method=FdfMethod.GRID.value, settings=settings, shape=ref.shape
    )


def _pairs_fdf(ref: np.ndarray, pairs: tuple[np.ndarray, np.ndarray] | None) -> FdfResult:
    """Point pairs given by a person, as they are."""
    if pairs is None:
        raise UserInputError("method 'pairs' needs point pairs")
    points_ref = np.asarray(pairs[0], dtype=np.float64).reshape(-1, 2)
    points_cur = np.asarray(pairs[1], dtype=np.float64).reshape(-1, 2)
    if len(points_ref) != len(points_cur) or len(points_ref) == 0:
        raise UserInputError("point pairs: need the same, non-zero number of reference and current points")
    return _result(
        points_ref,
        points_cur,
        candidates=len(points_ref),
        method=FdfMethod.PAIRS.value,
        settings={"source": "user-supplied pairs"},
        shape=ref.shape,
    )


def read_pairs_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read point pairs from a CSV file with columns ``x_ref, y_ref, x_cur, y_cur`` (header optional).

    Returns (points_ref Nx2, points_cur Nx2) float64 pixels.
    """
    rows = []
    with open(path, newline="") as handle:
        for line_no, row in enumerate(csv.reader(handle), start=1):
            cells = [c.strip() for c in row if c.strip()]
            if not cells or cells[0].startswith("#"):
                continue
            try:
                values = [float(c) for c in cells]
            except ValueError:
                if line_no == 1:
                    continue  # header
                raise UserInputError(f"{path}: line {line_no}: expected 4 numbers x_ref,y_ref,x_cur,y_cur") from None
            if len(values) != 4:
                raise UserInputError(
                    f"{path}: line {line_no}: expected 4 numbers x_ref,y_ref,x_cur,y_cur, got {len(values)}"
                )
            rows.append(values)
    if not rows:
        raise UserInputError(f"{path}: no point pairs")
    array = np.array(rows)
    return array[:, :2], array[:, 2:]
