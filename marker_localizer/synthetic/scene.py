"""Ground-truth renderer: diagonal markers, hard negatives and checkerboards with exact centres.

Coordinates: float64 pixels, x right, y down, (0, 0) at the centre of the
top-left pixel, so pixel (row i, column j) covers x in [j - 0.5, j + 0.5] and
y in [i - 0.5, i + 0.5].

Every target (marker, hard negative, checkerboard) is an analytic pattern on
a plane with coordinates (u, v), mapped into the image by a 3x3 homography
(plane -> image). Its ground-truth point is the image of the plane origin,
``H @ [0, 0, 1]``, so the truth is exact whatever the tilt or perspective.
Pixels integrate the pattern over their area with S x S samples; the frame
then goes through the imaging chain of :class:`ImagingConditions` (light,
shadows, optics, gamma, noise, 8-bit quantisation).

Stages, each a public function a flight simulator can reuse or replace:
:func:`marker_homography` (placement -> homography), :func:`render_targets`
(homographies -> 8-bit frame), :func:`apply_imaging` (radiance -> 8-bit frame).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np
from scipy.special import ndtr

from marker_localizer.core.image import BAYER_PATTERNS
from marker_localizer.errors import ConfigError
from marker_localizer.synthetic import crlb
from marker_localizer.synthetic.textures import (
    TEXTURE_SCALE_RANGE,
    flat_background,
    smooth_random_field,
    texture_background,
)

# --------------------------------------------------------------------------- constants

_LOG = logging.getLogger(__name__)

#: Half-side of the square plate that carries a marker, in marker radii.
PLATE_HALF_SIDE = 1.25
#: Focal length of the pinhole camera of :func:`marker_homography`, in pixels.
#: With a marker of radius 40 px this puts the camera 30 marker radii away (a
#: 0.5 m marker at 15 m), so a 60 degree tilt changes the scale by ~3 % across
#: the marker: mild, true perspective.
DEFAULT_FOCAL_PX = 1200.0
#: Reflectance ranges of the dark and bright paint (matte black / white).
DARK_REFLECTANCE_RANGE: tuple[float, float] = (0.05, 0.15)
BRIGHT_REFLECTANCE_RANGE: tuple[float, float] = (0.75, 0.95)
#: Largest bright - dark paint difference a contrast range may ask for: the
#: darkest dark paint against the brightest bright one.
MAX_CONTRAST = round(BRIGHT_REFLECTANCE_RANGE[1] - DARK_REFLECTANCE_RANGE[0], 9)
#: Reflectance of the "flat" background: mid-grey, distinct from both paints.
FLAT_BACKGROUND_LEVEL = 0.45
#: Sensor full-well capacity used for shot noise, in electrons: typical of
#: machine-vision CMOS sensors.
DEFAULT_FULL_WELL_E = 20000.0
#: Shot-noise variance per DN of signal of that sensor at full scale, DN
#: (255 / full well): the default of :class:`SceneConfig`.
DEFAULT_SHOT_NOISE_GAIN_DN = 255.0 / DEFAULT_FULL_WELL_E
#: Variance of rounding to integer DN, DN^2 (a uniform error over one level).
QUANTISATION_VARIANCE_DN2 = 1.0 / 12.0
#: A cast shadow reaches this many bounding radii of the marker's plate about
#: its centre: over the plate and the ground around it, like the shadow of a
#: pole or a wire, and clear of the neighbouring markers (placement keeps them
#: out of that reach).
CAST_SHADOW_REACH = 1.5
#: 10-90 % width of a cast shadow's edge, px: a hard shadow in sunlight.
CAST_SHADOW_PENUMBRA_PX = 1.0
#: A cast shadow's straight edge passes within this many foreshortened marker
#: radii of the marker centre, so it crosses the X itself.
CAST_SHADOW_MAX_OFFSET = 0.6
#: Samples per pixel along each axis that integrate a cast shadow's edge over
#: the pixel area (its penumbra is only about a pixel wide).
_SHADOW_SUPERSAMPLING = 4
#: Ratio of a normal CDF's 10-90 % width to its sigma: 2 * 1.2816.
_NORMAL_10_90_WIDTH = 2.5631
#: Largest tilt a placement may ask for, in degrees (beyond, the marker is a line).
MAX_TILT_DEG = 80.0
#: Free space kept between the bounding circles of two targets and between a
#: target and the frame border, in pixels: 3 sigma of the widest default PSF.
PLACEMENT_GAP_PX = 4.0
#: Random positions tried per target before giving up.
PLACEMENT_TRIES = 2048
_PLACEMENT_BATCH = 32
#: Largest number of sub-pixel samples evaluated at once (bounds memory to ~100 MB).
SAMPLE_CHUNK = 1 << 20
#: Distance from a pixel centre to its farthest sample, in pixels (< sqrt(2) / 2).
_PIXEL_HALF_DIAGONAL = 0.7072
#: Safety factor on the plane-space footprint of a pixel: covers the change of
#: the homography's Jacobian within one pixel.
_FOOTPRINT_MARGIN = 1.1

MARKER_KINDS: tuple[str, ...] = ("quarter_disks", "checker")
NEGATIVE_KINDS: tuple[str, ...] = (
    "l_corner",
    "quarter_disk",
    "t_junction",
    "bar",
    "triangle",
    "plus",
    "blob",
    "disc",
)
BACKGROUNDS: tuple[str, ...] = ("texture", "flat")

# --------------------------------------------------------------------------- patterns

_Field = Callable[[np.ndarray, np.ndarray], np.ndarray]
_Line = tuple[float, float, float]


@dataclass(frozen=True)
class Pattern:
    """An analytic binary pattern on the target plane (units: marker radius = 1).

    Attributes:
        name: Pattern name (a marker kind, a negative kind or ``"checkerboard"``).
        dark: ``dark(u, v)`` -> bool array, True where the paint is dark.
        edge_distance: ``edge_distance(u, v)`` -> a lower bound of the plane
            distance from (u, v) to the boundary of the dark region. Pixels
            farther than their footprint from every boundary are uniform and
            need one sample instead of S x S.
        half_extent: (half-width along u, half-height along v) of the plate;
            the dark region lies inside it.
        x_extent: ``x_extent(u, v)`` -> bool array, True inside the X (the
            quarter disks' circle, the checker's square) of a marker kind;
            None for other patterns. Its boundary is part of ``edge_distance``.
    """

    name: str
    dark: _Field
    edge_distance: _Field
    half_extent: tuple[float, float] = (PLATE_HALF_SIDE, PLATE_HALF_SIDE)
    x_extent: _Field | None = None


def _lines_distance(*lines: _Line) -> _Field:
    """Distance to the nearest of the lines a*u + b*v + c = 0 (unit normals (a, b))."""

    def distance(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        result = np.full(u.shape, np.inf)
        for a, b, c in lines:
            np.minimum(result, np.abs(a * u + b * v + c), out=result)
        return result

    return distance


def _with_circle(lines_distance: _Field, radius: float) -> _Field:
    """Add a circle of ``radius`` about the origin to a set of edges."""

    def distance(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.minimum(lines_distance(u, v), np.abs(np.hypot(u, v) - radius))

    return distance


def _axis_lines(*offsets: float) -> tuple[_Line, ...]:
    """Lines u = +-o and v = +-o for every offset o."""
    lines: list[_Line] = []
    for offset in offsets:
        lines += [(1.0, 0.0, -offset), (1.0, 0.0, offset), (0.0, 1.0, -offset), (0.0, 1.0, offset)]
    return tuple(lines)


def _line_through(p: tuple[float, float], q: tuple[float, float]) -> _Line:
    """The line through two plane points, with a unit normal."""
    a, b = q[1] - p[1], p[0] - q[0]
    norm = math.hypot(a, b)
    return a / norm, b / norm, -(a * p[0] + b * p[1]) / norm


def _quarter_disks_dark(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    # Quadrants 1 (u > 0, v > 0) and 3 (u < 0, v < 0) inside the unit circle.
    return (u * v > 0) & (u * u + v * v <= 1.0)


def _checker_dark(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return (u * v > 0) & (np.abs(u) <= 1.0) & (np.abs(v) <= 1.0)


def _unit_disk(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return u * u + v * v <= 1.0


def _unit_square(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return (np.abs(u) <= 1.0) & (np.abs(v) <= 1.0)


_BAR_HALF_WIDTH = 0.2  # thick line: 0.4 marker radii wide
_THIN_HALF_WIDTH = 0.06  # plus sign strokes: 0.12 marker radii wide
_TRIANGLE = ((-1.0, -0.8), (1.0, -0.8), (0.0, 1.0))
_BLOB_AXES = (0.55, 0.35)
_DISC_RADIUS = 0.6


def _l_corner_dark(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return (u >= 0) & (v >= 0) & (u <= 1.0) & (v <= 1.0)


def _quarter_disk_dark(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return (u >= 0) & (v >= 0) & (u * u + v * v <= 1.0)


def _bar_dark(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return (np.abs(v) <= _BAR_HALF_WIDTH) & (np.abs(u) <= 1.0)


def _t_junction_dark(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    stem = (np.abs(u) <= _BAR_HALF_WIDTH) & (v >= 0) & (v <= 1.0)
    return _bar_dark(u, v) | stem


def _plus_dark(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    horizontal = (np.abs(v) <= _THIN_HALF_WIDTH) & (np.abs(u) <= 1.0)
    vertical = (np.abs(u) <= _THIN_HALF_WIDTH) & (np.abs(v) <= 1.0)
    return horizontal | vertical


def _triangle_dark(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    inside = np.ones(u.shape, dtype=bool)
    for i in range(3):
        a, b, c = _line_through(_TRIANGLE[i], _TRIANGLE[(i + 1) % 3])
        inside &= a * u + b * v + c >= 0
    return inside


def _blob_dark(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return (u / _BLOB_AXES[0]) ** 2 + (v / _BLOB_AXES[1]) ** 2 <= 1.0


def _disc_dark(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return u * u + v * v <= _DISC_RADIUS**2


def _blob_distance(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    # q = |(u/a, v/b)| changes by at most 1/b per unit distance, so b*|q - 1| is a lower bound.
    q = np.hypot(u / _BLOB_AXES[0], v / _BLOB_AXES[1])
    return _BLOB_AXES[1] * np.abs(q - 1.0)


_CENTRE_LINES: tuple[_Line, ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))

#: Every built-in pattern by name: the marker kinds and the hard negatives.
PATTERNS: dict[str, Pattern] = {
    "quarter_disks": Pattern(
        "quarter_disks",
        _quarter_disks_dark,
        _with_circle(_lines_distance(*_CENTRE_LINES), 1.0),
        x_extent=_unit_disk,
    ),
    "checker": Pattern(
        "checker",
        _checker_dark,
        _lines_distance(*_CENTRE_LINES, *_axis_lines(1.0)),
        x_extent=_unit_square,
    ),
    "l_corner": Pattern(
        "l_corner", _l_corner_dark, _lines_distance(*_CENTRE_LINES, *_axis_lines(1.0))
    ),
    "quarter_disk": Pattern(
        "quarter_disk", _quarter_disk_dark, _with_circle(_lines_distance(*_CENTRE_LINES), 1.0)
    ),
    "t_junction": Pattern(
        "t_junction",
        _t_junction_dark,
        _lines_distance(*_CENTRE_LINES, *_axis_lines(_BAR_HALF_WIDTH, 1.0)),
    ),
    "bar": Pattern("bar", _bar_dark, _lines_distance(*_axis_lines(_BAR_HALF_WIDTH, 1.0))),
    "triangle": Pattern(
        "triangle",
        _triangle_dark,
        _lines_distance(*(_line_through(_TRIANGLE[i], _TRIANGLE[(i + 1) % 3]) for i in range(3))),
    ),
    "plus": Pattern("plus", _plus_dark, _lines_distance(*_axis_lines(_THIN_HALF_WIDTH, 1.0))),
    "blob": Pattern("blob", _blob_dark, _blob_distance),
    "disc": Pattern("disc", _disc_dark, _with_circle(_lines_distance(), _DISC_RADIUS)),
}


def checkerboard_pattern(inner_corners: tuple[int, int]) -> Pattern:
    """A chessboard with a one-square white border, in units of one square.

    Args:
        inner_corners: (columns, rows) of inner corners, i.e. corners where four
            squares meet, along u and v. The board has (columns + 1) x (rows + 1)
            squares, is centred on the origin, and its top-left square is dark.

    Returns:
        The pattern; inner corner (k, m) lies at
        u = k - (columns - 1) / 2, v = m - (rows - 1) / 2.
    """
    n_u, n_v = inner_corners
    half_u, half_v = (n_u + 1) / 2.0, (n_v + 1) / 2.0

    def dark(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        i, j = np.floor(u + half_u), np.floor(v + half_v)
        on_board = (i >= 0) & (i <= n_u) & (j >= 0) & (j <= n_v)
        return on_board & ((i + j) % 2 == 0)

    def edge_distance(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        # Distance to the nearest grid line of the board (lines at integer offsets).
        s, t = u + half_u, v + half_v
        return np.minimum(
            np.abs(s - np.clip(np.round(s), 0, n_u + 1)),
            np.abs(t - np.clip(np.round(t), 0, n_v + 1)),
        )

    return Pattern("checkerboard", dark, edge_distance, (half_u + 1.0, half_v + 1.0))


# --------------------------------------------------------------------------- placements


def _check_range(
    name: str, bounds: tuple[float, float], low: float, high: float = math.inf
) -> None:
    if len(bounds) != 2 or not low <= bounds[0] <= bounds[1] <= high:
        raise ConfigError(
            f"{name} must be (min, max) with {low} <= min <= max <= {high}, got {bounds!r}"
        )


@dataclass(frozen=True)
class MarkerPlacement:
    """Where and how to put one marker (or hard negative) in the image.

    Attributes:
        x: Image x of the marker centre, px.
        y: Image y of the marker centre, px.
        radius_px: Radius of the X (the quarter disks or checker squares)
            before tilt, px. The plate extends to 1.25 radii.
        rotation_rad: In-plane rotation, radians, from image +x towards +y.
        tilt_deg: Out-of-plane tilt, degrees, in [0, 80].
        tilt_axis_rad: Image direction of the tilt axis, radians from +x towards
            +y: lengths along it are kept, lengths across it shrink by
            cos(tilt), whatever the in-plane rotation.
        kind: A marker kind (:data:`MARKER_KINDS`) or a hard-negative kind
            (:data:`NEGATIVE_KINDS`).
        inverted: Swap dark and bright paint.
        dull_factor: Brightness of one bright quadrant of the X relative to
            the other, in (0, 1] (dirt, wear, sheen); 1: none. Marker kinds only.
        dull_quadrant: Which of the two bright quadrants is dull, 0 or 1 (0:
            the one at plane u < 0, v > 0; inverted markers: u > 0, v > 0).
    """

    x: float
    y: float
    radius_px: float
    rotation_rad: float = 0.0
    tilt_deg: float = 0.0
    tilt_axis_rad: float = 0.0
    kind: str = "quarter_disks"
    inverted: bool = False
    dull_factor: float = 1.0
    dull_quadrant: int = 0

    def __post_init__(self) -> None:
        if not self.radius_px > 0:
            raise ConfigError(f"radius_px must be > 0, got {self.radius_px!r}")
        if not 0.0 <= self.tilt_deg <= MAX_TILT_DEG:
            raise ConfigError(f"tilt_deg must be in [0, {MAX_TILT_DEG}], got {self.tilt_deg!r}")
        if self.kind not in PATTERNS:
            raise ConfigError(f"unknown kind {self.kind!r}; choose from {tuple(PATTERNS)}")
        if not 0.0 < self.dull_factor <= 1.0:
            raise ConfigError(f"dull_factor must be in (0, 1], got {self.dull_factor!r}")
        if self.dull_factor < 1.0 and PATTERNS[self.kind].x_extent is None:
            raise ConfigError(f"dull_factor needs a marker kind {MARKER_KINDS}, got {self.kind!r}")
        if self.dull_quadrant not in (0, 1):
            raise ConfigError(f"dull_quadrant must be 0 or 1, got {self.dull_quadrant!r}")

    @property
    def dull_signs(self) -> tuple[int, int] | None:
        """Signs (of u, of v) of the dull quadrant on the plane; None when none is dull."""
        if self.dull_factor >= 1.0:
            return None
        # The bright quadrants are u * v < 0, or u * v > 0 when the paints are swapped.
        signs = ((1, 1), (-1, -1)) if self.inverted else ((-1, 1), (1, -1))
        return signs[self.dull_quadrant]


def _rodrigues(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Rotation matrix about a unit ``axis`` by ``angle_rad``."""
    cross = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return (
        math.cos(angle_rad) * np.eye(3)
        + math.sin(angle_rad) * cross
        + (1.0 - math.cos(angle_rad)) * np.outer(axis, axis)
    )


