"""The Table 1 protocol on simulated counterparts of the real photographs.

For each kind of real scene, simulated scenes of that kind are rendered as
the real ones were taken: FGCD kinds as two observations (the revisit's
camera moved by :data:`REVISIT_OFFSET`) under an environment light and six
side lights (:data:`FGCD_LIGHTINGS`); the multi-light kind from one fixed
camera under the 12 directions of ``multilight/lights.txt``, the revisit
resampled by the same known motion as the real images. Stills as the
simulated camera takes them: supersampled, auto-exposed, with sensor noise.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from fgcd_cli.bench.lighting.cross_light import same_lighting_consensus, score_pairs
from fgcd_cli.bench.lighting.photographs import MULTILIGHT_KIND, failed_counts, frontal_light, known_motion, resampled
from fgcd_core.se3 import exp_se3
from fgcd_drivers.sim.appearance import Appearance
from fgcd_drivers.sim.camera import DEFAULT_EFFECTS, DEFAULT_INTRINSICS, STILL_SUPERSAMPLE
from fgcd_drivers.sim.lights import Light, Lighting
from fgcd_drivers.sim.render import Renderer
from fgcd_drivers.sim.scenes import load_scene

__all__ = [
    "FGCD_LIGHTINGS",
    "REVISIT_OFFSET",
    "SIM_SCENES",
    "multilight_lightings",
    "sim_fgcd_rows",
    "sim_multilight_rows",
]

#: Simulated scenes standing for each real kind (the first one is the quick run's).
SIM_SCENES = {
    "test_block": ("test_block", "mural"),
    "outdoor_relief": ("rock_niche", "relief_panel"),
    "statue": ("statue",),
    MULTILIGHT_KIND: ("statue", "grey_sphere"),
}
#: An FGCD observation's lightings: the environment light first, then six side lights around the lens.
FGCD_LIGHTINGS = ("front", "led:2", "led:4", "led:6", "led:8", "led:10", "led:12")
#: The revisit camera's offset from the reference: 2 mm along a fixed direction, 0.1 deg about a fixed axis
#: (a camera set up again by hand or a relocation's last residual).
REVISIT_OFFSET = (2.0, 0.1)


def _offset_pose(T_world_cam: np.ndarray, mm: float, deg: float) -> np.ndarray:
    d = np.array([1.0, 0.5, 0.3]) / np.linalg.norm([1.0, 0.5, 0.3])
    a = np.array([0.2, 1.0, 0.4]) / np.linalg.norm([0.2, 1.0, 0.4])
    return T_world_cam @ exp_se3(np.r_[d * mm / 1000.0, a * math.radians(deg)])


def _still(renderer: Renderer, T_world_cam: np.ndarray, lighting, rng: np.random.Generator) -> np.ndarray:
    """A simulated still as the camera takes it (auto exposure, noise, gamma), uint8 grey."""
    res = renderer.render(T_world_cam, DEFAULT_INTRINSICS, lighting, effects=DEFAULT_EFFECTS, rng=rng, want=("gray",))
    return np.clip(np.round(np.asarray(res.gray) * 255.0), 0, 255).astype(np.uint8)


def sim_fgcd_rows(kind: str, scene_name: str, *, appearance: Appearance | None = None, say: Callable = print) -> dict:
    """Cross-lighting rows of one simulated scene taken as an FGCD group (same keys as the real rows)."""
    scene = load_scene(scene_name)
    renderer = Renderer(scene, supersample=STILL_SUPERSAMPLE, appearance=appearance)
    rng = np.random.default_rng(0)
    T_ref = scene.default_T_world_cam
    T_cur = _offset_pose(T_ref, *REVISIT_OFFSET)
    ref = [_still(renderer, T_ref, name, rng) for name in FGCD_LIGHTINGS]
    cur = [_still(renderer, T_cur, name, rng) for name in FGCD_LIGHTINGS]
    H_c, spread, reason = same_lighting_consensus(ref, cur)
    if H_c is None:
        return {"rows": [], "reason": reason}
    pairs = [(f"{FGCD_LIGHTINGS[0]}/{FGCD_LIGHTINGS[k]}", ref[0], cur[k]) for k in range(1, len(FGCD_LIGHTINGS))]
    rows = score_pairs(kind, scene_name, pairs, H_c)
    say(f"sim {kind} {scene_name}: same-lighting spread {spread:.2f} px, {failed_counts(rows)}")
    return {"rows": rows, "same_light_spread_px": spread}


def multilight_lightings(directions: np.ndarray, T_world_cam: np.ndarray) -> list[Lighting]:
    """The multi-light set's lights as simulated directional lights fixed to the camera.

    ``lights.txt`` gives directions toward each light with x right, y up and z
    toward the viewer; the OpenCV camera frame has y down and z into the scene,
    so the direction is ``(x, -y, -z)`` there, then turned into the world.

    Parameters
    ----------
    directions : (N, 3) ndarray
    T_world_cam : (4, 4) ndarray
    """
    out = []
    for i, (x, y, z) in enumerate(directions):
        d_world = T_world_cam[:3, :3] @ np.array([x, -y, -z], dtype=float)
        light = Light(kind="directional", frame="world", direction=tuple(d_world / np.linalg.norm(d_world)))
        out.append(Lighting(name=f"multilight:{i}", lights=(light,), ambient=0.02))
    return out


def sim_multilight_rows(
    scene_name: str, directions: np.ndarray, *, appearance: Appearance | None = None, say: Callable = print
) -> dict:
    """Cross-lighting rows of one simulated scene under the multi-light set's directions (fixed camera)."""
    scene = load_scene(scene_name)
    renderer = Renderer(scene, supersample=STILL_SUPERSAMPLE, appearance=appearance)
    rng = np.random.default_rng(0)
    T = scene.default_T_world_cam
    images = [_still(renderer, T, lighting, rng) for lighting in multilight_lightings(directions, T)]
    H_known = known_motion(images[0].shape[:2])
    ref_index = frontal_light(directions)
    reference = images[ref_index]
    pairs = [
        (f"light-{ref_index:02d}/light-{i:02d}", reference, resampled(image, H_known))
        for i, image in enumerate(images)
        if i != ref_index
    ]
    rows = score_pairs(MULTILIGHT_KIND, scene_name, pairs, H_known)
    say(f"sim {MULTILIGHT_KIND} {scene_name}: {failed_counts(rows)}")
    return {"rows": rows}
