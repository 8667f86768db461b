"""``fgcd bench archive``: the archive analysis at scale on Dask (docs/benchmarks.md,
"Archive analysis on Dask (`fgcd bench archive`)").

Builds a synthetic archive (:mod:`fgcd_cli.bench.archive.data`: N stations x M
visits of small simulated images), then times the archive use case
(:func:`fgcd_cli.app.archive.analyze_archive`, the one the CLI calls) with 1 and
2 local workers (every visit forced), and a re-run when nothing changed.
Throughput counts from the first submission to the last result (the cluster's
start-up is reported apart); the scheduler's own cost per task is measured with
trivial tasks on the same kind of cluster.
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from pathlib import Path

from fgcd_cli.app.archive import ArchiveRequest, analyze_archive, dask_client
from fgcd_cli.app.archive_task import VisitStatus
from fgcd_cli.bench.archive.data import SyntheticArchiveConfig, build_synthetic_archive
from fgcd_cli.campaign import schema

TRIVIAL_TASKS = 2000


def trivial_task(i: int) -> int:
    """A task that does nothing (the scheduler-overhead measurement)."""
    return i


def _scheduler_overhead_ms(n_tasks: int) -> dict:
    """Wall time per trivial task on a 2-worker LocalCluster, ms (submitted together, gathered together)."""
    with dask_client(scheduler=None, workers=2) as client:
        client.gather(client.map(trivial_task, range(50), pure=False))  # warm: workers have imported this module
        t0 = time.perf_counter()
        client.gather(client.map(trivial_task, range(n_tasks), pure=False))
        batch = time.perf_counter() - t0
        t0 = time.perf_counter()
        for i in range(50):
            client.submit(trivial_task, i, pure=False).result()
        round_trip = time.perf_counter() - t0
    return {"per_task_ms": 1000 * batch / n_tasks, "round_trip_ms": 1000 * round_trip / 50, "tasks": n_tasks}


def _regions(root: Path) -> dict:
    out = {}
    for path in sorted(root.glob(f"*/stations/*/visits/*/{schema.change_relpath(schema.REGIONS_JSON)}")):
        regions = json.loads(path.read_text(encoding="utf-8"))["regions"]
        out[str(path.relative_to(root))] = [(r["area_px"], r["bbox_xywh"]) for r in regions]
    return out


def _timed_run(root: Path, *, workers: int, force: bool) -> dict:
    result = analyze_archive(ArchiveRequest(roots=[root], workers=workers, force=force))
    n = len(result.outcomes)
    return {
        "workers": result.workers,
        "visits": n,
        "done": result.count(VisitStatus.DONE),
        "skipped": result.count(VisitStatus.SKIPPED),
        "failed": result.count(VisitStatus.FAILED),
        "cluster_start_s": result.start_s,
        "run_s": result.run_s,
        "visits_per_minute": 60.0 * n / result.run_s if result.run_s > 0 else float("nan"),
        "task_s_median": sorted(o.seconds for o in result.outcomes)[n // 2] if n else float("nan"),
        "peak_worker_rss_mb": max((o.worker_peak_rss_mb for o in result.outcomes), default=0.0),
    }


def run(*, quick: bool) -> dict:
    """Build a synthetic archive, analyse it with 1 and 2 workers, re-run it unchanged (summary: issue 22's keys)."""
    config = (
        SyntheticArchiveConfig(campaigns=2, stations=2, visits=3)
        if quick
        else SyntheticArchiveConfig(campaigns=3, stations=3, visits=4)
    )
    with tempfile.TemporaryDirectory(prefix="fgcd-bench-archive-") as tmp:
        root = Path(tmp)
        t0 = time.perf_counter()
        build_synthetic_archive(root, config)
        build_s = time.perf_counter() - t0
        one = _timed_run(root, workers=1, force=True)
        regions_1w = _regions(root)
        two = _timed_run(root, workers=2, force=True)
        regions_2w = _regions(root)
        differ = sorted(k for k in regions_1w if regions_1w[k] != regions_2w.get(k))
        rerun = _timed_run(root, workers=2, force=False)
    overhead = _scheduler_overhead_ms(TRIVIAL_TASKS // (4 if quick else 1))
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    return {
        "archive": {
            "campaigns": config.campaigns,
            "stations_per_campaign": config.stations,
            "visits_per_station": config.visits,
            "image_size": [config.width, config.height],
            "lightings": 3,
            "build_s": build_s,
        },
        "runs": {"1_worker": one, "2_workers": two, "rerun_unchanged": rerun},
        "scheduler": overhead,
        "regions_identical_1w_2w": not differ,
        "regions_differ_1w_2w": {k: {"1w": regions_1w[k], "2w": regions_2w.get(k)} for k in differ},
        "machine": {"cpu_count": os.cpu_count(), "load_avg_1min": load},
        "summary": {
            "visits_per_minute_1w": one["visits_per_minute"],
            "visits_per_minute_2w": two["visits_per_minute"],
            "scheduler_overhead_ms": overhead["per_task_ms"],
            "peak_worker_rss_mb": max(one["peak_worker_rss_mb"], two["peak_worker_rss_mb"]),
            "rerun_skip_seconds": rerun["run_s"],
        },
    }
