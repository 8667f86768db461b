"""Lighting presets that reproduce the papers' conditions.

A :class:`Lighting` is a set of lights plus an ambient term. Lights are defined
in one of three frames:

* ``camera``: attached to the camera rig (the front light, the LED on an arm at
  a clock position around the optical axis, rACR §5.2.2);
* ``world``: fixed in the scene (the sun is a direction, lamps are points);
* ``scene``: the scene's own artificial lamp (``Scene.lamp_position``), used by
  the ``night`` preset.

Preset names (see :func:`list_lighting_presets`): ``front``, ``led:H`` (H = 1..12,
optional ``led:H,r=0.4`` arm radius in metres, default 0.6), ``sun:az=A,el=E`` (degrees;
azimuth from +y (north) towards +x (east)), ``sun:day=D,hour=H[,lat=L]`` (day of
year, local solar hour, latitude in degrees), ``sun-morning``, ``sun-noon``,
``sun-evening``, ``sun-winter-noon``, ``overcast``, ``night``, ``ambient``, ``dark``.

Who owns a light (docs/simulator.md, "Lights a rig carries"): presets whose
lights all ride on the camera (``front``, ``led:H``) are *rig lamps*, which a
rig switches; every other preset is *the world's light* (the sun, the sky, the
night's lamp, a lit room, a dark one), which only the visit's day and hour set.
:func:`compose` lights a world with one rig lamp switched on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "DARK",
    "Light",
    "Lighting",
    "compose",
    "is_rig_lamp",
    "lighting_preset",
    "list_lighting_presets",
    "solar_az_el",
    "sun_direction",
]

#: The world without light of its own: a closed room, or a night with no lamp (the rig's lamps alone light it).
DARK = "dark"


@dataclass(frozen=True, kw_only=True)
class Light:
    """One light.

    Attributes
    ----------
    kind : ``"point"`` or ``"directional"``.
    frame : ``"camera"``, ``"world"`` or ``"scene"`` (the scene's lamp position).
    position : (3,) metres in ``frame`` (point lights; ignored for ``scene``).
    direction : (3,) unit vector towards the light (directional lights).
    intensity : float
        Irradiance on a surface facing the light (at ``reference_distance_m`` for points).
    colour : (3,) RGB multiplier.
    reference_distance_m : float
        Point lights fall off as ``(reference_distance_m / d)**2``.
    cast_shadows : bool
    """

    kind: str
    frame: str
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    direction: tuple[float, float, float] = (0.0, 0.0, 1.0)
    intensity: float = 1.0
    colour: tuple[float, float, float] = (1.0, 1.0, 1.0)
    reference_distance_m: float = 1.0
    cast_shadows: bool = True


@dataclass(frozen=True, kw_only=True)
class Lighting:
    """A lighting condition.

    Attributes
    ----------
    name : str
    lights : tuple of Light
    ambient : float
        Ambient irradiance.
    ambient_colour : (3,) RGB
    sky_weight : float
        0 = uniform ambient; 1 = fully hemispherical (surfaces facing down get none).
    """

    name: str
    lights: tuple[Light, ...] = field(default_factory=tuple)
    ambient: float = 0.1
    ambient_colour: tuple[float, float, float] = (1.0, 1.0, 1.0)
    sky_weight: float = 0.0


def sun_direction(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Unit vector towards the sun in the world frame (z up, azimuth from +y towards +x)."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)])


def solar_az_el(day_of_year: float, solar_hour: float, latitude_deg: float = 40.0) -> tuple[float, float]:
    """Approximate solar azimuth and elevation (degrees) from day, local solar time and latitude.

    Cooper's declination and the standard hour-angle formula; good to about a degree,
    which is all a lighting condition needs.
    """
    decl = math.radians(23.45) * math.sin(2 * math.pi * (284 + day_of_year) / 365.0)
    lat = math.radians(latitude_deg)
    hour_angle = math.radians(15.0 * (solar_hour - 12.0))
    sin_el = math.sin(lat) * math.sin(decl) + math.cos(lat) * math.cos(decl) * math.cos(hour_angle)
    el = math.asin(max(-1.0, min(1.0, sin_el)))
    cos_az = (math.sin(decl) - math.sin(el) * math.sin(lat)) / max(1e-9, math.cos(el) * math.cos(lat))
    az = math.degrees(math.acos(max(-1.0, min(1.0, cos_az))))
    if hour_angle > 0:
        az = 360.0 - az
    return az, math.degrees(el)


def _sun(name: str, az: float, el: float) -> Lighting:
    if el <= 0:
        raise ValueError(f"the sun is below the horizon for {name} (elevation {el:.1f} deg)")
    # low sun is warmer and weaker (longer path through the air)
    warmth = math.exp(-el / 12.0)
    colour = (1.0, 0.95 - 0.25 * warmth, 0.88 - 0.45 * warmth)
    intensity = 1.2 * (1.0 - 0.5 * warmth)
    d = sun_direction(az, el)
    return Lighting(
        name=name,
        lights=(Light(kind="directional", frame="world", direction=tuple(d), intensity=intensity, colour=colour),),
        ambient=0.28,
        ambient_colour=(0.80, 0.88, 1.0),
        sky_weight=0.6,
    )


_NAMED_SUN = {
    "sun-morning": (100.0, 18.0),
    "sun-noon": (180.0, 58.0),
    "sun-evening": (262.0, 12.0),
    "sun-winter-noon": (180.0, 26.0),
    "sun-afternoon": (225.0, 38.0),
}


def list_lighting_presets() -> list[tuple[str, str]]:
    """``(name, description)`` of every preset (parametrised ones with an example)."""
    out = [
        ("front", "point light at the lens (ring light / flash), weak ambient"),
        ("led:3", "LED on a 0.6 m arm at a clock position 1-12 around the optical axis (rACR §5.2.2); led:H,r=0.5"),
        ("sun:az=120,el=35", "sun from azimuth/elevation in degrees (azimuth from +y towards +x) plus sky light"),
        ("sun:day=172,hour=9.5,lat=40", "sun for a day of year, local solar hour and latitude"),
    ]
    out += [(k, f"sun at azimuth {a:.0f} deg, elevation {e:.0f} deg") for k, (a, e) in _NAMED_SUN.items()]
    out += [
        ("overcast", "diffuse sky light, no hard shadows"),
        ("night", "artificial light only: the scene's warm lamp, raking, very low ambient"),
        ("ambient", "uniform ambient light only (albedo), no shading"),
        (DARK, "no light but the rig's lamps (a closed room); the world of a lamp preset"),
    ]
    return out


def _parse_kv(text: str) -> dict[str, float]:
    out = {}
    for item in text.split(","):
        if not item.strip():
            continue
        if "=" not in item:
            raise ValueError(f"expected key=value in {text!r}")
        k, v = item.split("=", 1)
        out[k.strip()] = float(v)
    return out


def lighting_preset(name: str) -> Lighting:
    """The :class:`Lighting` for a preset name (see the module docstring)."""
    key = name.strip().lower()
    if key == "front":
        return Lighting(
            name="front",
            lights=(Light(kind="point", frame="camera", position=(0.0, -0.04, 0.0), intensity=1.0),),
            ambient=0.08,
        )
    if key.startswith("led:"):
        parts = key[4:].split(",", 1)
        try:
            hour = int(parts[0])
            opts = _parse_kv(parts[1]) if len(parts) > 1 else {}
        except ValueError as exc:
            raise ValueError(f"bad LED preset {name!r}: use led:H or led:H,r=0.3 with H in 1..12") from exc
        if not 1 <= hour <= 12:
            raise ValueError(f"LED clock position must be 1..12, got {hour}")
        r = opts.get("r", 0.60)
        a = math.radians(30.0 * hour)
        # camera frame: x right, y down; 12 o'clock is up (-y), 3 o'clock is right (+x)
        pos = (r * math.sin(a), -r * math.cos(a), 0.0)
        return Lighting(
            name=f"led:{hour}" + (f",r={r:g}" if "r" in opts else ""),
            lights=(Light(kind="point", frame="camera", position=pos, intensity=1.0, colour=(0.95, 0.98, 1.0)),),
            ambient=0.05,
        )
    if key.startswith("sun:"):
        kv = _parse_kv(key[4:])
        if "az" in kv and "el" in kv:
            return _sun(name, kv["az"], kv["el"])
        if "day" in kv and "hour" in kv:
            az, el = solar_az_el(kv["day"], kv["hour"], kv.get("lat", 40.0))
            return _sun(name, az, el)
        raise ValueError(f"bad sun preset {name!r}: use sun:az=A,el=E or sun:day=D,hour=H[,lat=L]")
    if key in _NAMED_SUN:
        return _sun(key, *_NAMED_SUN[key])
    if key == "overcast":
        return Lighting(
            name="overcast",
            lights=(
                Light(
                    kind="directional", frame="world", direction=(0.0, -0.3, 0.95), intensity=0.25, cast_shadows=False
                ),
            ),
            ambient=0.75,
            ambient_colour=(0.95, 0.97, 1.0),
            sky_weight=0.8,
        )
    if key == "night":
        return Lighting(
            name="night",
            lights=(Light(kind="point", frame="scene", intensity=0.8, colour=(1.0, 0.72, 0.42)),),
            ambient=0.01,
            ambient_colour=(0.6, 0.7, 1.0),
        )
    if key == "ambient":
        return Lighting(name="ambient", lights=(), ambient=1.0)
    if key == DARK:
        return Lighting(name=DARK, lights=(), ambient=0.0)
    known = ", ".join(n for n, _ in list_lighting_presets())
    raise ValueError(f"unknown lighting {name!r}; known: {known}")


def is_rig_lamp(lighting: Lighting) -> bool:
    """True when every light of ``lighting`` rides on the camera: a lamp a rig carries and switches.

    Rule (docs/simulator.md, "Lights a rig carries"): a rig switches only what it
    carries; the sun, the sky, the night's lamp and the room are the world's.
    """
    return bool(lighting.lights) and all(light.frame == "camera" for light in lighting.lights)


def compose(world: Lighting, lamp: Lighting | None) -> Lighting:
    """The light on the object: the world's light plus one rig lamp (None: every lamp off).

    Irradiance adds: the lights are the union and the ambient terms sum (a lamp's
    own ambient is its spill off the surroundings); the ambient colour and the sky
    weighting are the ambient-weighted means. A dark world under a lamp is the
    lamp's preset unchanged, so indoor renders stay what they were.

    Parameters
    ----------
    world : Lighting
        The world's light (not a rig lamp).
    lamp : Lighting or None
        The rig lamp switched on.
    """
    if lamp is None:
        return world
    if not world.lights and world.ambient == 0.0:
        return lamp
    total = world.ambient + lamp.ambient
    w_world = world.ambient / total if total > 0 else 0.5
    w_lamp = 1.0 - w_world
    colour = tuple(w_world * a + w_lamp * b for a, b in zip(world.ambient_colour, lamp.ambient_colour))
    return Lighting(
        name=f"{world.name}+{lamp.name}",
        lights=world.lights + lamp.lights,
        ambient=total,
        ambient_colour=colour,
        sky_weight=w_world * world.sky_weight + w_lamp * lamp.sky_weight,
    )
