"""UR link cuts of ``fgcd bench faults``: the network to the fake UR controller cut from outside.

The fake controller runs in its own network namespace (or, where namespaces are
not permitted, behind a TCP proxy; :mod:`fgcd_drivers.testing.link_cut`), so a
cut loses every packet both ways with no RST, RTDE and dashboard alike, as a
pulled cable does. The judge (docs/hardware.md, "Faults in the field"):

* ``fgcd platform move`` ends with exit 7 and one line within
  :data:`COMMAND_END_S` of the cut;
* the arm stops by itself: the driver's RTDE watchdog stops the controller's
  program within ``URConfig.link_stop_s`` of the cut (:data:`STOP_MARGIN_S` more
  for the fake's own 10 ms check on a loaded machine);
* once the link is back, ``fgcd platform check`` connects afresh (pre-flight,
  recipes, TCP, watchdog) and reads the safety state; it releases nothing: a
  protective stop raised while the link was down is still raised after it.
"""

from __future__ import annotations

import time

import numpy as np

from fgcd_cli.bench.faults.checks import FaultOutcome, run_fgcd, wait_until
from fgcd_cli.bench.faults.motion import EXIT_PLATFORM, UR_MOVE

__all__ = ["COMMAND_END_S", "LINK_MOVE", "STOP_MARGIN_S", "UR_LINK_FAULTS", "ur_link_fault"]

UR_LINK_FAULTS = ("link_cut_ur_move", "link_cut_ur_idle")
#: The pre-flight and dashboard timeout of these moves, s: the driver's default (2 s), not ``UR_MOVE``'s 1 s,
#: so that a fake controller slow to answer on a machine at load 20 does not fail the move before the cut.
_TIMEOUT_S = 2.0
#: ``UR_MOVE`` (60 mm at 10 mm/s: 6 s) with that timeout.
LINK_MOVE = [*UR_MOVE[: UR_MOVE.index("--timeout")], "--timeout", str(_TIMEOUT_S)]


def _driver_config():
    from fgcd_drivers.ur import URConfig

    return URConfig(host="-", preflight_timeout_s=_TIMEOUT_S)


#: The arm's stop may be seen this much after ``link_stop_s``: the fake checks its watchdog every
#: 10 ms and answers ``state`` through a pipe, both on a machine shared with five other jobs.
STOP_MARGIN_S = 0.5
#: After a cut mid-move, the command ends within: stale state refused (``stale_after_s``), the dashboard
#: ``stop`` on a fresh connection given up (the ``--timeout``), then one line and the process exit.
COMMAND_END_S = _driver_config().stale_after_s + _TIMEOUT_S + 2.0


def _open(fault: str, seed: int, prefer: str):
    """The cuttable link and the fake controller behind it; or a failed outcome saying why not."""
    from fgcd_drivers.testing.fake_ur import FakeURProcess
    from fgcd_drivers.testing.link_cut import LinkUnavailable, open_link

    try:
        link = open_link(prefer=prefer)
    except LinkUnavailable as exc:
        return (
            None,
            None,
            FaultOutcome(
                fault=fault,
                seed=seed,
                command="-",
                code=-1,
                expected=(),
                stderr_lines=0,
                traceback=False,
                detail=f"no cuttable link here: {exc}",
            ),
        )
    fake = FakeURProcess(host=link.fake_host, prefix=link.prefix())
    try:
        fake.start()
    except RuntimeError:
        link.close()
        raise
    return link, fake, None


def _reconnect(link, fake, *, protective: bool) -> tuple[bool, str, dict]:
    """After the link is back: ``fgcd platform check`` connects cleanly and releases nothing."""
    link.restore()
    check = run_fgcd(["platform", "check", "--driver", "ur", "--host", link.address, "--json"], timeout_s=120)
    state = fake.state()
    info = {
        "reconnect_code": check.code,
        "reconnect_s": round(check.seconds, 2),
        "watchdog_stops": state.get("watchdog_stops"),
    }
    if protective:  # the stop raised while the link was down: reported, and still raised afterwards
        ok = check.code == EXIT_PLATFORM and "protective stop" in check.stderr and state["safety"] & 4 != 0
    else:
        ok = check.code == 0 and state["safety"] == 1
    ok = ok and state["moving"] == 0 and not check.traceback and check.failure_lines == (check.code != 0)
    return ok, "" if ok else f"reconnect after the cut: code {check.code}, {(check.lines or [''])[-1]}", info