def marker_homography(
    placement: MarkerPlacement, *, focal_px: float = DEFAULT_FOCAL_PX
) -> np.ndarray:
    """Plane -> image homography of a placed marker, seen by a pinhole camera.

    The marker plane (units: marker radius) is rotated in-plane, tilted about
    the axis ``tilt_axis_rad`` and set at depth 1 in front of a pinhole camera of focal
    length ``focal_px`` whose principal point is the requested centre, at the
    size that makes an untilted marker ``radius_px`` wide. Tilting therefore
    foreshortens by cos(tilt) and adds true perspective: a marker spanning
    2 * radius_px / focal_px radians changes scale across itself by about
    radius_px / focal_px * sin(tilt).

    Args:
        placement: Centre, radius, rotation and tilt.
        focal_px: Focal length of the camera, px; larger means less perspective.

    Returns:
        (3, 3) float64 homography H with H[2, 2] = 1 and H @ [0, 0, 1] exactly
        [placement.x, placement.y, 1].
    """
    scale = placement.radius_px / focal_px
    axis = np.array([math.cos(placement.tilt_axis_rad), math.sin(placement.tilt_axis_rad), 0.0])
    tilt = _rodrigues(axis, math.radians(placement.tilt_deg))
    cos, sin = math.cos(placement.rotation_rad), math.sin(placement.rotation_rad)
    in_plane = np.array([[cos, -sin, 0.0], [sin, cos, 0.0], [0.0, 0.0, 1.0]])
    # Plane point (u, v) -> camera point scale * (tilt @ [u, v, 0]) + [0, 0, 1].
    plane_to_camera = np.column_stack([scale * tilt[:, 0], scale * tilt[:, 1], [0.0, 0.0, 1.0]])
    camera = np.array([[focal_px, 0.0, placement.x], [0.0, focal_px, placement.y], [0.0, 0.0, 1.0]])
    # The third column is camera @ [0, 0, 1] = (x, y, 1) exactly: the truth is exact.
    return camera @ plane_to_camera @ in_plane


def project(homography: np.ndarray, points_uv: np.ndarray) -> np.ndarray:
    """Map plane points through a homography.

    Args:
        homography: (3, 3) plane -> image.
        points_uv: (N, 2) plane points.

    Returns:
        (N, 2) float64 image points (x, y).
    """
    points = np.asarray(points_uv, dtype=np.float64)
    mapped = points @ homography[:, :2].T + homography[:, 2]
    return mapped[:, :2] / mapped[:, 2:]


# --------------------------------------------------------------------------- truth records


@dataclass(frozen=True)
class MarkerTruth:
    """Exact ground truth of one rendered marker (or checkerboard corner).

    Attributes:
        x: Image x of the centre, px: the image of the plane origin.
        y: Image y of the centre, px.
        radius_px: Nominal radius before tilt, px (checkerboard: square side).
        kind: Marker kind, or ``"checkerboard_corner"``.
        homography: (3, 3) plane -> image, with H @ [0, 0, 1] ~ [x, y, 1].
        angles: Image directions, radians in [0, pi), of the two lines through
            the centre: the images of the plane's u and v axes.
        crlb_mean_abs_error_px: Expected Euclidean error of an efficient
            unbiased estimator of the centre that reads the X's pixels alone
            (Cramer-Rao bound over the X, the independent renderer's definition,
            :mod:`~marker_localizer.synthetic.crlb`; one that reads the whole
            window can go under it), px; NaN when not computed.
        dull_margin: How far the dull bright quadrant's paint stands above the
            dark paint, as a share of the other bright quadrant's lead, (dull x
            bright - dark) / (bright - dark): 1 without a dull quadrant; near 0 or
            below, the "dull" quadrant is as dark as the dark paint or darker, and
            what is painted is no longer an X but one bright quadrant on its plate
            (a dull factor of 0.45-0.8 does that to paint of contrast 0.35-0.55
            whose dark is a light grey).
        bound_parts: The centre's bound with the marker's other parameters unknown
            and from fewer pixels (:class:`~marker_localizer.synthetic.crlb.BoundParts`),
            where asked for.
        x_snr: The signal-to-noise ratio of its X, what an ideal detector has to go on
            (:func:`~marker_localizer.synthetic.crlb.x_snr`); NaN when not computed.
    """

    x: float
    y: float
    radius_px: float
    kind: str
    homography: np.ndarray = field(compare=False)  # arrays cannot take part in ==/hash
    angles: tuple[float, float]
    crlb_mean_abs_error_px: float = math.nan
    dull_margin: float = 1.0
    bound_parts: crlb.BoundParts | None = None
    x_snr: float = math.nan

    @classmethod
    def from_homography(
        cls, homography: np.ndarray, radius_px: float, kind: str, dull_margin: float = 1.0
    ) -> MarkerTruth:
        """Truth of a target whose plane origin is the marker centre."""
        h = np.asarray(homography, dtype=np.float64) / homography[2, 2]
        x, y = float(h[0, 2]), float(h[1, 2])
        (du_x, dv_x), (du_y, dv_y) = _origin_jacobian(h)
        angles = (math.atan2(du_y, du_x) % math.pi, math.atan2(dv_y, dv_x) % math.pi)
        return cls(x, y, float(radius_px), kind, h, angles, dull_margin=dull_margin)

    @property
    def foreshortened_radius_px(self) -> float:
        """The marker's radius along its most foreshortened direction, px.

        ``radius_px`` times the ratio of the smaller to the larger singular value
        of the plane -> image Jacobian at the centre: cos(tilt) for a marker of
        :func:`marker_homography`, up to the perspective across it.
        """
        singular = np.linalg.svd(_origin_jacobian(self.homography), compute_uv=False)
        return float(self.radius_px * singular[1] / singular[0])


def _origin_jacobian(homography: np.ndarray) -> np.ndarray:
    """(2, 2) Jacobian of the plane -> image map at the plane origin (H[2, 2] = 1).

    Its columns are the image directions of the plane's u and v axes.
    """
    h = homography
    return h[:2, :2] - np.outer(h[:2, 2], h[2, :2])


@dataclass(frozen=True)
class PlanarTarget:
    """One thing to paint into the frame: a pattern seen through a homography.

    This is the unit the compositing core works on; a flight simulator can
    build targets from camera-derived homographies directly.

    Attributes:
        homography: (3, 3) plane -> image; must map the whole plate in front
            of the camera.
        pattern: The analytic pattern.
        dark_reflectance: Reflectance of the dark paint, in [0, 1].
        bright_reflectance: Reflectance of the plate (bright paint), in [0, 1].
        on_plate: If True the pattern is painted on a bright plate that covers
            ``pattern.half_extent``; if False only the dark region covers the
            ground (a shape painted straight onto the ground).
        dull_signs: Signs (of u, of v) of a quadrant of the X whose paint is
            dulled by ``dull_factor`` (:attr:`MarkerPlacement.dull_signs`); None: none.
        dull_factor: Reflectance factor of that quadrant, in (0, 1].
    """

    homography: np.ndarray
    pattern: Pattern
    dark_reflectance: float
    bright_reflectance: float
    on_plate: bool = True
    dull_signs: tuple[int, int] | None = None
    dull_factor: float = 1.0

    @property
    def dull_margin(self) -> float:
        """The dull quadrant's lead over the dark paint (:attr:`MarkerTruth.dull_margin`)."""
        # An inverted marker's X is painted with the plate's paint: the brighter
        # paint is the one dulled, whichever it is.
        bright = max(self.bright_reflectance, self.dark_reflectance)
        dark = min(self.bright_reflectance, self.dark_reflectance)
        return (self.dull_factor * bright - dark) / (bright - dark)

    def translated(self, dx: float, dy: float) -> PlanarTarget:
        """The same target moved by (dx, dy) px in the image."""
        shift = np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])
        return replace(self, homography=shift @ _normalised(self.homography))


