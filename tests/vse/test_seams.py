"""The engine's parts and option dataclasses: former defaults, former call forms, variants by object."""

import json

import numpy as np
import pytest

from fgcd_core.se3 import exp_se3
from fgcd_cli.vse import MonocularVSE, RgbdVSE, SparseVSE, VisualSlamEngine, VseConfig, VseStatus, VseVariant, make_engine
from fgcd_cli.vse.ba import (BundleAdjustConfig, bundle_adjust,
                             bundle_adjust_rejecting_outliers)
from fgcd_cli.vse.cloud import DepthImageCloud, LandmarkCloud, SemiDenseCloud
from fgcd_cli.vse.depth_source import DepthImage, Triangulation
from fgcd_cli.vse.frontend import FrontendKind, KltTracking, OrbTracking
from fgcd_cli.vse.semidense import KeyframeDepthConfig, keyframe_depth


def test_status_is_a_string_with_the_former_values():
    assert [s.value for s in VseStatus] == ["initializing", "tracking", "lost", "failed"]
    assert VseStatus.TRACKING == "tracking" and f"{VseStatus.LOST}" == "lost"
    assert json.dumps({"status": VseStatus.FAILED}) == '{"status": "failed"}'


def _ba_problem():
    rng = np.random.default_rng(5)
    K = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])
    T = np.stack([exp_se3(np.r_[rng.normal(0, 0.02, 3), rng.normal(0, 0.02, 3)]) for _ in range(4)])
    X = rng.uniform([-0.3, -0.2, 0.5], [0.3, 0.2, 0.8], (80, 3))
    cam = np.repeat(np.arange(4), 80)
    pt = np.tile(np.arange(80), 4)
    Xc = np.einsum("mij,mj->mi", T[cam, :3, :3], X[pt]) + T[cam, :3, 3]
    uv = (Xc @ K.T)[:, :2] / Xc[:, 2:3] + rng.normal(0, 0.2, (len(cam), 2))
    uv[::23] += 4.0
    T0 = np.stack([exp_se3(rng.normal(0, 0.003, 6)) @ Ti for Ti in T])
    return T0, X + rng.normal(0, 0.004, X.shape), cam, pt, uv, K


def test_bundle_adjust_takes_its_options_as_one_config():
    """One call form: the options are a config dataclass; the former flat keywords are refused."""
    T0, X0, cam, pt, uv, K = _ba_problem()
    res = bundle_adjust(T0, X0, cam, pt, uv, K, config=BundleAdjustConfig(iterations=7, huber_px=1.2))
    assert res.iterations <= 7
    with pytest.raises(TypeError):
        bundle_adjust(T0, X0, cam, pt, uv, K, iterations=7)
    with pytest.raises(TypeError):
        bundle_adjust_rejecting_outliers(T0, X0, cam, pt, uv, K, max_rounds=2)


def test_keyframe_depth_keywords_equal_the_config(world, small_camera, helpers):
    T0, T1 = helpers.look_pose([0, 0, 0]), helpers.look_pose([0.012, 0.0, 0.0])
    i0, _ = world.render(small_camera, T0)
    i1, _ = world.render(small_camera, T1)
    nbs = [(i1, np.linalg.inv(T1) @ T0)]
    b = keyframe_depth(i0, nbs, small_camera.K, (1 / 0.8, 1 / 0.45),
                       config=KeyframeDepthConfig(max_points=2000, min_views=1))
    assert len(b.inv_depth) > 100 and len(b.pixels) <= 2000
    with pytest.raises(TypeError):
        keyframe_depth(i0, nbs, small_camera.K, (1 / 0.8, 1 / 0.45), max_points=2000)


@pytest.mark.parametrize(("variant", "cls", "frontend", "source", "cloud"), [
    ("mono", MonocularVSE, KltTracking, Triangulation, SemiDenseCloud),
    ("sparse", SparseVSE, OrbTracking, Triangulation, LandmarkCloud),
    ("rgbd", RgbdVSE, KltTracking, DepthImage, DepthImageCloud),
])
def test_variants_are_compositions_of_parts(small_camera, variant, cls, frontend, source, cloud):
    eng = make_engine(variant, small_camera, config=VseConfig(max_features=300))
    assert type(eng) is cls and isinstance(eng, VisualSlamEngine)
    assert isinstance(eng.frontend, frontend) and isinstance(eng.depth_source, source)
    assert isinstance(eng.cloud_builder, cloud)
    assert eng.state().status == VseStatus.INITIALIZING
    assert eng.state().scale_is_metric is eng.metric is (variant == VseVariant.RGBD)


def test_frontends_state_what_depends_on_keypoint_precision():
    cfg = VseConfig()
    klt, orb = KltTracking(cfg), OrbTracking(cfg)
    assert (klt.kind, klt.min_triangulation_deg, klt.noise_level_outliers) == (FrontendKind.KLT, 0.5, True)
    assert (orb.kind, orb.min_triangulation_deg, orb.noise_level_outliers) == (FrontendKind.ORB, 1.5, False)


def test_unknown_variant_is_refused(small_camera):
    with pytest.raises(ValueError):
        make_engine("stereo", small_camera)
