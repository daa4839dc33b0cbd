"""Detections scored against truth: one-to-one matching, recall, false positives, errors.

One module for every place that scores detections: ``bench accuracy`` (our
detector and its peers), ``replay`` and the tests (a bag's truth topics). Plain
numpy geometry with no knowledge of any detector. Coordinates: (N, 2) float64
arrays of (x, y) pixels, (0, 0) at the centre of the top-left pixel.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats
from scipy.optimize import linear_sum_assignment

from marker_localizer.core import verification

#: Default largest distance between a detection and the truth it may claim, px.
#: Two pixels: well above any refinement error worth the name, well below the
#: spacing of distinct markers (or of chessboard corners in the rendered families).
DEFAULT_GATE_PX = 2.0
#: Error level whose share the tables report (the paper's Table 1 uses 0.1 px).
FINE_ERROR_PX = 0.1
#: A candidate this close to a missed marker counts as its candidate when
#: :func:`tests_that_lost` looks for where the marker was lost, px: before the
#: centring, screening candidates sit up to about 2 px off a small marker's centre
#: (split peaks, coarse pyramid levels).
LOSS_RADIUS_PX = 3.0
#: :func:`tests_that_lost`'s answer for a marker that every test kept a candidate
#: near: its detection ended farther from it than the matching gate.
ASTRAY = "astray"
#: A detection lies this close to its own place in a survivor list when
#: :func:`readings_that_added` looks for the reading that added it, px: the lists hold
#: the detections' very positions, and no two detections lie within the detector's
#: merge radius (``DetectorConfig.merge_radius_px``) of each other.
ADDED_RADIUS_PX = 0.5
#: :func:`readings_that_added`'s answer for a detection no reading's list holds (a
#: detector whose survivors name other readings).
UNLISTED = "unlisted"
#: Coverage of the intervals beside a recall and a false-point rate
#: (:func:`recall_interval`, :func:`rate_interval`): the benchmark's sets hold
#: 36-600 markers and 3-24 frames, where those figures move by several points from
#: one sample of frames to the next.
INTERVAL_LEVEL = 0.95
#: The share of intervals that held the truth, measured (seeded Monte Carlo, 5000
#: draws each) on 3-24 frames of 12-30 markers whose recall or false-point rate
#: differs from frame to frame (intra-frame correlation 0-0.2, gamma-Poisson counts of
#: shape 0.3-2) or does not: with Student's t on frames - 1 degrees of freedom,
#: 0.942-1.000 (1.000 where the frames do not spread: the price of reading their spread
#: from three or four); with the normal quantile, as before, 0.69-0.94 where they
#: spread (``test_the_recall_interval_covers_its_level_where_the_frames_spread``).
INTERVAL_COVERAGE_MEASURED = (0.942, 1.000)
#: The heading of an interval's column in a printed table: its coverage.
INTERVAL_HEADING = f"{INTERVAL_LEVEL:.0%}"


@dataclass(frozen=True)
class Matching:
    """One-to-one pairing of detections with truth points inside a distance gate.

    Attributes:
        truth_index: (K,) index into the truth of every matched pair.
        detection_index: (K,) index into the detections of every matched pair.
        errors_px: (K,) Euclidean distance of every pair, px.
        n_truth: number of truth points.
        n_detections: number of detections.
        excused_index: indices of the unmatched detections within the gate of an
            excused point (a marker cut by the frame border): neither found nor false.
    """

    truth_index: np.ndarray
    detection_index: np.ndarray
    errors_px: np.ndarray
    n_truth: int
    n_detections: int
    excused_index: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))

    @property
    def n_matched(self) -> int:
        """Number of matched pairs (true positives)."""
        return len(self.errors_px)

    @property
    def n_false_positives(self) -> int:
        """Detections that claimed no truth point and are not excused."""
        return len(self.unmatched_detections)

    @property
    def unmatched_detections(self) -> np.ndarray:
        """Indices of the detections that claimed no truth point and are not excused."""
        claimed = np.concatenate([self.detection_index, self.excused_index])
        return np.setdiff1d(np.arange(self.n_detections), claimed)


def match_points(
    detections: np.ndarray,
    truth: np.ndarray,
    gate_px: float = DEFAULT_GATE_PX,
    excused: np.ndarray | None = None,
) -> Matching:
    """Pair detections with truth points one-to-one, minimising the summed distance.

    A pair farther apart than ``gate_px`` is never made, so a second detection
    on the same marker, or one on clutter, stays unmatched (a false positive).

    Args:
        detections: (N, 2) detected points, px; rows with NaN never match.
        truth: (M, 2) true points, px.
        gate_px: largest distance of a valid pair, px.
        excused: (K, 2) points that count neither way, px: an unmatched
            detection within ``gate_px`` of one is no false positive (a marker
            cut by the frame border, whose truth is not required to be found).

    Returns:
        The :class:`Matching`.
    """
    det = np.asarray(detections, dtype=np.float64).reshape(-1, 2)
    ref = np.asarray(truth, dtype=np.float64).reshape(-1, 2)
    rows: np.ndarray = np.empty(0, dtype=np.int64)
    cols: np.ndarray = rows
    distance: np.ndarray = np.empty((len(ref), len(det)))
    if len(det) and len(ref):
        distance = np.linalg.norm(ref[:, None, :] - det[None, :, :], axis=2)
        distance = np.where(np.isfinite(distance), distance, np.inf)
        # Pairs beyond the gate get a cost no valid assignment can prefer.
        cost = np.where(distance <= gate_px, distance, 1e6)
        rows, cols = linear_sum_assignment(cost)
        valid = distance[rows, cols] <= gate_px
        rows, cols = rows[valid], cols[valid]
    unmatched = np.setdiff1d(np.arange(len(det)), cols)
    excused_index: np.ndarray = np.empty(0, dtype=np.int64)
    if excused is not None:
        excused_index = unmatched[nearest_distances(det[unmatched], excused) <= gate_px]
    return Matching(rows, cols, distance[rows, cols], len(ref), len(det), excused_index)


def nearest_distances(points: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Distance from every point to its nearest target, px (inf without targets).

    Args:
        points: (N, 2) points, px.
        targets: (M, 2) points, px.

    Returns:
        (N,) distances, px.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    ref = np.asarray(targets, dtype=np.float64).reshape(-1, 2)
    if len(ref) == 0:
        return np.full(len(pts), np.inf)
    return np.linalg.norm(pts[:, None, :] - ref[None, :, :], axis=2).min(axis=1, initial=np.inf)


def tests_that_lost(
    survivors: Sequence[tuple[str, np.ndarray]],
    missed: np.ndarray,
    radius_px: float = LOSS_RADIUS_PX,
) -> list[str]:
    """For each missed marker, the first test after which no candidate was left near it.

    Args:
        survivors: (test, (K, 2) positions of the candidates that passed it), in
            the order the tests ran (a detector's ``DetectionResult.survivors``).
        missed: (M, 2) true centres of the markers not found, px.
        radius_px: how near a candidate must be to count as the marker's, px.

    Returns:
        M test names; :data:`ASTRAY` where a candidate passed every test.
    """
    points = np.asarray(missed, dtype=np.float64).reshape(-1, 2)
    lost = [ASTRAY] * len(points)
    alive = np.ones(len(points), dtype=bool)
    for test, xy in survivors:
        near = nearest_distances(points, xy) <= radius_px
        for k in np.flatnonzero(alive & ~near):
            lost[k] = test
        alive &= near
    return lost


def readings_that_added(
    survivors: Sequence[tuple[str, np.ndarray]],
    detections: np.ndarray,
    readings: Mapping[str, str],
    radius_px: float = ADDED_RADIUS_PX,
) -> list[str]:
    """For each detection, the reading whose survivor list holds it first, by its name.

    A detector that reads a frame more than once (a first pass, then second readings
    of what it lost) closes each reading with the list of its detections so far; the
    first list that holds a detection names the reading that added it.

    Args:
        survivors: (test, (K, 2) positions of the candidates that passed it), in
            the order the tests ran (a detector's ``DetectionResult.survivors``).
        detections: (M, 2) the detections reported, px.
        readings: the names of the survivor lists that close a reading, each with
            the name to give the reading (the detector's own, e.g.
            ``symmetry_path.READINGS``).
        radius_px: how near a listed position must lie to be the detection's, px.

    Returns:
        M reading names; :data:`UNLISTED` where no reading's list holds the detection.
    """
    points = np.asarray(detections, dtype=np.float64).reshape(-1, 2)
    added = [UNLISTED] * len(points)
    unclaimed = np.ones(len(points), dtype=bool)
    for name, xy in survivors:
        if name not in readings:
            continue
        listed = unclaimed & (nearest_distances(points, xy) <= radius_px)
        for k in np.flatnonzero(listed):
            added[k] = readings[name]
        unclaimed &= ~listed
    return added


@dataclass(frozen=True)
class ErrorStats:
    """Summary of localisation errors, px (NaN everywhere when there are none).

    Attributes:
        count: number of errors summarised.
        mean: mean error, px.
        rms: root mean square error, px.
        p95: 95th percentile, px.
        max: largest error, px.
        within_fine: share of errors within :data:`FINE_ERROR_PX` (0.1 px), in [0, 1].
    """

    count: int
    mean: float
    rms: float
    p95: float
    max: float
    within_fine: float

    @classmethod
    def from_errors(cls, errors_px: Sequence[float] | np.ndarray) -> ErrorStats:
        """Summarise a set of Euclidean errors, px (NaN entries are ignored)."""
        e = np.asarray(errors_px, dtype=np.float64).ravel()
        e = e[np.isfinite(e)]
        if len(e) == 0:
            nan = math.nan
            return cls(0, nan, nan, nan, nan, nan)
        return cls(
            count=len(e),
            mean=float(e.mean()),
            rms=float(np.sqrt(np.mean(e**2))),
            p95=float(np.percentile(e, 95)),
            max=float(e.max()),
            within_fine=float(np.mean(e <= FINE_ERROR_PX)),
        )


@dataclass
class DetectionTally:
    """Running totals of one detector on a set of frames (a family, a camera of a bag).

    Attributes:
        truth_per_frame: truth points of each frame scored.
        found_per_frame: truth points each frame found.
        false_per_frame: detections in each frame that claimed no truth point.
        errors_px: errors of all matched pairs, px.
        sigmas_px: reported 1-sigma of each matched pair, px (NaN where the
            detector reports none), aligned with ``errors_px``.
        crlb_px: Cramer-Rao bound of each matched truth point, px (NaN where
            unknown), aligned with ``errors_px``: the expected |error| of an
            efficient unbiased estimator of the pixels the bound sums over (the
            X's, in both renderers: an estimator that reads the whole window can
            go under it).
        seconds: wall time spent in the detector, s.
        found: per truth point, in the order seen, 1 where it was matched, else 0.
        line_errors_deg: each matched pair's line-direction error
            (:func:`line_direction_errors_deg`), degrees (NaN where the detector or
            the truth gives no directions), aligned with ``errors_px``.
        marker_ids: per truth point that names its marker, its identity (the same
            marker seen in several frames, by several cameras, has one). Aligned with
            ``found`` where every truth point names one; frames whose truth names none
            add nothing here.
    """

    # Typed arrays, not lists: a list holds a float as a pointer to a 24-byte object,
    # 140 bytes a matched marker in all, 350 MB for an hour of five cameras replayed
    # with truth; these hold its 8 bytes (the percentiles need every value).
    truth_per_frame: array[int] = field(default_factory=lambda: array("q"))
    found_per_frame: array[int] = field(default_factory=lambda: array("q"))
    false_per_frame: array[int] = field(default_factory=lambda: array("q"))
    errors_px: array[float] = field(default_factory=lambda: array("d"))
    sigmas_px: array[float] = field(default_factory=lambda: array("d"))
    crlb_px: array[float] = field(default_factory=lambda: array("d"))
    seconds: float = 0.0
    found: array[int] = field(default_factory=lambda: array("b"))
    line_errors_deg: array[float] = field(default_factory=lambda: array("d"))
    # uint32, the truth cloud's type: 4 bytes a truth point, not 8.
    marker_ids: array[int] = field(default_factory=lambda: array("I"))

    def add(
        self,
        matching: Matching,
        sigmas_px: np.ndarray | None = None,
        seconds: float = 0.0,
        truth_crlb_px: np.ndarray | None = None,
        line_angles: np.ndarray | None = None,
        truth_line_angles: np.ndarray | None = None,
        truth_marker_ids: np.ndarray | None = None,
    ) -> None:
        """Add one frame's matching.

        Args:
            matching: the frame's :class:`Matching`.
            sigmas_px: the detector's 1-sigma per detection, px; None: none reported.
            seconds: time the detector took on the frame, s.
            truth_crlb_px: the Cramer-Rao bound of every truth point, px; None: unknown.
            line_angles: (M, 2) the detector's line directions per detection, radians;
                None: none reported.
            truth_line_angles: (N, 2) every truth point's line directions, radians
                (NaN or None: unknown).
            truth_marker_ids: (N,) every truth point's marker identity, a uint32;
                None: the truth names no marker.

        Raises:
            ValueError: ``truth_marker_ids`` not one per truth point.
        """
        self.truth_per_frame.append(matching.n_truth)
        self.found_per_frame.append(matching.n_matched)
        self.false_per_frame.append(matching.n_false_positives)
        self.errors_px.frombytes(np.asarray(matching.errors_px, np.float64).tobytes())
        found = np.zeros(matching.n_truth, dtype=bool)
        found[matching.truth_index] = True
        self.found.frombytes(found.astype(np.int8).tobytes())
        if truth_marker_ids is not None:
            if len(truth_marker_ids) != matching.n_truth:
                raise ValueError(
                    f"{len(truth_marker_ids)} marker ids for {matching.n_truth} truth points"
                )
            self.marker_ids.frombytes(
                np.asarray(truth_marker_ids).astype(self.marker_ids.typecode).tobytes()
            )
        self.sigmas_px.extend(_aligned(sigmas_px, matching.detection_index))
        self.crlb_px.extend(_aligned(truth_crlb_px, matching.truth_index))
        self.seconds += seconds
        if line_angles is None or truth_line_angles is None:
            self.line_errors_deg.extend([math.nan] * matching.n_matched)
        else:
            self.line_errors_deg.frombytes(
                line_direction_errors_deg(
                    np.asarray(line_angles, np.float64)[matching.detection_index],
                    np.asarray(truth_line_angles, np.float64)[matching.truth_index],
                ).tobytes()
            )

    @classmethod
    def merged(cls, parts: Sequence[DetectionTally]) -> DetectionTally:
        """The totals of several tallies (of cameras, of families) as one."""
        total = cls()
        for part in parts:
            total.truth_per_frame.extend(part.truth_per_frame)
            total.found_per_frame.extend(part.found_per_frame)
            total.false_per_frame.extend(part.false_per_frame)
            total.errors_px.extend(part.errors_px)
            total.sigmas_px.extend(part.sigmas_px)
            total.crlb_px.extend(part.crlb_px)
            total.seconds += part.seconds
            total.found.extend(part.found)
            total.line_errors_deg.extend(part.line_errors_deg)
            total.marker_ids.extend(part.marker_ids)
        return total

    @property
    def frames(self) -> int:
        """Frames scored."""
        return len(self.truth_per_frame)

    @property
    def n_truth(self) -> int:
        """Truth points seen."""
        return sum(self.truth_per_frame)

    @property
    def n_matched(self) -> int:
        """Truth points found."""
        return sum(self.found_per_frame)

    @property
    def n_false_positives(self) -> int:
        """Detections that claimed no truth point."""
        return sum(self.false_per_frame)

    @property
    def recall(self) -> float:
        """Share of truth points found, in [0, 1] (NaN without truth)."""
        return self.n_matched / self.n_truth if self.n_truth else math.nan

    @property
    def fp_per_frame(self) -> float:
        """False positives per frame (NaN without frames)."""
        return self.n_false_positives / self.frames if self.frames else math.nan

    @property
    def clustered_by_marker(self) -> bool:
        """Whether the recall's interval clusters by marker: every truth point names one."""
        return 0 < len(self.found) == len(self.marker_ids)

    @property
    def recall_design_effect(self) -> float:
        """The design effect :attr:`recall_interval` is widened by: at least 1.

        Where :attr:`clustered_by_marker`, :func:`marker_design_effect` of the
        markers' counts (one marker: its sightings, so that they count as one
        trial); else :func:`frame_design_effect` of the frames'.
        """
        if self.clustered_by_marker:
            return marker_design_effect(*self._marker_counts())
        return frame_design_effect(self.found_per_frame, self.truth_per_frame)

    @property
    def fp_dispersion(self) -> float:
        """:func:`frame_dispersion` of the frames' false positives: at least 1."""
        return frame_dispersion(self.false_per_frame)

    @property
    def recall_interval(self) -> tuple[float, float]:
        """The recall's interval, widened by the spread between its clusters.

        Where every truth point names its marker (:attr:`clustered_by_marker`),
        :func:`marker_recall_interval`: a marker seen in many frames is one cluster,
        found again where it was found before. Else :func:`frame_recall_interval`:
        each frame is taken as a cluster of its own markers, which share its light
        and ground, and the frames as showing other markers; where they show the
        same markers frame after frame (a flight), the interval is then narrower
        than the recall's spread from one flight over other markers to the next.
        """
        if self.clustered_by_marker:
            return marker_recall_interval(np.asarray(self.found, bool), self.marker_ids)
        return frame_recall_interval(self.found_per_frame, self.truth_per_frame)

    def _marker_counts(self) -> tuple[list[int], list[int]]:
        """(found, truth) per marker named by the truth (:func:`marker_counts`)."""
        return marker_counts(np.asarray(self.found, bool), np.asarray(self.marker_ids))

    @property
    def fp_per_frame_interval(self) -> tuple[float, float]:
        """:func:`frame_rate_interval` of the false points per frame."""
        return frame_rate_interval(self.false_per_frame)

    @property
    def stats(self) -> ErrorStats:
        """Error statistics of the matched pairs."""
        return ErrorStats.from_errors(np.asarray(self.errors_px))

    @property
    def mean_crlb_px(self) -> float:
        """Mean Cramer-Rao bound of the truth points found, px.

        NaN if any is unknown; inf if any is inf (a marker whose information is
        singular: :func:`~marker_localizer.synthetic.crlb.crlb_mean_abs_error`).
        """
        bounds = np.asarray(self.crlb_px, dtype=np.float64)
        return float(bounds.mean()) if len(bounds) else math.nan

    @property
    def error_over_crlb(self) -> float:
        """Mean error over the mean Cramer-Rao bound of the same points.

        NaN where the mean bound is not a finite positive number: an infinite one
        would give 0, as if the detector erred infinitely less than its bound.
        """
        bound = self.mean_crlb_px
        return self.stats.mean / bound if math.isfinite(bound) and bound > 0 else math.nan

    @property
    def median_line_error_deg(self) -> float:
        """Median line-direction error of the matched pairs, degrees (NaN if none is known)."""
        errors = np.asarray(self.line_errors_deg, dtype=np.float64)
        errors = errors[np.isfinite(errors)]
        return float(np.median(errors)) if len(errors) else math.nan

    @property
    def within_two_sigma(self) -> float:
        """Share of matched errors within twice the reported sigma (NaN without sigmas)."""
        return share_within_sigma(np.asarray(self.errors_px), np.asarray(self.sigmas_px), 2.0)


def interval_quantile(level: float = INTERVAL_LEVEL, frames: int = 1) -> float:
    """The two-sided quantile of an interval whose spread is read from ``frames`` frames.

    Student's t on ``frames`` - 1 degrees of freedom where two or more frames give
    the spread (the design effect, the dispersion: a variance estimated from that
    many clusters); the normal quantile where one frame or none gives it (the
    spread is then the model's, independent markers or Poisson counts).
    """
    tail = 0.5 + 0.5 * level
    return float(stats.t.ppf(tail, frames - 1) if frames >= 2 else stats.norm.ppf(tail))


def recall_interval(
    found: int,
    total: int,
    level: float = INTERVAL_LEVEL,
    design_effect: float = 1.0,
    frames: int = 1,
) -> tuple[float, float]:
    """Wilson's score interval of the recall ``found`` / ``total``; (NaN, NaN) without truth.

    With a ``design_effect`` of 1 and one frame each marker counts as a trial of its
    own. The markers of one frame share its light, blur and ground, so the recall
    spreads more from one set of frames to the next than that: ``design_effect``
    (:func:`frame_design_effect`) is how many times more, read from ``frames``
    frames, and the interval is Wilson's on ``total / design_effect`` markers with
    Student's t on ``frames`` - 1 degrees of freedom for the normal quantile (Korn
    and Graubard's effective sample size, adjusted for its degrees of freedom:
    Korn and Graubard 1998, Survey Methodology 24(2):193-201). The t applies
    whatever the design effect came out: the floor at 1 guards the estimate, and a
    quantile chosen by which side of the floor it fell on would jump there, and
    under-cover where a few frames happen to agree (measured:
    :data:`INTERVAL_COVERAGE_MEASURED`).
    """
    if total <= 0:
        return math.nan, math.nan
    markers = total / max(design_effect, 1.0)
    share = found / total
    z2 = interval_quantile(level, frames) ** 2
    centre = (share + z2 / (2.0 * markers)) / (1.0 + z2 / markers)
    half = math.sqrt(z2 * (share * (1.0 - share) / markers + z2 / (4.0 * markers**2))) / (
        1.0 + z2 / markers
    )
    # At none or all found the interval ends at 0 or 1 exactly; rounding would miss it.
    low = 0.0 if found == 0 else max(centre - half, 0.0)
    high = 1.0 if found == total else min(centre + half, 1.0)
    return low, high


def interval_text(bounds: tuple[float, float], digits: int = 2, scale: float = 1.0) -> str:
    """An interval (:data:`INTERVAL_LEVEL`) as "low-high", times ``scale``; "-" if undefined."""
    low, high = bounds
    if not (math.isfinite(low) and math.isfinite(high)):
        return "-"
    return f"{scale * low:.{digits}f}-{scale * high:.{digits}f}"


def frame_recall_interval(
    found_per_frame: Sequence[int], truth_per_frame: Sequence[int], level: float = INTERVAL_LEVEL
) -> tuple[float, float]:
    """:func:`recall_interval` of the recall from each frame's counts, widened by their spread.

    The design effect is :func:`frame_design_effect`'s, read from the frames that
    hold truth. Nothing in it is particular to frames: given each marker's counts
    instead, it clusters by marker (:func:`marker_recall_interval`).
    """
    return recall_interval(
        int(sum(found_per_frame)),
        int(sum(truth_per_frame)),
        level,
        design_effect=frame_design_effect(found_per_frame, truth_per_frame),
        frames=int(np.count_nonzero(np.asarray(truth_per_frame))),
    )


def marker_recall_interval(
    found: Sequence[bool] | np.ndarray,
    marker_ids: Sequence[int] | np.ndarray,
    level: float = INTERVAL_LEVEL,
) -> tuple[float, float]:
    """:func:`recall_interval` of the recall of truth points that name their marker.

    Each marker is a cluster of its sightings (every frame and camera that held it
    as truth): a flight sees the same markers frame after frame, and a marker's
    size, contrast and ground make it found, or missed, again. The interval is
    :func:`recall_interval`'s widened by :func:`marker_design_effect` of the
    markers' counts (:func:`marker_counts`), with Student's t on markers - 1 degrees
    of freedom.

    One marker is one trial however often it was seen (its sightings share
    everything that makes it found), as two markers or more are each one cluster:
    the spread between markers cannot be read from one.

    Args:
        found: (N,) per truth point, whether it was matched.
        marker_ids: (N,) per truth point, its marker's identity.
        level: the interval's coverage.
    """
    hits, seen = marker_counts(np.asarray(found, bool), np.asarray(marker_ids))
    return recall_interval(
        sum(hits),
        sum(seen),
        level,
        design_effect=marker_design_effect(hits, seen),
        frames=len(seen),
    )


def marker_design_effect(found_per_marker: Sequence[int], truth_per_marker: Sequence[int]) -> float:
    """The design effect of the recall clustered by marker, from each marker's counts.

    :func:`frame_design_effect` of the markers' counts where two or more markers
    give their spread. Of one marker, the number of its sightings: they are one
    trial (:func:`marker_recall_interval`), and Wilson's interval on truth over
    this design effect is on one.
    """
    if len(truth_per_marker) == 1:
        return float(truth_per_marker[0])
    return frame_design_effect(found_per_marker, truth_per_marker)


def marker_counts(found: np.ndarray, marker_ids: np.ndarray) -> tuple[list[int], list[int]]:
    """(found, truth) per marker: its sightings matched, and all of them, in id order."""
    _, marker = np.unique(marker_ids, return_inverse=True)
    seen = np.bincount(marker)
    hits = np.bincount(marker, weights=found.astype(np.float64), minlength=len(seen))
    return hits.astype(np.int64).tolist(), seen.tolist()


def frame_design_effect(found_per_frame: Sequence[int], truth_per_frame: Sequence[int]) -> float:
    """How many times the spread between frames widens the recall's variance; at least 1.

    The recall is a ratio of sums over frames: its variance from the frames'
    residuals (found - recall x truth, the cluster-robust ratio estimator's) over
    the variance the same count of independent markers would give, p (1 - p) / n.
    1 where fewer than two frames hold truth, or none or every marker was found:
    then the frames say nothing of their spread.
    """
    found = np.asarray(found_per_frame, np.float64)
    truth = np.asarray(truth_per_frame, np.float64)
    frames, total = int(np.count_nonzero(truth)), float(truth.sum())
    share = found.sum() / total if total else math.nan
    if frames < 2 or not 0.0 < share < 1.0:
        return 1.0
    between = frames / (frames - 1) * float(np.sum((found - share * truth) ** 2)) / total**2
    return max(1.0, between / (share * (1.0 - share) / total))


def rate_interval(
    count: int,
    exposure: float,
    level: float = INTERVAL_LEVEL,
    dispersion: float = 1.0,
    frames: int = 1,
) -> tuple[float, float]:
    """The exact (Garwood) Poisson interval of ``count`` events over ``exposure``.

    ``exposure`` in the rate's unit: frames for false points per frame, megapixels
    for false points per megapixel. (NaN, NaN) without exposure. Zero events give
    (0, -ln((1 - level) / 2) / exposure): at 95 %, 3.69 / exposure. False points
    gather on the frames whose ground makes them (a lattice of discs), so they
    spread more from one set of frames to the next than Poisson counts:
    ``dispersion`` (:func:`frame_dispersion`) is how many times more, and the
    interval is Garwood's on ``count / dispersion`` events over ``exposure /
    dispersion`` (the quasi-Poisson scaling). Read from ``frames`` frames, the
    dispersion is scaled again by (t / z)^2, Student's t on ``frames`` - 1 degrees
    of freedom over the normal quantile: :func:`recall_interval`'s degrees-of-freedom
    adjustment, on the events. It applies with no event too: then the frames say
    nothing of their spread, and false points gathered on a frame or two leave
    most sets of a few frames with none (measured: :data:`INTERVAL_COVERAGE_MEASURED`;
    Garwood's alone where no event was seen, 0.84-0.89 where the counts' gamma shape
    was 0.3-0.5).
    """
    if not exposure > 0:
        return math.nan, math.nan
    freedom = (interval_quantile(level, frames) / interval_quantile(level)) ** 2
    scale = max(dispersion, 1.0) * freedom
    events = count / scale
    tail = (1.0 - level) / 2.0
    low = stats.chi2.ppf(tail, 2.0 * events) / 2.0 if count else 0.0
    high = stats.chi2.ppf(1.0 - tail, 2.0 * events + 2.0) / 2.0
    return float(low) * scale / exposure, float(high) * scale / exposure


def frame_rate_interval(
    counts_per_frame: Sequence[int], level: float = INTERVAL_LEVEL
) -> tuple[float, float]:
    """:func:`rate_interval` of events per frame from each frame's count.

    Widened by the counts' :func:`frame_dispersion`: the false points of a set of
    frames, in a tally or on the marker-free frames alike.
    """
    return rate_interval(
        sum(counts_per_frame),
        len(counts_per_frame),
        level,
        dispersion=frame_dispersion(counts_per_frame),
        frames=len(counts_per_frame),
    )


def frame_dispersion(counts_per_frame: Sequence[int]) -> float:
    """The frames' counts' variance over their mean (Poisson: 1); at least 1.

    1 with fewer than two frames or no event: then the frames say nothing of
    their spread.
    """
    counts = np.asarray(counts_per_frame, np.float64)
    if len(counts) < 2 or not counts.sum() > 0:
        return 1.0
    return max(1.0, float(counts.var(ddof=1) / counts.mean()))


def _aligned(values: np.ndarray | None, index: np.ndarray) -> list[float]:
    """``values[index]`` as a list, or NaN per index when there are no values."""
    if values is None:
        return [math.nan] * len(index)
    return np.asarray(values, dtype=np.float64)[index].tolist()


def line_direction_errors_deg(angles: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(N,) the larger of an X's two line-direction errors, degrees.

    :func:`~marker_localizer.core.verification.line_pair_difference` of ``angles``
    and ``truth`` (N, 2), radians: directions modulo pi, the lines paired the way
    that errs least (a detector may list them in either order). NaN where either
    is unknown.
    """
    return np.degrees(
        verification.line_pair_difference(
            np.asarray(angles, np.float64).reshape(-1, 2),
            np.asarray(truth, np.float64).reshape(-1, 2),
        )
    )


def share_within_sigma(errors_px: np.ndarray, sigmas_px: np.ndarray, k: float) -> float:
    """Share of errors no larger than ``k`` times their reported sigma.

    An honest 2-D radial sigma (sqrt(var_x + var_y)) of isotropic Gaussian errors
    puts 1 - exp(-k**2) of the errors within k sigma: 98.2 % for k = 2.

    Args:
        errors_px: (N,) Euclidean errors, px.
        sigmas_px: (N,) reported 1-sigma radial uncertainties, px; NaN rows are ignored.
        k: multiple of sigma.

    Returns:
        The share in [0, 1], NaN when no row has a sigma.
    """
    errors = np.asarray(errors_px, dtype=np.float64)
    sigmas = np.asarray(sigmas_px, dtype=np.float64)
    ok = np.isfinite(errors) & np.isfinite(sigmas)
    if not ok.any():
        return math.nan
    return float(np.mean(errors[ok] <= k * sigmas[ok]))
