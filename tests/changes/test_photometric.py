"""Photometric stereo on synthetic Lambertian scenes with known normals and albedo, and on one real group."""

from pathlib import Path

import cv2
import numpy as np
import pytest
from skimage import data

from fgcd_cli.changes.photometric.stereo import (
    JointFitConfig,
    PhotometricStereo,
    joint_photometric_stereo,
    photometric_stereo,
    relief_and_colour_cues,
)
from fgcd_cli.errors import UserInputError

GROUP = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "fgcd-dataset" / "Db" / "Db-1"

NOISE = 0.004  # image noise, ~1 grey level of 8 bits
AMBIENT = 0.25  # ambient image = AMBIENT x albedo


def normals_from_depth(depth: np.ndarray) -> np.ndarray:
    """Unit normals, camera frame (x right, y down, z away), of a depth map Z(x, y) in pixel units."""
    z_y, z_x = np.gradient(depth)
    n = np.stack([z_x, z_y, -np.ones_like(depth)], axis=-1)
    return n / np.linalg.norm(n, axis=2, keepdims=True)


def random_relief(size: int, rng, *, count: int, scale_px: tuple[float, float]) -> np.ndarray:
    """Depth map made of Gaussian bumps and dents, slopes up to ~30 degrees."""
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    depth = np.zeros((size, size))
    for _ in range(count):
        cx, cy = rng.uniform(0, size, 2)
        s = rng.uniform(*scale_px)
        depth += rng.uniform(-0.8, 0.8) * s * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * s * s))
    return depth


def textured_albedo(size: int, low: float = 0.3, high: float = 0.8) -> np.ndarray:
    """Colour albedo HxWx3 from a real texture (scikit-image 'gravel'), channel gains 0.9/0.7/0.5."""
    gravel = data.gravel()[: 2 * size, : 2 * size].astype(np.float32) / 255.0
    grey = cv2.resize(gravel, (size, size), interpolation=cv2.INTER_AREA)
    grey = low + (high - low) * (grey - grey.min()) / np.ptp(grey)
    return np.stack([grey * 0.9, grey * 0.7, grey * 0.5], axis=-1)


def side_lights(rng, k: int = 6, tilt_deg: float = 45.0) -> np.ndarray:
    """k lights around the lens (directions towards the light times intensity, rows), l_z < 0."""
    azimuth = np.radians(np.arange(k) * 360.0 / k + rng.uniform(0, 30))
    tilt = np.radians(tilt_deg + rng.uniform(-8, 8, k))
    intensity = rng.uniform(0.8, 1.2, k)
    dirs = np.stack([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), -np.cos(tilt)], axis=1)
    return dirs * intensity[:, None]


def render(normals, albedo, lights, rng, *, gains=None) -> list[np.ndarray]:
    """Ambient image then one Lambertian image per light, with noise, clipped to [0, 1], float32."""
    images = [AMBIENT * albedo]
    for k, light in enumerate(lights):
        shading = np.maximum(normals @ light, 0.0)
        if gains is not None:
            shading = shading * gains[k]
        images.append(albedo * shading[:, :, None])
    return [np.clip(im + rng.normal(0, NOISE, im.shape), 0, 1).astype(np.float32) for im in images]


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1.0, 1.0)))


