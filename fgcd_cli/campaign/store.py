"""The campaign store: a site, its stations, their reference observation and visits.

On disk (format version 1)::

    <campaign>/campaign.toml                 site, rig section, format version
    <campaign>/rig/<name>.json               calibration results (+ rig/history/)
    <campaign>/stations/<station>/station.json
    <campaign>/stations/<station>/reference/manifest.json, images/, arrays/, cloud.ply ...
    <campaign>/stations/<station>/visits/<UTC timestamp>/manifest.json, ...

An observation directory is assembled under a hidden temporary name and renamed
into place only once complete and fsynced, with its ``manifest.json`` (sha256 of
every file) written last; a reference observation is immutable once written
(its files are read-only and any second write is refused). Visits accept later
*derived* products (change maps, reports) which are added to the manifest
atomically.

Image files carry portable names (the lighting ``led:3`` is stored as
``images/led-3.png``: FAT, exFAT and NTFS media refuse ``:``) and the
manifest's ``images`` entry maps each name to its file; observations written
before that (``images/led:3.png``, no mapping) are read as they are.
"""

from __future__ import annotations

import io
import json
import os
import re
import shutil
import tomllib
import uuid
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
import tomli_w

from fgcd_cli import __version__
from fgcd_cli.campaign.atomic import (
    TMP_PREFIX,
    atomic_write_bytes,
    atomic_write_json,
    fsync_dir,
    sha256_bytes,
    sha256_file,
)
from fgcd_cli.errors import CampaignError, DataIntegrityError, ImmutableDataError, UserInputError

__all__ = [
    "FORMAT_VERSION",
    "Campaign",
    "Station",
    "Observation",
    "ObservationWriter",
    "init_campaign",
    "open_campaign",
    "utc_stamp",
    "image_file_stem",
    "image_relpath_candidates",
]

FORMAT_VERSION = 1
CAMPAIGN_FILE = "campaign.toml"
MANIFEST = "manifest.json"
_NAME_RE = re.compile(r"^[^/\\\x00]+$")
#: Characters no file name may hold on FAT, exFAT or NTFS (field laptops, SD cards), control characters included.
_NON_PORTABLE = re.compile(r'[<>:"/\\|?*\x00-\x1f]')
IMAGES_KEY = "images"


def utc_stamp(now: datetime | None = None) -> str:
    """A UTC timestamp usable as a directory name, e.g. ``20261122T041503Z``."""
    now = now or datetime.now(timezone.utc)
    return now.astimezone(timezone.utc).strftime("%Y%m%dT%H%M%S") + f"{now.microsecond // 1000:03d}Z"


def _now_iso() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def _check_name(name: str, what: str) -> str:
    name = name.strip()
    if not name or name in (".", "..") or not _NAME_RE.match(name) or name.startswith("."):
        raise UserInputError(f"invalid {what} name {name!r}: use a non-empty name without '/' that does not start with '.'")
    return name


# ----------------------------------------------------------------------------- image file names
def image_file_stem(name: str) -> str:
    """The portable file stem of an image name: ``led:3`` -> ``led-3``.

    Image names are lighting names, which may hold characters a FAT, exFAT or
    NTFS medium refuses (``:``); each such character becomes ``-`` and trailing
    dots and spaces (which Windows drops) are removed. The manifest keeps the
    name -> file mapping, so the name itself is never lost.
    """
    stem = _NON_PORTABLE.sub("-", name).rstrip(". ")
    if not stem or stem.startswith("."):
        raise UserInputError(f"invalid image name {name!r}: it leaves no portable file name")
    return stem


def image_relpath_candidates(name: str) -> list[str]:
    """Where an image of this name may be stored: the portable name, then the name as-is.

    Campaigns written before portable names stored ``images/led:3.png``; the
    second spelling lets them be read. Prefer :meth:`Observation.image_relpath`,
    which also follows the manifest's own name -> file mapping.
    """
    portable = f"images/{image_file_stem(name)}.png"
    legacy = f"images/{name}.png"
    return [portable] if legacy == portable else [portable, legacy]


