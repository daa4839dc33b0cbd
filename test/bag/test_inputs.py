"""The inputs flights come in: compressed images (JPEG, PNG) and ROS 1 bags, into replay.

Bags are written into ``tmp_path`` here, rosbag2 through the package's own
writer and ROS 1 through rosbags' (serialised with its ROS 1 Noetic typestore,
as a ROS 1 recorder writes them). Every frame holds one rendered marker whose
centre is known exactly.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from builtin_interfaces.msg import Time
from encoded_images import compressed_message, transport_encoded
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import CompressedImage, Image, PointCloud2, PointField
from std_msgs.msg import Header

from marker_localizer.bag.io import BagReader, BagWriter
from marker_localizer.bag.replay import image_cameras, replay_bag
from marker_localizer.core.image import bayer_to_grey
from marker_localizer.core.result import Detection
from marker_localizer.errors import ImageError
from marker_localizer.ros.conversions import (
    array_to_image,
    cloud_to_array,
    compressed_to_detector_input,
    detections_to_cloud,
)
from marker_localizer.synthetic import render_markers
from marker_localizer.synthetic.scene import MarkerPlacement, bayer_gain

CENTRE = (40.3, 30.6)
#: JPEG at quality 95 moves a 14 px marker's centre by a few hundredths of a pixel.
TOLERANCE_PX = 0.1
MAX_PIXELS = 10**8


def marker_frame() -> np.ndarray:
    """An 80 x 64 frame with one blurred marker of radius 14 px at CENTRE."""
    placement = MarkerPlacement(*CENTRE, 14.0, rotation_rad=0.4)
    return render_markers(
        (64, 80), [placement], 1, reflectances=(0.1, 0.9), blur_sigma_px=0.8
    ).image


def encoded(kind: str, pixels: np.ndarray | None = None) -> bytes:
    """``pixels`` (the marker frame if None) as the compressed plugin encodes them."""
    return transport_encoded(kind, marker_frame() if pixels is None else pixels)


def compressed(kind: str, sec: int, data: bytes | None = None) -> CompressedImage:
    """The marker frame (or ``data``) as the compressed plugin publishes it for camera "cam"."""
    return compressed_message(kind, sec, encoded(kind) if data is None else data, "cam")


def points(replay_out: Path, camera: str) -> list[np.ndarray]:
    """The (N, 2) marker centres of each frame of ``camera`` in a replay's output."""
    with BagReader(replay_out) as bag:
        arrays = [cloud_to_array(m.decode()) for m in bag.messages({f"/{camera}/marker_points"})]
    return [np.column_stack([a["x"], a["y"]]) for a in arrays]


@pytest.mark.parametrize("kind", ["jpeg", "png"])
def test_a_compressed_image_decodes_to_the_pixels_the_detector_reads(kind):
    pixels = compressed_to_detector_input(compressed(kind, 1), MAX_PIXELS)
    assert pixels.shape == (64, 80) and pixels.dtype == np.uint8
    assert np.abs(pixels.astype(int) - marker_frame()).max() <= (0 if kind == "png" else 12)


def test_a_16_bit_png_stays_16_bit():
    deep = marker_frame().astype(np.uint16) * 257
    msg = compressed("png", 1, encoded("png", deep))
    np.testing.assert_array_equal(compressed_to_detector_input(msg, MAX_PIXELS), deep)


def test_undecodable_data_is_an_image_error_naming_the_format():
    with pytest.raises(ImageError, match=r"compressed image .*jpeg compressed.*not a readable"):
        compressed_to_detector_input(compressed("jpeg", 1, b"\x00" * 64), MAX_PIXELS)
    # OpenCV's own words for it were "(!buf.empty())".
    with pytest.raises(ImageError, match=r"compressed image .*: no data \(0 bytes\)$"):
        compressed_to_detector_input(compressed("jpeg", 1, b""), MAX_PIXELS)


