"""Changes with ground-truth masks, scenes, the rig and its ground truth."""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers.cameras import CameraIntrinsics, CameraSource
from drivers.sim.changes import ChangeSpec, random_changes
from drivers.sim.lights import Lighting, lighting_preset, list_lighting_presets, solar_az_el
from drivers.sim.render import CameraEffects, Renderer
from drivers.sim.transforms import look_at

LINEAR = CameraEffects(gamma=1.0)
AMBIENT = Lighting(name="a", lights=(), ambient=1.0)


def _frontal(intr):
    T = look_at((0.0, -0.5, 1.0), (0.0, 0.0, 1.0))
    uu, vv = np.meshgrid(np.arange(intr.width, dtype=float), np.arange(intr.height, dtype=float))
    # back-project pixel centres onto the plane y = 0 (camera 0.5 m away, frontal)
    x = (uu - intr.cx) / intr.fx * 0.5
    z = 1.0 - (vv - intr.cy) / intr.fy * 0.5
    return T, x, z


@pytest.mark.parametrize("kind", ["stain", "crack", "flaking", "missing"])
def test_change_mask_exactly_where_injected(factories, kind):
    intr = CameraIntrinsics(fx=500.0, fy=500.0, cx=49.5, cy=49.5, width=100, height=100)  # 1 mm per pixel
    scene = factories.make_scene([factories.plane_part(albedo=0.5)])
    T, x, z = _frontal(intr)
    centre = (0.004, 0.0, 1.003)
    ch = ChangeSpec(kind=kind, position=centre, normal=(0, -1, 0), size_mm=40.0, seed=3)
    r = Renderer(scene)
    before = r.render(T, intr, AMBIENT, exposure=1.0, effects=LINEAR, want=("gray",))
    after = r.render(T, intr, AMBIENT, changes=[ch], exposure=1.0, effects=LINEAR, want=("gray",))
    e1, e2 = ch.basis()
    P = np.stack([x, np.zeros_like(x), z], -1) - np.asarray(centre)
    F = ch.footprint_at((P @ e1).ravel(), (P @ e2).ravel()).reshape(x.shape)
    np.testing.assert_array_equal(after.change_mask, F >= 0.5)
    assert after.change_mask.sum() > 15
    assert not before.change_mask.any()
    diff = np.abs(after.gray - before.gray)
    assert np.all(diff[F == 0] == 0)  # nothing changes outside the footprint
    assert np.mean(diff[after.change_mask] > 0.01) > 0.95
    if ch.depth_m > 0:  # geometry changes push the surface back by up to their depth
        dz = after.depth - before.depth
        assert dz[after.change_mask].max() == pytest.approx(ch.depth_m, rel=0.05)
        assert np.all(dz[F == 0] == 0)
    else:
        np.testing.assert_array_equal(after.depth, before.depth)


def test_change_mask_seen_from_another_camera_lands_on_the_same_surface_point(factories):
    scene = factories.make_scene([factories.plane_part()])
    intr = CameraIntrinsics(fx=400.0, fy=400.0, cx=79.5, cy=59.5, width=160, height=120)
    ch = ChangeSpec(kind="stain", position=(0.05, 0.0, 1.02), normal=(0, -1, 0), size_mm=15.0, seed=1)
    T = look_at((0.3, -0.6, 1.2), (0.0, 0.0, 1.0))
    res = Renderer(scene).render(T, intr, None, changes=[ch], want=("labels",))
    vs, us = np.nonzero(res.change_mask)
    z = res.depth[vs, us]
    p_cam = np.stack([(us - intr.cx) / intr.fx * z, (vs - intr.cy) / intr.fy * z, z], 1)
    p = p_cam @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(p[:, 1], 0.0, atol=1e-5)
    assert np.all(np.linalg.norm(p - ch.position, axis=1) < 0.6 * 0.015 * np.sqrt(2))
    np.testing.assert_allclose(p.mean(axis=0), ch.position, atol=0.003)


