"""sensor_msgs <-> numpy conversions: every encoding, row padding, byte order, errors, clouds."""

import array

import cv2
import numpy as np
import pytest
from builtin_interfaces.msg import Time
from node_testing import x_marker_64
from numpy.lib import recfunctions
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import Image, PointCloud2, PointField
from std_msgs.msg import Header

from marker_localizer.config import DetectorConfig
from marker_localizer.core.pipeline import Detector
from marker_localizer.core.result import Detection
from marker_localizer.errors import ImageError
from marker_localizer.ros.conversions import (
    BAYER_ENCODINGS,
    CLOUD_FIELDS,
    ENCODINGS,
    MARKER_ID_FIELD,
    SEMIPLANAR_YUV420,
    YUV422_LUMA_BYTE,
    array_to_image,
    cloud_to_array,
    detections_to_cloud,
    image_to_array,
    image_to_detector_input,
)

HEADER = Header(stamp=Time(sec=1_700_000_123, nanosec=456_789_012), frame_id="cam3_optical")


def pixels_for(encoding: str, height: int = 5, width: int = 7) -> np.ndarray:
    dtype, channels = ENCODINGS[encoding]
    shape = (height, width) if channels == 1 else (height, width, channels)
    high = 65535 if dtype == np.uint16 else 255
    return np.random.default_rng(3).integers(0, high + 1, shape).astype(dtype)


