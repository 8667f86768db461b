"""The file layout of a campaign (format version 1), in one place.

On disk::

    <campaign>/campaign.toml                 site, rig section, format version
    <campaign>/rig/<name>.json               calibration records (+ rig/history/<name>-<stamp>.json)
    <campaign>/stations/<station>/station.json
    <campaign>/stations/<station>/reference/manifest.json, images/, arrays/, cloud.ply ...
    <campaign>/stations/<station>/visits/<UTC timestamp>/manifest.json, ...

Within an observation: ``images/<portable name>.png`` (one per lighting),
``arrays/<name>.npy``, ``cloud.ply``, ``relocation.jsonl`` and ``coarse.jsonl``
(visits), ``evaluation/sim_truth.json`` (simulator only), and the derived
products of a diff: ``changes/<file>``, ``report.html``, ``afd.json``.

Only names and pure path functions live here; reading and writing is
:mod:`fgcd_cli.campaign.store` (campaign, station), :mod:`.observation` and
:mod:`.records` (rig records).
"""

from __future__ import annotations

import re
from datetime import UTC, datetime
from enum import StrEnum

from fgcd_cli.errors import UserInputError

FORMAT_VERSION = 1

# ----------------------------------------------------------------------------- campaign
CAMPAIGN_FILE = "campaign.toml"
STATIONS_DIR = "stations"
RIG_DIR = "rig"
RIG_HISTORY_DIR = "history"
STATION_FILE = "station.json"
#: Per-station lock files of running captures and revisits (``<campaign>/.locks/<station>.lock``).
LOCKS_DIR = ".locks"
HISTORY_REPORT = "history.html"
"""A station's history report (``fgcd report``), next to its ``station.json``."""

# ----------------------------------------------------------------------------- observations
MANIFEST = "manifest.json"
IMAGES_KEY = "images"
"""The manifest's image name -> file mapping."""
REFERENCE_DIR = "reference"
VISITS_DIR = "visits"
IMAGES_DIR = "images"
ARRAYS_DIR = "arrays"
CLOUD = "cloud"
"""Stem of the observation's point cloud: ``cloud.ply`` and ``arrays/cloud_points.npy`` etc."""
CLOUD_FILE = f"{CLOUD}.ply"
RELOCATION_LOG = "relocation.jsonl"
COARSE_LOG = "coarse.jsonl"
SCENE_UNCERTAINTY_PREFIX = "scene_uncertainty"
"""Station-level cache of the reference's scene uncertainty map: ``<prefix>-<key>.npz`` beside ``reference/``."""
#: The journal of a revisit in progress, in the station's visits folder (``fgcd relocate --resume``).
VISIT_JOURNAL = ".in-progress.jsonl"
SIM_TRUTH = "evaluation/sim_truth.json"
"""The simulator's truth of an observation (evaluation only; the tool never reads it)."""

# ----------------------------------------------------------------------------- arrays of an observation
ARRAY_CLOUD_POINTS = f"{CLOUD}_points"
ARRAY_CLOUD_INTENSITIES = f"{CLOUD}_intensities"
ARRAY_T_REF_CAMREF = "T_ref_camref"
ARRAY_KEYFRAME_POSES = "keyframe_poses"
ARRAY_KEYFRAME_IMAGES = "keyframe_images"

# ----------------------------------------------------------------------------- derived products of a diff
CHANGES_DIR = "changes"
REPORT_HTML = "report.html"
AFD_JSON = "afd.json"
CHANGE_SCORE_PNG = "change_score.png"
CHANGE_SCORE_NPY = "change_score.npy"
CHANGE_MASK_PNG = "change_mask.png"
OVERLAY_PNG = "overlay.png"
REGIONS_JSON = "regions.json"
FDF_PNG = "fdf.png"
ANALYSIS_JSON = "analysis.json"
"""``changes/analysis.json``: the record of an archive analysis (detector version, input and product checksums),
written last, so that its presence with matching checksums means the visit's products are complete."""
SITE_REPORT = "site.html"
"""A campaign's site page (``fgcd archive history``), next to its ``campaign.toml``."""

# ----------------------------------------------------------------------------- rig records
RIG_HANDEYE = "handeye"
RIG_INTRINSICS = "intrinsics"
RIG_CHECKSUM_KEY = "record_sha256"


class ObservationKind(StrEnum):
    """What an observation directory is (the manifest's ``kind``)."""

    REFERENCE = "reference"
    VISIT = "visit"


_NAME_RE = re.compile(r"^[^/\\\x00]+$")
#: Characters no file name may hold on FAT, exFAT or NTFS (field laptops, SD cards), control characters included.
_NON_PORTABLE = re.compile(r'[<>:"/\\|?*\x00-\x1f]')


def utc_stamp(now: datetime | None = None) -> str:
    """A UTC timestamp usable as a directory name, e.g. ``20261122T041503Z``."""
    now = now or datetime.now(UTC)
    return now.astimezone(UTC).strftime("%Y%m%dT%H%M%S") + f"{now.microsecond // 1000:03d}Z"


def now_iso() -> str:
    """The current UTC time, ISO 8601 to the second (``created``, ``written`` fields)."""
    return datetime.now(UTC).isoformat(timespec="seconds")


def check_name(name: str, what: str) -> str:
    """``name`` stripped, if usable as one path component; UserInputError otherwise."""
    name = name.strip()
    if not name or name in (".", "..") or not _NAME_RE.match(name) or name.startswith("."):
        raise UserInputError(
            f"invalid {what} name {name!r}: use a non-empty name without '/' that does not start with '.'"
        )
    return name


def rig_record_file(name: str) -> str:
    """The file of rig record ``name``, relative to ``rig/``: ``handeye.json``."""
    return f"{check_name(name, 'rig record')}.json"


def rig_history_file(name: str, stamp: str) -> str:
    """The kept copy of a rig record, relative to ``rig/history/``."""
    return f"{name}-{stamp}.json"


def visit_relpath(stamp: str) -> str:
    """A visit relative to its station: ``visits/<stamp>`` (the form ``station.json`` indexes)."""
    return f"{VISITS_DIR}/{stamp}"


def array_relpath(name: str) -> str:
    """The file of array ``name`` in an observation: ``arrays/<name>.npy``."""
    return f"{ARRAYS_DIR}/{name}.npy"


def change_relpath(name: str) -> str:
    """Where a visit stores a diff product: ``report.html`` at its root, the others under ``changes/``."""
    return REPORT_HTML if name == REPORT_HTML else f"{CHANGES_DIR}/{name}"


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


def image_relpath(name: str) -> str:
    """Where an image of this name is written: ``images/<portable stem>.png``."""
    return f"{IMAGES_DIR}/{image_file_stem(name)}.png"


def image_relpath_candidates(name: str) -> list[str]:
    """Where an image of this name may be stored: the portable name, then the name as-is.

    Campaigns written before portable names stored ``images/led:3.png``; the
    second spelling lets them be read. Prefer :meth:`Observation.image_relpath`,
    which also follows the manifest's own name -> file mapping.
    """
    portable = image_relpath(name)
    legacy = f"{IMAGES_DIR}/{name}.png"
    return [portable] if legacy == portable else [portable, legacy]


def image_name_of(relpath: str) -> str | None:
    """The image name of an ``images/<name>.png`` file (observations without a mapping); None for other files."""
    prefix, suffix = f"{IMAGES_DIR}/", ".png"
    if relpath.startswith(prefix) and relpath.endswith(suffix):
        return relpath[len(prefix) : -len(suffix)]
    return None
