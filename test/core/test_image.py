"""Input normalisation (core/image.py): one channel in its own dtype, white from the bit depth."""

import re

import cv2
import numpy as np
import pytest

from marker_localizer import Detector, DetectorConfig
from marker_localizer.core.image import (
    FLOAT_OVERSHOOT,
    bayer_to_grey,
    bit_depth_hint,
    bit_depth_scale,
    peak_level,
    to_gray,
    underexposed,
)
from marker_localizer.errors import ImageError
from marker_localizer.synthetic.scene import RAW_BAYER_GAINS, bayer_gain


def _x_marker_12_bit(dark: float = 30.0, bright: float = 200.0) -> np.ndarray:
    """The Detector docstring's X (centre (31.5, 31.5)) as a 12-bit sensor writes it.

    ``dark`` and ``bright`` are its quadrants' levels in 8-bit grey levels.
    """
    image = np.full((64, 64), bright, np.float32)
    image[:32, :32] = image[32:, 32:] = dark
    return (cv2.GaussianBlur(image, (0, 0), 1.0) * 16).round().astype(np.uint16)


@pytest.mark.parametrize(
    ("dtype", "bits", "white"),
    [
        (np.uint8, 16, 255.0),
        (np.uint8, 12, 255.0),
        (np.uint16, 16, 65535.0),
        (np.uint16, 12, 4095.0),
        (np.uint16, 10, 1023.0),
    ],
)
def test_white_is_set_by_the_type_and_the_bit_depth(dtype, bits, white):
    assert bit_depth_scale(np.dtype(dtype), bits) == white


def test_the_full_scale_of_one_camera_does_not_move_with_the_frame_content():
    dim = np.full((8, 8), 100, np.uint16)
    hot = dim.copy()
    hot[0, 0] = 65535  # a hot pixel or a specular glint
    assert to_gray(dim, bit_depth=12)[1] == to_gray(hot, bit_depth=12)[1] == 4095.0


def test_a_12_bit_sensor_is_detected_when_the_detector_is_told_its_bit_depth():
    image = _x_marker_12_bit(dark=100.0, bright=140.0)
    told = Detector(DetectorConfig(bit_depth=12))
    (found,) = told.detect(image)
    assert (found.x, found.y) == (pytest.approx(31.5, abs=1e-3), pytest.approx(31.5, abs=1e-3))
    # The same frame with a saturated pixel far from the marker: same thresholds, same answer.
    glint = image.copy()
    glint[2, 60] = 65535
    assert len(told.detect(glint)) == 1
    # Read as 16-bit words, its 40-DN-of-255 contrast is 2.5 DN at a mean of 7.5 DN:
    # under min_contrast_dn even lowered as far as the shadow gain goes (4-fold).
    assert len(Detector(DetectorConfig(bit_depth=16)).detect(image)) == 0


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32, np.float64])
def test_a_grey_image_keeps_its_pixels_and_its_dtype_only_float64_becomes_float32(dtype):
    image = np.arange(12, dtype=dtype).reshape(3, 4) / (1 if np.dtype(dtype).kind == "u" else 20)
    image = image.astype(dtype)
    grey, full_scale = to_gray(image)
    assert grey.dtype == (np.float32 if np.dtype(dtype).kind == "f" else dtype)
    np.testing.assert_array_equal(grey, image.astype(grey.dtype))
    assert full_scale == {np.uint8: 255.0, np.uint16: 65535.0}.get(dtype, 1.0)


def test_colour_is_reduced_with_the_bt601_weights_and_rgb_swaps_the_channels():
    blue_first = np.zeros((2, 2, 3), np.uint8)
    blue_first[..., 0] = 200  # blue in BGR
    grey_bgr, _ = to_gray(blue_first)
    grey_rgb, _ = to_gray(blue_first, rgb=True)  # the same bytes read as red
    assert grey_bgr[0, 0] == round(0.114 * 200)
    assert grey_rgb[0, 0] == round(0.299 * 200)


