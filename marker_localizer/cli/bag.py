"""``marker-localizer simulate|replay|play``: the bag commands' arguments and summaries.

The work is the library's (:mod:`marker_localizer.bag`); each command here
parses its arguments, shows a progress bar, prints the summary and returns its
exit status: :data:`~marker_localizer.cli.exits.EXIT_INCOMPLETE` when ``replay``
or ``play`` skipped or could not read part of the bag. Errors and signals are
mapped by :func:`~marker_localizer.cli.exits.run_command`.
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Sequence
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.signals import SignalHandlerOptions

from marker_localizer.bag.io import DEFAULT_STORAGE, STORAGES, BagReader, missing_messages_text
from marker_localizer.bag.play import NODE_NAME as PLAYER_NODE_NAME
from marker_localizer.bag.play import PlayOptions, PlayReport, play_bag
from marker_localizer.bag.record import record_flight
from marker_localizer.bag.replay import format_report, replay_bag
from marker_localizer.blas import single_thread_blas
from marker_localizer.cli.arguments import count_type, seed_type
from marker_localizer.cli.exits import EXIT_INCOMPLETE, PROG
from marker_localizer.cli.progress import ProgressBar
from marker_localizer.config import DetectorConfig, detector_config, tracker_config
from marker_localizer.core.image import BAYER_PATTERNS
from marker_localizer.errors import ConfigError
from marker_localizer.evaluation import DEFAULT_GATE_PX
from marker_localizer.ros.parameters import NodeConfig, own_arguments
from marker_localizer.synthetic.flight import FlightConfig, FlightSimulator

#: What ``replay`` and ``play`` read (:class:`~marker_localizer.bag.io.BagReader`).
BAG_HELP = "the bag: a rosbag2 (its directory, or a bare .mcap or .db3) or a ROS 1 .bag"
#: What ``simulate`` and ``replay`` write (:class:`~marker_localizer.bag.io.BagWriter`).
OUT_HELP = "the bag directory to create, as ros2 bag record -o makes (no .mcap, .db3 or .bag)"

# --------------------------------------------------------------------------- simulate


def build_simulate_parser() -> argparse.ArgumentParser:
    """Arguments of ``marker-localizer simulate``."""
    parser = argparse.ArgumentParser(
        allow_abbrev=False,
        prog=f"{PROG} simulate",
        description="Fly the five-camera UAV simulator over a marked ground and record a "
        "rosbag2 with images, camera_info, /tf_static and the exact marker truth.",
    )
    defaults = FlightConfig()
    parser.add_argument("--out", required=True, type=Path, help=OUT_HELP)
    parser.add_argument(
        "--frames",
        type=count_type,
        default=defaults.n_frames,
        help="frame sets to record (default: %(default)s)",
    )
    parser.add_argument(
        "--width",
        type=count_type,
        default=defaults.width,
        help="image width, px (default: %(default)s)",
    )
    parser.add_argument(
        "--height",
        type=count_type,
        default=defaults.height,
        help="image height, px (default: %(default)s)",
    )
    parser.add_argument(
        "--cameras",
        type=int,
        default=defaults.n_cameras,
        help="cameras: nadir, forward, backward, left, right, in this order (default: %(default)s)",
    )
    parser.add_argument(
        "--seed",
        type=seed_type,
        default=0,
        help="seed of the world and the noise (default: %(default)s)",
    )
    parser.add_argument(
        "--storage",
        choices=tuple(STORAGES),
        default=DEFAULT_STORAGE,
        help="rosbag2 storage format (default: %(default)s)",
    )
    parser.add_argument(
        "--altitude",
        type=float,
        default=None,
        metavar="M",
        help="flying height, m (default: markers of "
        f"{defaults.nadir_marker_radius_px:g} px radius at nadir)",
    )
    parser.add_argument(
        "--marker-radius",
        type=float,
        default=defaults.marker_radius_m,
        metavar="M",
        help="marker radius, m (default: %(default)s)",
    )
    parser.add_argument(
        "--fps",
        type=float,
        default=defaults.frame_rate_hz,
        help="frame sets per second, Hz (default: %(default)s)",
    )
    parser.add_argument(
        "--speed",
        type=float,
        default=defaults.speed_mps,
        metavar="M/S",
        help="ground speed, m/s (default: %(default)s)",
    )
    parser.add_argument(
        "--tilt",
        type=float,
        default=defaults.tilt_deg,
        metavar="DEG",
        help="tilt of the oblique cameras, degrees (default: %(default)s)",
    )
    parser.add_argument(
        "--bayer",
        type=str.lower,
        choices=BAYER_PATTERNS,
        default=None,
        metavar="PATTERN",
        help="record each camera's raw Bayer mosaic (bayer_<PATTERN>8) instead of mono8: "
        f"one of {', '.join(BAYER_PATTERNS)}, in either case",
    )
    return parser


#: The ``simulate`` option that sets each :class:`FlightConfig` field it sets (the
#: option's argparse destination holds the value).
_SIMULATE_OPTIONS = {
    "width": "--width",
    "height": "--height",
    "n_frames": "--frames",
    "n_cameras": "--cameras",
    "frame_rate_hz": "--fps",
    "tilt_deg": "--tilt",
    "marker_radius_m": "--marker-radius",
    "altitude_m": "--altitude",
    "speed_mps": "--speed",
    "bayer_pattern": "--bayer",
}


def config_from_args(args: argparse.Namespace) -> FlightConfig:
    """The :class:`FlightConfig` a parsed ``simulate`` command line asks for.

    Raises:
        ConfigError: as :class:`FlightConfig` does, naming the options, not its fields
            (``--cameras 0 must be in [1, 5]``, not ``n_cameras=0``).
    """
    values = vars(args)
    try:
        return FlightConfig(
            **{
                field: values[option.removeprefix("--").replace("-", "_")]
                for field, option in _SIMULATE_OPTIONS.items()
            }
        )
    except ConfigError as err:
        text = str(err)
        for field, option in _SIMULATE_OPTIONS.items():
            text = re.sub(rf"\b{field}=", f"{option} ", text)
        raise ConfigError(text) from err


def simulate(argv: Sequence[str]) -> int:
    """Run ``marker-localizer simulate``; returns the exit status."""
    args = build_simulate_parser().parse_args(argv)
    config = config_from_args(args)
    simulator = FlightSimulator(config, seed=args.seed)
    with ProgressBar(config.n_frames, "simulate") as bar:
        summary = record_flight(simulator, args.out, storage=args.storage, progress=bar.update)
    sys.stdout.write(
        f"wrote {summary.path} ({args.storage}): {summary.frame_sets} x "
        f"{len(summary.cameras)} cameras at {config.width}x{config.height} px, "
        f"{summary.truth_markers} markers in the truth, {summary.messages} messages; "
        f"altitude {config.flight_altitude_m:.1f} m, focal length {config.focal_px:.1f} px\n"
    )
    smallest = DetectorConfig.marker_radius_min_px
    if config.marker_radius_at_nadir_px < smallest:
        sys.stderr.write(
            f"{PROG}: warning: markers are {config.marker_radius_at_nadir_px:.2g} px in radius "
            f"at nadir, under the detector's smallest radius by default ({smallest:g} px): "
            "replay finds them only with a smaller marker_radius_min_px\n"
        )
    return 0


# --------------------------------------------------------------------------- replay


def build_replay_parser() -> argparse.ArgumentParser:
    """Arguments of ``marker-localizer replay``."""
    parser = argparse.ArgumentParser(
        allow_abbrev=False,
        prog=f"{PROG} replay",
        description="Run every <cam>/image_raw frame of a bag (or <cam>/image_raw/compressed, "
        "where a camera has no raw frame) through the node's processing (no frame dropped) "
        "and write <cam>/marker_points and /diagnostics to a new bag; prints per-camera "
        "throughput and, when the bag has truth, accuracy.",
    )
    parser.add_argument("bag", type=Path, help=BAG_HELP)
    parser.add_argument("--out", required=True, type=Path, help=OUT_HELP)
    parser.add_argument(
        "--params-file",
        type=Path,
        default=None,
        help="the node's parameter YAML; its detector.* and tracker.* values are used",
    )
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a detector parameter over the file's (repeatable), as detect takes it, "
        "e.g. marker_radius_min_px=4",
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=NodeConfig().workers,
        help="workers (default: %(default)s, as the node)",
    )
    parser.add_argument(
        "--worker-threads",
        action="store_true",
        help="run the workers as threads of this process, not as processes of their own "
        "(the node's worker_processes:=false)",
    )
    parser.add_argument(
        "--storage",
        choices=tuple(STORAGES),
        default=DEFAULT_STORAGE,
        help="storage of the output bag (default: %(default)s)",
    )
    parser.add_argument(
        "--match-distance",
        type=float,
        default=DEFAULT_GATE_PX,
        metavar="PX",
        help="largest detection-to-truth distance of a match, px (default: %(default)s)",
    )
    return parser


def replay(argv: Sequence[str]) -> int:
    """Run ``marker-localizer replay``; 0, or EXIT_INCOMPLETE when a frame gave no result."""
    args = build_replay_parser().parse_args(argv)
    config = detector_config(args.params_file, args.param)
    tracking = tracker_config(args.params_file)
    # With --worker-threads the detector runs in this process (marker_localizer.blas).
    single_thread_blas()
    with ProgressBar(0, "replay") as bar:
        report = replay_bag(
            args.bag,
            args.out,
            config=config,
            tracker_config=tracking,
            workers=args.workers,
            worker_processes=not args.worker_threads,
            storage=args.storage,
            match_distance_px=args.match_distance,
            progress=bar.update,
        )
    sys.stdout.write(format_report(report) + "\n")
    return 0 if report.complete else EXIT_INCOMPLETE


# --------------------------------------------------------------------------- play


def build_play_parser() -> argparse.ArgumentParser:
    """Arguments of ``marker-localizer play``."""
    parser = argparse.ArgumentParser(
        allow_abbrev=False,
        prog=f"{PROG} play",
        description="Publish a rosbag2's messages on their ROS 2 topics, like 'ros2 bag play'. "
        "ROS arguments follow --ros-args.",
    )
    defaults = PlayOptions()
    parser.add_argument("bag", type=Path, help=BAG_HELP)
    timing = parser.add_mutually_exclusive_group()
    timing.add_argument(
        "--rate",
        type=float,
        default=defaults.rate,
        help="playback speed relative to the recording (default: %(default)s)",
    )
    timing.add_argument(
        "--as-fast-as-possible",
        action="store_true",
        help="publish each message once the previous one on its topic was "
        "acknowledged by every subscriber",
    )
    parser.add_argument(
        "--clock", action="store_true", help="publish the bag time on /clock (for use_sim_time)"
    )
    parser.add_argument(
        "--loop",
        action="store_true",
        help="play the bag again from its start after its last message, until Ctrl-C "
        "(as 'ros2 bag play --loop': recorded stamps, /clock back at the start)",
    )
    parser.add_argument(
        "--clock-hz",
        type=float,
        default=defaults.clock_hz,
        help="/clock rate between messages, Hz (default: %(default)s)",
    )
    parser.add_argument(
        "--topics", nargs="+", default=None, metavar="TOPIC", help="play only these topics"
    )
    parser.add_argument(
        "--wait-for-subscribers",
        type=float,
        default=defaults.wait_for_subscribers_s,
        metavar="S",
        help="longest wait for the image topics' subscribers, s (default: %(default)s)",
    )
    return parser


def play(argv: Sequence[str]) -> int:
    """Run ``marker-localizer play``; 0, or EXIT_INCOMPLETE when the bag is damaged.

    ROS arguments (``--ros-args ...``) go to rclpy, the rest to the parser.
    """
    ros_argv = [PLAYER_NODE_NAME, *argv]
    args = build_play_parser().parse_args(own_arguments(ros_argv))
    options = PlayOptions(
        rate=args.rate,
        as_fast_as_possible=args.as_fast_as_possible,
        clock=args.clock,
        loop=args.loop,
        clock_hz=args.clock_hz,
        topics=tuple(args.topics) if args.topics else None,
        wait_for_subscribers_s=args.wait_for_subscribers,
    )
    BagReader(args.bag)  # a missing or foreign path fails before DDS starts
    # Our own context: the player can run beside other rclpy users in one
    # process, and Ctrl-C stays a KeyboardInterrupt (rclpy's handler would
    # shut the context down under the publishers).
    context = Context()
    rclpy.init(args=ros_argv, context=context, signal_handler_options=SignalHandlerOptions.NO)
    try:
        with ProgressBar(0, "play") as bar:
            node = rclpy.create_node(PLAYER_NODE_NAME, context=context)
            try:
                report = play_bag(args.bag, node, options, progress=bar.update)
            finally:
                node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    sys.stdout.write(format_play_report(args.bag, report) + "\n")
    return EXIT_INCOMPLETE if report.damage else 0


def format_play_report(bag: Path, report: PlayReport) -> str:
    """The summary ``play`` prints: what was published, skipped and damaged."""
    total, topics = sum(report.published.values()), len(report.published)
    lines = [
        f"played {total} message{'s' * (total != 1)} on {topics} topic{'s' * (topics != 1)} "
        f"of {bag} in {report.wall_s:.2f} s (bag time {report.bag_s:.2f} s)"
    ]
    if report.skipped_topics:
        lines.append(f"skipped, no message class: {missing_messages_text(report.skipped_topics)}")
    lines += [
        f"skipped, not a valid ROS 2 topic name: {topic} ({why})"
        for topic, why in sorted(report.invalid_names.items())
    ]
    if report.absent_topics:
        lines.append(f"not in the bag: {', '.join(report.absent_topics)}")
    if report.without_subscribers:
        lines.append(f"no subscriber when playing started: {', '.join(report.without_subscribers)}")
    if report.unacknowledged:
        lines.append(f"{report.unacknowledged} messages not acknowledged in time")
    lines += [f"damaged storage: {line}" for line in report.damage]
    return "\n".join(lines)
