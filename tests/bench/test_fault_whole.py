"""Whole-operation faults of ``fgcd bench faults``: phases read from fgcd's stderr, the failing light controller,
and a seeded fault inside a whole revisit (slow)."""

from __future__ import annotations

import signal
import threading

import pytest

from fgcd_cli.bench.faults import whole as fault_whole
from fgcd_cli.bench.faults.failing_lights import FaultyLightController
from fgcd_cli.bench.faults.whole import PhaseTracker, phase_of, resume_mode

#: stderr of a simulated ``fgcd relocate`` off a terminal (progress step lines and the use case's lines).
RELOCATE_STDERR = """\
opening the rig
a new visit
starting the VSE
exploring to initialise the VSE and its scale
exploration 1/6: VSE tracking
exploration 2/6: VSE tracking
initial alignment to the reference
relocating (racr) to the reference of station 'real'
adjustment 1: waiting for an alignment of the current view
adjustment 1: moving
adjustment  1 (3d)  g = 1.23e-02  remaining   12.30 mm  turn 0.50 deg
the image stage measures under the reference's light (led:3)
image stage 1/3: matching the current image with the reference
adjustment  4 (image)  step   0.40 mm  turn 0.02 deg
settling at the reached pose
images under each lighting 1/2
writing the visit
"""


def test_each_phase_is_recognised_from_its_progress_line():
    phases = [phase_of(line) for line in RELOCATE_STDERR.splitlines()]
    seen = [p for i, p in enumerate(phases) if p is not None and p != (phases[:i] or [None])[-1]]
    assert [p for p in dict.fromkeys(seen)] == [
        "exploration",
        "alignment_wait",
        "adjustment_motion",
        "image_stage",
        "stills",
        "writing",
    ]
    assert phase_of("image stage (3D degenerate) 2/6: moving 1.2 mm / 0.05 deg") == "adjustment_motion"
    assert phase_of("opening the rig") is None
    assert phase_of("the image stage measures under the reference's light (led:3)") is None  # said before the loop
    assert phase_of("  still aligning (10 s; latest estimate: none yet)") is None


def test_the_phases_drawn_are_the_operations_and_the_draw_is_seeded():
    draws = {fault_whole._draw("relocate_sigterm", seed)[:2] for seed in range(40)}
    assert {phase for phase, _ in draws} == set(fault_whole.RELOCATE_PHASES)
    assert all(0 <= delay <= fault_whole.PHASE_DELAY_S[phase] for phase, delay in draws)
    assert {fault_whole._draw("capture_sigint", s)[0] for s in range(40)} == set(fault_whole.CAPTURE_PHASES)
    assert fault_whole._draw("relocate_sighup", 7)[:2] == fault_whole._draw("relocate_sighup", 7)[:2]


class _Child:
    """A stand-in for the child process: running until told otherwise."""

    def __init__(self) -> None:
        self.code = None

    def poll(self):
        return self.code


def test_the_tracker_fires_once_inside_the_target_phase():
    fired = threading.Event()
    hits = []
    tracker = PhaseTracker("image_stage", 0.0, lambda proc: (hits.append(tracker.current), fired.set()))
    child = _Child()
    for line in RELOCATE_STDERR.splitlines()[:13]:
        tracker.on_line(line, child)
    assert fired.wait(10)
    tracker.on_line("adjustment  5 (image)  step   0.10 mm", child)
    assert hits == ["image_stage"]
    assert tracker.phases_seen[:3] == ["exploration", "alignment_wait", "adjustment_motion"]


def test_a_target_phase_the_run_skips_is_hit_at_the_next_one():
    hits = []
    fired = threading.Event()
    tracker = PhaseTracker(
        "image_stage", 0.0, lambda proc: (hits.append(tracker.current), fired.set()), order=fault_whole.RELOCATE_PHASES
    )
    for line in ("exploration 1/6: VSE tracking", "adjustment 1: moving 3.0 mm / 0.10 deg", "writing the visit"):
        tracker.on_line(line, _Child())
    assert fired.wait(10) and hits == ["writing"]


