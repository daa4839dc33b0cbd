"""``marker-localizer replay``: run a bag through the node's own frame processing, offline.

Every ``/<cam>/image_raw`` (sensor_msgs/Image) frame of the input bag, or
``/<cam>/image_raw/compressed`` (sensor_msgs/CompressedImage, JPEG or PNG) where a
camera has no raw topic, goes
through :class:`marker_localizer.ros.processing.FrameProcessor`, the worker
pool the node uses, in its blocking mode: the reader waits for a free worker
instead of letting a newer frame replace a waiting one, so no frame is
dropped. Results are written to a new bag as ``/<cam>/marker_points`` at the
input frame's bag time (the header is the input's, unchanged, as the node
publishes it), with ``/diagnostics`` every second of bag time and once at the
end. The processor's clock is the bag time, as the node's is under
``use_sim_time`` with ``play --clock``.

Input the replay will not process, each counted per camera and shown in the summary:

* an image whose encoding the node does not accept (``skipped: encoding``);
* an image whose header stamp is not newer than the last processed frame of
  its camera (``skipped: order``). Replay streams the bag in one pass, and a
  stream consumer (the node, a navigation filter) cannot go back in time
  either, so such frames are skipped, not re-sorted; duplicates of a stamp
  are skipped by the same rule;
* a frame the processor rejects (bad step or data size, more than
  ``max_pixels``) or fails on (``failed``);
* a message whose bytes do not decode as its type (``undecodable``; counted per
  topic for the truth topics too): a cut-short or bit-flipped recording.

Damage to the storage itself is read around (:class:`~marker_localizer.bag.io.BagReader`):
an MCAP file cut short or damaged part-way is read front to back, so every
whole message still reaches the output, and the summary lists the damage.
``marker-localizer replay`` exits 0 when every image message gave a result, 3 when the
output was written but something was skipped, failed or unreadable (the
summary says what), 1 when nothing could be processed.

When the bag carries ``/<cam>/marker_points_truth`` (as ``simulate`` writes),
the detections of each frame are matched one-to-one to the truth of the same
stamp (minimum total distance, within ``match_distance_px``) and the summary
adds recall, false positives per frame and the error statistics. The recall's
interval clusters by marker where the truth names its markers (``simulate``'s
``marker_id`` field: a marker seen in many frames is one cluster), else by frame,
and the report says which. Detections on
a marker listed in ``/<cam>/marker_points_partial`` (cut by the frame border)
count neither way. A frame with a result but no truth at its stamp, and truth with
no result at its stamp (its frame skipped, or stamped otherwise), are counted
beside the accuracy, not evaluated.

Memory does not grow with the bag's length, but for the accuracy's tallies: results
go to the output bag as they come, the summary keeps running sums, and a frame is
matched to its truth as soon as both are in, then forgotten (:class:`TruthMatcher`).
The tallies keep a few numbers a frame and a matched marker, 8 bytes each, and a
truth point's marker id, 4 bytes
(:class:`~marker_localizer.evaluation.DetectionTally`: the error percentiles and the
intervals need them; about 100 MB for an hour of five cameras at 10 Hz with 14
matched markers of 15 a frame), and only where the bag has truth.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from sensor_msgs.msg import CompressedImage, Image, PointCloud2

from marker_localizer.bag.io import DEFAULT_STORAGE, BagMessage, BagReader, BagWriter
from marker_localizer.bag.record import PARTIAL_SUFFIX, TRUTH_SUFFIX, stamp_msg
from marker_localizer.config import NODE_NAME, DetectorConfig, TrackerConfig
from marker_localizer.core.image import underexposed, underexposure_warning
from marker_localizer.errors import BagError, ConfigError, ImageError, described, shorten
from marker_localizer.evaluation import (
    DEFAULT_GATE_PX,
    INTERVAL_HEADING,
    DetectionTally,
    interval_text,
    match_points,
)
from marker_localizer.ros.conversions import (
    ENCODINGS,
    ENCODINGS_TEXT,
    IMAGE_TRANSPORTS,
    MARKER_ID_FIELD,
    POINTS_SUFFIX,
    cloud_to_array,
    topic_name_problem,
    unsupported_encoding,
)
from marker_localizer.ros.diagnostics import bit_depth_warning
from marker_localizer.ros.parameters import NodeConfig, diagnostic_thresholds
from marker_localizer.ros.processing import FrameProcessor, stamp_to_ns

CLOUD_TYPE = "sensor_msgs/msg/PointCloud2"
DIAGNOSTICS_TOPIC = "/diagnostics"
#: What the recall's interval in the report assumes where the truth names no marker
#: (truth recorded without :data:`MARKER_ID_FIELD`): it clusters by frame alone; on a
#: flight that sees the same markers frame after frame it is narrower than the recall's
#: spread from one flight over other markers to the next (measured in seeded model
#: flights: ``test_evaluation``'s marker-clustered coverage test beside it).
RECALL_INTERVAL_ASSUMES = (
    "the recall's takes each frame's markers as other markers than the last frame's "
    "(the truth names none): for the same markers seen again it is too narrow"
)
#: What it does where every truth point names its marker (``simulate``'s truth): each
#: marker is one cluster of all its sightings, the same marker seen by several cameras
#: too (the truth's ids are the flight's).
RECALL_INTERVAL_BY_MARKER = (
    f"the recall's clusters by the truth's {MARKER_ID_FIELD}: a marker seen in many frames "
    "counts as one"
)


# --------------------------------------------------------------------------- report


@dataclass
class CameraReplay:
    """What replay did with one camera's frames.

    Attributes:
        camera: Camera name (the topic prefix, e.g. ``cam0``).
        frames: Frames processed and written.
        full_frame_passes: Of those, the frames the detector searched whole: every
            frame without tracking; with it, the scheduled passes and the frames where
            tracking failed (as the camera's diagnostics count them).
        markers: Markers detected in them.
        processing_ms_total: Over the processed frames, the time from submission
            to the worker pool to the delivered result, ms (conversion, detection,
            point cloud packing): a sum, not a list, so that a long bag costs no memory.
        skipped_encoding: Frames with an encoding the node does not accept.
        skipped_out_of_order: Frames whose stamp was not newer than the last one.
        failed: Frames the processor rejected or failed on.
        undecodable: Image messages whose bytes do not decode.
        last_error: Text of the newest failure (or refusal of an encoding).
        bit_depth_hint: Where every 16-bit frame of the replay's last statistics window
            stayed dim at the configured bit depth, the depth its levels fit
            (:func:`~marker_localizer.core.image.bit_depth_hint`); None otherwise.
        peak_share: The brightest level of that window's frames over white (NaN:
            none read); under half, the report calls them underexposed
            (:func:`~marker_localizer.core.image.underexposed`).
        evaluation: Against the bag's truth; None without truth topics.
        without_truth: Of the frames processed, those with no truth at their stamp,
            not evaluated (where the bag has truth).
        truth_without_result: Truth messages whose stamp has no processed frame: its
            frame skipped, or stamped otherwise.
    """

    camera: str
    frames: int = 0
    full_frame_passes: int = 0
    markers: int = 0
    processing_ms_total: float = 0.0
    skipped_encoding: int = 0
    skipped_out_of_order: int = 0
    failed: int = 0
    undecodable: int = 0
    last_error: str = ""
    bit_depth_hint: int | None = None
    peak_share: float = math.nan
    evaluation: DetectionTally | None = None
    without_truth: int = 0
    truth_without_result: int = 0

    @property
    def skipped(self) -> int:
        """Image messages that gave no result, for any reason."""
        return self.skipped_encoding + self.skipped_out_of_order + self.failed + self.undecodable

    @property
    def markers_per_frame(self) -> float:
        """Mean markers per processed frame (NaN if none)."""
        return self.markers / self.frames if self.frames else math.nan

    @property
    def mean_ms(self) -> float:
        """Mean processing time per frame, ms (NaN if none)."""
        return self.processing_ms_total / self.frames if self.frames else math.nan


@dataclass
class ReplayReport:
    """Outcome of :func:`replay_bag`.

    Attributes:
        bag: Input bag.
        out: Output bag.
        workers: Workers used.
        worker_processes: whether they were processes (or threads).
        wall_s: Wall time from the first frame read to the last result written, s.
        cameras: Per camera, in topic order.
        undecodable: Per topic other than the images (truth), messages whose
            bytes do not decode, or decode to points without x and y.
        damage: What the reader could not read, one line each.
        unread_topics: Image topics not read, each with why (:func:`unread_image_topics`).
        match_distance_px: the largest detection-to-truth distance of a match, px.
    """

    bag: Path
    out: Path
    workers: int
    worker_processes: bool
    wall_s: float
    cameras: dict[str, CameraReplay]
    undecodable: dict[str, int] = field(default_factory=dict)
    damage: list[str] = field(default_factory=list)
    unread_topics: dict[str, str] = field(default_factory=dict)
    match_distance_px: float = DEFAULT_GATE_PX

    @property
    def complete(self) -> bool:
        """Every image message gave a result and the whole bag could be read."""
        return not (
            self.damage
            or any(self.undecodable.values())
            or any(c.skipped for c in self.cameras.values())
        )

    @property
    def frames(self) -> int:
        """Frames processed, all cameras."""
        return sum(c.frames for c in self.cameras.values())

    @property
    def frames_per_s(self) -> float:
        """Processed frames per second of wall time."""
        return self.frames / self.wall_s if self.wall_s > 0 else math.nan

    @property
    def evaluation(self) -> DetectionTally | None:
        """All cameras' evaluations merged (None without truth)."""
        parts = [c.evaluation for c in self.cameras.values() if c.evaluation is not None]
        return DetectionTally.merged(parts) if parts else None


