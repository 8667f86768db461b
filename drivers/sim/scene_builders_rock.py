"""Rock-cut relief outdoors: a seated figure in high relief in a deep niche cut into rough rock.

The outdoor relief of the FGCD dataset (``Dp``) and of the grottoes it stands
for is carved into the living rock: a niche a quarter of a metre deep, a figure
in high relief, the rock around it broken into facets centimetres across, and a
sandstone whose albedo barely varies. Most of what a feature detector finds on
it is the shading of that relief, which moves with the light (docs/simulator.md,
"Scenes"); the granite ``relief_panel``'s features are mostly albedo speckle,
which does not.
"""

from __future__ import annotations

import cv2
import numpy as np

from fgcd_drivers.sim.scene_builders import _floor, _grid, _grid_to_texture, _panel_relief_part, _seated_figure
from fgcd_drivers.sim.textures import blend_detail, fractal_noise, stone

__all__ = ["ROCK_BUILDERS", "build_rock_niche"]


def build_rock_niche(p: dict, rng) -> dict:
    """A rock face ``width_m`` x ``height_m`` with an arched niche and a seated figure in high relief.

    Parameters (``p``): ``width_m`` (1.6), ``height_m`` (1.5), ``cell_mm`` (mesh resolution, 4),
    ``niche_depth_mm`` (250), ``figure_scale`` (the figure's height above the niche's back, as a
    multiple of the shallow panel's, 3), ``rock_relief_mm`` (amplitude of the rock's facets, 40),
    ``texture_contrast`` (albedo contrast of the sandstone, 0.25), ``colour`` (linear RGB).
    """
    W, Hh = p.get("width_m", 1.6), p.get("height_m", 1.5)
    cell = p.get("cell_mm", 4.0) / 1000
    Xg, Yg = _grid(W, Hh, cell)
    cx = W / 2
    nw, nb, nh = 0.36, 0.18, 0.95  # niche half-width, bottom, height of its straight part (m)
    rect = (np.abs(Xg - cx) < nw) & (Yg > nb) & (Yg < nb + nh)
    arch = np.hypot(Xg - cx, Yg - (nb + nh)) < nw
    niche = cv2.GaussianBlur((rect | arch).astype(np.float32), (0, 0), 3.0)
    depth = p.get("niche_depth_mm", 250.0) / 1000
    rock = p.get("rock_relief_mm", 40.0) / 1000
    # the rock: broken facets (coarse fractal) and weathered pitting (fine), only outside the niche
    facets = rock * fractal_noise(Xg.shape, rng, octaves=4, base_sigma=12, wrap=False)
    pits = 0.15 * rock * fractal_noise(Xg.shape, rng, octaves=3, base_sigma=2, wrap=False)
    Hgrid = (facets + pits) * (1.0 - niche) - depth * niche
    figure = p.get("figure_scale", 3.0) * _seated_figure(Xg, Yg, cx, nb, s=0.9)
    Hgrid = np.maximum(Hgrid, -depth + figure * (niche > 0.5))
    # tool marks and weathering on every carved surface
    Hgrid += 0.002 * fractal_noise(Hgrid.shape, rng, base_sigma=4, wrap=False)
    th, tw = int(Hh / 0.0015), int(W / 0.0015)
    tex = stone(
        rng,
        size=1024,
        photo_name="gravel",
        colour=p.get("colour", (0.66, 0.55, 0.40)),
        contrast=p.get("texture_contrast", 0.25),
        detail=0.05,
    )
    tex = cv2.resize(tex, (tw, th))
    # weathering: a darker crust on the exposed rock, the niche's back a little sheltered and paler
    crust = _grid_to_texture(1.0 - niche, (th, tw)) * 0.12
    tex = blend_detail(tex * (1.0 - crust[..., None]), rng, amount=0.05, base_sigma=2.0)
    face = _panel_relief_part(
        name="rock_face", width=W, height=Hh, Hgrid=Hgrid, tex=np.clip(tex, 0, 1), origin=(-W / 2, -0.05, 0.2)
    )
    return {"parts": [face, _floor(rng)]}


ROCK_BUILDERS = {"rock_niche": build_rock_niche}
