"""Section 3.2, first layers: candidates, density mean shift, grid entropy."""

import cv2
import numpy as np
import pytest

from marker_localizer import DetectorConfig
from marker_localizer.core import screening
from marker_localizer.core.preprocessing import StructureComponents
from marker_localizer.synthetic import MarkerPlacement, render_markers

#: The detector's settings: the screening is specified as the detector runs it.
_DEFAULTS = DetectorConfig()
_SADDLE_THRESHOLD = _DEFAULTS.saddle_threshold


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
        np.clip(image, 0, 1).astype(np.float32),
        (3.0, 40.0),
        min_contrast=20 / 255,
        relative_threshold=_SADDLE_THRESHOLD,
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
    placement = MarkerPlacement(
        48.3, 47.6, 6.2, 0.0, 48.0, 2.36, kind="quarter_disks", inverted=True
    )
    scene = render_markers(
        (96, 96), [placement], 0, blur_sigma_px=0.7, noise_sigma_dn=1.2, background_level=0.35
    )
    level = screening.saddle_levels((6.0, 40.0)).start
    assert level == 1
    half = cv2.resize(scene.image, (48, 48), interpolation=cv2.INTER_AREA)
    assert screening.saddle_response(half)[24, 24] < 0  # (u, v) = (23.9, 23.55): no saddle
    found = screening.saddle_candidates(
        scene.image, (6.0, 40.0), min_contrast=5.0, relative_threshold=_SADDLE_THRESHOLD
    )
    assert np.linalg.norm(found.xy - [48.3, 47.6], axis=1).min() < 0.5


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("shape", [(4, 9), (5, 5), (70, 131)])
def test_integer_images_give_the_response_of_their_float_copy_bit_for_bit(dtype, shape):
    # The float copy takes cv2.Sobel's 5x5 kernels; an integer image their 1-D passes
    # on its own levels.
    high = np.iinfo(dtype).max
    image = np.random.default_rng(7).integers(0, high, shape, endpoint=True).astype(dtype)
    image[0, :2] = high  # the extremes, next to corners the borders reflect
    image[-1, -2:] = 0
    np.testing.assert_array_equal(
        screening.saddle_response(image), screening.saddle_response(image.astype(np.float32))
    )


def test_saddle_levels_start_at_full_resolution_only_for_small_markers():
    assert screening.saddle_levels((3.0, 40.0)).start == 0
    assert screening.saddle_levels((20.0, 80.0)).start == 2
    assert screening.saddle_levels((3.0, 40.0)).stop >= 4


def test_a_candidates_level_scale_is_that_of_the_level_that_found_it_uncapped():
    scales = np.array([2.5, 4.0, 6.0, 8.0, 12.0, 16.0])
    np.testing.assert_array_equal(screening.level_scale(scales), [2.5, 4.0, 8.0, 8.0, 16.0, 16.0])
    for r_min, r_max in ((6.0, 40.0), (7.0, 24.0), (12.0, 60.0), (3.0, 30.0)):
        for level in screening.saddle_levels((r_min, r_max)):
            scale = np.array([screening.candidate_scale(level, (r_min, r_max))])
            assert screening.level_scale(scale)[0] == screening.LEVEL_SCALE_PX * 2**level


def _sampled_peak(sigma: float, x: float, y: float) -> tuple[np.ndarray, np.ndarray]:
    """A Gaussian peak at (x, y) sampled at a pixel and its eight neighbours (centre, (1, 8))."""
    value = [
        np.exp(-((col - x) ** 2 + (row - y) ** 2) / (2 * sigma**2))
        for row, col in screening._NEIGHBOURS
    ]
    return np.array([np.exp(-(x**2 + y**2) / (2 * sigma**2))]), np.array([value])


def test_a_peak_narrower_than_the_grid_is_placed_by_its_centroid_a_broad_one_by_parabolas():
    centre, neighbours = _sampled_peak(0.5, 0.3, -0.2)
    dx, dy = screening.peak_offset(centre, neighbours)
    assert abs(dx[0] - 0.3) < 0.03 and abs(dy[0] + 0.2) < 0.03
    # A parabola through three samples of so narrow a peak falls halfway short.
    assert screening.parabolic_offset(neighbours[:, 0], centre, neighbours[:, 1])[0] < 0.15
    centre, neighbours = _sampled_peak(1.5, 0.3, -0.2)
    dx, dy = screening.peak_offset(centre, neighbours)
    assert dx[0] == screening.parabolic_offset(neighbours[:, 0], centre, neighbours[:, 1])[0]
    assert dy[0] == screening.parabolic_offset(neighbours[:, 2], centre, neighbours[:, 3])[0]
    assert abs(dx[0] - 0.3) < 0.03 and abs(dy[0] + 0.2) < 0.03