def padded_message(pixels: np.ndarray, encoding: str, pad: int, bigendian: bool) -> Image:
    """An Image whose rows carry ``pad`` garbage bytes, in the byte order asked for.

    Semi-planar YUV's chroma rows (one for every two of ``pixels``, its luma) are random.
    """
    order = ">" if bigendian else "<"
    rows = pixels.astype(pixels.dtype.newbyteorder(order)).reshape(pixels.shape[0], -1)
    raw = rows.view(np.uint8).reshape(pixels.shape[0], -1)
    if encoding in SEMIPLANAR_YUV420:
        chroma = np.random.default_rng(4).integers(0, 256, ((len(raw) + 1) // 2, raw.shape[1]))
        raw = np.vstack([raw, chroma.astype(np.uint8)])
    padded = np.hstack([raw, np.full((raw.shape[0], pad), 0xAB, np.uint8)])
    return Image(
        header=HEADER,
        height=pixels.shape[0],
        width=pixels.shape[1],
        encoding=encoding,
        is_bigendian=bigendian,
        step=padded.shape[1],
        data=array.array("B", padded.tobytes()),
    )


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
def test_array_to_image_round_trips_every_encoding(encoding):
    pixels = pixels_for(encoding)
    msg = array_to_image(pixels, encoding, HEADER)
    assert (msg.encoding, msg.height, msg.width) == (encoding, 5, 7)
    assert msg.header == HEADER
    np.testing.assert_array_equal(image_to_array(msg), pixels)


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
@pytest.mark.parametrize("bigendian", [False, True])
def test_image_to_array_honours_row_padding_and_byte_order(encoding, bigendian):
    pixels = pixels_for(encoding)
    msg = padded_message(pixels, encoding, pad=5, bigendian=bigendian)
    result = image_to_array(msg)
    assert result.dtype.isnative
    np.testing.assert_array_equal(result, pixels)


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
@pytest.mark.parametrize("pad", [1, 5])
def test_detector_input_is_the_same_whatever_bytes_pad_the_rows(encoding, pad):
    """Padding of bytes that are not a whole pixel (an odd step of 16-bit pixels) too:
    the rows then lie at odd addresses, which OpenCV does not take."""
    pixels = pixels_for(encoding, height=6, width=8)
    plain = image_to_detector_input(padded_message(pixels, encoding, 0, False))
    padded = image_to_detector_input(padded_message(pixels, encoding, pad, False))
    np.testing.assert_array_equal(padded, plain)
    assert Detector().detect(padded).counts["accepted"] == 0


def test_image_to_array_reads_big_endian_mono16_values():
    msg = Image(height=1, width=2, encoding="mono16", is_bigendian=True, step=4)
    msg.data = array.array("B", bytes([0x12, 0x34, 0xFF, 0x00]))
    np.testing.assert_array_equal(image_to_array(msg), [[0x1234, 0xFF00]])


@pytest.mark.parametrize(
    ("encoding", "expected_bgr"),
    [
        ("rgb8", [30, 20, 10]),
        ("rgba8", [30, 20, 10, 40]),
        ("bgr8", [10, 20, 30]),
        ("rgb16", [30, 20, 10]),
        ("rgba16", [30, 20, 10, 40]),
        ("bgra16", [10, 20, 30, 40]),
    ],
)
def test_detector_input_is_in_bgr_order(encoding, expected_bgr):
    dtype, channels = ENCODINGS[encoding]
    pixels = np.tile(np.array([10, 20, 30, 40][:channels], dtype), (2, 3, 1))
    result = image_to_detector_input(array_to_image(pixels, encoding))
    assert result.dtype == dtype
    np.testing.assert_array_equal(result[1, 2], expected_bgr)


@pytest.mark.parametrize(
    ("encoding", "opencv_code"),
    [
        ("uyvy", cv2.COLOR_YUV2GRAY_UYVY),
        ("yuv422", cv2.COLOR_YUV2GRAY_UYVY),
        ("yuyv", cv2.COLOR_YUV2GRAY_YUY2),
        ("yuv422_yuy2", cv2.COLOR_YUV2GRAY_YUY2),
    ],
)
def test_packed_yuv_is_read_as_its_luma_as_cv_bridge_reads_it(encoding, opencv_code):
    luma = x_marker_64()
    chroma = np.random.default_rng(5).integers(0, 256, luma.shape).astype(np.uint8)
    pixels = np.dstack([chroma, luma] if YUV422_LUMA_BYTE[encoding] else [luma, chroma])
    grey = image_to_detector_input(padded_message(pixels, encoding, pad=4, bigendian=False))
    np.testing.assert_array_equal(grey, luma)
    np.testing.assert_array_equal(grey, cv2.cvtColor(pixels, opencv_code))
    (found,) = Detector(DetectorConfig()).detect(grey).detections
    assert np.hypot(found.x - 31.5, found.y - 31.5) < 1e-3


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
def test_detector_finds_the_exact_centre_through_every_encoding(encoding):
    grey = x_marker_64()
    dtype, channels = ENCODINGS[encoding]
    pixels = grey.astype(np.uint16) * 257 if dtype == np.uint16 else grey
    if channels > 1:
        pixels = np.repeat(pixels[:, :, None], channels, axis=2)
    msg = padded_message(pixels, encoding, pad=3, bigendian=True)
    (found,) = Detector(DetectorConfig()).detect(image_to_detector_input(msg)).detections
    # Demosaicing weighs the channels differently at each pixel of a Bayer cell.
    tolerance_px = 0.03 if encoding in BAYER_ENCODINGS else 1e-3
    assert np.hypot(found.x - 31.5, found.y - 31.5) < tolerance_px


def test_semi_planar_yuv_is_read_as_its_luma_plane_and_its_chroma_rows_must_be_there():
    luma = x_marker_64()
    msg = padded_message(luma, "nv12", pad=6, bigendian=False)
    np.testing.assert_array_equal(image_to_detector_input(msg), luma)
    # A driver's 4:2:0 frame of 64 rows holds 96 rows of data (sensor_msgs' scaling of 1.5).
    assert len(msg.data) == 96 * msg.step
    msg.data = msg.data[: 64 * msg.step]
    with pytest.raises(ImageError, match=r"but \(height 64 \+ 32 chroma rows\) x step 70"):
        image_to_array(msg)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"encoding": "nv24"}, r"unsupported encoding 'nv24'"),
        ({"encoding": "32FC1"}, r"unsupported encoding '32FC1'"),
        ({"height": 0, "data": array.array("B")}, r"empty image \(7x0\)"),
        ({"width": 0}, r"empty image \(0x5\)"),
        ({"step": 6}, r"step 6 B is shorter than one row of 7 mono8 pixels \(7 B\)"),
        ({"data": array.array("B", bytes(34))}, r"data holds 34 B but height 5 x step 7 = 35 B"),
    ],
)
def test_image_to_array_raises_naming_the_problem(change, match):
    msg = array_to_image(pixels_for("mono8"), "mono8", HEADER)
    for name, value in change.items():
        setattr(msg, name, value)
    with pytest.raises(ImageError, match=match):
        image_to_array(msg)


