"""Motion faults inside a whole ``fgcd relocate`` whose motions go through the real GRBL and UR drivers.

Each fault runs a real ``fgcd relocate`` of a station captured on the same
wired rig (:mod:`fgcd_cli.bench.faults.wired_launch`: the simulated world is the
camera and the scene, the real driver behind the MotionGuard is the platform,
against the GRBL pty emulator or the fake UR controller). The fault hits at a
seeded instant while the emulator itself reports motion, in the exploration
or in the adjustments (drawn from the seed): the cable pulled, an alarm, a
silent controller, garbage on the line; a protective stop, the RTDE link
closed, a frozen controller. Afterwards the emulator's *own* state says
whether the platform still moves (a pulled cable or a hung link cannot carry
a stop: judged after :data:`fgcd_cli.bench.faults.motion.BLOCK_END_S`), and the
exit code, the one stderr line, ``campaign verify`` and the earlier data are
judged as for every fault (:class:`fgcd_cli.bench.faults.checks.FaultOutcome`).
"""

from __future__ import annotations

import json
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fgcd_cli.bench.faults.campaign_faults import calibrate_campaign
from fgcd_cli.bench.faults.checks import (
    FaultOutcome,
    campaign_problems,
    committed_digests,
    earlier_changed,
    run_fgcd,
    wait_until,
)
from fgcd_cli.bench.faults.motion import BLOCK_END_S, EXIT_PLATFORM
from fgcd_cli.bench.faults.wired_rig import ENV_LOG, ENV_TARGET
from fgcd_cli.campaign import schema

__all__ = [
    "FAULTS",
    "PER_CLASS_FULL",
    "STATIONS",
    "WiredPlan",
    "clean_revisit",
    "draw_plan",
    "inject",
    "prepare_wired_station",
]

FAULTS = (
    "relocate_grbl_link_lost",
    "relocate_grbl_alarm",
    "relocate_grbl_silent",
    "relocate_grbl_garbage",
    "relocate_ur_protective_stop",
    "relocate_ur_link_lost",
    "relocate_ur_frozen",
)
PER_CLASS_FULL = 5
#: The wired stations of the bench campaign, captured once each through the launcher.
STATIONS = {"grbl": "wired-grbl", "ur": "wired-ur"}
#: Motions of a wired revisit the fault may land in, per stage (sub-steps of 5 mm / 1 deg): no more than a clean
#: wired revisit from the bench's 30 mm start makes in that stage (adjustment faults explore with the fixed
#: pattern, whose first adjustments carry the start offset); the counts: docs/lab/2026-12-02-faults.md.
MOTIONS = {"exploration": 24, "adjustment": 6}
#: Latest moment inside a sub-step the fault is drawn at, s (a 5 mm sub-step lasts 0.25 s at 20 mm/s).
MAX_DELAY_S = 0.15
#: A GRBL stage mid-travel, so that every motion of a revisit is inside its soft limits.
GRBL_TRAVEL_MM, GRBL_START_MM = 400.0, -200.0
#: Longest wait for the fake UR's fixed ports (another run's fake may hold them), s.
UR_PORTS_WAIT_S = 300.0
#: Faults whose stop can still reach the controller (the others: no stop can travel).
_CAN_STOP = ("relocate_grbl_alarm", "relocate_grbl_garbage", "relocate_ur_protective_stop")
_UR_COMMANDS = {
    "relocate_ur_protective_stop": "protective_stop",
    "relocate_ur_link_lost": "disconnect",
    "relocate_ur_frozen": "freeze",
}


@dataclass(frozen=True, kw_only=True)
class WiredPlan:
    """Where and how one wired fault hits: the stage, which of its motions, the delay inside it, the fault's bytes."""

    fault: str
    phase: str
    motion: int
    delay_s: float
    alarm: int = 2
    garbage: bytes = b""


def draw_plan(fault: str, seed: int) -> WiredPlan:
    """The seeded instant of a fault: every draw from ``np.random.default_rng(seed)``."""
    rng = np.random.default_rng(seed)
    phase = str(rng.choice(sorted(MOTIONS)))
    motion = int(rng.integers(0, MOTIONS[phase]))
    delay = float(rng.uniform(0.0, MAX_DELAY_S))
    alarm = int(rng.choice([2, 3]))  # soft limit, abort
    garbage = bytes(rng.integers(0, 256, size=int(rng.integers(1, 64)), dtype=np.uint8))
    return WiredPlan(fault=fault, phase=phase, motion=motion, delay_s=delay, alarm=alarm, garbage=garbage)


class _GrblSide:
    """The GRBL pty emulator as the injector sees it."""

    kind = "grbl"

    def __init__(self, emu) -> None:
        self.emu = emu
        self.target = f"grbl:{emu.port}"
        self.start = np.array(emu.position())

    def moving(self) -> bool:
        return self.emu.moving()

    def travelled_mm(self) -> float:
        """How far the emulator's own MPos is from where it started."""
        return float(np.linalg.norm(np.array(self.emu.position()) - self.start))

    def hit(self, plan: WiredPlan) -> None:
        if plan.fault == "relocate_grbl_link_lost":
            self.emu.unplug()
        elif plan.fault == "relocate_grbl_alarm":
            self.emu.inject_alarm(plan.alarm)
        elif plan.fault == "relocate_grbl_silent":
            self.emu.set_silent(True)
        elif plan.fault == "relocate_grbl_garbage":
            self.emu.inject_garbage(plan.garbage)