def _polygon(corners: list[tuple[float, float]], per_side: int = 12) -> np.ndarray:
    """Points along a closed polygon, ``per_side`` per side, corners included."""
    corners_ = np.array(corners, dtype=float)
    ends = np.roll(corners_, -1, axis=0)
    t = np.arange(per_side)[:, None] / per_side
    return np.concatenate([a + t * (b - a) for a, b in zip(corners_, ends, strict=True)])


def test_eq4_gives_one_minus_the_cosine_of_the_turn_at_every_corner_of_polygons():
    triangle = _polygon([(0, 0), (30, 0), (15, 15 * np.sqrt(3))])  # turns of 120 degrees
    square = _polygon([(0, 0), (20, 0), (20, 20), (0, 20)])  # 90 degrees
    half_square = _polygon([(0, 0), (40, 0), (40, 40)])  # 135, 90 and 135 degrees
    contours = screening.ContourSet.from_list([triangle, square, half_square])
    kappa = screening.contour_curvature(contours, window_px=3)
    offset = 0
    for points, turns in ((triangle, [120] * 3), (square, [90] * 4), (half_square, [135, 90, 135])):
        corner_kappa = kappa[offset : offset + len(points)][::12]
        np.testing.assert_allclose(corner_kappa, 1.0 - np.cos(np.deg2rad(turns)), atol=1e-9)
        mid_side = kappa[offset + 6 : offset + len(points) : 12]
        np.testing.assert_allclose(mid_side, 0.0, atol=1e-9)
        offset += len(points)


def test_robust_mean_and_std_match_a_normal_bulk_and_ignore_its_heavy_tail():
    rng = np.random.default_rng(3)
    bulk = rng.normal(0.2, 0.05, 20000)
    values = np.r_[bulk, rng.uniform(1.0, 2.0, 1500)]
    mean, std = screening.robust_mean_std(values)
    assert mean == pytest.approx(0.2, abs=0.01)
    assert std == pytest.approx(0.05, abs=0.01)
    assert values.mean() + 3 * values.std() > 1.0 > mean + 3 * std
    # Weights: a sample of weight 3 counts as three samples of weight 1.
    weighted = screening.robust_mean_std(np.array([1.0, 2.0, 9.0]), np.array([1.0, 3.0, 1.0]))
    assert weighted == screening.robust_mean_std(np.array([1.0, 2.0, 2.0, 2.0, 9.0]))


def test_sectors_that_touch_only_at_a_corner_are_traced_as_two_contours():
    mask = np.zeros((20, 20), bool)
    mask[2:10, 2:10] = mask[10:18, 10:18] = True
    contours = screening.trace_contours(mask, min_points=4)
    assert len(np.unique(contours.start)) == 2
    assert np.unique(contours.start, return_counts=True)[1].max() < 8 * 4


def test_the_local_level_is_the_x_midlevel_and_absent_on_flat_ground():
    image = _x_frame(80.4, 70.6, 20.0)
    level = screening.local_threshold(image, screening.threshold_diameters((6.0, 30.0)), 0.1)
    dark, bright = np.percentile(image[60:80, 70:90], [2, 98])
    assert level[70, 80] == pytest.approx(0.5 * (dark + bright), abs=0.03)
    flat = np.full((50, 50), 0.4, np.float32)
    assert np.isnan(screening.local_threshold(flat, (13, 27), 0.1)).all()


def test_the_connected_domain_check_drops_domains_below_the_area_floor():
    mask = np.zeros((30, 30), bool)
    mask[2:4, 2:4] = True  # 4 px
    mask[10:20, 10:20] = True  # 100 px
    kept = screening.connected_domain_check(mask, min_area_px=5.0)
    assert not kept[2:4, 2:4].any() and kept[10:20, 10:20].all()


def test_contour_pixels_land_on_the_level_line_of_a_blurred_edge():
    x = np.arange(60, dtype=np.float32)
    edge_x = 30.3 + 0.2 * np.arange(60)[:, None]  # a tilted edge: x = 30.3 + 0.2 y
    image = (0.2 + 0.6 * 0.5 * (1 + np.tanh((x[None, :] - edge_x) / 1.2))).astype(np.float32)
    level = np.full(image.shape, 0.5, np.float32)
    contours = screening.trace_contours(image > level, min_points=4)
    moved, strength = screening.onto_level_line(contours, image, level)
    inside = (moved.points[:, 1] > 5) & (moved.points[:, 1] < 50) & (moved.points[:, 0] > 5)
    inside &= moved.points[:, 0] < 55
    residual = moved.points[inside, 0] - (30.3 + 0.2 * moved.points[inside, 1])
    staircase = contours.points[inside, 0] - (30.3 + 0.2 * contours.points[inside, 1])
    assert np.abs(staircase).max() > 0.4
    assert np.abs(residual).max() < 0.15
    assert strength[inside].min() > 0.1