def format_report(report: ReplayReport) -> str:
    """The summary tables replay prints: throughput per camera, then accuracy if truth exists."""
    cams = list(report.cameras.values())
    lines = [
        f"replayed {report.bag} -> {report.out}: {report.frames} frames in "
        f"{report.wall_s:.2f} s ({report.frames_per_s:.2f} frames/s, {report.workers} worker "
        f"{'processes' if report.worker_processes else 'threads'})",
        f"{'camera':<12}{'frames':>8}{'full-frame passes':>19}{'markers/frame':>15}"
        f"{'ms/frame':>10}{'skipped: encoding':>19}{'order':>7}{'failed':>8}{'undecodable':>13}",
    ]
    total = CameraReplay(
        "all",
        frames=report.frames,
        full_frame_passes=sum(c.full_frame_passes for c in cams),
        markers=sum(c.markers for c in cams),
        processing_ms_total=sum(c.processing_ms_total for c in cams),
        skipped_encoding=sum(c.skipped_encoding for c in cams),
        skipped_out_of_order=sum(c.skipped_out_of_order for c in cams),
        failed=sum(c.failed for c in cams),
        undecodable=sum(c.undecodable for c in cams),
    )
    for c in [*cams, total]:
        lines.append(
            f"{c.camera:<12}{c.frames:>8}{c.full_frame_passes:>19}{c.markers_per_frame:>15.2f}"
            f"{c.mean_ms:>10.1f}"
            f"{c.skipped_encoding:>19}{c.skipped_out_of_order:>7}{c.failed:>8}{c.undecodable:>13}"
        )
    for c in cams:
        if c.last_error:
            lines.append(f"{c.camera}: last failure: {c.last_error}")
        if c.skipped_out_of_order:
            lines.append(
                f"{c.camera}: {c.skipped_out_of_order} frames stamped no later than the one "
                "before (a message recorded twice; a driver that leaves header.stamp unset "
                "stamps every frame 0)"
            )
        if c.bit_depth_hint is not None:
            lines.append(f"{c.camera}: {bit_depth_warning(c.bit_depth_hint)}")
        elif underexposed(c.peak_share):
            lines.append(f"{c.camera}: {underexposure_warning(c.peak_share)}")
        if c.without_truth:
            lines.append(
                f"{c.camera}: {c.without_truth} frames not evaluated: no "
                f"{TRUTH_SUFFIX} at their stamp"
            )
        if c.truth_without_result:
            lines.append(
                f"{c.camera}: {c.truth_without_result} {TRUTH_SUFFIX} messages not "
                "evaluated: no frame processed at their stamp (skipped, stamped "
                "otherwise, or its truth out of stamp order)"
            )
    lines += [f"not read: {topic} ({why})" for topic, why in report.unread_topics.items()]
    lines += [f"undecodable {topic}: {n} skipped" for topic, n in report.undecodable.items()]
    lines += [f"damaged storage: {line}" for line in report.damage]
    if not report.complete:
        lines.append(
            f"incomplete: {total.skipped} image messages gave no result"
            + (", the storage is damaged" if report.damage else "")
            + f"; every frame that gave a result is in {report.out}"
        )
    overall = report.evaluation
    if overall is None:
        return "\n".join(lines)
    rows = [(c.camera, c.evaluation) for c in cams if c.evaluation is not None]
    rows.append(("all", overall))
    lines += [
        f"accuracy against {TRUTH_SUFFIX} (one-to-one matches within "
        f"{report.match_distance_px:g} px; "
        f"{INTERVAL_HEADING} intervals widened by the spread between their clusters; "
        f"{_recall_interval_note(rows)}):",
        f"{'camera':<12}{'truth':>7}{'recall':>8}{INTERVAL_HEADING:>13}{'FP/frame':>10}"
        f"{INTERVAL_HEADING:>12}"
        f"{'mean px':>9}{'RMS px':>9}{'p95 px':>9}{'max px':>9}",
    ]
    for name, evaluation in rows:
        stats = evaluation.stats
        lines.append(
            f"{name:<12}{evaluation.n_truth:>7}{evaluation.recall:>8.3f}"
            f"{interval_text(evaluation.recall_interval, 3):>13}"
            f"{evaluation.fp_per_frame:>10.2f}{interval_text(evaluation.fp_per_frame_interval):>12}"
            f"{stats.mean:>9.4f}{stats.rms:>9.4f}{stats.p95:>9.4f}{stats.max:>9.4f}"
        )
    return "\n".join(lines)


