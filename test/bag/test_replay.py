"""Simulate -> bag -> offline replay through the node's frame processor, and bad input.

Bags are written into ``tmp_path`` by the code under test (``simulate``) or by
small helpers here; nothing binary is committed. Frames are 320 x 240 (the
simulator keeps markers at 4 to 20 px radius at any frame size).
"""

from __future__ import annotations

import math
import os
import re
import sqlite3
import struct
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from blas_threads import openblas_threads, two_threaded_openblas
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus
from scenes import panning_frames
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from scipy.stats import t as student_t
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_msgs.msg import Header

from marker_localizer import evaluation
from marker_localizer.bag import replay
from marker_localizer.bag.io import BagReader, BagWriter, typestore
from marker_localizer.bag.record import PARTIAL_SUFFIX, TRUTH_SUFFIX, recorded_flight
from marker_localizer.bag.replay import (
    RECALL_INTERVAL_ASSUMES,
    RECALL_INTERVAL_BY_MARKER,
    TruthMatcher,
    format_report,
    replay_bag,
)
from marker_localizer.cli import main as cli
from marker_localizer.config import DetectorConfig, TrackerConfig
from marker_localizer.core.result import Detection
from marker_localizer.errors import BagError, ConfigError
from marker_localizer.evaluation import interval_text
from marker_localizer.ros.conversions import (
    CLOUD_FIELDS,
    MARKER_ID_FIELD,
    array_to_image,
    cloud_to_array,
    detections_to_cloud,
)
from marker_localizer.synthetic import render_markers
from marker_localizer.synthetic.scene import MarkerPlacement

REPO = Path(__file__).resolve().parents[2]
PARAMS_FILE = REPO / "config" / "marker_localizer.yaml"
CAMERAS = ("cam0", "cam1", "cam2", "cam3", "cam4")
FRAMES = 3
S = 1_000_000_000  # ns per s
#: What replay must reach on the simulated 320 x 240 flight (measured: recall
#: 0.955 to 0.987 of 157 markers, mean error 0.018 px, no false positive).
MIN_RECALL = 0.9
MAX_MEAN_ERROR_PX = 0.1


# --------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def flight_bag(tmp_path_factory):
    path = tmp_path_factory.mktemp("flight") / "flight"
    argv = ["--out", str(path), "--frames", str(FRAMES), "--width", "320", "--height", "240"]
    assert cli(["simulate", *argv, "--seed", "0"]) == 0
    return path


@pytest.fixture(scope="module")
def replayed(flight_bag, tmp_path_factory):
    out = tmp_path_factory.mktemp("replay") / "out"
    return replay_bag(flight_bag, out, workers=2), out


def stamp(ns: int) -> Time:
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def x_marker_frame(centre=(40.3, 30.6)) -> np.ndarray:
    """A 80 x 64 frame with one blurred marker of radius 14 px at ``centre``."""
    scene = render_markers(
        (64, 80),
        [MarkerPlacement(*centre, 14.0, rotation_rad=0.4)],
        1,
        reflectances=(0.1, 0.9),
        blur_sigma_px=0.8,
    )
    return scene.image


#: The truth of :func:`x_marker_frame`'s marker.
X_MARKER_TRUTH = [
    Detection(x=40.3, y=30.6, score=1.0, sigma=0.0, angle1=0.4, angle2=2.0, radius_px=14)
]


def write_bag(path: Path, frames, storage: str = "mcap") -> Path:
    """A bag of ``(topic, stamp_ns, Image)``; bag time = stamp."""
    with BagWriter(path, storage) as bag:
        for topic, stamp_ns, msg in frames:
            bag.add_topic(topic, "sensor_msgs/msg/Image")
            bag.write(topic, stamp_ns, msg)
    return path


def image(pixels: np.ndarray, stamp_ns: int, encoding: str = "mono8") -> Image:
    return array_to_image(pixels, encoding, Header(stamp=stamp(stamp_ns), frame_id="cam0_optical"))


def leftovers(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir())


# --------------------------------------------------------------------------- simulate


def test_simulated_bag_has_images_camera_info_truth_and_tf_static_per_camera(flight_bag):
    with BagReader(flight_bag) as bag:
        topics = bag.topics
        counts = bag.message_counts
        for cam in CAMERAS:
            assert topics[f"/{cam}/image_raw"] == "sensor_msgs/msg/Image"
            assert topics[f"/{cam}/camera_info"] == "sensor_msgs/msg/CameraInfo"
            assert topics[f"/{cam}/marker_points_truth"] == "sensor_msgs/msg/PointCloud2"
            assert counts[f"/{cam}/image_raw"] == FRAMES
        assert topics["/tf_static"] == "tf2_msgs/msg/TFMessage"
        messages = list(bag.messages())
    images = [m for m in messages if m.topic == "/cam3/image_raw"]
    info = next(m for m in messages if m.topic == "/cam3/camera_info").decode()
    truth = next(m for m in messages if m.topic == "/cam3/marker_points_truth").decode()
    first = images[0].decode()
    assert (first.encoding, first.width, first.height) == ("mono8", 320, 240)
    assert first.header.frame_id == "cam3_optical"
    for m in images:  # bag time is the header stamp is the frame time, 2 Hz
        header = m.decode().header
        assert header.stamp.sec * 1_000_000_000 + header.stamp.nanosec == m.time_ns
    assert np.diff([m.time_ns for m in images]).tolist() == [500_000_000] * (FRAMES - 1)
    k = np.reshape(info.k, (3, 3))
    assert k[0, 0] == pytest.approx(160.0 / np.tan(np.radians(30.0)))
    assert (k[0, 2], k[1, 2]) == (159.5, 119.5)
    np.testing.assert_array_equal(np.reshape(info.p, (3, 4))[:, :3], k)
    np.testing.assert_array_equal(info.d, np.zeros(5))
    np.testing.assert_array_equal(np.reshape(info.r, (3, 3)), np.eye(3))
    points = cloud_to_array(truth)
    assert points.dtype.names == (*CLOUD_FIELDS, MARKER_ID_FIELD) and len(points) > 3
    assert points.dtype[MARKER_ID_FIELD] == np.uint32
    assert (points["sigma"] == 0).all() and (points["score"] == 1).all()
    tf_raw = next(m for m in messages if m.topic == "/tf_static").raw
    tf = typestore().deserialize_cdr(tf_raw, "tf2_msgs/msg/TFMessage")
    assert [t.child_frame_id for t in tf.transforms] == [f"{c}_optical" for c in CAMERAS]
    assert {t.header.frame_id for t in tf.transforms} == {"base_link"}
    nadir = tf.transforms[0].transform.rotation  # optical z = body -z: 180 deg about an xy axis
    assert abs(nadir.w) < 1e-9