@pytest.mark.parametrize(("radius", "tilt"), [(7.0, 0.0), (20.0, 50.0)])
def test_curvature_candidates_put_a_point_near_the_centre_of_an_x(radius, tilt):
    scene = render_markers(
        (160, 200), [MarkerPlacement(80.4, 70.6, radius, 0.4, tilt)], 0, blur_sigma_px=1.0
    )
    image = scene.image.astype(np.float32) / 255.0
    structure = StructureComponents(image, xi=_DEFAULTS.structure_xi, t=_DEFAULTS.structure_t)
    found = screening.curvature_candidates(
        image,
        structure,
        (6.0, 30.0),
        20 / 255,
        _DEFAULTS.curvature_threshold_std,
        _DEFAULTS.min_peak_separation_px,
        _DEFAULTS.structure_keep_fraction,
        _DEFAULTS.density_sigma_px,
        _DEFAULTS.mean_shift_h_px,
    )
    assert np.linalg.norm(found.xy - [80.4, 70.6], axis=1).min() < 1.5


def test_a_point_suppresses_only_weaker_points_of_its_own_group():
    xy = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    keep = screening.non_maximum_suppression(
        xy, np.array([1.0, 2.0, 3.0]), radius_px=5.0, group=np.array([0, 0, 1])
    )
    assert keep.tolist() == [False, True, True]


def test_non_maximum_suppression_keeps_the_strongest_of_close_points():
    xy = np.array([[0.0, 0.0], [1.0, 0.0], [10.0, 0.0]])
    keep = screening.non_maximum_suppression(xy, np.array([1.0, 2.0, 0.5]), radius_px=2.0)
    assert keep.tolist() == [False, True, True]


def test_candidates_centred_together_are_one_screened_as_widely_as_the_widest():
    candidates = screening.Candidates(
        np.array([[10.0, 10.0], [11.0, 10.0], [40.0, 40.0], [40.5, 40.0]]),
        np.array([2.0, 1.0, 0.5, 0.9]),
        np.array([6.0, 16.0, 8.0, 4.0]),
    )
    kept, merged = candidates.without_duplicates(1.5)
    assert merged == 2
    # The stronger's position and strength, the wider's scale.
    assert kept.xy.tolist() == [[10.0, 10.0], [40.5, 40.0]]
    assert kept.strength.tolist() == [2.0, 0.9]
    assert kept.scale_px.tolist() == [16.0, 8.0]


def test_candidates_apart_keep_their_own_scales():
    candidates = screening.Candidates(
        np.array([[10.0, 10.0], [12.0, 10.0]]), np.array([2.0, 1.0]), np.array([6.0, 16.0])
    )
    kept, merged = candidates.without_duplicates(1.5)
    assert merged == 0
    assert kept.scale_px.tolist() == [6.0, 16.0]
    assert screening.Candidates.empty().without_duplicates(1.5)[1] == 0


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


def _greedy_by_hand(candidates, cell_px, target):
    """The paper's loop, step by step: remove the weakest point of the most crowded cell."""
    keep = np.ones(len(candidates), bool)
    cells = [tuple(c) for c in np.floor(candidates.xy / cell_px).astype(int)]
    entropies = [screening.grid_entropy(candidates.xy, cell_px)]
    while entropies[-1] < target:
        alive = np.flatnonzero(keep)
        names, counts = np.unique([cells[i] for i in alive], axis=0, return_counts=True)
        crowded = tuple(names[np.argmax(counts)])
        members = [i for i in alive if cells[i] == crowded]
        trial = keep.copy()
        trial[min(members, key=lambda i: candidates.strength[i])] = False
        entropy = screening.grid_entropy(candidates.xy[trial], cell_px)
        if entropy <= entropies[-1]:
            break
        keep = trial
        entropies.append(entropy)
    return keep, entropies


