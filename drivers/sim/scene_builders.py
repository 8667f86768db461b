"""Procedural builders of the heritage scenes (one function per scene kind).

World frame: z up, metres, the object near the origin, its front facing -y
(the viewer stands at negative y). Each builder takes the spec's ``params``
table and a seeded generator and returns the mesh parts; everything random
comes from that generator, so a scene is a pure function of (spec, seed).
"""

from __future__ import annotations

import cv2
import numpy as np

from fgcd_drivers.sim.meshes import MeshPart, box, heightfield, implicit_surface, quad, revolution, uv_sphere
from fgcd_drivers.sim.scene import OBJECT_LABEL
from fgcd_drivers.sim.textures import blend_detail, fractal_noise, photo, stone, tinted

__all__ = ["BUILDERS"]

FLOOR_LABEL = 2
WALL_LABEL = 3
PLINTH_LABEL = 4

X = np.array([1.0, 0.0, 0.0])
Z = np.array([0.0, 0.0, 1.0])


# ----------------------------------------------------------------------------- helpers
def _floor(rng, *, size=8.0, repeat=0.8) -> MeshPart:
    tex = stone(rng, size=1024, photo_name="gravel", colour=(0.55, 0.52, 0.48), contrast=0.9)
    v, t, uv = quad(
        origin=(-size / 2, -size / 2, 0.0),
        axis_u=X,
        axis_v=(0, 1, 0),
        size_u=size,
        size_v=size,
        uv_repeat_m=(repeat, repeat),
    )
    return MeshPart(
        name="floor",
        label=FLOOR_LABEL,
        vertices=v,
        triangles=t,
        tri_uv=uv,
        texture=tex,
        texel_size_m=repeat / 1024,
        smooth=False,
    )


def _back_wall(rng, *, y=0.0, width=6.0, height=3.5, repeat=1.0) -> MeshPart:
    tex = stone(rng, size=1024, photo_name="gravel", colour=(0.78, 0.74, 0.68), contrast=0.25, detail=0.05)
    v, t, uv = quad(
        origin=(-width / 2, y, 0.0), axis_u=X, axis_v=Z, size_u=width, size_v=height, uv_repeat_m=(repeat, repeat)
    )
    return MeshPart(
        name="wall",
        label=WALL_LABEL,
        vertices=v,
        triangles=t,
        tri_uv=uv,
        texture=tex,
        texel_size_m=repeat / 1024,
        smooth=False,
    )


def _grid(size_u, size_v, cell):
    nu = int(round(size_u / cell)) + 1
    nv = int(round(size_v / cell)) + 1
    xs = np.linspace(0, size_u, nu)
    ys = np.linspace(0, size_v, nv)
    return np.meshgrid(xs, ys)  # (nv, nu), row 0 at the bottom


def _bump(Xg, Yg, cx, cy, a, b, h):
    """Ellipsoidal bump of half-axes a, b (m) and height h (m)."""
    r = 1.0 - ((Xg - cx) / a) ** 2 - ((Yg - cy) / b) ** 2
    return h * np.sqrt(np.clip(r, 0, None))


def _grid_to_texture(grid: np.ndarray, size) -> np.ndarray:
    """Resize a grid (row 0 = bottom) to texture layout (row 0 = top)."""
    return cv2.resize(np.flipud(grid).astype(np.float32), (size[1], size[0]), interpolation=cv2.INTER_LINEAR)


