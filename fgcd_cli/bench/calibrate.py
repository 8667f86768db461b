"""``fgcd bench calibrate``: intrinsics, hand-eye (board and target-free) and map scale on simulated rigs.

Each rig (seeded: its own hidden hand-eye, true intrinsics and platform errors)
goes through what a user does on site:

1. intrinsics from ChArUco views rendered with the rig camera's true intrinsics
   and distortion (:func:`fgcd_drivers.sim.board.render_board_view`);
2. hand-eye with a board: the simulated platform visits the target stops (with
   its execution and encoder errors), the camera sees a board fixed in the
   world, ``solvePnP`` with the *calibrated* intrinsics, OpenCV's solvers;
3. target-free (rACR): the platform makes the exploration motions in the
   rendered scene, the monocular VSE (with the calibrated intrinsics) tracks
   them, ``X`` and the map scale ``s`` are solved jointly.

Ground truth (true intrinsics, hand-eye, camera poses) is read here only to
render the board and to score. The map scale's truth is the scale of the VSE's
*map*: for every keyframe, the median ratio of the true depth (rendered at the
keyframe's true pose) to the map depth of its cloud points, then the median over
the keyframes (:func:`_true_map_scale`). Scales fitted to the VSE's camera
*positions* are kept for reference (``scale_true_poses``: Sim(3) with the
rotation from the orientations; ``scale_true_centres``: Umeyama over the centres
alone, the former definition); they are no truth: the stop positions' errors are
a sizeable fraction of the small motion span, so such fits depend on the
regression direction (docs/lab/2026-11-22-calibrate.md, "Target-free image refinement").
"""

from __future__ import annotations

import math
import time

import numpy as np

from fgcd_cli.app.calibrate import HandEyeRig, run_handeye
from fgcd_cli.calibration.board import BoardSpec
from fgcd_cli.calibration.handeye.with_target import solve_handeye_target
from fgcd_cli.calibration.intrinsics import calibrate_intrinsics
from fgcd_cli.calibration.motions import interpolate_steps, target_motions
from fgcd_core.camera import PinholeCamera
from fgcd_core.platform import MotionGuard
from fgcd_core.se3 import invert_pose, make_pose, pose_distance
from fgcd_core.sim3 import umeyama
from fgcd_drivers.sim.board import BoardViewOptions, SimBoard, random_board_poses, render_board_view
from fgcd_drivers.sim.rig import SimRigConfig, build_sim_rig

__all__ = ["run", "TARGETS", "RIGS"]

TARGETS = {"intrinsics_err_pct": 0.5, "handeye_rot_err_deg": 0.3, "handeye_trans_err_mm": 3.0, "scale_err_pct": 0.5}

#: (seed, platform noise preset): five hand-eye transforms, three noise levels.
RIGS = [(0, "default"), (1, "default"), (2, "default"), (3, "precise"), (4, "sloppy")]
QUICK_RIGS = [(0, "default"), (3, "precise")]
INTRINSICS_VIEWS = 20


def _pinhole(intr) -> PinholeCamera:
    return PinholeCamera(
        fx=intr.fx, fy=intr.fy, cx=intr.cx, cy=intr.cy, width=intr.width, height=intr.height, dist=tuple(intr.dist)
    )


def _intrinsics_error_pct(est: PinholeCamera, true: PinholeCamera) -> float:
    """Largest relative error of fx, fy, and of cx, cy relative to the focal length, percent."""
    return 100.0 * max(
        abs(est.fx / true.fx - 1),
        abs(est.fy / true.fy - 1),
        abs(est.cx - true.cx) / true.fx,
        abs(est.cy - true.cy) / true.fy,
    )


def _board_spec(board: SimBoard) -> BoardSpec:
    return BoardSpec(
        squares_x=board.squares_x,
        squares_y=board.squares_y,
        square_m=board.square_m,
        marker_m=board.marker_m,
        dictionary=board.dictionary,
    )


def _intrinsics_stage(true: PinholeCamera, seed: int, n_views: int) -> tuple[PinholeCamera, dict]:
    board = SimBoard()
    rng = np.random.default_rng([seed, 1])
    poses = random_board_poses(board, n_views, true, rng=rng)
    images = [render_board_view(board, T, true, options=BoardViewOptions(supersample=2), rng=rng) for T in poses]
    res = calibrate_intrinsics(images, _board_spec(board))
    return res.camera, {"err_pct": _intrinsics_error_pct(res.camera, true), "rms_px": res.rms_px, "views": res.n_views}


