"""The simulated rig switches only the lamps it carries; the sun, the sky and the night are the world's.

docs/simulator.md, "Lights a rig carries".
"""

import numpy as np
import pytest

from fgcd_core.camera import CameraIntrinsics
from fgcd_drivers.lights import AMBIENT, LightsError
from fgcd_drivers.sim.lights import DARK, compose, is_rig_lamp, lighting_preset
from fgcd_drivers.sim.render import Renderer
from fgcd_drivers.sim.scenes import load_scene
from fgcd_drivers.sim.sensor import CameraEffects
from fgcd_drivers.sim.world import DEFAULT_LAMPS, SimLights


@pytest.mark.parametrize("world", ["sun-morning", "sun-noon", "overcast", "night", "sun:day=80,hour=10"])
def test_no_switch_moves_the_sun_or_turns_night_into_day(world):
    lights = SimLights(world)
    assert lights.current == AMBIENT and lights.world == lighting_preset(world).name
    for other in ("sun-evening", "sun-noon", "overcast", "night", "sun:az=90,el=30"):
        if lighting_preset(other).name == lights.world:
            continue
        with pytest.raises(LightsError, match="world's"):
            lights.set(other)
        assert lights.lighting == lighting_preset(world)  # nothing changed
    # what it lists is only what it can switch: ambient and its lamps
    assert lights.available() == [AMBIENT, *DEFAULT_LAMPS]
    assert all(is_rig_lamp(lighting_preset(n)) for n in lights.available() if n != AMBIENT)


def test_a_lamp_adds_to_the_worlds_light_and_ambient_switches_it_off():
    lights = SimLights("sun-evening")
    lights.set("led:3")
    assert lights.current == "led:3"
    lit = lights.lighting
    sun, led = lighting_preset("sun-evening"), lighting_preset("led:3")
    assert lit.lights == sun.lights + led.lights
    assert lit.ambient == pytest.approx(sun.ambient + led.ambient)
    lights.set(AMBIENT)
    assert lights.current == AMBIENT and lights.lighting == sun
    lights.set("led:3")
    lights.set("sun-evening")  # the day's own name: every lamp off
    assert lights.current == AMBIENT


def test_a_lamp_scenario_is_that_lamp_in_a_dark_world_as_before():
    lights = SimLights("led:9")
    assert lights.world == DARK and lights.current == "led:9"
    assert lights.lighting == lighting_preset("led:9")  # indoor renders are unchanged
    lights.set("front")
    assert lights.lighting == lighting_preset("front")
    lights.set(AMBIENT)
    assert lights.lighting.lights == () and lights.lighting.ambient == 0.0  # a dark room, every lamp off


def test_a_rig_carries_only_the_lamps_it_is_given():
    lights = SimLights("sun-noon", lamps=["front", "led:3"])
    assert lights.available() == [AMBIENT, "front", "led:3"]
    with pytest.raises(LightsError, match="carries no lamp 'led:9'"):
        lights.set("led:9")
    with pytest.raises(LightsError, match="world's light"):
        lights.mount(["front", "sun-noon"])
    lights.set("led:3")
    lights.mount(["front"])  # the lamp switched on is taken off the rig: it is off
    assert lights.current == AMBIENT


def _plane_render(lighting, exposure=0.5):
    """Linear grey (gamma 1, no noise, fixed exposure) of the test plane from its default view."""
    scene = load_scene("plane", seed=0)
    intr = CameraIntrinsics(fx=160.0, fy=160.0, cx=39.5, cy=29.5, width=80, height=60)
    res = Renderer(scene).render(
        scene.default_T_world_cam, intr, lighting, exposure=exposure, effects=CameraEffects(gamma=1.0)
    )
    return np.asarray(res.gray, dtype=np.float64)


def test_irradiance_adds_the_render_of_sun_plus_lamp_is_the_sum_of_the_two():
    """Light is linear: the radiance under the sun with a lamp on is the radiance under each alone.

    A lamp's own ambient (its spill) is rendered with it, so the sum is exact up to
    float32 rounding and the 8-bit-free linear output (gamma 1, fixed exposure, no noise).
    """
    sun, led = lighting_preset("sun-noon"), lighting_preset("led:3")
    both = _plane_render(compose(sun, led))
    parts = _plane_render(sun) + _plane_render(led)
    assert both.max() < 0.99  # nothing clipped, so linearity is testable
    np.testing.assert_allclose(both, parts, atol=2e-3)
    assert np.mean(both) > np.mean(_plane_render(sun)) + 0.01  # the lamp adds light a camera sees
