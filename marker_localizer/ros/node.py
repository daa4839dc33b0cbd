"""The ROS 2 node: per-camera subscriptions feeding a :class:`FrameProcessor`, points out.

Topics, relative to the node's namespace and remappable as usual:

* in ``<cam>/image_raw`` (sensor_msgs/Image: one of
  :data:`~marker_localizer.ros.conversions.ENCODINGS`: YUV read as its luma, a raw
  Bayer mosaic as grey), or with ``image_transport`` = ``compressed``,
  ``<cam>/image_raw/compressed`` (sensor_msgs/CompressedImage, JPEG or PNG), which
  a remap of ``<cam>/image_raw`` moves with it, as image_transport names it. QoS
  reliable, keep-last 1. Measured on this stack (two processes, default Fast
  DDS): a best-effort subscription receives none of the 1.2 MB or 12 MB images a
  reliable publisher sends, while reliable keep-last 1 receives them, with frames
  the node has no time for replaced by newer ones. Switch to best effort through
  the parameter ``qos_overrides./<cam>/image_raw.subscription.reliability`` if your
  driver publishes best effort.
* in ``<cam>/camera_info`` (sensor_msgs/CameraInfo), cached and reported in
  the diagnostics when published, a WARN where it describes images of another
  size than the camera's frames; best effort, so that reliable and best-effort
  publishers alike match (its QoS overrides take durability too, for a driver that
  latches it).
* out ``<cam>/marker_points`` (sensor_msgs/PointCloud2, layout in
  :mod:`marker_localizer.ros.conversions`): one per processed frame, with the
  input image's header unchanged, empty when no marker was found.
* out ``<cam>/marker_overlay`` (sensor_msgs/Image, bgr8) when ``publish_overlay``.
* out ``/diagnostics`` (diagnostic_msgs/DiagnosticArray) every
  ``diagnostics_period_s``; a camera's status, named and identified by the camera,
  gives the topic its frames are read from, remaps applied (``image topic``).

Executor callbacks never block: an image callback only puts the frame into the
camera's mailbox; worker threads do the rest.
"""

from __future__ import annotations

import argparse
import copy
import sys
import threading
import time
import traceback
from collections.abc import Mapping, Sequence
from functools import partial
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import SingleThreadedExecutor
from rclpy.expand_topic_name import expand_topic_name
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSPolicyKind, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2

from marker_localizer.blas import single_thread_blas
from marker_localizer.config import NODE_NAME, DetectorConfig, TrackerConfig
from marker_localizer.errors import ConfigError, MarkerLocalizerError, WorkerError, shorten
from marker_localizer.node import PROG
from marker_localizer.ros import diagnostics
from marker_localizer.ros.conversions import (
    CAMERA_INFO_SUFFIX,
    IMAGE_TRANSPORTS,
    OVERLAY_SUFFIX,
    POINTS_SUFFIX,
    camera_info_image_size,
    topic_name_problem,
)
from marker_localizer.ros.parameters import (
    LiveParameters,
    NodeConfig,
    changed_fields,
    diagnostic_thresholds,
    own_arguments,
)
from marker_localizer.ros.processing import FrameProcessor
from marker_localizer.stopping import Interrupted, on_stop_signal, run_interruptible

#: Per camera, at most one log line about failing frames, and one about dropped
#: frames, in this many seconds: a camera sending bad frames at 10 Hz must not
#: flood the log, and the diagnostics carry the counts and the last error anyway.
_CAMERA_LOG_PERIOD_S = 5.0
#: How often the main loop looks at the stop flag set by SIGINT/SIGTERM, s.
_SPIN_PERIOD_S = 0.1
#: The ROS options that take a value: what follows them is not an option
#: (:func:`logger_name`).
_ROS_OPTIONS_WITH_VALUE = frozenset(
    {"-p", "--param", "--params-file", "-r", "--remap", "-e", "--enclave", "--log-level"}
    | {"--log-file-name", "--log-config-file"}
)
#: The remap rules' names for the node's name and namespace, as rcl's lexer reads them.
_NAME_KEYS, _NAMESPACE_KEY = ("__node", "__name"), "__ns"

