"""Is a visit's stored analysis up to date? The detector's version, the inputs' checksums, the products present.

An archive analysis of a visit ends by writing ``changes/analysis.json``
(:data:`fgcd_cli.campaign.schema.ANALYSIS_JSON`) after every product: the
detector version, the options, the sha256 of every input (as the reference's and
the visit's manifests record them) and of every product. A visit is up to date
when that record exists, names the current :data:`DETECTOR_VERSION` and the same
options and inputs, and every product it lists is still in the visit as
recorded. A run killed between two products leaves no record (or one whose
product checksums no longer match), so the visit is done again
(docs/archive.md, "Up to date").
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from enum import StrEnum

from fgcd_cli import __version__
from fgcd_cli.campaign import schema
from fgcd_cli.campaign.atomic import sha256_file
from fgcd_cli.changes.version import DETECTOR_VERSION
from fgcd_cli.errors import DataIntegrityError

__all__ = [
    "AnalysisOptions",
    "Freshness",
    "analysis_inputs",
    "analysis_record",
    "freshness",
    "stored_options",
    "verify_inputs",
    "ANALYSIS_RELPATH",
]

ANALYSIS_RELPATH = schema.change_relpath(schema.ANALYSIS_JSON)
_REFERENCE_ARRAYS = (schema.array_relpath(schema.ARRAY_CLOUD_POINTS), schema.array_relpath(schema.ARRAY_T_REF_CAMREF))


@dataclass(frozen=True, kw_only=True)
class AnalysisOptions:
    """The diff options an archive analysis runs with (those of ``fgcd diff -c``); part of the up-to-date key.

    Attributes
    ----------
    edge_check_px : int or None
        Region-level edge check shift, px (None: the campaign diff's default).
    mm_per_px : float or None
        Fixed scale, mm per px (None: from the reference's metric cloud).
    register : bool
        Register the visit's images onto the reference first.
    eval_mask_sha256 : str or None
        sha256 of the region of interest (``--roi``) the diff compared within (None: the whole image; the stored key keeps its first name).
    min_contrast : float or None
        Contrast floor of a reported region (``--min-contrast``; None: the detector's default).
    geometry : bool
        Warp the visit by the reference depth and its measured residual pose (``--no-geometry``: off).
    """

    edge_check_px: int | None = None
    mm_per_px: float | None = None
    register: bool = True
    eval_mask_sha256: str | None = None
    min_contrast: float | None = None
    geometry: bool = True


class Freshness(StrEnum):
    """Where a visit's stored analysis stands (the values are what ``--dry-run`` prints)."""

    UP_TO_DATE = "up to date"
    NOT_ANALYSED = "not analysed"
    DETECTOR_CHANGED = "detector version changed"
    OPTIONS_CHANGED = "options changed"
    INPUTS_CHANGED = "inputs changed"
    PRODUCTS_MISSING = "products missing"


def _metadata_sha(metadata: dict) -> str:
    return hashlib.sha256(json.dumps(metadata.get("intrinsics"), sort_keys=True).encode()).hexdigest()


def analysis_inputs(reference, visit) -> dict[str, str]:
    """sha256 of everything a campaign diff reads, keyed ``reference/<file>`` and ``visit/<file>``.

    The images of both observations, the reference's metric cloud and camera pose
    (the pixel areas), and the reference's intrinsics record; the checksums are the
    ones the manifests hold (nothing is read but the manifests).
    """
    inputs = {}
    for prefix, obs, extra in (("reference", reference, _REFERENCE_ARRAYS), ("visit", visit, ())):
        files = obs.files()
        for rel in [*obs.image_files().values(), *extra]:
            if rel in files:
                inputs[f"{prefix}/{rel}"] = files[rel]["sha256"]
    inputs["reference/manifest.json#intrinsics"] = _metadata_sha(reference.metadata)
    return inputs


def verify_inputs(reference, visit, inputs: dict[str, str]) -> None:
    """Check the input files against their recorded checksums (sha256 of the bytes on disk).

    Raises
    ------
    DataIntegrityError
        Naming the first input file that is missing or no longer matches its manifest.
    """
    for key, expected in inputs.items():
        prefix, _, rel = key.partition("/")
        if "#" in rel:
            continue
        path = (reference if prefix == "reference" else visit).path / rel
        try:
            actual = sha256_file(path)
        except OSError as exc:
            raise DataIntegrityError(
                f"{path}: cannot be read ({exc.strerror or exc}); run `fgcd campaign verify`"
            ) from None
        if actual != expected:
            raise DataIntegrityError(f"{path}: damaged, does not match its checksum; run `fgcd campaign verify`")


def analysis_record(visit, *, inputs: dict[str, str], options: AnalysisOptions, seconds: float) -> dict:
    """The ``changes/analysis.json`` record of a finished analysis: version, options, inputs and product checksums."""
    products = {
        rel: entry["sha256"] for rel, entry in visit.files().items() if entry.get("derived") and rel != ANALYSIS_RELPATH
    }
    return {
        "detector_version": DETECTOR_VERSION,
        "fgcd_version": __version__,
        "written": schema.now_iso(),
        "options": asdict(options),
        "inputs": inputs,
        "products": products,
        "seconds": seconds,
    }


def _products_present(visit, products: dict[str, str]) -> bool:
    files = visit.files()
    for rel, sha in products.items():
        entry = files.get(rel)
        if entry is None or entry.get("sha256") != sha:
            return False
        path = visit.path / rel
        if not path.is_file() or path.stat().st_size != entry.get("bytes"):
            return False
    return True


def _recorded_options(record: dict) -> dict | None:
    """A record's options with the defaults of fields it predates (a record of an older fgcd keeps its meaning)."""
    options = record.get("options")
    return {**asdict(AnalysisOptions()), **options} if isinstance(options, dict) else None


def stored_options(visit) -> AnalysisOptions | None:
    """The options the visit's stored diff was made with (its ``changes/analysis.json``), or None if not recorded."""
    if not visit.has(ANALYSIS_RELPATH) or not (visit.path / ANALYSIS_RELPATH).is_file():
        return None
    try:
        options = _recorded_options(visit.json(ANALYSIS_RELPATH))
        return AnalysisOptions(**options) if options is not None else None
    except (ValueError, TypeError, AttributeError, DataIntegrityError):
        return None


def freshness(reference, visit, options: AnalysisOptions) -> Freshness:
    """Where ``visit``'s stored analysis stands against the current detector, ``options`` and inputs."""
    if not visit.has(ANALYSIS_RELPATH) or not (visit.path / ANALYSIS_RELPATH).is_file():
        return Freshness.NOT_ANALYSED
    try:
        record = visit.json(ANALYSIS_RELPATH)
    except (ValueError, DataIntegrityError):
        return Freshness.NOT_ANALYSED
    if record.get("detector_version") != DETECTOR_VERSION:
        return Freshness.DETECTOR_CHANGED
    if _recorded_options(record) != asdict(options):
        return Freshness.OPTIONS_CHANGED
    if record.get("inputs") != analysis_inputs(reference, visit):
        return Freshness.INPUTS_CHANGED
    products = record.get("products") or {}
    if schema.change_relpath(schema.REGIONS_JSON) not in products or not _products_present(visit, products):
        return Freshness.PRODUCTS_MISSING
    return Freshness.UP_TO_DATE