def _recall_interval_note(rows: Sequence[tuple[str, DetectionTally]]) -> str:
    """What the accuracy table's recall intervals cluster by; the rows named where they differ."""
    by_marker = [name for name, tally in rows if tally.clustered_by_marker]
    by_frame = [name for name, tally in rows if not tally.clustered_by_marker]
    if not by_frame:
        return RECALL_INTERVAL_BY_MARKER
    if not by_marker:
        return RECALL_INTERVAL_ASSUMES
    return (
        f"{RECALL_INTERVAL_BY_MARKER} ({', '.join(by_marker)}); "
        f"{RECALL_INTERVAL_ASSUMES} ({', '.join(by_frame)})"
    )


# --------------------------------------------------------------------------- replay


def image_cameras(
    topics: dict[str, str], message_counts: dict[str, int] | None = None
) -> dict[str, str]:
    """Cameras of a bag and the image topic each is read from.

    A camera is a namespace with ``<cam>/image_raw`` (sensor_msgs/Image) or
    ``<cam>/image_raw/compressed`` (sensor_msgs/CompressedImage), the node's two
    ``image_transport`` inputs, whose output topics ROS 2 takes as names; where a
    bag has both, the raw one is read, unless ``message_counts`` (topic ->
    messages) shows it empty and the compressed one not: a recording may declare
    a topic that never carried a frame.

    Returns:
        Camera name (the topic's namespace without the leading slash) -> image topic.
    """
    counts = message_counts or {}
    cameras: dict[str, str] = {}
    # Raw last, so that it wins where a camera has both, unless it holds no frame.
    for suffix, message_type in reversed(IMAGE_TRANSPORTS.values()):
        msgtype = f"sensor_msgs/msg/{message_type.__name__}"
        for topic in sorted(t for t, m in topics.items() if m == msgtype):
            camera = _camera_of(topic, suffix)
            if camera is None or _camera_name_problem(camera) is not None:
                continue
            chosen = cameras.get(camera)
            if chosen is None or counts.get(topic, 0) or not counts.get(chosen, 0):
                cameras[camera] = topic
    return dict(sorted(cameras.items()))


