"""Throughput of the node: five cameras of rendered 12 MP frames over real DDS, 1 and 2 workers.

The workers are the node's default, processes (``worker_processes``), or with
``--worker-threads`` threads of the node's process.

``marker-localizer bench throughput`` (or ``python -m marker_localizer.bench.throughput``)
renders one ground frame per camera once, then for each worker count starts a
:class:`MarkerLocalizerNode` in this process and a camera process that
publishes the five cameras over DDS at ``--rate-hz`` each, faster than the node
can keep up with, for ``--seconds``. The cameras pan over their ground at
:data:`PAN_STEP_PX` per frame and turn back at the end of their ground, so
tracking mode (the node's default, ``tracker.enabled``) meets moving markers,
markers entering and leaving the view and changes of direction, as in flight.
The ground is the speed benchmark's clutter (radius 6-40 px), or with
``--ground flight`` the flight simulator's five cameras (give ``--radius-range
3 30``: its oblique views hold markers of 4 to 20 px).
The cameras run in their own process, as camera drivers do: the 12 MB
messages they build and serialise do not take this process's cores. With
``--compressed`` they publish ``<cam>/image_raw/compressed`` instead, JPEG of
:data:`JPEG_QUALITY` as image_transport's compressed plugin writes it by default,
encoded before the run (the node's ``image_transport`` is ``compressed``); of mono8,
or with ``--compressed bgr8`` of a colour camera (the ground in each channel).
This process takes one BLAS thread, as the node's ``main`` does for its own
(:mod:`marker_localizer.blas`): with ``--worker-threads`` the detector runs here.

Publishing stops, the frames already in the node are finished, and the run
reports:

* frames processed per second: results delivered / (time from the first
  publish to the last result). Every worker is busy from start to end, so this
  is the pool's capacity;
* the scaling ratio (2 workers over 1);
* dropped frames: replaced in a mailbox, too old, or never reaching the node
  (replaced in the keep-last-1 DDS queue). When publishing stops, the frames
  still waiting in the mailboxes grow old and are dropped by age (up to one
  per camera): the end of the feed, not a steady-state loss;
* latency p50/p95 from the header stamp to the result's arrival at a subscriber;
* the full-frame passes among the frames processed: with tracking, a frame is
  searched whole where a pass is scheduled or the tracker lost a marker, and
  frames a mailbox drops leave the tracker longer steps to follow;
* CPU use of the node's process with its worker processes and of the camera
  process (100 % = one core busy), the node's CPU time per frame processed, CPU
  used meanwhile by any other process on the machine (from /proc/stat), and the
  node process's peak resident memory (its worker processes' not included). On
  a shared machine the scaling ratio means little unless the other processes
  left the second core free.

``--json PATH`` saves these figures as well, as the other benchmarks save theirs.
"""

from __future__ import annotations

import argparse
import dataclasses
import multiprocessing
import os
import resource
import signal
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import cv2
import numpy as np
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import CompressedImage, Image, PointCloud2
from std_msgs.msg import Header

from marker_localizer.bench import speed
from marker_localizer.bench.runner import Report, add_json_option, run_and_save
from marker_localizer.blas import single_thread_blas
from marker_localizer.cli.arguments import count_type, positive_float
from marker_localizer.config import DetectorConfig, TrackerConfig
from marker_localizer.errors import ConfigError
from marker_localizer.ros.conversions import array_to_image
from marker_localizer.ros.diagnostics import frames_lost_upstream
from marker_localizer.ros.node import MarkerLocalizerNode
from marker_localizer.ros.processing import stamp_to_ns
from marker_localizer.synthetic import render_scene

CAMERAS = ("cam0", "cam1", "cam2", "cam3", "cam4")
#: Image motion of every camera per frame, px (x, y): a drone at 10 m/s and 10 Hz.
PAN_STEP_PX = (3, 2)
#: Frames a camera pans before it turns back (its ground is that much larger).
PAN_FRAMES = 32
#: Longest wait for the frames in flight after publishing stops, s.
_DRAIN_TIMEOUT_S = 120.0
#: Longest wait for the camera process to start publishing (imports, DDS discovery), s.
_CAMERA_START_TIMEOUT_S = 120.0
_NS_PER_S = 1_000_000_000
#: JPEG quality of ``--compressed``: image_transport's compressed plugin's default.
JPEG_QUALITY = 95
#: The cameras' encodings ``--compressed`` takes: a mono camera's, a colour camera's.
COMPRESSED_ENCODINGS = ("mono8", "bgr8")
#: The Fast DDS profile for 12 MP images the benchmark runs with (README, "Speed").
FASTDDS_PROFILE_NAME = "fastdds_large_images.xml"
_PROFILE_VARIABLE = "FASTRTPS_DEFAULT_PROFILES_FILE"