@pytest.mark.parametrize("truth_topic", [TRUTH_SUFFIX, PARTIAL_SUFFIX])
def test_the_recorded_flights_poses_and_markers_project_through_the_bags_calibration_onto_its_truth(
    flight_bag, truth_topic
):
    """What a pose estimator fed the bag is checked against: the aircraft's pose at each
    frame and the markers' world positions, through /tf_static and camera_info alone;
    each truth point names the marker that projects onto it (its marker_id), a marker
    the frame border cuts (the partial topic) as one wholly inside."""
    flight = recorded_flight(flight_bag)
    with BagReader(flight_bag) as bag:
        messages = list(bag.messages())
    tf_raw = next(m for m in messages if m.topic == "/tf_static").raw
    [extrinsic] = [
        t.transform
        for t in typestore().deserialize_cdr(tf_raw, "tf2_msgs/msg/TFMessage").transforms
        if t.child_frame_id == "cam2_optical"
    ]
    q, v = extrinsic.rotation, extrinsic.translation
    rotation_body_camera = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    k = np.reshape(next(m for m in messages if m.topic == "/cam2/camera_info").decode().k, (3, 3))
    world = np.array([[m.x_m, m.y_m, 0.0] for m in flight.markers])
    truths = [m for m in messages if m.topic == f"/cam2/{truth_topic}"]
    assert [p.stamp_ns for p in flight.poses] == [m.time_ns for m in truths]
    for pose, truth in zip(flight.poses, truths, strict=True):
        rotation = pose.rotation_world_body @ rotation_body_camera
        centre = pose.position_m + pose.rotation_world_body @ [v.x, v.y, v.z]
        in_camera = (world - centre) @ rotation
        ahead = in_camera[:, 2] > 0
        pixels = (in_camera[ahead] / in_camera[ahead, 2:]) @ k.T
        points = cloud_to_array(truth.decode())
        xy = np.column_stack([points["x"], points["y"]])
        assert len(xy) > 3
        distance, nearest = cKDTree(pixels[:, :2]).query(xy)
        assert distance.max() < 1e-6
        assert np.flatnonzero(ahead)[nearest].tolist() == points[MARKER_ID_FIELD].tolist()


def test_a_bag_simulate_did_not_write_has_no_recorded_flight(tmp_path):
    with BagWriter(tmp_path / "other") as bag:
        bag.add_topic("/note", "std_msgs/msg/String")
    with pytest.raises(BagError, match="no flight that simulate recorded"):
        recorded_flight(tmp_path / "other")


def test_the_bags_simulate_and_replay_write_name_ros_2_jazzy_as_their_distro(flight_bag, replayed):
    """metadata.yaml's ros_distro is the distro of the bag's message definitions, as
    rosbag2 writes it, not the name of the library that wrote the bag."""
    _, replayed_bag = replayed
    for bag in (flight_bag, replayed_bag):
        metadata = yaml.safe_load((bag / "metadata.yaml").read_text())
        assert metadata["rosbag2_bagfile_information"]["ros_distro"] == "jazzy"
        with BagReader(bag) as reader:
            assert reader.damage == []


def embedded_metadata(storage_file: Path) -> dict:
    """The copy of the metadata a storage file holds: what rosbag2 reads of a bare file."""
    if storage_file.suffix == ".db3":
        with sqlite3.connect(storage_file) as db:
            (text,) = db.execute("SELECT metadata FROM metadata").fetchone()
    else:  # the MCAP metadata record "rosbag2": {"serialized_metadata": YAML}
        data = storage_file.read_bytes()
        at = data.index(b"serialized_metadata") + len("serialized_metadata")
        (length,) = struct.unpack_from("<I", data, at)
        text = data[at + 4 : at + 4 + length].decode()
    return yaml.safe_load(text)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_bag_is_laid_out_as_ros2_bag_record_and_every_copy_of_its_metadata_names_jazzy(
    tmp_path, storage
):
    """NAME/NAME_0.<ext>, as rosbag2 numbers a bag's files (``ros2 bag reindex`` finds them
    by that number), and the storage's own copy of the metadata (what ``ros2 bag info``
    shows of a bare file, and reindex copies) says jazzy as metadata.yaml does."""
    bag = tmp_path / "flight"
    with BagWriter(bag, storage) as writer:
        writer.add_topic("/cam0/image_raw", "sensor_msgs/msg/Image")
        writer.write("/cam0/image_raw", 5, image(np.zeros((4, 4), np.uint8), 5))
        writer.set_metadata("note", "kept")
    extension = {"mcap": ".mcap", "sqlite3": ".db3"}[storage]
    assert sorted(os.listdir(bag)) == sorted([f"flight_0{extension}", "metadata.yaml"])
    metadata = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert metadata["relative_file_paths"] == [f"flight_0{extension}"]
    embedded = embedded_metadata(bag / f"flight_0{extension}")
    assert embedded == metadata
    assert embedded["ros_distro"] == "jazzy" and embedded["custom_data"] == {"note": "kept"}
    for path in (bag, bag / f"flight_0{extension}"):
        with BagReader(path) as reader:
            assert [m.time_ns for m in reader.messages()] == [5] and reader.damage == []


# --------------------------------------------------------------------------- replay


def test_replay_finds_the_simulated_markers_with_sub_pixel_error(replayed):
    report, _ = replayed
    assert list(report.cameras) == list(CAMERAS)
    assert all(c.frames == FRAMES for c in report.cameras.values())
    overall = report.evaluation
    stats = overall.stats
    sys.stdout.write(
        f"\nreplay 320x240 x5 cameras x{FRAMES}: recall {overall.recall:.3f} of {overall.n_truth}, "
        f"FP/frame {overall.fp_per_frame:.2f}, error mean {stats.mean:.4f} "
        f"RMS {stats.rms:.4f} p95 {stats.p95:.4f} max {stats.max:.4f} px\n"
    )
    assert overall.recall >= MIN_RECALL
    assert stats.mean <= MAX_MEAN_ERROR_PX
    assert overall.fp_per_frame <= 0.5
    for camera in report.cameras.values():
        assert camera.evaluation.recall >= 0.8
        assert camera.mean_ms > 0


def test_replays_accuracy_table_gives_each_recall_and_false_point_rate_its_interval(replayed):
    report, _ = replayed
    overall = report.evaluation
    # The throughput table's total row comes first, the accuracy table's last.
    *_, row = [line for line in format_report(report).splitlines() if line.startswith("all ")]
    low, high = overall.recall_interval
    assert low < overall.recall <= high
    assert f"{overall.recall:.3f}{f'{low:.3f}-{high:.3f}':>13}" in row
    assert f"{overall.fp_per_frame:.2f}" in row
    assert "-".join(f"{b:.2f}" for b in overall.fp_per_frame_interval) in row


