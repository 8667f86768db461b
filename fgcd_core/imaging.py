"""Grey images on declared dtypes, local contrast (CLAHE), SIFT features and matching.

Pixel ranges come from the dtype, never from the values: ``uint8`` is
``[0, 255]``, ``uint16`` is ``[0, 65535]``, floating point (``float32``,
``float64``) is taken as already in ``[0, 1]``. Any other dtype raises
``TypeError``. Colour images are ``(H, W, 3)`` or ``(H, W, 4)`` in RGB(A) order;
the alpha channel is ignored.

Channel rule (:class:`GrayChannels`): Rec. 601 luma
``Y = 0.299 R + 0.587 G + 0.114 B`` by default, computed by OpenCV
(``cv2.COLOR_RGB2GRAY``) in the image's own dtype, so integer images are
rounded to their integer type before scaling; or the plain channel mean where
colour balance must not weigh in.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from enum import StrEnum

import cv2
import numpy as np

__all__ = [
    "GrayChannels",
    "U8Rounding",
    "DescriptorMatcher",
    "to_float01",
    "to_gray_f32",
    "to_gray_u8",
    "clahe",
    "sift_features",
    "match_descriptors",
    "match_sift",
]

#: Full-scale value of each integer dtype (the float dtypes are already in [0, 1]).
_FULL_SCALE = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}
_FLOATS = (np.dtype(np.float32), np.dtype(np.float64))
_LUMA_601 = np.array([0.299, 0.587, 0.114], dtype=np.float32)


class GrayChannels(StrEnum):
    """How a colour image becomes one grey channel."""

    LUMA_601 = "luma601"
    """Rec. 601 luma by ``cv2.cvtColor(RGB2GRAY)`` in the image's dtype (float64 as float32),
    then scaled to [0, 1]: uint8/uint16 luma is rounded to the integer type first."""
    LUMA_601_F32 = "luma601_f32"
    """Rec. 601 luma as a float32 dot product on the image already scaled to [0, 1]
    (scaling multiplies by the float32 reciprocal of the full scale), clipped to [0, 1]:
    no intermediate rounding. The camera sources' pipeline (``fgcd_drivers.cameras``)."""
    MEAN = "mean"
    """``(R + G + B) / 3`` in float32 on the image scaled to [0, 1] (no colour weighting)."""


class U8Rounding(StrEnum):
    """How ``[0, 1]`` floats become 8-bit levels (always clipped to [0, 255])."""

    HALF_UP_F32 = "half_up_f32"
    """``floor(x * 255 + 0.5)`` evaluated in float32."""
    HALF_UP_F64 = "half_up_f64"
    """``floor(x * 255 + 0.5)`` evaluated in float64 (exact for float32 inputs); about 8 in
    10^6 uniform values land one level apart from :attr:`HALF_UP_F32`."""
    TRUNCATE_F32 = "truncate_f32"
    """``floor(x * 255)`` evaluated in float32."""


class DescriptorMatcher(StrEnum):
    """Nearest-neighbour search of :func:`match_descriptors`."""

    BRUTE_FORCE = "brute_force"
    """Exact L2 search (``cv2.BFMatcher``)."""
    FLANN = "flann"
    """Approximate kd-tree search (4 trees, 64 checks; ``cv2.FlannBasedMatcher``)."""


def _checked(image: np.ndarray) -> np.ndarray:
    """The image as an array of a declared dtype and shape (H, W), (H, W, 3) or (H, W, 4)."""
    img = np.asarray(image)
    if img.dtype not in _FULL_SCALE and img.dtype not in _FLOATS:
        raise TypeError(f"image dtype {img.dtype} is not uint8, uint16, float32 or float64")
    if not (img.ndim == 2 or (img.ndim == 3 and img.shape[2] in (3, 4))):
        raise ValueError(f"image shape {img.shape} is neither (H, W) nor (H, W, 3|4)")
    return img


def _scaled_f32(img: np.ndarray) -> np.ndarray:
    """float32 copy in [0, 1]: integer dtypes divided by their full scale, floats cast."""
    full = _FULL_SCALE.get(img.dtype)
    if full is None:
        return np.asarray(img, dtype=np.float32)
    return img.astype(np.float32) / full


def _opencv_luma(img: np.ndarray) -> np.ndarray:
    """Rec. 601 luma by OpenCV in the image's dtype (float64 is computed as float32)."""
    rgb = img[..., :3] if img.dtype != np.float64 else img[..., :3].astype(np.float32)
    return cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)