def fastdds_profile(module: Path = Path(__file__)) -> Path | None:
    """Where :data:`FASTDDS_PROFILE_NAME` is, for a checkout or an install; None: nowhere.

    ``config/`` beside the sources (a checkout, an editable install, colcon's
    ``--symlink-install``), else ``share/marker_localizer/config/`` under the
    install prefix, where ``setup.py``'s data files go (a wheel, colcon without
    ``--symlink-install``): the prefix holds ``lib/pythonX.Y/site-packages``.

    Args:
        module: this module's file, ``PACKAGE/bench/throughput.py``.
    """
    parents = module.resolve().parents
    places = [parents[2] / "config"]
    if len(parents) > 5:
        places.append(parents[5] / "share" / "marker_localizer" / "config")
    return next(
        (p / FASTDDS_PROFILE_NAME for p in places if (p / FASTDDS_PROFILE_NAME).is_file()), None
    )


@dataclass(frozen=True)
class RunResult:
    """Figures of one run with a given number of workers."""

    workers: int
    worker_processes: bool
    published: int
    received: int
    processed: int
    dropped_mailbox: int
    dropped_age: int
    #: What the node's diagnostics count as lost before the node, from stamp gaps.
    lost_by_stamps: int
    #: Frames processed per second of the stream the cameras offered (published frames
    #: at rate_hz each).
    frames_per_s: float
    latency_p50_ms: float
    latency_p95_ms: float
    #: Frames processed that the detector searched whole (the camera statistics' count).
    full_frame_passes: int
    cpu_percent: float
    #: CPU time of the node's process and its worker processes per frame processed, ms.
    cpu_ms_per_frame: float
    camera_cpu_percent: float
    others_cpu_percent: float
    peak_rss_mb: float

    @property
    def dropped_in_transport(self) -> int:
        """Frames published that never reached a mailbox (replaced in the DDS queue)."""
        return self.published - self.received


def render_grounds(width: int, height: int, directory: Path, markers: int = 24) -> Path:
    """Render each camera's ground once: the frame plus its pan.

    The grounds are the speed benchmark's cluttered scenes (24 markers of radius
    6-40 px, 400 hard negatives, strong light gradient, shadows), so the node's
    figures and the single-core figures describe the same frames.

    Args:
        width: width of the published frames, px.
        height: height of the published frames, px.
        directory: where to write the grounds.
        markers: markers per ground (fewer for small test frames).

    Returns:
        Path of a (cameras, H, W) uint8 ``.npy`` file, read by the camera process.
    """
    dx, dy = PAN_STEP_PX
    config = speed.cluttered_scene(width + PAN_FRAMES * dx, height + PAN_FRAMES * dy)
    # The hard negatives at the speed benchmark's density.
    area = config.width * config.height / (speed.FRAME_WIDTH * speed.FRAME_HEIGHT)
    config = dataclasses.replace(
        config, n_markers=markers, n_hard_negatives=round(config.n_hard_negatives * area)
    )
    path = Path(directory) / "grounds.npy"
    np.save(path, np.stack([render_scene(config, seed).image for seed in range(len(CAMERAS))]))
    return path


def render_flight_grounds(width: int, height: int, directory: Path, seed: int = 0) -> Path:
    """Each camera's ground from the flight simulator: its five cameras' view of one frame set.

    Rendered larger than the published frames by the pan, with the simulator's
    default rig (markers of 0.5 m: about 15 px at nadir, 4 to 20 px in the oblique
    views, as the frame size does not change the markers' size in pixels).

    Returns:
        Path of a (cameras, H, W) uint8 ``.npy`` file, read by the camera process.
    """
    from marker_localizer.synthetic.flight import FlightConfig, FlightSimulator  # noqa: PLC0415

    dx, dy = PAN_STEP_PX
    config = FlightConfig(
        width=width + PAN_FRAMES * dx,
        height=height + PAN_FRAMES * dy,
        n_frames=1,
        n_cameras=len(CAMERAS),
    )
    frame_set = FlightSimulator(config, seed=seed).render(0)
    path = Path(directory) / "grounds.npy"
    np.save(path, np.stack([camera.image for camera in frame_set.cameras]))
    return path


