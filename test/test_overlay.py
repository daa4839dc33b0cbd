"""Annotated frames (overlay.py): drawn on an 8-bit copy, never on the caller's frame."""

import dataclasses

import numpy as np
import pytest

from marker_localizer.core.result import Detection
from marker_localizer.overlay import draw_detections

MARKER = Detection(
    x=8.0, y=8.0, score=1.0, sigma=0.01, angle1=0.0, angle2=np.pi / 2, radius_px=5.0, evidence=1.0
)


@pytest.mark.parametrize(
    "frame",
    [
        np.full((16, 16), 100, np.uint8),
        np.full((16, 16, 1), 100, np.uint8),
        np.full((16, 16, 3), 100, np.uint8),
        np.full((16, 16, 4), 100, np.uint8),
        np.full((16, 16), 25700, np.uint16),
        np.full((16, 16, 3), 25700, np.uint16),
        np.full((16, 16), 100 / 255, np.float32),
    ],
    ids=["mono8", "mono8_one_channel", "bgr8", "bgra8", "mono16", "bgr16", "float"],
)
def test_the_overlay_is_an_8_bit_copy_at_the_frames_levels_and_leaves_the_frame_as_it_was(frame):
    before = frame.copy()
    drawn = draw_detections(frame, [MARKER])
    np.testing.assert_array_equal(frame, before)
    assert drawn.dtype == np.uint8 and drawn.shape == (16, 16, 3)
    np.testing.assert_allclose(drawn[0, 15], [100, 100, 100], atol=1)  # away from the lines
    assert (drawn != 100).any()  # the marker was drawn


def test_a_colour_frame_in_any_memory_layout_is_drawn_as_its_c_ordered_copy():
    # An rgb8 message's channels reordered to BGR by fancy indexing, a Fortran-order
    # array: cv2 draws on neither as they are.
    frame = np.random.default_rng(0).integers(0, 255, (16, 16, 3), dtype=np.uint8)
    expected = draw_detections(frame, [MARKER])
    for layout in (frame[:, :, [2, 1, 0]][:, :, [2, 1, 0]], np.asfortranarray(frame)):
        np.testing.assert_array_equal(draw_detections(layout, [MARKER]), expected)


def _centroid(weights):
    rows, cols = np.nonzero(weights)
    mass = weights[rows, cols].astype(float)
    return np.array([cols @ mass, rows @ mass]) / mass.sum()


@pytest.mark.parametrize("centre", [(10.3, 11.7), (11.75, 10.25)])
def test_the_true_centres_cross_is_drawn_at_its_sub_pixel_position(centre):
    # It was rounded to the pixel: half a pixel off where the demo's errors are hundredths.
    drawn = draw_detections(np.zeros((24, 24), np.uint8), [], truth=np.array([centre]))
    np.testing.assert_allclose(_centroid(drawn[:, :, 0]), centre, atol=0.1)


@pytest.mark.parametrize(
    "change",
    [
        {"x": np.nan},
        {"y": np.inf},
        {"x": -np.inf},
        {"angle2": np.nan},
        {"radius_px": np.nan},
        {"radius_px": -1.0},
    ],
    ids=["x-nan", "y-inf", "x-minus-inf", "angle-nan", "radius-nan", "radius-negative"],
)
def test_a_detection_that_cannot_be_drawn_is_refused_with_its_index_and_value(change):
    """Not a bare numpy or OpenCV error from deep inside the drawing, nor half a canvas."""
    ((name, value),) = change.items()
    bad = dataclasses.replace(MARKER, **change)
    message = rf"detection 2 has {name}={value!r}"
    with pytest.raises(ValueError, match=message):
        draw_detections(np.zeros((16, 16), np.uint8), [MARKER, MARKER, bad])


@pytest.mark.parametrize(
    "change",
    [{"x": 1e9}, {"y": -1e300}, {"x": -30.0, "radius_px": 20.0}],
    ids=["far-right", "far-up", "just-off"],
)
def test_a_finite_detection_off_the_frame_draws_nothing_however_far_off(change):
    frame = np.zeros((16, 16), np.uint8)
    off = dataclasses.replace(MARKER, **change)
    np.testing.assert_array_equal(
        draw_detections(frame, [MARKER, off]), draw_detections(frame, [MARKER])
    )


def test_a_true_centre_that_is_not_finite_is_refused_with_its_row():
    frame = np.zeros((16, 16), np.uint8)
    with pytest.raises(ValueError, match=r"truth row 1 is \(nan, 3.0\)"):
        draw_detections(frame, [MARKER], truth=np.array([[4.0, 4.0], [np.nan, 3.0]]))
    with pytest.raises(ValueError, match=r"truth of shape \(2, 3\) is not \(N, 2\)"):
        draw_detections(frame, [MARKER], truth=np.zeros((2, 3)))
    far = draw_detections(frame, [], truth=np.array([[4.0, 4.0], [1e12, 3.0]]))
    np.testing.assert_array_equal(far, draw_detections(frame, [], truth=np.array([[4.0, 4.0]])))
