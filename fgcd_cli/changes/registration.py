"""Residual registration of a current image onto the reference image, robust to lighting.

Rule (``docs/change-detection.md``, "Change detection pipeline"): a spatially
varying light gain biases ECC on raw intensities by pixels, while gradient
magnitudes are nearly insensitive to it (``docs/lab/2026-11-25-code-comment-measurements.md``,
"Change detection"). So: SIFT homography for the start (when features match), then
coarse-to-fine ECC on gradient magnitudes.

Convention: ``H_cur_ref`` (3x3) maps homogeneous reference pixel coordinates
(x right, y down, pixel centres at integers) to current-image pixel coordinates.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from enum import StrEnum

import cv2
import numpy as np

from fgcd_core.imaging import U8Rounding, to_gray_u8
from fgcd_core.imaging import match_sift as core_match_sift


class RegistrationInit(StrEnum):
    """How the ECC refinement was started (``Registration.init``)."""

    SIFT = "sift"
    """From the SIFT + RANSAC homography."""
    IDENTITY = "identity"
    """From the identity (features did not match)."""
    NONE = "none"
    """No registration was asked for (the identity homography, not refined)."""


@dataclass(kw_only=True)
class Registration:
    """Result of :func:`register_to_reference`."""

    H_cur_ref: np.ndarray
    """3x3 float64 homography, reference pixel -> current pixel."""
    ok: bool
    """False when the two images could not be registered (see ``reason``)."""
    reason: str = ""
    ecc_correlation: float = float("nan")
    """ECC correlation coefficient on gradient magnitudes at the final level (1 = perfect)."""
    overlap_fraction: float = 0.0
    """Fraction of reference pixels that land inside the current image."""
    sift_inliers: int = 0
    init: RegistrationInit = RegistrationInit.IDENTITY
    """How the ECC was started."""
    settings: dict = field(default_factory=dict)


#: Lowest ECC correlation of the gradient-magnitude images (zero-mean normalised) at which a
#: registration is trusted (``register_to_reference``; the grid AFD's whole-image start).
MIN_GRADIENT_CORRELATION = 0.3


def gradient_magnitude(gray: np.ndarray, *, sigma_px: float = 1.0) -> np.ndarray:
    """Gradient magnitude of a Gaussian-smoothed image.

    Parameters
    ----------
    gray : ndarray, HxW float32
    sigma_px : float
        Gaussian pre-smoothing, pixels.

    Returns
    -------
    ndarray, HxW float32 (intensity units per pixel).
    """
    smooth = cv2.GaussianBlur(gray.astype(np.float32), (0, 0), sigma_px)
    gx = cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(smooth, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    return cv2.magnitude(gx, gy)


def to_uint8(gray: np.ndarray) -> np.ndarray:
    """float [0, 1] grey -> uint8 for OpenCV feature detectors: ``floor(x * 255 + 0.5)`` clipped,
    evaluated in the image's own float precision (:func:`fgcd_core.imaging.to_gray_u8`)."""
    rounding = U8Rounding.HALF_UP_F64 if np.asarray(gray).dtype == np.float64 else U8Rounding.HALF_UP_F32
    return to_gray_u8(gray, rounding=rounding)


def match_sift(
    ref_gray: np.ndarray,
    cur_gray: np.ndarray,
    *,
    ratio: float = 0.75,
    max_features: int = 4000,
) -> tuple[np.ndarray, np.ndarray]:
    """SIFT keypoints matched with Lowe's ratio test.

    Parameters
    ----------
    ref_gray, cur_gray : ndarray, HxW float32 in [0, 1]
    ratio : float
        Lowe ratio (best distance / second-best distance must be below it).
    max_features : int
        Strongest keypoints kept per image.

    Returns
    -------
    points_ref, points_cur : ndarray, Nx2 float64, pixels (x, y)
    """
    return core_match_sift(to_uint8(ref_gray), to_uint8(cur_gray), ratio=ratio, max_features=max_features)


def ransac_homography(
    points_ref: np.ndarray, points_cur: np.ndarray, *, ransac_px: float = 3.0
) -> tuple[np.ndarray | None, np.ndarray]:
    """RANSAC homography ref -> cur; returns (H_cur_ref or None, inlier mask N bool)."""
    n = len(points_ref)
    if n < 4:
        return None, np.zeros(n, dtype=bool)
    cv2.setRNGSeed(0)  # the same pair registers the same way every time (RANSAC samples with OpenCV's RNG)
    H, inliers = cv2.findHomography(
        points_ref, points_cur, cv2.RANSAC, float(ransac_px), maxIters=5000, confidence=0.999
    )
    if H is None:
        return None, np.zeros(n, dtype=bool)
    return H.astype(np.float64), inliers.ravel().astype(bool)