#: What ``--ground`` chooses: the speed benchmark's clutter, or the flight simulator's.
GROUNDS = {"cluttered": render_grounds, "flight": render_flight_grounds}


def pan_step(frame: int) -> int:
    """How many :data:`PAN_STEP_PX` steps frame ``frame`` lies along the pan (0..PAN_FRAMES)."""
    step = frame % (2 * PAN_FRAMES)
    return step if step <= PAN_FRAMES else 2 * PAN_FRAMES - step


def camera_view(ground: np.ndarray, frame: int) -> np.ndarray:
    """Frame ``frame`` of a camera panning over ``ground`` and turning back every PAN_FRAMES."""
    dx, dy = PAN_STEP_PX
    k = pan_step(frame)
    height = ground.shape[0] - PAN_FRAMES * dy
    width = ground.shape[1] - PAN_FRAMES * dx
    return ground[k * dy : k * dy + height, k * dx : k * dx + width]


def run_once(
    grounds: Path,
    workers: int,
    seconds: float,
    rate_hz: float,
    *,
    tracking: bool = True,
    radius_range: tuple[float, float] = speed.RADIUS_RANGE,
    worker_processes: bool = True,
    compressed: str | None = None,
) -> RunResult:
    """Start a node with ``workers`` workers, feed it from a camera process, finish, measure.

    Args:
        grounds: the cameras' grounds from :func:`render_grounds`.
        workers: the node's ``workers`` parameter.
        seconds: how long to publish, s.
        rate_hz: frames per second and camera.
        tracking: the node's ``tracker.enabled`` parameter.
        radius_range: the node's marker radius range, px.
        worker_processes: the node's ``worker_processes`` parameter.
        compressed: the cameras publish JPEG (:data:`JPEG_QUALITY`) of this encoding
            (:data:`COMPRESSED_ENCODINGS`) on ``<cam>/image_raw/compressed``, which
            the node subscribes; None: raw mono8 on ``<cam>/image_raw``.

    Returns:
        The run's figures.
    """
    namespace = f"/bench_w{workers}"
    node = MarkerLocalizerNode(
        f"bench_localizer_w{workers}",
        namespace=namespace,
        parameter_overrides=[
            Parameter("workers", value=workers),
            Parameter("worker_processes", value=worker_processes),
            Parameter("image_transport", value="raw" if compressed is None else "compressed"),
            Parameter("tracker.enabled", value=tracking),
            # The diagnostics' window over the whole run, to compare their loss count.
            Parameter("stats_window_s", value=min(seconds + _CAMERA_START_TIMEOUT_S, 3600.0)),
            # The marker sizes of the scenes, as a user configures them.
            Parameter("detector.marker_radius_min_px", value=float(radius_range[0])),
            Parameter("detector.marker_radius_max_px", value=float(radius_range[1])),
        ],
    )
    peer = Node("bench_results", namespace=namespace)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    executor.add_node(peer)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    arrivals: list[tuple[int, int]] = []  # (arrival ns, stamp ns) per result

    def on_points(cloud: PointCloud2) -> None:
        arrivals.append((time.time_ns(), stamp_to_ns(cloud.header)))

    for camera in CAMERAS:
        peer.create_subscription(PointCloud2, f"{camera}/marker_points", on_points, 50)
    # Spawned, not forked: the child starts its own rclpy context.
    context = multiprocessing.get_context("spawn")
    started, report = context.Event(), context.Queue()
    cameras = context.Process(
        target=_camera_process,
        args=(str(grounds), namespace, rate_hz, seconds, compressed, started, report),
        name="bench_cameras",
    )
    spinner.start()
    cameras.start()
    try:
        _wait(
            lambda: started.is_set() or not cameras.is_alive(),
            "the camera process",
            _CAMERA_START_TIMEOUT_S,
        )
        if not started.is_set():
            raise RuntimeError(f"the camera process exited with code {cameras.exitcode}")
        cpu_start = _node_cpu_s(cameras.pid)
        machine_start, start_ns = _machine_busy_s(), time.time_ns()
        published, camera_cpu_s = report.get(timeout=seconds + _CAMERA_START_TIMEOUT_S)
        cameras.join()
        if not node.processor.wait_idle(_DRAIN_TIMEOUT_S):
            raise RuntimeError(f"frames still in flight {_DRAIN_TIMEOUT_S:g} s after the end")
        _wait(lambda: len(arrivals) >= _processed(node), "the last results")
        cpu_s = _node_cpu_s(cameras.pid) - cpu_start
        machine_s = _machine_busy_s() - machine_start
        end_ns = max(a for a, _ in arrivals) if arrivals else time.time_ns()
    finally:
        if cameras.is_alive():
            cameras.terminate()
        executor.shutdown()
        spinner.join()
        node.destroy_node()
        peer.destroy_node()
    snaps = node.processor.snapshots().values()
    latency_ms = np.array([(a - s) / 1e6 for a, s in arrivals])
    span_s = (end_ns - start_ns) / _NS_PER_S
    return RunResult(
        workers=workers,
        worker_processes=worker_processes,
        published=published,
        received=sum(s.received for s in snaps),
        processed=len(arrivals),
        dropped_mailbox=sum(s.dropped_mailbox for s in snaps),
        dropped_age=sum(s.dropped_age for s in snaps),
        lost_by_stamps=sum(
            frames_lost_upstream(s.window_stamps_ns, s.window_arrivals_ns)[0] for s in snaps
        ),
        # Per second of the stream the cameras offered (their ticks at rate_hz): divided
        # by the span to the last result, a run's ends made it read above the offered
        # rate (20.35 of 20 in 4 s; about 0.1 more in 30 s, before 2026-12-02).
        frames_per_s=len(arrivals) * rate_hz * len(CAMERAS) / max(published, 1),
        latency_p50_ms=float(np.percentile(latency_ms, 50)) if arrivals else float("nan"),
        latency_p95_ms=float(np.percentile(latency_ms, 95)) if arrivals else float("nan"),
        full_frame_passes=sum(s.full_frame_passes for s in snaps),
        cpu_percent=100.0 * cpu_s / span_s,
        cpu_ms_per_frame=1000.0 * cpu_s / len(arrivals) if arrivals else float("nan"),
        camera_cpu_percent=100.0 * camera_cpu_s / span_s,
        others_cpu_percent=100.0 * max(machine_s - cpu_s - camera_cpu_s, 0.0) / span_s,
        # ru_maxrss is in KiB on Linux.
        peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    )


