"""The dense refinement's smooth field: a robust local-polynomial fit of a raw flow (:mod:`fgcd_cli.changes.dense.refine`).

Confidence-weighted local-polynomial normalized convolution (Knutsson & Westin,
CVPR 1993; Farnebaeck 2002 for the separable applicability) with a Gaussian
applicability, iterated with Cauchy weights (IRLS); the scale that keeps a change
of a given size from steering it is :func:`smoothing_scale_px`.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

MAX_CHANGE_PX = 60.0
"""Diameter (px) of the largest compact change the refinement must leave intact."""

CHANGE_SHARE = 0.25
"""Largest share of the smoothing window a change of ``MAX_CHANGE_PX`` may hold at its centre."""

FIT_ORDER = 2
"""Degree of the local polynomial fitted to the flow (0, 1 or 2)."""

RIDGE = 0.05
"""Ridge on the non-constant coefficients of the local fit, as a fraction of the window's
weight. It keeps a one-sided window (frame border, edge of ``valid``) from extrapolating;
where the support surrounds the pixel it hardly matters (``docs/lab/2026-11-25-code-comment-measurements.md``,
"Change detection")."""


def smoothing_scale_px(
    change_px: float = MAX_CHANGE_PX, *, share: float = CHANGE_SHARE, order: int = FIT_ORDER
) -> float:
    """Gaussian scale of the flow fit that keeps a change of ``change_px`` from steering it.

    With uniform weights, a local polynomial fit with a Gaussian window ``g`` of
    scale ``sigma`` is a linear filter (its equivalent kernel). At the centre of a
    disc of diameter ``D`` (``U = (D/2)^2 / (2 sigma^2)``), the disc's share of that
    kernel is ``1 - exp(-U)`` for a local constant or linear fit (the slope terms
    vanish at the centre by symmetry) and ``1 - (1 - U) exp(-U)`` for a local
    quadratic (kernel ``g(r) (2 - r^2 / (2 sigma^2))``). Setting the share to
    ``share`` and solving for ``sigma`` gives the scale.

    Parameters
    ----------
    change_px : float
        Diameter of the largest compact change to keep, pixels.
    share : float
        Largest share of the fit that change may hold, in (0, 1).
    order : int
        Degree of the local fit: 0, 1 or 2.

    Returns
    -------
    float, Gaussian sigma in pixels (60 px, 25 %: 39.6 px for order 0-1, 57.0 px for order 2).
    """
    if not 0.0 < share < 1.0:
        raise ValueError(f"share must lie in (0, 1), got {share}")
    if order <= 1:
        u = math.log(1.0 / (1.0 - share))
    else:
        # (1 - U) exp(-U) = 1 - share, decreasing in U on [0, 1]: bisection.
        lo, hi = 0.0, 1.0
        for _ in range(60):
            u = 0.5 * (lo + hi)
            lo, hi = (u, hi) if (1.0 - u) * math.exp(-u) > 1.0 - share else (lo, u)
    return float(change_px / 2.0 / math.sqrt(2.0 * u))


def _gaussian_moment_kernels(sigma: float, max_power: int) -> list[np.ndarray]:
    """1-D kernels ``g(d) * (d / sigma)^p`` for p = 0..max_power (g: Gaussian, sum 1)."""
    radius = int(math.ceil(3.0 * sigma))
    d = np.arange(-radius, radius + 1, dtype=np.float64)
    g = np.exp(-0.5 * (d / sigma) ** 2)
    g /= g.sum()
    return [(g * (d / sigma) ** p).astype(np.float32) for p in range(max_power + 1)]


def _monomials(order: int) -> list[tuple[int, int]]:
    """Exponents (px, py) of the 2-D polynomial basis up to ``order``, constant first."""
    return [(px, total - px) for total in range(order + 1) for px in range(total, -1, -1)]


def local_poly_fit(
    values: np.ndarray, weight: np.ndarray, sigma: float, order: int, ridge: float
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted local polynomial fit (normalized convolution, Gaussian applicability).

    For every pixel ``i`` solves ``min sum_j w_j g(x_j - x_i) (v_j - p_i((x_j - x_i)/sigma))^2``
    over polynomials ``p_i`` of degree ``order`` and returns ``p_i(0)`` per channel.
    The weighted moments are separable correlations with ``g(d) (d/sigma)^p``.
    ``ridge`` (a fraction of the local weight) pulls the non-constant coefficients
    to 0 where the support is one-sided or sparse, so the fit degrades to a local
    mean instead of extrapolating.

    Parameters
    ----------
    values : ndarray, HxWxK float32
    weight : ndarray, HxW float32 >= 0
    sigma : float, pixels of this grid
    order : int, 0, 1 or 2
    ridge : float

    Returns
    -------
    fit : ndarray, HxWxK float32 (NaN where the window holds no weight)
    support : ndarray, HxW float32, the Gaussian-weighted mean weight in the window
    """
    kernels = _gaussian_moment_kernels(sigma, 2 * order)

    def corr(image: np.ndarray, px: int, py: int) -> np.ndarray:
        out = cv2.sepFilter2D(image, cv2.CV_32F, kernels[px], kernels[py], borderType=cv2.BORDER_CONSTANT)
        return out.astype(np.float64)

    basis = _monomials(order)
    n = len(basis)
    w = np.ascontiguousarray(weight, dtype=np.float32)
    moments: dict[tuple[int, int], np.ndarray] = {}
    h, wd = w.shape
    A = np.empty((h, wd, n, n))
    for i, (ax, ay) in enumerate(basis):
        for j, (bx, by) in enumerate(basis):
            key = (ax + bx, ay + by)
            if key not in moments:
                moments[key] = corr(w, *key)
            A[..., i, j] = moments[key]
    s00 = moments[(0, 0)]
    for i in range(1, n):
        A[..., i, i] += ridge * s00
    n_values = values.shape[2]
    b = np.empty((h, wd, n, n_values))
    for c in range(n_values):
        wv = np.ascontiguousarray(w * values[..., c])
        for i, (ax, ay) in enumerate(basis):
            b[..., i, c] = corr(wv, ax, ay)
    empty = s00 < 1e-6
    A[empty] = np.eye(n)
    fit = np.linalg.solve(A, b)[..., 0, :].astype(np.float32)
    fit[empty] = np.nan
    return fit, s00.astype(np.float32)


