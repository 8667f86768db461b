"""Texture lookups against synthetic truth: a mip level keeps detail where the surface carries it."""

import numpy as np
import pytest

from fgcd_drivers.sim.texture_sampling import mip_pyramid, sample_mipmapped

SIZE = 256
BLOB_XY = (100.3, 60.7)  # texels, off every level's grid
BLOB_SIGMA = 6.0  # texels: still a blob at level 3 (8 texels per level-3 texel)


def _blob_texture(shape=(SIZE, SIZE)) -> np.ndarray:
    y, x = np.mgrid[0 : shape[0], 0 : shape[1]] + 0.5  # texel centres
    blob = np.exp(-((x - BLOB_XY[0]) ** 2 + (y - BLOB_XY[1]) ** 2) / (2 * BLOB_SIGMA**2))
    return np.repeat(blob[:, :, None], 3, axis=2).astype(np.float32)


@pytest.mark.parametrize("shape", [(SIZE, SIZE), (SIZE - 1, SIZE + 3)])
@pytest.mark.parametrize("level", [0.0, 1.0, 2.0, 2.5, 3.0])
def test_a_blob_stays_where_it_is_at_every_level(shape, level):
    pyramid = mip_pyramid(_blob_texture(shape))
    # sample twice as densely as level 0, so the centroid is the texture's, not the sampling's
    v, u = np.mgrid[0 : 2 * shape[0], 0 : 2 * shape[1]]
    uv = np.column_stack([(u.ravel() + 0.5) / (2 * shape[1]), (v.ravel() + 0.5) / (2 * shape[0])]).astype(np.float32)
    value = sample_mipmapped(pyramid, uv, np.full(len(uv), level, np.float32))[:, 0]
    centroid = (value / value.sum()) @ (uv * np.array([shape[1], shape[0]]))
    # A level that slid would move the blob by (2^k - 1) / 2 texels (0.5 at level 1, 3.5 at level 3);
    # odd sizes resize by a ratio a hair off 2, which moves a blob 100 texels in by under 0.5 texel at level 3.
    tolerance = 0.01 if shape == (SIZE, SIZE) else 0.5
    assert np.allclose(centroid, BLOB_XY, atol=tolerance)


def test_levels_halve_down_to_four_texels_and_keep_the_mean():
    texture = np.random.default_rng(0).random((64, 48, 3)).astype(np.float32)
    pyramid = mip_pyramid(texture)
    assert [p.shape[:2] for p in pyramid] == [(64, 48), (32, 24), (16, 12), (8, 6), (4, 3)]
    for level in pyramid:
        assert level.mean() == pytest.approx(texture.mean(), rel=1e-4)
