"""Scenes standing for the real kinds of docs/simulator.md, "Scenes": their geometry as stated."""

import numpy as np
import pytest

from fgcd_core.camera import CameraIntrinsics
from fgcd_drivers.sim.render import Renderer
from fgcd_drivers.sim.scene import OBJECT_LABEL
from fgcd_drivers.sim.scenes import load_scene, scene_spec

INTR = CameraIntrinsics(fx=120.0, fy=120.0, cx=79.5, cy=59.5, width=160, height=120)


def test_the_rock_niche_is_as_deep_as_stated_and_its_figure_stands_out_of_it():
    scene = load_scene("rock_niche")
    params = scene_spec("rock_niche")["params"]
    res = Renderer(scene).render(scene.default_T_world_cam, INTR, None, want=("depth", "labels"))
    depth = np.where(res.labels == OBJECT_LABEL, res.depth, np.nan)
    # straight ahead of the camera: the figure's torso; beside it, at the same height, the niche's back
    # and, further out, the rock face (pixels at the niche's half-width plus a margin)
    row = INTR.height // 2
    ahead = depth[row, int(INTR.cx)]
    u_of = lambda x_m: int(round(INTR.cx + INTR.fx * x_m / ahead))  # noqa: E731
    niche_back = np.nanmedian(depth[row - 3 : row + 4, u_of(0.28) : u_of(0.32)])
    rock_face = np.nanmedian(depth[row - 3 : row + 4, u_of(0.55) : u_of(0.65)])
    assert niche_back - rock_face == pytest.approx(params["niche_depth_mm"] / 1000, abs=0.05)
    assert niche_back - ahead > 0.1  # the figure in high relief, not a shallow carving
