"""``play``: a bag's messages published over real DDS, into the running node and into plain peers.

Everything runs in this process with its own rclpy Context (the player makes
its own, as its command does); ``ROS_DOMAIN_ID`` from conftest.py isolates the
traffic. Waits are polls with deadlines, never fixed sleeps.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections import defaultdict

import numpy as np
import pytest
import rclpy
import waiting
from builtin_interfaces.msg import Time
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, Imu, PointCloud2
from std_msgs.msg import Header

from marker_localizer.bag.io import BagReader, BagWriter, missing_message_reason
from marker_localizer.bag.play import PlayOptions, play_bag
from marker_localizer.cli import main as cli
from marker_localizer.errors import BagError, ConfigError
from marker_localizer.evaluation import DetectionTally, match_points
from marker_localizer.ros.conversions import array_to_image, cloud_to_array
from marker_localizer.ros.node import MarkerLocalizerNode

CAMERAS = ("cam0", "cam1", "cam2", "cam3", "cam4")
TIMEOUT_S = 60.0
#: A reliable keep-last-1 subscription: the QoS the node subscribes images with.
KEEP_LAST_1 = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
#: /clock is best effort (as ``ros2 bag play --clock``); a reliable reader would not match.
CLOCK_QOS = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT)


def wait_until(predicate, what, timeout_s=TIMEOUT_S):
    """Poll ``predicate`` for up to this module's timeout."""
    return waiting.wait_until(predicate, what, timeout_s)


def time_ns(t) -> int:
    return t.sec * 1_000_000_000 + t.nanosec


def stamp_ns(header) -> int:
    return time_ns(header.stamp)


def xy(cloud: PointCloud2) -> np.ndarray:
    points = cloud_to_array(cloud)
    return np.column_stack([points["x"], points["y"]]).reshape(-1, 2)


