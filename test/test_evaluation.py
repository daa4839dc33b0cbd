"""Specification of scoring detections against truth (marker_localizer.evaluation)."""

from __future__ import annotations

import math
import tracemalloc

import numpy as np
import pytest
from scipy import stats

from marker_localizer import evaluation

# --------------------------------------------------------------------------- matching


def test_a_detection_0p3_px_off_has_error_0p3():
    matching = evaluation.match_points(np.array([[10.3, 20.0]]), np.array([[10.0, 20.0]]))
    assert matching.n_matched == 1
    assert matching.errors_px[0] == pytest.approx(0.3)


def test_a_detection_beyond_the_gate_is_a_false_positive_and_the_truth_is_missed():
    matching = evaluation.match_points(np.array([[50.0, 50.0]]), np.array([[10.0, 10.0]]), 2.0)
    assert matching.n_matched == 0
    assert matching.n_false_positives == 1
    assert matching.unmatched_detections.tolist() == [0]


def test_a_second_detection_on_the_same_marker_is_a_false_positive():
    truth = np.array([[10.0, 10.0]])
    detections = np.array([[10.5, 10.0], [10.1, 10.0]])
    matching = evaluation.match_points(detections, truth)
    assert matching.n_matched == 1
    assert matching.detection_index.tolist() == [1]
    assert matching.n_false_positives == 1


def test_matching_is_one_to_one_and_minimises_the_total_distance():
    truth = np.array([[0.0, 0.0], [1.5, 0.0]])
    detections = np.array([[1.0, 0.0], [2.2, 0.0]])
    matching = evaluation.match_points(detections, truth)
    pairs = dict(zip(matching.truth_index.tolist(), matching.detection_index.tolist(), strict=True))
    assert pairs == {0: 0, 1: 1}


def test_nan_detections_never_match():
    matching = evaluation.match_points(np.array([[np.nan, np.nan]]), np.array([[0.0, 0.0]]))
    assert matching.n_matched == 0
    assert matching.n_false_positives == 1


def test_matching_with_no_detections_reports_every_truth_missed():
    matching = evaluation.match_points(np.empty((0, 2)), np.array([[1.0, 1.0], [5.0, 5.0]]))
    assert (matching.n_matched, matching.n_truth, matching.n_false_positives) == (0, 2, 0)


def test_nearest_distances_measures_to_the_closest_target():
    d = evaluation.nearest_distances(
        np.array([[0.0, 0.0], [10.0, 0.0]]), np.array([[3.0, 4.0], [10.0, 1.0]])
    )
    np.testing.assert_allclose(d, [5.0, 1.0])


# --------------------------------------------------------------------------- statistics


def test_error_stats_of_known_errors():
    stats = evaluation.ErrorStats.from_errors([0.05, 0.1, 0.2, 0.4])
    assert stats.count == 4
    assert stats.mean == pytest.approx(0.1875)
    assert stats.rms == pytest.approx(math.sqrt((0.0025 + 0.01 + 0.04 + 0.16) / 4))
    assert stats.max == pytest.approx(0.4)
    assert stats.within_fine == pytest.approx(0.5)
    assert stats.p95 == pytest.approx(np.percentile([0.05, 0.1, 0.2, 0.4], 95))


def test_error_stats_of_nothing_are_nan():
    stats = evaluation.ErrorStats.from_errors([])
    assert stats.count == 0
    assert math.isnan(stats.mean)


def test_tally_counts_recall_and_false_positives_per_frame():
    tally = evaluation.DetectionTally()
    truth = np.array([[0.0, 0.0], [10.0, 0.0]])
    tally.add(evaluation.match_points(np.array([[0.1, 0.0], [40.0, 40.0]]), truth))
    tally.add(evaluation.match_points(np.array([[0.0, 0.2], [10.0, 0.1], [80.0, 0.0]]), truth))
    assert tally.recall == pytest.approx(3 / 4)
    assert tally.fp_per_frame == pytest.approx(1.0)
    assert tally.stats.mean == pytest.approx((0.1 + 0.2 + 0.1) / 3)


