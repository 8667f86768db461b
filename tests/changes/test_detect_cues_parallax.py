"""Issue 19 acceptance: a pit is found and labelled relief, a stain colour; light changes and parallax are not changes.

Every pair is rendered here with a Lambertian model of a textured, non-planar
surface: a colour albedo (scikit-image 'gravel') on a height field (a broad dome
plus random bumps), one ambient image (index 0) and six directional lights at
the even clock positions, 45 degrees from the optical axis, with sensor noise.
Camera frame as in :mod:`fgcd_cli.changes.photometric.stereo`: x right, y down, z away
from the camera; a surface facing the camera has normal ~(0, 0, -1).
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fgcd_cli.changes.config import DetectionConfig
from fgcd_cli.changes.detect import detect_changes
from fgcd_cli.changes.result import ChangeResult

from .conftest import textured_scene

SIZE = 300
NOISE = 0.004
"""Sensor noise, standard deviation (~1 grey level of 8 bits)."""
AMBIENT = 0.25
"""Ambient image = AMBIENT x albedo."""
TILT_DEG = 45.0
"""Angle of every directional light from the optical axis."""
CLOCK_HOURS = (12, 2, 4, 6, 8, 10)
"""Positions of the six directional lights around the lens."""

PIT_XY, PIT_RADIUS_PX, PIT_RIM_SLOPE_DEG = (175, 110), 10.0, 35.0
STAIN_XY, STAIN_RADIUS_PX, STAIN_FACTOR = (95, 200), 10.0, 0.5
FLAKE_FLOOR_FACTOR = 0.7
"""Albedo of a lost flake's floor (the pit's disc) relative to the paint: |ln 0.7| = 0.36 ~ the pit's tilt."""

DOME_XY, DOME_SIGMA_PX, DOME_HEIGHT_PX = (0.55 * SIZE, 0.45 * SIZE), 75.0, 30.0
"""The broad dome of the relief (towards the camera); its parallax is the non-planar part of the view change."""
PARALLAX_PEAK_PX = 3.0
"""Extra disparity of the dome's top over its foot in the shifted view, px."""
PARALLAX_DIRECTION = (0.8, 0.6)
"""Direction of the baseline of the shifted view in the image."""
VIEW_SHIFT_PX = (1.2, -0.7)
"""Disparity of the foot of the relief (what a homography can take)."""

SMOOTH_SIGMA_PX = 2.0
"""detect_changes' default smoothing of the score (and of the cues)."""

_YY, _XX = np.mgrid[0:SIZE, 0:SIZE].astype(np.float64)


# --------------------------------------------------------------------------- renderer


def light_directions() -> np.ndarray:
    """6x3 unit vectors towards the lights (camera frame; 12 o'clock is image up, -y)."""
    hours = np.radians(np.array(CLOCK_HOURS) * 30.0)
    tilt = np.radians(TILT_DEG)
    return np.stack(
        [np.sin(tilt) * np.sin(hours), -np.sin(tilt) * np.cos(hours), -np.cos(tilt) * np.ones_like(hours)], axis=1
    )


def albedo() -> np.ndarray:
    """HxWx3 colour albedo in 0.3..0.8 (grey texture, channel weights 0.9 / 0.7 / 0.5)."""
    grey = textured_scene(SIZE).astype(np.float64)
    grey = 0.3 + 0.5 * (grey - grey.min()) / np.ptp(grey)
    return np.stack([grey * 0.9, grey * 0.7, grey * 0.5], axis=-1)


def dome() -> np.ndarray:
    """Height of the broad dome towards the camera, px (>= 0)."""
    return DOME_HEIGHT_PX * np.exp(-((_XX - DOME_XY[0]) ** 2 + (_YY - DOME_XY[1]) ** 2) / (2 * DOME_SIGMA_PX**2))


def depth_map(seed: int = 3) -> np.ndarray:
    """Depth Z(x, y) in px (away from the camera): the dome plus 30 random bumps and dents 10-30 px wide."""
    rng = np.random.default_rng(seed)
    depth = -dome()
    for _ in range(30):
        cx, cy = rng.uniform(0, SIZE, 2)
        s = rng.uniform(10, 30)
        depth += rng.uniform(-0.6, 0.6) * s * np.exp(-((_XX - cx) ** 2 + (_YY - cy) ** 2) / (2 * s * s))
    return depth


