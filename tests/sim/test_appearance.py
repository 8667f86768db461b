"""The simulated world's appearance (docs/simulator.md, "Appearance"): the specular lobe, the worlds, the camera's
quantisation and compression, each on synthetic ground truth."""

import numpy as np
import pytest

from fgcd_core.camera import CameraIntrinsics
from fgcd_drivers.sim.appearance import WORLD_ENV, WORLDS, Appearance, Specular, ggx_specular, world_appearance
from fgcd_drivers.sim.lights import Light, Lighting
from fgcd_drivers.sim.render import Renderer
from fgcd_drivers.sim.scenes import load_scene
from fgcd_drivers.sim.sensor import CameraEffects, apply_camera_response

LINEAR = CameraEffects(gamma=1.0)


def _unit(v):
    v = np.asarray(v, float)
    return (v / np.linalg.norm(v)).astype(np.float32)


def _lobe_in_plane(light_deg: float, roughness: float) -> tuple[np.ndarray, np.ndarray]:
    """The lobe seen from view angles -80..80 degrees in the plane of the light and the normal."""
    view_deg = np.linspace(-80.0, 80.0, 1601)
    views = np.stack([np.sin(np.radians(view_deg)), np.zeros_like(view_deg), np.cos(np.radians(view_deg))], 1)
    n = np.tile(np.array([0.0, 0.0, 1.0], np.float32), (len(views), 1))
    light = _unit([np.sin(np.radians(light_deg)), 0.0, np.cos(np.radians(light_deg))])
    return view_deg, ggx_specular(n, light, views.astype(np.float32), Specular(f0=0.04, roughness=roughness))


@pytest.mark.parametrize("light_deg", [20.0, 45.0, 60.0])
def test_the_lobe_peaks_at_the_mirror_direction(light_deg):
    view_deg, lobe = _lobe_in_plane(light_deg, 0.2)
    assert view_deg[np.argmax(lobe)] == pytest.approx(-light_deg, abs=0.5)  # mirrored about the normal
    # a rough lobe's peak moves off the mirror direction towards grazing (Fresnel and 1/(n.v) grow there),
    # never towards the normal
    view_deg, rough = _lobe_in_plane(light_deg, 0.5)
    assert view_deg[np.argmax(rough)] < -light_deg


def test_a_rougher_surface_spreads_its_lobe_and_lowers_its_peak():
    view_deg, sharp = _lobe_in_plane(30.0, 0.2)
    _, broad = _lobe_in_plane(30.0, 0.7)

    def width(lobe):  # degrees above half the peak
        return float(np.ptp(view_deg[lobe >= lobe.max() / 2]))

    assert width(broad) > 3 * width(sharp)
    assert broad.max() < sharp.max() / 5


def test_no_lobe_where_the_light_or_the_view_is_behind_the_surface():
    n = np.array([[0.0, 0.0, 1.0]], np.float32)
    spec = Specular(f0=0.04, roughness=0.5)
    assert ggx_specular(n, _unit([0, 0, -1]), _unit([0, 0, 1]), spec)[0] == 0.0
    assert ggx_specular(n, _unit([0, 0, 1]), _unit([0, 0.5, -1]), spec)[0] == 0.0
    assert ggx_specular(n, _unit([0, 0, 1]), _unit([0, 0, 1]), Specular(f0=0.0))[0] == 0.0


def test_a_rendered_highlight_sits_where_the_light_mirrors_into_the_camera():
    # A flat slab lit by one distant light beside the camera: the highlight is where the mirror direction
    # of the light meets the camera, i.e. where the surface normal bisects the light and the view.
    scene = load_scene("plane")
    T = scene.default_T_world_cam  # faces the slab squarely
    intr = CameraIntrinsics(fx=200.0, fy=200.0, cx=79.5, cy=59.5, width=160, height=120)
    to_light_cam = _unit([0.3, 0.0, -1.0])  # from the slab towards the camera, tilted to the camera's +x
    to_light = (T[:3, :3] @ to_light_cam).astype(float)
    lighting = Lighting(
        name="one", lights=(Light(kind="directional", frame="world", direction=tuple(to_light)),), ambient=0.0
    )
    glossy = Renderer(scene, appearance=Appearance(name="g", specular=Specular(f0=0.04, roughness=0.3)))
    matte = Renderer(scene, appearance=Appearance(name="m"))
    a = glossy.render(T, intr, lighting, exposure=0.2, effects=LINEAR, want=("gray",))
    b = matte.render(T, intr, lighting, exposure=0.2, effects=LINEAR, want=("gray",))
    assert a.gray.max() < 1.0  # nothing clipped
    excess = (a.gray - b.gray)[60]  # the row through the principal point
    assert excess.max() > 0
    # the normal (towards the camera, -z_cam) bisects the light and the ray to the pixel at column u:
    # the ray's angle from the axis equals the light's, on the same side (+x)
    theta = np.arctan2(to_light_cam[0], -to_light_cam[2])
    u_expected = intr.cx + intr.fx * np.tan(theta)
    assert np.argmax(excess) == pytest.approx(u_expected, abs=3.0)


def test_worlds_are_chosen_by_name_and_by_the_environment(monkeypatch):
    monkeypatch.delenv(WORLD_ENV, raising=False)
    assert world_appearance().name == "calibrated"
    assert WORLDS["calibrated"].mesostructure.slope_rms > 0 and WORLDS["calibrated"].specular.f0 > 0
    assert WORLDS["smooth"].mesostructure.slope_rms == 0 and WORLDS["smooth"].specular.f0 == 0
    monkeypatch.setenv(WORLD_ENV, "smooth")
    assert world_appearance().name == "smooth"
    assert Renderer(load_scene("plane")).appearance.name == "smooth"
    with pytest.raises(ValueError, match="unknown simulated world 'glossy'"):
        world_appearance("glossy")


def test_an_8_bit_camera_outputs_whole_levels_and_a_jpeg_one_blocks():
    rng = np.random.default_rng(0)
    linear = rng.uniform(0.0, 1.0, (64, 64)).astype(np.float32)
    out = apply_camera_response(linear, exposure=1.0, effects=CameraEffects(gamma=1.0, bit_depth=8))
    levels = out * 255.0
    np.testing.assert_allclose(levels, np.round(levels), atol=1e-4)
    assert np.abs(out - linear).max() <= 0.5 / 255 + 1e-6
    smooth = np.tile(np.linspace(0.2, 0.8, 64, dtype=np.float32), (64, 1))
    noisy = smooth + rng.normal(0, 0.05, smooth.shape).astype(np.float32)
    jpeg = apply_camera_response(noisy, exposure=1.0, effects=CameraEffects(gamma=1.0, jpeg_quality=30))
    # compression drops the fine noise (not the ramp): what stays is closer to the ramp than the input was
    assert np.abs(jpeg - smooth).mean() < 0.8 * np.abs(noisy - smooth).mean()
    np.testing.assert_allclose(jpeg * 255.0, np.round(jpeg * 255.0), atol=1e-4)
