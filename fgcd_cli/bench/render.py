"""Benchmark of the simulator's renderer: per-frame time at 640x480 for each scene."""

from __future__ import annotations

import os
import statistics
import time

import numpy as np

from fgcd_core.camera import CameraIntrinsics
from fgcd_drivers.sim.appearance import world_appearance
from fgcd_drivers.sim.render import Renderer
from fgcd_drivers.sim.scenes import list_scenes, load_scene

__all__ = ["run", "TARGET_MS"]

TARGET_MS = 200.0


def run(*, quick: bool = False, supersample: int = 1, lighting: str = "front") -> dict:
    """Time the shaded gray frame (depth, normals, labels included) of every scene.

    Each scene renders ``repeats`` frames at small random offsets around its default
    camera after one warm-up frame (ray cache, first-touch allocations). ``quick``
    uses 3 scenes and 3 frames each. The world is the process's (``fgcd bench --world``).

    Returns
    -------
    dict with ``scenes`` (per-scene medians), ``summary`` (``ms_per_frame_median``
    over all frames, ``ms_per_frame_p90``, ``target_ms``) and the machine load.
    """
    appearance = world_appearance()
    intr = CameraIntrinsics(fx=600.0, fy=600.0, cx=319.5, cy=239.5, width=640, height=480)
    names = [s.name for s in list_scenes()]
    if quick:
        names = [n for n in ("stele", "plane", "sphere") if n in names] or names[:3]
    repeats = 3 if quick else 8
    rng = np.random.default_rng(0)
    per_scene = []
    all_ms = []
    all_cpu = []  # process CPU time (all threads): what a frame costs, whatever else runs on the machine
    for name in names:
        t0 = time.perf_counter()
        sc = load_scene(name)
        build_s = time.perf_counter() - t0
        r = Renderer(sc, supersample=supersample, appearance=appearance)
        r.render(sc.default_T_world_cam, intr, lighting, want=("gray",))
        times, cpu = [], []
        for _ in range(repeats):
            T = sc.default_T_world_cam.copy()
            T[:3, 3] += rng.normal(0, 0.01, 3)
            t0, c0 = time.perf_counter(), time.process_time()
            r.render(T, intr, lighting, want=("gray",))
            times.append((time.perf_counter() - t0) * 1000)
            cpu.append((time.process_time() - c0) * 1000)
        all_ms += times
        all_cpu += cpu
        per_scene.append(
            {
                "scene": name,
                "ms_median": statistics.median(times),
                "ms_min": min(times),
                "cpu_ms_median": statistics.median(cpu),
                "triangles": sc.n_triangles,
                "build_s": build_s,
            }
        )
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return {
        "settings": {
            "width": 640,
            "height": 480,
            "supersample": supersample,
            "lighting": lighting,
            "world": appearance.name,
            "frames_per_scene": repeats,
            "quick": quick,
        },
        "scenes": per_scene,
        "machine": {"cpu_count": os.cpu_count(), "load_avg_1min": load},
        "summary": {
            "ms_per_frame_median": statistics.median(all_ms),
            "ms_per_frame_p90": float(np.percentile(all_ms, 90)),
            "ms_per_frame_min": min(all_ms),
            "cpu_ms_per_frame_median": statistics.median(all_cpu),
            "target_ms": TARGET_MS,
        },
    }