def test_replay_clusters_a_simulated_flights_recall_interval_by_marker_and_says_so(replayed):
    # simulate's truth names its markers, and a flight sees them frame after frame: the
    # interval counts a marker seen again as the same one, every camera's and all.
    report, _ = replayed
    heading = next(line for line in format_report(report).splitlines() if "accuracy" in line)
    assert RECALL_INTERVAL_BY_MARKER in heading and RECALL_INTERVAL_ASSUMES not in heading
    overall = report.evaluation
    assert overall.clustered_by_marker
    assert all(c.evaluation.clustered_by_marker for c in report.cameras.values())
    assert overall.recall_interval == evaluation.marker_recall_interval(
        overall.found, overall.marker_ids
    )


#: A truth point on the blank ground of :func:`x_marker_frame`: never found.
BLANK_TRUTH = Detection(x=10.0, y=52.0, score=1.0, sigma=0.0, angle1=0.4, angle2=2.0, radius_px=14)


def seen_again_bag(path: Path, named: bool) -> Path:
    """Four frames of one camera: its marker (id 7) in each, found, and a truth point on
    blank ground, missed: id 9 in the first two frames, 11 in the last two. ``named``:
    the truth names its markers (marker_id), else the layout recorded before it did."""
    pixels = x_marker_frame()
    with BagWriter(path) as bag:
        bag.add_topic("/cam0/image_raw", "sensor_msgs/msg/Image")
        bag.add_topic(f"/cam0/{TRUTH_SUFFIX}", "sensor_msgs/msg/PointCloud2")
        for k, missed in enumerate([9, 9, 11, 11]):
            t = (k + 1) * S // 10
            bag.write("/cam0/image_raw", t, image(pixels, t))
            ids = [7, missed] if named else None
            cloud = detections_to_cloud(Header(stamp=stamp(t)), [*X_MARKER_TRUTH, BLANK_TRUTH], ids)
            bag.write(f"/cam0/{TRUTH_SUFFIX}", t, cloud)
    return path


def _wilson(found: int, total: int, design_effect: float, quantile: float) -> tuple[float, float]:
    """Wilson's score interval on total / design_effect trials, written out."""
    n, p, z2 = total / design_effect, found / total, quantile**2
    centre = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = math.sqrt(z2 * (p * (1 - p) / n + z2 / (4 * n * n))) / (1 + z2 / n)
    return centre - half, centre + half


def test_a_bag_whose_truth_names_its_markers_gives_the_marker_clustered_recall_interval(
    tmp_path,
):
    report = replay_bag(seen_again_bag(tmp_path / "named", True), tmp_path / "out", workers=1)
    tally = report.cameras["cam0"].evaluation
    assert (tally.n_matched, tally.n_truth) == (4, 8)
    # Per marker (found, truth): 7 (4, 4), 9 (0, 2), 11 (0, 2). Residuals 2, -1, -1 give
    # 3 / 2 x 6 / 8^2 against 0.25 / 8: a design effect of 4.5, t on 3 - 1 freedoms.
    assert list(tally.marker_ids) == [7, 9, 7, 9, 7, 11, 7, 11]
    assert tally.recall_design_effect == pytest.approx(4.5)
    expected = _wilson(4, 8, 4.5, student_t.ppf(0.975, 2))
    assert tally.recall_interval == pytest.approx(expected, abs=1e-12)
    text = format_report(report)
    assert RECALL_INTERVAL_BY_MARKER in text and RECALL_INTERVAL_ASSUMES not in text
    assert f"{interval_text(expected, 3):>13}" in text


def test_a_bag_whose_truth_names_no_marker_still_gives_the_frame_clustered_interval_and_says_so(
    tmp_path,
):
    # Truth recorded before it named its markers: each frame finds one of its two, so
    # the frames do not spread (t on 4 - 1 freedoms), and the report says what that assumes.
    report = replay_bag(seen_again_bag(tmp_path / "old", False), tmp_path / "out", workers=1)
    tally = report.cameras["cam0"].evaluation
    assert (tally.n_matched, tally.n_truth) == (4, 8)
    assert not tally.clustered_by_marker
    expected = _wilson(4, 8, 1.0, student_t.ppf(0.975, 3))
    assert tally.recall_interval == pytest.approx(expected, abs=1e-12)
    heading = next(line for line in format_report(report).splitlines() if "accuracy" in line)
    assert RECALL_INTERVAL_ASSUMES in heading and RECALL_INTERVAL_BY_MARKER not in heading
    assert "same markers seen again it is too narrow" in heading


@pytest.mark.parametrize("named", [True, False], ids=["partial names its markers", "old layout"])
def test_a_detection_on_a_marker_the_border_cuts_counts_neither_way_whatever_its_layout(
    tmp_path, named
):
    """Two frames: the found marker listed as cut by the border (id 7 where the partial
    list names its markers, as simulate now writes it; none, as it wrote it before), the
    truth a missed marker (id 9). Either way the detection is no false positive and the
    truth's ids cluster the recall."""
    pixels = x_marker_frame()
    with BagWriter(tmp_path / "cut") as bag:
        bag.add_topic("/cam0/image_raw", "sensor_msgs/msg/Image")
        bag.add_topic(f"/cam0/{TRUTH_SUFFIX}", "sensor_msgs/msg/PointCloud2")
        bag.add_topic(f"/cam0/{PARTIAL_SUFFIX}", "sensor_msgs/msg/PointCloud2")
        for k in range(2):
            t = (k + 1) * S // 10
            header = Header(stamp=stamp(t))
            bag.write("/cam0/image_raw", t, image(pixels, t))
            bag.write(f"/cam0/{TRUTH_SUFFIX}", t, detections_to_cloud(header, [BLANK_TRUTH], [9]))
            partial = detections_to_cloud(header, X_MARKER_TRUTH, [7] if named else None)
            bag.write(f"/cam0/{PARTIAL_SUFFIX}", t, partial)
    report = replay_bag(tmp_path / "cut", tmp_path / "out", workers=1)
    camera = report.cameras["cam0"]
    tally = camera.evaluation
    assert report.complete and report.undecodable == {}
    assert (camera.frames, camera.markers) == (2, 2)
    assert (tally.n_truth, tally.n_matched, tally.n_false_positives) == (2, 0, 0)
    assert tally.clustered_by_marker and list(tally.marker_ids) == [9, 9]


