"""`fgcd campaign verify`: check every manifest and checksum, name each problem.

Rule: verify checks everything it can. A damaged file is named and the check
goes on: a malformed or missing ``campaign.toml`` does not stop the stations
from being checked, and a damaged ``station.json`` does not stop that station's
observations from being checked (only the index comparison needs it).
"""

from __future__ import annotations

import json
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

from fgcd_cli.campaign.atomic import TMP_PREFIX, sha256_file
from fgcd_cli.campaign.records import load_rig_record
from fgcd_cli.campaign.schema import (
    AFD_JSON,
    CAMPAIGN_FILE,
    CHANGES_DIR,
    FORMAT_VERSION,
    MANIFEST,
    RELOCATION_LOG,
    REPORT_HTML,
    RIG_DIR,
    STATION_FILE,
    STATIONS_DIR,
    VISIT_JOURNAL,
    VISITS_DIR,
)
from fgcd_cli.campaign.store import Campaign, Station, open_campaign
from fgcd_cli.errors import CampaignError, DataIntegrityError

__all__ = ["Problem", "VerifyReport", "committed_visit_of_journal", "verify_campaign", "verify_campaign_dir"]


@dataclass(frozen=True)
class Problem:
    """One damaged, missing or unexpected file."""

    path: str
    kind: str  # missing | checksum | size | unreadable | manifest | campaign | station | unindexed | unlisted | incomplete-write | interrupted-visit | journal | scale
    detail: str
    severity: str = "error"  # error (damage, exit 4) | warning (a leftover, safe to delete) | note (nothing wrong)


#: Severities in the order the summary counts them, with the noun it counts them by (docs/user-guide.md §2).
SEVERITY_NOUNS = (("error", "problem"), ("warning", "warning"), ("note", "note"))


def counted(n: int, noun: str) -> str:
    """``1 problem``, ``2 problems``, ``0 files``."""
    return f"{n} {noun}{'' if n == 1 else 's'}"


