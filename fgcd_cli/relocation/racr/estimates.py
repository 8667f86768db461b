"""Getting a 3D estimate for the loop: waiting for the alignment thread, or aligning in turn.

Parallel mode waits on the alignment thread's condition (never by sleeping in a
loop) and pauses when its estimates stay untrustworthy; serial mode aligns
once, now. Every wait is counted in the session's time on the rig
(``SessionTiming.wait_s``).
"""

from __future__ import annotations

import time

import numpy as np

from fgcd_cli.errors import AlgorithmError
from fgcd_cli.relocation.adjustment import camera_in_reference
from fgcd_cli.relocation.enums import LoopMode
from fgcd_cli.relocation.loop.context import LoopContext, LoopState
from fgcd_cli.relocation.loop.worker import ALIGNMENT_STEP_S, AlignmentWorker
from fgcd_cli.relocation.racr.aligner import AlignmentEstimate, scaled_pose
from fgcd_cli.vse.types import VseStatus

__all__ = ["DegenerateGeometry", "align_now", "fresh_3d_estimate", "wait_for_estimate"]

#: Slack added to a deadline so that a wake-up at the deadline finds it passed, seconds.
_DEADLINE_SLACK_S = 0.01


class DegenerateGeometry(AlgorithmError):
    """The alignment found degenerate geometry in as many estimates in a row as the loop's patience allows
    (``detail``: the last estimate's reason)."""

    def __init__(self, message: str, *, detail: str = ""):
        super().__init__(message)
        self.detail = detail


class _Patience:
    """Counts the untrustworthy estimates published while the loop waits (``RelocationConfig`` patience rules;
    ``degenerate_patience`` overrides the configured one)."""

    def __init__(self, degenerate_patience: int | None = None):
        self.bad: set[int] = set()  # serials of untrustworthy estimates since the wait started
        self.degenerate: set[int] = set()  # ... of those flagged degenerate geometry, in a row
        self.degenerate_patience = degenerate_patience

    def check(self, est: AlignmentEstimate, waited: float, ctx: LoopContext) -> None:
        """Note an untrustworthy estimate; raise AlgorithmError when a patience rule runs out."""
        config = ctx.config
        self.bad.add(est.serial)
        if est.degenerate:
            self.degenerate.add(est.serial)
        else:
            self.degenerate.clear()
        if len(self.degenerate) >= (self.degenerate_patience or config.degenerate_patience):
            ctx.session.timing.wait_s += waited
            raise DegenerateGeometry(
                f"alignment found degenerate geometry in {len(self.degenerate)} estimates in a "
                f"row ({waited:.0f} s), motion paused: {est.reason}",
                detail=est.reason,
            )
        if len(self.bad) >= config.untrusted_patience and waited >= config.untrusted_min_wait_s:
            ctx.session.timing.wait_s += waited
            raise AlgorithmError(
                f"alignment untrustworthy in {len(self.bad)} estimates in a row "
                f"({waited:.0f} s), motion paused: {est.reason}"
            )


def _none_yet(ctx: LoopContext) -> str:
    """Why the alignment thread has published nothing: it aligns only a tracking VSE state with at least
    ``min_points`` cloud points."""
    state = ctx.session.vse.latest()
    return (
        f"no estimate yet (the VSE is {state.status}, its cloud has {len(state.cloud)} points, "
        f"alignment needs {ctx.config.min_points})"
    )


class _StandingStill:
    """Watches a VSE state the alignment thread cannot align (not tracking, or fewer than ``min_points``
    cloud points) while the loop waits with the camera standing still.

    Rule: the cloud grows only with new keyframes, and a standing camera makes none, so a state that
    has not changed for ``untrusted_min_wait_s`` (the loop's patience with untrustworthy estimates)
    will not change by waiting the rest of ``estimate_timeout_s``: the loop pauses then (and the image
    fallback may take over) instead of waiting out the timeout.
    """

    def __init__(self):
        self.seen: tuple | None = None  # (status, cloud size) last seen
        self.since = 0.0  # seconds into the wait when it was first seen

    def check(self, ctx: LoopContext, worker: AlignmentWorker, waited: float) -> None:
        """Raise AlgorithmError when the unalignable state stood still for the patience."""
        state = ctx.session.vse.latest()
        key = (state.status, len(state.cloud))
        if key != self.seen:
            self.seen, self.since = key, waited
            return
        if not worker.can_align(state) and waited - self.since >= ctx.config.untrusted_min_wait_s:
            ctx.session.timing.wait_s += waited
            raise AlgorithmError(
                f"no alignment possible, motion paused: {_none_yet(ctx)}, unchanged for "
                f"{waited - self.since:.0f} s with the camera standing still"
            )


def _heartbeat(ctx: LoopContext, worker: AlignmentWorker, waited: float) -> None:
    est = worker.latest()
    ctx.say(
        f"  still aligning ({waited:.0f} s; latest estimate: "
        + (_none_yet(ctx) if est is None else f"{est.stage}, {'ok' if est.ok else est.reason}")
        + ")"
    )


