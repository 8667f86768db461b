"""Campaign faults of ``fgcd bench faults``: real ``fgcd diff`` and ``fgcd relocate`` processes on a campaign,
signalled, starved of disk, doubled, or fed a damaged reference.

The bench campaign holds stations whose reference and visit are simulator
renders written through the store (the same writer ``fgcd capture`` uses):
``s1`` for diffs and concurrent revisits, ``s2`` whose reference is damaged
and repaired around each damaged-reference fault. After every fault the
earlier observations' checksums and ``fgcd campaign verify`` are checked.
"""

from __future__ import annotations

import json
import shutil
import signal
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from fgcd_cli.bench.faults.checks import (
    FaultOutcome,
    campaign_problems,
    committed_digests,
    earlier_changed,
    fresh_station,
    run_fgcd,
    send_signal,
    wait_until,
)
from fgcd_cli.campaign import schema

__all__ = ["DATA_FAULTS", "data_fault", "prepare_campaign"]

DATA_FAULTS = (
    "sigint_during_write",
    "sigkill_during_write",
    "enospc_during_write",
    "two_relocates_at_once",
    "damaged_reference",
)
#: Faults on a whole simulated ``fgcd capture`` (about 90 s each on 2 busy cores): fewer of them per run.
CAPTURE_FAULTS = ("signal_during_capture", "enospc_during_capture")
#: Documented exit codes (README, "Errors").
EXIT_OS, EXIT_CAMPAIGN, EXIT_INTEGRITY, EXIT_ALGORITHM, EXIT_INTERRUPTED = 1, 3, 4, 6, 130


def prepare_campaign(folder: Path) -> Path:
    """A campaign with stations ``s1`` and ``s2``: simulated reference and visit (3 small changes), written once."""
    from fgcd_cli.campaign.store import init_campaign, open_campaign
    from fgcd_drivers.sim.rig import SimRigConfig, build_sim_rig

    path = Path(folder) / "campaign"
    if (path / "campaign.toml").exists():
        return path
    camp = init_campaign(path, site="fault bench", rig={"driver": "sim", "sim": {"scene": "stele", "seed": 0}})
    rig = build_sim_rig(scene="stele", config=SimRigConfig(lighting="led:3", seed=0))
    camp.write_rig("handeye", {"T_flange_cam": np.eye(4).tolist()})
    meta = {
        "lightings": ["led:3", "led:9"],
        "driver": "sim",
        "scenario": {"scene": "stele", "seed": 0, "noise": "default"},
    }

    def images() -> dict[str, np.ndarray]:
        out = {}
        for name in meta["lightings"]:
            rig.lights.set(name)
            frame = rig.camera.grab()
            out[name] = np.asarray(frame.rgb if getattr(frame, "rgb", None) is not None else frame.image)
        return out

    reference = images()
    rng = np.random.default_rng(0)
    points = rng.uniform(-0.05, 0.05, size=(2000, 3)) + [0.0, 0.0, 0.4]
    for name in ("s1", "s2"):
        with camp.station_or_create(name).write_reference(meta) as w:
            for lighting, img in reference.items():
                w.add_image(lighting, img)
            w.add_cloud(points, colors=np.full(len(points), 0.5, np.float32))
            w.add_array(schema.ARRAY_CLOUD_INTENSITIES, np.full(len(points), 0.5, np.float32))
            w.add_array(schema.ARRAY_T_REF_CAMREF, np.eye(4))
            w.commit()
    rig.inject_changes(n=3, seed=1, size_mm=(4.0, 12.0))
    with open_campaign(path).station("s1").new_visit(meta) as w:
        for lighting, img in images().items():
            w.add_image(lighting, img)
        w.commit()
    return path


class _Case(NamedTuple):
    """One injected fault: its class, seed and the command it hit."""

    fault: str
    seed: int
    command: str


def _outcome(
    case: _Case, run, expected, *, campaign, before, allowed=frozenset(), extra: dict | None = None
) -> FaultOutcome:
    """Judge one fault on its run, the campaign's consistency and the earlier data (``extra``: its details)."""
    fault, seed, command = case
    changed = earlier_changed(before, committed_digests(campaign))
    changed = [c for c in changed if str(campaign / schema.STATIONS_DIR / c) not in allowed]
    problems = campaign_problems(campaign, allowed=set(allowed))
    killed = run.code == -signal.SIGKILL
    return FaultOutcome(
        fault=fault,
        seed=seed,
        command=command,
        code=run.code,
        expected=expected,
        stderr_lines=run.failure_lines,
        traceback=run.traceback,
        campaign_inconsistent=bool(problems),
        earlier_data_changed=bool(changed),
        one_line_expected=run.code != 0 and not killed,
        detail="; ".join(problems + changed) or (run.error_lines or run.lines or [""])[-1],
        extra=extra or {},
    )


