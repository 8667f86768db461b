"""``fgcd bench align``: scale-aware point cloud alignment (rACR §3.4).

Two parts.

**VSE sessions in the simulator** (the issue's main measurement). A reference
session and current sessions (another start offset, another lighting) are
rendered by the simulator and run through :class:`fgcd_cli.vse.MonocularVSE`;
the alignment sees only the VSE clouds, keyframes and images. Each session's
map is made metric as calibration would: the reference with the exact scale
(its frame is the world frame up to the VSE's own error), the current one with
a scale that is wrong by a few per cent (the session-scale error the alignment
must absorb). Initial similarities are the true one composed with random
errors up to 15 deg / 15 cm / 20 % scale. Errors are those of the current
keyframe *camera poses* mapped into the reference frame (what relocation
uses), against the renderer's true poses, in mm and degrees; the scale error is
against the similarity fitted between VSE and true camera centres. Each trial
runs the one-way fast alignment (``fast_*``: the API's default) and the
relocation loop's (``loop_fast_*``: the two-way scale); rACR's fine stage starts
from the loop's, as in the loop, and ``ablation_F`` is the loop's fast stage.

**Synthetic clouds** (controlled studies): timing on 20k current / 50k
reference points, and the paper's Fig. 4 noise study: half of the reference
points are "non-repeated", displaced by Gaussian noise with sigma
``r x cloud width`` (r = 1 ... 16 %).

Ground truth is read here only (evaluation code).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from fgcd_cli.alignment.fast import fast_align
from fgcd_cli.alignment.fast_config import FastAlignConfig, ScaleStepConfig
from fgcd_cli.alignment.fine import fine_align
from fgcd_cli.alignment.fine_config import FineAlignConfig
from fgcd_cli.alignment.reference import ReferenceIndex
from fgcd_cli.alignment.synthetic import ReliefScene, random_similarity
from fgcd_cli.relocation.config import RelocationConfig
from fgcd_cli.vse.types import VseStatus
from fgcd_core.camera import PinholeCamera
from fgcd_core.se3 import exp_se3, pose_distance, project_to_so3
from fgcd_core.sim3 import Sim3

#: The relocation loop's fast alignment (the two-way scale, docs/alignment.md, "Fast alignment").
LOOP_FAST = RelocationConfig().fast_align
SUCCESS_ROT_DEG = 1.0
SUCCESS_TRANS_MM = 20.0
SUCCESS_SCALE_PCT = 2.0
MAX_INIT = dict(rotation_deg=15.0, translation_m=0.15, scale_rel=0.20)
NOISE_LEVELS = (0.01, 0.02, 0.04, 0.08, 0.16)


# --------------------------------------------------------------------------- VSE sessions
def _vse_session(renderer, intr, camera, T_start, *, lighting, frames, radius, rng):
    """Render a small loop around ``T_start``, run the monocular VSE; returns its state and true poses."""
    from fgcd_cli.vse.engine import MonocularVSE

    engine = MonocularVSE(camera)
    truth = []
    state = None
    phase = rng.uniform(0, 2 * np.pi)
    for i in range(frames):
        a = phase + 2 * np.pi * i / frames
        T = T_start @ exp_se3(
            np.array([radius * np.sin(a), 0.6 * radius * np.sin(2 * a), 0.4 * radius * (np.cos(a) - 1), 0, 0, 0])
        )
        img = renderer.render(T, intr, lighting, want=("gray",), rng=rng).gray
        state = engine.process(img, 0.1 * i)
        truth.append((state.frames_processed, T))
    return state, dict(truth)


def _cloud_depth_ratio(state, truth_by_frame, T_world_map: Sim3, renderer, intr, camera) -> float:
    """Median ratio of the cloud's depths to the true depths, over the session's keyframes.

    The monocular VSE's cloud can be a little shallower or deeper than its own
    trajectory (docs/benchmarks.md, "Scale-aware point cloud alignment (`fgcd bench align`)"); that is
    the VSE's error, not the alignment's, so the benchmark defines each session's metric frame by its cloud.
    """
    P = T_world_map.apply(np.asarray(state.cloud.points, dtype=float))
    ratios = []
    for kf in state.keyframes:
        frame = int(round(kf.timestamp_s / 0.1)) + 1
        m = np.asarray(state.cloud.keyframe_ids) == kf.id
        if frame not in truth_by_frame or m.sum() < 50:
            continue
        T = truth_by_frame[frame]
        X = (P[m] - T[:3, 3]) @ T[:3, :3]
        uv, ok = camera.project(X)
        depth = renderer.render(T, intr, None, want=()).depth
        ui = np.clip(np.round(uv[ok]).astype(int), 0, [camera.width - 1, camera.height - 1])
        z_true = depth[ui[:, 1], ui[:, 0]]
        good = z_true > 0
        if good.sum() > 20:
            ratios.append(float(np.median(X[ok][good, 2] / z_true[good])))
    return float(np.median(ratios)) if ratios else 1.0


def _metric_session(state, truth_by_frame, *, scale_error: float, renderer=None, intr=None, camera=None):
    """Keyframes, cloud and the VSE-map -> world similarity of a session.

    With a renderer, the map -> world similarity is corrected (about the mean
    camera centre) so that the cloud, not the trajectory, matches the true depths.
    """
    kf_truth = []
    kf_est = []
    for kf in state.keyframes:
        frame = int(round(kf.timestamp_s / 0.1)) + 1
        if frame in truth_by_frame:
            kf_truth.append(truth_by_frame[frame])
            kf_est.append(np.asarray(kf.T_map_cam, dtype=float))
    T_world_map = _fit_map_to_world(kf_est, kf_truth)
    depth_ratio = 1.0
    if renderer is not None:
        depth_ratio = _cloud_depth_ratio(state, truth_by_frame, T_world_map, renderer, intr, camera)
        c = np.mean([T[:3, 3] for T in kf_truth], axis=0)
        T_world_map = Sim3(np.eye(3), c - c / depth_ratio, 1.0 / depth_ratio) @ T_world_map
    s = T_world_map.scale * (1.0 + scale_error)
    keyframes = []
    for kf, T in zip(state.keyframes, kf_est):
        Tm = T.copy()
        Tm[:3, 3] *= s
        keyframes.append((Tm, np.asarray(kf.image, dtype=np.float32)))
    points = np.asarray(state.cloud.points, dtype=float) * s
    # metric map frame -> world
    T_world_cur = T_world_map @ Sim3(np.eye(3), np.zeros(3), 1.0 / s)
    return keyframes, points, T_world_cur, kf_truth, depth_ratio


def _fit_map_to_world(est: list[np.ndarray], true: list[np.ndarray]) -> Sim3:
    """VSE map -> world similarity from keyframe poses: rotation from the orientations
    (chordal mean; camera centres of a few-cm loop pin it down poorly), then scale and
    translation from the centres by least squares."""
    M = sum(Tt[:3, :3] @ Te[:3, :3].T for Te, Tt in zip(est, true))
    R = project_to_so3(M)
    ce = np.array([T[:3, 3] for T in est]) @ R.T
    ct = np.array([T[:3, 3] for T in true])
    ce_c, ct_c = ce - ce.mean(axis=0), ct - ct.mean(axis=0)
    s = float(np.sum(ce_c * ct_c) / np.sum(ce_c * ce_c))
    return Sim3(R, ct.mean(axis=0) - s * ce.mean(axis=0), s)


def _camera_errors(T_ref_cur: Sim3, poses, truths) -> tuple[float, float]:
    errs = np.array([pose_distance(T_ref_cur.transform_pose(P), T) for P, T in zip(poses, truths)])
    return float(errs[:, 0].mean()), float(errs[:, 1].mean())


@dataclass(frozen=True, kw_only=True)
class _AlignSession:
    """One simulated revisit session as the alignment trials see it (current map -> reference: ``T_true``)."""

    lighting: str
    cloud_depth_ratio: float
    cur_points: np.ndarray
    keyframes: list
    vse_poses: list
    truths_ref: list
    T_true: Sim3


def _trial_row(
    session: _AlignSession, ref_index, camera, rng: np.random.Generator, *, fine: bool, small_start: bool
) -> dict:
    """One alignment trial from a random start: fast, rACR-S, and (``fine``) the fine stage with and without P.

    Half of the trials (``small_start``) start within 5 deg / 5 cm / 5 % (the loop's usual case), half up
    to the maxima of :data:`MAX_INIT`.
    """
    u = rng.uniform(0, 1, 3) * (1.0 / 3.0 if small_start else 1.0)
    pert = random_similarity(
        rng,
        rotation_deg=MAX_INIT["rotation_deg"] * u[0],
        translation_m=MAX_INIT["translation_m"] * u[1],
        scale_rel=MAX_INIT["scale_rel"] * u[2],
    )
    T_true, vse_poses, truths_ref = session.T_true, session.vse_poses, session.truths_ref
    init = pert @ T_true
    small = pert.rotation_deg() <= 5.0 and np.linalg.norm(pert.t) <= 0.05 and abs(pert.scale - 1) <= 0.05
    row = {
        "lighting": session.lighting,
        "cloud_depth_ratio": session.cloud_depth_ratio,
        "init_small": bool(small),
        "init_rot_deg": pert.rotation_deg(),
        "init_trans_mm": float(np.linalg.norm(pert.t) * 1e3),
        "init_scale_pct": 100 * abs(pert.scale - 1),
    }
    fast = fast_align(session.cur_points, ref_index, init=init)
    # the relocation loop's fast stage (the two-way scale): what the fine stage starts from in the loop
    loop = fast_align(session.cur_points, ref_index, init=init, config=LOOP_FAST)
    # rACR-S: the session scale is taken as exact (sigma_p = 1), only R, t are estimated.
    no_scale = fast_align(
        session.cur_points,
        ref_index,
        init=Sim3(init.R, init.t, 1.0),
        config=FastAlignConfig(scale=ScaleStepConfig(estimate=False)),
    )
    row.update(_score("fast", fast.T_ref_cur, vse_poses, truths_ref, T_true, fast.health.ok))
    row["fast_seconds"] = fast.seconds
    row.update(_score("loop", loop.T_ref_cur, vse_poses, truths_ref, T_true, loop.health.ok))
    row["loop_seconds"] = loop.seconds
    row["fast_start"] = str(fast.start)
    row.update(_score("S", no_scale.T_ref_cur, vse_poses, truths_ref, T_true, no_scale.health.ok))
    if loop.health.ok and fine:
        common = dict(ref_points=ref_index, cur_keyframes=session.keyframes, camera=camera, init=loop.T_ref_cur)
        fine_r = fine_align(**common, cur_points=session.cur_points)
        fine_p = fine_align(**common, cur_points=session.cur_points, config=FineAlignConfig(refine_keyframes=False))
        row.update(_score("fine", fine_r.T_ref_cur, fine_r.keyframe_poses, truths_ref, T_true, fine_r.health.ok))
        row.update(_score("P", fine_p.T_ref_cur, vse_poses, truths_ref, T_true, fine_p.health.ok))
        row["fine_seconds"] = fine_r.seconds
        row["fine_reason"] = fine_r.health.reason
    return row


def _vse_part(*, quick: bool, rng: np.random.Generator) -> dict:
    from fgcd_core.camera import CameraIntrinsics
    from fgcd_drivers.sim.render import Renderer
    from fgcd_drivers.sim.scenes import load_scene

    scene_name = "relief_panel"
    sc = load_scene(scene_name)
    renderer = Renderer(sc)
    w, h, f = 320, 240, 320.0
    intr = CameraIntrinsics(fx=f, fy=f, cx=(w - 1) / 2, cy=(h - 1) / 2, width=w, height=h)
    camera = PinholeCamera(fx=f, fy=f, cx=(w - 1) / 2, cy=(h - 1) / 2, width=w, height=h)
    T0 = sc.default_T_world_cam
    t = time.perf_counter()
    ref_state, ref_truth = _vse_session(
        renderer, intr, camera, T0, lighting="front", frames=40 if quick else 60, radius=0.06, rng=rng
    )
    ref_kfs, ref_pts, T_world_ref, _, ref_ratio = _metric_session(
        ref_state, ref_truth, scale_error=0.0, renderer=renderer, intr=intr, camera=camera
    )
    # The reference frame is the world frame as the reference session's VSE saw it.
    ref_points = T_world_ref.apply(ref_pts)  # reference frame := world (as the reference VSE saw it)
    ref_index = ReferenceIndex(
        ref_points, intensities=np.asarray(ref_state.cloud.intensities, dtype=float), view=(T0, camera)
    )
    session_specs = (
        [("sun-morning", 0.04, 0.015)]
        if quick
        else [("sun-morning", 0.04, 0.015), ("led:3", -0.05, -0.02), ("overcast", 0.02, 0.03)]
    )
    trials_per_session = 6 if quick else 10
    rows = []
    vse_seconds = time.perf_counter() - t
    for lighting, offset, scale_error in session_specs:
        T_start = T0 @ exp_se3(np.array([offset, -0.5 * offset, 0.3 * offset, 0.0, math.radians(2.0), 0.0]))
        t = time.perf_counter()
        state, truth = _vse_session(
            renderer, intr, camera, T_start, lighting=lighting, frames=30 if quick else 40, radius=0.05, rng=rng
        )
        vse_seconds += time.perf_counter() - t
        if state.status != VseStatus.TRACKING or len(state.keyframes) < 2:
            rows.append({"lighting": lighting, "vse_failed": True, "status": state.status})
            continue
        keyframes, cur_points, T_world_cur, kf_truth, cur_ratio = _metric_session(
            state, truth, scale_error=scale_error, renderer=renderer, intr=intr, camera=camera
        )
        keyframes = keyframes[-6:]
        kf_truth = kf_truth[-6:]
        session = _AlignSession(
            lighting=lighting,
            cloud_depth_ratio=cur_ratio,
            cur_points=cur_points,
            keyframes=keyframes,
            vse_poses=[T for T, _ in keyframes],
            truths_ref=kf_truth,
            T_true=T_world_cur,  # the reference cloud was put into the world frame, so ref = world here
        )
        rows += [
            _trial_row(session, ref_index, camera, rng, fine=k < (3 if quick else 5), small_start=not k % 2)
            for k in range(trials_per_session)
        ]
    degenerate = [
        _degenerate_case(name, intr, camera, rng, frames=25 if quick else 35)
        for name in DEGENERATE_SCENES + NEAR_PLANAR_SCENES
    ]
    return {
        "scene": scene_name,
        "reference_points": len(ref_index),
        "vse_seconds": vse_seconds,
        "degenerate_scenes": degenerate,
        "reference_cloud_depth_ratio": ref_ratio,
        "image_size": [w, h],
        "rows": rows,
    }


#: Scenes whose geometry leaves directions free: the health check must flag them.
DEGENERATE_SCENES = ("plane", "sphere")
#: Near-planar objects whose shallow relief, joints or outline pin them: smoothed normals call
#: them flat, the weak-direction probe must not (and the result must be right).
NEAR_PLANAR_SCENES = ("stele", "mural", "bricks")


def _degenerate_case(scene_name, intr, camera, rng, *, frames: int) -> dict:
    """VSE clouds of one scene aligned from near the truth: flags, probe and registration error."""
    from fgcd_drivers.sim.render import Renderer
    from fgcd_drivers.sim.scenes import load_scene

    sc = load_scene(scene_name)
    renderer = Renderer(sc)
    T0 = sc.default_T_world_cam
    ref_state, ref_truth = _vse_session(
        renderer, intr, camera, T0, lighting="front", frames=frames, radius=0.06, rng=rng
    )
    T_start = T0 @ exp_se3(np.array([0.03, -0.02, 0.01, 0.0, math.radians(1.5), 0.0]))
    cur_state, cur_truth = _vse_session(
        renderer, intr, camera, T_start, lighting="sun-morning", frames=frames, radius=0.05, rng=rng
    )
    if len(ref_state.keyframes) < 2 or len(cur_state.keyframes) < 2:
        return {"scene": scene_name, "vse_failed": True}
    # Each session's metric frame is defined by its cloud (renderer depths), as in the main part:
    # the VSE cloud and its own trajectory differ in scale on these walls too
    # (docs/lab/2026-11-25-code-comment-measurements.md, "Alignment").
    _, ref_pts, T_world_ref, _, _ = _metric_session(
        ref_state, ref_truth, scale_error=0.0, renderer=renderer, intr=intr, camera=camera
    )
    kfs, cur_pts, T_world_cur, kf_truth, _ = _metric_session(
        cur_state, cur_truth, scale_error=0.01, renderer=renderer, intr=intr, camera=camera
    )
    ref = ReferenceIndex(T_world_ref.apply(ref_pts), view=(T0, camera))
    init = random_similarity(rng, rotation_deg=2.0, translation_m=0.02, scale_rel=0.02) @ T_world_cur
    res = fast_align(cur_pts, ref, init=init)
    out = {
        "scene": scene_name,
        "flagged_degenerate": bool(res.health.degenerate),
        "ok": bool(res.health.ok),
        "condition_ratio": res.health.condition_ratio,
        "weak_probe": list(res.health.weak_probe),
        "reason": res.health.reason,
    }
    out.update(_score("fast", res.T_ref_cur, [T for T, _ in kfs], kf_truth, T_world_cur, res.health.ok))
    return out


def _score(prefix, T_est: Sim3, poses, truths, T_true: Sim3, ok: bool) -> dict:
    mm, deg = _camera_errors(T_est, poses, truths)
    scale_pct = 100 * abs(T_est.scale / T_true.scale - 1)
    success = deg < SUCCESS_ROT_DEG and mm < SUCCESS_TRANS_MM and scale_pct < SUCCESS_SCALE_PCT
    return {
        f"{prefix}_trans_mm": mm,
        f"{prefix}_rot_deg": deg,
        f"{prefix}_scale_pct": scale_pct,
        f"{prefix}_ok": bool(ok),
        f"{prefix}_success": bool(success),
    }


# --------------------------------------------------------------------------- synthetic clouds
def _synthetic_part(*, quick: bool, rng: np.random.Generator) -> dict:
    scene = ReliefScene(seed=3, width=0.6, amplitude=0.04)
    ref_pts, ref_n, ref_i = scene.sample(50000, rng=rng)
    ref = ReferenceIndex(ref_pts, normals=ref_n, intensities=ref_i)
    ref.normals  # noqa: B018 - build once, outside the timings

    def current(n=20000):
        p, _, _ = scene.sample(n, rng=rng, xlim=(-0.27, 0.2), ylim=(-0.22, 0.27))
        return p + rng.normal(0, 0.002, p.shape)

    # timing: warm re-alignment (the loop's steady state) and cold start from the largest errors
    warm, warm_loop, cold, cold_ok = [], [], [], []
    for _ in range(5 if quick else 15):
        p = current()
        T_true = random_similarity(rng, rotation_deg=rng.uniform(0, 180), translation_m=1.0, scale_rel=0.05)
        cur = T_true.inverse().apply(p)
        init = random_similarity(rng, rotation_deg=1.0, translation_m=0.01, scale_rel=0.01) @ T_true
        warm.append(fast_align(cur, ref, init=init).seconds)
        warm_loop.append(fast_align(cur, ref, init=init, config=LOOP_FAST).seconds)
        init = random_similarity(rng, rotation_deg=15.0, translation_m=0.15, scale_rel=0.2) @ T_true
        r = fast_align(cur, ref, init=init)
        cold.append(r.seconds)
        E = r.T_ref_cur @ T_true.inverse()
        cold_ok.append(E.rotation_deg() < SUCCESS_ROT_DEG and abs(E.scale - 1) < SUCCESS_SCALE_PCT / 100)
    # noise study (paper Fig. 4)
    noise = []
    trials = 6 if quick else 20
    for r_rel in NOISE_LEVELS:
        noisy = ref_pts.copy()
        moved = rng.random(len(noisy)) < 0.5
        noisy[moved] += rng.normal(0, r_rel * ref.width, (int(moved.sum()), 3))
        ref_noisy = ReferenceIndex(noisy)
        succ = oks = 0
        for _ in range(trials):
            p = current(10000)
            T_true = random_similarity(rng, rotation_deg=rng.uniform(0, 180), translation_m=1.0, scale_rel=0.05)
            u = rng.uniform(0, 1, 3)
            init = (
                random_similarity(rng, rotation_deg=15 * u[0], translation_m=0.15 * u[1], scale_rel=0.2 * u[2]) @ T_true
            )
            res = fast_align(T_true.inverse().apply(p), ref_noisy, init=init)
            E = res.T_ref_cur @ T_true.inverse()
            point_mm = float(np.mean(np.linalg.norm(E.apply(p) - p, axis=1)) * 1e3)
            succ += E.rotation_deg() < SUCCESS_ROT_DEG and point_mm < SUCCESS_TRANS_MM and abs(E.scale - 1) < 0.02
            oks += res.health.ok
        noise.append({"r_pct": 100 * r_rel, "success_rate": succ / trials, "health_ok_rate": oks / trials})
    return {
        "reference_points": len(ref),
        "current_points": 20000,
        "warm_median_s": float(np.median(warm)),
        "warm_loop_median_s": float(np.median(warm_loop)),
        "cold_median_s": float(np.median(cold)),
        "cold_success_rate_at_max_errors": float(np.mean(cold_ok)),
        "noise_study": noise,
    }


def _mean(rows, key):
    vals = [r[key] for r in rows if key in r]
    return float(np.mean(vals)) if vals else float("nan")


def run(*, quick: bool) -> dict:
    """Run the alignment benchmark; returns ``{"summary": {...}, "vse": ..., "synthetic": ...}``."""
    rng = np.random.default_rng(2024)
    t0 = time.perf_counter()
    synthetic = _synthetic_part(quick=quick, rng=rng)
    vse = _vse_part(quick=quick, rng=rng)
    rows = [r for r in vse["rows"] if not r.get("vse_failed")]
    fine_rows = [r for r in rows if "fine_rot_deg" in r]
    summary = {
        "fast_success_rate": _mean(rows, "fast_success"),
        "fast_hz": 1.0 / synthetic["warm_median_s"],
        "loop_fast_hz": 1.0 / synthetic["warm_loop_median_s"],
        "fast_cold_seconds": synthetic["cold_median_s"],
        "fine_seconds": _mean(fine_rows, "fine_seconds"),
        "rot_err_deg": _mean(fine_rows, "fine_rot_deg"),
        "trans_err_mm": _mean(fine_rows, "fine_trans_mm"),
        "scale_err_pct": _mean(fine_rows, "fine_scale_pct"),
        "fast_rot_err_deg": _mean(fine_rows, "fast_rot_deg"),
        "fast_trans_err_mm": _mean(fine_rows, "fast_trans_mm"),
        "fast_scale_err_pct": _mean(fine_rows, "fast_scale_pct"),
        "loop_fast_rot_err_deg": _mean(fine_rows, "loop_rot_deg"),
        "loop_fast_trans_err_mm": _mean(fine_rows, "loop_trans_mm"),
        "loop_fast_scale_err_pct": _mean(fine_rows, "loop_scale_pct"),
        "ablation_F_rot_err_deg": _mean(fine_rows, "loop_rot_deg"),
        "ablation_F_trans_err_mm": _mean(fine_rows, "loop_trans_mm"),
        "ablation_P_rot_err_deg": _mean(fine_rows, "P_rot_deg"),
        "ablation_P_trans_err_mm": _mean(fine_rows, "P_trans_mm"),
        "ablation_S_rot_err_deg": _mean(rows, "S_rot_deg"),
        "ablation_S_trans_err_mm": _mean(rows, "S_trans_mm"),
        "ablation_S_scale_err_pct": _mean(rows, "S_scale_pct"),
        "fast_success_rate_small_init": _mean([r for r in rows if r["init_small"]], "fast_success"),
        "fast_success_rate_large_init": _mean([r for r in rows if not r["init_small"]], "fast_success"),
        "degenerate_flagged_rate": float(
            np.mean(
                [
                    d.get("flagged_degenerate", False) and not d.get("ok", True)
                    for d in vse["degenerate_scenes"]
                    if d["scene"] in DEGENERATE_SCENES
                ]
            )
        ),
        "near_planar_trusted_rate": float(
            np.mean([bool(d.get("ok")) for d in vse["degenerate_scenes"] if d["scene"] in NEAR_PLANAR_SCENES])
        ),
        "near_planar_confident_wrong": int(
            sum(
                bool(d.get("fast_ok")) and not d.get("fast_success")
                for d in vse["degenerate_scenes"]
                if d["scene"] in NEAR_PLANAR_SCENES
            )
        ),
        "fast_confident_wrong_rate": float(np.mean([r["fast_ok"] and not r["fast_success"] for r in rows]))
        if rows
        else float("nan"),
    }
    for entry in synthetic["noise_study"]:
        summary[f"noise_success_r{entry['r_pct']:g}pct"] = entry["success_rate"]
    return {
        "summary": summary,
        "targets": {"fast_hz": 10.0, "fine_seconds": 1.0, "noise_success_up_to_r8pct": 0.95},
        "quick": quick,
        "seconds": time.perf_counter() - t0,
        "vse": vse,
        "synthetic": synthetic,
    }