def test_lighting_presets_parse():
    names = [n for n, _ in list_lighting_presets()]
    for n in names:
        lighting_preset(n)
    led3 = lighting_preset("led:3").lights[0]
    assert led3.frame == "camera" and led3.position[0] > 0.1 and abs(led3.position[1]) < 1e-9  # right of the lens
    led12 = lighting_preset("led:12").lights[0]
    assert led12.position[1] < -0.1  # above the lens (camera y points down)
    with pytest.raises(ValueError):
        lighting_preset("led:13")
    with pytest.raises(ValueError):
        lighting_preset("disco")
    az, el = solar_az_el(172, 12.0, 40.0)  # June solstice noon at 40 N: sun due south, el = 90 - 40 + 23.45
    assert az == pytest.approx(180.0, abs=1.0) and el == pytest.approx(73.45, abs=0.5)
    assert lighting_preset("sun:day=172,hour=12").lights[0].direction[2] > 0.9


def test_scene_catalogue_and_determinism():
    from drivers.sim.scenes import _load, list_scenes, load_scene, scene_spec

    names = [s.name for s in list_scenes()]
    assert len(names) >= 9
    for required in ("stele", "relief_panel", "mural", "plane", "sphere", "stupa", "statue", "plaster", "bricks"):
        assert required in names
    a = _load.__wrapped__("plane", 0, 0.0)
    b = _load.__wrapped__("plane", 0, 0.0)
    c = _load.__wrapped__("plane", 1, 0.0)
    np.testing.assert_array_equal(a.parts[0].texture, b.parts[0].texture)
    assert not np.array_equal(a.parts[0].texture, c.parts[0].texture)
    s = load_scene("plane")
    # default camera 0.4-2 m from the object, looking at it
    T = s.default_T_world_cam
    intr = CameraIntrinsics(fx=60.0, fy=60.0, cx=31.5, cy=23.5, width=64, height=48)
    res = Renderer(s).render(T, intr, None, want=("labels",))
    assert (res.labels == 1).mean() > 0.5
    assert 0.4 <= res.depth[res.labels == 1].min() and res.depth.max() <= 3.0
    with pytest.raises(ValueError):
        scene_spec("no_such_scene")


def test_random_changes_lie_on_the_visible_object():
    from drivers.sim.scenes import load_scene

    s = load_scene("plane")
    chs = random_changes(s, n=6, seed=2)
    assert len(chs) == 6
    for ch in chs:
        assert abs(ch.position[1]) < 1e-3 and 1.0 <= ch.size_mm <= 20.0
    assert random_changes(s, n=6, seed=2)[0].position == chs[0].position


def test_rig_home_pose_camera_and_ground_truth():
    from drivers.sim.rig import build_sim_rig

    rig = build_sim_rig(scene="plane", noise="none", intrinsics_error="none", seed=4)
    gt = rig.ground_truth
    T0 = rig.world.scene.default_T_world_cam
    np.testing.assert_allclose(gt.T_world_cam_true(), T0, atol=1e-9)
    X = gt.T_flange_cam_true()
    assert 0.05 <= np.linalg.norm(X[:3, 3]) <= 0.15
    assert isinstance(rig.camera, CameraSource)
    assert rig.camera.synthetic_overhead_s() == 0.0
    t0 = time.monotonic()
    f = rig.camera.grab()
    grab_s = time.monotonic() - t0
    assert f.image.shape == (480, 640) and f.image.dtype == np.float32 and 0.2 < f.image.mean() < 0.8
    # the rendering time is accounted (for the rig-time model), within the grab's wall time
    assert 0.0 < rig.camera.synthetic_overhead_s() <= grab_s
    # the VSE thread and a caller taking images may grab at once: each render is counted once
    import threading

    before, errors = rig.camera.synthetic_overhead_s(), []

    def grab():
        try:
            rig.camera.grab()
        except Exception as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    workers = [threading.Thread(target=grab) for _ in range(3)]
    t0 = time.monotonic()
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    assert not errors
    assert 0.0 < rig.camera.synthetic_overhead_s() - before <= 3 * (time.monotonic() - t0)
    # move the flange: the camera follows through the hidden hand-eye
    T = rig.platform.flange_pose()
    T[:3, 3] += [0.01, 0.0, 0.0]
    rig.platform.move_to(T)
    np.testing.assert_allclose(gt.T_world_cam_true(), gt.T_world_base_true() @ T @ X, atol=1e-12)
    assert rig.clock.now() == pytest.approx(1.5 + rig.platform.settle_s)
    # true AFD: zero for the same pose; for a sideways shift dx of a frontal plane at Z: fx dx / Z
    assert gt.true_afd_px(T0, T0) == pytest.approx(0.0, abs=1e-9)
    T1 = T0.copy()
    T1[:3, 3] += T0[:3, 0] * 0.01  # 1 cm along the camera x axis
    z = 0.8
    assert gt.true_afd_px(T0, T1) == pytest.approx(600 * 0.01 / z, rel=1e-3)
    # lights switch
    rig.lights.set("led:9")
    assert rig.lights.current == "led:9"


