"""Section 3.2, first layers: candidates, density mean shift, grid entropy."""

import cv2
import numpy as np
import pytest

from marker_localizer.core import screening
from marker_localizer.core.preprocessing import structure_map
from marker_localizer.synthetic import MarkerPlacement, render_markers


def test_contour_curvature_is_zero_on_a_line_and_one_at_a_right_angle():
    side = np.arange(10, dtype=float)
    square = np.concatenate(
        [
            np.stack([side, np.zeros(10)], 1),
            np.stack([np.full(10, 10.0), side], 1),
            np.stack([10 - side, np.full(10, 10.0)], 1),
            np.stack([np.zeros(10), 10 - side], 1),
        ]
    )
    kappa = screening.contour_curvature(square, window_px=2)
    assert kappa[5] == pytest.approx(0.0, abs=1e-6)
    assert kappa[10] == pytest.approx(1.0, abs=1e-6)  # the corner (10, 0)


def _x_frame(x: float, y: float, radius: float, shape=(160, 200)) -> np.ndarray:
    scene = render_markers(shape, [MarkerPlacement(x, y, radius)], 0, blur_sigma_px=0.8)
    return scene.image.astype(np.float32) / 255.0


def test_saddle_candidates_find_small_and_large_markers_within_a_pixel():
    image = _x_frame(50.3, 60.7, 4.0) + _x_frame(140.2, 90.4, 30.0) - 0.45
    found = screening.saddle_candidates(
        np.clip(image, 0, 1).astype(np.float32), (3.0, 40.0), min_contrast=20 / 255
    )
    # The small one answers at full resolution, the large one at a coarse level.
    for truth, tolerance in (([50.3, 60.7], 1.0), ([140.2, 90.4], 4.0)):
        assert np.linalg.norm(found.xy - truth, axis=1).min() < tolerance


def test_split_peak_midpoints_join_equal_peaks_within_reach_only():
    peaks = screening.Candidates(
        np.array([[10.0, 10.0], [16.0, 12.0], [100.0, 100.0], [104.0, 100.0]]),
        np.array([2.0, 2.5, 1.0, 3.0]),  # the far pair differs threefold in strength
        np.full(4, 6.0),
    )
    midpoints = screening.split_peak_midpoints(peaks, max_distance_px=15.0)
    np.testing.assert_allclose(midpoints.xy, [[13.0, 11.0]])
    assert midpoints.strength.tolist() == [2.0]
    assert midpoints.scale_px.tolist() == [6.0]
    assert len(screening.split_peak_midpoints(peaks, max_distance_px=5.0)) == 0


def test_a_tilted_marker_whose_saddle_peak_splits_gets_a_candidate_at_its_centre():
    # A 6.2 px marker tilted 48 degrees, the smallest of a 6-40 px range, seen at the
    # first level (half resolution): the 5x5 Sobel smoothing is wider than the
    # marker, so its centre is no saddle there and the response peaks either side.
    placement = MarkerPlacement(48.3, 47.6, 6.2, 0.0, 48.0, 2.36, kind="quarter_disks",
                                inverted=True)
    scene = render_markers((96, 96), [placement], 0, blur_sigma_px=0.7, noise_sigma_dn=1.2,
                           background_level=0.35)
    level = screening.saddle_levels((6.0, 40.0)).start
    assert level == 1
    half = cv2.resize(scene.image, (48, 48), interpolation=cv2.INTER_AREA)
    assert screening.saddle_response(half)[24, 24] < 0  # (u, v) = (23.9, 23.55): no saddle
    found = screening.saddle_candidates(scene.image, (6.0, 40.0), min_contrast=5.0)
    assert np.linalg.norm(found.xy - [48.3, 47.6], axis=1).min() < 0.5


def test_saddle_levels_start_at_full_resolution_only_for_small_markers():
    assert screening.saddle_levels((3.0, 40.0)).start == 0
    assert screening.saddle_levels((20.0, 80.0)).start == 2
    assert screening.saddle_levels((3.0, 40.0)).stop >= 4


def test_curvature_candidates_put_a_point_near_the_centre_of_an_x():
    image = _x_frame(80.4, 70.6, 20.0)
    found = screening.curvature_candidates(image, structure_map(image), (6.0, 30.0))
    assert np.linalg.norm(found.xy - [80.4, 70.6], axis=1).min() < 2.0


def test_non_maximum_suppression_keeps_the_strongest_of_close_points():
    xy = np.array([[0.0, 0.0], [1.0, 0.0], [10.0, 0.0]])
    keep = screening.non_maximum_suppression(xy, np.array([1.0, 2.0, 0.5]), radius_px=2.0)
    assert keep.tolist() == [False, True, True]


def test_density_mean_shift_merges_duplicates_of_one_corner():
    candidates = screening.Candidates(
        np.array([[10.0, 10.0], [11.0, 10.5], [40.0, 40.0]]),
        np.array([1.0, 0.8, 0.9]),
        np.array([4.0, 8.0, 4.0]),
    )
    merged = screening.density_mean_shift(candidates, sigma_px=2.0, h_px=2.0, merge_px=2.0)
    assert len(merged) == 2
    near = np.linalg.norm(merged.xy - [10.5, 10.25], axis=1).argmin()
    assert np.linalg.norm(merged.xy[near] - [10.5, 10.25]) < 0.6
    assert merged.scale_px[near] == 8.0  # the merged point keeps the larger scale


def test_grid_entropy_of_one_point_per_cell_is_log_of_the_cell_count():
    xy = np.array([[5.0, 5.0], [70.0, 5.0], [5.0, 70.0], [70.0, 70.0]])
    assert np.isclose(screening.grid_entropy(xy, cell_px=64), np.log(4))


def test_grid_entropy_thinning_trims_crowded_cells_weakest_first_and_raises_entropy():
    rng = np.random.default_rng(1)
    crowded = rng.uniform(0, 60, (50, 2))
    sparse = np.array([[100.0, 100.0], [200.0, 10.0]])
    xy = np.vstack([crowded, sparse])
    strength = np.r_[np.arange(50, dtype=float), 100.0, 100.0]
    candidates = screening.Candidates(xy, strength, np.ones(len(xy)))
    thinned = screening.grid_entropy_thinning(candidates, cell_px=64, max_per_cell=5)
    assert len(thinned) == 7
    assert sorted(thinned.strength[:5]) == [45.0, 46.0, 47.0, 48.0, 49.0]
    assert screening.grid_entropy(thinned.xy, 64) > screening.grid_entropy(xy, 64)