# ----------------------------------------------------------------------------- encoding helpers
def encode_png(image: np.ndarray) -> bytes:
    """PNG bytes of an 8- or 16-bit grayscale/RGB image (float [0,1] becomes 16-bit)."""
    import cv2

    img = np.asarray(image)
    if img.dtype.kind == "f":
        img = np.clip(np.nan_to_num(img), 0.0, 1.0)
        img = (img * 65535.0 + 0.5).astype(np.uint16)
    elif img.dtype == np.bool_:
        img = img.astype(np.uint8) * 255
    elif img.dtype not in (np.uint8, np.uint16):
        raise UserInputError(f"cannot store an image of dtype {img.dtype}")
    if img.ndim == 3 and img.shape[2] == 3:
        img = img[:, :, ::-1]  # RGB -> BGR for OpenCV
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise CampaignError("PNG encoding failed")
    return buf.tobytes()


def decode_png(data: bytes) -> np.ndarray:
    """Image from PNG bytes, RGB order for colour images, dtype preserved."""
    import cv2

    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise DataIntegrityError("image file cannot be decoded")
    if img.ndim == 3:
        img = img[:, :, ::-1].copy()
    return img


def encode_npy(array: np.ndarray) -> bytes:
    """``.npy`` bytes of an array (no pickles)."""
    buf = io.BytesIO()
    np.save(buf, np.asarray(array), allow_pickle=False)
    return buf.getvalue()


def encode_ply(points: np.ndarray, colors: np.ndarray | None = None, normals: np.ndarray | None = None) -> bytes:
    """Binary little-endian PLY of a point cloud (readable by Open3D, MeshLab, CloudCompare).

    Written with numpy rather than Open3D because Open3D's writer needs a real
    file path and cannot be made atomic; the format is a short header plus a
    packed record array.
    """
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    if normals is not None:
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    if colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    rec = np.empty(len(P), dtype=fields)
    rec["x"], rec["y"], rec["z"] = P[:, 0], P[:, 1], P[:, 2]
    if normals is not None:
        N = np.asarray(normals, dtype=np.float32).reshape(-1, 3)
        rec["nx"], rec["ny"], rec["nz"] = N[:, 0], N[:, 1], N[:, 2]
    if colors is not None:
        C = np.asarray(colors)
        if C.ndim == 1:
            C = np.repeat(C[:, None], 3, axis=1)
        if C.dtype.kind == "f":
            C = np.clip(C * 255.0 + 0.5, 0, 255)
        C = C.astype(np.uint8)
        rec["red"], rec["green"], rec["blue"] = C[:, 0], C[:, 1], C[:, 2]
    type_names = {"<f8": "double", "<f4": "float", "u1": "uchar"}
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(P)}"]
    header += [f"property {type_names[t]} {n}" for n, t in fields]
    header += ["end_header"]
    return ("\n".join(header) + "\n").encode("ascii") + rec.tobytes()


# ----------------------------------------------------------------------------- rig records
RIG_CHECKSUM_KEY = "record_sha256"


def _rig_checksum(record: dict) -> str:
    body = {k: v for k, v in record.items() if k != RIG_CHECKSUM_KEY}
    return sha256_bytes(json.dumps(body, sort_keys=True, ensure_ascii=False, separators=(",", ":")).encode("utf-8"))


