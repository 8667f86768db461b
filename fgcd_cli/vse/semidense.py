"""Semi-dense depth of a keyframe by epipolar search in neighbouring keyframes.

The method follows LSD-SLAM/DSO: high-gradient pixels of the reference
keyframe (:func:`select_pixels`) are searched along their epipolar line in
each neighbour keyframe (:func:`~fgcd_cli.vse.epipolar.epipolar_search`) and
fused over the neighbours with an outlier-rejecting inverse-variance mean
(:func:`fuse_estimates`). Finally each keyframe's depths are fused with the other keyframes' estimates
of the same surface points (:func:`fuse_across_keyframes`): a depth found from
one reference keyframe keeps that reference's pattern noise however many
neighbours it was matched in, while another keyframe's estimate has its own.

All images are undistorted float32 in [0, 1]; poses are 4x4; inverse depths in
1/map units.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from fgcd_cli.vse.epipolar import PATTERN, EpipolarSearchConfig, GradientImage, epipolar_search, image_gradients  # noqa: F401
from fgcd_core.camera import pinhole_pixels

__all__ = [
    "SemiDenseDepth",
    "EpipolarSearchConfig",
    "KeyframeDepthConfig",
    "GradientImage",
    "select_pixels",
    "image_gradients",
    "epipolar_search",
    "fuse_estimates",
    "keyframe_depth",
    "fuse_across_keyframes",
]


@dataclass(frozen=True, kw_only=True)
class SemiDenseDepth:
    """Fused semi-dense depth of one keyframe.

    Attributes
    ----------
    pixels : (N, 2) float ndarray
        ``(u, v)`` pixels in the (undistorted) keyframe image.
    inv_depth : (N,) ndarray
        Fused inverse depth, 1/map units.
    inv_depth_sigma : (N,) ndarray
        One-sigma uncertainty of the inverse depth.
    n_views : (N,) int ndarray
        Neighbour keyframes whose estimate agreed.
    intensities : (N,) float32 ndarray
        Grey value of the pixel.
    """

    pixels: np.ndarray
    inv_depth: np.ndarray
    inv_depth_sigma: np.ndarray
    n_views: np.ndarray
    intensities: np.ndarray

    @property
    def depth(self) -> np.ndarray:
        """z-depth in map units."""
        return 1.0 / self.inv_depth

    @property
    def depth_sigma(self) -> np.ndarray:
        """One-sigma z-depth uncertainty, first order, map units."""
        return self.inv_depth_sigma / self.inv_depth**2


def select_pixels(
    image: np.ndarray, *, grad_threshold: float, max_points: int, cell_px: int = 4, border_px: int = 6
) -> np.ndarray:
    """High-gradient pixels, at most one per ``cell_px`` square, strongest first.

    Parameters
    ----------
    image : (H, W) float32 ndarray
        Undistorted keyframe, [0, 1].
    grad_threshold : float
        Minimum gradient magnitude in grey levels (0-255) per pixel; the local
        threshold also adapts to the median gradient of 32-pixel blocks (DSO).

    Returns
    -------
    (N, 2) int ndarray of ``(u, v)``.
    """
    img = image.astype(np.float32) * 255.0
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    mag = np.sqrt(gx * gx + gy * gy)
    h, w = mag.shape
    # adaptive threshold: median of 32x32 blocks (upsampled) + constant
    bh, bw = max(1, h // 32), max(1, w // 32)
    blocks = mag[: bh * 32, : bw * 32].reshape(bh, 32, bw, 32).transpose(0, 2, 1, 3).reshape(bh, bw, -1)
    med = np.median(blocks, axis=2).astype(np.float32)
    med_full = cv2.resize(med, (w, h), interpolation=cv2.INTER_LINEAR)
    thr = np.maximum(grad_threshold, med_full + 0.5 * grad_threshold)
    score = np.where(mag >= thr, mag, 0.0)
    score[:border_px] = 0
    score[-border_px:] = 0
    score[:, :border_px] = 0
    score[:, -border_px:] = 0
    ch, cw = h // cell_px, w // cell_px
    cells = (
        score[: ch * cell_px, : cw * cell_px]
        .reshape(ch, cell_px, cw, cell_px)
        .transpose(0, 2, 1, 3)
        .reshape(ch, cw, -1)
    )
    arg = np.argmax(cells, axis=2)
    best = np.take_along_axis(cells, arg[..., None], axis=2)[..., 0]
    cy, cx = np.nonzero(best > 0)
    a = arg[cy, cx]
    v = cy * cell_px + a // cell_px
    u = cx * cell_px + a % cell_px
    order = np.argsort(-best[cy, cx])[:max_points]
    return np.column_stack([u[order], v[order]]).astype(int)


def fuse_estimates(
    rho: np.ndarray, sigma: np.ndarray, *, gate: float = 2.5
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Outlier-rejecting inverse-variance fusion of per-neighbour estimates.

    Parameters
    ----------
    rho, sigma : (N, V) ndarrays
        Inverse depths and sigmas from V neighbours, NaN where missing.
    gate : float
        Estimates further than ``gate`` combined sigmas from the weighted median are dropped.

    Returns
    -------
    rho_fused, sigma_fused : (N,) ndarrays
    n_views : (N,) int ndarray
    """
    valid = np.isfinite(rho) & np.isfinite(sigma) & (sigma > 0)
    wts = np.where(valid, 1.0 / np.where(valid, sigma, 1.0) ** 2, 0.0)
    r0 = np.where(valid, rho, 0.0)
    # weighted median as anchor
    order = np.argsort(np.where(valid, rho, np.inf), axis=1)
    rs = np.take_along_axis(r0, order, axis=1)
    ws = np.take_along_axis(wts, order, axis=1)
    cw = np.cumsum(ws, axis=1)
    tot = cw[:, -1:]
    k = np.argmax(cw >= 0.5 * np.maximum(tot, 1e-300), axis=1)
    anchor = rs[np.arange(len(rs)), k]
    s_anchor = np.take_along_axis(np.where(valid, sigma, np.inf), order, axis=1)[np.arange(len(rs)), k]
    keep = valid & (
        np.abs(r0 - anchor[:, None]) <= gate * np.sqrt(np.where(valid, sigma, 0.0) ** 2 + s_anchor[:, None] ** 2)
    )
    wk = np.where(keep, wts, 0.0)
    W = wk.sum(axis=1)
    n_views = keep.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        fused = np.where(W > 0, (wk * r0).sum(axis=1) / W, np.nan)
        sig = np.where(W > 0, 1.0 / np.sqrt(W), np.nan)
    return fused, sig, n_views


