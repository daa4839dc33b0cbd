"""The frame's Poisson-Gaussian noise, measured from the frame itself."""

import numpy as np
import pytest

from marker_localizer.core.noise import estimate_noise, grey_step


def _quantised(image: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("sigma", [1.0, 3.0, 6.0])
def test_the_noise_of_a_flat_frame_is_its_read_noise_plus_quantisation(sigma):
    rng = np.random.default_rng(0)
    image = _quantised(rng.normal(100.0, sigma, (800, 800)))
    expected = np.sqrt(sigma**2 + 1.0 / 12.0)
    assert float(estimate_noise(image, 255.0).std(100.0)) == pytest.approx(expected, rel=0.05)


def test_shot_noise_grows_with_the_signal_and_both_terms_are_recovered():
    rng = np.random.default_rng(1)
    signal = np.tile(np.linspace(20.0, 230.0, 1000), (1000, 1))
    image = _quantised(signal + rng.normal(0.0, 1.0, signal.shape) * np.sqrt(4.0 + 0.05 * signal))
    noise = estimate_noise(image, 255.0)
    for level in (20.0, 120.0, 230.0):
        truth = np.sqrt(4.0 + 0.05 * level + 1.0 / 12.0)
        assert float(noise.std(level)) == pytest.approx(truth, rel=0.08)


def test_texture_and_edges_are_not_taken_for_noise():
    rng = np.random.default_rng(2)
    y, x = np.mgrid[:600, :600]
    # Smooth shading and a hard edge, both far stronger than the 2 DN of noise.
    scene = 80.0 + 60.0 * np.sin(x / 17.0) * np.cos(y / 23.0) + 90.0 * (x > 300)
    image = _quantised(scene + rng.normal(0.0, 2.0, scene.shape))
    assert float(estimate_noise(image, 255.0).std(120.0)) == pytest.approx(2.0, rel=0.15)


def test_a_noise_free_frame_reports_the_quantisation_of_its_grey_levels():
    image = np.full((100, 100), 128, np.uint8)
    assert float(estimate_noise(image, 255.0).std(128.0)) == pytest.approx(1.0 / np.sqrt(12.0))


def test_the_grey_step_is_the_smallest_difference_of_levels_around_the_points():
    rng = np.random.default_rng(3)
    noisy = _quantised(rng.normal(100.0, 3.0, (60, 60)))
    thresholded = np.where(noisy > 100, 255, 0).astype(np.uint8)
    ramp = np.tile(np.linspace(0.0, 255.0, 60), (60, 1))
    four_levels = (np.rint(ramp / 85.0) * 85.0).astype(np.uint8)
    centre = np.array([[30.0, 30.0]])
    assert grey_step(noisy, centre) == 1.0
    assert grey_step(thresholded, centre) == 255.0
    assert grey_step(four_levels, centre) == 85.0
    assert grey_step(np.full((60, 60), 7, np.uint8), centre) == 0.0
