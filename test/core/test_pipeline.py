"""The Detector end to end: analytic images, rendered frames, input handling.

Also the default path's checks and second readings; the paper's path and the
template path have their own files (test_paper_path.py, test_template_path.py).
"""

import collections
import dataclasses
import itertools
import multiprocessing
import pickle
import threading
import warnings
from collections.abc import Iterable
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from typing import Any

import cv2
import numpy as np
import pytest
from scenes import (
    SMALL_SCENE,
    TEMPLATE_DECISION,
    checker_2x2,
    faint_tilted_markers,
    found_false_errors,
    neutral_and_coloured_xs,
    through_demosaicing,
)
from scipy.spatial import cKDTree
from shared_data import SHARED_DATA, needs_shared_data

from marker_localizer import Detector, DetectorConfig, evaluation
from marker_localizer.bench import real_data
from marker_localizer.bench.accuracy import (
    DISC_LATTICE_RADIUS_RANGE,
    Family,
    disc_lattice_frame,
    families,
    wider_range,
)
from marker_localizer.bench.ground import x_tiling_frame
from marker_localizer.core import (
    acceptance,
    paper_path,
    plate,
    second_reading,
    shadow,
    subpixel,
    symmetry_path,
    template_path,
    verification,
)
from marker_localizer.core.result import CAP_COUNTS, SearchPlan, extents, positions
from marker_localizer.core.tracking import MarkerTracker
from marker_localizer.errors import ImageError
from marker_localizer.synthetic import (
    MarkerPlacement,
    SceneConfig,
    render_checkerboard,
    render_markers,
    render_scene,
)
from marker_localizer.synthetic.flight import FlightConfig, FlightSimulator


def test_the_corner_of_a_2x2_checkerboard_is_exactly_between_the_four_pixels():
    result = Detector().detect(checker_2x2())
    assert len(result) == 1
    assert result[0].x == pytest.approx(31.5, abs=1e-3)
    assert result[0].y == pytest.approx(31.5, abs=1e-3)
    assert 0 < result[0].sigma < 0.05


def test_detections_carry_both_line_angles_and_the_marker_extent():
    d = Detector().detect(checker_2x2())[0]
    assert sorted([d.angle1, d.angle2]) == pytest.approx([0.0, np.pi / 2], abs=0.02) or sorted(
        [d.angle1, d.angle2]
    ) == pytest.approx([np.pi / 2, np.pi], abs=0.02)
    assert d.radius_px >= 16


def test_cluttered_frames_meet_the_core_targets():
    """Issue 2: recall >= 95 %, mean error <= 0.05 px, <= 1 false positive per frame.

    Over twelve frames: the ground's texture saddles come a few frames at a time (on
    these, five false points in two of the twelve).
    """
    frames = [render_scene(SceneConfig(), seed) for seed in range(11, 23)]
    detector = Detector(DetectorConfig(marker_radius_min_px=6.0, marker_radius_max_px=40.0))
    found = false = total = 0
    errors = []
    for scene in frames:
        hits, misses, err = found_false_errors(detector.detect(scene.image), scene.centres)
        found, false, total = found + hits, false + misses, total + len(scene.centres)
        errors.extend(err)
    assert found / total >= 0.95
    assert np.mean(errors) <= 0.05
    assert false / len(frames) <= 1.0


def test_reported_line_directions_follow_the_markers_lines(cluttered_frames):
    """Each detection's two angles are the images of the marker's axes, tilt and all."""
    detector = Detector(DetectorConfig(marker_radius_min_px=6.0, marker_radius_max_px=40.0))
    worst = []
    for scene in cluttered_frames:
        found = detector.detect(scene.image)
        distance, index = cKDTree(scene.centres).query(positions(found))
        for detection, d, i in zip(found, distance, index, strict=True):
            if d > 1.5:
                continue
            truth = np.array([scene.markers[i].angles])
            measured = np.array([[detection.angle1, detection.angle2]])
            worst.append(float(verification.line_pair_difference(measured, truth)[0]))
    assert len(worst) >= 30
    assert np.median(worst) < np.deg2rad(3.0)
    assert max(worst) < np.deg2rad(12.0)


def test_the_papers_ncc_refinement_is_selectable_and_less_precise(cluttered_frames):
    scene = cluttered_frames[0]
    base = dict(marker_radius_min_px=6.0, marker_radius_max_px=40.0)
    _, _, paper = found_false_errors(
        Detector(DetectorConfig(refinement="ncc", **base)).detect(scene.image),
        scene.centres,
    )
    _, _, ours = found_false_errors(
        Detector(DetectorConfig(**base)).detect(scene.image), scene.centres
    )
    assert len(paper) >= 0.9 * len(scene.centres)
    assert np.mean(paper) < 0.25
    assert np.mean(ours) < np.mean(paper)


def _markers_found(detector: Detector, image: np.ndarray, centres: np.ndarray) -> set[int]:
    """Indices of the ``centres`` with a detection within 2 px (the benchmark's match)."""
    distance, index = cKDTree(centres).query(
        positions(detector.detect(image)), distance_upper_bound=2.0
    )
    return set(index[np.isfinite(distance)].tolist())


def _found_only_at_the_looser_range(
    family: Family, looser: tuple[float, float], seeds: Iterable[int]
) -> list[tuple[int, int]]:
    """(seed, marker) of the family's frames found at ``looser`` but not at its own range."""
    given, loose = (
        Detector(DetectorConfig(marker_radius_min_px=r_min, marker_radius_max_px=r_max))
        for r_min, r_max in (family.radius_range, looser)
    )
    lost = []
    for seed in seeds:
        scene = family.render(seed)
        found = [_markers_found(d, scene.image, scene.centres) for d in (given, loose)]
        lost += [(seed, k) for k in found[1] - found[0]]
    return lost