@pytest.mark.parametrize("encoding", ["8UC1", "16UC1", "8UC3", "32FC1"])
def test_a_generic_opencv_type_is_refused_saying_why_and_naming_the_grey_ones(encoding):
    """Its bytes could be read, but not as grey: a 16UC1 frame is a depth image, most often."""
    msg = array_to_image(pixels_for("mono8"), "mono8", HEADER)
    msg.encoding = encoding
    with pytest.raises(ImageError, match=rf"^unsupported encoding '{encoding}': a generic type, "):
        image_to_detector_input(msg)
    msg.encoding = "mono 8"
    with pytest.raises(ImageError, match=r"^unsupported encoding 'mono 8' \(expected one of mono"):
        image_to_detector_input(msg)


def test_an_image_over_max_pixels_is_refused_from_its_width_and_height_alone():
    msg = array_to_image(pixels_for("mono8"), "mono8", HEADER)
    msg.height, msg.width, msg.step = 30000, 30000, 30000  # data is still 35 B
    with pytest.raises(ImageError, match=r"image: 30000x30000 = 900000000 px exceeds max_pix"):
        image_to_detector_input(msg, DetectorConfig().max_pixels)
    assert image_to_detector_input(array_to_image(pixels_for("mono8"), "mono8"), 35).shape == (5, 7)


def test_a_hostile_encoding_string_is_quoted_short():
    msg = array_to_image(pixels_for("mono8"), "mono8", HEADER)
    msg.encoding = "x" * 1_000_000
    with pytest.raises(ImageError) as raised:
        image_to_array(msg)
    assert len(str(raised.value)) < 400
    assert "(1000002 characters)" in str(raised.value)


def test_array_to_image_rejects_pixels_that_do_not_fit_the_encoding():
    with pytest.raises(ImageError, match=r"a bgr8 image needs 3 channel\(s\) of uint8"):
        array_to_image(np.zeros((4, 4), np.uint8), "bgr8")
    with pytest.raises(ImageError, match=r"unsupported encoding 'mono32'"):
        array_to_image(np.zeros((4, 4), np.uint32), "mono32")


def make_detections(n):
    return [
        Detection(
            x=10.25 + i,
            y=20.5 - i,
            score=0.9,
            sigma=0.01 * (i + 1),
            angle1=0.1,
            angle2=1.7,
            radius_px=12.0,
        )
        for i in range(n)
    ]


def test_detections_to_cloud_has_the_documented_layout():
    cloud = detections_to_cloud(HEADER, make_detections(3))
    assert cloud.header == HEADER
    assert (cloud.height, cloud.width, cloud.point_step, cloud.row_step) == (1, 3, 48, 144)
    assert cloud.is_dense and not cloud.is_bigendian
    assert [(f.name, f.offset, f.datatype, f.count) for f in cloud.fields] == [
        (name, 8 * i, PointField.FLOAT64, 1) for i, name in enumerate(CLOUD_FIELDS)
    ]
    assert len(cloud.data) == 144


def test_a_truth_cloud_names_each_marker_in_a_uint32_after_the_nodes_fields():
    detections = make_detections(3)
    cloud = detections_to_cloud(HEADER, detections, marker_ids=[7, 0, 2**32 - 1])
    assert (cloud.width, cloud.point_step, cloud.row_step, len(cloud.data)) == (3, 56, 168, 168)
    assert [(f.name, f.offset, f.datatype, f.count) for f in cloud.fields] == [
        *((name, 8 * i, PointField.FLOAT64, 1) for i, name in enumerate(CLOUD_FIELDS)),
        (MARKER_ID_FIELD, 48, PointField.UINT32, 1),
    ]
    points = cloud_to_array(deserialize_message(serialize_message(cloud), PointCloud2))
    assert points[MARKER_ID_FIELD].tolist() == [7, 0, 2**32 - 1]
    # The node's fields hold what they hold without the ids, byte for byte.
    plain = cloud_to_array(detections_to_cloud(HEADER, detections))
    for name in CLOUD_FIELDS:
        np.testing.assert_array_equal(points[name], plain[name])
    with pytest.raises(ValueError, match="2 marker ids for 3 detections"):
        detections_to_cloud(HEADER, detections, marker_ids=[1, 2])
    with pytest.raises(ValueError, match="outside uint32"):
        detections_to_cloud(HEADER, detections, marker_ids=[1, 2, -1])


