"""Specification of the grid metrics (marker_localizer.bench.metrics) and peer helpers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from marker_localizer import Detector, DetectorConfig
from marker_localizer.bench import accuracy, metrics
from marker_localizer.bench.peers import parse_mrgingham, subpix_half_window
from marker_localizer.core.result import positions


def projective_grid(rows: int, cols: int, shift: tuple[float, float] = (100.0, 80.0)) -> np.ndarray:
    """A (rows, cols, 2) grid through a strong perspective homography, moved by ``shift``, px."""
    h = np.array([[40.0, 6.0, shift[0]], [-3.0, 35.0, shift[1]], [2e-3, 1.5e-2, 1.0]])
    v, u = np.mgrid[:rows, :cols].astype(np.float64)
    mapped = np.stack([u, v, np.ones_like(u)], axis=-1) @ h.T
    return mapped[..., :2] / mapped[..., 2:]


# --------------------------------------------------------------------------- grid geometry


def test_line_residual_of_exactly_collinear_points_is_zero():
    points = np.array([[0.0, 1.0], [1.0, 3.0], [2.5, 6.0], [4.0, 9.0]])
    np.testing.assert_allclose(metrics.straight_line_residuals(points), 0.0, atol=1e-12)


def test_line_residual_of_a_point_off_the_line_is_its_share_of_the_offset():
    points = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.3], [3.0, 0.0], [4.0, 0.0]])
    residuals = metrics.straight_line_residuals(points)
    assert residuals[2] - residuals[0] == pytest.approx(0.3, abs=0.02)


def test_a_grid_seen_through_a_homography_has_zero_line_and_spacing_residuals():
    result = metrics.line_residuals(projective_grid(6, 8))
    assert result.straight_rms_px == pytest.approx(0.0, abs=1e-9)
    assert result.spacing_rms_px == pytest.approx(0.0, abs=1e-9)
    assert result.n_lines == 6 + 8


def test_uneven_spacing_along_a_straight_line_shows_in_the_spacing_residual_only():
    grid = projective_grid(5, 7)
    grid[2, 3] += 0.2 * (grid[2, 4] - grid[2, 2]) / np.linalg.norm(grid[2, 4] - grid[2, 2])
    result = metrics.line_residuals(grid[2:3])
    assert result.straight_rms_px == pytest.approx(0.0, abs=1e-6)
    assert result.spacing_rms_px > 0.05


def test_missing_corners_are_skipped_and_short_lines_do_not_count():
    grid = projective_grid(3, 5)
    grid[:, 1:] = np.nan
    result = metrics.line_residuals(grid)
    assert result.n_lines == 1  # only the first column keeps three points


def test_pooled_residuals_weight_boards_by_their_degrees_of_freedom():
    a = metrics.LineResiduals(1.0, 1.0, 30, 3, 24, 21)
    b = metrics.LineResiduals(0.0, 0.0, 10, 1, 8, 7)
    pooled = metrics.pool_line_residuals([a, b])
    assert pooled.straight_rms_px == pytest.approx(math.sqrt(24 / 32))
    assert pooled.spacing_rms_px == pytest.approx(math.sqrt(21 / 28))
    assert pooled.n_points == 40
    assert (pooled.straight_freedom, pooled.spacing_freedom) == (32, 28)


def test_line_and_spacing_residuals_recover_the_corners_noise_on_a_perfect_grid():
    # A 4x6 board (ValidationBoof's) seen square on, each corner off by sigma on each
    # axis: a row of four keeps two of its four squared errors across its line and one
    # along it, so the plain RMS read 0.76 and 0.61 sigma; over the residual degrees of
    # freedom both read sigma, as the lens model's does.
    rng = np.random.default_rng(0)
    columns, rows = np.meshgrid(40.0 * np.arange(4) + 100.0, 40.0 * np.arange(6) + 50.0)
    board = np.stack([columns, rows], axis=-1)
    sigma = 0.1
    pooled = metrics.pool_line_residuals(
        [metrics.line_residuals(board + rng.normal(0.0, sigma, board.shape)) for _ in range(500)]
    )
    assert pooled.straight_rms_px == pytest.approx(sigma, rel=0.03)
    assert pooled.spacing_rms_px == pytest.approx(sigma, rel=0.03)
    assert pooled.straight_plain_rms_px == pytest.approx(sigma * math.sqrt(28 / 48), rel=0.03)


# --------------------------------------------------------------------------- lens model

_IMAGE_SHAPE = (960, 1280)


def through_a_radial_lens(grid: np.ndarray, k1: float) -> np.ndarray:
    """``grid`` moved along its rays from the image centre by 1 + k1 r^2 (r in half-diagonals)."""
    centre = np.array([(_IMAGE_SHAPE[1] - 1) / 2, (_IMAGE_SHAPE[0] - 1) / 2])
    offset = (grid - centre) / (np.hypot(*_IMAGE_SHAPE) / 2)
    return centre + (grid - centre) * (1.0 + k1 * (offset**2).sum(axis=-1, keepdims=True))


def test_a_board_through_a_barrel_lens_bends_its_rows_but_fits_its_lens_model_exactly():
    grid = through_a_radial_lens(projective_grid(7, 9, (150.0, 120.0)), k1=-0.2)
    assert metrics.line_residuals(grid).straight_rms_px > 0.5
    residuals = metrics.lens_model_residuals(grid, _IMAGE_SHAPE)
    assert residuals.shape == (63, 2)
    np.testing.assert_allclose(residuals, 0.0, atol=1e-6)


def test_the_residual_about_the_lens_model_is_the_corners_rms_error():
    rng = np.random.default_rng(3)
    noise_px = 0.05  # per coordinate: an RMS error of 0.0707 px a corner
    grids = [
        through_a_radial_lens(projective_grid(7, 9, (100.0 + 60 * k, 80.0 + 30 * k)), k1=-0.15)
        + rng.normal(0.0, noise_px, (7, 9, 2))
        for k in range(12)
    ]
    pooled = metrics.pool_lens_model_residuals(grids, [_IMAGE_SHAPE] * len(grids))
    assert pooled.rms_px == pytest.approx(np.sqrt(2) * noise_px, rel=0.08)
    assert (pooled.n_points, pooled.n_boards) == (12 * 63, 12)


def test_boards_with_fewer_corners_than_the_lens_model_has_parameters_are_left_out():
    small = projective_grid(3, 3, (200.0, 200.0))
    assert len(metrics.lens_model_residuals(small, _IMAGE_SHAPE)) == 0
    pooled = metrics.pool_lens_model_residuals([small], [_IMAGE_SHAPE])
    assert math.isnan(pooled.rms_px) and pooled.n_boards == 0


def test_a_board_seen_only_along_one_row_is_left_out_of_the_lens_model():
    grid = projective_grid(3, 16, (100.0, 200.0))
    grid[[0, 2]] = np.nan
    assert len(metrics.lens_model_residuals(grid, _IMAGE_SHAPE)) == 0


def test_on_a_rendered_chessboard_the_residual_about_the_lens_model_is_our_rms_error():
    """A pinhole view of a planar board: the model holds, and what it leaves is the error."""
    (family,) = [f for f in accuracy.families() if f.key == "e"]
    scene = family.render(0)
    truth = scene.centres.reshape(10, 10, 2)
    low, high = family.radius_range
    detector = Detector(DetectorConfig(marker_radius_min_px=low, marker_radius_max_px=high))
    found = metrics.grid_positions(truth, positions(detector.detect(scene.image)))
    error = np.linalg.norm(found - truth, axis=2)
    assert np.isfinite(error).all()
    pooled = metrics.pool_lens_model_residuals([found], [scene.image.shape])
    assert pooled.rms_px == pytest.approx(np.sqrt(np.mean(error**2)), rel=0.1)


def test_grid_positions_places_each_detection_at_its_corner():
    grid = projective_grid(3, 4)
    detections = grid.reshape(-1, 2)[[5, 0, 11]] + 0.1
    placed = metrics.grid_positions(grid, detections)
    assert np.isfinite(placed).all(axis=2).sum() == 3
    np.testing.assert_allclose(placed[1, 1], grid[1, 1] + 0.1)


def test_order_grid_recovers_rows_and_columns_from_shuffled_points():
    grid = projective_grid(6, 4)
    shuffled = np.random.default_rng(1).permutation(grid.reshape(-1, 2))
    ordered = metrics.order_grid(shuffled, (4, 6))
    assert ordered is not None
    assert ordered.shape == (6, 4, 2)
    residuals = metrics.line_residuals(ordered)
    assert residuals.straight_rms_px == pytest.approx(0.0, abs=1e-9)


def test_order_grid_refuses_points_of_another_pattern():
    assert metrics.order_grid(projective_grid(5, 5).reshape(-1, 2), (4, 6)) is None


# --------------------------------------------------------------------------- peer helpers


def test_mrgingham_output_is_parsed_and_failures_give_no_points():
    text = "# filename x y level\nimg.png 10.5 20.25 0\nimg.png 11 21 1\nother.png - - -\n"
    np.testing.assert_allclose(parse_mrgingham(text), [[10.5, 20.25], [11.0, 21.0]])
    assert parse_mrgingham("# filename x y level\nimg.png - - -\n").shape == (0, 2)


def test_cornersubpix_window_follows_the_smallest_radius_within_limits():
    assert subpix_half_window((6.0, 40.0)) == 4
    assert subpix_half_window((2.5, 5.0)) == 2
    assert subpix_half_window((30.0, 60.0)) == 10
