"""The node with real rclpy and real DDS: rendered frames in, sub-pixel points and diagnostics out.

Nodes under test run in this process (each spun by its own executor thread) and,
once, as a separate process started like a user would. A tester node publishes
rendered frames with exact ground truth and listens to every output. Waits are
polls with generous deadlines, never fixed sleeps.
"""

import array
import os
import signal
import subprocess
import sys
import threading
import time
from collections import defaultdict
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
import pytest
import rclpy
import waiting
import yaml
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import (
    DescribeParameters,
    GetParameters,
    SetParameters,
    SetParametersAtomically,
)
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CompressedImage, Image, PointCloud2
from std_msgs.msg import Header

from marker_localizer.bench import throughput
from marker_localizer.cli import main as cli_main
from marker_localizer.config import DetectorConfig
from marker_localizer.errors import ConfigError, ImageError
from marker_localizer.ros.conversions import array_to_image, cloud_to_array
from marker_localizer.ros.diagnostics import ERROR, OK, WARN
from marker_localizer.ros.node import MarkerLocalizerNode
from marker_localizer.ros.parameters import params_yaml
from marker_localizer.ros.processing import FrameProcessor
from marker_localizer.synthetic import SceneConfig, render_scene

REPO = Path(__file__).resolve().parents[2]
PARAMS_FILE = REPO / "config" / "marker_localizer.yaml"
CAMERAS = ("cam0", "cam1", "cam2", "cam3", "cam4")
TIMEOUT_S = 30.0
#: Sub-pixel accuracy the node must deliver on rendered frames, px.
TOLERANCE_PX = 0.1
IMAGE_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)


# --------------------------------------------------------------------------- helpers



def wait_until(predicate, what, timeout_s=TIMEOUT_S):
    """Poll ``predicate`` for up to this module's timeout."""
    return waiting.wait_until(predicate, what, timeout_s)


def scene(width, height, n_markers, seed):
    """A rendered frame on flat ground with exact marker centres."""
    config = SceneConfig(
        width=width,
        height=height,
        n_markers=n_markers,
        radius_px=(12.0, 30.0),
        max_tilt_deg=30.0,
        noise_sigma_dn=(0.0, 2.0),
        background="flat",
        n_hard_negatives=0,
        supersampling=4,
    )
    return render_scene(config, seed)


def x_marker_64():
    """The analytic X of the Detector docstring: exact centre (31.5, 31.5)."""
    image = np.full((64, 64), 200, np.uint8)
    image[:32, :32] = image[32:, 32:] = 30
    return cv2.GaussianBlur(image, (0, 0), 1.0)


def points_xy(cloud):
    points = cloud_to_array(cloud)
    return np.column_stack([points["x"], points["y"]])


def assert_matches_truth(found_xy, truth_xy):
    """Every marker found within TOLERANCE_PX of its truth, and nothing else found."""
    assert len(found_xy) == len(truth_xy), f"found {found_xy}, truth {truth_xy}"
    distance = np.linalg.norm(found_xy[:, None, :] - truth_xy[None, :, :], axis=2)
    assert distance.min(axis=0).max() < TOLERANCE_PX
    assert distance.min(axis=1).max() < TOLERANCE_PX


def level_of(status):
    return status.level[0]


def values_of(status):
    return {kv.key: kv.value for kv in status.values}


class Spinner:
    """Spin one node with its own executor in a background thread."""

    def __init__(self, node):
        self.node = node
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def stop(self):
        self.executor.shutdown()
        self.thread.join(TIMEOUT_S)
        self.node.destroy_node()


class Peer:
    """The other side of the node: publishes frames, collects outputs, calls services."""

    def __init__(self, name, namespace):
        self.node = rclpy.create_node(name, namespace=namespace)
        self.lock = threading.Lock()
        self.received = defaultdict(list)  # topic -> messages
        self.publishers = {}
        self.subscriptions = {}
        self.spinner = Spinner(self.node)

    def listen(self, topic, msg_type):
        """Subscribe to ``topic`` (once) and wait until a publisher is matched."""
        if topic not in self.subscriptions:
            def collect(msg, topic=topic):
                with self.lock:
                    self.received[topic].append(msg)

            self.subscriptions[topic] = self.node.create_subscription(
                msg_type, topic, collect, 50
            )
        sub = self.subscriptions[topic]
        wait_until(lambda: sub.get_publisher_count() > 0, f"a publisher on {topic}")

    def messages(self, topic):
        with self.lock:
            return list(self.received[topic])

    def frame(self, pixels, encoding="mono8", frame_id="camera", stamp=None):
        header = Header(stamp=stamp or self.node.get_clock().now().to_msg(), frame_id=frame_id)
        return array_to_image(pixels, encoding, header)

    def publish(self, topic, msg):
        if topic not in self.publishers:
            self.publishers[topic] = self.node.create_publisher(Image, topic, IMAGE_QOS)
        pub = self.publishers[topic]
        wait_until(lambda: pub.get_subscription_count() > 0, f"the node subscribing {topic}")
        pub.publish(msg)

    def result_for(self, topic, header, timeout_s=TIMEOUT_S):
        """The output on ``topic`` whose stamp is the stamp of ``header``."""
        return wait_until(
            lambda: next((m for m in self.messages(topic) if m.header.stamp == header.stamp), None),
            f"{topic} for stamp {header.stamp.sec}.{header.stamp.nanosec:09d}",
            timeout_s,
        )

    def call(self, srv_type, name, request):
        client = self.node.create_client(srv_type, name)
        try:
            wait_until(lambda: client.wait_for_service(timeout_sec=0.1), f"service {name}")
            future = client.call_async(request)
            wait_until(future.done, f"the answer of {name}")
            return future.result()
        finally:
            self.node.destroy_client(client)

    def set_parameters(self, node_fqn, parameters, atomically=False):
        msgs = [Parameter(name, value=value).to_parameter_msg() for name, value in parameters]
        if atomically:
            request = SetParametersAtomically.Request(parameters=msgs)
            return [self.call(SetParametersAtomically, f"{node_fqn}/set_parameters_atomically",
                              request).result]
        request = SetParameters.Request(parameters=msgs)
        return self.call(SetParameters, f"{node_fqn}/set_parameters", request).results

    def get_parameter(self, node_fqn, name):
        request = GetParameters.Request(names=[name])
        (value,) = self.call(GetParameters, f"{node_fqn}/get_parameters", request).values
        return parameter_value_to_python(value)

    def stop(self):
        self.spinner.stop()