@dataclass(frozen=True)
class CastShadow:
    """A hard cast shadow over one marker and the ground around it (image space).

    The shadowed region is the half-plane ``cos(a) (x - x0) + sin(a) (y - y0)
    >= offset_px`` within ``reach_px`` of (x0, y0); both borders have a normal
    CDF profile of 10-90 % width ``penumbra_px``, integrated over the pixel area.

    Attributes:
        x: x0, image x of the point the shadow is placed about (a marker centre), px.
        y: y0, px.
        normal_rad: a, direction from the edge into the shadow, radians from +x to +y.
        offset_px: Signed distance of the straight edge from (x0, y0), px.
        darkening: Fraction of the light the shadow takes away, in (0, 1).
        reach_px: Radius of the disk the shadow stays in, px.
        penumbra_px: 10-90 % width of the shadow's borders, px.
    """

    x: float
    y: float
    normal_rad: float
    offset_px: float
    darkening: float
    reach_px: float
    penumbra_px: float = CAST_SHADOW_PENUMBRA_PX

    def __post_init__(self) -> None:
        if not 0.0 < self.darkening < 1.0:
            raise ConfigError(f"darkening must be in (0, 1), got {self.darkening!r}")
        if not self.reach_px > abs(self.offset_px):
            raise ConfigError(
                f"reach_px={self.reach_px!r} must exceed |offset_px|={abs(self.offset_px)!r}"
            )
        if not self.penumbra_px > 0:
            raise ConfigError(f"penumbra_px must be > 0, got {self.penumbra_px!r}")

    def is_about(self, x: float, y: float) -> bool:
        """Whether this shadow is placed about the point (x, y) (a marker's centre)."""
        return bool(np.isclose(self.x, x) and np.isclose(self.y, y))

    def apply(self, gain: np.ndarray) -> None:
        """Multiply a (height, width) light gain image by this shadow, in place."""
        height, width = gain.shape
        r0, r1 = (
            max(0, math.floor(self.y - self.reach_px) - 2),
            min(height, math.ceil(self.y + self.reach_px) + 3),
        )
        c0, c1 = (
            max(0, math.floor(self.x - self.reach_px) - 2),
            min(width, math.ceil(self.x + self.reach_px) + 3),
        )
        if r0 >= r1 or c0 >= c1:
            return
        steps = (np.arange(_SHADOW_SUPERSAMPLING) + 0.5) / _SHADOW_SUPERSAMPLING - 0.5
        y = (np.arange(r0, r1)[:, None] + steps[None, :]).ravel() - self.y
        x = (np.arange(c0, c1)[:, None] + steps[None, :]).ravel() - self.x
        sigma = self.penumbra_px / _NORMAL_10_90_WIDTH
        across = (
            math.cos(self.normal_rad) * x[None, :]
            + math.sin(self.normal_rad) * y[:, None]
            - self.offset_px
        )
        inside = self.reach_px - np.hypot(x[None, :], y[:, None])
        shade = ndtr(across / sigma) * ndtr(inside / sigma)
        n = _SHADOW_SUPERSAMPLING
        # Mean of the n x n samples of each pixel.
        shade = shade.reshape(r1 - r0, n, c1 - c0, n).mean(axis=(1, 3))
        gain[r0:r1, c0:c1] *= (1.0 - self.darkening * shade).astype(np.float32)


#: Strongest light field :func:`illumination_field` draws: a gain from 0.05 to 1, 20 to
#: 1 across a frame, the widest the independent renderer's clutter frames show (their
#: light, blurred by 60 px, spans 6-20 to 1: docs/accuracy-journal.md, "The independent
#: renderer's light on (d)").
MAX_ILLUMINATION_STRENGTH = 1.9


@dataclass(frozen=True)
class ImagingConditions:
    """Light, optics and sensor of one frame; applied by :func:`apply_imaging`.

    Attributes:
        blur_sigma_px: Sigma of the Gaussian PSF, px (0: none).
        motion_blur_px: Length of the linear motion blur, px (0: none).
        motion_blur_angle_rad: Direction of the motion, radians from +x to +y.
        illumination_strength: 0 = uniform light; s > 0 = a smooth gain field
            (linear gradient plus random bumps) spanning 1 - s / 2 to 1.0, s at
            most :data:`MAX_ILLUMINATION_STRENGTH`.
        n_shadows: Number of soft-edged shadow polygons (gain 0.4 to 0.7).
        vignetting: Fraction of light lost in the frame corners (0: none).
        gamma: Display gamma; the encoded signal is radiance ** (1 / gamma).
        noise_sigma_dn: Gaussian read-noise sigma in output DN (8-bit levels).
        shot_noise_gain_dn: Shot-noise variance per DN of signal, DN (a
            full well of F electrons at full scale gives 255 / F); 0: none.
        peak_level: Output level of white (radiance 1) as a fraction of 255:
            the exposure, in (0, 1].
        cast_shadows: Hard cast shadows (applied with the light, before the optics).
        jpeg_quality: JPEG quality (1-100) the camera writes the frame with,
            applied last; None: the frame stays as quantised.
    """

    blur_sigma_px: float = 0.0
    motion_blur_px: float = 0.0
    motion_blur_angle_rad: float = 0.0
    illumination_strength: float = 0.0
    n_shadows: int = 0
    vignetting: float = 0.0
    gamma: float = 1.0
    noise_sigma_dn: float = 0.0
    shot_noise_gain_dn: float = 0.0
    peak_level: float = 1.0
    cast_shadows: tuple[CastShadow, ...] = ()
    jpeg_quality: int | None = None

    def __post_init__(self) -> None:
        checks = {
            "blur_sigma_px": self.blur_sigma_px >= 0,
            "motion_blur_px": self.motion_blur_px >= 0,
            "illumination_strength": 0 <= self.illumination_strength <= MAX_ILLUMINATION_STRENGTH,
            "n_shadows": self.n_shadows >= 0,
            "vignetting": 0 <= self.vignetting < 1,
            "gamma": self.gamma > 0,
            "noise_sigma_dn": self.noise_sigma_dn >= 0,
            "shot_noise_gain_dn": self.shot_noise_gain_dn >= 0,
            "peak_level": 0 < self.peak_level <= 1,
            "jpeg_quality": self.jpeg_quality is None or 1 <= self.jpeg_quality <= 100,
        }
        for name, ok in checks.items():
            if not ok:
                raise ConfigError(f"{name} out of range: {getattr(self, name)!r}")

    def pixel_variance_dn2(self, signal_dn: np.ndarray) -> np.ndarray:
        """Noise variance of each pixel of a noise-free signal, DN^2.

        Read noise, shot noise and rounding to integer DN (JPEG left out):
        ``noise_sigma_dn**2 + shot_noise_gain_dn * signal + 1/12``.
        """
        return (
            self.noise_sigma_dn**2
            + QUANTISATION_VARIANCE_DN2
            + self.shot_noise_gain_dn * np.maximum(signal_dn, 0.0)
        )


@dataclass(frozen=True)
class RenderedScene:
    """A rendered frame and its exact ground truth.

    Attributes:
        image: (height, width) uint8 frame.
        markers: Truth of every marker (or checkerboard corner), in the order
            the markers were given or placed.
        negatives: (kind, x, y) of every hard negative; (x, y) is the image of
            its plane origin (the corner, junction or centre of the shape).
        imaging: The light, optics and sensor the frame was rendered with.
    """

    image: np.ndarray
    markers: list[MarkerTruth]
    negatives: list[tuple[str, float, float]]
    imaging: ImagingConditions = field(default_factory=ImagingConditions)

    @property
    def centres(self) -> np.ndarray:
        """(N, 2) float64 array of the marker centres (x, y), px."""
        return np.array([(m.x, m.y) for m in self.markers], dtype=np.float64).reshape(-1, 2)

    @property
    def crlb_px(self) -> np.ndarray:
        """(N,) each marker's ``crlb_mean_abs_error_px`` (NaN where not computed), px."""
        return np.array([m.crlb_mean_abs_error_px for m in self.markers], dtype=np.float64)

    @property
    def shadow_crossed(self) -> np.ndarray:
        """(N,) bool: a cast shadow (:class:`CastShadow`) is placed about the marker's centre."""
        shadows = self.imaging.cast_shadows
        return np.array([any(c.is_about(m.x, m.y) for c in shadows) for m in self.markers], bool)


# --------------------------------------------------------------------------- compositing core


def _normalised(homography: np.ndarray) -> np.ndarray:
    h = np.asarray(homography, dtype=np.float64)
    if h.shape != (3, 3) or h[2, 2] == 0:
        raise ConfigError(f"homography must be 3x3 with H[2, 2] != 0, got {h!r}")
    return h / h[2, 2]


def _plate_corners(target: PlanarTarget) -> np.ndarray:
    eu, ev = target.pattern.half_extent
    return np.array([[-eu, -ev], [eu, -ev], [eu, ev], [-eu, ev]])


def target_bounding_radius(target: PlanarTarget) -> float:
    """Largest image distance from the target's centre to its plate corners, px."""
    h = _normalised(target.homography)
    corners = project(h, _plate_corners(target))
    return float(np.max(np.hypot(corners[:, 0] - h[0, 2], corners[:, 1] - h[1, 2])))


def _pixel_box(
    h: np.ndarray, target: PlanarTarget, shape: tuple[int, int]
) -> tuple[int, int, int, int] | None:
    """Rows [r0, r1) and columns [c0, c1) that can touch the target's plate."""
    corners = _plate_corners(target)
    w = corners @ h[2, :2] + h[2, 2]
    if np.any(w <= 0):
        raise ConfigError("the homography maps part of the plate behind the camera")
    xy = project(h, corners)
    # The image of a convex plate in front of the camera is the convex hull of its corners.
    c0 = max(0, math.floor(xy[:, 0].min()) - 1)
    c1 = min(shape[1], math.ceil(xy[:, 0].max()) + 2)
    r0 = max(0, math.floor(xy[:, 1].min()) - 1)
    r1 = min(shape[0], math.ceil(xy[:, 1].max()) + 2)
    return (r0, r1, c0, c1) if r0 < r1 and c0 < c1 else None