def test_greedy_entropy_thinning_raises_the_entropy_at_every_step_up_to_the_threshold():
    rng = np.random.default_rng(5)
    xy = np.vstack(
        [
            rng.uniform(0, 64, (40, 2)),
            rng.uniform(64, 128, (12, 2)),
            [[200.0, 10.0], [10.0, 200.0], [150.0, 150.0]],
        ]
    )
    candidates = screening.Candidates(xy, rng.uniform(0, 1, len(xy)), np.ones(len(xy)))
    n_cells = 5
    for evenness in (0.6, 0.8, 0.9, 1.0):
        target = evenness * np.log(n_cells)
        by_hand, entropies = _greedy_by_hand(candidates, 64, target)
        assert np.all(np.diff(entropies) > 0)
        thinned = screening.greedy_entropy_thinning(candidates, 64, evenness)
        assert sorted(map(tuple, thinned.xy)) == sorted(map(tuple, xy[by_hand]))
        assert screening.grid_entropy(thinned.xy, 64) >= min(target, entropies[-1]) - 1e-12
    assert len(screening.greedy_entropy_thinning(candidates, 64, 0.0)) == len(xy)


def _maxima_by_hand(response, threshold):
    """Above the threshold, no larger neighbour, ties to the first pixel in raster order."""
    height, width = response.shape
    found = []
    for row in range(1, height - 1):
        for col in range(1, width - 1):
            value = response[row, col]
            neighbours = [
                (d_row, d_col, response[row + d_row, col + d_col])
                for d_row in (-1, 0, 1)
                for d_col in (-1, 0, 1)
                if (d_row, d_col) != (0, 0)
            ]
            if value > threshold and all(
                n < value or (n == value and (d_row, d_col) > (0, 0))
                for d_row, d_col, n in neighbours
            ):
                found.append(row * width + col)
    return found


@pytest.mark.parametrize("threshold", [0.5, 18.5], ids=["busy", "quiet"])
def test_local_maxima_are_the_3x3_maxima_with_ties_to_the_first_pixel_on_busy_and_quiet_ground(
    threshold,
):
    # Integer levels make plateaus: each must give exactly one peak.
    response = np.random.default_rng(3).integers(0, 20, (40, 50)).astype(np.float32)
    share_above = np.mean(response > threshold)
    # The busy response takes the dilation, the quiet one the neighbour look-ups.
    assert (share_above > screening._DENSE_MAXIMA_SHARE) == (threshold < 1)
    peaks, values = screening._local_maxima(response, threshold)
    assert list(peaks) == _maxima_by_hand(response, threshold)
    np.testing.assert_array_equal(values, response.reshape(-1)[peaks])


@pytest.mark.parametrize(
    "shape",
    [(257, 600), (300, 600), (683, 96), (700, 96)],
    ids=["wide, a last strip of one row", "wide", "narrow, one row", "narrow"],
)
@pytest.mark.parametrize("threshold", [40.0**2, 400.0**2], ids=["busy", "quiet"])
def test_the_response_and_peaks_found_strip_by_strip_are_those_of_the_whole_image(shape, threshold):
    # A narrow image (a tracked frame's side band) takes taller strips, as many pixels.
    height, width = shape
    assert 2 * screening._strip_rows(width) < height
    noise = np.random.default_rng(4).normal(128, 40, (height + 7, width + 5))
    # A crop, as a window is: no strip edge may act as the image's border.
    image = np.clip(noise, 0, 255).astype(np.uint8)[3 : height + 3, 5:]
    found = screening.saddle_peaks(image, threshold)
    whole = screening.saddle_response(image)
    whole_peaks, whole_values = screening._local_maxima(whole, threshold)
    np.testing.assert_array_equal(found.flat_index, whole_peaks)
    np.testing.assert_array_equal(found.values, whole_values)
    np.testing.assert_array_equal(found.neighbours, _neighbours(whole, whole_peaks))
    assert len(whole_peaks) > 0 and found.bound == 0 and found.unexamined == 0


def _neighbours(response, peaks):
    """(N, 8) the responses left, right, above and below each peak, then its diagonals."""
    rows, cols = np.divmod(peaks, response.shape[1])
    return np.stack(
        [response[rows + d_row, cols + d_col] for d_row, d_col in screening._NEIGHBOURS], axis=1
    )


@pytest.mark.parametrize("at_least", [0.0, 300.0**2])
def test_the_strongest_peaks_are_every_peak_of_at_least_the_bound_the_rest_counted_as_pixels(
    at_least,
):
    image = np.clip(np.random.default_rng(6).normal(128, 40, (700, 300)), 0, 255).astype(np.uint8)
    threshold = 40.0**2
    found = screening.saddle_peaks(image, threshold, strongest=500, at_least=at_least)
    whole = screening.saddle_response(image)
    every, values = screening._local_maxima(whole, threshold)
    strong = values >= found.bound
    assert found.bound >= at_least and 500 <= len(found.flat_index) < 0.5 * len(every)
    np.testing.assert_array_equal(found.flat_index, every[strong])
    np.testing.assert_array_equal(found.values, values[strong])
    np.testing.assert_array_equal(found.neighbours, _neighbours(whole, every[strong]))
    assert found.unexamined == np.count_nonzero((whole > threshold) & (whole < found.bound))


