"""The node in this process with real rclpy and DDS: rendered frames in, sub-pixel points out."""

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from encoded_images import compressed_message, transport_encoded
from node_testing import (
    CAMERAS,
    IMAGE_QOS,
    Peer,
    Spinner,
    assert_matches_truth,
    level_of,
    points_xy,
    scene,
    serving,
    values_of,
    wait_until,
    x_marker_64,
)
from rclpy.parameter import Parameter
from rclpy.qos import ReliabilityPolicy, qos_profile_sensor_data
from scenes import neutral_and_coloured_xs
from scipy.spatial import cKDTree
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2

from marker_localizer.core.image import bit_depth_scale, peak_level
from marker_localizer.ros import node as node_module
from marker_localizer.ros.conversions import BAYER_ENCODINGS
from marker_localizer.ros.diagnostics import OK, WARN
from marker_localizer.ros.node import MarkerLocalizerNode

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


#: One encoding of each kind the node reads besides mono8.
NODE_ENCODINGS = ["mono16", "bgr8", "rgb8", "rgba16", "yuyv", "nv12", "bayer_rggb8", "bayer_gbrg16"]


@pytest.mark.parametrize("encoding", NODE_ENCODINGS)
def test_node_reads_colour_16_bit_yuv_and_raw_bayer_frames(localizer, tester, encoding):
    # Two cameras share the frames: on one, their stamps (taken as the tests come) would
    # give enough uneven gaps to estimate frames lost upstream, which the node's status
    # test then reads as a warning (diagnostics.frames_lost_upstream).
    camera = ("cam2", "cam3")[NODE_ENCODINGS.index(encoding) % 2]
    tester.listen(f"{camera}/marker_points", PointCloud2)
    grey = x_marker_64()
    words = grey.astype(np.uint16) * 257  # white at 65535
    pixels = {
        "mono16": words,
        "bgr8": np.dstack([grey] * 3),
        "rgb8": np.dstack([grey] * 3),
        "rgba16": np.dstack([words] * 3 + [np.full_like(words, 7)]),  # any alpha
        "yuyv": np.dstack([grey, np.full_like(grey, 128)]),  # luma, then neutral chroma
        "nv12": grey,  # the luma plane; the chroma rows follow it, neutral
        "bayer_rggb8": grey,  # a grey scene through a sensor of equal channel gains
        "bayer_gbrg16": words,
    }[encoding]
    frame = tester.frame(pixels, encoding)
    tester.publish(f"{camera}/image_raw", frame)
    cloud = tester.result_for(f"{camera}/marker_points", frame.header)
    # Demosaicing weighs the channels differently at each pixel of a Bayer cell.
    tolerance_px = 0.03 if encoding in BAYER_ENCODINGS else 1e-3
    np.testing.assert_allclose(points_xy(cloud), [[31.5, 31.5]], atol=tolerance_px)


def test_a_colour_cameras_small_xs_drawn_in_colour_are_not_published(ros):
    """bgr8 frames through a worker process: the check reads their colour planes."""
    colour, _, centres = neutral_and_coloured_xs()
    settings = {
        "cameras": ["cam0"],
        "detector.marker_radius_min_px": 4.0,
        "detector.marker_radius_max_px": 12.0,
    }
    with serving("colour", settings) as (_, tester):
        tester.listen("cam0/marker_points", PointCloud2)
        frame = tester.frame(colour, "bgr8")
        tester.publish("cam0/image_raw", frame)
        found = points_xy(tester.result_for("cam0/marker_points", frame.header))
    distance, nearest = cKDTree(centres).query(found)
    assert len(found) == 4 and (distance < 0.5).all() and sorted(nearest) == [0, 1, 2, 3]


def test_frames_of_a_refused_encoding_are_each_counted_and_logged_in_one_line(
    ros, capfd, monkeypatch
):
    """A driver publishing depth (16UC1), then other encodings the node cannot read as grey.

    Every frame is an error of its camera; the log says why once, not once a frame
    (the throttle's window made to span the test however slow the machine).
    """
    monkeypatch.setattr(node_module, "_CAMERA_LOG_PERIOD_S", 3600.0)
    encodings = ["16UC1", "8UC1", "8UC3", "32FC1", "bogus"] * 2
    with serving("refused", {"cameras": ["cam0"], "worker_processes": False}) as (node, peer):
        capfd.readouterr()
        for sent, encoding in enumerate(encodings, 1):
            frame = peer.frame(x_marker_64())
            frame.encoding = encoding
            peer.publish("cam0/image_raw", frame)
            wait_until(lambda n=sent: node.processor.snapshots()["cam0"].errors == n, "a refusal")
        snapshot = node.processor.snapshots()["cam0"]
        assert (snapshot.processed, snapshot.errors) == (0, len(encodings))
        assert "unsupported encoding 'bogus' (expected one of mono" in snapshot.last_error
    (logged,) = [line for line in capfd.readouterr().err.splitlines() if "cam0: frame" in line]
    assert "cam0: frame rejected: unsupported encoding '16UC1': a generic type" in logged


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

        def publish(data, sec):
            msg = compressed_message("jpeg", sec, data, "cam0")
            pub.publish(msg)
            return msg.header

        publish(b"\xff\xd8 cut short", 1)
        wait_until(lambda: node.processor.snapshots()["cam0"].errors == 1, "the error counted")
        assert "truncated JPEG" in node.processor.snapshots()["cam0"].last_error
        jpeg = transport_encoded("jpeg", x_marker_64())
        cloud = peer.result_for("cam0/marker_points", publish(jpeg, 2))
        np.testing.assert_allclose(points_xy(cloud), [[31.5, 31.5]], atol=0.05)
        assert (
            node.get_parameter(
                "qos_overrides./jpeg/cam0/image_raw/compressed.subscription.reliability"
            ).value
            == "reliable"
        )
    finally:
        peer.stop()
        spinner.stop()


