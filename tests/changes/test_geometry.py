"""The geometry of a campaign diff against synthetic ground truth: a textured plane and a raised block seen
from two poses, each plane rendered by its exact plane-induced homography (independent of the code tested)."""

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from fgcd_cli.changes.config import DetectionConfig
from fgcd_cli.changes.detect import detect_changes
from fgcd_cli.changes.geometry.depth import ReferenceGeometry, depth_from_cloud
from fgcd_cli.changes.geometry.pnp import residual_pose
from fgcd_cli.changes.geometry.stack_warp import geometry_warp
from fgcd_cli.changes.geometry.warp import depth_warp_maps, parallax_edges

sys.path.insert(0, str(Path(__file__).resolve().parent))
from plane_scene import BLOCK, D_BG, D_BLOCK, N_BG, N_BLOCK, F, H, K, W, homography, make_pose, plane_depth, scene  # noqa: E402


def test_depth_warp_is_the_plane_homography():
    T = make_pose((12.0, -7.0, 5.0), (0.2, -0.3, 0.1))
    map_x, map_y = depth_warp_maps(plane_depth(N_BG, D_BG), K, T)
    Hm = homography(T, N_BG, D_BG)
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    den = Hm[2, 0] * u + Hm[2, 1] * v + Hm[2, 2]
    # float32 maps: ~1e-4 px of rounding at 480 px
    assert np.abs(map_x - (Hm[0, 0] * u + Hm[0, 1] * v + Hm[0, 2]) / den).max() < 1e-3
    assert np.abs(map_y - (Hm[1, 0] * u + Hm[1, 1] * v + Hm[1, 2]) / den).max() < 1e-3


def test_unknown_depth_gives_no_position():
    depth = plane_depth(N_BG, D_BG)
    depth[:10] = np.nan
    map_x, _ = depth_warp_maps(depth, K, make_pose((1.0, 0.0, 0.0)))
    assert np.isnan(map_x[:10]).all() and np.isfinite(map_x[10:]).all()


def test_parallax_edges_follow_the_block_when_its_jump_exceeds_the_tolerance():
    depth = plane_depth(N_BG, D_BG)
    depth[BLOCK] = plane_depth(N_BLOCK, D_BLOCK)[BLOCK]
    block = np.zeros((H, W), bool)
    block[BLOCK] = True
    ring = cv2.dilate(block.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool) & ~cv2.erode(
        block.astype(np.uint8), np.ones((7, 7), np.uint8)
    ).astype(bool)
    # 50 mm sideways: the block's parallax exceeds the background's by F t (1/0.95 - 1/Z_bg) ~ 1.3-1.9 px.
    edges = parallax_edges(*depth_warp_maps(depth, K, make_pose((50.0, 0.0, 0.0))), tolerance_px=1.0, window_px=1)
    assert edges[ring].mean() > 0.6  # the block's outline (its top and bottom rows are cut by the tilt)
    far = ~cv2.dilate(block.astype(np.uint8), np.ones((13, 13), np.uint8)).astype(bool)
    assert not edges[far].any()
    # 10 mm: a jump of ~0.3 px, within the score's tolerance: nothing left out.
    small = parallax_edges(*depth_warp_maps(depth, K, make_pose((10.0, 0.0, 0.0))), tolerance_px=1.0, window_px=1)
    assert not small.any()


def test_residual_pose_recovers_the_visit_pose():
    T = make_pose((8.0, -5.0, 4.0), (0.15, -0.2, 0.1))
    ref, cur, depth = scene(T, block=False)
    pose = residual_pose(ref, cur, depth, K)
    assert pose.ok and pose.inliers > 100
    # SIFT localises to a few tenths of a pixel; over >100 matches spread across the view the pose
    # is fixed to well under a millimetre at 1 m (0.3 px / 600 px x 1 m = 0.5 mm per single match).
    assert np.linalg.norm(pose.T_cur_ref[:3, 3] - T[:3, 3]) * 1e3 < 0.5
    dR = pose.T_cur_ref[:3, :3] @ T[:3, :3].T
    assert np.rad2deg(np.linalg.norm(cv2.Rodrigues(dR)[0])) < 0.03
    assert pose.translation_mm == pytest.approx(np.linalg.norm([8.0, -5.0, 4.0]), abs=0.5)


