"""The image stage measures under the reference's own light when the rig can switch to it."""

from types import SimpleNamespace

import numpy as np

from fgcd_cli.app import session as capture_uc


class _Lights:
    def __init__(self, current):
        self.current = current
        self.history = []

    def set(self, name):
        self.history.append(name)
        self.current = name

    @staticmethod
    def available():
        return ["front", "led:3", "ambient"]


class _Vse:
    def __init__(self):
        self.holds = 0

    def held(self):
        vse = self

        class _Ctx:
            def __enter__(self):
                vse.holds += 1

            def __exit__(self, *exc):
                return False

        return _Ctx()


def _rig(lights):
    def grab_still():
        return SimpleNamespace(image=np.full((4, 4), 0.5 if lights is None or lights.current == "front" else 0.2))

    return SimpleNamespace(lights=lights, camera_source=SimpleNamespace(grab_still=grab_still))


def test_lighting_is_the_references_first_switchable_one():
    assert capture_uc.measurement_lighting(_rig(_Lights("led:3")), ["ambient", "front"]) == "front"
    assert capture_uc.measurement_lighting(_rig(_Lights("led:3")), ["sunset"]) is None  # the rig cannot make it
    assert capture_uc.measurement_lighting(_rig(None), ["front"]) is None  # lights not switchable: day's light


def test_image_is_grabbed_under_the_reference_light_with_the_vse_held_and_the_day_light_restored():
    lights, vse = _Lights("led:3"), _Vse()
    image = capture_uc.grab_gray_under(_rig(lights), vse, "front")
    assert np.allclose(image, 0.5)  # grabbed under "front"
    assert lights.history == ["front", "led:3"] and lights.current == "led:3"
    assert vse.holds == 1


def test_no_switch_when_already_under_that_light_or_without_lights():
    lights, vse = _Lights("front"), _Vse()
    capture_uc.grab_gray_under(_rig(lights), vse, "front")
    assert lights.history == [] and vse.holds == 0
    assert np.allclose(capture_uc.grab_gray_under(_rig(None), vse, None), 0.5)


def test_outdoors_the_simulated_rig_never_measures_under_the_reference_days_sun():
    """The reference's sun or night is the world's: no lamp of the rig makes it, so the stage measures across."""
    from fgcd_drivers.sim.world import SimLights

    for reference, today in (("sun-morning", "sun-evening"), ("sun-noon", "night"), ("overcast", "sun-noon")):
        lights = SimLights(today)
        assert capture_uc.measurement_lighting(_rig(lights), [reference]) is None
        # the visit's images: today's light only, the reference's cannot be taken again
        assert capture_uc.visit_lightings(today, [reference], available=lights.available()) == [today]
    # indoors the rig's own lamp makes the reference's light again
    lights = SimLights("led:3")
    assert capture_uc.measurement_lighting(_rig(lights), ["front"]) == "front"
    assert capture_uc.visit_lightings("led:3", ["front"], available=lights.available()) == ["led:3", "front"]


def test_visit_lightings_without_switchable_lights_or_with_a_person_asked():
    assert capture_uc.visit_lightings("day", ["front", "led:3"], available=None) == ["day"]
    # a manual rig that lists no channel: the person is asked for every reference lighting
    assert capture_uc.visit_lightings("day", ["front", "led:3"], available=["ambient"]) == ["day", "front", "led:3"]
    assert capture_uc.visit_lightings("led:3", ["front", "led:3"], available=["ambient", "led:3"]) == ["led:3"]