def test_a_single_channel_axis_and_an_alpha_channel_are_accepted():
    assert to_gray(np.full((2, 3, 1), 7, np.uint8))[0].shape == (2, 3)
    bgra = np.zeros((2, 3, 4), np.uint8)
    bgra[..., 1] = 100  # green
    assert to_gray(bgra)[0][0, 0] == round(0.587 * 100)


def test_float_images_overshooting_0_1_a_little_are_clipped_to_it():
    grey, full_scale = to_gray(np.array([[-FLOAT_OVERSHOOT, 0.25], [1.0, 1.0 + FLOAT_OVERSHOOT]]))
    np.testing.assert_array_equal(grey, np.array([[0.0, 0.25], [1.0, 1.0]], np.float32))
    assert full_scale == 1.0


@pytest.mark.parametrize(
    ("levels", "advice"),
    [
        ((0.0, 255.0), "divide them by the camera's white level"),
        ((-1.0, 1.0), "shift and scale them into it"),
    ],
)
def test_float_images_of_another_scale_are_refused_not_clipped_to_a_blank_frame(levels, advice):
    image = np.array([levels], np.float32)
    with pytest.raises(ImageError, match=r"beyond \[0, 1\] \(white 1\): " + re.escape(advice)):
        to_gray(image)


@pytest.mark.parametrize(
    ("image", "message"),
    [
        ([[1, 2], [3, 4]], "expected a numpy array, got list"),
        (None, r"got None \(cv2.imread's answer to a file it cannot read\)"),
        (np.zeros((0, 4), np.uint8), r"empty image \(shape \(0, 4\)\)"),
        (np.zeros((4, 4), np.int32), "unsupported dtype int32"),
        (np.zeros((4, 4, 2), np.uint8), "unsupported channel count 2"),
        (np.zeros((2, 2, 2, 2), np.uint8), "expected a 2-D grey or 3-D colour image"),
        (np.array([[0.0, np.nan]]), "NaN or infinite"),
    ],
)
def test_bad_input_is_one_error_naming_what_is_wrong(image, message):
    with pytest.raises(ImageError, match=message):
        to_gray(image)


def test_a_big_endian_array_is_read_as_the_same_levels():
    levels = np.arange(12, dtype=np.uint16).reshape(3, 4) * 4000
    grey, white = to_gray(levels.astype(">u2"))
    assert grey.dtype.isnative and white == 65535.0
    np.testing.assert_array_equal(grey, levels)
    unit, _ = to_gray((levels / 65535.0).astype(">f4"))
    np.testing.assert_allclose(unit, levels / 65535.0, rtol=1e-6)


