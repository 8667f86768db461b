"""Triangle meshes with per-triangle texture coordinates, and the builders scenes use.

A :class:`MeshPart` is one textured surface of a scene. Texture coordinates are
per triangle corner (so seams need no duplicated vertices) in units of texture
repeats (1.0 = one texture width; textures wrap).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["MeshPart", "heightfield", "quad", "box", "revolution", "uv_sphere", "implicit_surface", "vertex_normals"]


@dataclass(kw_only=True)
class MeshPart:
    """One textured surface.

    Attributes
    ----------
    name : str
        Part name (``object``, ``floor``, ``wall``...).
    label : int
        Label written in the label buffer (>= 1).
    vertices : (N, 3) float64, metres, world frame.
    triangles : (M, 3) int64 vertex indices, counter-clockwise seen from outside.
    tri_uv : (M, 3, 2) float32 texture coordinates of each triangle corner.
    texture : (H, W, 3) float32 albedo in [0, 1].
    texel_size_m : float
        Approximate size of one texel on the surface (mip-level selection).
    smooth : bool
        Interpolate vertex normals (True) or use face normals (False).
    """

    name: str
    label: int
    vertices: np.ndarray
    triangles: np.ndarray
    tri_uv: np.ndarray
    texture: np.ndarray
    texel_size_m: float
    smooth: bool = True
    vertex_normals: np.ndarray | None = field(default=None)

    def __post_init__(self) -> None:
        self.vertices = np.asarray(self.vertices, dtype=np.float64)
        self.triangles = np.asarray(self.triangles, dtype=np.int64)
        self.tri_uv = np.asarray(self.tri_uv, dtype=np.float32)
        if self.tri_uv.shape != (len(self.triangles), 3, 2):
            raise ValueError(f"tri_uv of part {self.name} has shape {self.tri_uv.shape}")
        if self.smooth and self.vertex_normals is None:
            self.vertex_normals = vertex_normals(self.vertices, self.triangles)

    def transformed(self, T: np.ndarray) -> MeshPart:
        """A copy moved by the 4x4 pose ``T``."""
        v = self.vertices @ T[:3, :3].T + T[:3, 3]
        return MeshPart(
            name=self.name,
            label=self.label,
            vertices=v,
            triangles=self.triangles,
            tri_uv=self.tri_uv,
            texture=self.texture,
            texel_size_m=self.texel_size_m,
            smooth=self.smooth,
        )


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals, (N, 3) float32 unit vectors."""
    v0, v1, v2 = (vertices[triangles[:, i]] for i in range(3))
    fn = np.cross(v1 - v0, v2 - v0)
    vn = np.zeros_like(vertices)
    for i in range(3):
        np.add.at(vn, triangles[:, i], fn)
    n = np.linalg.norm(vn, axis=1, keepdims=True)
    return (vn / np.maximum(n, 1e-20)).astype(np.float32)


def _grid_triangles(nu: int, nv: int) -> np.ndarray:
    idx = np.arange(nu * nv).reshape(nv, nu)
    a = idx[:-1, :-1].ravel()
    b = idx[:-1, 1:].ravel()
    c = idx[1:, :-1].ravel()
    d = idx[1:, 1:].ravel()
    return np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])