# --------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def ros():
    rclpy.init()
    yield
    rclpy.try_shutdown()


@pytest.fixture(scope="module")
def localizer(ros):
    """The node under test in namespace /inproc, default cameras, fast diagnostics.

    No age limit and a loose latency limit: on a loaded 2-core machine five
    1280x960 frames may wait longer than the defaults allow for a worker (both
    limits have their own tests).
    """
    node = MarkerLocalizerNode(
        namespace="/inproc",
        parameter_overrides=[
            Parameter("max_frame_age_s", value=0.0),
            Parameter("latency_warn_ms", value=60_000.0),
            Parameter("diagnostics_period_s", value=0.2),
            Parameter("input_timeout_s", value=600.0),
        ],
    )
    spinner = Spinner(node)
    yield node
    spinner.stop()


@pytest.fixture(scope="module")
def tester(ros):
    tester = Peer("tester", "/inproc")
    yield tester
    tester.stop()


# --------------------------------------------------------------------------- in-process node


def test_node_publishes_points_at_ground_truth_with_headers_unchanged_on_five_cameras(
    localizer, tester
):
    seeds = (0, 2, 3, 4, 5)
    scenes = {cam: scene(1280, 960, 4, seed) for cam, seed in zip(CAMERAS, seeds, strict=True)}
    for camera in CAMERAS:
        tester.listen(f"{camera}/marker_points", PointCloud2)
    sent = {}
    for camera, rendered in scenes.items():
        sent[camera] = tester.frame(rendered.image, frame_id=f"{camera}_optical")
        tester.publish(f"{camera}/image_raw", sent[camera])
    for camera, rendered in scenes.items():
        cloud = tester.result_for(f"{camera}/marker_points", sent[camera].header)
        assert cloud.header == sent[camera].header  # stamp and frame_id unchanged
        assert_matches_truth(points_xy(cloud), rendered.centres)
        assert cloud.is_dense
        assert cloud.point_step == 48


def test_node_publishes_empty_cloud_when_frame_has_no_marker(localizer, tester):
    tester.listen("cam2/marker_points", PointCloud2)
    blank = np.random.default_rng(7).normal(120.0, 3.0, (240, 320)).clip(0, 255).astype(np.uint8)
    frame = tester.frame(blank, frame_id="cam2_optical")
    tester.publish("cam2/image_raw", frame)
    cloud = tester.result_for("cam2/marker_points", frame.header)
    assert cloud.header == frame.header
    assert (cloud.width, len(cloud.data)) == (0, 0)


@pytest.mark.parametrize("encoding", ["mono16", "bgr8", "rgb8"])
def test_node_reads_colour_and_16_bit_frames(localizer, tester, encoding):
    tester.listen("cam3/marker_points", PointCloud2)
    grey = x_marker_64()
    pixels = {
        "mono16": grey.astype(np.uint16) * 257,  # white at 65535
        "bgr8": np.dstack([grey] * 3),
        "rgb8": np.dstack([grey] * 3),
    }[encoding]
    frame = tester.frame(pixels, encoding)
    tester.publish("cam3/image_raw", frame)
    cloud = tester.result_for("cam3/marker_points", frame.header)
    np.testing.assert_allclose(points_xy(cloud), [[31.5, 31.5]], atol=1e-3)


def test_with_compressed_transport_each_camera_reads_jpeg_and_counts_undecodable_data(ros):
    node = MarkerLocalizerNode(
        "jpeg_localizer",
        namespace="/jpeg",
        parameter_overrides=[
            Parameter("image_transport", value="compressed"),
            Parameter("cameras", value=["cam0"]),
        ],
    )
    spinner = Spinner(node)
    peer = Peer("jpeg_peer", "/jpeg")
    try:
        peer.listen("cam0/marker_points", PointCloud2)
        pub = peer.node.create_publisher(CompressedImage, "cam0/image_raw/compressed", IMAGE_QOS)
        wait_until(lambda: pub.get_subscription_count() > 0, "the node subscribing")
        ok, jpeg = cv2.imencode(".jpg", x_marker_64(), [cv2.IMWRITE_JPEG_QUALITY, 95])
        assert ok

        def publish(data, sec):
            msg = CompressedImage(header=Header(stamp=Time(sec=sec), frame_id="cam0"),
                                  format="mono8; jpeg compressed mono8", data=data)
            pub.publish(msg)
            return msg.header

        publish(b"\xff\xd8 cut short", 1)
        wait_until(lambda: node.processor.snapshots()["cam0"].errors == 1, "the error counted")
        assert "not a readable image" in node.processor.snapshots()["cam0"].last_error
        cloud = peer.result_for("cam0/marker_points", publish(jpeg.tobytes(), 2))
        np.testing.assert_allclose(points_xy(cloud), [[31.5, 31.5]], atol=0.05)
        assert node.get_parameter(
            "qos_overrides./jpeg/cam0/image_raw/compressed.subscription.reliability"
        ).value == "reliable"
    finally:
        peer.stop()
        spinner.stop()