@pytest.mark.parametrize("high", [3, 2**40, 2**62], ids=["ties", "spread", "no room"])
def test_stable_order_is_the_stable_argsort_ties_in_index_order(high):
    keys = np.random.default_rng(8).integers(0, high, 5000).astype(np.int64)
    np.testing.assert_array_equal(screening.stable_order(keys), np.argsort(keys, kind="stable"))


def test_sort_keys_order_points_by_cell_then_strongest_first_whatever_the_sign():
    cell = np.array([1, 0, 1, 0, 1, 0])
    strength = np.array([-2.0, 0.0, 3.5, -1.0, 0.0, 7.0])
    order = np.argsort(screening.strongest_first_in_cell(cell, strength))
    assert list(order) == [5, 1, 3, 2, 4, 0]


def test_the_strongest_candidates_keep_their_order():
    candidates = screening.Candidates(
        np.arange(10.0).reshape(5, 2), np.array([1.0, 5.0, 3.0, 5.0, 2.0]), np.ones(5)
    )
    assert list(candidates.strongest(3).strength) == [5.0, 3.0, 5.0]
    assert candidates.strongest(9) is candidates
    # Of equal strengths at the limit the first go on, NaN or not among the rest.
    for weak in (2.0, np.nan):
        tied = screening.Candidates(
            np.arange(12.0).reshape(6, 2), np.array([2.0, 5.0, 2.0, 5.0, 2.0, weak]), np.ones(6)
        )
        assert list(tied.strongest(3).xy[:, 0]) == [0.0, 2.0, 6.0]