@dataclass(frozen=True, kw_only=True)
class KeyframeDepthConfig:
    """Options of :func:`keyframe_depth`.

    Attributes
    ----------
    grad_threshold : float
        Minimum gradient of a candidate pixel, grey levels (0-255) per pixel (:func:`select_pixels`).
    max_points : int
        Most candidate pixels.
    cell_px : int
        At most one candidate pixel per ``cell_px`` square.
    min_views : int
        Agreeing neighbours a pixel needs (capped at the number of neighbours).
    max_rel_sigma : float
        Maximum depth sigma over depth of a kept point.
    noise_sigma : float
        Image noise, grey levels on the [0, 1] scale (:class:`EpipolarSearchConfig`).
    """

    grad_threshold: float = 6.0
    max_points: int = 12000
    cell_px: int = 3
    min_views: int = 2
    max_rel_sigma: float = 0.02
    noise_sigma: float = 2.0 / 255.0


def keyframe_depth(
    ref_img: np.ndarray,
    neighbors: list[tuple[np.ndarray, np.ndarray]],
    K: np.ndarray,
    inv_depth_range: tuple[float, float],
    *,
    config: KeyframeDepthConfig | None = None,
) -> SemiDenseDepth:
    """Semi-dense depth of a reference keyframe from its neighbours.

    Parameters
    ----------
    ref_img : (H, W) float32 ndarray
        Undistorted reference image, [0, 1].
    neighbors : list of (image, T_nb_ref)
        Undistorted neighbour images and the reference pose in each neighbour frame.
    K : (3, 3) ndarray
        Pinhole intrinsics.
    inv_depth_range : (float, float)
        Inverse-depth search interval (from the sparse map).
    config : KeyframeDepthConfig, optional
        Options (default: :class:`KeyframeDepthConfig`).

    Returns
    -------
    SemiDenseDepth
    """
    cfg = config if config is not None else KeyframeDepthConfig()
    pixels = select_pixels(ref_img, grad_threshold=cfg.grad_threshold, max_points=cfg.max_points, cell_px=cfg.cell_px)
    if len(pixels) == 0 or not neighbors:
        return SemiDenseDepth(
            pixels=np.zeros((0, 2)),
            inv_depth=np.zeros(0),
            inv_depth_sigma=np.zeros(0),
            n_views=np.zeros(0, int),
            intensities=np.zeros(0, np.float32),
        )
    ref = GradientImage.of(ref_img)
    search = EpipolarSearchConfig(noise_sigma=cfg.noise_sigma)
    rhos, sigs = [], []
    for nb_img, T_nb_ref in neighbors:
        r, s = epipolar_search(ref, GradientImage.of(nb_img), T_nb_ref, K, pixels, inv_depth_range, config=search)
        rhos.append(r)
        sigs.append(s)
    rho, sig, nv = fuse_estimates(np.column_stack(rhos), np.column_stack(sigs))
    need = min(cfg.min_views, len(neighbors))
    keep = np.isfinite(rho) & (rho > 0) & (nv >= need) & (sig / np.maximum(rho, 1e-12) < cfg.max_rel_sigma)
    px = pixels[keep]
    return SemiDenseDepth(
        pixels=px.astype(float),
        inv_depth=rho[keep],
        inv_depth_sigma=sig[keep],
        n_views=nv[keep],
        intensities=ref_img[px[:, 1], px[:, 0]].astype(np.float32),
    )


