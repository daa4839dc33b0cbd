"""Section 3.1: GDWGIF, dynamic gamma and the structure map."""

import cv2
import numpy as np
import pytest

from marker_localizer import DetectorConfig
from marker_localizer.core import preprocessing

#: The detector's settings: the stages are specified as the detector runs them.
_DEFAULTS = DetectorConfig()


def _local_gamma(image: np.ndarray) -> preprocessing.LocalGamma:
    """Eq. (2) at the detector's alpha and window, on an 8-bit frame."""
    return preprocessing.LocalGamma(
        image, 255.0, _DEFAULTS.gamma_alpha, _DEFAULTS.illumination_window_px
    )


def _noisy_step(noise: float = 0.03, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    clean = np.full((80, 80), 0.2, np.float32)
    clean[:, 40:] = 0.8
    noisy = clean + np.random.default_rng(seed).normal(0, noise, clean.shape).astype(np.float32)
    return clean, noisy


def test_gdwgif_smooths_flat_noise_and_keeps_the_edge():
    _clean, noisy = _noisy_step()
    filtered = preprocessing.gdwgif(noisy, radius_px=2, regularisation=0.01)
    flat = np.s_[10:70, 5:30]
    assert filtered[flat].std() < 0.5 * noisy[flat].std()
    # The step keeps at least 90 % of its height across two pixels.
    step = filtered[10:70, 41].mean() - filtered[10:70, 38].mean()
    assert step > 0.9 * 0.6


def test_gdwgif_returns_float32_of_the_input_shape():
    _, noisy = _noisy_step()
    out = preprocessing.gdwgif(noisy, _DEFAULTS.gdwgif_radius_px, _DEFAULTS.gdwgif_lambda)
    assert out.shape == noisy.shape and out.dtype == np.float32


def test_dynamic_gamma_leaves_mid_grey_alone_and_brightens_dark_surroundings():
    mid = np.full((40, 40), 0.5, np.float32)
    np.testing.assert_allclose(
        preprocessing.dynamic_gamma(mid, alpha=2.0, window_px=9), 0.5, rtol=1e-5
    )
    dark = np.full((40, 40), 0.2, np.float32)
    assert (preprocessing.dynamic_gamma(dark, alpha=2.0, window_px=9) > 0.2).all()
    bright = np.full((40, 40), 0.8, np.float32)
    assert (preprocessing.dynamic_gamma(bright, alpha=2.0, window_px=9) < 0.8).all()


def test_eq_2_stretches_a_dark_surround_no_further_than_a_square_root():
    """The power that evens shot noise; a stronger one magnifies the dark paint's noise.

    Ground at 4 % of white asks Eq. (2) for a gamma of 0.08; the frame and the
    samples the checks read both get the square root.
    """
    dark = np.full((40, 40), 0.04, np.float32)
    np.testing.assert_allclose(
        preprocessing.dynamic_gamma(dark, alpha=2.0, window_px=9), 0.2, rtol=1e-5
    )
    image = np.full((200, 200), 0.04 * 255.0, np.float32)
    samples = np.array([[0.0, 0.04 * 255.0, 0.16 * 255.0]])
    read = _local_gamma(image)(samples, np.array([[100.0, 100.0]]))
    np.testing.assert_allclose(read, np.sqrt(samples / 255.0).clip(1e-3), rtol=1e-4)


def test_structure_map_follows_eq_3_for_a_known_local_std():
    # Alternating rows of 0 and 1: every 3x3 window holds 3 or 6 ones, std sqrt(2)/3.
    image = np.zeros((30, 30), np.float32)
    image[::2] = 1.0
    xi, t = 0.3, 1.5
    expected = 1.0 - np.exp(-(((np.sqrt(2.0) / 3.0) / xi) ** t))
    s = preprocessing.structure_map(image, diameters_px=(3,), xi=xi, t=t)
    np.testing.assert_allclose(s[5:-5, 5:-5], expected, rtol=1e-4)


def test_structure_map_is_zero_on_flat_ground():
    s = preprocessing.structure_map(
        np.full((20, 20), 0.4, np.float32), xi=_DEFAULTS.structure_xi, t=_DEFAULTS.structure_t
    )
    assert s.max() == pytest.approx(0.0, abs=1e-3)


def test_structure_components_at_points_equal_the_structure_map_of_eq_3():
    rng = np.random.default_rng(2)
    image = rng.random((60, 80)).astype(np.float32)
    image[20:40, 30:50] += 0.5
    full = preprocessing.structure_map(image, xi=0.05, t=1.3)
    sampled = preprocessing.StructureComponents(image, xi=0.05, t=1.3)
    rows, cols = np.mgrid[5:55, 5:75]
    xy = np.stack([cols.ravel(), rows.ravel()], axis=1).astype(float)
    np.testing.assert_allclose(sampled.at(xy), full[rows.ravel(), cols.ravel()], atol=1e-5)
    assert sampled.quantile(0.3) == pytest.approx(np.quantile(full[2::4, 2::4], 0.3), abs=0.02)


def test_noise_sigma_reads_the_pixel_noise_not_the_edges():
    rng = np.random.default_rng(4)
    image = np.zeros((200, 200), np.float32)
    image[:, 100:] = 1.0  # one strong edge
    image += rng.normal(0.0, 0.02, image.shape).astype(np.float32)
    assert preprocessing.noise_sigma(image) == pytest.approx(0.02, rel=0.1)


def test_the_darkest_mean_along_a_row_bounds_the_local_mean_at_every_point_of_it():
    rng = np.random.default_rng(3)
    ramp = np.linspace(10, 240, 640)[None, :] * np.linspace(0.2, 1.0, 480)[:, None]
    image = np.clip(ramp + rng.normal(0, 8, (480, 640)), 0, 255).astype(np.uint8)
    gamma = _local_gamma(image)
    xy = rng.uniform([0, 0], [640, 480], (2000, 2))
    bound = gamma.darkest_mean_on_rows(xy[:, 1])
    assert np.all(gamma.mean_at(xy) >= bound - 1e-6)
    # Tight: the darkest point of a row is near its bound.
    assert gamma.darkest_mean == pytest.approx(bound.min(), abs=0.02)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32])