def test_cameras_are_found_in_either_form_and_raw_wins_where_both_hold_frames():
    topics = {
        "/cam0/image_raw": "sensor_msgs/msg/Image",
        "/cam0/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
        "/cam1/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
        "/cam2/image_raw/compressed": "sensor_msgs/msg/Image",  # wrong type: not a camera
        "/image_raw/compressed": "sensor_msgs/msg/CompressedImage",  # no camera name
    }
    assert image_cameras(topics) == {
        "cam0": "/cam0/image_raw",
        "cam1": "/cam1/image_raw/compressed",
    }
    # A raw topic declared but never written to: its camera's frames are the compressed.
    counts = {"/cam0/image_raw": 0, "/cam0/image_raw/compressed": 3}
    assert image_cameras(topics, counts)["cam0"] == "/cam0/image_raw/compressed"
    counts = {"/cam0/image_raw": 1, "/cam0/image_raw/compressed": 3}
    assert image_cameras(topics, counts)["cam0"] == "/cam0/image_raw"


def test_replay_reads_compressed_frames_and_counts_undecodable_ones_per_camera(tmp_path):
    bag = tmp_path / "compressed"
    with BagWriter(bag) as writer:
        for camera in ("cam0", "cam1"):
            writer.add_topic(f"/{camera}/image_raw/compressed", "sensor_msgs/msg/CompressedImage")
        # Declared, never written to (its frames were not published while recording).
        writer.add_topic("/cam1/image_raw", "sensor_msgs/msg/Image")
        for sec, (camera, msg) in enumerate(
            [
                ("cam0", compressed("jpeg", 1)),
                ("cam1", compressed("png", 2)),
                ("cam1", compressed("png", 3, b"not an image")),
                ("cam0", compressed("jpeg", 4)),
            ],
            start=1,
        ):
            writer.write(f"/{camera}/image_raw/compressed", sec * 10**9, msg)
    report = replay_bag(bag, tmp_path / "out", workers=1)
    assert (report.cameras["cam0"].frames, report.cameras["cam0"].failed) == (2, 0)
    assert (report.cameras["cam1"].frames, report.cameras["cam1"].failed) == (1, 1)
    assert "not a readable image" in report.cameras["cam1"].last_error
    for camera in ("cam0", "cam1"):
        for found in points(tmp_path / "out", camera):
            np.testing.assert_allclose(found, [CENTRE], atol=TOLERANCE_PX)


def test_replay_counts_truth_clouds_without_x_and_y_and_reads_an_empty_one_as_no_markers(
    tmp_path,
):
    """A cloud of other fields (a foreign publisher's) is not truth; one of no points and
    no declared layout (a default PointCloud2) is a frame without markers."""
    foreign = PointCloud2(header=Header(stamp=Time(sec=1)), height=1, width=1, point_step=8)
    foreign.fields = [PointField(name="u", offset=0, datatype=PointField.FLOAT64, count=1)]
    foreign.row_step, foreign.data = 8, bytes(8)
    bag = _bag_with_truth(tmp_path, [foreign, PointCloud2(header=Header(stamp=Time(sec=2)))])
    report = replay_bag(bag, tmp_path / "out", workers=1)
    assert report.undecodable == {"/cam0/marker_points_truth": 1}
    assert report.cameras["cam0"].frames == 2
    # The second frame's truth holds no marker: its detection is a false point.
    evaluation = report.cameras["cam0"].evaluation
    assert (evaluation.frames, evaluation.n_truth, evaluation.n_false_positives) == (1, 0, 1)


def test_replay_counts_truth_whose_marker_ids_are_no_uint32_and_reads_the_rest(tmp_path):
    """A marker_id field of float64 (a foreign truth's) names no marker: that truth is
    counted undecodable, not clustered by ids cast from fractions; uint32 ids are read."""
    fields = ["x", "y", "marker_id"]
    foreign = PointCloud2(header=Header(stamp=Time(sec=1)), height=1, width=1, point_step=24)
    foreign.fields = [
        PointField(name=name, offset=8 * i, datatype=PointField.FLOAT64, count=1)
        for i, name in enumerate(fields)
    ]
    foreign.row_step, foreign.data = 24, np.array([*CENTRE, 2.5]).tobytes()
    truth = Detection(*CENTRE, score=1.0, sigma=0.0, angle1=0.4, angle2=2.0, radius_px=14.0)
    named = detections_to_cloud(Header(stamp=Time(sec=2)), [truth], marker_ids=[3])
    bag = _bag_with_truth(tmp_path, [foreign, named])
    report = replay_bag(bag, tmp_path / "out", workers=1)
    assert report.undecodable == {"/cam0/marker_points_truth": 1}
    evaluation = report.cameras["cam0"].evaluation
    assert (evaluation.frames, evaluation.n_matched, list(evaluation.marker_ids)) == (1, 1, [3])
    assert evaluation.clustered_by_marker


