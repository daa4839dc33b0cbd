"""What a detector pass gives back, and where a tracking pass searches."""

import re

import numpy as np
import pytest
from scenes import checker_2x2

from marker_localizer import Detector, DetectorConfig
from marker_localizer.core import decision, second_reading
from marker_localizer.core.result import (
    CAP_COUNTS,
    SECOND_READING_CAP_COUNTS,
    TABLE_COLUMNS,
    DetectionResult,
    SearchPlan,
    detections_of,
    extents,
    line_directions,
    positions,
    scores,
    sigmas,
    strongest_first,
)
from marker_localizer.synthetic import SceneConfig, render_scene


def test_detections_are_built_row_by_row_in_the_order_given():
    detections = detections_of(
        xy=np.array([[10.5, 20.25], [3.0, 4.0]]),
        score=np.array([0.9, 0.7]),
        sigma=np.array([0.01, 0.02]),
        line_angles=np.array([[0.1, 1.7], [0.2, 1.8]]),
        radius_px=np.array([12.0, 6.0]),
        evidence=np.array([0.95, 0.8]),
    )
    first, second = detections
    assert (first.x, first.y, first.score, first.sigma) == (10.5, 20.25, 0.9, 0.01)
    assert (first.angle1, first.angle2, first.radius_px, first.evidence) == (0.1, 1.7, 12.0, 0.95)
    assert (second.x, second.y, second.evidence) == (3.0, 4.0, 0.8)
    assert all(type(value) is float for value in vars(first).values())
    np.testing.assert_array_equal(positions(detections), [[10.5, 20.25], [3.0, 4.0]])
    np.testing.assert_array_equal(extents(detections), [12.0, 6.0])
    np.testing.assert_array_equal(line_directions(detections), [[0.1, 1.7], [0.2, 1.8]])
    np.testing.assert_array_equal(scores(detections), [0.9, 0.7])
    np.testing.assert_array_equal(sigmas(detections), [0.01, 0.02])
    assert positions([]).shape == line_directions([]).shape == (0, 2)
    assert extents([]).shape == scores([]).shape == sigmas([]).shape == (0,)


def test_the_rows_kept_come_strongest_first():
    score = np.array([0.2, 0.9, 0.5, 0.7])
    np.testing.assert_array_equal(strongest_first(np.array([0, 2, 3]), score), [3, 2, 0])
    assert strongest_first(np.zeros(0, np.intp), score).shape == (0,)


def test_rows_of_equal_score_keep_the_order_they_were_given_in():
    # Forty rows, ten to each of four scores: past the length at which numpy's
    # default sort stops being an insertion sort and moves equal keys.
    levels = np.array([0.2, 0.9, 0.5, 0.7])
    score = np.repeat(levels, 10)
    rows = np.random.default_rng(0).permutation(len(score))
    expected = np.concatenate([rows[score[rows] == level] for level in np.sort(levels)[::-1]])
    np.testing.assert_array_equal(strongest_first(rows, score), expected)


def test_arrays_of_unequal_rows_are_refused():
    with pytest.raises(ValueError):
        detections_of(
            np.zeros((2, 2)), np.zeros(1), np.zeros(2), np.zeros((2, 2)), np.zeros(2), np.zeros(2)
        )


def test_a_result_iterates_and_tabulates_its_detections():
    result = DetectionResult(
        detections=detections_of(
            np.array([[1.0, 2.0]]),
            np.array([0.5]),
            np.array([0.1]),
            np.array([[0.0, 1.5]]),
            np.array([7.0]),
            np.array([0.6]),
        )
    )
    assert len(result) == 1 and result[0].x == 1.0 and [d.y for d in result] == [2.0]
    np.testing.assert_array_equal(result.as_array(), [[1.0, 2.0, 0.5, 0.1, 0.0, 1.5, 7.0]])
    assert TABLE_COLUMNS == ("x", "y", "score", "sigma", "angle1", "angle2", "radius_px")
    assert DetectionResult().as_array().shape == (0, 7)
    assert positions([]).shape == (0, 2)