def unread_image_topics(topics: dict[str, str], cameras: dict[str, str]) -> dict[str, str]:
    """The bag's image topics (Image, CompressedImage) that replay does not read, each with why.

    Args:
        topics: topic -> type, every topic of the bag.
        cameras: what :func:`image_cameras` gave for them.
    """
    read = set(cameras.values())
    unread: dict[str, str] = {}
    for suffix, message_type in IMAGE_TRANSPORTS.values():
        msgtype = f"sensor_msgs/msg/{message_type.__name__}"
        for topic in sorted(t for t, m in topics.items() if m == msgtype and t not in read):
            camera = _camera_of(topic, suffix)
            if camera is None and topic.strip("/") == suffix:
                unread[topic] = f"no camera's namespace: a camera's images are /<cam>/{suffix}"
            elif camera is None:
                unread[topic] = f"not /<cam>/{suffix}"
            elif (problem := _camera_name_problem(camera)) is not None:
                unread[topic] = f"camera {camera!r}: {problem}"
            else:
                unread[topic] = f"camera {camera} is read from {cameras[camera]}"
    # A camera's input name holding another type (a String on /cam0/image_raw, say).
    for suffix, message_type in IMAGE_TRANSPORTS.values():
        msgtype = f"sensor_msgs/msg/{message_type.__name__}"
        for topic, other in topics.items():
            if topic.endswith(f"/{suffix}") and other != msgtype and topic not in unread:
                unread[topic] = f"holds {other}, not {msgtype}"
    return dict(sorted(unread.items()))


def _camera_of(topic: str, suffix: str) -> str | None:
    """The camera whose ``suffix`` topic ``topic`` is (its namespace); None if none."""
    camera = topic.removesuffix(f"/{suffix}").lstrip("/")
    return camera if topic.endswith(f"/{suffix}") and camera else None


def _camera_name_problem(camera: str) -> str | None:
    """Why ROS 2 would refuse ``camera``'s output topic, as the node's publisher would."""
    return topic_name_problem(f"/{camera}/{POINTS_SUFFIX}")


def _points(cloud: PointCloud2) -> tuple[np.ndarray, np.ndarray | None]:
    """(N, 2) the points' x and y, and (N,) their marker ids where the cloud names them.

    The ids are the truth's :data:`MARKER_ID_FIELD` (None: a cloud without it, as
    truth recorded before it was written, and the node's detections). A cloud of no
    points is no markers, whatever fields it declares.

    Raises:
        ImageError: points without x and y, or marker ids that are no uint32
            values (the tallies keep them so).
    """
    points = cloud_to_array(cloud)
    names = points.dtype.names or ()
    ids = None
    if MARKER_ID_FIELD in names:
        ids = points[MARKER_ID_FIELD]
        uint32 = np.iinfo(np.uint32)
        if not np.issubdtype(ids.dtype, np.integer) or (
            len(ids) and not uint32.min <= ids.min() <= ids.max() <= uint32.max
        ):
            raise ImageError(
                f"point field {MARKER_ID_FIELD!r} of {ids.dtype} holds no marker ids "
                f"(integers {uint32.min}-{uint32.max})"
            )
        ids = ids.astype(np.uint32)
    if not len(points):
        return np.empty((0, 2)), ids
    if not {"x", "y"} <= set(names):
        fields = ", ".join(map(repr, names)) or "none"
        raise ImageError(f"points without fields 'x' and 'y' (their fields: {shorten(fields)})")
    return np.column_stack([points["x"], points["y"]]), ids


@dataclass
class _InFlight:
    stamp_ns: int
    time_ns: int
    started_s: float


#: The kind of a frame's detections among its parts (:meth:`TruthMatcher.add`); its
#: truth and its partial list are :data:`TRUTH_SUFFIX` and :data:`PARTIAL_SUFFIX`.
FOUND = "found"
#: The part that says a frame gives no detections: skipped or failed
#: (:meth:`TruthMatcher.no_result`).
NO_RESULT = "no result"
#: The part beside a frame's truth that names its markers, where the truth does.
TRUTH_MARKER_IDS = "truth marker ids"