def test_a_recall_interval_holds_the_recall_and_narrows_as_markers_are_added():
    low, high = evaluation.recall_interval(47, 48)
    assert low < 47 / 48 < high <= 1.0
    # Wilson's interval of 47 of 48 at 95 %: 0.891-0.996.
    assert (low, high) == pytest.approx((0.891, 0.996), abs=1e-3)
    ten_times_the_markers = evaluation.recall_interval(470, 480)
    assert ten_times_the_markers[1] - ten_times_the_markers[0] < high - low


def test_a_recall_interval_reaches_the_ends_only_at_none_or_all_found():
    assert evaluation.recall_interval(0, 10)[0] == 0.0
    assert evaluation.recall_interval(10, 10)[1] == 1.0
    assert evaluation.recall_interval(10, 10, design_effect=3.0)[1] == 1.0
    assert evaluation.recall_interval(1, 10)[0] > 0.0
    assert evaluation.recall_interval(9, 10)[1] < 1.0
    assert all(math.isnan(b) for b in evaluation.recall_interval(0, 0))


def test_no_false_point_in_three_frames_still_allows_one_a_frame():
    # Exact Poisson: no event in 3 frames bounds the rate at -ln(0.025) / 3 a frame.
    assert evaluation.rate_interval(0, 3) == pytest.approx((0.0, -math.log(0.025) / 3))
    low, high = evaluation.rate_interval(1, 3)
    assert (low, high) == pytest.approx((0.00844, 1.857), rel=1e-3)
    assert all(math.isnan(b) for b in evaluation.rate_interval(2, 0))


def test_a_tally_gives_the_intervals_of_its_recall_and_false_points():
    tally = evaluation.DetectionTally()
    truth = np.array([[0.0, 0.0], [10.0, 0.0]])
    tally.add(evaluation.match_points(np.array([[0.1, 0.0], [40.0, 40.0]]), truth))
    tally.add(evaluation.match_points(np.array([[0.0, 0.2], [10.0, 0.1]]), truth))
    # One marker of two found on the first frame, both on the second: the recall's
    # residuals (-0.5, +0.5 markers) give 4/3 the variance of four independent
    # markers. One false point and none: less spread than Poisson counts, taken as 1.
    assert evaluation.frame_design_effect([1, 2], [2, 2]) == pytest.approx(4 / 3)
    assert tally.recall_design_effect == pytest.approx(4 / 3)
    assert tally.fp_dispersion == 1.0
    # Both spreads read from two frames: Student's t on one degree of freedom.
    assert tally.recall_interval == pytest.approx(
        evaluation.recall_interval(3, 4, design_effect=4 / 3, frames=2)
    )
    assert tally.fp_per_frame_interval == evaluation.rate_interval(1, 2, frames=2)


def test_a_recall_interval_matches_scipys_wilson_interval_at_any_count():
    for found, total in [(0, 7), (3, 7), (7, 7), (47, 48), (301, 600)]:
        wilson = stats.binomtest(found, total).proportion_ci(0.95, method="wilson")
        assert evaluation.recall_interval(found, total) == pytest.approx(
            (wilson.low, wilson.high), abs=1e-12
        )


def _tally(found_per_frame, truth_per_frame, false_per_frame) -> evaluation.DetectionTally:
    """A tally of frames whose first ``found`` truth points are found, in a row."""
    tally = evaluation.DetectionTally()
    for found, truth, false in zip(found_per_frame, truth_per_frame, false_per_frame, strict=True):
        points = np.column_stack([10.0 * np.arange(truth), np.zeros(truth)])
        far = np.column_stack([1000.0 + 10.0 * np.arange(false), np.zeros(false)])
        tally.add(evaluation.match_points(np.vstack([points[:found], far]), points))
    return tally


def test_markers_missed_together_on_one_frame_widen_the_recall_interval():
    # 36 of 40 both times: one missed on each frame, or all four on one.
    spread = _tally([9, 9, 9, 9], [10] * 4, [0] * 4)
    together = _tally([10, 10, 10, 6], [10] * 4, [0] * 4)
    assert spread.recall == together.recall == 0.9
    assert spread.recall_interval == pytest.approx(evaluation.recall_interval(36, 40, frames=4))
    low, high = together.recall_interval
    assert low < spread.recall_interval[0] and high > spread.recall_interval[1]
    assert low < 0.9 < high


