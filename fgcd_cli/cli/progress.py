"""Rich progress for the long steps of a command.

Algorithms never import rich: they report through a plain callback
``on_progress(done, total, label)`` (``total <= 0``: length unknown). A command
wraps its work in :func:`step_progress` and hands the callback down. The bar
lives on stderr (``--json`` stdout stays one object), shares the console of
:func:`fgcd_cli.cli.output.info` so progress lines print above it, and is
transient: once a command ends, only its lines and result remain.

When stderr is not a terminal (a pipe, a log file) no bar is drawn: a plain
line names each step that lasts :data:`PLAIN_STEP_DELAY_S` (:class:`PlainSteps`;
a command that fails at once prints its one error line only), and a heartbeat thread
re-prints the current step with its elapsed time whenever nothing was printed
on stderr for :data:`HEARTBEAT_S` seconds, so that a long step (the hand-eye
image refinement, a scene uncertainty map, a change detection) is never silent
in a log (issue 48, item 6).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

__all__ = ["HEARTBEAT_S", "PlainSteps", "ProgressCallback", "StepBar", "step_progress"]

ProgressCallback = Callable[[int, int, str], None]

#: Off a terminal, the longest silence on stderr during a step before the step is named again, seconds
#: (``FGCD_HEARTBEAT_S`` overrides it: tests of a whole command shorten it). The rule is no silence over
#: 10 s in a log; beating at 8 s leaves 2 s for a loaded machine (the pipe's and the scheduler's delays).
HEARTBEAT_S = float(os.environ.get("FGCD_HEARTBEAT_S", "8"))
#: Off a terminal, how long a step runs before its line is printed, seconds (or one heartbeat, if shorter):
#: a step that ends sooner is not named, so a command that fails at once prints its one error line only
#: (``FGCD_STEP_DELAY_S`` overrides it: tests of a command's one error line lengthen it, as a loaded
#: machine can take a second to reach the error).
PLAIN_STEP_DELAY_S = float(os.environ.get("FGCD_STEP_DELAY_S", "1"))


class StepBar:
    """The callback a command hands down: ``bar(done, total, label)`` updates a rich progress bar.

    A new label starts a new step (its elapsed time restarts), except that
    labels differing only in a parenthesised detail (``exploring (3/12)``)
    are one step; ``total <= 0`` shows a pulsing bar for a step whose length
    is unknown.
    """

    def __init__(self, progress) -> None:
        self._progress = progress
        self._task = None
        self._label: str | None = None
        self._counting = False  # a counted step is under way (not yet at its total)

    def __call__(self, done: int, total: int, label: str) -> None:
        known = total is not None and total > 0
        self._counting = known and done < total
        step = _step(label)
        if step != self._label:
            if self._task is not None:
                self._progress.remove_task(self._task)
            self._task = self._progress.add_task(label, total=total if known else None, count="")
            self._label = step
        self._progress.update(
            self._task,
            completed=done if known else 0,
            total=total if known else None,
            count=f"{done}/{total}" if known else "",
            description=label,
        )

    def lines(self, say: Callable[[str], None]) -> Callable[[str], None]:
        """``say`` whose lines also name the bar's step while no counted step is under way.

        A use case's lines (``adjustment 3: waiting for an alignment``) say
        what it does between counted steps: the bar then shows that line with
        its own elapsed time instead of a finished step's. Indented lines are
        details of the current step and leave the bar alone; so does any line
        said in the middle of a counted step (``exploring 3/12``).
        """

        def wrapped(text: str) -> None:
            say(text)
            if text[:1].isspace() or self._counting:
                return
            self(0, 0, text.strip())

        return wrapped

    def paused(self, ask: Callable[[str], bool] | None) -> Callable[[str], bool] | None:
        """``ask`` run with the bar hidden (a question on the terminal is not drawn over)."""
        if ask is None:
            return None

        def wrapped(text: str) -> bool:
            self._progress.stop()
            try:
                return ask(text)
            finally:
                self._progress.start()

        return wrapped


def _step(label: str) -> str:
    """The step a label belongs to: labels differing only in a parenthesised detail are one step."""
    return label.split(" (")[0]


class PlainSteps:
    """The callback off a terminal: one plain stderr line per step, and a heartbeat during a long one.

    Same interface as :class:`StepBar`. A step prints its (latest) label once
    it has lasted :data:`PLAIN_STEP_DELAY_S` or one heartbeat, if shorter; while it runs, a daemon thread prints ``  ... <label> <done>/<total>, <n> s``
    whenever nothing was printed on stderr (this renderer's lines or
    :func:`fgcd_cli.cli.output.info`) for ``heartbeat_s`` seconds.
    """

    def __init__(
        self, write: Callable[[str], None], *, heartbeat_s: float, last_printed: Callable[[], float] = lambda: 0.0
    ) -> None:
        self._write = write
        self._heartbeat_s = float(heartbeat_s)
        self._last_printed = last_printed  # when another writer last printed on stderr (time.monotonic)
        self._lock = threading.Lock()
        self._step: str | None = None
        self._label = ""
        self._count = ""
        self._started = self._printed = time.monotonic()
        self._counting = False
        self._named = False  # the current step's line is printed (after PLAIN_STEP_DELAY_S)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._beat, name="fgcd-progress-heartbeat", daemon=True)

    def __call__(self, done: int, total: int, label: str) -> None:
        known = total is not None and total > 0
        with self._lock:
            self._counting = known and done < total
            self._label, self._count = label, (f" {done}/{total}" if known else "")
            if _step(label) == self._step:
                return
            self._step, self._started, self._named = _step(label), time.monotonic(), False

    def lines(self, say: Callable[[str], None]) -> Callable[[str], None]:
        """``say`` whose lines also name the step between counted steps (as :meth:`StepBar.lines`), not printed twice."""

        def wrapped(text: str) -> None:
            say(text)
            if text[:1].isspace() or self._counting:
                return
            with self._lock:  # the line itself names the step: no second line
                self._step, self._label, self._count = _step(text.strip()), text.strip(), ""
                self._started = self._printed = time.monotonic()
                self._named = True

        return wrapped

    def paused(self, ask: Callable[[str], bool] | None) -> Callable[[str], bool] | None:
        """``ask`` as it is (nothing is drawn that a question could be hidden by)."""
        return ask

    def _print(self, text: str) -> None:
        self._printed = time.monotonic()
        self._write(text)

    def _beat(self) -> None:
        delay = min(PLAIN_STEP_DELAY_S, self._heartbeat_s)
        wait = delay
        while not self._stop.wait(wait):
            with self._lock:
                now = time.monotonic()
                due = max(self._printed, self._last_printed()) + self._heartbeat_s  # the silence ends here
                if self._step is None:  # no step yet: nothing to name
                    due = now + delay
                elif not self._named:  # a step is named once it has lasted `delay`
                    due = self._started + delay
                    if now >= due:
                        self._named = True
                        self._print(self._label)
                        due = now + self._heartbeat_s
                elif now >= due:
                    self._print(f"  ... {self._label}{self._count}, {now - self._started:.0f} s")
                    due = now + self._heartbeat_s
                wait = max(0.01, due - now)  # wake at the end of the silence, not a polling period later

    def __enter__(self) -> PlainSteps:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


@contextmanager
def step_progress(*, enabled: bool, heartbeat_s: float | None = None) -> Iterator[StepBar | PlainSteps | None]:
    """A rich progress bar fed by ``(done, total, label)`` calls, or None when disabled.

    Parameters
    ----------
    enabled : bool
        False (``--json``) yields None: callers pass it on as "no progress".
    heartbeat_s : float, optional
        Off a terminal, the heartbeat's interval (default :data:`HEARTBEAT_S`, read at the call).

    Yields
    ------
    StepBar, PlainSteps or None
        A ``(done, total, label)`` callable: the rich bar on a terminal, plain lines otherwise.
    """
    if not enabled:
        yield None
        return
    from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    from fgcd_cli.cli.output import err_console, plain_line, state

    if not err_console.is_terminal:
        # a log file, a pipe: no live display (it would only leave a blank line), plain lines instead
        with PlainSteps(
            plain_line,
            heartbeat_s=HEARTBEAT_S if heartbeat_s is None else heartbeat_s,
            last_printed=lambda: state.last_line_at,
        ) as steps:
            yield steps
        return

    columns = (
        SpinnerColumn(),
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.fields[count]}"),
        TimeElapsedColumn(),
    )
    with Progress(*columns, console=err_console, transient=True) as progress:
        yield StepBar(progress)
