"""The OpenCV device camera refuses an absent or forbidden device in one line (CameraError, exit 7 at the CLI)."""

from __future__ import annotations

import sys

import pytest

from fgcd_drivers.cameras import CameraError, OpenCVCamera


def test_a_device_path_that_does_not_exist_is_named(tmp_path):
    with pytest.raises(CameraError, match=rf"^no camera at {tmp_path / 'video7'}: connect it"):
        OpenCVCamera(str(tmp_path / "video7"))


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="camera indices are /dev/videoN on Linux")
def test_an_index_without_its_device_names_the_device(monkeypatch):
    import fgcd_drivers.cameras as cameras

    monkeypatch.setattr(cameras.os.path, "exists", lambda path: False)
    with pytest.raises(CameraError, match=r"^no camera at /dev/video3 \(camera 3\): connect it, or choose another"):
        OpenCVCamera(3)


def test_a_file_that_is_no_video_cannot_be_opened(tmp_path):
    not_video = tmp_path / "notes.avi"
    not_video.write_text("not a video")
    with pytest.raises(CameraError, match="cannot open camera"):
        OpenCVCamera(str(not_video))