def test_compressed_frames_follow_a_remapped_raw_topic_as_image_transport_names_them(ros):
    """Remapping <cam>/image_raw moves <cam>/image_raw/compressed with it."""
    node = MarkerLocalizerNode(
        "remap_localizer",
        namespace="/remap",
        cli_args=["--ros-args", "-r", "cam0/image_raw:=/drv/front/image"],
        parameter_overrides=[
            Parameter("image_transport", value="compressed"),
            Parameter("cameras", value=["cam0"]),
            Parameter("workers", value=1),
            Parameter("worker_processes", value=False),
        ],
    )
    spinner = Spinner(node)
    peer = Peer("remap_peer", "/remap")
    try:
        peer.listen("cam0/marker_points", PointCloud2)
        pub = peer.node.create_publisher(CompressedImage, "/drv/front/image/compressed", IMAGE_QOS)
        wait_until(lambda: pub.get_subscription_count() > 0, "the node subscribing")
        msg = compressed_message("png", 3, transport_encoded("png", x_marker_64()), "front")
        pub.publish(msg)
        cloud = peer.result_for("cam0/marker_points", msg.header)
        assert cloud.header == msg.header
        np.testing.assert_allclose(points_xy(cloud), [[31.5, 31.5]], atol=1e-3)
    finally:
        peer.stop()
        spinner.stop()


def _camera_info_reported(peer, pub, status_name, size):
    """Publish a CameraInfo of ``size`` (width, height) on ``pub``; whether the diagnostics
    status ``status_name`` the ``peer`` heard reports that size."""
    width, height = size
    pub.publish(CameraInfo(width=width, height=height))
    return any(
        values_of(s)["camera_info"] == f"{width}x{height}"
        for array_msg in peer.messages("/diagnostics")
        for s in array_msg.status
        if s.name == status_name
    )


def test_camera_info_follows_a_remapped_image_topic_as_image_transport_names_it(ros):
    """The sibling of the image topic, unless <cam>/camera_info is remapped itself.

    A driver publishes <ns>/image_raw and <ns>/camera_info side by side; one remap of
    the image puts both where the driver is, for the compressed transport too.
    """
    node = MarkerLocalizerNode(
        "info_localizer",
        namespace="/info",
        cli_args=[
            "--ros-args",
            "-r",
            "cam0/image_raw:=/drv/front/image_raw",
            "-r",
            "cam1/image_raw:=/drv/rear/image",
            "-r",
            "cam1/camera_info:=/calib/rear",
        ],
        parameter_overrides=[
            Parameter("image_transport", value="compressed"),
            Parameter("cameras", value=["cam0", "cam1", "cam2"]),
            Parameter("workers", value=1),
            Parameter("worker_processes", value=False),
            Parameter("diagnostics_period_s", value=0.1),
        ],
    )
    spinner = Spinner(node)
    peer = Peer("info_peer", "/info")
    try:
        subscribed = {
            name: [type_name.split("/")[-1] for type_name in types]
            for name, types in node.get_subscriber_names_and_types_by_node(
                "info_localizer", "/info"
            )
            if not name.startswith("/parameter_events")
        }
        assert subscribed == {
            "/drv/front/image_raw/compressed": ["CompressedImage"],
            "/drv/front/camera_info": ["CameraInfo"],
            "/drv/rear/image/compressed": ["CompressedImage"],
            "/calib/rear": ["CameraInfo"],
            "/info/cam2/image_raw/compressed": ["CompressedImage"],
            "/info/cam2/camera_info": ["CameraInfo"],
        }
        peer.listen("/diagnostics", DiagnosticArray)
        pub = peer.node.create_publisher(CameraInfo, "/drv/front/camera_info", 1)
        wait_until(lambda: pub.get_subscription_count() > 0, "the node subscribing")
        wait_until(
            lambda: _camera_info_reported(peer, pub, "info/info_localizer: cam0", (1280, 960)),
            "cam0's camera_info in the diagnostics",
        )
    finally:
        peer.stop()
        spinner.stop()


