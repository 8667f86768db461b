"""Benchmark of the visual SLAM engines on simulated scenes along robot exploration motions.

For each scene a simulated rig (640x480 camera, exact nominal intrinsics so
that only the VSE is measured) is driven through an exploration pattern in
small guarded steps (a slow robot: ~1.5 mm and ~0.2 deg between frames); the
frames are rendered once and given to every engine variant. Evaluation reads
the simulator's ground truth (allowed here, never in ``fgcd_cli/vse``):

* ``ate_mm``: RMS camera-centre error over the tracked frames after the Sim(3)
  that best aligns the estimated centres to the true ones (Umeyama);
* ``cloud_median_error_pct_depth``: median of |z_est - z_true| / z_true over
  the cloud points, where z is the depth of the point along its keyframe ray,
  z_true the rendered depth at that pixel of the keyframe's true pose, and the
  map scale is the one that best fits the cloud (median ratio); the same with
  the trajectory's Sim(3) scale is reported as
  ``cloud_median_error_pct_depth_traj_scale`` (over a few-cm sweep that scale
  is itself uncertain by ~ATE / sweep size);
* ``cloud_points``; ``track_fps`` (tracking front-end) and ``overall_fps``
  (including keyframe mapping done inline).
"""

from __future__ import annotations

import math
import time

import numpy as np

from fgcd_cli.vse.engine import VseVariant, make_engine
from fgcd_cli.vse.types import VseConfig, VseStatus
from fgcd_core.camera import PinholeCamera
from fgcd_core.se3 import interpolate_pose, invert_pose, transform_points
from fgcd_core.sim3 import umeyama

__all__ = ["run", "exploration_waypoints", "evaluate"]

TEXTURED_SCENES = ("stele", "relief_panel", "mural")
HARD_SCENES = ("plaster", "plane", "sphere")
TARGETS = {"ate_mm": 2.0, "cloud_median_error_pct_depth": 0.5, "cloud_points": 10000, "track_fps": 15.0}


def exploration_waypoints(*, translation_m: float = 0.03, rotation_deg: float = 4.0, legs: int = 6) -> list[np.ndarray]:
    """Flange-frame waypoints of the exploration the relocation sessions make (shared definition)."""
    from fgcd_cli.relocation.session import exploration_waypoints as waypoints

    return waypoints(translation_m=translation_m, rotation_rad=math.radians(rotation_deg), legs=legs)


def _render_sequence(scene: str, *, legs: int, step_m: float, step_deg: float, seed: int = 0):
    from fgcd_core.platform import MotionGuard
    from fgcd_drivers.sim.rig import SimRigConfig, build_sim_rig

    rig = build_sim_rig(scene=scene, config=SimRigConfig(lighting="front", seed=seed, intrinsics_error="none"))
    try:
        intr = rig.camera.intrinsics_nominal
        camera = PinholeCamera(
            fx=intr.fx, fy=intr.fy, cx=intr.cx, cy=intr.cy, width=intr.width, height=intr.height, dist=intr.dist
        )
        guard = MotionGuard(rig.platform)
        T0 = rig.platform.flange_pose()
        images, truth = [], []

        def grab():
            f = rig.camera.grab()
            img = np.asarray(f.image)
            images.append(img if img.dtype == np.uint8 else np.clip(img * 255 + 0.5, 0, 255).astype(np.uint8))
            truth.append(rig.ground_truth.T_world_cam_true())

        grab()
        wps = exploration_waypoints(legs=legs)
        for a, b in zip(wps[:-1], wps[1:]):
            Ta, Tb = T0 @ a, T0 @ b
            dist = np.linalg.norm(Tb[:3, 3] - Ta[:3, 3])
            ang = math.degrees(np.arccos(np.clip((np.trace(Ta[:3, :3].T @ Tb[:3, :3]) - 1) / 2, -1, 1)))
            n = max(1, int(math.ceil(max(dist / step_m, ang / step_deg))))
            for k in range(1, n + 1):
                guard.move_to(interpolate_pose(Ta, Tb, k / n))
                grab()
        return camera, images, truth, rig.ground_truth
    finally:
        rig.close()


