"""Input normalisation: the full scale of a 16-bit image comes from its bit depth."""

import cv2
import numpy as np
import pytest

from marker_localizer import Detector, DetectorConfig
from marker_localizer.core.image import bit_depth_scale, to_gray


def _x_marker_12_bit() -> np.ndarray:
    """The Detector docstring's X (centre (31.5, 31.5)) as a 12-bit sensor writes it."""
    image = np.full((64, 64), 200.0, np.float32)
    image[:32, :32] = image[32:, 32:] = 30.0
    return (cv2.GaussianBlur(image, (0, 0), 1.0) * 16).round().astype(np.uint16)


@pytest.mark.parametrize(("dtype", "bits", "white"), [
    (np.uint8, 16, 255.0), (np.uint8, 12, 255.0), (np.uint16, 16, 65535.0),
    (np.uint16, 12, 4095.0), (np.uint16, 10, 1023.0),
])
def test_white_is_set_by_the_type_and_the_bit_depth(dtype, bits, white):
    assert bit_depth_scale(np.dtype(dtype), bits) == white


def test_the_full_scale_of_one_camera_does_not_move_with_the_frame_content():
    dim = np.full((8, 8), 100, np.uint16)
    hot = dim.copy()
    hot[0, 0] = 65535  # a hot pixel or a specular glint
    assert to_gray(dim, bit_depth=12)[1] == to_gray(hot, bit_depth=12)[1] == 4095.0


def test_a_12_bit_sensor_is_detected_when_the_detector_is_told_its_bit_depth():
    image = _x_marker_12_bit()
    told = Detector(DetectorConfig(bit_depth=12))
    (found,) = told.detect(image)
    assert (found.x, found.y) == (pytest.approx(31.5, abs=1e-3), pytest.approx(31.5, abs=1e-3))
    # The same frame with a saturated pixel far from the marker: same thresholds, same answer.
    glint = image.copy()
    glint[2, 60] = 65535
    assert len(told.detect(glint)) == 1
    # Read as 16-bit words, its 170-DN-of-255 contrast is 10 DN: under min_contrast_dn.
    assert len(Detector(DetectorConfig(bit_depth=16)).detect(image)) == 0
