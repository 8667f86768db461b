"""The campaign store: a site, its stations, their reference observation and visits.

The file layout is :mod:`fgcd_cli.campaign.schema`; observations (reference,
visits) are :mod:`fgcd_cli.campaign.observation`, rig records
:mod:`fgcd_cli.campaign.records`, file encodings :mod:`fgcd_cli.campaign.codecs`.
This module opens and creates campaigns and stations. Its former contents stay
importable from here.
"""

from __future__ import annotations

import json
import shutil
import tomllib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomli_w

from fgcd_cli import __version__
from fgcd_cli.campaign.atomic import TMP_PREFIX, atomic_write_bytes, atomic_write_json, fsync_dir
from fgcd_cli.campaign.observation import Observation, ObservationWriter, load_observation
from fgcd_cli.campaign.records import load_rig_record, write_rig_record
from fgcd_cli.campaign.schema import (
    CAMPAIGN_FILE,
    FORMAT_VERSION,
    MANIFEST,
    REFERENCE_DIR,
    RIG_DIR,
    STATION_FILE,
    STATIONS_DIR,
    VISITS_DIR,
    ObservationKind,
    check_name,
    now_iso,
    rig_record_file,
    utc_stamp,
)
from fgcd_cli.errors import CampaignError, DataIntegrityError, ImmutableDataError, UserInputError

__all__ = ["Campaign", "Station", "init_campaign", "open_campaign"]


# ----------------------------------------------------------------------------- station
@dataclass
class Station:
    """A viewpoint of a campaign: one reference observation and its visits."""

    campaign: Campaign
    name: str
    path: Path
    info: dict = field(default_factory=dict)

    @property
    def reference_path(self) -> Path:
        """Where the reference observation lives."""
        return self.path / REFERENCE_DIR

    def has_reference(self) -> bool:
        """True once a reference observation was committed."""
        return (self.reference_path / MANIFEST).exists()

    def reference(self) -> Observation:
        """The reference observation (error if none yet)."""
        if not self.reference_path.exists():
            raise CampaignError(f"station '{self.name}' has no reference observation yet (run `fgcd capture`)")
        return load_observation(self.reference_path, ObservationKind.REFERENCE)

    def write_reference(self, metadata: dict | None = None) -> ObservationWriter:
        """Start writing the reference observation; refused if one exists."""
        if self.reference_path.exists():
            raise ImmutableDataError(
                f"station '{self.name}' already has a reference observation; it is immutable "
                "(create a new station to capture another reference)"
            )
        return ObservationWriter(self.reference_path, ObservationKind.REFERENCE, metadata, on_commit=self._index)

    def visit_names(self) -> list[str]:
        """Committed visits, oldest first."""
        vdir = self.path / VISITS_DIR
        if not vdir.is_dir():
            return []
        return sorted(p.name for p in vdir.iterdir() if p.is_dir() and not p.name.startswith("."))

    def visits(self) -> list[Observation]:
        """Committed visits, oldest first."""
        return [self.visit(n) for n in self.visit_names()]

    def missing_visit_names(self) -> list[str]:
        """Visits ``station.json`` records whose folders are gone, oldest first ([] without an index)."""
        present = set(self.visit_names())
        prefix = f"{VISITS_DIR}/"
        recorded = {rel.removeprefix(prefix) for rel in self.indexed_observations() or [] if rel.startswith(prefix)}
        return sorted(recorded - present)

    def visit(self, name: str | None = None) -> Observation:
        """A visit by name; the latest recorded one when ``name`` is None.

        Rule: a visit ``station.json`` records whose folder is gone is damage
        (DataIntegrityError, exit 4), never skipped: asked for by name, or as the
        latest, it is named; an older visit is never taken for the latest.
        """
        names = self.visit_names()
        missing = self.missing_visit_names()
        if name is None and missing and (not names or missing[-1] > names[-1]):
            older = f"; give --visit {names[-1]} for the latest one present" if names else ""
            raise DataIntegrityError(
                f"station '{self.name}': the latest recorded visit {missing[-1]} is missing "
                f"(its folder {self.path / VISITS_DIR / missing[-1]} is gone){older}; "
                "run `fgcd campaign verify`"
            )
        if name in missing:
            raise DataIntegrityError(
                f"station '{self.name}': visit {name} is recorded in {STATION_FILE} but its "
                f"folder {self.path / VISITS_DIR / name} is gone; run `fgcd campaign verify`"
            )
        if not names:
            raise CampaignError(f"station '{self.name}' has no visits yet (run `fgcd relocate`)")
        if name is None:
            name = names[-1]
        if name not in names:
            raise CampaignError(f"station '{self.name}' has no visit '{name}' (visits: {', '.join(names)})")
        return load_observation(self.path / VISITS_DIR / name, ObservationKind.VISIT)

    def new_visit(self, metadata: dict | None = None, *, stamp: str | None = None) -> ObservationWriter:
        """Start writing a new visit named by its UTC time."""
        vdir = self.path / VISITS_DIR
        vdir.mkdir(parents=True, exist_ok=True)
        return ObservationWriter(vdir / (stamp or utc_stamp()), ObservationKind.VISIT, metadata, on_commit=self._index)

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
        sfile = self.path / STATION_FILE
        try:  # re-read: another Station object may have indexed an observation since
            self.info = json.loads(sfile.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError):
            pass
        index = self.indexed_observations() or []
        # An observation committed by a process killed before its own index update is indexed now: it is whole
        # (renamed into place with its manifest), and `campaign verify` only warned it was unindexed.
        index += [r for r in self._committed_on_disk() if r not in index and r != rel]
        if rel not in index:
            index.append(rel)
        self.info = {**self.info, "observations": index}
        atomic_write_json(sfile, self.info)

    def _committed_on_disk(self) -> list[str]:
        """The committed observations in the station folder (with their manifest), reference first, as indexed."""
        found = [REFERENCE_DIR] if (self.path / REFERENCE_DIR / MANIFEST).is_file() else []
        return found + [
            f"{VISITS_DIR}/{n}" for n in self.visit_names() if (self.path / VISITS_DIR / n / MANIFEST).is_file()
        ]