def load_rig_record(path: Path) -> dict:
    """Read a rig record and check its embedded checksum (records without one are accepted)."""
    try:
        record = json.loads(Path(path).read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataIntegrityError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(record, dict):
        raise DataIntegrityError(f"{path}: not a rig record (a JSON object)")
    stored = record.pop(RIG_CHECKSUM_KEY, None)
    if stored is not None and stored != _rig_checksum(record):
        raise DataIntegrityError(f"{path}: content does not match its sha256 (edited or damaged)")
    return record


# ----------------------------------------------------------------------------- observation
@dataclass
class Observation:
    """A written observation (a station's reference, or one visit). Read-only view."""

    path: Path
    kind: str  # "reference" or "visit"
    manifest: dict

    @property
    def name(self) -> str:
        """Directory name (``reference`` or the visit's UTC stamp)."""
        return self.path.name

    @property
    def metadata(self) -> dict:
        """Free-form metadata recorded at capture time."""
        return self.manifest.get("metadata", {})

    def files(self) -> dict[str, dict]:
        """Relative path -> ``{"sha256", "bytes"}`` for every listed file."""
        return self.manifest.get("files", {})

    def has(self, relpath: str) -> bool:
        """True if the manifest lists ``relpath``."""
        return relpath in self.files()

    def _read(self, relpath: str) -> bytes:
        if relpath not in self.files():
            raise CampaignError(f"{self.path / relpath}: not part of this observation")
        p = self.path / relpath
        try:
            return p.read_bytes()
        except FileNotFoundError:
            raise DataIntegrityError(f"{p}: missing (run `fgcd campaign verify`)") from None

    def image_files(self) -> dict[str, str]:
        """Image name (a lighting, e.g. ``led:3``) -> its file, relative to the observation.

        The manifest's own mapping when it has one; otherwise (observations
        written before portable file names) every ``images/*.png`` file, named
        by its stem.
        """
        mapping = self.manifest.get(IMAGES_KEY)
        if isinstance(mapping, dict):
            return {str(k): str(v) for k, v in mapping.items() if str(v) in self.files()}
        return {
            k[len("images/") : -len(".png")]: k for k in self.files() if k.startswith("images/") and k.endswith(".png")
        }

    def image_names(self) -> list[str]:
        """Names of the stored images (lighting names, e.g. ``front``, ``led:3``)."""
        return sorted(self.image_files())

    def image_relpath(self, name: str) -> str | None:
        """The file of image ``name`` in either spelling (portable ``led-3.png`` or old ``led:3.png``); None if absent."""
        mapped = self.image_files().get(name)
        if mapped is not None:
            return mapped
        return next((rel for rel in image_relpath_candidates(name) if rel in self.files()), None)

    def has_image(self, name: str) -> bool:
        """True if the observation holds an image of this name (either file spelling)."""
        return self.image_relpath(name) is not None

    def image(self, name: str) -> np.ndarray:
        """A stored image by name (a lighting name, e.g. ``led:3``)."""
        rel = self.image_relpath(name)
        if rel is None:
            known = ", ".join(self.image_names()) or "none"
            raise CampaignError(f"{self.path}: no image '{name}' (images: {known})")
        return decode_png(self._read(rel))

    def array(self, name: str) -> np.ndarray:
        """A stored numpy array by name."""
        return np.load(io.BytesIO(self._read(f"arrays/{name}.npy")), allow_pickle=False)

    def json(self, relpath: str) -> Any:
        """A stored JSON document."""
        return json.loads(self._read(relpath).decode("utf-8"))

    def bytes(self, relpath: str) -> bytes:
        """Raw bytes of a stored file."""
        return self._read(relpath)

    def add_derived(self, relpath: str, data: bytes) -> Path:
        """Add or replace a derived product (visit only): file + manifest, atomically.

        Files written at capture time are never replaced; derived products
        (change maps, reports) may be recomputed.
        """
        if self.kind == "reference":
            raise ImmutableDataError(f"{self.path}: the reference observation is immutable")
        relpath = relpath.replace("\\", "/").lstrip("/")
        if relpath == MANIFEST or ".." in relpath.split("/"):
            raise UserInputError(f"invalid derived file name {relpath!r}")
        entry = self.files().get(relpath)
        if entry is not None and not entry.get("derived", False):
            raise ImmutableDataError(f"{self.path / relpath}: captured data cannot be replaced")
        target = self.path / relpath
        atomic_write_bytes(target, data)
        manifest = dict(self.manifest)
        files = dict(manifest.get("files", {}))
        files[relpath] = {"sha256": sha256_bytes(data), "bytes": len(data), "derived": True}
        manifest["files"] = files
        manifest["updated"] = _now_iso()
        atomic_write_json(self.path / MANIFEST, manifest)
        self.manifest = manifest
        return target


class ObservationWriter:
    """Assembles an observation in a hidden temporary directory, then commits it.

    Use as a context manager; on an exception (or Ctrl-C) nothing is committed
    and the temporary directory is removed.
    """

    def __init__(
        self,
        final_path: Path,
        kind: str,
        metadata: dict | None = None,
        *,
        on_commit: Callable[[Path], None] | None = None,
    ) -> None:
        self.final_path = Path(final_path)
        self.kind = kind
        self._on_commit = on_commit
        self.metadata = dict(metadata or {})
        self.tmp_path = self.final_path.parent / f"{TMP_PREFIX}{self.final_path.name}-{uuid.uuid4().hex[:8]}"
        self.tmp_path.mkdir(parents=True)
        self._files: dict[str, dict] = {}
        self._images: dict[str, str] = {}
        self._committed = False

    def __enter__(self) -> "ObservationWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None or not self._committed:
            self.abort()

    def add_bytes(self, relpath: str, data: bytes) -> None:
        """Add a file with the given bytes."""
        relpath = relpath.replace("\\", "/").lstrip("/")
        if relpath == MANIFEST or ".." in relpath.split("/") or relpath in self._files:
            raise UserInputError(f"invalid or duplicate file name {relpath!r}")
        p = self.tmp_path / relpath
        p.parent.mkdir(parents=True, exist_ok=True)
        with open(p, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        self._files[relpath] = {"sha256": sha256_bytes(data), "bytes": len(data)}

    def add_image(self, name: str, image: np.ndarray) -> None:
        """Add image ``name`` as ``images/<portable name>.png`` (``led:3`` -> ``images/led-3.png``)."""
        name = _check_name(name, "image")
        if name in self._images:
            raise UserInputError(f"duplicate image name {name!r}")
        relpath = f"images/{image_file_stem(name)}.png"
        if relpath in self._files:
            other = next((n for n, rel in self._images.items() if rel == relpath), relpath)
            raise UserInputError(f"image names {other!r} and {name!r} would share the file {relpath}")
        self.add_bytes(relpath, encode_png(image))
        self._images[name] = relpath

    def add_array(self, name: str, array: np.ndarray) -> None:
        """Add ``arrays/<name>.npy``."""
        self.add_bytes(f"arrays/{_check_name(name, 'array')}.npy", encode_npy(array))

    def add_json(self, relpath: str, data: Any) -> None:
        """Add a JSON document."""
        self.add_bytes(relpath, (json.dumps(data, indent=2, ensure_ascii=False) + "\n").encode("utf-8"))

    def add_cloud(
        self,
        points: np.ndarray,
        *,
        colors: np.ndarray | None = None,
        normals: np.ndarray | None = None,
        name: str = "cloud",
    ) -> None:
        """Add ``<name>.ply`` plus exact arrays ``arrays/<name>_points.npy`` etc."""
        self.add_bytes(f"{name}.ply", encode_ply(points, colors, normals))
        self.add_array(f"{name}_points", np.asarray(points, dtype=np.float64))
        if colors is not None:
            self.add_array(f"{name}_colors", np.asarray(colors))
        if normals is not None:
            self.add_array(f"{name}_normals", np.asarray(normals, dtype=np.float32))

    def commit(self) -> Observation:
        """Write the manifest, then move the directory into place atomically."""
        if self._committed:
            raise CampaignError("observation already committed")
        manifest = {
            "format_version": FORMAT_VERSION,
            "kind": self.kind,
            "created": _now_iso(),
            "fgcd_version": __version__,
            "metadata": self.metadata,
            "files": self._files,
        }
        if self._images:
            manifest[IMAGES_KEY] = dict(self._images)
        atomic_write_json(self.tmp_path / MANIFEST, manifest)
        fsync_dir(self.tmp_path)
        if self.final_path.exists():
            self.abort()
            if self.kind == "reference":
                raise ImmutableDataError(
                    f"{self.final_path}: a reference observation already exists and is immutable"
                )
            raise CampaignError(f"{self.final_path} already exists")
        os.rename(self.tmp_path, self.final_path)
        fsync_dir(self.final_path.parent)
        if self.kind == "reference":
            for rel in list(self._files) + [MANIFEST]:
                try:
                    os.chmod(self.final_path / rel, 0o444)
                except OSError:
                    pass
        self._committed = True
        if self._on_commit is not None:
            self._on_commit(self.final_path)
        return Observation(self.final_path, self.kind, manifest)

    def abort(self) -> None:
        """Drop the temporary directory."""
        if self.tmp_path.exists():
            shutil.rmtree(self.tmp_path, ignore_errors=True)


def _load_observation(path: Path, kind: str) -> Observation:
    mpath = path / MANIFEST
    try:
        manifest = json.loads(mpath.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DataIntegrityError(f"{mpath}: manifest missing") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataIntegrityError(f"{mpath}: manifest is not valid JSON ({exc})") from None
    if not isinstance(manifest, dict) or not isinstance(manifest.get("files"), dict):
        raise DataIntegrityError(f"{mpath}: manifest has no file list")
    return Observation(path, kind, manifest)


# ----------------------------------------------------------------------------- station
@dataclass
class Station:
    """A viewpoint of a campaign: one reference observation and its visits."""

    campaign: "Campaign"
    name: str
    path: Path
    info: dict = field(default_factory=dict)

    @property
    def reference_path(self) -> Path:
        """Where the reference observation lives."""
        return self.path / "reference"

    def has_reference(self) -> bool:
        """True once a reference observation was committed."""
        return (self.reference_path / MANIFEST).exists()

    def reference(self) -> Observation:
        """The reference observation (error if none yet)."""
        if not self.reference_path.exists():
            raise CampaignError(f"station '{self.name}' has no reference observation yet (run `fgcd capture`)")
        return _load_observation(self.reference_path, "reference")

    def write_reference(self, metadata: dict | None = None) -> ObservationWriter:
        """Start writing the reference observation; refused if one exists."""
        if self.reference_path.exists():
            raise ImmutableDataError(
                f"station '{self.name}' already has a reference observation; it is immutable "
                "(create a new station to capture another reference)"
            )
        return ObservationWriter(self.reference_path, "reference", metadata, on_commit=self._index)

    def visit_names(self) -> list[str]:
        """Committed visits, oldest first."""
        vdir = self.path / "visits"
        if not vdir.is_dir():
            return []
        return sorted(p.name for p in vdir.iterdir() if p.is_dir() and not p.name.startswith("."))

    def visits(self) -> list[Observation]:
        """Committed visits, oldest first."""
        return [self.visit(n) for n in self.visit_names()]

    def visit(self, name: str | None = None) -> Observation:
        """A visit by name; the latest when ``name`` is None."""
        names = self.visit_names()
        if not names:
            raise CampaignError(f"station '{self.name}' has no visits yet (run `fgcd relocate`)")
        if name is None:
            name = names[-1]
        if name not in names:
            raise CampaignError(f"station '{self.name}' has no visit '{name}' (visits: {', '.join(names)})")
        return _load_observation(self.path / "visits" / name, "visit")

    def new_visit(self, metadata: dict | None = None, *, stamp: str | None = None) -> ObservationWriter:
        """Start writing a new visit named by its UTC time."""
        vdir = self.path / "visits"
        vdir.mkdir(parents=True, exist_ok=True)
        return ObservationWriter(vdir / (stamp or utc_stamp()), "visit", metadata, on_commit=self._index)

    def indexed_observations(self) -> list[str] | None:
        """Observations recorded in ``station.json`` (``reference``, ``visits/<stamp>``).

        ``None`` for a station written before the index existed. ``fgcd campaign
        verify`` uses it to notice a whole observation deleted behind the tool's back.
        """
        index = self.info.get("observations")
        return list(index) if isinstance(index, list) else None

    def _index(self, obs_path: Path) -> None:
        """Record a committed observation in ``station.json`` (atomic rewrite)."""
        rel = obs_path.relative_to(self.path).as_posix()
        sfile = self.path / "station.json"
        try:  # re-read: another Station object may have indexed an observation since
            self.info = json.loads(sfile.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError):
            pass
        index = self.indexed_observations() or []
        if rel not in index:
            index.append(rel)
        self.info = {**self.info, "observations": index}
        atomic_write_json(self.path / "station.json", self.info)


def _read_station_info(sfile: Path) -> dict:
    """The content of a ``station.json`` ({} if absent); DataIntegrityError naming it when damaged."""
    if not sfile.exists():
        return {}
    try:
        info = json.loads(sfile.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataIntegrityError(f"{sfile}: damaged station record, not valid JSON ({exc}); "
                                 "run `fgcd campaign verify`") from None
    except OSError as exc:
        raise DataIntegrityError(f"{sfile}: damaged station record, cannot be read ({exc.strerror or exc})") from None
    if not isinstance(info, dict):
        raise DataIntegrityError(f"{sfile}: damaged station record, not a JSON object; run `fgcd campaign verify`")
    return info


def _remove_unused_station(station: Station) -> None:
    """Remove a station directory that holds nothing but its ``station.json`` and write leftovers."""
    if station.has_reference() or station.visit_names():
        return
    leftovers = {"station.json", "visits", "reference"}
    for entry in station.path.iterdir():
        if entry.name not in leftovers and not entry.name.startswith(TMP_PREFIX):
            return
        if entry.name in ("visits", "reference") and any(
            not p.name.startswith(TMP_PREFIX) for p in entry.iterdir()
        ):
            return
    shutil.rmtree(station.path, ignore_errors=True)
    fsync_dir(station.path.parent)


# ----------------------------------------------------------------------------- campaign
@dataclass
class Campaign:
    """An opened campaign directory."""

    path: Path
    config: dict

    @property
    def site(self) -> str:
        """The site name."""
        return str(self.config.get("campaign", {}).get("site", ""))

    @property
    def rig_config(self) -> dict:
        """The ``[rig]`` section of campaign.toml (driver, port, host, lights...)."""
        return dict(self.config.get("rig", {}))

    # -- stations
    def station_names(self) -> list[str]:
        """Names of the stations, sorted."""
        sdir = self.path / "stations"
        if not sdir.is_dir():
            return []
        return sorted(p.name for p in sdir.iterdir() if p.is_dir() and not p.name.startswith("."))

    def station(self, name: str) -> Station:
        """An existing station; DataIntegrityError when its ``station.json`` is damaged."""
        name = _check_name(name, "station")
        path = self.path / "stations" / name
        if not path.is_dir():
            known = ", ".join(self.station_names()) or "none"
            raise CampaignError(f"campaign has no station '{name}' (stations: {known})")
        return Station(self, name, path, _read_station_info(path / "station.json"))

    def existing_station(self, name: str) -> Station | None:
        """The station if it exists, None if not; DataIntegrityError when it is damaged. Writes nothing."""
        name = _check_name(name, "station")
        path = self.path / "stations" / name
        if path.is_dir():
            return self.station(name)
        if path.exists():
            raise CampaignError(f"{path} exists but is not a station directory")
        return None

    def create_station(self, name: str, *, description: str = "", **info: Any) -> Station:
        """Create a station (error if it exists)."""
        name = _check_name(name, "station")
        path = self.path / "stations" / name
        if path.exists():
            raise CampaignError(f"station '{name}' already exists")
        path.mkdir(parents=True)
        data = {"name": name, "description": description, "created": _now_iso(), **info, "observations": []}
        atomic_write_json(path / "station.json", data)
        return Station(self, name, path, data)

    def station_or_create(self, name: str, **info: Any) -> Station:
        """The station, created if missing.

        A station that exists but cannot be read is reported as damaged
        (DataIntegrityError), never re-created over.
        """
        station = self.existing_station(name)
        return station if station is not None else self.create_station(name, **info)

    @contextmanager
    def station_for_writing(self, name: str, **info: Any) -> Iterator[Station]:
        """The station, created if missing, for a command that may fail.

        Rule: a failed command leaves nothing behind. A station this call
        created is removed again when the block raises (Ctrl-C included),
        provided it still holds no committed observation.
        """
        name = _check_name(name, "station")
        existed = (self.path / "stations" / name).exists()
        station = self.station_or_create(name, **info)
        try:
            yield station
        except BaseException:
            if not existed:
                _remove_unused_station(station)
            raise

    # -- rig calibration records
    def rig_path(self, name: str) -> Path:
        """Path of a rig record, e.g. ``rig/handeye.json``."""
        return self.path / "rig" / f"{_check_name(name, 'rig record')}.json"

    def read_rig(self, name: str) -> dict | None:
        """A rig record (intrinsics, handeye...), or None if absent.

        Raises DataIntegrityError when the record is not valid JSON or no longer
        matches the checksum it was written with.
        """
        p = self.rig_path(name)
        if not p.exists():
            return None
        return load_rig_record(p)

    def write_rig(self, name: str, record: dict) -> Path:
        """Store a rig record atomically; the previous one is kept in ``rig/history/``.

        The record carries the sha256 of its own content (``record_sha256``), so
        damage is found by ``fgcd campaign verify`` and refused by :meth:`read_rig`.
        """
        p = self.rig_path(name)
        record = {"written": _now_iso(), **record}
        record.pop(RIG_CHECKSUM_KEY, None)
        record = json.loads(json.dumps(record, ensure_ascii=False))  # the form it is read back in
        record[RIG_CHECKSUM_KEY] = _rig_checksum(record)
        history = self.path / "rig" / "history"
        history.mkdir(parents=True, exist_ok=True)
        atomic_write_json(history / f"{name}-{utc_stamp()}.json", record)
        atomic_write_json(p, record)
        return p

    def update_config(self, section: str, values: dict) -> None:
        """Merge ``values`` into a section of campaign.toml (atomic rewrite)."""
        cfg = dict(self.config)
        sec = dict(cfg.get(section, {}))
        sec.update(values)
        cfg[section] = sec
        atomic_write_bytes(self.path / CAMPAIGN_FILE, tomli_w.dumps(cfg).encode("utf-8"))
        self.config = cfg

    def iter_observations(self) -> Iterator[tuple[Station, Path, str]]:
        """``(station, path, kind)`` for every observation directory present."""
        for sname in self.station_names():
            st = self.station(sname)
            if st.reference_path.exists():
                yield st, st.reference_path, "reference"
            for vname in st.visit_names():
                yield st, st.path / "visits" / vname, "visit"


def init_campaign(path: Path, *, site: str, description: str = "", rig: dict | None = None) -> Campaign:
    """Create a new campaign directory with its campaign.toml."""
    path = Path(path)
    if not site.strip():
        raise UserInputError("--site must not be empty")
    if (path / CAMPAIGN_FILE).exists():
        raise CampaignError(f"{path} already holds a campaign")
    if path.exists() and not path.is_dir():
        raise UserInputError(f"{path} exists and is not a directory")
    try:
        path.mkdir(parents=True, exist_ok=True)
        (path / "stations").mkdir(exist_ok=True)
        (path / "rig").mkdir(exist_ok=True)
        config = {
            "campaign": {
                "format_version": FORMAT_VERSION,
                "site": site.strip(),
                "description": description,
                "created": _now_iso(),
                "fgcd_version": __version__,
            },
            "rig": dict(rig or {}),
        }
        atomic_write_bytes(path / CAMPAIGN_FILE, tomli_w.dumps(config).encode("utf-8"))
    except PermissionError as exc:
        raise CampaignError(f"cannot write to {exc.filename or path}: permission denied") from None
    except OSError as exc:
        raise CampaignError(f"cannot create a campaign in {path}: {exc.strerror or exc}") from None
    return Campaign(path, config)


def open_campaign(path: Path) -> Campaign:
    """Open an existing campaign; one clear error if it is not one."""
    path = Path(path)
    if not path.exists():
        raise CampaignError(f"{path}: no such directory")
    cfile = path / CAMPAIGN_FILE
    if not cfile.exists():
        raise CampaignError(f"{path} is not a campaign (no {CAMPAIGN_FILE}; create one with `fgcd campaign init`)")
    try:
        config = tomllib.loads(cfile.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise CampaignError(f"{cfile}: malformed TOML ({exc})") from None
    camp = config.get("campaign")
    if not isinstance(camp, dict) or "format_version" not in camp:
        raise CampaignError(f"{cfile}: no [campaign] section with a format_version")
    version = camp.get("format_version")
    if not isinstance(version, int) or version > FORMAT_VERSION:
        raise CampaignError(
            f"{cfile}: format version {version!r} is not supported by fgcd {__version__} (max {FORMAT_VERSION})"
        )
    return Campaign(path, config)