def _text_mask(rng, n_lines: int) -> np.ndarray:
    """Inscription mask (1 = letter): lines of random capitals in a serif Hershey font.

    Drawn with OpenCV at 4 px per mm-ish resolution so the 3 mm cells of the
    relief see clean V-cut strokes after smoothing.
    """
    letters = "ABCDEFGHIKLMNOPQRSTVXY"
    h_line, w = 160, 1400
    canvas = np.zeros((h_line * n_lines, w), np.uint8)
    for k in range(n_lines):
        words = ["".join(rng.choice(list(letters), size=int(rng.integers(2, 7)))) for _ in range(4)]
        text = " ".join(words)
        scale = 3.2
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_TRIPLEX, scale, 7)
        scale *= min(1.0, (w - 40) / tw)
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_TRIPLEX, scale, 7)
        cv2.putText(
            canvas,
            text,
            ((w - tw) // 2, k * h_line + (h_line + th) // 2),
            cv2.FONT_HERSHEY_TRIPLEX,
            scale,
            255,
            7,
            cv2.LINE_AA,
        )
    return canvas.astype(np.float32) / 255.0


def _panel_relief_part(*, name, width, height, Hgrid, tex, origin, label=OBJECT_LABEL, frame_depth=0.0):
    """A relief panel: height grid ``Hgrid`` (m, row 0 at the bottom) over a ``width`` x ``height`` m
    rectangle in the x-z plane at ``origin``, textured with ``tex``; ``frame_depth`` > 0 folds the
    border back by that much (m)."""
    if frame_depth > 0:  # fold the border back so the panel reads as a slab
        Hgrid = Hgrid.copy()
        Hgrid[[0, -1], :] = -frame_depth
        Hgrid[:, [0, -1]] = -frame_depth
    v, t, uv = heightfield(origin=origin, axis_u=X, axis_v=Z, size_u=width, size_v=height, height=Hgrid)
    texel = max(width / tex.shape[1], height / tex.shape[0])
    return MeshPart(name=name, label=label, vertices=v, triangles=t, tri_uv=uv, texture=tex, texel_size_m=texel)


# ----------------------------------------------------------------------------- scenes
def build_stele(p: dict, rng) -> dict:
    W, Hh, D = p.get("width_m", 0.8), p.get("height_m", 1.6), p.get("depth_m", 0.25)
    cell = p.get("cell_mm", 3.0) / 1000
    carve = p.get("carve_depth_mm", 3.0) / 1000
    base_h = 0.2
    Xg, Yg = _grid(W, Hh, cell)
    Hgrid = np.zeros_like(Xg)
    # raised border band
    band = 0.045
    inner = (Xg > band) & (Xg < W - band) & (Yg > band) & (Yg < Hh - band)
    Hgrid[~inner] += 0.006
    # roundel with a relief portrait (the bundled 'camera' photo as a height map) near the top
    rc = 0.23
    cx, cy = W / 2, Hh - 0.33
    portrait = photo("camera").mean(axis=2)
    portrait = cv2.GaussianBlur(portrait, (0, 0), 3)
    rr = np.hypot(Xg - cx, Yg - cy)
    inside = rr < rc
    u = ((Xg - (cx - rc)) / (2 * rc) * 511).clip(0, 511).astype(int)
    vv = (((cy + rc) - Yg) / (2 * rc) * 511).clip(0, 511).astype(int)
    Hgrid[inside] += -0.012 + 0.012 * portrait[vv[inside], u[inside]]
    Hgrid[np.abs(rr - rc) < 0.012] += 0.004  # moulded ring
    # inscription in the lower part
    x0, x1, y0, y1 = 0.08, W - 0.08, 0.12, Hh - 0.65
    letters = _text_mask(rng, int(p.get("inscription_lines", 4)))
    field = (Xg >= x0) & (Xg < x1) & (Yg >= y0) & (Yg < y1)
    iu = ((Xg - x0) / (x1 - x0) * (letters.shape[1] - 1)).clip(0, letters.shape[1] - 1).astype(int)
    iv = (((y1 - Yg) / (y1 - y0)) * (letters.shape[0] - 1)).clip(0, letters.shape[0] - 1).astype(int)
    lmask = np.where(field, letters[iv, iu], 0.0)
    lmask = cv2.GaussianBlur(lmask.astype(np.float32), (0, 0), 0.7)
    Hgrid -= carve * lmask
    Hgrid += 0.0004 * fractal_noise(Hgrid.shape, rng, base_sigma=20, wrap=False)
    # texture: sandstone, dirt in the grooves and on the lower part
    th, tw = int(Hh / 0.001), int(W / 0.001)
    tex = stone(rng, size=1024, photo_name="gravel", colour=p.get("colour", (0.74, 0.66, 0.54)))
    tex = cv2.resize(tex, (tw, th), interpolation=cv2.INTER_LINEAR)
    tex = blend_detail(tex, rng, amount=0.06, base_sigma=2.0)
    dirt = _grid_to_texture(np.clip(-Hgrid / carve, 0, 1), (th, tw))
    grime = np.linspace(0.85, 1.0, th, dtype=np.float32)[::-1][:, None]  # darker at the foot
    tex = tex * (1 - 0.45 * dirt[..., None]) * grime[..., None]
    front = _panel_relief_part(
        name="stele", width=W, height=Hh, Hgrid=Hgrid, tex=np.clip(tex, 0, 1), origin=(-W / 2, -D / 2, base_h)
    )
    sides_tex = stone(rng, size=512, photo_name="gravel", colour=p.get("colour", (0.74, 0.66, 0.54)))
    v, t, uv = box(center=(0, 0, base_h + Hh / 2), size=(W, D, Hh), skip=("-y", "-z"), uv_repeat_m=0.5)
    sides = MeshPart(
        name="stele",
        label=OBJECT_LABEL,
        vertices=v,
        triangles=t,
        tri_uv=uv,
        texture=sides_tex,
        texel_size_m=0.5 / 512,
        smooth=False,
    )
    v, t, uv = box(center=(0, 0, base_h / 2), size=(W + 0.3, D + 0.25, base_h), skip=("-z",), uv_repeat_m=0.5)
    plinth = MeshPart(
        name="plinth",
        label=PLINTH_LABEL,
        vertices=v,
        triangles=t,
        tri_uv=uv,
        texture=stone(rng, size=512, photo_name="grass", colour=(0.5, 0.5, 0.48)),
        texel_size_m=0.5 / 512,
        smooth=False,
    )
    return {"parts": [front, sides, plinth, _floor(rng)]}


def _seated_figure(Xg, Yg, cx, by, s=1.0):
    """Height of a seated figure (halo, head, torso, arms, crossed legs, lotus base); by = base y."""
    h = np.zeros_like(Xg)
    parts = [
        (cx, by + 0.42 * s, 0.30 * s, 0.09 * s, 0.050),  # crossed legs
        (cx, by + 0.66 * s, 0.17 * s, 0.22 * s, 0.060),  # torso
        (cx - 0.17 * s, by + 0.62 * s, 0.06 * s, 0.17 * s, 0.045),  # left arm
        (cx + 0.17 * s, by + 0.62 * s, 0.06 * s, 0.17 * s, 0.045),  # right arm
        (cx, by + 0.50 * s, 0.11 * s, 0.05 * s, 0.062),  # hands in the lap
        (cx, by + 0.95 * s, 0.085 * s, 0.105 * s, 0.065),  # head
        (cx, by + 1.06 * s, 0.04 * s, 0.035 * s, 0.060),  # ushnisha
        (cx, by + 0.84 * s, 0.05 * s, 0.03 * s, 0.050),  # neck
    ]
    for x, y, a, b, hh in parts:
        h = np.maximum(h, _bump(Xg, Yg, x, y, a, b, hh))
    # lotus base: a row of petals
    for k in range(-4, 5):
        h = np.maximum(h, _bump(Xg, Yg, cx + k * 0.07 * s, by + 0.29 * s, 0.038 * s, 0.05 * s, 0.03))
    # halo ring behind the head
    r = np.hypot(Xg - cx, Yg - (by + 0.95 * s))
    ring = (np.abs(r - 0.19 * s) < 0.012 * s).astype(float) * 0.012
    return np.maximum(h, ring)


def build_relief_panel(p: dict, rng) -> dict:
    W, Hh = p.get("width_m", 1.2), p.get("height_m", 1.5)
    cell = p.get("cell_mm", 3.0) / 1000
    Xg, Yg = _grid(W, Hh, cell)
    cx = W / 2
    # niche: rectangle with a round arch, recessed
    nw, nb, nh = 0.38, 0.12, 1.05
    rect = (np.abs(Xg - cx) < nw) & (Yg > nb) & (Yg < nb + nh)
    arch = np.hypot(Xg - cx, Yg - (nb + nh)) < nw
    niche = (rect | arch).astype(np.float32)
    niche = cv2.GaussianBlur(niche, (0, 0), 2.0)
    depth = p.get("niche_depth_mm", 60.0) / 1000
    Hgrid = -depth * niche
    fig = _seated_figure(Xg, Yg, cx, nb, s=0.95)
    Hgrid = np.maximum(Hgrid, -depth + fig)
    Hgrid += 0.0006 * fractal_noise(Hgrid.shape, rng, base_sigma=15, wrap=False)
    th, tw = int(Hh / 0.0012), int(W / 0.0012)
    tex = stone(rng, size=1024, photo_name="gravel", colour=p.get("colour", (0.62, 0.6, 0.57)), contrast=0.7)
    tex = cv2.resize(tex, (tw, th))
    tex = blend_detail(tex, rng, amount=0.07, base_sigma=2.0)
    soot = _grid_to_texture(niche, (th, tw)) * 0.15
    tex = tex * (1 - soot[..., None])
    panel = _panel_relief_part(
        name="relief",
        width=W,
        height=Hh,
        Hgrid=Hgrid,
        tex=np.clip(tex, 0, 1),
        origin=(-W / 2, -0.06, 0.3),
        frame_depth=0.06,
    )
    return {"parts": [panel, _back_wall(rng, y=0.0), _floor(rng)]}


def _aged_painting(rng, th, tw) -> np.ndarray:
    """A fresco-like composition of bundled photographs with registers, fading and stains."""
    canvas = np.ones((th, tw, 3), np.float32) * np.array([0.80, 0.72, 0.58], np.float32)
    names = ["astronaut", "coffee", "chelsea", "rocket", "immunohistochemistry", "retina"]
    rng.shuffle(names)
    cols, rows = 3, 2
    mw, mh = tw // 40, th // 30
    cw, ch = (tw - (cols + 1) * mw) // cols, (th - (rows + 1) * mh) // rows
    for k, name in enumerate(names[: cols * rows]):
        r, c = divmod(k, cols)
        img = photo(name, size=(ch, cw))
        x, y = mw + c * (cw + mw), mh + r * (ch + mh)
        canvas[y : y + ch, x : x + cw] = img
        cv2.rectangle(canvas, (x - 4, y - 4), (x + cw + 3, y + ch + 3), (0.35, 0.18, 0.10), 6)
    # ageing: desaturate towards ochre, fade, blotches, fine grain
    gray = canvas.mean(axis=2, keepdims=True)
    canvas = 0.55 * canvas + 0.45 * gray * np.array([1.05, 0.95, 0.78], np.float32)
    canvas = 0.75 * canvas + 0.2
    blot = fractal_noise((th, tw), rng, base_sigma=tw / 20, wrap=False)
    canvas *= (1.0 + 0.08 * blot)[..., None]
    return blend_detail(np.clip(canvas, 0, 1), rng, amount=0.06, base_sigma=1.5)


def build_mural(p: dict, rng) -> dict:
    W, Hh = p.get("width_m", 3.0), p.get("height_m", 2.0)
    cell = p.get("cell_mm", 5.0) / 1000
    Xg, Yg = _grid(W, Hh, cell)
    Hgrid = p.get("relief_mm", 1.5) / 1000 * fractal_noise(Xg.shape, rng, base_sigma=25, wrap=False)
    th, tw = int(Hh / 0.0015), int(W / 0.0015)
    tex = _aged_painting(rng, th, tw)
    part = _panel_relief_part(name="mural", width=W, height=Hh, Hgrid=Hgrid, tex=tex, origin=(-W / 2, 0.0, 0.4))
    return {"parts": [part, _floor(rng)]}


def build_plane(p: dict, rng) -> dict:
    W, Hh = p.get("width_m", 2.5), p.get("height_m", 2.5)
    rep = p.get("texture_repeat_m", 0.6)
    tex = stone(rng, size=1024, photo_name=p.get("photo", "gravel"), colour=(0.7, 0.66, 0.6), contrast=0.8)
    big = photo("moon", size=(1024, 1024)).mean(axis=2)
    tex = np.clip(tex * (0.75 + 0.5 * big)[..., None], 0, 1)
    v, t, uv = quad(origin=(-W / 2, 0.0, 0.0), axis_u=X, axis_v=Z, size_u=W, size_v=Hh, uv_repeat_m=(rep, rep))
    part = MeshPart(
        name="plane",
        label=OBJECT_LABEL,
        vertices=v,
        triangles=t,
        tri_uv=uv,
        texture=tex,
        texel_size_m=rep / 1024,
        smooth=False,
    )
    return {"parts": [part]}


def build_sphere(p: dict, rng) -> dict:
    r = p.get("radius_m", 0.75)
    c = tuple(p.get("center", (0.0, 0.0, 1.0)))
    rep = p.get("texture_repeat_m", 0.6)
    if "albedo" in p:  # a matte calibration sphere: one grey albedo, no texture
        tex = np.full((4, 4, 3), float(p["albedo"]), np.float32)
    else:
        tex = stone(rng, size=1024, photo_name="moon", colour=(0.72, 0.7, 0.66), contrast=1.0)
    v, t, uv = uv_sphere(
        center=c, radius=r, n_lat=int(p.get("n_lat", 240)), n_lon=int(p.get("n_lon", 480)), uv_repeat_m=rep
    )
    part = MeshPart(
        name="sphere", label=OBJECT_LABEL, vertices=v, triangles=t, tri_uv=uv, texture=tex, texel_size_m=rep / 1024
    )
    return {"parts": [part]}


def build_plaster(p: dict, rng) -> dict:
    W, Hh = p.get("width_m", 2.0), p.get("height_m", 2.0)
    cell = p.get("cell_mm", 4.0) / 1000
    Xg, Yg = _grid(W, Hh, cell)
    Hgrid = p.get("relief_mm", 0.4) / 1000 * fractal_noise(Xg.shape, rng, base_sigma=30, wrap=False)
    size = 1024
    base = np.full((size, size), 0.84, np.float32)
    base *= 1.0 + p.get("contrast", 0.025) * fractal_noise((size, size), rng, base_sigma=60)
    base *= 1.0 + p.get("grain", 0.01) * fractal_noise((size, size), rng, base_sigma=1.5)  # millimetre grain
    tex = tinted(np.clip(base, 0, 1), (1.0, 0.98, 0.93))
    v, t, uv = heightfield(
        origin=(-W / 2, 0.0, 0.3), axis_u=X, axis_v=Z, size_u=W, size_v=Hh, height=Hgrid, uv_repeat_m=(1.0, 1.0)
    )
    part = MeshPart(
        name="plaster", label=OBJECT_LABEL, vertices=v, triangles=t, tri_uv=uv, texture=tex, texel_size_m=1.0 / size
    )
    return {"parts": [part, _floor(rng)]}


def build_bricks(p: dict, rng) -> dict:
    W, Hh = p.get("width_m", 2.4), p.get("height_m", 2.0)
    cell = p.get("cell_mm", 4.0) / 1000
    bw, bh, mortar = 0.215, 0.065, 0.010
    Xg, Yg = _grid(W, Hh, cell)
    course = np.floor(Yg / (bh + mortar)).astype(int)
    xoff = Xg + (course % 2) * (bw + mortar) / 2
    col = np.floor(xoff / (bw + mortar)).astype(int)
    fx = np.mod(xoff, bw + mortar)
    fy = np.mod(Yg, bh + mortar)
    brick = (fx > mortar) & (fy > mortar)
    ids = course * 1000 + col
    jitter = rng.normal(0, 0.0012, 65536)  # each brick sits a little proud or back
    Hgrid = np.where(brick, jitter[np.mod(ids * 7919 + 13, 65536)], -p.get("mortar_depth_mm", 8.0) / 1000)
    Hgrid = cv2.GaussianBlur(Hgrid.astype(np.float32), (0, 0), 0.6)
    # texture at 1.5 mm per texel: each brick takes a random patch of the brick photo and a tint
    res = 0.0015
    th, tw = int(Hh / res), int(W / res)
    ty, tx = np.mgrid[0:th, 0:tw].astype(np.float32)
    Yt = Hh - (ty + 0.5) * res
    Xt = (tx + 0.5) * res
    course_t = np.floor(Yt / (bh + mortar)).astype(int)
    xo = Xt + (course_t % 2) * (bw + mortar) / 2
    col_t = np.floor(xo / (bw + mortar)).astype(int)
    brick_t = (np.mod(xo, bw + mortar) > mortar) & (np.mod(Yt, bh + mortar) > mortar)
    photo_b = photo("gravel").mean(axis=2)  # fired-clay grain (the bundled brick photo has its own joints)
    idt = np.mod(course_t * 7919 + col_t * 104729, 4096)
    offs = rng.integers(0, 512, (4096, 2))
    tints = np.clip(np.array([0.62, 0.30, 0.20]) * rng.normal(1.0, 0.12, (4096, 1)), 0, 1).astype(np.float32)
    px = ((np.mod(xo, bw + mortar) / res).astype(int) + offs[idt, 0]) % 512
    py = ((np.mod(Yt, bh + mortar) / res).astype(int) + offs[idt, 1]) % 512
    shade = 0.55 + 0.9 * photo_b[py, px]
    tex = tints[idt] * shade[..., None]
    mortar_c = stone(rng, size=512, photo_name="gravel", colour=(0.7, 0.68, 0.64))
    mortar_s = mortar_c[ty.astype(int) % 512, tx.astype(int) % 512]
    tex = np.where(brick_t[..., None], tex, mortar_s).astype(np.float32)
    tex = blend_detail(np.clip(tex, 0, 1), rng, amount=0.05, base_sigma=1.5)
    part = _panel_relief_part(name="bricks", width=W, height=Hh, Hgrid=Hgrid, tex=tex, origin=(-W / 2, 0.0, 0.0))
    return {"parts": [part, _floor(rng)]}


def build_stupa(p: dict, rng) -> dict:
    R = p.get("radius_m", 1.0)
    n_theta = int(p.get("n_theta", 1024))
    # profile: plinth, drum with a carved frieze, dome, harmika, spire
    seg = [
        (0.00, R * 1.15),
        (0.25, R * 1.15),
        (0.26, R * 1.02),
        (0.30, R),
        (0.85, R),
        (0.88, R * 1.04),
        (0.92, R * 0.97),
    ]
    dome = [(0.92 + R * 0.95 * np.sin(a), R * 0.97 * np.cos(a)) for a in np.linspace(0.05, np.pi / 2 - 0.12, 40)]
    top = [
        (dome[-1][0] + 0.02, 0.28),
        (dome[-1][0] + 0.30, 0.28),
        (dome[-1][0] + 0.32, 0.06),
        (dome[-1][0] + 0.9, 0.02),
        (dome[-1][0] + 0.92, 0.0),
    ]
    prof = np.array(seg + dome + top)
    # resample the profile to ~6 mm steps along its arc length
    s = np.concatenate([[0], np.cumsum(np.hypot(np.diff(prof[:, 0]), np.diff(prof[:, 1])))])
    ss = np.linspace(0, s[-1], int(s[-1] / 0.006))
    z = np.interp(ss, s, prof[:, 0])
    r = np.interp(ss, s, prof[:, 1])
    # carved frieze on the drum (0.34..0.80 m): the bundled 'camera' and 'astronaut' photos as relief panels
    theta = np.linspace(0, 2 * np.pi, n_theta, endpoint=False)
    disp = np.zeros((len(z), n_theta))
    band = (z > 0.34) & (z < 0.80)
    reliefs = [cv2.GaussianBlur(photo(n).mean(axis=2), (0, 0), 2.0) for n in ("camera", "astronaut", "coins", "clock")]
    n_panels = 12
    pw = 2 * np.pi / n_panels
    for k in range(n_panels):
        img = reliefs[k % len(reliefs)]
        t0 = k * pw + 0.08 * pw
        t1 = (k + 1) * pw - 0.08 * pw
        cols = (theta >= t0) & (theta < t1)
        ui = ((theta[cols] - t0) / (t1 - t0) * (img.shape[1] - 1)).astype(int)
        vi = ((0.80 - z[band]) / 0.46 * (img.shape[0] - 1)).astype(int)
        disp[np.ix_(band, cols)] = -0.012 + 0.012 * img[np.ix_(vi, ui)]
    disp += 0.0005 * fractal_noise(disp.shape, rng, base_sigma=10, wrap=True)
    v, t, uv = revolution(z=z, radius=r, n_theta=n_theta, displacement=disp, uv_repeat_m=0.8)
    tex = stone(rng, size=1024, photo_name="gravel", colour=(0.82, 0.78, 0.70), contrast=0.5)
    tex = np.clip(tex * (0.8 + 0.35 * photo("moon", size=(1024, 1024)).mean(axis=2))[..., None], 0, 1)
    part = MeshPart(
        name="stupa", label=OBJECT_LABEL, vertices=v, triangles=t, tri_uv=uv, texture=tex, texel_size_m=0.8 / 1024
    )
    return {"parts": [part, _floor(rng, size=12.0)]}


def build_statue(p: dict, rng) -> dict:
    vox = p.get("voxel_mm", 8.0) / 1000
    Hh = p.get("height_m", 1.3)
    base_h = 0.5
    nx, ny, nz = int(0.7 / vox), int(0.5 / vox), int((Hh + 0.1) / vox)
    gx, gy, gz = np.meshgrid(
        np.arange(nx) * vox - 0.35, np.arange(ny) * vox - 0.25, np.arange(nz) * vox - 0.05, indexing="ij"
    )
    s = Hh / 1.3
    blobs = [  # (x, y, z, rx, ry, rz) of a standing draped figure, slightly contrapposto
        (0.0, 0.0, 1.20, 0.085, 0.095, 0.11),
        (0.0, 0.0, 1.05, 0.06, 0.06, 0.07),
        (0.0, 0.0, 0.88, 0.19, 0.12, 0.18),
        (0.0, 0.01, 0.62, 0.17, 0.12, 0.16),
        (-0.07, 0.0, 0.32, 0.10, 0.10, 0.30),
        (0.08, 0.02, 0.30, 0.09, 0.10, 0.30),
        (-0.22, -0.02, 0.80, 0.06, 0.06, 0.22),
        (0.21, -0.05, 0.78, 0.06, 0.07, 0.2),
        (0.18, -0.12, 0.66, 0.05, 0.06, 0.06),
        (0.0, 0.0, 0.06, 0.22, 0.17, 0.08),
    ]
    f = np.zeros(gx.shape, np.float32)
    for x, y, z, rx, ry, rz in blobs:
        q = ((gx - x * s) / (rx * s)) ** 2 + ((gy - y * s) / (ry * s)) ** 2 + ((gz - z * s) / (rz * s)) ** 2
        f += np.exp(-q * 1.5).astype(np.float32)
    f += 0.04 * fractal_noise((nx, ny * nz), rng, base_sigma=3, wrap=False).reshape(f.shape)
    f[:, :, 0] = 0
    f[:, :, -1] = 0
    v, t, uv = implicit_surface(f, origin=(-0.35, -0.25, base_h - 0.05), voxel_m=vox, level=0.45, uv_repeat_m=0.4)
    marble = photo("moon", size=(1024, 1024)).mean(axis=2)
    veins = np.abs(fractal_noise((1024, 1024), rng, base_sigma=40))
    g = np.clip(0.62 + 0.35 * (marble - marble.mean()) - 0.25 * np.exp(-veins * 6), 0, 1)
    tex = blend_detail(tinted(g, (0.98, 0.96, 0.92)), rng, amount=0.05)
    statue = MeshPart(
        name="statue", label=OBJECT_LABEL, vertices=v, triangles=t, tri_uv=uv, texture=tex, texel_size_m=0.4 / 1024
    )
    vb, tb, uvb = box(center=(0, 0, base_h / 2), size=(0.6, 0.5, base_h), skip=("-z",), uv_repeat_m=0.5)
    plinth = MeshPart(
        name="plinth",
        label=PLINTH_LABEL,
        vertices=vb,
        triangles=tb,
        tri_uv=uvb,
        texture=stone(rng, size=512, photo_name="gravel", colour=(0.5, 0.48, 0.46)),
        texel_size_m=0.5 / 512,
        smooth=False,
    )
    return {"parts": [statue, plinth, _floor(rng)]}


BUILDERS = {
    "stele": build_stele,
    "relief_panel": build_relief_panel,
    "mural": build_mural,
    "plane": build_plane,
    "sphere": build_sphere,
    "plaster": build_plaster,
    "bricks": build_bricks,
    "stupa": build_stupa,
    "statue": build_statue,
}
