"""Changes with ground-truth masks, scenes, the rig and its ground truth."""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest

from fgcd_core.camera import CameraIntrinsics
from fgcd_drivers.cameras import CameraSource
from fgcd_drivers.sim.appearance import WORLD_ENV
from fgcd_drivers.sim.change_placement import random_changes
from fgcd_drivers.sim.changes import ALL_KINDS, CHANGE_CATEGORY, KINDS, ChangeSpec, evaluate_changes
from fgcd_drivers.sim.lights import Lighting, lighting_preset, list_lighting_presets, solar_az_el
from fgcd_drivers.sim.render import Renderer
from fgcd_drivers.sim.sensor import CameraEffects
from fgcd_drivers.sim.transforms import look_at

LINEAR = CameraEffects(gamma=1.0)


@pytest.fixture(autouse=True)
def _smooth_world(monkeypatch):
    """These tests check the changes' geometry, normals and shading against analytic values of the Lambert model: the smooth
    world. The calibrated world's grain and lobe have their own tests (test_appearance, test_mesostructure)."""
    monkeypatch.setenv(WORLD_ENV, "smooth")


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
    from fgcd_drivers.sim.scenes import _load, list_scenes, load_scene, scene_spec

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
    from fgcd_drivers.sim.scenes import load_scene

    s = load_scene("plane")
    chs = random_changes(s, n=6, seed=2)
    assert len(chs) == 6
    for ch in chs:
        assert abs(ch.position[1]) < 1e-3 and 1.0 <= ch.size_mm <= 20.0
    assert random_changes(s, n=6, seed=2)[0].position == chs[0].position


def test_object_mm_per_px_is_the_fronto_parallel_footprint_of_the_nominal_camera():
    """The plane scene's slab is fronto-parallel 0.8 m from its default camera (scene_specs/plane.toml):
    a pixel of the 640 x 480 camera (fx 600 px) spans 800 / 600 mm there, whatever the texture."""
    from fgcd_drivers.sim.camera import DEFAULT_INTRINSICS
    from fgcd_drivers.sim.change_placement import object_mm_per_px
    from fgcd_drivers.sim.scenes import load_scene

    expected = 0.8 * 1000.0 / DEFAULT_INTRINSICS.fx
    assert object_mm_per_px(load_scene("plane")) == pytest.approx(expected, rel=1e-3)
    # twice as far, twice the footprint
    T = load_scene("plane").default_T_world_cam.copy()
    T[1, 3] -= 0.8
    assert object_mm_per_px(load_scene("plane"), T) == pytest.approx(2 * expected, rel=1e-3)


# random_changes(load_scene("plane"), n=12, seed=0) recorded before pit and lifted existed: (kind, seed, size_mm)
_PLANE_12_SEED_0 = [
    ("stain", 330529326, 2.243885060187946),
    ("crack", 17746413, 11.43112505181846),
    ("missing", 1042327185, 6.155329991455284),
    ("stain", 583712889, 16.464830777272045),
    ("missing", 423214460, 1.008237556829487),
    ("stain", 36062236, 8.898229901136776),
    ("crack", 23731787, 13.274606911924353),
    ("crack", 321813192, 3.5475518652144635),
    ("crack", 8895210, 1.451096420079578),
    ("stain", 694914446, 6.318798246003776),
    ("flaking", 864350543, 19.833530958985794),
    ("flaking", 736095100, 7.018867263540793),
]


def test_random_changes_default_kinds_draw_as_before_and_kinds_select():
    from fgcd_drivers.sim.scenes import load_scene

    s = load_scene("plane")
    chs = random_changes(s, n=12, seed=0)
    # kinds and seeds exactly; sizes to float precision (the last bit differs between numpy builds)
    assert [(c.kind, c.seed) for c in chs] == [(kind, seed) for kind, seed, _ in _PLANE_12_SEED_0]
    np.testing.assert_allclose([c.size_mm for c in chs], [size for _, _, size in _PLANE_12_SEED_0], rtol=1e-12)
    np.testing.assert_allclose(chs[0].position, (-0.28133331656455995, 0.0, 1.0620000112056731), atol=1e-6)
    assert KINDS == ("crack", "flaking", "stain", "missing") and ALL_KINDS == KINDS + ("pit", "lifted")
    for kind in ALL_KINDS:  # the category says what the kind changes: relief (a depth), colour (an albedo weight)
        ch = ChangeSpec(kind=kind, position=(0, 0, 1), normal=(0, -1, 0), size_mm=5.0, seed=1)
        relief, colour = ch.depth_m != 0, ch.target_albedo[1] > 0
        expected = {(True, True): "both", (True, False): "relief", (False, True): "colour"}[relief, colour]
        assert ch.category == CHANGE_CATEGORY[kind] == expected
    picked = random_changes(s, n=30, seed=0, kinds=("pit", "lifted", "stain"))
    assert {c.kind for c in picked} == {"pit", "lifted", "stain"}
    assert {c.category for c in picked} == {"relief", "colour"}
    with pytest.raises(ValueError):
        random_changes(s, n=1, seed=0, kinds=("pit", "dent"))
    with pytest.raises(ValueError):  # a lifted flake rises: its depth is negative
        ChangeSpec(kind="lifted", position=(0, 0, 1), normal=(0, -1, 0), size_mm=5.0, depth_mm=1.0)