def test_the_cell_cap_bounds_busy_ground_per_level_and_keeps_what_the_frames_cap_keeps():
    """Sensor noise fills every level with peaks: capped per level, the frame's cap keeps
    (nearly) the same points, and a marker in the noise stays a candidate."""
    marker = _x_frame(120.3, 80.6, 8.0, shape=(256, 320)) * 180 + 40
    noisy = marker + np.random.default_rng(5).normal(0, 40, marker.shape)
    image = np.clip(noisy, 0, 255).astype(np.uint8)
    uncapped = screening.saddle_candidates(
        image, (3.0, 30.0), 20.0, relative_threshold=_SADDLE_THRESHOLD
    )
    capped = screening.saddle_candidates(
        image,
        (3.0, 30.0),
        20.0,
        cell_cap=screening.CellCap(64, 48),
        relative_threshold=_SADDLE_THRESHOLD,
    )
    levels = len(screening.saddle_levels((3.0, 30.0)))
    cells = (256 // 64) * (320 // 64)
    # Each level's peaks are capped, plus the first level's split-peak midpoints.
    assert len(capped) <= 2 * levels * cells * 48 < len(uncapped) / 10
    kept_uncapped = screening.grid_entropy_thinning(uncapped, 64, 48)
    kept_capped = screening.grid_entropy_thinning(capped, 64, 48)
    common = {tuple(p) for p in kept_uncapped.xy.round(9)} & {
        tuple(p) for p in kept_capped.xy.round(9)
    }
    assert len(common) >= 0.95 * len(kept_uncapped)
    assert np.linalg.norm(capped.xy - [120.3, 80.6], axis=1).min() < 1.0


def test_a_window_caps_its_cells_on_the_frames_grid():
    """A window's candidates are capped in the frame's cells, as a full pass caps them."""
    image = np.clip(np.random.default_rng(6).normal(128, 40, (192, 256)), 0, 255).astype(np.uint8)
    cap = screening.CellCap(64, 8)
    full = screening.saddle_candidates(
        image, (6.0, 30.0), 20.0, cell_cap=cap, relative_threshold=_SADDLE_THRESHOLD
    )
    x0, y0 = 32, 64  # the crop starts mid-cell in x
    part = screening.saddle_candidates(
        image[y0:, x0:],
        (6.0, 30.0),
        20.0,
        cell_cap=cap._replace(origin_px=(x0, y0)),
        relative_threshold=_SADDLE_THRESHOLD,
    )
    inside = (full.xy[:, 0] >= x0 + 16) & (full.xy[:, 1] >= y0 + 16)
    wanted = {tuple(p) for p in full.xy[inside].round(6)}
    got = {tuple(p) for p in (part.xy + [x0, y0]).round(6)}
    assert wanted and wanted <= got


def test_the_floor_of_the_frames_cap_leaves_what_both_caps_keep_unchanged():
    image = np.clip(np.random.default_rng(7).normal(128, 40, (256, 320)), 0, 255).astype(np.uint8)
    cells = screening.CellCap(64, 48)
    both = cells._replace(max_total=300)
    without = screening.saddle_candidates(
        image, (3.0, 30.0), 20.0, cell_cap=cells, relative_threshold=_SADDLE_THRESHOLD
    )
    floored = screening.saddle_candidates(
        image, (3.0, 30.0), 20.0, cell_cap=both, relative_threshold=_SADDLE_THRESHOLD
    )
    assert len(floored) < len(without) / 5
    kept = [
        {tuple(p) for p in screening.grid_entropy_thinning(c, 64, 48).strongest(300).xy}
        for c in (without, floored)
    ]
    assert kept[0] == kept[1]


@pytest.mark.parametrize("max_total", [150, 600, 2500, None])
@pytest.mark.parametrize("earlier_floor", [0.0, 1.6, 4.0])
def test_a_levels_floor_found_from_its_strongest_peaks_is_that_of_capping_all_of_them(
    max_total, earlier_floor
):
    """The search among the strongest peaks first gives what capping, refining and
    flooring every peak gives, whether the floor lies among them, above the earlier
    levels' floor or nowhere; where peaks weaker than those listed would decide, it
    says so."""
    image = np.clip(np.random.default_rng(8).normal(128, 40, (256, 320)), 0, 255)
    response = screening.saddle_response(image.astype(np.uint8))
    expected = 20.0
    level = (0, (3, 5), expected, 3.0)
    index, values = screening._local_maxima(response, 40.0**2)
    every_peak = screening.SaddlePeaks(
        response.shape, index, values, _neighbours(response, index), 0.0, 0
    )
    peaks = screening._LevelPeaks(every_peak, *level)
    cap = screening.CellCap(64, 48, max_total, (16.0, 0.0))
    every = peaks.refined(np.flatnonzero(cap.keep(peaks.pixel_xy(), values)))
    floor = max(earlier_floor, cap.floor(every))
    found, new_floor = peaks.over_floor(cap, earlier_floor)
    assert new_floor == floor
    np.testing.assert_array_equal(found.xy, every.take(every.strength >= floor).xy)
    assert peaks.capped_count(cap) == len(every)
    if max_total is not None:
        search = screening._floor_search(max_total)
        listed = screening.saddle_peaks(
            image.astype(np.uint8),
            40.0**2,
            strongest=search,
            at_least=screening._floor_bound(earlier_floor, expected),
        )
        strongest = screening._LevelPeaks(listed, *level).over_floor(cap, earlier_floor)
        if strongest is not None:
            np.testing.assert_array_equal(strongest[0].xy, found.xy)
            assert strongest[1] == new_floor


def test_the_even_cap_keeps_every_cells_strongest_before_a_crowded_cells_next():
    rng = np.random.default_rng(2)
    crowded = rng.uniform(0, 60, (40, 2))  # one cell of strong texture
    lone = np.array([[100.0, 100.0], [300.0, 20.0], [20.0, 300.0]])  # weak, alone
    candidates = screening.Candidates(
        np.vstack([crowded, lone]), np.r_[np.arange(51.0, 91.0), 1.0, 2.0, 3.0], np.ones(43)
    )
    kept = screening.even_cap(candidates, 6, cell_px=64)
    assert sorted(kept.strength) == [1.0, 2.0, 3.0, 88.0, 89.0, 90.0]
    assert screening.even_cap(candidates, 43, cell_px=64) is candidates


def test_the_even_order_lists_points_as_the_even_cap_keeps_them_so_any_cap_keeps_a_prefix():
    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 256, (200, 2))
    strength = rng.uniform(0, 1, 200)
    order = screening.even_order(xy, strength, cell_px=64)
    assert sorted(order) == list(range(200))
    for limit in (1, 16, 17, 90):
        assert list(screening.even_cap_index(xy, strength, limit, 64)) == sorted(order[:limit])
    # Round by round: the first 16 are the 16 cells' strongest.
    cells = screening.grid_cells(xy, 64)
    assert len(set(cells[order[:16]])) == 16


def _light(weight: float) -> screening.LightWeight:
    def everywhere(points: np.ndarray) -> np.ndarray:
        return np.full(len(points), weight)

    def on_spans(y: np.ndarray, x_first: np.ndarray, x_last: np.ndarray) -> np.ndarray:
        return np.full((len(y), len(x_first)), weight)

    return screening.LightWeight(everywhere, on_spans)