def test_replay_writes_points_with_the_input_header_at_the_input_bag_time(flight_bag, replayed):
    _, out = replayed
    with BagReader(flight_bag) as bag:
        inputs = {
            (m.topic.split("/")[1], m.time_ns): m.decode().header
            for m in bag.messages([f"/{c}/image_raw" for c in CAMERAS])
        }
    with BagReader(out) as bag:
        assert bag.topics["/diagnostics"] == "diagnostic_msgs/msg/DiagnosticArray"
        outputs = list(bag.messages([f"/{c}/marker_points" for c in CAMERAS]))
        diagnostics = [m.decode() for m in bag.messages(["/diagnostics"])]
    assert len(outputs) == len(inputs) == FRAMES * len(CAMERAS)
    for message in outputs:
        cloud = message.decode()
        header = inputs[(message.topic.split("/")[1], message.time_ns)]
        assert cloud.header == header
        assert cloud_to_array(cloud).dtype.names == CLOUD_FIELDS
    assert diagnostics, "at least the final /diagnostics"
    names = {s.name for s in diagnostics[-1].status}
    assert {f"marker_localizer: {c}" for c in CAMERAS} <= names
    final = {s.name: {kv.key: kv.value for kv in s.values} for s in diagnostics[-1].status}
    assert final["marker_localizer: cam0"]["frames processed"] == str(FRAMES)
    # The node's own status content (FrameProcessor.diagnostics), marked as a replay.
    node = final["marker_localizer: node"]
    assert node["mode"] == "replay"
    assert {"workers", "frames in flight", "max frame age (s)", "marker radius range (px)"} <= (
        set(node)
    )


def test_replay_main_reads_sqlite3_with_the_node_params_file_and_prints_both_tables(
    tmp_path, capsys
):
    bag = tmp_path / "flight_sqlite"
    argv = ["--out", str(bag), "--frames", "1", "--width", "320", "--height", "240"]
    assert cli(["simulate", *argv, "--storage", "sqlite3", "--seed", "4"]) == 0
    assert (bag / "flight_sqlite_0.db3").exists()
    out = tmp_path / "replayed_sqlite"
    status = cli(
        [
            "replay",
            str(bag),
            "--out",
            str(out),
            "--params-file",
            str(PARAMS_FILE),
            "--storage",
            "sqlite3",
            "--workers",
            "2",
        ]
    )
    text = capsys.readouterr().out
    assert status == 0, text
    assert "2 worker processes" in text
    assert "markers/frame" in text and "ms/frame" in text
    assert "recall" in text and "p95 px" in text
    all_row = next(line for line in text.splitlines() if line.startswith("all ") and "." in line)
    assert all_row.split()[1] == "5"  # frames
    with BagReader(out) as replayed_bag:
        assert replayed_bag.message_counts["/cam0/marker_points"] == 1


def test_replay_with_worker_threads_runs_them_on_one_blas_thread(flight_bag, tmp_path, capsys):
    """The detector then runs in the command's process: BLAS's threads would spin beside it."""
    threaded = two_threaded_openblas()
    argv = ["replay", str(flight_bag), "--out", str(tmp_path / "out"), "--worker-threads"]
    status = cli([*argv, "--workers", "1"])
    text = capsys.readouterr().out
    assert status == 0, text
    assert "1 worker threads" in text
    assert [openblas_threads()[library] for library in threaded] == [1] * len(threaded)


@pytest.mark.parametrize("distance", [-1.0, 0.0, float("nan")])
def test_replay_refuses_a_match_distance_that_is_not_a_positive_distance(
    flight_bag, tmp_path, distance
):
    """Before, every detection and truth point went unmatched without a word."""
    with pytest.raises(ConfigError, match=f"match_distance_px={distance!r}"):
        replay_bag(flight_bag, tmp_path / "out", match_distance_px=distance)
    assert not (tmp_path / "out").exists()


def test_the_report_names_the_match_distance_the_replay_used(flight_bag, tmp_path):
    report = replay_bag(flight_bag, tmp_path / "out", match_distance_px=5.0, workers=1)
    assert "one-to-one matches within 5 px" in format_report(report)


def test_simulate_refuses_an_existing_output_and_a_bad_configuration(tmp_path, capsys):
    taken = tmp_path / "taken"
    taken.mkdir()
    assert (
        cli(["simulate", "--out", str(taken), "--frames", "1", "--width", "64", "--height", "48"])
        == 1
    )
    assert cli(["simulate", "--out", str(tmp_path / "new"), "--width", "30"]) == 1
    err = capsys.readouterr().err.splitlines()
    assert "taken: output path exists" in err[0]
    assert "must hold a marker's plate at nadir" in err[1]
    assert leftovers(tmp_path) == ["taken"]


def test_simulate_warns_where_its_markers_are_smaller_than_the_detector_looks_for(tmp_path, capsys):
    argv = ["--frames", "1", "--width", "64", "--height", "48", "--cameras", "1"]
    assert cli(["simulate", "--out", str(tmp_path / "low"), *argv]) == 0
    assert "warning" not in capsys.readouterr().err
    assert cli(["simulate", "--out", str(tmp_path / "high"), *argv, "--altitude", "100"]) == 0
    assert capsys.readouterr().err == (
        "marker-localizer: warning: markers are 0.28 px in radius at nadir, under the "
        "detector's smallest radius by default (4 px): replay finds them only with a "
        "smaller marker_radius_min_px\n"
    )


def test_an_output_under_a_file_is_refused_naming_the_file(tmp_path, capsys):
    """Before: ``cannot create bag ([Errno 17] File exists: '.../notes.txt')``."""
    (tmp_path / "notes.txt").write_text("")
    out = tmp_path / "notes.txt" / "flight"
    assert (
        cli(["simulate", "--out", str(out), "--frames", "1", "--width", "64", "--height", "48"])
        == 1
    )
    assert capsys.readouterr().err == (
        f"marker-localizer simulate: error: {out}: cannot create bag "
        f"({tmp_path / 'notes.txt'} is a file, not a folder)\n"
    )


@pytest.mark.parametrize(
    ("option", "message"),
    [
        (["--cameras", "0"], "--cameras 0 must be in [1, 5]"),
        (["--fps", "0"], "--fps 0.0 must be positive and finite"),
        (["--tilt", "90"], "--tilt 90.0 must be in [0, 45]"),
    ],
)
def test_a_bad_flight_is_refused_naming_the_option_not_the_configs_field(
    tmp_path, option, message, capsys
):
    """Before, ``n_cameras=0``, ``frame_rate_hz=0.0``: names the command line does not take."""
    assert cli(["simulate", "--out", str(tmp_path / "flight"), *option]) == 1
    assert capsys.readouterr().err == f"marker-localizer simulate: error: {message}\n"


@pytest.mark.parametrize("name", ["flight.mcap", "flight.db3", "flight.bag", "flight.MCAP"])
def test_an_output_named_as_a_bag_file_is_refused_in_one_line_that_names_the_directory_to_give(
    flight_bag, tmp_path, name, capsys
):
    """A rosbag2 is a directory: ``--out flight.mcap`` made ``flight.mcap/flight.mcap.mcap``."""
    out = tmp_path / name
    assert (
        cli(["simulate", "--out", str(out), "--frames", "1", "--width", "64", "--height", "48"])
        == 1
    )
    assert cli(["replay", str(flight_bag), "--out", str(out)]) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2
    for line in err:
        assert f"{name}: names a bag directory" in line
        assert f"e.g. {tmp_path / 'flight'}" in line
    assert leftovers(tmp_path) == []


