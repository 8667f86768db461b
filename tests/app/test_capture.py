"""app/capture.py: capturing a station's reference."""

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


def _fake_capture_world(monkeypatch, events: list):
    """A VSE session, a scale and an image grab standing in for the rig (``events`` records their order);
    the rig's handles."""
    import fgcd_cli.app.capture as capture_uc
    from fgcd_cli.relocation.session import ScaleEstimate

    class Cloud:
        points = np.random.default_rng(0).random((1200, 3))
        intensities = np.ones(1200)

        def __len__(self):
            return len(self.points)

    state = SimpleNamespace(status="tracking", T_map_cam=np.eye(4), cloud=Cloud(), keyframes=[])
    session = SimpleNamespace(
        move_to_flange=lambda *a, **k: events.append("return"),
        tracking_state=lambda: state,
        settle=lambda **k: state,
        timing=SimpleNamespace(platform_s=0.0),
    )
    scale = ScaleEstimate(scale=1.0, scale_std=0.0, n_samples=3, residual_rms_mm=0.0, method="test")

    def start_session(rig, **k):
        events.append("explore")
        return session, SimpleNamespace(stop=lambda: None), scale, np.eye(4)

    def grab_images(rig, lightings):
        events.append("images")
        return {"front": np.zeros((4, 4), np.float32)}

    monkeypatch.setattr(capture_uc, "start_session", start_session)
    monkeypatch.setattr(capture_uc, "grab_images", grab_images)
    return capture_uc.RigHandles(
        guard=SimpleNamespace(platform=SimpleNamespace(flange_pose=lambda: np.eye(4))),
        camera_source=None,
        intrinsics=SimpleNamespace(to_dict=lambda: {}),
        T_flange_cam=np.eye(4),
        vse_factory=lambda: None,
    )


def test_the_reference_is_named_not_written_when_ctrl_c_comes_while_writing(monkeypatch):
    import fgcd_cli.app.capture as capture_uc

    rig = _fake_capture_world(monkeypatch, [])
    station = SimpleNamespace(name="north-wall", write_reference=lambda meta: _InterruptedWriter())
    run_record.reset()
    with pytest.raises(KeyboardInterrupt):
        capture_uc.capture_reference(rig, station, lightings=["front"])
    assert run_record.writes_clause() == "not written: the reference of station 'north-wall'"
    run_record.reset()


class _RecordingWriter:
    """An observation writer that keeps what it is given."""

    def __init__(self):
        self.json = {}

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def add_image(self, name, img):
        pass

    def add_cloud(self, points, colors=None):
        pass

    def add_array(self, name, array):
        pass

    def add_json(self, name, data):
        self.json[name] = data

    def commit(self):
        return SimpleNamespace(path="obs")


def test_the_simulator_truth_is_taken_when_the_reference_images_are(monkeypatch):
    """The reference's truth is the camera where its images were taken: after the exploration and the return to
    the reference pose (with the platform's errors), not before (evaluation only)."""
    import fgcd_cli.app.capture as capture_uc
    from fgcd_cli.campaign import schema

    events = []
    rig = _fake_capture_world(monkeypatch, events)
    writer = _RecordingWriter()
    station = SimpleNamespace(name="s", write_reference=lambda meta: writer)
    truth = {"T_world_cam": "where the images were taken"}

    def evaluation():
        events.append("truth")
        return truth

    capture_uc.capture_reference(rig, station, lightings=["front"], evaluation=evaluation)
    assert events == ["explore", "return", "images", "truth"]
    assert writer.json[schema.SIM_TRUTH] is truth
