"""The node under load and fault: drops logged with their reason, diagnostics levels, the drain.

A camera too slow for its frames is a stand-in that holds them (:func:`node_testing.holding`),
never the real detector being slower than something.
"""

import itertools
import threading

import numpy as np
import pytest
import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from node_testing import (
    TIMEOUT_S,
    Peer,
    Spinner,
    clock_ahead,
    holding,
    level_of,
    serving,
    stamped,
    values_of,
    wait_until,
    x_marker_64,
)
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock
from scenes import panning_frames
from sensor_msgs.msg import CameraInfo, PointCloud2

from marker_localizer.ros.diagnostics import ERROR, OK, WARN
from marker_localizer.ros.node import MarkerLocalizerNode

# --------------------------------------------------------------------------- diagnostics levels


def test_dropped_frames_are_logged_with_their_reason(ros, capfd):
    """Replaced in the mailbox (INFO), then waited too long (WARN), from one camera."""
    held, release = holding("cam0")
    processor_class, advance = clock_ahead(held)
    # An age no real wait on a loaded machine reaches: only advance() crosses it.
    settings = {
        "cameras": ["cam0"],
        "workers": 1,
        "max_frame_age_s": 60.0,
        "diagnostics_period_s": 0.1,
    }
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
                "the mailbox drop logged",
            )
            advance(120.0)  # the waiting frame grows stale behind the held one
            release.set()
            wait_until(lambda: stats()["cam0"].dropped_age == 1, "the age drop")
            assert "WARN" in wait_until(
                lambda: logged_line(
                    "cam0: 1 frame(s) dropped: 1 waited longer than max_frame_age_s = 60 s"
                ),
                "the age drop logged, after the 5 s throttle",
            )
        finally:
            release.set()


def test_shutdown_waits_at_most_shutdown_timeout_for_frames_in_flight_and_names_them(ros, capfd):
    """And names the cameras whose frame waiting behind it is not processed.

    The frame it abandoned, released once its worker processes are ended, is not
    logged as failed: it was said abandoned.
    """
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
        peer.publish("cam0/image_raw", peer.frame(x_marker_64()))
        wait_until(lambda: node.processor.snapshots()["cam0"].received == 2, "one waiting")
        spinner.stop()  # destroys the node: the drain gives up on the held frame
        assert node.processor.in_flight() == ["cam0"]
        err = capfd.readouterr().err
        assert "stopping: waiting up to 0.2 s for the frames in flight (cam0)" in err
        assert "stopping: frames still in flight after 0.2 s were abandoned (cam0)" in err
        assert "stopping: the frames waiting for a worker were not processed (cam0)" in err
        release.set()
        wait_until(lambda: not node.processor.in_flight(), "the abandoned frame's worker")
        assert "frame failed" not in capfd.readouterr().err
    finally:
        release.set()
        peer.stop()