def _moving_cut(seed: int, link, fake) -> FaultOutcome:
    """The network cut at a seeded moment of a 6 s ``fgcd platform move``."""
    rng = np.random.default_rng(seed)
    delay = float(rng.uniform(0.5, 4.0))
    protective = bool(rng.random() < 0.5)  # someone hits the stop while the link is down
    seen: dict = {}

    def inject(proc) -> None:
        if not wait_until(lambda: fake.state()["moving"] == 1, timeout_s=60, proc=proc):
            return
        time.sleep(delay)
        if proc.poll() is not None:
            return  # the move ended first: no cut
        link.cut()
        seen["cut"] = time.monotonic()
        if wait_until(lambda: fake.state()["moving"] == 0, timeout_s=30):
            seen["stopped"] = time.monotonic()
        if protective:
            fake.send("protective_stop")

    run = run_fgcd(
        ["platform", "move", "--driver", "ur", "--host", link.address, "--yes", *LINK_MOVE],
        inject=inject,
        timeout_s=120,
    )
    seen["ended"] = time.monotonic()
    return _judge(
        ("link_cut_ur_move", seed, "platform move --driver ur (network cut)"),
        run,
        seen,
        link,
        fake,
        protective=protective,
        extra={"at_s": round(delay, 3)},
    )


def _idle_cut(seed: int, link, fake) -> FaultOutcome:
    """The network is down when ``fgcd platform move`` starts: refused before anything moves."""
    rng = np.random.default_rng(seed)
    protective = bool(rng.random() < 0.5)
    link.cut()
    seen = {"cut": time.monotonic()}
    if protective:
        fake.send("protective_stop")
    before = fake.state()
    run = run_fgcd(
        ["platform", "move", "--driver", "ur", "--host", link.address, "--yes", *LINK_MOVE], timeout_s=120
    )  # its end is not timed from the cut: the process started after it
    seen["stopped"] = seen["cut"] if before["moving"] == 0 and fake.state()["moving"] == 0 else None
    return _judge(
        ("link_cut_ur_idle", seed, "platform move --driver ur (network down)"),
        run,
        seen,
        link,
        fake,
        protective=protective,
        extra={},
    )


def _judge(case, run, seen: dict, link, fake, *, protective: bool, extra: dict) -> FaultOutcome:
    """Exit 7 in one line within the stated time; the arm stopped within its bound; a clean reconnect."""
    fault, seed, command = case
    cut, stopped = seen.get("cut"), seen.get("stopped")
    config = _driver_config()
    expected = (EXIT_PLATFORM,)
    detail = (run.error_lines or run.lines or [""])[-1]
    if cut is None:  # the move ended before the cut: no fault reached it, it must have succeeded
        expected = (0,)
        detail = detail if run.code != 0 else "the move ended before the cut"
        stop_s = None
    else:
        stop_s = None if stopped is None else stopped - cut
    left_moving = cut is not None and (stop_s is None or stop_s > config.link_stop_s + STOP_MARGIN_S)
    outcome = FaultOutcome(
        fault=fault,
        seed=seed,
        command=command,
        code=run.code,
        expected=expected,
        stderr_lines=run.failure_lines,
        traceback=run.traceback,
        platform_left_moving=left_moving,
        detail=detail,
        one_line_expected=run.code != 0,
        extra={
            **extra,
            "link": link.kind,
            "protective_during_cut": protective,
            "arm_stopped_after_cut_s": None if stop_s is None else round(stop_s, 3),
            "stated_stop_s": round(config.link_stop_s, 3),
        },
    )
    if cut is not None and "ended" in seen:
        ended_s = seen["ended"] - cut
        outcome.extra["command_ended_after_cut_s"] = round(ended_s, 3)
        if ended_s > COMMAND_END_S:
            outcome.expected = ()
            outcome.detail = f"the command ended {ended_s:.1f} s after the cut (stated {COMMAND_END_S:.1f} s): {detail}"
    ok, why, info = _reconnect(link, fake, protective=protective and cut is not None)
    outcome.extra.update(info)
    if not ok:
        outcome.expected, outcome.detail = (), why
    return outcome


def ur_link_fault(fault: str, seed: int, *, prefer: str = "netns") -> FaultOutcome:
    """One UR link cut on a fresh fake controller behind a fresh cuttable link (always removed).

    ``prefer="proxy"`` uses the TCP proxy even where a network namespace can be made.
    """
    link, fake, failed = _open(fault, seed, prefer)
    if failed is not None:
        return failed
    try:
        return (_moving_cut if fault == "link_cut_ur_move" else _idle_cut)(seed, link, fake)
    finally:
        fake.stop()
        link.close()