class Spun:
    """Nodes spun by one executor in a background thread, all in ``context``."""

    def __init__(self, context: Context, *nodes) -> None:
        self.nodes = nodes
        self.executor = SingleThreadedExecutor(context=context)
        for node in nodes:
            self.executor.add_node(node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def stop(self) -> None:
        self.executor.shutdown()
        self.thread.join(TIMEOUT_S)
        for node in self.nodes:
            node.destroy_node()


class CountedWaits:
    """The player's clock, advanced by the waits it asks for (real waits, counted exactly)."""

    def __init__(self):
        self.now_s = 0.0

    def monotonic(self):
        return self.now_s

    def sleep(self, seconds):
        time.sleep(seconds)
        self.now_s += seconds


class Listener:
    """Collects every message on the given topics."""

    def __init__(self, context: Context, topics: dict[str, type], qos=50) -> None:
        self.node = rclpy.create_node("play_listener", context=context)
        self.lock = threading.Lock()
        self.received: dict[str, list] = defaultdict(list)
        for topic, msg_type in topics.items():
            self.node.create_subscription(
                msg_type,
                topic,
                lambda msg, topic=topic: self._keep(topic, msg),
                CLOCK_QOS if topic == "/clock" else qos,
            )

    def _keep(self, topic, msg) -> None:
        with self.lock:
            self.received[topic].append(msg)

    def messages(self, topic: str) -> list:
        with self.lock:
            return list(self.received[topic])


@pytest.fixture(scope="module")
def context():
    context = Context()
    rclpy.init(context=context)
    yield context
    rclpy.try_shutdown(context=context)


@pytest.fixture(scope="module")
def tiny_sqlite_bag(tmp_path_factory):
    path = tmp_path_factory.mktemp("play_sqlite") / "tiny"
    argv = ["--out", str(path), "--frames", "4", "--width", "64", "--height", "48"]
    assert cli(["simulate", *argv, "--storage", "sqlite3", "--cameras", "2"]) == 0
    return path


def bag_truth(path) -> tuple[dict, dict, dict]:
    """(camera, stamp) -> truth and partial centres; camera -> image stamps, from the bag."""
    truth, partial, stamps = {}, {}, defaultdict(list)
    with BagReader(path) as bag:
        for message in bag.messages():
            camera, _, kind = message.topic.strip("/").partition("/")
            if kind == "marker_points_truth":
                cloud = message.decode()
                truth[(camera, stamp_ns(cloud.header))] = xy(cloud)
            elif kind == "marker_points_partial":
                cloud = message.decode()
                partial[(camera, stamp_ns(cloud.header))] = xy(cloud)
            elif kind == "image_raw":
                stamps[camera].append(message.time_ns)
    return truth, partial, stamps


# --------------------------------------------------------------------------- into the node


def test_playing_into_the_running_node_gives_points_at_the_truth_on_sim_time(
    context, small_flight, capsys
):
    truth, partial, stamps = bag_truth(small_flight)
    localizer = MarkerLocalizerNode(
        context=context, parameter_overrides=[Parameter("use_sim_time", value=True)]
    )
    points = {f"/{c}/marker_points": PointCloud2 for c in CAMERAS}
    listener = Listener(context, {**points, "/clock": Clock})
    spun = Spun(context, localizer, listener.node)
    try:
        status = cli(["play", str(small_flight), "--as-fast-as-possible", "--clock"])
        assert status == 0
        summary = capsys.readouterr().out
        assert re.search(r"played 60 messages on 20 topics", summary), summary
        assert "/tf_static (tf2_msgs/msg/TFMessage: package tf2_msgs not installed)" in summary
        # The newest frame of a camera is never replaced in the node's mailbox.
        for camera in CAMERAS:
            last = stamps[camera][-1]
            wait_until(
                lambda camera=camera, last=last: any(
                    stamp_ns(m.header) == last
                    for m in listener.messages(f"/{camera}/marker_points")
                ),
                f"the {camera} result of the last frame",
            )
        evaluation = DetectionTally()
        for camera in CAMERAS:
            for cloud in listener.messages(f"/{camera}/marker_points"):
                assert cloud.header.frame_id == f"{camera}_optical"
                key = (camera, stamp_ns(cloud.header))
                evaluation.add(match_points(xy(cloud), truth[key], excused=partial[key]))
        mean_px = evaluation.stats.mean
        sys.stdout.write(
            f"\nplay -> node: {evaluation.frames} of 15 frames processed, recall "
            f"{evaluation.recall:.3f} of {evaluation.n_truth}, mean error {mean_px:.4f} px, "
            f"FP/frame {evaluation.fp_per_frame:.2f}\n"
        )
        assert evaluation.frames >= len(CAMERAS)
        assert evaluation.recall >= 0.9, evaluation
        assert mean_px <= 0.1
        assert evaluation.fp_per_frame <= 0.5
        clock = [time_ns(m.clock) for m in listener.messages("/clock")]
        assert clock and clock == sorted(clock)
        # The node ran on the bag's time (use_sim_time), so no frame was too old for it.
        last_ns = max(stamps["cam0"])
        wait_until(lambda: localizer.get_clock().now().nanoseconds == last_ns, "sim time")
    finally:
        spun.stop()


# --------------------------------------------------------------------------- plain peers


@pytest.mark.parametrize("as_fast_as_possible", [False, True])
def test_a_keep_last_1_subscriber_receives_every_frame_in_order_from_sqlite3(
    context, tiny_sqlite_bag, as_fast_as_possible
):
    _, _, stamps = bag_truth(tiny_sqlite_bag)
    listener = Listener(context, {"/cam0/image_raw": Image, "/cam1/image_raw": Image}, KEEP_LAST_1)
    spun = Spun(context, listener.node)
    player = rclpy.create_node("test_player", context=context)
    try:
        options = PlayOptions(rate=4.0, as_fast_as_possible=as_fast_as_possible)
        waits = CountedWaits()
        report = play_bag(tiny_sqlite_bag, player, options, timekeeper=waits)
        assert report.published["/cam0/image_raw"] == 4
        assert report.skipped_topics == {"/tf_static": "tf2_msgs/msg/TFMessage"}
        assert report.without_subscribers == [] and report.unacknowledged == 0
        if not as_fast_as_possible:  # the waits asked for spread 1.5 s of bag time at 4x
            assert report.wall_s == pytest.approx(report.bag_s / 4.0, abs=1e-9)
        for camera in ("cam0", "cam1"):
            topic = f"/{camera}/image_raw"
            wait_until(
                lambda topic=topic: len(listener.messages(topic)) == 4, f"4 frames on {topic}"
            )
            received = [stamp_ns(m.header) for m in listener.messages(topic)]
            assert received == stamps[camera]
    finally:
        player.destroy_node()
        spun.stop()


def test_the_player_waits_for_the_subscribers_of_compressed_frames_only(context, tmp_path):
    """A bag of compressed frames: an image topic, awaited as raw ones are, not every topic."""
    bag = tmp_path / "compressed"
    with BagWriter(bag) as writer:
        writer.add_topic("/cam0/image_raw/compressed", "sensor_msgs/msg/CompressedImage")
        writer.add_topic("/imu/data", "sensor_msgs/msg/Imu")  # no one subscribes
        for sec in (1, 2):
            writer.write("/imu/data", sec * 10**9, Imu())
            frame = CompressedImage(format="mono8; png compressed mono8", data=b"\x89PNG")
            writer.write("/cam0/image_raw/compressed", sec * 10**9, frame)
    listener = Listener(context, {"/cam0/image_raw/compressed": CompressedImage}, KEEP_LAST_1)
    spun = Spun(context, listener.node)
    player = rclpy.create_node("test_player_compressed", context=context)
    try:
        # Long enough for discovery; the wait must end at the subscriber, not here.
        options = PlayOptions(as_fast_as_possible=True, wait_for_subscribers_s=20.0)
        report = play_bag(bag, player, options, timekeeper=CountedWaits())
        assert report.without_subscribers == []
        assert report.published == {"/cam0/image_raw/compressed": 2, "/imu/data": 2}
        wait_until(
            lambda: len(listener.messages("/cam0/image_raw/compressed")) == 2, "the 2 frames"
        )
    finally:
        player.destroy_node()
        spun.stop()


def interrupted_play(arguments, until, what, signum):
    """``play ARGUMENTS``, sent ``signum`` once ``until()`` holds: (status, stderr)."""
    player = subprocess.Popen(
        [sys.executable, "-m", "marker_localizer.cli", "play", *arguments],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        wait_until(until, what)
        player.send_signal(signum)
        _, err = player.communicate(timeout=TIMEOUT_S)
    finally:
        player.kill()
    return player.returncode, err


def test_sigterm_while_playing_stops_the_player_cleanly_with_status_143(context, small_flight):
    """The player publishes /clock while it waits between frames: the signal comes then."""
    listener = Listener(context, {"/clock": Clock})
    spun = Spun(context, listener.node)
    try:
        status, err = interrupted_play(
            [str(small_flight), "--rate", "0.01", "--clock", "--wait-for-subscribers", "0"],
            lambda: listener.messages("/clock"),
            "the player playing",
            signal.SIGTERM,
        )
    finally:
        spun.stop()
    assert status == 128 + signal.SIGTERM
    assert err == "marker-localizer play: interrupted by SIGTERM\n"


# --------------------------------------------------------------------------- pacing

#: A bag time of 2023 (ns): a float of it is 21 ns off, as were the /clock times reckoned in floats.
LATE_NS = 1_700_000_000_123_456_789
MS = 1_000_000


def imu(time_ns: int) -> Imu:
    return Imu(header=Header(stamp=Time(sec=time_ns // 10**9, nanosec=time_ns % 10**9)))


def imu_bag(path, times_ns, storage="mcap"):
    with BagWriter(path, storage) as writer:
        writer.add_topic("/imu/data", "sensor_msgs/msg/Imu")
        for time_ns in times_ns:
            writer.write("/imu/data", time_ns, imu(time_ns))
    return path


def test_play_keeps_the_bags_spacing_times_the_rate_into_a_subscriber(context, tmp_path):
    """0.1 s apart in the bag, at rate 2: published 50 ms apart by the player's clock (its
    waits really slept, and counted exactly), and received by a subscriber in order, each
    with its recorded stamp. The spacing is read from the player's clock, not the host's:
    a loaded host delays deliveries, not the schedule."""
    times_ns = [LATE_NS + k * 100 * MS for k in range(8)]
    bag = imu_bag(tmp_path / "imu", times_ns)
    listener = Listener(context, {"/imu/data": Imu})
    spun = Spun(context, listener.node)
    player = rclpy.create_node("test_player_pacing", context=context)
    waits = CountedWaits()
    published_s = []
    try:
        options = PlayOptions(rate=2.0, wait_for_subscribers_s=20.0)
        report = play_bag(
            bag,
            player,
            options,
            timekeeper=waits,
            progress=lambda done, total: published_s.append(waits.monotonic()),
        )
        assert report.without_subscribers == []
        wait_until(lambda: len(listener.messages("/imu/data")) == len(times_ns), "every message")
    finally:
        player.destroy_node()
        spun.stop()
    assert [stamp_ns(m.header) for m in listener.messages("/imu/data")] == times_ns
    gaps_s = np.diff(published_s)
    assert gaps_s == pytest.approx([0.05] * (len(times_ns) - 1), abs=1e-9)
    assert report.bag_s == pytest.approx(0.7)


class SlowFirstRead(BagReader):
    """A reader whose first message takes 0.5 s to come (a 12 MB frame from a cold disk)."""

    waits: CountedWaits

    def messages(self, topics=None):
        for n, message in enumerate(super().messages(topics)):
            if n == 0:
                self.waits.now_s += 0.5
            yield message


def test_the_schedule_starts_at_the_first_message_and_clock_never_goes_back(
    context, tmp_path, monkeypatch
):
    """The messages go out at their bag times from the first one (not 0.5 s early: the
    first read's wait was counted in the schedule, and the frames due meanwhile went in a
    burst); /clock, at a 2023 bag time, never goes back (two messages 5 ns apart made it
    go 16 ns back: the bag time was reckoned in floats)."""
    offsets_ns = [0, 5, 100 * MS, 200 * MS + 7, 300 * MS]
    times_ns = [LATE_NS + offset for offset in offsets_ns]
    bag = imu_bag(tmp_path / "imu", times_ns)
    waits = CountedWaits()
    SlowFirstRead.waits = waits
    monkeypatch.setattr("marker_localizer.bag.play.BagReader", SlowFirstRead)
    listener = Listener(context, {"/clock": Clock})
    spun = Spun(context, listener.node)
    player = rclpy.create_node("test_player_schedule", context=context)
    published_s = []
    try:
        wait_until(lambda: player.count_subscribers("/clock"), "the /clock subscriber")
        options = PlayOptions(rate=2.0, clock=True, wait_for_subscribers_s=0.0)
        play_bag(
            bag,
            player,
            options,
            timekeeper=waits,
            progress=lambda done, total: published_s.append(waits.monotonic()),
        )
        wait_until(
            lambda: LATE_NS + 300 * MS in [time_ns(m.clock) for m in listener.messages("/clock")],
            "the last message's time on /clock",
        )
    finally:
        player.destroy_node()
        spun.stop()
    due_s = [0.5 + (t - LATE_NS) / 1e9 / 2.0 for t in times_ns]
    assert published_s == pytest.approx(due_s, abs=1e-9)
    clock = [time_ns(m.clock) for m in listener.messages("/clock")]
    assert clock == sorted(clock), [c - LATE_NS for c in clock]
    assert min(clock) >= LATE_NS and max(clock) == times_ns[-1]


def test_loop_plays_the_bag_again_with_its_stamps_and_clock_from_the_start_until_ctrl_c(
    context, tmp_path
):
    """As ``ros2 bag play --loop``: the recorded messages again (their header stamps as
    recorded), and /clock back at the bag's first time for each pass; Ctrl-C ends it."""
    times_ns = [LATE_NS + k * 100 * MS for k in range(3)]
    bag = imu_bag(tmp_path / "imu", times_ns)
    listener = Listener(context, {"/imu/data": Imu, "/clock": Clock})
    spun = Spun(context, listener.node)
    try:
        status, err = interrupted_play(
            [str(bag), "--loop", "--clock", "--wait-for-subscribers", str(TIMEOUT_S)],
            lambda: len(listener.messages("/imu/data")) >= 2 * len(times_ns),
            "two passes",
            signal.SIGINT,
        )
    finally:
        spun.stop()
    assert status == 128 + signal.SIGINT
    assert err == "marker-localizer play: interrupted by SIGINT\n"
    stamps = [stamp_ns(m.header) for m in listener.messages("/imu/data")]
    assert stamps[: 2 * len(times_ns)] == times_ns * 2
    clock = [time_ns(m.clock) for m in listener.messages("/clock")]
    end_of_first_pass = clock.index(times_ns[-1])
    assert times_ns[0] in clock[end_of_first_pass:], [c - LATE_NS for c in clock]


def test_a_pass_of_loop_starts_once_the_last_passs_last_message_can_have_been_taken(
    context, tmp_path
):
    """Published at once after it, the next pass's first message replaced the last pass's
    last in a keep-last-1 subscriber's history (the node's images): lost on every pass."""
    times_ns = [LATE_NS + k * 100 * MS for k in range(3)]
    bag = imu_bag(tmp_path / "imu", times_ns)
    waits = CountedWaits()
    published_s: list[float] = []

    def until_the_second_pass_begins(done, total):
        published_s.append(waits.monotonic())
        if len(published_s) == len(times_ns) + 1:
            raise KeyboardInterrupt

    player = rclpy.create_node("test_player_loop_gap", context=context)
    try:
        with pytest.raises(KeyboardInterrupt):
            options = PlayOptions(loop=True, wait_for_subscribers_s=0.0)
            play_bag(bag, player, options, timekeeper=waits, progress=until_the_second_pass_begins)
    finally:
        player.destroy_node()
    gap_s = published_s[-1] - published_s[-2]
    assert gap_s >= PlayOptions().min_topic_interval_s
    assert published_s[:3] == pytest.approx([0.0, 0.1, 0.2], abs=1e-9)


#: A subscriber of /cam0/image_raw that says "received" on its first frame.
_CAM0_SUBSCRIBER = """
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

rclpy.init()
node = rclpy.create_node("cam0_subscriber")
qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
node.create_subscription(Image, "/cam0/image_raw", lambda msg: print("received", flush=True), qos)
rclpy.spin(node)
"""
#: Fast DDS drops a participant silent for its lease (20 s by default), and a wait for
#: its acknowledgements ends with it; with an hour's lease a stopped one stays matched.
_HOUR_LEASE_PROFILE = """<?xml version="1.0" encoding="UTF-8"?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <participant profile_name="hour_lease" is_default_profile="true">
    <rtps><builtin><discovery_config>
      <leaseDuration><sec>3600</sec></leaseDuration>
    </discovery_config></builtin></rtps>
  </participant>
</profiles>
"""
#: ``marker-localizer play`` waiting up to an hour for acknowledgements.
_PLAY_WAITING_AN_HOUR_FOR_ACKS = """
import functools, sys
import marker_localizer.cli.bag as bag
bag.PlayOptions = functools.partial(bag.PlayOptions, ack_timeout_s=3600.0)
from marker_localizer.cli import main
sys.exit(main(["play", *sys.argv[1:]]))
"""


def test_ctrl_c_stops_play_waiting_for_a_stopped_subscribers_acknowledgement(context, tmp_path):
    """A subscriber stopped (SIGSTOP) while matched never acknowledges: the player's wait
    for it at the end, an hour here, gives way to Ctrl-C. Before, the wait was one call
    into C, and Python ran the signal's handler only after it."""
    frames = [
        ("/cam0/image_raw", LATE_NS),
        ("/cam0/image_raw", LATE_NS + 1000 * MS),
        ("/cam1/image_raw", LATE_NS + 1001 * MS),
    ]
    bag = tmp_path / "two_cameras"
    with BagWriter(bag, "mcap") as writer:
        for topic in ("/cam0/image_raw", "/cam1/image_raw"):
            writer.add_topic(topic, "sensor_msgs/msg/Image")
        for topic, time_ns in frames:
            writer.write(topic, time_ns, Image(header=imu(time_ns).header))
    profile = tmp_path / "hour_lease.xml"
    profile.write_text(_HOUR_LEASE_PROFILE)
    listener = Listener(context, {"/cam1/image_raw": Image})
    spun = Spun(context, listener.node)
    stopped = subprocess.Popen(
        [sys.executable, "-c", _CAM0_SUBSCRIBER],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "FASTRTPS_DEFAULT_PROFILES_FILE": str(profile)},
    )
    player = subprocess.Popen(
        [sys.executable, "-c", _PLAY_WAITING_AN_HOUR_FOR_ACKS, str(bag)]
        + ["--wait-for-subscribers", str(TIMEOUT_S)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        # Stopped after cam0's first frame, a second before its second: that one it never
        # acknowledges, and the player's last wait begins with cam0's.
        assert stopped.stdout is not None and stopped.stdout.readline() == "received\n"
        stopped.send_signal(signal.SIGSTOP)
        wait_until(lambda: listener.messages("/cam1/image_raw"), "cam1's frame, the last")
        player.send_signal(signal.SIGINT)
        _, err = player.communicate(timeout=TIMEOUT_S)
    finally:
        player.kill()
        stopped.kill()
        stopped.wait(TIMEOUT_S)
        spun.stop()
    assert player.returncode == 128 + signal.SIGINT
    assert err == "marker-localizer play: interrupted by SIGINT\n"


# --------------------------------------------------------------------------- bad input


def test_play_of_a_missing_bag_exits_1_with_one_line(tmp_path, capsys):
    assert cli(["play", str(tmp_path / "gone")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "gone: no such bag" in err


def test_play_with_unknown_ros_arguments_exits_1_with_one_line(tiny_sqlite_bag, capsys):
    # rclpy's UnknownROSArgsError was a traceback.
    assert cli(["play", str(tiny_sqlite_bag), "--ros-args", "--bogus"]) == 1
    assert capsys.readouterr().err == (
        "marker-localizer play: error: unknown ROS arguments ['--bogus'] (after --ros-args: "
        "-p name:=value, --params-file FILE, -r from:=to, --log-level LEVEL)\n"
    )


def test_play_with_nothing_to_play_raises_bag_error(context, tiny_sqlite_bag, capsys):
    player = rclpy.create_node("test_player_nothing", context=context)
    try:
        with pytest.raises(BagError, match=r"nothing to play .*asked for: /nope"):
            play_bag(tiny_sqlite_bag, player, PlayOptions(topics=("/nope",)))
    finally:
        player.destroy_node()
    assert cli(["play", str(tiny_sqlite_bag), "--topics", "/tf_static"]) == 1
    assert "no message class: /tf_static (tf2_msgs/msg/TFMessage: " in capsys.readouterr().err


def camera_info_only(path):
    """A recording whose camera declared its image topic but wrote only camera_info."""
    with BagWriter(path) as writer:
        writer.add_topic("/cam0/image_raw", "sensor_msgs/msg/Image")
        writer.add_topic("/cam0/camera_info", "sensor_msgs/msg/CameraInfo")
        for sec in (1, 2):
            writer.write("/cam0/camera_info", sec * 10**9, CameraInfo())
    return path


def test_a_bag_of_declared_topics_without_a_message_is_one_line_exit_1(tmp_path, capsys):
    """It played 0 messages, exit 0, after waiting for the image topic's subscriber."""
    bag = tmp_path / "declared"
    with BagWriter(bag) as writer:
        writer.add_topic("/cam0/image_raw", "sensor_msgs/msg/Image")
        writer.add_topic("/cam0/camera_info", "sensor_msgs/msg/CameraInfo")
    assert cli(["play", str(bag)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "declared: nothing to play: no message on /cam0/camera_info, /cam0/image_raw" in err
    info = camera_info_only(tmp_path / "info")
    assert cli(["play", str(info), "--topics", "/cam0/image_raw"]) == 1
    assert "info: nothing to play: no message on /cam0/image_raw" in capsys.readouterr().err


def test_topics_asked_for_that_the_bag_does_not_hold_are_named(tmp_path, capsys):
    # A typo in --topics played the other topics without a word.
    info = camera_info_only(tmp_path / "info")
    asked = ["/cam0/camera_info", "/cam0/camera_inf"]
    assert cli(["play", str(info), "--topics", *asked, "--wait-for-subscribers", "0"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("played 2 messages on 1 topic")
    assert "not in the bag: /cam0/camera_inf\n" in out


def test_an_image_topic_without_a_message_is_not_waited_for(context, tmp_path):
    """Only camera_info to play: the player waits for its subscriber, not the frames' (it
    waited the whole 2 s for them and said the image topic had no subscriber)."""
    listener = Listener(context, {"/cam0/camera_info": CameraInfo})
    spun = Spun(context, listener.node)
    player = rclpy.create_node("test_player_info", context=context)
    try:
        options = PlayOptions(as_fast_as_possible=True, wait_for_subscribers_s=20.0)
        report = play_bag(camera_info_only(tmp_path / "info"), player, options)
        assert report.without_subscribers == []
        assert report.published == {"/cam0/camera_info": 2}
        wait_until(lambda: len(listener.messages("/cam0/camera_info")) == 2, "camera_info")
    finally:
        player.destroy_node()
        spun.stop()


def test_a_topic_without_a_message_class_is_named_with_why():
    """A package missing, or a ROS 1 type (``/rosout``'s) that ROS 2 Jazzy's package lacks."""
    assert missing_message_reason("no_such_msgs/msg/Thing") == "package no_such_msgs not installed"
    assert (
        missing_message_reason("rosgraph_msgs/msg/Log")
        == "no such type in ROS 2 Jazzy's rosgraph_msgs"
    )


def test_topics_ros_2_would_refuse_by_name_are_skipped_and_named_not_a_traceback(
    context, tmp_path, capsys
):
    """A ROS 1 bag's ``/cam-0/image_raw``: rclpy refuses a publisher of that name."""
    bag = tmp_path / "odd"
    with BagWriter(bag) as writer:
        for topic in ("/cam-0/image_raw", "/cam0/image_raw"):
            writer.add_topic(topic, "sensor_msgs/msg/Image")
            writer.write(topic, 1, array_to_image(np.zeros((4, 4), np.uint8), "mono8"))
    player = rclpy.create_node("test_player_names", context=context)
    try:
        options = PlayOptions(as_fast_as_possible=True, wait_for_subscribers_s=0.0)
        report = play_bag(bag, player, options)
    finally:
        player.destroy_node()
    assert report.published == {"/cam0/image_raw": 1}
    assert report.invalid_names == {
        "/cam-0/image_raw": "topic name must not contain characters other than "
        "alphanumerics, '_', or '/'"
    }
    assert cli(["play", str(bag), "--wait-for-subscribers", "0"]) == 0
    assert "skipped, not a valid ROS 2 topic name: /cam-0/image_raw (" in capsys.readouterr().out


def test_play_options_are_validated(tiny_sqlite_bag):
    with pytest.raises(ConfigError, match="rate"):
        PlayOptions(rate=0.0)
    with pytest.raises(ConfigError, match="qos_depth"):
        PlayOptions(qos_depth=0)
    # A NaN wait never ended: play hung before its first message.
    with pytest.raises(ConfigError, match="wait_for_subscribers_s=nan"):
        PlayOptions(wait_for_subscribers_s=float("nan"))
    with pytest.raises(ConfigError, match="clock_hz=inf"):
        PlayOptions(clock_hz=float("inf"))
    assert cli(["play", str(tiny_sqlite_bag), "--rate", "-1"]) == 1