def angle_up_to_relief_sign_deg(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Angle to the truth, or to its concave/convex mirror (n_x, n_y) -> -(n_x, n_y), whichever is smaller.

    Uncalibrated photometric stereo cannot tell the two apart (bas-relief ambiguity).
    """
    direct = np.nanmedian(angle_deg(estimate, truth))
    mirrored = np.nanmedian(angle_deg(estimate, truth * np.array([-1.0, -1.0, 1.0])))
    return angle_deg(estimate, truth if direct <= mirrored else truth * np.array([-1.0, -1.0, 1.0]))


def with_ambient_row(lights: np.ndarray) -> np.ndarray:
    return np.vstack([np.zeros(3), lights])


def hemisphere_scene(size: int = 160, radius: float = 60.0):
    """A hemisphere bulging towards the camera on a frontal plane: analytic normals."""
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64) + 0.5
    dx, dy = xx - size / 2, yy - size / 2
    inside = dx**2 + dy**2 < radius**2
    dz = np.sqrt(np.maximum(radius**2 - dx**2 - dy**2, 0.0))
    normals = np.where(inside[:, :, None], np.stack([dx, dy, -dz], axis=-1) / radius, [0.0, 0.0, -1.0])
    return normals


# --------------------------------------------------------------------------- calibrated


def test_calibrated_hemisphere_normals_and_albedo():
    rng = np.random.default_rng(0)
    normals = hemisphere_scene()
    albedo = textured_albedo(normals.shape[0])
    lights = side_lights(rng)
    images = render(normals, albedo, lights, rng)
    result = photometric_stereo(images, light_dirs=with_ambient_row(lights), falloff_sigma_px=None)

    assert isinstance(result, PhotometricStereo) and result.calibrated
    assert result.normals.shape == normals.shape and result.normals.dtype == np.float32
    assert result.albedo.shape == albedo.shape and result.residual.shape == normals.shape[:2]
    assert result.used.tolist() == [False] + [True] * 6
    np.testing.assert_allclose(result.light_dirs[1:], lights)
    # Up to 60 degrees of tilt at least 4 of the 6 lights (45 degrees off axis) see the surface.
    tilt = np.degrees(np.arccos(-normals[:, :, 2]))
    scored = tilt < 60
    error = angle_deg(result.normals, normals)[scored]
    # Noise 0.004 on albedo >= 0.15 (darkest channel) over ~5 lights: b's tangential std is
    # ~0.004 / sqrt(1.5) per axis, i.e. < 1.5 degrees at the darkest pixels; median far below.
    assert np.median(error) < 1.0
    assert np.percentile(error, 95) < 3.0
    relative = np.abs(result.albedo / albedo - 1.0)[scored]
    assert np.median(relative) < 0.02
    assert np.percentile(relative, 95) < 0.06
    assert np.nanmedian(result.residual[scored]) < 0.03  # noise / level ~ 0.004 / 0.3


def test_falloff_correction_handles_near_lights():
    """Each light's intensity ramps +-35 % across the image (near lamps): the local gain model absorbs it."""
    rng = np.random.default_rng(1)
    size = 192
    normals = normals_from_depth(random_relief(size, rng, count=200, scale_px=(3, 7)))
    albedo = textured_albedo(size, 0.2, 0.6)
    lights = side_lights(rng)
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    gains = []
    for _ in lights:
        theta = rng.uniform(0, 2 * np.pi)
        gains.append(1.0 + 0.35 * ((xx - size / 2) * np.cos(theta) + (yy - size / 2) * np.sin(theta)) / (size / 2))
    images = render(normals, albedo, lights, rng, gains=gains)
    plain = photometric_stereo(images, light_dirs=with_ambient_row(lights), falloff_sigma_px=None)
    corrected = photometric_stereo(images, light_dirs=with_ambient_row(lights), falloff_sigma_px=40.0)
    err_plain = np.median(angle_deg(plain.normals, normals))
    err_corrected = angle_deg(corrected.normals, normals)
    # The ramps tilt the uncorrected normals by ~10 degrees; corrected, what remains is the noise
    # (< 1 degree) plus the deviation of the surface's 40 px mean normal from frontal (~0.5 degree).
    assert err_plain > 6.0
    assert np.median(err_corrected) < 1.5
    assert np.percentile(err_corrected, 95) < 5.0


def test_cast_shadows_and_highlights_are_outliers():
    """A cast shadow (one lighting at 25 % where the surface faces the lamp) and a clipped highlight."""
    rng = np.random.default_rng(2)
    size = 128
    normals = normals_from_depth(random_relief(size, rng, count=30, scale_px=(6, 16)))
    albedo = textured_albedo(size)
    lights = side_lights(rng)
    images = render(normals, albedo, lights, rng)
    shadow = np.zeros((size, size), bool)
    shadow[30:42, 30:42] = True
    highlight = np.zeros((size, size), bool)
    highlight[80:90, 70:80] = True
    images[2][shadow] *= 0.25
    images[4][highlight] = 1.0
    outliers = shadow | highlight
    result = photometric_stereo(images, light_dirs=with_ambient_row(lights), falloff_sigma_px=None)

    error = angle_deg(result.normals, normals)
    assert np.median(error[~outliers]) < 1.0
    assert np.percentile(error[~outliers], 99) < 4.0
    # Robust: the shadowed / clipped sample is left out, the 5 others still determine the normal
    # (a pixel on a steep slope may be left with fewer than 3 lit samples: unknown, not wrong).
    assert np.isfinite(error[outliers]).mean() > 0.9
    assert np.nanmedian(error[outliers]) < 3.0
    # ...whereas plain least squares with all 6 samples is far off there (the test means something).
    lights32 = lights.astype(np.float32)
    stack = np.stack([im.mean(axis=2) for im in images[1:]]).reshape(6, -1)
    b_plain = np.linalg.lstsq(lights32, stack, rcond=None)[0].T.reshape(size, size, 3)
    n_plain = b_plain / np.linalg.norm(b_plain, axis=2, keepdims=True)
    assert np.median(angle_deg(n_plain, normals)[shadow]) > 8.0
    # The residual flags them: one sample of six off by ~75 % of the pixel's level (shadow).
    assert np.nanmedian(result.residual[shadow]) > 0.15
    assert np.nanmedian(result.residual[highlight]) > 0.08
    assert np.nanpercentile(result.residual[~outliers], 99) < 0.06


# --------------------------------------------------------------------------- uncalibrated


def test_uncalibrated_normals_match_up_to_bas_relief_sign():
    """The scene meets the frame conventions (frontal on average, isotropic, lights 45 deg off axis)."""
    rng = np.random.default_rng(3)
    size = 192
    normals = normals_from_depth(random_relief(size, rng, count=25, scale_px=(6, 20)))
    albedo = textured_albedo(size)
    lights = side_lights(rng)
    images = render(normals, albedo, lights, rng)
    # A cast shadow on ~1 % of the pixels must not disturb the factorization either.
    images[3][100:120, 40:58] *= 0.3
    result = photometric_stereo(images, falloff_sigma_px=None)
    assert not result.calibrated
    assert np.all(np.isnan(result.light_dirs[0])) and np.all(np.isfinite(result.light_dirs[1:]))
    error = angle_up_to_relief_sign_deg(result.normals, normals)
    # Integrability fixes the in-plane axes; the remaining GBR parameters follow the conventions,
    # which this scene satisfies to within a degree or two.
    assert np.nanmedian(error) < 2.0
    assert np.nanpercentile(error, 95) < 6.0
    # Lights: tilt set to 45 degrees by convention (truth 45 +- 8), azimuths measured.
    est = result.light_dirs[1:]
    tilt = np.degrees(np.arctan2(np.linalg.norm(est[:, :2], axis=1), -est[:, 2]))
    assert abs(np.median(tilt) - 45.0) < 1.0


def test_uncalibrated_convexity_convention_on_a_dome():
    rng = np.random.default_rng(4)
    size = 160
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    depth = -30.0 * np.exp(-((xx - 80) ** 2 + (yy - 80) ** 2) / (2 * 35.0**2))  # bulges towards the camera
    normals = normals_from_depth(depth)
    images = render(normals, textured_albedo(size), side_lights(rng), rng)
    result = photometric_stereo(images, falloff_sigma_px=None)
    assert np.nanmedian(angle_deg(result.normals, normals)) < 2.0


WHITE_BALANCE = np.array([1.1, 1.0, 0.9])


def pit_and_stain_scene(seed: int, size: int = 256):
    rng = np.random.default_rng(seed)
    depth = random_relief(size, rng, count=25, scale_px=(6, 20))
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    pit_xy, stain_xy = (80, 170), (180, 70)
    r_pit = np.hypot(xx - pit_xy[0], yy - pit_xy[1])
    r_stain = np.hypot(xx - stain_xy[0], yy - stain_xy[1])
    # Pit: a Gaussian depression 4 px deep, sigma 5 px (slopes up to ~26 degrees); albedo unchanged.
    depth_cur = depth + 4.0 * np.exp(-(r_pit**2) / (2 * 5.0**2))
    # Stain: albedo x 0.6 on a disc of radius 10 px; relief unchanged.
    stain = r_stain <= 10
    albedo = textured_albedo(size)
    albedo_cur = albedo * np.where(stain, 0.6, 1.0)[:, :, None]
    lights = side_lights(rng)
    n_ref, n_cur = normals_from_depth(depth), normals_from_depth(depth_cur)
    ref = render(n_ref, albedo, lights, rng)
    # The current observation: exposure x 1.2 and a white-balance change.
    cur = [np.clip(im * 1.2 * WHITE_BALANCE, 0, 1) for im in render(n_cur, albedo_cur, lights, rng)]
    return dict(ref=ref, cur=cur, pit=r_pit <= 8, stain=stain, n_ref=n_ref, n_cur=n_cur)


@pytest.mark.parametrize("seed", [0, 1])
def test_joint_uncalibrated_separates_relief_from_colour(seed):
    scene = pit_and_stain_scene(seed)
    ref, cur = joint_photometric_stereo(scene["ref"], scene["cur"])
    valid = np.ones(scene["pit"].shape, bool)
    relief, colour = relief_and_colour_cues(ref, cur, valid=valid)
    assert relief.dtype == np.float32 and colour.dtype == np.float32
    pit, stain = scene["pit"], scene["stain"]
    elsewhere = ~(pit | stain)

    # Relief: the pit's true normal change (mean ~0.35-0.4 rad) is recovered, stands far above
    # the noise elsewhere (median ~0.01 rad), and the stain does not look like relief (its darker
    # albedo only raises the noise, by 1 / 0.6).
    true_angle = np.arccos(np.clip(np.sum(scene["n_ref"] * scene["n_cur"], axis=2), -1, 1))
    assert 0.7 < relief[pit].mean() / true_angle[pit].mean() < 1.3
    assert relief[pit].mean() > 5 * np.percentile(relief[elsewhere], 99)
    assert np.median(relief[stain]) < 3 * np.median(relief[elsewhere])

    # Colour: the stain gives 3 x |ln 0.6| = 1.53 less the eps damping (<= 20 %); the pit and the
    # unchanged surface stay low: exposure and white balance are absorbed.
    expected = 3 * abs(np.log(0.6))
    assert 0.8 * expected < np.median(colour[stain]) < 1.05 * expected
    assert np.median(colour[pit]) < 0.2 * np.median(colour[stain])
    assert np.median(colour[elsewhere]) < 0.05 * np.median(colour[stain])
    # The basis alignment absorbed the exposure (grey); the white balance stays in the albedo
    # (the colour cue's per-channel gain removes it).
    ratio = np.median(cur.albedo[elsewhere] / ref.albedo[elsewhere], axis=0)
    np.testing.assert_allclose(ratio, WHITE_BALANCE, rtol=0.02)
    # Both fits share one frame: unchanged normals agree to a fraction of a degree.
    assert np.degrees(np.median(relief[elsewhere])) < 1.0


def test_joint_separate_factorizations_are_aligned():
    """same_lights=False: each stack has its own 3x3 ambiguity; the robust alignment removes it."""
    scene = pit_and_stain_scene(5, size=192)
    ref, cur = joint_photometric_stereo(scene["ref"], scene["cur"], config=JointFitConfig(same_lights=False))
    relief, _ = relief_and_colour_cues(ref, cur, valid=np.ones(scene["pit"].shape, bool))
    elsewhere = ~(scene["pit"] | scene["stain"])
    assert np.degrees(np.median(relief[elsewhere])) < 1.5
    assert relief[scene["pit"]].mean() > 5 * np.percentile(relief[elsewhere], 99)


def test_colour_cue_gain_without_basis_alignment():
    """align=False: the exposure stays in the current albedo; the cue's robust gain removes it."""
    scene = pit_and_stain_scene(7, size=192)
    ref, cur = joint_photometric_stereo(scene["ref"], scene["cur"], config=JointFitConfig(align=False))
    ratio = np.median(cur.albedo / np.maximum(ref.albedo, 1e-6), axis=(0, 1))
    np.testing.assert_allclose(ratio, 1.2 * WHITE_BALANCE, rtol=0.03)
    _, colour = relief_and_colour_cues(ref, cur, valid=np.ones(scene["pit"].shape, bool))
    elsewhere = ~(scene["pit"] | scene["stain"])
    assert np.median(colour[elsewhere]) < 0.05 * np.median(colour[scene["stain"]])


def test_cues_are_zero_outside_valid():
    scene = pit_and_stain_scene(6, size=128)
    ref, cur = joint_photometric_stereo(scene["ref"], scene["cur"])
    valid = np.zeros(scene["pit"].shape, bool)
    valid[:, :64] = True
    relief, colour = relief_and_colour_cues(ref, cur, valid=valid)
    assert not relief[:, 64:].any() and not colour[:, 64:].any()
    assert relief[:, :64].any() and colour[:, :64].any()


def test_invalid_inputs_are_reported():
    images = [np.full((20, 20), 0.5, np.float32)] * 3
    with pytest.raises(UserInputError, match="3 directional"):
        photometric_stereo(images)  # image 0 is ambient: only 2 directional lightings
    with pytest.raises(UserInputError, match="light_dirs"):
        photometric_stereo(images, ambient_index=None, light_dirs=np.eye(2))
    with pytest.raises(UserInputError, match="same size|shape"):
        photometric_stereo(images[:2] + [np.zeros((10, 10), np.float32)], ambient_index=None)


# --------------------------------------------------------------------------- real data


@pytest.mark.skipif(not GROUP.is_dir(), reason=f"real FGCD dataset not found at {GROUP.resolve()}")
def test_real_group_db1_fits_seven_lightings():
    images = [cv2.imread(str(GROUP / f"2-{k}.png"))[:, :, ::-1] for k in range(1, 8)]
    mask = cv2.imread(str(GROUP / "mask.png"), cv2.IMREAD_GRAYSCALE) > 127
    result = photometric_stereo(images, valid=mask)
    assert result.used.tolist() == [False] + [True] * 6
    known = np.isfinite(result.normals[:, :, 0])
    assert not known[~mask].any()
    # Orange and brown paints clip the red channel under most lamps: the grey of those pixels is
    # taken from the unclipped channels, so almost every pixel keeps a normal.
    assert known[mask].mean() > 0.9
    # Matte painted plaster, 8-bit images: read noise and quantisation are ~1 % of the level and
    # the lamps are near; a rank-3 Lambertian fit that is right explains the stack to a few
    # percent (2 % measured). Wrong lights leave 11-18 % (a guessed ring of six lamps at 45 degrees
    # given as calibration, in the images' order or shuffled).
    assert np.nanmedian(result.residual[mask]) < 0.05
    # The pseudo-normals face the camera (the plate is flat): median tilt well below 30 degrees.
    tilt = np.degrees(np.arccos(-result.normals[:, :, 2][known]))
    assert np.median(tilt) < 20.0
