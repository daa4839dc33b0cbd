"""Tracking mode: same markers and positions as full-frame detection, fewer pixels read."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from marker_localizer import Detector, DetectorConfig
from marker_localizer.bench.ground import x_tiling_frame
from marker_localizer.config import TrackerConfig, param_specs
from marker_localizer.core import symmetry_path, tracking
from marker_localizer.core.result import DetectionResult, positions, sigmas
from marker_localizer.core.tracking import MarkerTracker
from marker_localizer.evaluation import match_points
from marker_localizer.synthetic import MarkerPlacement, render_markers
from marker_localizer.synthetic.flight import FlightConfig, FlightSimulator

CENTRES = np.array([[150.3, 120.6], [420.8, 260.1], [260.2, 380.7], [520.5, 110.4]])


def _frame(
    offset: np.ndarray, seed: int, centres: np.ndarray = CENTRES
) -> tuple[np.ndarray, np.ndarray]:
    placements = [
        MarkerPlacement(x + offset[0], y + offset[1], 14.0, 0.3 * k, 20.0, 0.5)
        for k, (x, y) in enumerate(centres)
    ]
    scene = render_markers(
        (480, 640), placements, seed, background="texture", blur_sigma_px=0.9, noise_sigma_dn=2.0
    )
    return scene.image, scene.centres


def _detector() -> Detector:
    return Detector(DetectorConfig(marker_radius_min_px=6.0, marker_radius_max_px=20.0))


def _offsets(n_frames: int, step: tuple[float, float], seed: int) -> list[np.ndarray]:
    """Constant image motion per frame plus an attitude jitter of a few pixels."""
    rng = np.random.default_rng(seed)
    return [np.array(step) * k + rng.normal(0, 3.0, 2) for k in range(n_frames)]


def _assert_same_as_full_frame(
    tracked: DetectionResult, full: DetectionResult, truth: np.ndarray
) -> None:
    """The same markers as a full pass, at its positions; false points only where it has them.

    A tracked marker is read by the same stages from its centring on, so its centre
    agrees with a full pass's to well within 0.01 px. A full pass may find a false
    point in the interior that tracking does not search.
    """
    tracked_xy, full_xy = positions(tracked), positions(full)
    on_tracked, on_full = match_points(tracked_xy, truth), match_points(full_xy, truth)
    assert sorted(on_tracked.truth_index) == sorted(on_full.truth_index)
    np.testing.assert_allclose(
        tracked_xy[on_tracked.detection_index[np.argsort(on_tracked.truth_index)]],
        full_xy[on_full.detection_index[np.argsort(on_full.truth_index)]],
        atol=0.01,
    )
    false_tracked = np.delete(tracked_xy, on_tracked.detection_index, axis=0)
    false_full = np.delete(full_xy, on_full.detection_index, axis=0)
    for point in false_tracked:
        assert len(false_full) and np.linalg.norm(false_full - point, axis=1).min() < 0.01


@pytest.fixture(scope="module")
def moving_frames():
    return [_frame(offset, k) for k, offset in enumerate(_offsets(6, (6.0, -3.0), 5))]


def test_tracking_finds_what_full_frame_detection_finds_at_the_same_positions(moving_frames):
    detector = _detector()
    tracker = MarkerTracker(detector, TrackerConfig(full_frame_every=10))
    full_passes = []
    for k, (image, truth) in enumerate(moving_frames):
        result = tracker.update(image, stamp_s=0.1 * k)
        _assert_same_as_full_frame(result, detector.detect(image), truth)
        assert len(result) == len(truth)
        assert cKDTree(truth).query(positions(result))[0].max() < 0.1
        full_passes.append(result.counts["full_frame"])
    # Only the first frame: the second is tracked although no track has a velocity yet.
    assert full_passes == [1, 0, 0, 0, 0, 0]


@pytest.mark.parametrize("refinement", ["ncc", "symmetry"])
def test_the_papers_path_tracks_with_its_own_location_and_sigma(moving_frames, refinement):
    # Its tracked frames were located by the default path's fit: sigma 0.476 px on a
    # full pass, 0.028 px on the tracked frame after it, and back again.
    config = _detector().config.replace(candidate_detector="curvature", refinement=refinement)
    detector = Detector(config)
    tracker = MarkerTracker(detector)
    for k, (image, _) in enumerate(moving_frames[:4]):
        tracked, full = tracker.update(image, stamp_s=0.1 * k), detector.detect(image)
        assert tracked.counts["full_frame"] == (k == 0)
        pairs = match_points(positions(tracked), positions(full), gate_px=0.01)
        assert len(pairs.truth_index) == len(full) == len(tracked) > 0
        np.testing.assert_allclose(
            sigmas(tracked)[pairs.detection_index],
            sigmas(full)[pairs.truth_index],
            rtol=0.05,
        )


def test_a_full_frame_pass_runs_every_full_frame_every_frames(moving_frames):
    tracker = MarkerTracker(_detector(), TrackerConfig(full_frame_every=3))
    passes = [
        tracker.update(image, stamp_s=0.1 * k).counts["full_frame"]
        for k, (image, _) in enumerate(moving_frames)
    ]
    assert passes == [1, 0, 0, 1, 0, 0]


def test_a_phase_brings_the_first_scheduled_full_pass_that_many_frames_early(moving_frames):
    tracker = MarkerTracker(_detector(), TrackerConfig(full_frame_every=4), phase=2)
    passes = [
        tracker.update(image, stamp_s=0.1 * k).counts["full_frame"]
        for k, (image, _) in enumerate(moving_frames)
    ]
    assert passes == [1, 0, 1, 0, 0, 0]


@pytest.mark.parametrize("phase", [-1, float("nan"), 2.5, "3", True])
def test_a_phase_that_is_not_a_whole_number_of_frames_from_0_is_refused(phase):
    """NaN passed the test of a negative phase, and brought an extra full pass."""
    with pytest.raises(ValueError, match="phase"):
        MarkerTracker(_detector(), phase=phase)


def test_a_phase_of_numpys_integer_type_is_taken_as_an_int():
    assert MarkerTracker(_detector(), phase=np.int64(3)).phase == 3


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        # A dict of settings failed on the first frame, on a missing attribute.
        (
            {"config": {"full_frame_every": 2}},
            r"TrackerConfig instance.*TrackerConfig\(\*\*values\)",
        ),
        ({"config": TrackerConfig}, "TrackerConfig instance"),
        ({"detector": Detector}, "Detector instance"),
    ],
)
def test_a_config_or_detector_of_another_type_is_refused_at_construction(arguments, message):
    with pytest.raises(TypeError, match=message):
        MarkerTracker(**{"detector": _detector(), **arguments})


def test_a_disabled_tracker_gives_every_frame_a_full_pass(moving_frames):
    # TrackerConfig(enabled=False) was ignored: the frames were tracked all the same.
    detector = _detector()
    tracker = MarkerTracker(detector, TrackerConfig(enabled=False))
    for k, (image, _) in enumerate(moving_frames[:3]):
        result = tracker.update(image, stamp_s=0.1 * k)
        assert (result.counts["full_frame"], result.counts["tracked"]) == (1, 0)
        np.testing.assert_array_equal(result.as_array(), detector.detect(image).as_array())


def test_the_cameras_phases_spread_over_the_full_pass_period():
    assert [tracking.staggered_phase(k, 5, 10) for k in range(5)] == [0, 2, 4, 6, 8]
    assert [tracking.staggered_phase(k, 3, 10) for k in range(3)] == [0, 3, 6]
    # More cameras than frames in a period: they share the frames evenly.
    assert [tracking.staggered_phase(k, 4, 2) for k in range(4)] == [0, 0, 1, 1]


def test_a_stamp_that_does_not_advance_resets_the_tracks(moving_frames):
    tracker = MarkerTracker(_detector())
    image, _ = moving_frames[0]
    tracker.update(image, stamp_s=1.0)
    tracker.update(image, stamp_s=1.1)
    result = tracker.update(image, stamp_s=0.5)
    assert result.counts["full_frame"] == 1


def test_a_frame_of_another_size_resets_the_tracks_and_gets_a_full_pass(moving_frames):
    tracker = MarkerTracker(_detector())
    (image, truth), (later, _) = moving_frames[0], moving_frames[1]
    tracker.update(image, stamp_s=1.0)
    window = tracker.update(image[:240, :320], stamp_s=1.1)
    assert window.counts["full_frame"] == 1
    # Back to the whole frame: the markers outside the window are found at once.
    whole = tracker.update(later, stamp_s=1.2)
    assert whole.counts["full_frame"] == 1
    assert len(whole.as_array()) == len(truth)


@pytest.mark.parametrize("stamp_s", [float("nan"), float("inf")])
def test_a_stamp_that_is_not_a_finite_time_is_refused(moving_frames, stamp_s):
    tracker = MarkerTracker(_detector())
    image, _ = moving_frames[0]
    tracker.update(image, stamp_s=1.0)
    with pytest.raises(ValueError, match="stamp_s must be a finite time in seconds"):
        tracker.update(image, stamp_s=stamp_s)
    assert tracker.update(image, stamp_s=1.1).counts["full_frame"] == 0


def _faded(image: np.ndarray, centre: np.ndarray, half_px: int, factor: float) -> np.ndarray:
    """The image with the contrast around ``centre`` scaled by ``factor`` (haze, glare)."""
    faded = image.astype(np.float64)
    x, y = np.round(centre).astype(int)
    window = faded[y - half_px : y + half_px + 1, x - half_px : x + half_px + 1]
    window[:] = window.mean() + factor * (window - window.mean())
    return np.round(faded).astype(np.uint8)


def test_a_marker_in_view_but_rejected_on_one_frame_costs_no_full_pass_and_is_found_again():
    frames = [_frame(offset, k) for k, offset in enumerate(_offsets(6, (6.0, -3.0), 7))]
    image, truth = frames[3]
    # Below the detector's contrast threshold, but the same pattern.
    frames[3] = (_faded(image, truth[1], 24, 0.05), truth)
    detector = _detector()
    tracker = MarkerTracker(detector, TrackerConfig(full_frame_every=10, max_missed_frames=2))
    results = [tracker.update(image, stamp_s=0.5 * k) for k, (image, _) in enumerate(frames)]
    assert len(detector.detect(frames[3][0])) == 3  # a full pass would not find it either
    assert [r.counts["full_frame"] for r in results] == [1, 0, 0, 0, 0, 0]
    assert [len(r) for r in results] == [4, 4, 4, 3, 4, 4]
    # Found again in its window: the same position as the truth, not a new marker.
    assert cKDTree(frames[4][1]).query(positions(results[4]))[0].max() < 0.1


def test_markers_with_a_dull_quadrant_are_tracked_as_the_full_passes_find_them():
    """Their fit at the prediction misses them, and the detector in a window around
    each found only the finest level's candidate, which the prescreen rejects: tracked
    frames reported none of the 13 markers the full passes found on them."""
    detector = Detector(DetectorConfig(marker_radius_min_px=6, marker_radius_max_px=24))
    tracker = MarkerTracker(detector)
    sites = [
        (80.3, 70.6, 10),
        (200.8, 140.1, 14),
        (130.2, 200.7, 9),
        (260.4, 60.3, 12),
        (60.7, 190.2, 16),
    ]
    for k in range(5):
        placements = [
            MarkerPlacement(
                x + 4 * k,
                y + 1.5 * k,
                r,
                0.5 * i + 0.2,
                20.0,
                0.3,
                "quarter_disks",
                False,
                0.4,
                i % 2,
            )
            for i, (x, y, r) in enumerate(sites)
        ]
        scene = render_markers(
            (280, 360), placements, k, background="texture", noise_sigma_dn=2.0, blur_sigma_px=0.8
        )
        tracked = tracker.update(scene.image, float(k))
        full = detector.detect(scene.image)
        assert tracked.counts["full_frame"] == (k == 0)
        assert len(full) >= 2
        same = match_points(positions(tracked), positions(full), gate_px=0.01)
        assert len(same.truth_index) == len(full) == len(tracked)


class _RejectingNear(Detector):
    """A detector whose full passes and windows reject any X near ``rejected``, but not
    :meth:`Detector.locate`: as a test it does not read (the screening, the ground
    around an X) rejects a texture saddle that one pass accepted."""

    rejected: np.ndarray | None = None

    def detect(self, image, plan=None, colour=None):
        result = super().detect(image, plan, colour=colour)
        if self.rejected is not None:
            result.detections = [
                d for d in result.detections if np.hypot(*(self.rejected - (d.x, d.y))) > 3.0
            ]
        return result


def test_an_x_the_full_passes_reject_is_not_confirmed_again_by_the_fit_alone():
    """Kept for ``max_missed_frames`` after the pass that missed it, it was confirmed by
    :meth:`Detector.locate` on the next frame, and missed and confirmed again after every
    pass: a false point reported for ever. The detector judges it in its window instead."""
    frames = [_frame(offset, k) for k, offset in enumerate(_offsets(8, (6.0, -3.0), 7))]
    detector = _RejectingNear(_detector().config)
    tracker = MarkerTracker(detector, TrackerConfig(full_frame_every=3, max_missed_frames=2))
    reported, passes = [], []
    for k, (image, truth) in enumerate(frames):
        detector.rejected = truth[1] if k >= 3 else None
        result = tracker.update(image, stamp_s=0.5 * k)
        passes.append(result.counts["full_frame"])
        reported.append(len(result))
    assert passes == [1, 0, 0, 1, 0, 0, 1, 0]
    assert reported == [4, 4, 4, 3, 3, 3, 3, 3]


def test_a_marker_that_disappears_is_lost_and_gets_a_full_pass_on_the_same_frame():
    offsets = _offsets(5, (6.0, -3.0), 8)
    frames = [
        _frame(offset, k, np.delete(CENTRES, 1, axis=0) if k >= 2 else CENTRES)
        for k, offset in enumerate(offsets)
    ]
    tracker = MarkerTracker(_detector(), TrackerConfig(full_frame_every=10))
    passes = [
        tracker.update(image, stamp_s=0.5 * k).counts["full_frame"]
        for k, (image, _) in enumerate(frames)
    ]
    # Neither confirmed nor its patch found where predicted: the pass ends its track.
    assert passes == [1, 0, 1, 0, 0]


def test_a_frame_after_more_tracks_than_one_pass_fits_gets_a_full_pass(monkeypatch):
    """On a tiling of X's a tracked frame confirms every track and adds what its bands
    find; without the full pass the tracks would grow frame after frame."""
    monkeypatch.setattr(symmetry_path, "MAX_CONFIRMED", 30)
    tiling = x_tiling_frame(seed=1, shape=(280, 360))
    tracker = MarkerTracker(
        Detector(DetectorConfig(marker_radius_min_px=3.0, marker_radius_max_px=30.0))
    )
    results = [
        tracker.update(np.ascontiguousarray(tiling[2 * k : 2 * k + 240, 3 * k : 3 * k + 320]), k)
        for k in range(6)
    ]
    assert tracker.detector.max_fitted == 30
    crowded = [len(r) > 30 for r in results]
    assert any(crowded)
    for before, after in zip(crowded[:-1], results[1:], strict=True):
        assert after.counts["full_frame"] == (1 if before else 0)


#: Markers 75 px apart: under twice a motion of 40 px a frame.
GRID = np.array([[160.3 + 75.0 * i, 90.6 + 75.0 * j] for i in range(6) for j in range(4)])


@pytest.mark.parametrize(
    ("seed", "centres", "step_px", "max_motion_px"),
    [(3, CENTRES, 25.0, 16.0), (5, CENTRES, 25.0, 16.0), (3, GRID, 40.0, 32.0)],
    ids=["sparse, seed 3", "sparse, seed 5", "markers under twice the motion apart"],
)
def test_a_flight_moving_farther_a_frame_than_max_motion_px_is_tracked_from_its_third_frame(
    seed, centres, step_px, max_motion_px
):
    """25 px a frame against a 16 px ``max_motion_px``: the second frame's full pass finds
    every marker that much from its track, their common shift. The tracks get their
    velocity from it, and the frames after are tracked (each was a full pass: the
    anchors' patches, searched within 16 px, found none or a neighbour). Where the
    markers lie under twice the motion apart, a neighbour's patch gives a wrong motion
    that still puts most predictions within ``max_motion_px`` of some marker: the common
    shift was not sought, and every frame was a full pass."""
    frames = [
        _frame(offset, k, centres) for k, offset in enumerate(_offsets(5, (-step_px, 0.0), seed))
    ]
    detector = _detector()
    tracker = MarkerTracker(
        detector, TrackerConfig(max_motion_px=max_motion_px, full_frame_every=100)
    )
    passes = []
    for k, (image, truth) in enumerate(frames):
        result = tracker.update(image, stamp_s=0.5 * k)
        _assert_same_as_full_frame(result, detector.detect(image), truth)
        passes.append(result.counts["full_frame"])
    assert passes == [1, 1, 0, 0, 0]


def test_at_the_largest_max_motion_px_the_anchors_lie_in_the_frames_central_half(
    moving_frames,
):
    """1000 px on 640 x 480 frames: no marker lies that far plus its patch from every
    border, so without anchors each frame whose fit misses its prediction (the jitter's
    3 px) would be a full pass. The anchors come from the frame's central half instead,
    and the flight is tracked from its second frame."""
    largest = param_specs(TrackerConfig)["max_motion_px"][1].high
    assert largest == 1000.0
    detector = _detector()
    tracker = MarkerTracker(detector, TrackerConfig(max_motion_px=largest, full_frame_every=100))
    passes = []
    for k, (image, truth) in enumerate(moving_frames):
        result = tracker.update(image, stamp_s=0.1 * k)
        _assert_same_as_full_frame(result, detector.detect(image), truth)
        passes.append(result.counts["full_frame"])
    assert passes == [1, 0, 0, 0, 0, 0]


def test_markers_entering_and_leaving_across_the_border_are_tracked_as_full_frames_see_them():
    # Image content moving right: one marker enters on the left, one leaves on the right.
    centres = np.vstack([CENTRES[:3], [[-40.0, 250.0], [560.0, 330.0]]])
    frames = [_frame(offset, k, centres) for k, offset in enumerate(_offsets(12, (10.0, -2.0), 9))]
    detector = _detector()
    tracker = MarkerTracker(detector, TrackerConfig(full_frame_every=100))
    counts = []
    for k, (image, truth) in enumerate(frames):
        result = tracker.update(image, stamp_s=0.5 * k)
        _assert_same_as_full_frame(result, detector.detect(image), truth)
        assert result.counts["full_frame"] == (k == 0)
        counts.append(len(result))
    assert counts[0] == 4 and max(counts) == 5 and counts[-1] == 4  # one in, then one out


def test_tracking_keeps_recall_and_error_of_full_frame_detection_on_a_simulated_flight():
    config = FlightConfig(
        width=640, height=480, n_frames=10, n_cameras=2, frame_rate_hz=6.0, n_shadows=2
    )
    simulator = FlightSimulator(config, seed=4)
    detector = Detector(DetectorConfig(marker_radius_min_px=4.0, marker_radius_max_px=30.0))
    trackers: dict[str, MarkerTracker] = {}
    matched = {"full": 0, "tracking": 0}
    errors: dict[str, list[float]] = {"full": [], "tracking": []}
    tracked_frames = 0
    for frame in simulator:
        for view in frame.cameras:
            tracker = trackers.setdefault(view.camera.name, MarkerTracker(detector))
            result = tracker.update(view.image, frame.pose.stamp_ns / 1e9)
            tracked_frames += 1 - result.counts["full_frame"]
            truth = np.array([(m.x, m.y) for m in view.markers]).reshape(-1, 2)
            for name, found in (("full", detector.detect(view.image)), ("tracking", result)):
                matching = match_points(positions(found), truth)
                matched[name] += matching.n_matched
                errors[name] += matching.errors_px.tolist()
    assert matched["tracking"] == matched["full"] > 0
    # The same fit, over the extent each marker had when last measured (not the one
    # this frame's rings would read): its mean and 95th percentile stay within a tenth
    # of the full pass's (flights of seeds 1-8: 0.99-1.07).
    for statistic in (np.mean, lambda e: np.percentile(e, 95)):
        assert statistic(errors["tracking"]) <= 1.10 * statistic(errors["full"])
    assert tracked_frames >= 10  # of 20: tracking did the work, not full passes


class _CountingDetector(Detector):
    """The detector, counting the fits it runs on tracked markers (:meth:`Detector.locate`)."""

    locate_calls = 0

    def locate(self, *args, **kwargs):
        self.locate_calls += 1
        return super().locate(*args, **kwargs)


def _tracked_run(frames, detector):
    tracker = MarkerTracker(detector, TrackerConfig(full_frame_every=100))
    results, calls = [], []
    for k, (image, _) in enumerate(frames):
        before = detector.locate_calls
        results.append(tracker.update(image, stamp_s=0.5 * k))
        calls.append(detector.locate_calls - before)
    return results, calls


def test_once_the_fit_at_the_predictions_fails_the_anchors_measure_the_next_frames_motion(
    monkeypatch,
):
    # A jitter of 6 px a frame: the constant-velocity predictions miss the fit's reach.
    rng = np.random.default_rng(11)
    frames = [_frame(np.array([5.0, 2.0]) * k + rng.normal(0.0, 6.0, 2), k) for k in range(7)]
    retried, retried_calls = _tracked_run(frames, _CountingDetector(_detector().config))
    monkeypatch.setattr(tracking, "_FIT_MOTION_RETRY_FRAMES", 0)
    every, every_calls = _tracked_run(frames, _CountingDetector(_detector().config))
    assert [r.counts["full_frame"] for r in retried] == [1, 0, 0, 0, 0, 0, 0]
    # The fit at the predictions, then at the anchors' motion: twice a frame, or once.
    assert every_calls == [0, 2, 2, 2, 2, 2, 2]
    assert retried_calls == [0, 2, 1, 1, 1, 1, 2]
    for a, b in zip(retried, every, strict=True):
        np.testing.assert_array_equal(a.as_array(), b.as_array())
