"""Campaign store: round trips, immutability, portable image file names, and the bad input it must survive."""

import json
import os
import stat
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from fgcd_cli.campaign.atomic import sha256_bytes
from fgcd_cli.campaign.codecs import encode_png
from fgcd_cli.campaign.schema import MANIFEST
from fgcd_cli.campaign.store import init_campaign, open_campaign
from fgcd_cli.campaign.verify import verify_campaign
from fgcd_cli.errors import CampaignError, DataIntegrityError, ImmutableDataError, UserInputError


@pytest.fixture
def camp(tmp_path):
    return init_campaign(tmp_path / "camp", site="Stele Forest, Xi'an")


def _write_reference(station, value=7):
    with station.write_reference({"lighting": "front"}) as w:
        w.add_image("front", np.full((12, 16), value, np.uint8))
        w.add_array("T_ref_cam", np.eye(4))
        w.add_cloud(np.random.default_rng(0).normal(size=(30, 3)), colors=np.linspace(0, 1, 30))
        w.add_json("capture.json", {"note": "Référence ✓"})
        return w.commit()


def test_round_trip_reference_and_visits(camp):
    st = camp.create_station("north-face", description="the inscription")
    ref = _write_reference(st)
    assert st.has_reference()
    again = open_campaign(camp.path).station("north-face").reference()
    assert again.image_names() == ["front"]
    assert np.array_equal(again.image("front"), np.full((12, 16), 7, np.uint8))
    assert np.array_equal(again.array("T_ref_cam"), np.eye(4))
    assert again.json("capture.json")["note"] == "Référence ✓"
    assert again.metadata == {"lighting": "front"}
    assert again.array("cloud_points").shape == (30, 3)
    for i in range(2):
        with st.new_visit({"i": i}, stamp=f"2026010{i}T000000000Z") as w:
            w.add_image("cur", np.zeros((4, 4, 3), np.uint8))
            w.commit()
    assert st.visit_names() == ["20260100T000000000Z", "20260101T000000000Z"]
    assert st.visit().metadata == {"i": 1}
    assert verify_campaign(camp).ok
    assert ref.path.name == "reference"


def test_16bit_and_float_images_are_kept(camp):
    st = camp.create_station("s")
    img16 = (np.arange(12 * 16).reshape(12, 16) * 300).astype(np.uint16)
    with st.write_reference() as w:
        w.add_image("a", img16)
        w.add_image("b", np.linspace(0, 1, 20).reshape(4, 5).astype(np.float32))
        w.commit()
    ref = st.reference()
    assert np.array_equal(ref.image("a"), img16)
    assert ref.image("b").dtype == np.uint16 and ref.image("b").max() == 65535


def test_reference_is_immutable(camp):
    st = camp.create_station("s")
    ref = _write_reference(st)
    with pytest.raises(ImmutableDataError):
        st.write_reference()
    with pytest.raises(ImmutableDataError):
        ref.add_derived("changes/x.png", b"123")
    mode = os.stat(ref.path / "images" / "front.png").st_mode & 0o777
    assert mode == 0o444


def test_visit_derived_products_update_manifest(camp):
    st = camp.create_station("s")
    with st.new_visit() as w:
        w.add_image("cur", np.zeros((4, 4), np.uint8))
        visit = w.commit()
    visit.add_derived("changes/regions.json", b"[]")
    visit.add_derived("changes/regions.json", b"[1]")  # recomputed
    assert verify_campaign(camp).ok
    with pytest.raises(ImmutableDataError):
        visit.add_derived("images/cur.png", b"x")
    with pytest.raises(UserInputError):
        visit.add_derived("../escape.txt", b"x")


def test_wrong_checksum_is_named(camp):
    st = camp.create_station("s")
    ref = _write_reference(st)
    target = ref.path / "images" / "front.png"
    os.chmod(target, 0o644)
    data = bytearray(target.read_bytes())
    data[-5] ^= 0xFF
    target.write_bytes(bytes(data))
    report = verify_campaign(camp)
    assert not report.ok
    assert [p.path for p in report.problems if p.severity == "error"] == [str(target)]
    assert report.problems[0].kind == "checksum"


def test_deleted_image_is_named(camp):
    st = camp.create_station("s")
    ref = _write_reference(st)
    target = ref.path / "images" / "front.png"
    target.unlink()
    report = verify_campaign(camp)
    assert [(p.path, p.kind) for p in report.problems] == [(str(target), "missing")]
    with pytest.raises(DataIntegrityError, match="front.png"):
        st.reference().image("front")


