"""CPU renderer of a simulated scene on Open3D's ``RaycastingScene``.

Per pixel: a ray through the (optionally distorted) pixel centre; the hit gives
z-depth (rays have camera-z component 1, so ``t_hit`` *is* z-depth), the
triangle and its barycentric weights (Open3D's ``primitive_uvs`` are the weights
of corners 1 and 2, not texture coordinates). Texture coordinates and smooth
normals are interpolated from per-triangle data; albedo is sampled bilinearly
from a mip pyramid (trilinear between levels, chosen from the pixel footprint)
so that distant texture does not alias. Shading is Lambert with an ambient
(optionally hemispherical) term and hard cast shadows (occlusion rays towards
each light), plus the world's specular lobe and mesostructure
(:mod:`fgcd_drivers.sim.appearance`). Optional supersampling (``supersample=s``) shades an s x s grid per
pixel and box-filters it (anti-aliased edges); depth, normals, labels, change
masks and change ids always come from the pixel centres.

The camera response (exposure, vignetting, noise, gamma) is applied by
:func:`fgcd_drivers.sim.sensor.apply_camera_response` (that module also holds
:class:`CameraEffects`, :func:`auto_exposure` and ``LUMA``; import them from there).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import cv2
import numpy as np
import open3d as o3d

from fgcd_core.camera import CameraIntrinsics
from fgcd_drivers.sim.appearance import Appearance, ggx_specular, world_appearance
from fgcd_drivers.sim.changes import evaluate_changes
from fgcd_drivers.sim.lights import Lighting, lighting_preset
from fgcd_drivers.sim.mesostructure import slope_texture, triangle_tangents
from fgcd_drivers.sim.render_buffers import RenderResult, Surface
from fgcd_drivers.sim.scene import Scene
from fgcd_drivers.sim.sensor import LUMA, CameraEffects, apply_camera_response, auto_exposure
from fgcd_drivers.sim.texture_sampling import bent_normals, mip_pyramid, sample_mipmapped

__all__ = ["Renderer"]

_MISS = np.uint32(0xFFFFFFFF)


@dataclass
class _PartData:
    triangles: np.ndarray
    tri_uv: np.ndarray
    vertex_normals: np.ndarray | None
    pyramid: list[np.ndarray]
    texel_size_m: float
    label: int
    slope_pyramid: list[np.ndarray] | None = None


class Renderer:
    """Renders a :class:`Scene` from any camera pose.

    Parameters
    ----------
    scene : Scene
    supersample : int
        Shading samples per pixel along each axis (1 = one ray per pixel).
    nthreads : int
        Open3D ray-casting threads (0 = all cores).
    appearance : Appearance, optional
        The world's surfaces (default: :func:`fgcd_drivers.sim.appearance.world_appearance`,
        the process's world).
    """

    def __init__(self, scene: Scene, *, supersample: int = 1, nthreads: int = 0, appearance: Appearance | None = None):
        if supersample < 1:
            raise ValueError("supersample must be >= 1")
        self.scene = scene
        self.appearance = appearance if appearance is not None else world_appearance()
        meso = self.appearance.mesostructure
        self.mesostructure = meso if meso.slope_rms > 0 else None
        self.supersample = int(supersample)
        self.nthreads = int(nthreads)
        self._rc = o3d.t.geometry.RaycastingScene()
        self._parts: dict[int, _PartData] = {}
        # Global per-triangle tables (all parts concatenated) so that one gather serves every hit.
        offsets, uvs, corner_normals, part_of_tri, tangents = {}, [], [], [], []
        n_tri = 0
        for index, part in enumerate(scene.parts):
            gid = self._rc.add_triangles(part.vertices.astype(np.float32), part.triangles.astype(np.uint32))
            slopes = None
            if self.mesostructure is not None:
                texture = slope_texture(part.texture.shape[:2], part.texel_size_m, self.mesostructure, index)
                slopes = mip_pyramid(texture)
                tangents.append(triangle_tangents(part.vertices, part.triangles, part.tri_uv))
            self._parts[gid] = _PartData(
                triangles=part.triangles,
                tri_uv=part.tri_uv,
                vertex_normals=part.vertex_normals if part.smooth else None,
                pyramid=mip_pyramid(part.texture),
                texel_size_m=float(part.texel_size_m),
                label=int(part.label),
                slope_pyramid=slopes,
            )
            offsets[gid] = n_tri
            uvs.append(part.tri_uv.astype(np.float32))
            if part.smooth:
                cn = part.vertex_normals[part.triangles].astype(np.float32)  # (M, 3 corners, 3)
            else:
                v = part.vertices[part.triangles]
                fn = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
                fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-20)
                cn = np.repeat(fn[:, None, :], 3, axis=1).astype(np.float32)
            corner_normals.append(cn)
            part_of_tri.append(np.full(len(part.triangles), gid, np.int32))
            n_tri += len(part.triangles)
        max_gid = max(offsets) if offsets else 0
        self._tri_offset = np.zeros(max_gid + 1, np.int64)
        for gid, off in offsets.items():
            self._tri_offset[gid] = off
        self._tri_uv = np.concatenate(uvs) if uvs else np.zeros((0, 3, 2), np.float32)
        self._corner_normals = np.concatenate(corner_normals) if corner_normals else np.zeros((0, 3, 3), np.float32)
        self._tri_gid = np.concatenate(part_of_tri) if part_of_tri else np.zeros(0, np.int32)
        self._tri_tangents = np.concatenate(tangents) if tangents else None
        self._labels_by_gid = np.zeros(max_gid + 2, np.int32)
        for gid, pd in self._parts.items():
            self._labels_by_gid[gid] = pd.label
        self._ray_cache: dict = {}

    # ------------------------------------------------------------------ rays
    def with_supersample(self, supersample: int) -> Renderer:
        """This renderer (same ray-casting scene and textures, shared) shading ``supersample``² rays per pixel.

        The copy has its own ray cache, so that two threads can render with the two at once.
        """
        if supersample < 1:
            raise ValueError("supersample must be >= 1")
        twin = copy.copy(self)
        twin.supersample = int(supersample)
        twin._ray_cache = {}
        return twin

    def camera_rays(self, intrinsics: CameraIntrinsics, factor: int = 1) -> np.ndarray:
        """(H*f*W*f, 3) float32 ray directions in the camera frame with z = 1 (cached).

        Sample (i, j) of the f x f grid of pixel (u, v) sits at ``u + (j + 0.5)/f - 0.5``;
        lens distortion is inverted with OpenCV so that rays go through the
        distorted pixel positions.
        """
        key = (intrinsics, factor)
        if key in self._ray_cache:
            return self._ray_cache[key]
        w, h = intrinsics.width * factor, intrinsics.height * factor
        us = (np.arange(w, dtype=np.float64) + 0.5) / factor - 0.5
        vs = (np.arange(h, dtype=np.float64) + 0.5) / factor - 0.5
        uu, vv = np.meshgrid(us, vs)
        if intrinsics.has_distortion:
            pts = np.stack([uu.ravel(), vv.ravel()], 1).reshape(-1, 1, 2)
            und = cv2.undistortPointsIter(
                pts,
                intrinsics.K,
                intrinsics.dist_array,
                None,
                None,
                (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10),
            )
            xy = und.reshape(-1, 2)
        else:
            xy = np.stack(
                [(uu.ravel() - intrinsics.cx) / intrinsics.fx, (vv.ravel() - intrinsics.cy) / intrinsics.fy], 1
            )
        d = np.concatenate([xy, np.ones((len(xy), 1))], 1).astype(np.float32)
        if len(self._ray_cache) > 8:
            self._ray_cache.clear()
        self._ray_cache[key] = d
        return d

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> dict:
        """Raw ray cast: world origins (N,3) and directions (N,3) -> numpy hit buffers."""
        rays = np.empty((len(directions), 6), np.float32)
        rays[:, :3] = origins
        rays[:, 3:] = directions
        ans = self._rc.cast_rays(o3d.core.Tensor(rays), nthreads=self.nthreads)
        return {
            k: ans[k].numpy() for k in ("t_hit", "geometry_ids", "primitive_ids", "primitive_uvs", "primitive_normals")
        }

    def occluded(self, origins: np.ndarray, directions: np.ndarray, tfar: float) -> np.ndarray:
        """True where a segment ``origin + t * direction, t in (0, tfar)`` hits the scene."""
        if len(origins) == 0:
            return np.zeros(0, bool)
        rays = np.empty((len(origins), 6), np.float32)
        rays[:, :3] = origins
        rays[:, 3:] = directions
        occ = self._rc.test_occlusions(o3d.core.Tensor(rays), tnear=0.0, tfar=float(tfar), nthreads=self.nthreads)
        return occ.numpy().astype(bool)

    # ------------------------------------------------------------------ surface
    def _surface(self, hits: dict, dirs_world: np.ndarray, fx: float, want_albedo: bool):
        """Per valid hit: index, t, part labels, shading normal, geometric normal, albedo (float32)."""
        t = hits["t_hit"]
        valid = np.isfinite(t)
        n_all = len(t)
        idx = np.flatnonzero(valid)
        if len(idx) == n_all:  # everything hit: no gathers needed
            take = lambda a: a  # noqa: E731
        else:
            take = lambda a: a[idx]  # noqa: E731
        gids = take(hits["geometry_ids"])
        gtri = self._tri_offset[gids] + take(hits["primitive_ids"])
        bary = take(hits["primitive_uvs"])
        w1, w2 = bary[:, 0:1], bary[:, 1:2]
        w0 = 1.0 - w1 - w2
        d = take(dirs_world)
        geo_n = take(hits["primitive_normals"])
        ddotn = np.einsum("ij,ij->i", geo_n, d)
        geo_n[ddotn > 0] *= -1
        cn = self._corner_normals[gtri]
        shade_n = w0 * cn[:, 0] + w1 * cn[:, 1] + w2 * cn[:, 2]
        shade_n /= np.maximum(np.sqrt(np.einsum("ij,ij->i", shade_n, shade_n)), 1e-12)[:, None]
        # orient like the geometric normal (towards the camera)
        flip = np.einsum("ij,ij->i", shade_n, geo_n) < 0
        shade_n[flip] *= -1
        tt = take(t)
        albedo = None
        if want_albedo:
            albedo = np.empty((len(idx), 3), np.float32)
            tuv = self._tri_uv[gtri]
            uv = w0 * tuv[:, 0] + w1 * tuv[:, 1] + w2 * tuv[:, 2]
            uv -= np.floor(uv)  # textures repeat; keeps remap coordinates small
            dnorm = np.sqrt(np.einsum("ij,ij->i", d, d))
            cos_view = np.abs(ddotn) / dnorm
            # pixel footprint on the surface in metres (mip level selection)
            foot = tt * dnorm / np.float32(fx) / np.sqrt(np.maximum(cos_view, 0.2))
            slope = np.zeros((len(idx), 3), np.float32) if self.mesostructure is not None else None
            for gid, pd in self._parts.items():
                sel = np.flatnonzero(gids == gid) if len(self._parts) > 1 else np.arange(len(idx))
                if len(sel) == 0:
                    continue
                level = np.log2(np.maximum(foot[sel] / pd.texel_size_m, 1e-6))
                level = np.clip(level, 0.0, len(pd.pyramid) - 1.0)
                albedo[sel] = sample_mipmapped(pd.pyramid, uv[sel], level)
                if slope is not None and pd.slope_pyramid is not None:
                    slope[sel] = sample_mipmapped(pd.slope_pyramid, uv[sel], level)
            if slope is not None:
                shade_n = bent_normals(shade_n, slope, self._tri_tangents[gtri])
        labels = self._labels_by_gid[gids]
        return idx, tt, labels, shade_n, geo_n, albedo

    # ------------------------------------------------------------------ shading
    def _light_world(self, light, T_world_cam):
        if light.frame == "camera":
            return T_world_cam[:3, :3] @ np.asarray(light.position) + T_world_cam[:3, 3]
        if light.frame == "scene":
            return np.asarray(self.scene.lamp_position, float)
        return np.asarray(light.position, float)

    def _shade(self, surf: Surface, lighting: Lighting, T_world_cam) -> np.ndarray:
        """Linear RGB radiance (N, 3) float32 of surface samples (all inputs float32)."""
        points, shade_n, geo_n, albedo = surf.points, surf.shade_n, surf.geo_n, surf.albedo
        depth, cavity, shadow_lift = surf.depth, surf.cavity, surf.shadow_lift
        up = np.asarray(self.scene.up, np.float32)
        if lighting.sky_weight > 0:
            sky = (1.0 - lighting.sky_weight) + lighting.sky_weight * (0.5 + 0.5 * (shade_n @ up))
        else:
            sky = np.ones(len(points), np.float32)
        amb = np.float32(lighting.ambient) * sky * cavity
        E = amb[:, None] * np.asarray(lighting.ambient_colour, np.float32)[None, :]
        offset = None
        specular = self.appearance.specular
        to_view = None
        if specular.f0 > 0 and lighting.lights:
            to_view = T_world_cam[:3, 3].astype(np.float32)[None, :] - points
            to_view /= np.maximum(np.sqrt(np.einsum("ij,ij->i", to_view, to_view)), np.float32(1e-9))[:, None]
        glossy = None
        for light in lighting.lights:
            if light.kind == "point":
                pos = self._light_world(light, T_world_cam).astype(np.float32)
                L = pos[None, :] - points
                dist = np.sqrt(np.einsum("ij,ij->i", L, L))
                inv = 1.0 / np.maximum(dist, np.float32(1e-6))
                cos = np.einsum("ij,ij->i", shade_n, L) * inv
                cos_geo = np.einsum("ij,ij->i", geo_n, L)
                atten = (np.float32(light.reference_distance_m) * inv) ** 2
                atten = np.minimum(atten, np.float32(1e6))
            else:
                to_light = np.asarray(light.direction, np.float32) / np.float32(np.linalg.norm(light.direction))
                cos = shade_n @ to_light
                cos_geo = geo_n @ to_light
                atten = np.float32(1.0)
            # light below the geometric surface never reaches it (no leaking at grazing angles)
            lit = (cos > 0) & (cos_geo > 0)
            strength = np.where(lit, cos, np.float32(0)) * atten
            if light.cast_shadows and lit.any():
                li = np.flatnonzero(lit)
                if offset is None:
                    offset = (np.float32(0.0005) + np.float32(0.002) * depth)[:, None] * geo_n
                    if shadow_lift is not None:
                        offset = offset + shadow_lift[:, None] * geo_n
                org = points[li] + offset[li]
                if light.kind == "point":
                    occ = self.occluded(org, pos[None, :] - org, 0.999)
                else:
                    occ = self.occluded(org, np.broadcast_to(to_light, org.shape), math.inf)
                strength[li[occ]] = 0.0
            colour = np.asarray(light.colour, np.float32)[None, :]
            E += (np.float32(light.intensity) * strength)[:, None] * colour
            if to_view is not None:
                # the lobe of a dielectric is the light's colour, not the albedo's (appearance.ggx_specular)
                to_light_n = L * inv[:, None] if light.kind == "point" else to_light
                lobe = ggx_specular(shade_n, to_light_n, to_view, specular)
                lobe = np.where(strength > 0, lobe * np.float32(light.intensity) * atten, np.float32(0))
                glossy = lobe[:, None] * colour if glossy is None else glossy + lobe[:, None] * colour
        return albedo * E if glossy is None else albedo * E + glossy

    def _shade_rays(self, T_world_cam, dirs_cam, fx, lighting, changes, want_albedo=True):
        """Cast rays and shade: per-ray radiance (N,3) and per-ray buffers."""
        R, o = T_world_cam[:3, :3].astype(np.float32), T_world_cam[:3, 3].astype(np.float32)
        dirs_world = dirs_cam @ R.T
        hits = self.cast(o[None, :], dirs_world)
        idx, t, labels, shade_n, geo_n, albedo = self._surface(hits, dirs_world, fx, want_albedo)
        d_hit = dirs_world[idx]
        points = o[None, :] + t[:, None] * d_hit
        cavity = np.ones(len(idx), np.float32)
        ids_local = np.zeros(len(idx), np.int32)
        shadow_lift = None
        if changes:
            eff = evaluate_changes(changes, points.astype(np.float64), shade_n.astype(np.float64))
            if len(eff.index):
                k = eff.index
                ndotd = np.abs(np.einsum("ij,ij->i", geo_n[k], d_hit[k]))
                t = t.copy()
                t[k] = t[k] + (eff.height_m / np.maximum(ndotd, 0.05)).astype(np.float32)
                points[k] = o[None, :] + t[k, None] * d_hit[k]
                n = shade_n[k] + eff.slope.astype(np.float32)
                shade_n[k] = n / np.linalg.norm(n, axis=1, keepdims=True)
                cavity[k] = 1.0 - eff.occlusion
                lift = eff.height_m - eff.shadow_height_m
                if np.any(lift != 0):
                    shadow_lift = np.zeros(len(idx), np.float32)
                    shadow_lift[k] = lift
                if want_albedo:
                    albedo[k] = eff.albedo_of(albedo[k])
                ids_local[k] = np.where(eff.footprint >= 0.5, eff.change_index + 1, 0)
        radiance = None
        if want_albedo and lighting is not None:
            surf = Surface(
                points=points,
                shade_n=shade_n,
                geo_n=geo_n,
                albedo=albedo,
                depth=t,
                cavity=cavity,
                shadow_lift=shadow_lift,
            )
            radiance = self._shade(surf, lighting, T_world_cam)
        return dict(n=len(dirs_cam), idx=idx, t=t, labels=labels, normals=shade_n, radiance=radiance, ids=ids_local)

    # ------------------------------------------------------------------ public
    def render(
        self,
        T_world_cam: np.ndarray,
        intrinsics: CameraIntrinsics,
        lighting: Lighting | str | None = "front",
        *,
        changes=None,
        exposure: float | str = "auto",
        effects: CameraEffects | None = None,
        rng: np.random.Generator | None = None,
        want=("gray", "depth"),
    ) -> RenderResult:
        """Render one view.

        Parameters
        ----------
        T_world_cam : (4, 4) camera pose in the world (OpenCV camera frame).
        intrinsics : CameraIntrinsics (distortion honoured).
        lighting : Lighting, preset name, or None (geometry only).
        changes : sequence of ChangeSpec, optional.
        exposure : float or ``"auto"``.
        effects : CameraEffects (default: gamma 2.2, no noise, no vignetting).
        rng : numpy Generator for the sensor noise.
        want : which of ``gray rgb depth normals labels change_mask change_ids`` are
            needed (depth, normals, labels, change_mask and change_ids are always
            returned; asking for neither gray nor rgb skips shading).

        Returns
        -------
        RenderResult
        """
        T_world_cam = np.asarray(T_world_cam, dtype=float)
        if isinstance(lighting, str):
            lighting = lighting_preset(lighting)
        effects = effects or CameraEffects()
        shade = lighting is not None and ("gray" in want or "rgb" in want)
        h, w = intrinsics.height, intrinsics.width
        s = self.supersample
        dirs = self.camera_rays(intrinsics, 1)
        prim = self._shade_rays(
            T_world_cam,
            dirs,
            intrinsics.fx,
            lighting if (shade and s == 1) else None,
            changes,
            want_albedo=(shade and s == 1),
        )
        depth = np.zeros(h * w, np.float32)
        depth[prim["idx"]] = prim["t"]
        normals = np.zeros((h * w, 3), np.float32)
        normals[prim["idx"]] = prim["normals"]
        labels = np.zeros(h * w, np.int32)
        labels[prim["idx"]] = prim["labels"]
        ids = np.zeros(h * w, np.int32)
        ids[prim["idx"]] = prim["ids"]
        gray = rgb = None
        exp_used = float(exposure) if not isinstance(exposure, str) else 1.0
        if shade:
            if s == 1:
                lin = np.zeros((h * w, 3), np.float32)
                lin[prim["idx"]] = prim["radiance"]
                lin = lin.reshape(h, w, 3)
                valid = (labels > 0).reshape(h, w)
            else:
                fine = self._shade_rays(
                    T_world_cam, self.camera_rays(intrinsics, s), intrinsics.fx * s, lighting, changes, want_albedo=True
                )
                lin_f = np.zeros((h * s * w * s, 3), np.float32)
                lin_f[fine["idx"]] = fine["radiance"]
                lin = cv2.resize(lin_f.reshape(h * s, w * s, 3), (w, h), interpolation=cv2.INTER_AREA)
                valid = (labels > 0).reshape(h, w)
            lin_gray = lin @ LUMA
            if isinstance(exposure, str):
                if exposure != "auto":
                    raise ValueError(f"exposure must be a number or 'auto', got {exposure!r}")
                # centre-weighted metering, as most cameras do: the middle half of the frame
                meter = np.zeros_like(valid)
                meter[h // 4 : h - h // 4, w // 4 : w - w // 4] = True
                meter &= valid
                exp_used = auto_exposure(lin_gray, meter if meter.any() else valid, max_exposure=effects.max_exposure)
            if "gray" in want:
                gray = apply_camera_response(lin_gray, exposure=exp_used, effects=effects, rng=rng)
            if "rgb" in want:
                rgb = apply_camera_response(lin, exposure=exp_used, effects=effects, rng=rng)
        return RenderResult(
            gray=gray,
            rgb=rgb,
            depth=depth.reshape(h, w),
            normals=normals.reshape(h, w, 3),
            labels=labels.reshape(h, w),
            change_mask=(ids > 0).reshape(h, w),
            change_ids=ids.reshape(h, w),
            exposure=exp_used,
        )
