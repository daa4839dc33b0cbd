"""Reference-free precision of grid corners: straight lines, projective spacing, a lens model.

Matching detections to truth, recall and error statistics are
:mod:`marker_localizer.evaluation`'s; this module adds what only chessboards
allow, so the accuracy benchmark scores our detector and every peer on real
boards without reference points. A real lens bends a board's rows by more than
a corner detector's error, and that bend is common to every detector; the
residual about a board's lens model (:func:`lens_model_residuals`) takes it out.
Coordinates: (N, 2) float64 arrays of (x, y) pixels, (0, 0) at the centre of the
top-left pixel.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares

from marker_localizer.evaluation import DEFAULT_GATE_PX, match_points

#: Parameters a row's or column's straight line takes from its points: its direction
#: and its offset. A line of N points leaves N - 2 residual degrees of freedom.
LINE_PARAMETERS = 2
#: Parameters of the 1-D projective map from grid index to position along a line,
#: (a k + b) / (c k + 1): a line of N points leaves N - 3 (its place along the line is
#: the map's b, its direction the straight line's).
SPACING_PARAMETERS = 3


@dataclass(frozen=True)
class LineResiduals:
    """Reference-free precision of corners on a planar grid.

    Both figures are corrected for the parameters fitted, as the lens model's is
    (:class:`LensModelResiduals`): the root of the summed squared residuals over the
    residual degrees of freedom. Where the corners err by sigma on each axis,
    independently, both estimate sigma (a row of four points keeps only two of its
    four squared errors across the line, one of four along it).

    Attributes:
        straight_rms_px: RMS distance of the points from their row's or column's
            total-least-squares line, px, over N - :data:`LINE_PARAMETERS` degrees of
            freedom a line of N points.
        spacing_rms_px: RMS residual of the positions along each line against the
            best 1-D projective map from grid index to line coordinate, px, over
            N - :data:`SPACING_PARAMETERS` degrees of freedom a line of N points.
        n_points: points that took part (each counted once per line).
        n_lines: rows and columns with at least three points.
        straight_freedom: residual degrees of freedom of the straight lines.
        spacing_freedom: residual degrees of freedom of the spacing (lines of four
            points or more).
    """

    straight_rms_px: float
    spacing_rms_px: float
    n_points: int
    n_lines: int
    straight_freedom: int
    spacing_freedom: int

    @property
    def straight_plain_rms_px(self) -> float:
        """The straight lines' RMS residual over the points, uncorrected, px.

        The points' distances from lines fitted to them, as a measure of a grid's
        bend (``real_data``'s planarity test was set on it), not of the corners' error.
        """
        if not self.n_points:
            return math.nan
        return self.straight_rms_px * math.sqrt(self.straight_freedom / self.n_points)


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
        return LineResiduals(math.nan, math.nan, 0, 0, 0, 0)
    straight_freedom = sum(len(r) - LINE_PARAMETERS for r in straight)
    spacing_freedom = sum(len(r) - SPACING_PARAMETERS for r in spacing)
    return LineResiduals(
        _rms_over(straight, straight_freedom),
        _rms_over(spacing, spacing_freedom),
        sum(len(r) for r in straight),
        len(straight),
        straight_freedom,
        spacing_freedom,
    )


def _rms_over(residuals: Sequence[np.ndarray], freedom: int) -> float:
    """sqrt(sum of squared ``residuals`` / ``freedom``), px; NaN without freedom."""
    if freedom <= 0:
        return math.nan
    return math.sqrt(sum(float((r**2).sum()) for r in residuals) / freedom)


def pool_line_residuals(parts: Sequence[LineResiduals]) -> LineResiduals:
    """Combine per-board residuals into one, pooled over their degrees of freedom."""
    used = [p for p in parts if p.n_points]
    if not used:
        return LineResiduals(math.nan, math.nan, 0, 0, 0, 0)

    def pooled(rms: list[float], freedom: list[int]) -> float:
        total = sum(f for r, f in zip(rms, freedom, strict=True) if f > 0)
        if not total:
            return math.nan
        squares = sum(f * r * r for r, f in zip(rms, freedom, strict=True) if f > 0)
        return math.sqrt(squares / total)

    straight_freedom = [p.straight_freedom for p in used]
    spacing_freedom = [p.spacing_freedom for p in used]
    return LineResiduals(
        pooled([p.straight_rms_px for p in used], straight_freedom),
        pooled([p.spacing_rms_px for p in used], spacing_freedom),
        sum(p.n_points for p in used),
        sum(p.n_lines for p in used),
        sum(straight_freedom),
        sum(spacing_freedom),
    )


#: The lens model's distortion terms: OpenCV's camera calibration's by default, Brown's
#: radial k1, k2, k3 and tangential p1, p2. On ValidationBoof's boards the radial terms
#: alone leave 15 % more for every detector, and libcbdetect's boards twice as much.
LENS_DISTORTION_TERMS = 5
#: The model's parameters: the board plane's homography (8) and the distortion terms.
LENS_MODEL_PARAMETERS = 8 + LENS_DISTORTION_TERMS
#: Fewest corners of a board read against the model: as many residual degrees of
#: freedom as parameters, so that one board's few corners do not fit themselves.
LENS_MODEL_MIN_CORNERS = LENS_MODEL_PARAMETERS


@dataclass(frozen=True)
class LensModelResiduals:
    """Precision of corners about their boards' lens models.

    Attributes:
        rms_px: the corners' RMS distance from the model, px, corrected for the
            parameters fitted: sqrt(2 x sum of squared residuals / (2 N - P)) over
            the boards, each with N corners and P = :data:`LENS_MODEL_PARAMETERS`.
            Where the boards are planar and the lens follows the model, it is the
            corners' RMS error, less what is common to every corner of a board.
        n_points: corners that took part.
        n_boards: boards with at least :data:`LENS_MODEL_MIN_CORNERS` corners.
    """

    rms_px: float
    n_points: int
    n_boards: int


def lens_model_residuals(grid: np.ndarray, image_shape: tuple[int, ...]) -> np.ndarray:
    """Residuals of a board's corners about a pinhole view of its plane through a lens.

    The model maps grid index (column, row) through a homography to the
    undistorted image, then distorts it as OpenCV's camera model does (Brown's
    radial terms k1, k2, k3 and tangential p1, p2), in units of half the image's
    diagonal about its centre, taken as the principal point. It is fitted by
    Levenberg-Marquardt from the homography of the distorted corners. A real
    lens's bend of the rows is common to every detector of a board's corners; the
    residual about the model is what differs.

    Args:
        grid: (rows, cols, 2) corner positions, px; NaN where a corner is missing.
        image_shape: the image's shape, (height, width, ...): its centre is the
            lens's.

    Returns:
        (N, 2) residuals of the N corners present, px; empty where N is under
        :data:`LENS_MODEL_MIN_CORNERS` or the corners lie along one row or column.
    """
    present = np.isfinite(grid).all(axis=2)
    row, col = np.nonzero(present)
    # Corners along one row or column give no homography: the plane is not seen.
    if len(row) < LENS_MODEL_MIN_CORNERS or len(set(row)) < 2 or len(set(col)) < 2:
        return np.empty((0, 2))
    plane = np.column_stack([col, row, np.ones(len(row))]).astype(np.float64)
    corners = grid[present].astype(np.float64)
    height, width = image_shape[:2]
    centre = np.array([(width - 1) / 2, (height - 1) / 2])
    half_diagonal = float(np.hypot(width, height)) / 2

    def model(parameters: np.ndarray) -> np.ndarray:
        mapped = plane @ np.append(parameters[:8], 1.0).reshape(3, 3).T
        x, y = ((mapped[:, :2] / mapped[:, 2:] - centre) / half_diagonal).T
        k1, k2, k3, p1, p2 = parameters[8:]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        distorted = np.column_stack(
            [
                x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y,
            ]
        )
        return centre + half_diagonal * distorted

    homography, _ = cv2.findHomography(plane[:, :2], corners, 0)
    start = np.concatenate(
        [(homography / homography[2, 2]).ravel()[:8], np.zeros(LENS_DISTORTION_TERMS)]
    )
    fit = least_squares(lambda p: (model(p) - corners).ravel(), start, method="lm", x_scale="jac")
    return fit.fun.reshape(-1, 2)


def pool_lens_model_residuals(
    grids: Sequence[np.ndarray], image_shapes: Sequence[tuple[int, ...]]
) -> LensModelResiduals:
    """:func:`lens_model_residuals` of every board, pooled over their degrees of freedom."""
    residuals = [
        r
        for grid, shape in zip(grids, image_shapes, strict=True)
        if len(r := lens_model_residuals(grid, shape))
    ]
    if not residuals:
        return LensModelResiduals(math.nan, 0, 0)
    squares = sum(float((r**2).sum()) for r in residuals)
    freedom = sum(r.size - LENS_MODEL_PARAMETERS for r in residuals)
    points = sum(len(r) for r in residuals)
    return LensModelResiduals(math.sqrt(2.0 * squares / freedom), points, len(residuals))


def grid_positions(
    reference_grid: np.ndarray, detections: np.ndarray, gate_px: float = DEFAULT_GATE_PX
) -> np.ndarray:
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


def order_grid(
    points: np.ndarray, pattern: tuple[int, int], tolerance: float = 0.3
) -> np.ndarray | None:
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
