"""Lights for real rigs: the GRBL outputs (pins the emulator drives), the serial controller, the manual prompt,
and real light drivers wired to the simulated scene."""

from __future__ import annotations

import numpy as np
import pytest

from fgcd_drivers.connect import open_lights
from fgcd_drivers.grbl.config import GrblConfig
from fgcd_drivers.grbl.platform import GrblPlatform
from fgcd_drivers.lights import AMBIENT, LightsDriver, LightsError, LightsSpec, ManualLights
from fgcd_drivers.lights_grbl import GrblLights
from fgcd_drivers.testing.grbl_emulator import GrblEmulator
from fgcd_drivers.testing.light_controller_emulator import LightControllerEmulator

pytestmark = pytest.mark.timeout(120)

GRBL_CHANNELS = {"led:3": "flood", "led:9": "mist", "led:6": "spindle:250"}


@pytest.fixture
def emulator():
    emu = GrblEmulator(time_scale=0.05)
    try:
        yield emu
    finally:
        emu.close()


@pytest.fixture
def board(emulator):
    platform = GrblPlatform(
        GrblConfig(port=emulator.port, answer_timeout_s=0.8, banner_timeout_s=0.8, open_banner_wait_s=0.05)
    )
    platform.connect()
    try:
        yield platform
    finally:
        platform.close()


@pytest.mark.parametrize(
    "lighting, pins",
    [
        ("led:3", {"spindle": False, "spindle_pwm": 0.0, "flood": True, "mist": False}),
        ("led:9", {"spindle": False, "spindle_pwm": 0.0, "flood": False, "mist": True}),
        # spindle:250 with $30 = 1000: a quarter PWM duty
        ("led:6", {"spindle": True, "spindle_pwm": 0.25, "flood": False, "mist": False}),
        (AMBIENT, {"spindle": False, "spindle_pwm": 0.0, "flood": False, "mist": False}),
    ],
)
def test_grbl_lights_drive_exactly_one_output(board, emulator, lighting, pins):
    lights = GrblLights(board, GRBL_CHANNELS)
    lights.set("led:9")  # another light on first: switching must turn it off
    lights.set(lighting)
    assert emulator.outputs() == pins
    assert lights.current == lighting and lights.reported_lighting() == lighting


def test_grbl_lights_switch_only_after_the_queued_motion(board, emulator):
    """M-codes are synchronised with the planner: the light comes on once the stage has arrived."""
    start = board.flange_pose()
    target = start.copy()
    target[0, 3] += 0.004
    board.send_line(f"G1 X{target[0, 3] * 1000:.3f} F600")
    GrblLights(board, GRBL_CHANNELS).set("led:3")
    assert emulator.state == "Idle" and emulator.outputs()["flood"]
    np.testing.assert_allclose(emulator.position()[0], target[0, 3] * 1000, atol=1e-6)


def test_grbl_lights_refuse_unknown_names_and_shared_outputs(board):
    with pytest.raises(LightsError, match="no light 'led:12'"):
        GrblLights(board, GRBL_CHANNELS).set("led:12")
    with pytest.raises(LightsError, match="same output"):
        GrblLights(board, {"led:3": "flood", "led:6": "flood"})
    with pytest.raises(LightsError, match="unknown GRBL light output"):
        GrblLights(board, {"led:3": "laser"})


def test_grbl_alarm_switches_the_lights_off_and_is_reported(board, emulator):
    lights = GrblLights(board, GRBL_CHANNELS)
    lights.set("led:3")
    emulator.inject_alarm(1)
    assert not emulator.outputs()["flood"]
    with pytest.raises(LightsError, match="ALARM:1"):
        lights.set("led:9")


def test_grbl_lights_share_the_stage_connection_or_open_their_own(board, emulator):
    shared = open_lights(
        LightsSpec(driver=LightsDriver.GRBL, port=emulator.port, channels=GRBL_CHANNELS), platform=board
    )
    assert shared._platform is board
    shared.set("led:3")
    assert emulator.outputs()["flood"]


def test_serial_controller_relays_follow_the_lightings():
    with LightControllerEmulator(n_relays=4) as emu:
        lights = open_lights(
            LightsSpec(driver=LightsDriver.SERIAL, port=emu.port, channels={"led:3": "1", "led:6": "2", "led:9": "4"})
        )
        for lighting, relays in (("led:3", {1}), ("led:9", {4}), (AMBIENT, set())):
            lights.set(lighting)
            assert emu.relays_on == relays
        lights.set("led:6")
        emu.set_silent()
        with pytest.raises(LightsError, match="did not answer"):
            lights.set("led:3")
        emu.set_silent(False)
        lights.close()
        assert emu.relays_on == set()


def test_serial_controller_without_the_configured_relay_is_refused_at_open():
    from fgcd_core.platform import PlatformConnectionError

    with LightControllerEmulator(n_relays=2) as emu:
        with pytest.raises(PlatformConnectionError, match="relays 1..2"):
            open_lights(LightsSpec(driver=LightsDriver.SERIAL, port=emu.port, channels={"led:3": "3"}))


def test_manual_lights_ask_once_per_switch_and_refuse_a_no():
    prompts: list[str] = []
    answers = iter(["", "n"])
    lights = ManualLights(["led:3", "led:9"], ask=lambda text: prompts.append(text) or next(answers))
    lights.set("led:3")
    lights.set("led:3")  # already on: not asked again
    assert len(prompts) == 1 and "3 o'clock" in prompts[0]
    with pytest.raises(LightsError, match="not confirmed"):
        lights.set("led:9")
    assert lights.current == "led:3"


