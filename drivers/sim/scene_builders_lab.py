"""Laboratory test objects: the painted plaster test block of ageing experiments (the FGCD dataset's Db kind).

A plaster disc with patches of thick paint (impasto brush ridges, flat colours)
and rough plaster between them, as the real test blocks of
``../shared/data/fgcd-dataset/Db`` are: most of what a feature detector finds
on them is relief shading, which moves with the light, not albedo, which does
not (docs/simulator.md, "Scenes").
"""

from __future__ import annotations

import cv2
import numpy as np

from fgcd_drivers.sim.meshes import MeshPart, heightfield
from fgcd_drivers.sim.scene import OBJECT_LABEL
from fgcd_drivers.sim.scene_builders import WALL_LABEL, X, Z, _grid_to_texture
from fgcd_drivers.sim.textures import fractal_noise, tinted

__all__ = ["LAB_BUILDERS", "build_test_block"]

#: Paint colours of the patches (linear RGB albedo): teal, orange, oxide red.
PAINTS = ((0.38, 0.72, 0.64), (0.85, 0.38, 0.16), (0.36, 0.10, 0.09))


def _brush_ridges(shape: tuple[int, int], rng, *, angle_rad: float, period_px: float) -> np.ndarray:
    """Zero-mean unit-std ridges along one stroke direction (anisotropic noise), (H, W) float32."""
    h, w = shape
    noise = rng.standard_normal((h, w)).astype(np.float32)
    k = int(2 * round(3 * period_px) + 1)
    # long along the stroke, short across it
    kernel = cv2.getGaussianKernel(k, period_px * 2.5) @ cv2.getGaussianKernel(k, period_px * 0.35).T
    rot = cv2.getRotationMatrix2D((k / 2.0, k / 2.0), np.degrees(angle_rad), 1.0)
    kernel = cv2.warpAffine(kernel.astype(np.float32), rot, (k, k))
    out = cv2.filter2D(noise, -1, kernel, borderType=cv2.BORDER_REFLECT)
    return (out - out.mean()) / (out.std() + 1e-12)


def build_test_block(p: dict, rng) -> dict:
    """A square plaster block ``size_m`` across with a 3 x 3 grid of paint patches, on a wall.

    Parameters (``p``): ``size_m`` (0.3), ``cell_mm`` (mesh resolution, 0.75), ``paint_mm``
    (patch thickness, 1.5), ``ridge_mm`` (brush-ridge amplitude, 0.5), ``plaster_mm`` (rough
    plaster between the patches, 0.6).
    """
    size = p.get("size_m", 0.3)
    cell = p.get("cell_mm", 0.75) / 1000.0
    n = int(round(size / cell)) + 1
    shape = (n, n)
    plaster = p.get("plaster_mm", 0.6) / 1000.0 * fractal_noise(shape, rng, base_sigma=6, wrap=False)
    height = plaster.astype(np.float64) + p.get("plaster_mm", 0.6) / 1000.0
    albedo = np.empty((n, n, 3), np.float32)
    albedo[:] = 0.82
    albedo *= (1.0 + 0.06 * fractal_noise(shape, rng, base_sigma=2, wrap=False))[:, :, None]
    margin, step = n // 14, n // 3
    for i in range(3):
        for j in range(3):
            y0 = i * step + margin + int(rng.integers(-margin // 2, margin // 2 + 1))
            x0 = j * step + margin + int(rng.integers(-margin // 2, margin // 2 + 1))
            y1, x1 = min(n, y0 + step - 2 * margin), min(n, x0 + step - 2 * margin)
            # ragged patch edge: a thresholded blur of noise inside the rectangle
            patch = np.zeros(shape, np.float32)
            patch[y0:y1, x0:x1] = 1.0
            patch = cv2.GaussianBlur(patch, (0, 0), margin / 3.0)
            patch += 0.25 * fractal_noise(shape, rng, base_sigma=margin / 2.0, wrap=False)
            inside = patch > 0.5
            ridges = _brush_ridges(shape, rng, angle_rad=float(rng.uniform(0, np.pi)), period_px=3.0)
            thickness = p.get("paint_mm", 1.5) / 1000.0 + p.get("ridge_mm", 0.5) / 1000.0 * ridges
            height = np.where(inside, np.maximum(height, thickness), height)
            colour = np.asarray(PAINTS[int(rng.integers(len(PAINTS)))], np.float32)
            shade = 1.0 + 0.04 * fractal_noise(shape, rng, base_sigma=4, wrap=False)
            albedo[inside] = colour[None, :] * shade[inside][:, None]
    texture = _grid_to_texture(np.clip(albedo, 0.0, 1.0), (1024, 1024))
    v, t, uv = heightfield(
        origin=(-size / 2, 0.0, 1.0 - size / 2), axis_u=X, axis_v=Z, size_u=size, size_v=size, height=height
    )
    block = MeshPart(
        name="test_block",
        label=OBJECT_LABEL,
        vertices=v,
        triangles=t,
        tri_uv=uv,
        texture=texture,
        texel_size_m=size / 1024,
    )
    wall_tex = tinted(np.clip(0.9 + 0.02 * fractal_noise((256, 256), rng, base_sigma=20), 0, 1), (0.95, 0.95, 0.95))
    wv, wt, wuv = heightfield(
        origin=(-0.6, 0.004, 0.4), axis_u=X, axis_v=Z, size_u=1.2, size_v=1.2, height=np.zeros((2, 2))
    )
    wall = MeshPart(
        name="wall", label=WALL_LABEL, vertices=wv, triangles=wt, tri_uv=wuv, texture=wall_tex, texel_size_m=1.2 / 256
    )
    return {"parts": [block, wall]}


LAB_BUILDERS = {"test_block": build_test_block}
