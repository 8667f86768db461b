"""app/relocate.py: a revisit, from its session to the visit it writes."""

from contextlib import nullcontext
from types import SimpleNamespace

import numpy as np
import pytest

from fgcd_cli.errors import run_record


class _InterruptedWriter:
    """An observation writer whose first image write is interrupted (Ctrl-C)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def add_image(self, name, img):
        raise KeyboardInterrupt


def _stand_in_session(monkeypatch, capture_uc, grabbed: list):
    """The VSE session, the alignments and the rACR loop replaced by stand-ins; the loop grabs one image to
    measure. Returns the loop's result."""
    import fgcd_cli.alignment.initial as alignment_initial
    import fgcd_cli.alignment.reference as alignment_reference
    from fgcd_cli.relocation.session import ScaleEstimate

    class Cloud:
        points = np.zeros((10, 3))
        intensities = np.ones(10)

        def __len__(self):
            return 10

    state = SimpleNamespace(status="tracking", T_map_cam=np.eye(4), cloud=Cloud())
    session = SimpleNamespace(tracking_state=lambda: state, settle=lambda **k: state)
    scale = ScaleEstimate(scale=1.0, scale_std=0.0, n_samples=3, residual_rms_mm=0.0, method="test")
    reference = SimpleNamespace(points=np.zeros((10, 3)), intensities=np.ones(10), T_ref_camref=np.eye(4))
    result = SimpleNamespace(
        converged=True,
        reason="ok",
        adjustments=1,
        wall_s=1.0,
        session_s=1.0,
        platform_s=1.0,
        synthetic_s=0.0,
        records=[],
        residual=None,
    )
    held = SimpleNamespace(stop=lambda: None, held=nullcontext)

    def loop(ctx):
        grabbed.append((ctx.grab_current(), sorted(ctx.reference_images)))
        return result

    monkeypatch.setattr(capture_uc, "load_reference", lambda station: reference)
    monkeypatch.setattr(alignment_reference, "ReferenceIndex", lambda *a, **k: None)
    monkeypatch.setattr(
        alignment_initial, "initial_guess", lambda **k: SimpleNamespace(T_ref_cur=np.eye(4), source="test", fast=None)
    )
    monkeypatch.setattr(
        capture_uc, "start_revisit_session", lambda rig, station, reference, **k: (session, held, scale, None)
    )
    monkeypatch.setattr(capture_uc, "relocate", loop)
    return result


def test_the_visit_is_named_not_written_when_ctrl_c_comes_while_writing(monkeypatch):
    import fgcd_cli.app.relocate as capture_uc

    result = _stand_in_session(monkeypatch, capture_uc, [])
    monkeypatch.setattr(capture_uc, "relocate", lambda ctx: result)  # this rig has no camera to measure with
    monkeypatch.setattr(capture_uc, "reference_images", lambda station: {})
    monkeypatch.setattr(capture_uc, "grab_images", lambda rig, lightings: {"front": np.zeros((4, 4), np.float32)})

    from fgcd_cli.relocation.config import RelocationConfig

    station = SimpleNamespace(name="north-wall", new_visit=lambda meta: _InterruptedWriter())
    rig = capture_uc.RigHandles(
        guard=SimpleNamespace(platform=SimpleNamespace(flange_pose=lambda: np.eye(4))),
        camera_source=None,
        intrinsics=SimpleNamespace(to_dict=lambda: {}),
        T_flange_cam=np.eye(4),
        vse_factory=lambda: None,
    )
    run_record.reset()
    with pytest.raises(KeyboardInterrupt):
        capture_uc.relocate_and_capture(
            rig,
            station,
            capture_uc.RelocateRequest(config=RelocationConfig(mode="parallel"), lightings=["front"], coarse=None),
        )
    assert run_record.writes_clause() == "not written: the visit of station 'north-wall'"
    run_record.reset()