def test_a_marker_in_deep_shadow_is_screened_with_the_shadow_gain_and_only_then():
    # An X of 12 grey levels on ground 5 levels bright: 20 levels of contrast in the open.
    dark = (5 + 12 * _x_frame(80.4, 70.6, 12.0)).astype(np.float32) / 255.0
    alone = screening.saddle_candidates(
        dark, (6.0, 20.0), min_contrast=20 / 255, relative_threshold=_SADDLE_THRESHOLD
    )
    shaded = screening.saddle_candidates(
        dark,
        (6.0, 20.0),
        min_contrast=20 / 255,
        light=_light(4.0),
        relative_threshold=_SADDLE_THRESHOLD,
    )
    assert len(alone) == 0
    assert np.linalg.norm(shaded.xy - [80.4, 70.6], axis=1).min() < 1.0


def test_a_shadow_over_part_of_each_row_gives_the_candidates_of_its_gain_at_every_peak():
    # The threshold is lowered by a bound on the gain over each span of a row, and every
    # peak under the open threshold is then held to its own gain: the candidates are
    # those of a bound over the whole row (the dark stretch on the left of every row).
    noise = np.random.default_rng(7).normal(0.5, 0.06, (240, 320))
    image = np.clip(noise + 0.5 * _x_frame(250.3, 120.6, 10.0, (240, 320)), 0, 1).astype(np.float32)

    def at(xy: np.ndarray) -> np.ndarray:
        return np.where(xy[:, 0] < 100, 4.0, 1.0 + xy[:, 0] / 1000)

    def on_spans(y: np.ndarray, x_first: np.ndarray, x_last: np.ndarray) -> np.ndarray:
        return np.repeat(np.where(x_first < 100, 4.0, 1.0 + x_last / 1000)[None], len(y), axis=0)

    def on_rows(y: np.ndarray, x_first: np.ndarray, x_last: np.ndarray) -> np.ndarray:
        return np.full((len(y), len(x_first)), 4.0)

    spans, rows = (
        screening.saddle_candidates(
            image,
            (4.0, 20.0),
            min_contrast=60 / 255,
            light=screening.LightWeight(at, bound),
            relative_threshold=_SADDLE_THRESHOLD,
        )
        for bound in (on_spans, on_rows)
    )
    assert len(spans) > 20 and (spans.xy[:, 0] < 100).any() and (spans.xy[:, 0] >= 100).any()
    assert np.array_equal(spans.xy, rows.xy) and np.array_equal(spans.strength, rows.strength)


def test_the_frames_cap_keeps_the_saddle_of_most_contrast_over_its_light():
    # The same print under two lights: an X of 0.1 of white where the light weighs 2 (a
    # dim stretch) and one of 0.3 where it weighs a quarter (bright ground). The bright
    # one's response is nine times the dim one's; over its light, 9 / 64 of it.
    image = 0.3 + 0.1 * (_x_frame(50.3, 80.6, 12.0, (160, 200)) - 0.5)
    image += 0.3 * (_x_frame(150.2, 80.4, 12.0, (160, 200)) - 0.5)
    image = np.clip(image, 0, 1).astype(np.float32)
    light = screening.LightWeight(
        lambda xy: np.where(xy[:, 0] < 100, 2.0, 0.25),
        lambda y, x_first, x_last: np.repeat(
            np.where(x_first < 100, 2.0, 0.25)[None], len(y), axis=0
        ),
    )
    cap = screening.CellCap(64, 48, max_total=1)
    plain = screening.saddle_candidates(
        image, (6.0, 20.0), 20 / 255, cell_cap=cap, relative_threshold=_SADDLE_THRESHOLD
    )
    weighed = screening.saddle_candidates(
        image,
        (6.0, 20.0),
        20 / 255,
        cell_cap=cap,
        light=light,
        relative_threshold=_SADDLE_THRESHOLD,
    )
    assert np.linalg.norm(plain.xy - [150.2, 80.4], axis=1).min() < 1.0
    assert len(weighed) == 1 and np.linalg.norm(weighed.xy[0] - [50.3, 80.6]) < 1.0