def _two_rows_of_four_found(
    seed: int, spacing_px: float, radius_px: tuple[float, float], min_radius_px: float, **light: Any
) -> tuple[int, int]:
    """Markers found and false points on eight markers ``spacing_px`` apart, drawn in ``light``.

    Checkers and quarter disks in turn, tilted up to 30 degrees, read at
    ``min_radius_px``-40 px.
    """
    rng = np.random.default_rng(seed)
    placements = [
        MarkerPlacement(
            spacing_px * (0.5 + i % 4),
            spacing_px * (0.5 + i // 4),
            rng.uniform(*radius_px),
            rng.uniform(0.0, np.pi),
            rng.uniform(0.0, 30.0),
            0.7,
            ("checker", "quarter_disks")[i % 2],
        )
        for i in range(8)
    ]
    shape = (round(2 * spacing_px), round(4 * spacing_px))
    scene = render_markers(shape, placements, seed, **light)
    detector = Detector(
        DetectorConfig(marker_radius_min_px=min_radius_px, marker_radius_max_px=40.0)
    )
    found, false, _ = found_false_errors(detector.detect(scene.image), scene.centres)
    return found, false


@pytest.mark.parametrize("seed", range(2))
def test_faint_markers_blurred_past_their_innermost_rings_floor_are_found(seed):
    """Paint 0.14 apart on dull ground, blurred by 1.8 px, as in a frame's dim corner.

    The rings at 2 and 2.8 px, where a run of rings must start, see less than the
    20 DN floor; the blur explains it, and the rings past them clear it.
    """
    found_false = _two_rows_of_four_found(
        seed,
        100.0,
        (12.0, 24.0),
        4.0,
        reflectances=(0.22, 0.36),
        blur_sigma_px=1.8,
        noise_sigma_dn=1.0,
        background_level=0.3,
    )
    assert found_false == (8, 0)


@pytest.mark.parametrize("seed", range(2))
def test_markers_in_a_dark_surround_whose_black_paint_sits_at_the_sensors_floor_are_found(seed):
    """White paint at 18 % of full scale, black at none, on ground at 10 %, 3.5 DN of noise.

    An underexposed corner of a frame: its black paint reads 0-10 DN, noise and the
    floor of the sensor's range. Eq. (2) brightens the dark surround; a power
    stronger than a square root would spread those levels over half the range and
    turn the lines the innermost rings read (with a clip of 1/4: 0-2 of 8 found).
    """
    found_false = _two_rows_of_four_found(
        seed,
        120.0,
        (12.0, 30.0),
        6.0,
        reflectances=(0.0, 0.18),
        blur_sigma_px=0.7,
        noise_sigma_dn=3.5,
        background_level=0.1,
    )
    assert found_false == (8, 0)


@pytest.mark.parametrize(
    "view",
    [
        pytest.param(("a", (4.0, 40.0)), id="(a) 6-40 px against the default 4-40"),
        pytest.param(("b", (2.0, 6.0)), id="(b) 2.5-5 px against 2-6"),
    ],
)
def test_a_tighter_correct_radius_range_never_loses_a_marker(view):
    """Issue 12, item 5: a family's own range against a looser one, seeds 0-5.

    Every marker found with the looser range is found with the tighter one: the
    small-marker score floor follows texture's size, not the range, and the
    prescreen's rings the level's. (b) at 2-6 px finds the same markers as at
    2.5-5 on seeds 0-23 too; (a) at 4-40 finds one more there (seed 16, below).
    Further below, the flight simulator's tilted markers are held to it at 6-24 px
    against 4-30.
    """
    key, looser = view
    family = next(f for f in families() if f.key == key and not f.variant)
    assert _found_only_at_the_looser_range(family, looser, range(6)) == []


_WIDER_RANGE_FINDS = [
    pytest.param(
        ("a", (16,)),
        id="(a) seed 16: a 14.4 px marker, under its floor at 6-40, found from level 0 at 4.8-50",
    ),
    pytest.param(
        ("b", (21,)),
        id="(b) seed 21: a 3.8 px marker, lost at 2.5-5's prescreen, found from level 1 at 2-6.25",
    ),
    pytest.param(
        ("c", (8, 18)),
        id="(c) seeds 8, 18: lost at 6-40, found at 4.8-50 from level 0 and on a 4.8 px rung",
    ),
    pytest.param(
        ("d", (106, 107)),
        id="(d) seeds 106, 107: an 8.4 px marker read 4.0 px at 4-40, another lost at the gate",
    ),
    pytest.param(
        ("g", (3,)),
        id="(g) seed 3: two markers with a dull quadrant, found at 4-37.5 by their plate (4 px)",
    ),
]


@pytest.mark.xfail(
    strict=True,
    reason="issue 12, item 5: the range sets the ring ladder's rungs and the levels searched",
)
@pytest.mark.parametrize("view", _WIDER_RANGE_FINDS)
def test_a_tighter_correct_radius_range_keeps_every_marker_a_wider_one_finds(view):
    """Issue 12, item 5, where it does not hold yet: each family's own range against the
    benchmark's wider one (:func:`accuracy.wider_range`, a quarter wider either way).

    Not yet true. The ring ladder starts at half the smallest radius, so the two
    ranges read a marker on different rungs, and the extent read sets its score
    floor and whether it is a tiny X for the plate reading; the smallest radius
    also sets the first pyramid level searched, and the largest the last ((b)'s
    6.25 px adds level 1). A marker near a gate crosses it on one ladder and not
    the other, either way: on development seeds 0-23 the own range finds 4, 2, 3,
    11 and 9 markers of (a), (b), (c), (d) and (g) that the wider one does not,
    and loses 1, 1, 3, 2 and 7 that it finds (docs/accuracy-journal.md, "Item 5 on every
    family"). (d)'s seed 106 marker (8.4 px, 5.0 at its shortest) reads 4.0 px at
    4-40, a small marker's floor, and 6.4 px at 3.2-50; seed 107's reads 5.66 px
    at 4-40, where the modulation gate reads its paint and fails it, and 4.53 px
    at 3.2-50. Strict: the fix that makes a view pass removes it here.
    """
    key, seeds = view
    family = next(f for f in families() if f.key == key and not f.variant)
    assert _found_only_at_the_looser_range(family, wider_range(family.radius_range), seeds) == []


_TIGHTER_RANGE_VIEWS = [
    pytest.param((11, 8, 1, 4), id="seed 11: a 9.4 px marker, 5.6 px at its shortest"),
    pytest.param((19, 4, 3, 3), id="seed 19: a 9.0 px marker, 5.2 px at its shortest"),
    pytest.param((37, 4, 0, 4), id="seed 37: a 9.1 px marker, 5.4 px at its shortest"),
]


@pytest.mark.parametrize("view", _TIGHTER_RANGE_VIEWS)
def test_a_tighter_correct_radius_range_keeps_the_flight_simulators_tilted_markers(view):
    """Issue 12, item 5, on the flight simulator's rig: 6-24 px instead of 4-30 px.

    The rig shows its markers at 8.4-17.3 px, so both ranges are correct. From a
    6 px minimum the first level searched is the pyramid's second, and these
    steeply seen markers are narrow for it. Seed 11's candidate lies 0.6 px off:
    the prescreen's rings, held to the level's own scale, still show its X. Seed
    19's saddle peak is narrower than a level pixel, where parabolas left its
    candidate 0.8 px off; its centroid places it 0.23 px off. Seed 37's candidate
    lies 0.03 px off, and the rings of a range from 3 px show its X on to 12 px,
    past the marker, at a fifth of its contrast: the run ends at its first dim
    ring, where the template of that extent matches.
    """
    seed, n_frames, frame, camera_index = view
    flight = FlightSimulator(FlightConfig(width=1280, height=960, n_frames=n_frames), seed=seed)
    camera = flight.render(frame).cameras[camera_index]
    centres = np.array([(m.x, m.y) for m in camera.markers])
    loose, tight = (
        _markers_found(
            Detector(DetectorConfig(marker_radius_min_px=r_min, marker_radius_max_px=r_max)),
            camera.image,
            centres,
        )
        for r_min, r_max in ((4.0, 30.0), (6.0, 24.0))
    )
    assert loose <= tight


def test_every_stage_reports_its_count_and_time(cluttered_frames):
    result = Detector().detect(cluttered_frames[1].image)
    for key in (
        "candidates",
        "after_suppression",
        "rejected_symmetry",
        "rejected_template",
        "rejected_lines",
        "rejected_refinement",
        "rejected_score",
        "rejected_x_end",
        "accepted",
    ):
        assert key in result.counts
    assert result.counts["accepted"] == len(result)
    assert set(result.timings_ms) >= {"preprocessing", "screening", "verification", "subpixel"}


@pytest.mark.parametrize("max_candidates", [50, 1_000_000])
def test_every_candidate_the_screenings_caps_cut_is_counted_whenever_it_is_cut(max_candidates):
    """Cut early (busy ground sets the frame cap's floor in the screening) or late alike;
    the pixels the floor spared the look for peaks are counted too."""
    noise = np.random.default_rng(4).normal(128, 40, (256, 320))
    image = np.clip(noise, 0, 255).astype(np.uint8)
    config = DetectorConfig(
        marker_radius_min_px=3.0, marker_radius_max_px=30.0, max_candidates=max_candidates
    )
    counts = Detector(config).detect(image).counts
    prescreened = counts["rejected_prescreen"] + counts["dropped_over_verification_cap"]
    passed = counts["after_suppression"] - counts["dropped_over_cap"]
    assert passed == min(max_candidates, counts["after_suppression"])
    assert prescreened <= passed <= counts["after_suppression"] <= counts["candidates"]
    # The frame's cap as a floor: everything over 50 is cut, and counted.
    assert counts["dropped_over_cap"] == (
        counts["after_suppression"] - 50 if max_candidates == 50 else 0
    )
    if max_candidates == 50:
        assert counts["unexamined_below_floor"] > 10 * counts["candidates"] > 1000
    else:
        assert counts["unexamined_below_floor"] == 0 and counts["candidates"] > 10_000


@pytest.mark.parametrize("cap", [1, 2, 3])
def test_a_frame_cap_of_one_to_three_candidates_keeps_that_many_and_counts_the_rest(cap):
    """The cap's floor is sought among a sample of the peaks: at least its strongest."""
    noise = np.random.default_rng(4).normal(128, 40, (256, 320))
    config = DetectorConfig(marker_radius_min_px=3.0, marker_radius_max_px=30.0, max_candidates=cap)
    counts = Detector(config).detect(np.clip(noise, 0, 255).astype(np.uint8)).counts
    assert counts["after_suppression"] > cap
    assert counts["after_suppression"] - counts["dropped_over_cap"] == cap


def test_more_xs_than_the_costly_checks_take_are_cut_over_the_frame_and_counted():
    """A tiling of X's passes every check: the cap after the ring checks bounds the work."""
    image = x_tiling_frame(seed=1, shape=(400, 900))
    detector = Detector(DetectorConfig(marker_radius_min_px=3.0, marker_radius_max_px=30.0))
    result = detector.detect(image)
    found = positions(result)
    # Each of the cap's X's is a marker but for a few whose neighbours' sectors
    # carry their pattern on beyond their extent: those the X-end gate counts.
    assert len(found) + result.counts["rejected_x_end"] == symmetry_path.MAX_CONFIRMED
    assert result.counts["rejected_x_end"] < 0.05 * symmetry_path.MAX_CONFIRMED
    assert result.counts["dropped_over_verification_cap"] > 1000
    # Spread over the frame: every 100 px column band keeps its share.
    per_band = np.bincount((found[:, 0] // 100).astype(int), minlength=9)
    assert per_band.min() >= 0.5 * len(found) / 9


def test_a_frame_tiled_with_xs_reads_at_most_the_caps_plates_and_counts_the_rest():
    """Thinned to the cap over a wider frame, no X has a board's neighbour near: all ask
    for their plate, and those over acceptance.MAX_PLATE_ASKED are rejected unread."""
    image = x_tiling_frame(seed=1, shape=(1200, 1600))
    detector = Detector(DetectorConfig(marker_radius_min_px=3.0, marker_radius_max_px=30.0))
    result = detector.detect(image)
    counts = result.counts
    assert counts["plate_asked_over_cap"] > acceptance.MAX_PLATE_ASKED
    assert counts["plate_asked_over_cap"] <= counts["rejected_quartic"]
    rejected = counts["rejected_x_end"] + counts["rejected_quartic"]
    assert len(result) + rejected == symmetry_path.MAX_CONFIRMED
    assert "plate_asked_over_cap" in CAP_COUNTS


def test_markers_already_located_are_not_searched_again_but_the_others_are(cluttered_frames):
    """Tracking mode passes the markers the fit confirmed as ``known``."""
    detector = Detector(DetectorConfig(marker_radius_min_px=6.0, marker_radius_max_px=40.0))
    image = cluttered_frames[0].image
    full = positions(detector.detect(image))
    known, others = full[::2], full[1::2]
    height, width = image.shape[:2]
    plan = SearchPlan(regions=np.array([[0, 0, width, height]]), known=known)
    result = detector.detect(image, plan)
    found = positions(result)
    assert result.counts["skipped_known"] >= len(known)
    assert len(found) == len(others)
    assert np.abs(np.sort(found, axis=0) - np.sort(others, axis=0)).max() < 1e-9


def test_seeded_markers_take_the_full_passs_stages_and_end_at_its_centres(cluttered_frames):
    """Tracking mode seeds markers the border cuts at their predicted centres."""
    detector = Detector(DetectorConfig(marker_radius_min_px=6.0, marker_radius_max_px=40.0))
    image = cluttered_frames[1].image
    full = positions(detector.detect(image))
    texture = np.array([[5.0, 5.0], [600.0, 20.0]])  # no marker there
    seeds = np.vstack([full + [0.4, -0.3], texture])
    result = detector.detect(image, SearchPlan(seeds=seeds))
    found = positions(result)
    distance, index = cKDTree(found).query(full)
    assert len(found) == len(full)
    assert distance.max() < 0.005
    assert len(np.unique(index)) == len(full)


def test_an_image_without_markers_gives_no_candidate_and_an_empty_result():
    result = Detector().detect(np.full((960, 1280), 90, np.uint8))
    assert len(result) == 0
    assert result.counts["candidates"] == 0  # no point reaches the costly stages


@pytest.mark.parametrize(
    "convert",
    [
        lambda g: cv2.cvtColor(g, cv2.COLOR_GRAY2BGR),
        lambda g: g.astype(np.uint16) * 257,  # mono16: white at 65535
        lambda g: g.astype(np.float32) / 255.0,
    ],
    ids=["bgr8", "mono16", "float"],
)
def test_colour_16_bit_and_float_images_are_converted_not_rejected(convert):
    result = Detector().detect(convert(checker_2x2()))
    assert len(result) == 1 and result[0].x == pytest.approx(31.5, abs=1e-3)


def test_on_a_colour_frame_small_xs_drawn_in_colour_are_rejected_and_counted():
    colour, grey, centres = neutral_and_coloured_xs()
    detector = Detector(DetectorConfig(marker_radius_min_px=4.0, marker_radius_max_px=12.0))
    assert _markers_found(detector, grey, centres) == set(range(8))
    result = detector.detect(colour)
    assert _markers_found(detector, colour, centres) == {0, 1, 2, 3}
    assert len(result) == 4 and result.counts["rejected_chroma"] == 4
    assert result.counts["accepted"] == 4 and result.survivors[-1][0] == "chroma"
    # The grey given with its colour planes beside it reads as the colour frame.
    beside = detector.detect(grey, colour=colour)
    assert [(d.x, d.y) for d in beside] == [(d.x, d.y) for d in result]
    assert detector.detect(grey).counts["rejected_chroma"] == 0
    # Float levels, float64 or undershooting 0 a little (clipped in the grey), and
    # big-endian words read the same.
    levels = colour / 255.0
    for same in (levels, levels - 0.03, (colour.astype(np.uint16) * 257).astype(">u2")):
        assert _markers_found(detector, same, centres) == {0, 1, 2, 3}
        tracked = MarkerTracker(detector).update(same, 1.0)
        assert tracked.counts["rejected_chroma"] == 4 and len(tracked) == 4
    grey_levels = detector.detect(grey / 255.0, colour=levels)
    assert grey_levels.counts["rejected_chroma"] == 4 and len(grey_levels) == 4
    off = Detector(detector.config.replace(max_x_chroma_share=100.0))
    assert _markers_found(off, colour, centres) == set(range(8))


@pytest.mark.parametrize(
    "demosaicing",
    [cv2.COLOR_BayerBG2BGR, cv2.COLOR_BayerBG2BGR_EA],
    ids=["bilinear", "edge-aware"],
)
def test_a_colour_cameras_demosaicing_costs_no_tiny_marker(demosaicing):
    """A raw mosaic demosaiced as image_proc does it, sent uncompressed (bgr8).

    Not VNG: OpenCV 4.6's (the lowest the package allows) gives a grey in which the
    detector finds half these markers.
    """
    rng = np.random.default_rng(1)
    places = [
        MarkerPlacement(
            30.0 + 40 * (k % 8) + rng.uniform(0, 1),
            30.0 + 40 * (k // 8) + rng.uniform(0, 1),
            float(rng.uniform(2.8, 4.6)),
            float(rng.uniform(0, np.pi)),
            float(rng.uniform(0, 45)),
            float(rng.uniform(0, np.pi)),
        )
        for k in range(32)
    ]
    scene = render_markers(
        (190, 340), places, 1, reflectances=(0.25, 0.75), blur_sigma_px=0.8, noise_sigma_dn=1.5
    )
    colour = through_demosaicing(scene.image, demosaicing)
    detector = Detector(DetectorConfig(marker_radius_min_px=2.5, marker_radius_max_px=5.0))
    in_grey = _markers_found(detector, cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY), scene.centres)
    assert len(in_grey) >= 28
    assert _markers_found(detector, colour, scene.centres) == in_grey


def test_tracked_colour_frames_leave_out_the_small_xs_drawn_in_colour_too():
    colour, _, centres = neutral_and_coloured_xs()
    detector = Detector(DetectorConfig(marker_radius_min_px=4.0, marker_radius_max_px=12.0))
    tracker = MarkerTracker(detector)
    for stamp in (1.0, 2.0, 3.0):
        result = tracker.update(colour, stamp)
        distance, nearest = cKDTree(centres).query(positions(result))
        assert sorted(nearest[distance < 1.0]) == [0, 1, 2, 3] and len(result) == 4
    assert result.counts["full_frame"] == 0 and result.counts["tracked"] == 4


@pytest.mark.parametrize(
    ("colour", "message"),
    [
        (np.zeros((64, 64), np.uint8), "must be an"),
        (np.zeros((32, 64, 3), np.uint8), "is not the colour of the grey image"),
        (np.zeros((64, 64, 3), np.uint16), "is not the colour of the grey image"),
    ],
)
def test_colour_planes_that_do_not_belong_to_the_grey_image_raise_a_clear_error(colour, message):
    with pytest.raises(ImageError, match=message):
        Detector().detect(checker_2x2(), colour=colour)
    with pytest.raises(ImageError, match="this image is colour"):
        Detector().detect(cv2.cvtColor(checker_2x2(), cv2.COLOR_GRAY2BGR), colour=colour)


@pytest.mark.parametrize(
    ("image", "message"),
    [
        (np.zeros((0, 10), np.uint8), "empty image"),
        (np.zeros((8, 8), np.complex64), "unsupported dtype complex64"),
        (np.zeros((8, 8, 2), np.uint8), "unsupported channel count 2"),
        (np.full((8, 8), np.nan, np.float32), "NaN"),
    ],
)
def test_bad_images_raise_a_clear_image_error(image, message):
    with pytest.raises(ImageError, match=message):
        Detector().detect(image)


@pytest.mark.parametrize(
    "config",
    [{"marker_radius_min_px": 12.0}, {}, DetectorConfig, 0],
    ids=["mapping", "empty-mapping", "the-class", "zero"],
)
def test_a_detector_refuses_settings_that_are_not_a_detector_config(config):
    """Not read as the defaults (the class, an empty mapping, 0) nor failing deep inside."""
    with pytest.raises(TypeError, match="DetectorConfig instance"):
        Detector(config)


def test_a_detectors_config_is_read_only_as_its_stages_keep_theirs():
    detector = Detector()
    with pytest.raises(AttributeError):
        detector.config = DetectorConfig(marker_radius_min_px=12.0)
    assert detector.config == DetectorConfig()


#: A detector on each of its paths: the default, the template decision, the paper's.
PATHS = {
    "default": DetectorConfig(),
    "template": DetectorConfig(refinement="template"),
    "curvature": DetectorConfig(candidate_detector="curvature"),
}


#: How far apart two threads' or two processes' detections of one frame may lie, in
#: their own units (px): a multithreaded BLAS may sum in another order from one call
#: to the next (OpenBLAS 0.3.23, numpy 1.26's, moves a detection by 4e-17 px between
#: threads, and by 1.4e-17 px between a test process and its workers, which agree to
#: the bit with one BLAS thread), and nothing else.
THREADS_ROUNDING = 1e-12


def _same_result(one, other, rounding: float = 0.0) -> bool:
    """Whether two results hold the same detections (to ``rounding``), counts and survivors."""

    def close(a: np.ndarray, b: np.ndarray) -> bool:
        return a.shape == b.shape and np.allclose(a, b, rtol=0.0, atol=rounding)

    return (
        close(one.as_array(), other.as_array())
        and one.counts == other.counts
        and [name for name, _ in one.survivors] == [name for name, _ in other.survivors]
        and all(close(a, b) for (_, a), (_, b) in zip(one.survivors, other.survivors, strict=True))
    )


@pytest.mark.parametrize("config", PATHS.values(), ids=PATHS.keys())
def test_threads_sharing_one_detector_get_what_each_call_gives_alone(config):
    """Four threads, each on its own frame, at once and again and again: what each gives alone.

    The detector's stages keep only what their config gives; the sample grids cached
    across calls (``functools.lru_cache``, thread-safe) are only read.
    """
    frames = [render_scene(SMALL_SCENE, seed).image for seed in (1, 2, 3, 4)]
    detector = Detector(config)
    together = threading.Barrier(len(frames))

    def detect_again_and_again(k: int) -> list:
        together.wait()
        return [detector.detect(frames[k]) for _ in range(3)]

    alone = [detector.detect(frame) for frame in frames]
    assert sum(len(result) for result in alone) >= len(frames)
    with ThreadPoolExecutor(len(frames)) as pool:
        shared = list(pool.map(detect_again_and_again, range(len(frames))))
    for one, others in zip(alone, shared, strict=True):
        assert all(_same_result(one, other, THREADS_ROUNDING) for other in others)
    # Nor did the threads leave anything behind for the next call.
    assert all(
        _same_result(one, detector.detect(f), THREADS_ROUNDING)
        for f, one in zip(frames, alone, strict=True)
    )


@pytest.mark.parametrize("method", ["fork", "spawn", "forkserver"])
def test_a_detector_sent_to_worker_processes_detects_there_what_it_does_here(method):
    """``ProcessPoolExecutor(...).map(detector.detect, frames)``: the detector is pickled."""
    if method not in multiprocessing.get_all_start_methods():
        pytest.skip(f"no {method} start method on this platform")
    config = DetectorConfig(marker_radius_min_px=6.0, marker_radius_max_px=20.0)
    detector = Detector(config)
    frames = [render_scene(SMALL_SCENE, seed).image for seed in (5, 6)]
    here = [detector.detect(frame) for frame in frames]
    assert sum(len(result) for result in here) >= len(frames)
    copy = pickle.loads(pickle.dumps(detector))
    assert type(copy) is Detector and copy.config == config
    assert all(_same_result(copy.detect(f), one) for f, one in zip(frames, here, strict=True))
    context = multiprocessing.get_context(method)
    with ProcessPoolExecutor(len(frames), mp_context=context) as pool:
        assert pool.submit(getattr, detector, "config").result() == config
        there = list(pool.map(detector.detect, frames))
    assert all(
        _same_result(one, other, THREADS_ROUNDING) for one, other in zip(here, there, strict=True)
    )


def _strip_across_an_x(height: int, width: int, seed: int) -> np.ndarray:
    """A noisy strip cut across a blurred X's centre: saddles, but no room for a ring."""
    x = checker_2x2(size=128).astype(np.float64)
    top, left = 64 - height // 2, 64 - width // 2
    strip = x[top : top + height, left : left + width]
    noise = np.random.default_rng(seed).normal(0.0, 20.0, strip.shape)
    return (strip + noise).clip(0, 255).astype(np.uint8)


@pytest.mark.parametrize(
    "shape",
    [(1, 1), (1, 64), (64, 1), (2, 52), (4, 51), (5, 5), (63, 2)],
    ids=lambda s: f"{s[0]}x{s[1]}",
)
@pytest.mark.parametrize(
    "config",
    [
        DetectorConfig(),
        DetectorConfig(refinement="template"),
        DetectorConfig(refinement="ncc"),
        DetectorConfig(candidate_detector="curvature"),
    ],
    ids=["default", "template", "ncc", "curvature"],
)
def test_images_narrower_than_a_marker_give_an_empty_result_on_every_path_and_entry(shape, config):
    """A crop or strip too small for any ring, one row or one column too: no marker,
    and no error or warning, whether screened, seeded, located or tracked."""
    detector = Detector(config)
    height, width = shape
    # The strip's centre, on the X's, and its far corner, where a ring reads the border.
    xy = np.array([[(width - 1) / 2, (height - 1) / 2], [width - 1.0, height - 1.0]])
    seeded = SearchPlan(regions=np.array([[0, 0, width, height]]), seeds=xy)
    lines = np.tile([np.pi / 4, 3 * np.pi / 4], (len(xy), 1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for seed in range(4):
            image = _strip_across_an_x(*shape, seed)
            assert len(detector.detect(image)) == len(detector.detect(image, seeded)) == 0
            assert len(detector.locate(image, xy, np.full(2, 8.0), lines, np.ones(2))) == 0
            assert len(MarkerTracker(detector).update(image, stamp_s=0.0)) == 0


# Uneven light: a dull quadrant, a shadow's edge (family (g)); both decisions.


def _uneven_light(seeds: tuple[int, ...]):
    family = next(f for f in families() if f.key == "g")
    return family.radius_range, [family.render(seed) for seed in seeds]


@pytest.fixture(scope="module")
def uneven_light_frames():
    return _uneven_light((1, 2))


@pytest.fixture(scope="module")
def read_again_frames():
    """(g) frames on which the lost wide candidates centred again and those read with a
    shadow's edge divided out each add markers the first pass does not find."""
    return _uneven_light((8, 9))


def _recall_and_false(config: DetectorConfig, frames) -> tuple[float, float]:
    detector = Detector(config)
    found = false = total = 0
    for scene in frames:
        hits, misses, _ = found_false_errors(detector.detect(scene.image), scene.centres)
        found, false, total = found + hits, false + misses, total + len(scene.centres)
    return found / total, false / len(frames)


def _wide_dull_markers(
    seeds,
    dull_factors,
    radii=(16, 28),
    radius_range=(10.0, 30.0),
    max_tilt_deg=40.0,
    blur_sigma_px=1.0,
):
    """Found and false points over frames of six markers, each with a dull quadrant."""
    found = false = 0
    for seed in seeds:
        rng = np.random.default_rng(seed)
        placements = [
            MarkerPlacement(
                160 + 320 * (i % 3) + rng.uniform(-20, 20),
                160 + 320 * (i // 3) + rng.uniform(-20, 20),
                rng.uniform(*radii),
                rng.uniform(0, np.pi),
                rng.uniform(0, max_tilt_deg),
                rng.uniform(0, np.pi),
                "quarter_disks",
                dull_factor=rng.uniform(*dull_factors),
                dull_quadrant=int(rng.integers(2)),
            )
            for i in range(6)
        ]
        scene = render_markers(
            (640, 960), placements, seed, blur_sigma_px=blur_sigma_px, noise_sigma_dn=2.0
        )
        config = DetectorConfig(
            marker_radius_min_px=radius_range[0], marker_radius_max_px=radius_range[1]
        )
        hits, misses, _ = found_false_errors(Detector(config).detect(scene.image), scene.centres)
        found, false = found + hits, false + misses
    return found, false


def _family_detector(family) -> Detector:
    """The default detector given a rendered family's radius range, as a user gives it."""
    return Detector(
        DetectorConfig(
            marker_radius_min_px=family.radius_range[0],
            marker_radius_max_px=family.radius_range[1],
        )
    )


def _found_and_counted(detector: Detector, frames: list, count: str) -> tuple[int, int, int]:
    """Markers found, false points, and the detector's ``count`` summed over ``frames``."""
    results = [detector.detect(scene.image) for scene in frames]
    scores = [found_false_errors(r, s.centres) for r, s in zip(results, frames, strict=True)]
    hits = sum(found for found, _, _ in scores)
    false = sum(false for _, false, _ in scores)
    return hits, false, sum(r.counts[count] for r in results)


def test_faint_small_markers_the_modulation_gate_rejects_are_kept_by_their_model(monkeypatch):
    # The gate asks the paint for a modulation of 0.3; these markers' is 0.2. Where
    # the X has ended, the blurred X explains the disk and the plate model holds,
    # they go on (20 of these 30 found; 7 with the gate alone, 6 of them those of
    # texture's size that their plate finds after the pass), and the texture gives no
    # false point more.
    frames = [faint_tilted_markers(seed) for seed in (0, 1)]
    detector = Detector(DetectorConfig(marker_radius_min_px=6.0, marker_radius_max_px=40.0))

    hits, false, kept = _found_and_counted(detector, frames, "kept_faint")
    monkeypatch.setattr(acceptance, "GATE_MIN_NCC", 1.1)
    gate_hits, gate_false, gate_kept = _found_and_counted(detector, frames, "kept_faint")
    assert gate_kept == 0
    assert kept >= 15
    assert hits >= gate_hits + 10
    assert false <= gate_false


def _matching(detector: Detector, frame) -> evaluation.Matching:
    """A rendered ``frame``'s detections matched to its markers as the benchmark matches
    them, within its 2 px (:func:`evaluation.match_points`)."""
    return evaluation.match_points(positions(detector.detect(frame.image)), frame.centres)


def _found_and_false(detector: Detector, frame, marker: int) -> tuple[bool, int]:
    """Whether ``marker`` of a rendered ``frame`` is found, and the frame's false points."""
    matching = _matching(detector, frame)
    return bool(marker in matching.truth_index), matching.n_false_positives


@pytest.mark.parametrize(("key", "seed", "marker"), [("a", 114, 11), ("c", 230, 7)])
def test_an_x_over_its_floor_whose_paint_alone_the_gate_doubts_is_vouched_for_at_looser_bars(
    monkeypatch, key: str, seed: int, marker: int
):
    # Families (a) and (c) at 6-40 px: a small tilted marker of a grey dark paint,
    # its rings over their floor, modulates under the gate's 0.3; the blurred X
    # matches it under the floor's 0.98 or leaves more than its 0.02. Only its paint
    # is in doubt, and at the gate's looser bars the marker's model vouches for it;
    # held to the floor's it is lost. The frame gains no false point.
    family = next(f for f in families() if f.key == key and not f.variant)
    frame = family.render(seed)
    detector = _family_detector(family)

    found, false = _found_and_false(detector, frame, marker)
    monkeypatch.setattr(acceptance, "GATE_MIN_NCC", acceptance.FAINT_MIN_NCC)
    monkeypatch.setattr(acceptance, "GATE_MAX_MISFIT", acceptance.FAINT_MAX_MISFIT)
    found_at_floor_bars, false_at_floor_bars = _found_and_false(detector, frame, marker)
    assert found and not found_at_floor_bars
    assert false <= false_at_floor_bars


def test_a_saddle_whose_dark_gaps_differ_is_not_scored_as_a_dull_marker(monkeypatch):
    # Family (a)'s seed 603 at 6-40 px: a saddle of 12 px between stones whose dark
    # pair differs as its bright pair does. Scored with both pairs' own levels it
    # clears its floor and is a false point; with the bright pair's alone (black
    # paint stays black) it is not, and no marker is lost.
    family = next(f for f in families() if f.key == "a" and not f.variant)
    frame = family.render(603)
    detector = _family_detector(family)

    def read() -> tuple[int, int]:
        matching = _matching(detector, frame)
        return len(matching.truth_index), matching.n_false_positives

    found, false = read()
    monkeypatch.setattr(subpixel, "_bright_pair_step", lambda steps, samples, weight: steps)
    found_both, false_both = read()
    assert found == found_both
    assert false < false_both


def test_small_tilted_markers_under_their_score_floor_are_kept_by_their_model(monkeypatch):
    # Family (d)'s clutter frames at 4-40 px: tilted markers whose rings measure
    # 5.7 px fit to 0.87-0.91, under the floor texture's saddles of that extent set.
    # Where the model holds they go on; the look-alikes and ground add no false
    # point (one marker more in each of these three frames).
    family = next(f for f in families() if f.key == "d" and not f.variant)
    frames = [family.render(seed) for seed in (204, 215, 223)]
    detector = _family_detector(family)

    hits, false, kept = _found_and_counted(detector, frames, "kept_under_floor")
    monkeypatch.setattr(acceptance, "FAINT_MIN_NCC", 1.1)
    floor_hits, floor_false, floor_kept = _found_and_counted(detector, frames, "kept_under_floor")
    assert floor_kept == 0
    assert kept >= 3
    assert hits >= floor_hits + 3
    assert false <= floor_false


def test_where_no_tiny_marker_is_expected_a_tiny_x_under_its_floor_is_a_tilted_markers(
    monkeypatch,
):
    # Family (c) at 6-40 px: a marker of 6.6 px whose rings measure 4.24 px, texture's
    # size, fits under that extent's floor. Its saddle stands out of its ground, which
    # passes it by the floors; read without its ground, as no tiny marker is expected
    # its plate is not read, and the model of a marker vouches for it instead.
    family = next(f for f in families() if f.key == "c" and not f.variant)
    frame = family.render(685)
    detector = _family_detector(family)

    result = detector.detect(frame.image)
    near = cKDTree(frame.centres).query(positions(result))[0] <= 2.0
    tiny = extents(result) < verification.X_END_MAX_EXTENT_PX
    assert (near & tiny).sum() >= 2 and not (~near).any()
    monkeypatch.setattr(acceptance, "MIN_SADDLE_OVER_GROUND", np.inf)
    vouched = detector.detect(frame.image)
    assert len(vouched) == len(result)
    assert vouched.counts["kept_under_floor"] >= 1
    monkeypatch.setattr(acceptance, "FAINT_MIN_NCC", 1.1)
    unvouched = detector.detect(frame.image).as_array()
    assert len(unvouched) == len(result) - vouched.counts["kept_under_floor"]


@pytest.mark.parametrize(
    ("key", "seed", "standing_out"), [("c", 685, 1), ("d", 109, 1), ("d", 101, 0)]
)
def test_the_detections_a_floor_kept_because_their_saddle_stands_out_are_counted(
    monkeypatch, key: str, seed: int, standing_out: int
):
    # Families (c) at 6-40 px and (d) at 4-40 px: markers whose X reads texture's
    # size score under a floor, and pass it because their saddle stands out of their
    # ground (c 685, d 109: one each). Held to the floors, and with the marker's model,
    # which vouches for such X's in their stead, held too, a frame loses exactly the
    # detections counted as kept for standing out or vouched for, and no other. An X
    # that the floor's allowance passes as clearly ended needed no standing out and is
    # not counted (d 101: two such, nothing lost).
    family = next(f for f in families() if f.key == key and not f.variant)
    frame = family.render(seed)
    detector = _family_detector(family)

    result = detector.detect(frame.image)
    monkeypatch.setattr(acceptance, "MIN_SADDLE_OVER_GROUND", np.inf)
    monkeypatch.setattr(acceptance, "FAINT_MIN_NCC", 1.1)
    held = detector.detect(frame.image)
    counts = result.counts
    assert held.counts["kept_standing_out"] == held.counts["kept_under_floor"] == 0
    assert {tuple(p) for p in positions(held)} <= {tuple(p) for p in positions(result)}
    assert len(held) == len(result) - counts["kept_standing_out"] - counts["kept_under_floor"]
    assert counts["kept_standing_out"] == standing_out


def test_a_marker_whose_rings_stop_a_rung_short_of_its_x_is_not_taken_for_texture():
    # Family (d)'s clutter frames at 4-40 px: markers of 7.1-8.1 px whose rings
    # measure 4 px, texture's size, and whose X goes on beyond that; it ends a ring
    # rung further out, within the expected radii, and there the last two show the
    # plate that the tiny markers' plate model, read at 4 px, misses.
    family = next(f for f in families() if f.key == "d" and not f.variant)
    detector = _family_detector(family)
    for seed, marker in ((214, 7), (221, 9), (205, 10), (206, 8)):
        frame = family.render(seed)
        assert frame.markers[marker].radius_px > 7.0
        found = positions(detector.detect(frame.image))
        assert np.hypot(*(found - frame.centres[marker]).T).min() <= 2.0


def test_texture_xs_that_barely_clear_their_floor_and_show_no_plate_are_rejected(monkeypatch):
    # Family (c)'s ground photographs at 6-40 px: texture X's of 6-12 px score
    # 0.006-0.007 over their floors and their plate model leaves 1.06-1.43 of a
    # quartic's residual, read at their extent and a rung out (two of these frames'
    # seven false points; OpenCV 5 renders them with nine, and two go too); the
    # markers found are the same with the plate asked or not.
    family = next(f for f in families() if f.key == "c" and not f.variant)
    frames = [family.render(seed) for seed in (603, 615, 618)]
    detector = _family_detector(family)

    hits, false, rejected = _found_and_counted(detector, frames, "rejected_quartic")
    monkeypatch.setattr(acceptance, "PLATE_DOUBT_MARGIN", -1.0)
    monkeypatch.setattr(acceptance, "PLATE_ASKED_MAX_EXTENT_PX", 0.0)
    unasked_hits, unasked_false, _ = _found_and_counted(detector, frames, "rejected_quartic")
    assert hits == unasked_hits
    assert rejected >= 2
    assert false <= unasked_false - 2


def test_texture_xs_near_their_floor_whose_plate_leaves_most_of_a_quartic_are_rejected(
    monkeypatch,
):
    # Families (a) and (d) at their ranges: four texture X's of 6-11 px clear their
    # floors by 0.007-0.026, and their plate model, read at their extent and a rung
    # out, leaves 0.87-0.99 of a quartic's residual at best: more than the markers
    # near their floors leave (up to 0.7 on the development frames, (g)'s shadowed
    # aside), under the 1.0 that texture of the tiny markers' size is held to.
    cases = [
        (next(f for f in families() if f.key == key and not f.variant), seed)
        for key, seed in (("a", 628), ("d", 118))
    ]
    frames = [family.render(seed) for family, seed in cases]
    detectors = [_family_detector(family) for family, _ in cases]

    def found() -> np.ndarray:
        return np.sum(
            [
                _found_and_counted(detector, [frame], "rejected_quartic")
                for detector, frame in zip(detectors, frames, strict=True)
            ],
            axis=0,
        )

    hits, false, rejected = found()
    monkeypatch.setattr(acceptance, "PLATE_DOUBT_MAX_TO_QUARTIC", plate.MAX_TO_QUARTIC_ANY)
    loose_hits, loose_false, loose_rejected = found()
    assert hits == loose_hits
    assert false <= loose_false - 4
    assert rejected >= loose_rejected + 4


@needs_shared_data
def test_chessboard_corners_near_their_floor_are_kept_by_their_neighbours(monkeypatch):
    # pycbd's warped board at 10-80 px: six corners, read at 57 px under squares of
    # 190 px, score just over their floor and have no plate (the squares go on); each
    # has a neighbouring corner within 4 extents, and all are kept.
    image = real_data.read_gray(SHARED_DATA / "pycbd" / "warped.jpg")
    detector = Detector(DetectorConfig(marker_radius_min_px=10.0, marker_radius_max_px=80.0))

    def corners() -> set[tuple[float, float]]:
        return {(round(d.x, 3), round(d.y, 3)) for d in detector.detect(image)}

    kept = corners()
    monkeypatch.setattr(acceptance, "BOARD_NEIGHBOUR_EXTENTS", 0.0)
    alone = corners()
    monkeypatch.setattr(acceptance, "PLATE_DOUBT_MARGIN", -1.0)
    monkeypatch.setattr(acceptance, "PLATE_ASKED_MAX_EXTENT_PX", 0.0)
    unasked = corners()
    assert kept == unasked
    assert len(unasked - alone) >= 5


def _line_errors_deg(detections, truth) -> np.ndarray:
    """Each detection's larger line error against the nearest truth's lines, degrees."""
    _, index = cKDTree(np.array([(m.x, m.y) for m in truth])).query(
        np.array([[d.x, d.y] for d in detections])
    )
    found = np.array([[d.angle1, d.angle2] for d in detections])
    expected = np.array([truth[k].angles for k in index])
    return np.degrees(verification.line_pair_difference(found, expected))


@pytest.mark.parametrize(("exposure", "least_found"), [(2.0, 291), (2.5, 270)])
def test_an_over_exposed_chessboard_keeps_its_corners_and_their_lines(exposure, least_found):
    # At twice the exposure the white squares clip: each edge's gradient moves to its
    # dark side, on a line's two halves to opposite sides, so a line read through the
    # centre is turned (3.7 degrees, median), and the blurred X, which never clips,
    # leaves 0.11 of a true corner's disk unexplained (median). With each half-line read
    # about its own mean and the clipped samples left out of the template, the corners
    # stand (114 of these 300 without). At 2.5 times the halves of different lines
    # cross over 2 px from the centre, and the double-line check reads the lines
    # midway between each line's halves (195 of 300 without).
    family = next(f for f in families() if f.key == "e")
    detector = _family_detector(family)
    found, errors = 0, []
    for seed in (100, 101, 102):
        scene = family.render(seed)
        exposed = np.clip(np.round(exposure * scene.image.astype(np.float64)), 0, 255)
        exposed = exposed.astype(np.uint8)
        result = detector.detect(exposed)
        hits, _, _ = found_false_errors(result, scene.centres)
        found += hits
        errors.append(_line_errors_deg(list(result), scene.markers))
    assert found >= least_found
    assert np.median(np.concatenate(errors)) < 1.0


def test_the_default_finds_wide_markers_with_a_dull_quadrant_and_no_texture_with_them():
    # Bright quadrants 0.45-0.6 as bright as their opposites on markers of 16-28 px:
    # the plain rings see two sectors, not four, and the centring is pulled 1-3 px
    # towards the brighter side. The equalised rings read where the X's lines cross,
    # the template match and the fit giving the quadrants their levels, find them
    # (0 of these 12 before the equalised rings, 5 before the lines' crossing, 11).
    found, false = _wide_dull_markers((0, 3), (0.45, 0.6))
    assert found >= 10
    assert false == 0


def test_wide_markers_the_centring_leaves_off_are_found_centred_with_the_light_slope():
    # Bright quadrants 0.45-0.7 as bright as their opposites on markers of 10-25 px
    # tilted up to 55 degrees: centred without the light's slope, some settle towards
    # the brighter side where the rings do not see them whole (31 of these 36 found
    # then); centred again with the slope where no marker was found, 34.
    found, false = _wide_dull_markers(range(6), (0.45, 0.7), (10, 25), (6.0, 30.0), 55.0)
    assert found >= 33
    assert false == 0


def test_lost_wide_candidates_read_again_are_counted_and_add_only_new_markers(
    read_again_frames,
):
    (low, high), frames = read_again_frames
    detector = Detector(DetectorConfig(marker_radius_min_px=low, marker_radius_max_px=high))
    recentred = shadowed = 0
    for scene in frames:
        result = detector.detect(scene.image)
        counts = result.counts
        assert 0 <= counts["found_recentred"] <= counts["recentred"]
        assert 0 <= counts["found_shadowed"] <= counts["shadow_read"]
        assert 0 <= counts["located_in_shadow"] <= counts["found_shadowed"]
        assert 0 <= counts["kept_dull"] <= counts["dull_read"]
        recentred += counts["found_recentred"]
        shadowed += counts["found_shadowed"]
        first = dict(result.survivors)["merging"]
        assert len(result) == len(first) + counts["found_recentred"] + counts["found_shadowed"]
        distance = cKDTree(positions(result)).query(positions(result), k=2)[0]
        assert len(result) < 2 or distance[:, 1].min() > detector.config.merge_radius_px
    assert recentred > 0 and shadowed > 0


def test_markers_a_shadows_edge_crosses_are_found_with_the_shadow_divided_out(monkeypatch):
    # Rendered (g) frames of markers of 10-30 px, whose lost candidates include markers
    # a hard shadow's edge crosses; with no edge ever found (an explained share over
    # 1), they stay lost.
    family = next(f for f in families() if f.key == "g")
    low, high = family.radius_range
    detector = Detector(DetectorConfig(marker_radius_min_px=low, marker_radius_max_px=high))
    scene = dataclasses.replace(family.scene, radius_px=(10.0, 30.0))
    frames = [render_scene(scene, seed) for seed in (5, 11)]
    with_edges = [found_false_errors(detector.detect(s.image), s.centres)[:2] for s in frames]
    added = sum(detector.detect(s.image).counts["found_shadowed"] for s in frames)
    monkeypatch.setattr(shadow, "MIN_EXPLAINED", 1.1)
    without = [found_false_errors(detector.detect(s.image), s.centres)[:2] for s in frames]
    assert sum(f for f, _ in with_edges) - sum(f for f, _ in without) == added >= 3
    assert sum(m for _, m in with_edges) == sum(m for _, m in without) == 0


def test_a_milder_dull_quadrant_costs_wide_markers_almost_nothing():
    # At 0.6-0.8 the plain rings may still see four sectors, but score lower, and
    # the centring is pulled off the centre; the equalised rings score such an X
    # as even paint wherever the plain rings show it wider than texture, and read
    # it where its lines cross when screened beyond texture's scale (18 of these 24
    # found with neither, 22 with the first, 24 with both).
    found, false = _wide_dull_markers(range(4), (0.6, 0.8))
    assert found >= 23
    assert false == 0


def test_the_equalised_rings_stand_whole_where_the_plain_ones_score_under_their_floor():
    # A dull quadrant shortens the plain rings' reach and lowers their score: their
    # extent's floor rejects the X that the equalised rings show wider and clean
    # (9 of these 12 found where the plain extent stood, 12 with the equalised).
    found, false = _wide_dull_markers((3, 4), (0.6, 0.8), (12, 20), (8.0, 24.0))
    assert found >= 11
    assert false == 0


def test_equalised_rings_count_from_7_px_where_texture_stops():
    # Markers of 10-16 px tilted up to 40 degrees: their equalised rings may reach
    # only the 8.49 px rung of the ladder at 6-20 px (19 of these 24 found when
    # they had to reach 9 px, 22 from 7 px; texture's reach 6 px).
    found, false = _wide_dull_markers(range(4), (0.6, 0.8), (10, 16), (6.0, 20.0))
    assert found >= 22
    assert false == 0


def _sharp_dull_markers_of_11_to_13_px(radius_range):
    """Found and false points: 24 markers of 11-13 px, one bright quadrant 0.58-0.62 as
    bright as the other, tilted up to 20 degrees, sharp (blur 0.5 px), on flat ground."""
    return _wide_dull_markers(range(4), (0.58, 0.62), (11.0, 13.0), radius_range, 20.0, 0.5)


@pytest.mark.parametrize("radius_range", [(6.0, 40.0), (7.0, 24.0)])
def test_a_dull_x_screened_at_two_levels_is_read_as_the_wider_level_reads_it(radius_range):
    # From a 6-8 px minimum the first level searched is the half-resolution one, whose
    # candidates are labelled with that minimum, under the wide readings' 8 px; the
    # next level's candidate at the same X is wide. Centred together they are one
    # candidate, the first level's the stronger: it keeps the wider level's scale, and
    # with it the equalised rings that a dull quadrant under the rings' mid level needs
    # (16 of these 24 found at 6-40 and at 7-24 px where the stronger candidate's own
    # scale stood, 23 and 24 with the wider level's; 24 at 4-40 px).
    found, false = _sharp_dull_markers_of_11_to_13_px(radius_range)
    assert found >= 21
    assert false == 0


def test_small_markers_with_a_dull_quadrant_are_read_again_from_the_light_slopes_centre(
    monkeypatch,
):
    # Markers of 5.5-8 px, one bright quadrant 0.6-0.8 as bright as the other: at their
    # true centre the plain rings show no X and the equalised ones show it to 5 px, a
    # rung under texture's 7; the centring leaves them towards the brighter side. Read
    # again from the light slope's centre, with the marker's model vouching, 42 of these
    # 48 are found; without that reading, 38, four of them passing their floors because
    # their saddle stands out of their ground.
    found, false = _wide_dull_markers(range(8), (0.6, 0.8), (5.5, 8.0), (5.0, 30.0))
    monkeypatch.setattr(second_reading, "MAX_DULL_READ", 0)
    unread, unread_false = _wide_dull_markers(range(8), (0.6, 0.8), (5.5, 8.0), (5.0, 30.0))
    assert found >= 41 and found - unread >= 4
    assert false == unread_false == 0


def _small_dull_markers(radius_range):
    """Found and false points: 24 markers of 7-9 px, one bright quadrant 0.6-0.75 as bright
    as the other, tilted up to 30 degrees, on flat ground, read at ``radius_range``."""
    return _wide_dull_markers(range(4), (0.6, 0.75), (7.0, 9.0), radius_range, 30.0)


@pytest.mark.parametrize("radius_range", [(4.0, 40.0), (5.0, 40.0), (8.0, 40.0)])
def test_small_markers_with_a_dull_quadrant_are_found_where_their_level_counts_as_wide(
    radius_range,
):
    # From a smallest radius under 6 px the search starts at full resolution and the
    # half-resolution level's candidates are labelled 8 px; from 8 px that level's are
    # labelled 8 px too: screened wide, they are read with the bright sectors
    # equalised and where their lines cross (24 of these 24 found at 5-40 and 8-40).
    found, false = _small_dull_markers(radius_range)
    assert found >= 23
    assert false == 0


@pytest.mark.xfail(
    strict=True,
    reason="issue 12, items 3 and 5: from a minimum of 6 px up to under 8 the first "
    "level's candidates are labelled with it, under the wide readings' 8 px",
)
@pytest.mark.parametrize("tighter", [(6.0, 40.0), (6.0, 24.0)])
def test_a_range_from_6_px_keeps_the_small_dull_markers_one_from_5_px_finds(tighter):
    """Issue 12, items 3 and 5, where they do not hold yet.

    From a smallest radius of 6 px up to under 8 the search starts at the
    half-resolution level and labels its candidates with that radius, under
    :data:`second_reading.WIDE_SCALE_PX`: they get neither the equalised rings nor
    the reading where their lines cross, and a dull quadrant under the rings' mid
    level leaves them two sectors, not four (8 of these 24 found at 6-40 and 6-24,
    24 at 5-40). Counting that level's candidates as wide finds 24, but reads the
    first level's texture as wide too: 11-25 % more time on the speed benchmark's
    frames, 80 % more on the real aerial frames at 6-40 px (docs/accuracy-journal.md,
    "Small markers with a dull quadrant from a 6-8 px minimum"). Strict: the fix
    that makes it pass removes it here.
    """
    at_5, _ = _small_dull_markers((5.0, tighter[1]))
    at_tighter, false = _small_dull_markers(tighter)
    assert at_tighter >= at_5
    assert false == 0


def test_small_xs_whose_dull_sector_the_rings_read_are_located_by_their_quadrants_levels(
    monkeypatch,
):
    """Family (g), development seeds 300, 314 and 329: four X's of 6-9 px whose dull bright
    quadrant leads the dark paint by 0.5-0.7 of the other's lead score 28-44 on the pairs'
    statistic for the quadrants' own levels, under :data:`subpixel.LEVELS_REFIT_MIN_CHI2`,
    and the blend leaves them 0.2-0.5 px off. Where the rings read the dull sector
    (:data:`subpixel.DULL_SECTOR_MAX_BALANCE`), their quadrants' own levels take every X
    under 10 px of those frames within 0.17 px (their mean error 0.23 -> 0.06 px), the
    same markers found.
    """
    family = next(f for f in families() if f.key == "g" and not f.variant)
    detector = Detector(
        DetectorConfig(
            marker_radius_min_px=family.radius_range[0],
            marker_radius_max_px=family.radius_range[1],
        )
    )
    frames = [family.render(seed) for seed in (300, 314, 329)]

    def small_errors() -> dict[tuple[int, int], float]:
        errors = {}
        for index, scene in enumerate(frames):
            found = positions(detector.detect(scene.image).detections)
            match = evaluation.match_points(found, scene.centres)
            for d, t in zip(match.detection_index, match.truth_index, strict=True):
                if scene.markers[t].radius_px < 10.0:
                    errors[index, int(t)] = float(np.hypot(*(found[d] - scene.centres[t])))
        return errors

    with_rings = small_errors()
    monkeypatch.setattr(subpixel, "DULL_SECTOR_MAX_BALANCE", 0.0)
    without = small_errors()
    assert with_rings.keys() == without.keys()
    assert sum(error > 0.2 for error in without.values()) >= 3
    assert max(with_rings.values()) < 0.2
    assert np.mean(list(with_rings.values())) < 0.5 * np.mean(list(without.values()))


def test_both_decisions_keep_markers_with_a_dull_quadrant_or_a_shadow_edge(
    uneven_light_frames,
):
    """Plain grey-level symmetry loses most of them; the sector order and the fit fewer.

    (The default gives the quadrants their levels in the template match and the
    fit, equalises the rings of X's wider than texture's and reads them where the
    X's lines cross: 13 -> 25 -> 33 % of these frames' markers when their radii
    were drawn uniformly; the template decision 33 %. With the radii drawn
    log-uniformly, as now, more of them small: 46 % and 29 %.)
    """
    (low, high), frames = uneven_light_frames
    radius = {"marker_radius_min_px": low, "marker_radius_max_px": high}
    for config in (DetectorConfig(**radius), DetectorConfig(**radius, **TEMPLATE_DECISION)):
        recall, false = _recall_and_false(config, frames)
        assert recall >= 0.25
        assert false <= 0.5


def test_the_verification_cap_takes_the_strongest_prescreened_candidates_and_counts_the_rest(
    monkeypatch,
):
    """A frame with more X's than the cap: the cap's worth are verified, the rest counted."""
    board = render_checkerboard(
        (480, 640),
        (9, 7),
        32.0,
        rotation_rad=0.2,
        blur_sigma_px=1.0,
        noise_sigma_dn=2.0,
        seed=2,
    )
    detector = Detector(DetectorConfig(marker_radius_min_px=12.0, marker_radius_max_px=32.0))
    everything = detector.detect(board.image)
    assert len(everything) == 63
    monkeypatch.setattr(symmetry_path, "MAX_VERIFIED", 10)
    capped = detector.detect(board.image)
    counts = capped.counts
    assert len(capped) == 10
    assert counts["dropped_over_verification_cap"] > 53
    after_screening = counts["after_suppression"] - counts["dropped_over_cap"]
    assert after_screening == (
        counts["rejected_prescreen"] + counts["dropped_over_verification_cap"] + 10
    )
    # The ten are corners the full pass found, at the same positions.
    distance, _ = cKDTree(positions(everything)).query(positions(capped))
    assert np.all(distance < 1e-6)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda a: {**a, "radius_px": a["radius_px"][:1]}, r"one row per marker .*'radius_px': 1"),
        (lambda a: {**a, "xy": a["xy"] * np.nan}, "locate's xy holds a NaN or an infinity"),
        (lambda a: {**a, "evidence": a["evidence"] + np.inf}, "evidence holds a NaN"),
        (lambda a: {**a, "radius_px": a["radius_px"] * 0}, "locate's radius_px must be positive"),
        (lambda a: {**a, "radius_px": -a["radius_px"]}, "locate's radius_px must be positive"),
        # Read as rows, a (2, N) transpose or an (N, 3) array was N or 3N/2 points.
        (lambda a: {**a, "xy": np.zeros((2, 3))}, r"xy must be \(N, 2\), got shape \(2, 3\)"),
        (lambda a: {**a, "line_angles": np.zeros((2, 2, 1))}, r"line_angles must be \(N, 2\)"),
        (lambda a: {**a, "evidence": np.ones((2, 1))}, r"evidence must be \(N,\), got shape"),
    ],
)
def test_markers_to_locate_not_n_finite_rows_of_positive_extent_are_refused_with_what_is_wrong(
    change, message
):
    markers = {
        "xy": np.array([[31.5, 31.5], [10.0, 12.0]]),
        "radius_px": np.array([12.0, 12.0]),
        "line_angles": np.array([[0.0, np.pi / 2]] * 2),
        "evidence": np.array([0.9, 0.9]),
    }
    image = np.full((64, 64), 200, np.uint8)
    with pytest.raises(ValueError, match=message):
        Detector(DetectorConfig()).locate(image, **change(markers))


def test_an_empty_search_plan_searches_nowhere():

    image = np.full((64, 64), 200, np.uint8)
    image[:32, :32] = image[32:, 32:] = 30
    image = cv2.GaussianBlur(image, (0, 0), 1.0)
    assert len(Detector(DetectorConfig()).detect(image)) == 1
    assert len(Detector(DetectorConfig()).detect(image, SearchPlan())) == 0


@pytest.mark.parametrize("white_share", [0.08, 0.12])
def test_markers_in_deep_shadow_are_found_as_in_the_open(white_share):
    """The raw contrast floors follow the light down (preprocessing.ShadowedContrast).

    White at 8-12 % of full scale leaves 15-25 grey levels between the quadrants,
    under the 20 the screening asks for in the open; a marker of that modulation
    is still one, and Eq. (2) restores its contrast for the checks.
    """
    scene_config = dataclasses.replace(
        SMALL_SCENE, noise_sigma_dn=(0.5, 1.0), peak_level=(white_share, white_share)
    )
    detector = Detector(DetectorConfig(marker_radius_min_px=6.0, marker_radius_max_px=20.0))
    found = false = total = 0
    for seed in range(4):
        scene = render_scene(scene_config, seed)
        result = detector.detect(scene.image)
        hits, misses, _ = found_false_errors(result, scene.centres)
        found, false, total = found + hits, false + misses, total + len(scene.centres)
        # Tracking confirms them by the fit alone, whose contrast floor follows the light too.
        tracked = detector.locate(
            scene.image,
            np.array([[d.x, d.y] for d in result]),
            np.array([d.radius_px for d in result]),
            np.array([[d.angle1, d.angle2] for d in result]),
            np.array([d.evidence for d in result]),
        )
        assert len(tracked) == len(result)
    assert found / total >= 0.85
    assert false == 0


@pytest.mark.parametrize("max_candidates", [50, 400])
def test_a_marker_under_dim_light_beside_bright_busy_ground_is_within_the_frames_cap(
    max_candidates,
):
    """The caps rank saddles by their contrast over their light (screening.LightWeight).

    Bright textured ground (150 grey levels, 60 of texture) fills the frame's cap with
    saddles whose raw responses beat a marker's 36 levels under light of 20 levels;
    over their light they are texture's contrast, and the marker's paint is a print's.
    """
    rng = np.random.default_rng(3)
    texture = cv2.GaussianBlur(rng.normal(0, 1, (240, 480)).astype(np.float32), (0, 0), 2.0)
    image = 150 + 60 * texture / texture.std()
    marker = render_markers((240, 240), [MarkerPlacement(120.3, 120.6, 14.0)], 0, blur_sigma_px=0.8)
    image[:, 240:] = 4 + marker.image.astype(np.float32) * (40 / 255)
    image = np.clip(np.round(image + rng.normal(0, 1.0, image.shape)), 0, 255).astype(np.uint8)
    config = DetectorConfig(
        marker_radius_min_px=6.0, marker_radius_max_px=40.0, max_candidates=max_candidates
    )
    result = Detector(config).detect(image)
    assert result.counts["dropped_over_cap"] > 100
    hits, misses, _ = found_false_errors(result, np.array([[360.3, 120.6]]))
    assert (hits, misses) == (1, 0)


def test_on_stony_ground_small_xs_that_do_not_end_are_texture_and_are_counted(monkeypatch):
    # Three frames of family (b) (tiny markers) whose ground makes many saddles that
    # score like them; seeds no benchmark table renders. Of the 10 false points
    # there the X-end gate takes 9 (19 candidates, some duplicates), at most a marker.
    # The template's misfit and the plate model's quartic test, after it, take some or
    # all of the same saddles: they are lifted here, so the gate is measured alone.
    monkeypatch.setattr(acceptance, "MAX_TEMPLATE_MISFIT", np.inf)
    monkeypatch.setattr(plate, "MAX_TO_QUARTIC_ANY", np.inf)
    family = next(f for f in families() if f.key == "b")
    detector = _family_detector(family)
    scenes = [family.render(seed) for seed in (300, 305, 313)]

    def false_and_true(results):
        false = true = 0
        for scene, result in zip(scenes, results, strict=True):
            near = cKDTree(scene.centres).query(positions(result))[0] <= 2.0
            false, true = false + int((~near).sum()), true + int(near.sum())
        return false, true

    gated = [detector.detect(scene.image) for scene in scenes]
    taken = sum(result.counts["rejected_x_end"] for result in gated)
    monkeypatch.setattr(verification, "MAX_MODULATION_BEYOND", np.inf)
    ungated = [detector.detect(scene.image) for scene in scenes]
    (false, true), (false_before, true_before) = false_and_true(gated), false_and_true(ungated)
    assert all(result.counts["rejected_x_end"] == 0 for result in ungated)
    assert taken >= false_before - false >= 7
    assert true_before - true <= 1


def test_the_survivors_narrow_test_by_test_down_to_the_detections():
    scene = render_scene(SMALL_SCENE, 2)
    result = Detector(DetectorConfig(marker_radius_min_px=6.0, marker_radius_max_px=20.0)).detect(
        scene.image
    )
    tests = [test for test, _ in result.survivors]
    sizes = [len(xy) for _, xy in result.survivors]
    assert tuple(tests) == symmetry_path.SURVIVOR_TESTS
    # Each named once: a marker lost at a floor or a cap says which one.
    assert len(set(tests)) == len(tests)
    # Each test keeps a subset of what reached it (the centring moves candidates and
    # merges duplicates, so it keeps no more than it was given); the last three, the
    # second readings of the lost wide candidates and of the tiny X's plates, only
    # add markers to the detections.
    assert all(later <= earlier for earlier, later in itertools.pairwise(sizes[:-3]))
    assert sizes[-4] <= sizes[-3] <= sizes[-2] <= sizes[-1] == len(result) > 0
    survivors = dict(result.survivors)
    detections = positions(result)
    assert np.allclose(np.sort(survivors["plate"], axis=0), np.sort(detections, axis=0))
    assert cKDTree(detections).query(survivors["merging"])[0].max() < 0.5


def _marker_grid_scene(seed: int, radius_px: tuple[float, float], tilt_deg: tuple[float, float]):
    """24 markers on a grid on ground texture, radii (px) and tilts (degrees) drawn in the ranges.

    Under 1.4 px of blur and 2 DN of noise, half of them checkers.
    """
    rng = np.random.default_rng(seed)
    placements = [
        MarkerPlacement(
            40 + 60 * (i % 6) + rng.uniform(-4, 4),
            40 + 60 * (i // 6) + rng.uniform(-4, 4),
            rng.uniform(*radius_px),
            rng.uniform(0, np.pi),
            rng.uniform(*tilt_deg),
            kind=("quarter_disks", "checker")[i % 2],
        )
        for i in range(24)
    ]
    return render_markers(
        (280, 400), placements, seed, background="texture", blur_sigma_px=1.4, noise_sigma_dn=2.0
    )


def _tiny_marker_scene(seed: int):
    """24 markers of 3-4 px seen up to 30 degrees from face on (:func:`_marker_grid_scene`)."""
    return _marker_grid_scene(seed, (3.0, 4.0), (0.0, 30.0))


_TINY_CONFIG = DetectorConfig(marker_radius_min_px=2.5, marker_radius_max_px=5.0)


def test_tiny_markers_the_blur_nearly_merges_are_found_by_their_plate():
    # Foreshortened radius over blur 1.9-2.9: the template's NCC, the score floors
    # and the X's end take half of them (24 of these 48 found before the plate was
    # read, 38 with it), and texture's saddles none.
    found = false = added = 0
    for seed in (0, 1):
        scene = _tiny_marker_scene(seed)
        result = Detector(_TINY_CONFIG).detect(scene.image)
        hits, misses, _ = found_false_errors(result, scene.centres)
        found, false = found + hits, false + misses
        added += result.counts["found_plate"]
    assert found >= 34
    assert added >= 10
    assert false == 0


def test_each_detection_is_put_down_to_the_reading_that_counts_it(read_again_frames):
    # The readings' survivor lists say which added each detection, as their counts do:
    # the first pass, the lost wide candidates centred again, those read with a
    # shadow's edge divided out, and the tiny X's judged by their plate.
    (low, high), frames = read_again_frames
    detector = Detector(DetectorConfig(marker_radius_min_px=low, marker_radius_max_px=high))
    tiny = Detector(_TINY_CONFIG)
    added = collections.Counter()
    for result in [detector.detect(s.image) for s in frames] + [
        tiny.detect(_tiny_marker_scene(seed).image) for seed in (0, 1)
    ]:
        readings = collections.Counter(
            evaluation.readings_that_added(
                result.survivors, positions(result), symmetry_path.READINGS
            )
        )
        counts = result.counts
        assert readings == collections.Counter(
            {
                "first pass": len(dict(result.survivors)["lattice"]),
                "recentring": counts["found_recentred"],
                "shadow": counts["found_shadowed"],
                "plate": counts["found_plate"],
            }
        )
        added += readings
    assert all(added[name] > 0 for name in symmetry_path.READINGS.values())


def test_tracking_confirms_tiny_markers_by_their_plate_and_nothing_where_they_are_not():
    # The fit's floors, which tracking holds a marker to, reject many a tiny marker a
    # full pass found by its plate alone (20 of 44 on the rendered (b) frames of seeds
    # 200-207).
    scene = _tiny_marker_scene(0)
    detector = Detector(_TINY_CONFIG)
    result = detector.detect(scene.image)
    xy = positions(result)
    radius = np.array([d.radius_px for d in result])
    angles = np.array([[d.angle1, d.angle2] for d in result])
    evidence = np.array([d.evidence for d in result])
    assert result.counts["found_plate"] >= 5
    tracked = detector.locate(scene.image, xy + 0.3, radius, angles, evidence)
    assert len(tracked) == len(result)
    assert cKDTree(positions(tracked)).query(xy)[0].max() < 0.1
    moved = detector.locate(scene.image, xy + [12.0, 7.0], radius, angles, evidence)
    assert len(moved) == 0


def _foreshortened_small_marker_scene(seed: int):
    """24 markers of 6-8 px seen 50-60 degrees from face on (:func:`_marker_grid_scene`)."""
    return _marker_grid_scene(seed, (6.0, 8.0), (50.0, 60.0))


def test_markers_seen_foreshortened_to_textures_size_are_found_by_their_plate_at_any_range():
    # At a range from 6 px, the rings read some of these X's at texture's size, and
    # the X's own tests lose 26 of the 96 (70 found before plates were read at every
    # range); their plate, read a rung out, finds 11 of them and no texture saddle.
    # A tracked frame confirms what the pass found.
    detector = Detector(DetectorConfig(marker_radius_min_px=6.0, marker_radius_max_px=40.0))
    found = false = added = 0
    for seed in range(4):
        scene = _foreshortened_small_marker_scene(seed)
        result = detector.detect(scene.image)
        hits, misses, _ = found_false_errors(result, scene.centres)
        found, false = found + hits, false + misses
        added += result.counts["found_plate"]
        if seed == 0:
            xy = positions(result)
            radius = np.array([d.radius_px for d in result])
            angles = np.array([[d.angle1, d.angle2] for d in result])
            evidence = np.array([d.evidence for d in result])
            tracked = detector.locate(scene.image, xy + 0.3, radius, angles, evidence)
            assert len(tracked) == len(result)
    assert found >= 77
    assert added >= 7
    assert false == 0


def test_tiny_xs_a_quartic_explains_better_than_their_plate_are_texture(monkeypatch):
    # Three frames of family (b) on stony ground, seeds no benchmark table renders:
    # texture saddles pass every other test (two with the pinned versions, one with
    # the newest OpenCV and numpy); the model of a marker on its plate leaves more of
    # them than a smooth quartic does (as it does of 2 of the 477 tiny markers found
    # on the development frames, two of them here).
    family = next(f for f in families() if f.key == "b")
    low, high = family.radius_range
    detector = Detector(DetectorConfig(marker_radius_min_px=low, marker_radius_max_px=high))
    scenes = [family.render(seed) for seed in (300, 303, 305)]

    def true_and_false() -> tuple[int, int]:
        true = false = 0
        for scene in scenes:
            hits, misses, _ = found_false_errors(detector.detect(scene.image), scene.centres)
            true, false = true + hits, false + misses
        return true, false

    true, false = true_and_false()
    monkeypatch.setattr(plate, "MAX_TO_QUARTIC_ANY", np.inf)
    true_before, false_before = true_and_false()
    assert false == 0
    assert false_before >= 1
    assert true_before - true <= 2


def test_faint_paint_beyond_textures_reach_is_not_held_to_the_modulation_gate():
    # Paint of reflectance 0.6 and 0.95 modulates 0.23, under min_modulation: on
    # markers of 8-10 px, whose rings reach 8.5 px, beyond what texture's reach
    # (verification.EQUALISED_MIN_EXTENT_PX), the gate is not asked (none of these
    # 16 found while it was asked up to 9 px).
    found = false = 0
    for seed in (0, 1):
        rng = np.random.default_rng(seed)
        placements = [
            MarkerPlacement(
                100 + 200 * (i % 4) + rng.uniform(-5, 5),
                100 + 200 * (i // 4) + rng.uniform(-5, 5),
                rng.uniform(8, 10),
                rng.uniform(0, np.pi),
                rng.uniform(0, 30),
            )
            for i in range(8)
        ]
        scene = render_markers(
            (400, 800),
            placements,
            seed,
            blur_sigma_px=1.0,
            noise_sigma_dn=1.0,
            reflectances=(0.6, 0.95),
        )
        config = DetectorConfig(marker_radius_min_px=6.0, marker_radius_max_px=40.0)
        hits, misses, _ = found_false_errors(Detector(config).detect(scene.image), scene.centres)
        found, false = found + hits, false + misses
    assert found >= 14
    assert false == 0


def test_saddles_between_the_discs_of_a_lattice_are_no_xs():
    # Rendered coins at 0.25 frame px per photograph px, seeds no benchmark table
    # renders: between two discs the grey levels are point-symmetric and four-sectored
    # and score like markers of 8-11 px at a radius range from 4 px (27 and 23 false
    # points on these frames), but the X with straight lines leaves 0.08-0.12 of them
    # unexplained beyond the noise.
    detector = Detector(DetectorConfig(marker_radius_min_px=4.0, marker_radius_max_px=40.0))
    frames = [
        disc_lattice_frame(seed, scales=(0.25, 0.25), stretch=(1.0, 1.0)) for seed in (105, 110)
    ]
    results = [detector.detect(frame.image) for frame in frames]
    assert all(len(result) == 0 for result in results)
    assert sum(result.counts["rejected_misfit"] for result in results) >= 40


def test_a_lattice_of_flat_discs_is_ground_its_saddles_repeated_not_a_field_of_markers(
    monkeypatch,
):
    # Rendered disc lattices (seeds no benchmark table renders) whose saddles fit and
    # score as X's of 6-12 px: each one's disk recurs on both sides of it.
    detector = Detector(DetectorConfig(marker_radius_min_px=6.0, marker_radius_max_px=40.0))
    frames = [disc_lattice_frame(seed).image for seed in (105, 107, 112)]
    results = [detector.detect(frame) for frame in frames]
    monkeypatch.setattr(acceptance, "MIN_LATTICE_RECURRENCE", np.inf)
    unasked = sum(len(detector.detect(frame)) for frame in frames)
    assert unasked >= 40
    assert sum(len(result) for result in results) <= unasked // 4
    assert sum(result.counts["rejected_lattice"] for result in results) >= unasked // 2


def test_a_lattice_cut_by_the_frames_border_is_ground_along_the_border_too():
    # Rendered disc lattices (seeds no benchmark table renders) whose saddles by the
    # border, their opposite copies cut off, passed for markers (four on these
    # frames); read two copies in a row on the side in view, they are the lattice's.
    # Its saddles within the frame that pass (seed 112's three) recur too little.
    low, high = DISC_LATTICE_RADIUS_RANGE
    detector = Detector(DetectorConfig(marker_radius_min_px=low, marker_radius_max_px=high))
    for seed in (107, 112):
        image = disc_lattice_frame(seed).image
        height, width = image.shape
        for detection in detector.detect(image):
            # Where the recurrence's window reaches the border.
            reach = (verification.RECURRENCE_REACH[1] + 1.0) * detection.radius_px
            x, y = detection.x, detection.y
            assert min(x, y, width - 1 - x, height - 1 - y) > reach


def test_a_marker_by_the_frames_border_stands_alone_though_its_ground_repeats_it_once():
    # Family (a) seed 123: a marker of 15 px, its centre 31 px from the top, above
    # a crossing of bright lines that repeats its X once (NCC 0.8); its copy one
    # period further is not there, and the opposite one is cut off.
    family = next(f for f in families() if f.key == "a" and f.variant == "")
    scene = family.render(123)
    assert 6 in _matching(_family_detector(family), scene).truth_index
    assert scene.centres[6, 1] < 32.0


def test_markers_and_a_chessboards_corners_stand_alone_as_the_lattice_test_reads_them():
    # A marker's ground does not repeat its X; a chessboard repeats its corners, but
    # its lines go on as edges from corner to corner.
    for family in families():
        if family.key in ("a", "e") and family.variant == "":
            detector = _family_detector(family)
            for seed in (600, 601):
                result = detector.detect(family.render(seed).image)
                assert len(result) >= 10 and result.counts["rejected_lattice"] == 0


def _grid_of_markers(spacing: float) -> np.ndarray:
    """A frame of 5 x 4 identical markers of radius 12 px, ``spacing`` radii apart."""
    radius = 12.0
    placements = [
        MarkerPlacement(60 + i * spacing * radius, 60 + j * spacing * radius, radius, 0.3)
        for i in range(5)
        for j in range(4)
    ]
    shape = (round(120 + 3 * spacing * radius), round(120 + 4 * spacing * radius))
    return render_markers(shape, placements, 0, blur_sigma_px=1.0, noise_sigma_dn=2.0).image


@pytest.mark.parametrize("spacing", [3.0, 3.5])
def test_a_grid_of_markers_stands_alone_from_three_and_a_half_radii_apart(spacing):
    # Identical markers in rows recur on both sides of each as a lattice's saddles
    # do: 3.5 radii apart (centre to centre) each stands alone, at 3 only those at
    # the grid's edge do.
    image = _grid_of_markers(spacing)
    result = Detector(DetectorConfig(marker_radius_min_px=6.0)).detect(image)
    if spacing >= 3.5:
        assert len(result) == 20 and result.counts["rejected_lattice"] == 0
    else:
        assert result.counts["rejected_lattice"] >= 12
        # A tighter target array turns the test off.
        config = DetectorConfig(marker_radius_min_px=6.0, lattice_check=False)
        assert len(Detector(config).detect(image)) == 20


def test_known_markers_are_located_by_their_x_their_ground_left_to_the_pass_that_found_them():
    # Tracking confirms the last frame's markers with locate. The ground around a
    # marker (its plate, whether it recurs as a lattice's saddle) does not change
    # with the camera's motion: the full pass judged it and judges it again. Here
    # the grid of markers 3 radii apart that a full pass reads as a lattice (above).
    image = _grid_of_markers(3.0)
    unjudged = Detector(DetectorConfig(marker_radius_min_px=6.0, lattice_check=False))
    known = unjudged.detect(image)
    assert len(known) == 20
    detector = Detector(DetectorConfig(marker_radius_min_px=6.0))
    assert detector.detect(image).counts["rejected_lattice"] >= 12
    xy = positions(known)
    tracked = detector.locate(
        image,
        xy + 0.3,
        np.array([d.radius_px for d in known]),
        np.array([[d.angle1, d.angle2] for d in known]),
        np.array([d.evidence for d in known]),
    )
    assert len(tracked) == 20 and tracked.counts["rejected_lattice"] == 0
    assert cKDTree(positions(tracked)).query(xy)[0].max() < 0.01


def test_a_known_marker_is_read_as_a_full_pass_reads_it_whatever_extent_and_lines_it_had(
    cluttered_frames,
):
    """Tracking's known markers: their extent and line directions are measured again.

    A tracked marker kept the extent and lines of the pass that found it: a camera
    that climbs or turns changes both, and the centre moved with them, by up to
    0.05 px on the flight simulator's frames.
    """
    detector = Detector(DetectorConfig(marker_radius_min_px=6.0, marker_radius_max_px=40.0))
    scene = cluttered_frames[0]
    full = detector.detect(scene.image)
    assert len(full) >= 8
    xy = positions(full)
    stale = detector.locate(
        scene.image,
        xy + [0.4, -0.3],
        np.array([d.radius_px for d in full]) * 1.41,
        np.array([[d.angle1, d.angle2] for d in full]) + np.deg2rad(12.0),
        np.array([d.evidence for d in full]),
    )
    assert len(stale) == len(full)
    distance, index = cKDTree(xy).query(positions(stale))
    assert distance.max() < 2e-3  # the fit's tolerance, 0.001 px a step
    for tracked, k in zip(stale, index, strict=True):
        assert tracked.radius_px == full.detections[k].radius_px
        assert abs(tracked.angle1 - full.detections[k].angle1) < 1e-3


def test_a_shadows_edge_keeps_the_markers_whose_x_alone_leaves_it_unexplained(monkeypatch):
    # Rendered (g) frames of markers of 10-30 px: a hard shadow's edge across a marker
    # is shape the blurred X does not have. With the edge sought nowhere (a reach of
    # 1e-3 px), the misfit takes 3 of these markers.
    family = next(f for f in families() if f.key == "g")
    low, high = family.radius_range
    detector = Detector(DetectorConfig(marker_radius_min_px=low, marker_radius_max_px=high))
    scenes = [
        render_scene(dataclasses.replace(family.scene, radius_px=(10.0, 30.0)), seed)
        for seed in (15, 26, 55)
    ]

    def found() -> int:
        results = [detector.detect(scene.image) for scene in scenes]
        return sum(
            found_false_errors(r, s.centres)[0] for r, s in zip(results, scenes, strict=True)
        )

    kept = found()
    monkeypatch.setattr(shadow, "DETECTION_REACH_EXTENTS", 1e-3)
    assert kept - found() >= 3


@pytest.mark.parametrize(
    ("candidate_detector", "refinement", "cap"),
    [
        ("saddle", "symmetry", symmetry_path.MAX_CONFIRMED),
        ("saddle", "template", template_path.MAX_GROWN),
        ("curvature", "template", paper_path.MAX_LOCATED),
        ("curvature", "ncc", paper_path.MAX_LOCATED),
    ],
)
def test_the_most_a_pass_fits_is_the_cap_of_the_path_the_config_names(
    candidate_detector, refinement, cap
):
    config = DetectorConfig(candidate_detector=candidate_detector, refinement=refinement)
    assert Detector(config).max_fitted == cap
