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


def test_the_reference_is_named_not_written_when_ctrl_c_comes_while_writing(monkeypatch):
    import fgcd_cli.app.capture as capture_uc
    from fgcd_cli.relocation.session import ScaleEstimate

    class Cloud:
        points = np.random.default_rng(0).random((1200, 3))
        intensities = np.ones(1200)

        def __len__(self):
            return len(self.points)

    cloud = Cloud()
    state = SimpleNamespace(status="tracking", T_map_cam=np.eye(4), cloud=cloud, keyframes=[])
    session = SimpleNamespace(
        move_to_flange=lambda *a, **k: 0.0,
        tracking_state=lambda: state,
        settle=lambda **k: state,
        timing=SimpleNamespace(platform_s=0.0),
    )
    scale = ScaleEstimate(scale=1.0, scale_std=0.0, n_samples=3, residual_rms_mm=0.0, method="test")
    monkeypatch.setattr(
        capture_uc, "start_session", lambda rig, **k: (session, SimpleNamespace(stop=lambda: None), scale, np.eye(4))
    )
    monkeypatch.setattr(capture_uc, "grab_images", lambda rig, lightings: {"front": np.zeros((4, 4), np.float32)})

    station = SimpleNamespace(name="north-wall", write_reference=lambda meta: _InterruptedWriter())
    rig = capture_uc.RigHandles(
        guard=SimpleNamespace(platform=SimpleNamespace(flange_pose=lambda: np.eye(4))),
        camera_source=None,
        intrinsics=SimpleNamespace(to_dict=lambda: {}),
        T_flange_cam=np.eye(4),
        vse_factory=lambda: None,
    )
    run_record.reset()
    with pytest.raises(KeyboardInterrupt):
        capture_uc.capture_reference(rig, station, lightings=["front"])
    assert run_record.writes_clause() == "not written: the reference of station 'north-wall'"
    run_record.reset()
