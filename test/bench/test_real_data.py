"""Reading the real data sets' files."""

import cv2
import numpy as np
from encoded_images import with_exif_orientation

from marker_localizer.bench.real_data import read_gray
from marker_localizer.config import DetectorConfig
from marker_localizer.image_files import read_image_file


def test_read_gray_keeps_the_stored_pixel_order_of_a_jpeg_with_an_exif_orientation(tmp_path):
    """As ``detect`` reads it: Orientation 6 (turn 90 degrees clockwise to view) is not applied."""
    image = np.zeros((64, 96), np.uint8)
    image[:16, :48] = 255  # a bright block in the top left of the stored rows
    jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 98])[1].tobytes()
    plain, turned = tmp_path / "plain.jpg", tmp_path / "turned.jpg"
    plain.write_bytes(jpeg)
    turned.write_bytes(with_exif_orientation(jpeg, 6))
    grey = read_gray(turned)
    assert grey.shape == read_image_file(turned, DetectorConfig().max_pixels).shape[:2]
    np.testing.assert_array_equal(grey, read_gray(plain))