class _URSide:
    """The fake UR controller process as the injector sees it."""

    kind = "ur"
    target = "ur:127.0.0.1"

    def __init__(self, fake) -> None:
        self.fake = fake
        self.seen_moving = False

    def moving(self) -> bool:
        moving = self.fake.state()["moving"] == 1
        self.seen_moving = self.seen_moving or moving
        return moving

    def travelled_mm(self) -> float:
        """The fake's state has no pose: 1 when it was seen moving, else 0 (a flag, not a distance)."""
        return float(self.seen_moving)

    def watchdog_stops(self) -> int | None:
        """How often the fake's RTDE watchdog stopped the program (None: a fake that does not say)."""
        value = self.fake.state().get("watchdog_stops")
        return None if value is None else int(value)

    def hit(self, plan: WiredPlan) -> None:
        self.fake.send(_UR_COMMANDS[plan.fault])


@contextmanager
def _controller(kind: str) -> Iterator[object]:
    """A fresh emulator for one run: GRBL on a pty, or the fake UR process (fixed ports: one at a time)."""
    if kind == "grbl":
        from fgcd_drivers.testing.grbl_emulator import GrblEmulator

        emu = GrblEmulator(max_travel_mm=GRBL_TRAVEL_MM, start_mm=[GRBL_START_MM] * 3)
        try:
            yield _GrblSide(emu)
        finally:
            emu.close()
        return
    from fgcd_drivers.testing.fake_ur import FakeURProcess

    deadline = time.monotonic() + UR_PORTS_WAIT_S
    while True:  # the fixed ports may be held by another run's fake for a while: wait for them
        try:
            fake = FakeURProcess().start()
            break
        except RuntimeError:
            if time.monotonic() > deadline:
                raise
            time.sleep(5.0)
    try:
        yield _URSide(fake)
    finally:
        fake.stop()


def _wired(side, log: Path) -> dict:
    return {ENV_TARGET: side.target, ENV_LOG: str(log)}


def prepare_wired_station(campaign: Path, kind: str) -> str:
    """Capture the wired station of ``kind`` in the bench campaign through the launcher (once); its name.

    Raises
    ------
    RuntimeError
        The capture failed, or the emulator did not move (the run was not through the driver).
    """
    calibrate_campaign(campaign)
    station = STATIONS[kind]
    reference = Path(campaign) / schema.STATIONS_DIR / station / schema.REFERENCE_DIR / schema.MANIFEST
    if reference.is_file():
        return station
    with tempfile.TemporaryDirectory(prefix="fgcd-wired-") as tmp, _controller(kind) as side:
        log = Path(tmp) / "motions.jsonl"
        run = run_fgcd(
            ["capture", "-c", str(campaign), "-s", station, "--light", "led:3,led:9", "--yes", "--json"],
            launcher=["fgcd_cli.bench.faults.wired_launch"],
            env=_wired(side, log),
            timeout_s=1800,
        )
        if run.code != 0 or not reference.is_file():
            raise RuntimeError(f"the wired {kind} station's capture failed: {(run.lines or ['?'])[-1]}")
    return station


def _revisit_args(campaign: Path, kind: str, session_seed: int, *, guided: bool = True) -> list[str]:
    """``fgcd relocate`` of the wired station; an XYZ stage cannot turn, so its start is displaced without rotation.

    A guided exploration ends near the reference and leaves the adjustments a
    sub-millimetre step; a fault meant for the adjustments explores with the
    fixed pattern (``--no-guided``), whose adjustments travel the whole offset.
    """
    args = [
        "relocate",
        "-c",
        str(campaign),
        "-s",
        STATIONS[kind],
        "--yes",
        "--json",
        "--session-seed",
        str(session_seed),
    ]
    return args + (["--start-offset-deg", "0"] if kind == "grbl" else []) + ([] if guided else ["--no-guided"])


def clean_revisit(campaign: Path, kind: str, *, session_seed: int = 1, guided: bool = True) -> dict:
    """A wired revisit without fault: exit code, motions per stage, the emulator's travel, the final true error."""
    prepare_wired_station(campaign, kind)
    with tempfile.TemporaryDirectory(prefix="fgcd-wired-") as tmp, _controller(kind) as side:
        log = Path(tmp) / "motions.jsonl"
        if kind == "ur":
            import threading

            done = threading.Event()

            def watch(proc) -> None:  # the fake's state has no pose: it is watched for motion instead
                while proc.poll() is None and not done.is_set():
                    side.moving()
                    time.sleep(0.05)

            run = run_fgcd(
                _revisit_args(campaign, kind, session_seed, guided=guided),
                inject=watch,
                launcher=["fgcd_cli.bench.faults.wired_launch"],
                env=_wired(side, log),
                timeout_s=1800,
            )
            done.set()
        else:
            run = run_fgcd(
                _revisit_args(campaign, kind, session_seed, guided=guided),
                launcher=["fgcd_cli.bench.faults.wired_launch"],
                env=_wired(side, log),
                timeout_s=1800,
            )
        motions = _motions(log)
        return {
            "code": run.code,
            "seconds": round(run.seconds, 1),
            "motions": {p: motions.count(p) for p in set(motions)},
            "emulator_travel_mm": round(side.travelled_mm(), 2),
            "last_line": (run.lines or [""])[-1],
        }