def test_cloud_round_trips_through_serialisation():
    detections = make_detections(4)
    wire = serialize_message(detections_to_cloud(HEADER, detections))
    cloud = deserialize_message(wire, PointCloud2)
    points = cloud_to_array(cloud)
    assert points.dtype.names == CLOUD_FIELDS
    expected = [[d.x, d.y, d.sigma, d.score, d.angle1, d.angle2] for d in detections]
    np.testing.assert_array_equal(recfunctions.structured_to_unstructured(points), expected)
    assert cloud.header == HEADER


def test_cloud_of_no_detection_is_empty():
    cloud = detections_to_cloud(HEADER, [])
    assert (cloud.width, cloud.row_step, len(cloud.data)) == (0, 0, 0)
    assert cloud_to_array(cloud).shape == (0,)


def test_a_cloud_of_no_points_and_no_declared_layout_is_empty():
    assert cloud_to_array(PointCloud2()).shape == (0,)


def _cloud(fields: list[tuple[str, int]], point_step: int, width: int = 2) -> PointCloud2:
    """A cloud of ``width`` zero points with float64 ``fields`` at (name, offset)."""
    cloud = PointCloud2(height=1, width=width, point_step=point_step, row_step=width * point_step)
    cloud.fields = [
        PointField(name=name, offset=offset, datatype=PointField.FLOAT64, count=1)
        for name, offset in fields
    ]
    cloud.data = bytes(width * point_step)
    return cloud


@pytest.mark.parametrize(
    ("cloud", "match"),
    [
        (_cloud([("x", 0), ("x", 8)], 16), r"point field 'x' is given twice"),
        (_cloud([("x", 0), ("y", 8)], 12), r"'y' \(8 B at offset 8\) overruns point_step 12 B"),
        (_cloud([], 0), r"2 points of point_step 0 B"),
    ],
    ids=["a name twice", "a field past the point", "points of no size"],
)
def test_cloud_to_array_refuses_a_layout_that_cannot_hold_its_fields(cloud, match):
    with pytest.raises(ImageError, match=match):
        cloud_to_array(cloud)


def test_cloud_to_array_reads_a_foreign_padded_big_endian_cloud():
    points = np.array([(1.5, -2.0), (3.25, 4.0)], dtype=[("u", ">f4"), ("v", ">f8")])
    cloud = PointCloud2(height=1, width=2, point_step=16, row_step=32, is_bigendian=True)
    cloud.fields = [
        PointField(name="u", offset=0, datatype=PointField.FLOAT32, count=1),
        PointField(name="v", offset=8, datatype=PointField.FLOAT64, count=1),
    ]
    packed = np.zeros(
        2, dtype={"names": ["u", "v"], "formats": [">f4", ">f8"], "offsets": [0, 8], "itemsize": 16}
    )
    packed["u"], packed["v"] = points["u"], points["v"]
    cloud.data = array.array("B", packed.tobytes())
    result = cloud_to_array(cloud)
    np.testing.assert_array_equal(result["u"], [1.5, 3.25])
    np.testing.assert_array_equal(result["v"], [-2.0, 4.0])


def test_cloud_to_array_rejects_vector_fields_and_short_data():
    cloud = detections_to_cloud(HEADER, make_detections(2))
    cloud.data = cloud.data[:-1]
    with pytest.raises(ImageError, match=r"cloud data holds 95 B"):
        cloud_to_array(cloud)
    cloud.fields[0].count = 3
    with pytest.raises(ImageError, match=r"point field 'x': datatype 8 x count 3"):
        cloud_to_array(cloud)