def test_false_points_gathered_on_one_frame_widen_their_rate_interval():
    # Four false points in four frames: one on each, or all on one.
    even = _tally([1] * 4, [1] * 4, [1, 1, 1, 1])
    gathered = _tally([1] * 4, [1] * 4, [0, 0, 0, 4])
    assert even.fp_per_frame_interval == evaluation.rate_interval(4, 4, frames=4)
    # Variance 4 over a mean of 1: Garwood's interval on 1 event over 1 frame, times 4 / 4
    # (both then scaled alike for the four frames' degrees of freedom).
    assert evaluation.frame_dispersion([0, 0, 0, 4]) == pytest.approx(4.0)
    assert gathered.fp_per_frame_interval == pytest.approx(
        evaluation.rate_interval(4, 4, dispersion=4.0, frames=4)
    )
    assert evaluation.rate_interval(4, 4, dispersion=4.0) == pytest.approx(
        evaluation.rate_interval(1, 1)
    )
    low, high = gathered.fp_per_frame_interval
    assert low < even.fp_per_frame_interval[0] and high > even.fp_per_frame_interval[1]


def test_one_frame_or_none_missed_says_nothing_of_the_spread_between_frames():
    assert evaluation.frame_design_effect([3], [4]) == 1.0
    assert evaluation.frame_design_effect([4, 5], [4, 5]) == 1.0
    assert evaluation.frame_design_effect([0, 0], [4, 5]) == 1.0
    assert evaluation.frame_dispersion([0, 0, 0]) == 1.0
    assert evaluation.frame_dispersion([2]) == 1.0


def test_share_within_two_sigma_counts_errors_against_their_own_sigma():
    errors = np.array([0.01, 0.05, 0.2])
    sigmas = np.array([0.01, 0.01, 0.2])
    assert evaluation.share_within_sigma(errors, sigmas, 2.0) == pytest.approx(2 / 3)


def test_tally_keeps_the_sigma_of_the_matched_detection():
    tally = evaluation.DetectionTally()
    matching = evaluation.match_points(np.array([[90.0, 0.0], [0.03, 0.0]]), np.array([[0.0, 0.0]]))
    tally.add(matching, sigmas_px=np.array([5.0, 0.01]))
    assert list(tally.sigmas_px) == [0.01]
    assert tally.within_two_sigma == 0.0


def test_a_line_direction_error_pairs_the_lines_either_way_modulo_pi():
    truth = np.radians([[10.0, 100.0], [10.0, 100.0], [179.0, 60.0]])
    found = np.radians([[12.0, 99.0], [101.0, 7.0], [1.0, 60.5]])
    # In order: 2 and 1 degrees off; listed the other way round: 1 and 3; across 0/180: 2.
    np.testing.assert_allclose(
        evaluation.line_direction_errors_deg(found, truth), [2.0, 3.0, 2.0], atol=1e-9
    )


def test_tally_keeps_the_line_error_of_the_matched_detection_where_both_give_lines():
    truth = np.array([[0.0, 0.0]])
    matching = evaluation.match_points(np.array([[90.0, 0.0], [0.03, 0.0]]), truth)
    tally = evaluation.DetectionTally()
    tally.add(
        matching,
        line_angles=np.radians([[45.0, 135.0], [31.0, 120.0]]),
        truth_line_angles=np.radians([[30.0, 120.0]]),
    )
    tally.add(matching)  # a detector that reports no lines
    assert list(tally.line_errors_deg) == pytest.approx([1.0, np.nan], nan_ok=True)
    assert tally.median_line_error_deg == pytest.approx(1.0)
    assert np.isnan(evaluation.DetectionTally().median_line_error_deg)


def test_a_detection_on_an_excused_marker_counts_neither_way():
    truth = np.array([[10.0, 10.0], [30.0, 10.0]])
    found = np.array([[10.05, 10.0], [10.5, 10.0], [60.0, 60.0], [90.0, 5.0]])
    matching = evaluation.match_points(found, truth, 2.0, excused=np.array([[90.5, 5.0]]))
    assert (matching.n_truth, matching.n_matched) == (2, 1)
    assert matching.errors_px == pytest.approx([0.05])
    assert matching.excused_index.tolist() == [3]
    assert matching.unmatched_detections.tolist() == [1, 2]  # a duplicate, and nothing


