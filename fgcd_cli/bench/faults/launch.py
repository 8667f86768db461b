"""``python -m fgcd_cli.bench.faults.launch ARGS``: ``fgcd ARGS`` whose campaign writes hit a full disk.

Fault injection for ``fgcd bench faults`` only. Every binary file opened for writing
through ``os.fdopen`` (the store's atomic writes, :mod:`fgcd_cli.campaign.atomic`) or ``open``
(an observation's files, :meth:`fgcd_cli.campaign.observation.ObservationWriter.add_bytes`) under ``FGCD_BENCH_ENOSPC_UNDER`` shares a budget of ``FGCD_BENCH_ENOSPC_AFTER``
bytes; the write that crosses it writes what fits, then fails with ``ENOSPC``
as a full file system does.
"""

from __future__ import annotations

import builtins
import errno
import os
from pathlib import Path

__all__ = ["install_enospc"]


class _Budgeted:
    """A binary file whose writes draw on a shared byte budget."""

    def __init__(self, raw, budget: dict) -> None:
        self._raw = raw
        self._budget = budget

    def write(self, data) -> int:
        view = memoryview(data).cast("B")
        if len(view) > self._budget["left"]:
            self._raw.write(view[: self._budget["left"]])
            self._budget["left"] = 0
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._budget["left"] -= len(view)
        return self._raw.write(view)

    def __getattr__(self, name):
        return getattr(self._raw, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self._raw.close()


def install_enospc(budget_bytes: int, under: str) -> None:
    """Make writes under ``under`` fail with ENOSPC once ``budget_bytes`` are written."""
    real = os.fdopen
    budget = {"left": int(budget_bytes)}
    root = os.path.realpath(under)

    def fdopen(fd, mode="r", *args, **kwargs):
        handle = real(fd, mode, *args, **kwargs)
        try:
            path = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            return handle
        if ("w" in mode or "a" in mode) and "b" in mode and path.startswith(root):
            return _Budgeted(handle, budget)
        return handle

    real_open = builtins.open

    def open_budgeted(file, mode="r", *args, **kwargs):
        handle = real_open(file, mode, *args, **kwargs)
        if isinstance(mode, str) and ("w" in mode or "a" in mode) and "b" in mode and isinstance(file, (str, Path)):
            if os.path.realpath(file).startswith(root):
                return _Budgeted(handle, budget)
        return handle

    os.fdopen = fdopen
    builtins.open = open_budgeted


if __name__ == "__main__":
    import runpy

    install_enospc(int(os.environ["FGCD_BENCH_ENOSPC_AFTER"]), os.environ["FGCD_BENCH_ENOSPC_UNDER"])
    runpy.run_module("fgcd_cli.cli.app", run_name="__main__", alter_sys=True)  # the fgcd command itself
