"""The rig lamp's own image on the simulated rig: the same under two suns, where the day's images are not."""

from contextlib import contextmanager, nullcontext
from types import SimpleNamespace

import numpy as np
import pytest

from fgcd_cli.app.lamp_image import (
    DARK_WORLD_LAMP_SHARE,
    can_flash,
    dark_world,
    flash_name,
    grab_flash,
    lamp_alone_now,
    reference_flash,
)
from fgcd_cli.app.session import measurement_lighting, visit_lightings
from fgcd_core.camera import CameraIntrinsics
from fgcd_core.flash import CAMERA_RESPONSE_GAMMA
from fgcd_drivers.lights import AMBIENT
from fgcd_drivers.sim.rig import SimRigConfig, build_sim_rig

#: A quarter-size camera: the lamp's image does not need the full frame, the test's time does.
SMALL = CameraIntrinsics(fx=300.0, fy=300.0, cx=159.5, cy=119.5, width=320, height=240)


def _rig(light: str):
    sim = build_sim_rig(
        scene="stele",
        config=SimRigConfig(lighting=light, noise="none", intrinsics_error="none", intrinsics_nominal=SMALL),
    )
    said: list[str] = []
    return SimpleNamespace(lights=sim.lights, camera_source=sim.camera, say=said.append, said=said)


@pytest.fixture(scope="module")
def two_suns():
    return _rig("sun-morning"), _rig("sun-evening")


def test_exposure_lock_holds_the_last_stills_exposure(two_suns):
    rig = two_suns[0]
    rig.lights.set("front")
    lit = rig.camera_source.grab_still().exposure
    with rig.camera_source.exposure_locked():
        rig.lights.set(AMBIENT)
        assert rig.camera_source.grab_still().exposure == lit
    # automatic again: the darker scene (lamp off) calls for a longer exposure
    assert rig.camera_source.grab_still().exposure > lit


def test_the_lamps_image_is_the_same_under_two_suns(two_suns):
    morning, evening = two_suns
    lamp = [grab_flash(r) for r in two_suns]
    days = []
    for r in two_suns:
        r.lights.set(AMBIENT)
        days.append(r.camera_source.grab_still().image.astype(np.float64))
    face = lamp[0].image > 0.3  # the stele's face and the ground near it, lit by the lamp
    assert face.mean() > 0.2

    def spread(a, b):
        la, lb = a**CAMERA_RESPONSE_GAMMA, b**CAMERA_RESPONSE_GAMMA
        ratio = la[face] / np.maximum(lb[face], 1e-6)
        return np.median(np.abs(ratio / np.median(ratio) - 1))

    # a noiseless sensor at one pose: the lamp's images agree to float rounding (a response exponent
    # of 1 instead of 2.2 leaves about 10 % of the day in them); the days' images swap their grooves'
    # lit and shaded flanks, tens of % apart
    assert spread(lamp[0].image, lamp[1].image) < 0.02
    assert spread(days[0], days[1]) > 3 * spread(lamp[0].image, lamp[1].image)
    for got in lamp:
        assert 0.1 < got.lamp_share < 0.95
    # the lights are back as they were
    assert morning.lights.current == evening.lights.current == AMBIENT


def test_a_reference_under_the_sun_stores_it_and_a_visit_measures_on_it(two_suns):
    morning, evening = two_suns
    assert can_flash(morning)
    lamp = reference_flash(morning, morning.say)
    ((name, image),) = lamp.images.items()
    assert name == flash_name() and image.shape == (240, 320)
    assert not dark_world(lamp.metadata) and 0.1 < lamp.metadata["lamp_share"] < DARK_WORLD_LAMP_SHARE
    assert any("alone" in line for line in morning.said)
    lightings = visit_lightings("sun-evening", ["sun-morning", name], available=evening.lights.available())
    assert lightings == ["sun-evening", name]
    assert measurement_lighting(evening, ["sun-morning", name]) == name


def test_a_dark_world_keeps_the_lamps_images_as_they_are():
    rig = _rig("led:3")  # a dark room: the LED alone lights the object
    lamp = reference_flash(rig, rig.say)
    assert lamp.images == {} and dark_world(lamp.metadata)
    assert any("lamps alone" in line for line in rig.said)
    assert measurement_lighting(rig, ["led:3"]) == "led:3"
    # a visit in the dark again measures under the lamp as it is
    assert lamp_alone_now(rig, SimpleNamespace(held=nullcontext), lamp.metadata, "led:3", rig.say) is None


