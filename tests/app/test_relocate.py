"""app/relocate.py: a revisit, from its session to the visit it writes."""

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


def test_the_visit_is_named_not_written_when_ctrl_c_comes_while_writing(monkeypatch):
    import fgcd_cli.alignment.initial as alignment_initial
    import fgcd_cli.alignment.reference as alignment_reference
    import fgcd_cli.app.relocate as capture_uc
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
    monkeypatch.setattr(capture_uc, "load_reference", lambda station: reference)
    monkeypatch.setattr(alignment_reference, "ReferenceIndex", lambda *a, **k: None)
    monkeypatch.setattr(
        alignment_initial, "initial_guess", lambda **k: SimpleNamespace(T_ref_cur=np.eye(4), source="test", fast=None)
    )
    monkeypatch.setattr(
        capture_uc,
        "start_revisit_session",
        lambda rig, station, reference, **k: (session, SimpleNamespace(stop=lambda: None), scale, None),
    )
    monkeypatch.setattr(capture_uc, "relocate", lambda ctx: result)
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