def test_damaged_manifest_is_named(camp):
    st = camp.create_station("s")
    ref = _write_reference(st)
    m = ref.path / "manifest.json"
    os.chmod(m, 0o644)
    m.write_text("{ not json")
    report = verify_campaign(camp)
    assert not report.ok and report.problems[0].path == str(m)
    with pytest.raises(DataIntegrityError):
        st.reference()


def test_missing_and_malformed_campaign_toml(tmp_path):
    with pytest.raises(CampaignError, match="not a campaign"):
        open_campaign(tmp_path)
    with pytest.raises(CampaignError, match="no such directory"):
        open_campaign(tmp_path / "nope")
    (tmp_path / "campaign.toml").write_text("[campaign\nsite = ")
    with pytest.raises(CampaignError, match="malformed TOML"):
        open_campaign(tmp_path)
    (tmp_path / "campaign.toml").write_text("[other]\nx = 1\n")
    with pytest.raises(CampaignError, match="format_version"):
        open_campaign(tmp_path)
    (tmp_path / "campaign.toml").write_text("[campaign]\nformat_version = 99\n")
    with pytest.raises(CampaignError, match="not supported"):
        open_campaign(tmp_path)


def test_init_refuses_existing_and_bad_places(tmp_path):
    init_campaign(tmp_path / "c", site="x")
    with pytest.raises(CampaignError, match="already holds"):
        init_campaign(tmp_path / "c", site="x")
    (tmp_path / "file").write_text("x")
    with pytest.raises(UserInputError):
        init_campaign(tmp_path / "file", site="x")
    with pytest.raises(CampaignError):
        init_campaign(tmp_path / "file" / "sub", site="x")  # parent is a file: unwritable
    with pytest.raises(UserInputError):
        init_campaign(tmp_path / "d", site="  ")


def test_unwritable_directory(tmp_path, monkeypatch):
    # Running as root ignores permission bits, so make the OS refuse the write.
    import fgcd_cli.campaign.store as store

    def deny(*a, **k):
        raise PermissionError(13, "Permission denied", str(tmp_path / "ro"))

    monkeypatch.setattr(store, "atomic_write_bytes", deny)
    with pytest.raises(CampaignError, match="permission denied"):
        init_campaign(tmp_path / "ro", site="x")


def test_non_ascii_site_and_station_names(tmp_path):
    camp = init_campaign(tmp_path / "莫高窟", site="敦煌 莫高窟 — Höhle 45")
    camp.create_station("北壁")
    again = open_campaign(tmp_path / "莫高窟")
    assert again.site == "敦煌 莫高窟 — Höhle 45"
    assert again.station_names() == ["北壁"]


def test_invalid_station_names(camp):
    for bad in ["", "a/b", "..", ".hidden"]:
        with pytest.raises(UserInputError):
            camp.create_station(bad)
    with pytest.raises(CampaignError, match="no station"):
        camp.station("ghost")


def test_killed_during_write_leaves_no_valid_half_observation(camp):
    """A process killed while writing a visit leaves only a hidden temp dir."""
    camp.create_station("s")
    script = textwrap.dedent(
        f"""
        import os, signal, numpy as np
        from fgcd_cli.campaign.store import open_campaign
        st = open_campaign({str(camp.path)!r}).station("s")
        w = st.new_visit()
        w.add_image("a", np.zeros((64, 64), np.uint8))
        w.add_bytes("big.bin", os.urandom(1 << 16))
        os.kill(os.getpid(), signal.SIGKILL)  # dies before commit
        """
    )
    proc = subprocess.run([sys.executable, "-c", script], cwd=Path(__file__).parents[2])
    assert proc.returncode == -9
    st = camp.station("s")
    assert st.visit_names() == []
    report = verify_campaign(camp)
    assert report.ok  # nothing valid is damaged...
    assert any(p.kind == "incomplete-write" for p in report.problems)  # ...and the leftover is reported


def test_killed_during_atomic_file_write_keeps_old_content(tmp_path):
    target = tmp_path / "rec.json"
    target.write_text('{"v": 1}')
    script = textwrap.dedent(
        f"""
        import os, signal
        import fgcd_cli.campaign.atomic as atomic
        real_replace = os.replace
        def dying_replace(a, b):
            os.kill(os.getpid(), signal.SIGKILL)
        atomic.os.replace = dying_replace
        atomic.atomic_write_json({str(target)!r}, {{"v": 2}})
        """
    )
    proc = subprocess.run([sys.executable, "-c", script], cwd=Path(__file__).parents[2])
    assert proc.returncode == -9
    assert json.loads(target.read_text()) == {"v": 1}


