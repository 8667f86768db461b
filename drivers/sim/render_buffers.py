"""The renderer's buffers (:class:`fgcd_drivers.sim.render.Renderer`): the visible surface samples it shades,
and the buffers of one rendered view it returns."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["RenderResult", "Surface"]


@dataclass(frozen=True, kw_only=True)
class Surface:
    """Visible surface samples of one ray batch, the input of shading (float32 arrays).

    Attributes
    ----------
    points : (N, 3) world points, m.
    shade_n, geo_n : (N, 3) shading and geometric unit normals.
    albedo : (N, 3) linear RGB albedo.
    depth : (N,) ray distance, m.
    cavity : (N,) ambient occlusion factor in [0, 1].
    shadow_lift : (N,) m or None
        Shadow rays start that much further along the geometric normal (back on
        the mesh surface for relief-only changes).
    """

    points: np.ndarray
    shade_n: np.ndarray
    geo_n: np.ndarray
    albedo: np.ndarray
    depth: np.ndarray
    cavity: np.ndarray
    shadow_lift: np.ndarray | None = None


@dataclass(kw_only=True)
class RenderResult:
    """Buffers of one rendered view (H, W at the requested intrinsics).

    Attributes
    ----------
    gray : (H, W) float32 in [0, 1] or None
    rgb : (H, W, 3) float32 in [0, 1] or None
    depth : (H, W) float32 z-depth in metres, 0 where nothing was hit.
    normals : (H, W, 3) float32 unit normals in the world frame, 0 where nothing.
    labels : (H, W) int32 part labels (1 = object, 0 = nothing).
    change_mask : (H, W) bool, pixels on an injected change.
    change_ids : (H, W) int32, 0 where no change, else 1 + the index (in the
        ``changes`` given to :meth:`Renderer.render`) of the change whose footprint
        is the strongest there; ``change_mask == (change_ids > 0)``.
    exposure : float used.
    """

    gray: np.ndarray | None
    rgb: np.ndarray | None
    depth: np.ndarray
    normals: np.ndarray
    labels: np.ndarray
    change_mask: np.ndarray
    change_ids: np.ndarray
    exposure: float = 1.0