def test_camera_info_published_best_effort_is_reported(localizer, tester):
    """Drivers that publish best-effort images often publish their camera_info so.

    Of the 64x64 frames the other tests send cam3: one of another size would turn the
    shared node's cam3 to WARN for the tests after this one.
    """
    tester.listen("/diagnostics", DiagnosticArray)
    pub = tester.node.create_publisher(CameraInfo, "cam3/camera_info", qos_profile_sensor_data)
    try:
        wait_until(lambda: pub.get_subscription_count() > 0, "the node subscribing camera_info")
        wait_until(
            lambda: _camera_info_reported(tester, pub, "inproc/marker_localizer: cam3", (64, 64)),
            "cam3's camera_info in the diagnostics",
        )
    finally:
        tester.node.destroy_publisher(pub)


def test_overlay_is_published_once_switched_on_live(localizer, tester):
    tester.listen("cam4/marker_points", PointCloud2)
    tester.listen("cam4/marker_overlay", Image)
    (result,) = tester.set_parameters("/inproc/marker_localizer", [("publish_overlay", True)])
    assert result.successful, result.reason
    try:
        frame = tester.frame(x_marker_64(), frame_id="cam4_optical")
        tester.publish("cam4/image_raw", frame)
        overlay = tester.result_for("cam4/marker_overlay", frame.header)
        # An rgb8 camera's channels come to the overlay reordered, not in C order.
        colour = tester.frame(np.dstack([x_marker_64()] * 3), "rgb8", frame_id="cam4_optical")
        tester.publish("cam4/image_raw", colour)
        colour_overlay = tester.result_for("cam4/marker_overlay", colour.header)
        (points,) = [m for m in tester.messages("cam4/marker_points") if m.header == colour.header]
    finally:
        tester.set_parameters("/inproc/marker_localizer", [("publish_overlay", False)])
    assert overlay.header == frame.header
    assert (overlay.encoding, overlay.width, overlay.height) == ("bgr8", 64, 64)
    assert colour_overlay.data == overlay.data
    assert points.width == 1


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
            cam0 = statuses.get("inproc/marker_localizer: cam0")
            if cam0 and int(values_of(cam0)["frames processed"]) >= 1:
                return statuses
        return None

    statuses = wait_until(fresh_status, "diagnostics counting the cam0 frame")
    cam0 = statuses["inproc/marker_localizer: cam0"]
    assert (level_of(cam0), cam0.hardware_id) == (OK, "inproc/cam0")
    values = values_of(cam0)
    assert float(values["latency p95 (ms)"]) > 0.0
    assert values["camera_info"] == "none received"
    node = statuses["inproc/marker_localizer: node"]
    assert level_of(node) == OK
    assert values_of(node)["workers"] == "2"
    assert values_of(node)["worker kind"] == "processes"


#: Frames a camera's diagnostics warn of, in 8- and 16-bit words, the warning, and a
#: frame exposed for its markers.
_DIM_FRAMES = [
    pytest.param(
        (x_marker_64() // 3, "mono8"),
        "frames underexposed: the brightest level is 26 % of white, under 1/2",
        (x_marker_64(), "mono8"),
        id="white paint at a quarter of white",
    ),
    pytest.param(
        (x_marker_64().astype(np.uint16) * 16, "mono16"),
        "16-bit frames under 1/16 of white: a 12-bit camera wants detector.bit_depth 12",
        (x_marker_64().astype(np.uint16) * 257, "mono16"),
        id="a 12-bit camera's words read at 16 bits",
    ),
]


@pytest.mark.parametrize(("dim", "warning", "exposed"), _DIM_FRAMES)
def test_diagnostics_warn_of_a_cameras_dim_frames_until_one_exposed_for_its_markers(
    ros, dim, warning, exposed
):
    # A node of its own: the module's has lit every camera's window.
    settings = {
        "cameras": ["cam1"],
        "diagnostics_period_s": 0.1,
        "input_timeout_s": 600.0,
        "latency_warn_ms": 60_000.0,
    }
    with serving("levels", settings) as (_, tester):
        tester.listen("/diagnostics", DiagnosticArray)
        tester.listen("cam1/marker_points", PointCloud2)
        frame = tester.frame(*dim)
        tester.publish("cam1/image_raw", frame)
        tester.result_for("cam1/marker_points", frame.header)

        def status():
            """cam1's newest status (the module's node publishes /diagnostics too)."""
            for array_msg in reversed(tester.messages("/diagnostics")):
                for camera in array_msg.status:
                    if camera.name == "levels/levels_localizer: cam1":
                        return camera
            return None

        cam1 = wait_until(
            lambda: (latest := status()) and level_of(latest) == WARN and latest,
            f"cam1's diagnostics warning: {warning}",
        )
        assert cam1.message.startswith(warning)
        peak = float(values_of(cam1)["peak level in window (% of white)"])
        white = bit_depth_scale(dim[0].dtype)
        assert peak == pytest.approx(100.0 * peak_level(dim[0]) / white, abs=0.05)
        bright = tester.frame(*exposed)
        tester.publish("cam1/image_raw", bright)
        tester.result_for("cam1/marker_points", bright.header)
        wait_until(
            lambda: (latest := status()) and level_of(latest) == OK,
            "cam1's diagnostics back to OK after a frame exposed for its markers",
        )
