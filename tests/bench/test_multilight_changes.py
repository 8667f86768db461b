"""The multi-light part of ``fgcd bench changes``: the revisit it simulates is the one it states."""

import math

import cv2
import numpy as np
import pytest

from fgcd_cli.bench.changes.multilight import (
    GAIN_RANGE,
    MOTION_DEG,
    MOTION_PX,
    InjectedChange,
    change_truth,
    revisit_images,
    sensor_noise_dn,
)


def _blob_image(shape=(240, 320), centre=(150.3, 110.7), level=200.0) -> np.ndarray:
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]].astype(float)
    blob = level * np.exp(-((xx - centre[0]) ** 2 + (yy - centre[1]) ** 2) / (2 * 8.0**2))
    return np.repeat(blob[:, :, None], 3, axis=2).round().astype(np.uint8)


def _centroid(image: np.ndarray) -> np.ndarray:
    g = image[:, :, 0].astype(float)
    g = np.where(g > 20, g, 0.0)  # above the noise
    yy, xx = np.mgrid[0 : g.shape[0], 0 : g.shape[1]]
    return np.array([(g * xx).sum(), (g * yy).sum()]) / g.sum()


def test_every_lighting_moves_alike_by_the_stated_residual_with_its_own_gain():
    reference = [_blob_image(), _blob_image(level=120.0), _blob_image(level=240.0)]
    current = revisit_images(reference, rng=np.random.default_rng(4))
    moves = np.array([_centroid(c) - _centroid(r) for r, c in zip(reference, current)])
    # One rigid motion for the stack: MOTION_PX plus the turn's displacement at the blob
    # (0.1 deg at ~30 px from the centre is 0.05 px); the centroid of a noisy blob is good to ~0.05 px.
    turn_px = math.radians(MOTION_DEG) * math.hypot(150.3 - 159.5, 110.7 - 119.5)
    assert np.allclose(moves, moves.mean(axis=0), atol=0.05)
    assert abs(np.linalg.norm(moves.mean(axis=0)) - MOTION_PX) < turn_px + 0.05
    # on the blob's core (the motion barely changes it; the dark background's clipped noise would bias a sum)
    core = [r[:, :, 0] > 0.5 * r.max() for r in reference]
    gains = [c[m, 0].astype(float).mean() / r[m, 0].astype(float).mean() for r, c, m in zip(reference, current, core)]
    assert all(GAIN_RANGE[0] - 0.02 < g < GAIN_RANGE[1] + 0.02 for g in gains)
    assert len({round(g, 3) for g in gains}) == 3  # drawn per lighting


def test_noise_follows_the_stated_model():
    flat = [np.full((200, 200, 3), 128, np.uint8)]
    current = revisit_images(flat, rng=np.random.default_rng(1))[0].astype(float)
    # the gain moves the level; the spread about it is the model's at that level (plus rounding's 1/12)
    level = current.mean()
    assert current.std() == pytest.approx(math.sqrt(sensor_noise_dn(level) ** 2 + 1 / 12), rel=0.05)


def test_painted_changes_scale_the_light_by_their_factor_where_the_truth_says():
    reference = [np.full((120, 160, 3), 100, np.uint8)]
    stain = InjectedChange("stain", (60.0, 50.0), 9.0, (0.5, 0.5, 0.5))
    truth = change_truth((120, 160), [stain])
    assert truth.sum() == pytest.approx(math.pi * 9.0**2, rel=0.05)
    current = revisit_images(reference, rng=np.random.default_rng(2), changes=[stain])[0][:, :, 0].astype(float)
    inner = cv2.erode(truth.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    outer = ~(cv2.dilate(truth.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0)
    assert current[inner].mean() / current[outer].mean() == pytest.approx(0.5, abs=0.02)