def test_rig_records_keep_history(camp):
    camp.write_rig("handeye", {"T_flange_cam": np.eye(4).tolist(), "method": "test"})
    camp.write_rig("handeye", {"T_flange_cam": np.eye(4).tolist(), "method": "test2"})
    assert camp.read_rig("handeye")["method"] == "test2"
    assert len(list((camp.path / "rig" / "history").glob("handeye-*.json"))) == 2
    assert camp.read_rig("intrinsics") is None


def test_malformed_manifest_entries_are_named_not_crashing(camp):
    st = camp.create_station("s")
    with st.new_visit(stamp="20260101T000000000Z") as w:
        w.add_image("cur", np.zeros((4, 4), np.uint8))
        visit = w.commit()
    m = visit.path / "manifest.json"
    manifest = json.loads(m.read_text())
    manifest["files"]["images/cur.png"] = 3  # not a {"sha256", "bytes"} entry
    manifest["files"]["../../../campaign.toml"] = {"sha256": "0" * 64, "bytes": 1}
    m.write_text(json.dumps(manifest))
    report = verify_campaign(camp)
    errors = [(p.path, p.kind) for p in report.problems if p.severity == "error"]
    assert errors == [(str(m), "manifest"), (str(m), "manifest")]
    assert "images/cur.png" in report.problems[0].detail and "campaign.toml" in report.problems[1].detail


def test_deleted_observation_directories_are_named(camp):
    st = camp.create_station("s")
    ref = _write_reference(st)
    for i in range(2):
        with st.new_visit(stamp=f"2026010{i}T000000000Z") as w:
            w.add_image("cur", np.zeros((4, 4), np.uint8))
            w.commit()
    assert json.loads((st.path / "station.json").read_text())["observations"] == [
        "reference",
        "visits/20260100T000000000Z",
        "visits/20260101T000000000Z",
    ]
    assert verify_campaign(camp).ok
    os.chmod(ref.path, 0o755)
    for p in ref.path.rglob("*"):
        os.chmod(p, 0o755 if p.is_dir() else 0o644)
    import shutil

    shutil.rmtree(ref.path)
    shutil.rmtree(st.path / "visits" / "20260100T000000000Z")
    report = verify_campaign(camp)
    assert not report.ok
    assert [(p.path, p.kind) for p in report.problems if p.severity == "error"] == [
        (str(st.path / "reference"), "missing"),
        (str(st.path / "visits" / "20260100T000000000Z"), "missing"),
    ]


def _three_visits(st):
    for i in range(3):
        with st.new_visit(stamp=f"2026010{i}T000000000Z") as w:
            w.add_image("cur", np.zeros((4, 4), np.uint8))
            w.commit()


def test_latest_recorded_visit_missing_is_named_never_replaced_by_an_older_one(camp):
    import shutil

    st = camp.create_station("s")
    _write_reference(st)
    _three_visits(st)
    shutil.rmtree(st.path / "visits" / "20260102T000000000Z")
    st = open_campaign(camp.path).station("s")
    assert st.missing_visit_names() == ["20260102T000000000Z"]
    with pytest.raises(
        DataIntegrityError,
        match=r"latest recorded visit 20260102T000000000Z is missing.*"
        r"--visit 20260101T000000000Z",
    ):
        st.visit()
    with pytest.raises(DataIntegrityError, match="recorded in station.json but its folder"):
        st.visit("20260102T000000000Z")
    assert st.visit("20260101T000000000Z").name == "20260101T000000000Z"  # asked for by name: given
    shutil.rmtree(st.path / "visits" / "20260100T000000000Z")  # an older one missing too: the latest present is fine
    (st.path / "station.json").write_text(
        json.dumps(
            {**st.info, "observations": ["reference", "visits/20260100T000000000Z", "visits/20260101T000000000Z"]}
        )
    )
    assert open_campaign(camp.path).station("s").visit().name == "20260101T000000000Z"


def test_verify_names_a_diff_made_with_a_non_physical_scale(camp):
    st = camp.create_station("s")
    _write_reference(st)
    _three_visits(st)
    visit = st.visit()
    for scale, bad in (
        ("0.5 mm per px (given)", False),
        ("-1.0 mm per px (given)", True),
        ("0.0 mm per px (given)", True),
        ("from the reference metric cloud", False),
    ):
        visit.add_derived(
            "changes/regions.json", json.dumps({"regions": [], "metadata": {"metric scale": scale}}).encode()
        )
        report = verify_campaign(camp)
        assert report.ok != bad, scale
        assert [p.kind for p in report.problems] == (["scale"] if bad else [])
    visit.add_derived("changes/regions.json", json.dumps({"metadata": {"scale (mm per px)": float("nan")}}).encode())
    assert [p.path for p in verify_campaign(camp).problems] == [str(visit.path / "changes" / "regions.json")]