def test_a_peak_counts_its_response_times_its_lights_weight_squared():
    image = np.clip(_x_frame(80.4, 70.6, 12.0) - 0.2, 0, 1).astype(np.float32)
    plain = screening.saddle_candidates(
        image, (6.0, 20.0), min_contrast=20 / 255, relative_threshold=_SADDLE_THRESHOLD
    )
    for weight in (0.25, 0.5, 1.0):
        # A weight under 1 (bright light) leaves the threshold as it is: the same peaks
        # pass, their strength weighed (their refinement, on responses weighed alike,
        # moves by float rounding alone).
        weighed = screening.saddle_candidates(
            image,
            (6.0, 20.0),
            min_contrast=20 / 255,
            light=_light(weight),
            relative_threshold=_SADDLE_THRESHOLD,
        )
        np.testing.assert_allclose(weighed.xy, plain.xy, atol=1e-6)
        np.testing.assert_allclose(weighed.strength, weight * plain.strength, rtol=1e-6)


def test_rows_in_the_open_keep_the_configured_threshold():
    frame = np.clip(_x_frame(50.3, 60.7, 10.0) + _x_frame(140.2, 100.4, 10.0) - 0.45, 0, 1)
    image = frame.astype(np.float32)
    plain = screening.saddle_candidates(
        image, (6.0, 20.0), min_contrast=20 / 255, relative_threshold=_SADDLE_THRESHOLD
    )
    lit = screening.saddle_candidates(
        image,
        (6.0, 20.0),
        min_contrast=20 / 255,
        light=_light(1.0),
        relative_threshold=_SADDLE_THRESHOLD,
    )
    assert np.array_equal(plain.xy, lit.xy) and np.array_equal(plain.strength, lit.strength)
    # Shadow over the lower rows only: the upper rows' candidates stay exactly as they were.
    lower = screening.LightWeight(
        lambda xy: np.where(xy[:, 1] >= 80, 4.0, 1.0),
        lambda y, x_first, x_last: np.where(y[:, None] >= 80, 4.0, np.ones(len(x_first))),
    )
    shaded = screening.saddle_candidates(
        image, (6.0, 20.0), min_contrast=20 / 255, light=lower, relative_threshold=_SADDLE_THRESHOLD
    )
    upper = plain.xy[:, 1] < 70
    assert np.array_equal(plain.xy[upper], shaded.xy[shaded.xy[:, 1] < 70])
    assert len(shaded) >= len(plain)


def _tiny_marker_on_texture():
    """A marker of 4 px at (150.3, 99.6) on ground texture, 300 x 200 px."""
    placement = MarkerPlacement(150.3, 99.6, 4.0, 0.3, 20.0, 0.0)
    return render_markers((200, 300), [placement], 0, background="texture")


def _ring_mean_on_the_frame(response: np.ndarray, x: int, y: int) -> float:
    """The mean positive response on the ground's ring about (x, y), read on the frame."""
    inner, outer = screening.GROUND_RING_HALF_SIDES_PX
    ground = np.maximum(response, 0.0).astype(np.float64)
    boxes = [ground[y - h : y + h + 1, x - h : x + h + 1] for h in (outer, inner)]
    return (boxes[0].sum() - boxes[1].sum()) / (boxes[0].size - boxes[1].size)


def test_a_saddle_over_its_ground_is_its_peak_over_its_rings_mean_as_the_frame_reads_them():
    # Read from windows laid side by side, the ratio is the frame's own response: its
    # 3x3 peak at the point over the mean of its positive part on the ring.
    scene = _tiny_marker_on_texture()
    response = screening.saddle_response(scene.image)
    points = np.array([[150.3, 99.6], [60.0, 50.0], [240.2, 150.7], [40.0, 160.0]])
    ratio = screening.saddle_over_ground(scene.image, points)
    for (x, y), read in zip(np.rint(points).astype(int), ratio, strict=True):
        peak = response[y - 1 : y + 2, x - 1 : x + 2].max()
        assert read == pytest.approx(peak / _ring_mean_on_the_frame(response, x, y), rel=1e-5)
    assert ratio[0] >= 60.0 > ratio[1:].max()


def test_a_saddle_over_its_ground_holds_in_any_light_and_is_unread_where_the_frame_cuts_its_ring():
    scene = _tiny_marker_on_texture()
    half = screening.GROUND_RING_HALF_SIDES_PX[1]
    points = np.array([[150.3, 99.6], [half + 2.0, 100.0], [half + 1.0, 100.0], [150.0, 2.0]])
    ratio = screening.saddle_over_ground(scene.image, points)
    dimmer = screening.saddle_over_ground(scene.image.astype(np.float32) * 0.5, points)
    assert np.isfinite(ratio[:2]).all() and np.isnan(ratio[2:]).all()
    assert dimmer[:2] == pytest.approx(ratio[:2], rel=1e-5)
    assert np.isnan(dimmer[2:]).all()
