"""Photometric stereo for change cues: relief change (normals) apart from colour change (albedo).

An observation is a stack of K images from one camera pose under K lightings
(usually one ambient, the others directional). Under the Lambertian model each
directional lighting ``k`` gives, per pixel, ``I_k = l_k . b`` with
``b = albedo * n``:

* calibrated (light directions known): per-pixel least squares, Woodham,
  "Photometric method for determining surface orientation from multiple
  images", Opt. Eng. 19(1), 1980, made robust by reweighting;
* uncalibrated: the (pixels x lightings) matrix has rank 3 and its SVD gives
  ``B`` and ``L`` up to an invertible 3x3 matrix ``A`` (Hayakawa,
  "Photometric stereo under a light source with arbitrary motion", JOSA A
  11(11), 1994). In theory integrability narrows ``A`` to the generalised
  bas-relief group (Belhumeur, Kriegman & Yuille, IJCV 35(1), 1999); here it
  fixes the in-plane axes and the rest is set by stated conventions
  (:func:`photometric_stereo`, Notes).

Change detection needs both observations in one basis, not the metric shape:
:func:`joint_photometric_stereo` factorizes both stacks together and maps the
current basis onto the reference one with a robust 3x3 fit.

No PyPI package does photometric stereo well (none offers a robust, vectorised,
uncalibrated fit of colour stacks under near lights), so the solver is written
here on numpy and OpenCV.

Frame of every normal and light vector: camera frame, x right, y down (image
columns and rows), z away from the camera; a surface facing the camera has
normal ~(0, 0, -1); a light on the camera side has l_z < 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgcd_cli.changes.photometric.basis import align_basis, canonical_basis, factorize_lights
from fgcd_cli.changes.photometric.stack import DARK_LEVEL, Stack, prepare_stack
from fgcd_cli.errors import UserInputError

# Rules of the robust per-pixel fit (both cases).
_OUTLIER_FRACTION = 0.3  # Tukey cut-off of a sample's residual, relative to the pixel's RMS level
_IRLS_ITERATIONS = 3
_MIN_CONDITION = 1e-4  # det / (trace/3)^3 of the weighted 3x3 system below this: the pixel is unknown


@dataclass(kw_only=True)
class PhotometricStereo:
    """Photometric stereo of one observation (one camera pose, K lightings).

    Attributes
    ----------
    normals : ndarray, HxWx3 float32
        Unit normals in the camera frame (x right, y down, z away from the
        camera: a frontal surface has ~(0, 0, -1)); pseudo-normals when
        uncalibrated (see :func:`photometric_stereo`). NaN where unknown: outside
        ``valid``, dark, or fewer than 3 usable lightings.
    albedo : ndarray, HxW float32 (grey input) or HxWx3 float32 (colour input)
        Albedo times light intensity, >= 0, such that ``I = albedo (n . l)``
        (image-intensity units per unit ``|l|``); 0 where the normal is unknown.
        Each channel is fitted with the normal of the grey fit.
    residual : ndarray, HxW float32
        Relative RMS misfit of the Lambertian model,
        ``sqrt(mean_k (I_k - max(0, l_k . b))^2) / sqrt(mean_k I_k^2)`` over all
        directional lightings, including the samples the robust fit left out,
        so that cast shadows, highlights and clipping show up. NaN where the
        normal is unknown.
    light_dirs : ndarray, Kx3 float64
        Direction towards each light times its intensity (rows), in the frame of
        ``normals``. Uncalibrated: estimated, NaN rows for lightings not fitted
        (the ambient one). Calibrated: the given rows (the current observation of
        :func:`joint_photometric_stereo` carries them mapped by the basis alignment).
    calibrated : bool
        True when the light directions were given.
    used : ndarray, K bool
        Lightings that entered the normal estimate (False for the ambient one).
    """

    normals: np.ndarray
    albedo: np.ndarray
    residual: np.ndarray
    light_dirs: np.ndarray
    calibrated: bool
    used: np.ndarray


def _weighted_ls(lights: np.ndarray, weights: np.ndarray, intensity: np.ndarray):
    """``min_b sum_k w_k (I_k - l_k . b)^2`` for every pixel at once, by the 3x3 adjugate.

    lights (K', 3) float32; weights, intensity (K', N) float32. Returns b (3, N), ok (N,) bool.
    """
    pairs = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]
    outer = np.stack([lights[:, i] * lights[:, j] for i, j in pairs])  # (6, K')
    m00, m01, m02, m11, m12, m22 = outer @ weights
    rhs = lights.T @ (weights * intensity)  # (3, N)
    c00 = m11 * m22 - m12 * m12
    c01 = m02 * m12 - m01 * m22
    c02 = m01 * m12 - m02 * m11
    c11 = m00 * m22 - m02 * m02
    c12 = m01 * m02 - m00 * m12
    c22 = m00 * m11 - m01 * m01
    det = m00 * c00 + m01 * c01 + m02 * c02
    ok = det > _MIN_CONDITION * np.maximum(((m00 + m11 + m22) / 3.0) ** 3, 1e-30)
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0).astype(np.float32)
    b = np.empty_like(rhs)
    b[0] = (c00 * rhs[0] + c01 * rhs[1] + c02 * rhs[2]) * inv
    b[1] = (c01 * rhs[0] + c11 * rhs[1] + c12 * rhs[2]) * inv
    b[2] = (c02 * rhs[0] + c12 * rhs[1] + c22 * rhs[2]) * inv
    return b, ok


def _robust_fit(stack: Stack, lights: np.ndarray, shadow_fraction: float):
    """Per-pixel robust least squares of ``b`` (Woodham 1980 with IRLS).

    Rules, per pixel: a clipped sample never enters; a sample darker than
    ``shadow_fraction`` x the pixel's brightest one (each lighting first divided
    by its median level, so that a weaker lamp is not taken for a shadow) is a
    shadow and never enters; the others are weighted by Tukey's biweight of
    their residual, cut off at ``_OUTLIER_FRACTION`` x the pixel's RMS level
    (cast shadows with ambient fill, highlights). The pixel is unknown when its
    weighted system is singular (fewer than 3 usable lightings in general
    position) or it is dark.

    Returns b (3, N) float32 with NaN columns where unknown, and the final weights (K', N).
    """
    grey = stack.grey
    lights = lights.astype(np.float32)
    usable = ~stack.saturated
    level = np.array([np.median(g[u]) if u.any() else 1.0 for g, u in zip(grey, usable)], np.float32)
    relative = np.where(usable, grey / np.maximum(level, 1e-6)[:, None], 0.0)
    hard = usable & (relative >= shadow_fraction * relative.max(axis=0)) & (grey.max(axis=0) >= DARK_LEVEL)
    weights = hard.astype(np.float32)
    cutoff = _OUTLIER_FRACTION * (np.sqrt(np.mean(grey * grey, axis=0)) + 1e-4)
    b, ok = _weighted_ls(lights, weights, grey)
    for _ in range(_IRLS_ITERATIONS):
        u = (grey - lights @ b) / cutoff
        new_weights = np.where(hard & (np.abs(u) < 1.0), (1.0 - u * u) ** 2, 0.0).astype(np.float32)
        new_b, new_ok = _weighted_ls(lights, new_weights, grey)
        keep = new_ok | ~ok  # where down-weighting left too few lightings, keep the previous solution
        b = np.where(keep, new_b, b)
        weights = np.where(keep, new_weights, weights)
        ok = np.where(keep, new_ok, ok)
    b[:, ~ok] = np.nan
    return b, weights


def _finish(
    stack: Stack, b: np.ndarray, weights: np.ndarray, lights: np.ndarray, light_rows: np.ndarray | None
) -> PhotometricStereo:
    """Normals, per-channel albedo and residual images from the fitted ``b`` (3, N)."""
    h, w = stack.shape
    lights32 = lights.astype(np.float32)
    norm = np.sqrt(np.sum(b * b, axis=0))
    known = np.isfinite(norm) & (norm > 1e-8)
    safe_b = np.where(known, b, 0.0).astype(np.float32)
    n = safe_b / np.where(known, norm, 1.0)
    normals = np.full((h * w, 3), np.nan, np.float32)
    normals[stack.index] = np.where(known, n, np.nan).T
    if stack.colour is None:
        albedo = np.zeros(h * w, np.float32)
        albedo[stack.index] = np.where(known, norm, 0.0)
        albedo = albedo.reshape(h, w)
    else:
        # Per channel: rho_c = argmin sum_k w_k (I_kc - rho_c s_k)^2 with the shading s_k of the
        # grey normal; a clipped sample does not enter its channel unless all of them are clipped
        # (then they give a lower bound).
        shading = np.maximum(lights32 @ n, 0.0)  # (K', N)
        ws = weights * shading
        albedo = np.zeros((h * w, 3), np.float32)
        for c in range(3):
            clean = ~stack.channel_saturated[c]
            num = np.sum(ws * clean * stack.colour[c], axis=0)
            den = np.sum(ws * clean * shading, axis=0)
            blind = den <= 1e-12
            if blind.any():
                num = np.where(blind, np.sum(ws * stack.colour[c], axis=0), num)
                den = np.where(blind, np.sum(ws * shading, axis=0), den)
            good = known & (den > 1e-12)
            albedo[stack.index, c] = np.where(good, np.maximum(num, 0.0) / np.where(good, den, 1.0), 0.0)
        albedo = albedo.reshape(h, w, 3)
    predicted = np.maximum(lights32 @ safe_b, 0.0)
    misfit = np.sqrt(np.mean((stack.grey - predicted) ** 2, axis=0))
    level = np.sqrt(np.mean(stack.grey * stack.grey, axis=0)) + 1e-4
    residual = np.full(h * w, np.nan, np.float32)
    residual[stack.index] = np.where(known, misfit / level, np.nan)
    light_dirs = np.full((stack.used.size, 3), np.nan)
    if light_rows is not None:
        light_dirs[:] = light_rows
    light_dirs[stack.used] = lights
    return PhotometricStereo(
        normals=normals.reshape(h, w, 3),
        albedo=albedo,
        residual=residual.reshape(h, w),
        light_dirs=light_dirs,
        calibrated=light_rows is not None,
        used=stack.used.copy(),
    )


# --------------------------------------------------------------------------- uncalibrated


def _given_lights(light_dirs, stack: Stack) -> tuple[np.ndarray, np.ndarray]:
    rows = np.asarray(light_dirs, np.float64)
    if rows.shape != (stack.used.size, 3):
        raise UserInputError(f"light_dirs must be {stack.used.size}x3 (one row per image), got {rows.shape}")
    lights = rows[stack.used]
    if not np.all(np.isfinite(lights)) or np.linalg.matrix_rank(lights) < 3:
        raise UserInputError("the light directions of the directional lightings must be finite and span 3 dimensions")
    return lights, rows


def photometric_stereo(
    images: list[np.ndarray],
    *,
    light_dirs: np.ndarray | None = None,
    valid: np.ndarray | None = None,
    ambient_index: int | None = 0,
    shadow_fraction: float = 0.2,
    falloff_sigma_px: float | None = 40.0,
) -> PhotometricStereo:
    """Normals and albedo of one observation (Woodham 1980 calibrated, Hayakawa 1994 uncalibrated).

    Parameters
    ----------
    images : list of K ndarrays, HxW or HxWx3, float32 in [0, 1] (integer images are scaled)
        One image per lighting, all in one registered frame.
    light_dirs : ndarray, Kx3, optional
        Direction towards each light times its intensity, camera frame (x right,
        y down, z away from the camera: a light beside the lens has l_z < 0).
        The ambient row is ignored. None: uncalibrated.
    valid : ndarray, HxW bool, optional
        Pixels to fit (None: all); normals are NaN elsewhere.
    ambient_index : int or None
        The ambient (non-directional) image, left out of the fit; None if all
        images are directional.
    shadow_fraction : float
        Per pixel, a lighting whose level (divided by that lighting's median
        level over the valid pixels) is below this fraction of the pixel's
        brightest is a shadow and is not fitted. Clipped samples (>= 0.98) are
        not fitted either; the remaining ones are reweighted by their residual.
    falloff_sigma_px : float or None
        Near lights: each directional image is divided by its smooth gain
        relative to the mean directional image (locally linear in a Gaussian
        window of this sigma, pixels; median kept). Relief finer than ~sigma is
        kept; shape at larger scales is flattened towards the image-wide mean
        normal and its shading, like shading common to all lightings (e.g.
        daylight cast shadows), stays in the albedo. None for distant lights or
        whole-object shape. The default 40 px is the scale of near-light
        fall-off on the real groups (``docs/lab/2026-11-25-code-comment-measurements.md``, "Change detection").

    Returns
    -------
    PhotometricStereo

    Notes
    -----
    Uncalibrated normals are pseudo-normals. The rank-3 factorization leaves an
    invertible 3x3 ambiguity ``A``. In theory integrability reduces it to a
    generalised bas-relief (GBR) transform (relief depth, mean slope,
    concave/convex sign); here it is used only where it is well conditioned,
    to fix the in-plane rotation and mirror, and the rest is set by
    conventions: the mean normal faces the camera, the median slope is zero,
    the tangential spread is isotropic, the lights' median tilt is 45 degrees,
    and the relief is convex on average. The last one is a weak cue on nearly
    flat reliefs (it can flip between two fits of similar stacks). None of
    this matters for change detection: angles between two fits in one basis
    (:func:`joint_photometric_stereo`) are meaningful, absolute slopes are not.
    """
    stack = prepare_stack(
        images, valid=valid, ambient_index=ambient_index, falloff_sigma_px=falloff_sigma_px, name="photometric stereo"
    )
    if light_dirs is not None:
        lights, rows = _given_lights(light_dirs, stack)
        b, weights = _robust_fit(stack, lights, shadow_fraction)
        return _finish(stack, b, weights, lights, rows)
    lights = factorize_lights([stack], shadow_fraction)
    b, weights = _robust_fit(stack, lights, shadow_fraction)
    a = canonical_basis(b.T, stack.shape, stack.index, lights)
    return _finish(stack, (b.T @ a).T.astype(np.float32), weights, lights @ np.linalg.inv(a).T, None)


@dataclass(frozen=True, kw_only=True)
class JointFitConfig:
    """Options of :func:`joint_photometric_stereo` besides the data (see its Parameters)."""

    shadow_fraction: float = 0.2
    falloff_sigma_px: float | None = 40.0
    same_lights: bool = True
    align: bool = True


def joint_photometric_stereo(
    ref_images: list[np.ndarray],
    cur_images: list[np.ndarray],
    *,
    valid: np.ndarray | None = None,
    ambient_index: int | None = 0,
    light_dirs: np.ndarray | None = None,
    config: JointFitConfig | None = None,
) -> tuple[PhotometricStereo, PhotometricStereo]:
    """Photometric stereo of a reference and a registered current observation, in one basis.

    Parameters
    ----------
    ref_images, cur_images : lists of K ndarrays, HxW or HxWx3 float32 in [0, 1]
        The two stacks, same lightings in the same order, the current one
        already registered onto the reference frame.
    valid : ndarray, HxW bool, optional
        Pixels valid in both (e.g. the registered overlap); None: all.
    ambient_index, light_dirs
        As in :func:`photometric_stereo`; ``light_dirs`` applies to both stacks.
    config : JointFitConfig, optional (default: the shipped one); its fields:
    shadow_fraction, falloff_sigma_px
        As in :func:`photometric_stereo`.
    same_lights : bool
        Uncalibrated only. True (one rig): one light matrix is factorized from
        the pixels of both stacks together. False: each stack is factorized
        alone and the basis alignment carries the whole 3x3 ambiguity.
    align : bool
        Fit a robust 3x3 ``X`` with ``B_cur X ~ B_ref`` over the valid pixels
        (IRLS; changes, a few percent of the pixels, are outliers) and express
        the current fit in the reference basis (``L_cur <- L_cur X^-T``): a
        global exposure change or a slight change of the lights is absorbed.

    Returns
    -------
    (ref, cur) : tuple of PhotometricStereo
        Both in the reference basis. Uncalibrated: pseudo-normals whose frame
        conventions (:func:`photometric_stereo`, Notes) are computed on the reference.
    """
    config = config or JointFitConfig()
    shadow_fraction, same_lights, align = config.shadow_fraction, config.same_lights, config.align
    if len(ref_images) != len(cur_images):
        raise UserInputError(f"{len(ref_images)} reference image(s) but {len(cur_images)} current image(s)")
    if not same_lights and not align and light_dirs is None:
        raise UserInputError("same_lights=False needs align=True: separate factorizations share no basis")
    options = dict(valid=valid, ambient_index=ambient_index, falloff_sigma_px=config.falloff_sigma_px)
    ref = prepare_stack(ref_images, name="reference", **options)
    cur = prepare_stack(cur_images, name="current", **options)
    if ref.shape != cur.shape:
        raise UserInputError(f"reference images are {ref.shape}, current images are {cur.shape}: sizes must match")
    rows = None
    if light_dirs is not None:
        lights_ref, rows = _given_lights(light_dirs, ref)
        lights_cur = lights_ref
    elif same_lights:
        lights_ref = lights_cur = factorize_lights([ref, cur], shadow_fraction)
    else:
        lights_ref = factorize_lights([ref], shadow_fraction)
        lights_cur = factorize_lights([cur], shadow_fraction)
    b_ref, w_ref = _robust_fit(ref, lights_ref, shadow_fraction)
    b_cur, w_cur = _robust_fit(cur, lights_cur, shadow_fraction)
    b_ref, b_cur = b_ref.T, b_cur.T
    if light_dirs is None:
        a = canonical_basis(b_ref, ref.shape, ref.index, lights_ref)
        a_inv_t = np.linalg.inv(a).T
        b_ref, lights_ref = b_ref @ a, lights_ref @ a_inv_t
        b_cur, lights_cur = b_cur @ a, lights_cur @ a_inv_t
    if align:
        x = align_basis(b_cur, b_ref)
        b_cur, lights_cur = b_cur @ x, lights_cur @ np.linalg.inv(x).T
    return (
        _finish(ref, b_ref.T.astype(np.float32), w_ref, lights_ref, rows),
        _finish(cur, b_cur.T.astype(np.float32), w_cur, lights_cur, rows),
    )


def relief_and_colour_cues(
    ref: PhotometricStereo,
    cur: PhotometricStereo,
    *,
    valid: np.ndarray,
    eps_fraction: float = 0.05,
) -> tuple[np.ndarray, np.ndarray]:
    """Relief cue (normal angle) and colour cue (log albedo ratio) between two fits in one basis.

    Parameters
    ----------
    ref, cur : PhotometricStereo
        Fits of the reference and current observations in a common basis
        (:func:`joint_photometric_stereo`).
    valid : ndarray, HxW bool
        Pixels to score. Both cues are 0 outside it and where either normal is unknown.
    eps_fraction : float
        ``eps_c = eps_fraction x`` the median reference albedo of channel c over
        the scored pixels, added to both albedos so that dark pixels (albedo
        mostly noise) do not give large log ratios; relative, because
        uncalibrated albedo has an arbitrary unit. 0.05: a stain on the darkest
        paints still counts, read noise on them does not explode.

    Returns
    -------
    relief : ndarray, HxW float32
        Angle between the reference and current normals, radians in [0, pi].
    colour : ndarray, HxW float32
        ``sum_c |log((g_c a_cur_c + eps_c) / (a_ref_c + eps_c))|`` over channels
        (dimensionless), where the gain ``g_c`` is the median of ``a_ref_c / a_cur_c``
        over the scored pixels (exposure, white balance).
    """
    valid = np.asarray(valid, bool)
    if ref.normals.shape != cur.normals.shape or valid.shape != ref.normals.shape[:2]:
        raise UserInputError("relief_and_colour_cues: the two fits and the valid mask must have the same size")
    known = valid & np.isfinite(ref.normals[:, :, 0]) & np.isfinite(cur.normals[:, :, 0])
    n_ref = np.where(known[:, :, None], ref.normals, 0.0)
    n_cur = np.where(known[:, :, None], cur.normals, 0.0)
    dot = np.sum(n_ref * n_cur, axis=2)
    cross = np.linalg.norm(np.cross(n_ref, n_cur), axis=2)
    relief = np.where(known, np.arctan2(cross, dot), 0.0).astype(np.float32)

    a_ref = ref.albedo if ref.albedo.ndim == 3 else ref.albedo[:, :, None]
    a_cur = cur.albedo if cur.albedo.ndim == 3 else cur.albedo[:, :, None]
    colour = np.zeros(valid.shape, np.float32)
    for c in range(a_ref.shape[2]):
        r, k = a_ref[:, :, c], a_cur[:, :, c]
        sel = known & (r > 0) & (k > 0)
        if not sel.any():
            continue
        gain = float(np.median(r[sel] / k[sel]))
        eps = eps_fraction * float(np.median(r[sel])) + 1e-12
        colour += np.abs(np.log((gain * k + eps) / (r + eps))).astype(np.float32)
    return relief, np.where(known, colour, 0.0).astype(np.float32)
