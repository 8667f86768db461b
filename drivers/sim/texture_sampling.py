"""Texture lookups of the renderer: mip pyramids, trilinear sampling, bump-mapped normals (docs/simulator.md, "Renderer")."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["mip_pyramid", "sample_mipmapped", "bent_normals"]


def mip_pyramid(texture: np.ndarray) -> list[np.ndarray]:
    """A texture and its successive halvings down to 4 texels (float32).

    Every level keeps the texture where it is: a texel's centre ``(i + 0.5) / n`` in
    texture coordinates is the centre of what it averages (docs/simulator.md, "Renderer").
    """
    pyr = [np.ascontiguousarray(texture, dtype=np.float32)]
    while min(pyr[-1].shape[:2]) > 4:
        pyr.append(_halve(pyr[-1]))
    return pyr


def _halve(tex: np.ndarray) -> np.ndarray:
    """One mip level down: the binomial filter [1, 3, 3, 1] / 8 centred between each texel pair.

    Written out because ``cv2.pyrDown`` centres output texel ``i`` on input texel ``2i``, not
    between ``2i`` and ``2i + 1``: each level would slide the texture by half a texel of the
    level above, (2^k - 1) / 2 texels at level k, so detail would move on the surface as the
    camera's distance changes the level. Here a [1, 2, 1] / 4 blur (wrapping, as the lookups
    do) followed by an area halving (the 2 x 2 mean; OpenCV's half-pixel-centred area resize
    for odd sizes) makes the centred [1, 3, 3, 1] / 8.
    """
    h, w = tex.shape[:2]
    padded = cv2.copyMakeBorder(tex, 1, 1, 1, 1, cv2.BORDER_WRAP)  # OpenCV's filters refuse BORDER_WRAP
    kernel = np.array([0.25, 0.5, 0.25], np.float32)
    blurred = cv2.sepFilter2D(padded, -1, kernel, kernel)[1 : h + 1, 1 : w + 1]
    return cv2.resize(blurred, (max(1, w // 2), max(1, h // 2)), interpolation=cv2.INTER_AREA)


def sample_mipmapped(pyramid: list[np.ndarray], uvs: np.ndarray, level: np.ndarray) -> np.ndarray:
    """Trilinear lookup: bilinear in the two mip levels around ``level`` (N,), blended; (N, 3) float32."""
    l0 = np.floor(level).astype(np.int64)
    frac = (level - l0).astype(np.float32)[:, None]
    out = np.empty((len(uvs), 3), np.float32)
    lo, hi = int(l0.min()), int(l0.max())
    for lv in range(lo, hi + 1):
        m = slice(None) if lo == hi else np.flatnonzero(l0 == lv)
        if not isinstance(m, slice) and len(m) == 0:
            continue
        acc = None
        for k, wgt in ((lv, 1.0 - frac[m]), (min(lv + 1, len(pyramid) - 1), frac[m])):
            tex = pyramid[k]
            th, tw = tex.shape[:2]
            x = uvs[m, 0] * np.float32(tw) - np.float32(0.5)
            y = uvs[m, 1] * np.float32(th) - np.float32(0.5)
            smp = _remap_1d(tex, x, y)
            smp *= wgt
            acc = smp if acc is None else acc + smp
        out[m] = acc
    return out


def bent_normals(normals: np.ndarray, slope: np.ndarray, tangents: np.ndarray) -> np.ndarray:
    """Shading normals bent by the mesostructure's slope: ``n' ∝ n - (s_u t_u + s_v t_v)`` (bump mapping).

    Parameters
    ----------
    normals : (N, 3) float32 unit normals.
    slope : (N, 3) float32, the sampled slope texture (``d h / d u_m``, ``d h / d v_m``, 0).
    tangents : (N, 2, 3) float32 unit world directions of u and v on each hit's triangle.
    """
    t_u, t_v = tangents[:, 0], tangents[:, 1]
    # into the shading normal's tangent plane (interpolated normals are not the face's)
    t_u = t_u - np.einsum("ij,ij->i", t_u, normals)[:, None] * normals
    t_v = t_v - np.einsum("ij,ij->i", t_v, normals)[:, None] * normals
    bent = normals - slope[:, 0:1] * t_u - slope[:, 1:2] * t_v
    return bent / np.maximum(np.sqrt(np.einsum("ij,ij->i", bent, bent)), 1e-12)[:, None]


def _remap_1d(img: np.ndarray, x: np.ndarray, y: np.ndarray, border=cv2.BORDER_WRAP) -> np.ndarray:
    """Bilinear lookup of ``img`` at N float pixel coordinates (cv2.remap, 1/32 px precision).

    cv2.remap is limited to < 32767 columns, so the N samples are laid out as rows of 1024.
    """
    n = x.size
    cols = 1024
    rows = max(1, (n + cols - 1) // cols)
    mx = np.zeros(rows * cols, np.float32)
    my = np.zeros(rows * cols, np.float32)
    mx[:n] = x
    my[:n] = y
    out = cv2.remap(img, mx.reshape(rows, cols), my.reshape(rows, cols), cv2.INTER_LINEAR, borderMode=border)
    return out.reshape(rows * cols, -1)[:n]