def _temporaries(campaign: Path) -> set[Path]:
    """The store's temporary files and folders under ``stations/`` (writes in progress, or left by a killed one)."""
    return set((campaign / schema.STATIONS_DIR).rglob(".tmp-*"))


def _signal_fault(fault: str, seed: int, campaign: Path) -> FaultOutcome:
    """SIGINT or SIGKILL to ``fgcd diff`` at a random moment, or (every other seed) during a store write."""
    rng = np.random.default_rng(seed)
    sig = signal.SIGINT if fault == "sigint_during_write" else signal.SIGKILL
    during_write = seed % 2 == 0  # otherwise any moment (store writes of station.json and manifests included)
    delay = float(rng.uniform(0.3, 6.0))
    before = committed_digests(campaign)

    left = _temporaries(campaign)  # leftovers of earlier killed writes are not this run's writes

    def inject(proc) -> None:
        if during_write:
            wait_until(lambda: bool(_temporaries(campaign) - left), timeout_s=120, proc=proc)
        else:
            time.sleep(delay)
        send_signal(proc, sig)

    run = run_fgcd(["diff", "-c", str(campaign), "-s", "s1", "--json"], inject=inject)
    expected = (0, EXIT_INTERRUPTED) if sig == signal.SIGINT else (0, -signal.SIGKILL)
    return _outcome(
        _Case(fault, seed, "diff -c C -s s1"),
        run,
        expected,
        campaign=campaign,
        before=before,
        extra={"moment": "during a write" if during_write else f"at {delay:.2f} s"},
    )


def _enospc_fault(seed: int, campaign: Path) -> FaultOutcome:
    """``fgcd diff`` on a disk that fills after a random number of bytes."""
    rng = np.random.default_rng(seed)
    budget = int(rng.integers(0, 400_000))
    before = committed_digests(campaign)
    run = run_fgcd(
        ["diff", "-c", str(campaign), "-s", "s1", "--json"],
        launcher=["fgcd_cli.bench.faults.launch"],
        env={"FGCD_BENCH_ENOSPC_AFTER": str(budget), "FGCD_BENCH_ENOSPC_UNDER": str(campaign / schema.STATIONS_DIR)},
    )
    return _outcome(
        _Case("enospc_during_write", seed, "diff -c C -s s1 (disk full)"),
        run,
        (0, EXIT_OS),
        campaign=campaign,
        before=before,
        extra={"budget_bytes": budget},
    )


def _lock_holder(campaign: Path, pid: int) -> bool:
    try:
        return json.loads((campaign / schema.LOCKS_DIR / "s1.lock").read_text())["pid"] == pid
    except (OSError, ValueError, KeyError):
        return False


def _two_relocates(seed: int, campaign: Path) -> FaultOutcome:
    """A second ``fgcd relocate`` of a station while the first runs: exit 3 in one line; then the first is stopped."""
    before = committed_digests(campaign)
    second: dict = {}

    def inject(first) -> None:
        if wait_until(lambda: _lock_holder(campaign, first.pid), timeout_s=120, proc=first):
            second["run"] = run_fgcd(
                ["relocate", "-c", str(campaign), "-s", "s1", "--yes", "--session-seed", str(seed)]
            )
        send_signal(first, signal.SIGINT)

    first = run_fgcd(["relocate", "-c", str(campaign), "-s", "s1", "--yes"], inject=inject)
    run = second.get("run")
    if run is None:
        return FaultOutcome(
            fault="two_relocates_at_once",
            seed=seed,
            command="relocate x2",
            code=first.code,
            expected=(EXIT_CAMPAIGN,),
            stderr_lines=first.failure_lines,
            traceback=first.traceback,
            detail="the first relocate never held the lock: " + (first.lines or [""])[-1],
        )
    outcome = _outcome(
        _Case("two_relocates_at_once", seed, "relocate (second, while the first runs)"),
        run,
        (EXIT_CAMPAIGN,),
        campaign=campaign,
        before=before,
        extra={"first_code": first.code},
    )
    outcome.traceback = outcome.traceback or first.traceback
    if first.code not in (EXIT_INTERRUPTED, EXIT_ALGORITHM, 0) or first.failure_lines > 1:
        outcome.detail = f"the first relocate ended with {first.code}: {first.lines[-1:]}"
        outcome.expected = ()
    return outcome


