"""How the simulated world's surfaces look under light: the world presets and the specular lobe.

Two worlds (docs/simulator.md, "Appearance"):

- ``calibrated`` (the default): surfaces carry mesostructure (grain below the
  mesh, :mod:`fgcd_drivers.sim.mesostructure`) at the slope measured on real
  plaster, and a dielectric's specular lobe (a microfacet GGX lobe, Fresnel
  reflectance 0.04 at normal incidence, the value of stone, plaster and most
  paints) on top of the Lambertian body.
- ``smooth``: Lambert only, surfaces smooth below the mesh: the appearance the
  benches ran on before issue 45, kept selectable to compare.

The world of a process is ``$FGCD_SIM_WORLD`` if set, else ``calibrated``
(:func:`world_appearance`); a renderer given no appearance uses it, so a rig, a
bench and ``fgcd sim render`` see the same world.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from fgcd_drivers.sim.mesostructure import PLASTER_SLOPE_RMS, Mesostructure

__all__ = [
    "Appearance",
    "Specular",
    "WORLDS",
    "DEFAULT_WORLD",
    "WORLD_ENV",
    "world_appearance",
    "ggx_specular",
]

#: Environment variable naming the simulated world of a process.
WORLD_ENV = "FGCD_SIM_WORLD"

#: The world the simulator renders unless told otherwise.
DEFAULT_WORLD = "calibrated"


@dataclass(frozen=True, kw_only=True)
class Specular:
    """A dielectric's specular lobe (GGX microfacet distribution, Schlick Fresnel, Smith-Schlick shadowing).

    Attributes
    ----------
    f0 : float
        Fresnel reflectance at normal incidence (0: no lobe, Lambert only; 0.04: stone, plaster,
        paint; 0.05-0.06: glazes).
    roughness : float
        Perceptual roughness in (0, 1]; the GGX width is ``alpha = roughness**2``.
    """

    f0: float = 0.0
    roughness: float = 0.6


@dataclass(frozen=True, kw_only=True)
class Appearance:
    """One simulated world's appearance model.

    Attributes
    ----------
    name : str
    mesostructure : Mesostructure
        Relief finer than the mesh (slope 0: smooth).
    specular : Specular
        The surfaces' specular lobe (``f0`` 0: Lambert only).
    """

    name: str
    mesostructure: Mesostructure = field(default_factory=Mesostructure)
    specular: Specular = field(default_factory=Specular)


#: The selectable worlds. ``calibrated``: grain at real plaster's roughness (PLASTER_SLOPE_RMS,
#: docs/lab/2026-12-06-lighting.md "Lead 4") and a dielectric lobe (F0 0.04, the reflectance of
#: a refractive index near 1.5; roughness 0.6, a honed, not polished, stone).
WORLDS: dict[str, Appearance] = {
    "calibrated": Appearance(
        name="calibrated",
        mesostructure=Mesostructure(slope_rms=PLASTER_SLOPE_RMS),
        specular=Specular(f0=0.04, roughness=0.6),
    ),
    "smooth": Appearance(name="smooth"),
}


def world_appearance(name: str | None = None) -> Appearance:
    """The appearance of world ``name`` (default: ``$FGCD_SIM_WORLD``, else :data:`DEFAULT_WORLD`).

    Raises
    ------
    ValueError
        For a name that is not a world (one line, listing the worlds).
    """
    chosen = name if name is not None else os.environ.get(WORLD_ENV, "").strip() or DEFAULT_WORLD
    if chosen not in WORLDS:
        raise ValueError(f"unknown simulated world {chosen!r}: choose one of {', '.join(sorted(WORLDS))}")
    return WORLDS[chosen]


def ggx_specular(normals: np.ndarray, to_light: np.ndarray, to_view: np.ndarray, specular: Specular) -> np.ndarray:
    """Specular radiance factor of a microfacet lobe, per sample: ``pi * D * F * G / (4 (n.v))``.

    The renderer's diffuse radiance is ``albedo * E * (n.l)`` (a Lambertian BRDF
    ``albedo / pi`` under irradiance ``pi * E``), so the specular radiance on the
    same scale is ``E * (n.l) * pi * f_s`` with the Cook-Torrance BRDF
    ``f_s = D F G / (4 (n.l)(n.v))``; ``(n.l)`` cancels. ``D`` is GGX
    (``alpha = roughness**2``), ``F`` Schlick's Fresnel on ``v.h``, ``G`` Smith-Schlick
    with ``k = alpha / 2``. Zero where the light or the view is below the normal.

    Parameters
    ----------
    normals : (N, 3) float32
        Unit shading normals.
    to_light, to_view : (N, 3) or (3,) float32
        Unit directions from the surface to the light and to the camera.
    specular : Specular

    Returns
    -------
    (N,) float32
        Multiply by the light's irradiance scale (intensity x attenuation) and the light's colour.
    """
    if specular.f0 <= 0:
        return np.zeros(len(normals), np.float32)
    to_light = np.broadcast_to(to_light, normals.shape)
    to_view = np.broadcast_to(to_view, normals.shape)
    half = to_light + to_view
    half = half / np.maximum(np.linalg.norm(half, axis=1, keepdims=True), 1e-12)
    n_l = np.einsum("ij,ij->i", normals, to_light)
    n_v = np.einsum("ij,ij->i", normals, to_view)
    n_h = np.clip(np.einsum("ij,ij->i", normals, half), 0.0, 1.0)
    v_h = np.clip(np.einsum("ij,ij->i", to_view, half), 0.0, 1.0)
    alpha = np.float32(max(specular.roughness, 1e-3) ** 2)
    a2 = alpha * alpha
    denom = n_h * n_h * (a2 - 1.0) + 1.0
    d = a2 / (np.float32(np.pi) * denom * denom)
    fresnel = specular.f0 + (1.0 - specular.f0) * (1.0 - v_h) ** 5
    k = alpha / 2.0
    nl_c, nv_c = np.maximum(n_l, 1e-4), np.maximum(n_v, 1e-4)
    g = (nl_c / (nl_c * (1.0 - k) + k)) * (nv_c / (nv_c * (1.0 - k) + k))
    out = np.float32(np.pi) * d * fresnel * g / (4.0 * nv_c)
    return np.where((n_l > 0) & (n_v > 0), out, 0.0).astype(np.float32)
