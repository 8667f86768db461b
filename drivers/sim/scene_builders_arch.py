"""Builders of architectural scene kinds: an overhanging cornice and a lettered slab (issue 25).

Same conventions as :mod:`fgcd_drivers.sim.scene_builders`: world z up, metres, the
object's front facing -y, everything random from the given generator.

* ``cornice``: an ashlar wall under a classical cornice that projects 28 cm
  toward the viewer (fascia, a row of dentils, the corona's flat soffit, a cyma
  moulding), seen from below: surfaces at every orientation, and an overhang
  whose underside hides what is above it.
* ``lettered_slab``: a granite grave slab leaning back a few degrees, its face
  covered with deep V-cut lettering and lichen: near-planar geometry whose
  texture is mostly the letters.
"""

from __future__ import annotations

import cv2
import numpy as np

from fgcd_drivers.sim.meshes import MeshPart, box
from fgcd_drivers.sim.scene import OBJECT_LABEL
from fgcd_drivers.sim.scene_builders import _floor, _grid, _grid_to_texture, _panel_relief_part, _text_mask
from fgcd_drivers.sim.textures import blend_detail, fractal_noise, stone

__all__ = ["ARCH_BUILDERS", "build_cornice", "build_lettered_slab"]


def _extrusion(profile_yz: np.ndarray, *, x0: float, x1: float, nx: int, repeat_m: float):
    """A profile ``(K, 2)`` of ``(y, z)`` points (metres) swept along x from ``x0`` to ``x1``.

    The profile runs bottom to top on the viewer's side, so the surface faces -y / down.
    Returns ``(vertices (N, 3), triangles (M, 3), tri_uv (M, 3, 2))`` as :func:`~fgcd_drivers.sim.meshes.heightfield`.
    """
    P = np.asarray(profile_yz, float)
    xs = np.linspace(x0, x1, nx)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(P[:, 0]), np.diff(P[:, 1])))])
    K = len(P)
    V = np.stack(np.broadcast_arrays(xs[None, :], P[:, 0][:, None], P[:, 1][:, None]), -1).reshape(-1, 3)
    uv = np.stack(np.broadcast_arrays(xs[None, :] / repeat_m, arc[:, None] / repeat_m), -1).reshape(-1, 2)
    idx = np.arange(K * nx).reshape(K, nx)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    tris = np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)])
    return V, tris, uv[tris].astype(np.float32)


def _merge(meshes):
    """Concatenate ``(vertices, triangles, tri_uv)`` meshes into one."""
    vs, ts, uvs, off = [], [], [], 0
    for v, t, uv in meshes:
        vs.append(v)
        ts.append(t + off)
        uvs.append(uv)
        off += len(v)
    return np.concatenate(vs), np.concatenate(ts), np.concatenate(uvs)


def _ashlar_wall(p: dict, rng, *, width: float, height: float, z0: float, tex) -> MeshPart:
    """Coursed ashlar: blocks 0.3-0.6 m long in 0.25 m courses, 6 mm joints, tooling marks."""
    cell = p.get("cell_mm", 4.0) / 1000
    Xg, Yg = _grid(width, height, cell)
    course_h = 0.25
    course = np.floor(Yg / course_h).astype(int)
    lengths = rng.uniform(0.3, 0.6, (int(height / course_h) + 2, 16))
    starts = np.cumsum(lengths, axis=1) - rng.uniform(0.0, 0.3, (lengths.shape[0], 1))
    joint = np.zeros_like(Xg, dtype=bool)
    for k in range(lengths.shape[0]):
        rows = course == k
        for s in starts[k]:
            joint |= rows & (np.abs(Xg - s) < 0.003)
    joint |= np.mod(Yg, course_h) < 0.006
    Hgrid = np.where(joint, -0.006, 0.0) + 0.0008 * fractal_noise(Xg.shape, rng, base_sigma=12, wrap=False)
    Hgrid = cv2.GaussianBlur(Hgrid.astype(np.float32), (0, 0), 0.7)
    return _panel_relief_part(
        name="wall", width=width, height=height, Hgrid=Hgrid, tex=tex, origin=(-width / 2, 0.0, z0)
    )


