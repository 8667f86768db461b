"""Motion faults of ``fgcd bench faults``: a real ``fgcd platform move`` against the GRBL pty emulator or the
fake UR controller, hit mid-move at a seeded random moment.

The move goes through the same MotionGuard and drivers as every capture and
revisit. After the command ends, the emulator's *own* state says whether the
platform still moves: GRBL ``moving()`` (a block executing, not held, not in
alarm), the fake UR's ``state`` (its motion progressing). A pulled cable or a
hung link cannot carry a stop: the board then ends the one block it holds (the
driver never queues more than one), so it is judged after that block's
duration plus a margin (:data:`BLOCK_END_S`).
"""

from __future__ import annotations

import time

import numpy as np

from fgcd_cli.bench.faults.checks import FaultOutcome, run_fgcd, wait_until

__all__ = ["GRBL_FAULTS", "UR_FAULTS", "grbl_fault", "ur_fault"]

#: Exit code of a platform failure (README, "Errors").
EXIT_PLATFORM = 7
#: A GRBL move of the bench: 20 mm at the driver's 20 mm/s (speed fraction 1) takes 1 s.
GRBL_MOVE = ["--dx", "-20", "--speed-fraction", "1", "--max-step-mm", "60", "--timeout", "1.5"]
#: A UR move of the bench: 60 mm at 10 % of the driver's 0.1 m/s takes 6 s.
UR_MOVE = ["--dx", "60", "--speed-fraction", "0.1", "--max-step-mm", "80", "--timeout", "1"]
#: Time after the command's end by which a board that could not be told to stop has ended its block, s.
BLOCK_END_S = 2.5

GRBL_FAULTS = ("grbl_link_dropped", "grbl_garbage", "grbl_alarm", "grbl_hard_limit", "grbl_frozen")
UR_FAULTS = ("ur_protective_stop", "ur_emergency_stop", "ur_frozen", "ur_link_dropped")


def _is_motion(line: str) -> bool:
    """A G-code motion or jog line (``G90 G1 X..``, ``$J=..``)."""
    return line.startswith("$J=") or any(word in ("G0", "G1") for word in line.split())


def _grbl_inject(emu, fault: str, rng: np.random.Generator):
    """The injection thread's body: wait for the motion line, a random delay inside the move, then the fault."""
    delay = float(rng.uniform(0.05, 0.8))
    garbage = bytes(rng.integers(0, 256, size=int(rng.integers(1, 64)), dtype=np.uint8))

    def inject(proc) -> None:
        if not wait_until(lambda: any(_is_motion(line) for line in emu.lines_received), timeout_s=60, proc=proc):
            return
        time.sleep(delay)
        if fault == "grbl_link_dropped":
            emu.unplug()
        elif fault == "grbl_garbage":
            emu.inject_garbage(garbage)
        elif fault == "grbl_alarm":
            emu.inject_alarm(int(rng.choice([2, 3])))  # soft limit, abort
        elif fault == "grbl_hard_limit":
            emu.inject_alarm(1)
        elif fault == "grbl_frozen":
            emu.set_silent(True)

    return inject, delay


def grbl_fault(fault: str, seed: int) -> FaultOutcome:
    """One GRBL fault mid-move; the outcome judged on the emulator's own state."""
    from fgcd_drivers.testing.grbl_emulator import GrblEmulator

    rng = np.random.default_rng(seed)
    emu = GrblEmulator(time_scale=1.0)
    try:
        inject, delay = _grbl_inject(emu, fault, rng)
        run = run_fgcd(
            ["platform", "move", "--driver", "grbl", "--port", emu.port, "--yes", *GRBL_MOVE],
            inject=inject,
            timeout_s=120,
        )
        could_stop = fault not in ("grbl_link_dropped", "grbl_frozen")
        moving = emu.moving() if could_stop else not wait_until(lambda: not emu.moving(), timeout_s=BLOCK_END_S)
        expected = (0, EXIT_PLATFORM) if fault == "grbl_garbage" else (EXIT_PLATFORM,)
        # a fault that lands after arrival (the delay is drawn inside a nominal 1 s move) is no fault: exit 0 is right
        if run.code == 0 and fault != "grbl_garbage":
            expected = (0, EXIT_PLATFORM)
        return FaultOutcome(
            fault=fault,
            seed=seed,
            command="platform move --driver grbl",
            code=run.code,
            expected=expected,
            stderr_lines=run.failure_lines,
            traceback=run.traceback,
            platform_left_moving=moving,
            detail=(run.error_lines or run.lines or [""])[-1],
            one_line_expected=run.code != 0,
            extra={"at_s": round(delay, 3)},
        )
    finally:
        emu.close()


def ur_fault(fault: str, seed: int, fake) -> FaultOutcome:
    """One UR fault mid-move on a fresh fake controller process ``fake`` (started, fixed ports)."""
    rng = np.random.default_rng(seed)
    delay = float(rng.uniform(0.5, 4.0))  # inside the 6 s move, after the client has connected and started it
    command = {
        "ur_protective_stop": "protective_stop",
        "ur_emergency_stop": "emergency_stop",
        "ur_frozen": "freeze",
        "ur_link_dropped": "disconnect",
    }[fault]

    def inject(proc) -> None:
        if not wait_until(lambda: fake.state()["moving"] == 1, timeout_s=60, proc=proc):
            return
        time.sleep(delay)
        fake.send(command)

    run = run_fgcd(
        ["platform", "move", "--driver", "ur", "--host", "127.0.0.1", "--yes", *UR_MOVE], inject=inject, timeout_s=120
    )
    moving = not wait_until(lambda: fake.state()["moving"] == 0, timeout_s=0.5)
    return FaultOutcome(
        fault=fault,
        seed=seed,
        command="platform move --driver ur",
        code=run.code,
        expected=(EXIT_PLATFORM,),
        stderr_lines=run.failure_lines,
        traceback=run.traceback,
        platform_left_moving=moving,
        detail=(run.error_lines or run.lines or [""])[-1],
        extra={"at_s": round(delay, 3)},
    )
