"""Frame processing shared by the node and bag replay: mailboxes, a worker pool, one Detector.

The node's executor callbacks only :meth:`FrameProcessor.submit` a frame and
return; worker threads convert, detect and hand the result to a callback. Bag
replay drives the same object with ``submit(..., block=True)`` and
:meth:`FrameProcessor.wait_idle`, so that no frame is dropped.

Threads or processes (``worker_processes``): worker threads share the frame and
the Detector, and wait for the GIL wherever the detector runs Python rather than
OpenCV or numpy, which on busy ground is much of its time. Measured on the
2-core development machine (docs/speed.md, "Two worker threads against one, by
ground"): two threads do 1.1-1.5x the frames a second of one on the speed
benchmark's and the real aerial frames and 0.8-0.9x on the demo's busy
1280x960 gravel, where each waits a third of its time for the GIL; two
processes do 1.8-2.0x of one on all three, once each runs one BLAS thread
(:func:`single_thread_blas`). With processes, each worker thread hands its
frame to a worker process and waits: the frame through the thread's shared
memory block, the Detector (its settings, 2 kB) and the camera's
:class:`MarkerTracker` (its tracks and anchor patches, about 25 kB) pickled;
the result and the tracker come back. So any process may serve any camera,
a parameter change reaches the next frame as with threads, and the
mailboxes, scheduling and guarantees below are the same either way. The
processes are forked from a fork server that imported the detector once (a
new one starts in milliseconds); a process that dies (killed for memory, a
crash in native code) fails the frame it had, counted as a failure, and the
next frames go to a fresh one (each process is a pool of its own, which its
death alone breaks: the others' frames go on); a worker whose node died
(however it died) exits. The worker processes ignore SIGINT and SIGTERM: the
node stops them.

Guarantees:

* one bounded mailbox per camera holding only the newest frame; a frame that a
  newer one replaces is counted (``dropped by mailbox``);
* a frame that waited longer than ``max_frame_age_s`` in the node (from its
  arrival to a worker taking it) is dropped and counted (``dropped by age``).
  Header stamps are copied onto the results, never judged: they may come from
  another clock (a camera's device clock, an old bag played without /clock, a
  stamp in the future), so freshness is measured from the frame's arrival, on
  the clock passed in;
* at most one frame per camera is processed at a time, so each camera's
  results are delivered in order; of the cameras with a frame waiting, the one
  served least recently goes first, and between two not yet served the one
  whose mailbox has held a frame longer (replacing its frame does not reset its
  wait), so every camera gets an equal turn however the frames of the cameras
  interleave: synchronised cameras, whose frames arrive in the same order each
  time, are not served in that order's favour;
* the result callback is never called concurrently with itself, and never
  after :meth:`FrameProcessor.shutdown` returned;
* a frame that fails (bad input, an exception in the detector or in the result
  callback) is counted with its error and reported to the error callback; the
  worker goes on with the next frame.
"""

from __future__ import annotations

import contextlib
import itertools
import math
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from multiprocessing import forkserver, resource_tracker, shared_memory
from typing import NamedTuple

import cv2
import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import CompressedImage, Image, PointCloud2
from std_msgs.msg import Header

from marker_localizer.blas import single_thread_blas
from marker_localizer.config import DetectorConfig, TrackerConfig
from marker_localizer.core.image import peak_level
from marker_localizer.core.pipeline import Detector
from marker_localizer.core.result import (
    CAP_COUNTS,
    SECOND_READING_CAP_COUNTS,
    Detection,
    DetectionResult,
)
from marker_localizer.core.tracking import MarkerTracker, staggered_phase
from marker_localizer.errors import ConfigError, WorkerError, described
from marker_localizer.overlay import draw_detections
from marker_localizer.ros.conversions import (
    EncodedFrame,
    array_to_image,
    detections_to_cloud,
    message_to_detector_input,
)
from marker_localizer.ros.diagnostics import (
    CameraSnapshot,
    CameraStats,
    DiagnosticThresholds,
    camera_status,
    clock_started_since,
    diagnostic_array,
    node_status,
)
from marker_localizer.stopping import STOP_SIGNALS

#: Receives (camera, marker cloud); the cloud carries the input's header.
ResultCallback = Callable[[str, PointCloud2], None]
#: Receives (camera, overlay image), after the frame's cloud; it carries the input's header.
OverlayCallback = Callable[[str, Image], None]
#: Receives (camera, the exception a frame failed with).
ErrorCallback = Callable[[str, Exception], None]
#: What the detector is handed: the pixels as it reads them, or a compressed frame,
#: which a worker process decodes itself.
FrameInput = np.ndarray | EncodedFrame


class InputLevels(NamedTuple):
    """What the diagnostics read of a frame's pixels, wherever they were decoded.

    Attributes:
        peak: the brightest level (:func:`~marker_localizer.core.image.peak_level`).
        sixteen_bit: the pixels are 16-bit (their bit depth is then judged).
        size: the frame's (width, height), px, which its camera_info must describe;
            None: not read.
    """

    peak: float
    sixteen_bit: bool
    size: tuple[int, int] | None = None


