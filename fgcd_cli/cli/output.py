"""Output at the CLI edge: rich for people, one JSON object for scripts.

Commands call :func:`emit` with a plain dict and an optional rich renderer.
With ``--json`` the dict is printed as one JSON object on stdout and nothing else.
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console

from fgcd_cli.errors import ConfirmationNeeded

console = Console(highlight=False, soft_wrap=True)
err_console = Console(stderr=True, highlight=False, soft_wrap=True)


@dataclass
class OutputState:
    """Global output options set by the root callback, and whether a JSON result was printed."""

    verbose: bool = False
    emitted: bool = False  # a JSON result is on stdout: an error must not print a second object
    last_line_at: float = 0.0  # time.monotonic() of the last line on stderr (the progress heartbeat's silence)

    def reset(self) -> None:
        """Defaults again (a new command line starts)."""
        self.verbose = False
        self.emitted = False
        self.last_line_at = 0.0


state = OutputState()


def _default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    if isinstance(obj, Path):
        return str(obj)
    if hasattr(obj, "__dataclass_fields__"):
        from dataclasses import asdict

        return asdict(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def _clean(obj: Any) -> Any:
    """Replace NaN/inf by None so the output is strict JSON."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    return obj


def to_json(data: Any) -> str:
    """Strict JSON text of ``data`` (numpy, paths and dataclasses allowed)."""
    return json.dumps(_clean(json.loads(json.dumps(data, default=_default, allow_nan=True))), ensure_ascii=False)


def emit(data: dict, *, as_json: bool, render: Callable[[Console], None] | None = None) -> None:
    """Print a command's result: JSON for scripts, rich for people."""
    if as_json:
        print(to_json(data), flush=True)
        state.emitted = True
        return
    if render is not None:
        render(console)
    else:
        for key, value in data.items():
            console.print(f"[bold]{key}[/bold]: {value}")


def info(message: str) -> None:
    """A progress line for people (stderr, so --json stdout stays clean)."""
    err_console.print(message)
    state.last_line_at = time.monotonic()


def plain_line(text: str) -> None:
    """A progress line off a terminal, printed as it is (no markup), flushed at once (a log follows it live)."""
    err_console.print(text, markup=False, highlight=False)
    err_console.file.flush()
    state.last_line_at = time.monotonic()


def debug(message: str) -> None:
    """Printed only with --verbose."""
    if state.verbose:
        err_console.print(f"[dim]{message}[/dim]")
        state.last_line_at = time.monotonic()


def confirmer(*, yes: bool) -> Callable[[str], bool] | None:
    """The confirmation callback of a command that moves a platform.

    Parameters
    ----------
    yes : bool
        ``--yes`` was given: no question is asked (returns None).

    Returns
    -------
    callable(str) -> bool or None
        Asks on the terminal (prompt on stderr, so ``--json`` stdout stays one
        object; default no).

    Raises
    ------
    ConfirmationNeeded
        No ``--yes`` and stdin is not a terminal: refused up front, before
        anything is opened or moved.
    """
    if yes:
        return None
    if not stdin_is_terminal():
        raise ConfirmationNeeded.for_prompt()

    def confirm(text: str) -> bool:
        import typer

        return typer.confirm(text, default=False, err=True)

    return confirm


def stdin_is_terminal() -> bool:
    """True when stdin is an open terminal (a person can answer a prompt)."""
    try:
        return sys.stdin is not None and sys.stdin.isatty()
    except (ValueError, OSError):  # closed or detached stdin
        return False


def ask_line(text: str) -> str:
    """A question on stderr (``--json`` stdout stays one object) and the answer line; EOFError without stdin."""
    print(text, end="", file=sys.stderr, flush=True)
    answer = sys.stdin.readline() if sys.stdin is not None else ""
    if not answer:
        raise EOFError
    return answer