def test_the_named_readers_take_a_result_and_read_the_columns_of_its_table():
    """Code reads a result by field, not by column number: the two agree."""
    result = Detector(DetectorConfig()).detect(checker_2x2(96))
    assert len(result) == 1
    table = result.as_array()
    column = {name: table[:, k] for k, name in enumerate(TABLE_COLUMNS)}
    np.testing.assert_array_equal(positions(result), np.c_[column["x"], column["y"]])
    np.testing.assert_array_equal(scores(result), column["score"])
    np.testing.assert_array_equal(sigmas(result), column["sigma"])
    np.testing.assert_array_equal(
        line_directions(result), np.c_[column["angle1"], column["angle2"]]
    )
    np.testing.assert_array_equal(extents(result), column["radius_px"])


def test_a_search_plan_of_the_wrong_shape_is_refused_with_its_name():
    with pytest.raises(ValueError, match=r"SearchPlan.regions of shape \(3,\) is not \(N, 4\)"):
        SearchPlan(regions=np.array([0, 0, 8]))
    with pytest.raises(ValueError, match=r"SearchPlan.seeds holds a NaN or infinite position"):
        SearchPlan(seeds=np.array([[np.nan, 3.0]]))
    # Its size a multiple of the columns, a transpose or a 3-D array was read as rows.
    with pytest.raises(ValueError, match=r"SearchPlan.known of shape \(2, 4\) is not \(N, 2\)"):
        SearchPlan(known=np.zeros((2, 4)))
    with pytest.raises(ValueError, match=r"SearchPlan.seeds of shape \(1, 2, 2\)"):
        SearchPlan(seeds=np.zeros((1, 2, 2)))


def test_plans_and_results_compare_by_identity_not_by_their_arrays():
    # A dataclass's == compared the arrays and raised on their truth value.
    plan, result = SearchPlan(), DetectionResult()
    assert plan == plan and plan != SearchPlan() and hash(plan) == hash(plan)
    assert result == result and result != DetectionResult()


def test_a_search_plan_holds_its_own_typed_copies():
    regions = np.array([[0.0, 0.0, 64.0, 48.0]])
    plan = SearchPlan(regions=regions, known=[[5, 6]])
    regions[0, 0] = 99.0
    assert plan.regions.dtype == np.int64 and plan.regions[0, 0] == 0
    assert plan.known.dtype == np.float64 and plan.known.shape == (1, 2)
    assert plan.seeds.shape == (0, 2)


@pytest.mark.parametrize(
    "config",
    [DetectorConfig(), DetectorConfig(refinement="template"), DetectorConfig(refinement="ncc")],
    ids=["default", "template", "ncc"],
)
def test_every_count_a_pass_reports_is_named_where_the_counts_are_described(config):
    """``DetectionResult.counts`` is the user's account of each stage: no key unexplained."""
    image = checker_2x2(96)
    detector = Detector(config)
    found = detector.detect(image)
    tracked = detector.locate(
        image,
        positions(found),
        extents(found),
        line_directions(found),
        np.array([d.evidence for d in found]),
    )
    assert len(found) == len(tracked) == 1
    described = set(re.findall(r"``([a-z_]+)``", DetectionResult.__doc__ or ""))
    described |= {f"rejected_{reason}" for reason in decision.REASONS}
    assert set(found.counts) | set(tracked.counts) <= described


def test_every_cap_a_pass_reports_is_summed_where_the_diagnostics_show_the_caps():
    """Nothing a cap leaves unread goes without a figure: busy ground fills the caps of
    the screening, of the checks and of the second readings (the dull reading's too)."""
    counts = Detector(DetectorConfig()).detect(render_scene(SceneConfig(), 1).image).counts
    caps = {key for key in counts if "_over_" in key and key.endswith("cap")}
    assert caps == set(CAP_COUNTS) | set(SECOND_READING_CAP_COUNTS)
    assert counts["dull_read"] == second_reading.MAX_DULL_READ
    assert counts["dull_over_cap"] > 0