@dataclass
class VerifyReport:
    """Result of verifying a campaign."""

    campaign: str
    observations: int = 0
    files_checked: int = 0
    problems: list[Problem] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True when no error-level problem was found."""
        return not any(p.severity == "error" for p in self.problems)

    def count(self, severity: str) -> int:
        """How many problems of ``severity`` were found."""
        return sum(p.severity == severity for p in self.problems)

    def summary(self) -> str:
        """One line: ``OK: ...``, ``OK, 1 warning: ...``, ``DAMAGED, 2 problems, 1 note: ...``."""
        counts = [counted(self.count(severity), noun) for severity, noun in SEVERITY_NOUNS if self.count(severity)]
        head = ", ".join(["OK" if self.ok else "DAMAGED", *counts])
        return f"{head}: {counted(self.observations, 'observation')}, {counted(self.files_checked, 'file')} checked"

    def to_dict(self) -> dict:
        """JSON-friendly form (``errors``, ``warnings``, ``notes``: the counts of ``problems`` by severity)."""
        return {
            "campaign": self.campaign,
            "ok": self.ok,
            "observations": self.observations,
            "files_checked": self.files_checked,
            **{f"{severity}s": self.count(severity) for severity, _ in SEVERITY_NOUNS},
            "problems": [p.__dict__ for p in self.problems],
        }


def _verify_observation(obs_path: Path, report: VerifyReport) -> None:
    mpath = obs_path / MANIFEST
    if not mpath.exists():
        report.problems.append(Problem(str(mpath), "manifest", "manifest missing"))
        return
    try:
        manifest = json.loads(mpath.read_text(encoding="utf-8"))
        files = manifest["files"]
        if not isinstance(files, dict):
            raise TypeError("files is not a mapping")
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError) as exc:
        report.problems.append(Problem(str(mpath), "manifest", f"manifest unreadable ({exc})"))
        return
    report.observations += 1
    for rel, entry in files.items():
        report.files_checked += 1
        parts = PurePosixPath(rel).parts
        if not isinstance(entry, dict) or not rel or PurePosixPath(rel).is_absolute() or ".." in parts:
            report.problems.append(Problem(str(mpath), "manifest", f"manifest entry {rel!r} is malformed"))
            continue
        p = obs_path / rel
        if not p.is_file():
            report.problems.append(Problem(str(p), "missing", "listed in the manifest but missing"))
            continue
        size = p.stat().st_size
        if "bytes" in entry and size != entry["bytes"]:
            report.problems.append(Problem(str(p), "size", f"size {size} B, manifest says {entry['bytes']} B"))
            continue
        try:
            digest = sha256_file(p)
        except OSError as exc:
            report.problems.append(Problem(str(p), "unreadable", f"cannot be read ({exc.strerror or exc})"))
            continue
        if digest != entry.get("sha256"):
            report.problems.append(Problem(str(p), "checksum", "sha256 does not match the manifest"))
        elif rel == _REGIONS:
            _verify_scale(p, report)
    listed = set(files) | {MANIFEST}
    for p in sorted(obs_path.rglob("*")):
        if p.is_file():
            rel = p.relative_to(obs_path).as_posix()
            if rel not in listed:
                if p.name.startswith(TMP_PREFIX):
                    report.problems.append(
                        Problem(
                            str(p),
                            "incomplete-write",
                            "a file write interrupted before its rename; safe to delete",
                            "warning",
                        )
                    )
                else:
                    report.problems.append(Problem(str(p), "unlisted", _unlisted_detail(rel), "warning"))


_REGIONS = "changes/regions.json"
_GIVEN_SCALE = re.compile(r"^\s*(\S+) mm per px \(given\)")


def _verify_scale(path: Path, report: VerifyReport) -> None:
    """A stored diff's areas rest on a physical scale: a given mm per px that is not positive and finite is named.

    (``fgcd diff`` refuses such a scale up front; this finds diffs an older fgcd wrote with one.)
    """
    try:
        metadata = json.loads(path.read_text(encoding="utf-8")).get("metadata") or {}
        scale = metadata.get("scale (mm per px)")
        if scale is None and (given := _GIVEN_SCALE.match(str(metadata.get("metric scale", "")))):
            scale = float(given.group(1))
    except (OSError, ValueError, AttributeError):
        return  # its checksum matched: what it says is checked by `fgcd diff`, not here
    if scale is not None and not (isinstance(scale, (int, float)) and math.isfinite(scale) and scale > 0):
        report.problems.append(
            Problem(
                str(path),
                "scale",
                f"diff made with a non-physical scale ({scale} mm per px): "
                "its areas are wrong; run `fgcd diff` on this visit again to replace it",
            )
        )


def verify_campaign_dir(path: Path) -> VerifyReport:
    """Verify the campaign in ``path``, even when its ``campaign.toml`` is damaged.

    Parameters
    ----------
    path : Path
        The campaign directory.

    Returns
    -------
    VerifyReport
        Every problem found; a damaged or missing ``campaign.toml`` is one of them.

    Raises
    ------
    CampaignError
        ``path`` is not a campaign at all (no ``campaign.toml`` and no
        ``stations/``), or its ``campaign.toml`` was written by a newer fgcd
        (its format is unknown here, which is not damage).
    """
    path = Path(path)
    try:
        return verify_campaign(open_campaign(path))
    except CampaignError as exc:
        problem = _campaign_file_problem(path, exc)
    report = verify_campaign(Campaign(path, {}))
    report.problems.insert(0, problem)
    return report


def _campaign_file_problem(path: Path, exc: CampaignError) -> Problem:
    """The damage ``open_campaign`` ran into, or ``exc`` again when it is not damage."""
    cfile = path / CAMPAIGN_FILE
    if not cfile.exists():
        if not (path / STATIONS_DIR).is_dir():
            raise exc  # not a campaign: nothing to verify
        return Problem(str(cfile), "missing", f"{CAMPAIGN_FILE} is gone (the campaign's site and rig settings)")
    if _written_by_newer_fgcd(cfile):
        raise exc
    return Problem(str(cfile), "campaign", str(exc).removeprefix(f"{cfile}: "))


def _written_by_newer_fgcd(cfile: Path) -> bool:
    """True when ``campaign.toml`` parses and declares a format newer than this fgcd's."""
    try:
        version = tomllib.loads(cfile.read_text(encoding="utf-8")).get("campaign", {}).get("format_version")
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError, AttributeError):
        return False
    return isinstance(version, int) and version > FORMAT_VERSION