_NS_PER_S = 1_000_000_000
#: What a worker process imports once, in the fork server its workers are forked from,
#: so that a new worker starts in milliseconds, not the seconds these imports take.
_WORKER_PRELOAD = ["marker_localizer.ros.processing"]
#: Where POSIX shared memory blocks are files (Linux).
_SHARED_MEMORY_DIR = "/dev/shm"
#: Frames a worker thread sends pickled after shared memory had no room for one,
#: before it asks again. Each ask fills tmpfs to its limit for a moment (tmpfs gives
#: the pages, then takes them back), and Fast DDS's transport shares it; at the
#: cameras' 4-20 Hz room freed since is still found within seconds.
NO_ROOM_RETRY_FRAMES = 50
#: How often the shutdown's wait for the frames in flight looks whether it was told
#: to give up on them (:meth:`FrameProcessor.abandon`), s.
_ABANDON_POLL_S = 0.05


@dataclass(frozen=True)
class _Frame:
    camera: str
    msg: Image | CompressedImage
    received_ns: int
    #: Since when the camera's mailbox has been non-empty: a replacement keeps it,
    #: so a camera whose frames keep being replaced is not pushed back in the queue.
    waiting_since_ns: int
    #: The arrival on the steady clock, which the latency is measured on: the
    #: processor's own clock may be a bag's, frozen while a frame is processed, or
    #: gone back since the frame arrived (a bag played again).
    received_steady_ns: int


def _reserve_pages(block: shared_memory.SharedMemory) -> None:
    """Have tmpfs give every page of ``block`` now.

    Raises:
        OSError: it has no room for them (ENOSPC).
    """
    path = os.path.join(_SHARED_MEMORY_DIR, block.name.lstrip("/"))
    if not os.path.exists(path):
        return  # not Linux: the block is not a file there
    descriptor = os.open(path, os.O_RDWR)
    try:
        os.posix_fallocate(descriptor, 0, block.size)
    finally:
        os.close(descriptor)


def _start_worker_process() -> None:
    """Initialiser of a worker process."""
    # Ctrl-C reaches the whole process group, and a service manager's SIGTERM may reach
    # the whole control group; the parent finishes the frames in flight on them, which a
    # worker that died of the signal would fail.
    for stop in STOP_SIGNALS:
        signal.signal(stop, signal.SIG_IGN)
    # Its task queue never closes (each worker holds both ends), so a worker of a node
    # that was killed would wait for tasks for ever, and keep the fork server alive.
    parent = multiprocessing.parent_process()
    if parent is not None:
        threading.Thread(
            target=_exit_with, args=(parent,), name="marker_parent_watch", daemon=True
        ).start()
    # One worker per core: OpenCV's and BLAS's thread pools would compete with the others.
    cv2.setNumThreads(1)
    single_thread_blas()


class _AbandonedError(Exception):
    """A frame in flight at the shutdown's timeout: its worker process was killed."""


def _kill_workers(pool: ProcessPoolExecutor) -> None:
    """SIGKILL ``pool``'s worker processes (they ignore SIGINT and SIGTERM).

    Left alone, a worker still busy at the shutdown's timeout would finish its frame
    first, and the interpreter's exit waits for the pool: the node would outlast its
    ``shutdown_timeout_s`` by the frame's time. The pool's processes are private to
    it (a public way to end them comes with Python 3.14's ``kill_workers``).
    """
    # None once the pool is shut down.
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        process.kill()


def _exit_with(parent: multiprocessing.process.BaseProcess) -> None:
    """End this worker process once ``parent`` has ended, however it ended."""
    parent.join()
    os._exit(1)


def _worker_ready() -> None:
    """Nothing: the task whose return shows that a worker process is up."""


def _start_helper_processes() -> None:
    """Start multiprocessing's resource tracker and fork server deaf to the stop signals.

    Each unless it runs already. The stop signals reach the whole process group
    (Ctrl-C, a closed terminal's SIGHUP) or control group (a service manager's
    SIGTERM), and both helpers must outlive the node's drain: a fresh tracker, told
    to forget shared memory and semaphores it never knew, writes a KeyError traceback
    for each; and the pools learn of each worker's end through the fork server, so
    that its death makes them take their living workers for dead and fail the frames
    in flight. The tracker ignores SIGINT and SIGTERM but not SIGHUP, the fork server
    SIGINT alone. Started from a thread that blocks the stop signals, each keeps them
    blocked (the tracker unblocks only the two it ignores), as do the workers the
    fork server forks, and ends with the node, whose end closes its pipe. Blocked
    anew for each: starting the tracker unblocks SIGINT and SIGTERM in its thread.
    """
    for ensure_running in (resource_tracker.ensure_running, forkserver.ensure_running):
        blocked = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
        try:
            ensure_running()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, blocked)