def build_cornice(p: dict, rng) -> dict:
    W = p.get("width_m", 2.4)
    z_c = p.get("cornice_z_m", 1.55)  # underside of the fascia
    proj = p.get("projection_m", 0.28)
    wall_tex = stone(rng, size=1024, photo_name="gravel", colour=(0.76, 0.70, 0.60), contrast=0.45)
    wall_tex = blend_detail(cv2.resize(wall_tex, (2048, int(2048 * z_c / W))), rng, amount=0.06, base_sigma=2.0)
    wall = _ashlar_wall(p, rng, width=W, height=z_c, z0=0.0, tex=wall_tex)
    # the cornice's profile, bottom to top: fascia, dentil bed, corona soffit and face, cyma, top
    t = np.linspace(0.0, np.pi / 2, 12)
    cyma = np.column_stack([-(proj - 0.06) - 0.06 * np.sin(t), z_c + 0.27 + 0.10 * (1 - np.cos(t))])
    profile = np.vstack(
        [
            [
                [0.0, z_c],
                [-0.03, z_c],
                [-0.03, z_c + 0.10],
                [-0.05, z_c + 0.10],
                [-0.05, z_c + 0.17],
                [-(proj - 0.06), z_c + 0.17],
                [-(proj - 0.06), z_c + 0.27],
            ],
            cyma,
            [[-proj, z_c + 0.40], [-0.05, z_c + 0.40]],
        ]
    )
    dense = [profile[0]]
    for a, b in zip(profile[:-1], profile[1:]):  # ~4 mm steps so shading follows the mouldings
        n = max(1, int(np.hypot(*(b - a)) / 0.004))
        dense.extend(a + (b - a) * (k / n) for k in range(1, n + 1))
    body = _extrusion(np.array(dense), x0=-W / 2, x1=W / 2, nx=int(W / 0.004), repeat_m=0.5)
    pitch, dw = p.get("dentil_pitch_m", 0.09), 0.055
    dentils = [
        box(center=(x, -0.08, z_c + 0.135), size=(dw, 0.06, 0.07), skip=("+y",), uv_repeat_m=0.5)
        for x in np.arange(-W / 2 + pitch / 2, W / 2, pitch)
    ]
    v, tri, uv = _merge([body, *dentils])
    tex = stone(rng, size=1024, photo_name="gravel", colour=(0.80, 0.75, 0.66), contrast=0.8)
    tex = np.clip(tex * (0.85 + 0.3 * (fractal_noise((1024, 1024), rng, base_sigma=60) > 0.8))[..., None], 0, 1)
    cornice = MeshPart(
        name="cornice",
        label=OBJECT_LABEL,
        vertices=v,
        triangles=tri,
        tri_uv=uv,
        texture=blend_detail(tex, rng, amount=0.08, base_sigma=1.5),
        texel_size_m=0.5 / 1024,
        smooth=False,
    )
    return {"parts": [wall, cornice, _floor(rng)]}


def build_lettered_slab(p: dict, rng) -> dict:
    W, Hh, D = p.get("width_m", 0.7), p.get("height_m", 1.0), p.get("depth_m", 0.12)
    cell = p.get("cell_mm", 2.5) / 1000
    carve = p.get("carve_depth_mm", 5.0) / 1000
    lean = np.radians(p.get("lean_deg", 6.0))
    Xg, Yg = _grid(W, Hh, cell)
    letters = _text_mask(rng, int(p.get("inscription_lines", 8)))
    x0, x1, y0, y1 = 0.05, W - 0.05, 0.08, Hh - 0.06
    field = (Xg >= x0) & (Xg < x1) & (Yg >= y0) & (Yg < y1)
    iu = ((Xg - x0) / (x1 - x0) * (letters.shape[1] - 1)).clip(0, letters.shape[1] - 1).astype(int)
    iv = (((y1 - Yg) / (y1 - y0)) * (letters.shape[0] - 1)).clip(0, letters.shape[0] - 1).astype(int)
    lmask = cv2.GaussianBlur(np.where(field, letters[iv, iu], 0.0).astype(np.float32), (0, 0), 0.8)
    Hgrid = -carve * lmask + 0.0005 * fractal_noise(Xg.shape, rng, base_sigma=25, wrap=False)
    th, tw = int(Hh / 0.001), int(W / 0.001)
    granite = stone(rng, size=1024, photo_name="gravel", colour=(0.55, 0.55, 0.56), contrast=1.0)
    tex = blend_detail(cv2.resize(granite, (tw, th)), rng, amount=0.08, base_sigma=1.5)
    lichen = np.clip(fractal_noise((th, tw), rng, base_sigma=tw / 12, wrap=False) - 0.6, 0, 1)[..., None]
    tex = tex * (1 - 0.6 * lichen) + 0.6 * lichen * np.array([0.78, 0.74, 0.45], np.float32)
    tex = tex * (1 - 0.5 * _grid_to_texture(lmask, (th, tw))[..., None])  # dark, weathered letter grooves
    front = _panel_relief_part(
        name="slab",
        width=W,
        height=Hh,
        Hgrid=Hgrid,
        tex=np.clip(tex, 0, 1).astype(np.float32),
        origin=(-W / 2, -D / 2, 0.0),
    )
    v, t, uv = box(center=(0, 0, Hh / 2), size=(W, D, Hh), skip=("-y", "-z"), uv_repeat_m=0.4)
    sides = MeshPart(
        name="slab",
        label=OBJECT_LABEL,
        vertices=v,
        triangles=t,
        tri_uv=uv,
        texture=stone(rng, size=512, photo_name="gravel", colour=(0.5, 0.5, 0.5)),
        texel_size_m=0.4 / 512,
        smooth=False,
    )
    # lean back about the slab's foot (the x axis through its base)
    c, s = np.cos(lean), np.sin(lean)
    T = np.eye(4)
    T[:3, :3] = [[1, 0, 0], [0, c, s], [0, -s, c]]
    return {"parts": [front.transformed(T), sides.transformed(T), _floor(rng)]}


ARCH_BUILDERS = {"cornice": build_cornice, "lettered_slab": build_lettered_slab}
