"""Whole-operation faults of ``fgcd bench faults``: a real ``fgcd capture`` or ``fgcd relocate`` on the simulated
rig, hit at a seeded instant of one of its phases (docs/hardware.md, "Faults in the field").

The phase is drawn from the operation's phases (:data:`RELOCATE_PHASES`,
:data:`CAPTURE_PHASES`) and recognised as it starts from the child's stderr
progress lines (:func:`phase_of`, read as they come by
:func:`fgcd_cli.bench.faults.checks.run_fgcd_lines`), or for the writing phase
from the store's temporary observation folder appearing (``.tmp-*``, the atomic
write of docs/user-guide.md, the campaign folder); the fault comes a seeded delay into it. A
signal (SIGINT, SIGTERM, SIGHUP, SIGKILL) must end the command with its
documented code and one line (none for SIGKILL), a stuck light controller with
exit 7 (``relocate_light_stuck``, :mod:`fgcd_cli.bench.faults.failing_lights`). The
simulated platform lives in the fgcd process: it is stopped when the process has
ended, which every fault waits for.

After each relocate fault ``fgcd relocate --resume`` runs and must succeed and
say whether it continued the interrupted visit or started over
(:mod:`fgcd_cli.app.visit_journal`); its visit is earlier data for the next fault.
"""

from __future__ import annotations

import re
import signal
import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fgcd_cli.bench.faults.campaign_faults import _Case, _outcome, _temporaries, calibrate_campaign
from fgcd_cli.bench.faults.checks import FaultOutcome, FgcdRun, fresh_station, run_fgcd, run_fgcd_lines, send_signal
from fgcd_cli.bench.faults.station import REAL_STATION_LIGHTS, prepare_real_station
from fgcd_cli.campaign import schema

__all__ = [
    "CAPTURE_PHASES",
    "FAULTS",
    "PER_CLASS_FULL",
    "PhaseTracker",
    "RELOCATE_PHASES",
    "inject",
    "phase_of",
    "resume_mode",
]

FAULTS = (
    "capture_sigint",
    "capture_sigkill",
    "capture_sigterm",
    "relocate_sigint",
    "relocate_sigkill",
    "relocate_sigterm",
    "relocate_sighup",
    "relocate_light_stuck",
)
#: 8 classes x 5 = 40 faults here; with the wired group's 4 x 5 the whole-operation group tries 60 over 12 classes.
PER_CLASS_FULL = 5

#: Exit codes (README, "Errors"): a signal's, 0 when the command ended before it, 6 a revisit that did not converge.
EXIT_CODES = {signal.SIGINT: 130, signal.SIGTERM: 143, signal.SIGHUP: 129, signal.SIGKILL: -signal.SIGKILL}
EXIT_OK, EXIT_NOT_CONVERGED, EXIT_PLATFORM = 0, 6, 7

#: A phase -> the stderr progress lines that start it (``fgcd relocate``/``capture`` off a terminal:
#: :class:`fgcd_cli.cli.progress.PlainSteps` names a step once it has lasted 1 s; use-case lines print at once).
PHASE_MARKERS = {
    "exploration": r"exploring to initialise|exploration \d+/\d+|^\s*\.\.\. exploration",
    "alignment_wait": r"waiting for an alignment|waiting for a 3D estimate",
    # a motion of the 3D loop or of the image stage (which leads when the 3D alignment is degenerate)
    "adjustment_motion": r"(adjustment\s+\d+|image (stage|fallback)\b.*\d+/\d+): moving|^adjustment\s+\d+ \((?!image)",
    "image_stage": r"^image (stage|fallback)\b.*\d+/\d+|^adjustment\s+\d+ \(image\)",
    "stills": r"images under each lighting",
    "writing": r"writing the (visit|reference)",
}
RELOCATE_PHASES = ("exploration", "alignment_wait", "adjustment_motion", "image_stage", "writing")
CAPTURE_PHASES = ("exploration", "stills", "writing")
#: The longest seeded delay into each phase, s: inside its usual length on 2 busy cores (a delay that outlasts
#: the phase hits the next one; the row's ``phase_at_fault`` says which).
PHASE_DELAY_S = {
    "exploration": 20.0,
    "alignment_wait": 3.0,
    "adjustment_motion": 2.0,
    "image_stage": 4.0,
    "stills": 4.0,
    "writing": 0.3,
}


