"""Initial guess from the first camera, and the global multi-start fallback."""

from __future__ import annotations

import numpy as np
import pytest

from fgcd_cli.alignment.initial import camera_prior, initial_guess
from fgcd_cli.alignment.reference import ReferenceIndex
from fgcd_cli.alignment.synthetic import ReliefScene, look_at, random_similarity
from fgcd_core.se3 import exp_se3, pose_distance


@pytest.fixture(scope="module")
def world():
    rng = np.random.default_rng(8)
    scene = ReliefScene(seed=1)
    pts, normals, _ = scene.sample(30000, rng=rng)
    ref = ReferenceIndex(pts, normals=normals)
    p, _, _ = scene.sample(8000, rng=rng, xlim=(-0.2, 0.2), ylim=(-0.2, 0.2))
    p += rng.normal(0, 0.001, p.shape)
    T_true = random_similarity(rng, rotation_deg=70, translation_m=0.8, scale_rel=0.04)
    T_ref_camref = look_at([0.0, 0.0, -0.6], [0.0, 0.0, 0.0])
    return rng, ref, p, T_true, T_ref_camref


def test_camera_prior_maps_first_camera_onto_reference_camera():
    rng = np.random.default_rng(1)
    A = exp_se3(rng.normal(size=6))
    B = exp_se3(rng.normal(size=6))
    T = camera_prior(A, B, scale=1.3)
    np.testing.assert_allclose(T.transform_pose(B), A, atol=1e-12)


def test_initial_guess_from_nearby_first_camera(world):
    rng, ref, p, T_true, T_ref_camref = world
    cur = T_true.inverse().apply(p)
    # The first current camera is 6 cm / 5 deg away from the reference camera.
    T_ref_cam0 = T_ref_camref @ exp_se3(np.concatenate([[0.04, -0.03, 0.03], np.radians([3.0, -4.0, 0.0])]))
    T_cur_cam0 = T_true.inverse().transform_pose(T_ref_cam0)
    guess = initial_guess(T_ref_camref=T_ref_camref, T_cur_cam0=T_cur_cam0, cur_points=cur, reference=ref)
    assert guess.source == "first_camera+fast"
    assert guess.fast.health.ok, guess.fast.health.reason
    E = guess.T_ref_cur @ T_true.inverse()
    assert E.rotation_deg() < 0.1
    assert abs(E.scale - 1) < 0.005
    # Without clouds: only the prior, scale 1.
    prior = initial_guess(T_ref_camref=T_ref_camref, T_cur_cam0=T_cur_cam0)
    assert prior.source == "first_camera" and prior.T_ref_cur.scale == 1.0
    mm, deg = pose_distance(prior.T_ref_cur.transform_pose(T_cur_cam0), T_ref_camref)
    assert mm < 1e-6 and deg < 1e-6


def test_global_fallback_when_the_prior_is_wrong(world):
    rng, ref, p, T_true, T_ref_camref = world
    cur = T_true.inverse().apply(p)
    # The session started on the far side: the prior is off by 120 degrees.
    T_ref_cam0 = T_ref_camref @ exp_se3(np.concatenate([[0.1, 0.0, 0.0], np.radians([0.0, 0.0, 120.0])]))
    T_cur_cam0 = T_true.inverse().transform_pose(T_ref_cam0)
    guess = initial_guess(T_ref_camref=T_ref_camref, T_cur_cam0=T_cur_cam0, cur_points=cur, reference=ref)
    assert guess.source == "global"
    assert guess.fast.health.ok, guess.fast.health.reason
    E = guess.T_ref_cur @ T_true.inverse()
    assert E.rotation_deg() < 0.1


def test_an_empty_current_cloud_gives_the_camera_prior_without_a_multi_start(world):
    """A VSE that tracks but has no cloud yet (a statue run): the prior stands, marked failed, and the
    multi-start is not tried on nothing (it averaged an empty array)."""
    import warnings

    _rng, ref, _p, _T_true, T_ref_camref = world
    T_cur_cam0 = exp_se3([0.01, 0.0, 0.0, 0.0, 0.0, 0.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        guess = initial_guess(
            T_ref_camref=T_ref_camref, T_cur_cam0=T_cur_cam0, cur_points=np.zeros((0, 3)), reference=ref
        )
    assert guess.source == "first_camera+fast"
    assert not guess.fast.health.ok
    np.testing.assert_allclose(guess.T_ref_cur.transform_pose(T_cur_cam0), T_ref_camref, atol=1e-9)