def _started_pools(count: int) -> list[ProcessPoolExecutor]:
    """``count`` pools of one worker process each, forked from a fork server, up and ready.

    A pool a process: concurrent.futures breaks a whole pool when one of its processes
    dies, and every frame its other processes had in flight failed with it.
    """
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(_WORKER_PRELOAD)
    _start_helper_processes()
    pools = [
        ProcessPoolExecutor(1, mp_context=context, initializer=_start_worker_process)
        for _ in range(count)
    ]
    for started in [pool.submit(_worker_ready) for pool in pools]:
        started.result()
    return pools


@dataclass(frozen=True)
class _Settings:
    """What a frame is processed with, swapped whole: a frame sees all of a change or none."""

    detector: Detector
    tracker_config: TrackerConfig
    publish_overlay: bool


@dataclass(frozen=True)
class _SharedFrame:
    """A frame in a shared memory block, as a worker process finds it.

    The block holds the pixels, or where ``compressed_format`` is given, a
    compressed frame's bytes (``shape`` their count).
    """

    block: str
    shape: tuple[int, ...]
    dtype: str
    compressed_format: str | None = None

    def read(self) -> FrameInput:
        """A copy of the frame, the block left unmapped (a view would pin it open)."""
        block = shared_memory.SharedMemory(self.block)
        try:
            # No name holds the view: it must be gone before the block closes.
            if self.compressed_format is None:
                return np.ndarray(self.shape, self.dtype, buffer=block.buf).copy()
            data = np.ndarray(self.shape, self.dtype, buffer=block.buf).tobytes()
            return EncodedFrame(data, self.compressed_format)
        finally:
            block.close()


def _detect_shared_frame(
    detector: Detector, tracker: MarkerTracker | None, frame: _SharedFrame, stamp_s: float
) -> tuple[DetectionResult, MarkerTracker | None, InputLevels]:
    """:func:`_detect_frame` in a worker process, the frame read from shared memory."""
    return _detect_frame(detector, tracker, frame.read(), stamp_s)


def _detect_frame(
    detector: Detector, tracker: MarkerTracker | None, frame: FrameInput, stamp_s: float
) -> tuple[DetectionResult, MarkerTracker | None, InputLevels]:
    """One frame, in a worker thread or process: the camera's tracker, or a full pass.

    A compressed frame is decoded here first (:meth:`EncodedFrame.decode`, within
    the detector's ``max_pixels``).

    Returns:
        The result without its survivors (the candidates' positions after each
        test, up to a few hundred kB a frame that a process would copy back for
        nothing: the node publishes the detections and counts), the tracker,
        which has moved on by this frame, and the levels of its pixels.

    Raises:
        ImageError: a compressed frame that does not decode, or too large.
    """
    if isinstance(frame, EncodedFrame):
        frame = frame.decode(detector.config.max_pixels)
    result = detector.detect(frame) if tracker is None else tracker.update(frame, stamp_s)
    levels = InputLevels(
        peak_level(frame), frame.dtype == np.uint16, (frame.shape[1], frame.shape[0])
    )
    return DetectionResult(result.detections, result.counts, result.timings_ms), tracker, levels


def stamp_to_ns(header: Header) -> int:
    """Header stamp in nanoseconds."""
    return int(header.stamp.sec) * _NS_PER_S + int(header.stamp.nanosec)