def phase_of(line: str) -> str | None:
    """The phase a stderr line starts (None: it starts none)."""
    for phase, pattern in PHASE_MARKERS.items():
        if re.search(pattern, line, flags=re.IGNORECASE):
            return phase
    return None


def resume_mode(stderr: str) -> str | None:
    """What ``fgcd relocate --resume`` said it did: ``continued``, ``started over``, or None (it did not say)."""
    if re.search(r"continuing the interrupted visit", stderr):
        return "continued"
    if re.search(r"starting over|starting a new one", stderr):
        return "started over"
    return None


@dataclass
class PhaseTracker:
    """Follows a child's phases from its stderr lines and fires ``action`` a delay into the ``target`` phase.

    Attributes
    ----------
    target : str
        The phase the fault is drawn in.
    delay_s : float
        Seconds into it.
    action : callable
        ``action(process)``: the fault.
    watch : Path or None
        For the writing phase: the campaign, under whose stations the store's temporary folder appears.
    order : tuple of str
        The operation's phases in order: a later one starting before the target was seen (a run whose
        alignment was ready at once, a loop that converged without its image stage) arms the fault too.
    """

    target: str
    delay_s: float
    action: object
    watch: Path | None = None
    order: tuple[str, ...] = ()
    current: str | None = None
    phases_seen: list[str] = field(default_factory=list)
    fired_in: str | None = None
    _armed: bool = False
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def on_line(self, line: str, proc) -> None:
        """A stderr line of the child: note the phase it starts, arm the fault when it is the target."""
        phase = phase_of(line)
        if phase is None:
            return
        self.current = phase
        if not self.phases_seen or self.phases_seen[-1] != phase:
            self.phases_seen.append(phase)
        if phase == self.target or self._later(phase):
            self.arm(proc)

    def _later(self, phase: str) -> bool:
        """``phase`` comes after the target in the operation's order."""
        if self.target not in self.order or phase not in self.order:
            return False
        if (self.target, phase) == ("adjustment_motion", "image_stage"):
            return False  # the image stage makes motions of its own: wait for them
        return self.order.index(phase) > self.order.index(self.target)

    def arm(self, proc) -> None:
        """Start the delay to the fault (once)."""
        with self._lock:
            if self._armed:
                return
            self._armed = True
        timer = threading.Timer(self.delay_s, self._fire, args=(proc,))
        timer.daemon = True
        timer.start()

    def _fire(self, proc) -> None:
        if proc.poll() is not None:
            return
        self.fired_in = self.current
        self.action(proc)

    def watch_writes(self, proc, left: set[Path]) -> threading.Thread:
        """For the writing phase: arm when a new temporary folder appears under :attr:`watch` (polled every 10 ms)."""

        def poll() -> None:
            while proc.poll() is None and not self._armed:
                if any(p.is_dir() for p in _temporaries(self.watch) - left):
                    self.current = "writing"
                    self.phases_seen.append("writing (.tmp folder)")
                    self.arm(proc)
                    return
                threading.Event().wait(0.01)

        thread = threading.Thread(target=poll, daemon=True)
        thread.start()
        return thread


def _draw(fault: str, seed: int) -> tuple[str, float, np.random.Generator]:
    """The phase and the delay into it of fault ``seed``; the generator for its further draws."""
    rng = np.random.default_rng(seed)
    phases = CAPTURE_PHASES if fault.startswith("capture") else RELOCATE_PHASES
    # offset by the class: the classes of one seed hit different phases (one run per class covers them all)
    phase = str(phases[(int(rng.integers(len(phases))) + FAULTS.index(fault)) % len(phases)])
    return phase, float(rng.uniform(0.0, PHASE_DELAY_S[phase])), rng


def _visits(campaign: Path, station: str) -> int:
    """Committed visits of ``station``."""
    return len(list((campaign / schema.STATIONS_DIR / station / schema.VISITS_DIR).glob(f"*/{schema.MANIFEST}")))