def test_merged_tallies_sum_their_counts_and_keep_every_error():
    truth = np.array([[0.0, 0.0]])
    one, two = evaluation.DetectionTally(), evaluation.DetectionTally()
    one.add(evaluation.match_points(np.array([[0.1, 0.0]]), truth))
    two.add(evaluation.match_points(np.array([[5.0, 5.0]]), truth))
    both = evaluation.DetectionTally.merged([one, two])
    assert (both.frames, both.n_truth, both.n_matched, both.n_false_positives) == (2, 2, 1, 1)
    assert list(both.errors_px) == pytest.approx([0.1])
    assert list(both.found) == [1, 0]


def test_a_missed_marker_is_lost_at_the_first_test_that_leaves_no_candidate_near_it():
    survivors = [
        ("screening", np.array([[10.0, 10.0], [50.0, 50.0], [90.0, 90.0]])),
        ("prescreen", np.array([[10.5, 10.0], [51.0, 50.0]])),
        ("symmetry", np.array([[10.0, 10.2]])),
        ("fit", np.array([[10.0, 10.1]])),
    ]
    missed = np.array([[10.0, 10.0], [50.0, 50.0], [90.0, 90.0], [200.0, 5.0]])
    lost = evaluation.tests_that_lost(survivors, missed)
    assert lost == [evaluation.ASTRAY, "symmetry", "prescreen", "screening"]


def test_a_candidate_further_than_the_loss_radius_is_not_the_markers():
    survivors = [("screening", np.array([[10.0 + evaluation.LOSS_RADIUS_PX + 0.1, 10.0]]))]
    assert evaluation.tests_that_lost(survivors, np.array([[10.0, 10.0]])) == ["screening"]


def test_a_detection_is_added_by_the_first_reading_whose_list_holds_it():
    first_pass, recentred, plated = [10.0, 10.0], [50.0, 50.0], [90.0, 90.0]
    survivors = [
        # A test's list inside a reading claims nothing: only the readings' lists do.
        ("fit", np.array([first_pass, recentred])),
        ("lattice", np.array([first_pass])),
        ("recentring", np.array([first_pass, recentred])),
        ("plate", np.array([first_pass, recentred, plated])),
    ]
    detections = np.array([plated, first_pass, recentred, [200.0, 5.0]])
    readings = {"lattice": "first pass", "recentring": "recentring", "plate": "plate"}
    added = evaluation.readings_that_added(survivors, detections, readings)
    assert added == ["plate", "first pass", "recentring", evaluation.UNLISTED]


def test_a_listed_position_further_than_the_added_radius_is_not_the_detections():
    listed = [10.0 + evaluation.ADDED_RADIUS_PX + 0.1, 10.0]
    survivors = [("lattice", np.array([listed])), ("plate", np.array([[10.0, 10.0]]))]
    detection = np.array([[10.0, 10.0]])
    readings = {"lattice": "first pass", "plate": "plate"}
    assert evaluation.readings_that_added(survivors, detection, readings) == ["plate"]


def test_a_tally_keeps_a_matched_marker_in_at_most_40_bytes():
    """replay of an hour of five cameras with truth keeps every error for its percentiles:
    8-byte values (before, Python floats in lists: 140 bytes a matched marker); where the
    truth names its markers, each truth point's id in 4 bytes more (a uint32, not 8)."""
    rng = np.random.default_rng(0)
    truth = rng.uniform(0.0, 1000.0, (15, 2))
    matching = evaluation.match_points(truth[:14] + rng.normal(0.0, 0.02, (14, 2)), truth)
    sigmas, bounds = rng.uniform(0.01, 0.03, 14), rng.uniform(0.005, 0.02, 15)
    angles, truth_angles = rng.uniform(0.0, np.pi, (14, 2)), rng.uniform(0.0, np.pi, (15, 2))
    frames = 2000
    kept = {}
    for ids in (None, np.arange(15)):
        tally = evaluation.DetectionTally()
        tracemalloc.start()
        try:
            before = tracemalloc.get_traced_memory()[0]
            for _ in range(frames):
                tally.add(matching, sigmas, 0.1, bounds, angles, truth_angles, ids)
            kept[ids is not None] = tracemalloc.get_traced_memory()[0] - before
        finally:
            tracemalloc.stop()
        assert tally.n_matched == 14 * frames
        assert tally.clustered_by_marker == (ids is not None)
        assert tally.stats.mean == pytest.approx(float(np.mean(matching.errors_px)))
    assert kept[False] / tally.n_matched <= 40
    # 4.2 bytes measured: the array's room to grow over the 4.
    assert (kept[True] - kept[False]) / tally.n_truth <= 5