def test_an_adjustment_motion_fault_waits_for_the_image_stages_motion():
    hits = []
    fired = threading.Event()
    tracker = PhaseTracker(
        "adjustment_motion",
        0.0,
        lambda proc: (hits.append(tracker.current), fired.set()),
        order=fault_whole.RELOCATE_PHASES,
    )
    tracker.on_line("image stage (3D degenerate) 1/6: matching the current image with 1 reference image(s)", _Child())
    assert not fired.wait(0.3)
    tracker.on_line("image stage (3D degenerate) 1/6: moving 1.2 mm / 0.05 deg", _Child())
    assert fired.wait(10) and hits == ["adjustment_motion"]


def test_the_tracker_does_not_fire_at_a_child_that_has_ended():
    hits = []
    child = _Child()
    tracker = PhaseTracker("exploration", 0.2, lambda proc: hits.append(1))
    tracker.on_line("exploration 1/6: VSE tracking", child)
    child.code = 0
    threading.Event().wait(0.5)
    assert hits == [] and tracker.fired_in is None


def test_the_expected_codes_follow_the_signal_and_the_commit():
    sigterm = signal.SIGTERM
    assert fault_whole._expected(sigterm, {"sent": True, "committed_before": False}, (0, 6)) == (143,)
    assert fault_whole._expected(sigterm, {"sent": True, "committed_before": True}, (0, 6)) == (143, 0, 6)
    assert fault_whole._expected(signal.SIGKILL, {}, (0,)) == (0,)  # the command had ended: no fault


def test_the_resume_says_which():
    assert resume_mode("continuing the interrupted visit after its 2 adjustments\n") == "continued"
    assert resume_mode("the interrupted visit made no adjustment yet: starting over") == "started over"
    assert resume_mode("no interrupted visit of station 'real': starting a new one") == "started over"
    assert resume_mode("a new visit") is None


@pytest.mark.parametrize("mode", ["stuck", "wrong", "refuses", "silent"])
def test_a_failed_light_controller_is_refused_by_the_serial_driver(mode):
    from fgcd_drivers.lights import LightsDriver, LightsError, LightsSpec
    from fgcd_drivers.lights_serial import SerialLights

    with FaultyLightController() as emu:
        lights = SerialLights.open(
            LightsSpec(driver=LightsDriver.SERIAL, port=emu.port, channels={"led:3": "1", "led:9": "2"}), timeout_s=0.3
        )
        try:
            lights.set("led:3")
            assert not emu.showed_fault
            emu.fail(mode)
            with pytest.raises(LightsError):
                lights.set("led:9")
        finally:
            lights.close()
        assert emu.showed_fault  # judged once the driver has closed: its best-effort close does not count


def test_a_light_fault_after_the_last_switch_is_not_shown():
    from fgcd_drivers.lights import LightsDriver, LightsSpec
    from fgcd_drivers.lights_serial import SerialLights

    with FaultyLightController() as emu:
        lights = SerialLights.open(
            LightsSpec(driver=LightsDriver.SERIAL, port=emu.port, channels={"led:3": "1"}), timeout_s=0.3
        )
        lights.set("led:3")
        emu.fail("silent")
        lights.close()  # ignores the silence, as fgcd's rig does when it closes
        assert not emu.showed_fault


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_a_seeded_sigterm_inside_a_revisit_ends_in_one_line_and_resumes(tmp_path):
    # One fault of the bench on a fresh campaign (calibration, the real station's capture, the revisit
    # signalled, then --resume): every check of the bench holds.
    from fgcd_cli.bench.faults.campaign_faults import prepare_campaign

    campaign = prepare_campaign(tmp_path)
    outcome = fault_whole.inject("relocate_sigterm", 3, campaign)
    assert outcome.ok, outcome.to_dict()
    assert outcome.extra["resume"] in ("continued", "started over")
