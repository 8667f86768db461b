"""ICCV 2015 baseline (Feng et al.): normal-aware lighting correction + low-rank/sparse separation.

Synthetic Lambertian scene: a smooth relief with an albedo texture, rendered
under one ambient and six directional lights (camera frame: x right, y down,
z away from the camera, frontal normal (0, 0, -1)).
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fgcd_cli.changes.baseline_iccv import ICCV2015Config, iccv2015_details, iccv2015_score
from fgcd_cli.errors import UserInputError
from fgcd_cli.metrics.change_scores import sweep_scores

SIZE = 128
STAIN_CENTRE, STAIN_RADIUS = (40, 44), 11  # (x, y), px
PIT_CENTRE, PIT_SIGMA = (88, 80), 6.0  # (x, y), px; Gaussian pit
PIT_DEPTH = 6.0  # px: slopes up to ~0.6, i.e. normals tilted by up to ~30 degrees
TRUTH_ANGLE_DEG = 5.0  # the pit's changed pixels: normal turned by more than this
AMBIENT = 0.15


def _lights(tilt_deg: float = 40.0, azimuth_offset_deg: float = 0.0) -> np.ndarray:
    """Six unit directions towards the lights (rows), on the camera side (l_z < 0)."""
    azimuths = np.deg2rad(np.arange(6) * 60.0 + 15.0 + azimuth_offset_deg)
    tilt = np.deg2rad(tilt_deg)
    return np.stack(
        [np.sin(tilt) * np.cos(azimuths), np.sin(tilt) * np.sin(azimuths), -np.cos(tilt) * np.ones(6)], axis=1
    )


def _height(pit: bool) -> np.ndarray:
    ys, xs = np.mgrid[0:SIZE, 0:SIZE].astype(np.float64)
    h = 6.0 * np.sin(xs / 17.0) * np.cos(ys / 23.0) + 4.0 * np.exp(-((xs - 60) ** 2 + (ys - 100) ** 2) / 600.0)
    if pit:
        h -= PIT_DEPTH * np.exp(-((xs - PIT_CENTRE[0]) ** 2 + (ys - PIT_CENTRE[1]) ** 2) / (2 * PIT_SIGMA**2))
    return h


def _normals(height: np.ndarray) -> np.ndarray:
    """Unit normals of the surface z = -height (height towards the camera)."""
    hy, hx = np.gradient(height)
    n = np.stack([-hx, -hy, -np.ones_like(height)], axis=2)
    return n / np.linalg.norm(n, axis=2, keepdims=True)


def _albedo(seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    noise = cv2.GaussianBlur(rng.random((SIZE, SIZE)).astype(np.float32), (0, 0), 2.0)
    noise = (noise - noise.min()) / (noise.max() - noise.min())
    return (0.35 + 0.5 * noise).astype(np.float64)


def _render(albedo, normals, lights, gains, ambient_gain, noise_seed):
    """[ambient, directional x6] images, float32 in [0, 1], with read noise (sigma 0.003)."""
    rng = np.random.default_rng(noise_seed)
    images = [albedo * AMBIENT * ambient_gain]
    for light, gain in zip(lights, gains):
        shading = np.maximum(normals @ light, 0.0)
        images.append(albedo * (AMBIENT * ambient_gain + 0.75 * gain * shading))
    return [np.clip(im + rng.normal(0, 0.003, im.shape), 0, 1).astype(np.float32) for im in images]


def _truths():
    ys, xs = np.mgrid[0:SIZE, 0:SIZE]
    stain = (xs - STAIN_CENTRE[0]) ** 2 + (ys - STAIN_CENTRE[1]) ** 2 <= STAIN_RADIUS**2
    n0, n1 = _normals(_height(False)), _normals(_height(True))
    angle = np.degrees(np.arccos(np.clip(np.sum(n0 * n1, axis=2), -1, 1)))
    return stain, angle > TRUTH_ANGLE_DEG


# Current observation: everything 20 % darker, and each light's own gain off by up to +-15 %.
CURRENT_GAINS = 0.8 * np.array([0.9, 1.15, 1.0, 0.85, 1.1, 0.95])
CURRENT_AMBIENT = 0.7


@pytest.fixture(scope="module")
def scene():
    albedo = _albedo()
    stain, pit = _truths()
    lights = _lights()
    ref = _render(albedo, _normals(_height(False)), lights, np.ones(6), 1.0, noise_seed=1)
    stained = np.where(stain, albedo * 0.7, albedo)  # a 30 % darker stain
    cur = _render(stained, _normals(_height(True)), lights, CURRENT_GAINS, CURRENT_AMBIENT, noise_seed=2)
    unchanged = _render(albedo, _normals(_height(False)), lights, CURRENT_GAINS, CURRENT_AMBIENT, noise_seed=3)
    valid = np.ones((SIZE, SIZE), bool)
    return dict(ref=ref, cur=cur, unchanged=unchanged, stain=stain, pit=pit, valid=valid, lights=lights)


def test_finds_stain_and_pit(scene):
    score = iccv2015_score(scene["ref"], scene["cur"], valid=scene["valid"])
    assert score.shape == (SIZE, SIZE) and score.dtype == np.float32
    truth = scene["stain"] | scene["pit"]
    sweep = sweep_scores(score, truth)
    # The 2 px smoothing blurs a ~1 px band on either side of each change's edge (stain radius
    # 11 px, pit truth radius ~8 px): up to ~20 % of the changed area is ambiguous, so F1 > 0.8.
    assert sweep.best_f1 > 0.8, sweep
    assert sweep.average_precision > 0.8, sweep
    # Each change on its own is found: its median score is above the best threshold.
    for name in ("stain", "pit"):
        assert np.median(score[scene[name]]) > sweep.best_threshold, name


def test_unchanged_pair_under_lighting_change_stays_low(scene):
    changed = iccv2015_score(scene["ref"], scene["cur"], valid=scene["valid"])
    quiet = iccv2015_score(scene["ref"], scene["unchanged"], valid=scene["valid"])
    inside = np.median(changed[scene["stain"] | scene["pit"]])
    assert np.percentile(quiet, 99.9) < 0.3 * inside, (np.percentile(quiet, 99.9), inside)


def _moved_lights():
    """Current lights turned by 10 degrees in azimuth and 5 in tilt, with the gains of CURRENT_GAINS."""
    return _lights(45.0, 10.0)


def test_unchanged_pair_under_moved_lights_stays_low(scene):
    # The current/reference ratio of each lighting now depends on the normal.
    moved = _render(_albedo(), _normals(_height(False)), _moved_lights(), CURRENT_GAINS, CURRENT_AMBIENT, noise_seed=4)
    changed = iccv2015_score(scene["ref"], scene["cur"], valid=scene["valid"])
    quiet = iccv2015_score(scene["ref"], moved, valid=scene["valid"])
    inside = np.median(changed[scene["stain"] | scene["pit"]])
    assert np.percentile(quiet, 99.9) < 0.3 * inside, (np.percentile(quiet, 99.9), inside)


def test_normal_groups_follow_the_normal_dependent_ratio(scene):
    # Under moved lights the true log ratio of an unchanged pixel is a function of its normal.
    # Each normal group's gain must match the median true ratio of its pixels, and the grouped
    # correction must explain clearly more of the per-pixel ratio than one gain per lighting.
    normals = _normals(_height(False))
    moved = _render(_albedo(), normals, _moved_lights(), CURRENT_GAINS, CURRENT_AMBIENT, noise_seed=4)
    details = iccv2015_details(scene["ref"], moved, valid=scene["valid"], config=ICCV2015Config(spatial_sigma_px=None))
    groups = details.normal_groups
    big = [g for g in range(16) if np.count_nonzero(groups == g) > 300]
    assert len(big) >= 8
    for k in range(1, 7):
        cur = AMBIENT * CURRENT_AMBIENT + 0.75 * CURRENT_GAINS[k - 1] * np.maximum(normals @ _moved_lights()[k - 1], 0)
        ref = AMBIENT + 0.75 * np.maximum(normals @ _lights()[k - 1], 0)
        true = np.log(cur / ref)
        per_group = np.array([np.median(true[groups == g]) for g in big])
        assert np.ptp(per_group) > 0.06, k  # the ratio does vary with the normal
        assert np.abs(per_group - details.group_log_gains[k, big]).max() < 0.03, k
        grouped = np.mean(np.abs(true - details.group_log_gains[k][groups]))
        single = np.mean(np.abs(true - np.median(true)))
        assert grouped < 0.7 * single, (k, grouped, single)


def test_group_gains_recover_the_light_gains(scene):
    # Same light directions, other intensities: every normal group of lighting k should get the
    # log of the current/reference intensity ratio (ambient included in the directional images).
    details = iccv2015_details(
        scene["ref"], scene["unchanged"], valid=scene["valid"], config=ICCV2015Config(spatial_sigma_px=None)
    )
    groups = details.normal_groups
    assert groups.min() >= 0 and groups.max() <= 16
    big = [g for g in range(16) if np.count_nonzero(groups == g) > 500]
    assert len(big) >= 4
    ambient_gain = np.log(CURRENT_AMBIENT)
    assert abs(details.group_log_gains[0, big] - ambient_gain).max() < 0.03
    # A directional image mixes ambient and direct light: its ratio lies between the two gains.
    for k in range(1, 7):
        lo = min(np.log(CURRENT_GAINS[k - 1]), ambient_gain) - 0.03
        hi = max(np.log(CURRENT_GAINS[k - 1]), ambient_gain) + 0.03
        assert np.all((details.group_log_gains[k, big] > lo) & (details.group_log_gains[k, big] < hi)), k


def test_valid_mask_and_grey_input(scene):
    valid = scene["valid"].copy()
    valid[:, :20] = False
    grey_ref = [im for im in scene["ref"]]
    colour_cur = [np.repeat(im[:, :, None], 3, axis=2) for im in scene["cur"]]
    score = iccv2015_score(grey_ref, colour_cur, valid=valid)
    assert np.all(score[~valid] == 0)
    assert np.all(np.isfinite(score)) and score.min() >= 0


def test_rejects_bad_input(scene):
    with pytest.raises(UserInputError):
        iccv2015_score(scene["ref"], scene["cur"][:-1], valid=scene["valid"])
    with pytest.raises(UserInputError):
        iccv2015_score(scene["ref"], scene["cur"], valid=scene["valid"][:-1])
    with pytest.raises(UserInputError):
        iccv2015_score(scene["ref"], scene["cur"], valid=scene["valid"], config=ICCV2015Config(rank=0))
