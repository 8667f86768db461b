"""What a run depended on, the deterministic mode's pinned native threads (docs/relocation.md, "Reproducibility"),
and the one BLAS thread of every command (:func:`limit_blas_threads`).

The parallel rACR loop varies from run to run: how many frames the VSE
processes while an alignment runs, and which estimate an adjustment takes,
depend on the machine's speed and load. A deterministic run
(``RelocationConfig.deterministic``) steps the threads in a fixed order and
pins the native thread pools to one thread, so that the same seeds give the
same figures. Every visit records :func:`run_conditions` in its manifest.
"""

from __future__ import annotations

import os
import platform
import sys
from dataclasses import replace
from importlib import metadata

__all__ = [
    "NATIVE_THREAD_VARIABLES",
    "deterministic_rig",
    "limit_blas_threads",
    "pin_native_threads",
    "run_conditions",
    "scenario_seeds",
]

#: The variables that size a BLAS pool: a user who sets one has chosen the pool, and it is left alone.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")

#: Environment variables that size the native thread pools (OpenMP: Open3D; BLAS: numpy, scipy), read when
#: each library loads: the CLI sets them before it imports one (:func:`pin_native_threads`).
NATIVE_THREAD_VARIABLES = ("OMP_NUM_THREADS", *BLAS_THREAD_VARIABLES)

_PACKAGES = (
    "fgcd",
    "numpy",
    "scipy",
    "threadpoolctl",
    "opencv-python",
    "opencv-python-headless",
    "opencv-contrib-python",
    "opencv-contrib-python-headless",
    "open3d",
    "open3d-cpu",
)


def limit_blas_threads() -> None:
    """One BLAS thread for the rest of the process and its children, unless the user sized the pool.

    Rule: fgcd's BLAS products are tall and thin (N x 3 points, 3 x N pseudo-normals, small normal
    equations) and run beside OpenCV's own pool and, in a relocation, beside the VSE, alignment and
    adjustment threads. A BLAS call split over two threads whose second core is busy waits for that
    core, and costs many times its one-thread time (docs/lab/2026-12-07-blas-threads.md). Sets the
    variables (children such as Dask workers load their BLAS afterwards; every visit's manifest records
    them, :func:`run_conditions`) and, with ``threadpoolctl``, limits the pools already loaded.
    """
    if any(name in os.environ for name in BLAS_THREAD_VARIABLES):
        return
    for name in BLAS_THREAD_VARIABLES:
        os.environ[name] = "1"
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # a pool loaded before keeps its size
        return
    threadpool_limits(1, user_api="blas")


def pin_native_threads() -> dict:
    """One thread in every native pool a deterministic run meets; what was pinned.

    Environment variables for the libraries not yet loaded; ``cv2.setNumThreads(1)``; and, when
    ``threadpoolctl`` is installed, the pools of the libraries already loaded (BLAS, OpenMP).
    Floating-point sums split across threads can differ in their last bits from run to run.
    """
    for name in NATIVE_THREAD_VARIABLES:
        os.environ[name] = "1"
    pinned = {"environment": {name: "1" for name in NATIVE_THREAD_VARIABLES}}
    import cv2

    cv2.setNumThreads(1)
    pinned["opencv_threads"] = cv2.getNumThreads()
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        pinned["threadpoolctl"] = "not installed: pools loaded before the pin keep their size"
    else:
        threadpool_limits(1)
        pinned["threadpoolctl"] = "limited to 1"
    return pinned


def deterministic_rig(rig, deterministic: bool = True):
    """The rig's handles with a stepped VSE (:class:`fgcd_cli.vse.thread.SteppedVse`) instead of its thread
    (``deterministic`` False: the rig as it is)."""
    from fgcd_cli.vse.thread import SteppedVse

    if not deterministic:
        return rig
    factory = rig.vse_factory
    return replace(rig, vse_factory=lambda: SteppedVse.like(factory()))


def _versions() -> dict:
    out = {"python": sys.version.split()[0]}
    for name in _PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return out


def _thread_counts() -> dict:
    import cv2

    counts = {"cpu_count": os.cpu_count(), "opencv": cv2.getNumThreads()}
    counts.update({name: os.environ.get(name) for name in NATIVE_THREAD_VARIABLES})
    return counts


def scenario_seeds(metadata: dict | None) -> dict:
    """The seeds of a run's simulated world in a visit's metadata (``scenario``: world, session, changes)."""
    scenario = (metadata or {}).get("scenario") or {}
    return {k: v for k, v in scenario.items() if "seed" in k}


def run_conditions(config, metadata: dict | None = None) -> dict:
    """What a relocation's figures depended on, for its visit's manifest.

    Parameters
    ----------
    config : RelocationConfig
        Its ``mode`` and ``deterministic`` (the threads stepped in a fixed order, else side by side: the
        run may vary); the alignment stages' own seeds.
    metadata : dict, optional
        The visit's metadata: the seeds of its simulated world (:func:`scenario_seeds`).

    Returns
    -------
    dict
        ``threads``, ``mode``, ``deterministic``, ``seeds``, ``versions``, ``thread_counts``, ``machine``.
    """
    seeds = {**scenario_seeds(metadata), "fast_align": config.fast_align.seed, "fine_align": config.fine_align.seed}
    return {
        "threads": "stepped in a fixed order (deterministic)"
        if config.deterministic
        else f"{config.mode}: side by side, may vary from run to run",
        "mode": str(config.mode),
        "deterministic": bool(config.deterministic),
        "seeds": seeds,
        "versions": _versions(),
        "thread_counts": _thread_counts(),
        "machine": {
            "platform": platform.platform(),
            "machine": platform.machine(),
            "processor": platform.processor(),
            "node": platform.node(),
        },
    }
