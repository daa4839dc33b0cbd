"""``marker-localizer play``: publish a bag's messages on their topics, like ``ros2 bag play``.

``ros2 bag`` is not installable here, so this player reads the bag with
``rosbags`` and publishes the recorded CDR bytes unchanged through rclpy
publishers (no deserialisation, so 12 MB images cost one copy). Topics whose
message package is not installed (``/tf_static``: tf2_msgs has no wheel) are
skipped and listed.

Publishers are reliable, keep-last (``qos_depth``), the QoS camera drivers
use and the node subscribes with. Before the first message the player waits up
to ``wait_for_subscribers_s`` until every image topic (Image or CompressedImage;
every topic if the bag has no images) that holds a message has a subscriber, so
the first frames are not lost to discovery. A bag whose topics to play hold no
message is refused (:class:`~marker_localizer.errors.BagError`). Timing:

* at the recorded rate (times ``rate``): each message is published when its
  bag time is due on the wall clock, counted from the moment the first message
  was read (not from before the read: a first read slow to come, a 12 MB frame
  from a cold disk, would otherwise send the frames due meanwhile in a burst);
  a message late for its time (a slow read) goes out at once and the next keep
  their times, so the spacing stays the bag's on average;
* ``as_fast_as_possible``: a message is published once the previous one on
  its topic was acknowledged by every matched subscription
  (``wait_for_all_acked``) and ``min_topic_interval_s`` (0.1 s) has passed
  since it went out. An acknowledgement only says the sample reached the
  subscriber's history; the interval gives its executor time to take it
  before the next sample replaces it in a keep-last-1 history, so such a
  subscriber receives every frame. A consumer slower at *processing* than
  that (the node on 12 MP frames) still replaces frames in its own mailbox, as
  with a live camera, and counts them in its diagnostics; use ``rate`` to pace
  for it. Topics are paced independently, so five cameras go out in parallel.

At the end the player waits for every subscriber to acknowledge the last
messages before it destroys its publishers.

With ``loop`` it plays the bag again from its first message when it reaches
the last, until it is interrupted (Ctrl-C), as ``ros2 bag play --loop`` does
(rosbag2's player seeks its reader to the start and jumps its clock back there
before every pass): each pass sends the recorded bytes unchanged, so headers
carry their recorded stamps again, its schedule starts at its first message as
the first pass's did, and ``/clock`` starts again at the bag's first time. A
pass starts once the last one's last frames (the awaited topics') were taken, as
``as_fast_as_possible`` paces a topic (a keep-last-1 subscriber lost them).

With ``clock``, ``/clock`` (rosgraph_msgs/Clock, best effort, keep-last 1 as
``ros2 bag play --clock``) carries the bag time: before every message and at
``clock_hz`` while waiting, so nodes with ``use_sim_time`` follow the bag. It is
reckoned in integer nanoseconds (a float of a bag time near 2023's 1.7e18 ns is
off by up to 128 ns), never passes the next message's bag time and never goes
back, not even for a message older than the last (a bag read front to back
gives file order): a clock that jumps back makes nodes clear their tf buffers.
It goes back only where ``loop`` starts a pass, and must: the bag's times
begin again there.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from marker_localizer.bag.io import BagReader, message_class, missing_messages_text
from marker_localizer.bag.record import stamp_msg
from marker_localizer.errors import BagError, ConfigError, shorten
from marker_localizer.ros.conversions import topic_name_problem

NODE_NAME = "marker_localizer_player"
CLOCK_TOPIC = "/clock"
#: The image types whose topics the player waits for: raw frames and image_transport's
#: compressed ones (``<cam>/image_raw/compressed``, how most flights are recorded).
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
_CLOCK_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.BEST_EFFORT
)
#: How often the subscriber wait looks at the publishers' match counts, s.
_POLL_S = 0.01
#: The longest one wait for acknowledgements stays inside rclpy, s: Python runs a
#: stop signal's handler only between two calls into C, so a wait of
#: ``ack_timeout_s`` in one call (a subscriber stopped or hung, still matched)
#: held Ctrl-C back that long. A wait that is acknowledged ends at once anyway.
_ACK_SLICE_S = 0.1


@dataclass(frozen=True)
class PlayOptions:
    """How to play a bag; validated on construction (raises ConfigError).

    Attributes:
        rate: Playback speed relative to the recording (2.0 = twice as fast).
        as_fast_as_possible: Ignore the recorded timing; publish each message
            once the previous one on its topic was acknowledged.
        clock: Publish the bag time on ``/clock``.
        loop: Play the bag again from its start after its last message, until
            interrupted (``ros2 bag play --loop``); off by default, as there.
        clock_hz: ``/clock`` rate while waiting for the next message, Hz
            (``ros2 bag play``'s default 40).
        topics: Play only these topics (None: all playable).
        qos_depth: History depth of the reliable publishers.
        wait_for_subscribers_s: Longest wait for the image topics' subscribers
            before the first message, s; it ends as they match. A node started
            beside the player took 0.1-2.6 s to match it on a 2-core host
            (2026-12-06), and at 2 s a third of the plays lost their first frames;
            twice that, for a player whose image topics are not all subscribed.
        ack_timeout_s: Longest wait for a message's acknowledgement, s
            (``as_fast_as_possible``, and for the last messages at the end).
        min_topic_interval_s: ``as_fast_as_possible`` only: least time between
            two messages on one topic, s; lets a subscriber's executor take a
            frame from a keep-last-1 history before the next replaces it.
    """

    rate: float = 1.0
    as_fast_as_possible: bool = False
    clock: bool = False
    loop: bool = False
    clock_hz: float = 40.0
    topics: tuple[str, ...] | None = None
    qos_depth: int = 10
    wait_for_subscribers_s: float = 5.0
    ack_timeout_s: float = 10.0
    min_topic_interval_s: float = 0.1

    def __post_init__(self) -> None:
        for name in ("rate", "clock_hz"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"{name}={value!r} must be positive and finite")
        if self.qos_depth < 1:
            raise ConfigError(f"qos_depth={self.qos_depth!r} must be at least 1")
        for name in ("wait_for_subscribers_s", "ack_timeout_s", "min_topic_interval_s"):
            value = getattr(self, name)
            # A NaN wait would never end.
            if not (math.isfinite(value) and value >= 0):
                raise ConfigError(f"{name}={value!r} must be a finite time >= 0 s")


@dataclass
class PlayReport:
    """What :func:`play_bag` published.

    Attributes:
        published: Messages published per topic.
        skipped_topics: Topic -> type, for topics without a message class here (their
            package not installed, or a ROS 1 type ROS 2 Jazzy lacks).
        invalid_names: Topic -> why ROS 2 refuses its name (a ROS 1 bag's ``/cam-0/image``),
            for topics skipped for it.
        absent_topics: Topics ``topics`` asked for that the bag does not hold.
        without_subscribers: Awaited topics that had no subscriber when playing started.
        unacknowledged: Times a wait for acknowledgements ran out (``ack_timeout_s``).
        wall_s: Wall time of the playback, s.
        bag_s: Bag time between the first and the last message played, s.
        damage: What the reader could not read, one line each (see
            :class:`~marker_localizer.bag.io.BagReader`).
    """

    published: dict[str, int] = field(default_factory=dict)
    skipped_topics: dict[str, str] = field(default_factory=dict)
    invalid_names: dict[str, str] = field(default_factory=dict)
    absent_topics: list[str] = field(default_factory=list)
    without_subscribers: list[str] = field(default_factory=list)
    unacknowledged: int = 0
    wall_s: float = 0.0
    bag_s: float = 0.0
    damage: list[str] = field(default_factory=list)


class Timekeeper(Protocol):
    """Where the player reads the time and waits: the ``time`` module itself by default."""

    def monotonic(self) -> float:
        """Seconds on a clock that never goes back."""
        ...

    def sleep(self, seconds: float, /) -> None:
        """Wait ``seconds``."""
        ...


class _Player:
    """Publishers for a bag's topics and the pacing between messages."""

    def __init__(
        self, node: Node, topics: dict[str, str], options: PlayOptions, timekeeper: Timekeeper
    ) -> None:
        self.node = node
        self.options = options
        self.time = timekeeper
        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=options.qos_depth,
            reliability=ReliabilityPolicy.RELIABLE,
        )
        self.publishers: dict[str, Publisher] = {}
        for topic, msgtype in topics.items():
            cls = message_class(msgtype)
            assert cls is not None  # filtered by the caller
            self.publishers[topic] = node.create_publisher(cls, topic, qos)
        self.clock = (
            node.create_publisher(Clock, CLOCK_TOPIC, _CLOCK_QOS) if options.clock else None
        )
        self._last_publish_s: dict[str, float] = {}
        #: The newest bag time published on /clock, ns.
        self._clock_ns: int | None = None

    def destroy(self) -> None:
        for publisher in self.publishers.values():
            self.node.destroy_publisher(publisher)
        if self.clock is not None:
            self.node.destroy_publisher(self.clock)

    def wait_for_subscribers(self, topics: Sequence[str]) -> list[str]:
        """Wait until each of ``topics`` has a subscriber; return those still without."""
        deadline = self.time.monotonic() + self.options.wait_for_subscribers_s
        missing = list(topics)
        while True:
            missing = [t for t in missing if self.publishers[t].get_subscription_count() == 0]
            if not missing or self.time.monotonic() >= deadline:
                return missing
            self.time.sleep(_POLL_S)

    def restart_clock(self) -> None:
        """Let /clock go back: a pass of ``loop`` begins the bag's times again."""
        self._clock_ns = None

    def publish_clock(self, time_ns: int) -> None:
        """Publish ``time_ns`` on /clock (if asked for), or the newest time published if later."""
        if self.clock is not None:
            self._clock_ns = time_ns if self._clock_ns is None else max(self._clock_ns, time_ns)
            self.clock.publish(Clock(clock=stamp_msg(self._clock_ns)))

    def due_s(self, time_ns: int, first_ns: int, start_s: float) -> float:
        """Monotonic time at which the message of bag time ``time_ns`` is due, s.

        Args:
            time_ns: The message's bag time, ns.
            first_ns: Bag time of the first message played, ns.
            start_s: Monotonic time it was published at, s.
        """
        return start_s + (time_ns - first_ns) / 1e9 / self.options.rate

    def sleep_until(self, due_ns: int, first_ns: int, start_s: float) -> None:
        """Sleep until the message of bag time ``due_ns`` is due, with /clock meanwhile if asked.

        Args:
            due_ns: Bag time of the next message, ns.
            first_ns: Bag time of the first message played, ns.
            start_s: Monotonic time it was published at, s.
        """
        due_s = self.due_s(due_ns, first_ns, start_s)
        period_s = 1.0 / self.options.clock_hz
        while (remaining := due_s - self.time.monotonic()) > 0:
            self.time.sleep(min(remaining, period_s) if self.clock is not None else remaining)
            if self.clock is not None:
                elapsed_s = self.time.monotonic() - start_s
                # The offset in integer ns: the bag time itself is no float's.
                bag_ns = first_ns + round(elapsed_s * self.options.rate * 1e9)
                self.publish_clock(min(bag_ns, due_ns))

    def pace(self, topic: str) -> bool:
        """Hold the next message on ``topic`` until the consumer can have taken the last one.

        Waits until the previous message on ``topic`` was acknowledged by every
        matched subscription and at least ``min_topic_interval_s`` passed since
        it was published: an acknowledgement only means the sample reached the
        subscriber's history, and a keep-last-1 history loses it if the next
        one arrives before the subscriber's executor took it.

        Returns:
            False if the acknowledgement timed out.
        """
        publisher = self.publishers[topic]
        previous = self._last_publish_s.get(topic)
        if previous is None:
            return True
        acked = publisher.get_subscription_count() == 0 or self.acknowledged(publisher)
        remaining = previous + self.options.min_topic_interval_s - self.time.monotonic()
        if remaining > 0:
            self.time.sleep(remaining)
        return acked

    def publish(self, topic: str, raw: bytes) -> None:
        self.publishers[topic].publish(raw)
        self._last_publish_s[topic] = self.time.monotonic()

    def acknowledged(self, publisher: Publisher) -> bool:
        """Wait until every matched subscription acknowledged ``publisher``'s messages.

        Waits up to ``ack_timeout_s`` in all, in calls of at most :data:`_ACK_SLICE_S`.

        Returns:
            False if the wait ran out.
        """
        slices = max(1, math.ceil(self.options.ack_timeout_s / _ACK_SLICE_S))
        each = Duration(seconds=self.options.ack_timeout_s / slices)
        return any(publisher.wait_for_all_acked(each) for _ in range(slices))

    def flush(self) -> int:
        """Wait until every publisher's messages were acknowledged; return those that were not."""
        return sum(
            1
            for publisher in self.publishers.values()
            if publisher.get_subscription_count() and not self.acknowledged(publisher)
        )


def play_bag(
    bag: str | Path,
    node: Node,
    options: PlayOptions | None = None,
    *,
    progress: Callable[[int, int], None] | None = None,
    timekeeper: Timekeeper = time,
) -> PlayReport:
    """Publish the messages of ``bag`` on their topics through ``node``.

    Args:
        bag: The bag (directory, ``.mcap`` or ``.db3``).
        node: An rclpy node to create the publishers on; they are destroyed
            before returning. The node does not need spinning.
        options: Timing, clock and topic selection.
        progress: Called with (messages published, messages to publish).
        timekeeper: the clock the pacing reads and sleeps on (tests record the
            waits it asks for).

    Returns:
        Counts per topic and what was skipped.

    Raises:
        BagError: the bag is missing, corrupt or truncated, or has no topic
            left to play (after ``options.topics`` and the installed packages).
    """
    options = options or PlayOptions()
    report = PlayReport()
    with BagReader(bag) as reader:
        selected = {
            topic: msgtype
            for topic, msgtype in reader.topics.items()
            if (options.topics is None or topic in options.topics)
            and not (options.clock and topic == CLOCK_TOPIC)
        }
        report.absent_topics = sorted(set(options.topics or ()) - set(reader.topics))
        report.skipped_topics = {t: m for t, m in selected.items() if message_class(m) is None}
        report.invalid_names = {
            t: why for t in selected if (why := topic_name_problem(t)) is not None
        }
        playable = {
            t: m
            for t, m in selected.items()
            if t not in report.skipped_topics and t not in report.invalid_names
        }
        if not playable:
            raise BagError(
                f"{bag}: nothing to play (topics: {', '.join(sorted(reader.topics)) or 'none'}; "
                f"asked for: {', '.join(options.topics or ()) or 'all'}; "
                f"no message class: {missing_messages_text(report.skipped_topics) or 'none'}; "
                f"not valid ROS 2 names: {', '.join(report.invalid_names) or 'none'})"
            )
        counts = reader.message_counts
        total = sum(counts.get(t, 0) for t in playable)
        if not total:
            raise BagError(
                f"{bag}: nothing to play: no message on {shorten(', '.join(sorted(playable)))}"
            )
        player = _Player(node, playable, options, timekeeper)
        try:
            # Topics that hold a message: a camera_info beside an empty image topic
            # needs no wait for the image's subscriber, nor a line about it.
            holding = {t: m for t, m in playable.items() if counts.get(t, 0)}
            awaited = [t for t, m in holding.items() if m in IMAGE_TYPES] or list(holding)
            report.without_subscribers = player.wait_for_subscribers(awaited)
            _play(reader, player, playable, awaited, report, progress, total)
        finally:
            player.destroy()
        report.damage = list(reader.damage)
    return report


def _play(
    reader: BagReader,
    player: _Player,
    topics: dict[str, str],
    awaited: Sequence[str],
    report: PlayReport,
    progress: Callable[[int, int], None] | None,
    total: int,
) -> None:
    start_s, first_ns, last_ns = _play_pass(reader, player, topics, report, progress, total)
    # A bag whose pass yielded nothing (damaged past reading) has nothing to play again.
    while player.options.loop and first_ns is not None:
        # The last pass's last frames taken before the next pass's first follow them:
        # at once, a keep-last-1 subscriber (the node's images) lost them on every pass,
        # uncounted. The awaited topics only: a camera_info's acknowledgement can wait
        # for the writer's heartbeat, 2.4 s here, on every pass.
        report.unacknowledged += sum(not player.pace(topic) for topic in awaited)
        player.restart_clock()
        _play_pass(reader, player, topics, report, progress, total)
    # Publishers are destroyed next: let the last messages reach their subscribers.
    report.unacknowledged += player.flush()
    report.wall_s = player.time.monotonic() - start_s
    report.bag_s = (last_ns - first_ns) / 1e9 if first_ns is not None else 0.0


def _play_pass(
    reader: BagReader,
    player: _Player,
    topics: dict[str, str],
    report: PlayReport,
    progress: Callable[[int, int], None] | None,
    total: int,
) -> tuple[float, int | None, int]:
    """Publish the bag's messages once.

    Returns:
        When the pass started (monotonic, s), its first and last bag time (ns; None
        for the first where the reader yielded no message).
    """
    options = player.options
    start_s = player.time.monotonic()
    first_ns: int | None = None
    last_ns = 0
    for done, message in enumerate(reader.messages(topics), start=1):
        if first_ns is None:
            # The schedule starts when the first message is in hand, not before its read.
            start_s = player.time.monotonic()
            first_ns = message.time_ns
            player.publish_clock(first_ns)
        if not options.as_fast_as_possible:
            player.sleep_until(message.time_ns, first_ns, start_s)
        elif not player.pace(message.topic):
            report.unacknowledged += 1
        player.publish_clock(message.time_ns)
        player.publish(message.topic, message.raw)
        report.published[message.topic] = report.published.get(message.topic, 0) + 1
        last_ns = max(last_ns, message.time_ns)
        if progress is not None:
            progress(done, total)
    return start_s, first_ns, last_ns
