"""Output at the CLI edge: rich for people, one JSON object for scripts.

Commands call :func:`emit` with a plain dict and an optional rich renderer.
With ``--json`` the dict is printed as one JSON object on stdout and nothing else.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
from rich.console import Console

console = Console(highlight=False, soft_wrap=True)
err_console = Console(stderr=True, highlight=False, soft_wrap=True)


@dataclass
class OutputState:
    """Global output options set by the root callback."""

    verbose: bool = False


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
        print(to_json(data))
        return
    if render is not None:
        render(console)
    else:
        for key, value in data.items():
            console.print(f"[bold]{key}[/bold]: {value}")


def info(message: str) -> None:
    """A progress line for people (stderr, so --json stdout stays clean)."""
    err_console.print(message)


def debug(message: str) -> None:
    """Printed only with --verbose."""
    if state.verbose:
        err_console.print(f"[dim]{message}[/dim]")
