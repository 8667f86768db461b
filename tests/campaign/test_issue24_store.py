"""Issue 24 (item 16): portable image file names, old campaigns still read, a read-only reference."""

import json
import os
import stat

import numpy as np
import pytest

from fgcd_cli.campaign import init_campaign, open_campaign, verify_campaign
from fgcd_cli.campaign.atomic import sha256_bytes
from fgcd_cli.campaign.store import MANIFEST, encode_png
from fgcd_cli.errors import CampaignError, UserInputError

#: Characters FAT, exFAT and NTFS refuse in a file name.
NOT_PORTABLE = set('<>:"\\|?*')


@pytest.fixture
def camp(tmp_path):
    return init_campaign(tmp_path / "camp", site="x")


def test_image_files_have_portable_names_and_keep_their_lighting_names(camp):
    st = camp.create_station("s")
    img = np.full((6, 8), 40, np.uint8)
    with st.write_reference({"lightings": ["front", "led:3", "sun:az=120,el=30"]}) as w:
        for name in ("front", "led:3", "sun:az=120,el=30"):
            w.add_image(name, img)
        w.commit()
    ref = open_campaign(camp.path).station("s").reference()
    for rel in ref.files():
        assert not NOT_PORTABLE & set(rel), rel
    assert "images/led-3.png" in ref.files()
    assert ref.image_names() == ["front", "led:3", "sun:az=120,el=30"]
    assert np.array_equal(ref.image("led:3"), img)
    assert ref.has_image("led:3") and ref.image_relpath("led:3") == "images/led-3.png"
    assert verify_campaign(camp).ok


def test_old_campaigns_with_colon_file_names_are_still_read(camp):
    """An observation written before portable names: ``images/led:3.png``, no name mapping."""
    st = camp.create_station("old")
    visit = st.path / "visits" / "20250101T000000000Z"
    (visit / "images").mkdir(parents=True)
    img = np.full((6, 8), 90, np.uint8)
    data = encode_png(img)
    (visit / "images" / "led:3.png").write_bytes(data)
    manifest = {"format_version": 1, "kind": "visit", "metadata": {"lightings": ["led:3"]},
                "files": {"images/led:3.png": {"sha256": sha256_bytes(data), "bytes": len(data)}}}
    (visit / MANIFEST).write_text(json.dumps(manifest))
    old = st.visit()
    assert old.image_names() == ["led:3"]
    assert old.has_image("led:3") and old.image_relpath("led:3") == "images/led:3.png"
    assert np.array_equal(old.image("led:3"), img)
    with pytest.raises(CampaignError, match="no image 'front'"):
        old.image("front")


def test_the_single_helper_lists_both_spellings():
    from fgcd_cli.campaign.store import image_file_stem, image_relpath_candidates

    assert image_file_stem("led:3") == "led-3"
    assert image_relpath_candidates("led:3") == ["images/led-3.png", "images/led:3.png"]
    assert image_relpath_candidates("front") == ["images/front.png"]


def test_two_names_sharing_one_file_are_refused(camp):
    st = camp.create_station("s")
    with st.write_reference() as w:
        w.add_image("led:3", np.zeros((4, 4), np.uint8))
        with pytest.raises(UserInputError, match="share the file"):
            w.add_image("led-3", np.zeros((4, 4), np.uint8))


def test_every_reference_file_and_its_manifest_are_read_only(camp):
    st = camp.create_station("s")
    with st.write_reference() as w:
        w.add_image("led:3", np.zeros((4, 4), np.uint8))
        w.add_array("a", np.eye(4))
        w.commit()
    files = [p for p in st.reference_path.rglob("*") if p.is_file()]
    assert st.reference_path / MANIFEST in files
    for p in files:
        assert not os.stat(p).st_mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH), p