def test_accepted_parameter_change_takes_effect_on_the_next_frame(localizer, tester):
    tester.listen("cam1/marker_points", PointCloud2)
    image = x_marker_64()

    def markers_in_next_frame():
        frame = tester.frame(image)
        tester.publish("cam1/image_raw", frame)
        return tester.result_for("cam1/marker_points", frame.header).width

    assert markers_in_next_frame() == 1
    (result,) = tester.set_parameters(
        "/inproc/marker_localizer", [("detector.min_contrast_dn", 255.0)]
    )
    assert result.successful, result.reason
    assert tester.get_parameter("/inproc/marker_localizer", "detector.min_contrast_dn") == 255.0
    assert markers_in_next_frame() == 0  # no marker has 255 DN between its quadrants
    (result,) = tester.set_parameters(
        "/inproc/marker_localizer",
        [("detector.min_contrast_dn", DetectorConfig().min_contrast_dn)],
        atomically=True,
    )
    assert result.successful, result.reason
    assert markers_in_next_frame() == 1


@pytest.mark.parametrize(
    ("name", "value", "reason"),
    [
        ("detector.marker_radius_min_px", 0.5, "out of range"),
        ("detector.marker_radius_min_px", 50.0,
         "marker_radius_min_px=50.0 is larger than marker_radius_max_px=40.0"),
        ("detector.refinement", "magic", "refinement='magic' must be one of symmetry, ncc"),
        ("detector.marker_radius_max_px", "big", "Wrong parameter type"),
        ("detector.ncc_search_px", 2.5, "Wrong parameter type"),
        ("max_frame_age_s", -1.0, "out of range"),
        ("workers", 4, "read-only"),
        ("cameras", ["cam0"], "read-only"),
    ],
)
def test_invalid_parameter_values_are_rejected_with_a_reason(
    localizer, tester, name, value, reason
):
    before = tester.get_parameter("/inproc/marker_localizer", name)
    (result,) = tester.set_parameters("/inproc/marker_localizer", [(name, value)])
    assert not result.successful
    assert reason in result.reason
    assert tester.get_parameter("/inproc/marker_localizer", name) == before


def test_an_integer_is_taken_for_a_double_as_the_cli_takes_it(localizer, tester):
    name = "detector.marker_radius_max_px"
    (result,) = tester.set_parameters("/inproc/marker_localizer", [(name, 30)])
    try:
        assert result.successful, result.reason
        value = tester.get_parameter("/inproc/marker_localizer", name)
        assert (value, type(value)) == (30.0, float)
        assert localizer.processor.config.marker_radius_max_px == 30.0
    finally:
        tester.set_parameters("/inproc/marker_localizer", [(name, 40.0)])


PARAMS_ANY_NODE = """\
/**:
  ros__parameters:
    max_frame_age: 5.0
    detector:
      marker_radius_min_px: 5
      marker_radius_max_px: 30
"""


def test_a_params_file_keyed_for_any_node_applies_under_a_namespace_and_another_name(
    ros, tmp_path, capfd
):
    path = tmp_path / "params.yaml"
    path.write_text(PARAMS_ANY_NODE)
    node = MarkerLocalizerNode(
        "renamed", namespace="/uav1", cli_args=["--ros-args", "--params-file", str(path)]
    )
    try:
        config = node.processor.config
        assert (config.marker_radius_min_px, config.marker_radius_max_px) == (5.0, 30.0)
        assert node.get_parameter("detector.marker_radius_min_px").value == 5.0
        # A key no parameter has is named, not silently dropped.
        assert "ignoring unknown parameter(s): max_frame_age" in capfd.readouterr().err
    finally:
        node.destroy_node()
    assert cli_main(["detect", str(REPO / "docs" / "detection.jpg"), "--params-file", str(path),
                     "--json"]) == 0


def test_node_and_cli_refuse_an_unknown_detector_key_and_name_it(ros, tmp_path, capsys):
    path = tmp_path / "params.yaml"
    path.write_text(PARAMS_ANY_NODE.replace("marker_radius_max_px", "marker_radius_maximum_px"))
    with pytest.raises(ConfigError, match=r"unknown parameter\(s\): marker_radius_maximum_px"):
        MarkerLocalizerNode("typo", cli_args=["--ros-args", "--params-file", str(path)])
    assert cli_main(["detect", str(REPO / "docs" / "detection.jpg"), "--params-file",
                     str(path)]) == 1
    assert "unknown parameter(s): marker_radius_maximum_px" in capsys.readouterr().err


def test_atomic_request_with_one_invalid_value_applies_nothing(localizer, tester):
    (result,) = tester.set_parameters(
        "/inproc/marker_localizer",
        [("detector.marker_radius_max_px", 60.0), ("detector.marker_radius_min_px", 70.0)],
        atomically=True,
    )
    assert not result.successful
    assert "marker_radius_min_px=70.0 is larger than marker_radius_max_px=60.0" in result.reason
    assert tester.get_parameter("/inproc/marker_localizer", "detector.marker_radius_max_px") == 40.0
    assert localizer.processor.config.marker_radius_max_px == 40.0


def test_non_atomic_request_applies_each_parameter_on_its_own_in_order(localizer, tester):
    """SetParameters validates and applies one parameter after the other (README)."""
    node = "/inproc/marker_localizer"
    try:
        first, second = tester.set_parameters(
            node, [("detector.marker_radius_max_px", 60.0), ("detector.marker_radius_min_px", 70.0)]
        )
        assert first.successful  # valid alone: applied before the second is looked at
        assert not second.successful
        assert "marker_radius_min_px=70.0 is larger than marker_radius_max_px=60.0" in (
            second.reason)
        assert tester.get_parameter(node, "detector.marker_radius_max_px") == 60.0
        assert tester.get_parameter(node, "detector.marker_radius_min_px") == 4.0
        assert localizer.processor.config.marker_radius_max_px == 60.0
        # Values that are valid one after the other all apply.
        results = tester.set_parameters(
            node, [("detector.marker_radius_max_px", 80.0), ("detector.marker_radius_min_px", 70.0)]
        )
        assert [r.successful for r in results] == [True, True]
        assert localizer.processor.config.marker_radius_min_px == 70.0
    finally:
        tester.set_parameters(node, [("detector.marker_radius_min_px", 4.0),
                                     ("detector.marker_radius_max_px", 40.0)])
    assert localizer.processor.config.marker_radius_max_px == 40.0