def _in_reference(K: np.ndarray, other: tuple, radius_px: float, tree):
    """Another keyframe's points that project within ``radius_px`` of a reference pixel:
    ``(idx, rho, sigma, dist)`` with the reference pixel index, the inverse depth and its sigma
    in the reference camera and the pixel distance; None when there are none."""
    opx, orho, osig, T_ref_o = other
    if len(opx) == 0:
        return None
    rays = (np.linalg.inv(K) @ np.column_stack([opx, np.ones(len(opx))]).T).T
    Xo = rays / orho[:, None]
    Xr = Xo @ T_ref_o[:3, :3].T + T_ref_o[:3, 3]
    z = Xr[:, 2]
    front = z > 1e-9
    if not np.any(front):
        return None
    Xr, z, zo, osig_f = Xr[front], z[front], 1.0 / orho[front], osig[front]
    uv = pinhole_pixels(K, Xr)
    r_new = 1.0 / z
    # sigma in the reference camera: same depth sigma (the views are nearly parallel), rescaled
    s_new = osig_f * zo**2 / z**2
    dist, idx = tree.query(uv, distance_upper_bound=radius_px)
    hit = np.isfinite(dist)
    if not np.any(hit):
        return None
    return idx[hit], r_new[hit], s_new[hit], dist[hit]


def fuse_across_keyframes(
    K: np.ndarray,
    ref: tuple[np.ndarray, np.ndarray, np.ndarray],
    others: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
    *,
    radius_px: float = 0.75,
    gate: float = 2.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fuse a keyframe's inverse depths with other keyframes' estimates of the same surface points.

    The depth of a semi-dense pixel found from one reference keyframe carries
    the noise of that reference's pattern whatever the number of neighbours it
    was matched in (the same reference samples enter every match). Another
    keyframe's estimate of the same surface point has its own reference noise,
    so the two are fused: each point of ``others`` is moved into the reference
    camera, and a reference pixel takes, from each other keyframe, the nearest
    projected point within ``radius_px`` whose inverse depth agrees within
    ``gate`` combined sigmas (inverse-variance mean, as in the multi-keyframe
    fusion of DSO/LSD-SLAM point maps).

    Parameters
    ----------
    K : (3, 3) ndarray
        Pinhole intrinsics (undistorted pixels).
    ref : (pixels (N, 2), inv_depth (N,), inv_depth_sigma (N,))
        The reference keyframe's points.
    others : list of (pixels (M, 2), inv_depth (M,), inv_depth_sigma (M,), T_ref_other (4, 4))
        Other keyframes' points and their camera pose in the reference camera frame.
    radius_px : float
        Largest distance (pixels) between a reference pixel and a projected point.
    gate : float
        Agreement gate in combined sigmas.

    Returns
    -------
    inv_depth, inv_depth_sigma : (N,) ndarrays
        Fused values (unchanged where nothing agreed).
    n_fused : (N,) int ndarray
        Other keyframes that contributed.
    """
    from scipy.spatial import cKDTree

    px, rho, sig = (np.asarray(a, float) for a in ref)
    n = len(px)
    wsum = 1.0 / sig**2
    rsum = rho * wsum
    n_fused = np.zeros(n, int)
    if n == 0 or not others:
        return rho.copy(), sig.copy(), n_fused
    tree = cKDTree(px)
    for other in others:
        found = _in_reference(K, other, radius_px, tree)
        if found is None:
            continue
        idx, r_new, s_new, dist = found
        agree = np.abs(r_new - rho[idx]) <= gate * np.sqrt(s_new**2 + sig[idx] ** 2)
        idx, r_new, s_new, dist = idx[agree], r_new[agree], s_new[agree], dist[agree]
        # one contribution per reference pixel and keyframe: the nearest agreeing projection
        order = np.lexsort((dist, idx))
        first = np.ones(len(order), bool)
        first[1:] = idx[order][1:] != idx[order][:-1]
        sel = order[first]
        i, rn, sn = idx[sel], r_new[sel], s_new[sel]
        wsum[i] += 1.0 / sn**2
        rsum[i] += rn / sn**2
        n_fused[i] += 1
    return rsum / wsum, 1.0 / np.sqrt(wsum), n_fused