# relief and colour cues: a 10 mm change on a frontal plane of albedo 0.5 seen at 0.25 mm per pixel
_FINE = CameraIntrinsics(fx=2000.0, fy=2000.0, cx=49.5, cy=49.5, width=100, height=100)
# a camera LED on its 0.6 m arm lights the plane 0.5 m away at beta = atan(0.6 / 0.5) = 50 deg from the normal
_TAN_BETA = 0.6 / 0.5
_LIGHTINGS = [AMBIENT] + [
    lighting_preset(n) for n in ("front", "led:3", "led:9", "led:12", "sun-noon", "overcast", "night")
]


def _relative_change(r, ch, lighting):
    """Mean |after / before - 1| inside the change mask, linear response without clipping."""
    T, _, _ = _frontal(_FINE)
    kw = dict(exposure=0.2, effects=LINEAR, want=("gray",))
    before = r.render(T, _FINE, lighting, **kw)
    after = r.render(T, _FINE, lighting, changes=[ch], **kw)
    m = after.change_mask
    assert m.sum() > 300 and before.gray.max() < 1.0 and after.gray.max() < 1.0
    return float(np.mean(np.abs(after.gray[m] / before.gray[m] - 1.0)))


def _centred(kind, seed=1, **kw):
    return ChangeSpec(kind=kind, position=(0.0, 0.0, 1.0), normal=(0, -1, 0), size_mm=10.0, seed=seed, **kw)


def test_pit_is_relief_shown_by_a_side_light_and_a_stain_is_colour_under_every_light(factories):
    r = Renderer(factories.make_scene([factories.plane_part(albedo=0.5)]))
    pit, stain = _centred("pit"), _centred("stain")
    assert (pit.category, stain.category) == ("relief", "colour")
    pit_rel = {L.name: _relative_change(r, pit, L) for L in _LIGHTINGS}
    stain_rel = {L.name: _relative_change(r, stain, L) for L in _LIGHTINGS}
    # ambient light: only the cavity's occlusion, D F^2 with D = d^2 / (d^2 + R^2) the sky share the rim
    # hides at the bottom and F >= 0.5 in the mask
    d, R = pit.depth_m, 0.005
    D = d * d / (d * d + R * R)
    assert 0.25 * D < pit_rel["a"] < D
    assert pit_rel["a"] < 0.5 * stain_rel["a"]
    # the bowl 1 - (r/R)^2 slopes by s = 2 d r / R^2; to first order Lambert changes by s tan(beta) cos(phi),
    # which averages 2/3 * 2 d / (R sqrt 2) * tan(beta) * 2/pi = 0.29 over the mask (r < R / sqrt 2)
    expected_side = 2 / 3 * 2 * d / (R * np.sqrt(2)) * _TAN_BETA * 2 / np.pi
    for side in ("led:3", "led:9"):
        assert pit_rel[side] > 0.6 * expected_side
        assert pit_rel[side] > 2.5 * max(pit_rel["a"], pit_rel["front"])
    # the stain: same relative change under every light (the lamps' colours weigh its brown a few % apart)
    values = np.array(list(stain_rel.values()))
    assert values.min() > 0.2 and values.max() / values.min() < 1.05
    pit_values = np.array(list(pit_rel.values()))
    assert pit_values.max() / pit_values.min() > 2.5


def test_lifted_flake_is_raised_tilted_and_seen_only_by_its_shading(factories):
    r = Renderer(factories.make_scene([factories.plane_part(albedo=0.5)]))
    T, _, _ = _frontal(_FINE)
    for seed in (1, 2, 3):
        ch = _centred("lifted", seed=seed)
        assert ch.category == "relief" and ch.depth_m == pytest.approx(-0.002)
        kw = dict(exposure=0.2, effects=LINEAR, want=("gray",))
        before = r.render(T, _FINE, AMBIENT, **kw)
        after = r.render(T, _FINE, AMBIENT, changes=[ch], **kw)
        # no albedo change and no cavity: uniform ambient light sees nothing
        np.testing.assert_array_equal(after.gray, before.gray)
        height = before.depth - after.depth
        assert height.min() >= 0 and height.max() == pytest.approx(-ch.depth_m, rel=0.05)
        # the plate rises from 0.25 to 1 of the lift across the 10 mm flake: slope s = 0.75 * 2 mm / 10 mm, seen
        # by lights 90 deg apart (3 and 12 o'clock) as s tan(beta) |cos phi| with max(|cos|, |sin|) >= 1/sqrt 2
        s = 0.75 * -ch.depth_m / 0.010
        side = max(_relative_change(r, ch, lighting_preset(n)) for n in ("led:3", "led:12"))
        assert side > 0.6 * s * _TAN_BETA / np.sqrt(2)
        assert side > 2.0 * _relative_change(r, ch, lighting_preset("front"))