def _motions(log: Path) -> list[str]:
    """The stages of the motions announced so far."""
    try:
        text = log.read_text(encoding="utf-8")
    except OSError:
        return []
    return [json.loads(line)["phase"] for line in text.splitlines() if line.strip().endswith("}")]


def _injector(side, plan: WiredPlan, log: Path, record: dict):
    """The injection thread's body: the plan's motion, the emulator moving, the delay, the fault while it moves."""

    def reached() -> bool:
        return _motions(log).count(plan.phase) > plan.motion

    def inject(proc) -> None:
        if not wait_until(reached, timeout_s=1200, proc=proc):
            record["missed"] = f"the revisit ended before {plan.phase} motion {plan.motion + 1}"
            return
        for attempt in range(1, 21):  # the fault lands inside a motion: a sub-step that ended first is skipped
            if not wait_until(side.moving, timeout_s=30, proc=proc):
                break
            time.sleep(plan.delay_s)
            if side.moving():
                record.update(attempts=attempt, travelled_mm=round(side.travelled_mm(), 2))
                hit = time.monotonic()
                side.hit(plan)
                # how long the emulator went on moving after the fault (the rest of its block, or the stop)
                if wait_until(lambda: not side.moving(), timeout_s=BLOCK_END_S * 2):
                    record["moved_after_s"] = round(time.monotonic() - hit, 3)
                return
        record["missed"] = f"no motion lasted {plan.delay_s:.3f} s after {plan.phase} motion {plan.motion + 1}"

    return inject


def _left_moving(side, fault: str) -> bool:
    """The emulator's own state after the command: still moving (BLOCK_END_S where no stop could travel)."""
    if side.kind == "grbl" and fault not in _CAN_STOP:
        return not wait_until(lambda: not side.moving(), timeout_s=BLOCK_END_S)
    if side.kind == "grbl":
        return side.moving()
    return not wait_until(lambda: not side.moving(), timeout_s=0.5)


def inject(fault: str, seed: int, campaign: Path) -> FaultOutcome:
    """One wired fault in a whole ``fgcd relocate``, judged on the emulator's own state and the campaign."""
    if fault not in FAULTS:
        raise ValueError(f"unknown fault '{fault}'")
    kind = "grbl" if "_grbl_" in fault else "ur"
    campaign = Path(campaign)
    prepare_wired_station(campaign, kind)
    plan = draw_plan(fault, seed)
    before = committed_digests(campaign)
    record: dict = {}
    with tempfile.TemporaryDirectory(prefix="fgcd-wired-") as tmp, _controller(kind) as side:
        log = Path(tmp) / "motions.jsonl"
        args = _revisit_args(campaign, kind, 1 + seed % 1000, guided=plan.phase == "exploration")
        run = run_fgcd(
            args,
            inject=_injector(side, plan, log, record),
            launcher=["fgcd_cli.bench.faults.wired_launch"],
            env=_wired(side, log),
            timeout_s=1200,
        )
        moving = _left_moving(side, fault)
        motions = len(_motions(log))
        watchdog = side.watchdog_stops() if kind == "ur" else None
    changed = earlier_changed(before, committed_digests(campaign))
    problems = campaign_problems(campaign)
    expected = (0, 6, EXIT_PLATFORM) if fault == "relocate_grbl_garbage" else (EXIT_PLATFORM,)
    if "missed" in record:
        expected = ()  # the fault never hit a motion: not a pass, whatever the exit
    extra = {
        "phase": plan.phase,
        "motion": plan.motion + 1,
        "delay_s": round(plan.delay_s, 3),
        "motions": motions,
        "attempts": record.get("attempts"),
        "travelled_mm": record.get("travelled_mm"),
        "moved_after_s": record.get("moved_after_s"),
        "watchdog_stops": watchdog,
    }
    line = (run.error_lines or run.lines or [""])[-1]
    detail = "; ".join(problems + changed) or (f"{record['missed']}: {line}" if "missed" in record else line)
    return FaultOutcome(
        fault=fault,
        seed=seed,
        command=f"relocate (wired {kind})",
        code=run.code,
        expected=expected,
        stderr_lines=run.failure_lines,
        traceback=run.traceback,
        platform_left_moving=moving,
        campaign_inconsistent=bool(problems),
        earlier_data_changed=bool(changed),
        detail=detail,
        one_line_expected=run.code != 0,
        extra=extra,
        landed="missed" not in record,
    )
