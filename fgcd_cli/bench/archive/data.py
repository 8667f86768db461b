"""Small simulated campaigns for the archive benchmark and tests: N stations x M visits in seconds.

``fgcd demo`` builds one complete campaign through the rig (calibration, VSE,
relocation) in minutes; an archive of many stations needs campaigns faster.
Here the observations are rendered by the simulator at the station's reference
pose and written through the campaign store (:mod:`fgcd_cli.campaign.store`, the
one file-layout writer), like a capture and its revisits would write them:

- the reference: one image per lighting, a metric cloud (the rendered depth
  back-projected, standing in for the VSE's metric cloud a capture stores),
  ``T_ref_camref`` and the intrinsics;
- visit ``j``: the same lightings from a pose a relocation residual away
  (0.5 mm, 0.1 deg), another exposure and sensor noise, and the station's
  changes as they grow: change ``i`` appears at visit ``1 + i`` and its size
  grows by :data:`GROWTH_PER_VISIT` of its first size at every later visit.

Ground truth (the changes' sizes) is kept in ``evaluation/sim_truth.json``
(evaluation only; no algorithm reads it).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

from fgcd_cli.bench.changes.simulated import _changes_in_view
from fgcd_cli.campaign import schema
from fgcd_cli.campaign.store import init_campaign
from fgcd_core.camera import CameraIntrinsics
from fgcd_core.se3 import exp_se3
from fgcd_drivers.sim.render import Renderer
from fgcd_drivers.sim.scenes import load_scene
from fgcd_drivers.sim.sensor import CameraEffects

LIGHTINGS = ("led:2", "led:6", "led:10")
GROWTH_PER_VISIT = 0.5
"""Each change's size grows by this fraction of its first size per visit."""
VISIT_INTERVAL_DAYS = 91
FIRST_VISIT = datetime(2024, 3, 1, tzinfo=UTC)


@dataclass(frozen=True, kw_only=True)
class SyntheticArchiveConfig:
    """The shape of a synthetic archive.

    Attributes
    ----------
    campaigns, stations, visits : int
        Campaigns, stations per campaign, visits per station (the first visit shows no change).
    width, height : int
        Image size, px.
    focal_px : float
        Focal length, px (1000 px at the mural's 1.5 m: 1.5 mm per pixel).
    changes : int
        Changes per station (change ``i`` appears at visit ``1 + i``).
    size_mm : float
        First size of every change, mm.
    scene : str
        Simulator scene of every station (stations look at different parts of it).
    seed : int
    """

    campaigns: int = 3
    stations: int = 2
    visits: int = 3
    width: int = 320
    height: int = 240
    focal_px: float = 1000.0
    changes: int = 2
    size_mm: float = 14.0
    scene: str = "mural"
    seed: int = 0


def visit_stamp(index: int) -> str:
    """The directory name of visit ``index``: a UTC stamp one season after the previous one."""
    return schema.utc_stamp(FIRST_VISIT + timedelta(days=VISIT_INTERVAL_DAYS * index))