class TruthMatcher:
    """Each frame of the cameras with truth, matched once its parts are in, then forgotten.

    A frame's parts are its detections, its truth and, where the camera has a
    partial topic, its partial list. They come in any order (results come back from
    the workers while the reader goes on), and only the frames still waiting for a
    part are held; a frame stops waiting for a part that can no longer come:

    * its detections, once the camera has a result for a later stamp: a camera's
      results come in stamp order, and replay skips a frame older than the last;
      or at once where the frame was skipped for its encoding or failed
      (:meth:`no_result`), so that a camera whose every frame is skipped holds no truth;
    * its truth, once the camera's truth for a later stamp is in: truth is taken to
      come in stamp order, as ``simulate`` writes it (a frame with no truth, as
      where truth is given for some frames only, is then not evaluated, as before);
    * its partial list likewise; the frame is then matched without one.

    A frame forgotten with its detections but no truth, or its truth but no
    detections, is counted (:attr:`without_truth`, :attr:`truth_without_result`).

    So a bag of any length holds a frame or so per camera here, or where only some
    frames have truth, those between two that have (measured: at most 2 frames
    on a 3000-frame, five-camera bag with truth, where all were held to the end before).

    Args:
        truth_cameras: the cameras with a truth topic: each gets a tally.
        partial_cameras: those of them with a partial topic.
        match_distance_px: largest detection-to-truth distance of a match, px.
    """

    def __init__(
        self,
        truth_cameras: Collection[str],
        partial_cameras: Collection[str],
        match_distance_px: float,
    ) -> None:
        #: Per camera with truth, the tally of its frames matched so far.
        self.tallies = {camera: DetectionTally() for camera in truth_cameras}
        #: Per camera with truth, its frames forgotten with detections but no truth.
        self.without_truth = dict.fromkeys(truth_cameras, 0)
        #: Per camera with truth, its frames forgotten with truth but no detections.
        self.truth_without_result = dict.fromkeys(truth_cameras, 0)
        self._partial_cameras = set(partial_cameras)
        self._match_distance_px = match_distance_px
        # camera -> stamp ns -> the parts in so far, by kind.
        self._waiting: dict[str, dict[int, dict[str, np.ndarray]]] = {
            camera: {} for camera in truth_cameras
        }
        # camera -> kind -> the newest stamp of a part of that kind, ns.
        self._newest: dict[str, dict[str, int]] = {camera: {} for camera in truth_cameras}

    @property
    def waiting(self) -> int:
        """Frames held, waiting for a part."""
        return sum(len(frames) for frames in self._waiting.values())

    def wants(self, camera: str) -> bool:
        """Whether ``camera``'s frames are evaluated (it has a truth topic)."""
        return camera in self.tallies

    def add(
        self,
        kind: str,
        camera: str,
        stamp_ns: int,
        xy: np.ndarray,
        marker_ids: np.ndarray | None = None,
    ) -> None:
        """One part of a frame; nothing for a camera without truth.

        Args:
            kind: :data:`FOUND`, :data:`TRUTH_SUFFIX` or :data:`PARTIAL_SUFFIX`.
            camera: the frame's camera.
            stamp_ns: its header stamp, ns.
            xy: (N, 2) the part's points, px. A later part of the same kind replaces
                an earlier one while the frame waits.
            marker_ids: (N,) for the truth, each point's marker, where the truth names
                them (the recall's interval then clusters by marker); else None.
        """
        if not self.wants(camera):
            return
        frames = self._waiting[camera]
        parts = frames.setdefault(stamp_ns, {})
        parts[kind] = xy
        if kind == TRUTH_SUFFIX and marker_ids is not None:
            parts[TRUTH_MARKER_IDS] = marker_ids
        elif kind == TRUTH_SUFFIX:
            parts.pop(TRUTH_MARKER_IDS, None)
        newest = self._newest[camera]
        newest[kind] = max(newest.get(kind, stamp_ns), stamp_ns)
        for stamp in list(frames):
            self._settle(camera, stamp, frames[stamp], final=False)

    def no_result(self, camera: str, stamp_ns: int) -> None:
        """The frame of ``camera`` at ``stamp_ns`` gives no detections (skipped, failed).

        Its truth, in or to come, is then not held for detections; where another
        frame of the same stamp gave some, they are matched as before.
        """
        if not self.wants(camera):
            return
        parts = self._waiting[camera].setdefault(stamp_ns, {})
        parts[NO_RESULT] = np.empty((0, 2))
        self._settle(camera, stamp_ns, parts, final=False)

    def finish(self) -> None:
        """Match the frames still waiting for their partial list, each without it."""
        for camera, frames in self._waiting.items():
            for stamp in list(frames):
                self._settle(camera, stamp, frames[stamp], final=True)
            frames.clear()

    def _settle(self, camera: str, stamp: int, parts: dict[str, np.ndarray], final: bool) -> None:
        """Match the frame if it can be, forget it if it can no longer be; else leave it."""
        newest = self._newest[camera]

        def over(kind: str) -> bool:  # a part of this kind will not come any more
            return final or newest.get(kind, stamp) > stamp

        skipped_alone = NO_RESULT in parts and not ({FOUND, TRUTH_SUFFIX} & parts.keys())
        if skipped_alone and not over(TRUTH_SUFFIX):
            return  # its truth may be still to come: forgotten with it
        if (FOUND not in parts and (NO_RESULT in parts or over(FOUND))) or (
            TRUTH_SUFFIX not in parts and over(TRUTH_SUFFIX)
        ):
            del self._waiting[camera][stamp]
            if FOUND in parts:
                self.without_truth[camera] += 1
            elif TRUTH_SUFFIX in parts:
                self.truth_without_result[camera] += 1
            return
        if FOUND not in parts or TRUTH_SUFFIX not in parts:
            return
        if not (
            PARTIAL_SUFFIX in parts or camera not in self._partial_cameras or over(PARTIAL_SUFFIX)
        ):
            return
        del self._waiting[camera][stamp]
        self.tallies[camera].add(
            match_points(
                parts[FOUND],
                parts[TRUTH_SUFFIX],
                self._match_distance_px,
                parts.get(PARTIAL_SUFFIX),
            ),
            truth_marker_ids=parts.get(TRUTH_MARKER_IDS),
        )