def test_parameter_descriptors_state_unit_range_and_read_only(localizer, tester):
    names = ["detector.marker_radius_min_px", "detector.refinement", "workers", "max_frame_age_s"]
    request = DescribeParameters.Request(names=names)
    radius, refinement, workers, age = tester.call(
        DescribeParameters, "/inproc/marker_localizer/describe_parameters", request
    ).descriptors
    assert radius.description.endswith("[px]")
    assert radius.type == ParameterType.PARAMETER_DOUBLE
    assert (radius.floating_point_range[0].from_value, radius.floating_point_range[0].to_value) == (
        1.5, 1000.0)
    assert not radius.read_only
    assert refinement.additional_constraints == "one of: symmetry, ncc, template"
    assert workers.read_only
    assert workers.integer_range[0].from_value == 1
    assert age.description.endswith("[s]")


def test_overlay_is_published_once_switched_on_live(localizer, tester):
    tester.listen("cam4/marker_points", PointCloud2)
    tester.listen("cam4/marker_overlay", Image)
    (result,) = tester.set_parameters("/inproc/marker_localizer", [("publish_overlay", True)])
    assert result.successful, result.reason
    try:
        frame = tester.frame(x_marker_64(), frame_id="cam4_optical")
        tester.publish("cam4/image_raw", frame)
        overlay = tester.result_for("cam4/marker_overlay", frame.header)
    finally:
        tester.set_parameters("/inproc/marker_localizer", [("publish_overlay", False)])
    assert overlay.header == frame.header
    assert (overlay.encoding, overlay.width, overlay.height) == ("bgr8", 64, 64)


def test_image_subscriptions_are_reliable_keep_last_one_and_overridable(localizer, tester):
    (info,) = tester.node.get_subscriptions_info_by_topic("/inproc/cam0/image_raw")
    assert info.qos_profile.reliability == ReliabilityPolicy.RELIABLE
    name = "qos_overrides./inproc/cam0/image_raw.subscription.reliability"
    assert tester.get_parameter("/inproc/marker_localizer", name) == "reliable"
    depth = "qos_overrides./inproc/cam0/image_raw.subscription.depth"
    assert tester.get_parameter("/inproc/marker_localizer", depth) == 1


def test_diagnostics_report_ok_levels_values_and_node_status(localizer, tester):
    tester.listen("/diagnostics", DiagnosticArray)
    tester.listen("cam0/marker_points", PointCloud2)
    frame = tester.frame(x_marker_64())
    tester.publish("cam0/image_raw", frame)
    tester.result_for("cam0/marker_points", frame.header)

    def fresh_status():
        for array_msg in reversed(tester.messages("/diagnostics")):
            statuses = {s.name: s for s in array_msg.status}
            cam0 = statuses.get("marker_localizer: cam0")
            if cam0 and int(values_of(cam0)["frames processed"]) >= 1:
                return statuses
        return None

    statuses = wait_until(fresh_status, "diagnostics counting the cam0 frame")
    cam0 = statuses["marker_localizer: cam0"]
    assert (level_of(cam0), cam0.hardware_id) == (OK, "cam0")
    values = values_of(cam0)
    assert float(values["latency p95 (ms)"]) > 0.0
    assert values["camera_info"] == "none received"
    node = statuses["marker_localizer: node"]
    assert level_of(node) == OK
    assert values_of(node)["workers"] == "2"


# --------------------------------------------------------------------------- diagnostics levels


def holding(camera):
    """A worker pool whose detector holds ``camera``'s frames until the event is set.

    A stand-in for a detector too slow for its camera, whatever the speed of the
    real one: while a worker holds one frame, every newer frame of that camera
    replaces the one waiting in its mailbox.
    """
    release = threading.Event()

    class HeldCameraProcessor(FrameProcessor):
        def detect(self, frame_camera, pixels, stamp_s):
            if frame_camera == camera:
                release.wait(TIMEOUT_S)
            return super().detect(frame_camera, pixels, stamp_s)

    return HeldCameraProcessor, release


@contextmanager
def serving(name, overrides, processor_class=FrameProcessor):
    """A node ``<name>_localizer`` in namespace ``/<name>``, spun, and a peer beside it."""
    node = MarkerLocalizerNode(
        f"{name}_localizer",
        namespace=f"/{name}",
        processor_class=processor_class,
        parameter_overrides=[Parameter(key, value=value) for key, value in overrides.items()],
    )
    spinner = Spinner(node)
    peer = Peer(f"{name}_peer", f"/{name}")
    try:
        yield node, peer
    finally:
        peer.stop()
        spinner.stop()


def test_dropped_frames_are_logged_with_their_reason(ros, capfd):
    """Replaced in the mailbox (INFO), then waited too long (WARN), from one camera."""
    processor_class, release = holding("cam0")
    settings = {"cameras": ["cam0"], "workers": 1, "max_frame_age_s": 0.05,
                "diagnostics_period_s": 0.1}
    logged = []

    def logged_line(*words):
        logged.extend(capfd.readouterr().err.splitlines())
        return next((line for line in logged if all(w in line for w in words)), None)

    with serving("drop", settings, processor_class) as (node, peer):
        try:
            stats = node.processor.snapshots
            for received in (1, 2, 3):  # the first is held, the third replaces the second
                peer.publish("cam0/image_raw", peer.frame(x_marker_64()))
                wait_until(lambda n=received: stats()["cam0"].received == n, f"frame {received}")
            wait_until(lambda: stats()["cam0"].dropped_mailbox == 1, "the mailbox drop")
            assert "INFO" in wait_until(
                lambda: logged_line("cam0: 1 frame(s) dropped", "replaced in the mailbox"),
                "the mailbox drop logged")
            time.sleep(0.1)  # the waiting frame grows stale behind the held one
            release.set()
            wait_until(lambda: stats()["cam0"].dropped_age == 1, "the age drop")
            assert "WARN" in wait_until(
                lambda: logged_line("cam0: 1 frame(s) dropped: 1 waited longer than "
                                    "max_frame_age_s = 0.05 s"),
                "the age drop logged, after the 5 s throttle")
        finally:
            release.set()