def _read_station_info(sfile: Path) -> dict:
    """The content of a ``station.json`` ({} if absent); DataIntegrityError naming it when damaged."""
    if not sfile.exists():
        return {}
    try:
        info = json.loads(sfile.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataIntegrityError(
            f"{sfile}: damaged station record, not valid JSON ({exc}); run `fgcd campaign verify`"
        ) from None
    except OSError as exc:
        raise DataIntegrityError(f"{sfile}: damaged station record, cannot be read ({exc.strerror or exc})") from None
    if not isinstance(info, dict):
        raise DataIntegrityError(f"{sfile}: damaged station record, not a JSON object; run `fgcd campaign verify`")
    return info


def _remove_unused_station(station: Station) -> None:
    """Remove a station directory that holds nothing but its ``station.json`` and write leftovers."""
    if station.has_reference() or station.visit_names():
        return
    leftovers = {STATION_FILE, VISITS_DIR, REFERENCE_DIR}
    for entry in station.path.iterdir():
        if entry.name not in leftovers and not entry.name.startswith(TMP_PREFIX):
            return
        if entry.name in (VISITS_DIR, REFERENCE_DIR) and any(
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
        return dict(self.config.get(RIG_DIR, {}))

    # -- stations
    def station_names(self) -> list[str]:
        """Names of the stations, sorted."""
        sdir = self.path / STATIONS_DIR
        if not sdir.is_dir():
            return []
        return sorted(p.name for p in sdir.iterdir() if p.is_dir() and not p.name.startswith("."))

    def station(self, name: str) -> Station:
        """An existing station; DataIntegrityError when its ``station.json`` is damaged."""
        name = check_name(name, "station")
        path = self.path / STATIONS_DIR / name
        if not path.is_dir():
            known = ", ".join(self.station_names()) or "none"
            raise CampaignError(f"campaign has no station '{name}' (stations: {known})")
        return Station(self, name, path, _read_station_info(path / STATION_FILE))

    def existing_station(self, name: str) -> Station | None:
        """The station if it exists, None if not; DataIntegrityError when it is damaged. Writes nothing."""
        name = check_name(name, "station")
        path = self.path / STATIONS_DIR / name
        if path.is_dir():
            return self.station(name)
        if path.exists():
            raise CampaignError(f"{path} exists but is not a station directory")
        return None

    def create_station(self, name: str, *, description: str = "", **info: Any) -> Station:
        """Create a station (error if it exists)."""
        name = check_name(name, "station")
        path = self.path / STATIONS_DIR / name
        if path.exists():
            raise CampaignError(f"station '{name}' already exists")
        path.mkdir(parents=True)
        data = {"name": name, "description": description, "created": now_iso(), **info, "observations": []}
        try:
            atomic_write_json(path / STATION_FILE, data)
        except BaseException:
            # Rule: a station folder exists only with its station.json. A full disk (or Ctrl-C) here must not
            # leave an empty folder that every later command reads as a damaged station (docs/hardware.md,
            # "Faults in the field": no partial write remains); the write's temporary file is already gone.
            try:
                path.rmdir()
            except OSError:
                pass
            raise
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
        name = check_name(name, "station")
        path = self.path / STATIONS_DIR / name
        existed = path.exists()
        try:
            station = self.station_or_create(name, **info)
        except BaseException:
            # interrupted while creating it (Ctrl-C during the station.json write): no half-made station
            if not existed and path.is_dir() and all(p.name.startswith(TMP_PREFIX) for p in path.iterdir()):
                shutil.rmtree(path, ignore_errors=True)
            raise
        try:
            yield station
        except BaseException:
            if not existed:
                _remove_unused_station(station)
            raise

    # -- rig calibration records
    def rig_path(self, name: str) -> Path:
        """Path of a rig record, e.g. ``rig/handeye.json``."""
        return self.path / RIG_DIR / rig_record_file(name)

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
        return write_rig_record(self.rig_path(name), name, record)

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
                yield st, st.reference_path, ObservationKind.REFERENCE
            for vname in st.visit_names():
                yield st, st.path / VISITS_DIR / vname, ObservationKind.VISIT


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
        (path / STATIONS_DIR).mkdir(exist_ok=True)
        (path / RIG_DIR).mkdir(exist_ok=True)
        config = {
            "campaign": {
                "format_version": FORMAT_VERSION,
                "site": site.strip(),
                "description": description,
                "created": now_iso(),
                "fgcd_version": __version__,
            },
            RIG_DIR: dict(rig or {}),
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
