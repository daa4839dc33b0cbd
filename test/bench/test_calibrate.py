"""The decision's calibration (bench.calibrate) and the board areas it leaves out."""

from __future__ import annotations

import numpy as np
from scenes import SMALL_SCENE

from marker_localizer import Detector, DetectorConfig
from marker_localizer.bench import calibrate, real_data
from marker_localizer.synthetic import render_checkerboard, render_scene


def test_the_exponential_tail_recovers_the_rate_and_scale_of_exponential_scores():
    rng = np.random.default_rng(0)
    scores = 2.0 + rng.exponential(0.5, 20_000)
    threshold, rate, scale = calibrate.exponential_tail(scores, megapixels=100.0)
    assert threshold == np.sort(scores)[::-1][calibrate.TAIL_POINTS]
    assert rate == calibrate.TAIL_POINTS / 100.0
    # 25 excesses know the scale to ~20 %: two standard errors.
    assert abs(scale - 0.5) <= 0.4 * 0.5


def test_candidates_inside_an_excluded_area_are_neither_marker_nor_texture():
    scene = render_scene(SMALL_SCENE, 0)
    config = DetectorConfig(
        marker_radius_min_px=6.0, marker_radius_max_px=20.0, refinement="template"
    )
    verdicts = Detector(config).detect(scene.image).verdicts
    assert verdicts is not None
    left = np.zeros(scene.image.shape[:2], bool)
    left[:, : scene.image.shape[1] // 2] = True
    everywhere = calibrate.collect(verdicts, 6.0, scene.centres)[1]
    outside_left = calibrate.collect(verdicts, 6.0, scene.centres, left)[1]
    x = verdicts.xy[:, 0]
    # Markers and texture on both halves: the area has something to leave out.
    for half in (x < 239, x > 240):
        assert (everywhere[half] == 1).any() and (everywhere[half] == 0).any()
    assert (outside_left[x < 239] == -1).all()
    np.testing.assert_array_equal(outside_left[x > 240], everywhere[x > 240])


def test_a_boards_area_holds_every_corner_and_its_outer_squares_but_not_the_ground_beyond():
    board = render_checkerboard((360, 480), (5, 4), 36.0, seed=3)
    area = real_data.board_mask(board.image.shape, board.centres.reshape(4, 5, 2))
    (left, top), (right, bottom) = board.centres.min(axis=0), board.centres.max(axis=0)
    middle = (left + right) / 2.0
    col, row = np.round(board.centres).astype(int).T
    assert area[row, col].all()
    # One square beyond the outer corners, on every side, and at the corners too.
    for x, y in [(middle, top - 36), (middle, bottom + 36), (left - 36, 180), (right + 36, 180)]:
        assert area[round(y), round(x)]
    assert area[round(top - 25), round(left - 25)]
    # Two squares beyond: ground.
    for x, y in [(middle, top - 72), (middle, bottom + 72), (left - 72, 180), (right + 72, 180)]:
        assert not area[round(y), round(x)]
