"""A 24 MP ``fgcd diff`` under a memory limit (``fgcd bench faults``, class ``memory_limit_diff``).

``python -m fgcd_cli.bench.faults.memory_limit ARGS`` is ``fgcd ARGS`` with its address
space limited to ``FGCD_BENCH_RLIMIT_AS_MB`` MiB (``resource.setrlimit(RLIMIT_AS)``
in the child itself before fgcd is imported, as ``ulimit -v`` does in a shell;
the worker processes it starts inherit it). The pair is the one
:mod:`fgcd_cli.bench.changes.large` synthesises (Db-1 upscaled 7x, 24 MP), with
three of its lightings, made once per bench campaign. Expected: the diff
completes (exit 0, every product there) or ends with one line and exit 1 or 6
(README, "Errors"), and the output folder holds only complete products: no
``.tmp-*`` write leftover, every file readable.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from fgcd_cli.bench.faults.checks import run_fgcd

__all__ = ["LIGHTINGS", "memory_fault", "prepare_pair"]

#: The lightings of Db-1 in the pair (three of seven: the same 24 MP frames, a third of the bench's memory).
LIGHTINGS = (1, 4, 7)
#: Db-1 upscaled this much: ~4900 x 4900 px (24 MP).
FACTOR = 7
#: The address-space limit is drawn uniformly in this range, MiB: the bench's 24 MP diff peaks at ~3.4 GB
#: resident with seven lightings (docs/benchmarks.md, "Fine-grained change detection (`fgcd bench changes`)",
#: `peak_rss_mb_24mp`), so the range
#: spans failing early, late and completing.
LIMIT_MB = (1024, 6144)
#: The products a completed bare-image diff writes (fgcd_cli/app/diff.py, ``diff_products``).
REQUIRED = ("regions.json", "change_mask.png")
#: Exit codes (README, "Errors"): success, an operating-system error (out of memory), no trustworthy answer.
CODES = (0, 1, 6)


def prepare_pair(workdir: Path) -> Path | None:
    """The 24 MP pair under ``workdir`` (made once); None when the FGCD dataset's Db-1 is not there."""
    from fgcd_cli.bench.changes.large import DATASET, GROUP, synthesise

    folder = Path(workdir) / "fs-24mp"
    if (folder / ".done").is_file():
        return folder
    source = DATASET / GROUP[0] / GROUP[1]
    if not (source / "GT.png").is_file():
        return None
    synthesise(source, folder, factor=FACTOR, lightings=list(LIGHTINGS))
    (folder / ".done").write_text("ok\n")
    return folder


def _incomplete(out: Path) -> list[str]:
    """Files of ``out`` that are write leftovers or cannot be read back whole."""
    import cv2

    bad = []
    for path in sorted(out.rglob("*")):
        if not path.is_file():
            continue
        try:
            if path.name.startswith(".tmp-"):
                raise ValueError("write leftover")
            if path.suffix == ".json":
                json.loads(path.read_text(encoding="utf-8"))
            elif path.suffix == ".png" and cv2.imread(str(path), cv2.IMREAD_UNCHANGED) is None:
                raise ValueError("not a whole PNG")
            elif path.suffix == ".npy":
                np.load(path)
        except (OSError, ValueError):
            bad.append(path.relative_to(out).as_posix())
    return bad


def memory_fault(seed: int, campaign: Path):
    """One 24 MP bare-image diff under a seeded address-space limit; its judged outcome."""
    from fgcd_cli.bench.faults.fs_outcome import FsOutcome, skipped

    rng = np.random.default_rng(seed)
    limit_mb = int(rng.integers(*LIMIT_MB))
    pair = prepare_pair(Path(campaign).parent)
    if pair is None:
        return skipped("memory_limit_diff", seed, "the FGCD dataset's group Db-1 is not there to make a 24 MP pair")
    out = Path(tempfile.mkdtemp(prefix="fgcd-memdiff-", dir=str(Path(campaign).parent))) / "out"
    try:
        run = run_fgcd(
            [
                "diff",
                "--ref",
                ",".join(str(pair / f"ref-{k}.png") for k in LIGHTINGS),
                "--cur",
                ",".join(str(pair / f"cur-{k}.png") for k in LIGHTINGS),
                "-o",
                str(out),
                "--json",
            ],
            launcher=["fgcd_cli.bench.faults.memory_limit"],
            env={"FGCD_BENCH_RLIMIT_AS_MB": str(limit_mb)},
            timeout_s=1800,
        )
        bad = _incomplete(out) if out.exists() else []
        missing = [name for name in REQUIRED if run.code == 0 and not (out / name).is_file()]
        lines = run.error_lines or run.lines or [""]
        detail = "; ".join([f"half-written {b}" for b in bad] + [f"missing {m}" for m in missing]) or lines[-1]
        return FsOutcome(
            fault="memory_limit_diff",
            seed=seed,
            command=f"diff 24 MP (RLIMIT_AS {limit_mb} MiB)",
            code=run.code,
            expected=CODES,
            stderr_lines=run.failure_lines,
            traceback=run.traceback,
            one_line_expected=run.code != 0,
            detail=detail,
            leftovers=bad + missing,
            extra={
                "limit_mb": limit_mb,
                "seconds": round(run.seconds, 1),
                "products": sorted(p.name for p in out.iterdir()) if out.exists() else [],
            },
        )
    finally:
        shutil.rmtree(out.parent, ignore_errors=True)


def _limit_address_space() -> None:
    """``RLIMIT_AS`` from ``FGCD_BENCH_RLIMIT_AS_MB`` (soft and hard: the child cannot raise it again)."""
    import resource

    limit = int(os.environ["FGCD_BENCH_RLIMIT_AS_MB"]) << 20
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))


if __name__ == "__main__":
    import runpy

    _limit_address_space()
    runpy.run_module("fgcd_cli.cli.app", run_name="__main__", alter_sys=True)  # the fgcd command itself