def verify_campaign(campaign: Campaign) -> VerifyReport:
    """Check every observation's manifest and checksums, and leftovers of killed writes."""
    report = VerifyReport(str(campaign.path))
    for sname in campaign.station_names():
        _verify_station(_open_station(campaign, sname, report), report)
    _verify_rig(campaign.path / RIG_DIR, report)
    return report


def _open_station(campaign: Campaign, name: str, report: VerifyReport) -> Station:
    """The station, with an empty record when its ``station.json`` is damaged (named in the report)."""
    path = campaign.path / STATIONS_DIR / name
    info, problem = _read_station_info(path / STATION_FILE)
    if problem is not None:
        report.problems.append(problem)
    return Station(campaign, name, path, info)


def _read_station_info(sfile: Path) -> tuple[dict, Problem | None]:
    """``station.json`` as a dict, or ``{}`` and the problem that makes it unusable."""
    if not sfile.exists():
        return {}, Problem(str(sfile), "station", f"{STATION_FILE} missing (the station's record of its observations)")
    try:
        info = json.loads(sfile.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        return {}, Problem(str(sfile), "station", f"not valid JSON ({exc})")
    except OSError as exc:
        return {}, Problem(str(sfile), "station", f"cannot be read ({exc.strerror or exc})")
    if not isinstance(info, dict):
        return {}, Problem(str(sfile), "station", "not a JSON object")
    index = info.get("observations")
    if index is not None and not (isinstance(index, list) and all(isinstance(r, str) for r in index)):
        # The index cannot be trusted: compare nothing against it, check the observations anyway.
        info = {k: v for k, v in info.items() if k != "observations"}
        return info, Problem(str(sfile), "station", "'observations' is not a list of observation paths")
    return info, None


def _observation_dirs(st: Station) -> list[Path]:
    """The reference and visit directories present on disk."""
    candidates = [st.reference_path] if st.reference_path.exists() else []
    vdir = st.path / VISITS_DIR
    if vdir.is_dir():
        candidates += sorted(p for p in vdir.iterdir() if p.is_dir() and not p.name.startswith("."))
    return candidates


def _verify_station(st: Station, report: VerifyReport) -> None:
    """Every observation of the station, its index (when readable) and write leftovers."""
    candidates = _observation_dirs(st)
    for obs in candidates:
        _verify_observation(obs, report)
    index = st.indexed_observations()
    if index is not None:
        present = {obs.relative_to(st.path).as_posix() for obs in candidates}
        for rel in index:
            if rel not in present:
                report.problems.append(
                    Problem(str(st.path / rel), "missing", "observation recorded in station.json is gone")
                )
        for rel in sorted(present - set(index)):
            report.problems.append(
                Problem(
                    str(st.path / rel),
                    "unindexed",
                    f"observation not recorded in {STATION_FILE} (a write "
                    "interrupted between its commit and the index update, or a folder copied in)",
                    "warning",
                )
            )
    journal = st.path / VISITS_DIR / VISIT_JOURNAL
    if journal.exists():
        report.problems.append(_journal_problem(journal, st))
    for parent in [st.path, st.path / VISITS_DIR]:
        if parent.is_dir():
            for p in sorted(parent.iterdir()):
                if p.name.startswith(TMP_PREFIX):
                    report.problems.append(Problem(str(p), "incomplete-write", _leftover_detail(p, parent), "warning"))


def _verify_rig(rig: Path, report: VerifyReport) -> None:
    """Every rig record's embedded checksum."""
    if not rig.is_dir():
        return
    for p in sorted(rig.rglob("*.json")):
        report.files_checked += 1
        try:
            load_rig_record(p)
        except DataIntegrityError as exc:
            report.problems.append(Problem(str(p), "checksum", f"rig record: {str(exc).removeprefix(str(p) + ': ')}"))
        except OSError as exc:
            report.problems.append(Problem(str(p), "unreadable", f"rig record cannot be read ({exc.strerror or exc})"))


# ----------------------------------------------------------------------------- leftovers of interrupted writes
#: Files and folders a diff or report adds to a visit after its commit (docs/user-guide.md, the campaign folder).
_DERIVED = (f"{CHANGES_DIR}/", REPORT_HTML, AFD_JSON)


def _unlisted_detail(rel: str) -> str:
    """Why a file of an observation is not in its manifest, as far as its name tells."""
    if rel.startswith(_DERIVED):
        return (
            "a derived product whose manifest entry was not written (an interrupted `fgcd diff` or report): "
            "`fgcd diff` on this visit writes and lists it again; safe to delete"
        )
    return "file not in the manifest"


def _leftover_detail(path: Path, parent: Path) -> str:
    """What a store temporary (``.tmp-*``) in a station or its visits folder was being written."""
    if path.is_dir():
        what = "reference" if parent.name != VISITS_DIR else f"visit {path.name[len(TMP_PREFIX) :].rsplit('-', 1)[0]}"
        files = sum(1 for p in path.rglob("*") if p.is_file())
        state = "complete but not moved into place" if (path / MANIFEST).is_file() else "without its manifest"
        return (
            f"the {what} being written when the process stopped ({counted(files, 'file')}, {state}); "
            "nothing was committed; safe to delete"
        )
    target = path.name[len(TMP_PREFIX) :].rsplit(".", 1)[0]
    return f"a write of {target} interrupted before its rename (the {target} in place is intact); safe to delete"


def _journal_problem(journal: Path, st: Station) -> Problem:
    """The journal of a revisit in progress: a note when intact, a warning when a kill cut it or its visit was
    committed, an error when damaged otherwise (each line is written whole and fsynced, app/visit_journal.py)."""
    try:
        data = journal.read_bytes()
    except OSError as exc:
        return Problem(str(journal), "unreadable", f"the revisit journal cannot be read ({exc.strerror or exc})")
    lines = data.decode("utf-8", errors="replace").splitlines()
    entries = []
    for number, line in enumerate(lines, start=1):
        try:
            entries.append(json.loads(line))
        except ValueError:
            if number < len(lines) or data.endswith(b"\n"):
                return Problem(
                    str(journal),
                    "journal",
                    f"revisit journal damaged at line {number} (not what an "
                    "interrupted write leaves): `fgcd relocate --resume` will start over",
                )
            held = (
                f"the {counted(len(entries) - 1, 'adjustment')} before it hold: `fgcd relocate --resume` "
                "continues after them"
                if len(entries) > 1
                else "nothing to continue: `fgcd relocate` replaces it"
            )
            return Problem(
                str(journal),
                "incomplete-write",
                f"the revisit journal's last line (line {number}) was cut short by an interrupted write; {held}",
                "warning",
            )
    if not entries:
        return Problem(
            str(journal),
            "incomplete-write",
            "an empty revisit journal (the revisit stopped while "
            "writing its first line): `fgcd relocate` replaces it; safe to delete",
            "warning",
        )
    if not (isinstance(entries[0], dict) and entries[0].get("kind") == "start"):
        return Problem(
            str(journal),
            "journal",
            "revisit journal damaged: its first line is not the start line; `fgcd relocate --resume` will start over",
        )
    committed = committed_visit_of_journal(st, [e.get("record") if isinstance(e, dict) else None for e in entries[1:]])
    if committed is not None:
        return Problem(
            str(journal),
            "incomplete-write",
            f"the revisit this journal records was committed as "
            f"visits/{committed}; the journal is left from a stop right after that commit: safe to "
            "delete (`fgcd relocate --resume` would record another visit)",
            "warning",
        )
    # A note, not a warning: nothing is wrong, and deleting the journal loses the resumable revisit.
    return Problem(
        str(journal),
        "interrupted-visit",
        f"a revisit of station '{st.name}' was interrupted: "
        "`fgcd relocate --resume` continues it (a new `fgcd relocate` replaces it)",
        "note",
    )


def committed_visit_of_journal(st: Station, records: list) -> str | None:
    """The latest visit when its relocation log holds exactly the journal's adjustments (the journal outlived it).

    The one rule for a journal left by a stop between a visit's commit and the journal's removal: both
    ``campaign verify`` and ``fgcd relocate --resume`` (:func:`fgcd_cli.app.visit_journal.decide_resume`) use it.
    """
    names = st.visit_names()
    if not records or not names:
        return None
    log = st.path / VISITS_DIR / names[-1] / RELOCATION_LOG
    try:
        logged = [json.loads(line) for line in log.read_text(encoding="utf-8").splitlines() if line.strip()]
    except (OSError, ValueError):
        return None
    return names[-1] if logged == records else None