def test_an_infinite_bound_gives_no_error_over_bound_rather_than_zero():
    # crlb_mean_abs_error gives inf for singular information; the mean bound is then
    # inf, and err/CRLB has no value (printed "-"), not 0.00.
    tally = evaluation.DetectionTally()
    matching = evaluation.Matching(np.array([0, 1]), np.array([0, 1]), np.array([0.05, 0.04]), 2, 2)
    tally.add(matching, truth_crlb_px=np.array([0.01, np.inf]))
    assert tally.mean_crlb_px == math.inf
    assert math.isnan(tally.error_over_crlb)
    finite = evaluation.DetectionTally()
    finite.add(matching, truth_crlb_px=np.array([0.01, 0.03]))
    assert finite.error_over_crlb == pytest.approx(0.045 / 0.02)


def test_a_spread_read_from_a_few_frames_takes_students_t_on_their_degrees_of_freedom():
    # Four frames: t on 3 degrees of freedom (3.18) for the normal 1.96, whether the
    # design effect came out over its floor of 1 or under it, so the interval does not
    # jump where the estimate meets the floor.
    assert evaluation.interval_quantile(frames=4) == pytest.approx(stats.t.ppf(0.975, 3))
    assert evaluation.interval_quantile(frames=1) == pytest.approx(stats.norm.ppf(0.975))
    just_over = evaluation.recall_interval(30, 40, design_effect=1.0 + 1e-9, frames=4)
    at_floor = evaluation.recall_interval(30, 40, design_effect=1.0, frames=4)
    assert just_over == pytest.approx(at_floor)
    assert at_floor[0] < evaluation.recall_interval(30, 40)[0]
    # No false point in four frames: Garwood's 3.69 / 4 a frame, times (3.18 / 1.96)^2.
    ratio = (stats.t.ppf(0.975, 3) / stats.norm.ppf(0.975)) ** 2
    assert evaluation.frame_rate_interval([0, 0, 0, 0]) == pytest.approx(
        (0.0, -math.log(0.025) / 4 * ratio)
    )


def _recall_coverage(rng, frames, markers, recall, correlation, draws):
    """Share of draws whose interval holds the recall; each frame's recall a Beta draw."""
    shape = 1.0 / correlation - 1.0 if correlation else math.inf
    covered = 0
    for _ in range(draws):
        per_frame = (
            rng.beta(recall * shape, (1.0 - recall) * shape, frames)
            if correlation
            else np.full(frames, recall)
        )
        found = rng.binomial(markers, per_frame)
        low, high = evaluation.frame_recall_interval(found, [markers] * frames)
        covered += low <= recall <= high
    return covered / draws


def _rate_coverage(rng, frames, mean, shape, draws):
    """Share of draws whose interval holds the rate; counts gamma-Poisson (shape 0: Poisson)."""
    covered = 0
    for _ in range(draws):
        rates = rng.gamma(shape, mean / shape, frames) if shape else np.full(frames, mean)
        low, high = evaluation.frame_rate_interval(rng.poisson(rates).tolist())
        covered += low <= mean <= high
    return covered / draws


@pytest.mark.parametrize(
    ("frames", "markers", "recall", "correlation"),
    [
        (4, 12, 0.5, 0.0),
        (4, 12, 0.5, 0.1),
        (3, 12, 0.9, 0.1),
        (4, 30, 0.67, 0.1),
        (4, 30, 0.67, 0.2),
        (24, 12, 0.5, 0.1),
    ],
)
def test_the_recall_interval_covers_its_level_where_the_frames_spread(
    frames, markers, recall, correlation
):
    # The benchmark's sizes: 3-4 frames of 12-30 markers, each frame's recall drawn
    # around the true one (intra-frame correlation 0-0.2). With the normal quantile,
    # as before, 0.86-0.94 of 5000 intervals held the recall where the frames spread.
    rng = np.random.default_rng(frames * 1000 + markers)
    assert _recall_coverage(rng, frames, markers, recall, correlation, 1000) >= 0.93


