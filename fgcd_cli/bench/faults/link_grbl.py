"""GRBL link cuts of ``fgcd bench faults``: the serial line closed from the board's side mid-move.

The GRBL emulator's pty is closed under a real ``fgcd platform move`` at a
seeded moment (:meth:`~fgcd_drivers.testing.grbl_emulator.GrblEmulator.unplug`),
as a pulled USB cable: nothing reaches the board any more, not even a feed hold.
The board ends the one block it holds (fgcd never queues more), so its stated
bound is that block's remaining time at the cut. The cable is then plugged
back (:meth:`~fgcd_drivers.testing.grbl_emulator.GrblEmulator.replug`, a new
``/dev/pts`` path) and the reconnect is judged (docs/hardware.md, "Faults in the field"):

* ``link_cut_grbl_move``: exit 7 in one line within :data:`COMMAND_END_S` of
  the cut; the board idle within its block's remaining time (plus
  :data:`STOP_MARGIN_S`); ``fgcd platform check`` on the new port healthy;
* ``link_cut_grbl_reconnect``: an alarm is raised while the cable is out (a hard
  limit, or a reset that lost the position): ``fgcd platform check`` reports it
  (exit 7, one line), ``fgcd platform move`` is refused without a motion line,
  the board stays in alarm (no ``$X``/``$H`` sent by a connect) until a person
  runs ``fgcd platform home``.
"""

from __future__ import annotations

import time

import numpy as np

from fgcd_cli.bench.faults.checks import FaultOutcome, run_fgcd, wait_until
from fgcd_cli.bench.faults.motion import EXIT_PLATFORM, GRBL_MOVE, _is_motion

__all__ = ["COMMAND_END_S", "GRBL_LINK_FAULTS", "STOP_MARGIN_S", "grbl_link_fault"]

GRBL_LINK_FAULTS = ("link_cut_grbl_move", "link_cut_grbl_reconnect")
#: The board's idle state may be seen this much after its block's end (the emulator's 5 ms motion
#: loop and the judge's 10 ms poll, on a machine shared with five other jobs).
STOP_MARGIN_S = 0.5
#: After the cut the command ends within: the reader's next read fails at once (EIO), then one line and
#: the process exit; the answer timeout (``GRBL_MOVE``'s ``--timeout``) bounds a read that hangs instead.
COMMAND_END_S = float(GRBL_MOVE[GRBL_MOVE.index("--timeout") + 1]) + 2.0


def _cut_mid_move(emu, delay: float, seen: dict):
    """The injection: wait for the motion line, ``delay`` more, pull the cable; then time the board's stop."""

    def inject(proc) -> None:
        if not wait_until(lambda: any(_is_motion(line) for line in emu.lines_received), timeout_s=60, proc=proc):
            return
        time.sleep(delay)
        if proc.poll() is not None:
            return
        seen["block_left_s"] = emu.block_left_s()
        emu.unplug()
        seen["cut"] = time.monotonic()
        if wait_until(lambda: not emu.moving(), timeout_s=30):
            seen["stopped"] = time.monotonic()

    return inject


def _grbl(*args: str, port: str) -> list[str]:
    return ["platform", *args, "--driver", "grbl", "--port", port]


def _after_replug(fault: str, emu, port: str, code: int | None) -> tuple[bool, str, dict]:
    """The reconnect on the new port: healthy, or (an alarm during the cut) refused until a person homes."""
    mark = len(emu.lines_received)
    check = run_fgcd([*_grbl("check", port=port), "--json"], timeout_s=120)
    info = {"reconnect_code": check.code, "reconnect_s": round(check.seconds, 2)}
    if code is None:
        ok = check.code == 0 and emu.state == "Idle" and check.failure_lines == 0
        return ok, "" if ok else f"reconnect: code {check.code}, {(check.lines or [''])[-1]}", info
    move = run_fgcd([*_grbl("move", port=port), "--yes", *GRBL_MOVE], timeout_s=120)
    sent = emu.lines_received[mark:]
    unlocked = [line for line in sent if line.upper() in ("$X", "$H")]
    moved = [line for line in sent if _is_motion(line)]
    still = emu.state == "Alarm"
    home = run_fgcd([*_grbl("home", port=port), "--yes"], timeout_s=120)
    info.update(refused_move_code=move.code, home_code=home.code)
    problems = [
        text
        for bad, text in (
            (check.code != EXIT_PLATFORM or check.failure_lines != 1, f"check gave {check.code}: {check.lines[-1:]}"),
            (move.code != EXIT_PLATFORM or move.failure_lines != 1, f"move gave {move.code}: {move.lines[-1:]}"),
            (bool(unlocked), f"a connect sent {unlocked}"),
            (bool(moved), f"a motion line reached the board: {moved}"),
            (not still, f"the alarm was left before a person homed ({emu.state})"),
            (home.code != 0 or emu.state != "Idle", f"fgcd platform home gave {home.code}, state {emu.state}"),
            (check.traceback or move.traceback or home.traceback, "a traceback"),
        )
        if bad
    ]
    return not problems, "reconnect: " + "; ".join(problems), info


def grbl_link_fault(fault: str, seed: int) -> FaultOutcome:
    """One GRBL cable pull mid-move, then the cable back and the reconnect judged."""
    from fgcd_drivers.testing.grbl_emulator import GrblEmulator

    rng = np.random.default_rng(seed)
    delay = float(rng.uniform(0.05, 0.8))  # inside the 1 s block
    alarm = int(rng.choice([1, 3])) if fault == "link_cut_grbl_reconnect" else None  # hard limit, lost position
    emu = GrblEmulator(time_scale=1.0)
    emu.settings[22] = 1  # homing cycle enabled ($22), so a person can home after an alarm
    seen: dict = {}
    try:
        run = run_fgcd(
            [*_grbl("move", port=emu.port), "--yes", *GRBL_MOVE], inject=_cut_mid_move(emu, delay, seen), timeout_s=120
        )
        ended = time.monotonic()
        cut = seen.get("cut")
        if cut is not None and alarm is not None:
            emu.inject_alarm(alarm)  # while the cable is out: the board's ALARM line reaches no one
        stop_s = None if cut is None or "stopped" not in seen else seen["stopped"] - cut
        bound = seen.get("block_left_s", 0.0) + STOP_MARGIN_S
        outcome = FaultOutcome(
            fault=fault,
            seed=seed,
            command="platform move --driver grbl (cable pulled)",
            code=run.code,
            expected=(EXIT_PLATFORM,) if cut is not None else (0,),
            stderr_lines=run.failure_lines,
            traceback=run.traceback,
            platform_left_moving=cut is not None and (stop_s is None or stop_s > bound),
            detail=(run.error_lines or run.lines or ["the move ended before the cut"])[-1],
            one_line_expected=run.code != 0,
            extra={
                "at_s": round(delay, 3),
                "alarm_during_cut": alarm,
                "block_left_at_cut_s": round(seen.get("block_left_s", 0.0), 3),
                "board_stopped_after_cut_s": None if stop_s is None else round(stop_s, 3),
                "command_ended_after_cut_s": None if cut is None else round(ended - cut, 3),
            },
        )
        if cut is not None and ended - cut > COMMAND_END_S:
            outcome.expected = ()
            outcome.detail = f"the command ended {ended - cut:.1f} s after the cut (stated {COMMAND_END_S:.1f} s)"
        ok, why, info = _after_replug(fault, emu, emu.replug(), alarm if cut is not None else None)
        outcome.extra.update(info)
        if not ok:
            outcome.expected, outcome.detail = (), why
        return outcome
    finally:
        emu.close()
