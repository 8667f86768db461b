"""Random changes placed on the object where a camera sees it (rendered from the scene, so it sits above ``changes`` and ``render``)."""

from __future__ import annotations

import numpy as np

from fgcd_core.camera import CameraIntrinsics
from fgcd_drivers.sim.camera import DEFAULT_INTRINSICS
from fgcd_drivers.sim.changes import ALL_KINDS, KINDS, ChangeSpec
from fgcd_drivers.sim.render import Renderer

#: The placement's view: half the simulator's nominal camera (the object, its depth and normals, cheaply).
_PLACEMENT_INTRINSICS = CameraIntrinsics(fx=300, fy=300, cx=159.5, cy=119.5, width=320, height=240)


def _object_view(scene, T_world_cam: np.ndarray | None):
    """The scene rendered at the placement's view: (camera pose, render with depth, normals and labels)."""
    T = scene.default_T_world_cam if T_world_cam is None else T_world_cam
    res = Renderer(scene).render(T, _PLACEMENT_INTRINSICS, None, want=("depth", "normals", "labels"))
    return T, res


def object_mm_per_px(scene, T_world_cam: np.ndarray | None = None) -> float:
    """Millimetres per pixel of the simulator's nominal camera on the object, at its median depth.

    Rule: a fronto-parallel millimetre at depth ``z`` spans ``fx / (1000 z)`` pixels
    (``DEFAULT_INTRINSICS.fx``, 640 x 480), so a change sized in pixels of the stored
    images is ``size_px * 1000 z / fx`` millimetres.

    Parameters
    ----------
    scene : Scene
    T_world_cam : (4, 4) ndarray, optional; the view (default: the scene's default camera).

    Returns
    -------
    float, mm per px (NaN when the object is not in view).
    """
    _, res = _object_view(scene, T_world_cam)
    z = res.depth[(res.labels == 1) & (res.depth > 0)]
    return float(np.median(z) * 1000.0 / DEFAULT_INTRINSICS.fx) if len(z) else float("nan")


def random_changes(
    scene,
    *,
    n: int,
    seed: int,
    kinds=KINDS,
    size_mm: tuple[float, float] = (1.0, 20.0),
    T_world_cam: np.ndarray | None = None,
    margin_px: int = 40,
) -> list[ChangeSpec]:
    """``n`` random changes on the object, placed where the default camera sees it.

    Positions are drawn from surface points seen from ``T_world_cam`` (default:
    the scene's default camera) on the object (label 1), away from the image border;
    kinds are drawn uniformly from ``kinds`` (any of ``ALL_KINDS``); sizes are
    log-uniform in ``size_mm``.
    """
    unknown = [k for k in kinds if k not in ALL_KINDS]
    if unknown or not len(kinds):
        raise ValueError(f"kinds must be a non-empty subset of {', '.join(ALL_KINDS)}, got {list(kinds)}")
    rng = np.random.default_rng(seed)
    T, res = _object_view(scene, T_world_cam)
    intr = _PLACEMENT_INTRINSICS
    m = margin_px // 2
    ok = np.zeros_like(res.labels, bool)
    ok[m:-m, m:-m] = True
    ok &= (res.labels == 1) & (res.depth > 0)
    vs, us = np.nonzero(ok)
    if len(vs) == 0:
        raise ValueError(f"the object of scene {scene.name} is not visible from the camera")
    out = []
    for _ in range(n):
        j = rng.integers(len(vs))
        v, u = vs[j], us[j]
        z = float(res.depth[v, u])
        p_cam = np.array([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z])
        p = T[:3, :3] @ p_cam + T[:3, 3]
        kind = str(rng.choice(list(kinds)))
        size = float(np.exp(rng.uniform(np.log(size_mm[0]), np.log(size_mm[1]))))
        out.append(
            ChangeSpec(
                kind=kind,
                position=tuple(p),
                normal=tuple(res.normals[v, u]),
                size_mm=size,
                seed=int(rng.integers(1 << 30)),
            )
        )
    return out
