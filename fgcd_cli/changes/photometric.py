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

import cv2
import numpy as np

from fgcd_cli.changes.images import to_float_image
from fgcd_cli.errors import AlgorithmError, UserInputError

# Rules of the robust per-pixel fit (both cases).
_SATURATION = 0.98  # a sample (channel) at or above this level is clipped and never fitted
_OUTLIER_FRACTION = 0.3  # Tukey cut-off of a sample's residual, relative to the pixel's RMS level
_IRLS_ITERATIONS = 3
_MIN_CONDITION = 1e-4  # det / (trace/3)^3 of the weighted 3x3 system below this: the pixel is unknown
_DARK_LEVEL = 0.01  # a pixel whose brightest directional sample is below this is unknown

# Rules of the uncalibrated factorization.
_SVD_SAMPLES = 60_000  # reliable pixels (all stacks together) entering the SVD
_SVD_TRIM = 0.1  # fraction of worst-fitting rows dropped before the second SVD
_FRAME_SAMPLES = 200_000  # pixels used for the frame conventions and the basis alignment
_LIGHT_TILT_DEG = 45.0  # relief-depth convention: median angle of the lights from the optical axis
_ALIGN_ITERATIONS = 6


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


@dataclass(kw_only=True)
class _Stack:
    """The directional lightings of one observation, on its valid pixels (N of them)."""

    shape: tuple[int, int]
    index: np.ndarray  # (N,) flat indices of the valid pixels
    grey: np.ndarray  # (K', N) float32, falloff-corrected
    saturated: np.ndarray  # (K', N) bool: the grey sample is clipped
    colour: np.ndarray | None  # (3, K', N) float32, falloff-corrected; None for grey input
    channel_saturated: np.ndarray | None  # (3, K', N) bool
    used: np.ndarray  # (K,) bool


# --------------------------------------------------------------------------- input