def evaluate(states, truth: list[np.ndarray], gt, camera: PinholeCamera, *, frame_dt: float = 0.1) -> dict:
    """Accuracy of one run against the ground truth (see the module docstring)."""
    from fgcd_core.camera import CameraIntrinsics

    final = states[-1]
    tracked = [i for i, s in enumerate(states) if s.status == VseStatus.TRACKING and s.T_map_cam is not None]
    out = {
        "status": final.status,
        "message": final.message,
        "frames": len(states),
        "tracked_frames": len(tracked),
        "keyframes": len(final.keyframes),
        "cloud_points": len(final.cloud),
        "track_fps": final.track_fps,
        "overall_fps": final.overall_fps,
        "ate_mm": None,
        "cloud_median_error_pct_depth": None,
        "cloud_median_error_pct_depth_traj_scale": None,
    }
    if len(tracked) < 4:
        return out
    est = np.array([states[i].T_map_cam[:3, 3] for i in tracked])
    tru = np.array([truth[i][:3, 3] for i in tracked])
    S = umeyama(est, tru, with_scale=True)
    out["ate_mm"] = float(1000 * np.sqrt(np.mean(np.sum((S.apply(est) - tru) ** 2, axis=1))))
    out["map_scale_m_per_unit"] = S.scale
    cloud = final.cloud
    if len(cloud) == 0:
        return out
    intr = CameraIntrinsics(
        fx=camera.fx,
        fy=camera.fy,
        cx=camera.cx,
        cy=camera.cy,
        width=camera.width,
        height=camera.height,
        dist=camera.dist,
    )
    z_est_all, z_true_all = [], []
    for kf in final.keyframes:
        sel = cloud.keyframe_ids == kf.id
        if not np.any(sel):
            continue
        i = int(round(kf.timestamp_s / frame_dt))
        depth = gt.depth(truth[i], intr)
        u, v = np.round(cloud.pixels[sel]).astype(int).T
        inside = (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
        z_true = np.zeros(sel.sum())
        z_true[inside] = depth[v[inside], u[inside]]
        z_est = transform_points(invert_pose(kf.T_map_cam), cloud.points[sel])[:, 2]
        ok = z_true > 0
        z_est_all.append(z_est[ok])
        z_true_all.append(z_true[ok])
    if not z_est_all:
        return out
    z_est = np.concatenate(z_est_all)
    z_true = np.concatenate(z_true_all)
    s_cloud = float(np.median(z_true / z_est))
    rel = np.abs(z_est * s_cloud - z_true) / z_true
    rel_traj = np.abs(z_est * S.scale - z_true) / z_true
    out["cloud_median_error_pct_depth"] = float(100 * np.median(rel))
    out["cloud_p90_error_pct_depth"] = float(100 * np.percentile(rel, 90))
    out["cloud_median_error_pct_depth_traj_scale"] = float(100 * np.median(rel_traj))
    out["scene_depth_m"] = float(np.median(z_true))
    return out


def _run_engine(engine, images, *, frame_dt: float = 0.1):
    states = []
    t0 = time.perf_counter()
    for i, img in enumerate(images):
        states.append(engine.process(img, i * frame_dt))
    return states, time.perf_counter() - t0


def run(*, quick: bool, variant: str = "mono") -> dict:
    """Run the benchmark.

    Parameters
    ----------
    quick : bool
        Three scenes, half the exploration (three legs), no hard scenes.
    variant : {"mono", "sparse", "both"}
        Engines to run; the summary always holds the first engine's figures and,
        with ``both``, the sparse ones under ``sparse_*`` keys.

    Returns
    -------
    dict
        ``summary`` (``ate_mm``, ``cloud_median_error_pct_depth``, ``cloud_points``,
        ``track_fps``; medians over the textured scenes, worst ATE as ``ate_mm_max``),
        ``scenes`` (per scene and engine), ``targets``, ``settings``.
    """
    variants = {
        "mono": [VseVariant.MONO],
        "sparse": [VseVariant.SPARSE],
        "both": [VseVariant.MONO, VseVariant.SPARSE],
    }.get(variant)
    if variants is None:
        raise ValueError("variant must be mono, sparse or both")
    legs = 3 if quick else 6
    step_m, step_deg = 0.0015, 0.2
    scenes = list(TEXTURED_SCENES) + ([] if quick else list(HARD_SCENES))
    rows = []
    for scene in scenes:
        camera, images, truth, gt = _render_sequence(scene, legs=legs, step_m=step_m, step_deg=step_deg)
        for v in variants:
            eng = make_engine(v, camera, config=VseConfig())
            states, secs = _run_engine(eng, images)
            row = {"scene": scene, "variant": v, "textured": scene in TEXTURED_SCENES, "seconds": secs}
            row.update(evaluate(states, truth, gt, camera))
            rows.append(row)

    def agg(v: str) -> dict:
        rs = [r for r in rows if r["variant"] == v and r["textured"]]
        ate = [r["ate_mm"] for r in rs]
        cloud = [r["cloud_median_error_pct_depth"] for r in rs]
        nan = float("nan")
        return {
            "ate_mm": float(np.median(ate)) if rs and None not in ate else nan,
            "ate_mm_max": float(np.max(ate)) if rs and None not in ate else nan,
            "cloud_median_error_pct_depth": float(np.median(cloud)) if rs and None not in cloud else nan,
            "cloud_median_error_pct_depth_traj_scale": float(
                np.median([r["cloud_median_error_pct_depth_traj_scale"] for r in rs])
            )
            if rs and None not in cloud
            else nan,
            "cloud_points": int(np.median([r["cloud_points"] for r in rs])) if rs else 0,
            "track_fps": float(np.median([r["track_fps"] for r in rs])) if rs else nan,
            "overall_fps": float(np.median([r["overall_fps"] for r in rs])) if rs else nan,
        }

    summary = agg(variants[0])
    if VseVariant.SPARSE in variants and variants[0] != VseVariant.SPARSE:
        summary.update({f"sparse_{k}": val for k, val in agg(VseVariant.SPARSE).items()})
    summary["hard_scenes"] = {
        f"{r['scene']}/{r['variant']}": f"{r['status']}, {r['cloud_points']} points" for r in rows if not r["textured"]
    }
    return {
        "summary": summary,
        "scenes": rows,
        "targets": TARGETS,
        "settings": {
            "quick": quick,
            "variants": variants,
            "legs": legs,
            "step_m": step_m,
            "step_deg": step_deg,
            "resolution": [640, 480],
            "lighting": "front",
            "intrinsics": "exact nominal",
        },
    }