def _observations(campaign: Path, station: str) -> list[str]:
    """The observations ``station.json`` lists (empty: no station yet)."""
    import json

    path = campaign / schema.STATIONS_DIR / station / schema.STATION_FILE
    return json.loads(path.read_text(encoding="utf-8")).get("observations", []) if path.is_file() else []


def _signal_action(sig: int, state: dict, committed) -> callable:
    """The fault: ``sig`` to the child, noting whether its observation was already committed then."""

    def action(proc) -> None:
        state["committed_before"] = committed()
        state["sent"] = proc.poll() is None
        send_signal(proc, sig)

    return action


def _expected(sig: int, state: dict, natural: tuple[int, ...]) -> tuple[int, ...]:
    """The documented codes: the signal's once sent before the observation was committed, else ``natural`` too."""
    if not state.get("sent"):
        return natural  # the command ended before the instant: it must end as it would have
    if state.get("committed_before"):
        return (EXIT_CODES[sig], *natural)
    return (EXIT_CODES[sig],)


def _timing(tracker: PhaseTracker, delay: float) -> dict:
    return {
        "phase": tracker.target,
        "delay_s": round(delay, 2),
        "phase_at_fault": tracker.fired_in,
        "phases_seen": tracker.phases_seen[:12],
    }


def _capture_fault(fault: str, seed: int, campaign: Path) -> FaultOutcome:
    """``fgcd capture`` of a new station, signalled at a seeded instant of a seeded phase."""
    calibrate_campaign(campaign)
    sig = {"capture_sigint": signal.SIGINT, "capture_sigkill": signal.SIGKILL, "capture_sigterm": signal.SIGTERM}[fault]
    phase, delay, _ = _draw(fault, seed)
    station = fresh_station(campaign, f"{fault.replace('_', '-')}-{seed}")  # a new station per fault
    reference = campaign / schema.STATIONS_DIR / station / schema.REFERENCE_DIR / schema.MANIFEST
    before, left, state = _snapshot(campaign)
    tracker = PhaseTracker(
        phase, delay, _signal_action(sig, state, reference.is_file), watch=campaign, order=CAPTURE_PHASES
    )
    run = _run_tracked(
        ["capture", "-c", str(campaign), "-s", station, "--light", REAL_STATION_LIGHTS, "--yes"], tracker, left
    )
    outcome = _outcome(
        _Case(fault, seed, f"capture ({sig.name} in {phase})"),
        run,
        _expected(sig, state, (EXIT_OK,)),
        campaign=campaign,
        before=before,
        extra=_timing(tracker, delay),
    )
    outcome.landed = bool(state.get("sent"))
    return outcome


def _snapshot(campaign: Path) -> tuple[dict, set[Path], dict]:
    from fgcd_cli.bench.faults.checks import committed_digests

    return committed_digests(campaign), _temporaries(campaign), {}


def _run_tracked(args: list[str], tracker: PhaseTracker, left: set[Path]) -> FgcdRun:
    """Run ``fgcd ARGS`` with ``tracker`` on its stderr lines (and its writes, for the writing phase)."""
    started = {}

    def on_line(line: str, proc) -> None:
        if tracker.target == "writing" and "watch" not in started:
            started["watch"] = tracker.watch_writes(proc, left)
        tracker.on_line(line, proc)

    return run_fgcd_lines(args, on_line=on_line, timeout_s=1800)


def _relocate_args(campaign: Path, station: str, *, resume: bool = False) -> list[str]:
    # no --json: its progress lines are what the phases are read from
    return ["relocate", "-c", str(campaign), "-s", station, "--yes", *(["--resume"] if resume else [])]


def _resume(outcome: FaultOutcome, campaign: Path, station: str) -> FaultOutcome:
    """``fgcd relocate --resume`` after the fault: it must succeed and say whether it continued or started over."""
    run = run_fgcd(_relocate_args(campaign, station, resume=True), timeout_s=1800)
    mode = resume_mode(run.stderr)
    said = next((line for line in run.lines if resume_mode(line)), "")
    outcome.extra.update(
        {"resume": mode, "resume_reason": said, "resume_code": run.code, "resume_s": round(run.seconds, 1)}
    )
    if mode is None or run.code not in (EXIT_OK, EXIT_NOT_CONVERGED) or run.traceback:
        outcome.resume_failed = True
        outcome.detail = (
            f"the resume ended with {run.code} ({mode or 'saying neither continued nor started over'}): "
            + (run.lines or [""])[-1]
        )
    return outcome