def _camera_process(
    grounds: str,
    namespace: str,
    rate_hz: float,
    seconds: float,
    compressed: str | None,
    started: multiprocessing.synchronize.Event,
    report: multiprocessing.Queue,
) -> None:
    """The camera process: publish ``seconds * rate_hz`` panning frames per camera.

    Raw mono8 on ``<cam>/image_raw`` (:func:`_raw_cameras`), or with ``compressed``
    JPEG of that encoding on ``<cam>/image_raw/compressed`` (:func:`_jpeg_cameras`).
    Sets ``started`` once the node's subscriptions are matched, then puts
    (frames published, CPU seconds used while publishing) on ``report``.
    """
    # The bench ends this process (terminate: SIGTERM's default action) on the end of a
    # run and on Ctrl-C, which the terminal sends to it too: neither is a traceback here,
    # nor an RCLError from rclpy's handler shutting the context under a publish.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    ground = np.load(grounds)
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    try:
        node = Node("bench_cameras", namespace=namespace)
        qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
        publishers, messages, write_frame = (
            _raw_cameras(node, ground, qos)
            if compressed is None
            else _jpeg_cameras(node, ground, qos, compressed)
        )
        _wait(lambda: all(p.get_subscription_count() for p in publishers), "the node")
        started.set()
        cpu_start = _cpu_s()
        start = time.monotonic()
        ticks = max(1, round(seconds * rate_hz))
        for tick in range(ticks):
            for camera, (publisher, msg) in enumerate(zip(publishers, messages, strict=True)):
                write_frame(camera, tick)
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(time.time_ns(), _NS_PER_S)
                publisher.publish(msg)
            time.sleep(max(start + (tick + 1) / rate_hz - time.monotonic(), 0.0))
        report.put((ticks * len(CAMERAS), _cpu_s() - cpu_start))
        node.destroy_node()
    finally:
        rclpy.try_shutdown()


