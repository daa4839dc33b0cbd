"""Tracking mode: same markers and positions as full-frame detection, fewer pixels read."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from marker_localizer import Detector, DetectorConfig
from marker_localizer.core.tracking import MarkerTracker
from marker_localizer.synthetic import MarkerPlacement, render_markers


def _frame(offset: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    centres = np.array([[150.3, 120.6], [420.8, 260.1], [260.2, 380.7], [520.5, 110.4]])
    placements = [
        MarkerPlacement(x + offset[0], y + offset[1], 14.0, 0.3 * k, 20.0, 0.5)
        for k, (x, y) in enumerate(centres)
    ]
    scene = render_markers(
        (480, 640), placements, seed, background="texture", blur_sigma_px=0.9, noise_sigma_dn=2.0
    )
    return scene.image, scene.centres


@pytest.fixture(scope="module")
def moving_frames():
    # Constant image motion of (6, -3) px per frame plus a jitter of a few pixels.
    rng = np.random.default_rng(5)
    return [_frame(np.array([6.0, -3.0]) * k + rng.normal(0, 3.0, 2), k) for k in range(6)]


def test_tracking_finds_what_full_frame_detection_finds_at_the_same_positions(moving_frames):
    detector = Detector(DetectorConfig(marker_radius_min_px=6.0, marker_radius_max_px=20.0))
    tracker = MarkerTracker(detector, full_frame_every=10)
    tracked_frames = 0
    for k, (image, truth) in enumerate(moving_frames):
        result = tracker.update(image, stamp_s=0.1 * k)
        tracked = result.as_array()
        full = detector.detect(image).as_array()
        tracked_frames += 1 - result.counts["full_frame"]
        assert len(tracked) == len(full) == len(truth)
        np.testing.assert_allclose(np.sort(tracked[:, 0]), np.sort(full[:, 0]), atol=1e-9)
        assert cKDTree(truth).query(tracked[:, :2])[0].max() < 0.1
    assert tracked_frames >= 3  # after two full passes establish the velocities


def test_a_stamp_that_does_not_advance_resets_the_tracks(moving_frames):
    detector = Detector(DetectorConfig(marker_radius_min_px=6.0, marker_radius_max_px=20.0))
    tracker = MarkerTracker(detector)
    image, _ = moving_frames[0]
    tracker.update(image, stamp_s=1.0)
    tracker.update(image, stamp_s=1.1)
    result = tracker.update(image, stamp_s=0.5)
    assert result.counts["full_frame"] == 1