def _station_pose(scene, k: int) -> np.ndarray:
    """The reference camera of station ``k``: the scene's default view moved 0.25 m sideways per station."""
    T = np.asarray(scene.default_T_world_cam, dtype=float).copy()
    shift = np.array([0.25 * ((k % 5) - 2), 0.15 * ((k // 5) % 3 - 1), 0.0])
    T[:3, 3] += T[:3, :3] @ shift
    return T


def _reference_cloud(depth: np.ndarray, intr: CameraIntrinsics, T_ref_cam: np.ndarray, step: int = 2) -> np.ndarray:
    """(N, 3) points in the reference frame from a depth image (every ``step``-th pixel), metres."""
    v, u = np.mgrid[0 : depth.shape[0] : step, 0 : depth.shape[1] : step]
    z = depth[v, u]
    ok = np.isfinite(z) & (z > 0)
    x = (u[ok] - intr.cx) / intr.fx * z[ok]
    y = (v[ok] - intr.cy) / intr.fy * z[ok]
    pc = np.stack([x, y, z[ok]], axis=1)
    return pc @ T_ref_cam[:3, :3].T + T_ref_cam[:3, 3]


def _changes_at(base: list, visit: int) -> list:
    """The changes present at ``visit``: change ``i`` from visit ``1 + i``, grown by GROWTH_PER_VISIT a visit."""
    out = []
    for i, change in enumerate(base):
        age = visit - 1 - i
        if age >= 0:
            out.append(replace(change, size_mm=change.size_mm * (1.0 + GROWTH_PER_VISIT * age)))
    return out


def _write_station(camp, name: str, k: int, renderer: Renderer, config: SyntheticArchiveConfig) -> dict:
    scene, c = renderer.scene, config
    intr = CameraIntrinsics(
        fx=c.focal_px, fy=c.focal_px, cx=(c.width - 1) / 2, cy=(c.height - 1) / 2, width=c.width, height=c.height
    )
    T_ref = _station_pose(scene, k)
    rng = np.random.default_rng(c.seed * 1000 + k)
    effects = CameraEffects(read_noise=0.003, shot_noise=0.004)
    geometry = renderer.render(T_ref, intr, None, want=("depth",))
    exposure = renderer.render(T_ref, intr, LIGHTINGS[0], want=("gray",)).exposure
    station = camp.create_station(name, description=f"synthetic station {k} on scene {scene.name}")
    meta = {"lightings": list(LIGHTINGS), "intrinsics": intr.to_dict(), "synthetic": "fgcd_cli.bench.archive.data"}
    with station.write_reference(meta) as w:
        for light in LIGHTINGS:
            w.add_image(
                light,
                renderer.render(T_ref, intr, light, effects=effects, exposure=exposure, rng=rng, want=("rgb",)).rgb,
            )
        w.add_cloud(_reference_cloud(geometry.depth, intr, T_ref))
        w.add_array(schema.ARRAY_T_REF_CAMREF, T_ref)
        w.commit()
    base = [
        replace(ch, size_mm=c.size_mm)
        for ch in _changes_in_view(scene, T_ref, intr, n=c.changes, seed=c.seed * 1000 + k)
    ]
    truth = {}
    for j in range(c.visits):
        xi = np.r_[rng.normal(size=3) / np.sqrt(3) * 0.5e-3, rng.normal(size=3) / np.sqrt(3) * np.deg2rad(0.1)]
        T_cur = T_ref @ exp_se3(xi)
        present = _changes_at(base, j)
        with station.new_visit({"lightings": list(LIGHTINGS), "intrinsics": intr.to_dict()}, stamp=visit_stamp(j)) as w:
            for light in LIGHTINGS:
                w.add_image(
                    light,
                    renderer.render(
                        T_cur,
                        intr,
                        light,
                        changes=present or None,
                        effects=effects,
                        exposure=exposure * 0.85,
                        rng=rng,
                        want=("rgb",),
                    ).rgb,
                )
            w.add_json(
                schema.SIM_TRUTH,
                {
                    "changes": [
                        {"kind": ch.kind, "size_mm": ch.size_mm, "position": list(ch.position)} for ch in present
                    ]
                },
            )
            w.commit()
        truth[visit_stamp(j)] = len(present)
    return truth


def build_synthetic_archive(root: Path, config: SyntheticArchiveConfig = SyntheticArchiveConfig()) -> list[Path]:
    """Write ``config.campaigns`` simulated campaigns under ``root`` (``root/site-<i>``); returns their paths."""
    root = Path(root)
    renderer = Renderer(load_scene(config.scene))
    paths = []
    for i in range(config.campaigns):
        camp = init_campaign(root / f"site-{i}", site=f"synthetic site {i}")
        for s in range(config.stations):
            _write_station(camp, f"S{s + 1:02d}", i * config.stations + s, renderer, config)
        paths.append(camp.path)
    return paths
