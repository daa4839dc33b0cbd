"""Scoring detections: matching to truth, recall, false positives, error and line statistics.

Everything here is plain numpy geometry with no knowledge of any detector, so
the accuracy benchmark scores our detector and every peer with the same code.
Coordinates: (N, 2) float64 arrays of (x, y) pixels, (0, 0) at the centre of
the top-left pixel.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

#: Default largest distance between a detection and the truth it may claim, px.
#: Two pixels: well above any refinement error worth the name, well below the
#: spacing of distinct markers (or of chessboard corners in the rendered families).
DEFAULT_GATE_PX = 2.0
#: Error level whose share the tables report (the paper's Table 1 uses 0.1 px).
FINE_ERROR_PX = 0.1


@dataclass(frozen=True)
class Matching:
    """One-to-one pairing of detections with truth points inside a distance gate.

    Attributes:
        truth_index: (K,) index into the truth of every matched pair.
        detection_index: (K,) index into the detections of every matched pair.
        errors_px: (K,) Euclidean distance of every pair, px.
        n_truth: number of truth points.
        n_detections: number of detections.
    """

    truth_index: np.ndarray
    detection_index: np.ndarray
    errors_px: np.ndarray
    n_truth: int
    n_detections: int

    @property
    def n_matched(self) -> int:
        """Number of matched pairs (true positives)."""
        return len(self.errors_px)

    @property
    def n_false_positives(self) -> int:
        """Detections that claimed no truth point."""
        return self.n_detections - self.n_matched

    @property
    def unmatched_detections(self) -> np.ndarray:
        """Indices of the detections that claimed no truth point."""
        return np.setdiff1d(np.arange(self.n_detections), self.detection_index)


def match_points(
    detections: np.ndarray, truth: np.ndarray, gate_px: float = DEFAULT_GATE_PX
) -> Matching:
    """Pair detections with truth points one-to-one, minimising the summed distance.

    A pair farther apart than ``gate_px`` is never made, so a second detection
    on the same marker, or one on clutter, stays unmatched (a false positive).

    Args:
        detections: (N, 2) detected points, px; rows with NaN never match.
        truth: (M, 2) true points, px.
        gate_px: largest distance of a valid pair, px.

    Returns:
        The :class:`Matching`.
    """
    det = np.asarray(detections, dtype=np.float64).reshape(-1, 2)
    ref = np.asarray(truth, dtype=np.float64).reshape(-1, 2)
    empty = np.empty(0, dtype=np.int64)
    if len(det) == 0 or len(ref) == 0:
        return Matching(empty, empty, np.empty(0), len(ref), len(det))
    distance = np.linalg.norm(ref[:, None, :] - det[None, :, :], axis=2)
    distance = np.where(np.isfinite(distance), distance, np.inf)
    # Pairs beyond the gate get a cost no valid assignment can prefer.
    cost = np.where(distance <= gate_px, distance, 1e6)
    rows, cols = linear_sum_assignment(cost)
    valid = distance[rows, cols] <= gate_px
    rows, cols = rows[valid], cols[valid]
    return Matching(rows, cols, distance[rows, cols], len(ref), len(det))


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
    """Running totals of one detector on one family of frames.

    Attributes:
        frames: frames scored.
        n_truth: truth points seen.
        n_matched: truth points found.
        n_false_positives: detections that claimed no truth point.
        errors_px: errors of all matched pairs, px.
        sigmas_px: reported 1-sigma of each matched pair, px (NaN where the
            detector reports none), aligned with ``errors_px``.
        crlb_px: Cramer-Rao bound (expected |error| of an efficient unbiased
            estimator) of each matched truth point, px (NaN where unknown),
            aligned with ``errors_px``.
        seconds: wall time spent in the detector, s.
        found: per truth point, in the order seen, whether it was matched.
    """

    frames: int = 0
    n_truth: int = 0
    n_matched: int = 0
    n_false_positives: int = 0
    errors_px: list[float] = field(default_factory=list)
    sigmas_px: list[float] = field(default_factory=list)
    crlb_px: list[float] = field(default_factory=list)
    seconds: float = 0.0
    found: list[bool] = field(default_factory=list)

    def add(self, matching: Matching, sigmas_px: np.ndarray | None = None,
            seconds: float = 0.0, truth_crlb_px: np.ndarray | None = None) -> None:
        """Add one frame's matching.

        Args:
            matching: the frame's :class:`Matching`.
            sigmas_px: the detector's 1-sigma per detection, px; None: none reported.
            seconds: time the detector took on the frame, s.
            truth_crlb_px: the Cramer-Rao bound of every truth point, px; None: unknown.
        """
        self.frames += 1
        self.n_truth += matching.n_truth
        self.n_matched += matching.n_matched
        self.n_false_positives += matching.n_false_positives
        self.errors_px.extend(matching.errors_px.tolist())
        found = np.zeros(matching.n_truth, dtype=bool)
        found[matching.truth_index] = True
        self.found.extend(found.tolist())
        self.sigmas_px.extend(_aligned(sigmas_px, matching.detection_index))
        self.crlb_px.extend(_aligned(truth_crlb_px, matching.truth_index))
        self.seconds += seconds

    @property
    def recall(self) -> float:
        """Share of truth points found, in [0, 1] (NaN without truth)."""
        return self.n_matched / self.n_truth if self.n_truth else math.nan

    @property
    def fp_per_frame(self) -> float:
        """False positives per frame (NaN without frames)."""
        return self.n_false_positives / self.frames if self.frames else math.nan

    @property
    def stats(self) -> ErrorStats:
        """Error statistics of the matched pairs."""
        return ErrorStats.from_errors(np.asarray(self.errors_px))

    @property
    def mean_crlb_px(self) -> float:
        """Mean Cramer-Rao bound of the truth points found, px (NaN if any is unknown)."""
        bounds = np.asarray(self.crlb_px, dtype=np.float64)
        return float(bounds.mean()) if len(bounds) else math.nan

    @property
    def error_over_crlb(self) -> float:
        """Mean error over the mean Cramer-Rao bound of the same points: 1 is efficient."""
        bound = self.mean_crlb_px
        return self.stats.mean / bound if bound > 0 else math.nan

    @property
    def within_two_sigma(self) -> float:
        """Share of matched errors within twice the reported sigma (NaN without sigmas)."""
        return share_within_sigma(np.asarray(self.errors_px), np.asarray(self.sigmas_px), 2.0)


def _aligned(values: np.ndarray | None, index: np.ndarray) -> list[float]:
    """``values[index]`` as a list, or NaN per index when there are no values."""
    if values is None:
        return [math.nan] * len(index)
    return np.asarray(values, dtype=np.float64)[index].tolist()


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


# --------------------------------------------------------------------------- grid geometry

@dataclass(frozen=True)
class LineResiduals:
    """Reference-free precision of corners on a planar grid.

    Attributes:
        straight_rms_px: RMS distance of the points from their row's or column's
            total-least-squares line, px (each point counts once per line).
        spacing_rms_px: RMS residual of the positions along each line against the
            best 1-D projective map from grid index to line coordinate, px.
        n_points: points that took part (each counted once per line).
        n_lines: rows and columns with at least three points.
    """

    straight_rms_px: float
    spacing_rms_px: float
    n_points: int
    n_lines: int


def fit_line(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Total-least-squares line through points.

    Args:
        points: (N, 2) points, N >= 2, px.

    Returns:
        (centroid (2,), unit direction (2,)).
    """
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    return centroid, vt[0]