class FrameProcessor:
    """Newest-frame mailboxes per camera served by a pool of worker threads or processes.

    Args:
        cameras: camera names; :meth:`submit` accepts only these.
        config: detector configuration of the first frames.
        on_result: called with (camera, PointCloud2) for every processed frame,
            from a worker thread; the cloud carries the input's header.
        workers: number of worker threads (>= 1).
        max_frame_age_s: frames that waited longer than this in the node when a
            worker takes them are dropped, s; 0 disables the check (replay).
        clock_ns: current time in nanoseconds (default: wall clock); arrivals,
            waits, clock offsets and the statistics' windows are measured on it.
        steady_ns: a clock that never goes back, ns (default: the monotonic
            clock); the latency is measured on it, and so is a frame's wait where
            ``clock_ns`` went back since the frame arrived.
        publish_overlay: also render an overlay image (bgr8) per frame, handed to
            ``on_overlay`` once the frame's cloud is out.
        on_overlay: called with (camera, overlay) where ``publish_overlay``, from a
            worker thread; the overlay carries the input's header.
        on_error: called with (camera, exception) when a frame fails, from a
            worker thread.
        stats_window_s: sliding window of the per-camera statistics, s.
        steady_silence: a camera's time since its last frame (its input timeout)
            is read on ``steady_ns`` too, the longer taken: under ``use_sim_time`` the
            node's clock stands still while no /clock comes (a bag not playing, or
            ended). Replay, whose clock is its bag's, reads it on that alone.
        tracker_config: tracking-mode settings of the first frames.
        worker_processes: each worker thread runs the detector in a process of
            its own (see the module's docstring); blocks until they are up.

    Raises:
        ConfigError: no cameras, duplicate names, workers < 1, negative age
            or non-positive window.
    """

    def __init__(
        self,
        cameras: Sequence[str],
        config: DetectorConfig,
        on_result: ResultCallback,
        *,
        workers: int = 2,
        max_frame_age_s: float = 0.0,
        clock_ns: Callable[[], int] = time.time_ns,
        steady_ns: Callable[[], int] = time.monotonic_ns,
        publish_overlay: bool = False,
        on_overlay: OverlayCallback | None = None,
        on_error: ErrorCallback | None = None,
        stats_window_s: float = 10.0,
        steady_silence: bool = True,
        tracker_config: TrackerConfig | None = None,
        worker_processes: bool = False,
    ) -> None:
        if not cameras or len(set(cameras)) != len(cameras):
            raise ConfigError(f"cameras must be non-empty and unique, got {list(cameras)!r}")
        if workers < 1:
            raise ConfigError(f"workers={workers!r} must be at least 1")
        if stats_window_s <= 0:
            raise ConfigError(f"stats_window_s={stats_window_s!r} must be positive")
        self.max_frame_age_s = max_frame_age_s
        self._settings = _Settings(
            Detector(config), tracker_config or TrackerConfig(), publish_overlay
        )
        # One tracker per camera (a camera is processed by one worker at a time), built
        # for the detector in use and rebuilt when the configuration changes.
        self._trackers: dict[str, MarkerTracker] = {}
        self._on_result = on_result
        self._on_overlay = on_overlay
        self._on_error = on_error
        self._clock_ns = clock_ns
        self._steady_ns = steady_ns
        start_ns = clock_ns()
        start_steady_ns = steady_ns() if steady_silence else None
        self._stats = {
            c: CameraStats(c, start_ns, stats_window_s, start_steady_ns=start_steady_ns)
            for c in cameras
        }
        self._pending: dict[str, _Frame | None] = dict.fromkeys(cameras)
        self._busy: set[str] = set()
        self._discarded: list[str] = []
        # Each camera's place in the order of the frames taken (-1: none yet).
        self._last_taken = dict.fromkeys(cameras, -1)
        self._takes = itertools.count()
        self._cond = threading.Condition()
        self._stopping = False
        # Set by abandon(), maybe from a signal handler: a plain flag, no lock.
        self._abandon = False
        # Held while a result is delivered; shutdown takes it to close the gate.
        self._deliver_lock = threading.Lock()
        self._gate_open = True
        # Held to replace a pool whose process died (_in_worker_process), and to close.
        self._pool_lock = threading.Lock()
        # Under _pool_lock: the pools are shut down and the blocks unlinked (_close).
        self._closed = False
        # Each thread's block for the frames it hands to a process, and every block
        # made, to unlink at shutdown.
        self._frame_block = threading.local()
        # Each worker thread's settings of the frame it took: (detector, tracking settings).
        self._taken = threading.local()
        self._frame_blocks: list[shared_memory.SharedMemory] = []
        self._frames_pickled = 0
        # Worker thread i's process, a pool of its own (_started_pools).
        self._pools: list[ProcessPoolExecutor] | None = None
        if worker_processes:
            self._pools = self._start_pools(workers)
        self._threads = [
            threading.Thread(target=self._work, args=(i,), name=f"marker_worker_{i}", daemon=True)
            for i in range(workers)
        ]
        for thread in self._threads:
            thread.start()

    @property
    def cameras(self) -> list[str]:
        """Camera names, in the order given."""
        return list(self._stats)

    @property
    def workers(self) -> int:
        """Number of workers."""
        return len(self._threads)

    @property
    def worker_processes(self) -> bool:
        """Whether the workers run the detector in processes of their own."""
        return self._pools is not None

    @property
    def max_frame_age_s(self) -> float:
        """Longest wait of a frame in the node before a worker takes it, s (0: no limit)."""
        return self._max_frame_age_ns / _NS_PER_S

    @max_frame_age_s.setter
    def max_frame_age_s(self, value: float) -> None:
        if value < 0:
            raise ConfigError(f"max_frame_age_s={value!r} must be >= 0")
        self._max_frame_age_ns = int(value * _NS_PER_S)

    @property
    def config(self) -> DetectorConfig:
        """Configuration of the detector the next frame will use."""
        return self._settings.detector.config

    @property
    def tracker_config(self) -> TrackerConfig:
        """Tracking settings the next frame will use."""
        return self._settings.tracker_config

    @property
    def publish_overlay(self) -> bool:
        """Whether the next frame's overlay is drawn and handed to ``on_overlay``."""
        return self._settings.publish_overlay

    def reconfigure(
        self,
        config: DetectorConfig | None = None,
        tracker_config: TrackerConfig | None = None,
        publish_overlay: bool | None = None,
    ) -> None:
        """Use these settings from the next frame a worker takes; frames in flight finish unchanged.

        Those given change together: no frame is processed with some of them (a
        parameter change set atomically). A new ``tracker_config`` starts the
        cameras' tracks over.
        """
        now = self._settings
        # Rebinding one attribute is atomic: a worker reads it once per frame, as it takes it.
        self._settings = _Settings(
            now.detector if config is None else Detector(config),
            now.tracker_config if tracker_config is None else tracker_config,
            now.publish_overlay if publish_overlay is None else publish_overlay,
        )

    def submit(
        self,
        camera: str,
        msg: Image | CompressedImage,
        *,
        block: bool = False,
        timeout_s: float | None = None,
    ) -> bool:
        """Put a frame into the camera's mailbox; never waits unless ``block``.

        Args:
            camera: one of :attr:`cameras`.
            msg: the frame; the processor keeps a reference until it is processed.
            block: wait until the mailbox is empty instead of replacing the
                waiting frame (replay: no frame dropped by the mailbox).
            timeout_s: longest wait with ``block``, s (None: no limit).

        Returns:
            True if the frame was queued; False if the processor is shutting
            down or the blocking wait timed out.

        Raises:
            KeyError: ``camera`` is not one of :attr:`cameras`.
        """
        stats = self._stats[camera]
        with self._cond:
            if block:
                self._cond.wait_for(
                    lambda: self._pending[camera] is None or self._stopping, timeout_s
                )
                if self._pending[camera] is not None:
                    return False
            if self._stopping:
                return False
            now_ns = self._clock_ns()
            waiting = self._pending[camera]
            since_ns = now_ns if waiting is None else waiting.waiting_since_ns
            steady_ns = self._steady_ns()
            self._pending[camera] = _Frame(camera, msg, now_ns, since_ns, steady_ns)
            self._cond.notify_all()
        stats.frame_received(now_ns, stamp_to_ns(msg.header), steady_ns)
        if waiting is not None:
            stats.frame_replaced(now_ns, waiting.received_ns)
        return True

    def skipped(self, camera: str, msg: Image | CompressedImage, err: Exception | None) -> None:
        """Count a frame its caller did not submit (replay's checks), as the node counts it.

        The statistics see it arrive; with ``err`` (what processing would have
        raised: an unsupported encoding) it failed too, where the node would have
        failed it.

        Raises:
            KeyError: ``camera`` is not one of :attr:`cameras`.
        """
        stats = self._stats[camera]
        now_ns = self._clock_ns()
        stats.frame_received(now_ns, stamp_to_ns(msg.header), self._steady_ns())
        if err is not None:
            stats.frame_failed(now_ns, described(err))

    def wait_idle(self, timeout_s: float | None = None) -> bool:
        """Wait until every mailbox is empty and no frame is in flight.

        Returns:
            True if idle, False on timeout.
        """
        with self._cond:
            return self._cond.wait_for(self._idle, timeout_s)

    def in_flight(self) -> list[str]:
        """Cameras whose frame is being processed now, sorted."""
        with self._cond:
            return sorted(self._busy)

    @property
    def discarded(self) -> list[str]:
        """Cameras whose waiting frame :meth:`shutdown` discarded unprocessed, sorted."""
        with self._cond:
            return list(self._discarded)

    def snapshots(self) -> dict[str, CameraSnapshot]:
        """Statistics of every camera, now."""
        now_ns, steady_ns = self._clock_ns(), self._steady_ns()
        return {camera: stats.snapshot(now_ns, steady_ns) for camera, stats in self._stats.items()}

    def diagnostics(
        self,
        node_name: str,
        stamp: Time,
        thresholds: DiagnosticThresholds,
        *,
        snapshots: Mapping[str, CameraSnapshot] | None = None,
        camera_values: Mapping[str, Mapping[str, str]] | None = None,
        camera_info_sizes: Mapping[str, tuple[int, int] | None] | None = None,
        node_values: Mapping[str, str] | None = None,
        namespace: str = "/",
    ) -> DiagnosticArray:
        """The /diagnostics content of this pool: a status per camera and one for the node.

        The node publishes it and replay writes it into its output bag, so both
        report the same figures under the same keys.

        Args:
            node_name: node name without namespace.
            stamp: the array's header stamp.
            thresholds: limits that decide each camera's level.
            snapshots: the cameras' statistics (default: :meth:`snapshots`, now).
            camera_values: per camera, further key/value pairs of its status.
            camera_info_sizes: per camera, the image size its camera_info describes
                (:func:`~marker_localizer.ros.conversions.camera_info_image_size`),
                which its frames' must be; a camera missing here is not judged.
            node_values: further key/value pairs of the node's status.
            namespace: the node's namespace, which qualifies the statuses' names and
                ids (:func:`~marker_localizer.ros.diagnostics.qualified_name`).
        """
        snapshots = self.snapshots() if snapshots is None else snapshots
        extra, info_sizes = camera_values or {}, camera_info_sizes or {}
        statuses = [
            camera_status(
                node_name,
                snapshot,
                thresholds,
                extra.get(camera),
                info_sizes.get(camera),
                namespace,
            )
            for camera, snapshot in snapshots.items()
        ]
        config = self.config
        values = {
            "workers": str(self.workers),
            "worker kind": "processes" if self.worker_processes else "threads",
            "frames in flight": str(len(self.in_flight())),
            "max frame age (s)": f"{self.max_frame_age_s:g}",
            "marker radius range (px)": (
                f"{config.marker_radius_min_px:g}..{config.marker_radius_max_px:g}"
            ),
            **(node_values or {}),
        }
        if self.worker_processes:
            values["frames pickled (no room in shared memory)"] = str(self.frames_pickled)
        statuses.append(node_status(node_name, statuses, values, namespace))
        return diagnostic_array(stamp, statuses)

    def shutdown(self, timeout_s: float | None = None) -> bool:
        """Stop: discard waiting frames (:attr:`discarded`), finish and deliver those in flight.

        Args:
            timeout_s: longest wait for the frames in flight, s (None: no limit).

        Returns:
            True if every worker finished; False if some were still busy at
            the timeout or when :meth:`abandon` was called (their results will not
            be delivered, and worker processes still busy are killed).

        Raises:
            KeyboardInterrupt: the wait was interrupted (a second Ctrl-C in a
                command): the frames in flight are abandoned as at the timeout, then
                it is raised again.
        """
        with self._cond:
            self._stopping = True
            self._discarded = sorted(c for c, frame in self._pending.items() if frame is not None)
            self._pending = dict.fromkeys(self._pending)
            self._cond.notify_all()
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        try:
            for thread in self._threads:
                while thread.is_alive() and not self._abandon:
                    left_s = _ABANDON_POLL_S if deadline is None else deadline - time.monotonic()
                    if left_s <= 0:
                        break
                    thread.join(min(left_s, _ABANDON_POLL_S))
            finished = not any(thread.is_alive() for thread in self._threads)
            self._close(finished)
        except BaseException:
            self._close(finished=False)
            raise
        return finished

    def abandon(self) -> None:
        """Have :meth:`shutdown` give up on the frames in flight now, as at its timeout.

        Before or during the shutdown; safe in a signal handler (it sets a flag and
        takes no lock): the node's second Ctrl-C.
        """
        self._abandon = True

    @property
    def abandoned(self) -> bool:
        """Whether :meth:`abandon` was called."""
        return self._abandon

    def _close(self, finished: bool) -> None:
        """Stop delivering, end the worker processes and free the frames' shared memory.

        Worker processes are killed unless ``finished`` (they may hold a frame).
        Safe to call again, after an interruption of an earlier call included.
        """
        with self._deliver_lock:
            self._gate_open = False
        with self._pool_lock:
            self._closed = True
            for pool in self._pools or []:
                if not finished:
                    _kill_workers(pool)
                pool.shutdown(wait=True, cancel_futures=True)
            while self._frame_blocks:
                block = self._frame_blocks.pop()
                block.unlink()
                # A worker thread abandoned while it copies a frame in holds the mapping:
                # it goes with the thread's view (the name is gone already).
                with contextlib.suppress(BufferError):
                    block.close()

    def _start_pools(self, count: int) -> list[ProcessPoolExecutor]:
        """``count`` worker processes, up and ready, a pool each (:func:`_started_pools`).

        Started in a thread of its own, out of reach of Ctrl-C, which Python handles
        in the main thread: a launch cut short there leaves the fork server starting
        a process nobody waits for, which then looks for the pool's semaphores after
        this process has gone and says so in a traceback. Interrupted, the main thread
        waits for the launch to end (about a second; a further signal is noted, and a
        third ends the process), ends the pool and raises the interruption again.
        """
        launched: Future[list[ProcessPoolExecutor]] = Future()

        def launch() -> None:
            try:
                launched.set_result(_started_pools(count))
            except BaseException as err:
                launched.set_exception(err)

        threading.Thread(target=launch, name="marker_pool_start", daemon=True).start()
        try:
            return launched.result()
        except KeyboardInterrupt as err:
            interrupted = err
        while not launched.done():
            try:
                launched.exception()
            except KeyboardInterrupt as err:
                interrupted = err
        if launched.exception() is None:
            for pool in launched.result():
                pool.shutdown(wait=True, cancel_futures=True)
        raise interrupted

    @property
    def frames_pickled(self) -> int:
        """Frames sent to a worker process pickled: no room for them in shared memory."""
        return self._frames_pickled

    def _frame_block_for(self, size: int) -> shared_memory.SharedMemory | None:
        """This thread's shared memory block, made or grown to ``size`` bytes.

        None where shared memory has no room for it, and for the
        :data:`NO_ROOM_RETRY_FRAMES` frames after. A page of a block that tmpfs
        cannot give kills the process that writes it (SIGBUS), and a container's
        /dev/shm is 64 MB unless told otherwise, which Fast DDS shares: so a
        block's pages are reserved when it is made.
        """
        block: shared_memory.SharedMemory | None = getattr(self._frame_block, "memory", None)
        if block is not None and block.size >= size:
            return block
        waiting = getattr(self._frame_block, "frames_before_retry", 0)
        if waiting:
            self._frame_block.frames_before_retry = waiting - 1
            return None
        with self._pool_lock:
            if self._closed:  # a block made now would never be unlinked
                raise _AbandonedError
            if block is not None:
                self._frame_blocks.remove(block)
                block.close()
                block.unlink()
                self._frame_block.memory = None
            block = shared_memory.SharedMemory(create=True, size=max(size, 1))
            try:
                _reserve_pages(block)
            except OSError:
                block.close()
                block.unlink()
                self._frame_block.frames_before_retry = NO_ROOM_RETRY_FRAMES
                return None
            self._frame_blocks.append(block)
        self._frame_block.memory = block
        return block

    def _in_worker_process(
        self, detector: Detector, tracker: MarkerTracker | None, frame: FrameInput, stamp_s: float
    ) -> tuple[DetectionResult, MarkerTracker | None, InputLevels]:
        """:func:`_detect_frame` in one of the worker processes.

        The frame goes through this thread's shared memory block: pickled
        through the pool's pipe, a 12 MP frame's round trip took 49 ms, through
        the block 6 ms. A compressed frame goes as its bytes (2 MB for a 12 MP
        JPEG of quality 90, not 12 or 36).
        """
        assert self._pools is not None
        slot = getattr(self._taken, "slot", 0)
        pool = self._pools[slot]
        payload, compressed_format = (
            (np.frombuffer(frame.data, np.uint8), frame.format)
            if isinstance(frame, EncodedFrame)
            else (frame, None)
        )
        try:
            block = self._frame_block_for(payload.nbytes)
            if block is None:
                with self._pool_lock:
                    self._frames_pickled += 1
                return pool.submit(_detect_frame, detector, tracker, frame, stamp_s).result()
            shared = _SharedFrame(block.name, payload.shape, payload.dtype.str, compressed_format)
            np.ndarray(shared.shape, shared.dtype, buffer=block.buf)[...] = payload
            return pool.submit(_detect_shared_frame, detector, tracker, shared, stamp_s).result()
        except BrokenProcessPool as err:
            with self._pool_lock:
                if self._stopping:
                    raise _AbandonedError from err
                if self._pools[slot] is pool:
                    pool.shutdown(wait=False, cancel_futures=True)
                    self._pools[slot] = self._start_pools(1)[0]
            raise WorkerError(
                "its worker process ended abruptly (killed: out of memory, a signal); "
                "a fresh one serves the next frames"
            ) from err
        except RuntimeError as err:
            # A frame held past the shutdown's wait meets the pool it shut down
            # ("cannot schedule new futures after shutdown"): the shutdown named it.
            with self._pool_lock:
                if self._closed:
                    raise _AbandonedError from err
            raise

    def _tracker(self, camera: str, detector: Detector, config: TrackerConfig) -> MarkerTracker:
        """The camera's tracker around ``detector`` (a new one after a configuration change)."""
        tracker = self._trackers.get(camera)
        if tracker is None or tracker.detector is not detector or tracker.config is not config:
            cameras = self.cameras
            phase = staggered_phase(cameras.index(camera), len(cameras), config.full_frame_every)
            tracker = MarkerTracker(detector, config, phase)
            self._trackers[camera] = tracker
        return tracker

    def detect(self, camera: str, frame: FrameInput, stamp_s: float) -> DetectionResult:
        """The result of one frame: the camera's tracker, or a full pass without tracking.

        Every frame meets the detector here, in a worker thread (which hands it
        to its worker process with ``worker_processes``), so a subclass can
        stand in for the detector (the tests hold a camera's frames in it to make
        mailbox drops independent of how fast the detector is). The result
        carries no survivors (:func:`_detect_frame`); the levels of the frame's
        pixels are left in :attr:`taken_levels` for this thread.

        Args:
            camera: the frame's camera.
            frame: the frame as the detector takes it (see
                :func:`~marker_localizer.ros.conversions.image_to_detector_input`),
                or a compressed frame, decoded where the detector runs.
            stamp_s: the frame's header stamp, s.

        Raises:
            ImageError: a compressed frame that does not decode.
        """
        # Those the frame was taken with: a reconfiguration applies from the next frame.
        settings: _Settings = getattr(self._taken, "settings", None) or self._settings
        detector, tracking = settings.detector, settings.tracker_config
        tracker = self._tracker(camera, detector, tracking) if tracking.enabled else None
        if self._pools is None:
            result, _, self._taken.levels = _detect_frame(detector, tracker, frame, stamp_s)
            return result
        result, moved, self._taken.levels = self._in_worker_process(
            detector, tracker, frame, stamp_s
        )
        if moved is not None:
            # The copy that came back, tied to this side's detector and settings again,
            # which _tracker compares by identity.
            moved.detector, moved.config = detector, tracking
            self._trackers[camera] = moved
        return result

    @property
    def taken_levels(self) -> InputLevels:
        """The levels of the pixels of the frame this thread's :meth:`detect` last read."""
        levels: InputLevels = self._taken.levels
        return levels

    def _idle(self) -> bool:
        return not self._busy and all(frame is None for frame in self._pending.values())

    def _work(self, slot: int) -> None:
        self._taken.slot = slot  # its process: self._pools[slot]
        while True:
            with self._cond:
                frame = self._take()
                while frame is None and not self._stopping:
                    self._cond.wait()
                    frame = self._take()
                if frame is None:
                    return
            try:
                self._process(frame)
            finally:
                self._taken.settings = None
                with self._cond:
                    self._busy.discard(frame.camera)
                    self._cond.notify_all()

    def _take(self) -> _Frame | None:
        """Under the lock: claim the frame of the idle camera served least recently (None: none).

        Of cameras not yet served, the one waiting longest. The order of the waits
        alone would favour, under overload, the synchronised cameras whose frames
        arrive first each time: 41 % more frames for the first of five than for
        the last.
        """
        while not self._stopping:
            waiting = [f for c, f in self._pending.items() if f is not None and c not in self._busy]
            if not waiting:
                return None
            frame = min(waiting, key=lambda f: (self._last_taken[f.camera], f.waiting_since_ns))
            self._pending[frame.camera] = None
            self._cond.notify_all()
            now_ns = self._clock_ns()
            if self._max_frame_age_ns and self._waited_ns(frame, now_ns) > self._max_frame_age_ns:
                self._stats[frame.camera].frame_too_old(now_ns)
                continue
            self._busy.add(frame.camera)
            self._last_taken[frame.camera] = next(self._takes)
            return frame
        return None

    def _waited_ns(self, frame: _Frame, now_ns: int) -> int:
        """How long ``frame`` has waited since its arrival, ns, ``now_ns`` on the processor's clock.

        Where that clock went back since the frame arrived (a bag played again with
        ``use_sim_time``), the difference would be negative and the frame never too
        old, however long it waited; where it had not started (``use_sim_time``
        before the first /clock reads 0), the difference would be decades. Its wait
        is then read on the steady clock.
        """
        waited_ns = now_ns - frame.received_ns
        if waited_ns < 0 or clock_started_since(frame.received_ns, now_ns):
            return self._steady_ns() - frame.received_steady_ns
        return waited_ns

    def _process(self, frame: _Frame) -> None:
        stats = self._stats[frame.camera]
        header = frame.msg.header
        # Read once, as the frame is taken: its conversion, detection, overlay and
        # statistics all see the same settings, whatever changes while it is in flight.
        settings = self._taken.settings = self._settings
        config = settings.detector.config
        try:
            # A worker process decodes a compressed frame itself: decodes in one process
            # take turns (image_files), in several they do not.
            if self._pools is not None and isinstance(frame.msg, CompressedImage):
                taken: FrameInput = EncodedFrame.of(frame.msg)
            else:
                taken = message_to_detector_input(frame.msg, config.max_pixels)
            result = self.detect(frame.camera, taken, stamp_to_ns(header) / _NS_PER_S)
            levels = self.taken_levels
            detections = result.detections
            cloud = detections_to_cloud(header, detections)
            with self._deliver_lock:
                if not self._gate_open:
                    return
                self._on_result(frame.camera, cloud)
            delivered_steady_ns = self._steady_ns()
        except _AbandonedError:
            return  # the shutdown counts and names what it abandoned
        except Exception as err:  # one bad frame must not stop the worker
            stats.frame_failed(self._clock_ns(), described(err))
            if self._on_error is not None:
                self._on_error(frame.camera, err)
            return
        now_ns = self._clock_ns()
        stats.frame_processed(
            now_ns,
            latency_ms=(delivered_steady_ns - frame.received_steady_ns) / 1e6,
            # NaN before the clock started (use_sim_time before the first /clock: 0).
            clock_offset_s=(frame.received_ns - stamp_to_ns(header)) / _NS_PER_S
            if frame.received_ns
            else math.nan,
            markers=len(detections),
            capped=sum(result.counts.get(key, 0) for key in CAP_COUNTS),
            rereads_capped=sum(result.counts.get(key, 0) for key in SECOND_READING_CAP_COUNTS),
            peak=levels.peak,
            bit_depth=config.bit_depth if levels.sixteen_bit else 0,
            # Without tracking the detector's result counts no "full_frame": every frame is one.
            full_frame=bool(result.counts.get("full_frame", 1)),
            frame_size=levels.size,
        )
        if settings.publish_overlay and self._on_overlay is not None:
            # Drawn once the cloud is out: a pose estimator does not wait for a picture.
            self._publish_overlay(frame, taken, detections, config, self._on_overlay)

    def _publish_overlay(
        self,
        frame: _Frame,
        taken: FrameInput,
        detections: Sequence[Detection],
        config: DetectorConfig,
        on_overlay: OverlayCallback,
    ) -> None:
        """Draw ``frame``'s detections on its pixels and hand them to ``on_overlay``.

        A compressed frame a worker process decoded is decoded again here. A failure
        is counted and named in the camera's statistics: its cloud is out already.
        """
        try:
            pixels = (
                message_to_detector_input(frame.msg, config.max_pixels)
                if isinstance(taken, EncodedFrame)
                else taken
            )
            overlay = array_to_image(
                draw_detections(pixels, detections, bit_depth=config.bit_depth),
                "bgr8",
                frame.msg.header,
            )
            with self._deliver_lock:
                if self._gate_open:
                    on_overlay(frame.camera, overlay)
        except Exception as err:  # the frame's cloud is published: count, do not fail it
            self._stats[frame.camera].overlay_failed(self._clock_ns(), described(err))
            if self._on_error is not None:
                self._on_error(frame.camera, err)