class _Session:
    """Feeds one bag's frames to a FrameProcessor and writes what comes back.

    Worker threads only queue their results; the reading thread writes them
    (the sqlite3 storage accepts writes only from the thread that opened it)
    and hands them to the evaluation.
    """

    def __init__(
        self,
        cameras: Sequence[str],
        config: DetectorConfig,
        tracker_config: TrackerConfig,
        writer: BagWriter,
        workers: int,
        worker_processes: bool,
        evaluation: TruthMatcher,
    ) -> None:
        self.writer = writer
        self.workers = workers
        self.stats = {c: CameraReplay(c) for c in cameras}
        self.evaluation = evaluation
        self._last_stamp: dict[str, int] = {}
        self._in_flight: dict[str, _InFlight] = {}
        # (camera, header stamp ns, bag time ns, cloud) of each result not yet written.
        self._done: list[tuple[str, int, int, PointCloud2]] = []
        # (camera, header stamp ns) of each failed frame not yet told the evaluation.
        self._failed: list[tuple[str, int]] = []
        self._cond = threading.Condition()
        self.now_ns = 0
        settings = NodeConfig()
        self._thresholds = diagnostic_thresholds(settings)
        self._diagnostics_period_ns = round(settings.diagnostics_period_s * 1e9)
        self._next_diagnostics_ns: int | None = None
        self.processor = FrameProcessor(
            cameras,
            config,
            self._on_result,
            workers=workers,
            worker_processes=worker_processes,
            max_frame_age_s=0.0,
            clock_ns=lambda: self.now_ns,
            on_error=self._on_error,
            stats_window_s=settings.stats_window_s,
            steady_silence=False,
            tracker_config=tracker_config,
        )

    def submit(self, camera: str, message: BagMessage) -> None:
        """Hand one image to the pool, or count why it is skipped."""
        stats = self.stats[camera]
        self.now_ns = message.time_ns
        try:
            image: Image | CompressedImage = message.decode()
        except BagError as err:
            stats.undecodable += 1
            stats.last_error = shorten(str(err))
            return
        stamp_ns = stamp_to_ns(image.header)
        # The diagnostics count what is skipped here as the node would: a frame it
        # received, and for its encoding one that failed.
        if isinstance(image, Image) and image.encoding not in ENCODINGS:
            refused = unsupported_encoding(image.encoding)
            stats.skipped_encoding += 1
            stats.last_error = shorten(described(refused))
            self.processor.skipped(camera, image, refused)
            self.evaluation.no_result(camera, stamp_ns)
            return
        if stamp_ns <= self._last_stamp.get(camera, -1):
            stats.skipped_out_of_order += 1
            self.processor.skipped(camera, image, None)
            # No no_result: a frame of this stamp may be in flight (a message recorded
            # twice), whose truth would be forgotten before its result came. The
            # camera's next result settles an older stamp anyway.
            return
        self._last_stamp[camera] = stamp_ns
        # Start a frame only when a worker and the camera are free: the pool then
        # never holds a waiting frame, and submission-to-result is processing time.
        with self._cond:
            self._cond.wait_for(
                lambda: len(self._in_flight) < self.workers and camera not in self._in_flight
            )
            self._in_flight[camera] = _InFlight(stamp_ns, message.time_ns, time.perf_counter())
        self._write_done()
        if not self.processor.submit(camera, image, block=True):
            raise BagError(f"{self.writer.path}: the worker pool stopped unexpectedly")
        self._maybe_write_diagnostics()

    def finish(self) -> None:
        """Wait for every frame in flight, write the results and the final diagnostics."""
        with self._cond:
            self._cond.wait_for(lambda: not self._in_flight)
        self.processor.wait_idle()
        for camera, snapshot in self.processor.snapshots().items():
            self.stats[camera].full_frame_passes = snapshot.full_frame_passes
            self.stats[camera].bit_depth_hint = snapshot.bit_depth_hint
            self.stats[camera].peak_share = snapshot.peak_share
        self._write_done()
        if self._next_diagnostics_ns is not None:
            self._write_diagnostics(self.now_ns)
        self.evaluation.finish()

    def _on_result(self, camera: str, cloud: PointCloud2) -> None:
        delivered_s = time.perf_counter()
        with self._cond:
            flight = self._in_flight.pop(camera)
            stats = self.stats[camera]
            stats.processing_ms_total += (delivered_s - flight.started_s) * 1e3
            stats.frames += 1
            stats.markers += int(cloud.width) * int(cloud.height)
            self._done.append((camera, flight.stamp_ns, flight.time_ns, cloud))
            self._cond.notify_all()

    def _on_error(self, camera: str, err: Exception) -> None:
        with self._cond:
            flight = self._in_flight.pop(camera, None)
            if flight is not None:
                self._failed.append((camera, flight.stamp_ns))
            stats = self.stats[camera]
            stats.failed += 1
            stats.last_error = shorten(described(err))
            self._cond.notify_all()

    def _write_done(self) -> None:
        with self._cond:
            done, self._done = self._done, []
            failed, self._failed = self._failed, []
        for camera, stamp_ns, time_ns, cloud in done:
            self.writer.write(f"/{camera}/{POINTS_SUFFIX}", time_ns, cloud)
            if self.evaluation.wants(camera):
                self.evaluation.add(FOUND, camera, stamp_ns, _points(cloud)[0])
        for camera, stamp_ns in failed:
            self.evaluation.no_result(camera, stamp_ns)

    def _maybe_write_diagnostics(self) -> None:
        if self._next_diagnostics_ns is None:
            self._next_diagnostics_ns = self.now_ns + self._diagnostics_period_ns
        elif self.now_ns >= self._next_diagnostics_ns:
            self._write_diagnostics(self.now_ns)
            self._next_diagnostics_ns = self.now_ns + self._diagnostics_period_ns

    def _write_diagnostics(self, time_ns: int) -> None:
        """The node's /diagnostics content, stamped and written at bag time ``time_ns``."""
        self.writer.write(
            DIAGNOSTICS_TOPIC,
            time_ns,
            self.processor.diagnostics(
                NODE_NAME, stamp_msg(time_ns), self._thresholds, node_values={"mode": "replay"}
            ),
        )