@pytest.mark.parametrize(
    ("frames", "mean", "shape"),
    [(4, 2.0, 0.0), (4, 2.0, 1.0), (3, 10.0, 1.0), (4, 10.0, 2.0), (24, 2.0, 1.0), (4, 1.5, 0.3)],
)
def test_the_false_point_interval_covers_its_level_where_the_frames_spread(frames, mean, shape):
    # False points per frame gamma-Poisson (shape 0: Poisson); with the normal
    # quantile, as before, 0.75-0.93 of 5000 intervals held the rate where they gather.
    rng = np.random.default_rng(frames * 1000 + int(10 * mean))
    assert _rate_coverage(rng, frames, mean, shape, 1000) >= 0.93


# --------------------------------------------------------------------------- markers seen again


def _wilson(found: int, total: int, design_effect: float, quantile: float) -> tuple[float, float]:
    """Wilson's score interval on total / design_effect trials, written out."""
    n, p, z2 = total / design_effect, found / total, quantile**2
    centre = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = math.sqrt(z2 * (p * (1 - p) / n + z2 / (4 * n * n))) / (1 + z2 / n)
    return centre - half, centre + half


def _sightings(tally, frames_of_ids, found_ids, named=True):
    """Add frames whose truth are the markers ``frames_of_ids``; ``found_ids`` are found."""
    for ids in frames_of_ids:
        truth = np.column_stack([10.0 * np.asarray(ids, float), np.zeros(len(ids))])
        found = truth[[i in found_ids for i in ids]]
        matching = evaluation.match_points(found, truth)
        tally.add(matching, truth_marker_ids=np.asarray(ids) if named else None)


def _one_marker_flight() -> evaluation.DetectionTally:
    """Marker 7 in ten frames, missed in the fourth."""
    tally = evaluation.DetectionTally()
    truth = np.array([[70.0, 0.0]])
    for frame in range(10):
        found = truth[:0] if frame == 3 else truth
        tally.add(evaluation.match_points(found, truth), truth_marker_ids=np.array([7]))
    return tally


def _three_marker_flight() -> evaluation.DetectionTally:
    """Marker 7 found in the four frames it is in, 9 and 11 missed in their two each."""
    tally = evaluation.DetectionTally()
    _sightings(tally, [[7, 9], [7, 9], [7, 11], [7, 11]], {7})
    return tally


def test_a_marker_seen_in_many_frames_is_one_cluster_of_the_recall_interval():
    # Marker 7 found in all four frames it is in, 9 and 11 missed in the two each is in:
    # every frame finds one of two, so the frames do not spread, but the markers do.
    tally = _three_marker_flight()
    assert tally.clustered_by_marker
    # Per marker (found, truth): (4, 4), (0, 2), (0, 2); recall 4 / 8. Residuals
    # 4 - 2, 0 - 1, 0 - 1 give 3 / 2 x 6 / 8^2 against 0.25 / 8: a design effect of
    # 4.5, read from 3 markers, so Student's t on 2 degrees of freedom.
    assert evaluation.marker_counts(
        np.asarray(tally.found, bool), np.asarray(tally.marker_ids)
    ) == (
        [4, 0, 0],
        [4, 2, 2],
    )
    assert tally.recall_design_effect == pytest.approx(4.5)
    expected = _wilson(4, 8, 4.5, stats.t.ppf(0.975, 2))
    assert tally.recall_interval == pytest.approx(expected, abs=1e-12)
    assert evaluation.marker_recall_interval(tally.found, tally.marker_ids) == pytest.approx(
        expected, abs=1e-12
    )
    # By frame, as where the truth names no marker: no spread, t on 3 degrees of freedom.
    by_frame = evaluation.DetectionTally()
    _sightings(by_frame, [[7, 9], [7, 9], [7, 11], [7, 11]], {7}, named=False)
    assert not by_frame.clustered_by_marker
    assert by_frame.recall_interval == pytest.approx(
        _wilson(4, 8, 1.0, stats.t.ppf(0.975, 3)), abs=1e-12
    )
    low, high = tally.recall_interval
    assert low < by_frame.recall_interval[0] and high > by_frame.recall_interval[1]