def _damaged_reference(seed: int, campaign: Path) -> FaultOutcome:
    """One byte of a random file of station s2's reference flipped, then ``fgcd relocate``: exit 4, nothing moved."""
    rng = np.random.default_rng(seed)
    ref = campaign / schema.STATIONS_DIR / "s2" / schema.REFERENCE_DIR
    files = sorted(p for p in ref.rglob("*") if p.is_file() and p.name != schema.MANIFEST)
    victim = files[int(rng.integers(len(files)))]
    backup = victim.with_name(".bench-backup")
    shutil.copy2(victim, backup)
    data = bytearray(victim.read_bytes())
    data[int(rng.integers(len(data)))] ^= 0xFF
    victim.write_bytes(bytes(data))
    before = committed_digests(campaign)
    try:
        run = run_fgcd(["relocate", "-c", str(campaign), "-s", "s2", "--yes"], timeout_s=120)
        named = any(str(victim) in p for p in campaign_problems(campaign))
        outcome = _outcome(
            _Case("damaged_reference", seed, "relocate -s s2 (damaged reference)"),
            run,
            (EXIT_INTEGRITY,),
            campaign=campaign,
            before=before,
            allowed={str(victim)},
            extra={"damaged": victim.relative_to(campaign).as_posix()},
        )
        if not named:
            outcome.campaign_inconsistent = True
            outcome.detail = f"campaign verify did not name {victim}"
        return outcome
    finally:
        shutil.move(backup, victim)


def calibrate_campaign(campaign: Path) -> None:
    """The bench campaign's hand-eye from a real ``fgcd calibrate hand-eye`` (simulator), once: captures need it."""
    from fgcd_cli.campaign.store import open_campaign

    marker = campaign / ".bench-calibrated"
    if marker.exists():
        return
    # The faults need a stored hand-eye, not a good one: seed 0's motion pairs fit to 24 mm RMS, over the
    # 12 mm at which `fgcd calibrate hand-eye` refuses to store one (app/calibrate.py, MAX_HANDEYE_RMS_MM).
    run = run_fgcd(
        [
            "calibrate",
            "hand-eye",
            "-c",
            str(campaign),
            "--driver",
            "sim",
            "--scene",
            "stele",
            "--seed",
            "0",
            "--accept-residual",
            "--yes",
            "--json",
        ],
        timeout_s=1800,
    )
    if run.code != 0 or open_campaign(campaign).read_rig("handeye") is None:
        raise RuntimeError(f"the bench campaign's hand-eye calibration failed: {(run.lines or ['?'])[-1]}")
    marker.write_text("ok\n")


def _capture_fault(fault: str, seed: int, campaign: Path) -> FaultOutcome:
    """``fgcd capture`` of a new station, signalled (SIGINT or SIGKILL) or starved of disk at a seeded moment."""
    rng = np.random.default_rng(seed)
    station = fresh_station(campaign, f"{fault.split('_')[0]}-{seed}")  # a new station per fault
    before = committed_digests(campaign)
    args = ["capture", "-c", str(campaign), "-s", station, "--light", "led:3,led:9", "--yes", "--json"]
    if fault == "enospc_during_capture":
        budget = int(rng.integers(0, 1_500_000))  # below the reference's size (two images, cloud)
        run = run_fgcd(
            args,
            launcher=["fgcd_cli.bench.faults.launch"],
            timeout_s=900,
            env={
                "FGCD_BENCH_ENOSPC_AFTER": str(budget),
                "FGCD_BENCH_ENOSPC_UNDER": str(campaign / schema.STATIONS_DIR),
            },
        )
        return _outcome(
            _Case(fault, seed, "capture (disk full)"),
            run,
            (0, EXIT_OS),
            campaign=campaign,
            before=before,
            extra={"budget_bytes": budget},
        )
    sig = signal.SIGKILL if rng.random() < 0.5 else signal.SIGINT
    during_write = seed % 2 == 0
    delay = float(rng.uniform(1.0, 40.0))
    left = _temporaries(campaign)

    def inject(proc) -> None:
        if during_write:  # the observation's temporary folder (files are station.json's, manifests)
            wait_until(lambda: any(p.is_dir() for p in _temporaries(campaign) - left), timeout_s=900, proc=proc)
        else:
            time.sleep(delay)
        send_signal(proc, sig)

    run = run_fgcd(args, inject=inject, timeout_s=900)
    expected = (0, EXIT_INTERRUPTED) if sig == signal.SIGINT else (0, -signal.SIGKILL)
    return _outcome(
        _Case(fault, seed, f"capture ({sig.name})"),
        run,
        expected,
        campaign=campaign,
        before=before,
        extra={"moment": "during the reference write" if during_write else f"at {delay:.1f} s"},
    )


def data_fault(fault: str, seed: int, campaign: Path) -> FaultOutcome:
    """Run one campaign fault."""
    if fault in CAPTURE_FAULTS:
        calibrate_campaign(campaign)
        return _capture_fault(fault, seed, campaign)
    if fault in ("sigint_during_write", "sigkill_during_write"):
        return _signal_fault(fault, seed, campaign)
    if fault == "enospc_during_write":
        return _enospc_fault(seed, campaign)
    if fault == "two_relocates_at_once":
        return _two_relocates(seed, campaign)
    if fault == "damaged_reference":
        return _damaged_reference(seed, campaign)
    raise ValueError(f"unknown campaign fault '{fault}'")