def replay_bag(
    bag: str | Path,
    out: str | Path,
    *,
    config: DetectorConfig | None = None,
    tracker_config: TrackerConfig | None = None,
    workers: int | None = None,
    worker_processes: bool | None = None,
    storage: str = DEFAULT_STORAGE,
    match_distance_px: float = DEFAULT_GATE_PX,
    progress: Callable[[int, int], None] | None = None,
) -> ReplayReport:
    """Process every image of ``bag`` with the node's frame processor; write the results.

    Args:
        bag: Input bag (directory, ``.mcap`` or ``.db3``).
        out: Output bag directory to create; must not exist. It appears only
            when the replay finished.
        config: Detector configuration (default: the defaults).
        tracker_config: Tracking settings (default: the defaults, as the node's).
        workers: Workers (default: the node's default).
        worker_processes: run the workers as processes (default: the node's default).
        storage: Storage of the output, ``"mcap"`` or ``"sqlite3"``.
        match_distance_px: Largest detection-to-truth distance of a match, px.
        progress: Called with (image messages handled, image messages in the bag).

    Returns:
        Per-camera counts, times and, when the bag has truth, accuracy.

    Raises:
        BagError: ``bag`` is missing, not a bag, corrupt or truncated, or has
            no ``<cam>/image_raw`` topic; ``out`` exists, is named as a bag file
            (``.mcap``, ``.db3``, ``.bag``) or cannot be written.
        ConfigError: ``workers`` < 1, or ``match_distance_px`` not a positive distance.
    """
    if not (math.isfinite(match_distance_px) and match_distance_px > 0):
        raise ConfigError(f"match_distance_px={match_distance_px!r} must be positive and finite")
    defaults = NodeConfig()
    workers = defaults.workers if workers is None else workers
    if worker_processes is None:
        worker_processes = defaults.worker_processes
    with BagReader(bag) as reader:
        topics = reader.topics
        counts = reader.message_counts
        cameras = image_cameras(topics, counts)
        unread = unread_image_topics(topics, cameras)
        if not cameras:
            listed = ", ".join(f"{t} ({m})" for t, m in sorted(topics.items())) or "none"
            why = "".join(f"; {t}: {reason}" for t, reason in unread.items())
            raise BagError(
                f"{bag}: no image topics (sensor_msgs/msg/Image on /<cam>/image_raw or "
                f"sensor_msgs/msg/CompressedImage on /<cam>/image_raw/compressed); "
                f"topics: {shorten(listed)}{shorten(why)}"
            )
        truth = _cloud_topics(topics, cameras, TRUTH_SUFFIX)
        partial = _cloud_topics(topics, cameras, PARTIAL_SUFFIX)
        topic_camera = {topic: cam for cam, topic in cameras.items()}
        total = sum(counts.get(t, 0) for t in cameras.values())
        evaluation = TruthMatcher(truth, partial, match_distance_px)
        cloud_kind = {t: (TRUTH_SUFFIX, c) for c, t in truth.items()}
        cloud_kind |= {t: (PARTIAL_SUFFIX, c) for c, t in partial.items()}
        undecodable: dict[str, int] = {}
        with BagWriter(out, storage) as writer:
            for camera in cameras:
                writer.add_topic(f"/{camera}/{POINTS_SUFFIX}", CLOUD_TYPE)
            writer.add_topic(DIAGNOSTICS_TOPIC, "diagnostic_msgs/msg/DiagnosticArray")
            session = _Session(
                list(cameras),
                config or DetectorConfig(),
                tracker_config or TrackerConfig(),
                writer,
                workers,
                worker_processes,
                evaluation,
            )
            started = time.perf_counter()
            handled = 0
            try:
                for message in reader.messages({*cameras.values(), *cloud_kind}):
                    if message.topic in cloud_kind:
                        kind, camera = cloud_kind[message.topic]
                        try:
                            cloud: PointCloud2 = message.decode()
                            evaluation.add(kind, camera, stamp_to_ns(cloud.header), *_points(cloud))
                        except (BagError, ImageError):
                            undecodable[message.topic] = undecodable.get(message.topic, 0) + 1
                        continue
                    session.submit(topic_camera[message.topic], message)
                    handled += 1
                    if progress is not None:
                        progress(handled, total)
                session.finish()
                if not handled:
                    _no_frames(bag, list(cameras.values()), counts, unread, reader.damage)
                _require_results(bag, session.stats, unread)
            finally:
                session.processor.shutdown()
            wall_s = time.perf_counter() - started
        damage = list(reader.damage)
    for camera, tally in evaluation.tallies.items():
        session.stats[camera].evaluation = tally
        session.stats[camera].without_truth = evaluation.without_truth[camera]
        session.stats[camera].truth_without_result = evaluation.truth_without_result[camera]
    return ReplayReport(
        Path(bag),
        Path(out),
        workers,
        worker_processes,
        wall_s,
        session.stats,
        undecodable,
        damage,
        unread,
        match_distance_px,
    )