def test_a_node_destroyed_after_its_context_shut_down_abandons_its_frames_in_one_line(capfd):
    """rclpy's own Ctrl-C handling (spin, then destroy_node, in a user's program) shuts
    the context down first: the drain published into it, and each frame in flight failed
    with an RCLError traceback."""
    context = rclpy.Context()
    rclpy.init(context=context)
    processor_class, release = holding("cam0")
    node = MarkerLocalizerNode(
        "gone_localizer",
        context=context,
        processor_class=processor_class,
        # Threads: the stand-in holds the frame before it would reach a worker process.
        parameter_overrides=[
            Parameter("cameras", value=["cam0"]),
            Parameter("worker_processes", value=False),
        ],
    )
    try:
        node.processor.submit("cam0", stamped(1))
        wait_until(lambda: node.processor.in_flight() == ["cam0"], "cam0's frame held")
        context.shutdown()
        node.destroy_node()
        assert node.processor.abandoned
    finally:
        release.set()
        context.try_shutdown()
    err = capfd.readouterr().err
    assert "the ROS context is shut down, the frames in flight cannot be published" in err
    assert "frame failed" not in err


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
            Parameter(
                "qos_overrides./diag/cam2/image_raw.subscription.reliability", value="best_effort"
            ),
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
        bad_encoding.encoding = "nv24"
        truncated = tester.frame(small)
        truncated.data = truncated.data[: len(truncated.data) // 2]
        tester.publish("cam3/image_raw", bad_encoding)
        tester.publish("cam4/image_raw", truncated)

        def feed():
            steady_sent = 0
            while not stop.is_set():
                # cam0 sends its next frame once the last one's result is out: it
                # never has two frames in the node, however fast the detector is.
                # Its stamps are a camera's, one period apart whenever the frame is
                # sent: stamps of the send time would show a loaded machine's pauses
                # as frames lost before the node.
                if len(tester.messages("cam0/marker_points")) >= steady_sent:
                    stamp = Time(sec=1 + steady_sent // 10, nanosec=steady_sent % 10 * 100_000_000)
                    tester.publish("cam0/image_raw", tester.frame(small, stamp=stamp))
                    steady_sent += 1
                tester.publish("cam1/image_raw", tester.frame(small))  # held: replaced
                stop.wait(0.02)

        feeder = threading.Thread(target=feed, daemon=True)
        feeder.start()
        expected = {"cam0": OK, "cam1": WARN, "cam2": ERROR, "cam3": ERROR, "cam4": ERROR}
        last = {}

        def levels_reached():
            for array_msg in reversed(tester.messages("/diagnostics")[-5:]):
                statuses = {
                    s.name.removeprefix("diag/diag_localizer: "): s
                    for s in array_msg.status
                    if s.name.startswith("diag/diag_localizer: ")
                }
                last.update(statuses)
                if all(
                    c in statuses and level_of(statuses[c]) == lvl for c, lvl in expected.items()
                ):
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
            return any(
                "cam1: " in line and "replaced in the mailbox by a newer frame" in line
                for line in logged
            )

        wait_until(drops_logged, "the node logging cam1's drops with their reason")
        assert statuses["cam2"].message.startswith("no frame since start")
        assert "unsupported encoding 'nv24'" in statuses["cam3"].message
        assert "data holds 2048 B" in values_of(statuses["cam4"])["last error"]
        node_status = statuses["node"]
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
    settings = {
        "cameras": ["cam0", "cam1"],
        "diagnostics_period_s": 0.1,
        "input_timeout_s": 600.0,
        "max_frame_age_s": 0.0,
        "detector.max_pixels": 1_000_000,
    }
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
                    cam1 = statuses.get("flood/cam1")
                    if cam1 is not None and int(values_of(cam1)["errors"]) >= 30:
                        return array_msg
                return None

            array_msg = wait_until(flooded_status, "diagnostics of the flood")
            size = len(serialize_message(array_msg))
            assert size < 8_000, size  # a 1 MB encoding string made 3 MB every second
            cam1 = next(s for s in array_msg.status if s.hardware_id == "flood/cam1")
            assert level_of(cam1) == ERROR
        finally:
            stop.set()
            flooder.join(TIMEOUT_S)


def test_a_camera_info_for_another_frame_size_is_a_warning_naming_both_sizes(ros):
    """A pose estimator would project the 64x64 frames' points with 128x128 intrinsics.

    The camera's status says its frames' size; a camera_info of the same sensor whose
    binning halves its 128x128 describes them.
    """
    settings = {"cameras": ["cam0"], "diagnostics_period_s": 0.1, "input_timeout_s": 600.0}
    with serving("caminfo", settings) as (node, peer):
        peer.listen("/diagnostics", DiagnosticArray)
        info_publisher = peer.node.create_publisher(CameraInfo, "cam0/camera_info", 1)
        wait_until(lambda: info_publisher.get_subscription_count() > 0, "the node on camera_info")
        frame = peer.frame(x_marker_64())
        peer.publish("cam0/image_raw", frame)
        wait_until(lambda: node.processor.snapshots()["cam0"].processed == 1, "the frame")

        for binning, level, message in [
            (0, WARN, "camera_info is for 128x128 images, the frames are 64x64"),
            (2, OK, "ok"),
        ]:
            info = CameraInfo(header=frame.header, width=128, height=128)
            info.binning_x = info.binning_y = binning

            def status_at(level=level, info=info):
                info_publisher.publish(info)  # best effort: the node keeps the newest
                for array_msg in reversed(peer.messages("/diagnostics")[-3:]):
                    for status in array_msg.status:
                        values = values_of(status)
                        camera_info = (status.hardware_id, values.get("camera_info"))
                        if camera_info == ("caminfo/cam0", "128x128") and level_of(status) == level:
                            return status
                return None

            status = wait_until(status_at, f"cam0 at level {level}, binning {binning}")
            assert status.message.startswith(message)
            assert values_of(status)["frame size"] == "64x64"


def test_a_camera_info_published_once_latched_is_heard_where_its_qos_is_overridden_to_match(
    ros,
):
    """A driver publishes camera_info once, reliable and transient local, before the node
    starts: overridden to the driver's QoS, the node's subscription hears it (by default
    best effort and volatile, it is sent no earlier message)."""
    driver = rclpy.create_node("latched_driver", namespace="/latched")
    latched = QoSProfile(
        depth=1,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )
    driver.create_publisher(CameraInfo, "cam0/camera_info", latched).publish(
        CameraInfo(width=64, height=64)
    )
    subscription = "qos_overrides./latched/cam0/camera_info.subscription."
    settings = {
        "cameras": ["cam0"],
        "diagnostics_period_s": 0.1,
        "input_timeout_s": 600.0,
        subscription + "durability": "transient_local",
        subscription + "reliability": "reliable",
    }
    try:
        with serving("latched", settings) as (_, peer):
            peer.listen("/diagnostics", DiagnosticArray)

            def heard():
                return any(
                    status.hardware_id == "latched/cam0"
                    and values_of(status).get("camera_info") == "64x64"
                    for array_msg in peer.messages("/diagnostics")
                    for status in array_msg.status
                )

            wait_until(heard, "cam0's latched camera_info in the diagnostics")
    finally:
        driver.destroy_node()


def test_nodes_of_one_name_in_two_namespaces_publish_statuses_an_aggregator_tells_apart(ros):
    """/uav1/marker_localizer and /uav2/marker_localizer, each with a cam0: each status
    name and hardware_id is qualified by its namespace, as ROS 1's diagnostic_updater
    named them; a node in the root namespace keeps ROS 2's updater's names."""
    overrides = [
        Parameter("cameras", value=["cam0"]),
        Parameter("workers", value=1),
        Parameter("worker_processes", value=False),
        Parameter("diagnostics_period_s", value=0.1),
    ]
    nodes = [
        MarkerLocalizerNode(namespace=namespace, parameter_overrides=overrides)
        for namespace in ("/uav1", "/uav2", "/")
    ]
    spinners = [Spinner(node) for node in nodes]
    peer = Peer("namespaces_peer", "/")
    try:
        peer.listen("/diagnostics", DiagnosticArray)
        expected = {
            ("uav1/marker_localizer: cam0", "uav1/cam0"),
            ("uav1/marker_localizer: node", "uav1/marker_localizer"),
            ("uav2/marker_localizer: cam0", "uav2/cam0"),
            ("uav2/marker_localizer: node", "uav2/marker_localizer"),
            ("marker_localizer: cam0", "cam0"),
            ("marker_localizer: node", "marker_localizer"),
        }

        def heard():
            return {
                (status.name, status.hardware_id)
                for array_msg in peer.messages("/diagnostics")
                for status in array_msg.status
            }

        wait_until(lambda: expected <= heard(), f"statuses {sorted(expected)}")
    finally:
        peer.stop()
        for spinner in spinners:
            spinner.stop()


def test_a_cameras_status_names_the_topic_its_frames_come_from_as_remapped(ros):
    """``-r cam0/image_raw:=/uav1/front/image``: the status keeps its name and hardware_id
    (the camera's, stable whatever the wiring) and says where its frames are read from,
    the topic that counts the frame published there."""
    node = MarkerLocalizerNode(
        "remap_localizer",
        namespace="/remap",
        cli_args=["--ros-args", "-r", "cam0/image_raw:=/uav1/front/image"],
        parameter_overrides=[
            Parameter("cameras", value=["cam0", "cam1"]),
            Parameter("workers", value=1),
            Parameter("worker_processes", value=False),
            Parameter("diagnostics_period_s", value=0.1),
        ],
    )
    spinner = Spinner(node)
    peer = Peer("remap_peer", "/remap")
    try:
        peer.listen("/diagnostics", DiagnosticArray)
        peer.publish("/uav1/front/image", peer.frame(x_marker_64()))

        def statuses():
            for array_msg in reversed(peer.messages("/diagnostics")):
                by_camera = {s.hardware_id: s for s in array_msg.status}
                cam0 = by_camera.get("remap/cam0")
                if cam0 is not None and values_of(cam0)["frames received"] == "1":
                    return cam0, by_camera["remap/cam1"]
            return None

        cam0, cam1 = wait_until(statuses, "cam0's status counting the frame")
        assert cam0.name == "remap/remap_localizer: cam0"
        assert values_of(cam0)["image topic"] == "/uav1/front/image"
        assert values_of(cam1)["image topic"] == "/remap/cam1/image_raw"
    finally:
        peer.stop()
        spinner.stop()


def test_frames_lost_before_the_node_show_in_its_diagnostics_with_the_figure(ros):
    """The camera's stamps step 0.1 s; 12 of the 40 frames it stamped never reach the node."""
    settings = {
        "cameras": ["cam0"],
        "diagnostics_period_s": 0.1,
        "stats_window_s": 600.0,
        "input_timeout_s": 600.0,
    }
    lost = {3, 4, 9, 13, 14, 15, 22, 27, 30, 31, 35, 37}
    with serving("loss", settings) as (node, peer):
        peer.listen("/diagnostics", DiagnosticArray)
        sent = 0
        for k in range(40):
            if k in lost:
                continue
            frame = peer.frame(
                x_marker_64(), stamp=Time(sec=100 + k // 10, nanosec=(k % 10) * 100_000_000)
            )
            peer.publish("cam0/image_raw", frame)
            sent += 1
            wait_until(
                lambda n=sent: node.processor.snapshots()["cam0"].received == n,
                f"frame {k} received",
            )
            # Processed before the next is sent: a frame the next one replaced in the
            # mailbox would be a drop in the node, which this test is not about.
            assert node.processor.wait_idle(TIMEOUT_S)

        def warned():
            for array_msg in reversed(peer.messages("/diagnostics")):
                for status in array_msg.status:
                    if status.name == "loss/loss_localizer: cam0" and (
                        values_of(status)["frames received"] == str(sent)
                    ):
                        return status
            return None

        status = wait_until(warned, "the loss in the diagnostics")
        assert level_of(status) == WARN
        assert status.message == (
            "30 % of frames lost before the node (12 of 40 in 600 s, from stamp gaps at 10 Hz)"
        )
        assert values_of(status)["lost upstream in window"] == "12"


def test_diagnostics_are_published_under_sim_time_before_any_clock(ros):
    """A bag not playing yet: a timer on the node's simulated clock would never fire."""
    node = MarkerLocalizerNode(
        "simtime_localizer",
        namespace="/simtime",
        parameter_overrides=[
            Parameter("use_sim_time", value=True),
            Parameter("cameras", value=["cam0"]),
            Parameter("worker_processes", value=False),
            Parameter("diagnostics_period_s", value=0.2),
        ],
    )
    spinner = Spinner(node)
    peer = Peer("simtime_peer", "/simtime")
    try:
        peer.listen("/diagnostics", DiagnosticArray)

        def silent_camera():
            for array_msg in peer.messages("/diagnostics"):
                for status in array_msg.status:
                    if status.name == "simtime/simtime_localizer: cam0":
                        return status
            return None

        assert node.get_clock().now().nanoseconds == 0  # no /clock
        wait_until(silent_camera, "diagnostics without /clock")
    finally:
        peer.stop()
        spinner.stop()


@pytest.mark.parametrize("use_sim_time", [False, True])
def test_frames_stamped_on_another_clock_are_processed_with_their_stamps_copied(ros, use_sim_time):
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

    def tick():  # with use_sim_time: a simulator's clock from t = 1000 s on, 20 ms a tick
        for k in itertools.count():
            if stop.wait(0.02):
                return
            clock_pub.publish(Clock(clock=Time(sec=1000 + k // 50, nanosec=k % 50 * 20_000_000)))

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
                    if status.hardware_id == "clocks/cam0" and values["frames processed"] == "3":
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


def test_a_clock_that_jumps_back_restarts_the_windows_of_the_diagnostics(ros):
    """A bag played again: the frames of the first play are no longer in the window.

    Measured against times now in the future, the window never emptied, and its
    rate was counted over a span of one nanosecond.
    """
    settings = {
        "use_sim_time": True,
        "cameras": ["cam0"],
        "worker_processes": False,
        "max_frame_age_s": 0.0,
        "stats_window_s": 2.0,
    }
    with serving("rewind", settings) as (node, peer):
        peer.listen("cam0/marker_points", PointCloud2)
        clock_pub = peer.node.create_publisher(Clock, "/clock", 10)

        def frame_at(ns):
            stamp = Time(sec=ns // 10**9, nanosec=ns % 10**9)

            def clock_there():
                clock_pub.publish(Clock(clock=stamp))
                return node.get_clock().now().nanoseconds == ns

            wait_until(clock_there, f"the node's clock at {ns} ns")
            frame = peer.frame(x_marker_64(), stamp=stamp)
            peer.publish("cam0/image_raw", frame)
            peer.result_for("cam0/marker_points", frame.header)

        for k in range(3):  # the first play, at 10 Hz from t = 1000 s
            frame_at(1000 * 10**9 + k * 10**8)
        for k in range(5):  # played again from t = 100 s
            frame_at(100 * 10**9 + k * 10**8)
        snapshot = node.processor.snapshots()["cam0"]
        assert snapshot.received == 8
        assert snapshot.received_in_window == 5
        # 5 frames, 4 periods in the 0.4 s since the jump: the camera's 10 Hz.
        assert snapshot.input_rate_hz == pytest.approx(10.0)


# --------------------------------------------------------------------------- tracking


#: Frames of the panning flight each tracking test feeds the node.
PANNING_FRAMES = 5


def panning_flight_diagnostics(name, tracking):
    """cam0's /diagnostics values once the node has processed the whole panning flight.

    Each frame is sent once the last one's result is out, so that none is dropped.
    """
    settings = {
        "cameras": ["cam0"],
        "worker_processes": False,
        "diagnostics_period_s": 0.1,
        "input_timeout_s": 600.0,
        "max_frame_age_s": 0.0,
        "detector.marker_radius_min_px": 6.0,
        "detector.marker_radius_max_px": 20.0,
        "tracker.enabled": tracking,
    }
    with serving(name, settings) as (_, peer):
        peer.listen("cam0/marker_points", PointCloud2)
        peer.listen("/diagnostics", DiagnosticArray)
        for k, pixels in enumerate(panning_frames(PANNING_FRAMES)):
            frame = peer.frame(pixels, stamp=Time(sec=k + 1))
            peer.publish("cam0/image_raw", frame)
            assert peer.result_for("cam0/marker_points", frame.header).width == 3

        def after_the_flight():
            for array_msg in reversed(peer.messages("/diagnostics")):
                for status in array_msg.status:
                    values = values_of(status)
                    if status.hardware_id == f"{name}/cam0" and (
                        values["frames processed"] == str(PANNING_FRAMES)
                    ):
                        return values
            return None

        return wait_until(after_the_flight, "diagnostics of the whole flight")


def test_a_tracked_flight_shows_its_full_frame_passes_beside_the_frames_processed(ros):
    """The first frame is a full pass; the steady flight's next ones are tracked."""
    values = panning_flight_diagnostics("tracked", tracking=True)
    assert 1 <= int(values["full-frame passes"]) < PANNING_FRAMES
    assert float(values["full-frame passes in window (%)"]) < 100.0


def test_without_tracking_every_frame_processed_is_a_full_frame_pass(ros):
    values = panning_flight_diagnostics("untracked", tracking=False)
    assert values["full-frame passes"] == str(PANNING_FRAMES)
    assert values["full-frame passes in window (%)"] == "100.0"
