"""Per-camera statistics and /diagnostics messages in diagnostic_updater's conventions.

diagnostic_updater is not available as a wheel, so this module reproduces its
conventions: one DiagnosticStatus per task named ``"<node>: <task>"``, here
one per camera plus one for the node, values as KeyValue strings whose keys carry
their units (``"latency p95 (ms)"``). ``<node>`` is the node's fully qualified
name without its leading slash (:func:`qualified_name`), as ROS 1's updater named
it: ``marker_localizer`` in the root namespace, which is ROS 2's updater's name
too, and ``uav1/marker_localizer`` under ``/uav1``, where ROS 2's (without its
``use_fqn``) names the nodes of every namespace alike, and an aggregator merges
them. A camera's ``hardware_id`` is the camera qualified the same way (``cam0``,
``uav1/cam0``), the node's its qualified name.

Levels of a camera:

* ERROR: no frame arrived within ``input_timeout_s`` (counted from start when
  none ever arrived), or a frame failed (bad input or a processing exception)
  within the last ``window_s``.
* WARN: more than ``drop_warn_fraction`` of the frames received in the last
  ``window_s`` were dropped (replaced in the mailbox or waited too long); or
  more than that fraction of the frames the camera sent in the window never
  arrived (lost upstream: in DDS, in the camera driver, on the network), as the
  gaps between consecutive header stamps tell against the camera's own rate
  (:func:`frames_lost_upstream`; a jump of the stamps' clock counts none); or
  the latency p95 exceeds ``latency_warn_ms``; or more than
  ``drop_warn_fraction`` of the window's frames did not advance the header stamp
  (an unset or stuck stamp: a tracker restarts with a full pass on each,
  :func:`stalled_stamps`); or every 16-bit frame delivered in the window stayed
  under
  :data:`~marker_localizer.core.image.SHALLOW_PEAK_SHARE` of white, as a shallower
  sensor's words read at the configured ``bit_depth`` do
  (:func:`~marker_localizer.core.image.bit_depth_hint`); or, where that does not
  say why, every frame delivered in the window stayed under
  :data:`~marker_localizer.core.image.DIM_PEAK_SHARE` of white: underexposed for
  its markers (:func:`~marker_localizer.core.image.underexposed`); or the camera's
  camera_info describes images of another size than its frames (a pose estimator
  would project with intrinsics for other pixels: :func:`camera_info_mismatch`).
* OK otherwise.

Full-frame passes are counted beside the frames processed, not judged: with
tracking on, a share that stays high in the window is tracking giving up (attitude
jitter, a stuck stamp, too few anchors), each pass several times a tracked frame's
work, which shows otherwise only as latency that grows; without tracking every
frame is one.

Latency is the time a frame spent in the node, from its arrival to the
publication of its result. Header stamps are never judged: the clock offset
(arrival on the node's clock minus the header stamp: transport delay plus the
difference between the camera's clock and the node's) is reported, not
checked, so that an old bag played without /clock or a camera's device clock
shows up as what it is. Only the differences between one camera's stamps are
used, to count the frames that never arrived.

All times come from one clock in nanoseconds (the node's ROS clock, so
``use_sim_time`` applies); statistics are thread-safe because worker threads
write them while the executor reads them. A clock that jumps back by more than
:data:`CLOCK_JUMP_BACK_S` (``use_sim_time`` set live, a bag played again, a
simulator restarted) restarts a camera's windows from that moment: measured
against times now in the future, they would never empty, and their rates would
be counted over a negative span.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_msgs.msg import Header

from marker_localizer.core.image import (
    SHALLOW_PEAK_TEXT,
    bit_depth_hint,
    bit_depth_scale,
    underexposed,
    underexposure_warning,
)
from marker_localizer.errors import shorten

OK, WARN, ERROR = 0, 1, 2
_LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR"}
_NS_PER_S = 1_000_000_000
#: Results kept per camera for the windowed latency and marker statistics; the
#: newest 200 within the window bound memory and the sort, and give a stable p95.
_LATENCY_SAMPLES = 200
#: Frames a camera's windows hold at most (arrivals with their stamps, drops,
#: deliveries): the window is a time, and a clock that stands still (``use_sim_time``
#: before the first /clock, a simulator paused while the camera runs on) would keep
#: every frame in it for ever. 2^16 holds an 18 Hz camera over the longest window
#: (``stats_window_s`` 3600 s) and, at ~80 bytes a frame, is ~5 MB a camera at most.
#: Where more frames arrive in a window, the window is the span of the newest of them.
WINDOW_MAX_FRAMES = 1 << 16
#: A clock going back by more than this restarts the windows, s. Times read by one
#: thread may reach the statistics after a later time read by another; those stay
#: far below a second.
CLOCK_JUMP_BACK_S = 1.0
#: A clock that read 0 and then reads more than this had not started, s: ``use_sim_time``
#: before the first /clock reads 0, and a bag's clock then starts at its recording's
#: date. A simulator's own clock starting from 0 moves on without such a jump.
CLOCK_START_JUMP_S = 3600.0


def clock_started_since(then_ns: int, now_ns: int) -> bool:
    """Whether a clock that read ``then_ns`` had not started then (:data:`CLOCK_START_JUMP_S`)."""
    return then_ns == 0 and now_ns > CLOCK_START_JUMP_S * _NS_PER_S


#: Fewest stamp gaps from which a camera's frame period is estimated: a second
#: of a 10 Hz camera; with fewer, nothing is counted as lost.
_MIN_STAMP_GAPS = 8
#: Gaps shorter than this multiple of the 10th-percentile gap are one frame
#: period apart: stamps of a free-running camera jitter by far less than half a
#: period, and the 10th percentile is still one period with up to 90 % lost.
_SINGLE_PERIOD_GAP = 1.5
#: Times the period is centred on the gaps within half a period of it: each step
#: takes a bias of a fifth to a few percent, then to under one (:func:`frames_lost_upstream`).
_PERIOD_REFINEMENTS = 4
#: A stamp gap longer than its arrival gap by more than this is the stamps' clock
#: jumping, not frames lost, s: an unset stamp (0) between set ones, one frame
#: stamped ahead, stamps stepping back and then on again. A frame's delay on its
#: way to the node changes from one frame to the next by far less: the
#: subscription holds one frame, transport and the executor take milliseconds.
STAMP_JUMP_S = 1.0


@dataclass(frozen=True)
class DiagnosticThresholds:
    """When a camera's status turns WARN or ERROR.

    Attributes:
        latency_warn_ms: WARN when the latency p95 (arrival to publish) is above, ms.
        input_timeout_s: ERROR when no frame arrived for this long, s.
        window_s: sliding window of rates, drop fraction and recent errors, s.
        drop_warn_fraction: WARN when more than this fraction of the frames
            received in the window was dropped, or did not advance the header stamp,
            or of those sent was lost upstream.
        expected_rate_hz: the cameras' frame rate, Hz, against which stamp gaps
            count lost frames; 0 measures each camera's rate from its stamps.
    """

    latency_warn_ms: float
    input_timeout_s: float
    window_s: float
    drop_warn_fraction: float = 0.10
    expected_rate_hz: float = 0.0


@dataclass(frozen=True)
class CameraSnapshot:
    """Statistics of one camera at one instant (see :meth:`CameraStats.snapshot`).

    Attributes:
        camera: camera name.
        received: frames that entered the mailbox since start.
        processed: frames whose result was delivered since start.
        full_frame_passes: delivered frames the detector searched whole, since start:
            every frame without tracking; with it, the frames where tracking failed or
            a scheduled pass fell (:class:`~marker_localizer.core.tracking.MarkerTracker`).
        dropped_mailbox: frames replaced by a newer one before a worker took them.
        dropped_age: frames that waited longer than the age limit in the node.
        errors: frames that failed (bad input or processing exception).
        overlays_failed: processed frames (their clouds published) whose overlay
            could not be drawn or published.
        frames_capped: processed frames of which the detector's caps (its bounded
            worst case: ``max_candidates``, and the candidates it verifies) cut
            candidates, since start.
        candidates_capped: candidates those caps cut, since start.
        rereads_capped: rejected candidates the second readings' caps left
            unread (:data:`~marker_localizer.core.result.SECOND_READING_CAP_COUNTS`),
            since start.
        received_in_window: frames received within the window (at most
            :data:`WINDOW_MAX_FRAMES`: where more arrived, the window is the span of
            the newest that many, and every windowed figure is over that span).
        dropped_in_window: frames dropped (either reason) within the window.
        input_rate_hz: received frames per second over the window (NaN where the
            clock stood still: ``use_sim_time`` without /clock).
        processed_rate_hz: delivered results per second over the window (the same).
        latency_p50_ms: median time from arrival in the mailbox to publish in
            the window, ms (NaN: no sample).
        latency_p95_ms: 95th percentile of the same, ms (NaN: no sample).
        clock_offset_s: median of arrival time minus header stamp in the window,
            s (NaN: no sample); negative for stamps in the future.
        markers_per_frame: mean markers per delivered frame in the window (NaN: none).
        full_frame_share: share of the frames delivered in the window that were
            full-frame passes (NaN: none).
        window_stamps_ns: header stamps of the frames received in the window,
            in order of arrival, ns (their gaps tell the frames lost upstream).
        window_arrivals_ns: when each of those frames arrived, on the node's clock, ns.
        since_last_frame_s: time since the last frame arrived, or since start
            if none did, s; read on the steady clock too where one is given, and
            the longer taken (a ``use_sim_time`` clock stands still without /clock).
        any_frame: whether a frame ever arrived.
        last_error: text of the newest failure ("" if none).
        since_last_error_s: time since that failure, s (None if none).
        peak_share: the largest share of its own white that the brightest level of
            a frame delivered in the window reached (NaN: none read).
        bit_depth_hint: the bit depth the 16-bit frames of the window fit, where
            the configured one leaves them all dim
            (:func:`~marker_localizer.core.image.bit_depth_hint`); None otherwise.
        frame_size: (width, height) of the newest processed frame, px (None: none yet).
    """

    camera: str
    received: int
    processed: int
    full_frame_passes: int
    dropped_mailbox: int
    dropped_age: int
    errors: int
    overlays_failed: int
    frames_capped: int
    candidates_capped: int
    rereads_capped: int
    received_in_window: int
    dropped_in_window: int
    input_rate_hz: float
    processed_rate_hz: float
    latency_p50_ms: float
    latency_p95_ms: float
    clock_offset_s: float
    markers_per_frame: float
    full_frame_share: float
    window_stamps_ns: np.ndarray
    window_arrivals_ns: np.ndarray
    since_last_frame_s: float
    any_frame: bool
    last_error: str
    since_last_error_s: float | None
    peak_share: float = math.nan
    bit_depth_hint: int | None = None
    frame_size: tuple[int, int] | None = None


class _Delivered(NamedTuple):
    """What the statistics keep of one delivered frame, for its window."""

    #: When its result was delivered, on the statistics' clock, ns.
    at_ns: int
    #: Arrival in the mailbox to delivery, ms.
    latency_ms: float
    #: Arrival time minus the frame's header stamp, s.
    clock_offset_s: float
    #: Markers found in it.
    markers: int
    #: Its brightest level (:func:`~marker_localizer.core.image.peak_level`); NaN: not read.
    peak: float
    #: The configured bit depth where the frame is 16-bit; 0 for an 8-bit frame.
    bit_depth: int
    #: Whether the detector searched the whole frame (else tracking confirmed its markers).
    full_frame: bool


class CameraStats:
    """Thread-safe counters and sliding windows of one camera.

    Args:
        camera: camera name.
        start_ns: clock time at start, ns (the input timeout counts from it).
        window_s: length of the sliding window, s.
        start_steady_ns: steady clock time at start, ns, where the time since the
            last frame is read on the steady clock too (:meth:`frame_received`,
            :meth:`snapshot`); None: on the clock alone (replay, on its bag's times).
        max_window_frames: most frames the windows hold (:data:`WINDOW_MAX_FRAMES`).
    """

    def __init__(
        self,
        camera: str,
        start_ns: int,
        window_s: float,
        *,
        start_steady_ns: int | None = None,
        max_window_frames: int = WINDOW_MAX_FRAMES,
    ) -> None:
        if max_window_frames < 1:
            raise ValueError(f"max_window_frames must be at least 1, got {max_window_frames!r}")
        self.camera = camera
        self._lock = threading.Lock()
        self._start_ns = start_ns
        self._latest_ns = start_ns
        self._window_ns = int(window_s * _NS_PER_S)
        self._received = self._processed = self._full_frame_passes = 0
        self._dropped_mailbox = self._dropped_age = self._errors = self._overlays_failed = 0
        self._frames_capped = self._candidates_capped = self._rereads_capped = 0
        self._last_frame_ns: int | None = None
        self._last_frame_steady_ns = start_steady_ns
        self._last_error = ""
        self._last_error_ns: int | None = None
        self._frame_size: tuple[int, int] | None = None
        # Bounded by count too (WINDOW_MAX_FRAMES); _received_at and _stamps stay aligned.
        self._received_at: deque[int] = deque(maxlen=max_window_frames)
        self._stamps: deque[int] = deque(maxlen=max_window_frames)  # of each in _received_at
        self._dropped_at: deque[int] = deque(maxlen=max_window_frames)
        # When each result was delivered: the processed rate (_results keeps only the newest).
        self._processed_at: deque[int] = deque(maxlen=max_window_frames)
        self._results: deque[_Delivered] = deque()

    def _follow_clock(self, now_ns: int) -> None:
        """Under the lock: restart the windows where the clock went back (module docstring).

        Or where it starts: a clock that read 0 had not started (``use_sim_time``
        before the first /clock), and its first time, a bag's, is a jump forward of
        decades, after which every frame before it would have waited that long.
        """
        started = clock_started_since(self._latest_ns, now_ns)
        if started or now_ns < self._latest_ns - CLOCK_JUMP_BACK_S * _NS_PER_S:
            windows = (self._received_at, self._stamps, self._dropped_at, self._processed_at)
            for window in (*windows, self._results):
                window.clear()
            self._start_ns = now_ns
            if self._last_frame_ns is not None:
                self._last_frame_ns = now_ns if started else min(self._last_frame_ns, now_ns)
            if self._last_error_ns is not None:
                self._last_error_ns = now_ns if started else min(self._last_error_ns, now_ns)
            self._latest_ns = now_ns
        self._latest_ns = max(self._latest_ns, now_ns)

    def frame_received(self, now_ns: int, stamp_ns: int, steady_ns: int | None = None) -> None:
        """Count a frame put into the mailbox; ``stamp_ns`` is its header stamp.

        ``steady_ns``: the steady clock's time, where the statistics read it.
        """
        with self._lock:
            self._follow_clock(now_ns)
            self._received += 1
            self._last_frame_ns = now_ns
            if self._last_frame_steady_ns is not None and steady_ns is not None:
                self._last_frame_steady_ns = steady_ns
            self._received_at.append(now_ns)
            self._stamps.append(stamp_ns)

    def frame_replaced(self, now_ns: int, received_ns: int | None = None) -> None:
        """Count a frame replaced in the mailbox by a newer one.

        ``received_ns``: when the replaced frame arrived. One that arrived before
        the clock went back (``play --loop`` starting a pass with ``/clock``) is
        counted, but not in the windows restarted since: there, beside the one
        frame received, it read as 100 % dropped.
        """
        with self._lock:
            self._follow_clock(now_ns)
            self._dropped_mailbox += 1
            if received_ns is None or self._start_ns <= received_ns <= now_ns:
                self._dropped_at.append(now_ns)

    def frame_too_old(self, now_ns: int) -> None:
        """Count a frame dropped because it exceeded the age limit."""
        with self._lock:
            self._follow_clock(now_ns)
            self._dropped_age += 1
            self._dropped_at.append(now_ns)

    def frame_processed(
        self,
        now_ns: int,
        latency_ms: float,
        clock_offset_s: float,
        markers: int,
        capped: int = 0,
        rereads_capped: int = 0,
        peak: float = math.nan,
        bit_depth: int = 0,
        full_frame: bool = True,
        frame_size: tuple[int, int] | None = None,
    ) -> None:
        """Count a delivered result.

        Args:
            now_ns: clock time of delivery, ns.
            latency_ms: arrival in the mailbox to delivery, ms.
            clock_offset_s: arrival time minus the frame's header stamp, s.
            markers: markers found in the frame.
            capped: candidates the detector's caps cut in the frame.
            rereads_capped: rejected candidates its second readings' caps left unread.
            peak: the frame's brightest level
                (:func:`~marker_localizer.core.image.peak_level`).
            bit_depth: the configured bit depth where the frame is 16-bit; 0 for an
                8-bit frame.
            full_frame: whether the detector searched the whole frame (every frame
                does without tracking), or tracking confirmed its markers.
            frame_size: the frame's (width, height), px (None: not read).
        """
        with self._lock:
            self._follow_clock(now_ns)
            self._processed += 1
            self._frame_size = frame_size or self._frame_size
            self._full_frame_passes += full_frame
            self._frames_capped += capped > 0
            self._candidates_capped += capped
            self._rereads_capped += rereads_capped
            self._processed_at.append(now_ns)
            self._results.append(
                _Delivered(now_ns, latency_ms, clock_offset_s, markers, peak, bit_depth, full_frame)
            )
            while len(self._results) > _LATENCY_SAMPLES:
                self._results.popleft()

    def frame_failed(self, now_ns: int, message: str) -> None:
        """Count a frame that could not be processed; ``message``, shortened, is the last error."""
        with self._lock:
            self._follow_clock(now_ns)
            self._errors += 1
            self._last_error = shorten(message)
            self._last_error_ns = now_ns

    def overlay_failed(self, now_ns: int, message: str) -> None:
        """Count a processed frame whose overlay failed; it becomes the last error."""
        with self._lock:
            self._follow_clock(now_ns)
            self._overlays_failed += 1
            self._last_error = shorten(f"its overlay failed: {message}")
            self._last_error_ns = now_ns

    def snapshot(self, now_ns: int, steady_ns: int | None = None) -> CameraSnapshot:
        """Freeze the statistics at ``now_ns`` (clock time) and ``steady_ns`` (steady clock), ns."""
        with self._lock:
            self._follow_clock(now_ns)
            horizon = now_ns - self._window_ns
            while self._received_at and self._received_at[0] < horizon:
                self._received_at.popleft()
                self._stamps.popleft()
            if len(self._received_at) == self._received_at.maxlen:
                # More frames in the window than are kept: it starts at the oldest kept.
                horizon = max(horizon, self._received_at[0])
            for window in (self._dropped_at, self._processed_at):
                while window and window[0] < horizon:
                    window.popleft()
            recent = [r for r in self._results if r.at_ns >= horizon]
            latency = np.array([r.latency_ms for r in recent])
            deep = [r for r in recent if r.bit_depth]
            last_frame = self._start_ns if self._last_frame_ns is None else self._last_frame_ns
            since_last_frame_ns = max(now_ns - last_frame, 0)
            if self._last_frame_steady_ns is not None and steady_ns is not None:
                since_last_frame_ns = max(
                    since_last_frame_ns, steady_ns - self._last_frame_steady_ns
                )
            return CameraSnapshot(
                camera=self.camera,
                received=self._received,
                processed=self._processed,
                full_frame_passes=self._full_frame_passes,
                dropped_mailbox=self._dropped_mailbox,
                dropped_age=self._dropped_age,
                errors=self._errors,
                overlays_failed=self._overlays_failed,
                frames_capped=self._frames_capped,
                candidates_capped=self._candidates_capped,
                rereads_capped=self._rereads_capped,
                received_in_window=len(self._received_at),
                dropped_in_window=len(self._dropped_at),
                input_rate_hz=_rate_hz(self._received_at, now_ns, self._window_ns),
                processed_rate_hz=_rate_hz(self._processed_at, now_ns, self._window_ns),
                latency_p50_ms=_percentile(latency, 50),
                latency_p95_ms=_percentile(latency, 95),
                clock_offset_s=_percentile(np.array([r.clock_offset_s for r in recent]), 50),
                markers_per_frame=_mean([r.markers for r in recent]),
                full_frame_share=_mean([float(r.full_frame) for r in recent]),
                window_stamps_ns=np.array(self._stamps, dtype=np.int64),
                window_arrivals_ns=np.array(self._received_at, dtype=np.int64),
                since_last_frame_s=since_last_frame_ns / _NS_PER_S,
                any_frame=self._last_frame_ns is not None,
                last_error=self._last_error,
                since_last_error_s=None
                if self._last_error_ns is None
                else max(now_ns - self._last_error_ns, 0) / _NS_PER_S,
                peak_share=_peak_share(recent),
                bit_depth_hint=bit_depth_hint(max(r.peak for r in deep), deep[-1].bit_depth)
                if deep
                else None,
                frame_size=self._frame_size,
            )


def _rate_hz(times: Sequence[int], now_ns: int, window_ns: int) -> float:
    """Events a second in a window of their times: the intervals since its oldest.

    (count - 1) over the time since the oldest, so that a window younger than its
    length (a camera that started late, a bag replayed at its own times) is read
    over the time it holds: counted over the window's length, replay's first ten
    seconds read a 2 Hz camera at 0.3-0.6 Hz. NaN where no time passed (a clock
    standing still: ``use_sim_time`` without /clock, where it read 10^9 Hz).
    """
    if len(times) < 2:
        return len(times) * _NS_PER_S / window_ns
    span_ns = now_ns - times[0]
    return (len(times) - 1) * _NS_PER_S / span_ns if span_ns > 0 else math.nan


def _peak_share(results: Sequence[_Delivered]) -> float:
    """The largest share of its own white a delivered frame's brightest level reached (NaN: none).

    Each frame over its own white: a camera switched from 8- to 16-bit words
    within the window is judged by what each frame held.
    """
    shares = [
        r.peak / bit_depth_scale(np.dtype(np.uint16 if r.bit_depth else np.uint8), r.bit_depth)
        for r in results
        if not math.isnan(r.peak)
    ]
    return max(shares, default=math.nan)


def stalled_stamps(stamps_ns: np.ndarray) -> int:
    """How many frames carry a header stamp no later than the frame's before them."""
    return int(np.count_nonzero(np.diff(stamps_ns) <= 0))


def frames_lost_upstream(
    stamps_ns: np.ndarray, arrivals_ns: np.ndarray, rate_hz: float = 0.0
) -> tuple[int, float]:
    """Frames a camera sent but the node never received, from the gaps between its stamps.

    A gap of k frame periods (rounded) means k - 1 frames lost; gaps that are
    not positive (a repeated or an older stamp) count nothing, nor do gaps longer
    than the frames' arrival gap by more than :data:`STAMP_JUMP_S` (the stamps'
    clock jumped). The period is ``1 / rate_hz`` when the rate is known;
    otherwise the median of the gaps one period long (those under 1.5x the
    10th-percentile gap, then those within half a period of that), which sees
    random loss (DDS losing samples) and stamps jittering by up to a fifth of a
    period, but takes a camera of which every other frame is lost for one at half
    the rate.

    Args:
        stamps_ns: header stamps in order of arrival, ns.
        arrivals_ns: when each frame arrived, ns (any clock the node keeps).
        rate_hz: the camera's frame rate, Hz; 0 measures it from the gaps.

    Returns:
        (frames lost, the rate used in Hz); (0, NaN) when measuring and there
        are fewer than ``_MIN_STAMP_GAPS`` gaps to measure from.
    """
    gaps = np.diff(stamps_ns)
    gaps = gaps[(gaps > 0) & (gaps - np.diff(arrivals_ns) <= STAMP_JUMP_S * _NS_PER_S)]
    if rate_hz > 0:
        period_ns = _NS_PER_S / rate_hz
    elif gaps.size >= _MIN_STAMP_GAPS:
        period_ns = float(np.median(gaps[gaps < _SINGLE_PERIOD_GAP * np.percentile(gaps, 10)]))
        # Stamps that jitter (a driver stamping on arrival) put the 10th percentile
        # under the period, and that start with it: the gaps within half a period of
        # it, centred on again, are the single periods' (2, 20 ms of jitter at 10 Hz:
        # 78 -> 92 -> 98.5 -> 99.7 ms).
        for _ in range(_PERIOD_REFINEMENTS):
            single = gaps[np.abs(gaps - period_ns) < 0.5 * period_ns]
            period_ns = float(np.median(single))
    else:
        return 0, math.nan
    lost = int(np.maximum(np.rint(gaps / period_ns) - 1, 0).sum())
    return lost, _NS_PER_S / period_ns


def _percentile(values: np.ndarray, q: float) -> float:
    """The ``q``-th percentile of the values that are not NaN (NaN: none)."""
    values = values[~np.isnan(values)]
    return float(np.percentile(values, q)) if values.size else math.nan


def _mean(values: Sequence[float]) -> float:
    return float(np.mean(values)) if values else math.nan


def camera_level(
    snapshot: CameraSnapshot,
    thresholds: DiagnosticThresholds,
    camera_info_size: tuple[int, int] | None = None,
) -> tuple[int, str]:
    """Level (OK, WARN or ERROR) and a one-line reason for one camera.

    Args:
        snapshot: the camera's statistics.
        thresholds: limits; see the module docstring for the rules.
        camera_info_size: the (width, height) of the images the camera's camera_info
            describes, px (:func:`camera_info_mismatch`); None: none received.

    Returns:
        (level, message); every rule that fires is named in the message,
        the most severe first.
    """
    errors, warnings = [], []
    if snapshot.since_last_frame_s > thresholds.input_timeout_s:
        what = "no frame for" if snapshot.any_frame else "no frame since start,"
        errors.append(f"{what} {snapshot.since_last_frame_s:.1f} s")
    if (
        snapshot.since_last_error_s is not None
        and snapshot.since_last_error_s <= thresholds.window_s
    ):
        errors.append(
            f"frame failed {snapshot.since_last_error_s:.1f} s ago: {snapshot.last_error}"
        )
    if snapshot.received_in_window and (
        snapshot.dropped_in_window > thresholds.drop_warn_fraction * snapshot.received_in_window
    ):
        share = 100.0 * snapshot.dropped_in_window / snapshot.received_in_window
        warnings.append(f"{share:.0f} % of frames dropped")
    lost, rate_hz = frames_lost_upstream(
        snapshot.window_stamps_ns, snapshot.window_arrivals_ns, thresholds.expected_rate_hz
    )
    sent = snapshot.received_in_window + lost
    if lost > thresholds.drop_warn_fraction * sent:
        warnings.append(
            f"{100.0 * lost / sent:.0f} % of frames lost before the node ({lost} of {sent} "
            f"in {thresholds.window_s:g} s, from stamp gaps at {rate_hz:.3g} Hz)"
        )
    stalled = stalled_stamps(snapshot.window_stamps_ns)
    gaps = max(len(snapshot.window_stamps_ns) - 1, 0)
    if stalled > thresholds.drop_warn_fraction * gaps:
        warnings.append(
            f"{stalled} of {gaps} frames in {thresholds.window_s:g} s did not advance the "
            "header stamp (a tracker restarts with a full pass on each)"
        )
    if snapshot.latency_p95_ms > thresholds.latency_warn_ms:
        warnings.append(
            f"latency p95 {snapshot.latency_p95_ms:.0f} ms > {thresholds.latency_warn_ms:g} ms"
        )
    if snapshot.bit_depth_hint is not None:
        warnings.append(bit_depth_warning(snapshot.bit_depth_hint))
    elif underexposed(snapshot.peak_share):
        warnings.append(underexposure_warning(snapshot.peak_share))
    mismatch = camera_info_mismatch(snapshot.frame_size, camera_info_size)
    if mismatch is not None:
        warnings.append(mismatch)
    if errors:
        return ERROR, "; ".join(errors + warnings)
    if warnings:
        return WARN, "; ".join(warnings)
    return OK, "ok"


def camera_info_mismatch(
    frame_size: tuple[int, int] | None, camera_info_size: tuple[int, int] | None
) -> str | None:
    """The warning for frames of another size than their camera_info describes (None: none).

    The points are pixels of the frames; a consumer that projects them with this
    camera_info would use intrinsics calibrated for other pixels (a driver
    publishing its full-resolution calibration beside binned or scaled images).

    Args:
        frame_size: (width, height) of the camera's newest processed frame, px.
        camera_info_size: (width, height) of the images its camera_info describes, px
            (:func:`~marker_localizer.ros.conversions.camera_info_image_size`).
    """
    if frame_size is None or camera_info_size is None or frame_size == camera_info_size:
        return None
    return (
        f"camera_info is for {_size_text(camera_info_size)} images, the frames are "
        f"{_size_text(frame_size)}: its intrinsics do not fit the points"
    )


def _size_text(size: tuple[int, int] | None) -> str:
    return "none processed" if size is None else f"{size[0]}x{size[1]}"


def bit_depth_warning(hint: int) -> str:
    """The warning for a camera whose 16-bit frames fit ``hint`` bits (its diagnostics, replay)."""
    return (
        f"16-bit frames under {SHALLOW_PEAK_TEXT} of white: a {hint}-bit camera "
        f"wants detector.bit_depth {hint}"
    )


def drop_report(
    snapshot: CameraSnapshot, reported: tuple[int, int], max_frame_age_s: float
) -> str | None:
    """One line naming the frames of a camera dropped since the last report, and why.

    Args:
        snapshot: the camera's statistics now.
        reported: (dropped by mailbox, dropped by age) at the last report.
        max_frame_age_s: the age limit in force, s (named in the line).

    Returns:
        The line, or None when nothing was dropped since.
    """
    replaced = snapshot.dropped_mailbox - reported[0]
    waited = snapshot.dropped_age - reported[1]
    reasons = []
    if replaced > 0:
        reasons.append(f"{replaced} replaced in the mailbox by a newer frame (workers busy)")
    if waited > 0:
        reasons.append(f"{waited} waited longer than max_frame_age_s = {max_frame_age_s:g} s")
    if not reasons:
        return None
    return f"{snapshot.camera}: {replaced + waited} frame(s) dropped: {'; '.join(reasons)}"


def qualified_name(namespace: str, name: str) -> str:
    """``name`` in ``namespace``, without a leading slash: the statuses' names and ids.

    ``("/", "cam0")`` is ``cam0``, ``("/uav1", "cam0")`` is ``uav1/cam0``.
    """
    return f"{namespace.strip('/')}/{name}".lstrip("/")


def camera_status(
    node_name: str,
    snapshot: CameraSnapshot,
    thresholds: DiagnosticThresholds,
    extra: Mapping[str, str] | None = None,
    camera_info_size: tuple[int, int] | None = None,
    namespace: str = "/",
) -> DiagnosticStatus:
    """Build the DiagnosticStatus of one camera.

    Args:
        node_name: node name without namespace.
        snapshot: the camera's statistics.
        thresholds: limits that decide the level.
        extra: further key/value pairs to append (e.g. camera_info size).
        camera_info_size: the image size its camera_info describes, px, which the
            frames' must be (:func:`camera_level`).
        namespace: the node's namespace.

    Returns:
        Status named ``"<node>: <camera>"``, ``hardware_id`` the camera, each
        qualified by the namespace (:func:`qualified_name`).
    """
    level, message = camera_level(snapshot, thresholds, camera_info_size)
    lost, rate_hz = frames_lost_upstream(
        snapshot.window_stamps_ns, snapshot.window_arrivals_ns, thresholds.expected_rate_hz
    )
    dropped_pct = (
        100.0 * snapshot.dropped_in_window / snapshot.received_in_window
        if snapshot.received_in_window
        else 0.0
    )
    values = {
        "frames received": str(snapshot.received),
        "frames processed": str(snapshot.processed),
        "full-frame passes": str(snapshot.full_frame_passes),
        "full-frame passes in window (%)": f"{100.0 * snapshot.full_frame_share:.1f}",
        "dropped by mailbox": str(snapshot.dropped_mailbox),
        "dropped by age": str(snapshot.dropped_age),
        "dropped in window (%)": f"{dropped_pct:.1f}",
        "input rate (Hz)": f"{snapshot.input_rate_hz:.2f}",
        "processed rate (Hz)": f"{snapshot.processed_rate_hz:.2f}",
        "latency p50 (ms)": f"{snapshot.latency_p50_ms:.1f}",
        "latency p95 (ms)": f"{snapshot.latency_p95_ms:.1f}",
        "clock offset p50 (s)": f"{snapshot.clock_offset_s:.3f}",
        "frame size": _size_text(snapshot.frame_size),
        "markers per frame": f"{snapshot.markers_per_frame:.2f}",
        "peak level in window (% of white)": f"{100.0 * snapshot.peak_share:.1f}",
        "lost upstream in window": str(lost),
        "camera rate from stamps (Hz)": f"{rate_hz:.3g}",
        "time since last frame (s)": f"{snapshot.since_last_frame_s:.2f}",
        "errors": str(snapshot.errors),
        "overlays failed": str(snapshot.overlays_failed),
        "frames capped": str(snapshot.frames_capped),
        "candidates capped": str(snapshot.candidates_capped),
        "second readings capped": str(snapshot.rereads_capped),
        "last error": snapshot.last_error,
        "window (s)": f"{thresholds.window_s:g}",
        **(extra or {}),
    }
    node = qualified_name(namespace, node_name)
    camera = qualified_name(namespace, snapshot.camera)
    return _status(level, f"{node}: {snapshot.camera}", message, camera, values)


def node_status(
    node_name: str,
    cameras: Sequence[DiagnosticStatus],
    values: Mapping[str, str],
    namespace: str = "/",
) -> DiagnosticStatus:
    """Build the node's own status: the worst camera level and which cameras cause it.

    Args:
        node_name: node name without namespace.
        cameras: the camera statuses built by :func:`camera_status`.
        values: node-wide key/value pairs (workers, frames in flight, ...).
        namespace: the node's namespace.

    Returns:
        Status named ``"<node>: node"`` with ``hardware_id`` ``<node>``, the node's
        name qualified by the namespace (:func:`qualified_name`).
    """
    level = max((_level_of(s) for s in cameras), default=OK)
    problems = [
        f"{s.hardware_id} {_LEVEL_NAMES[_level_of(s)]}: {s.message}"
        for s in cameras
        if _level_of(s) != OK
    ]
    message = "; ".join(problems) if problems else f"all {len(cameras)} cameras ok"
    node = qualified_name(namespace, node_name)
    return _status(level, f"{node}: node", message, node, values)


def diagnostic_array(stamp: Time, statuses: Sequence[DiagnosticStatus]) -> DiagnosticArray:
    """Wrap statuses into the message published on /diagnostics."""
    array = DiagnosticArray()
    array.header = Header(stamp=stamp)
    array.status = list(statuses)
    return array


def _status(
    level: int, name: str, message: str, hardware_id: str, values: Mapping[str, str]
) -> DiagnosticStatus:
    status = DiagnosticStatus()
    # The message field is a ROS "byte": bytes of length 1 in rclpy.
    status.level = bytes([level])
    status.name = name
    status.message = message
    status.hardware_id = hardware_id
    status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
    return status


def _level_of(status: DiagnosticStatus) -> int:
    return status.level[0] if isinstance(status.level, bytes) else int(status.level)