def test_16_bit_levels_above_white_at_the_bit_depth_are_refused_not_saturated():
    # A 12-bit sensor's bits left-aligned in 16-bit words: told 12 bits, every
    # threshold would read a saturated frame and find nothing.
    left_aligned = np.full((8, 8), 200 * 16, np.uint16) * 16
    refused = r"100% of the levels lie above white at bit_depth 12 \(4095\), up to 51200"
    with pytest.raises(ImageError, match=refused):
        to_gray(left_aligned, bit_depth=12)
    assert to_gray(left_aligned, bit_depth=16)[1] == 65535.0
    assert to_gray(left_aligned // 16, bit_depth=12)[1] == 4095.0


@pytest.mark.parametrize(
    ("peak", "bit_depth", "hint"),
    [
        (4095, 16, 12),  # a 12-bit sensor's words read as 16-bit
        (1023, 16, 10),
        (200, 16, 8),  # a dark frame: the fewest bits that hold it, 8 at least
        (4096, 16, None),  # 1/16 of white and more: a frame of the configured depth
        (4095, 12, None),
        (60000, 16, None),
    ],
)
def test_a_16_bit_frame_dimmer_than_a_16th_of_white_is_advised_the_depth_its_levels_fit(
    peak, bit_depth, hint
):
    assert bit_depth_hint(peak, bit_depth) == hint


@pytest.mark.parametrize(
    ("peak_share", "dim"),
    [(0.0, True), (0.49, True), (0.5, False), (0.73, False), (float("nan"), False)],
)
def test_a_frame_whose_brightest_level_stays_under_half_of_white_is_underexposed(peak_share, dim):
    assert underexposed(peak_share) == dim


def test_the_peak_level_is_read_on_every_fourth_row_and_column_of_every_colour_plane():
    image = np.zeros((9, 9, 3), np.uint16)
    image[4, 8, 2] = 4000
    image[5, 5, 0] = 60000  # between the rows read
    assert peak_level(image) == 4000.0


def test_an_opaque_alpha_plane_neither_hides_an_underexposed_frame_nor_lies_above_white():
    colour = np.zeros((9, 9, 3), np.uint16)
    colour[4, 4] = 1000  # a 12-bit sensor's dim frame
    with_alpha = np.dstack([colour, np.full((9, 9), 65535, np.uint16)])
    assert peak_level(with_alpha) == peak_level(colour) == 1000.0
    assert to_gray(with_alpha, bit_depth=12)[1] == 4095.0


def _bayer(grey: np.ndarray, pattern: str, gains=RAW_BAYER_GAINS) -> np.ndarray:
    """The mosaic a sensor of ``pattern`` ("rggb", ...) writes of an achromatic scene."""
    return (grey * bayer_gain(grey.shape, pattern, gains)).round().astype(grey.dtype)


@pytest.mark.parametrize("pattern", ["rggb", "bggr", "gbrg", "grbg"])
def test_a_bayer_mosaic_is_demosaiced_to_the_bt601_grey_of_its_colours(pattern):
    # A flat scene seen with unequal channel gains is a flat colour once demosaiced;
    # a pattern read in the wrong order would swap the red and blue weights.
    mosaic = _bayer(np.full((8, 10), 200, np.uint8), pattern)
    grey = bayer_to_grey(mosaic, pattern)
    red, green, blue = (200 * gain for gain in RAW_BAYER_GAINS)
    assert grey.dtype == np.uint8 and grey.shape == (8, 10)
    assert np.all(grey[2:-2, 2:-2] == round(0.299 * red + 0.587 * green + 0.114 * blue))


@pytest.mark.parametrize("pattern", ["rggb", "gbrg"])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("gains", [(1.0, 1.0, 1.0), RAW_BAYER_GAINS])
def test_a_marker_seen_through_a_bayer_mosaic_keeps_its_centre_to_three_hundredths_of_a_pixel(
    pattern, dtype, gains
):
    # The demosaicing weighs the channels differently at each pixel of the cell, so a
    # sharp X's centre moves, here by 0.004-0.021 px (docs/accuracy-journal.md, "A camera's
    # raw Bayer mosaic").
    scene = cv2.GaussianBlur(_x_marker_12_bit().astype(np.float32) / 16, (0, 0), 0.5)
    if dtype == np.uint16:
        scene *= 257
    mosaic = _bayer(scene.round().astype(dtype), pattern, gains)
    found = Detector(DetectorConfig()).detect(bayer_to_grey(mosaic, pattern))
    assert len(found) == 1
    assert np.hypot(found[0].x - 31.5, found[0].y - 31.5) < 0.03


def test_a_bayer_reading_refuses_what_is_not_one_mosaic_of_a_known_pattern():
    with pytest.raises(ImageError, match="one channel of 8- or 16-bit pixels, not 4x4x3 uint8"):
        bayer_to_grey(np.zeros((4, 4, 3), np.uint8), "rggb")
    with pytest.raises(ImageError, match="unknown Bayer pattern 'rgbg'"):
        bayer_to_grey(np.zeros((4, 4), np.uint8), "rgbg")
    for height, width in ((1, 1), (1, 200), (200, 1)):
        with pytest.raises(ImageError, match=f"at least one 2x2 cell, not {width}x{height}"):
            bayer_to_grey(np.full((height, width), 200, np.uint8), "rggb")
