"""Observations (a station's reference, or one visit): the read-only view and the atomic writer.

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

import hashlib
import io
import json
import os
import shutil
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fgcd_cli import __version__
from fgcd_cli.campaign.atomic import TMP_PREFIX, atomic_write_bytes, atomic_write_json, fsync_dir, sha256_bytes
from fgcd_cli.campaign.codecs import decode_png, encode_npy, encode_ply, encode_png
from fgcd_cli.campaign.schema import (
    CLOUD,
    FORMAT_VERSION,
    IMAGES_KEY,
    MANIFEST,
    ObservationKind,
    array_relpath,
    check_name,
    image_name_of,
    image_relpath,
    image_relpath_candidates,
    now_iso,
)
from fgcd_cli.errors import CampaignError, DataIntegrityError, ImmutableDataError, UserInputError

__all__ = ["Observation", "ObservationWriter", "load_observation"]


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
            data = p.read_bytes()
        except FileNotFoundError:
            raise DataIntegrityError(f"{p}: missing (run `fgcd campaign verify`)") from None
        # Rule: data whose checksum no longer matches its manifest is never used (docs/hardware.md, Faults).
        expected = self.files()[relpath].get("sha256") if isinstance(self.files()[relpath], dict) else None
        if expected is not None and hashlib.sha256(data).hexdigest() != expected:
            raise DataIntegrityError(f"{p}: damaged (checksum differs from the manifest; run `fgcd campaign verify`)")
        return data

    def image_files(self) -> dict[str, str]:
        """Image name (a lighting, e.g. ``led:3``) -> its file, relative to the observation.

        The manifest's own mapping when it has one; otherwise (observations
        written before portable file names) every ``images/*.png`` file, named
        by its stem.
        """
        mapping = self.manifest.get(IMAGES_KEY)
        if isinstance(mapping, dict):
            return {str(k): str(v) for k, v in mapping.items() if str(v) in self.files()}
        return {name: k for k in self.files() if (name := image_name_of(k)) is not None}

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
        return np.load(io.BytesIO(self._read(array_relpath(name))), allow_pickle=False)

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
        if self.kind == ObservationKind.REFERENCE:
            raise ImmutableDataError(f"{self.path}: the reference observation is immutable")
        relpath = relpath.replace("\\", "/").lstrip("/")
        if relpath == MANIFEST or ".." in relpath.split("/"):
            raise UserInputError(f"invalid derived file name {relpath!r}")
        entry = self.files().get(relpath)
        if entry is not None and not entry.get("derived", False):
            raise ImmutableDataError(f"{self.path / relpath}: captured data cannot be replaced")
        target = self.path / relpath
        files = dict(self.manifest.get("files", {}))
        if entry is not None:
            # Rule: the manifest never lists a checksum its file does not have, even if the process
            # dies between the two writes: the old entry goes first (the file is then merely unlisted).
            files.pop(relpath)
            self._write_manifest(files)
        atomic_write_bytes(target, data)
        files[relpath] = {"sha256": sha256_bytes(data), "bytes": len(data), "derived": True}
        self._write_manifest(files)
        return target

    def _write_manifest(self, files: dict) -> None:
        """The manifest with ``files``, written atomically."""
        manifest = dict(self.manifest)
        manifest["files"] = files
        manifest["updated"] = now_iso()
        atomic_write_json(self.path / MANIFEST, manifest)
        self.manifest = manifest


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

    def __enter__(self) -> ObservationWriter:
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
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
            with open(p, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
        except OSError as exc:
            if exc.filename is not None or exc.errno is None:
                raise
            # Rule (README, "Errors"): a full disk names its file; a write's ENOSPC carries none. The file is named
            # where it was going (its temporary folder goes with the abort: docs/hardware.md, "Faults in the field").
            raise OSError(exc.errno, exc.strerror, str(self.final_path / relpath)) from None
        self._files[relpath] = {"sha256": sha256_bytes(data), "bytes": len(data)}

    def add_image(self, name: str, image: np.ndarray) -> None:
        """Add image ``name`` as ``images/<portable name>.png`` (``led:3`` -> ``images/led-3.png``)."""
        name = check_name(name, "image")
        if name in self._images:
            raise UserInputError(f"duplicate image name {name!r}")
        relpath = image_relpath(name)
        if relpath in self._files:
            other = next((n for n, rel in self._images.items() if rel == relpath), relpath)
            raise UserInputError(f"image names {other!r} and {name!r} would share the file {relpath}")
        self.add_bytes(relpath, encode_png(image))
        self._images[name] = relpath

    def add_array(self, name: str, array: np.ndarray) -> None:
        """Add ``arrays/<name>.npy``."""
        self.add_bytes(array_relpath(check_name(name, "array")), encode_npy(array))

    def add_json(self, relpath: str, data: Any) -> None:
        """Add a JSON document."""
        self.add_bytes(relpath, (json.dumps(data, indent=2, ensure_ascii=False) + "\n").encode("utf-8"))

    def add_cloud(
        self,
        points: np.ndarray,
        *,
        colors: np.ndarray | None = None,
        normals: np.ndarray | None = None,
        name: str = CLOUD,
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
            "created": now_iso(),
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
            if self.kind == ObservationKind.REFERENCE:
                raise ImmutableDataError(f"{self.final_path}: a reference observation already exists and is immutable")
            raise CampaignError(f"{self.final_path} already exists")
        os.rename(self.tmp_path, self.final_path)
        fsync_dir(self.final_path.parent)
        if self.kind == ObservationKind.REFERENCE:
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


def load_observation(path: Path, kind: str) -> Observation:
    """The observation at ``path`` from its manifest; DataIntegrityError naming a missing or damaged manifest."""
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