def heightfield(
    *,
    origin,
    axis_u,
    axis_v,
    size_u: float,
    size_v: float,
    height: np.ndarray,
    uv_repeat_m: tuple[float, float] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A rectangular grid displaced along its normal.

    Parameters
    ----------
    origin : (3,) corner of the rectangle (u = 0, v = 0), metres.
    axis_u, axis_v : (3,) unit vectors along the rectangle; the outward normal is ``u x v``.
    size_u, size_v : float, metres.
    height : (nv, nu) float array, metres along the normal (positive = towards the viewer).
    uv_repeat_m : (float, float), optional
        Metres per texture repeat along u and v; by default the texture covers the
        rectangle once (v = 0 at the top edge, which is at ``v = size_v``).

    Returns
    -------
    vertices (N, 3), triangles (M, 3), tri_uv (M, 3, 2)
    """
    origin = np.asarray(origin, float)
    au = np.asarray(axis_u, float)
    av = np.asarray(axis_v, float)
    n = np.cross(au, av)
    nv, nu = height.shape
    su, sv = np.meshgrid(np.linspace(0, size_u, nu), np.linspace(0, size_v, nv))
    verts = origin + su[..., None] * au + sv[..., None] * av + np.asarray(height)[..., None] * n
    verts = verts.reshape(-1, 3)
    if uv_repeat_m is None:
        tu, tv = su / size_u, 1.0 - sv / size_v
    else:
        tu, tv = su / uv_repeat_m[0], -sv / uv_repeat_m[1]
    uv = np.stack([tu.ravel(), tv.ravel()], 1)
    tris = _grid_triangles(nu, nv)
    return verts, tris, uv[tris].astype(np.float32)


def quad(*, origin, axis_u, axis_v, size_u, size_v, uv_repeat_m=None):
    """A flat rectangle (two triangles)."""
    return heightfield(
        origin=origin,
        axis_u=axis_u,
        axis_v=axis_v,
        size_u=size_u,
        size_v=size_v,
        height=np.zeros((2, 2)),
        uv_repeat_m=uv_repeat_m,
    )


def box(*, center, size, uv_repeat_m: float = 0.5, skip=()):
    """An axis-aligned box with separate vertices per face (sharp edges).

    ``skip`` lists faces to omit among ``+x -x +y -y +z -z``.
    """
    c = np.asarray(center, float)
    sx, sy, sz = (float(s) for s in size)
    h = np.array([sx, sy, sz]) / 2
    faces = {
        "+x": (c + [h[0], -h[1], -h[2]], [0, 1, 0], [0, 0, 1], sy, sz),
        "-x": (c + [-h[0], h[1], -h[2]], [0, -1, 0], [0, 0, 1], sy, sz),
        "+y": (c + [h[0], h[1], -h[2]], [-1, 0, 0], [0, 0, 1], sx, sz),
        "-y": (c + [-h[0], -h[1], -h[2]], [1, 0, 0], [0, 0, 1], sx, sz),
        "+z": (c + [-h[0], -h[1], h[2]], [1, 0, 0], [0, 1, 0], sx, sy),
        "-z": (c + [-h[0], h[1], -h[2]], [1, 0, 0], [0, -1, 0], sx, sy),
    }
    vs, ts, uvs = [], [], []
    off = 0
    for key, (o, au, av, su, sv) in faces.items():
        if key in skip:
            continue
        v, t, uv = quad(origin=o, axis_u=au, axis_v=av, size_u=su, size_v=sv, uv_repeat_m=(uv_repeat_m, uv_repeat_m))
        vs.append(v)
        ts.append(t + off)
        uvs.append(uv)
        off += len(v)
    return np.concatenate(vs), np.concatenate(ts), np.concatenate(uvs)


def revolution(
    *,
    z: np.ndarray,
    radius: np.ndarray,
    n_theta: int,
    displacement: np.ndarray | None = None,
    uv_repeat_m: float = 1.0,
    center=(0.0, 0.0, 0.0),
):
    """A body of revolution about the world z axis.

    Parameters
    ----------
    z, radius : (nz,) profile, metres (z increasing).
    n_theta : int, samples around.
    displacement : (nz, n_theta) radial offsets in metres (carvings), optional.
    uv_repeat_m : metres of arc length per texture repeat.
    """
    z = np.asarray(z, float)
    r = np.asarray(radius, float)
    theta = np.linspace(0, 2 * np.pi, n_theta, endpoint=False)
    R = r[:, None] + (0 if displacement is None else displacement)
    R = np.maximum(R, 0.0)
    x = R * np.cos(theta)[None, :]
    y = R * np.sin(theta)[None, :]
    Z = np.repeat(z[:, None], n_theta, axis=1)
    verts = np.stack([x, y, Z], -1).reshape(-1, 3) + np.asarray(center, float)
    nz = len(z)
    idx = np.arange(nz * n_theta).reshape(nz, n_theta)
    nxt = np.roll(idx, -1, axis=1)
    a, b, c, d = idx[:-1].ravel(), nxt[:-1].ravel(), idx[1:].ravel(), nxt[1:].ravel()
    tris = np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)])
    # arc length along the profile for v, mean circumference for u
    s = np.concatenate([[0], np.cumsum(np.hypot(np.diff(z), np.diff(r)))])
    circ = 2 * np.pi * max(float(r.mean()), 1e-3)
    U = np.repeat((theta / (2 * np.pi))[None, :], nz, 0) * circ / uv_repeat_m
    V = -np.repeat(s[:, None], n_theta, 1) / uv_repeat_m
    uv = np.stack([U.ravel(), V.ravel()], 1)[tris]
    # fix the wrap-around seam: corners with u far below the triangle's max get one turn added
    turn = circ / uv_repeat_m
    umax = uv[:, :, 0].max(axis=1, keepdims=True)
    uv[:, :, 0] += np.where(umax - uv[:, :, 0] > turn / 2, turn, 0.0)
    return verts, tris, uv.astype(np.float32)


def uv_sphere(*, center, radius: float, n_lat: int = 180, n_lon: int = 360, uv_repeat_m: float | None = None):
    """A sphere; texture in equirectangular layout (or repeating every ``uv_repeat_m``)."""
    lat = np.linspace(-np.pi / 2, np.pi / 2, n_lat)
    z = radius * np.sin(lat)
    r = radius * np.cos(lat)
    rep = uv_repeat_m if uv_repeat_m is not None else 2 * np.pi * radius
    v, t, uv = revolution(z=z, radius=r, n_theta=n_lon, uv_repeat_m=1.0, center=center)
    # revolution's u uses the mean circumference; rescale to the equator's
    circ_mean = 2 * np.pi * max(float(r.mean()), 1e-3)
    uv[:, :, 0] *= (2 * np.pi * radius) / circ_mean / rep
    uv[:, :, 1] /= rep
    return v, t, uv


def implicit_surface(field: np.ndarray, *, origin, voxel_m: float, level: float = 0.0, uv_repeat_m: float = 0.5):
    """Iso-surface of a sampled scalar field (positive inside) by marching cubes.

    Texture coordinates are a box projection chosen per triangle from its normal.
    """
    from skimage.measure import marching_cubes

    verts, faces, _, _ = marching_cubes(field, level=level, spacing=(voxel_m,) * 3, gradient_direction="ascent")
    verts = verts + np.asarray(origin, float)
    # gradient_direction="ascent" with positive-inside fields gives inward normals: flip winding
    faces = faces[:, [0, 2, 1]].astype(np.int64)
    v0, v1, v2 = (verts[faces[:, i]] for i in range(3))
    fn = np.cross(v1 - v0, v2 - v0)
    dom = np.abs(fn).argmax(axis=1)
    pts = verts[faces]  # (M, 3, 3)
    pairs = np.array([[1, 2], [0, 2], [0, 1]])[dom]  # axes spanning the projection plane
    u = np.take_along_axis(pts, pairs[:, None, 0:1].repeat(3, 1), axis=2)[..., 0]
    w = np.take_along_axis(pts, pairs[:, None, 1:2].repeat(3, 1), axis=2)[..., 0]
    uv = np.stack([u, -w], -1) / uv_repeat_m
    return verts, faces, uv.astype(np.float32)