def _falloff_gains(grey: np.ndarray, weight: np.ndarray, index: np.ndarray, shape: tuple[int, int],
                   sigma_px: float) -> np.ndarray:
    """Smooth brightness gain of each lighting relative to the mean directional image (near lights).

    Per lighting k and pixel x0, ``g_k(x0)`` is the intercept of the locally linear
    gain ``a + b . (x - x0)`` that best maps the mean directional image onto
    ``I_k`` in a Gaussian window of ``sigma_px`` (weighted least squares, pixels
    with a clipped sample left out). The ratio cancels the albedo; the linear
    term keeps a light falloff ramp unbiased up to the image border, where a
    plain ratio of blurs is not. Each gain is divided by its median, so that the
    lights keep their relative intensities. Relief finer than ~sigma survives;
    shape at larger scales is flattened towards the image-wide mean normal.

    grey (K', N) on the valid pixels ``index``; weight (H*W,) 0/1. Returns (K', N) float32.
    """
    h, w = shape
    factor = max(1, int(sigma_px / 6.0))  # the gain is smooth: work on a grid ~6 cells per sigma
    hs, ws = max(1, h // factor), max(1, w // factor)
    sigma = sigma_px * ws / w

    def down(values: np.ndarray) -> np.ndarray:
        full = np.zeros(h * w, np.float32)
        full[index] = values
        full *= weight
        return cv2.resize(full.reshape(h, w), (ws, hs), interpolation=cv2.INTER_AREA).astype(np.float64)

    def blur(image: np.ndarray) -> np.ndarray:
        return cv2.GaussianBlur(image, (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)

    ys, xs = np.mgrid[0:hs, 0:ws].astype(np.float64)
    mean = grey.mean(axis=0)
    u = down(mean * mean)
    s0, s_x, s_y = blur(u), blur(u * xs), blur(u * ys)
    m = np.empty((hs, ws, 3, 3))
    m[..., 0, 0] = s0
    m[..., 0, 1] = m[..., 1, 0] = s_x - xs * s0
    m[..., 0, 2] = m[..., 2, 0] = s_y - ys * s0
    m[..., 1, 1] = blur(u * xs * xs) - 2 * xs * s_x + xs * xs * s0
    m[..., 2, 2] = blur(u * ys * ys) - 2 * ys * s_y + ys * ys * s0
    m[..., 1, 2] = m[..., 2, 1] = blur(u * xs * ys) - xs * s_y - ys * s_x + xs * ys * s0
    # A small ridge on the slopes: where the window holds pixels on one line only, the gain
    # falls back to the plain weighted ratio.
    support = s0 > 1e-6 * max(float(s0.max()), 1e-30)
    ridge = 0.01 * sigma * sigma * np.where(support, s0, 1.0)
    m[..., 1, 1] += ridge
    m[..., 2, 2] += ridge
    m[~support] = np.eye(3)
    gains = np.empty_like(grey)
    for k in range(grey.shape[0]):
        v = down(grey[k] * mean)
        t0 = blur(v)
        rhs = np.stack([t0, blur(v * xs) - xs * t0, blur(v * ys) - ys * t0], axis=-1)
        a = np.linalg.solve(m, rhs[..., None])[..., 0, 0]
        a = np.where(support, a, np.nan)
        fill = np.nanmedian(a) if np.isfinite(a).any() else 1.0
        a = np.where(np.isfinite(a), a, fill).astype(np.float32)
        gain = cv2.resize(a, (w, h), interpolation=cv2.INTER_LINEAR).ravel()[index]
        median = float(np.median(gain)) if gain.size else 1.0
        gains[k] = np.clip(gain / max(median, 1e-6), 0.05, 20.0)
    return gains.astype(np.float32)


def _prepare(images, *, valid, ambient_index, falloff_sigma_px, name) -> _Stack:
    """Validate one stack and extract its directional lightings on the valid pixels."""
    if len(images) < 3:
        raise UserInputError(f"{name}: photometric stereo needs at least 3 images, got {len(images)}")
    floats = [to_float_image(im, name=f"{name} image {i + 1}") for i, im in enumerate(images)]
    shape = floats[0].shape
    for i, im in enumerate(floats):
        if im.shape != shape:
            raise UserInputError(f"{name} image {i + 1} has shape {im.shape}, image 1 has {shape}: all must match")
    h, w = shape[:2]
    used = np.ones(len(floats), bool)
    if ambient_index is not None:
        if not -len(floats) <= ambient_index < len(floats):
            raise UserInputError(f"{name}: ambient_index {ambient_index} is outside 0..{len(floats) - 1}")
        used[ambient_index] = False
    if used.sum() < 3:
        raise UserInputError(f"{name}: photometric stereo needs at least 3 directional lightings, got {used.sum()}")
    if valid is None:
        valid_mask = np.ones((h, w), bool)
    else:
        valid_mask = np.asarray(valid, bool)
        if valid_mask.shape != (h, w):
            raise UserInputError(f"{name}: valid mask is {valid_mask.shape}, images are {(h, w)}")
    directional = [floats[k] for k in np.flatnonzero(used)]
    index = np.flatnonzero(valid_mask.ravel())
    everything = index.size == h * w

    def pick(flat: np.ndarray) -> np.ndarray:
        return flat if everything else flat[index]

    colour = channel_saturated = None
    if len(shape) == 3:
        colour = np.stack([np.stack([pick(im[:, :, c].ravel()) for im in directional]) for c in range(3)])
        channel_saturated = colour >= _SATURATION
        # Bright paint clips one channel under most lights: a pixel's grey is the mean of
        # its channels never clipped, the same channels in every lighting (so that the
        # pixel stays Lambertian, with the mean albedo of those channels).
        clean = ~channel_saturated.any(axis=1)  # (3, N)
        count = clean.sum(axis=0)
        some = count > 0
        share = np.where(some, clean / np.maximum(count, 1), 1.0 / 3.0).astype(np.float32)
        grey = colour[0] * share[0] + colour[1] * share[1] + colour[2] * share[2]
        saturated = channel_saturated.any(axis=0) & ~some
        clipped_anywhere = ~clean.all(axis=0)
    else:
        grey = np.stack([pick(im.ravel()) for im in directional])
        saturated = grey >= _SATURATION
        clipped_anywhere = saturated.any(axis=0)

    if falloff_sigma_px:
        weight = np.zeros(h * w, np.float32)
        weight[index] = ~clipped_anywhere
        gains = _falloff_gains(grey, weight, index, (h, w), falloff_sigma_px)
        grey /= gains
        if colour is not None:
            colour /= gains[None]
    return _Stack(shape=(h, w), index=index, grey=grey.astype(np.float32), saturated=saturated,
                  colour=colour, channel_saturated=channel_saturated, used=used)


# --------------------------------------------------------------------------- per-pixel fit


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


def _robust_fit(stack: _Stack, lights: np.ndarray, shadow_fraction: float):
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
    hard = usable & (relative >= shadow_fraction * relative.max(axis=0)) & (grey.max(axis=0) >= _DARK_LEVEL)
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


def _finish(stack: _Stack, b: np.ndarray, weights: np.ndarray, lights: np.ndarray,
            light_rows: np.ndarray | None) -> PhotometricStereo:
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


def _factorize_lights(stacks: list[_Stack], shadow_fraction: float) -> np.ndarray:
    """Lights (K', 3) up to an invertible 3x3, from the rank-3 SVD of reliable pixels (Hayakawa 1994).

    The pixels of all stacks enter one matrix (one rig, one set of lights).
    Reliable: no clipped sample, no sample darker than ``shadow_fraction`` x the
    brightest (per-lighting median levels divided out), not dark. Each row is
    scaled to unit norm so that every pixel counts once whatever its albedo; a
    second SVD leaves out the ``_SVD_TRIM`` worst-fitting rows (cast shadows,
    highlights). The returned columns are orthonormal: ``B = I L`` on clean pixels.
    """
    rng = np.random.default_rng(0)
    rows = []
    for st in stacks:
        grey = st.grey
        rel = grey / np.maximum(np.median(grey, axis=1), 1e-6)[:, None]
        reliable = ~st.saturated.any(axis=0) & (rel.min(axis=0) >= shadow_fraction * rel.max(axis=0))
        reliable &= grey.max(axis=0) >= 5 * _DARK_LEVEL
        idx = np.flatnonzero(reliable)
        if idx.size > _SVD_SAMPLES // len(stacks):
            idx = np.sort(rng.choice(idx, _SVD_SAMPLES // len(stacks), replace=False))
        rows.append(grey[:, idx].T)
    m = np.concatenate(rows).astype(np.float64)
    if m.shape[0] < 10 * m.shape[1]:
        raise AlgorithmError(
            f"uncalibrated photometric stereo: only {m.shape[0]} reliable pixels (unshadowed, unclipped); "
            "give the light directions or a larger valid region"
        )
    m /= np.linalg.norm(m, axis=1, keepdims=True)
    _, _, vt = np.linalg.svd(m, full_matrices=False)
    misfit = np.linalg.norm(m - (m @ vt[:3].T) @ vt[:3], axis=1)
    keep = misfit <= np.quantile(misfit, 1.0 - _SVD_TRIM)
    _, _, vt = np.linalg.svd(m[keep], full_matrices=False)
    return vt[:3].T.copy()


def _unit_rows(b: np.ndarray) -> np.ndarray:
    return b / np.linalg.norm(b, axis=1, keepdims=True)


def _curl_div(b: np.ndarray, shape: tuple[int, int], index: np.ndarray):
    """Curl ``q_x - p_y`` and divergence ``p_x + q_y`` of the gradient field of pseudo-normal rows b (N, 3).

    ``(p, q) = (n_x, n_y) / -n_z = (dZ/dx, dZ/dy)`` for a depth map Z. Only pixels
    whose 5x5 neighbourhood has a non-grazing normal count (flattened arrays).
    """
    h, w = shape
    nz = -b[:, 2]
    ok = np.isfinite(nz) & (nz > 0.2 * np.linalg.norm(b, axis=1))
    safe = np.where(ok, nz, 1.0)
    lim = 3.0  # slopes beyond ~72 degrees are clipped: at grazing normals they are mostly noise
    p = np.zeros(h * w, np.float32)
    q = np.zeros(h * w, np.float32)
    known = np.zeros(h * w, np.uint8)
    p[index] = np.clip(np.where(ok, b[:, 0] / safe, 0.0), -lim, lim)
    q[index] = np.clip(np.where(ok, b[:, 1] / safe, 0.0), -lim, lim)
    known[index] = ok
    p = cv2.GaussianBlur(p.reshape(h, w), (0, 0), 1.0)
    q = cv2.GaussianBlur(q.reshape(h, w), (0, 0), 1.0)
    support = cv2.erode(known.reshape(h, w), np.ones((5, 5), np.uint8)).astype(bool)
    p_y, p_x = np.gradient(p)
    q_y, q_x = np.gradient(q)
    return (q_x - p_y)[support].astype(np.float64), (p_x + q_y)[support].astype(np.float64)


def _canonical_basis(b: np.ndarray, shape: tuple[int, int], index: np.ndarray, lights: np.ndarray) -> np.ndarray:
    """The 3x3 ``A`` (``B <- B A``, ``L <- L A^-T``) that fixes the uncalibrated frame.

    b (N, 3) pseudo-normal rows of the valid pixels (NaN where unknown); lights (K', 3).

    1. the mean unit pseudo-normal is turned to (0, 0, -1): the object faces the camera;
    2. a shear makes the median surface gradient zero (the GBR's mean slope);
    3. the tangential spread of the unit normals is whitened (made isotropic);
    4. the in-plane rotation and mirror left by 3 are those that make the gradient
       field most integrable (smallest curl): with ``curl(R_phi h) = cos(phi) curl h
       + sin(phi) div h`` this is the smallest eigenvector of a 2x2 matrix. It ties
       the normal axes to the image axes (x right, y down);
    5. the concave/convex sign, which no shading or shadow can tell (GBR), is set so
       that the relief is convex towards the camera on average (mean divergence > 0);
    6. the relief depth (GBR's lambda) is set so that the median light is
       ``_LIGHT_TILT_DEG`` from the optical axis, and the overall scale so that the
       median ``|l|`` is 1 (albedo in image-intensity units).
    Only step 4 is a measurement; 1-3 and 5-6 are conventions.
    """
    finite = np.all(np.isfinite(b), axis=1)
    sample = np.flatnonzero(finite)
    if sample.size > _FRAME_SAMPLES:
        sample = np.random.default_rng(1).choice(sample, _FRAME_SAMPLES, replace=False)
    rows = b[sample].astype(np.float64)
    rows = rows[np.linalg.norm(rows, axis=1) > 1e-8]
    if rows.shape[0] < 30:
        raise AlgorithmError("uncalibrated photometric stereo: too few pixels with a normal to fix the frame")
    # 1. mean direction -> -z
    mean = _unit_rows(rows).mean(axis=0)
    mean /= np.linalg.norm(mean)
    e1 = np.cross(np.eye(3)[np.argmin(np.abs(mean))], mean)
    e1 /= np.linalg.norm(e1)
    a = np.column_stack([e1, np.cross(mean, e1), -mean])
    # 2. median gradient -> 0: p' = p - p0  <=>  b_x' = b_x + p0 b_z
    cur = rows @ a
    nz = -cur[:, 2]
    front = nz > 0.2 * np.linalg.norm(cur, axis=1)
    shear = np.eye(3)
    if np.count_nonzero(front) >= 30:
        shear[2, 0] = np.median(cur[front, 0] / nz[front])
        shear[2, 1] = np.median(cur[front, 1] / nz[front])
    a = a @ shear
    # 3. whiten the tangential spread (twice: unit vectors are not linear in b)
    for _ in range(2):
        t = _unit_rows(rows @ a)[:, :2]
        r = np.linalg.norm(t, axis=1)
        t = t[r <= np.quantile(r, 0.98)]
        vals, vecs = np.linalg.eigh(np.cov(t.T) + 1e-12 * np.eye(2))
        vals = np.maximum(vals, 0.01 * vals.max())  # a nearly 1-D relief (a cylinder) is not blown up
        step = np.eye(3)
        step[:2, :2] = (vecs @ np.diag(np.sqrt(vals.mean() / vals)) @ vecs.T).T
        a = a @ step
    # 4. in-plane rotation and mirror by integrability
    best = None
    for flip in (np.eye(3), np.diag([1.0, -1.0, 1.0])):
        curl, div = _curl_div((b @ (a @ flip)).astype(np.float32), shape, index)
        gram = np.array([[curl @ curl, curl @ div], [curl @ div, div @ div]])
        vals, vecs = np.linalg.eigh(gram)
        ratio = vals[0] / max(vals[1], 1e-30)
        if best is None or ratio < best[0]:
            best = (ratio, flip, vecs[:, 0])
    _, flip, (c, s) = best
    rot = np.eye(3)
    rot[:2, :2] = [[c, s], [-s, c]]  # rows: b_xy' = b_xy R^T with R = [[c, -s], [s, c]]
    a = a @ flip @ rot
    # 5. convex towards the camera on average
    _, div = _curl_div((b @ a).astype(np.float32), shape, index)
    if div.size and float(np.mean(div)) < 0.0:
        a = a @ np.diag([-1.0, -1.0, 1.0])
    # 6. relief depth from the lights' tilt, then the overall scale
    lt = lights @ np.linalg.inv(a).T
    towards = -lt[:, 2]
    if np.median(towards) > 0:
        tan_tilt = float(np.median(np.linalg.norm(lt[:, :2], axis=1) / np.maximum(towards, 1e-9)))
        lam = tan_tilt / np.tan(np.radians(_LIGHT_TILT_DEG))
        if np.isfinite(lam) and lam > 1e-6:
            a = a @ np.diag([lam, lam, 1.0])
    lt = lights @ np.linalg.inv(a).T
    return a * float(np.median(np.linalg.norm(lt, axis=1)))


def _align_basis(b_cur: np.ndarray, b_ref: np.ndarray) -> np.ndarray:
    """Robust 3x3 ``X`` with ``b_cur X ~ b_ref`` (rows: the same pixels in both).

    Weighted least squares iterated with Tukey's biweight of the relative row
    residual (cut-off 4.685 robust sigmas): changed pixels, a few percent, drop
    out; an exposure or slight light change, linear in b, is absorbed.
    """
    ok = np.all(np.isfinite(b_cur), axis=1) & np.all(np.isfinite(b_ref), axis=1)
    idx = np.flatnonzero(ok)
    if idx.size < 30:
        return np.eye(3)
    if idx.size > _FRAME_SAMPLES:
        idx = np.random.default_rng(2).choice(idx, _FRAME_SAMPLES, replace=False)
    src = b_cur[idx].astype(np.float64)
    dst = b_ref[idx].astype(np.float64)
    size = np.linalg.norm(dst, axis=1)
    size += 1e-3 * np.median(size)
    weights = np.ones(idx.size)
    x = np.eye(3)
    for _ in range(_ALIGN_ITERATIONS + 1):
        ws = src * weights[:, None]
        x = np.linalg.solve(ws.T @ src + 1e-12 * np.eye(3), ws.T @ dst)
        err = np.linalg.norm(src @ x - dst, axis=1) / size
        u = err / (4.685 * 1.4826 * np.median(err) + 1e-12)
        weights = np.where(u < 1.0, (1.0 - u * u) ** 2, 0.0)
    return x


# --------------------------------------------------------------------------- public API


def _given_lights(light_dirs, stack: _Stack) -> tuple[np.ndarray, np.ndarray]:
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
        whole-object shape. The default 40 px was chosen on the real groups by
        the look of the normal maps and the rank-3 residual (with no correction
        Dp-1's normals drift by ~6 degrees across the image).

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
    stack = _prepare(images, valid=valid, ambient_index=ambient_index, falloff_sigma_px=falloff_sigma_px,
                     name="photometric stereo")
    if light_dirs is not None:
        lights, rows = _given_lights(light_dirs, stack)
        b, weights = _robust_fit(stack, lights, shadow_fraction)
        return _finish(stack, b, weights, lights, rows)
    lights = _factorize_lights([stack], shadow_fraction)
    b, weights = _robust_fit(stack, lights, shadow_fraction)
    a = _canonical_basis(b.T, stack.shape, stack.index, lights)
    return _finish(stack, (b.T @ a).T.astype(np.float32), weights, lights @ np.linalg.inv(a).T, None)


def joint_photometric_stereo(
    ref_images: list[np.ndarray],
    cur_images: list[np.ndarray],
    *,
    valid: np.ndarray | None = None,
    ambient_index: int | None = 0,
    light_dirs: np.ndarray | None = None,
    shadow_fraction: float = 0.2,
    falloff_sigma_px: float | None = 40.0,
    same_lights: bool = True,
    align: bool = True,
) -> tuple[PhotometricStereo, PhotometricStereo]:
    """Photometric stereo of a reference and a registered current observation, in one basis.

    Parameters
    ----------
    ref_images, cur_images : lists of K ndarrays, HxW or HxWx3 float32 in [0, 1]
        The two stacks, same lightings in the same order, the current one
        already registered onto the reference frame.
    valid : ndarray, HxW bool, optional
        Pixels valid in both (e.g. the registered overlap); None: all.
    ambient_index, light_dirs, shadow_fraction, falloff_sigma_px
        As in :func:`photometric_stereo`; ``light_dirs`` applies to both stacks.
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
    if len(ref_images) != len(cur_images):
        raise UserInputError(f"{len(ref_images)} reference image(s) but {len(cur_images)} current image(s)")
    if not same_lights and not align and light_dirs is None:
        raise UserInputError("same_lights=False needs align=True: separate factorizations share no basis")
    options = dict(valid=valid, ambient_index=ambient_index, falloff_sigma_px=falloff_sigma_px)
    ref = _prepare(ref_images, name="reference", **options)
    cur = _prepare(cur_images, name="current", **options)
    if ref.shape != cur.shape:
        raise UserInputError(f"reference images are {ref.shape}, current images are {cur.shape}: sizes must match")
    rows = None
    if light_dirs is not None:
        lights_ref, rows = _given_lights(light_dirs, ref)
        lights_cur = lights_ref
    elif same_lights:
        lights_ref = lights_cur = _factorize_lights([ref, cur], shadow_fraction)
    else:
        lights_ref = _factorize_lights([ref], shadow_fraction)
        lights_cur = _factorize_lights([cur], shadow_fraction)
    b_ref, w_ref = _robust_fit(ref, lights_ref, shadow_fraction)
    b_cur, w_cur = _robust_fit(cur, lights_cur, shadow_fraction)
    b_ref, b_cur = b_ref.T, b_cur.T
    if light_dirs is None:
        a = _canonical_basis(b_ref, ref.shape, ref.index, lights_ref)
        a_inv_t = np.linalg.inv(a).T
        b_ref, lights_ref = b_ref @ a, lights_ref @ a_inv_t
        b_cur, lights_cur = b_cur @ a, lights_cur @ a_inv_t
    if align:
        x = _align_basis(b_cur, b_ref)
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