def test_textureless_reference_falls_back():
    flat = np.full((H, W), 0.5, np.float32)
    pose = residual_pose(flat, flat, plane_depth(N_BG, D_BG), K)
    assert not pose.ok and "matches" in pose.reason
    warp = geometry_warp(
        ReferenceGeometry(
            depth=plane_depth(N_BG, D_BG), interpolated_depth=plane_depth(N_BG, D_BG), K=K, spacing_px=2.0
        ),
        flat,
        flat,
        np.eye(3),
        tolerance_px=1,
    )
    assert warp.map_x is None


def test_depth_from_cloud_interpolates_a_plane():
    depth = plane_depth(N_BG, D_BG)
    rng = np.random.default_rng(0)
    u, v = rng.uniform(0, W - 1, 3000), rng.uniform(0, H - 1, 3000)
    z = D_BG / (N_BG @ np.stack([(u - K[0, 2]) / F, (v - K[1, 2]) / F, np.ones_like(u)]))
    points = np.stack([(u - K[0, 2]) / F * z, (v - K[1, 2]) / F * z, z], axis=1)
    T_ref_cam = make_pose((100.0, -50.0, 20.0), (1.0, 2.0, 0.5))  # the cloud in another frame
    points_ref = points @ T_ref_cam[:3, :3].T + T_ref_cam[:3, 3]
    got = depth_from_cloud(points_ref, T_ref_cam, K, (H, W))
    known = np.isfinite(got)
    assert known.mean() > 0.9
    # z = d / (a u + b) is curved in the image: linear interpolation over a triangle of side s px errs by
    # s^2 |z''| / 8, |z''| ~ 2 z a^2 = 1.7e-7 m/px^2; slivers along the hull span ~100 px: 0.2 mm at most.
    assert np.abs(got[known] - depth[known]).max() < 5e-4
    assert np.median(np.abs(got[known] - depth[known])) < 1e-5


def test_detection_with_geometry_finds_the_change_and_leaves_the_block_edges_uncompared():
    T = make_pose((50.0, 10.0, 5.0), (0.1, -0.2, 0.05))
    ref, cur, depth = scene(T, block=True, paint=(100, 280))
    geometry = ReferenceGeometry(depth=depth, interpolated_depth=depth, K=K, spacing_px=1.0)
    result = detect_changes([ref], [cur], geometry=geometry, config=DetectionConfig.from_options(edge_check_px=2))
    geo = result.settings["geometry"]
    assert geo["warp"] == "reference depth and residual pose"
    assert abs(geo["residual_pose_mm"] - np.linalg.norm([50.0, 10.0, 5.0])) < 0.5
    assert len(result.regions) == 1
    x, y = result.regions[0].centroid_xy
    assert abs(x - 100) < 4 and abs(y - 280) < 4
    block = np.zeros((H, W), bool)
    block[BLOCK] = True
    outline = cv2.dilate(block.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~cv2.erode(
        block.astype(np.uint8), np.ones((3, 3), np.uint8)
    ).astype(bool)
    assert result.not_compared[outline].mean() > 0.6


def test_cloud_outliers_are_dropped_and_a_depth_step_is_kept():
    from fgcd_cli.changes.geometry.depth import depth_consistent

    rng = np.random.default_rng(1)
    uv = rng.uniform(0, [W - 1, H - 1], size=(4000, 2))
    step = uv[:, 0] > W / 2
    z = np.where(step, 0.95, 1.0) + rng.normal(0, 0.001, len(uv))  # a 5 cm step, 1 mm noise
    outliers = rng.choice(len(uv), 40, replace=False)
    z[outliers] += rng.choice([-0.2, 0.2], 40)
    keep = depth_consistent(uv, z)
    assert not keep[outliers].any()
    inliers = np.setdiff1d(np.arange(len(uv)), outliers)
    # both sides of the step survive; only points right on it, whose neighbours split, may go
    assert keep[inliers].mean() > 0.97
    assert keep[inliers][step[inliers]].mean() > 0.97 and keep[inliers][~step[inliers]].mean() > 0.97