# --------------------------------------------------------------------------- bad input


def test_missing_bag_raises_bag_error_naming_it_and_main_exits_1(tmp_path, capsys):
    missing = tmp_path / "nothing_here"
    with pytest.raises(BagError, match=re.escape(f"{missing}: no such bag")):
        replay_bag(missing, tmp_path / "out")
    assert cli(["replay", str(missing), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no such bag" in err
    assert leftovers(tmp_path) == []


def test_corrupt_metadata_and_foreign_paths_raise_bag_error(tmp_path):
    garbled = tmp_path / "garbled"
    garbled.mkdir()
    (garbled / "metadata.yaml").write_text("rosbag2_bagfile_information: [oops\n")
    with pytest.raises(BagError, match="garbled: cannot open bag"):
        replay_bag(garbled, tmp_path / "out1")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(BagError, match=r"no metadata\.yaml"):
        replay_bag(empty, tmp_path / "out2")
    text = tmp_path / "notes.txt"
    text.write_text("not a bag")
    with pytest.raises(BagError, match=r"notes\.txt: not a rosbag2"):
        replay_bag(text, tmp_path / "out3")


def test_bag_without_image_topics_raises_bag_error_listing_its_topics(tmp_path):
    bag = tmp_path / "no_images"
    with BagWriter(bag) as writer:
        writer.add_topic("/cam0/marker_points", "sensor_msgs/msg/PointCloud2")
    with pytest.raises(BagError, match=r"no image topics .*/cam0/marker_points"):
        replay_bag(bag, tmp_path / "out")
    assert cli(["replay", str(bag), "--out", str(tmp_path / "out")]) == 1


def test_existing_output_is_refused_and_left_untouched(flight_bag, tmp_path, capsys):
    out = tmp_path / "taken"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    with pytest.raises(BagError, match="taken: output path exists"):
        replay_bag(flight_bag, out)
    assert cli(["replay", str(flight_bag), "--out", str(out)]) == 1
    assert "output path exists" in capsys.readouterr().err
    assert leftovers(out) == ["keep.txt"]
    assert leftovers(tmp_path) == ["taken"]


def test_unknown_encodings_are_counted_and_skipped(tmp_path):
    pixels = x_marker_frame()
    yuv = array_to_image(np.zeros((64, 80, 3), np.uint8), "rgb8")
    yuv.encoding = "yuv444"
    yuv.header.stamp = stamp(2)
    bag = write_bag(
        tmp_path / "mixed", [("/cam0/image_raw", 1, image(pixels, 1)), ("/cam0/image_raw", 2, yuv)]
    )
    report = replay_bag(bag, tmp_path / "out", workers=1)
    cam = report.cameras["cam0"]
    assert (cam.frames, cam.skipped_encoding, cam.failed) == (1, 1, 0)
    assert cam.markers == 1
    assert "cam0: last failure: ImageError: unsupported encoding 'yuv444'" in format_report(report)


def test_the_replayed_diagnostics_count_skipped_frames_as_the_node_would(tmp_path):
    """The node would fail an unsupported encoding and receive a repeated stamp."""
    pixels = x_marker_frame()
    yuv = image(pixels, 2)
    yuv.encoding = "yuv444"
    frames = [("/cam0/image_raw", 1, image(pixels, 1)), ("/cam0/image_raw", 2, yuv)]
    frames += [("/cam0/image_raw", 3, image(pixels, 1)), ("/cam0/image_raw", 4, image(pixels, 4))]
    report = replay_bag(write_bag(tmp_path / "in", frames), tmp_path / "out", workers=1)
    with BagReader(tmp_path / "out") as out:
        (*_, last) = (m.decode() for m in out.messages(["/diagnostics"]))
    (camera,) = (status for status in last.status if status.name.endswith("cam0"))
    values = {v.key: v.value for v in camera.values}
    assert (values["frames received"], values["frames processed"], values["errors"]) == (
        "4",
        "2",
        "1",
    )
    assert "unsupported encoding 'yuv444'" in values["last error"]
    assert camera.level == DiagnosticStatus.ERROR
    # Submission to result, not the bag time between two frames (1 s here).
    assert float(values["latency p95 (ms)"]) < 1000.0
    summary = format_report(report).splitlines()
    assert any(
        line.startswith("cam0: last failure: ImageError: unsupported encoding 'yuv444'")
        for line in summary
    )


def test_image_topics_replay_does_not_read_are_named_with_why(tmp_path):
    pixels = x_marker_frame()
    frames = [
        (topic, 1, image(pixels, 1))
        for topic in ("/cam0/image_raw", "/image_raw", "/cam0/image_color", "/cam-1/image_raw")
    ]
    report = replay_bag(write_bag(tmp_path / "in", frames), tmp_path / "out", workers=1)
    assert list(report.cameras) == ["cam0"]
    assert report.unread_topics == {
        "/cam-1/image_raw": "camera 'cam-1': topic name must not contain characters other "
        "than alphanumerics, '_', or '/'",
        "/cam0/image_color": "not /<cam>/image_raw",
        "/image_raw": "no camera's namespace: a camera's images are /<cam>/image_raw",
    }
    assert "not read: /image_raw (no camera's namespace" in format_report(report)
    with pytest.raises(BagError, match=r"/image_raw: no camera's namespace"):
        replay_bag(write_bag(tmp_path / "alone", frames[1:2]), tmp_path / "out2")


def test_a_cameras_image_topic_holding_another_type_is_named_not_read(tmp_path):
    from std_msgs.msg import String  # noqa: PLC0415 - only this test writes one

    with BagWriter(tmp_path / "in", "mcap") as bag:
        bag.add_topic("/cam0/image_raw", "std_msgs/msg/String")
        bag.write("/cam0/image_raw", 1, String(data="not a frame"))
        bag.add_topic("/cam1/image_raw", "sensor_msgs/msg/Image")
        bag.write("/cam1/image_raw", 1, image(x_marker_frame(), 1))
    report = replay_bag(tmp_path / "in", tmp_path / "out", workers=1)
    assert list(report.cameras) == ["cam1"]
    assert report.unread_topics == {
        "/cam0/image_raw": "holds std_msgs/msg/String, not sensor_msgs/msg/Image"
    }


def test_worker_processes_and_worker_threads_write_the_same_points(tmp_path):
    frames = [("/cam0/image_raw", t, image(x_marker_frame(), t)) for t in (1, 2, 3)]
    bag = write_bag(tmp_path / "in", frames)
    points = {}
    for processes in (True, False):
        out = tmp_path / f"out_{processes}"
        report = replay_bag(bag, out, workers=2, worker_processes=processes)
        assert report.worker_processes is processes
        with BagReader(out) as written:
            clouds = [m.decode() for m in written.messages(["/cam0/marker_points"])]
        points[processes] = np.concatenate([cloud_to_array(c)[["x", "y"]].tolist() for c in clouds])
    assert points[True].shape == (3, 2)
    np.testing.assert_allclose(points[True], [(40.3, 30.6)] * 3, atol=0.05)
    np.testing.assert_allclose(points[True], points[False], atol=1e-9)


def test_bag_with_nothing_processable_fails_and_leaves_no_output(tmp_path):
    yuv = array_to_image(np.zeros((8, 8, 3), np.uint8), "rgb8")
    yuv.encoding = "yuv444"
    bag = write_bag(tmp_path / "yuv", [("/cam0/image_raw", 1, yuv)])
    with pytest.raises(BagError, match=r"no frame could be processed \(1 with an unsupported"):
        replay_bag(bag, tmp_path / "out")
    assert leftovers(tmp_path) == ["yuv"]


def test_a_bag_whose_image_topics_hold_no_message_is_one_line_saying_so(tmp_path, capsys):
    """Declared image topics, only camera_info written: it said 0 frames with an unsupported
    encoding, 0 out of order, 0 failed, 0 undecodable, and listed the encodings."""
    bag = tmp_path / "info"
    with BagWriter(bag, "sqlite3") as writer:
        writer.add_topic("/cam0/image_raw", "sensor_msgs/msg/Image")
        writer.add_topic("/cam0/camera_info", "sensor_msgs/msg/CameraInfo")
        for sec in (1, 2, 3):
            writer.write("/cam0/camera_info", sec * S, CameraInfo())
    assert cli(["replay", str(bag), "--out", str(tmp_path / "out"), "--workers", "1"]) == 1
    err = capsys.readouterr().err
    assert err == (
        f"marker-localizer replay: error: {bag}: no frame to process: no message on "
        "/cam0/image_raw (the bag holds: /cam0/camera_info 3)\n"
    )
    assert leftovers(tmp_path) == ["info"]
    empty = tmp_path / "empty"
    with BagWriter(empty) as writer:
        writer.add_topic("/cam0/image_raw/compressed", "sensor_msgs/msg/CompressedImage")
    no_message = r"no message on /cam0/image_raw/compressed \(the bag holds no message\)"
    with pytest.raises(BagError, match=no_message):
        replay_bag(empty, tmp_path / "out", workers=1)


def test_when_no_frame_can_be_processed_the_image_topics_not_read_are_named(tmp_path):
    """A driver's 8UC1 frames beside their JPEG copies: the error points at the copies."""
    raw = array_to_image(x_marker_frame(), "mono8", Header(stamp=stamp(1)))
    raw.encoding = "8UC1"
    ok, jpeg = cv2.imencode(".jpg", x_marker_frame())
    assert ok
    copy = CompressedImage(
        header=raw.header, format="8UC1; jpeg compressed mono8", data=jpeg.tobytes()
    )
    bag = tmp_path / "bag"
    with BagWriter(bag) as writer:
        writer.add_topic("/cam0/image_raw", "sensor_msgs/msg/Image")
        writer.add_topic("/cam0/image_raw/compressed", "sensor_msgs/msg/CompressedImage")
        writer.write("/cam0/image_raw", 10**9, raw)
        writer.write("/cam0/image_raw/compressed", 10**9, copy)
    with pytest.raises(
        BagError,
        match=r"no frame could be processed .*; not read: /cam0/image_raw/compressed "
        r"\(camera cam0 is read from /cam0/image_raw\)$",
    ):
        replay_bag(bag, tmp_path / "out", workers=1)
    assert leftovers(tmp_path) == ["bag"]


def test_frames_out_of_stamp_order_are_counted_and_skipped(tmp_path):
    pixels = x_marker_frame()
    frames = [
        ("/cam0/image_raw", t, image(pixels, s)) for t, s in [(1, 20), (2, 10), (3, 30), (4, 30)]
    ]
    report = replay_bag(write_bag(tmp_path / "order", frames), tmp_path / "out", workers=1)
    cam = report.cameras["cam0"]
    assert (cam.frames, cam.skipped_out_of_order) == (2, 2)  # 10 is older, 30 is a repeat
    assert "cam0: 2 frames stamped no later than the one before" in format_report(report)
    with BagReader(tmp_path / "out") as out:
        times = [m.time_ns for m in out.messages(["/cam0/marker_points"])]
    assert times == [1, 3]


def test_frame_with_a_bad_layout_is_counted_as_failed(tmp_path):
    good = image(x_marker_frame(), 1)
    bad = image(x_marker_frame(), 2)
    bad.step = 10  # shorter than a row
    report = replay_bag(
        write_bag(tmp_path / "bad", [("/cam0/image_raw", 1, good), ("/cam0/image_raw", 2, bad)]),
        tmp_path / "out",
        workers=1,
    )
    cam = report.cameras["cam0"]
    assert (cam.frames, cam.failed) == (1, 1)
    assert "step 10" in cam.last_error


def test_interrupted_replay_leaves_no_output_bag(flight_bag, tmp_path):
    def interrupt(done, total):
        if done == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        replay_bag(flight_bag, tmp_path / "out", progress=interrupt)
    assert leftovers(tmp_path) == []


def test_writer_in_a_missing_parent_creates_it_and_renames_only_on_success(tmp_path):
    target = tmp_path / "deep" / "bag"
    with pytest.raises(RuntimeError), BagWriter(target) as bag:
        bag.add_topic("/x/image_raw", "sensor_msgs/msg/Image")
        assert [p.name.startswith(".bag.partial-") for p in target.parent.iterdir()] == [True]
        raise RuntimeError("boom")
    assert leftovers(target.parent) == []
    with BagWriter(target, "sqlite3") as bag:
        bag.add_topic("/x/image_raw", "sensor_msgs/msg/Image")
        bag.write("/x/image_raw", 5, image(np.zeros((4, 4), np.uint8), 5))
    assert leftovers(target.parent) == ["bag"]
    assert sorted(os.listdir(target)) == ["bag_0.db3", "metadata.yaml"]
    with BagReader(target) as bag:
        assert [m.time_ns for m in bag.messages()] == [5]


def test_a_12_bit_camera_read_at_16_bits_is_named_in_the_report_with_its_depth(tmp_path):
    shallow = (x_marker_frame().astype(np.uint16) * 16).astype(np.uint16)  # 12-bit levels
    frames = [("/cam0/image_raw", n, image(shallow, n, "mono16")) for n in (1, 2)]
    report = replay_bag(write_bag(tmp_path / "deep", frames), tmp_path / "out", workers=1)
    assert report.cameras["cam0"].bit_depth_hint == 12
    assert (
        "cam0: 16-bit frames under 1/16 of white: a 12-bit camera wants detector.bit_depth 12"
        in (format_report(report).splitlines())
    )
    # As the node's diagnostics would: the output bag's say the same.
    with BagReader(tmp_path / "out") as out:
        (*_, last) = (m.decode() for m in out.messages(["/diagnostics"]))
    (camera,) = (status for status in last.status if status.name.endswith("cam0"))
    assert camera.level == DiagnosticStatus.WARN
    assert "a 12-bit camera wants detector.bit_depth 12" in camera.message
    full = [("/cam0/image_raw", n, image(shallow * 16, n, "mono16")) for n in (1, 2)]
    report = replay_bag(write_bag(tmp_path / "full", full), tmp_path / "out2", workers=1)
    assert report.cameras["cam0"].bit_depth_hint is None


def test_an_underexposed_camera_is_named_in_the_report_as_its_diagnostics_name_it(tmp_path):
    dim = x_marker_frame() // 3  # its white paint at 30 % of white
    frames = [("/cam0/image_raw", n, image(dim, n)) for n in (1, 2)]
    report = replay_bag(write_bag(tmp_path / "dim", frames), tmp_path / "out", workers=1)
    (line,) = (line for line in format_report(report).splitlines() if line.startswith("cam0: "))
    assert line.startswith("cam0: frames underexposed: the brightest level is 30 % of white")
    with BagReader(tmp_path / "out") as out:
        (*_, last) = (m.decode() for m in out.messages(["/diagnostics"]))
    (camera,) = (status for status in last.status if status.name.endswith("cam0"))
    assert camera.level == DiagnosticStatus.WARN
    assert camera.message == line.removeprefix("cam0: ")


@pytest.mark.parametrize(("tracking", "full_frame_passes"), [(True, 1), (False, 3)])
def test_the_summary_counts_each_cameras_full_frame_passes(tmp_path, tracking, full_frame_passes):
    """With tracking the steady flight's first frame is a full pass; without, every frame."""
    frames = [
        ("/cam0/image_raw", (k + 1) * S, image(pixels, (k + 1) * S))
        for k, pixels in enumerate(panning_frames(3))
    ]
    report = replay_bag(
        write_bag(tmp_path / "panning", frames),
        tmp_path / "out",
        config=DetectorConfig(marker_radius_min_px=6.0, marker_radius_max_px=20.0),
        tracker_config=TrackerConfig(enabled=tracking),
        workers=1,
        worker_processes=False,
    )
    assert report.cameras["cam0"].full_frame_passes == full_frame_passes
    header, row = (
        line for line in format_report(report).splitlines() if line.startswith(("camera", "cam0"))
    )
    assert header.split()[:4] == ["camera", "frames", "full-frame", "passes"]
    assert row.split()[:3] == ["cam0", "3", str(full_frame_passes)]


def test_a_flight_of_bayer_cameras_is_recorded_raw_and_replayed_as_grey(tmp_path):
    bag = tmp_path / "bayer_flight"
    argv = ["--out", str(bag), "--frames", "2", "--width", "320", "--height", "240"]
    assert cli(["simulate", *argv, "--seed", "0", "--bayer", "grbg"]) == 0
    with BagReader(bag) as recorded:
        image = next(recorded.messages({"/cam0/image_raw"})).decode()
    assert image.encoding == "bayer_grbg8"
    overall = replay_bag(bag, tmp_path / "out", workers=2).evaluation
    assert overall.n_truth > 0 and overall.recall >= MIN_RECALL
    assert overall.stats.mean <= MAX_MEAN_ERROR_PX


def test_replay_takes_detector_overrides_over_the_params_file_as_detect_does(
    flight_bag, tmp_path, capsys
):
    out = tmp_path / "overridden"
    argv = ["replay", str(flight_bag), "--out", str(out), "--params-file", str(PARAMS_FILE)]
    assert cli([*argv, "--param", "marker_radius_min_px=4", "--param", "min_score=0.85"]) == 0
    assert "recall" in capsys.readouterr().out
    assert cli([*argv[:3], str(tmp_path / "refused"), "--param", "min_score=2"]) == 1
    assert "min_score=2.0 is outside [0, 1]" in capsys.readouterr().err
    assert not (tmp_path / "refused").exists()


# --------------------------------------------------------------------------- long bags


def long_bag(path, frames, *, truth_every=0, bad_every=0, cameras=("cam0", "cam1")):
    """``frames`` frames a camera at 10 Hz of :func:`x_marker_frame`.

    With ``truth_every``, every so many frames carries its truth (the marker's
    centre) and every frame an empty partial list, at its bag time; with
    ``bad_every``, every so many frames has an encoding replay skips.
    """
    pixels = x_marker_frame()
    with BagWriter(path) as bag:
        for camera in cameras:
            bag.add_topic(f"/{camera}/image_raw", "sensor_msgs/msg/Image")
            if truth_every:
                bag.add_topic(f"/{camera}/{TRUTH_SUFFIX}", "sensor_msgs/msg/PointCloud2")
                bag.add_topic(f"/{camera}/{PARTIAL_SUFFIX}", "sensor_msgs/msg/PointCloud2")
        for k in range(frames):
            t = (k + 1) * S // 10
            for camera in cameras:
                frame = image(pixels, t)
                if bad_every and k % bad_every == bad_every - 1:
                    frame.encoding = "yuv444"
                bag.write(f"/{camera}/image_raw", t, frame)
                if truth_every:
                    header = Header(stamp=stamp(t))
                    if k % truth_every == 0:
                        cloud = detections_to_cloud(header, X_MARKER_TRUTH)
                        bag.write(f"/{camera}/{TRUTH_SUFFIX}", t, cloud)
                    bag.write(f"/{camera}/{PARTIAL_SUFFIX}", t, detections_to_cloud(header, []))
    return path


def test_a_long_replays_summary_keeps_sums_not_a_value_per_frame(tmp_path):
    """Before: each camera's processing times, one a frame (10 and 100 here)."""

    def held(report):
        return {
            name: len(value)
            for camera in report.cameras.values()
            for name, value in vars(camera).items()
            if isinstance(value, list | dict | tuple)
        }

    short = replay_bag(long_bag(tmp_path / "short", 10), tmp_path / "short_out", workers=2)
    long = replay_bag(long_bag(tmp_path / "long", 100), tmp_path / "long_out", workers=2)
    assert [c.frames for c in long.cameras.values()] == [100, 100]
    assert held(long) == held(short)
    # Each figure of ms/frame is its sum of times over its frames, the sums all there is.
    lines = format_report(long).splitlines()
    for camera in long.cameras.values():
        assert camera.processing_ms_total > 0
        assert camera.mean_ms == camera.processing_ms_total / 100
        (row,) = [line for line in lines if line.split()[0] == camera.camera]
        assert f"{camera.processing_ms_total / 100:>10.1f}" in row
    total = long.cameras["cam0"].processing_ms_total + long.cameras["cam1"].processing_ms_total
    assert f"{total / 200:>10.1f}" in lines[-1]


@pytest.mark.parametrize(
    ("truth_every", "bad_every"),
    [(1, 0), (5, 0), (1, 4)],
    ids=["truth on every frame", "truth on every fifth frame", "every fourth frame skipped"],
)
def test_replay_matches_each_frame_to_its_truth_as_it_comes_and_holds_only_those_waiting(
    tmp_path, monkeypatch, truth_every, bad_every
):
    """Before: every frame's detections, truth and partial list held to the end (the
    2 x 100 frames of the long bag: 200 of each)."""
    peaks = []

    class Counted(TruthMatcher):
        def add(self, *args):
            super().add(*args)
            peaks[-1] = max(peaks[-1], self.waiting)

    monkeypatch.setattr(replay, "TruthMatcher", Counted)
    reports = {}
    for frames in (10, 100):
        peaks.append(0)
        bag = long_bag(
            tmp_path / f"in{frames}", frames, truth_every=truth_every, bad_every=bad_every
        )
        reports[frames] = replay_bag(bag, tmp_path / f"out{frames}", workers=2)
    # However long the bag: a frame or two a camera, or those between two with truth.
    assert peaks[1] <= peaks[0] + 2
    assert peaks[1] <= 2 * (truth_every + 2)
    for frames, report in reports.items():
        kept = [k for k in range(frames) if not (bad_every and k % bad_every == bad_every - 1)]
        with_truth = [k for k in kept if k % truth_every == 0]
        for camera in report.cameras.values():
            assert camera.frames == len(kept)
            assert camera.evaluation.frames == len(with_truth)
            assert camera.evaluation.recall == 1.0
            assert camera.evaluation.n_false_positives == 0
            # Nothing left out uncounted: a frame without truth, truth without a frame.
            assert camera.without_truth == len(kept) - len(with_truth)
            truth_frames = [k for k in range(frames) if k % truth_every == 0]
            assert camera.truth_without_result == len(truth_frames) - len(with_truth)


def test_truth_out_of_stamp_order_is_counted_where_it_is_not_evaluated(tmp_path):
    """Truth is taken to come in stamp order: a recording whose truth stamps come in
    pairs swapped (1, 0, 3, 2, ...) cannot be matched frame by frame as it comes, and
    every frame and every truth message is then either evaluated or counted, and named.
    Before: those left out were forgotten without a word."""
    frames = 12
    pixels = x_marker_frame()
    path = tmp_path / "swapped"
    with BagWriter(path) as bag:
        bag.add_topic("/cam0/image_raw", "sensor_msgs/msg/Image")
        bag.add_topic(f"/cam0/{TRUTH_SUFFIX}", "sensor_msgs/msg/PointCloud2")
        for k in range(frames):
            t = (k + 1) * S // 10
            bag.write("/cam0/image_raw", t, image(pixels, t))
            swapped = (k ^ 1) + 1  # the stamp of the other frame of its pair
            cloud = detections_to_cloud(Header(stamp=stamp(swapped * S // 10)), X_MARKER_TRUTH)
            bag.write(f"/cam0/{TRUTH_SUFFIX}", t, cloud)
    report = replay_bag(path, tmp_path / "out", workers=2)
    camera = report.cameras["cam0"]
    evaluated = camera.evaluation.frames
    assert camera.frames == frames
    assert camera.without_truth >= frames // 2
    assert evaluated + camera.without_truth == frames
    assert evaluated + camera.truth_without_result == frames
    text = format_report(report)
    assert f"cam0: {camera.without_truth} frames not evaluated" in text
    assert f"cam0: {camera.truth_without_result} {TRUTH_SUFFIX} messages not evaluated" in text


def test_a_frame_recorded_twice_is_skipped_once_and_evaluated_against_its_truth(tmp_path):
    """The copy, skipped as no later than the frame before, said that stamp had no result
    while the frame was still in a worker: its truth was forgotten as without a result, and
    then its result as without truth (each image here twice: 12 frames, none evaluated)."""
    frames = 12
    pixels = x_marker_frame()
    path = tmp_path / "recorded_twice"
    with BagWriter(path) as bag:
        bag.add_topic("/cam0/image_raw", "sensor_msgs/msg/Image")
        bag.add_topic(f"/cam0/{TRUTH_SUFFIX}", "sensor_msgs/msg/PointCloud2")
        for k in range(frames):
            t = (k + 1) * S // 10
            bag.write("/cam0/image_raw", t, image(pixels, t))
            bag.write("/cam0/image_raw", t + S // 1000, image(pixels, t))
            cloud = detections_to_cloud(Header(stamp=stamp(t)), X_MARKER_TRUTH)
            bag.write(f"/cam0/{TRUTH_SUFFIX}", t + S // 1000, cloud)
    camera = replay_bag(path, tmp_path / "out", workers=2).cameras["cam0"]
    assert (camera.frames, camera.skipped_out_of_order) == (frames, frames)
    assert camera.evaluation.frames == frames and camera.evaluation.recall == 1.0
    assert (camera.without_truth, camera.truth_without_result) == (0, 0)


def test_a_camera_whose_every_frame_is_skipped_holds_none_of_its_truth(tmp_path, monkeypatch):
    """Its truth is counted as not evaluated as it comes, not held for detections that
    never come. Before: every frame's truth of such a camera was held to the end (all 40
    here; an hour of a camera at 10 Hz, 36 000)."""
    frames = 40
    pixels = x_marker_frame()
    path = tmp_path / "one_camera_skipped"
    with BagWriter(path) as bag:
        for camera in ("cam0", "cam1"):
            bag.add_topic(f"/{camera}/image_raw", "sensor_msgs/msg/Image")
            bag.add_topic(f"/{camera}/{TRUTH_SUFFIX}", "sensor_msgs/msg/PointCloud2")
        for k in range(frames):
            t = (k + 1) * S // 10
            for camera in ("cam0", "cam1"):
                frame = image(pixels, t)
                if camera == "cam1":
                    frame.encoding = "yuv444"
                bag.write(f"/{camera}/image_raw", t, frame)
                cloud = detections_to_cloud(Header(stamp=stamp(t)), X_MARKER_TRUTH)
                bag.write(f"/{camera}/{TRUTH_SUFFIX}", t, cloud)
    peak = [0]

    class Counted(TruthMatcher):
        def add(self, *args):
            super().add(*args)
            peak[0] = max(peak[0], self.waiting)

    monkeypatch.setattr(replay, "TruthMatcher", Counted)
    report = replay_bag(path, tmp_path / "out", workers=2)
    skipped, kept = report.cameras["cam1"], report.cameras["cam0"]
    assert skipped.skipped_encoding == frames
    assert skipped.truth_without_result == frames
    assert kept.evaluation.frames == frames
    assert kept.evaluation.recall == 1.0
    assert peak[0] <= 4