@pytest.mark.parametrize("kind", ["pit", "lifted"])
def test_relief_changes_mask_depth_normals_and_albedo(factories, kind):
    """Mask where the footprint is >= 0.5; the normal tilts as the displaced depth slopes; albedo untouched."""
    r = Renderer(factories.make_scene([factories.plane_part(albedo=0.5)]))
    T, x, z = _frontal(_FINE)
    ch = _centred(kind)
    before = r.render(T, _FINE, "led:3", exposure=0.2, want=("gray",))
    after = r.render(T, _FINE, "led:3", changes=[ch], exposure=0.2, want=("gray",))
    F = _footprint_image(ch, x, z)
    np.testing.assert_array_equal(after.change_mask, F >= 0.5)
    assert np.all(after.gray[F == 0] == before.gray[F == 0])
    height = (before.depth - after.depth).astype(float)  # outward, metres
    assert np.abs(height).max() == pytest.approx(abs(ch.depth_m), rel=0.05)
    # a height field y = -h(x, z) has the outward normal (-h_x, -1, -h_z) (up to scale)
    px = 0.5 / _FINE.fx
    h_v, h_u = np.gradient(height, px)
    n = after.normals.astype(float)
    inner = cv2.erode((F >= 0.5).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)  # off the walls
    err = np.hypot(n[..., 0] / -n[..., 1] + h_u, n[..., 2] / -n[..., 1] - h_v)
    assert np.percentile(err[inner], 95) < 0.01
    assert np.median(np.hypot(h_u, h_v)[inner]) > 0.1  # a relief that tilts the normal, not a flat step
    pts = np.stack([x, np.zeros_like(x), z], -1).reshape(-1, 3)
    eff = evaluate_changes([ch], pts, np.tile([0.0, -1.0, 0.0], (len(pts), 1)))
    assert len(eff.index) > 300 and np.all(eff.albedo_weight == 0)


def _stain_seeds() -> tuple[int, int]:
    """A seed drawing a dark (filtering) stain and one drawing an efflorescence (covering)."""
    kinds = {
        ChangeSpec(kind="stain", position=(0, 0, 1.0), normal=(0, -1, 0), size_mm=8.0, seed=s).albedo_filters: s
        for s in range(20)
    }
    return kinds[True], kinds[False]


def test_a_dark_stain_filters_the_stone_and_an_efflorescence_covers_it():
    # Model (drivers/sim/changes.py): at footprint F the albedo a becomes a (1 - w F (1 - T)) for a dark stain
    # (an absorbing layer: the same relative darkening on any stone) and a (1 - w F) + w F W for an
    # efflorescence (a crust: every stone moves towards the same white W).
    pts, normals = np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, -1.0, 0.0]])
    stones = (0.1, 0.6)
    changed = {}
    for seed in _stain_seeds():
        ch = ChangeSpec(kind="stain", position=(0, 0, 1.0), normal=(0, -1, 0), size_mm=8.0, seed=seed)
        eff = evaluate_changes([ch], pts, normals)
        assert eff.footprint[0] > 0.9  # the centre
        target, weight = ch.target_albedo
        wf = weight * float(eff.footprint[0])
        out = [eff.albedo_of(np.full((1, 3), a, np.float32))[0] for a in stones]
        changed[ch.albedo_filters] = out
        if ch.albedo_filters:
            for a, new in zip(stones, out):
                np.testing.assert_allclose(new / a, 1 - wf * (1 - target), rtol=1e-5)  # the same on both stones
            assert np.all(out[0] / stones[0] < 0.75) and out[0][2] < out[0][0]  # darker, and brown (less blue)
        else:
            for a, new in zip(stones, out):
                np.testing.assert_allclose(new, a * (1 - wf) + wf * target, rtol=1e-5)
            assert np.all(out[0] > stones[0] + 0.3) and np.all(out[1] > stones[1])  # lighter on both stones
    assert set(changed) == {True, False}


