"""The renderer's shading against a real matte sphere under known lights (``multilight/gray``).

The real sphere's normals follow from its outline (the sets are taken with a
long lens: orthographic to within its half-degree field); the render's come
from the renderer. Both images are binned by their normal (:data:`BIN`
wide in the normal's x and y, z toward the camera), and per light the render
is scaled by the one gain that fits it best (exposure is a free choice of
each shot). The error measure is the relative RMS difference of the binned
grey levels over the bins both see lit and unsaturated; beside it, the same
measure for an ideal Lambertian sphere with a linear camera, which tells how
far the real sphere is from that model.

The render is taken as the multi-light camera takes its images: a linear
response (:data:`MULTILIGHT_CAMERA`; an ideal Lambertian sphere fits the real
one far better with gamma 1 than 2.2, docs/lab/2026-12-06-lighting.md,
"Lead 1"), 8 bits, the simulated sensor's noise. The same render through the
field camera's response (gamma 2.2) is reported beside it.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from fgcd_cli.bench.lighting.renders import multilight_lightings
from fgcd_core.camera import CameraIntrinsics
from fgcd_drivers.sim.camera import DEFAULT_EFFECTS
from fgcd_drivers.sim.render import Renderer
from fgcd_drivers.sim.scenes import load_scene
from fgcd_drivers.sim.sensor import CameraEffects

__all__ = ["BIN", "DARK", "SATURATED", "MULTILIGHT_CAMERA", "binned_by_normal", "gain_fit_error", "sphere_shading"]

#: The photometric-stereo set's camera: linear response, 8 bits; noise as the simulated sensor's.
MULTILIGHT_CAMERA = CameraEffects(
    gamma=1.0, read_noise=DEFAULT_EFFECTS.read_noise, shot_noise=DEFAULT_EFFECTS.shot_noise, bit_depth=8
)

#: Width of a normal bin (in the normal's x and y).
BIN = 0.05
#: Grey levels (of 255) at or above which a pixel is saturated; at or below DARK, unlit or in noise.
SATURATED = 250
DARK = 8


def binned_by_normal(gray: np.ndarray, normals: np.ndarray, valid: np.ndarray) -> dict[tuple[int, int], float]:
    """Mean grey level per normal bin.

    Parameters
    ----------
    gray : (H, W) ndarray
        Grey levels (0-255).
    normals : (H, W, 3) ndarray
        Unit normals in a camera frame with x right, y down, z toward the camera.
    valid : (H, W) bool ndarray
    """
    keys = np.floor(normals[valid][:, :2] / BIN).astype(int)
    values = gray[valid].astype(float)
    sums: dict[tuple[int, int], list[float]] = {}
    for (i, j), v in zip(map(tuple, keys), values):
        acc = sums.setdefault((i, j), [0.0, 0.0])
        acc[0] += v
        acc[1] += 1.0
    return {k: s / n for k, (s, n) in sums.items() if n >= 3}


def gain_fit_error(real: dict, model: dict) -> float:
    """Relative RMS of ``real - g * model`` over shared lit, unsaturated bins, ``g`` the least-squares gain."""
    keys = [k for k in real if k in model and DARK < real[k] < SATURATED]
    if len(keys) < 10:
        return float("nan")
    r = np.array([real[k] for k in keys])
    m = np.array([model[k] for k in keys])
    g = float(r @ m / max(m @ m, 1e-12))
    return float(np.sqrt(np.mean((r - g * m) ** 2)) / np.mean(r))


def _real_sphere(folder: Path, n: int) -> tuple[list[np.ndarray], np.ndarray, np.ndarray, tuple]:
    mask = cv2.imread(str(folder / "mask.png"), cv2.IMREAD_GRAYSCALE) > 0
    ys, xs = np.nonzero(mask)
    cx, cy, r = xs.mean(), ys.mean(), np.sqrt(mask.sum() / np.pi)
    yy, xx = np.mgrid[0 : mask.shape[0], 0 : mask.shape[1]]
    nx, ny = (xx - cx) / r, (yy - cy) / r
    nz = np.sqrt(np.clip(1.0 - nx**2 - ny**2, 0.0, 1.0))
    normals = np.dstack([nx, ny, nz])
    inside = mask & (nx**2 + ny**2 < 0.95**2)  # the rim's normals are the least certain
    images = [cv2.imread(str(folder / f"light-{i:02d}.png"), cv2.IMREAD_GRAYSCALE) for i in range(n)]
    return images, normals, inside, (mask.shape, r)


def _rendered_sphere(directions: np.ndarray, shape: tuple[int, int], radius_px: float, effects: CameraEffects):
    scene = load_scene("grey_sphere")
    T = scene.default_T_world_cam
    distance = float(np.linalg.norm(T[:3, 3] - np.array([0.0, 0.0, 1.0])))
    f = radius_px * distance / 0.15  # the sphere as large in the image as the real one
    h, w = shape
    intr = CameraIntrinsics(fx=f, fy=f, cx=(w - 1) / 2.0, cy=(h - 1) / 2.0, width=w, height=h)
    renderer = Renderer(scene, supersample=2)
    rng = np.random.default_rng(0)
    out, normals, valid = [], None, None
    for lighting in multilight_lightings(directions, T):
        res = renderer.render(T, intr, lighting, effects=effects, rng=rng, want=("gray",))
        out.append(np.clip(np.round(res.gray * 255.0), 0, 255))
        if normals is None:
            n_cam = res.normals @ T[:3, :3]  # world -> OpenCV camera (x right, y down, z forward)
            normals = n_cam * np.array([1.0, 1.0, -1.0])  # z toward the camera
            valid = (res.labels > 0) & (normals[..., 0] ** 2 + normals[..., 1] ** 2 < 0.95**2)
    return out, normals, valid


def sphere_shading(folder: Path, directions: np.ndarray) -> dict:
    """Per light: the gain-fitted relative RMS error of the render, and of an ideal Lambertian sphere.

    Parameters
    ----------
    folder : Path
        ``multilight/gray``.
    directions : (N, 3) ndarray
        ``lights.txt`` (x right, y up, z toward the viewer).

    Returns
    -------
    dict
        ``render_rel_rms`` (the multi-light camera's response), ``field_camera_rel_rms`` (gamma 2.2)
        and ``lambert_rel_rms`` (lists, one per light), their medians, the render's maximum.
    """
    real, normals, inside, (shape, radius) = _real_sphere(folder, len(directions))
    rendered, r_normals, r_valid = _rendered_sphere(directions, shape, radius, MULTILIGHT_CAMERA)
    field, _, _ = _rendered_sphere(directions, shape, radius, DEFAULT_EFFECTS)
    render_err, field_err, lambert_err = [], [], []
    for i, (x, y, z) in enumerate(directions):
        real_bins = binned_by_normal(real[i], normals, inside)
        render_err.append(gain_fit_error(real_bins, binned_by_normal(rendered[i], r_normals, r_valid)))
        field_err.append(gain_fit_error(real_bins, binned_by_normal(field[i], r_normals, r_valid)))
        L = np.array([x, -y, z])  # lights.txt's y is up; the normals' y is down
        lambert = np.clip(normals @ L, 0.0, None) * 255.0
        lambert_err.append(gain_fit_error(real_bins, binned_by_normal(lambert, normals, inside)))
    return {
        "render_rel_rms": render_err,
        "lambert_rel_rms": lambert_err,
        "render_rel_rms_median": float(np.nanmedian(render_err)),
        "render_rel_rms_max": float(np.nanmax(render_err)),
        "field_camera_rel_rms": field_err,
        "field_camera_rel_rms_median": float(np.nanmedian(field_err)),
        "lambert_rel_rms_median": float(np.nanmedian(lambert_err)),
    }