def test_rig_intrinsics_error_and_depth_output():
    from drivers.sim.rig import build_sim_rig

    rig = build_sim_rig(scene="plane", seed=1, with_depth=True)
    true, nom = rig.ground_truth.intrinsics_true(), rig.camera.intrinsics_nominal
    assert true != nom and abs(true.fx / nom.fx - 1) < 0.05 and true.dist[0] < 0
    f = rig.camera.grab()
    assert f.depth is not None and np.all(f.depth > 0.5)
    # same seed, same noisy frame
    g = build_sim_rig(scene="plane", seed=1).camera.grab()
    np.testing.assert_array_equal(f.image, g.image)


def test_rig_sessions_changes_and_displaced_base():
    from drivers.sim.rig import build_sim_rig

    a = build_sim_rig(scene="plane", seed=2, session_seed=0)
    b = build_sim_rig(scene="plane", seed=2, session_seed=1)
    # same world: same hand-eye, base and intrinsics; another session: other noise
    np.testing.assert_array_equal(a.ground_truth.T_flange_cam_true(), b.ground_truth.T_flange_cam_true())
    np.testing.assert_array_equal(a.ground_truth.T_world_base_true(), b.ground_truth.T_world_base_true())
    assert not np.array_equal(a.camera.grab().image, b.camera.grab().image)
    chs = b.inject_changes(n=3, seed=5)
    assert len(chs) == 3 and b.ground_truth.changes() == chs
    assert b.ground_truth.change_mask().any()
    T0 = b.ground_truth.T_world_cam_true()
    delta = np.eye(4)
    delta[:3, 3] = [0.02, 0.0, 0.0]
    b.displace_base(delta)
    np.testing.assert_allclose(b.ground_truth.T_world_cam_true(), T0 @ delta, atol=1e-12)


def test_procedural_geometry_is_a_function_of_the_seed():
    """The irregular statue: same seed, identical mesh and textures; another seed, another statue."""
    from drivers.sim.scenes import _load

    a = _load.__wrapped__("statue", 0, 0.0)
    b = _load.__wrapped__("statue", 0, 0.0)
    c = _load.__wrapped__("statue", 1, 0.0)
    assert [p.name for p in a.parts] == [p.name for p in b.parts]
    for pa, pb in zip(a.parts, b.parts):
        np.testing.assert_array_equal(pa.vertices, pb.vertices)
        np.testing.assert_array_equal(pa.triangles, pb.triangles)
        np.testing.assert_array_equal(pa.texture, pb.texture)
    sa, sc = a.parts[0], c.parts[0]
    assert sa.name == sc.name == "statue"
    assert sa.vertices.shape != sc.vertices.shape or not np.array_equal(sa.vertices, sc.vertices)