def _linear_spread(a, b, where):
    """Median relative deviation of the linear ratio a / b from its median over ``where`` (gain-free)."""
    ratio = a[where] ** CAMERA_RESPONSE_GAMMA / np.maximum(b[where] ** CAMERA_RESPONSE_GAMMA, 1e-6)
    return float(np.median(np.abs(ratio / np.median(ratio) - 1)))


def test_a_dark_references_lamp_image_is_compared_with_the_lamp_alone_under_the_sun(two_suns):
    night = _rig("led:3")  # the reference: a dark world, the LED alone
    metadata = reference_flash(night, night.say).metadata
    reference = night.camera_source.grab_still().image.astype(np.float64)
    evening = two_suns[1]  # the visit: the evening sun, the same LED on the rig
    name = lamp_alone_now(evening, SimpleNamespace(held=nullcontext), metadata, "led:3", evening.say)
    assert name == flash_name("led:3")
    assert "dark" in evening.said[-1] and name in evening.said[-1]
    alone = grab_flash(evening, "led:3").image
    evening.lights.set("led:3")
    with_day = evening.camera_source.grab_still().image.astype(np.float64)
    evening.lights.set(AMBIENT)
    lit = reference > 0.3
    assert lit.mean() > 0.1
    # the lamp alone under the sun is the dark world's image (float rounding); with the sun in it, it is not
    assert _linear_spread(alone, reference, lit) < 0.03
    assert _linear_spread(with_day, reference, lit) > 3 * _linear_spread(alone, reference, lit)
    # a reference under the sun (no share recorded: an old campaign) never switches
    assert lamp_alone_now(evening, SimpleNamespace(held=nullcontext), {}, "led:3") is None


def test_a_campaign_diff_compares_a_dark_reference_with_the_visits_lamp_alone():
    from fgcd_cli.app.diff import _paired_lightings

    def observation(names, **metadata):
        return SimpleNamespace(
            metadata={"lightings": names, **metadata}, has_image=lambda n: n in names, image_names=lambda: names
        )

    dark = observation(["led:3", "led:5"], lamp_share=0.99)
    sunny_visit = observation(["sun-evening", "led:3", "led:5", flash_name("led:3")])
    assert _paired_lightings(dark, sunny_visit) == (["led:3", "led:5"], [flash_name("led:3"), "led:5"])
    from fgcd_cli.app.diff import _pairing_note

    assert "lamp alone" in _pairing_note(*_paired_lightings(dark, sunny_visit))
    # a dark visit holds no lamp-alone image: like with like, as before
    assert _paired_lightings(dark, observation(["led:3", "led:5"])) == (["led:3", "led:5"], ["led:3", "led:5"])


def test_an_undistorting_camera_offers_the_lock_exactly_when_its_camera_does(two_suns):
    from fgcd_cli.vse.undistort import UndistortedSource, Undistorter
    from fgcd_core.camera import PinholeCamera

    undistorter = Undistorter(PinholeCamera(fx=600.0, fy=600.0, cx=319.5, cy=239.5, width=640, height=480))
    wrapped = UndistortedSource(two_suns[0].camera_source, undistorter)
    assert hasattr(wrapped, "exposure_locked")
    assert wrapped.grab_still().exposure is not None
    assert not hasattr(UndistortedSource(SimpleNamespace(grab=None), undistorter), "exposure_locked")


class _DeadLampCamera:
    """A camera whose stills do not change when the lamp switches (a lamp that adds nothing)."""

    def __init__(self):
        self.image = np.random.default_rng(0).uniform(0.2, 0.8, (24, 32)).astype(np.float32)

    def grab_still(self):
        return SimpleNamespace(image=self.image, rgb=None, exposure=1.0)

    @contextmanager
    def exposure_locked(self):
        yield


def test_a_lamp_that_adds_nothing_costs_no_reference_and_no_visit_image():
    from fgcd_cli.app.session import grab_images
    from fgcd_drivers.sim.world import SimLights

    said: list[str] = []
    rig = SimpleNamespace(
        lights=SimLights("sun-noon"), camera_source=_DeadLampCamera(), say=said.append, progress=lambda *a: None
    )
    assert reference_flash(rig, rig.say).images == {}
    assert "adds no light" in said[-1]
    images = grab_images(rig, ["sun-noon", flash_name()])
    assert list(images) == ["sun-noon"]
    assert flash_name() in said[-1]
