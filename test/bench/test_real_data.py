"""Reading the real data sets' files."""

import cv2
import numpy as np
import pytest
from encoded_images import with_exif_orientation

from marker_localizer.bench.real_data import read_frame, read_gray
from marker_localizer.config import DetectorConfig
from marker_localizer.errors import ImageError
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


def test_read_gray_reduces_a_colour_jpeg_to_grey_as_detect_does(tmp_path):
    """OpenCV's weights on the decoded colour, not libjpeg's luma: the levels ``detect`` reads."""
    rng = np.random.default_rng(3)
    colour = rng.integers(0, 256, (48, 64, 3), np.uint8)
    path = tmp_path / "colour.jpg"
    path.write_bytes(cv2.imencode(".jpg", colour, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes())
    decoded = read_image_file(path, DetectorConfig().max_pixels)
    as_detect_reads = cv2.cvtColor(decoded, cv2.COLOR_BGR2GRAY)
    luma = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    assert np.abs(luma.astype(int) - as_detect_reads).max() > 0  # the two readings differ here
    np.testing.assert_array_equal(read_gray(path), as_detect_reads)


def test_read_frame_gives_a_colour_files_planes_beside_its_grey_and_none_for_a_grey_file(
    tmp_path,
):
    """The planes ``detect`` gives the detector's colour check; the grey its stages read."""
    colour = np.random.default_rng(4).integers(0, 256, (48, 64, 3), np.uint8)
    coloured, grey = tmp_path / "colour.png", tmp_path / "grey.png"
    coloured.write_bytes(cv2.imencode(".png", colour)[1].tobytes())
    grey.write_bytes(cv2.imencode(".png", colour[..., 1])[1].tobytes())
    image, planes = read_frame(coloured)
    np.testing.assert_array_equal(planes, colour)
    np.testing.assert_array_equal(image, read_gray(coloured))
    image, planes = read_frame(grey)
    assert planes is None
    np.testing.assert_array_equal(image, colour[..., 1])


def test_read_gray_names_a_file_that_is_not_an_image(tmp_path):
    path = tmp_path / "notes.jpg"
    path.write_text("not a picture")
    with pytest.raises(ImageError, match=r"notes\.jpg"):
        read_gray(path)
