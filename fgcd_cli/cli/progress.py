"""Rich progress for the long steps of a command.

Algorithms never import rich: they report through a plain callback
``on_progress(done, total, label)`` (``total <= 0``: length unknown). A command
wraps its work in :func:`step_progress` and hands the callback down. The bar
lives on stderr (``--json`` stdout stays one object), shares the console of
:func:`fgcd_cli.cli.output.info` so progress lines print above it, and is
transient: once a command ends, only its lines and result remain. When stderr
is not a terminal nothing is drawn (the lines still are).
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Callable, Iterator

__all__ = ["ProgressCallback", "StepBar", "step_progress"]

ProgressCallback = Callable[[int, int, str], None]


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
        step = label.split(" (")[0]
        if step != self._label:
            if self._task is not None:
                self._progress.remove_task(self._task)
            self._task = self._progress.add_task(label, total=total if known else None, count="")
            self._label = step
        self._progress.update(self._task, completed=done if known else 0, total=total if known else None,
                              count=f"{done}/{total}" if known else "", description=label)

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


@contextmanager
def step_progress(*, enabled: bool) -> Iterator[StepBar | None]:
    """A rich progress bar fed by ``(done, total, label)`` calls, or None when disabled.

    Parameters
    ----------
    enabled : bool
        False (``--json``) yields None: callers pass it on as "no progress".

    Yields
    ------
    StepBar or None
        A ``(done, total, label)`` callable.
    """
    if not enabled:
        yield None
        return
    from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    from fgcd_cli.cli.output import err_console

    columns = (SpinnerColumn(), TextColumn("{task.description}"), BarColumn(),
               TextColumn("{task.fields[count]}"), TimeElapsedColumn())
    # Not a terminal (a log file, a pipe): the steps are followed but nothing is drawn (a live
    # display there would only leave a blank line before the result or the error line).
    with Progress(*columns, console=err_console, transient=True, disable=not err_console.is_terminal) as progress:
        yield StepBar(progress)
