"""Bilinear sampling (core/sampling.py): exact on planes, its derivative is the interpolant's."""

import numpy as np
import pytest

from marker_localizer.core.sampling import (
    bilinear,
    bilinear_with_gradient,
    nearest_pixels,
    pad_patterns,
    pixels_at_offsets,
    square_offsets,
)

#: Step of the central differences, px: far below a pixel, so both sides lie in
#: one bilinear cell (where the interpolant is smooth), far above float64 rounding.
STEP_PX = 1e-6


def plane(a: float, b: float, c: float, shape=(12, 16)) -> np.ndarray:
    """The image a * x + b * y + c, (0, 0) at the centre of the top-left pixel."""
    y, x = np.mgrid[: shape[0], : shape[1]].astype(np.float64)
    return a * x + b * y + c


def random_positions(rng, n, shape, margin=0.0):
    """(x, y) inside the image, off the pixel grid lines (not at integers)."""
    x = rng.uniform(margin, shape[1] - 1 - margin, n)
    y = rng.uniform(margin, shape[0] - 1 - margin, n)
    return x, y


def test_bilinear_sampling_of_a_plane_is_the_plane_and_its_gradient_is_the_slope():
    image = plane(0.75, -2.5, 40.0)
    x, y = random_positions(np.random.default_rng(0), 200, image.shape)
    values, d_dx, d_dy, valid = bilinear_with_gradient(image, x, y)
    assert valid.all()
    np.testing.assert_allclose(values, 0.75 * x - 2.5 * y + 40.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(d_dx, 0.75, rtol=0, atol=1e-12)
    np.testing.assert_allclose(d_dy, -2.5, rtol=0, atol=1e-12)


def test_samples_at_pixel_centres_are_the_pixels_whatever_the_dtype():
    rng = np.random.default_rng(1)
    for dtype in (np.uint8, np.uint16, np.float32):
        image = (rng.uniform(0, 200, (6, 7))).astype(dtype)
        y, x = np.mgrid[:5, :6].astype(np.float64)  # the last row and column need a neighbour
        values, valid = bilinear(image, x, y)
        assert valid.all()
        np.testing.assert_array_equal(values, image[:5, :6].astype(np.float64))


def test_differences_of_unsigned_pixels_do_not_wrap_around():
    image = np.array([[200, 10], [10, 200]], np.uint8)
    values, d_dx, d_dy, _ = bilinear_with_gradient(image, np.array([0.25]), np.array([0.0]))
    assert values[0] == pytest.approx(200 - 0.25 * 190)
    assert d_dx[0] == pytest.approx(-190.0)
    assert d_dy[0] == pytest.approx(-190.0 * 0.75 + 190.0 * 0.25)  # down the left, the right


def test_the_gradient_equals_central_differences_of_the_samples_on_a_random_image():
    rng = np.random.default_rng(2)
    image = rng.uniform(0.0, 255.0, (20, 24))
    x, y = random_positions(rng, 500, image.shape, margin=0.01)
    # Keep both sides of each difference inside one cell: away from integer positions.
    inside = (np.abs(x - np.round(x)) > 10 * STEP_PX) & (np.abs(y - np.round(y)) > 10 * STEP_PX)
    x, y = x[inside], y[inside]
    _, d_dx, d_dy, _ = bilinear_with_gradient(image, x, y)
    right, _ = bilinear(image, x + STEP_PX, y)
    left, _ = bilinear(image, x - STEP_PX, y)
    below, _ = bilinear(image, x, y + STEP_PX)
    above, _ = bilinear(image, x, y - STEP_PX)
    np.testing.assert_allclose(d_dx, (right - left) / (2 * STEP_PX), rtol=0, atol=1e-6)
    np.testing.assert_allclose(d_dy, (below - above) / (2 * STEP_PX), rtol=0, atol=1e-6)


def test_the_value_with_the_gradient_is_the_plain_bilinear_sample():
    rng = np.random.default_rng(3)
    image = rng.uniform(0.0, 1.0, (9, 11)).astype(np.float32)
    x, y = random_positions(rng, 100, image.shape)
    plain, plain_valid = bilinear(image, x, y)
    values, _, _, valid = bilinear_with_gradient(image, x, y)
    np.testing.assert_array_equal(values, plain)
    np.testing.assert_array_equal(valid, plain_valid)


@pytest.mark.parametrize(("x", "y"), [(-0.01, 3.0), (3.0, -0.5), (15.0, 3.0), (3.0, 11.5)])
def test_a_sample_that_needs_a_pixel_outside_the_image_is_marked_invalid(x, y):
    image = plane(1.0, 1.0, 0.0)  # 12 rows, 16 columns
    _, valid = bilinear(image, np.array([x]), np.array([y]))
    assert not valid[0]


@pytest.mark.parametrize("shape", [(1, 5), (5, 1), (1, 1)], ids=lambda s: f"{s[0]}x{s[1]}")
def test_an_image_of_one_row_or_one_column_is_read_as_its_edge_repeated_and_no_sample_is_valid(
    shape,
):
    # A bilinear cell is 2 x 2: along the side of one pixel the row or column is
    # repeated, as the clamp reads the border, and along the other it is interpolated.
    image = plane(10.0, 20.0, 1.0, shape).astype(np.uint8)
    x, y = np.array([0.0, 0.5, 3.25, 0.0]), np.array([0.0, 0.0, 0.5, 2.75])
    values, _, _, valid = bilinear_with_gradient(image, x, y)
    inside_x, inside_y = np.minimum(x, shape[1] - 1), np.minimum(y, shape[0] - 1)
    np.testing.assert_allclose(values, 10.0 * inside_x + 20.0 * inside_y + 1.0)
    assert not valid.any()
    assert bilinear(image, x, y)[0] == pytest.approx(values)
    assert not bilinear(image, np.float64(0.0), np.float64(0.0))[1]


def test_samples_keep_the_shape_of_the_positions():
    image = plane(1.0, 2.0, 3.0)
    x = np.full((3, 4, 2), 2.5)
    values, valid = bilinear(image, x, x + 1.0)
    assert values.shape == valid.shape == (3, 4, 2)
    np.testing.assert_allclose(values, 2.5 + 2 * 3.5 + 3.0)


def test_patterns_of_different_lengths_are_zero_padded_with_a_mask_of_the_real_entries():
    stack, present = pad_patterns([np.ones((2, 2)), np.full((3, 2), 2.0)])
    assert stack.shape == (2, 3, 2)
    np.testing.assert_array_equal(present, [[True, True, False], [True, True, True]])
    np.testing.assert_array_equal(stack[0, 2], [0.0, 0.0])
    np.testing.assert_array_equal(stack[1], np.full((3, 2), 2.0))


def test_the_nearest_pixel_is_the_rounded_position_clamped_to_the_image():
    image = np.arange(12, dtype=np.uint16).reshape(3, 4)
    xy = np.array([[1.4, 0.6], [2.6, 1.2], [-3.0, 9.0]])
    np.testing.assert_array_equal(
        nearest_pixels(image, xy), [image[1, 1], image[1, 3], image[2, 0]]
    )


def test_pixels_at_offsets_reads_each_rounded_centres_window_with_its_channels():
    image = np.arange(5 * 6 * 3, dtype=np.uint8).reshape(5, 6, 3)
    offsets = np.array([[0, 0], [1, 0], [0, -1]])
    values, inside = pixels_at_offsets(image, np.array([[2.4, 2.6], [5.0, 0.0]]), offsets)
    assert values.dtype == np.float64 and values.shape == (2, 3, 3)
    np.testing.assert_array_equal(values[0], image[[3, 3, 2], [2, 3, 2]])
    assert inside.tolist() == [True, False]  # the second window leaves the image: clamped
    np.testing.assert_array_equal(values[1], image[[0, 0, 0], [5, 5, 5]])


def test_pixels_at_square_offsets_reshape_to_the_window_around_the_centre():
    image = np.arange(7 * 9, dtype=np.uint8).reshape(7, 9)
    values, inside = pixels_at_offsets(image, np.array([[4.2, 2.8]]), square_offsets(2))
    assert inside.tolist() == [True]
    np.testing.assert_array_equal(values.reshape(5, 5), image[1:6, 2:7])