def test_replay_reads_a_ros1_bag_raw_and_compressed(tmp_path):
    noetic = get_typestore(Stores.ROS1_NOETIC)
    types = noetic.types
    header = types["std_msgs/msg/Header"]
    stamp = types["builtin_interfaces/msg/Time"]
    frame = marker_frame()
    bag = tmp_path / "flight.bag"
    with Ros1Writer(bag) as writer:
        raw = writer.add_connection("/cam0/image_raw", "sensor_msgs/msg/Image", typestore=noetic)
        jpeg = writer.add_connection(
            "/cam1/image_raw/compressed", "sensor_msgs/msg/CompressedImage", typestore=noetic
        )
        for seq, sec in enumerate((5, 6)):
            image = types["sensor_msgs/msg/Image"](
                header=header(seq=seq, stamp=stamp(sec=sec, nanosec=0), frame_id="cam0_optical"),
                height=64,
                width=80,
                encoding="mono8",
                is_bigendian=0,
                step=80,
                data=frame.ravel(),
            )
            writer.write(raw, sec * 10**9, noetic.serialize_ros1(image, "sensor_msgs/msg/Image"))
            packed = types["sensor_msgs/msg/CompressedImage"](
                header=header(seq=seq, stamp=stamp(sec=sec, nanosec=1), frame_id="cam1_optical"),
                format="jpeg",
                data=np.frombuffer(encoded("jpeg"), np.uint8),
            )
            writer.write(
                jpeg,
                sec * 10**9 + 1,
                noetic.serialize_ros1(packed, "sensor_msgs/msg/CompressedImage"),
            )
    report = replay_bag(bag, tmp_path / "out", workers=1)
    assert report.complete, report.cameras
    assert {c: r.frames for c, r in report.cameras.items()} == {"cam0": 2, "cam1": 2}
    with BagReader(tmp_path / "out") as out:
        clouds = [m.decode() for m in out.messages({"/cam0/marker_points"})]
    # The ROS 1 header's stamp and frame_id come through unchanged (its seq has no place).
    assert [(c.header.stamp.sec, c.header.frame_id) for c in clouds] == [
        (5, "cam0_optical"),
        (6, "cam0_optical"),
    ]
    for camera in ("cam0", "cam1"):
        found = points(tmp_path / "out", camera)
        assert len(found) == 2
        for xy in found:
            np.testing.assert_allclose(xy, [CENTRE], atol=TOLERANCE_PX)


def assert_replay_finds_the_marker_in_each_camera(tmp_path: Path, frames: dict[str, Image]):
    """One frame a camera, written to a bag and replayed: each gives the marker at CENTRE."""
    bag = tmp_path / "bag"
    with BagWriter(bag) as writer:
        for camera, msg in frames.items():
            writer.add_topic(f"/{camera}/image_raw", "sensor_msgs/msg/Image")
            msg.header = Header(stamp=Time(sec=1), frame_id=f"{camera}_optical")
            writer.write(f"/{camera}/image_raw", 10**9, msg)
    report = replay_bag(bag, tmp_path / "out", workers=1)
    assert report.complete, report.cameras
    for camera in frames:
        (found,) = points(tmp_path / "out", camera)
        np.testing.assert_allclose(found, [CENTRE], atol=TOLERANCE_PX)


def test_replay_reads_a_cameras_raw_bayer_frames_as_grey(tmp_path):
    # The sensor's raw sites before white balance, as a driver publishes them.
    frame = marker_frame()
    mosaic = frame * bayer_gain(frame.shape, "rggb").astype(np.float64)
    assert_replay_finds_the_marker_in_each_camera(
        tmp_path,
        {
            "cam0": array_to_image(mosaic.round().astype(np.uint8), "bayer_rggb8"),
            "cam1": array_to_image((mosaic * 257).round().astype(np.uint16), "bayer_rggb16"),
        },
    )


