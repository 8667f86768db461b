"""The detector's grey images: the unweighted channel mean, float32, never a view of the input."""

import numpy as np

from fgcd_cli.changes.images import to_gray
from fgcd_cli.changes.tiled.inputs import as_float, gray_mean


def test_grey_is_the_channel_mean_without_alpha_in_a_new_float32_array():
    colour = np.array([[[0.3, 0.6, 0.9], [0.0, 0.0, 0.75]]], np.float32)
    np.testing.assert_allclose(to_gray(colour), [[0.6, 0.25]], atol=1e-7)
    rgba = np.dstack([colour, np.full((1, 2), 0.1, np.float32)])
    assert np.array_equal(to_gray(rgba), to_gray(colour))  # the alpha channel does not enter the mean
    rng = np.random.default_rng(5)
    rgb64 = rng.random((64, 80, 3)) ** 1.3  # float64 colour: averaged after the cast to float32
    assert to_gray(rgb64).dtype == np.float32
    np.testing.assert_allclose(to_gray(rgb64), rgb64.mean(axis=2), rtol=0, atol=3 * 2.0**-23)
    for grey in (rgb64[:, :, 0].astype(np.float32), rgb64[:, :, 0]):
        out = to_gray(grey)
        assert out.dtype == np.float32 and np.array_equal(out, grey.astype(np.float32))
        assert not np.shares_memory(out, grey)


def test_the_tiled_path_takes_the_same_mean_of_its_8_bit_crops():
    u8 = np.array([[[30, 60, 90], [255, 0, 0]]], np.uint8)
    np.testing.assert_allclose(gray_mean(as_float(u8)), [[60 / 255, 85 / 255]], atol=1e-7)
    colour = as_float(u8)
    np.testing.assert_array_equal(gray_mean(colour), to_gray(colour))
    grey = as_float(u8[:, :, 0])
    assert gray_mean(grey) is grey  # grey crops pass as they are
