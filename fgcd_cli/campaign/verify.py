"""`fgcd campaign verify`: check every manifest and checksum, name each problem."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

from fgcd_cli.campaign.atomic import TMP_PREFIX, sha256_file
from fgcd_cli.campaign.store import MANIFEST, Campaign, load_rig_record
from fgcd_cli.errors import DataIntegrityError

__all__ = ["Problem", "VerifyReport", "verify_campaign"]


@dataclass(frozen=True)
class Problem:
    """One damaged, missing or unexpected file."""

    path: str
    kind: str  # missing | checksum | size | manifest | station | unindexed | unlisted | incomplete-write
    detail: str
    severity: str = "error"  # error | warning


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

    def to_dict(self) -> dict:
        """JSON-friendly form."""
        return {
            "campaign": self.campaign,
            "ok": self.ok,
            "observations": self.observations,
            "files_checked": self.files_checked,
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
        if sha256_file(p) != entry.get("sha256"):
            report.problems.append(Problem(str(p), "checksum", "sha256 does not match the manifest"))
    listed = set(files) | {MANIFEST}
    for p in sorted(obs_path.rglob("*")):
        if p.is_file():
            rel = p.relative_to(obs_path).as_posix()
            if rel not in listed:
                kind = "incomplete-write" if p.name.startswith(TMP_PREFIX) else "unlisted"
                report.problems.append(Problem(str(p), kind, "file not in the manifest", "warning"))


def verify_campaign(campaign: Campaign) -> VerifyReport:
    """Check every observation's manifest and checksums, and leftovers of killed writes."""
    report = VerifyReport(str(campaign.path))
    for sname in campaign.station_names():
        try:
            st = campaign.station(sname)
        except DataIntegrityError as exc:
            # station.json damaged: name it and go on with the other stations.
            report.problems.append(Problem(str(campaign.path / "stations" / sname / "station.json"), "station", str(exc)))
            continue
        candidates = [st.reference_path] if st.reference_path.exists() else []
        vdir = st.path / "visits"
        if vdir.is_dir():
            candidates += sorted(p for p in vdir.iterdir() if p.is_dir() and not p.name.startswith("."))
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
                    Problem(str(st.path / rel), "unindexed", "observation not recorded in station.json", "warning")
                )
        for parent in [st.path, vdir]:
            if parent.is_dir():
                for p in parent.iterdir():
                    if p.name.startswith(TMP_PREFIX):
                        report.problems.append(
                            Problem(str(p), "incomplete-write", "left by an interrupted write; safe to delete", "warning")
                        )
    rig = campaign.path / "rig"
    if rig.is_dir():
        for p in sorted(rig.rglob("*.json")):
            report.files_checked += 1
            try:
                load_rig_record(p)
            except DataIntegrityError as exc:
                report.problems.append(Problem(str(p), "checksum", f"rig record: {str(exc).removeprefix(str(p) + ': ')}"))
    return report