def _revisit_on_the_simulated_rig(tmp_path, monkeypatch, reference_light: str, visit_light: str, **reference_metadata):
    """A reference imaged on the simulated rig under ``reference_light``; a revisit under ``visit_light``.

    Returns the visit, the rig's progress lines and the image the image stage measured (with the
    reference images it compared against)."""
    import fgcd_cli.app.relocate as capture_uc
    from fgcd_cli.app.relocate_request import RelocateRequest
    from fgcd_cli.app.rig import open_sim_rig
    from fgcd_cli.app.scenario import SimScenario
    from fgcd_cli.app.session import grab_images, rig_lightings, visit_lightings
    from fgcd_cli.campaign.store import init_campaign
    from fgcd_cli.relocation.config import RelocationConfig

    camp = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim"})
    station = camp.create_station("s")
    rig = open_sim_rig(SimScenario(scene="stele", lighting=reference_light), T_flange_cam=None, intrinsics=None)
    try:
        images = grab_images(rig.handles, [reference_light], average=1)
    finally:
        rig.close()
    with station.write_reference({"lightings": [reference_light], **reference_metadata}) as w:
        for name, img in images.items():
            w.add_image(name, img)
        w.commit()
    grabbed: list = []
    _stand_in_session(monkeypatch, capture_uc, grabbed)
    said: list[str] = []
    rig = open_sim_rig(
        SimScenario(scene="stele", lighting=visit_light), T_flange_cam=None, intrinsics=None, on_event=said.append
    )
    try:
        lightings = visit_lightings(visit_light, [reference_light], available=rig_lightings(rig.handles))
        capture_uc.relocate_and_capture(
            rig.handles,
            station,
            RelocateRequest(config=RelocationConfig(), lightings=lightings, coarse=None),
        )
        lights_after = rig.handles.lights.lighting
    finally:
        rig.close()
    return station.visits()[-1], said, grabbed, lights_after


@pytest.mark.parametrize(("reference_light", "visit_light"), [("sun-morning", "sun-evening"), ("sun-noon", "night")])
def test_an_outdoor_or_night_revisit_never_measures_under_a_light_the_rig_does_not_carry(
    tmp_path, monkeypatch, reference_light, visit_light
):
    from fgcd_drivers.sim.lights import lighting_preset

    visit, said, grabbed, lit = _revisit_on_the_simulated_rig(tmp_path, monkeypatch, reference_light, visit_light)
    stage = visit.metadata["relocation"]["image_stage"]
    assert stage == {"measured_under": "the day's light", "compared_with": [reference_light]}
    assert not any("measures under the reference's light" in line for line in said), said
    assert any("measures across lightings" in line for line in said), said
    assert visit.image_names() == [visit_light]  # the reference day's light is not retaken
    assert lit == lighting_preset(visit_light)  # the world kept its own light throughout
    ((image, compared),) = grabbed
    assert compared == [reference_light] and image.shape == (480, 640)


def test_an_indoor_revisit_measures_under_the_rigs_own_lamp(tmp_path, monkeypatch):
    visit, said, grabbed, _ = _revisit_on_the_simulated_rig(tmp_path, monkeypatch, "front", "led:3")
    assert visit.metadata["relocation"]["image_stage"] == {"measured_under": "front", "compared_with": ["front"]}
    assert any("measures under the reference's light (front)" in line for line in said), said
    assert sorted(visit.image_names()) == ["front", "led:3"]
    ((image, compared),) = grabbed
    assert compared == ["front"]


def test_a_sunny_revisit_of_a_dark_reference_measures_on_the_lamp_alone(tmp_path, monkeypatch):
    # the reference: a dark room lit by LED 3 (its capture measured the lamp's share: all of the light)
    visit, said, grabbed, _ = _revisit_on_the_simulated_rig(
        tmp_path, monkeypatch, "led:3", "sun-evening", lamp_share=1.0
    )
    stage = visit.metadata["relocation"]["image_stage"]
    assert stage == {"measured_under": "flash:led:3", "compared_with": ["flash:led:3"]}
    assert any("world was dark" in line and "flash:led:3" in line for line in said), said
    # the visit keeps the lamp-alone image for the change map, beside the day's and the lamp's with the day
    assert sorted(visit.image_names()) == ["flash:led:3", "led:3", "sun-evening"]
    ((image, compared),) = grabbed
    assert compared == ["flash:led:3"] and image.shape == (480, 640)
