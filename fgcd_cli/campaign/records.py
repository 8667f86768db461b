"""Rig records (``rig/<name>.json``) and the ``[rig]`` section of campaign.toml: the one place that reads and writes them.

A rig record carries the sha256 of its own content (``record_sha256``), so
damage is found by ``fgcd campaign verify`` and refused on reading; the previous
version of a record is kept in ``rig/history/``.
"""

from __future__ import annotations

import json
from pathlib import Path

from fgcd_cli.campaign.atomic import atomic_write_json, sha256_bytes
from fgcd_cli.campaign.schema import (
    RIG_CHECKSUM_KEY,
    RIG_HISTORY_DIR,
    now_iso,
    rig_history_file,
    utc_stamp,
)
from fgcd_cli.errors import DataIntegrityError

__all__ = [
    "campaign_world",
    "load_rig_record",
    "rig_checksum",
    "station_world",
    "write_rig_record",
]


def rig_checksum(record: dict) -> str:
    """sha256 of a rig record's content, its own checksum entry left out (canonical JSON)."""
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
    if stored is not None and stored != rig_checksum(record):
        raise DataIntegrityError(f"{path}: content does not match its sha256 (edited or damaged)")
    return record


def write_rig_record(path: Path, name: str, record: dict) -> Path:
    """Store rig record ``name`` at ``path`` atomically, a copy kept in ``rig/history/``; returns ``path``."""
    path = Path(path)
    record = {"written": now_iso(), **record}
    record.pop(RIG_CHECKSUM_KEY, None)
    record = json.loads(json.dumps(record, ensure_ascii=False))  # the form it is read back in
    record[RIG_CHECKSUM_KEY] = rig_checksum(record)
    history = path.parent / RIG_HISTORY_DIR
    history.mkdir(parents=True, exist_ok=True)
    atomic_write_json(history / rig_history_file(name, utc_stamp()), record)
    atomic_write_json(path, record)
    return path


def _int_or(value, default: int) -> int:
    try:
        return int(value)
    except (TypeError, ValueError):
        return default


def campaign_world(campaign) -> dict:
    """The campaign's default simulated world (``[rig.sim]`` of campaign.toml), never written by a capture."""
    sim = campaign.rig_config.get("sim", {})
    sim = sim if isinstance(sim, dict) else {}
    return {
        "scene": str(sim.get("scene", "stele")),
        "seed": _int_or(sim.get("seed"), 0),
        "noise": str(sim.get("noise", "default")),
    }


def station_world(campaign, reference) -> dict:
    """The simulated world a station's reference was captured in.

    Rule: the world belongs to the station. Its reference records the scene,
    seed and noise it was captured in; the campaign's ``[rig.sim]`` is only the
    default for references that do not say (written before the rule).
    """
    world = campaign_world(campaign)
    recorded = reference.metadata.get("scenario")
    if isinstance(recorded, dict):
        world.update({k: recorded[k] for k in ("scene", "seed", "noise") if recorded.get(k) is not None})
    return world