def wait_for_estimate(
    ctx: LoopContext, worker: AlignmentWorker, last_serial: int, *, degenerate_patience: int | None = None
) -> AlignmentEstimate:
    """The newest trustworthy alignment published after ``last_serial``; pause on failures.

    Raises
    ------
    DegenerateGeometry
        ``degenerate_patience`` (default: the configured one) estimates in a row found degenerate geometry.
    AlgorithmError
        The alignment thread failed, its estimates stayed untrustworthy (``untrusted_patience`` after
        ``untrusted_min_wait_s``), none came within ``estimate_timeout_s``, or none has come and the VSE
        state it would need has stood still for ``untrusted_min_wait_s`` (:class:`_StandingStill`).
    """
    config, now = ctx.config, getattr(ctx.session, "now", time.monotonic)  # deterministic: the step clock
    t0 = now()
    patience = _Patience(degenerate_patience)
    still = _StandingStill()
    next_note = t0 + config.heartbeat_s  # never silent for long (issue 24, item 7)
    while True:
        if now() >= next_note:
            _heartbeat(ctx, worker, now() - t0)
            next_note += config.heartbeat_s
        if worker.error:
            raise AlgorithmError(f"alignment thread stopped: {worker.error}")
        est = worker.latest()
        if est is not None and est.serial > last_serial and est.ok:
            ctx.session.timing.wait_s += now() - t0
            return est
        waited = now() - t0
        if est is not None and est.serial > last_serial:
            patience.check(est, waited, ctx)
        if est is None:
            still.check(ctx, worker, waited)
        if waited > config.estimate_timeout_s:
            ctx.session.timing.wait_s += waited
            why = est.reason if est is not None else _none_yet(ctx)
            raise AlgorithmError(
                f"no trustworthy alignment within {config.estimate_timeout_s:.0f} s, motion paused: {why}"
            )
        # sleep until the next publication or the next deadline (heartbeat, patience, timeout)
        deadlines = [next_note, t0 + config.estimate_timeout_s + _DEADLINE_SLACK_S]
        if waited < config.untrusted_min_wait_s:
            deadlines.append(t0 + config.untrusted_min_wait_s)
        seen = est.serial if est is not None else -1
        worker.wait_until(lambda e, seen=seen: e is not None and e.serial != seen, min(deadlines) - now())


def _aligned(ctx: LoopContext, state, init, serial: int = 0) -> list[AlignmentEstimate]:
    """Serial mode's alignment run; a deterministic run counts its nominal cost on the step clock."""
    ests = ctx.aligner(state=state, problem=ctx.problem(), init=init, serial=serial)
    advance = getattr(ctx.session.vse, "advance", None)
    if advance is not None:
        advance(ALIGNMENT_STEP_S)
    return ests


def align_now(ctx: LoopContext, state, init, serial: int, *, t0: float | None = None) -> AlignmentEstimate:
    """Serial mode: align ``state`` now; the last trustworthy estimate, else AlgorithmError (motion paused).

    The time from ``t0`` (default: now) counts as waiting in the session's time on the rig.
    """
    t0 = time.monotonic() if t0 is None else t0
    if len(state.cloud) < ctx.config.min_points:
        raise AlgorithmError(f"the VSE cloud has only {len(state.cloud)} points: cannot align")
    ests = _aligned(ctx, state, init, serial)
    ctx.session.timing.wait_s += time.monotonic() - t0
    oks = [e for e in ests if e.ok]
    est = oks[-1] if oks else ests[-1]
    if not est.ok:
        raise AlgorithmError(f"alignment failed, motion paused: {est.reason}")
    return est


def _wait_for_view_after(ctx: LoopContext, worker: AlignmentWorker, after_frame: int):
    """Parallel mode: a trustworthy estimate of a view after ``after_frame`` (waits at most ``agreement_wait_s``)."""
    wait_s = ctx.config.agreement_wait_s
    ctx.say("waiting for a 3D estimate of this view to compare with the image estimate")
    t0 = time.monotonic()
    worker.wait_until(lambda e: e is not None and e.ok and e.vse_frame > after_frame, wait_s)
    # the platform stood still for the whole wait, whether an estimate came or not
    ctx.session.timing.wait_s += time.monotonic() - t0
    if worker.error:
        return None, f"alignment thread stopped: {worker.error}"
    est = worker.latest_ok()
    if est is None or est.vse_frame <= after_frame:
        return None, f"no 3D estimate of this view within {wait_s:.0f} s"
    return est, ""


def fresh_3d_estimate(ctx: LoopContext, st: LoopState, after_frame: int) -> tuple[np.ndarray | None, str]:
    """The 3D estimate of the current camera from a view after ``after_frame``.

    Parallel mode waits (at most ``config.agreement_wait_s``) for the alignment thread
    to publish a trustworthy estimate of such a view; serial mode aligns once now,
    from the 3D loop's last estimate.

    Returns
    -------
    T_ref_cam : (4, 4) ndarray or None
        The current camera in the reference frame, or None.
    note : str
        Why there is none (empty when there is one).
    """
    session = ctx.session
    if st.last_T_ref_cur is None:
        return None, "no trustworthy 3D estimate in this run"
    if ctx.config.mode == LoopMode.PARALLEL:
        if st.worker is None:
            return None, "the 3D alignment was stopped"
        est, note = _wait_for_view_after(ctx, st.worker, after_frame)
        if est is None:
            return None, note
    else:
        ctx.say("aligning the current cloud to compare with the image estimate")
        state = session.tracking_state()
        t0 = time.monotonic()
        ests = _aligned(ctx, state, st.last_T_ref_cur)
        session.timing.wait_s += time.monotonic() - t0
        oks = [e for e in ests if e.ok]
        if not oks:
            return None, f"3D alignment untrustworthy: {ests[-1].reason}"
        est = oks[-1]
    state = session.vse.latest()
    if state.status != VseStatus.TRACKING or state.T_map_cam is None:
        return None, f"the VSE is not tracking ({state.status})"
    return camera_in_reference(est.T_ref_cur, scaled_pose(state.T_map_cam, ctx.scale)), ""