def test_manual_lights_without_a_terminal_say_how_to_configure():
    def eof(text):
        raise EOFError

    with pytest.raises(LightsError, match=r"\[rig.lights\]"):
        ManualLights(["led:3"], ask=eof).set("led:3")


def test_lights_spec_from_campaign_config():
    spec = LightsSpec.from_config({"driver": "grbl", "port": "/dev/ttyUSB0", "channels": {"led:3": "flood"}})
    assert spec.driver == LightsDriver.GRBL and spec.channels == {"led:3": "flood"}
    assert LightsSpec.from_config({"driver": "manual", "channels": ["led:3", "led:6"]}).channels == {
        "led:3": "",
        "led:6": "",
    }
    assert LightsSpec.from_config(None) is None
    from fgcd_core.platform import PlatformConnectionError

    with pytest.raises(PlatformConnectionError, match="driver must be one of"):
        LightsSpec.from_config({"driver": "dmx"})


# ----------------------------------------------------------------------------- wired to the simulated scene
def _sim_images(spec, lightings, hooks=None):
    from fgcd_cli.app.rig import RigHooks, RigRequest, open_rig
    from fgcd_cli.app.scenario import SimScenario
    from fgcd_cli.app.session import grab_images

    rig = open_rig(
        RigRequest(driver="sim", scenario=SimScenario(scene="stele", lighting="front"), lights=spec),
        hooks=hooks or RigHooks(),
    )
    try:
        return grab_images(rig.handles, lightings, average=1), rig.handles.lights
    finally:
        rig.close()


def test_grbl_lights_light_the_simulated_scene(emulator):
    """The scene is rendered under the light whose GRBL output the board reports on."""
    spec = LightsSpec(driver=LightsDriver.GRBL, port=emulator.port, channels={"led:3": "flood", "led:9": "mist"})
    images, lights = _sim_images(spec, ["ambient", "led:3", "led:9"])
    assert "M8" in emulator.lines_received and "M7" in emulator.lines_received
    assert emulator.outputs() == {"spindle": False, "spindle_pwm": 0.0, "flood": False, "mist": False}  # closed
    # the 3 o'clock and 9 o'clock LEDs light the relief from opposite sides: the images differ clearly,
    # by more than the sensor noise between two frames under one light (a few 1e-3)
    diff = float(np.mean(np.abs(images["led:3"] - images["led:9"])))
    assert diff > 0.01, diff


def test_manual_lights_light_the_simulated_scene():
    from fgcd_cli.app.rig import RigHooks

    prompts: list[str] = []
    spec = LightsSpec(driver=LightsDriver.MANUAL, channels={"led:3": "", "led:9": ""})
    images, _ = _sim_images(spec, ["led:3", "led:9"], RigHooks(ask_light=lambda t: prompts.append(t) or ""))
    assert len(prompts) == 2 and "3 o'clock" in prompts[0] and "9 o'clock" in prompts[1]
    assert float(np.mean(np.abs(images["led:3"] - images["led:9"]))) > 0.01


# ----------------------------------------------------------------------------- a whole simulated-platform capture
@pytest.mark.slow
@pytest.mark.timeout(900)
@pytest.mark.parametrize("driver", ["grbl", "manual"])
def test_a_simulated_capture_switches_real_lights_end_to_end(tmp_path, emulator, driver):
    """`fgcd capture --light ambient,led:3,led:9` on the simulated platform with GRBL or manual lights."""
    from fgcd_cli.app.capture import CaptureRequest, plan_capture, run_capture
    from fgcd_cli.app.rig import RigHooks
    from fgcd_cli.campaign.store import init_campaign
    from fgcd_drivers.sim.rig import build_sim_rig

    lights = {"driver": driver, "channels": {"led:3": "flood", "led:9": "mist"}}
    if driver == "grbl":
        lights["port"] = emulator.port
    camp = init_campaign(
        tmp_path / "c", site="x", rig={"driver": "sim", "sim": {"scene": "stele", "seed": 0}, "lights": lights}
    )
    # stands in for `fgcd calibrate hand-eye` (tested elsewhere): the simulated rig's mounting
    camp.write_rig(
        "handeye", {"T_flange_cam": build_sim_rig(scene="stele", seed=0).ground_truth.T_flange_cam_true().tolist()}
    )
    prompts: list[str] = []
    plan = plan_capture(camp, CaptureRequest(station="s1", light="ambient,led:3,led:9"))
    outcome = run_capture(camp, plan, hooks=RigHooks(ask_light=lambda t: prompts.append(t) or ""))
    ref = camp.station("s1").reference()
    assert outcome.result.images == ["ambient", "led:3", "led:9"]
    assert set(ref.image_names()) >= {"ambient", "led:3", "led:9"}
    diff = float(np.mean(np.abs(ref.image("led:3").astype(float) - ref.image("led:9").astype(float))))
    assert diff > 0.01 * (255 if ref.image("led:3").dtype == np.uint8 else 1), diff
    if driver == "grbl":
        assert emulator.lines_received.count("M8") == 1 and emulator.lines_received.count("M7") == 1
    else:
        assert len(prompts) == 3 and "off" in prompts[0]