def _relocate_signal_fault(fault: str, seed: int, campaign: Path) -> FaultOutcome:
    """``fgcd relocate -s real`` signalled at a seeded instant of a seeded phase, then ``--resume``."""
    station = prepare_real_station(campaign)
    sig = {
        "relocate_sigint": signal.SIGINT,
        "relocate_sigkill": signal.SIGKILL,
        "relocate_sigterm": signal.SIGTERM,
        "relocate_sighup": signal.SIGHUP,
    }[fault]
    phase, delay, _ = _draw(fault, seed)
    before, left, state = _snapshot(campaign)
    visits = _visits(campaign, station)
    tracker = PhaseTracker(
        phase,
        delay,
        _signal_action(sig, state, lambda: _visits(campaign, station) > visits),
        watch=campaign,
        order=RELOCATE_PHASES,
    )
    run = _run_tracked(_relocate_args(campaign, station), tracker, left)
    outcome = _outcome(
        _Case(fault, seed, f"relocate -s {station} ({sig.name} in {phase})"),
        run,
        _expected(sig, state, (EXIT_OK, EXIT_NOT_CONVERGED)),
        campaign=campaign,
        before=before,
        extra=_timing(tracker, delay),
    )
    outcome.landed = bool(state.get("sent"))
    return _resume(outcome, campaign, station)


def _light_fault(seed: int, campaign: Path) -> FaultOutcome:
    """``fgcd relocate -s real`` with serial lights whose controller fails at a seeded instant: exit 7, one line.

    The campaign's ``[rig.lights]`` wires the emulated controller for this fault only (campaign.toml is
    restored after, the resume included): the other classes run on the simulator's own lights.
    """
    from fgcd_cli.bench.faults.failing_lights import LIGHT_FAULT_MODES, FaultyLightController, lights_section

    station = prepare_real_station(campaign)
    phase, delay, rng = _draw("relocate_light_stuck", seed)
    mode = str(LIGHT_FAULT_MODES[int(rng.integers(len(LIGHT_FAULT_MODES)))])
    toml = campaign / "campaign.toml"
    original = toml.read_bytes()
    with FaultyLightController() as lights:
        toml.write_bytes(original + lights_section(lights.port, {"led:3": 1, "led:9": 2}).encode())
        try:
            before, left, state = _snapshot(campaign)
            visits = _visits(campaign, station)

            def action(proc) -> None:
                state["committed_before"] = _visits(campaign, station) > visits
                lights.fail(mode)

            tracker = PhaseTracker(phase, delay, action, watch=campaign, order=RELOCATE_PHASES)
            run = _run_tracked(_relocate_args(campaign, station), tracker, left)
            shown = lights.showed_fault and not state.get("committed_before")
            expected = (EXIT_PLATFORM,) if shown else (EXIT_OK, EXIT_NOT_CONVERGED, EXIT_PLATFORM)
            extra = {
                **_timing(tracker, delay),
                "light_fault": mode,
                "shown_to_fgcd": lights.showed_fault,
                "commands_after_fault": lights.commands_since_fault,
            }
            outcome = _outcome(
                _Case("relocate_light_stuck", seed, f"relocate -s {station} (lights {mode} in {phase})"),
                run,
                expected,
                campaign=campaign,
                before=before,
                extra=extra,
            )
            outcome.landed = bool(lights.showed_fault)
            lights.mode = None  # the operator has fixed the controller
            lights.set_silent(False)
            return _resume(outcome, campaign, station)
        finally:
            toml.write_bytes(original)


def inject(fault: str, seed: int, campaign: Path) -> FaultOutcome:
    """Run one whole-operation fault of class ``fault`` with ``seed`` on the bench ``campaign``."""
    if fault.startswith("capture_") and fault in FAULTS:
        return _capture_fault(fault, seed, campaign)
    if fault == "relocate_light_stuck":
        return _light_fault(seed, campaign)
    if fault in FAULTS:
        return _relocate_signal_fault(fault, seed, campaign)
    raise ValueError(f"unknown whole-operation fault '{fault}'")