def test_change_ids_tell_which_change_each_masked_pixel_is(factories):
    r = Renderer(factories.make_scene([factories.plane_part(albedo=0.5)]))
    T, x, z = _frontal(_FINE)
    stain = ChangeSpec(kind="stain", position=(-0.006, 0.0, 1.0), normal=(0, -1, 0), size_mm=8.0, seed=1)
    pit = ChangeSpec(kind="pit", position=(0.006, 0.0, 1.0), normal=(0, -1, 0), size_mm=8.0, seed=1)
    for changes in ([stain, pit], [pit, stain]):
        res = r.render(T, _FINE, "led:3", changes=changes, want=("gray",))
        assert res.change_ids.dtype == np.int32 and res.change_ids.shape == res.change_mask.shape
        np.testing.assert_array_equal(res.change_mask, res.change_ids > 0)
        for i, ch in enumerate(changes):
            F = _footprint_image(ch, x, z)
            np.testing.assert_array_equal(res.change_ids == i + 1, F >= 0.5)
            assert (res.change_ids == i + 1).sum() > 100
        assert set(np.unique(res.change_ids)) == {0, 1, 2}
    # overlapping footprints: the strongest one names the pixel (the first on ties)
    big = ChangeSpec(kind="stain", position=(0.0, 0.0, 1.0), normal=(0, -1, 0), size_mm=20.0, seed=2)
    res = r.render(T, _FINE, None, changes=[big, pit], want=("labels",))
    F1, F2 = _footprint_image(big, x, z), _footprint_image(pit, x, z)
    expected = np.where(np.maximum(F1, F2) >= 0.5, np.where(F2 > F1, 2, 1), 0)
    np.testing.assert_array_equal(res.change_ids, expected)
    assert ((expected == 2).sum() > 20) and ((expected == 1) & (F2 >= 0.5)).sum() > 20


def _footprint_image(ch, x, z):
    """Footprint of ``ch`` at the frontal plane's pixels (x, z world coordinates)."""
    P = np.stack([x, np.zeros_like(x), z], -1) - np.asarray(ch.position)
    e1, e2 = ch.basis()
    return ch.footprint_at((P @ e1).ravel(), (P @ e2).ravel()).reshape(x.shape)


def test_rig_home_pose_camera_and_ground_truth():
    from fgcd_drivers.sim.rig import SimRigConfig, build_sim_rig

    rig = build_sim_rig(scene="plane", config=SimRigConfig(noise="none", intrinsics_error="none", seed=4))
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
    mine = rig.camera.synthetic_overhead_s(threading.get_ident())
    assert mine == pytest.approx(before)  # so far every render was this thread's

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
    # by thread: the other threads' renders are not this thread's (a caller timing its own stills)
    assert rig.camera.synthetic_overhead_s(threading.get_ident()) == mine
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
    from fgcd_drivers.sim.rig import SimRigConfig, build_sim_rig

    rig = build_sim_rig(scene="plane", config=SimRigConfig(seed=1, with_depth=True))
    true, nom = rig.ground_truth.intrinsics_true(), rig.camera.intrinsics_nominal
    assert true != nom and abs(true.fx / nom.fx - 1) < 0.05 and true.dist[0] < 0
    f = rig.camera.grab()
    assert f.depth is not None and np.all(f.depth > 0.5)
    # same seed, same noisy frame
    g = build_sim_rig(scene="plane", config=SimRigConfig(seed=1)).camera.grab()
    np.testing.assert_array_equal(f.image, g.image)


def test_rig_sessions_changes_and_displaced_base():
    from fgcd_drivers.sim.rig import SimRigConfig, build_sim_rig

    a = build_sim_rig(scene="plane", config=SimRigConfig(seed=2, session_seed=0))
    b = build_sim_rig(scene="plane", config=SimRigConfig(seed=2, session_seed=1))
    # same world: same hand-eye, base and intrinsics; another session: other noise
    np.testing.assert_array_equal(a.ground_truth.T_flange_cam_true(), b.ground_truth.T_flange_cam_true())
    np.testing.assert_array_equal(a.ground_truth.T_world_base_true(), b.ground_truth.T_world_base_true())
    assert not np.array_equal(a.camera.grab().image, b.camera.grab().image)
    chs = b.inject_changes(n=3, seed=5)
    assert len(chs) == 3 and b.ground_truth.changes() == chs
    assert b.ground_truth.change_mask().any()
    ids = b.ground_truth.change_ids()
    np.testing.assert_array_equal(ids > 0, b.ground_truth.change_mask())
    assert ids.max() <= len(chs)
    T0 = b.ground_truth.T_world_cam_true()
    delta = np.eye(4)
    delta[:3, 3] = [0.02, 0.0, 0.0]
    b.displace_base(delta)
    np.testing.assert_allclose(b.ground_truth.T_world_cam_true(), T0 @ delta, atol=1e-12)


def test_procedural_geometry_is_a_function_of_the_seed():
    """The irregular statue: same seed, identical mesh and textures; another seed, another statue."""
    from fgcd_drivers.sim.scenes import _load

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