def to_plane(g: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map image points through the image -> plane homography ``g``."""
    w = g[2, 0] * x + g[2, 1] * y + g[2, 2]
    return (g[0, 0] * x + g[0, 1] * y + g[0, 2]) / w, (g[1, 0] * x + g[1, 1] * y + g[1, 2]) / w


def _footprint(
    g: np.ndarray, x: np.ndarray, y: np.ndarray, u: np.ndarray, v: np.ndarray
) -> np.ndarray:
    """Upper bound of the plane distance from a pixel centre to any of its samples."""
    w = g[2, 0] * x + g[2, 1] * y + g[2, 2]
    # Jacobian of the image -> plane map (times w); its largest singular value
    # is how far the plane moves per pixel in the worst direction.
    j00, j01 = g[0, 0] - u * g[2, 0], g[0, 1] - u * g[2, 1]
    j10, j11 = g[1, 0] - v * g[2, 0], g[1, 1] - v * g[2, 1]
    frobenius_sq = j00 * j00 + j01 * j01 + j10 * j10 + j11 * j11
    det = j00 * j11 - j01 * j10
    sigma_max_sq = 0.5 * (frobenius_sq + np.sqrt(np.maximum(frobenius_sq**2 - 4 * det**2, 0)))
    return _PIXEL_HALF_DIAGONAL * _FOOTPRINT_MARGIN * np.sqrt(sigma_max_sq) / np.abs(w)


def _masks(target: PlanarTarget, u: np.ndarray, v: np.ndarray) -> list[np.ndarray]:
    """Which plane samples the target covers, which are dark paint, and which are dulled.

    Returns [covered, dark] and, with a dull quadrant, [bright dulled, dark dulled].
    """
    dark = target.pattern.dark(u, v)
    if target.on_plate:
        eu, ev = target.pattern.half_extent
        covered = (np.abs(u) <= eu) & (np.abs(v) <= ev)
    else:
        covered = dark
    if target.dull_signs is None or target.pattern.x_extent is None:
        return [covered, dark]
    su, sv = target.dull_signs
    dull = (su * u > 0) & (sv * v > 0) & target.pattern.x_extent(u, v) & covered
    return [covered, dark, dull & ~dark, dull & dark]


def _paint(target: PlanarTarget, fractions: np.ndarray) -> np.ndarray:
    """Mean of coverage * reflectance, from the fractions of :func:`_masks`' samples."""
    coverage, dark_fraction, *dull = fractions
    bright, dark = target.bright_reflectance, target.dark_reflectance
    # The dark paint lies on the plate: bright everywhere covered, minus the dark part.
    paint = (
        dark * dark_fraction
        if not target.on_plate
        else bright * coverage + (dark - bright) * dark_fraction
    )
    if dull:
        paint -= (1.0 - target.dull_factor) * (bright * dull[0] + dark * dull[1])
    return paint


def _plate_distance(target: PlanarTarget, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    eu, ev = target.pattern.half_extent
    return np.minimum(np.abs(np.abs(u) - eu), np.abs(np.abs(v) - ev))


def _sample_offsets(supersampling: int) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel sample offsets (k + 0.5) / S - 0.5 on an S x S grid, flattened."""
    steps = (np.arange(supersampling) + 0.5) / supersampling - 0.5
    dy, dx = np.meshgrid(steps, steps, indexing="ij")
    return dx.ravel(), dy.ravel()


def _supersample(
    target: PlanarTarget,
    g: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    supersampling: int,
    n_masks: int,
) -> np.ndarray:
    """(n_masks, N) fractions of the S x S samples of each pixel in each of :func:`_masks`."""
    dx, dy = _sample_offsets(supersampling)
    # Homogeneous plane coordinates are linear in the image point, so a sample's
    # are its pixel centre's plus its offset's. Both are computed in float64;
    # float32 then carries plane coordinates of magnitude ~1 to ~1e-7, far
    # below any error that matters, at half the memory traffic.
    centre = (g @ np.stack([x, y, np.ones_like(x)])).astype(np.float32)
    offset = (g[:, :2] @ np.stack([dx, dy])).astype(np.float32)
    fractions = np.empty((n_masks, x.size))
    step = max(1, SAMPLE_CHUNK // dx.size)
    for start in range(0, x.size, step):
        rows = slice(start, start + step)
        w = centre[2, rows, None] + offset[2]
        u = (centre[0, rows, None] + offset[0]) / w
        v = (centre[1, rows, None] + offset[1]) / w
        for k, mask in enumerate(_masks(target, u, v)):
            fractions[k, rows] = np.count_nonzero(mask, axis=1) / dx.size
    return fractions


def composite_target(
    radiance: np.ndarray, target: PlanarTarget, supersampling: int = 16, *, exhaustive: bool = False
) -> None:
    """Paint one target into a reflectance image, integrating over pixel areas.

    Each pixel becomes coverage * paint + (1 - coverage) * ground, averaged over
    S x S samples at offsets (k + 0.5) / S - 0.5, each mapped to the plane
    through the inverse homography. Pixels whose footprint is farther from
    every edge than its own size are uniform; they get one sample, which gives
    the same value the S x S samples would (``exhaustive=True`` samples every
    pixel, for checking that claim).

    Args:
        radiance: (height, width) float32 image, modified in place.
        target: What to paint.
        supersampling: S, samples per pixel along each axis.
        exhaustive: Supersample every pixel of the bounding box.
    """
    h = _normalised(target.homography)
    box = _pixel_box(h, target, radiance.shape)
    if box is None:
        return
    r0, r1, c0, c1 = box
    g = np.linalg.inv(h)
    y, x = np.mgrid[r0:r1, c0:c1].astype(np.float64)
    u, v = to_plane(g, x, y)
    distance = target.pattern.edge_distance(u, v)
    if target.on_plate:
        distance = np.minimum(distance, _plate_distance(target, u, v))
    edge = np.full(u.shape, True) if exhaustive else distance <= _footprint(g, x, y, u, v)
    fractions = np.array([m.astype(np.float64) for m in _masks(target, u, v)])
    fractions[:, edge] = _supersample(target, g, x[edge], y[edge], supersampling, len(fractions))
    window = radiance[r0:r1, c0:c1]
    window[...] = (1.0 - fractions[0]) * window + _paint(target, fractions)


# --------------------------------------------------------------------------- imaging chain


def motion_blur_kernel(length_px: float, angle_rad: float) -> np.ndarray:
    """Centrally symmetric linear motion-blur kernel.

    The segment from -length/2 to +length/2 along ``angle_rad`` is sampled
    densely and splatted bilinearly, so fractional end points get partial
    weight; the kernel is odd-sized and point-symmetric about its centre, so
    blurring does not move anything.

    Args:
        length_px: Length of the motion, px (> 0).
        angle_rad: Direction, radians from +x towards +y.

    Returns:
        (k, k) float32 kernel, k odd, summing to 1.
    """
    radius = math.ceil(length_px / 2.0) + 1
    size = 2 * radius + 1
    n_samples = max(2, math.ceil(length_px * 16))
    t = ((np.arange(n_samples) + 0.5) / n_samples - 0.5) * length_px
    x, y = radius + t * math.cos(angle_rad), radius + t * math.sin(angle_rad)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    kernel: np.ndarray = np.zeros((size, size))
    for dy, dx, weight in (
        (0, 0, (1 - fx) * (1 - fy)),
        (0, 1, fx * (1 - fy)),
        (1, 0, (1 - fx) * fy),
        (1, 1, fx * fy),
    ):
        np.add.at(kernel, (y0 + dy, x0 + dx), weight)
    # Symmetrise away rounding so the kernel cannot shift the image.
    kernel = 0.5 * (kernel + kernel[::-1, ::-1])
    return (kernel / kernel.sum()).astype(np.float32)


def illumination_field(
    shape: tuple[int, int], strength: float, rng: np.random.Generator
) -> np.ndarray:
    """Smooth multiplicative light gain: a linear gradient plus random bumps.

    Args:
        shape: (height, width), px.
        strength: 0 gives a gain of 1 everywhere; s spans the gain 1 - s / 2 to 1.0
            (at most :data:`MAX_ILLUMINATION_STRENGTH`).
        rng: Source of randomness.

    Returns:
        float32 gain of the given shape, in [1 - strength / 2, 1].
    """
    height, width = shape
    angle = rng.uniform(0.0, 2.0 * math.pi)
    # The gradient is separable: a row term plus a column term, shifted to start at 0.
    along_x = (math.cos(angle) * np.arange(width)).astype(np.float32)
    along_y = (math.sin(angle) * np.arange(height)).astype(np.float32)
    along_x -= along_x.min()
    along_y -= along_y.min()
    span = max(float(along_x.max() + along_y.max()), 1e-6)
    mix = rng.uniform(0.3, 0.7)
    depth = 0.5 * strength
    # gain = 1 - depth * (mix * gradient + (1 - mix) * bumps), in place on the bumps.
    gain = smooth_random_field(shape, rng, cell_px=max(shape) / rng.uniform(2.0, 5.0))
    gain *= np.float32(-depth * (1.0 - mix))
    gain += (along_y[:, None] + along_x[None, :]) * np.float32(-depth * mix / span)
    gain += np.float32(1.0)
    return gain


_SHADOW_DOWNSCALE = 4  # shadows are smooth: draw them at quarter resolution


def shadow_field(shape: tuple[int, int], n_shadows: int, rng: np.random.Generator) -> np.ndarray:
    """Multiplicative gain of soft-edged polygonal shadows.

    Args:
        shape: (height, width), px.
        n_shadows: Number of shadows; each is a random 3- to 7-gon of 10-40 % of
            the smaller frame side in radius, with a penumbra of 2-15 px, that
            keeps 40-70 % of the light. Shadows may cross markers.
        rng: Source of randomness.

    Returns:
        float32 gain of the given shape, in (0, 1].
    """
    low_shape = (max(1, shape[0] // _SHADOW_DOWNSCALE), max(1, shape[1] // _SHADOW_DOWNSCALE))
    gain = np.ones(low_shape, dtype=np.float32)
    for _ in range(n_shadows):
        n_vertices = int(rng.integers(3, 8))
        centre = rng.uniform((0, 0), low_shape[::-1])
        radius = rng.uniform(0.1, 0.4) * min(low_shape) * rng.uniform(0.6, 1.0, n_vertices)
        angles = np.sort(rng.uniform(0, 2 * math.pi, n_vertices))
        polygon = centre + radius[:, None] * np.column_stack([np.cos(angles), np.sin(angles)])
        outline = np.zeros(low_shape, dtype=np.float32)
        cv2.fillPoly(outline, [np.round(polygon).astype(np.int32)], 1.0)
        penumbra_px = rng.uniform(2.0, 15.0) / _SHADOW_DOWNSCALE
        mask = cv2.GaussianBlur(outline, (0, 0), penumbra_px)
        gain *= 1.0 - np.float32(1.0 - rng.uniform(0.4, 0.7)) * mask
    return cv2.resize(gain, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR)


def vignetting_field(shape: tuple[int, int], vignetting: float) -> np.ndarray:
    """Radial gain 1 - vignetting * (r / r_corner)^2 about the frame centre (float32)."""
    height, width = shape
    x = (np.arange(width, dtype=np.float32) - (width - 1) / 2) / ((width - 1) / 2 or 1)
    y = (np.arange(height, dtype=np.float32) - (height - 1) / 2) / ((height - 1) / 2 or 1)
    return (1.0 - vignetting * 0.5 * (x[None, :] ** 2 + y[:, None] ** 2)).astype(np.float32)


def light_gain(
    shape: tuple[int, int], imaging: ImagingConditions, rng: np.random.Generator
) -> np.ndarray | None:
    """The frame's multiplicative light on the scene: illumination, soft and cast shadows.

    Args:
        shape: (height, width), px.
        imaging: Light, optics and sensor (only the light is used).
        rng: Source of randomness (the illumination field and the soft shadows).

    Returns:
        float32 gain of the given shape, or None for uniform light.
    """
    gain = None
    if imaging.illumination_strength > 0:
        gain = illumination_field(shape, imaging.illumination_strength, rng)
    if imaging.n_shadows > 0:
        shadows = shadow_field(shape, imaging.n_shadows, rng)
        gain = shadows if gain is None else gain * shadows
    if imaging.cast_shadows:
        gain = np.ones(shape, np.float32) if gain is None else gain
        for shadow in imaging.cast_shadows:
            shadow.apply(gain)
    return gain


def optics_margin_px(imaging: ImagingConditions) -> int:
    """How far the optics spread a point, px: a window grown by this renders exactly."""
    return math.ceil(4.0 * imaging.blur_sigma_px + 0.5 * imaging.motion_blur_px) + 2


def expose(
    radiance: np.ndarray,
    imaging: ImagingConditions,
    gain: np.ndarray | None,
    vignette: np.ndarray | None,
) -> np.ndarray:
    """Noise-free signal of a scene reflectance image (or a window of one), DN.

    Order: light on the scene; optics (Gaussian PSF, motion blur, vignetting);
    clipping to full scale; display gamma; the exposure's peak level.

    Args:
        radiance: (height, width) float32 reflectance in [0, 1]; overwritten.
        imaging: Light, optics and sensor.
        gain: Light gain of the same shape (:func:`light_gain`), or None.
        vignette: Vignetting gain of the same shape (:func:`vignetting_field`), or None.

    Returns:
        float32 signal in [0, 255 * peak_level] DN.
    """
    if gain is not None:
        radiance *= gain
    if imaging.blur_sigma_px > 0:
        radiance = cv2.GaussianBlur(radiance, (0, 0), imaging.blur_sigma_px)
    if imaging.motion_blur_px > 0:
        kernel = motion_blur_kernel(imaging.motion_blur_px, imaging.motion_blur_angle_rad)
        radiance = cv2.filter2D(radiance, -1, kernel, borderType=cv2.BORDER_REFLECT_101)
    if vignette is not None:
        radiance *= vignette
    np.clip(radiance, 0.0, 1.0, out=radiance)
    if imaging.gamma != 1.0:
        radiance = cv2.pow(radiance, 1.0 / imaging.gamma)
    radiance *= np.float32(255.0 * imaging.peak_level)
    return radiance


def record(
    signal_dn: np.ndarray, imaging: ImagingConditions, rng: np.random.Generator
) -> np.ndarray:
    """What the camera writes: Poisson-Gaussian noise, 8-bit rounding, optional JPEG.

    Noise (normal approximation of Poisson-Gaussian, variance
    :meth:`ImagingConditions.pixel_variance_dn2` less the rounding) is drawn on
    the encoded signal, so the read-noise sigma is exact in output DN.

    Args:
        signal_dn: (height, width) float32 noise-free signal, DN; overwritten.
        imaging: The sensor's noise and the JPEG quality.
        rng: Source of randomness.

    Returns:
        (height, width) uint8 frame.
    """
    if imaging.shot_noise_gain_dn > 0:
        # At > 100 electrons per pixel the Poisson law is indistinguishable from
        # this normal approximation.
        sigma = np.sqrt(
            np.float32(imaging.shot_noise_gain_dn) * np.maximum(signal_dn, 0)
            + np.float32(imaging.noise_sigma_dn**2)
        )
        signal_dn += sigma * rng.standard_normal(signal_dn.shape, dtype=np.float32)
    elif imaging.noise_sigma_dn > 0:
        signal_dn += np.float32(imaging.noise_sigma_dn) * rng.standard_normal(
            signal_dn.shape, dtype=np.float32
        )
    np.rint(signal_dn, out=signal_dn)
    np.clip(signal_dn, 0, 255, out=signal_dn)
    frame = signal_dn.astype(np.uint8)
    if imaging.jpeg_quality is None:
        return frame
    ok, encoded = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, imaging.jpeg_quality])
    decoded = cv2.imdecode(encoded, cv2.IMREAD_GRAYSCALE) if ok else None
    if decoded is None:
        raise ConfigError(f"JPEG round trip failed at quality {imaging.jpeg_quality!r}")
    return decoded


def apply_imaging(
    radiance: np.ndarray,
    imaging: ImagingConditions,
    rng: np.random.Generator,
    sensor_gain: np.ndarray | None = None,
) -> np.ndarray:
    """Turn a scene reflectance image into an 8-bit camera frame.

    :func:`light_gain`, :func:`expose` and :func:`record` in turn.

    Args:
        radiance: (height, width) float32 reflectance in [0, 1]; overwritten.
        imaging: Light, optics and sensor.
        rng: Source of randomness.
        sensor_gain: (height, width) float32 gain of each pixel's filter on the exposed
            signal, before the sensor's noise (a colour filter array's,
            :func:`bayer_gain`); None: a monochrome sensor.

    Returns:
        (height, width) uint8 frame.
    """
    gain = light_gain(radiance.shape, imaging, rng)
    vignette = (
        vignetting_field(radiance.shape, imaging.vignetting) if imaging.vignetting > 0 else None
    )
    signal = expose(radiance, imaging, gain, vignette)
    if sensor_gain is not None:
        signal *= sensor_gain
    return record(signal, imaging, rng)


#: A raw sensor's red, green and blue response to white light, relative to green,
#: before white balance: a CMOS sensor behind an infrared cut filter in daylight.
RAW_BAYER_GAINS: tuple[float, float, float] = (0.55, 1.0, 0.75)


def bayer_gain(
    shape: tuple[int, int], pattern: str, rgb_gains: tuple[float, float, float] = RAW_BAYER_GAINS
) -> np.ndarray:
    """(height, width) float32 gain of a Bayer filter's pixels on an achromatic scene.

    Args:
        shape: (height, width) of the frame, px.
        pattern: one of :data:`BAYER_PATTERNS`; the frame's pixel (0, 0) is its cell's first.
        rgb_gains: the red, green and blue pixels' response to white.

    Raises:
        ConfigError: an unknown pattern.
    """
    if pattern not in BAYER_PATTERNS:
        raise ConfigError(f"unknown Bayer pattern {pattern!r}; choose from {BAYER_PATTERNS}")
    by_colour = dict(zip("rgb", rgb_gains, strict=True))
    cell = np.array(
        [
            [by_colour[pattern[0]], by_colour[pattern[1]]],
            [by_colour[pattern[2]], by_colour[pattern[3]]],
        ],
        np.float32,
    )
    height, width = shape
    return np.tile(cell, ((height + 1) // 2, (width + 1) // 2))[:height, :width]


def make_background(
    shape: tuple[int, int],
    background: str | np.ndarray,
    rng: np.random.Generator,
    level: float = FLAT_BACKGROUND_LEVEL,
    texture_scale: tuple[float, float] = TEXTURE_SCALE_RANGE,
) -> np.ndarray:
    """Ground reflectance image: ``"texture"``, ``"flat"`` or a given array.

    Args:
        shape: (height, width), px.
        background: ``"texture"`` (cluttered photographs), ``"flat"`` (uniform
            ``level``) or a (height, width) array of reflectances in [0, 1].
        rng: Source of randomness (texture only).
        level: Reflectance of the flat background.
        texture_scale: (min, max) magnification of the photographs, frame px
            per texture px (texture only).

    Returns:
        A new float32 (height, width) array.
    """
    if isinstance(background, np.ndarray):
        if background.shape != tuple(shape):
            raise ConfigError(f"background shape {background.shape} != frame shape {shape}")
        return background.astype(np.float32, copy=True)
    if background == "texture":
        return texture_background(shape, rng, scale_range=texture_scale)
    if background == "flat":
        return flat_background(shape, level)
    raise ConfigError(f"unknown background {background!r}; choose from {BACKGROUNDS}")


def render_targets(
    shape: tuple[int, int],
    targets: Sequence[PlanarTarget],
    rng: np.random.Generator,
    *,
    background: str | np.ndarray = "flat",
    background_level: float = FLAT_BACKGROUND_LEVEL,
    imaging: ImagingConditions | None = None,
    supersampling: int = 16,
    texture_scale: tuple[float, float] = TEXTURE_SCALE_RANGE,
) -> np.ndarray:
    """Render planar targets over a background and through the imaging chain.

    The core every renderer of this package uses; it takes homographies (in
    the targets), so a flight simulator can feed camera-derived ones.

    Args:
        shape: (height, width) of the frame, px.
        targets: Painted in order (later ones cover earlier ones).
        rng: Source of randomness.
        background: See :func:`make_background`.
        background_level: Reflectance of the flat background.
        imaging: Light, optics and sensor; default: none of them (exact frame).
        supersampling: S, samples per pixel along each axis (>= 1).
        texture_scale: See :func:`make_background`.

    Returns:
        (height, width) uint8 frame.
    """
    image, _ = _render(
        shape,
        targets,
        rng,
        background,
        background_level,
        imaging or ImagingConditions(),
        supersampling,
        texture_scale,
    )
    return image


def _render(
    shape: tuple[int, int],
    targets: Sequence[PlanarTarget],
    rng: np.random.Generator,
    background: str | np.ndarray,
    background_level: float,
    imaging: ImagingConditions,
    supersampling: int,
    texture_scale: tuple[float, float],
    crlb_of: Sequence[int] = (),
    parts_within: float | None = None,
) -> tuple[np.ndarray, list[tuple[float, float, crlb.BoundParts | None]]]:
    """:func:`render_targets`, and the Cramer-Rao bound (px) and X's SNR of the targets ``crlb_of``.

    With ``parts_within``, each bound's :class:`~marker_localizer.synthetic.crlb.BoundParts`
    too (:func:`_marker_crlb`).
    """
    if supersampling < 1:
        raise ConfigError(f"supersampling must be >= 1, got {supersampling!r}")
    radiance = make_background(shape, background, rng, background_level, texture_scale)
    ground = radiance.copy() if crlb_of else radiance
    for target in targets:
        composite_target(radiance, target, supersampling)
    gain = light_gain(shape, imaging, rng)
    vignette = vignetting_field(shape, imaging.vignetting) if imaging.vignetting > 0 else None
    boxes = [_pixel_box(_normalised(t.homography), t, shape) for t in targets] if crlb_of else []
    bounds = [
        _marker_crlb(
            ground, targets, boxes, i, imaging, gain, vignette, supersampling, parts_within
        )
        for i in crlb_of
    ]
    return record(expose(radiance, imaging, gain, vignette), imaging, rng), bounds


#: Translation of a marker for the central differences of its Cramer-Rao bound, px,
#: before it is rounded to whole steps of the supersampling lattice (1/S px): an
#: edge along a pixel axis then moves across whole columns of samples, so its
#: area changes exactly (0.1 px on a 1/16 px lattice over-read such an edge's
#: derivative by 25 %). Small against the blur: the difference's error is about
#: step^2 / (6 sigma^2) of the information. Measured on blur 0.5-0.6 px: bounds
#: within 1 % (0.3 % on average) of those with a 0.025 px step and 4x finer
#: supersampling.
CRLB_STEP_PX = 0.1
#: The plane turned by one, two and three quarters, (u, v) -> (-v, u) and its powers,
#: as homographies of the plane: a marker's plate turned onto itself, its X onto its
#: negative.
_QUARTER_TURNS = tuple(
    np.linalg.matrix_power(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), k)
    for k in (1, 2, 3)
)


#: Central-difference steps of :class:`~marker_localizer.synthetic.crlb.BoundParts`'
#: smooth parameters: a paint's reflectance (its signal is linear in it) ...
BOUND_PAINT_STEP = 0.002
#: ... the optics' blur, px (the image is smooth in it; under 1 % of 0.5-1.5 px) ...
BOUND_BLUR_STEP_PX = 0.02
#: ... the light's slope, per px (the gain is linear in it) ...
BOUND_LIGHT_SLOPE_STEP_PER_PX = 1e-4
#: ... and a cast shadow's edge: its normal, rad, and its offset, px (its profile is
#: a normal CDF: smooth; the share of the light it takes steps as a paint does).
BOUND_SHADOW_NORMAL_STEP_RAD = 1e-3
BOUND_SHADOW_OFFSET_STEP_PX = 0.01


def _marker_crlb(
    ground: np.ndarray,
    targets: Sequence[PlanarTarget],
    boxes: Sequence[tuple[int, int, int, int] | None],
    index: int,
    imaging: ImagingConditions,
    gain: np.ndarray | None,
    vignette: np.ndarray | None,
    supersampling: int,
    parts_within: float | None = None,
) -> tuple[float, float, crlb.BoundParts | None]:
    """Cramer-Rao bound of ``targets[index]``'s centre as the expected |error|, px, and its X's SNR.

    The noise-free frame around the marker (its window grown by the optics'
    reach, with the ground and every other target in it) is re-rendered with
    the marker moved by about +-:data:`CRLB_STEP_PX` along x and y, through the
    frame's light, optics, gamma and exposure but without noise or JPEG; the
    central differences and :meth:`ImagingConditions.pixel_variance_dn2` of
    the unmoved signal give the Fisher information over the pixels whose
    centres lie inside the X (:func:`~marker_localizer.synthetic.crlb.fisher_information`),
    as the independent renderer's ``truth.json`` sums it: the bound of an estimator
    that reads the X's pixels alone. The arcs and the plate's outline carry more; a
    maximum-likelihood fit of the whole window goes under it (0.71-0.82 of it measured,
    :mod:`~marker_localizer.synthetic.crlb`).
    The same frame with the marker turned by quarters in its plane gives its X's
    signal-to-noise ratio (:func:`~marker_localizer.synthetic.crlb.x_snr`).

    With ``parts_within`` (a share of the radius), also the
    :class:`~marker_localizer.synthetic.crlb.BoundParts`: the information of every
    parameter of :data:`~marker_localizer.synthetic.crlb.BOUND_PARAMETERS`, over the
    X and over the pixels within that share of its radius. The homography's
    parameters move each plane point by a velocity V(x) that changes little over the
    blur, so their derivatives are those of the centre's, d mu / dx V_x + d mu / dy
    V_y: exact where finite differences of a sampled plate would not be (a share of a
    lattice step moves no sample). The rest by central differences
    (:func:`_smooth_derivatives`).
    """
    target, box = targets[index], boxes[index]
    x_extent = target.pattern.x_extent
    if x_extent is None:
        raise ConfigError(f"a Cramer-Rao bound needs a marker kind, got {target.pattern.name!r}")
    if box is None:
        return math.nan, math.nan, None
    margin = optics_margin_px(imaging) + math.ceil(CRLB_STEP_PX) + 1
    height, width = ground.shape
    r0, r1 = max(0, box[0] - margin), min(height, box[1] + margin)
    c0, c1 = max(0, box[2] - margin), min(width, box[3] + margin)
    base = ground[r0:r1, c0:c1].copy()
    for other, other_box in zip(targets, boxes, strict=True):
        if (
            other is target
            or other_box is None
            or other_box[0] >= r1
            or other_box[1] <= r0
            or other_box[2] >= c1
            or other_box[3] <= c0
        ):
            continue
        composite_target(base, other.translated(-c0, -r0), supersampling)
    window = (slice(r0, r1), slice(c0, c1))
    light = None if gain is None else gain[window]

    def signal(
        dx: float = 0.0,
        dy: float = 0.0,
        painted: PlanarTarget = target,
        seen: ImagingConditions = imaging,
        lit: np.ndarray | None = light,
    ) -> np.ndarray:
        radiance = base.copy()
        composite_target(radiance, painted.translated(dx - c0, dy - r0), supersampling)
        return expose(radiance, seen, lit, None if vignette is None else vignette[window]).astype(
            np.float64
        )

    step = max(1, round(CRLB_STEP_PX * supersampling)) / supersampling
    d_mu_dx = (signal(step, 0.0) - signal(-step, 0.0)) / (2.0 * step)
    d_mu_dy = (signal(0.0, step) - signal(0.0, -step)) / (2.0 * step)
    y, x = np.mgrid[r0:r1, c0:c1].astype(np.float64)
    homography = _normalised(target.homography)
    u, v = to_plane(np.linalg.inv(homography), x, y)
    still = signal()
    variance = imaging.pixel_variance_dn2(still)
    inside = x_extent(u, v)
    bound = crlb.crlb_mean_abs_error(crlb.fisher_information(d_mu_dx, d_mu_dy, variance, inside))
    turns = [
        signal(painted=replace(target, homography=homography @ turn)) for turn in _QUARTER_TURNS
    ]
    snr = crlb.x_snr([still, *turns], variance)
    if parts_within is None:
        return bound, snr, None
    derivatives = [d_mu_dx, d_mu_dy]
    for velocity in _homography_velocities(homography, u, v):
        derivatives.append(d_mu_dx * velocity[0] + d_mu_dy * velocity[1])
    derivatives += _smooth_derivatives(signal, target, imaging, light, (r0, c0), (x, y))
    near = np.hypot(u, v) < parts_within
    return (
        bound,
        snr,
        crlb.BoundParts.of(
            crlb.parameter_information(derivatives, variance, inside),
            crlb.parameter_information(derivatives, variance, inside & near),
        ),
    )


def _smooth_derivatives(
    signal: Callable[..., np.ndarray],
    target: PlanarTarget,
    imaging: ImagingConditions,
    light: np.ndarray | None,
    origin: tuple[int, int],
    grid: tuple[np.ndarray, np.ndarray],
) -> list[np.ndarray]:
    """Central differences of a marker's window by its smooth parameters (:func:`_marker_crlb`).

    In :data:`~marker_localizer.synthetic.crlb.BOUND_PARAMETERS`' order from the
    paints on: ``signal(painted=, seen=, lit=)`` renders the window with the target,
    the imaging and the light given; ``origin`` is the window's (row, column) in the
    frame and ``grid`` its pixels' (x, y). A parameter the marker does not have (a
    dull quadrant, a cast shadow; a blur of zero) gets a zero derivative: known.
    """

    def central(ahead: dict[str, Any], behind: dict[str, Any], step: float) -> np.ndarray:
        return (signal(**ahead) - signal(**behind)) / (2.0 * step)

    zero = np.zeros(grid[0].shape)
    derivatives = []
    for paint, has in (
        ("dark_reflectance", True),
        ("bright_reflectance", True),
        ("dull_factor", target.dull_signs is not None),
    ):
        value = getattr(target, paint)
        derivatives.append(
            central(
                {"painted": replace(target, **{paint: value + BOUND_PAINT_STEP})},
                {"painted": replace(target, **{paint: value - BOUND_PAINT_STEP})},
                BOUND_PAINT_STEP,
            )
            if has
            else zero
        )
    blur = imaging.blur_sigma_px
    derivatives.append(
        central(
            {"seen": replace(imaging, blur_sigma_px=blur + BOUND_BLUR_STEP_PX)},
            {"seen": replace(imaging, blur_sigma_px=blur - BOUND_BLUR_STEP_PX)},
            BOUND_BLUR_STEP_PX,
        )
        if blur > BOUND_BLUR_STEP_PX
        else zero
    )
    lit = np.ones(grid[0].shape, np.float32) if light is None else light
    centre = _normalised(target.homography)[:2, 2]
    for along in (grid[0] - centre[0], grid[1] - centre[1]):
        tilt = (BOUND_LIGHT_SLOPE_STEP_PER_PX * along).astype(np.float32)
        derivatives.append(
            central(
                {"lit": lit * (1 + tilt)}, {"lit": lit * (1 - tilt)}, BOUND_LIGHT_SLOPE_STEP_PER_PX
            )
        )
    shadow = next((c for c in imaging.cast_shadows if c.is_about(*centre)), None)
    if shadow is None:
        return derivatives + [zero] * 3
    row, column = origin

    def window_light(placed: CastShadow) -> np.ndarray:
        light = np.ones(grid[0].shape, np.float32)
        replace(placed, x=placed.x - column, y=placed.y - row).apply(light)
        return light

    unmoved = window_light(shadow)

    def shaded(moved: CastShadow) -> dict[str, Any]:
        # The light with this shadow in place of the frame's own.
        return {"lit": lit * window_light(moved) / unmoved}

    for field_name, step in (
        ("normal_rad", BOUND_SHADOW_NORMAL_STEP_RAD),
        ("offset_px", BOUND_SHADOW_OFFSET_STEP_PX),
        ("darkening", BOUND_PAINT_STEP),
    ):
        value = getattr(shadow, field_name)
        derivatives.append(
            central(
                shaded(replace(shadow, **{field_name: value + step})),
                shaded(replace(shadow, **{field_name: value - step})),
                step,
            )
        )
    return derivatives


def _homography_velocities(
    homography: np.ndarray, u: np.ndarray, v: np.ndarray
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Image velocity (vx, vy) of the plane points (u, v) per unit of each shape parameter.

    The parameters of :data:`~marker_localizer.synthetic.crlb.BOUND_PARAMETERS` after
    the centre: the homography H becomes H P with P = [[1 + a, b, 0], [c, 1 + d, 0],
    [g, h, 1]], which keeps the plane origin, so the centre, where it is.
    """
    plane = np.stack([u, v, np.ones_like(u)])
    image = np.einsum("ij,j...->i...", homography, plane)
    zero = np.zeros_like(u)
    velocities = []
    for moved in ((u, zero, zero), (zero, u, zero), (v, zero, zero), (zero, v, zero)):
        velocities.append(_projected_velocity(homography, image, moved))
    for weight in (u, v):
        velocities.append(_projected_velocity(homography, image, (zero, zero, weight)))
    return velocities


