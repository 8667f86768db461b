"""Epipolar search: the inverse depth of reference pixels from one neighbour keyframe.

High-gradient pixels of the reference keyframe are searched along their
epipolar line in the neighbour (sum of squared differences of a mean-free 5x5
pattern over a sampled inverse-depth range), refined to sub-pixel precision by
Gauss-Newton on the same cost along the line, and given an inverse-depth
variance from the photometric and geometric error (Engel et al. 2013),
vectorised with ``cv2.remap`` for sampling. Rectified ``StereoSGBM`` was the
alternative; the epipolar search works for any relative motion (including
forward motion, where rectification degenerates) and yields a per-pixel
uncertainty (docs/vse.md, "Design and why", item 4).

Images are undistorted float32 in [0, 1]; poses are 4x4; inverse depths in
1/map units.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np

__all__ = ["PATTERN", "EpipolarSearchConfig", "GradientImage", "image_gradients", "epipolar_search"]

# 5x5 pattern (25 pixels): over the short keyframe baselines of an exploration
# (1-2 % of the depth) the match error is dominated by the noise of the reference
# pattern itself, shared by every neighbour (fusing more neighbours does not
# average it out), so the pattern's support is what lowers it; rotations between
# keyframes are a few degrees, so the larger support costs no accuracy
# (docs/vse.md, "Design and why", item 4).
PATTERN = np.array([(x, y) for y in range(-2, 3) for x in range(-2, 3)], dtype=float)


def image_gradients(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Central-difference gradients (per pixel) of a float32 image."""
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=1, scale=0.5)
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=1, scale=0.5)
    return gx, gy


