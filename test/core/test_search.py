"""Section 3.2's first layers as the detector runs them: on the frame or in regions."""

import numpy as np
import pytest

from marker_localizer.config import DetectorConfig
from marker_localizer.core import search
from marker_localizer.core.image import to_gray
from marker_localizer.core.search import CandidateSearch
from marker_localizer.synthetic import SceneConfig, render_scene


@pytest.fixture(scope="module")
def frame():
    return to_gray(render_scene(SceneConfig(), 12).image)


def test_a_region_over_the_whole_frame_screens_what_the_frame_does(frame):
    gray, white = frame
    search = CandidateSearch(DetectorConfig())
    full = search.screen(gray, white, {})
    height, width = gray.shape
    for region in ([0, 0, width, height], [-50, -50, width + 50, height + 50]):
        part = search.screen(gray, white, {}, np.array([region]))
        np.testing.assert_array_equal(part.xy, full.xy)


def test_a_regions_candidates_lie_inside_it(frame):
    gray, white = frame
    region = np.array([[256, 192, 768, 576]])
    part = CandidateSearch(DetectorConfig()).screen(gray, white, {}, region)
    assert len(part) > 50
    assert np.all((part.xy >= [256, 192]) & (part.xy < [768, 576]))


def test_a_small_region_is_screened_at_every_pyramid_level_the_frame_is(frame):
    # A tracking window a few pixels wide, as the tracker asks around a marker its fit
    # missed: its crop is too small to be reduced as often as the frame, but the
    # frame's coarsest level finds its candidates there too (before, a dull marker's
    # only candidate that passes the prescreen, at that level, was missing).
    gray, white = frame
    search = CandidateSearch(DetectorConfig())
    full = search.screen(gray, white, {})
    coarsest = full.scale_px.max()
    assert coarsest > full.scale_px.min()
    for x, y in full.xy[full.scale_px == coarsest][:20]:
        x0, y0 = int(x) - 4, int(y) - 4
        part = search.screen(gray, white, {}, np.array([[x0, y0, x0 + 8, y0 + 8]]))
        same_level = part.xy[part.scale_px == coarsest]
        assert len(same_level) and np.hypot(*(same_level - [x, y]).T).min() < 0.01


@pytest.mark.parametrize(
    "region",
    [[-20, -20, -15, -15], [-50, 100, -1, 200], [2000, 100, 2100, 200]],
    ids=["above and left", "left", "right"],
)
def test_a_region_wholly_beyond_the_frame_holds_no_candidate(frame, region):
    # A tracked marker's region once it has left the view.
    gray, white = frame
    counts: dict[str, int] = {}
    found = CandidateSearch(DetectorConfig()).screen(gray, white, counts, np.array([region]))
    assert len(found) == 0 and counts["candidates"] == 0


def test_a_candidate_closer_than_the_separation_to_a_known_marker_is_that_markers():
    known = np.array([[100.0, 100.0], [300.0, 50.0]])
    xy = np.array([[103.0, 100.0], [100.0, 104.9], [100.0, 105.1], [300.0, 45.0], [10.0, 10.0]])
    np.testing.assert_array_equal(
        search.near_known(xy, known, separation_px=5.0), [True, True, False, False, False]
    )
    assert search.near_known(xy, np.zeros((0, 2)), 5.0).tolist() == [False] * 5
    assert search.near_known(np.zeros((0, 2)), known, 5.0).shape == (0,)