def _target_stage(rig, calibrated: PinholeCamera, true: PinholeCamera, seed: int) -> dict:
    """Hand-eye with a board fixed 0.45 m in front of the start camera pose."""
    board = SimBoard()
    spec = _board_spec(board)
    gt = rig.ground_truth
    rng = np.random.default_rng([seed, 2])
    w, h = board.size_m
    T_cam0_board = make_pose(np.eye(3), [-w / 2, -h / 2, 0.45])
    T_world_board = gt.T_world_cam_true() @ T_cam0_board
    guard = MotionGuard(rig.platform)
    T_start = rig.platform.flange_pose()
    hand, boards = [], []
    T_prev = T_start
    for T_rel in target_motions(rotation_deg=15.0):
        T_target = T_start @ T_rel
        for T_step in interpolate_steps(T_prev, T_target, max_step_m=0.045, max_step_deg=9.0):
            guard.move_to(T_step)
        T_prev = T_target
        T_cam_board = invert_pose(gt.T_world_cam_true()) @ T_world_board
        image = render_board_view(board, T_cam_board, true, options=BoardViewOptions(supersample=2), rng=rng)
        det = spec.detect(image)
        T_est = spec.estimate_pose(det, calibrated.K, calibrated.dist) if det.n_corners >= 12 else None
        if T_est is not None:
            hand.append(rig.platform.flange_pose())
            boards.append(T_est)
    for T_step in interpolate_steps(T_prev, T_start, max_step_m=0.045, max_step_deg=9.0):
        guard.move_to(T_step)
    res = solve_handeye_target(hand, boards)
    mm, deg = pose_distance(res.T_flange_cam, gt.T_flange_cam_true())
    return {
        "trans_err_mm": mm,
        "rot_err_deg": deg,
        "method": res.best.method,
        "samples": len(hand),
        "agreement_mm": res.agreement_mm,
        "agreement_deg": res.agreement_deg,
    }


def _true_scale(T_map_cam: list[np.ndarray], T_world_cam: list[np.ndarray]) -> float:
    """Scale of the Sim(3) taking the VSE stop poses onto the true ones (evaluation only).

    The rotation is the chordal mean of ``R_world_cam R_map_cam^T`` over the stops
    (the VSE orientations are good to a few tenths of a degree); scale and offset
    then follow by linear least squares over the camera centres.
    """
    from fgcd_core.se3 import project_to_so3

    R = project_to_so3(sum(t[:3, :3] @ e[:3, :3].T for e, t in zip(T_map_cam, T_world_cam)))
    v = np.array([R @ e[:3, 3] for e in T_map_cam])
    c = np.array([t[:3, 3] for t in T_world_cam])
    v, c = v - v.mean(0), c - c.mean(0)
    return float(np.sum(v * c) / np.sum(v * v))


class _PoseLog:
    """Frame source wrapper recording the true camera pose of every frame (evaluation only)."""

    def __init__(self, source, gt):
        self.source, self.gt, self.poses = source, gt, {}

    def grab(self):
        frame = self.source.grab()
        self.poses[float(frame.timestamp_s)] = self.gt.T_world_cam_true()
        return frame


def _true_map_scale(state, poses: dict, gt, camera: PinholeCamera) -> tuple[float, float]:
    """Metres per map unit of the VSE's map: true over map depth of the cloud pixels of each keyframe.

    Returns the median over keyframes and the relative spread (max - min) / median of the
    per-keyframe values.
    """
    from fgcd_core.camera import CameraIntrinsics

    intr = CameraIntrinsics(
        fx=camera.fx, fy=camera.fy, cx=camera.cx, cy=camera.cy, width=camera.width, height=camera.height
    )
    cloud = state.cloud
    per_kf = []
    for kf in state.keyframes:
        sel = cloud.keyframe_ids == kf.id
        T_true = poses.get(float(kf.timestamp_s))
        if T_true is None or sel.sum() < 50:
            continue
        depth = gt.depth(T_true, intrinsics=intr)
        px = np.round(cloud.pixels[sel]).astype(int)
        inside = (px[:, 0] >= 0) & (px[:, 0] < depth.shape[1]) & (px[:, 1] >= 0) & (px[:, 1] < depth.shape[0])
        T_cam_map = invert_pose(kf.T_map_cam)
        z_map = (cloud.points[sel] @ T_cam_map[:3, :3].T + T_cam_map[:3, 3])[:, 2][inside]
        z_true = depth[px[inside, 1], px[inside, 0]]
        good = (z_true > 0) & (z_map > 0)
        if good.sum() >= 50:
            per_kf.append(float(np.median(z_true[good] / z_map[good])))
    if not per_kf:
        return float("nan"), float("nan")
    med = float(np.median(per_kf))
    return med, (max(per_kf) - min(per_kf)) / med