def _luma_f32(img: np.ndarray) -> np.ndarray:
    """Rec. 601 luma as a float32 dot product after scaling by the reciprocal full scale, clipped."""
    full = _FULL_SCALE.get(img.dtype, 1.0)
    out = img.astype(np.float32) * np.float32(1.0 / full)
    if out.ndim == 3:
        out = out[:, :, :3] @ _LUMA_601
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def to_float01(image: np.ndarray) -> np.ndarray:
    """An image (grey or colour, channels kept) as float32 in [0, 1] by its declared dtype.

    uint8 is divided by 255 and uint16 by 65535; float images are taken as already in
    [0, 1] (cast, not clipped). Other dtypes raise ``TypeError``.

    Parameters
    ----------
    image : (H, W) or (H, W, C) ndarray

    Returns
    -------
    (H, W) or (H, W, C) float32 ndarray
    """
    return _scaled_f32(_checked(image))


def to_gray_f32(image: np.ndarray, *, channels: GrayChannels = GrayChannels.LUMA_601) -> np.ndarray:
    """Grey float32 image in [0, 1] (floats are not clipped) from a grey or colour image.

    Parameters
    ----------
    image : (H, W) or (H, W, 3|4) ndarray
        uint8, uint16, float32 or float64 (floats already in [0, 1]).
    channels : GrayChannels
        Channel rule for colour images (:data:`GrayChannels.LUMA_601_F32` also
        fixes the scaling of grey images, see there).

    Returns
    -------
    (H, W) float32 ndarray
    """
    img = _checked(image)
    if channels == GrayChannels.LUMA_601_F32:
        return _luma_f32(img)
    if img.ndim == 3 and channels == GrayChannels.LUMA_601:
        img = _opencv_luma(img)
    gray = _scaled_f32(img)
    if gray.ndim == 3:  # GrayChannels.MEAN
        gray = (gray[:, :, 0] + gray[:, :, 1] + gray[:, :, 2]) / np.float32(3)
    return gray