def test_index_survives_stale_station_objects(camp):
    a = camp.create_station("s")
    b = open_campaign(camp.path).station("s")  # loaded before a's commit
    _write_reference(a)
    with b.new_visit(stamp="20260101T000000000Z") as w:
        w.add_image("cur", np.zeros((4, 4), np.uint8))
        w.commit()
    assert camp.station("s").indexed_observations() == ["reference", "visits/20260101T000000000Z"]


def test_station_written_before_the_index_still_verifies(camp):
    st = camp.create_station("s")
    _write_reference(st)
    info = json.loads((st.path / "station.json").read_text())
    del info["observations"]
    (st.path / "station.json").write_text(json.dumps(info))
    report = verify_campaign(camp)
    assert report.ok and report.problems == []
    # an observation the index does not know (e.g. killed between rename and index update) is a warning
    st2 = camp.create_station("t")
    _write_reference(st2)
    info = json.loads((st2.path / "station.json").read_text())
    info["observations"] = []
    (st2.path / "station.json").write_text(json.dumps(info))
    report = verify_campaign(camp)
    assert report.ok and [(p.kind, p.severity) for p in report.problems] == [("unindexed", "warning")]


def test_damaged_station_json_is_named_and_other_stations_still_checked(camp):
    bad = camp.create_station("a")
    good = camp.create_station("b")
    ref = _write_reference(good)
    (bad.path / "station.json").write_text("{ broken")
    target = ref.path / "images" / "front.png"
    target.unlink()
    report = verify_campaign(camp)
    assert [(p.path, p.kind) for p in report.problems] == [
        (str(bad.path / "station.json"), "station"),
        (str(target), "missing"),
    ]


def test_edited_rig_record_is_named_and_refused(camp):
    path = camp.write_rig("handeye", {"T_flange_cam": np.eye(4).tolist(), "rmse_mm": 0.25, "note": "Kalibrierung ✓"})
    assert camp.read_rig("handeye")["rmse_mm"] == 0.25  # round trip, checksum key stripped
    assert "record_sha256" not in camp.read_rig("handeye")
    assert verify_campaign(camp).ok
    text = path.read_text().replace("0.25", "0.52")  # still valid JSON, different numbers
    path.write_text(text)
    report = verify_campaign(camp)
    assert [(p.path, p.kind) for p in report.problems if p.severity == "error"] == [(str(path), "checksum")]
    with pytest.raises(DataIntegrityError, match="sha256"):
        camp.read_rig("handeye")


def test_rig_record_without_checksum_is_still_read(camp):
    (camp.path / "rig" / "intrinsics.json").write_text(json.dumps({"fx": 500.0}))
    assert camp.read_rig("intrinsics") == {"fx": 500.0}
    assert verify_campaign(camp).ok


def test_platform_fault_while_writing_a_visit_leaves_the_campaign_consistent(camp):
    # A relocation writes its visit (images, cloud, relocation.jsonl) in one ObservationWriter;
    # a platform fault before commit must leave no visit, no leftover and a clean verify.
    from fgcd_core.platform import SafetyStop

    st = camp.create_station("s")
    _write_reference(st)
    with pytest.raises(SafetyStop):
        with st.new_visit({"driver": "grbl"}) as w:
            w.add_image("cur", np.zeros((4, 4), np.uint8))
            w.add_bytes("relocation.jsonl", b'{"adjustment": 1}\n')
            raise SafetyStop("GRBL ALARM:1 (hard limit triggered)")
    assert st.visit_names() == []
    assert [p.name for p in (st.path / "visits").iterdir()] == []
    report = verify_campaign(camp)
    assert report.ok and report.problems == []
    assert camp.station("s").indexed_observations() == ["reference"]


# ----------------------------------------------------------------------------- image file names, read-only references
#: Characters FAT, exFAT and NTFS refuse in a file name.
NOT_PORTABLE = set('<>:"\\|?*')


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
    manifest = {
        "format_version": 1,
        "kind": "visit",
        "metadata": {"lightings": ["led:3"]},
        "files": {"images/led:3.png": {"sha256": sha256_bytes(data), "bytes": len(data)}},
    }
    (visit / MANIFEST).write_text(json.dumps(manifest))
    old = st.visit()
    assert old.image_names() == ["led:3"]
    assert old.has_image("led:3") and old.image_relpath("led:3") == "images/led:3.png"
    assert np.array_equal(old.image("led:3"), img)
    with pytest.raises(CampaignError, match="no image 'front'"):
        old.image("front")


def test_a_lighting_name_gives_its_portable_file_then_its_old_spelling():
    from fgcd_cli.campaign.schema import image_file_stem, image_relpath_candidates

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