def normals_of(depth: np.ndarray) -> np.ndarray:
    z_y, z_x = np.gradient(depth)
    n = np.stack([z_x, z_y, -np.ones_like(depth)], axis=-1)
    return n / np.linalg.norm(n, axis=2, keepdims=True)


def disc(center, radius: float) -> np.ndarray:
    return (_XX - center[0]) ** 2 + (_YY - center[1]) ** 2 <= radius**2


def spherical_pit() -> tuple[np.ndarray, np.ndarray, float]:
    """Depth added by a spherical-cap pit (>= 0, away from the camera), its disc, and its sphere radius."""
    sphere = PIT_RADIUS_PX / np.sin(np.radians(PIT_RIM_SLOPE_DEG))
    r2 = (_XX - PIT_XY[0]) ** 2 + (_YY - PIT_XY[1]) ** 2
    inside = r2 <= PIT_RADIUS_PX**2
    cap = np.sqrt(np.maximum(sphere**2 - r2, 0.0)) - np.sqrt(sphere**2 - PIT_RADIUS_PX**2)
    return np.where(inside, cap, 0.0), inside, sphere


def render(depth, alb, *, rng=None, exposure=1.0, gains=None, ramp=None) -> list[np.ndarray]:
    """Ambient image then one Lambertian image per light, x exposure x per-light gain x ramp, + noise, in [0, 1]."""
    n = normals_of(depth)
    images = [AMBIENT * alb]
    for k, light in enumerate(light_directions()):
        shading = np.maximum(n @ light, 0.0) * (1.0 if gains is None else gains[k])
        images.append(alb * shading[:, :, None])
    out = []
    for image in images:
        image = image * exposure * (1.0 if ramp is None else ramp[:, :, None])
        if rng is not None:
            image = image + rng.normal(0.0, NOISE, image.shape)
        out.append(np.clip(image, 0.0, 1.0).astype(np.float32))
    return out