def straight_line_residuals(points: np.ndarray) -> np.ndarray:
    """Signed distances of points from their total-least-squares line, px."""
    centroid, direction = fit_line(points)
    normal = np.array([-direction[1], direction[0]])
    return (points - centroid) @ normal


def projective_spacing_residuals(index: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Residuals along a line against the best 1-D projective map index -> position.

    Equally spaced points on a plane, seen by a pinhole camera, lie on their
    image line at t(k) = (a k + b) / (c k + 1). The fit solves the linearised
    a k + b - c k t = t by least squares; needs four or more points to have a
    residual.

    Args:
        index: (N,) grid index of each point along its line.
        points: (N, 2) points, px.

    Returns:
        (N,) residuals along the line, px (zeros for fewer than four points).
    """
    centroid, direction = fit_line(points)
    t = (points - centroid) @ direction
    k = np.asarray(index, dtype=np.float64)
    if len(k) < 4:
        return np.zeros(len(k))
    design = np.column_stack([k, np.ones_like(k), -k * t])
    (a, b, c), *_ = np.linalg.lstsq(design, t, rcond=None)
    return t - (a * k + b) / (c * k + 1.0)


def line_residuals(grid: np.ndarray) -> LineResiduals:
    """Straight-line and projective-spacing residuals of every grid row and column.

    Args:
        grid: (rows, cols, 2) corner positions, px; NaN where a corner is missing.

    Returns:
        :class:`LineResiduals` over every row and column with >= 3 points
        (NaN figures when there is none).
    """
    straight: list[np.ndarray] = []
    spacing: list[np.ndarray] = []
    for lines in (grid, grid.transpose(1, 0, 2)):
        for line in lines:
            ok = np.isfinite(line).all(axis=1)
            if ok.sum() < 3:
                continue
            straight.append(straight_line_residuals(line[ok]))
            if ok.sum() >= 4:
                spacing.append(projective_spacing_residuals(np.flatnonzero(ok), line[ok]))
    if not straight:
        return LineResiduals(math.nan, math.nan, 0, 0)
    s = np.concatenate(straight)
    p = np.concatenate(spacing) if spacing else np.array([math.nan])
    return LineResiduals(
        float(np.sqrt(np.mean(s**2))), float(np.sqrt(np.mean(p**2))), len(s), len(straight)
    )


def pool_line_residuals(parts: Sequence[LineResiduals]) -> LineResiduals:
    """Combine per-board residuals into one, weighting each board by its point count."""
    used = [p for p in parts if p.n_points]
    if not used:
        return LineResiduals(math.nan, math.nan, 0, 0)
    weights = np.array([p.n_points for p in used], dtype=np.float64)

    def pooled(values: list[float]) -> float:
        v = np.asarray(values)
        ok = np.isfinite(v)
        if not ok.any():
            return math.nan
        return float(np.sqrt(np.sum(weights[ok] * v[ok] ** 2) / weights[ok].sum()))

    return LineResiduals(
        pooled([p.straight_rms_px for p in used]),
        pooled([p.spacing_rms_px for p in used]),
        int(weights.sum()),
        sum(p.n_lines for p in used),
    )


def grid_positions(reference_grid: np.ndarray, detections: np.ndarray,
                   gate_px: float = DEFAULT_GATE_PX) -> np.ndarray:
    """Place detections into a reference grid by matching them to its corners.

    Args:
        reference_grid: (rows, cols, 2) reference corners, px (NaN allowed).
        detections: (N, 2) detected points, px.
        gate_px: largest distance of a match, px.

    Returns:
        (rows, cols, 2) the matched detection at each grid node, NaN where none.
    """
    flat = reference_grid.reshape(-1, 2)
    matching = match_points(detections, flat, gate_px)
    placed = np.full_like(flat, np.nan, dtype=np.float64)
    placed[matching.truth_index] = np.asarray(detections, np.float64)[matching.detection_index]
    return placed.reshape(reference_grid.shape)


def order_grid(points: np.ndarray, pattern: tuple[int, int],
               tolerance: float = 0.3) -> np.ndarray | None:
    """Arrange an unordered set of grid corners into rows and columns.

    The four extreme corners of the points' convex hull are mapped to the
    corners of the index grid by a homography; every point then rounds to its
    grid index. Works under perspective and mild lens distortion.

    Args:
        points: (cols * rows, 2) corner positions, px, in any order.
        pattern: (cols, rows) inner corners; the longer side of the hull
            polygon is matched to the larger count.
        tolerance: largest distance of a mapped point from its integer index
            (in grid units) for the arrangement to be accepted.

    Returns:
        (rows, cols, 2) grid, or None when the points do not form that grid.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    cols, rows = pattern
    if len(pts) != cols * rows:
        return None
    quad = _hull_quadrilateral(pts)
    if quad is None:
        return None
    side = np.linalg.norm(quad - np.roll(quad, -1, axis=0), axis=1)
    first_long = side[0] + side[2] >= side[1] + side[3]
    long_n, short_n = max(cols, rows), min(cols, rows)
    target_w, target_h = (long_n, short_n) if first_long else (short_n, long_n)
    target = np.array(
        [[0, 0], [target_w - 1, 0], [target_w - 1, target_h - 1], [0, target_h - 1]], np.float64
    )
    homography = cv2.getPerspectiveTransform(quad.astype(np.float32), target.astype(np.float32))
    mapped = cv2.perspectiveTransform(pts[None].astype(np.float64), homography)[0]
    index = np.round(mapped).astype(np.int64)
    if np.abs(mapped - index).max() > tolerance:
        return None
    grid = np.full((target_h, target_w, 2), np.nan)
    grid[index[:, 1], index[:, 0]] = pts
    if not np.isfinite(grid).all():
        return None
    return grid if (target_w, target_h) == (cols, rows) else grid.transpose(1, 0, 2)


def _hull_quadrilateral(points: np.ndarray) -> np.ndarray | None:
    """The four points of the convex hull that best span it, in hull order."""
    hull = cv2.convexHull(points.astype(np.float32)).reshape(-1, 2)
    if len(hull) < 4:
        return None
    perimeter = cv2.arcLength(hull, closed=True)
    for fraction in (0.01, 0.02, 0.04, 0.06, 0.1):
        approx = cv2.approxPolyDP(hull, fraction * perimeter, closed=True).reshape(-1, 2)
        if len(approx) == 4:
            return approx.astype(np.float64)
    return None