def raw_mosaic() -> np.ndarray:
    """The 8-bit RGGB mosaic a colour camera gives of :func:`marker_frame`."""
    frame = marker_frame()
    return (frame * bayer_gain(frame.shape, "rggb").astype(np.float64)).round().astype(np.uint8)


def test_a_bayer_mosaic_kept_in_png_is_demosaiced_and_one_made_grey_for_jpeg_is_not():
    # image_transport's PNG keeps a Bayer frame's mosaic and names no target encoding;
    # its JPEG converts the frame to grey first and says so.
    mosaic = raw_mosaic()
    png = CompressedImage(format="bayer_rggb8; png compressed ", data=encoded("png", mosaic))
    np.testing.assert_array_equal(
        compressed_to_detector_input(png, MAX_PIXELS), bayer_to_grey(mosaic, "rggb")
    )
    data = encoded("jpeg", bayer_to_grey(mosaic, "rggb"))
    jpeg = CompressedImage(format="bayer_rggb8; jpeg compressed mono8", data=data)
    np.testing.assert_array_equal(
        compressed_to_detector_input(jpeg, MAX_PIXELS),
        cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED),
    )


def test_replay_finds_a_bayer_camera_where_its_raw_frames_put_it_from_its_png_frames(tmp_path):
    """The PNG transport's frames of a Bayer camera give the raw frames' points exactly."""
    mosaic = raw_mosaic()
    bag = tmp_path / "bag"
    with BagWriter(bag) as writer:
        writer.add_topic("/raw/image_raw", "sensor_msgs/msg/Image")
        writer.add_topic("/png/image_raw/compressed", "sensor_msgs/msg/CompressedImage")
        header = Header(stamp=Time(sec=1), frame_id="cam_optical")
        writer.write("/raw/image_raw", 10**9, array_to_image(mosaic, "bayer_rggb8", header))
        png = CompressedImage(
            header=header, format="bayer_rggb8; png compressed ", data=encoded("png", mosaic)
        )
        writer.write("/png/image_raw/compressed", 10**9, png)
    assert replay_bag(bag, tmp_path / "out", workers=1).complete
    (raw,) = points(tmp_path / "out", "raw")
    (from_png,) = points(tmp_path / "out", "png")
    assert raw.shape == (1, 2)
    np.testing.assert_array_equal(from_png, raw)


def test_replay_reads_packed_and_semi_planar_yuv_frames_by_their_luma(tmp_path):
    # A USB camera's frames (luma and a chroma sample a pixel, in either byte order), and
    # an OAK camera's (the luma plane, then the chroma rows).
    luma = marker_frame().round().astype(np.uint8)
    chroma = np.random.default_rng(2).integers(0, 256, luma.shape).astype(np.uint8)
    assert_replay_finds_the_marker_in_each_camera(
        tmp_path,
        {
            "cam0": array_to_image(np.dstack([chroma, luma]), "uyvy"),
            "cam1": array_to_image(np.dstack([luma, chroma]), "yuv422_yuy2"),
            "cam2": array_to_image(luma, "nv21"),
        },
    )


def _bag_with_truth(tmp_path, clouds):
    """A bag of cam0's marker frame at 1, 2, ... s, each beside its truth cloud."""
    bag = tmp_path / "truth"
    with BagWriter(bag) as writer:
        writer.add_topic("/cam0/image_raw", "sensor_msgs/msg/Image")
        writer.add_topic("/cam0/marker_points_truth", "sensor_msgs/msg/PointCloud2")
        for sec, cloud in enumerate(clouds, start=1):
            header = Header(stamp=Time(sec=sec), frame_id="cam0_optical")
            writer.write(
                "/cam0/image_raw", sec * 10**9, array_to_image(marker_frame(), "mono8", header)
            )
            writer.write("/cam0/marker_points_truth", sec * 10**9, cloud)
    return bag