_IMAGE_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE
)
#: Best effort takes camera_info from reliable publishers and from the drivers that
#: publish it best effort beside best-effort images (a reliable subscription matches
#: none of those): it is only cached, and the next one comes with the next frame.
_CAMERA_INFO_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.BEST_EFFORT
)
#: What a camera_info subscription's QoS overrides may set: with durability too, as a
#: driver that publishes camera_info once, latched (reliable, transient local), is
#: heard only by a subscription asking the same, which matches no other publisher.
_CAMERA_INFO_OVERRIDABLE = QoSOverridingOptions(
    policy_kinds=(
        QoSPolicyKind.HISTORY,
        QoSPolicyKind.DEPTH,
        QoSPolicyKind.RELIABILITY,
        QoSPolicyKind.DURABILITY,
    )
)
#: Results: keep a few so that a slow consumer does not lose points.
_OUTPUT_DEPTH = 10


class MarkerLocalizerNode(Node):
    """Detect diagonal markers in the images of several cameras and publish their centres.

    Args:
        node_name: name of the node (the parameter file's top-level key).
        processor_class: the worker pool to feed; a subclass of
            :class:`FrameProcessor` can stand in for the detector (tests).
        **kwargs: passed to :class:`rclpy.node.Node` (namespace, context,
            parameter_overrides, cli_args, ...).

    Raises:
        ConfigError: a parameter's start value is invalid.
    """

    def __init__(
        self,
        node_name: str = NODE_NAME,
        *,
        processor_class: type[FrameProcessor] = FrameProcessor,
        **kwargs: Any,
    ) -> None:
        try:
            super().__init__(node_name, **kwargs)
        except (InvalidParameterTypeException, InvalidParameterValueException) as err:
            # A start value of a parameter rclpy declares itself (use_sim_time:=1).
            raise ConfigError(str(err)) from err
        self._live = LiveParameters(self, self._on_parameters)
        settings = self._live.node_config
        suffix = IMAGE_TRANSPORTS[settings.image_transport][0]
        self._check_topic_names(
            settings.cameras, (POINTS_SUFFIX, OVERLAY_SUFFIX, suffix, CAMERA_INFO_SUFFIX)
        )
        self._thresholds = diagnostic_thresholds(settings)
        self._camera_info: dict[str, CameraInfo] = {}
        self._image_topics: dict[str, str] = {}
        self._last_failure_log: dict[str, float] = {}
        # Per camera: when drops were last logged, and the drop counts logged then.
        self._last_drop_log: dict[str, tuple[float, tuple[int, int]]] = {}
        self._points = {
            c: self.create_publisher(PointCloud2, f"{c}/{POINTS_SUFFIX}", _OUTPUT_DEPTH)
            for c in settings.cameras
        }
        self._overlays = {
            c: self.create_publisher(Image, f"{c}/{OVERLAY_SUFFIX}", _OUTPUT_DEPTH)
            for c in settings.cameras
        }
        inputs = {c: self._input_topics(c, suffix) for c in settings.cameras}
        self.processor = processor_class(
            settings.cameras,
            self._live.detector_config,
            self._deliver_points,
            workers=settings.workers,
            worker_processes=settings.worker_processes,
            max_frame_age_s=settings.max_frame_age_s,
            clock_ns=lambda: self.get_clock().now().nanoseconds,
            publish_overlay=settings.publish_overlay,
            on_overlay=self._deliver_overlay,
            on_error=self._frame_failed,
            stats_window_s=settings.stats_window_s,
            tracker_config=self._live.tracker_config,
        )
        try:
            self._start_serving(settings, inputs)
        except BaseException:  # rclpy refused, or Ctrl-C while starting: end the workers
            self.processor.shutdown(0.0)
            raise

    def _start_serving(self, settings: NodeConfig, inputs: Mapping[str, tuple[str, str]]) -> None:
        """Subscribe each camera's inputs, start the diagnostics, say what is served."""
        suffix, image_type = IMAGE_TRANSPORTS[settings.image_transport]
        for camera, (image_topic, info_topic) in inputs.items():
            subscription = self.create_subscription(
                image_type,
                image_topic,
                partial(self._on_image, camera),
                # A copy: rclpy writes a camera's QoS overrides into the profile it is given.
                copy.copy(_IMAGE_QOS),
                qos_overriding_options=QoSOverridingOptions.with_default_policies(),
            )
            # As rcl resolved it, remaps applied: the status names the topic the frames
            # come from, which the camera's name (its hardware_id) does not tell.
            self._image_topics[camera] = subscription.topic_name
            self.create_subscription(
                CameraInfo,
                info_topic,
                partial(self._on_camera_info, camera),
                copy.copy(_CAMERA_INFO_QOS),
                qos_overriding_options=_CAMERA_INFO_OVERRIDABLE,
            )
        self._diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", _OUTPUT_DEPTH)
        # On the steady clock: with use_sim_time and no /clock yet (a bag not playing),
        # a timer on the node's clock would never fire, and nothing would say why.
        self.create_timer(
            settings.diagnostics_period_s,
            self.publish_diagnostics,
            clock=Clock(clock_type=ClockType.STEADY_TIME),
        )
        # Declared by now, QoS overrides included: what is left is a typo or another node's.
        unknown = self._live.unknown(self)
        if unknown:
            self.get_logger().warning(f"ignoring unknown parameter(s): {', '.join(unknown)}")
        for camera, topics in inputs.items():
            read = [self.resolve_topic_name(topic) for topic in topics]
            unmapped = [
                self.resolve_topic_name(f"{camera}/{name}", only_expand=True)
                for name in (suffix, CAMERA_INFO_SUFFIX)
            ]
            if read != unmapped:
                self.get_logger().info(f"{camera}: reading {' and '.join(read)} (remapped)")
        kind = ("process", "processes") if settings.worker_processes else ("thread", "threads")
        self.get_logger().info(
            f"serving cameras {', '.join(settings.cameras)} with {settings.workers} worker "
            f"{kind[settings.workers != 1]}"
        )

    def publish_diagnostics(self) -> None:
        """Publish one DiagnosticArray: a status per camera and one for the node."""
        snapshots = self.processor.snapshots()
        self._log_drops(snapshots)
        self._diagnostics.publish(
            self.processor.diagnostics(
                self.get_name(),
                self.get_clock().now().to_msg(),
                self._thresholds,
                snapshots=snapshots,
                camera_values={
                    c: {"image topic": self._image_topics[c], "camera_info": self._info_text(c)}
                    for c in snapshots
                },
                camera_info_sizes={
                    c: camera_info_image_size(info) for c, info in self._camera_info.items()
                },
                namespace=self.get_namespace(),
            )
        )

    def _log_drops(self, snapshots: Mapping[str, diagnostics.CameraSnapshot]) -> None:
        """Log each camera's dropped frames with their reasons, throttled per camera."""
        now = time.monotonic()
        for camera, snapshot in snapshots.items():
            logged_at, reported = self._last_drop_log.get(camera, (-_CAMERA_LOG_PERIOD_S, (0, 0)))
            if now - logged_at < _CAMERA_LOG_PERIOD_S:
                continue
            line = diagnostics.drop_report(snapshot, reported, self.processor.max_frame_age_s)
            if line is None:
                continue
            self._last_drop_log[camera] = (now, (snapshot.dropped_mailbox, snapshot.dropped_age))
            # Replacing frames the workers have no time for is by design; stale ones are not.
            # (Two call sites: rclpy refuses a severity change at one.)
            if snapshot.dropped_age > reported[1]:
                self.get_logger().warning(line)
            else:
                self.get_logger().info(line)

    def destroy_node(self) -> None:
        """Drain the worker pool (frames in flight are published), then destroy the node.

        The frames still waiting for a worker are not processed; a line names their cameras.

        The drain waits at most ``shutdown_timeout_s`` and says for which cameras;
        after the processor was told to abandon its frames (the second signal), not
        at all, and silently: the line that names the signal says it. Where the ROS
        context is shut down already (rclpy's own Ctrl-C handling, in a program that
        spins the node itself), the frames in flight are abandoned, in one line.
        """
        timeout_s = self._live.node_config.shutdown_timeout_s
        in_flight = self.processor.in_flight()
        if in_flight and not self.context.ok():
            # rclpy's own Ctrl-C handling shut the context down first (spin, then
            # destroy_node, in a program of the user's): nothing can be published.
            self.processor.abandon()
            self.get_logger().info(
                "stopping: the ROS context is shut down, the frames in flight cannot be "
                f"published and are abandoned ({', '.join(in_flight)})"
            )
        elif in_flight:
            self.get_logger().info(
                f"stopping: waiting up to {timeout_s:g} s for the frames in flight "
                f"({', '.join(in_flight)})"
            )
        if not self.processor.shutdown(timeout_s) and not self.processor.abandoned:
            self.get_logger().warning(
                f"stopping: frames still in flight after {timeout_s:g} s were abandoned "
                f"({', '.join(self.processor.in_flight())})"
            )
        if self.processor.discarded:
            self.get_logger().info(
                "stopping: the frames waiting for a worker were not processed "
                f"({', '.join(self.processor.discarded)})"
            )
        super().destroy_node()

    def _on_image(self, camera: str, msg: Image | CompressedImage) -> None:
        self.processor.submit(camera, msg)

    def _on_camera_info(self, camera: str, msg: CameraInfo) -> None:
        self._camera_info[camera] = msg

    def _info_text(self, camera: str) -> str:
        info = self._camera_info.get(camera)
        return "none received" if info is None else f"{info.width}x{info.height}"

    def _check_topic_names(self, cameras: Sequence[str], suffixes: Sequence[str]) -> None:
        """ConfigError naming a camera whose topics ROS refuses under this node's namespace.

        The camera names' own rule holds (:class:`NodeConfig`); what it cannot know is
        the namespace, under which a long name makes a topic name longer than ROS takes.
        Checked before the workers start, which a refusal later would leave behind.
        """
        for camera in cameras:
            for suffix in suffixes:
                name = f"{camera}/{suffix}"
                reason = topic_name_problem(
                    expand_topic_name(name, self.get_name(), self.get_namespace())
                )
                if reason is not None:
                    raise ConfigError(f"camera {shorten(repr(camera))}: {reason}")

    def _input_topics(self, camera: str, suffix: str) -> tuple[str, str]:
        """The topics of ``camera``'s frames and camera_info, named as image_transport names them.

        The frames: ``<cam>/image_raw``, or a transport's topic under it
        (``<cam>/image_raw/compressed``), so that remapping ``<cam>/image_raw``
        moves the compressed topic with it; a remap of the compressed topic's own
        name still applies over that. The camera_info: the sibling of the (remapped)
        raw topic, ``camera_info`` in its namespace, as image_transport's camera
        subscriber (and so image_pipeline's nodes) reads it (``-r
        cam0/image_raw:=/front/image`` reads ``/front/camera_info``), unless
        ``<cam>/camera_info`` is remapped itself: that remap wins.

        Raises:
            ConfigError: the camera_info topic made so is one ROS refuses.
        """
        raw = IMAGE_TRANSPORTS["raw"][0]
        raw_topic = self.resolve_topic_name(f"{camera}/{raw}")
        image_topic = f"{camera}/{raw}" if suffix == raw else raw_topic + suffix.removeprefix(raw)
        info_topic = f"{camera}/{CAMERA_INFO_SUFFIX}"
        if self.resolve_topic_name(info_topic) == self.resolve_topic_name(
            info_topic, only_expand=True
        ):
            info_topic = f"{raw_topic.rpartition('/')[0]}/{CAMERA_INFO_SUFFIX}"
            reason = topic_name_problem(info_topic)
            if reason is not None:
                raise ConfigError(f"camera {shorten(repr(camera))}: {info_topic}: {reason}")
        return image_topic, info_topic

    def _deliver_points(self, camera: str, cloud: PointCloud2) -> None:
        self._points[camera].publish(cloud)

    def _deliver_overlay(self, camera: str, overlay: Image) -> None:
        self._overlays[camera].publish(overlay)

    def _frame_failed(self, camera: str, err: Exception) -> None:
        now = time.monotonic()
        if now - self._last_failure_log.get(camera, -_CAMERA_LOG_PERIOD_S) < (_CAMERA_LOG_PERIOD_S):
            return
        self._last_failure_log[camera] = now
        if isinstance(err, WorkerError):
            self.get_logger().error(f"{camera}: frame failed: {err}")
        elif isinstance(err, MarkerLocalizerError):
            self.get_logger().warning(f"{camera}: frame rejected: {err}")
        else:  # a bug: keep the traceback
            text = "".join(traceback.format_exception(err)).rstrip()
            self.get_logger().error(f"{camera}: frame failed:\n{text}")

    def _on_parameters(
        self, settings: NodeConfig, config: DetectorConfig, tracking: TrackerConfig
    ) -> None:
        self.processor.max_frame_age_s = settings.max_frame_age_s
        self._thresholds = diagnostic_thresholds(settings)
        changes = changed_fields(self.processor.config, config)
        tracker_changes = changed_fields(self.processor.tracker_config, tracking)
        # One swap: no frame is taken with part of an atomic change.
        self.processor.reconfigure(
            config if changes else None,
            tracking if tracker_changes else None,
            settings.publish_overlay,
        )
        for what, changed in (("detector", changes), ("tracker", tracker_changes)):
            if changed:
                listed = ", ".join(f"{k}={v!r}" for k, v in changed.items())
                self.get_logger().info(f"{what} reconfigured for the next frames: {listed}")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the node until SIGINT or SIGTERM.

    The first signal while it serves stops it cleanly (the frames in flight are
    published, at most ``shutdown_timeout_s`` waited for) with status 0, as a ROS
    node that was asked to stop; a signal before it serves (while rclpy starts,
    the workers start) or a second one during the drain interrupts it: one line
    naming the signal, the frames in flight abandoned, status 128 + its number
    (:mod:`marker_localizer.stopping`).

    Args:
        argv: command-line arguments after the program name (default:
            ``sys.argv[1:]``); ROS arguments follow ``--ros-args`` as for any
            node (``-p name:=value``, ``--params-file FILE``, ``-r from:=to``).

    Returns:
        Exit status: 0 after a clean shutdown, 1 on invalid configuration, 130 or
        143 when interrupted.
    """
    return run_interruptible(PROG, lambda: _start(argv))


def logger_name(args: Sequence[str], node_name: str = NODE_NAME) -> str:
    """The name of the logger rclpy gives the node ``node_name`` started with ``args``.

    The fatal lines of a start that is refused (a params file, a start value) come
    before the node exists, and rclpy names no logger before: they carry this one,
    as the node's own lines do (``uav1.front`` under ``-r __ns:=/uav1 -r
    __node:=front``). As rcl reads the remap rules after ``--ros-args`` (up to
    ``--``), and the rules outside it that it still applies with a deprecation
    warning: the first that renames the node (``__node:=`` or ``__name:=``, for
    every node or prefixed with its name, ``marker_localizer:__node:=``) names it,
    the first that moves it (``__ns:=``) puts it in a namespace, whose parts
    precede the name, joined by dots.

    Args:
        args: the program's arguments, ROS arguments included.
        node_name: the node's name before the rules.
    """
    name, namespace = node_name, "/"
    renamed = moved = in_ros_args = False
    words = iter(args)
    for word in words:
        if word in ("--ros-args", "--"):
            in_ros_args = word == "--ros-args"
            continue
        if in_ros_args:
            if word not in _ROS_OPTIONS_WITH_VALUE:
                continue
            rule = next(words, "")
            if word not in ("-r", "--remap"):
                continue
        else:
            rule = word  # a rule outside --ros-args: deprecated, which rcl still applies
        target, is_rule, replacement = rule.partition(":=")
        prefix, _, key = target.rpartition(":")
        if not is_rule or prefix not in ("", node_name):
            continue
        if key in _NAME_KEYS and not renamed:
            name, renamed = replacement, True
        elif key == _NAMESPACE_KEY and not moved:
            namespace, moved = replacement, True
    return ".".join([*filter(None, namespace.split("/")), name])


def _start(argv: Sequence[str] | None) -> int:
    """Parse the arguments, start rclpy and serve (:func:`main`)."""
    args = [sys.argv[0] if sys.argv else NODE_NAME, *(sys.argv[1:] if argv is None else argv)]
    # The node's logger, for the lines before the node exists.
    logger = rclpy.logging.get_logger(logger_name(args))
    try:
        own_args = own_arguments(args)
    except ConfigError as err:
        logger.fatal(str(err))
        return 1
    argparse.ArgumentParser(
        prog=PROG,
        description="ROS 2 node localising diagonal ground markers; configure it with "
        "--ros-args -p name:=value or --params-file config/marker_localizer.yaml.",
    ).parse_args(own_args)
    # The process is the node's: with worker threads (worker_processes:=false) the
    # detector runs here, and BLAS's threads would spin beside its small products.
    single_thread_blas()
    # rclpy's own handlers would shut the context down before the pool drains;
    # ours only set a flag, so frames in flight are still published.
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    try:
        try:
            node = MarkerLocalizerNode()
        except MarkerLocalizerError as err:
            logger.fatal(f"invalid configuration: {err}")
            return 1
        stop = threading.Event()
        again: list[int] = []

        def stop_at_once(signum: int) -> None:
            # Flags only, no exception: wherever the drain is when it comes, it ends
            # as at its timeout, worker processes killed and shared memory unlinked.
            again.append(signum)
            node.processor.abandon()

        with on_stop_signal(lambda _: stop.set(), again=stop_at_once):
            _run(node, stop)
        if again:
            raise Interrupted(again[0])
        node.get_logger().info("stopped")
        return 0
    finally:
        rclpy.try_shutdown()


def _run(node: MarkerLocalizerNode, stop: threading.Event) -> None:
    """Serve until ``stop`` is set, then drain and destroy the node."""
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        while not stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=_SPIN_PERIOD_S)
    finally:
        executor.remove_node(node)
        node.destroy_node()


if __name__ == "__main__":
    sys.exit(main())
