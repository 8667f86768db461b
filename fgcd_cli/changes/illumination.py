"""Illumination normalization between a registered current image and the reference."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

_ONE = np.ones((1, 1), np.float32)

_COLUMN_BAND_PX = 64
"""Width of the bands in which the column pass of a wide blur runs (its rows then stay in cache)."""


def _gaussian_blur(image: np.ndarray, sigma_px: float) -> np.ndarray:
    """``cv2.GaussianBlur(image, (0, 0), sigma_px)``, with its kernel and border, faster for wide float32 kernels.

    OpenCV's separable filter spends most of a wide kernel's time in its row pass;
    ``filter2D`` with the same one-row kernel computes the same sums several times
    faster. The column pass stays the separable one, run on bands of
    :data:`_COLUMN_BAND_PX` columns (each column is filtered alone, so the values
    are the same; the kernel's rows of a narrow band fit in cache). The result
    equals ``GaussianBlur``'s to float32 rounding (most frames: bit for bit).
    """
    ksize = int(round(sigma_px * 8 + 1)) | 1  # GaussianBlur's size for float images: 4 sigma each side
    h, w = image.shape[:2]
    if image.dtype != np.float32 or ksize < 49 or min(h, w) < ksize:
        return cv2.GaussianBlur(image, (0, 0), sigma_px)
    kernel = cv2.getGaussianKernel(ksize, sigma_px, cv2.CV_32F)
    rows = cv2.filter2D(image, -1, kernel.reshape(1, -1), borderType=cv2.BORDER_REFLECT_101).reshape(image.shape)
    out = np.empty_like(rows)
    for x0 in range(0, w, _COLUMN_BAND_PX):
        band = (slice(None), slice(x0, min(w, x0 + _COLUMN_BAND_PX)))
        done = cv2.sepFilter2D(rows[band], -1, _ONE, kernel, dst=out[band], borderType=cv2.BORDER_REFLECT_101)
        if not np.may_share_memory(done, out):  # OpenCV wrote elsewhere
            out[band] = done.reshape(out[band].shape)
    return out


def smooth_large(image: np.ndarray, sigma_px: float, *, window: tuple[slice, slice] | None = None) -> np.ndarray:
    """Gaussian blur of scale ``sigma_px``, computed on a reduced grid when the scale is large.

    For sigma >= 24 px the image is area-averaged by ``f = floor(sigma / 3)`` (a box
    of variance f^2/12, subtracted from the Gaussian's), blurred there and resized
    back bilinearly: ~8x faster than the full kernel, with errors of a few percent
    of the image's contrast where it has sharp edges (the box aliases them), so it
    is for the wide fallback window of the gain, not for the gain itself. Smaller
    scales use the exact kernel.

    Parameters
    ----------
    image : ndarray, HxW or HxWxC float32
    sigma_px : float, Gaussian scale in pixels of ``image``
    window : (rows, columns) slices, optional
        Return only this part of the result (the same values; on the reduced grid,
        only these pixels are resized back).

    Returns
    -------
    ndarray, float32, the shape of ``image`` (of ``window``)
    """
    factor = int(sigma_px // 3)
    h, w = image.shape[:2]
    if factor < 8 or min(h, w) < 8 * factor:
        out = _gaussian_blur(image, sigma_px)
        return out if window is None else np.ascontiguousarray(out[window])
    small = cv2.resize(image, (int(np.ceil(w / factor)), int(np.ceil(h / factor))), interpolation=cv2.INTER_AREA)
    sigma_small = np.sqrt(max(sigma_px**2 - factor**2 / 12.0, 1e-6)) / factor
    small = cv2.GaussianBlur(small, (0, 0), sigma_small, borderType=cv2.BORDER_REFLECT)
    rows, cols = (slice(0, h), slice(0, w)) if window is None else window
    y0, y1, _ = rows.indices(h)
    x0, x1, _ = cols.indices(w)
    # Map output pixel centres onto the reduced grid (pixel-centre convention of INTER_AREA).
    xs = (np.arange(x0, x1, dtype=np.float32) + 0.5) / factor - 0.5
    ys = (np.arange(y0, y1, dtype=np.float32) + 0.5) / factor - 0.5
    map_x = np.broadcast_to(xs[None, :], (y1 - y0, x1 - x0)).astype(np.float32)
    map_y = np.broadcast_to(ys[:, None], (y1 - y0, x1 - x0)).astype(np.float32)
    out = cv2.remap(small, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape((y1 - y0, x1 - x0) + image.shape[2:]).astype(np.float32, copy=False)


_WIDE_SUPPORT = 0.05
"""Below this narrow-window support (blurred weight) the gain blends towards the 4x wider window."""

Region = tuple[slice, slice]
"""Rows and columns (slices with positive steps of 1) of a part of an image."""


def _bounds(shape: tuple[int, ...], region: Region | None) -> tuple[int, int, int, int]:
    h, w = shape[:2]
    if region is None:
        return 0, h, 0, w
    y0, y1, _ = region[0].indices(h)
    x0, x1, _ = region[1].indices(w)
    return y0, y1, x0, x1


def _smooth_region(image: np.ndarray, sigma_px: float, region: Region | None) -> np.ndarray:
    """``smooth_large(image, sigma_px)[region]``, blurring only the pixels within the kernel's reach of ``region``.

    The exact kernel reads ``4 sigma_px`` around each pixel, so the region grown by that
    (clipped to the image, whose border is reflected as before) gives the same values.
    The reduced grid of wide scales is anchored at the image's corner: computed whole.
    """
    if region is None:
        return smooth_large(image, sigma_px)
    h, w = image.shape[:2]
    if int(sigma_px // 3) >= 8 and min(h, w) >= 8 * int(sigma_px // 3):
        return smooth_large(image, sigma_px, window=region)
    y0, y1, x0, x1 = _bounds(image.shape, region)
    reach = (int(round(sigma_px * 8 + 1)) | 1) // 2
    gy0, gy1, gx0, gx1 = max(0, y0 - reach), min(h, y1 + reach), max(0, x0 - reach), min(w, x1 + reach)
    return smooth_large(image[gy0:gy1, gx0:gx1], sigma_px)[y0 - gy0 : y1 - gy0, x0 - gx0 : x1 - gx0]


@dataclass(frozen=True, kw_only=True)
class GainWeight:
    """A gain weight and its blurs, shared by every lighting (see :func:`prepare_gain_weight`).

    Arrays are replicated over the images' channels, so that the per-lighting
    arithmetic runs on arrays of one shape (numpy broadcasting over a last axis
    of 1 is several times slower).
    """

    sigma_px: float
    shape: tuple[int, ...]
    """Shape of the images the weight applies to."""
    region: Region | None
    """Part of the images where the gain is wanted (None: everywhere)."""
    weight: np.ndarray
    """float32, the images' shape."""
    denom: np.ndarray
    """``max(blur(weight, sigma_px), 1e-6)`` inside ``region``."""
    window: Region | None
    """Rows and columns of the region (relative to it) that hold every pixel where the wide window
    contributes (None: nowhere)."""
    wide_denom: np.ndarray | None
    """The same as ``denom`` for the wide window (``4 sigma_px``), inside ``window``."""
    alpha: np.ndarray | None
    """Blend weight of the narrow window inside ``window`` (the wide one has ``1 - alpha``)."""
    one_minus_alpha: np.ndarray | None


def _replicate(plane: np.ndarray, channels: int) -> np.ndarray:
    return plane if channels == 0 else cv2.merge([plane] * channels).reshape(plane.shape + (channels,))


def _shift(window: Region, y0: int, x0: int) -> Region:
    return slice(window[0].start + y0, window[0].stop + y0), slice(window[1].start + x0, window[1].stop + x0)


def prepare_gain_weight(
    weight: np.ndarray, sigma_px: float, image_shape: tuple[int, ...], *, region: Region | None = None
) -> GainWeight:
    """Blur a gain weight once, for :func:`normalize_local_gain` on several lightings of the same frame.

    Parameters
    ----------
    weight : ndarray, HxW float in [0, 1], trust of each pixel (see :func:`normalize_local_gain`).
    sigma_px : float, Gaussian scale of the gain field, pixels.
    image_shape : tuple, shape of the images it will weight (HxW or HxWxC).
    region : (rows, columns) slices, optional
        Part of the images where the gain will be wanted (see :func:`normalize_local_gain`).

    Returns
    -------
    GainWeight
    """
    w = np.asarray(weight, dtype=np.float32)
    channels = image_shape[2] if len(image_shape) == 3 else 0
    y0, _, x0, _ = _bounds(w.shape, region)
    support = _smooth_region(w, sigma_px, region)
    wide_denom = window = alpha = one_minus_alpha = None
    if float(support.min()) < _WIDE_SUPPORT:
        low = support < _WIDE_SUPPORT
        rows, cols = np.flatnonzero(low.any(axis=1)), np.flatnonzero(low.any(axis=0))
        window = (slice(int(rows[0]), int(rows[-1]) + 1), slice(int(cols[0]), int(cols[-1]) + 1))
        wide = smooth_large(w, 4.0 * sigma_px)[_shift(window, y0, x0)]
        wide_denom = _replicate(np.maximum(wide, 1e-6), channels)
        alpha = _replicate(np.clip(support[window] / _WIDE_SUPPORT, 0.0, 1.0), channels)
        one_minus_alpha = 1.0 - alpha
    return GainWeight(
        sigma_px=float(sigma_px),
        shape=tuple(image_shape),
        region=region,
        weight=_replicate(w, channels),
        denom=_replicate(np.maximum(support, 1e-6), channels),
        window=window,
        wide_denom=wide_denom,
        alpha=alpha,
        one_minus_alpha=one_minus_alpha,
    )


def _gain_ratio(mean_ref: np.ndarray, mean_cur: np.ndarray, denom: np.ndarray, floor: float) -> np.ndarray:
    """``(mean_ref / denom + floor) / (mean_cur / denom + floor)``, in place."""
    np.divide(mean_ref, denom, out=mean_ref)
    mean_ref += floor
    np.divide(mean_cur, denom, out=mean_cur)
    mean_cur += floor
    return np.divide(mean_ref, mean_cur, out=mean_ref)


def normalize_local_gain(
    ref_image: np.ndarray,
    cur_warped: np.ndarray,
    *,
    sigma_px: float = 12.0,
    floor: float = 0.01,
    weight: np.ndarray | GainWeight | None = None,
    region: Region | None = None,
) -> np.ndarray:
    """Correct a smooth, spatially varying light gain on the current image.

    The gain ``G = mean_ref / mean_cur`` (local Gaussian means, per channel)
    absorbs light falloff, exposure and white-balance differences whose scale is
    larger than ``sigma_px``; changes smaller than that survive.

    A change inside the window biases the local means: a dark spot of a few
    hundred pixels lowers ``mean_cur`` and brightens its unchanged surroundings
    by 20-50 %, a halo as wide as the window. ``weight`` (0 on pixels suspected
    of change) makes the means weighted (normalized convolution), so the gain
    there is interpolated from the unchanged surroundings.

    Parameters
    ----------
    ref_image, cur_warped : ndarray, HxW or HxWx3 float32 in [0, 1], same frame.
    sigma_px : float
        Gaussian scale of the gain field, pixels.
    floor : float
        Added to both means so dark areas do not explode the gain.
    weight : ndarray, HxW float in [0, 1], or GainWeight, optional
        Trust of each pixel for the gain estimate (None: all pixels count).
        Where the weighted window holds almost no trusted pixel, a 4x wider
        window is used. A :class:`GainWeight` (:func:`prepare_gain_weight`, same
        ``sigma_px`` and ``region``) saves blurring the same weight again for every lighting.
    region : (rows, columns) slices, optional
        Return only this part of the result: the same values, with the local means
        taken on the whole images (only the pixels they read are blurred).

    Returns
    -------
    ndarray, the current image with the gain applied (float32, the shape of the images or of ``region``).
    """
    y0, y1, x0, x1 = _bounds(np.shape(ref_image), region)
    if weight is None:
        gain = _smooth_region(ref_image, sigma_px, region)
        gain += floor
        mean_cur = _smooth_region(cur_warped, sigma_px, region)
        mean_cur += floor
        np.divide(gain, mean_cur, out=gain)
        return (cur_warped[y0:y1, x0:x1] * gain).astype(np.float32, copy=False)
    if not isinstance(weight, GainWeight):
        weight = prepare_gain_weight(weight, sigma_px, np.shape(ref_image), region=region)
    elif (
        weight.sigma_px != float(sigma_px)
        or weight.shape != np.shape(ref_image)
        or _bounds(weight.shape, weight.region) != (y0, y1, x0, x1)
    ):
        raise ValueError(
            f"gain weight prepared for sigma {weight.sigma_px}, shape {weight.shape} and region "
            f"{weight.region}, used with sigma {sigma_px}, shape {np.shape(ref_image)} "
            f"and region {region}"
        )
    weighted_ref, weighted_cur = weight.weight * ref_image, weight.weight * cur_warped
    gain = _gain_ratio(
        _smooth_region(weighted_ref, sigma_px, region),
        _smooth_region(weighted_cur, sigma_px, region),
        weight.denom,
        floor,
    )
    if weight.window is not None:
        window = weight.window
        inside = _shift(window, y0, x0)
        wide = _gain_ratio(
            smooth_large(weighted_ref, 4.0 * sigma_px, window=inside),
            smooth_large(weighted_cur, 4.0 * sigma_px, window=inside),
            weight.wide_denom,
            floor,
        )
        # Blend smoothly towards the wide estimate where the narrow window has little support
        # (alpha is 1, and the narrow gain kept as it is, outside the window).
        gain[window] = weight.alpha * gain[window] + weight.one_minus_alpha * wide
    return (cur_warped[y0:y1, x0:x1] * gain).astype(np.float32, copy=False)


def shading_from_normals(normals_cam: np.ndarray, light_dir_cam: np.ndarray) -> np.ndarray:
    """Lambertian shading ``max(0, n·l)`` for per-pixel normals and one light direction.

    Parameters
    ----------
    normals_cam : ndarray, HxWx3 float, unit normals in the camera frame (NaN where unknown).
    light_dir_cam : ndarray, 3, direction towards the light in the camera frame.

    Returns
    -------
    ndarray, HxW float32 in [0, 1] (0 where the normal is unknown).
    """
    light = np.asarray(light_dir_cam, dtype=np.float64)
    light = light / np.linalg.norm(light)
    shading = np.einsum("hwc,c->hw", np.nan_to_num(normals_cam.astype(np.float64)), light)
    return np.clip(shading, 0.0, 1.0).astype(np.float32)


def normalize_shading(
    ref_image: np.ndarray,
    cur_warped: np.ndarray,
    *,
    shading_ref: np.ndarray,
    shading_cur: np.ndarray,
    min_shading: float = 0.05,
) -> np.ndarray:
    """Re-light the current image to the reference's lighting with known shading maps.

    With per-pixel normals (from the observation's 3D points) and the capture's
    light direction, albedo ``= image / shading``; the current image is divided by
    its own shading and multiplied by the reference's, so only albedo or geometry
    changes remain. Pixels with shading below ``min_shading`` keep their value.

    Parameters
    ----------
    ref_image, cur_warped : ndarray, HxW or HxWx3 float32, reference frame.
    shading_ref, shading_cur : ndarray, HxW float32, shading of each capture in the reference frame.
    """
    ratio = np.where(
        (shading_cur > min_shading) & (shading_ref > min_shading),
        shading_ref / np.maximum(shading_cur, min_shading),
        1.0,
    ).astype(np.float32)
    if cur_warped.ndim == 3:
        ratio = ratio[:, :, None]
    return np.clip(cur_warped * ratio, 0.0, 1.0).astype(np.float32)