def parallax(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Scene point seen at reference pixel (x, y) is seen at (x, y) + P in the shifted view: shift + k x dome."""
    m = PARALLAX_PEAK_PX * np.exp(-((x - DOME_XY[0]) ** 2 + (y - DOME_XY[1]) ** 2) / (2 * DOME_SIGMA_PX**2))
    return VIEW_SHIFT_PX[0] + PARALLAX_DIRECTION[0] * m, VIEW_SHIFT_PX[1] + PARALLAX_DIRECTION[1] * m


def shifted_view(images: list[np.ndarray], rng) -> list[np.ndarray]:
    """The (noise-free) images as seen from the shifted viewpoint, then sensor noise.

    out(y) = in(y + Q(y)) with Q(y) = -P(y + Q(y)) (fixed point; |grad P| < 0.03, a contraction).
    """
    qx, qy = np.zeros_like(_XX), np.zeros_like(_YY)
    for _ in range(30):
        px, py = parallax(_XX + qx, _YY + qy)
        qx, qy = -px, -py
    map_x, map_y = (_XX + qx).astype(np.float32), (_YY + qy).astype(np.float32)
    moved = [cv2.remap(im, map_x, map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT) for im in images]
    return [np.clip(im + rng.normal(0.0, NOISE, im.shape), 0.0, 1.0).astype(np.float32) for im in moved]


def calibrated_lights() -> np.ndarray:
    """7x3 light rows for detect_changes (the ambient row is ignored)."""
    return np.vstack([np.zeros(3), light_directions()])


# --------------------------------------------------------------------------- fixtures and helpers


@pytest.fixture(scope="module")
def scene() -> dict:
    alb, depth = albedo(), depth_map()
    pit_depth, pit_disc, sphere = spherical_pit()
    return dict(
        albedo=alb,
        depth=depth,
        pit_depth=pit_depth,
        pit=pit_disc,
        sphere=sphere,
        stain=disc(STAIN_XY, STAIN_RADIUS_PX),
        ref=render(depth, alb, rng=np.random.default_rng(0)),
    )


def stained(scene: dict) -> np.ndarray:
    return scene["albedo"] * np.where(scene["stain"], STAIN_FACTOR, 1.0)[:, :, None]


def region_on(result: ChangeResult, truth: np.ndarray):
    """The region overlapping ``truth`` most, with its pixels."""
    best = max(result.regions, key=lambda r: np.count_nonzero((result.labels == r.id) & truth), default=None)
    assert best is not None and np.any((result.labels == best.id) & truth), "no region on the change"
    return best, result.labels == best.id


def describe(result: ChangeResult) -> list:
    """(id, area, cue, evidence, magnitude) of every region, for assertion messages."""
    maps = result.cue_maps
    return [
        (r.id, r.area_px, r.cue, maps.evidence.get(r.id), getattr(maps, "magnitude", {}).get(r.id))
        for r in result.regions
    ]


def assert_found(result: ChangeResult, truth: np.ndarray, radius_px: float):
    """The change is one region holding most of the disc and little else; nothing else is flagged.

    Recall >= 0.9: only a pit's centre (normal tilt < 10 degrees, r < 3 px, 9 % of the disc) can be
    weak, and it is a hole below max_hole_px (30 px) that the cleaning fills. Precision: the score is
    smoothed by sigma = 2 px and tolerates a 1 px shift, so the region may reach 2 sigma beyond the
    disc: at least (r / (r + 2 sigma))^2 of it lies on the disc.
    """
    region, pixels = region_on(result, truth)
    recall = np.count_nonzero(pixels & truth) / np.count_nonzero(truth)
    precision = np.count_nonzero(pixels & truth) / np.count_nonzero(pixels)
    assert recall >= 0.9, (recall, describe(result))
    assert precision >= (radius_px / (radius_px + 2 * SMOOTH_SIGMA_PX)) ** 2, (precision, describe(result))
    assert len(result.regions) == 1, describe(result)
    return region, pixels


def pit_tilt(scene: dict) -> float:
    """Median over the pit's disc of the true angle between the reference and current normals, radians."""
    n_ref = normals_of(scene["depth"])
    n_cur = normals_of(scene["depth"] + scene["pit_depth"])
    angle = np.arccos(np.clip(np.sum(n_ref * n_cur, axis=2), -1.0, 1.0))
    return float(np.median(angle[scene["pit"]]))


def check_pit_label(result: ChangeResult, scene: dict, region) -> None:
    # A pure normal change: relief is the label, the relief cue is in the pair's top 1 % (evidence >= 2).
    assert region.cue == "relief", describe(result)
    relief, colour = result.cue_maps.magnitude[region.id]
    assert result.cue_maps.evidence[region.id][0] >= 2.0, describe(result)
    # The relief magnitude (radians x tan 45 deg) is the pit's normal tilt; the region reaching 2 sigma
    # beyond the disc and the sigma smoothing can at most halve its median, fitting noise not double it.
    tilt = pit_tilt(scene)
    assert 0.5 * tilt < relief < 1.5 * tilt, (tilt, describe(result))
    # Same albedo: what the colour cue shows is misfit, below a quarter of the relief (the label's
    # 'both' needs a half).
    assert colour < 0.25 * relief, describe(result)


def check_stain_label(result: ChangeResult, region) -> None:
    # A pure albedo change: colour is the label, the colour cue is in the pair's top 1 %.
    assert region.cue == "colour", describe(result)
    relief, colour = result.cue_maps.magnitude[region.id]
    assert result.cue_maps.evidence[region.id][1] >= 2.0, describe(result)
    # |ln 0.5| = 0.69 per channel, less the cue's eps damping (<= 20 %) and the smoothing of the rim
    # over a region up to 2 sigma wider than the disc (at most halves the median).
    expected = abs(np.log(STAIN_FACTOR))
    assert 0.5 * expected < colour < 1.05 * expected, describe(result)
    # Same shape: the relief magnitude is only noise, raised by 1 / 0.5 on the darker albedo.
    assert relief < 0.1 * colour, describe(result)


# --------------------------------------------------------------------------- tests


def test_renderer_matches_the_stated_case(scene):
    """The scene is what the tests below assume: non-planar, unclipped, lights at 45 degrees."""
    lights = light_directions()
    np.testing.assert_allclose(np.degrees(np.arccos(-lights[:, 2])), TILT_DEG)
    np.testing.assert_allclose(
        lights[0], [0.0, -np.sin(np.radians(TILT_DEG)), -np.cos(np.radians(TILT_DEG))], atol=1e-12
    )  # 12 o'clock is image up
    slope = np.degrees(np.arccos(-normals_of(scene["depth"])[:, :, 2]))
    assert 10.0 < np.median(slope) and slope.max() < TILT_DEG  # relief everywhere, no attached shadow
    assert max(float(im.max()) for im in scene["ref"]) < 0.98  # nothing clipped
    # The pit: 3.1 px deep, rim slope 35 degrees.
    assert scene["pit_depth"].max() == pytest.approx(
        scene["sphere"] - np.sqrt(scene["sphere"] ** 2 - PIT_RADIUS_PX**2), rel=0.02
    )


@pytest.mark.parametrize("calibrated", [False, True], ids=["uncalibrated", "calibrated"])
def test_pit_is_found_and_labelled_relief(scene, calibrated):
    cur = render(scene["depth"] + scene["pit_depth"], scene["albedo"], rng=np.random.default_rng(1))
    result = detect_changes(
        scene["ref"], cur, config=DetectionConfig.from_options(light_dirs=calibrated_lights() if calibrated else None)
    )
    region, _ = assert_found(result, scene["pit"], PIT_RADIUS_PX)
    check_pit_label(result, scene, region)


@pytest.mark.parametrize("calibrated", [False, True], ids=["uncalibrated", "calibrated"])
def test_stain_is_found_and_labelled_colour(scene, calibrated):
    cur = render(scene["depth"], stained(scene), rng=np.random.default_rng(2))
    result = detect_changes(
        scene["ref"], cur, config=DetectionConfig.from_options(light_dirs=calibrated_lights() if calibrated else None)
    )
    region, _ = assert_found(result, scene["stain"], STAIN_RADIUS_PX)
    check_stain_label(result, region)


def test_lost_flake_changes_both_relief_and_colour(scene):
    """The pit with a darker floor: both cues change, by about as much, so the label is both."""
    floor = scene["albedo"] * np.where(scene["pit"], FLAKE_FLOOR_FACTOR, 1.0)[:, :, None]
    cur = render(scene["depth"] + scene["pit_depth"], floor, rng=np.random.default_rng(6))
    result = detect_changes(scene["ref"], cur)
    region, _ = assert_found(result, scene["pit"], PIT_RADIUS_PX)
    assert region.cue == "both", describe(result)
    relief, colour = result.cue_maps.magnitude[region.id]
    assert min(result.cue_maps.evidence[region.id]) >= 2.0, describe(result)
    # Relief ~ the median tilt 0.38 rad x tan 45 deg, colour ~ |ln 0.7| = 0.36, each diluted alike by the
    # region's rim: their ratio is ~0.9, well inside the rule's 'both' (>= 0.5).
    assert min(relief, colour) > 0.7 * max(relief, colour), describe(result)


def test_unchanged_pair_under_different_light_gives_no_region(scene):
    # Exposure x 0.8, each lamp up to 8 % weaker or stronger, a fall-off ramp 0.85..1.15 across the
    # image: all smooth or global, none a change (and nothing clips: 0.67 x 0.8 x 1.08 x 1.15 = 0.67).
    gains = np.array([1.05, 0.95, 1.08, 0.92, 1.0, 1.03])
    ramp = np.broadcast_to(np.linspace(0.85, 1.15, SIZE)[None, :], (SIZE, SIZE))
    cur = render(scene["depth"], scene["albedo"], rng=np.random.default_rng(3), exposure=0.8, gains=gains, ramp=ramp)
    assert max(float(im.max()) for im in cur) < 0.98
    result = detect_changes(scene["ref"], cur)
    assert result.comparable
    assert result.regions == [], describe(result)
    assert result.not_compared.mean() < 0.02  # not hidden either: ~1 % at the frame border


def true_residual_flow(result: ChangeResult) -> np.ndarray:
    """The flow the dense stage should find after the homography: H^-1(x + P(x)) - x."""
    inv = np.linalg.inv(result.registration.H_cur_ref)
    px, py = parallax(_XX, _YY)
    x, y = _XX + px, _YY + py
    den = inv[2, 0] * x + inv[2, 1] * y + inv[2, 2]
    fx = (inv[0, 0] * x + inv[0, 1] * y + inv[0, 2]) / den - _XX
    fy = (inv[1, 0] * x + inv[1, 1] * y + inv[1, 2]) / den - _YY
    return np.stack([fx, fy], axis=2)


def peak_bias_px(smooth_px: float) -> float:
    """Bias of the dense stage's local-quadratic fit at the top of the Gaussian parallax bump, px.

    Its equivalent kernel g(r) (2 - r^2 / (2 s^2)) returns (1 + 2t) / (1 + t)^2 of a Gaussian bump's
    peak, t = s^2 / b^2 (as in test_dense.py).
    """
    t = (smooth_px / DOME_SIGMA_PX) ** 2
    return PARALLAX_PEAK_PX * (1.0 - (1.0 + 2.0 * t) / (1.0 + t) ** 2)


@pytest.fixture(scope="module")
def parallax_pair(scene) -> dict:
    clean = render(scene["depth"], scene["albedo"])
    cur = shifted_view(clean, np.random.default_rng(4))
    return dict(
        cur=cur,
        dense=detect_changes(scene["ref"], cur),
        homography=detect_changes(scene["ref"], cur, config=DetectionConfig.from_options(dense=False)),
    )


def test_parallax_is_aligned_not_flagged(scene, parallax_pair):
    result = parallax_pair["dense"]
    assert result.comparable and result.dense is not None
    assert result.regions == [], describe(result)
    assert result.not_compared.mean() < 0.02, result.not_compared.mean()  # aligned, not hidden
    truth = true_residual_flow(result)
    magnitude = np.hypot(truth[..., 0], truth[..., 1])
    # The case is one a homography cannot explain: after it, >= 1 px of parallax is left on the dome.
    assert magnitude[result.valid].max() > 1.0, magnitude[result.valid].max()
    error = np.hypot(*(result.dense.flow - truth).transpose(2, 0, 1))
    textured = result.valid & (result.dense.confidence > 0.5)
    assert textured.mean() > 0.8  # gravel everywhere
    # DIS on a textured, noise-free-ish pair is good to ~0.1 px; the largest error is the fit's
    # known bias at the dome's top (0.40 px here) plus that noise.
    assert error[textured].mean() < 0.15, error[textured].mean()
    assert np.percentile(error[textured], 95) < 0.3, np.percentile(error[textured], 95)
    assert error[textured].max() < peak_bias_px(result.dense.settings["smooth_px"]) + 0.15, error[textured].max()


def test_parallax_left_to_the_homography_misaligns(scene, parallax_pair):
    """Evidence that the dense stage does the work: without it the dome stays visibly misaligned."""
    dense, plain = parallax_pair["dense"], parallax_pair["homography"]
    assert plain.dense is None
    left = true_residual_flow(plain)
    # Where the homography leaves more than 1 px of parallax (the dome's top, ~14 % of the pixels).
    dome_top = dense.valid & plain.valid & (np.hypot(left[..., 0], left[..., 1]) > 1.0)
    assert dome_top.mean() > 0.05
    ref = scene["ref"][0].mean(axis=2)

    def residual(result):
        return float(np.abs(ref - result.current_registered[0].mean(axis=2))[dome_top].mean())

    # First-order size of that misalignment in the ambient image, mean |grad I . d| (~0.0065, twice the
    # noise floor ~0.003): left to the homography it adds at least half of it to the residual (noise and
    # misalignment add in quadrature at worst); the dense stage takes it out (its error: the test above).
    grad_y, grad_x = np.gradient(render(scene["depth"], scene["albedo"])[0].mean(axis=2).astype(np.float64))
    first_order = float(np.abs(grad_x * left[..., 0] + grad_y * left[..., 1])[dome_top].mean())
    assert residual(plain) > residual(dense) + 0.5 * first_order, (residual(plain), residual(dense), first_order)


def test_changes_under_parallax_are_found_and_labelled(scene):
    """A pit and a stain on the shifted view: the dense stage keeps both, each with its own label."""
    clean = render(scene["depth"] + scene["pit_depth"], stained(scene))
    cur = shifted_view(clean, np.random.default_rng(5))
    result = detect_changes(scene["ref"], cur)
    assert len(result.regions) == 2, describe(result)
    for truth, radius in ((scene["pit"], PIT_RADIUS_PX), (scene["stain"], STAIN_RADIUS_PX)):
        region, pixels = region_on(result, truth)
        recall = np.count_nonzero(pixels & truth) / np.count_nonzero(truth)
        precision = np.count_nonzero(pixels & truth) / np.count_nonzero(pixels)
        # As in assert_found, plus the dense fit's error (<= 0.3 px on 95 % of pixels) in the extent.
        assert recall >= 0.9 and precision >= (radius / (radius + 2 * SMOOTH_SIGMA_PX + 0.3)) ** 2, describe(result)
    pit_region, _ = region_on(result, scene["pit"])
    check_pit_label(result, scene, pit_region)
    stain_region, _ = region_on(result, scene["stain"])
    check_stain_label(result, stain_region)