def _sample(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``img`` at float coordinates of any shape (NaN outside)."""
    shape = x.shape
    n = x.size
    cols = 1024
    rows = (n + cols - 1) // cols
    mx = np.full(rows * cols, -10.0, np.float32)
    my = np.full(rows * cols, -10.0, np.float32)
    mx[:n] = x.ravel()
    my[:n] = y.ravel()
    out = cv2.remap(
        img,
        mx.reshape(rows, cols),
        my.reshape(rows, cols),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=np.nan,
    )
    return out.ravel()[:n].reshape(shape)


@dataclass(frozen=True, kw_only=True)
class EpipolarSearchConfig:
    """Options of :func:`epipolar_search`.

    Attributes
    ----------
    noise_sigma : float
        Image noise, grey levels on the [0, 1] scale.
    geometric_sigma_px : float
        Error of the epipolar line position from pose and calibration errors, pixels.
    max_samples : int
        Most inverse-depth samples along a line (the lines' 95th-percentile
        length at 0.8 px per sample, at least 8).
    uniqueness : float
        The best cost must be below this fraction of the best cost more than
        two samples away.
    max_cost_per_px : float
        Largest mean-free SSD per pattern pixel of a match, before and after refinement.
    chunk : int
        Reference pixels searched at once (memory).
    """

    noise_sigma: float = 2.0 / 255.0
    geometric_sigma_px: float = 0.1
    max_samples: int = 160
    uniqueness: float = 0.7
    max_cost_per_px: float = (12.0 / 255.0) ** 2
    chunk: int = 2048


class GradientImage(NamedTuple):
    """An undistorted float32 image in [0, 1] (H, W) with its x and y gradients (:func:`image_gradients`)."""

    image: np.ndarray
    gx: np.ndarray
    gy: np.ndarray

    @classmethod
    def of(cls, image: np.ndarray) -> GradientImage:
        return cls(image, *image_gradients(image))


class _EpipolarLines:
    """Neighbour pixels of reference pixels (m, 2) as a function of their inverse depth."""

    def __init__(self, K: np.ndarray, T_nb_ref: np.ndarray, pix: np.ndarray) -> None:
        R, t = T_nb_ref[:3, :3], T_nb_ref[:3, 3]
        ph = np.column_stack([pix, np.ones(len(pix))])
        self.A = (K @ R @ (np.linalg.inv(K) @ ph.T)).T  # (m, 3)
        self.B = K @ t  # (3,)

    def __call__(self, rho: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (..., 2) and neighbour-camera depth factors (...) at inverse depths ``rho`` ((m,) or (m, M))."""
        a = self.A if rho.ndim == 1 else self.A[:, None, :]
        q = a + rho[..., None] * self.B
        return q[..., :2] / q[..., 2:3], q[..., 2]


def _pattern_at(img: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Samples (..., P) of the pattern centred at pixels ``q`` (..., 2)."""
    sx = q[..., 0][..., None] + PATTERN[..., 0]
    sy = q[..., 1][..., None] + PATTERN[..., 1]
    return _sample(img, sx, sy)


def _mean_free(v: np.ndarray) -> np.ndarray:
    return v - v.mean(axis=-1, keepdims=True)


def _discrete_search(
    nb_img: np.ndarray,
    lines: _EpipolarLines,
    ref_v: np.ndarray,
    lo: float,
    hi: float,
    M: int,
    cfg: EpipolarSearchConfig,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Best of ``M`` inverse-depth samples in ``[lo, hi]`` by mean-free SSD: ``(rho (m,), ok (m,), step)``."""
    m = len(ref_v)
    rhos = np.linspace(lo, hi, M)
    step = (hi - lo) / (M - 1)
    q, zq = lines(np.broadcast_to(rhos, (m, M)))  # (m, M, 2), (m, M)
    nb_v = _mean_free(_pattern_at(nb_img, q))  # (m, M, P)
    cost = np.sum((nb_v - ref_v[:, None, :]) ** 2, axis=2)
    cost[~np.isfinite(cost) | (zq <= 0)] = np.inf
    best = np.argmin(cost, axis=1)
    bcost = cost[np.arange(m), best]
    # uniqueness: best cost outside +-2 samples of the minimum
    far = np.abs(np.arange(M)[None, :] - best[:, None]) > 2
    second = np.where(far, cost, np.inf).min(axis=1)
    ok = (
        np.isfinite(bcost)
        & (best > 0)
        & (best < M - 1)
        & (bcost < cfg.uniqueness * second)
        & (bcost < cfg.max_cost_per_px * len(PATTERN))
    )
    return lo + best * step, ok, step


def _refine_along_line(
    nb: GradientImage, lines: _EpipolarLines, ref_v: np.ndarray, rho: np.ndarray, step: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Newton on the same cost along the line (3 iterations, steps within one sample).

    Returns the inverse depths (m,), the line direction ``dq`` (m, 2) in pixels
    per unit inverse depth and the Gauss-Newton curvature ``H`` (m,) at the last iteration.
    """
    for _ in range(3):
        qq, _z = lines(rho)
        dq = (lines(rho + 1e-3 * step)[0] - lines(rho - 1e-3 * step)[0]) / (2e-3 * step)
        val = _pattern_at(nb.image, qq)
        gx = _pattern_at(nb.gx, qq)
        gy = _pattern_at(nb.gy, qq)
        r = _mean_free(val) - ref_v
        J = _mean_free(gx * dq[:, 0:1] + gy * dq[:, 1:2])
        H = np.sum(J * J, axis=1)
        g = np.sum(J * r, axis=1)
        d = -g / np.maximum(H, 1e-20)
        d = np.clip(d, -step, step)
        d[~np.isfinite(d)] = 0.0
        rho = rho + d
    return rho, dq, H


def _inverse_depth_sigma(
    ref_g: tuple[np.ndarray, np.ndarray], dq: np.ndarray, H: np.ndarray, cfg: EpipolarSearchConfig
) -> np.ndarray:
    """One-sigma inverse depth (m,): photometric (noise through the gradient along the line) and
    geometric (line position error through the gradient across it) error, Engel et al. 2013,
    plus a 0.05 px floor; ``ref_g`` are the reference gradients (m,) at the pixels."""
    gxr, gyr = ref_g
    dq_norm = np.linalg.norm(dq, axis=1)
    line = dq / np.maximum(dq_norm, 1e-12)[:, None]
    H_px = H / np.maximum(dq_norm, 1e-12) ** 2  # sum (g . l)^2, intensity^2 per px^2
    sig_photo_px = cfg.noise_sigma * np.sqrt(2.0) / np.sqrt(np.maximum(H_px, 1e-20))
    g_along = np.abs(gxr * line[:, 0] + gyr * line[:, 1])
    g_perp = np.abs(-gxr * line[:, 1] + gyr * line[:, 0])
    sig_geo_px = cfg.geometric_sigma_px * g_perp / np.maximum(g_along, 1e-6)
    sig_px = np.sqrt(sig_photo_px**2 + sig_geo_px**2 + 0.05**2)
    return sig_px / np.maximum(dq_norm, 1e-12)


def _search_chunk(
    ref: GradientImage,
    nb: GradientImage,
    T_nb_ref: np.ndarray,
    K: np.ndarray,
    pix: np.ndarray,
    inv_depth_range: tuple[float, float],
    cfg: EpipolarSearchConfig,
):
    """:func:`epipolar_search` for pixels ``pix`` (m, 2) float: ``(rho, sigma, ok)`` or None when no line is finite."""
    lo, hi = float(inv_depth_range[0]), float(inv_depth_range[1])
    h, w = nb.image.shape
    m = len(pix)
    lines = _EpipolarLines(K, T_nb_ref, pix)
    p_lo, _ = lines(np.full(m, lo))
    p_hi, _ = lines(np.full(m, hi))
    length = np.linalg.norm(p_hi - p_lo, axis=1)
    finite_len = length[np.isfinite(length)]
    if finite_len.size == 0:
        return None
    M = int(np.clip(np.ceil(np.percentile(finite_len, 95) / 0.8) + 1, 8, cfg.max_samples))
    ref_v = _mean_free(_pattern_at(ref.image, pix))  # (m, P)
    rho, ok, step = _discrete_search(nb.image, lines, ref_v, lo, hi, M, cfg)
    rho, dq, H = _refine_along_line(nb, lines, ref_v, rho, step)
    ok &= np.isfinite(rho) & (rho > 0)
    u, v = pix[:, 0].astype(int), pix[:, 1].astype(int)
    sig_rho = _inverse_depth_sigma((ref.gx[v, u], ref.gy[v, u]), dq, H, cfg)
    # final check on the refined cost
    qq, zz = lines(rho)
    rc = np.sum((_mean_free(_pattern_at(nb.image, qq)) - ref_v) ** 2, axis=1)
    ok &= np.isfinite(rc) & (rc < cfg.max_cost_per_px * len(PATTERN)) & (zz > 0)
    ok &= (qq[:, 0] > 2) & (qq[:, 0] < w - 3) & (qq[:, 1] > 2) & (qq[:, 1] < h - 3)
    return rho, sig_rho, ok


def epipolar_search(
    ref: GradientImage,
    nb: GradientImage,
    T_nb_ref: np.ndarray,
    K: np.ndarray,
    pixels: np.ndarray,
    inv_depth_range: tuple[float, float],
    *,
    config: EpipolarSearchConfig | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Inverse depth of reference pixels from one neighbour keyframe.

    The mean-free SSD of :data:`PATTERN` is minimised over inverse-depth
    samples along the epipolar line, refined by Gauss-Newton along the line
    and given a variance (see the module docstring).

    Parameters
    ----------
    ref, nb : GradientImage
        Undistorted reference and neighbour images, [0, 1], with their gradients.
    T_nb_ref : (4, 4) ndarray
        Pose of the reference camera in the neighbour camera frame (map units).
    K : (3, 3) ndarray
        Pinhole intrinsics of both images.
    pixels : (N, 2) int ndarray
        Reference pixels ``(u, v)``.
    inv_depth_range : (float, float)
        Search interval of inverse depth, 1/map units.
    config : EpipolarSearchConfig, optional
        Options (default: :class:`EpipolarSearchConfig`).

    Returns
    -------
    inv_depth : (N,) ndarray
        NaN where the search failed (out of view, ambiguous, bad match).
    inv_depth_sigma : (N,) ndarray
    """
    cfg = config if config is not None else EpipolarSearchConfig()
    n = len(pixels)
    out_rho = np.full(n, np.nan)
    out_sig = np.full(n, np.nan)
    for s in range(0, n, cfg.chunk):
        pix = pixels[s : s + cfg.chunk].astype(float)
        found = _search_chunk(ref, nb, T_nb_ref, K, pix, inv_depth_range, cfg)
        if found is None:
            continue
        rho, sig_rho, ok = found
        out_rho[s : s + len(pix)][ok] = rho[ok]
        out_sig[s : s + len(pix)][ok] = sig_rho[ok]
    return out_rho, out_sig