def to_gray_u8(
    image: np.ndarray,
    *,
    channels: GrayChannels = GrayChannels.LUMA_601,
    rounding: U8Rounding = U8Rounding.HALF_UP_F32,
) -> np.ndarray:
    """Grey uint8 image from a grey or colour image (uint8 grey passes through unchanged).

    Parameters
    ----------
    image : (H, W) or (H, W, 3|4) ndarray
        uint8, uint16, float32 or float64 (floats already in [0, 1]).
    channels : GrayChannels
        Channel rule for colour images.
    rounding : U8Rounding
        How non-uint8 grey values become levels; uint16 is first scaled to
        [0, 1] in float32.

    Returns
    -------
    (H, W) uint8 ndarray
    """
    img = _checked(image)
    if img.ndim == 3:
        img = _opencv_luma(img) if channels == GrayChannels.LUMA_601 else to_gray_f32(img, channels=channels)
    if img.dtype == np.uint8:
        return img
    if img.dtype == np.uint16:
        img = _scaled_f32(img)
    if rounding == U8Rounding.HALF_UP_F64:
        return np.clip(np.asarray(img, dtype=np.float64) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    levels = np.asarray(img, dtype=np.float32) * 255.0
    if rounding == U8Rounding.HALF_UP_F32:
        levels = levels + 0.5
    return np.clip(levels, 0, 255).astype(np.uint8)


def clahe(gray_u8: np.ndarray, *, clip_limit: float, tiles: int) -> np.ndarray:
    """Contrast-limited adaptive histogram equalisation (OpenCV CLAHE) of a uint8 grey image.

    Parameters
    ----------
    gray_u8 : (H, W) uint8 ndarray
    clip_limit : float
        Histogram clip limit, relative to a uniform histogram (OpenCV's ``clipLimit``).
    tiles : int
        The image is equalised on a ``tiles x tiles`` grid of tiles.

    Returns
    -------
    (H, W) uint8 ndarray
    """
    img = np.asarray(gray_u8)
    if img.dtype != np.uint8 or img.ndim != 2:
        raise TypeError(f"clahe needs a (H, W) uint8 image, got {img.dtype} {img.shape}")
    op = cv2.createCLAHE(clipLimit=float(clip_limit), tileGridSize=(int(tiles), int(tiles)))
    return op.apply(img)


def sift_features(
    gray_u8: np.ndarray, *, n_features: int, mask: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """SIFT keypoints and descriptors of a uint8 grey image (OpenCV ``SIFT_create``).

    Parameters
    ----------
    gray_u8 : (H, W) uint8 ndarray
    n_features : int
        Strongest keypoints kept (OpenCV's ``nfeatures``; 0 keeps all).
    mask : (H, W) uint8 ndarray, optional
        Detect only where non-zero.

    Returns
    -------
    xy : (N, 2) float64 ndarray
        Keypoint positions ``(x, y)``, pixels.
    descriptors : (N, 128) float32 ndarray
    """
    sift = cv2.SIFT_create(nfeatures=int(n_features))
    kp, desc = sift.detectAndCompute(gray_u8, mask)
    xy = np.array([k.pt for k in kp], dtype=np.float64).reshape(-1, 2)
    return xy, (desc if desc is not None else np.zeros((0, 128), np.float32))


def match_descriptors(
    desc_a: np.ndarray,
    desc_b: np.ndarray,
    *,
    ratio: float,
    matcher: DescriptorMatcher = DescriptorMatcher.BRUTE_FORCE,
    one_to_one: bool = False,
) -> np.ndarray:
    """Index pairs ``(i_a, i_b)`` of descriptors passing Lowe's ratio test.

    A pair is kept when its L2 distance is below ``ratio`` times the distance
    to the second-nearest descriptor of ``b`` (Lowe 2004, §7.1).

    Parameters
    ----------
    desc_a, desc_b : (N_a, D), (N_b, D) float32 ndarray
    ratio : float
        Lowe ratio in (0, 1).
    matcher : DescriptorMatcher
        Exact or approximate nearest-neighbour search.
    one_to_one : bool
        Drop every pair whose ``b`` descriptor is the match of more than one ``a``.

    Returns
    -------
    (M, 2) int ndarray
        Ordered by ``i_a`` (by ``i_b`` when ``one_to_one``).
    """
    if matcher == DescriptorMatcher.FLANN:
        search = cv2.FlannBasedMatcher({"algorithm": 1, "trees": 4}, {"checks": 64})
        knn = search.knnMatch(np.asarray(desc_a, np.float32), np.asarray(desc_b, np.float32), k=2)
    else:
        knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(desc_a, desc_b, k=2)
    good = [(m[0].queryIdx, m[0].trainIdx) for m in knn if len(m) == 2 and m[0].distance < ratio * m[1].distance]
    idx = np.array(good, dtype=int).reshape(-1, 2)
    if one_to_one and len(idx):
        _, first, counts = np.unique(idx[:, 1], return_index=True, return_counts=True)
        idx = idx[first[counts == 1]]
    return idx


def match_sift(
    gray_a_u8: np.ndarray, gray_b_u8: np.ndarray, *, ratio: float = 0.75, max_features: int = 4000
) -> tuple[np.ndarray, np.ndarray]:
    """SIFT keypoints of two uint8 grey images matched by the ratio test (exact search).

    Parameters
    ----------
    gray_a_u8, gray_b_u8 : (H, W) uint8 ndarray
    ratio : float
        Lowe ratio (best distance / second-best distance must be below it).
    max_features : int
        Strongest keypoints kept per image.

    Returns
    -------
    points_a, points_b : (N, 2) float64 ndarray
        Matched positions ``(x, y)``, pixels; empty when either image has fewer
        than two keypoints.

    Notes
    -----
    The last results are kept by the images' contents (:data:`_MATCH_MEMO`): the same
    pair matched again costs a digest of its pixels.
    """
    key = (_content_key(gray_a_u8), _content_key(gray_b_u8), float(ratio), int(max_features))
    with _MATCH_MEMO_LOCK:
        hit = _MATCH_MEMO.get(key)
        if hit is not None:
            _MATCH_MEMO.move_to_end(key)
    if hit is None:
        hit = _match_sift_uncached(gray_a_u8, gray_b_u8, ratio=ratio, max_features=max_features)
        with _MATCH_MEMO_LOCK:
            _MATCH_MEMO[key] = hit
            while len(_MATCH_MEMO) > _MATCH_MEMO_SIZE:
                _MATCH_MEMO.popitem(last=False)
    return hit[0].copy(), hit[1].copy()


#: The last :func:`match_sift` results, keyed by the two images' contents and the options. ``fgcd diff``
#: matches its first lighting's pair for the registration and again for the FDF (the authors' protocol:
#: the same ratio and keypoint budget), and SIFT is deterministic, so the second call returns the first's
#: matches. Written here because OpenCV and functools memoise nothing on array contents.
_MATCH_MEMO: OrderedDict[tuple, tuple[np.ndarray, np.ndarray]] = OrderedDict()
_MATCH_MEMO_SIZE = 2
_MATCH_MEMO_LOCK = threading.Lock()


def _content_key(image: np.ndarray) -> tuple:
    """An image's identity for :data:`_MATCH_MEMO`: dtype, shape and a 128-bit digest of its pixels."""
    image = np.ascontiguousarray(image)
    return (image.dtype.str, image.shape, hashlib.blake2b(image.data, digest_size=16).digest())


def _match_sift_uncached(
    gray_a_u8: np.ndarray, gray_b_u8: np.ndarray, *, ratio: float, max_features: int
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`match_sift` itself (features of both images, ratio test)."""
    xy_a, desc_a = sift_features(gray_a_u8, n_features=max_features)
    xy_b, desc_b = sift_features(gray_b_u8, n_features=max_features)
    empty = np.zeros((0, 2))
    if len(xy_a) < 2 or len(xy_b) < 2:
        return empty, empty.copy()
    idx = match_descriptors(desc_a, desc_b, ratio=ratio)
    if not len(idx):
        return empty, empty.copy()
    return xy_a[idx[:, 0]], xy_b[idx[:, 1]]