#: Writes camera ``camera``'s frame ``tick`` (its index in :data:`CAMERAS`) into its message.
_FrameWriter = Callable[[int, int], None]


def _raw_cameras(
    node: Node, ground: np.ndarray, qos: QoSProfile
) -> tuple[list[Publisher], list[Image], _FrameWriter]:
    """The cameras' publishers of ``<cam>/image_raw``, their messages, and their frames' writer.

    One message per camera, its pixels rewritten in place for every frame: a camera
    driver fills its buffer, it does not build a new 12 MB message.
    """
    publishers = [node.create_publisher(Image, f"{c}/image_raw", qos) for c in CAMERAS]
    messages = [
        array_to_image(camera_view(view, 0).copy(), "mono8", Header(frame_id=camera))
        for camera, view in zip(CAMERAS, ground, strict=True)
    ]
    pixels = [
        np.frombuffer(msg.data, dtype=np.uint8).reshape(msg.height, msg.width) for msg in messages
    ]

    def write_frame(camera: int, tick: int) -> None:
        pixels[camera][:] = camera_view(ground[camera], tick)

    return publishers, messages, write_frame


def _jpeg_cameras(
    node: Node, ground: np.ndarray, qos: QoSProfile, encoding: str
) -> tuple[list[Publisher], list[CompressedImage], _FrameWriter]:
    """:func:`_raw_cameras` as JPEG on ``<cam>/image_raw/compressed``, every view encoded once.

    ``encoding``: ``bgr8`` encodes the ground in each channel, as a colour camera's.
    A camera encodes its own frames; here the encoding would take this process's
    cores, and one camera's views repeat as it pans back and forth.
    """
    publishers = [
        node.create_publisher(CompressedImage, f"{c}/image_raw/compressed", qos) for c in CAMERAS
    ]

    def jpeg(pixels: np.ndarray) -> bytes:
        if encoding == "bgr8":
            pixels = cv2.cvtColor(pixels, cv2.COLOR_GRAY2BGR)
        return cv2.imencode(".jpg", pixels, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])[1].tobytes()

    views = [[jpeg(camera_view(view, k)) for k in range(PAN_FRAMES + 1)] for view in ground]
    messages = [
        CompressedImage(header=Header(frame_id=c), format=f"{encoding}; jpeg compressed {encoding}")
        for c in CAMERAS
    ]

    def write_frame(camera: int, tick: int) -> None:
        messages[camera].data = views[camera][pan_step(tick)]

    return publishers, messages, write_frame


def _processed(node: MarkerLocalizerNode) -> int:
    return sum(s.processed for s in node.processor.snapshots().values())


def _cpu_s() -> float:
    times = os.times()
    return times.user + times.system


class ProcessStat(NamedTuple):
    """One process's line of ``/proc/<pid>/stat``: what the benchmark and its tests read."""

    parent: int  # the parent's pid
    state: str  # R, S, D, Z (a zombie: exited, not yet waited for), ...
    cpu_s: float  # user + system CPU seconds it has used


def process_table() -> dict[int, ProcessStat]:
    """Every process's :class:`ProcessStat` by pid (empty where there is no /proc)."""
    tick = os.sysconf("SC_CLK_TCK")
    table = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            # The command name may hold spaces; the fields from the state on follow its ')'.
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        table[int(stat.parent.name)] = ProcessStat(
            int(fields[1]), fields[0], (int(fields[11]) + int(fields[12])) / tick
        )
    return table


def _node_cpu_s(camera_pid: int | None) -> float:
    """CPU seconds of this process and its descendants but the camera process's subtree.

    The node's worker processes are children of its fork server; a process that
    has exited no longer counts (the workers live as long as the node).
    """
    table = process_table()
    tree, frontier = {os.getpid()}, {os.getpid()}
    while frontier:
        frontier = {
            pid for pid, stat in table.items() if stat.parent in frontier and pid != camera_pid
        }
        tree |= frontier
    return sum(table[pid].cpu_s for pid in tree if pid in table)


