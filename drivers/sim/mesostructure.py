"""Mesostructure: relief finer than the mesh (grain, tool marks, pits), as a slope field on each surface.

Real stone and plaster are rough below a millimetre: under a side light each
grain is lit on one flank and dark on the other, so the shading texture of a
surface moves with the light while its albedo does not (docs/simulator.md,
"Appearance"). The renderer bends each shading normal by the local slope of
a height field ``h`` (classic bump mapping): ``n' ∝ n - grad h`` with
``grad h`` in the surface's tangent plane. The slope field is a wrapped
fractal texture in each part's own texture space, filtered with the same mip
pyramid as the albedo, so relief finer than a pixel averages out as a pixel
does; stills (supersampled) keep the shading of the grains they resolve.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgcd_drivers.sim.textures import fractal_noise

__all__ = ["PLASTER_SLOPE_RMS", "Mesostructure", "slope_texture", "triangle_tangents"]

#: The RMS slope at which the simulated test block's pixel-scale roughness matches real plaster's,
#: both measured the same way: photometric stereo under the multi-light set's 12 lights, the median
#: angle between each normal and its 2-pixel Gaussian neighbourhood (the figures:
#: docs/lab/2026-12-06-lighting.md, "Lead 4"). The calibrated world's slope (appearance.WORLDS).
PLASTER_SLOPE_RMS = 0.2


@dataclass(frozen=True, kw_only=True)
class Mesostructure:
    """How rough the surfaces are below the mesh's resolution.

    Attributes
    ----------
    slope_rms : float
        RMS of the height field's gradient ``|grad h|`` (dimensionless: 0.1 tilts
        normals by about 6 degrees RMS); 0 leaves the surfaces smooth (the
        appearance before mesostructure).
    finest_texels : float
        Blur (sigma, texels) of the finest octave: the smallest grain.
    octaves : int
        Octaves of the fractal, each twice as coarse as the one before.
    seed : int
    """

    slope_rms: float = 0.0
    finest_texels: float = 0.7
    octaves: int = 4
    seed: int = 7


def slope_texture(shape: tuple[int, int], texel_size_m: float, meso: Mesostructure, part_index: int) -> np.ndarray:
    """A part's slope texture: ``(d h / d u_m, d h / d v_m, 0)`` per texel, float32 (H, W, 3).

    ``u_m``, ``v_m`` are metres along the texture's axes; the field wraps as the
    textures do. Its RMS gradient magnitude is ``meso.slope_rms`` at the texel
    scale.

    Parameters
    ----------
    shape : (H, W)
        The part's texture size (texels).
    texel_size_m : float
        Metres per texel.
    meso : Mesostructure
    part_index : int
        Seeds each part differently.
    """
    rng = np.random.default_rng([meso.seed, part_index, 0x3E5])
    # finest octave first, each next one twice as coarse (fractal_noise halves sigma: start from the coarsest)
    coarsest = meso.finest_texels * 2.0 ** (meso.octaves - 1)
    h = fractal_noise(shape, rng, octaves=meso.octaves, base_sigma=coarsest, persistence=0.5).astype(np.float64)
    gx = (np.roll(h, -1, axis=1) - np.roll(h, 1, axis=1)) / (2.0 * texel_size_m)
    gy = (np.roll(h, -1, axis=0) - np.roll(h, 1, axis=0)) / (2.0 * texel_size_m)
    rms = float(np.sqrt(np.mean(gx**2 + gy**2)))
    k = meso.slope_rms / rms if rms > 0 else 0.0
    out = np.zeros((*shape, 3), np.float32)
    out[..., 0] = gx * k
    out[..., 1] = gy * k
    return out


def triangle_tangents(vertices: np.ndarray, triangles: np.ndarray, tri_uv: np.ndarray) -> np.ndarray:
    """Per triangle, the unit world directions of increasing texture u and v, (M, 2, 3) float32.

    Solves ``dP = dU T`` on each triangle's two edges (``T`` the 2x3 derivative of
    the position by (u, v)); degenerate UV triangles get zero tangents (no relief).

    Parameters
    ----------
    vertices : (V, 3) ndarray
    triangles : (M, 3) int ndarray
    tri_uv : (M, 3, 2) ndarray
        Texture coordinates of each corner.
    """
    v = vertices[triangles].astype(np.float64)
    e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
    uv = tri_uv.astype(np.float64)
    d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)[:, None]
    t_u = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * inv
    t_v = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * inv
    out = np.stack([t_u, t_v], axis=1)
    norm = np.linalg.norm(out, axis=2, keepdims=True)
    return np.where(norm > 1e-12, out / np.maximum(norm, 1e-12), 0.0).astype(np.float32)