def overlap_fraction(H_cur_ref: np.ndarray, shape: tuple[int, int]) -> float:
    """Fraction of reference pixels whose image under ``H_cur_ref`` lies inside the current image."""
    h, w = shape
    step = max(1, min(h, w) // 64)
    ys, xs = np.mgrid[0:h:step, 0:w:step]
    pts = np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)]).astype(np.float64)
    mapped = H_cur_ref @ pts
    with np.errstate(divide="ignore", invalid="ignore"):
        u = mapped[0] / mapped[2]
        v = mapped[1] / mapped[2]
        inside = (mapped[2] > 0) & (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    return float(inside.mean())


def _scale_homography(H: np.ndarray, factor: float) -> np.ndarray:
    """Express a pixel homography at a resolution ``factor`` times the current one."""
    S = np.diag([factor, factor, 1.0])
    return S @ H @ np.linalg.inv(S)


@contextmanager
def without_ipp() -> Iterator[None]:
    """Run OpenCV without its Intel IPP kernels in the calling thread (the switch is thread-local).

    Rule: the same pair must register to the same homography every time. With IPP,
    ``cv2.findTransformECC``'s result depends on the memory alignment of its inputs,
    so identical images can register (and be decided) differently from call to call;
    without IPP it is repeatable (``docs/lab/2026-11-28-changes-simulated-pairs.md``,
    "The registration's run-to-run variation, and ε = 10 with stills").
    """
    before = cv2.ipp.useIPP()
    cv2.ipp.setUseIPP(False)
    try:
        yield
    finally:
        cv2.ipp.setUseIPP(before)


def ecc_gradient(
    ref_gray: np.ndarray,
    cur_gray: np.ndarray,
    H_init: np.ndarray,
    *,
    levels: int = 3,
    iterations: int = 100,
    eps: float = 1e-6,
) -> tuple[np.ndarray, float]:
    """Coarse-to-fine ECC homography on gradient-magnitude images.

    Returns (H_cur_ref, correlation at full resolution). Raises ``cv2.error`` when
    ECC diverges.
    """
    H = H_init.astype(np.float64)
    correlation = float("nan")
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, iterations, eps)
    with without_ipp():
        for level in reversed(range(levels)):
            factor = 0.5**level
            if min(ref_gray.shape) * factor < 48:
                continue
            size = (max(1, int(round(ref_gray.shape[1] * factor))), max(1, int(round(ref_gray.shape[0] * factor))))
            ref_l = cv2.resize(ref_gray, size, interpolation=cv2.INTER_AREA) if level else ref_gray
            cur_l = cv2.resize(cur_gray, size, interpolation=cv2.INTER_AREA) if level else cur_gray
            H_l = _scale_homography(H, factor).astype(np.float32)
            correlation, H_l = cv2.findTransformECC(
                gradient_magnitude(ref_l), gradient_magnitude(cur_l), H_l, cv2.MOTION_HOMOGRAPHY, criteria, None, 5
            )
            H = _scale_homography(H_l.astype(np.float64), 1.0 / factor)
    return H / H[2, 2], float(correlation)


def gradient_correlation(ref_gray: np.ndarray, cur_gray: np.ndarray, H_cur_ref: np.ndarray) -> float:
    """ECC's criterion at a given homography: the zero-mean normalised correlation of the
    gradient-magnitude images over the reference pixels the current image covers.

    Parameters
    ----------
    ref_gray, cur_gray : ndarray, HxW float32 in [0, 1].
    H_cur_ref : ndarray, 3x3, reference pixel -> current pixel.

    Returns
    -------
    float in [-1, 1] (``nan`` when fewer than 16 pixels overlap or a side is flat).
    """
    warped, valid = warp_to_reference(gradient_magnitude(cur_gray), H_cur_ref, ref_gray.shape)
    if np.count_nonzero(valid) < 16:
        return float("nan")
    a = gradient_magnitude(ref_gray)[valid].astype(np.float64)
    b = warped[valid].astype(np.float64)
    a -= a.mean()
    b -= b.mean()
    norm = float(np.linalg.norm(a) * np.linalg.norm(b))
    return float(a @ b / norm) if norm > 0 else float("nan")