def _projected_velocity(
    homography: np.ndarray, image: np.ndarray, moved: tuple[np.ndarray, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """The image velocity of the points ``image`` (homogeneous) as their plane points move."""
    change = np.einsum("ij,j...->i...", homography, np.stack(moved))
    w = image[2]
    return (
        change[0] / w - image[0] * change[2] / w**2,
        change[1] / w - image[1] * change[2] / w**2,
    )


# --------------------------------------------------------------------------- placement


def _random_paint(
    rng: np.random.Generator, contrast: tuple[float, float] | None = None
) -> tuple[float, float]:
    """(dark, bright) paint: from the paint ranges, or with a contrast drawn from ``contrast``."""
    if contrast is None:
        return (
            float(rng.uniform(*DARK_REFLECTANCE_RANGE)),
            float(rng.uniform(*BRIGHT_REFLECTANCE_RANGE)),
        )
    difference = float(rng.uniform(*contrast))
    low = DARK_REFLECTANCE_RANGE[0]
    dark = float(rng.uniform(low, max(low, BRIGHT_REFLECTANCE_RANGE[1] - difference)))
    return dark, dark + difference


def _target(
    placement: MarkerPlacement, paint: tuple[float, float], on_plate: bool = True
) -> PlanarTarget:
    dark, bright = paint[::-1] if placement.inverted else paint
    return PlanarTarget(
        marker_homography(placement),
        PATTERNS[placement.kind],
        dark,
        bright,
        on_plate,
        placement.dull_signs,
        placement.dull_factor,
    )


def _find_spot(
    radius: float, shape: tuple[int, int], occupied: np.ndarray, rng: np.random.Generator
) -> tuple[float, float] | None:
    """A random centre whose circle of ``radius`` keeps clear of the border and others.

    Args:
        radius: Bounding radius of the new target, px.
        shape: (height, width), px.
        occupied: (M, 3) rows of (x, y, radius) already taken.
        rng: Source of randomness.

    Returns:
        (x, y), or None after :data:`PLACEMENT_TRIES` failed tries.
    """
    reach = radius + PLACEMENT_GAP_PX
    low = (reach - 0.5, reach - 0.5)
    high = (shape[1] - 0.5 - reach, shape[0] - 0.5 - reach)
    if low[0] > high[0] or low[1] > high[1]:
        return None
    # Small batches: in a sparse frame the first batch nearly always succeeds.
    for _ in range(PLACEMENT_TRIES // _PLACEMENT_BATCH):
        candidates = rng.uniform(low, high, size=(_PLACEMENT_BATCH, 2))
        gaps = np.hypot(
            candidates[:, None, 0] - occupied[None, :, 0],
            candidates[:, None, 1] - occupied[None, :, 1],
        )
        clear = np.flatnonzero(np.all(gaps >= occupied[None, :, 2] + reach, axis=1))
        if clear.size:
            return float(candidates[clear[0], 0]), float(candidates[clear[0], 1])
    return None


def _bounding_radius(placement: MarkerPlacement) -> float:
    return target_bounding_radius(_target(placement, (0.0, 1.0)))


def _occupied(placements: Sequence[MarkerPlacement]) -> np.ndarray:
    rows = [(p.x, p.y, _bounding_radius(p)) for p in placements]
    return np.array(rows, dtype=np.float64).reshape(-1, 3)


def random_negatives(
    shape: tuple[int, int],
    n_negatives: int,
    rng: np.random.Generator,
    avoid: Sequence[MarkerPlacement] = (),
    *,
    radius_px: tuple[float, float] = (6.0, 40.0),
    max_tilt_deg: float = 60.0,
) -> list[tuple[MarkerPlacement, bool]]:
    """Random hard negatives that overlap neither ``avoid`` nor each other.

    Kinds are drawn from :data:`NEGATIVE_KINDS`; half are painted on a bright
    plate, half straight onto the ground. A negative that finds no free spot
    is left out (see the length of the result).

    Args:
        shape: (height, width), px.
        n_negatives: How many to try to place.
        rng: Source of randomness.
        avoid: Placements (markers) to keep clear of.
        radius_px: (min, max) size, px.
        max_tilt_deg: Largest tilt, degrees.

    Returns:
        (placement, on_plate) per placed negative.
    """
    occupied = _occupied(avoid)
    placed: list[tuple[MarkerPlacement, bool]] = []
    for _ in range(n_negatives):
        shape_only = _random_placement(rng, NEGATIVE_KINDS, radius_px, max_tilt_deg, 0.5)
        spot = _find_spot(_bounding_radius(shape_only), shape, occupied, rng)
        if spot is None:
            continue
        negative = MarkerPlacement(
            spot[0],
            spot[1],
            shape_only.radius_px,
            shape_only.rotation_rad,
            shape_only.tilt_deg,
            shape_only.tilt_axis_rad,
            shape_only.kind,
            shape_only.inverted,
        )
        occupied = np.vstack([occupied, (spot[0], spot[1], _bounding_radius(negative))])
        placed.append((negative, bool(rng.random() < 0.5)))
    if len(placed) < n_negatives:
        _LOG.warning(
            "placed only %d of %d hard negatives in a %dx%d frame",
            len(placed),
            n_negatives,
            shape[1],
            shape[0],
        )
    return placed


def _random_placement(
    rng: np.random.Generator,
    kinds: Sequence[str],
    radius_px: tuple[float, float],
    max_tilt_deg: float,
    inverted_fraction: float,
) -> MarkerPlacement:
    """A placement at (0, 0) with random size, rotation, tilt, kind and polarity.

    The radius is drawn log-uniformly: a marker's size in the image goes as one over
    its range, so each octave of size is as likely as the next. Drawn uniformly, as
    before, a range of 6-40 px put 9 % of the markers under 1.5 times its smallest
    radius, where the independent renderer's frames (``../shared/data/independent``,
    median radius 14 px at 6-40) put 31 %: the small tilted markers, whose X's
    shortest reach falls under the smallest radius, were rare here.
    """
    return MarkerPlacement(
        0.0,
        0.0,
        float(np.exp(rng.uniform(*np.log(radius_px)))),
        rotation_rad=float(rng.uniform(0.0, 2.0 * math.pi)),
        tilt_deg=float(rng.uniform(0.0, max_tilt_deg)),
        tilt_axis_rad=float(rng.uniform(0.0, math.pi)),
        kind=str(kinds[int(rng.integers(len(kinds)))]),
        inverted=bool(rng.random() < inverted_fraction),
    )


# --------------------------------------------------------------------------- public renderers


def render_markers(
    shape: tuple[int, int],
    markers: Sequence[MarkerPlacement],
    rng: int | np.random.Generator | None = None,
    *,
    background: str | np.ndarray = "flat",
    background_level: float = FLAT_BACKGROUND_LEVEL,
    reflectances: tuple[float, float] | None = None,
    contrast: tuple[float, float] | None = None,
    blur_sigma_px: float = 0.0,
    motion_blur_px: float = 0.0,
    motion_blur_angle_rad: float = 0.0,
    illumination_strength: float = 0.0,
    n_shadows: int = 0,
    cast_shadows: Sequence[CastShadow] = (),
    vignetting: float = 0.0,
    gamma: float = 1.0,
    peak_level: float = 1.0,
    noise_sigma_dn: float = 0.0,
    shot_noise_gain_dn: float = 0.0,
    jpeg_quality: int | None = None,
    n_hard_negatives: int = 0,
    negative_radius_px: tuple[float, float] = (6.0, 40.0),
    negative_max_tilt_deg: float = 60.0,
    texture_scale: tuple[float, float] = TEXTURE_SCALE_RANGE,
    supersampling: int = 16,
    crlb: bool = False,
    bound_parts_within: float | None = None,
) -> RenderedScene:
    """Render markers at explicit placements; the defaults give an exact, clean frame.

    With the defaults (flat background, no blur, gamma 1, no noise, no
    negatives) every pixel is exactly the area-weighted paint, up to 1/S of
    the pixel area and 8-bit rounding. Placements are used as given: they are
    not checked for overlap or for lying inside the frame.

    Args:
        shape: (height, width) of the frame, px.
        markers: Where to put each marker (with its dull quadrant, if any).
        rng: Seed or Generator for everything random (paint, texture, light,
            negatives, noise).
        background: ``"flat"``, ``"texture"`` or a reflectance array.
        background_level: Reflectance of the flat background, [0, 1].
        reflectances: (dark, bright) paint for every marker; None draws each
            marker's (see ``contrast``).
        contrast: (min, max) bright - dark reflectance of the drawn paint;
            None: dark from :data:`DARK_REFLECTANCE_RANGE`, bright from
            :data:`BRIGHT_REFLECTANCE_RANGE`. Negatives are drawn the same way.
        blur_sigma_px: Gaussian PSF sigma, px.
        motion_blur_px: Length of the linear, centred motion blur, px.
        motion_blur_angle_rad: Its direction, radians from +x towards +y.
        illumination_strength: 0 (uniform) to :data:`MAX_ILLUMINATION_STRENGTH`
            (:func:`illumination_field`: a gain of 1 - strength / 2 to 1.0).
        n_shadows: Number of soft shadow polygons.
        cast_shadows: Hard cast shadows (:class:`CastShadow`).
        vignetting: Fraction of light lost in the frame corners.
        gamma: Display gamma (signal = radiance ** (1 / gamma)).
        peak_level: Output level of white as a fraction of 255.
        noise_sigma_dn: Gaussian read-noise sigma, output DN.
        shot_noise_gain_dn: Shot-noise variance per DN of signal, DN; 0: none.
        jpeg_quality: JPEG quality the frame is written with; None: no JPEG.
        n_hard_negatives: Number of hard negatives to scatter, clear of markers.
        negative_radius_px: (min, max) radius of the negatives, px.
        negative_max_tilt_deg: Largest tilt of the negatives, degrees.
        texture_scale: (min, max) magnification of the ground photographs.
        supersampling: S, samples per pixel along each axis.
        crlb: Compute each marker's Cramer-Rao bound
            (``MarkerTruth.crlb_mean_abs_error_px``) and its X's signal-to-noise
            ratio (``MarkerTruth.x_snr``); a few more renders per marker.
        bound_parts_within: Also each marker's bounds with its other parameters
            unknown (``MarkerTruth.bound_parts``), the inner ones from the pixels
            within this share of its radius; implies ``crlb``, a few more renders.

    Returns:
        The frame, one :class:`MarkerTruth` per placement (same order) and the
        negatives actually drawn.
    """
    rng = np.random.default_rng(rng)
    imaging = ImagingConditions(
        blur_sigma_px,
        motion_blur_px,
        motion_blur_angle_rad,
        illumination_strength,
        n_shadows,
        vignetting,
        gamma,
        noise_sigma_dn,
        shot_noise_gain_dn,
        peak_level,
        tuple(cast_shadows),
        jpeg_quality,
    )
    targets = [_target(p, reflectances or _random_paint(rng, contrast)) for p in markers]
    truths = [
        MarkerTruth.from_homography(t.homography, p.radius_px, p.kind, t.dull_margin)
        for t, p in zip(targets, markers, strict=True)
    ]
    negatives = random_negatives(
        shape,
        n_hard_negatives,
        rng,
        markers,
        radius_px=negative_radius_px,
        max_tilt_deg=negative_max_tilt_deg,
    )
    targets += [_target(p, _random_paint(rng, contrast), on_plate) for p, on_plate in negatives]
    image, bounds = _render(
        shape,
        targets,
        rng,
        background,
        background_level,
        imaging,
        supersampling,
        texture_scale,
        range(len(truths)) if crlb or bound_parts_within is not None else (),
        bound_parts_within,
    )
    if bounds:
        truths = [
            replace(t, crlb_mean_abs_error_px=bound, x_snr=snr, bound_parts=parts)
            for t, (bound, snr, parts) in zip(truths, bounds, strict=True)
        ]
    return RenderedScene(image, truths, [(p.kind, p.x, p.y) for p, _ in negatives], imaging)


#: Default range of the JPEG quality of :class:`SceneConfig`: what cameras write
#: (70 for bandwidth-limited links, 95 for archival).
JPEG_QUALITY_RANGE: tuple[int, int] = (70, 95)
#: Default range of a dull quadrant's brightness relative to the other bright one:
#: dirt, wear and sheen as the issue's field reports describe them.
DULL_FACTOR_RANGE: tuple[float, float] = (0.45, 0.8)
#: Default range of the light a cast shadow takes away: direct sunlight blocked,
#: skylight still there.
SHADOW_DARKENING_RANGE: tuple[float, float] = (0.4, 0.65)


@dataclass(frozen=True)
class SceneConfig:
    """Random scene to render with :func:`render_scene`; validated on construction.

    Ranges are (min, max) and drawn uniformly, per marker or per frame (the
    radius log-uniformly: each octave of size alike, as ranges vary). The
    defaults render the frames this package rendered before its field
    conditions existed; :func:`render_scene` draws the field conditions (contrast,
    peak level, shot noise, JPEG, dull quadrants, cast shadows) from a child
    generator, so a seed still gives the same frame while they are off.

    Attributes:
        width: Frame width, px.
        height: Frame height, px.
        n_markers: Number of markers; all must fit without overlap.
        radius_px: Marker radius range before tilt, px.
        blur_sigma_px: Gaussian PSF sigma range (per frame), px.
        motion_blur_px: Linear motion blur length range (per frame), px.
        noise_sigma_dn: Read-noise sigma range (per frame), DN.
        max_tilt_deg: Largest marker tilt, degrees (<= 80).
        marker_kinds: Marker kinds to draw from (:data:`MARKER_KINDS`).
        background: ``"texture"`` or ``"flat"``.
        n_hard_negatives: Hard negatives to scatter (fewer if they do not fit).
        illumination_strength: 0 = uniform light, 1 = strong gradients/bumps (a gain
            of 0.5 to 1), up to :data:`MAX_ILLUMINATION_STRENGTH`.
        n_shadows: Number of soft shadow polygons.
        gamma: Display gamma range (per frame).
        supersampling: S, samples per pixel along each axis.
        inverted_fraction: Probability that a marker's polarity is swapped.
        vignetting: Fraction of light lost in the frame corners.
        shot_noise_gain_dn: Shot-noise variance per DN of signal (per frame),
            DN; default: a 20000-electron full well.
        contrast: Bright - dark paint reflectance range (per marker and
            negative); None: the paint ranges (0.6-0.9).
        peak_level: Output level of white as a fraction of 255 (per frame).
        texture_scale: Magnification range of the ground photographs, frame px
            per texture px (per layer).
        jpeg_probability: Share of frames written as JPEG.
        jpeg_quality: JPEG quality range (per frame).
        dull_probability: Probability that a marker has one dull bright quadrant.
        dull_factor: That quadrant's brightness relative to the other (per marker).
        shadow_probability: Probability that a hard cast shadow's edge crosses
            a marker (within :data:`CAST_SHADOW_MAX_OFFSET` foreshortened radii
            of its centre).
        shadow_darkening: Light the cast shadow takes away (per marker).
    """

    width: int = 1280
    height: int = 960
    n_markers: int = 12
    radius_px: tuple[float, float] = (6.0, 40.0)
    blur_sigma_px: tuple[float, float] = (0.5, 1.4)
    motion_blur_px: tuple[float, float] = (0.0, 0.0)
    noise_sigma_dn: tuple[float, float] = (0.0, 4.0)
    max_tilt_deg: float = 60.0
    marker_kinds: tuple[str, ...] = ("quarter_disks", "checker")
    background: str = "texture"
    n_hard_negatives: int = 20
    illumination_strength: float = 0.5
    n_shadows: int = 2
    gamma: tuple[float, float] = (0.8, 1.25)
    supersampling: int = 16
    inverted_fraction: float = 0.5
    vignetting: float = 0.0
    shot_noise_gain_dn: tuple[float, float] = (
        DEFAULT_SHOT_NOISE_GAIN_DN,
        DEFAULT_SHOT_NOISE_GAIN_DN,
    )
    contrast: tuple[float, float] | None = None
    peak_level: tuple[float, float] = (1.0, 1.0)
    texture_scale: tuple[float, float] = TEXTURE_SCALE_RANGE
    jpeg_probability: float = 0.0
    jpeg_quality: tuple[int, int] = JPEG_QUALITY_RANGE
    dull_probability: float = 0.0
    dull_factor: tuple[float, float] = DULL_FACTOR_RANGE
    shadow_probability: float = 0.0
    shadow_darkening: tuple[float, float] = SHADOW_DARKENING_RANGE

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise ConfigError(f"frame size must be positive, got {self.width}x{self.height}")
        if self.n_markers < 0 or self.n_hard_negatives < 0 or self.n_shadows < 0:
            raise ConfigError("n_markers, n_hard_negatives and n_shadows must be >= 0")
        _check_range("radius_px", self.radius_px, 0.5)
        _check_range("blur_sigma_px", self.blur_sigma_px, 0.0)
        _check_range("motion_blur_px", self.motion_blur_px, 0.0)
        _check_range("noise_sigma_dn", self.noise_sigma_dn, 0.0)
        _check_range("gamma", self.gamma, 0.05)
        _check_range("shot_noise_gain_dn", self.shot_noise_gain_dn, 0.0)
        if self.contrast is not None:
            _check_range("contrast", self.contrast, 0.0, MAX_CONTRAST)
        _check_range("peak_level", self.peak_level, 0.01, 1.0)
        _check_range("texture_scale", self.texture_scale, 0.01)
        _check_range("jpeg_quality", self.jpeg_quality, 1, 100)
        _check_range("dull_factor", self.dull_factor, 0.01, 1.0)
        _check_range("shadow_darkening", self.shadow_darkening, 0.01, 0.99)
        if not 0.0 <= self.max_tilt_deg <= MAX_TILT_DEG:
            raise ConfigError(
                f"max_tilt_deg must be in [0, {MAX_TILT_DEG}], got {self.max_tilt_deg!r}"
            )
        unknown = set(self.marker_kinds) - set(MARKER_KINDS)
        if not self.marker_kinds or unknown:
            raise ConfigError(
                f"marker_kinds must be a non-empty subset of {MARKER_KINDS}, "
                f"got {self.marker_kinds!r}"
            )
        if self.background not in BACKGROUNDS:
            raise ConfigError(f"background must be one of {BACKGROUNDS}, got {self.background!r}")
        if self.supersampling < 1:
            raise ConfigError(f"supersampling must be >= 1, got {self.supersampling!r}")
        for name in (
            "inverted_fraction",
            "jpeg_probability",
            "dull_probability",
            "shadow_probability",
        ):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(f"{name} must be in [0, 1], got {getattr(self, name)!r}")
        # Validates the remaining scalar ranges with the same rules as the renderer.
        ImagingConditions(
            illumination_strength=self.illumination_strength, vignetting=self.vignetting
        )


@dataclass(frozen=True)
class _ShadowDraft:
    """A cast shadow drawn for a marker before the marker has a position."""

    normal_rad: float
    offset_px: float
    darkening: float
    reach_px: float

    def at(self, x: float, y: float) -> CastShadow:
        return CastShadow(x, y, self.normal_rad, self.offset_px, self.darkening, self.reach_px)


def _field_conditions(
    draft: MarkerPlacement, config: SceneConfig, rng: np.random.Generator
) -> tuple[MarkerPlacement, _ShadowDraft | None]:
    """A draft with its dull quadrant (if drawn), and its cast shadow (if drawn)."""
    if rng.random() < config.dull_probability:
        draft = replace(
            draft,
            dull_factor=float(rng.uniform(*config.dull_factor)),
            dull_quadrant=int(rng.integers(2)),
        )
    if not rng.random() < config.shadow_probability:
        return draft, None
    foreshortened = MarkerTruth.from_homography(
        marker_homography(draft), draft.radius_px, draft.kind
    ).foreshortened_radius_px
    offset = rng.uniform(-CAST_SHADOW_MAX_OFFSET, CAST_SHADOW_MAX_OFFSET) * foreshortened
    return draft, _ShadowDraft(
        float(rng.uniform(0.0, 2.0 * math.pi)),
        float(offset),
        float(rng.uniform(*config.shadow_darkening)),
        CAST_SHADOW_REACH * _bounding_radius(draft),
    )


def _place_markers(
    config: SceneConfig, rng: np.random.Generator, conditions_rng: np.random.Generator
) -> tuple[list[MarkerPlacement], list[CastShadow]]:
    """Random non-overlapping marker placements (largest first, which packs best).

    A marker with a cast shadow keeps the other markers out of the shadow's reach.
    """
    shape = (config.height, config.width)
    drafts = [
        _field_conditions(
            _random_placement(
                rng,
                config.marker_kinds,
                config.radius_px,
                config.max_tilt_deg,
                config.inverted_fraction,
            ),
            config,
            conditions_rng,
        )
        for _ in range(config.n_markers)
    ]
    drafts.sort(key=lambda d: _bounding_radius(d[0]), reverse=True)
    occupied: np.ndarray = np.empty((0, 3))
    placed: list[MarkerPlacement] = []
    shadows: list[CastShadow] = []
    for draft, shadow in drafts:
        radius = max(_bounding_radius(draft), shadow.reach_px if shadow else 0.0)
        spot = _find_spot(radius, shape, occupied, rng)
        if spot is None:
            raise ConfigError(
                f"could not place marker {len(placed) + 1} of {config.n_markers} "
                f"(bounding radius {radius:.1f} px) in a {config.width}x{config.height} frame "
                f"after {PLACEMENT_TRIES} tries without overlap; use fewer markers "
                f"(n_markers={config.n_markers}) or smaller radius_px={config.radius_px}"
            )
        placed.append(replace(draft, x=spot[0], y=spot[1]))
        if shadow is not None:
            shadows.append(shadow.at(*spot))
        occupied = np.vstack([occupied, (spot[0], spot[1], radius)])
    return placed, shadows


def render_scene(
    config: SceneConfig,
    seed: int | np.random.Generator,
    *,
    crlb: bool = False,
    bound_parts_within: float | None = None,
    ground: np.ndarray | None = None,
) -> RenderedScene:
    """Render a random frame of markers and hard negatives on cluttered ground.

    Args:
        config: What to render.
        seed: Seed or Generator; the same seed gives the same frame.
        crlb: Compute each marker's Cramer-Rao bound (see :func:`render_markers`).
        bound_parts_within: Also its bounds with the other parameters unknown (see
            :func:`render_markers`).
        ground: (height, width) reflectances in [0, 1] to draw on instead of
            ``config.background`` (a photograph of real ground, say).

    Returns:
        The frame and its exact truth.

    Raises:
        ConfigError: (a ValueError) if the markers do not all fit in the frame.
    """
    rng = np.random.default_rng(seed)
    # A child stream (spawning leaves rng's own stream untouched) for the field conditions.
    conditions = rng.spawn(1)[0]
    placements, shadows = _place_markers(config, rng, conditions)
    jpeg = (
        int(conditions.integers(config.jpeg_quality[0], config.jpeg_quality[1] + 1))
        if conditions.random() < config.jpeg_probability
        else None
    )
    return render_markers(
        (config.height, config.width),
        placements,
        rng,
        background=config.background if ground is None else ground,
        contrast=config.contrast,
        blur_sigma_px=float(rng.uniform(*config.blur_sigma_px)),
        motion_blur_px=float(rng.uniform(*config.motion_blur_px)),
        motion_blur_angle_rad=float(rng.uniform(0.0, math.pi)),
        illumination_strength=config.illumination_strength,
        n_shadows=config.n_shadows,
        cast_shadows=shadows,
        vignetting=config.vignetting,
        gamma=float(rng.uniform(*config.gamma)),
        peak_level=float(conditions.uniform(*config.peak_level)),
        noise_sigma_dn=float(rng.uniform(*config.noise_sigma_dn)),
        shot_noise_gain_dn=float(conditions.uniform(*config.shot_noise_gain_dn)),
        jpeg_quality=jpeg,
        n_hard_negatives=config.n_hard_negatives,
        negative_radius_px=config.radius_px,
        negative_max_tilt_deg=config.max_tilt_deg,
        texture_scale=config.texture_scale,
        supersampling=config.supersampling,
        crlb=crlb,
        bound_parts_within=bound_parts_within,
    )


def render_checkerboard(
    shape: tuple[int, int] = (960, 1280),
    inner_corners: tuple[int, int] = (10, 10),
    square_px: float = 40.0,
    *,
    centre: tuple[float, float] | None = None,
    rotation_rad: float = 0.0,
    tilt_deg: float = 0.0,
    tilt_axis_rad: float = 0.0,
    homography: np.ndarray | None = None,
    background: str | np.ndarray = "texture",
    reflectances: tuple[float, float] = (0.08, 0.85),
    blur_sigma_px: float = 0.8,
    noise_sigma_dn: float = 2.0,
    gamma: float = 1.0,
    seed: int | np.random.Generator | None = 0,
    supersampling: int = 16,
) -> RenderedScene:
    """Render a chessboard under perspective; its inner corners are the truth.

    Args:
        shape: (height, width) of the frame, px.
        inner_corners: (columns, rows) of inner corners (4 squares meeting).
        square_px: Side of a square before tilt, px.
        centre: Image position of the board centre, px; default: frame centre.
        rotation_rad: In-plane rotation of the board, radians.
        tilt_deg: Out-of-plane tilt, degrees.
        tilt_axis_rad: Tilt axis direction in the board plane, radians.
        homography: (3, 3) board plane -> image, the plane in units of one
            square with the origin at the board centre; overrides the pose
            arguments above.
        background: ``"texture"``, ``"flat"`` or a reflectance array.
        reflectances: (dark, bright) paint of the board.
        blur_sigma_px: Gaussian PSF sigma, px.
        noise_sigma_dn: Gaussian read-noise sigma, DN.
        gamma: Display gamma.
        seed: Seed or Generator.
        supersampling: S, samples per pixel along each axis.

    Returns:
        The frame; ``markers`` holds one truth per inner corner, row by row
        (v outer, u inner, as OpenCV orders chessboard corners), each with the
        homography translated so that its plane origin is that corner.

    Raises:
        ConfigError: If the board (with its white border) leaves the frame.
    """
    rng = np.random.default_rng(seed)
    if homography is None:
        x, y = centre if centre is not None else ((shape[1] - 1) / 2, (shape[0] - 1) / 2)
        homography = marker_homography(
            MarkerPlacement(x, y, square_px, rotation_rad, tilt_deg, tilt_axis_rad, "checker")
        )
    board = PlanarTarget(
        _normalised(homography), checkerboard_pattern(inner_corners), *reflectances
    )
    outline = project(board.homography, _plate_corners(board))
    if outline.min() < -0.5 or np.any(outline.max(axis=0) > (shape[1] - 0.5, shape[0] - 0.5)):
        raise ConfigError(
            f"a board of {inner_corners} inner corners with {square_px} px "
            f"squares does not fit in a {shape[1]}x{shape[0]} frame"
        )
    n_u, n_v = inner_corners
    truths = []
    for m in range(n_v):
        for k in range(n_u):
            to_corner = np.array(
                [[1.0, 0.0, k - (n_u - 1) / 2], [0.0, 1.0, m - (n_v - 1) / 2], [0.0, 0.0, 1.0]]
            )
            truths.append(
                MarkerTruth.from_homography(
                    board.homography @ to_corner, square_px, "checkerboard_corner"
                )
            )
    imaging = ImagingConditions(
        blur_sigma_px=blur_sigma_px, gamma=gamma, noise_sigma_dn=noise_sigma_dn
    )
    image = render_targets(
        shape, [board], rng, background=background, imaging=imaging, supersampling=supersampling
    )
    return RenderedScene(image, truths, [], imaging)
