"""Small synthetic scenes for fast simulator tests."""

from __future__ import annotations

import numpy as np
import pytest

from fgcd_core.camera import CameraIntrinsics
from fgcd_drivers.sim.meshes import MeshPart, box, quad, uv_sphere
from fgcd_drivers.sim.scene import Scene
from fgcd_drivers.sim.transforms import look_at


def uniform_texture(value: float = 0.5) -> np.ndarray:
    return np.full((16, 16, 3), value, np.float32)


def plane_part(*, albedo: float = 0.5, size: float = 4.0, y: float = 0.0) -> MeshPart:
    """Vertical plane y = const facing -y, centred on x = 0, z = 1."""
    v, t, uv = quad(
        origin=(-size / 2, y, 1.0 - size / 2),
        axis_u=(1, 0, 0),
        axis_v=(0, 0, 1),
        size_u=size,
        size_v=size,
        uv_repeat_m=(0.5, 0.5),
    )
    return MeshPart(
        name="plane",
        label=1,
        vertices=v,
        triangles=t,
        tri_uv=uv,
        texture=uniform_texture(albedo),
        texel_size_m=0.5 / 16,
        smooth=False,
    )


def make_scene(parts, eye=(0.0, -1.0, 1.0), target=(0.0, 0.0, 1.0)) -> Scene:
    return Scene(
        name="test",
        description="test scene",
        seed=0,
        parts=list(parts),
        default_T_world_cam=look_at(eye, target),
        lamp_position=np.array([0.0, -2.0, 1.0]),
    )


@pytest.fixture
def small_intr() -> CameraIntrinsics:
    return CameraIntrinsics(fx=80.0, fy=80.0, cx=39.5, cy=29.5, width=80, height=60)


@pytest.fixture
def plane_scene() -> Scene:
    return make_scene([plane_part()])


@pytest.fixture
def sphere_scene() -> Scene:
    v, t, uv = uv_sphere(center=(0.0, 0.0, 1.0), radius=0.5, n_lat=180, n_lon=360)
    part = MeshPart(
        name="sphere", label=1, vertices=v, triangles=t, tri_uv=uv, texture=uniform_texture(), texel_size_m=0.1
    )
    return make_scene([part], eye=(0.0, -1.5, 1.0))


__all__ = ["uniform_texture", "plane_part", "make_scene", "box"]


@pytest.fixture
def factories():
    """Helpers as a fixture (test modules cannot import conftest)."""

    class F:
        pass

    f = F()
    f.uniform_texture = uniform_texture
    f.plane_part = plane_part
    f.make_scene = make_scene
    f.box = box
    return f