def register_to_reference(
    ref_gray: np.ndarray,
    cur_gray: np.ndarray,
    *,
    min_sift_inliers: int = 15,
    min_overlap: float = 0.5,
    min_correlation: float = MIN_GRADIENT_CORRELATION,
) -> Registration:
    """Register the current image onto the reference (homography), robust to lighting.

    Parameters
    ----------
    ref_gray, cur_gray : ndarray, HxW float32 in [0, 1], same size.
    min_sift_inliers : int
        Below this, ECC starts from the identity instead of the SIFT homography.
    min_overlap : float
        Fraction of the reference that must be seen in the current image.
    min_correlation : float
        Minimal ECC correlation on gradient images for a trustworthy result.

    Returns
    -------
    Registration (``ok`` False with a reason when the pair cannot be registered).
    """
    settings = {
        "model": "homography",
        "init": "SIFT ratio 0.75 + RANSAC 3 px",
        "refine": "ECC on gradient magnitude, 3-level pyramid",
        "min_sift_inliers": min_sift_inliers,
        "min_overlap": min_overlap,
        "min_correlation": min_correlation,
    }
    points_ref, points_cur = match_sift(ref_gray, cur_gray)
    H_sift, inliers = ransac_homography(points_ref, points_cur)
    n_inliers = int(inliers.sum())
    if H_sift is not None and n_inliers >= min_sift_inliers:
        H_init, init = H_sift, RegistrationInit.SIFT
    else:
        H_init, init = np.eye(3), RegistrationInit.IDENTITY
    try:
        H, correlation = ecc_gradient(ref_gray, cur_gray, H_init)
    except cv2.error:
        if init == RegistrationInit.SIFT:
            H, correlation = H_sift, float("nan")
        else:
            return Registration(
                H_cur_ref=np.eye(3),
                ok=False,
                reason="registration failed: ECC did not converge and no features matched",
                sift_inliers=n_inliers,
                init=init,
                settings=settings,
            )
    if init == RegistrationInit.SIFT and np.isfinite(correlation) and correlation < min_correlation:
        # ECC can wander off a good start (it then ends below the bar instead of raising):
        # the same criterion judges the SIFT homography, and the better of the two is kept.
        sift_correlation = gradient_correlation(ref_gray, cur_gray, H_sift)
        if np.isfinite(sift_correlation) and sift_correlation > correlation:
            H, correlation = H_sift, sift_correlation
    overlap = overlap_fraction(H, ref_gray.shape)
    result = Registration(
        H_cur_ref=H,
        ok=True,
        ecc_correlation=correlation,
        overlap_fraction=overlap,
        sift_inliers=n_inliers,
        init=init,
        settings=settings,
    )
    if overlap < min_overlap:
        result.ok = False
        result.reason = (
            f"images overlap on only {overlap * 100:.0f} % of the reference (need {min_overlap * 100:.0f} %)"
        )
    elif np.isfinite(correlation) and correlation < min_correlation:
        result.ok = False
        result.reason = f"registration unreliable: gradient correlation {correlation:.2f} < {min_correlation}"
    return result


#: The interpolation of every warp of the current images (homography, homography + flow, tiles), Lanczos
#: 8 x 8, not bilinear: a bilinear sample at a fractional offset ``t`` is the filter ``[1 - t, t]``, which
#: blurs a one-pixel line or a sharp outline by up to half its contrast while the reference, never
#: resampled, keeps it sharp; the blur then reads as change along every fine dark line and outline
#: (docs/change-detection.md, pipeline step 2). Its overshoot is clipped (:func:`clip_to_source`).
WARP_INTERPOLATION = cv2.INTER_LANCZOS4


def warp_to_reference(
    image: np.ndarray, H_cur_ref: np.ndarray, shape: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """Resample a current image into the reference frame (:data:`WARP_INTERPOLATION`, :func:`clip_to_source`).

    Returns (warped image float32, valid mask HxW bool: pixels that came from inside the current image).
    """
    h, w = shape
    source = image.astype(np.float32)
    warped = cv2.warpPerspective(
        source, H_cur_ref, (w, h), flags=WARP_INTERPOLATION | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REFLECT
    )
    ones = np.ones(image.shape[:2], np.float32)
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    valid = cv2.warpPerspective(ones, H_cur_ref, (w, h), flags=flags, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return clip_to_source(warped, source), valid > 0.999


def homography_points(H_cur_ref: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the homography sends reference positions ``(x, y)`` (arrays of any shape, px): the current-image
    ``(x', y')`` as float32 maps for ``cv2.remap``, and where the point lies in front (denominator > 0)."""
    H = np.asarray(H_cur_ref, dtype=np.float64)
    den = H[2, 0] * x + H[2, 1] * y + H[2, 2]
    map_x = ((H[0, 0] * x + H[0, 1] * y + H[0, 2]) / den).astype(np.float32)
    map_y = ((H[1, 0] * x + H[1, 1] * y + H[1, 2]) / den).astype(np.float32)
    return map_x, map_y, den > 0


def clip_to_source(resampled: np.ndarray, source: np.ndarray) -> np.ndarray:
    """``resampled`` (a :data:`WARP_INTERPOLATION` warp of ``source``) clipped to ``source``'s range: the
    interpolation's overshoot at steps (a few percent) is not in the image. In place; returns ``resampled``."""
    return np.clip(resampled, float(source.min()), float(source.max()), out=resampled)