def _no_frames(
    bag: str | Path,
    read: list[str],
    counts: dict[str, int],
    unread: dict[str, str],
    damage: list[str],
) -> None:
    """Raise for a bag whose image topics read gave no message (declared, never written).

    The error says so and what the bag holds instead (``camera_info`` without
    frames, say), and the damage where the storage is damaged (a recording cut
    before its first frame), rather than counting no frame as 0 skipped of each kind.
    """
    held = ", ".join(f"{topic} {n}" for topic, n in sorted(counts.items()) if n)
    not_read = "".join(f"; not read: {topic} ({why})" for topic, why in unread.items())
    if damage:  # what could be read of a damaged storage, not what it held
        found = f"read of the bag: {shorten(held)}" if held else "nothing could be read"
    else:
        found = f"the bag holds: {shorten(held)}" if held else "the bag holds no message"
    damaged = f"; damaged storage: {shorten('; '.join(damage))}" if damage else ""
    raise BagError(
        f"{bag}: no frame to process: no message on {shorten(', '.join(read))} "
        f"({found}){shorten(not_read)}{damaged}"
    )


def _require_results(
    bag: str | Path, stats: dict[str, CameraReplay], unread: dict[str, str]
) -> None:
    """Raise when no frame gave a result: the output bag is then not kept.

    The error names the image topics not read (``unread``, as the summary would):
    a camera's compressed copies, say, beside raw frames of an unsupported encoding.
    """
    if any(c.frames for c in stats.values()):
        return
    skipped_encoding = sum(c.skipped_encoding for c in stats.values())
    skipped_order = sum(c.skipped_out_of_order for c in stats.values())
    undecodable = sum(c.undecodable for c in stats.values())
    failed = [c for c in stats.values() if c.last_error]
    reason = f"; last failure: {failed[-1].last_error}" if failed else ""
    not_read = "".join(f"; not read: {topic} ({why})" for topic, why in unread.items())
    raise BagError(
        f"{bag}: no frame could be processed ({skipped_encoding} with an unsupported "
        f"encoding, {skipped_order} out of order, {sum(c.failed for c in stats.values())} "
        f"failed, {undecodable} undecodable; supported encodings: {ENCODINGS_TEXT})"
        f"{reason}{shorten(not_read)}"
    )


def _cloud_topics(topics: dict[str, str], cameras: dict[str, str], suffix: str) -> dict[str, str]:
    return {
        camera: f"/{camera}/{suffix}"
        for camera in cameras
        if topics.get(f"/{camera}/{suffix}") == CLOUD_TYPE
    }