def _target_free_stage(rig, calibrated: PinholeCamera) -> dict:
    gt = rig.ground_truth
    guard = MotionGuard(rig.platform)
    t0 = time.perf_counter()
    from fgcd_cli.app.rig import undistorted

    # the VSE works on undistorted frames, as in the field commands (fgcd_cli.app.rig)
    ideal, source = undistorted(calibrated, rig.camera)
    log = _PoseLog(source, gt)
    run = run_handeye(HandEyeRig(guard=guard, camera_source=log, intrinsics=ideal)).run
    X_true = gt.T_flange_cam_true()
    mm, deg = pose_distance(run.result.T_flange_cam, X_true)
    # True camera poses of the stops: reported flange poses through the true hand-eye
    # (the simulated encoders' errors are negligible next to the hand-eye's).
    true_cams = [T @ X_true for T in run.T_base_flange]
    s_true, s_true_spread = _true_map_scale(run.engine.state(), log.poses, gt, ideal)
    s_poses = _true_scale(run.T_map_cam, true_cams)
    s_centres = umeyama(np.array([T[:3, 3] for T in run.T_map_cam]), np.array([T[:3, 3] for T in true_cams])).scale
    ref = run.result.refinement
    linear = {}
    if ref:
        lmm, ldeg = pose_distance(np.array(ref["linear_T_flange_cam"]), X_true)
        linear = {
            "linear_trans_err_mm": lmm,
            "linear_rot_err_deg": ldeg,
            "linear_scale_err_pct": 100.0 * abs(ref["linear_scale"] / s_true - 1),
            "ba_points": ref["points"],
            "ba_rms_px": ref["rms_px"],
            "ba_std_mm": ref["std_mm"],
            "ba_std_deg": ref["std_deg"],
            "ba_views": ref.get("views"),
            "platform_rotation_scale": ref.get("platform_rotation_scale"),
            "platform_rotation_scale_std": ref.get("platform_rotation_scale_std"),
            "platform_rotation_scale_true": gt.platform_rotation_scale_true(),
        }
    return {
        "method": run.result.method,
        "trans_err_mm": mm,
        "rot_err_deg": deg,
        "scale": run.result.scale,
        "scale_true": s_true,
        "scale_true_kf_spread_pct": 100.0 * s_true_spread,
        "scale_true_poses": s_poses,
        "scale_true_centres": s_centres,
        "scale_method": ref.get("scale_method", "linear") if ref else "linear",
        "scale_from_motions_err_pct": (100.0 * abs(ref["scale_from_motions"] / s_true - 1)) if ref else None,
        "scale_err_pct": 100.0 * abs(run.result.scale / s_true - 1),
        **linear,
        "samples": run.result.n_samples,
        "rms_mm": run.result.rms_mm,
        "rms_deg": run.result.rms_deg,
        "frames": run.frames,
        "seconds": time.perf_counter() - t0,
    }


def run(*, quick: bool = False) -> dict:
    """Run the calibration benchmark.

    Returns
    -------
    dict
        ``summary`` (means over the default-noise rigs: ``intrinsics_err_pct``,
        ``handeye_rot_err_deg``, ``handeye_trans_err_mm``, ``scale_err_pct`` of the
        target-free mode, plus the board mode's errors), ``targets`` and ``rigs``.
    """
    rigs_out = []
    for seed, noise in QUICK_RIGS if quick else RIGS:
        t0 = time.perf_counter()
        rig = build_sim_rig(scene="stele", config=SimRigConfig(seed=seed, noise=noise))
        true = _pinhole(rig.ground_truth.intrinsics_true())
        # the same board views in both runs, so that the quick run is a subset of the full one
        # (the hand-eye follows the intrinsics' error)
        calibrated, intr = _intrinsics_stage(true, seed, INTRINSICS_VIEWS)
        target = _target_stage(rig, calibrated, true, seed)
        rig.close()
        rig = build_sim_rig(scene="stele", config=SimRigConfig(seed=seed, noise=noise))
        try:
            free = _target_free_stage(rig, calibrated)
        except Exception as exc:  # a failed session is a benchmark result, reported as such
            free = {"error": f"{type(exc).__name__}: {exc}"}
        rig.close()
        rigs_out.append(
            {
                "seed": seed,
                "noise": noise,
                "intrinsics": intr,
                "target": target,
                "target_free": free,
                "seconds": time.perf_counter() - t0,
            }
        )

    default = [r for r in rigs_out if r["noise"] == "default"]

    def mean(values):
        values = [v for v in values if v is not None and math.isfinite(v)]
        return float(np.mean(values)) if values else float("nan")

    free_ok = [r["target_free"] for r in default if "error" not in r["target_free"]]
    summary = {
        "intrinsics_err_pct": mean([r["intrinsics"]["err_pct"] for r in default]),
        "handeye_rot_err_deg": mean([f["rot_err_deg"] for f in free_ok]),
        "handeye_trans_err_mm": mean([f["trans_err_mm"] for f in free_ok]),
        "scale_err_pct": mean([f["scale_err_pct"] for f in free_ok]),
        "target_handeye_rot_err_deg": mean([r["target"]["rot_err_deg"] for r in default]),
        "target_handeye_trans_err_mm": mean([r["target"]["trans_err_mm"] for r in default]),
        "target_free_failures": sum("error" in r["target_free"] for r in rigs_out),
    }
    return {"summary": summary, "targets": TARGETS, "rigs": rigs_out, "quick": quick}