def _machine_busy_s() -> float:
    """CPU seconds all processes have used since boot (NaN where /proc/stat is missing)."""
    try:
        with open("/proc/stat") as stat:
            fields = [int(v) for v in stat.readline().split()[1:]]
    except OSError:
        return float("nan")
    idle = fields[3] + fields[4]  # idle + iowait
    return (sum(fields[:8]) - idle) / os.sysconf("SC_CLK_TCK")


def _wait(predicate: Callable[[], bool], what: str, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise RuntimeError(f"timed out waiting for {what}")
        time.sleep(0.05)


def format_table(results: Sequence[RunResult]) -> str:
    """The results as a fixed-width text table, one row per worker count."""
    header = (
        f"{'workers':>7} {'kind':>9} {'frames/s':>9} {'processed':>9} {'published':>9} "
        f"{'drop DDS':>8} {'diag lost':>9} {'drop mbox':>9} {'drop age':>8} {'lat p50 ms':>10} "
        f"{'lat p95 ms':>10} {'full':>5} {'CPU %':>6} {'CPU ms/fr':>9} {'cameras %':>9} "
        f"{'others %':>8} {'peak MB':>8}"
    )
    rows = [header, "-" * len(header)]
    for r in results:
        rows.append(
            f"{r.workers:>7} {'processes' if r.worker_processes else 'threads':>9} "
            f"{r.frames_per_s:>9.3f} {r.processed:>9} {r.published:>9} "
            f"{r.dropped_in_transport:>8} {r.lost_by_stamps:>9} {r.dropped_mailbox:>9} "
            f"{r.dropped_age:>8} "
            f"{r.latency_p50_ms:>10.0f} {r.latency_p95_ms:>10.0f} {r.full_frame_passes:>5} "
            f"{r.cpu_percent:>6.0f} {r.cpu_ms_per_frame:>9.0f} "
            f"{r.camera_cpu_percent:>9.0f} {r.others_cpu_percent:>8.0f} {r.peak_rss_mb:>8.0f}"
        )
    return "\n".join(rows)


def build_parser() -> argparse.ArgumentParser:
    """Command-line options of the benchmark."""
    parser = argparse.ArgumentParser(
        allow_abbrev=False,
        prog="marker-localizer bench throughput",
        description="Frames per second of the node with 1 and 2 workers, five cameras.",
    )
    parser.add_argument(
        "--width", type=count_type, default=4096, help="frame width, px (default: %(default)s)"
    )
    parser.add_argument(
        "--height", type=count_type, default=3000, help="frame height, px (default: %(default)s)"
    )
    parser.add_argument(
        "--seconds",
        type=positive_float,
        default=40.0,
        help="publishing time per worker count, s (default: %(default)s)",
    )
    parser.add_argument(
        "--rate-hz",
        type=positive_float,
        default=4.0,
        help="frames per second and camera published (default: %(default)s; 20 in all, about "
        "what two workers take)",
    )
    parser.add_argument(
        "--workers",
        type=count_type,
        nargs="+",
        default=[1, 2],
        help="worker counts to run (default: 1 2)",
    )
    parser.add_argument(
        "--ground",
        choices=sorted(GROUNDS),
        default="cluttered",
        help="what the cameras see: the speed benchmark's clutter (default) or the flight "
        "simulator's five cameras",
    )
    parser.add_argument(
        "--radius-range",
        type=float,
        nargs=2,
        default=list(speed.RADIUS_RANGE),
        metavar=("MIN", "MAX"),
        help="the node's marker radius range, px (default 6 40)",
    )
    parser.add_argument(
        "--worker-threads",
        action="store_true",
        help="the node's workers as threads of its process (worker_processes:=false) "
        "instead of processes of their own",
    )
    parser.add_argument(
        "--compressed",
        nargs="?",
        const=COMPRESSED_ENCODINGS[0],
        choices=COMPRESSED_ENCODINGS,
        metavar="ENCODING",
        help=f"the cameras publish JPEG (quality {JPEG_QUALITY}) on <cam>/image_raw/compressed "
        "and the node reads it (image_transport:=compressed) instead of raw mono8; of "
        f"{' or '.join(COMPRESSED_ENCODINGS)} (default {COMPRESSED_ENCODINGS[0]}: a colour "
        "camera's frames are 3x the pixels to decode and convert)",
    )
    parser.add_argument(
        "--full-frame",
        action="store_true",
        help="a full-frame detection per frame (tracker.enabled off) instead of the "
        "node's default tracking mode",
    )
    add_json_option(parser)
    return parser


def run(args: argparse.Namespace, report: Report) -> dict[str, Any]:
    """Render the grounds, run the node with each worker count, report the table.

    Args:
        args: the command line, from :func:`build_parser`.
        report: prints the table.

    Returns:
        The figures the table and the lines around it give.
    """
    tracking = not args.full_frame
    # Before rclpy starts; the camera process inherits it. A profile of the user's own
    # (the variable already set) is kept.
    profile = fastdds_profile()
    if _PROFILE_VARIABLE not in os.environ and profile is not None:
        os.environ[_PROFILE_VARIABLE] = str(profile)
    transport = os.environ.get(
        _PROFILE_VARIABLE, f"Fast DDS defaults ({FASTDDS_PROFILE_NAME} not installed)"
    )
    with tempfile.TemporaryDirectory(prefix="marker_bench_") as directory:
        print(
            f"rendering {len(CAMERAS)} grounds for {args.width}x{args.height} frames ...",
            flush=True,
        )
        try:
            grounds = GROUNDS[args.ground](args.width, args.height, Path(directory))
        except ConfigError as err:
            # The renderer names its own settings, which are no options of this command.
            raise ConfigError(
                f"--width {args.width} --height {args.height}: frames too small for the "
                f"{args.ground} ground's markers (the renderer could not place them all "
                "without overlap); 640x480 and larger hold them"
            ) from err
        # This process runs the node as the node's main() does (worker threads detect here).
        single_thread_blas()
        # As the node's main(): rclpy's own handler would shut the context down under
        # the frames in flight on Ctrl-C, which the node's drain then fails to publish.
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        try:
            results = []
            for workers in args.workers:
                print(f"running {workers} worker(s) for {args.seconds:g} s ...", flush=True)
                results.append(
                    run_once(
                        grounds,
                        workers,
                        args.seconds,
                        args.rate_hz,
                        tracking=tracking,
                        radius_range=tuple(args.radius_range),
                        worker_processes=not args.worker_threads,
                        compressed=args.compressed,
                    )
                )
        finally:
            rclpy.try_shutdown()
    full_frame_every = TrackerConfig().full_frame_every
    mode = (
        f"tracking (full frame every {full_frame_every} frames)"
        if tracking
        else "full-frame detection"
    )
    lines = [
        f"{len(CAMERAS)} cameras, {args.width}x{args.height} "
        f"{f'{args.compressed} JPEG (quality {JPEG_QUALITY})' if args.compressed else 'mono8'} "
        "panning "
        f"{PAN_STEP_PX} px per frame, {args.rate_hz:g} Hz each, {args.seconds:g} s per run, "
        f"{mode}, {args.ground} ground, radius {args.radius_range[0]:g}-"
        f"{args.radius_range[1]:g} px, {os.cpu_count()} CPUs, DDS profile: {transport}",
        format_table(results),
    ]
    by_workers = {r.workers: r for r in results}
    scaling = None
    if 1 in by_workers and 2 in by_workers:
        scaling = by_workers[2].frames_per_s / by_workers[1].frames_per_s
        lines.append(f"scaling 2 workers / 1 worker: {scaling:.2f}x")
    report("\n".join(lines))
    return {
        "cameras": len(CAMERAS),
        "width": args.width,
        "height": args.height,
        "pan_step_px": list(PAN_STEP_PX),
        "rate_hz": args.rate_hz,
        "seconds": args.seconds,
        "tracking": tracking,
        "full_frame_every": full_frame_every if tracking else None,
        "ground": args.ground,
        "compressed": args.compressed,
        "radius_range": list(args.radius_range),
        "cpus": os.cpu_count(),
        "dds_profile": transport,
        "runs": [
            {**dataclasses.asdict(r), "dropped_in_transport": r.dropped_in_transport}
            for r in results
        ],
        "scaling_2_over_1": scaling,
    }


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark, print a table, save its figures with ``--json``; the exit status."""
    args = build_parser().parse_args(argv)
    # The node refuses a range the configuration refuses: before minutes of rendering.
    DetectorConfig(
        marker_radius_min_px=args.radius_range[0], marker_radius_max_px=args.radius_range[1]
    )
    return run_and_save("throughput benchmark", lambda report: run(args, report), args.json)


if __name__ == "__main__":
    raise SystemExit(main())
