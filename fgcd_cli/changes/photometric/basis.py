"""The basis of uncalibrated photometric stereo: the lights from the rank-3 SVD (Hayakawa 1994), the
conventions that fix the 3x3 ambiguity (:func:`fgcd_cli.changes.photometric.stereo.photometric_stereo`, Notes),
and the robust alignment of a second basis onto the first.
"""

from __future__ import annotations

import cv2
import numpy as np

from fgcd_cli.changes.photometric.stack import DARK_LEVEL, Stack
from fgcd_cli.errors import AlgorithmError

_SVD_SAMPLES = 60_000  # reliable pixels (all stacks together) entering the SVD
_SVD_TRIM = 0.1  # fraction of worst-fitting rows dropped before the second SVD
_FRAME_SAMPLES = 200_000  # pixels used for the frame conventions and the basis alignment
LIGHT_TILT_DEG = 45.0
"""Relief-depth convention: median angle of the lights from the optical axis."""
_ALIGN_ITERATIONS = 6


def factorize_lights(stacks: list[Stack], shadow_fraction: float) -> np.ndarray:
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
        reliable &= grey.max(axis=0) >= 5 * DARK_LEVEL
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


def canonical_basis(b: np.ndarray, shape: tuple[int, int], index: np.ndarray, lights: np.ndarray) -> np.ndarray:
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
       ``LIGHT_TILT_DEG`` from the optical axis, and the overall scale so that the
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
        lam = tan_tilt / np.tan(np.radians(LIGHT_TILT_DEG))
        if np.isfinite(lam) and lam > 1e-6:
            a = a @ np.diag([lam, lam, 1.0])
    lt = lights @ np.linalg.inv(a).T
    return a * float(np.median(np.linalg.norm(lt, axis=1)))


def align_basis(b_cur: np.ndarray, b_ref: np.ndarray) -> np.ndarray:
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