def test_shutdown_waits_at_most_shutdown_timeout_for_frames_in_flight_and_names_them(
    ros, capfd
):
    processor_class, release = holding("cam0")
    node = MarkerLocalizerNode(
        "drain_localizer",
        namespace="/drain",
        processor_class=processor_class,
        parameter_overrides=[
            Parameter("cameras", value=["cam0", "cam1"]),
            Parameter("shutdown_timeout_s", value=0.2),
        ],
    )
    spinner = Spinner(node)
    peer = Peer("drain_peer", "/drain")
    try:
        peer.publish("cam0/image_raw", peer.frame(x_marker_64()))
        wait_until(lambda: node.processor.in_flight() == ["cam0"], "cam0's frame held")
        spinner.stop()  # destroys the node: the drain gives up on the held frame
        assert node.processor.in_flight() == ["cam0"]
        err = capfd.readouterr().err
        assert "stopping: waiting up to 0.2 s for the frames in flight (cam0)" in err
        assert "stopping: frames still in flight after 0.2 s were abandoned (cam0)" in err
    finally:
        release.set()
        peer.stop()


def test_diagnostics_levels_ok_warn_on_drops_error_on_silence_and_bad_input(ros, capfd):
    """One node, five cameras in five states: steady, flooded, silent, bad encoding, truncated."""
    processor_class, release = holding("cam1")
    node = MarkerLocalizerNode(
        "diag_localizer",
        namespace="/diag",
        processor_class=processor_class,
        parameter_overrides=[
            Parameter("diagnostics_period_s", value=0.2),
            Parameter("input_timeout_s", value=1.0),
            Parameter("stats_window_s", value=60.0),
            Parameter("latency_warn_ms", value=60_000.0),
            Parameter("qos_overrides./diag/cam2/image_raw.subscription.reliability",
                      value="best_effort"),
        ],
    )
    spinner = Spinner(node)
    tester = Peer("diag_tester", "/diag")
    stop = threading.Event()
    try:
        tester.listen("/diagnostics", DiagnosticArray)
        tester.listen("cam0/marker_points", PointCloud2)
        tester.listen("cam4/marker_points", PointCloud2)
        small = x_marker_64()
        bad_encoding = tester.frame(np.zeros((48, 64), np.uint8))
        bad_encoding.encoding = "yuv422"
        truncated = tester.frame(small)
        truncated.data = truncated.data[: len(truncated.data) // 2]
        tester.publish("cam3/image_raw", bad_encoding)
        tester.publish("cam4/image_raw", truncated)

        def feed():
            next_steady = 0.0
            while not stop.is_set():
                if time.monotonic() >= next_steady:
                    tester.publish("cam0/image_raw", tester.frame(small))
                    next_steady = time.monotonic() + 0.2
                tester.publish("cam1/image_raw", tester.frame(small))  # held: replaced
                stop.wait(0.02)

        feeder = threading.Thread(target=feed, daemon=True)
        feeder.start()
        expected = {"cam0": OK, "cam1": WARN, "cam2": ERROR, "cam3": ERROR, "cam4": ERROR}
        last = {}

        def levels_reached():
            for array_msg in reversed(tester.messages("/diagnostics")[-5:]):
                statuses = {s.hardware_id: s for s in array_msg.status
                            if s.name.startswith("diag_localizer: ")}
                last.update(statuses)
                if all(c in statuses and level_of(statuses[c]) == lvl
                       for c, lvl in expected.items()):
                    return statuses
            return None

        try:
            statuses = wait_until(levels_reached, "the five camera levels")
        except AssertionError:
            raise AssertionError({c: (level_of(s), s.message) for c, s in last.items()}) from None
        stop.set()
        feeder.join(TIMEOUT_S)

        assert statuses["cam0"].message == "ok"
        assert "% of frames dropped" in statuses["cam1"].message
        assert int(values_of(statuses["cam1"])["dropped by mailbox"]) > 0
        logged = []

        def drops_logged():
            logged.extend(capfd.readouterr().err.splitlines())
            return any("cam1: " in line and "replaced in the mailbox by a newer frame" in line
                       for line in logged)

        wait_until(drops_logged, "the node logging cam1's drops with their reason")
        assert statuses["cam2"].message.startswith("no frame since start")
        assert "unsupported encoding 'yuv422'" in statuses["cam3"].message
        assert "data holds 2048 B" in values_of(statuses["cam4"])["last error"]
        node_status = statuses["diag_localizer"]
        assert level_of(node_status) == ERROR
        assert "cam3 ERROR" in node_status.message

        # The camera that sent a truncated frame is served again as soon as a good one comes.
        good = tester.frame(small)
        tester.publish("cam4/image_raw", good)
        assert tester.result_for("cam4/marker_points", good.header).width == 1
        (info,) = tester.node.get_subscriptions_info_by_topic("/diag/cam2/image_raw")
        assert info.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
    finally:
        stop.set()
        release.set()
        tester.stop()
        spinner.stop()


def test_a_flood_of_bad_frames_costs_no_good_frame_and_keeps_diagnostics_small(ros):
    """cam1 floods hostile frames while every frame cam0 sends gets its result."""
    settings = {"cameras": ["cam0", "cam1"], "diagnostics_period_s": 0.1,
                "input_timeout_s": 600.0, "max_frame_age_s": 0.0,
                "detector.max_pixels": 1_000_000}
    oversized = stamped(1, np.zeros((4, 4), np.uint8))
    oversized.height, oversized.width, oversized.step = 30000, 30000, 30000  # 16 B of data
    long_encoding = stamped(2, np.zeros((4, 4), np.uint8))
    long_encoding.encoding = "x" * 1_000_000
    truncated = stamped(3)
    truncated.data = truncated.data[:100]
    hostile = [oversized, long_encoding, truncated]
    stop = threading.Event()

    with serving("flood", settings) as (node, peer):
        def flood():
            k = 0
            while not stop.is_set():
                peer.publish("cam1/image_raw", hostile[k % len(hostile)])
                k += 1

        flooder = threading.Thread(target=flood, daemon=True)
        try:
            peer.listen("cam0/marker_points", PointCloud2)
            peer.listen("/diagnostics", DiagnosticArray)
            flooder.start()
            wait_until(lambda: node.processor.snapshots()["cam1"].errors >= 30, "the flood")
            for _ in range(5):
                good = peer.frame(x_marker_64())
                peer.publish("cam0/image_raw", good)
                assert peer.result_for("cam0/marker_points", good.header).width == 1
            snap = node.processor.snapshots()
            assert (snap["cam0"].processed, snap["cam0"].errors) == (5, 0)
            assert snap["cam1"].processed == 0

            def flooded_status():
                for array_msg in reversed(peer.messages("/diagnostics")[-3:]):
                    statuses = {s.hardware_id: s for s in array_msg.status}
                    if "cam1" in statuses and int(values_of(statuses["cam1"])["errors"]) >= 30:
                        return array_msg
                return None

            array_msg = wait_until(flooded_status, "diagnostics of the flood")
            size = len(serialize_message(array_msg))
            assert size < 8_000, size  # a 1 MB encoding string made 3 MB every second
            cam1 = next(s for s in array_msg.status if s.hardware_id == "cam1")
            assert level_of(cam1) == ERROR
        finally:
            stop.set()
            flooder.join(TIMEOUT_S)


def test_frames_lost_before_the_node_show_in_its_diagnostics_with_the_figure(ros):
    """The camera's stamps step 0.1 s; 12 of the 40 frames it stamped never reach the node."""
    settings = {"cameras": ["cam0"], "diagnostics_period_s": 0.1, "stats_window_s": 600.0,
                "input_timeout_s": 600.0}
    lost = {3, 4, 9, 13, 14, 15, 22, 27, 30, 31, 35, 37}
    with serving("loss", settings) as (node, peer):
        peer.listen("/diagnostics", DiagnosticArray)
        sent = 0
        for k in range(40):
            if k in lost:
                continue
            frame = peer.frame(x_marker_64(), stamp=Time(sec=100 + k // 10,
                                                         nanosec=(k % 10) * 100_000_000))
            peer.publish("cam0/image_raw", frame)
            sent += 1
            wait_until(lambda n=sent: node.processor.snapshots()["cam0"].received == n,
                       f"frame {k} received")

        def warned():
            for array_msg in reversed(peer.messages("/diagnostics")):
                for status in array_msg.status:
                    if status.name == "loss_localizer: cam0" and (
                        values_of(status)["frames received"] == str(sent)
                    ):
                        return status
            return None

        status = wait_until(warned, "the loss in the diagnostics")
        assert level_of(status) == WARN
        assert status.message == ("30 % of frames lost before the node (12 of 40 in 600 s, "
                                  "from stamp gaps at 10 Hz)")
        assert values_of(status)["lost upstream in window"] == "12"


@pytest.mark.parametrize("use_sim_time", [False, True])
def test_frames_stamped_on_another_clock_are_processed_with_their_stamps_copied(
    ros, use_sim_time
):
    """An old bag played without /clock, a camera's device clock, a stamp from the future."""
    node = MarkerLocalizerNode(
        "clock_localizer",
        namespace="/clocks",
        parameter_overrides=[
            Parameter("use_sim_time", value=use_sim_time),
            Parameter("cameras", value=["cam0"]),
            Parameter("max_frame_age_s", value=2.0),
            Parameter("diagnostics_period_s", value=0.2),
        ],
    )
    spinner = Spinner(node)
    peer = Peer("clock_peer", "/clocks")
    clock_pub = peer.node.create_publisher(Clock, "/clock", 10)
    stop = threading.Event()

    def tick():  # with use_sim_time: a simulator's clock from t = 1000 s on, at real rate
        start = time.monotonic()
        while not stop.wait(0.02):
            clock_pub.publish(Clock(clock=Time(sec=1000 + int(time.monotonic() - start))))

    ticker = threading.Thread(target=tick, daemon=True)
    ticker.start()
    try:
        if use_sim_time:
            wait_until(lambda: node.get_clock().now().nanoseconds >= 1000 * 10**9, "sim time")
        now_s = node.get_clock().now().nanoseconds // 10**9
        peer.listen("cam0/marker_points", PointCloud2)
        peer.listen("/diagnostics", DiagnosticArray)
        old, device, future = (
            peer.frame(x_marker_64(), stamp=Time(sec=sec)) for sec in (1, 2, now_s + 3600)
        )
        for frame in (old, device, future):
            peer.publish("cam0/image_raw", frame)
            assert peer.result_for("cam0/marker_points", frame.header).header == frame.header
        assert node.processor.snapshots()["cam0"].dropped_age == 0

        def offsets():
            for array_msg in reversed(peer.messages("/diagnostics")):
                for status in array_msg.status:
                    values = values_of(status)
                    if status.hardware_id == "cam0" and values["frames processed"] == "3":
                        return status, float(values["clock offset p50 (s)"])
            return None

        status, offset_s = wait_until(offsets, "diagnostics of the three frames")
        # Median of (arrival - stamp): the device-clock frame's, about now - 2 s.
        assert offset_s == pytest.approx(now_s - 2, abs=5.0)
        assert level_of(status) == OK
    finally:
        stop.set()
        ticker.join(TIMEOUT_S)
        peer.stop()
        spinner.stop()


# --------------------------------------------------------------------------- FrameProcessor


class Collector:
    """Result callback that records (camera, stamp sec) and can hold the worker."""

    def __init__(self):
        self.results = []
        self.release = threading.Event()
        self.release.set()
        self.entered = threading.Event()

    def __call__(self, camera, cloud, overlay):
        self.entered.set()
        self.release.wait(TIMEOUT_S)
        self.results.append((camera, cloud.header.stamp.sec, cloud.width))


def stamped(sec, pixels=None):
    pixels = x_marker_64() if pixels is None else pixels
    return array_to_image(pixels, "mono8", Header(stamp=Time(sec=sec)))


def clock_at(seconds):
    return lambda: int(seconds * 1e9)


def test_mailbox_keeps_only_the_newest_frame_and_counts_the_replaced_ones():
    collect = Collector()
    processor = FrameProcessor(["cam0"], DetectorConfig(), collect, workers=1,
                               clock_ns=clock_at(10))
    try:
        collect.release.clear()
        processor.submit("cam0", stamped(1))
        wait_until(collect.entered.is_set, "the worker to take frame 1")
        processor.submit("cam0", stamped(2))
        processor.submit("cam0", stamped(3))  # replaces frame 2
        collect.release.set()
        assert processor.wait_idle(TIMEOUT_S)
    finally:
        processor.shutdown()
    assert collect.results == [("cam0", 1, 1), ("cam0", 3, 1)]
    snap = processor.snapshots()["cam0"]
    assert (snap.received, snap.processed, snap.dropped_mailbox) == (3, 2, 1)


def test_camera_waiting_longest_is_served_first_even_if_its_frame_was_replaced():
    collect = Collector()
    now = [0]
    processor = FrameProcessor(["a", "b", "c"], DetectorConfig(), collect, workers=1,
                               clock_ns=lambda: now[0])
    try:
        collect.release.clear()
        processor.submit("a", stamped(1))
        wait_until(collect.entered.is_set, "the worker to take a's frame")
        for camera, sec in [("b", 2), ("c", 3), ("a", 4), ("b", 5)]:  # b's frame 2 replaced
            now[0] += 1
            processor.submit(camera, stamped(sec))
        collect.release.set()
        assert processor.wait_idle(TIMEOUT_S)
    finally:
        processor.shutdown()
    assert [(c, s) for c, s, _ in collect.results] == [("a", 1), ("b", 5), ("c", 3), ("a", 4)]


def test_frames_that_waited_longer_than_max_age_in_the_node_are_dropped_whatever_their_stamp():
    collect = Collector()
    now = [100 * 10**9]
    processor = FrameProcessor(["a", "b"], DetectorConfig(), collect, workers=1,
                               max_frame_age_s=2.0, clock_ns=lambda: now[0])
    try:
        collect.release.clear()
        processor.submit("a", stamped(1))  # stamped 99 s before it arrives: taken at once
        wait_until(collect.entered.is_set, "the worker to take a's frame")
        processor.submit("b", stamped(500))  # from the future; waits behind a's frame
        now[0] += 3 * 10**9  # the worker stays busy 3 s
        collect.release.set()
        assert processor.wait_idle(TIMEOUT_S)
        processor.submit("b", stamped(501), block=True)  # arrives now, taken at once
        assert processor.wait_idle(TIMEOUT_S)
    finally:
        processor.shutdown()
    assert collect.results == [("a", 1, 1), ("b", 501, 1)]
    snap = processor.snapshots()["b"]
    assert (snap.dropped_age, snap.processed) == (1, 1)


def test_blocking_submit_processes_every_frame_in_order_per_camera():
    collect = Collector()
    processor = FrameProcessor(["a", "b"], DetectorConfig(), collect, workers=2)
    try:
        for sec in range(1, 9):
            for camera in ("a", "b"):
                assert processor.submit(camera, stamped(sec), block=True)
        assert processor.wait_idle(TIMEOUT_S)
    finally:
        processor.shutdown()
    for camera in ("a", "b"):
        assert [s for c, s, _ in collect.results if c == camera] == list(range(1, 9))
    assert all(s.dropped_mailbox == s.dropped_age == 0 for s in processor.snapshots().values())


def test_candidates_the_detectors_caps_cut_reach_the_cameras_diagnostics():
    collect = Collector()
    noise = np.random.default_rng(1).integers(0, 256, (64, 64), dtype=np.uint8)
    # The X gives 3 candidates, noise dozens: a cap of 3 cuts the noise's only.
    config = DetectorConfig(max_candidates=3, tracking=False)
    processor = FrameProcessor(["cam0"], config, collect, workers=1)
    try:
        assert processor.submit("cam0", stamped(1), block=True)
        assert processor.submit("cam0", stamped(2, noise), block=True)
        assert processor.wait_idle(TIMEOUT_S)
    finally:
        processor.shutdown()
    snap = processor.snapshots()["cam0"]
    assert snap.frames_capped == 1
    assert snap.candidates_capped > 10


def test_shutdown_delivers_the_frame_in_flight_and_discards_waiting_ones():
    collect = Collector()
    processor = FrameProcessor(["cam0"], DetectorConfig(), collect, workers=1)
    collect.release.clear()
    processor.submit("cam0", stamped(1))
    wait_until(collect.entered.is_set, "the worker to take frame 1")
    processor.submit("cam0", stamped(2))  # still waiting in the mailbox at shutdown
    finished = []
    stopper = threading.Thread(target=lambda: finished.append(processor.shutdown()))
    stopper.start()
    wait_until(lambda: not processor.submit("cam0", stamped(3)), "the processor to refuse frames")
    collect.release.set()
    stopper.join(TIMEOUT_S)
    assert finished == [True]  # every worker ended
    assert collect.results == [("cam0", 1, 1)]


def test_failed_frame_is_counted_and_the_worker_goes_on():
    collect = Collector()
    failures = []
    processor = FrameProcessor(["cam0"], DetectorConfig(), collect, workers=1,
                               on_error=lambda camera, err: failures.append((camera, err)))
    bad = stamped(1)
    bad.data = array.array("B", bytes(10))
    try:
        processor.submit("cam0", bad, block=True)
        processor.submit("cam0", stamped(2), block=True)
        assert processor.wait_idle(TIMEOUT_S)
    finally:
        processor.shutdown()
    assert collect.results == [("cam0", 2, 1)]
    ((camera, err),) = failures
    assert camera == "cam0"
    assert isinstance(err, ImageError)
    snap = processor.snapshots()["cam0"]
    assert snap.errors == 1
    assert snap.last_error.startswith("ImageError: data holds 10 B")


def test_frame_over_max_pixels_fails_and_the_next_smaller_one_is_served():
    collect = Collector()
    processor = FrameProcessor(["cam0"], DetectorConfig(max_pixels=64 * 64), collect, workers=1)
    try:
        processor.submit("cam0", stamped(1, np.zeros((64, 65), np.uint8)), block=True)
        processor.submit("cam0", stamped(2), block=True)
        assert processor.wait_idle(TIMEOUT_S)
    finally:
        processor.shutdown()
    assert collect.results == [("cam0", 2, 1)]
    snap = processor.snapshots()["cam0"]
    assert snap.last_error == "ImageError: image: 65x64 = 4160 px exceeds max_pixels=4096"


# --------------------------------------------------------------------------- benchmark


def test_benchmark_cameras_pan_at_a_constant_step_and_turn_back_at_the_end_of_their_ground():
    dx, dy = throughput.PAN_STEP_PX
    frames = throughput.PAN_FRAMES
    ground = np.arange(50 + frames * dy)[:, None] * 1000 + np.arange(60 + frames * dx)
    views = [throughput.camera_view(ground, k) for k in range(2 * frames + 2)]
    assert {v.shape for v in views} == {(50, 60)}
    origins = [(int(v[0, 0]) % 1000, int(v[0, 0]) // 1000) for v in views]
    assert origins[:3] == [(0, 0), (dx, dy), (2 * dx, 2 * dy)]
    assert origins[frames] == (frames * dx, frames * dy)  # the far end of the ground
    assert origins[frames + 1] == ((frames - 1) * dx, (frames - 1) * dy)  # turned back
    assert origins[2 * frames] == (0, 0)


def test_throughput_benchmark_measures_one_and_two_workers_on_small_frames(ros, tmp_path):
    grounds = throughput.render_grounds(320, 240, directory=tmp_path, markers=1)
    results = [throughput.run_once(grounds, n, seconds=1.0, rate_hz=10.0) for n in (1, 2)]
    for result in results:
        assert result.processed > 0
        assert result.frames_per_s > 0
        assert result.published == 5 * 10
        assert result.dropped_mailbox + result.dropped_age + result.processed <= result.received
        assert result.latency_p95_ms >= result.latency_p50_ms > 0
    table = throughput.format_table(results)
    assert table.splitlines()[0].split()[:2] == ["workers", "frames/s"]
    assert "cameras %" in table.splitlines()[0]  # the camera process's CPU apart
    assert len(table.splitlines()) == 4


# --------------------------------------------------------------------------- separate process


def test_parameter_file_lists_every_parameter_at_its_default():
    assert PARAMS_FILE.read_text() == params_yaml()
    params = yaml.safe_load(PARAMS_FILE.read_text())["/**"]["ros__parameters"]
    assert DetectorConfig(**params["detector"]) == DetectorConfig()


def installed_script(name):
    """A console script where pip (beside the interpreter) or colcon (<prefix>/lib/<pkg>) put it."""
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    places = [Path(sys.executable).with_name(name),
              *(Path(p) / "lib" / "marker_localizer" / name for p in prefixes)]
    return str(next((p for p in places if p.is_file()), places[0]))


#: The two ways a user starts the node: the console script setup.py declares, and -m.
CONSOLE_SCRIPT = [installed_script("marker_localizer_node")]
MODULE = [sys.executable, "-m", "marker_localizer.node"]


def node_command(launcher, *ros_args):
    return [*launcher, "--ros-args", "--params-file", str(PARAMS_FILE), *ros_args]


@pytest.mark.parametrize(
    ("launcher", "stop_signal"),
    [(CONSOLE_SCRIPT, signal.SIGINT), (MODULE, signal.SIGTERM)],
    ids=["console-script-SIGINT", "python-m-SIGTERM"],
)
def test_node_process_serves_a_frame_and_stops_cleanly_on_signal(ros, launcher, stop_signal):
    process = subprocess.Popen(
        node_command(launcher, "-p", "cameras:=[cam0,cam1]", "-p", "workers:=1",
                     "-r", "cam0/marker_points:=cam0/points_remapped"),
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=os.environ.copy(),
    )
    tester = Peer(f"process_tester_{stop_signal.name.lower()}", "/")
    try:
        rendered = scene(1280, 960, 3, 12)
        tester.listen("/cam0/points_remapped", PointCloud2)
        frame = tester.frame(rendered.image, frame_id="cam0_optical")
        tester.publish("/cam0/image_raw", frame)
        cloud = tester.result_for("/cam0/points_remapped", frame.header, timeout_s=60.0)
        assert cloud.header == frame.header
        assert_matches_truth(points_xy(cloud), rendered.centres)
    finally:
        process.send_signal(stop_signal)
        stdout, stderr = process.communicate(timeout=TIMEOUT_S)
        tester.stop()
    assert process.returncode == 0, stderr
    assert "Traceback" not in stderr + stdout
    assert "stopped" in stderr + stdout


def test_node_process_exits_with_status_1_on_invalid_configuration():
    result = subprocess.run(
        node_command(MODULE, "-p", "detector.marker_radius_min_px:=50.0"),
        capture_output=True, text=True, timeout=TIMEOUT_S, check=False,
    )
    assert result.returncode == 1
    assert "invalid configuration: marker_radius_min_px=50.0 is larger than" in result.stderr
    assert "Traceback" not in result.stderr


def test_node_process_with_a_params_file_that_is_not_yaml_exits_1_in_one_line(tmp_path):
    broken = tmp_path / "broken.yaml"
    broken.write_text("marker_localizer:\n  ros__parameters:\n    workers: [oops\n")
    result = subprocess.run(
        [*MODULE, "--ros-args", "--params-file", str(broken)],
        capture_output=True, text=True, timeout=TIMEOUT_S, check=False,
    )
    assert result.returncode == 1
    (line,) = result.stderr.splitlines()
    assert "invalid ROS arguments: " in line and "Couldn't parse params file" in line