def test_one_marker_seen_in_many_frames_is_one_trial_of_the_recall_interval():
    """A landing pad seen in 10 frames and found in 9: one marker, however often seen,
    not 10 independent trials (Wilson's interval of 9 of 10 is 0.60-0.98)."""
    tally = _one_marker_flight()
    expected = _wilson(9, 10, 10.0, stats.norm.ppf(0.975))
    assert tally.recall_interval == pytest.approx(expected, abs=1e-12)
    assert expected[1] - expected[0] > 0.7
    # The design effect said beside the interval is the one it is widened by.
    assert tally.recall_design_effect == 10.0


@pytest.mark.parametrize(
    ("flight", "quantile"),
    [(_one_marker_flight, stats.norm.ppf(0.975)), (_three_marker_flight, stats.t.ppf(0.975, 2))],
    ids=["one marker", "three markers"],
)
def test_the_recall_design_effect_reported_is_the_one_its_interval_is_widened_by(flight, quantile):
    tally = flight()
    expected = _wilson(tally.n_matched, tally.n_truth, tally.recall_design_effect, quantile)
    assert tally.recall_interval == pytest.approx(expected, abs=1e-12)


def test_tallies_merged_cluster_by_marker_only_where_every_truth_point_names_one():
    # Two cameras that see marker 7: one cluster in the merged tally.
    cam0, cam1, unnamed = (evaluation.DetectionTally() for _ in range(3))
    _sightings(cam0, [[7, 9]], {7})
    _sightings(cam1, [[7, 11]], {7})
    _sightings(unnamed, [[7, 11]], {7}, named=False)
    both = evaluation.DetectionTally.merged([cam0, cam1])
    assert both.clustered_by_marker
    assert evaluation.marker_counts(np.asarray(both.found, bool), np.asarray(both.marker_ids)) == (
        [2, 0, 0],
        [2, 1, 1],
    )
    assert not evaluation.DetectionTally.merged([cam0, unnamed]).clustered_by_marker
    assert not evaluation.DetectionTally().clustered_by_marker
    with pytest.raises(ValueError, match="1 marker ids for 2 truth points"):
        cam0.add(evaluation.match_points(np.empty((0, 2)), np.zeros((2, 2))), truth_marker_ids=[3])


def _model_flight_coverage(rng, flights, frames, moves_every):
    """Share of model flights whose recall interval holds the recall, by marker and by frame.

    The audit's model of a flight: 30 markers on the ground, each found with its own
    probability q ~ Beta(2, 0.5) (mean 0.8, the recall of a flight over other markers)
    in every frame that sees it; each frame sees 12 of them, a window that moves one
    marker along every ``moves_every`` frames.
    """
    covered = {"marker": 0, "frame": 0}
    for _ in range(flights):
        q = rng.beta(2.0, 0.5, 30)
        seen = (np.arange(12)[None, :] + np.arange(frames)[:, None] // moves_every) % 30
        found = rng.random(seen.shape) < q[seen]
        tally = evaluation.DetectionTally()
        for ids, hits in zip(seen, found, strict=True):
            index = np.flatnonzero(hits)
            matching = evaluation.Matching(index, index, np.zeros(len(index)), len(ids), len(index))
            tally.add(matching, truth_marker_ids=ids)
        by_frame = evaluation.frame_recall_interval(tally.found_per_frame, tally.truth_per_frame)
        for kind, (low, high) in (("marker", tally.recall_interval), ("frame", by_frame)):
            covered[kind] += low <= 0.8 <= high
    return {kind: n / flights for kind, n in covered.items()}


def test_the_recall_interval_of_model_flights_clustered_by_marker_covers_its_level():
    # The audit's flights (scratch /tmp/s120/evalaudit/replay_deff.py) shortened to 60
    # frames whose window moves every 2 (all 30 markers still seen, each in ~24 frames).
    # On 2000 flights 0.962 of the intervals held the recall (0.943 on the audit's 300
    # frames); by frame, as before the truth named its markers, 0.562 (0.257).
    coverage = _model_flight_coverage(np.random.default_rng(3), 400, 60, 2)
    assert coverage["marker"] >= 0.92
    assert coverage["frame"] <= 0.7