@pytest.mark.parametrize(("factor", "extra"), [(2, 0), (3, 0), (8, 0), (8, 5), (16, 0), (17, 0)])
def test_area_reduced_is_opencvs_area_resize_bit_for_bit(dtype, factor, extra):
    rng = np.random.default_rng(factor + extra)
    shape = (factor * 7 + extra, factor * 9)
    if dtype is np.float32:
        image = rng.random(shape, np.float32)
    else:
        # Levels of a few steps: many blocks whose mean lies halfway between two levels.
        image = (rng.integers(0, 5, shape) * (np.iinfo(dtype).max // 4)).astype(dtype)
    size = (shape[1] // factor, shape[0] // factor)
    expected = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    reduced = preprocessing.area_reduced(image, size)
    assert reduced.dtype == expected.dtype
    np.testing.assert_array_equal(reduced, expected)


def test_the_darkest_mean_on_a_span_of_a_row_bounds_the_local_mean_there_tighter_than_the_row():
    rng = np.random.default_rng(4)
    # Light falling from left to right: every row holds a dark stretch.
    ramp = np.linspace(10, 240, 640)[None, :] * np.linspace(0.6, 1.0, 480)[:, None]
    image = np.clip(ramp + rng.normal(0, 8, (480, 640)), 0, 255).astype(np.uint8)
    gamma = _local_gamma(image)
    x_first = np.arange(-16.0, 640.0, 64.0)
    x_last = x_first + 63.0
    y = rng.uniform(-8, 488, 300)
    bound = gamma.darkest_mean_on_spans(y, x_first, x_last)
    assert bound.shape == (300, len(x_first))
    for span, (a, b) in enumerate(zip(x_first, x_last, strict=True)):
        xy = np.stack([rng.uniform(a, b, len(y)), y], axis=1)
        assert np.all(gamma.mean_at(xy) >= bound[:, span])
    row = gamma.darkest_mean_on_rows(y)
    assert np.all(bound >= row[:, None] - 1e-6)
    # A lit span's bound is far above the row's, whose darkest stretch is on the left
    # (the last span reaches out of the image, where the local mean is 0.5).
    inside = (y >= 0) & (y < 480)
    assert np.all(bound[inside, -2] - row[inside] > 0.4)


def test_the_contrast_floors_follow_the_light_down_by_webers_law_and_no_further_than_the_cap():
    shadowed = preprocessing.ShadowedContrast(min_contrast=20.0 / 255.0, min_modulation=0.3)
    # A marker of modulation 0.3 under a mean L has contrast 0.6 L: at L 1/3 of white
    # and brighter it clears the floor in the open; darker, the floor follows it.
    mean = np.array([0.5, 20.0 / 255.0 / 0.6, 0.05, 0.02, 0.001])
    gain = shadowed.gain(mean)
    assert gain[:2].tolist() == [1.0, 1.0]
    assert gain[2] == pytest.approx((20.0 / 255.0) / (0.6 * 0.05))
    assert gain[3:].tolist() == [preprocessing.MAX_SHADOW_GAIN] * 2


def test_the_shadow_gain_is_looked_up_only_where_the_surroundings_are_dark():
    image = np.full((300, 400), 200, np.uint8)
    shadowed = preprocessing.ShadowedContrast(min_contrast=20.0 / 255.0, min_modulation=0.3)
    xy = np.array([[50.0, 50.0], [350.0, 250.0]])
    assert shadowed.gain_at(_local_gamma(image), xy) is None
    image[:, 200:] = 8
    gain = shadowed.gain_at(_local_gamma(image), xy)
    assert gain is not None
    assert gain[0] == 1.0 and gain[1] > 1.0


def test_a_points_window_is_the_two_by_two_pixels_around_it():
    xy = np.array([[3.4, 7.9], [2.0, 5.0], [-0.5, 10.25]])
    np.testing.assert_array_equal(
        preprocessing.point_windows(xy), [[3, 7, 5, 9], [2, 5, 4, 7], [-1, 10, 1, 12]]
    )


def test_the_local_means_at_points_are_read_from_their_windows_alone():
    image = np.full((200, 300), 30, np.uint8)
    xy = np.array([[40.3, 50.7], [250.0, 150.5]])
    gamma = preprocessing.LocalGamma(
        image,
        255.0,
        _DEFAULTS.gamma_alpha,
        _DEFAULTS.illumination_window_px,
        regions=preprocessing.point_windows(xy),
    )
    # Outside every region the map would read no mean (0.5 stands in).
    np.testing.assert_allclose(gamma.mean_at(xy), 30 / 255, rtol=1e-5)


def test_a_passs_regions_take_its_points_windows_and_the_whole_frame_stays_whole():
    regions = np.array([[0, 0, 64, 64]])
    seeds = np.array([[100.5, 20.2]])
    np.testing.assert_array_equal(
        preprocessing.regions_and_points(regions, seeds), [[0, 0, 64, 64], [100, 20, 102, 22]]
    )
    assert preprocessing.regions_and_points(regions, np.zeros((0, 2))) is regions
    assert preprocessing.regions_and_points(None, seeds) is None
