"""Dense, confidence-weighted refinement of a homography registration (residual parallax).

A homography aligns a plane; a relief or a statue seen from a slightly different
pose keeps a residual parallax of 0.5-5 px that varies smoothly over tens of
pixels except at depth edges, and shows up as false changes along edges. This
module estimates that residual as a dense flow field between the reference and
the homography-warped current image, regularised so strongly that it cannot
absorb a real change, and marks the pixels where no trustworthy alignment exists
as *not compared* instead of letting them become changes.

Rules the implementation follows:

- **Lighting invariance.** The flow is computed on local-contrast-normalised log
  images (:func:`lighting_invariant`): a gain that is smooth at the scale of the
  normalisation (exposure, light fall-off, white balance, daylight) cancels in
  ``log I - local mean``, and dividing by the local standard deviation equalises
  contrast. DIS normalises each patch's mean, not its contrast, so a blotchy gain
  would cost raw-intensity matches their forward-backward consistency
  (``docs/lab/2026-11-25-code-comment-measurements.md``, "Change detection").
- **Raw matches.** OpenCV's DIS optical flow (Kroeger, Timofte, Dai, Van Gool,
  "Fast Optical Flow using Dense Inverse Search", ECCV 2016;
  ``cv2.DISOpticalFlow_create``), preset MEDIUM, forward (reference -> current)
  and backward (current -> reference), on 8-bit versions of those images.
- **The flow must not swallow changes.** DIS follows anything that looks like
  motion, a change included: its raw flow on changed pixels is larger than around
  them, and resampling through it would shrink a grown loss back
  (``docs/lab/2026-11-25-code-comment-measurements.md``, "Change detection"). The field is
  therefore replaced by a robust, low-order, large-scale fit: confidence-weighted
  local-quadratic normalized convolution (Knutsson & Westin, "Normalized and
  differential convolution", CVPR 1993; Farnebaeck, "Polynomial expansion for
  orientation and motion estimation", 2002, for the separable applicability)
  with a Gaussian applicability of ``smooth_px``, iterated with Cauchy robust
  weights (IRLS) so that raw flows departing from the smooth model by more than
  ~1 px lose their say. Quadratic rather than linear: at an equal share of a
  change in the window (below) it follows a parallax bump with half the bias.
- **Scale from the changes to keep** (:func:`smoothing_scale_px`): changes are
  compact blobs 5-60 px across or thin cracks; parallax is smooth over tens of
  px. The share of a centred disc of diameter ``D`` in the fit's equivalent
  kernel must stay below 25 % for ``D = 60 px``; that gives ``sigma = 57 px``
  for the local-quadratic fit (40 px for a local constant or linear one). Even
  a blob whose own flow is confidently wrong (the worst case, before the robust
  weights reject it) moves the fit by at most a quarter of its deviation there;
  a 25 px blob holds about 5 %.
- **Cap.** A residual beyond ``max_flow_px`` after a good homography is not
  parallax a smooth field should explain (another depth layer, a failed
  registration): those pixels are not compared and the field is clipped there.
- **Confidence** (0..1): forward-backward consistency of the raw flows
  ``|f(x) + b(x + f(x))|`` times a gradient-energy term (a flat area carries no
  information: the smooth field is interpolated there, the confidence is low,
  the pixel is still compared) times the agreement of the raw flow with the fit.
- **Not compared**: outside ``valid`` or sampled from outside it through the
  flow (disocclusion at the frame border); smoothed flow beyond the cap;
  forward-backward error of the *smoothed* forward and backward fields above
  ``fb_px`` (the two directions disagree: occlusion or a fold of the field).
  A raw flow that is inconsistent (no match) or that departs from the fit only
  lowers the confidence: a change and an occlusion at a depth edge look alike to
  the flow, and masking such pixels would hide true change pixels
  (``docs/lab/2026-11-25-code-comment-measurements.md``, "Change detection").

Convention: ``flow[y, x] = (dx, dy)`` means that reference pixel ``(x, y)`` is
seen at ``(x + dx, y + dy)`` in the homography-warped current image, so
``apply_flow(cur_warped, flow)`` brings the current image onto the reference.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from fgcd_cli.changes.dense.fit import (
    FIT_ORDER,
    robust_smooth,
    smoothing_scale_px,
)
from fgcd_cli.changes.registration import WARP_INTERPOLATION, clip_to_source, homography_points


@dataclass(kw_only=True)
class DenseAlignment:
    """Result of :func:`refine_dense`, in the reference frame."""

    flow: np.ndarray
    """HxWx2 float32, px: reference pixel (x, y) is seen at (x + flow_x, y + flow_y) in the
    homography-warped current image. Smooth; clipped to ``max_flow_px``."""
    confidence: np.ndarray
    """HxW float32 in [0, 1]: how much raw evidence supports the flow at this pixel."""
    not_compared: np.ndarray
    """HxW bool: pixels whose alignment cannot be trusted (outside ``valid`` or sampled from
    outside it, forward-backward inconsistent after smoothing, flow beyond the cap)."""
    max_flow_px: float
    settings: dict = field(default_factory=dict)

    @property
    def magnitude(self) -> np.ndarray:
        """HxW float32, flow length in pixels."""
        return np.hypot(self.flow[..., 0], self.flow[..., 1])


def lighting_invariant(gray: np.ndarray, *, sigma_px: float = 4.0, eps: float = 0.02) -> np.ndarray:
    """Local-contrast-normalised log image as uint8, for optical flow under lighting change.

    ``(L - G*L) / (sqrt(G*(L - G*L)^2) + floor)`` with ``L = log(I + eps)``: a
    gain that is smooth at the scale ``sigma_px`` cancels; local contrast is
    equalised.

    Parameters
    ----------
    gray : ndarray, HxW float32 in [0, 1]
    sigma_px : float
        Gaussian scale of the local mean and standard deviation, pixels (half
        of DIS's 8 px patch: the patch sees a normalised neighbourhood).
    eps : float
        Offset before the logarithm (intensity units) so black pixels stay finite.

    Returns
    -------
    ndarray, HxW uint8, 128 = local mean, 40 grey levels per local standard deviation.
    """
    log = np.log(gray.astype(np.float32) + eps)
    detail = log - cv2.GaussianBlur(log, (0, 0), sigma_px)
    spread = np.sqrt(cv2.GaussianBlur(detail * detail, (0, 0), sigma_px))
    # Floor in log units (~2 % contrast): flat areas stay flat instead of amplifying noise.
    normalised = detail / (spread + 0.02)
    return np.clip(128.0 + 40.0 * normalised, 0, 255).astype(np.uint8)


def apply_flow(image: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """Resample an image along a flow: ``out(x, y) = image(x + flow_x, y + flow_y)``.

    Parameters
    ----------
    image : ndarray, HxW or HxWxC (any C), float32 (other types are converted)
        Typically the homography-warped current image.
    flow : ndarray, HxWx2 float32, pixels
        As in :class:`DenseAlignment`.

    Returns
    -------
    ndarray, float32, the shape of ``image``: bilinear resampling, border reflected.

    Notes
    -----
    Applied to the homography-warped image, this is a second interpolation: the
    extra blur costs the gradient cues as much as a small parallax does
    (``docs/lab/2026-11-25-code-comment-measurements.md``, "Change detection"). To resample the
    current image for comparison, use :func:`warp_with_flow` (one interpolation).
    """
    h, w = flow.shape[:2]
    if image.shape[:2] != (h, w):
        raise ValueError(f"image is {image.shape[:2]} but the flow is {(h, w)}")
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    map_x = xs + flow[..., 0].astype(np.float32)
    map_y = ys + flow[..., 1].astype(np.float32)
    src = np.ascontiguousarray(image, dtype=np.float32)

    def remap(a: np.ndarray) -> np.ndarray:
        return cv2.remap(a, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)

    if src.ndim == 2 or src.shape[2] <= 4:
        out = remap(src)
        return out.reshape(src.shape) if src.ndim == 3 else out
    return np.stack([remap(np.ascontiguousarray(src[..., c])) for c in range(src.shape[2])], axis=2)


def _forward_backward_error(forward: np.ndarray, backward: np.ndarray) -> np.ndarray:
    """``|f(x) + b(x + f(x))|`` in pixels (HxW float32); 0 for perfectly consistent flows."""
    back_at_target = apply_flow(backward, forward)
    return np.hypot(forward[..., 0] + back_at_target[..., 0], forward[..., 1] + back_at_target[..., 1])


def _texture_confidence(gray: np.ndarray, *, window_px: float, gradient_half: float) -> np.ndarray:
    """Gradient energy of the log image mapped to [0, 1): ``E / (E + E0)``.

    ``E`` is the Gaussian-windowed mean of ``|grad log I|^2``; ``E0 = gradient_half^2``
    is the energy at which confidence is 1/2 (log units per pixel).
    """
    log = np.log(gray.astype(np.float32) + 0.02)
    log = cv2.GaussianBlur(log, (0, 0), 1.0)
    gx = cv2.Sobel(log, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(log, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    energy = cv2.GaussianBlur(gx * gx + gy * gy, (0, 0), window_px)
    return energy / (energy + gradient_half**2)


@dataclass(frozen=True, kw_only=True)
class DenseConfig:
    """Options of :func:`refine_dense` (the rules of the module docstring)."""

    max_flow_px: float = 5.0
    """Cap on the residual flow, pixels. After a homography fitted by ECC, the parallax of a relief
    or a statue seen from a slightly different pose is 0.5-5 px; more means another depth layer or
    a failed registration, which a smooth field should not explain. Beyond: clipped and not compared."""
    smooth_px: float = smoothing_scale_px()
    """Gaussian scale of the robust local fit, pixels. Default from :func:`smoothing_scale_px`: a
    60 px change holds at most 25 % of the local-quadratic fit at its centre (57 px)."""
    fb_px: float = 1.0
    """Forward-backward error of the smoothed fields above which a pixel is not compared, pixels:
    the change cues tolerate a 1 px shift, so a 1 px disagreement is where the alignment stops
    being usable. Half of it is the raw forward-backward error at which a match keeps half its weight."""
    robust_px: float = 1.0
    """Cauchy scale of the IRLS weights on |raw flow - fit|, pixels: the same 1 px tolerance; a raw
    flow 3 px off the fit keeps 10 % of its weight."""
    robust_iterations: int = 3
    """Robust re-weightings (IRLS) after the non-robust start; the field converges within them."""
    texture_half: float = 0.016
    """Root-mean-square gradient of the log image (log units per pixel) at which the texture
    confidence is 1/2: 0.016 is ~2 grey levels per pixel at mid-grey in 8 bits, the texture floor
    of :func:`fgcd_cli.changes.images.image_health`."""
    normalise_px: float = 4.0
    """Scale of the local contrast normalisation feeding DIS, pixels: half the 8 px DIS patch, so
    each patch sees a normalised neighbourhood."""
    order: int = FIT_ORDER
    """Degree of the local polynomial (0, 1, 2); with a non-default order, pass
    ``smooth_px=smoothing_scale_px(order=order)`` to keep the same guarantee."""

    def settings(self) -> dict:
        """The options as :attr:`DenseAlignment.settings` records them."""
        return {
            "model": "DIS optical flow (Kroeger et al. 2016), preset MEDIUM, forward and backward, on "
            "local-contrast-normalised log images; robust local polynomial normalized convolution",
            "max_flow_px": self.max_flow_px,
            "smooth_px": self.smooth_px,
            "fb_px": self.fb_px,
            "robust_px": self.robust_px,
            "robust_iterations": self.robust_iterations,
            "texture_half": self.texture_half,
            "normalise_px": self.normalise_px,
            "order": self.order,
        }


def refine_dense(
    ref_gray: np.ndarray,
    cur_warped_gray: np.ndarray,
    *,
    valid: np.ndarray | None = None,
    config: DenseConfig | None = None,
) -> DenseAlignment:
    """Dense residual alignment of a homography-warped current image onto the reference.

    Parameters
    ----------
    ref_gray : ndarray, HxW float32 in [0, 1]
        Reference image (grey).
    cur_warped_gray : ndarray, HxW float32 in [0, 1]
        Current image already resampled into the reference frame by the homography
        (:func:`fgcd_cli.changes.registration.warp_to_reference`).
    valid : ndarray, HxW bool, optional
        Pixels that carry data in both images (the warp's valid mask). Outside:
        no weight in the fit, not compared. None: every pixel. Intersect it with
        the region of interest when that mask cuts an object out of a background at
        another depth: a background off the object's homography otherwise drags
        the fit near the silhouette.
    config : DenseConfig, optional
        The options (default: the shipped ones).

    Returns
    -------
    DenseAlignment
        ``flow`` (HxWx2 float32, px), ``confidence`` (HxW float32, 0..1),
        ``not_compared`` (HxW bool), all in the reference frame.
    """
    config = config or DenseConfig()
    if ref_gray.ndim != 2 or ref_gray.shape != cur_warped_gray.shape:
        raise ValueError(f"expected two HxW grey images of one size, got {ref_gray.shape} and {cur_warped_gray.shape}")
    if config.order not in (0, 1, 2):
        raise ValueError(f"order must be 0, 1 or 2, got {config.order}")
    h, w = ref_gray.shape
    valid_mask = np.ones((h, w), bool) if valid is None else np.asarray(valid, bool)
    ref8 = lighting_invariant(ref_gray, sigma_px=config.normalise_px)
    cur8 = lighting_invariant(cur_warped_gray, sigma_px=config.normalise_px)
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    forward = dis.calc(ref8, cur8, None)
    backward = dis.calc(cur8, ref8, None)
    texture = np.minimum(
        _texture_confidence(ref_gray, window_px=config.normalise_px, gradient_half=config.texture_half),
        _texture_confidence(cur_warped_gray, window_px=config.normalise_px, gradient_half=config.texture_half),
    )
    valid_f = valid_mask.astype(np.float32)
    consistent_f, weight_f = _evidence(forward, backward, texture, valid_f, config)
    _, weight_b = _evidence(backward, forward, texture, valid_f, config)
    fit = dict(
        sigma_px=config.smooth_px, robust_px=config.robust_px, iterations=config.robust_iterations, order=config.order
    )
    smooth_f = robust_smooth(forward, weight_f, **fit)
    smooth_b = robust_smooth(backward, weight_b, **fit)

    max_flow_px = config.max_flow_px
    magnitude = np.hypot(smooth_f[..., 0], smooth_f[..., 1])
    beyond_cap = magnitude > max_flow_px
    flow = (smooth_f * np.minimum(1.0, max_flow_px / np.maximum(magnitude, 1e-6))[..., None]).astype(np.float32)
    fb_smooth = _forward_backward_error(smooth_f, smooth_b)
    sampled_valid = apply_flow(valid_f, flow) > 0.999 if valid is not None else np.ones((h, w), bool)
    not_compared = ~valid_mask | ~sampled_valid | beyond_cap | (fb_smooth > config.fb_px)

    deviation = np.hypot(forward[..., 0] - smooth_f[..., 0], forward[..., 1] - smooth_f[..., 1])
    agreement = 1.0 / (1.0 + (deviation / config.robust_px) ** 2)
    confidence = np.clip(consistent_f * texture * agreement, 0.0, 1.0).astype(np.float32)
    confidence[not_compared] = 0.0
    return DenseAlignment(
        flow=flow,
        confidence=confidence,
        not_compared=not_compared,
        max_flow_px=float(max_flow_px),
        settings=config.settings(),
    )


def _evidence(
    flow: np.ndarray, other: np.ndarray, texture: np.ndarray, valid_f: np.ndarray, config: DenseConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Raw evidence of a flow: forward-backward consistency, and the fit weight (consistency, texture in
    both images, inside valid, and not absurdly long: a match twice the cap away is no parallax evidence)."""
    consistent = 1.0 / (1.0 + (_forward_backward_error(flow, other) / (0.5 * config.fb_px)) ** 2)
    in_cap = np.hypot(flow[..., 0], flow[..., 1]) <= 2.0 * config.max_flow_px
    return consistent, (consistent * texture * valid_f * in_cap).astype(np.float32)


def warp_with_flow(image: np.ndarray, H_cur_ref: np.ndarray, flow: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Resample the *original* current image into the reference frame through homography and flow at once.

    Equivalent to ``apply_flow(warp_to_reference(image, H)[0], flow)`` but with a
    single interpolation (``changes.registration.WARP_INTERPOLATION``, clipped): a second one
    adds blur (a bilinear one up to 0.5 px standard deviation), which the gradient-based change cues
    read as change.

    Parameters
    ----------
    image : ndarray, HxW or HxWxC, the current image (any size)
    H_cur_ref : ndarray, 3x3, reference pixel -> current pixel (as in registration.py)
    flow : ndarray, hxwx2 float32, px, from :func:`refine_dense` (reference frame, h x w)

    Returns
    -------
    warped : ndarray, float32, hxw or hxwxC
    valid : ndarray, hxw bool, pixels that came from inside the current image
    """
    h, w = flow.shape[:2]
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    x = xs + flow[..., 0]
    y = ys + flow[..., 1]
    map_x, map_y, ahead = homography_points(H_cur_ref, x, y)
    warped, inside = remap_image(image, map_x, map_y)
    return warped, ahead & inside


def warp_with_maps(
    image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray, flow: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Resample the current image into the reference frame through a per-pixel warp and the flow at once.

    The reference pixel ``p`` takes the current image at ``map(p + flow(p))`` (the maps interpolated
    bilinearly; they are smooth where defined): one interpolation of the image, as :func:`warp_with_flow`.

    Parameters
    ----------
    image : ndarray, HxW or HxWxC, the current image (any size)
    map_x, map_y : ndarray, hxw float32, current-image position of each reference pixel (finite everywhere)
    flow : ndarray, hxwx2 float32, px, optional (none: the maps alone)

    Returns
    -------
    warped : ndarray, float32, hxw or hxwxC
    valid : ndarray, hxw bool, pixels that came from inside the current image
    """
    if flow is not None:
        h, w = flow.shape[:2]
        xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
        at_x, at_y = xs + flow[..., 0], ys + flow[..., 1]
        map_x, map_y = (
            cv2.remap(
                np.ascontiguousarray(m, dtype=np.float32), at_x, at_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
            )
            for m in (map_x, map_y)
        )
    return remap_image(image, np.asarray(map_x, np.float32), np.asarray(map_y, np.float32))


def remap_image(image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``cv2.remap`` of ``image`` (any number of channels) with ``changes.registration.WARP_INTERPOLATION``,
    clipped to the source's range; and the pixels whose position lies inside the source image."""
    h, w = map_x.shape
    src = np.ascontiguousarray(image, dtype=np.float32)
    if src.ndim == 3 and src.shape[2] > 4:
        warped = np.stack(
            [
                cv2.remap(
                    np.ascontiguousarray(src[..., c]), map_x, map_y, WARP_INTERPOLATION, borderMode=cv2.BORDER_REFLECT
                )
                for c in range(src.shape[2])
            ],
            axis=2,
        )
    else:
        warped = cv2.remap(src, map_x, map_y, WARP_INTERPOLATION, borderMode=cv2.BORDER_REFLECT)
        warped = warped.reshape((h, w) + src.shape[2:])
    warped = clip_to_source(warped, src)
    ch, cw = src.shape[:2]
    valid = (map_x >= 0) & (map_x <= cw - 1) & (map_y >= 0) & (map_y <= ch - 1)
    return warped, valid