def _block_mean(image: np.ndarray, factor: int) -> np.ndarray:
    """Mean over ``factor`` x ``factor`` blocks (the size must be a multiple of ``factor``)."""
    if factor == 1:
        return image.astype(np.float32)
    h, w = image.shape[:2]
    return cv2.resize(image.astype(np.float32), (w // factor, h // factor), interpolation=cv2.INTER_AREA)


def robust_smooth(
    flow: np.ndarray,
    weight: np.ndarray,
    *,
    sigma_px: float,
    robust_px: float,
    iterations: int,
    order: int,
) -> np.ndarray:
    """Robust large-scale fit of a raw flow field: IRLS around a local polynomial normalized convolution.

    Works on a grid ``factor`` times coarser (weighted block means), ``factor``
    chosen so that ``sigma_px`` spans about 8 cells: the fit is smooth at that
    scale, so bilinear upsampling loses nothing and the cost stays small.

    The start is the non-robust fit at twice the scale: there a change of the
    largest kept size holds ~7 % of the window instead of 25 %, so the start sits
    on the surroundings' motion, and the Cauchy weights of the following
    iterations then reject the change's flow instead of following it. Where the
    window holds little trusted weight (flat or masked areas), the fit falls back
    to the coarser one, then to the global weighted mean.

    Parameters
    ----------
    flow : ndarray, HxWx2 float32, raw flow (px)
    weight : ndarray, HxW float32 in [0, 1], data confidence
    sigma_px : float, Gaussian applicability, full-resolution pixels
    robust_px : float, Cauchy scale of the residual |raw - fit| (px)
    iterations : int, robust re-weightings after the start
    order : int, degree of the local polynomial

    Returns
    -------
    ndarray, HxWx2 float32, the smooth field at full resolution (px).
    """
    h, w = weight.shape
    factor = max(1, int(sigma_px // 8))
    ph, pw = -h % factor, -w % factor
    wpad = cv2.copyMakeBorder(weight.astype(np.float32), 0, ph, 0, pw, cv2.BORDER_CONSTANT, value=0)
    fpad = cv2.copyMakeBorder(flow.astype(np.float32), 0, ph, 0, pw, cv2.BORDER_REFLECT)
    w_grid = _block_mean(wpad, factor)
    f_grid = _block_mean(fpad * wpad[..., None], factor) / np.maximum(w_grid, 1e-6)[..., None]
    sigma = sigma_px / factor
    total = float(w_grid.sum())
    global_mean = (f_grid * w_grid[..., None]).sum(axis=(0, 1)) / total if total > 0 else np.zeros(2)

    def blend(fit: np.ndarray, support: np.ndarray, fallback: np.ndarray) -> np.ndarray:
        # Support = Gaussian-weighted mean weight in the window; at 5 % the two count equally.
        alpha = (support / (support + 0.05))[..., None]
        fit = np.where(np.isfinite(fit), fit, fallback)
        return (alpha * fit + (1.0 - alpha) * fallback).astype(np.float32)

    coarse, support = local_poly_fit(f_grid, w_grid, 2.0 * sigma, order, RIDGE)
    coarse = blend(coarse, support, np.broadcast_to(global_mean.astype(np.float32), f_grid.shape))
    fit = coarse
    for _ in range(iterations):
        residual = np.hypot(f_grid[..., 0] - fit[..., 0], f_grid[..., 1] - fit[..., 1])
        robust = 1.0 / (1.0 + (residual / robust_px) ** 2)
        fine, support = local_poly_fit(f_grid, w_grid * robust, sigma, order, RIDGE)
        fit = blend(fine, support, coarse)
    full = cv2.resize(fit, (w + pw, h + ph), interpolation=cv2.INTER_LINEAR)[:h, :w]
    return np.ascontiguousarray(full)
