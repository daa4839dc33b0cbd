"""Section 3.2 of the paper, geometric checks: centre symmetry and double-line intersection.

A diagonal marker keeps two invariants under blur, perspective and uneven light:
(1) centre symmetry: on any circle around the centre the grey levels repeat
after 180 degrees, with two dark and two bright sectors; (2) double line: two
straight edges cross at the centre. :func:`centre_symmetry_check` tests (1) on
concentric rings and, because the edges of an X are straight lines through the
centre, also requires the sector boundaries to keep their angles from ring to
ring (which rejects bars, blobs and plus signs that pass a single ring).
:func:`double_line_check` tests (2) with OpenCV's LSD.

What the constants here rest on, measured: docs/accuracy-journal.md, "What the geometric
checks' constants rest on".
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple, cast

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy import special

from marker_localizer.core import template
from marker_localizer.core.image import clipped
from marker_localizer.core.sampling import Normaliser, bilinear, in_blocks, nan_median
from marker_localizer.core.screening import Candidates, level_scale, parabolic_offset

N_ANGLES = 36  # the paper's 10-degree sampling of the annulus
#: Smallest LSD window side, px: smaller windows are enlarged so that the edges of a
#: 3-5 px marker make segments LSD accepts.
_LSD_MIN_WINDOW_PX = 24
#: LSD window half-width in marker radii: the X and a margin for its blurred edges,
#: but not the plate's outline, whose segments would only add crossings to test.
LSD_WINDOW_RADII = 1.25
#: Smallest half-width of an LSD window, px, before the enlargement to
#: :data:`_LSD_MIN_WINDOW_PX`: at :data:`LSD_WINDOW_RADII` alone a 3 px X's window
#: would be 9 x 9 pixels, its blurred edges cut a pixel beyond its extent; this widens
#: the windows of X's under 4.8 px.
_LSD_MIN_HALF_WINDOW_PX = 6.0
#: Smallest angle between the double-line check's two lines: a right-angled X seen 80
#: degrees off its normal still shows about 20 degrees (2 atan(cos 80 degrees)); the
#: crossing of lines nearer parallel moves far with a small error in either's direction.
LINE_MIN_ANGLE_RAD = float(np.deg2rad(20.0))
_HALF_TURN = N_ANGLES // 2
#: A centrally symmetric X's opposite sector boundaries lie half a turn apart within
#: this, radians (three of the annulus' 10-degree samples): a tilt keeps them opposite,
#: but a ring centred off the X sees them turned from it.
_OPPOSITE_TOLERANCE_RAD = np.deg2rad(30.0)
#: Paper's annular check: a derivative extremum is an edge from this fraction of the
#: ring's strongest: under the edges of a dulled bright sector, over most of ground
#: texture's wiggles.
EDGE_FRACTION = 0.3
#: Largest departure of an edge pair from 180 degrees: a candidate 1 px off the centre
#: moves the crossings of a 6 px ring by ~10 degrees each.
MAX_PHASE_ERROR_RAD = np.deg2rad(25.0)
#: Smallest angle between an X's two lines (a marker tilted 60 degrees keeps ~53).
MIN_LINE_ANGLE_RAD = np.deg2rad(25.0)
#: Most significant edges on a good ring: an X's four and a shadow edge's two crossings.
MAX_RING_EDGES = 6
#: Largest move of a candidate to where the lines found on its rings cross, px: contour
#: corners sit up to ~2 px from the X centre.
RECENTRE_MAX_PX = 3.0
#: ... and the largest departure from 180 degrees when the crossings are paired only to
#: find where the lines cross (a line 1.5 px off the centre of a 3 px ring: 60 degrees).
RECENTRE_PHASE_ERROR_RAD = np.deg2rad(60.0)
#: Largest change of a line's angle between the rings of one run of the paper's
#: annular check by edge phase (:func:`edge_phase_check`): over the spread of a
#: marker's own rings.
MAX_LINE_DRIFT_RAD = np.deg2rad(8.0)
#: The same for the default path's ring check (:func:`centre_symmetry_check`), whose
#: line directions come from the rings' symmetric profiles, not their edge phases.
MAX_RING_LINE_DRIFT_RAD = np.deg2rad(15.0)
#: A run of good rings starts on one of this many innermost rings.
MAX_FIRST_RING = 2
#: Widest blur (Gaussian sigma, px) that may dim the innermost rings of an X's run
#: (:func:`blurred_contrast_share`): optics of up to 1.5 px (the package's renderer and
#: the independent one), with a 4 px motion blur's 1.2 px along it, 1.9 px.
RING_BLUR_SIGMA_PX = 2.0
#: Rings of a run see at least this fraction of the candidate's best ring contrast,
#: under what a marker's rings keep, blur and tilt included. A ring under it lies on
#: the marker's outline or past it (:func:`_past_a_dim_ring`).
RING_CONTRAST_FRACTION = 0.5
#: The prescreen's 180-degree self-correlation threshold: lenient, the candidate may
#: sit a fraction of its scale off the centre.
PRESCREEN_SYMMETRY = 0.5
#: Prescreen ring radii in units of the candidate's scale, the likeliest ring first. The
#: outermost stays at 0.6: a level answers to markers whose major radius matches its
#: scale, and a 60-degree tilt halves the minor one, so a wider ring runs past a
#: tilted X onto its plate.
PRESCREEN_RINGS = (0.5, 0.35, 0.6)
#: Smallest prescreen ring radius, px. A nearest-pixel ring of 1.4 px (0.35 of the
#: first level's 4 px scale) visits only the eight neighbours; around a candidate up to
#: half a pixel off the centre (the level's parabolic peak) that misplaces each sector
#: boundary by ~20 degrees and fails the four-sector test on sharp, aliased chessboard
#: corners. Rings this small are sensitive to the exact radius, so the floor sits
#: inside the span that keeps the real boards' corners, not at its edge.
PRESCREEN_MIN_RING_PX = 1.8
#: ... but never beyond this fraction of the smallest expected radius: in frames of
#: tiny markers the 1.4 px ring lies well inside the smallest one, and a larger ring
#: there lets texture saddles through.
PRESCREEN_MIN_RING_FRACTION = 0.5
#: Prescreen rings (of three) that must show the X: all of them. Each marker has a
#: candidate close enough to its centre at some level for all three to pass, while
#: texture saddles rarely keep the X over a factor of two in radius.
PRESCREEN_GOOD_RINGS = 3
#: Ratio of consecutive rings of the annular scan (:func:`ring_radii`): an X's extent,
#: its last ring that shows the X, reads up to this factor short of its shortest reach.
RING_STEP = float(np.sqrt(2.0))
#: The annular scan's first ring (:func:`ring_radii`): this share of the smallest
#: radius, so each radius range reads its own rungs ...
FIRST_RING_RADIUS_SHARE = 0.5
#: ... and this far from the centre at least, px: a sample on a sector's bisector lies
#: 0.71 of its ring's radius from either line, and on a nearer ring within a blur
#: width (about 1 px) of both, where little of the X's modulation is left.
FIRST_RING_MIN_PX = 1.5
#: Rings that say where an X's lines cross (:func:`line_crossing_centres`): those a
#: run of good rings may start on and the next (:data:`MAX_FIRST_RING`, plus one), so
#: among those the check reads for every point first, whose samples they take.
LINE_CROSSING_RINGS = MAX_FIRST_RING + 1
#: Slack of the extent test, px: the ring ladder's radii are products of floats, and a
#: ring exactly at the required extent passes.
_EXTENT_SLACK_PX = 1e-9
#: The adaptive template's NCC and its grey levels are read within this fraction of the
#: X's extent from the centre: inside the four sectors, clear of the plate's outline.
TEMPLATE_RADIUS_FRACTION = 0.6
#: ... over a disk of at least this radius, px: a smaller one holds too few samples of
#: each sector for the NCC to tell an X.
TEMPLATE_MIN_RADIUS_PX = 2.5
#: The LSD pair's line directions replace the rings' where both agree this closely:
#: LSD's are the more precise where right, and the rings' stand where LSD is wrong.
LINE_ANGLE_AGREEMENT_RAD = np.deg2rad(5.0)
#: Sector levels sampled closer than this to the centre are mixed by the blur, px.
MODULATION_MIN_OFFSET_PX = 2.5
#: ... and from this distance on they are clear of it for any expected blur, px.
MODULATION_FREE_OFFSET_PX = 3.0
#: Ground texture makes saddles that pass the geometric checks up to this extent, px.
#: Below it the modulation gate applies, a detection needs the score floor of its
#: extent from :data:`TEXTURE_SCORE_FLOORS` and, where it is also no larger than the
#: smallest expected marker, ``min_score_small`` (:func:`minimum_score`).
TEXTURE_EXTENT_PX = 9.0
#: (extent below, px; lowest score): each band's floor lies over what ground
#: texture's saddles of those extents score, and under most markers of them.
TEXTURE_SCORE_FLOORS = ((6.0, 0.92), (TEXTURE_EXTENT_PX, 0.88))
#: Smallest extent, px, at which rings read with their bright sectors equalised
#: (:func:`equalise_bright_sectors`) count as an X: equalised, texture saddles pass
#: out to the ring ladder's 6 px rung, and a dull marker's rings reach the next rungs
#: (7.07 px at 5-30 px, 8.49 at 6-40 px).
EQUALISED_MIN_EXTENT_PX = 7.0
#: ... and a rung under it, the smallest where a candidate read again from the light
#: slope's centre counts, if the marker's model vouches for it too (a dull quadrant
#: leaves a marker of 5-8 px equalised rings to 3.5-7 px even at its true centre;
#: :func:`second_reading.read_dull`): the ladder's 5 px rung at 5-30 px, 6 px at 6-40 px.
DULL_MIN_EXTENT_PX = 5.0
#: Detections whose X extends no further than the smallest expected radius (times this,
#: for the ring ladder's rounding), or than :data:`SMALL_EXTENT_MAX_RADIUS_PX` where that
#: is smaller, are small markers.
SMALL_EXTENT_FACTOR = 1.05
#: px: ground texture makes saddles of this extent and less that score up to
#: ``min_score_small``, rarely larger ones. The rule follows the ground here, not the
#: radius range: were it to follow a larger ``marker_radius_min_px``, a tighter,
#: correct range would demand more of the same marker.
SMALL_EXTENT_MAX_RADIUS_PX = 4.0
# Indices of each angle's neighbours and opposite on the ring: a gather along the
# last axis costs a fraction of np.roll's slicing and concatenation, which the small
# per-call arrays of a few candidates make the cost.
_PREVIOUS = np.roll(np.arange(N_ANGLES), 1)
_NEXT = np.roll(np.arange(N_ANGLES), -1)
_OPPOSITE = np.roll(np.arange(N_ANGLES), -_HALF_TURN)
#: Row m: each sample's index counted from the half turn before sample m, as 8-bit
#: integers (:func:`equalise_bright_sectors`: a row per ring, looked up rather than a
#: 64-bit modulo of every sample).
_TURNED_FROM = (
    (np.arange(N_ANGLES)[None, :] - np.arange(N_ANGLES)[:, None] + _HALF_TURN) % N_ANGLES
).astype(np.int8)
#: The annular check's angular Gaussian (binomial, sigma 1 sample) and, convolved with
#: the central difference [1, 0, -1] / 2, its derivative filter.
_SMOOTHING_KERNEL = np.array([1.0, 4.0, 6.0, 4.0, 1.0]) / 16.0
_DERIVATIVE_KERNEL = np.convolve(_SMOOTHING_KERNEL, [0.5, 0.0, -0.5])[::-1]


def annular_profiles(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    radii_px: NDArray[np.float64],
    normalise: Normaliser | None = None,
) -> NDArray[np.float64]:
    """Grey levels on rings around each point, every 10 degrees.

    Args:
        image: (H, W) image (any numeric dtype).
        xy: (N, 2) ring centres.
        radii_px: (J,) ring radii.
        normalise: applied to each point's samples (e.g. the dynamic gamma).

    Returns:
        (N, J, 36) samples; angle k is 10 k degrees from +x towards +y. NaN where
        the ring leaves the image.
    """
    theta = np.deg2rad(np.arange(N_ANGLES) * 360.0 / N_ANGLES)
    x = xy[:, 0, None, None] + radii_px[None, :, None] * np.cos(theta)
    y = xy[:, 1, None, None] + radii_px[None, :, None] * np.sin(theta)
    values, valid = bilinear(image, x, y)
    if normalise is not None:
        values = normalise(values, xy)
    values[~valid] = np.nan
    return values


def annular_profiles_at(
    image: NDArray[Any], xy: NDArray[np.float64], radius_px: NDArray[np.float64]
) -> NDArray[np.float64]:
    """(N, 36) grey levels on one ring per point, each of its own radius (N,); NaN outside."""
    theta = np.deg2rad(np.arange(N_ANGLES) * 360.0 / N_ANGLES)
    x = xy[:, 0, None] + radius_px[:, None] * np.cos(theta)
    y = xy[:, 1, None] + radius_px[:, None] * np.sin(theta)
    values, valid = bilinear(image, x, y)
    return np.where(valid, values, np.nan)


def ring_symmetry(profiles: NDArray[np.float64]) -> NDArray[np.float64]:
    """(...,) 180-degree self-correlation of [1, 2, 1]-smoothed ring profiles (-1 outside)."""
    return _smoothed_contrast_symmetry(profiles)[2]


def _circular_smooth(profile: NDArray[np.float64]) -> NDArray[np.float64]:
    """Smooth along the angle axis with a [1, 2, 1] / 4 kernel (the paper's DoG pre-filter)."""
    # 0.25 ((2 profile + previous) + next), summed in that order in one array (C-ordered,
    # its raveling a view): along the raveled rings, two additions of one long run each
    # (slices of a ring's 36 samples cost a loop a ring); then each ring's ends, whose
    # neighbours there were the next ring's and the last one's, summed again with their own.
    smooth = np.multiply(2.0, profile, order="C")
    flat, samples = smooth.reshape(-1), profile.reshape(-1)
    flat[1:] += samples[:-1]
    flat[:-1] += samples[1:]
    first = 2.0 * profile[..., 0]
    first += profile[..., -1]
    first += profile[..., 1]
    last = 2.0 * profile[..., -1]
    last += profile[..., -2]
    last += profile[..., 0]
    smooth[..., 0] = first
    smooth[..., -1] = last
    smooth *= 0.25
    return smooth


class RingAnalysis(NamedTuple):
    """Per-ring measurements of :func:`analyse_rings`, each (N, J).

    Attributes:
        contrast: bright minus dark level on the ring, in image units.
        symmetry: correlation of the ring profile with itself turned by 180 degrees.
        four_sectors: True where the ring has exactly two dark and two bright
            sectors, each boundary 180 +- 30 degrees from its opposite twin.
        line_angles: (N, J, 2) directions in [0, pi) of the two lines through the
            centre, from the sector boundaries.
    """

    contrast: NDArray[np.float64]
    symmetry: NDArray[np.float64]
    four_sectors: NDArray[np.bool_]
    line_angles: NDArray[np.float64]

    def good(
        self, min_contrast: float | NDArray[np.float64], min_symmetry: float
    ) -> NDArray[np.bool_]:
        """(N, J) True for the rings that show an X: four sectors, contrast, symmetry."""
        return _shows_x(self.four_sectors, self.contrast, self.symmetry, min_contrast, min_symmetry)


def _shows_x(
    four_sectors: NDArray[np.bool_],
    contrast: NDArray[np.float64],
    symmetry: NDArray[np.float64],
    min_contrast: float | NDArray[np.float64],
    min_symmetry: float,
) -> NDArray[np.bool_]:
    """:meth:`RingAnalysis.good` from the rings' four-sector test, contrast and symmetry."""
    return four_sectors & (contrast >= min_contrast) & (symmetry >= min_symmetry)


def _smoothed_contrast_symmetry(
    profiles: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The [1, 2, 1]-smoothed profiles, their contrast, 180-degree self-correlation, mid level.

    The mid level is halfway between the smoothed profile's extremes.
    """
    f, contrast, level, missing = _smoothed_extremes(profiles)
    return f, contrast, _self_correlation(f, missing), level


def _smoothed_extremes(
    profiles: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """The [1, 2, 1]-smoothed profiles (NaN as 0), contrast, mid level, and the rings with NaN.

    The contrast is 0 on a ring with NaN samples.
    """
    f, high, low, missing = _smoothed_range(profiles)
    return f, np.where(missing, 0.0, high - low), 0.5 * (high + low), missing


def _smoothed_range(
    profiles: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """The [1, 2, 1]-smoothed profiles (NaN as 0), their maxima and minima, the rings with NaN."""
    f = _circular_smooth(profiles)
    high, low = f.max(axis=-1), f.min(axis=-1)
    # The maximum propagates NaN: it finds the few rings with NaN samples without a
    # look at every sample, and only they are smoothed again with those samples as 0.
    missing = np.isnan(high)
    if missing.any():
        partial = profiles[missing]
        f[missing] = _circular_smooth(np.where(np.isnan(partial), 0.0, partial))
        high[missing], low[missing] = f[missing].max(axis=-1), f[missing].min(axis=-1)
    return f, high, low, missing


def _self_correlation(f: NDArray[np.float64], missing: NDArray[np.bool_]) -> NDArray[np.float64]:
    """180-degree self-correlation of smoothed profiles; -1 on the rings ``missing`` samples."""
    centred = f - f.mean(axis=-1, keepdims=True)
    # The profile turned by 180 degrees holds the same samples: the same norm, and each
    # product of opposite samples twice.
    products = 2.0 * (centred[..., :_HALF_TURN] * centred[..., _HALF_TURN:]).sum(-1)
    energy = np.square(centred, out=centred).sum(-1)
    return cast("NDArray[np.float64]", np.where(missing, -1.0, products / (energy + 1e-12)))


def analyse_rings(profiles: NDArray[np.float64]) -> RingAnalysis:
    """Measure the centre-symmetry invariants of annular profiles (section 3.2, check 1).

    Args:
        profiles: (N, J, 36) from :func:`annular_profiles`.

    Returns:
        :class:`RingAnalysis`; rings with NaN samples get symmetry -1 and contrast 0;
        line angles are those of rings with four sector boundaries (0 elsewhere).
    """
    return _sector_analysis(*_smoothed_contrast_symmetry(profiles))


def _sector_analysis(
    f: NDArray[np.float64],
    contrast: NDArray[np.float64],
    symmetry: NDArray[np.float64],
    level: NDArray[np.float64],
) -> RingAnalysis:
    """:func:`analyse_rings` from the smoothed profiles, their contrast, symmetry and mid level."""
    four, boundaries = _four_crossings(f, contrast, level)
    # Each line's direction: circular mean of a boundary and its opposite twin (mod pi),
    # the doubled angles' unit vectors summed.
    cos2, sin2 = np.cos(2.0 * boundaries), np.sin(2.0 * boundaries)
    line_angles = np.zeros((*four.shape, 2))
    line_angles[four] = (
        np.arctan2(sin2[:, :2] + sin2[:, 2:], cos2[:, :2] + cos2[:, 2:]) / 2.0
    ) % np.pi
    four[four] = _opposite_pairs(boundaries)
    return RingAnalysis(contrast, symmetry, four, line_angles)


def _four_sectors(
    f: NDArray[np.float64], contrast: NDArray[np.float64], level: NDArray[np.float64]
) -> NDArray[np.bool_]:
    """:attr:`RingAnalysis.four_sectors` alone, without the line angles."""
    four, boundaries = _four_crossings(f, contrast, level)
    four[four] = _opposite_pairs(boundaries)
    return four


def _four_crossings(
    f: NDArray[np.float64], contrast: NDArray[np.float64], level: NDArray[np.float64]
) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """The rings whose smoothed profile crosses its mid level four times, and where.

    Returns:
        (N, J) True for those rings, and (M, 4) the sub-sample angles of their
        crossings (sector boundaries), radians, the M rings in order.
    """
    above = f > level[..., None]
    # Each sample against the next along the raveled rings, then each ring's last
    # against its first: a compare of one long run in place of np.roll's copies.
    crossing = np.empty(above.shape, dtype=bool)
    flat = above.reshape(-1)
    np.not_equal(flat[:-1], flat[1:], out=crossing.reshape(-1)[:-1])
    np.not_equal(above[..., -1], above[..., 0], out=crossing[..., -1])
    four = (crossing.sum(axis=-1) == 4) & (contrast > 0)
    # The crossings lie between samples k and k+1 (linear interpolation).
    crossed = np.flatnonzero(crossing & four[..., None])
    ring, k = np.divmod(crossed, N_ANGLES)
    samples = f.reshape(-1)
    start, end = samples[crossed], samples[crossed - k + (k + 1) % N_ANGLES]
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.clip((level.reshape(-1)[ring] - start) / (end - start), 0.0, 1.0)
    boundaries = (k + np.where(np.isnan(frac), 0.0, frac)).reshape(-1, 4) * (2 * np.pi / N_ANGLES)
    return four, boundaries


def _opposite_pairs(boundaries: NDArray[np.float64]) -> NDArray[np.bool_]:
    """(M,) True where boundaries i and i+2 of (M, 4) are half a turn apart.

    Within :data:`_OPPOSITE_TOLERANCE_RAD`: they are on a centrally symmetric X.
    """
    gap = np.abs(_wrapped(boundaries[:, 2:] - boundaries[:, :2] - np.pi))
    return cast("NDArray[np.bool_]", (gap < _OPPOSITE_TOLERANCE_RAD).all(axis=-1))


def _wrapped(angle: NDArray[np.float64]) -> NDArray[np.float64]:
    """Angles, radians, wrapped to [-pi, pi].

    The argument of exp(i angle), with real functions: a complex exponential of
    the same samples costs half as much again.
    """
    return cast("NDArray[np.float64]", np.arctan2(np.sin(angle), np.cos(angle)))


def _nearest_ring(
    image: NDArray[Any], xy: NDArray[np.float64], radius_px: NDArray[np.float64]
) -> NDArray[np.float64]:
    """(N, 36) float32 nearest-pixel samples, each point's ring of its own radius (N,).

    Rows whose ring leaves the image are NaN.
    """
    theta = np.arange(N_ANGLES) * (2.0 * np.pi / N_ANGLES)
    height, width = image.shape
    reach = np.ceil(radius_px) + 1.0
    inside = (
        (xy[:, 0] >= reach)
        & (xy[:, 1] >= reach)
        & (xy[:, 0] < width - reach)
        & (xy[:, 1] < height - reach)
    )
    centre = xy + 0.5
    # Coordinates are positive on the image, so truncation after +0.5 rounds to the
    # nearest pixel there; rows off the image are set apart below.
    # The flat index is formed in place in float64 (exact below 2^53): one conversion
    # to integers instead of three integer passes.
    col = radius_px[:, None] * np.cos(theta)
    col += centre[:, 0, None]
    index = radius_px[:, None] * np.sin(theta)
    index += centre[:, 1, None]
    np.trunc(index, out=index)
    index *= width
    index += np.trunc(col, out=col)
    # A row off the image reads its first pixel (and is NaN after).
    index[~inside] = 0.0
    values = image.reshape(-1)[index.astype(np.intp)].astype(np.float32)
    values[~inside] = np.nan
    return cast("NDArray[np.float64]", values)


def equalise_bright_sectors(profiles: NDArray[np.float64]) -> NDArray[np.float64]:
    """Ring profiles with the brighter bright sector scaled down to the duller one's level.

    A marker whose bright quadrants differ (a dull one: wear, dirt, sheen) is
    point-symmetric in its geometry but not in its grey levels; scaled about the
    ring's dark level to match the duller sector, its ring reads as that of an X of
    one paint. The duller level is the highest that two opposite samples both
    reach; the brighter sector is the run of samples above halfway to it from the
    dark level that holds the ring's maximum (on the [1, 2, 1]-smoothed profile).
    A sector's shape is kept, only its contrast scaled: a texture saddle's bright
    stones differ in shape as well as level, and stay asymmetric. Rings whose
    maximum is not in such a run (no dark sample either side) are left as they are.

    Args:
        profiles: (..., 36) ring samples, NaN where the ring leaves the image.

    Returns:
        The equalised profiles, of the same shape and dtype.
    """
    shape = profiles.shape
    rings = profiles.reshape(-1, N_ANGLES).astype(np.float64)
    smooth, peak, dark, _ = _smoothed_range(rings)
    top = smooth.argmax(axis=1)
    duller = _duller_bright_level(smooth)
    # Each sample's angle from the ring's maximum, which sits at the half turn.
    turned = _TURNED_FROM[top]
    low = smooth <= (0.5 * (dark + duller))[:, None]
    start = np.where(low & (turned < _HALF_TURN), turned, np.int8(-1)).max(axis=1)
    stop = np.where(low & (turned > _HALF_TURN), turned, np.int8(N_ANGLES)).min(axis=1)
    scalable = (start >= 0) & (stop < N_ANGLES) & (duller > dark)
    sector = scalable[:, None] & (turned > start[:, None]) & (turned < stop[:, None])
    gain = (duller - dark) / np.maximum(peak - dark, 1e-12)
    scaled = rings - dark[:, None]
    scaled *= gain[:, None]
    scaled += dark[:, None]
    # The rings are a copy already: the sectors are scaled in place.
    np.copyto(rings, scaled, where=sector)
    return cast("NDArray[np.float64]", rings.reshape(shape).astype(profiles.dtype, copy=False))


def bright_sector_balance(profiles: NDArray[np.float64]) -> NDArray[np.float64]:
    """(...,) the duller bright sector's lead over a ring's dark level, over the brighter's.

    On the [1, 2, 1]-smoothed ring (..., 36): the duller bright sector's level as
    :func:`equalise_bright_sectors` reads it (the highest that two opposite samples
    both reach) above the ring's minimum, over the ring's maximum above it. An X of one
    paint reads about 1, one whose bright quadrant is dull about that quadrant's share
    of the other's lead. NaN on a flat ring and where the ring leaves the image.
    """
    rings = profiles.reshape(-1, N_ANGLES).astype(np.float64)
    smooth, peak, dark, missing = _smoothed_range(rings)
    span = peak - dark
    balance = (_duller_bright_level(smooth) - dark) / np.where(span > 0.0, span, np.nan)
    return cast(
        "NDArray[np.float64]",
        np.where(missing, np.nan, balance).reshape(profiles.shape[:-1]),
    )


def _duller_bright_level(smooth: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N,) the highest level two opposite samples of each smoothed ring (N, 36) both reach."""
    return cast(
        "NDArray[np.float64]",
        np.minimum(smooth[:, :_HALF_TURN], smooth[:, _HALF_TURN:]).max(axis=1),
    )


#: Candidates the prescreen's cascade takes at a time (:func:`~marker_localizer.core.
#: sampling.in_blocks`): its (candidates, 36) float32 rings are smaller than the
#: check's, and each block pays the cascade's calls.
_CASCADE_BLOCK = 4096


class RingCount(NamedTuple):
    """:func:`count_symmetric_rings`'s counts, with the first ring's samples as read.

    Attributes:
        good: (N,) int number of good rings (below ``min_good`` where the cascade
            dropped the point, not necessarily its exact count).
        first_ring: (N, 36) float32 nearest-pixel samples of each point's first
            ring (:func:`_nearest_ring`), before any equalising; NaN rows where the
            ring leaves the image.
    """

    good: NDArray[np.int64]
    first_ring: NDArray[np.float64]


def count_symmetric_rings(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    radii_px: NDArray[np.float64],
    *,
    min_contrast: float | NDArray[np.float64],
    min_symmetry: float,
    min_good: int,
    equalise: bool = False,
    first_ring: NDArray[np.float64] | None = None,
) -> RingCount:
    """Rings (of ``radii_px``, per point) with contrast, 180-degree symmetry and four sectors.

    A cascade for many candidates: nearest-pixel rings of the raw image are
    tested one radius at a time on the points that can still reach ``min_good``
    good rings, and the sector analysis of :func:`analyse_rings` runs only on
    those that do. Points that cannot reach ``min_good`` get a count below it
    (not necessarily their exact count).

    Every point's first ring is read (the cascade's first round), so a second
    cascade on some of the same points at the same radii (the equalised re-read of
    the prescreen's rejects) can take those samples, ``first_ring``, instead of
    gathering them again: nearest-pixel samples are the same bit for bit, and the
    gather is ~1 ms of the re-read's 8 on a 12 MP frame's ~3800 wide rejects.

    Args:
        image: (H, W) image, native dtype.
        xy: (N, 2) points.
        radii_px: (J,) ring radii, or (N, J): each point's own (one cascade for
            candidates of every scale).
        min_contrast: smallest bright-minus-dark level of a good ring, image units;
            or (N,) one per point.
        min_symmetry: smallest 180-degree self-correlation of a good ring.
        min_good: the count the caller will require.
        equalise: read each ring after :func:`equalise_bright_sectors`.
        first_ring: (N, 36) the points' first-ring samples at their first radius,
            as a previous call returned them; None reads them.

    Returns:
        :class:`RingCount`.
    """
    n_rings = np.shape(radii_px)[-1]
    radii = np.broadcast_to(np.asarray(radii_px, dtype=np.float64), (len(xy), n_rings))
    floor = np.broadcast_to(np.asarray(min_contrast, dtype=np.float64), (len(xy),))
    cascade = functools.partial(
        _count_symmetric_rings, image, limits=(min_symmetry, min_good), equalise=equalise
    )
    per_point = (xy, radii, floor) if first_ring is None else (xy, radii, floor, first_ring)
    return in_blocks(cascade, _CASCADE_BLOCK, *per_point)


def _count_symmetric_rings(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    radii: NDArray[np.float64],
    min_contrast: NDArray[np.float64],
    first_ring: NDArray[np.float64] | None = None,
    *,
    limits: tuple[float, int],
    equalise: bool,
) -> RingCount:
    """:func:`count_symmetric_rings` of the points ``xy`` with their (N, J) ring radii.

    ``min_contrast`` is (N,), one floor per point; ``first_ring`` the (N, 36) samples
    of the first ring or None; ``limits`` are ``min_symmetry`` and ``min_good``.
    """
    min_symmetry, min_good = limits
    n_rings = radii.shape[1]
    passed = np.zeros(len(xy), dtype=np.int64)
    alive = np.arange(len(xy))
    # The smoothing weighs four samples below 2^16 into a sum below 2^24: on 8- and
    # 16-bit images the float32 smoothed rings, their extremes and mid levels are those
    # of float64, and the sector analysis takes them rather than smoothing again.
    exact = np.issubdtype(image.dtype, np.integer) and image.dtype.itemsize <= 2 and not equalise
    sampled = []  # (points, their ring j's measures) per radius, for the survivors
    # The first round reads every point: its samples are returned for reuse.
    first = _nearest_ring(image, xy, radii[:, 0]) if first_ring is None else first_ring
    for j in range(n_rings):
        ring = first if j == 0 else _nearest_ring(image, xy[alive], radii[alive, j])
        if equalise:
            ring = equalise_bright_sectors(ring)
        f, contrast, level, missing = _smoothed_extremes(ring)
        symmetry = _self_correlation(f, missing)
        passed[alive] += (contrast >= min_contrast[alive]) & (symmetry >= min_symmetry)
        sampled.append((alive, (f, contrast, level, missing) if exact else (ring,)))
        failed = j + 1 - passed[alive]
        alive = alive[failed <= n_rings - min_good]
    # Points that dropped out have failed too many rings; their partial count says so.
    np.minimum(passed, min_good - 1, out=passed)
    if len(alive):
        # The survivors are a sorted subset of every earlier round's points.
        stacked = [
            np.stack(
                [measures[m][np.searchsorted(points, alive)] for points, measures in sampled],
                axis=1,
            )
            for m in range(len(sampled[0][1]))
        ]
        if exact:
            f, contrast, level = (a.astype(np.float64) for a in stacked[:3])
            missing = cast("NDArray[np.bool_]", stacked[3])
        else:
            f, contrast, level, missing = _smoothed_extremes(stacked[0].astype(np.float64))
        # Only how many rings show the X counts here: their line angles are not needed.
        good = _shows_x(
            _four_sectors(f, contrast, level),
            contrast,
            _self_correlation(f, missing),
            min_contrast[alive, None],
            min_symmetry,
        )
        passed[alive] = good.sum(axis=1)
    return RingCount(passed, first)


def _angle_difference(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Absolute difference of line directions modulo pi."""
    return np.abs(_wrapped(2.0 * (a - b))) / 2.0


def _pairing_differences(
    angles: NDArray[np.float64], reference: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Largest line-direction difference of two line pairs (..., 2), as given and swapped.

    Two measurements of an X may list its lines in either order.
    """
    same = np.maximum(
        _angle_difference(angles[..., 0], reference[..., 0]),
        _angle_difference(angles[..., 1], reference[..., 1]),
    )
    swap = np.maximum(
        _angle_difference(angles[..., 0], reference[..., 1]),
        _angle_difference(angles[..., 1], reference[..., 0]),
    )
    return same, swap


def line_pair_difference(
    angles: NDArray[np.float64], reference: NDArray[np.float64]
) -> NDArray[np.float64]:
    """(N,) largest angle between corresponding lines of two (N, 2) line pairs, radians.

    The lines are paired whichever way fits better.
    """
    return np.minimum(*_pairing_differences(angles, reference))


class SymmetryCheck(NamedTuple):
    """Result of :func:`centre_symmetry_check` for N candidates.

    Attributes:
        accepted: (N,) bool.
        score: (N,) mean symmetry over the three innermost accepted rings (0 where rejected).
        radius_px: (N,) largest ring radius that still shows the X: the marker's extent.
        line_angles: (N, 2) directions in [0, pi) of the marker's two lines.
        contrast: (N,) bright-minus-dark level on the innermost accepted ring.
    """

    accepted: NDArray[np.bool_]
    score: NDArray[np.float64]
    radius_px: NDArray[np.float64]
    line_angles: NDArray[np.float64]
    contrast: NDArray[np.float64]

    def with_rows(
        self,
        index: NDArray[np.integer[Any]],
        other: SymmetryCheck,
        rows: NDArray[np.integer[Any]] | NDArray[np.bool_] | slice = slice(None),
    ) -> SymmetryCheck:
        """A copy with the candidates ``index`` replaced by ``other``'s ``rows``."""
        return SymmetryCheck(
            *(_scatter(a, index, b[rows]) for a, b in zip(self, other, strict=True))
        )


def with_equalised(
    plain: SymmetryCheck,
    rows: NDArray[np.intp],
    equalised: SymmetryCheck,
    plain_floor: NDArray[np.float64],
) -> SymmetryCheck:
    """The plain ring check with the equalised reading of its ``rows`` where that is believed.

    Equalised rings (:func:`equalise_bright_sectors`) see through a dull bright
    quadrant, and texture through them at its own sizes, so their reading stands
    only where it shows the X out to :data:`EQUALISED_MIN_EXTENT_PX`, and where the
    plain rings rejected the X, scored it under its floor (``plain_floor``, (M,) for
    the rows), or scored lower. Where the plain rings accept the X above that floor,
    the equalised ones may raise its score, not its extent: beyond the plate,
    equalising lets the ground pass as the X. Under it (a dull quadrant cuts both),
    the equalised reading stands whole.

    Args:
        plain: (N,) the plain check.
        rows: (M,) the candidates read equalised too.
        equalised: (M,) their equalised check.
        plain_floor: (M,) the score floor of the plain extent of each.
    """
    accepted = plain.accepted[rows]
    weak = accepted & (plain.score[rows] < plain_floor)
    better = (
        equalised.accepted
        & (equalised.radius_px >= EQUALISED_MIN_EXTENT_PX)
        & (~accepted | weak | (equalised.score > plain.score[rows]))
    )
    reach = np.where(
        accepted & ~weak,
        np.minimum(equalised.radius_px, plain.radius_px[rows]),
        equalised.radius_px,
    )
    return plain.with_rows(rows[better], equalised._replace(radius_px=reach), better)


def ring_radii(radius_range_px: tuple[float, float]) -> NDArray[np.float64]:
    """Ring radii of the annular scan: a :data:`RING_STEP` progression across the expected radii.

    It starts at :data:`FIRST_RING_RADIUS_SHARE` of the smallest radius
    (:data:`FIRST_RING_MIN_PX` at least), so each range reads its own rungs. On one
    grid for every range, a tighter range would read a subset of a looser one's
    rungs; but the extent edges (:data:`TEXTURE_SCORE_FLOORS`,
    :data:`SMALL_EXTENT_FACTOR`, :data:`EQUALISED_MIN_EXTENT_PX`) lie between the
    rungs of the ranges they were set on, and on such a grid at or next to a rung,
    where each rung's side trades texture's false points against markers
    (docs/accuracy-journal.md, "Two more grids").
    """
    r_min, r_max = radius_range_px
    start = max(FIRST_RING_MIN_PX, FIRST_RING_RADIUS_SHARE * r_min)
    count = int(np.floor(np.log(max(r_max, start) / start) / np.log(RING_STEP))) + 1
    return cast("NDArray[np.float64]", start * RING_STEP ** np.arange(count))


#: Rings :func:`centre_symmetry_check` reads first beyond those a run may start at: the
#: runs of ground texture's saddles end within them, and only the runs still going on
#: their last are read further.
_RINGS_READ_BEYOND_START = 2
#: Candidates :func:`centre_symmetry_check` takes at a time (:func:`~marker_localizer.
#: core.sampling.in_blocks`): with 512, its (candidates, 4 rings, 36) temporaries stay
#: in a core's cache.
_CHECK_BLOCK = 512


def centre_symmetry_check(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    radii_px: NDArray[np.float64],
    *,
    min_contrast: float,
    min_symmetry: float,
    max_angle_drift_rad: float = MAX_RING_LINE_DRIFT_RAD,
    max_first_ring: int = MAX_FIRST_RING,
    normalise: Normaliser | None = None,
    equalise: bool = False,
    inner_profiles: NDArray[np.float64] | None = None,
) -> SymmetryCheck:
    """Annular-scan centre-symmetry check (section 3.2, invariant 1).

    A ring is "good" when it has enough contrast, correlates with itself turned
    by 180 degrees at least ``min_symmetry``, shows exactly four sector boundaries
    in opposite pairs, its line angles agree with the innermost good ring, and no
    good ring inside it was dim (:func:`_past_a_dim_ring`: a dim ring may end a
    run, not carry it on). A candidate passes when a run of at least two
    consecutive good rings starts at one of the ``max_first_ring`` innermost rings
    (the X must reach the centre). Blur dims those rings most: where none of them
    has the contrast, one that keeps the share of the brightest ring's that the
    widest blur leaves (:func:`blurred_contrast_share`) may start the run.

    Args:
        image: (H, W) float image.
        xy: (N, 2) candidate centres (already centred to ~1 px).
        radii_px: (J,) ring radii, increasing (see :func:`ring_radii`).
        min_contrast: minimum ring contrast in image units.
        min_symmetry: minimum 180-degree self-correlation.
        max_angle_drift_rad: largest change of a line angle between rings.
        max_first_ring: the run must start at a ring index below this.
        normalise: applied to the ring samples (contrast is measured after it).
        equalise: read each ring after :func:`equalise_bright_sectors` too.
        inner_profiles: the rings every point is read on first, as
            :func:`centre_symmetry_inner_profiles` read them with the same
            ``radii_px``, ``max_first_ring`` and ``normalise``; None reads them.

    Returns:
        :class:`SymmetryCheck`.
    """
    check = functools.partial(
        _centre_symmetry_check,
        image,
        radii_px=radii_px,
        options=(min_contrast, min_symmetry, max_angle_drift_rad, max_first_ring),
        normalise=normalise,
        equalise=equalise,
    )
    if inner_profiles is None:
        return in_blocks(check, _CHECK_BLOCK, xy)
    return in_blocks(check, _CHECK_BLOCK, xy, inner_profiles)


@dataclass(frozen=True)
class RingReader:
    """:func:`centre_symmetry_check` on one image with one ladder, floor and threshold.

    Attributes:
        image: (H, W) grey image, raw levels.
        radii_px: (J,) the ring ladder (:func:`ring_radii`).
        min_contrast: a good ring's least contrast, after ``normalise``.
        min_symmetry: a good ring's least 180-degree self-correlation.
        normalise: applied to the ring samples.
    """

    image: NDArray[Any]
    radii_px: NDArray[np.float64]
    min_contrast: float
    min_symmetry: float
    normalise: Normaliser | None = None

    def __call__(
        self,
        xy: NDArray[np.float64],
        *,
        equalise: bool = False,
        inner_profiles: NDArray[np.float64] | None = None,
    ) -> SymmetryCheck:
        """The check at ``xy``; ``equalise`` and ``inner_profiles`` as for the function."""
        return centre_symmetry_check(
            self.image,
            xy,
            self.radii_px,
            min_contrast=self.min_contrast,
            min_symmetry=self.min_symmetry,
            normalise=self.normalise,
            equalise=equalise,
            inner_profiles=inner_profiles,
        )


class RingReading(NamedTuple):
    """What :func:`ring_check` read.

    Attributes:
        candidates: the candidates, those the lines' crossing recentred moved.
        check: their :class:`SymmetryCheck`.
        equalised_x: (N,) where the equalised rings read at the candidate showed an X
            of any extent.
    """

    candidates: Candidates
    check: SymmetryCheck
    equalised_x: NDArray[np.bool_]


def ring_check(
    rings: RingReader,
    candidates: Candidates,
    wide: NDArray[np.bool_],
    floor: Callable[[NDArray[np.float64]], NDArray[np.float64]],
) -> RingReading:
    """The centre-symmetry check, and for X's wider than texture's its equalised twin.

    A dull bright quadrant breaks the grey-level symmetry of the rings, not the
    X's geometry; :func:`equalise_bright_sectors` gives the two bright sectors one
    level. That is evidence texture can fake at its own sizes (equalised
    everywhere, texture saddles of extent 2-6 px pass on the renderer's (a) and
    (c) and on real aerial ground), so it is read for the candidates screened
    beyond texture's scale (``wide``) or shown out to
    :data:`EQUALISED_MIN_EXTENT_PX` by the plain rings, and :func:`with_equalised`
    says where it is believed (``floor``: the score floor of each extent).

    The same quadrant pulls the centring, a fit of grey-level symmetry, towards
    the brighter side: 1-3 px on the renderer's (g) markers of 10-30 px, where
    the inner rings no longer see the X symmetric, equalised or not. Wide
    candidates still rejected are therefore read again, equalised, where the lines
    found on their innermost rings cross (:func:`line_crossing_centres`: edges'
    phases only, which the levels leave in place), and move there where the X
    shows out to that extent. Measured: docs/method.md, "Equalised rings for X's
    wider than texture's" and "The lines' crossing, not grey-level symmetry, for
    a dull X's centre"; docs/accuracy-journal.md, "Figures the fit's and the detector's
    docstrings carried".

    Args:
        rings: the check, on the frame, as the detector reads rings.
        candidates: the centred candidates.
        wide: (N,) those screened beyond texture's scale.
        floor: the score floor of an X of each extent.

    Returns:
        :class:`RingReading`.
    """
    xy = candidates.xy
    # The inner rings read once: the equalised reading of the same points takes them.
    inner = centre_symmetry_inner_profiles(
        rings.image, xy, rings.radii_px, normalise=rings.normalise
    )
    ring = rings(xy, inner_profiles=inner)
    retry = np.flatnonzero(wide | (ring.accepted & (ring.radius_px >= EQUALISED_MIN_EXTENT_PX)))
    equalised_x = np.zeros(len(xy), dtype=bool)
    if len(retry):
        equalised = rings(xy[retry], equalise=True, inner_profiles=inner[retry])
        equalised_x[retry] = equalised.accepted
        ring = with_equalised(ring, retry, equalised, floor(ring.radius_px[retry]))
    lost = np.flatnonzero(wide & ~ring.accepted)
    if not len(lost):
        return RingReading(candidates, ring, equalised_x)
    crossing, _ = line_crossing_centres(
        rings.image,
        xy[lost],
        rings.radii_px[:LINE_CROSSING_RINGS],
        min_contrast=rings.min_contrast,
        normalise=rings.normalise,
        profiles=inner[lost, :LINE_CROSSING_RINGS],
    )
    # Those the crossing left where they were have had their equalised reading.
    shifted = (crossing != xy[lost]).any(axis=1)
    lost, crossing = lost[shifted], crossing[shifted]
    there = rings(crossing, equalise=True)
    found = there.accepted & (there.radius_px >= EQUALISED_MIN_EXTENT_PX)
    return RingReading(
        candidates.moved(lost[found], crossing[found]),
        ring.with_rows(lost[found], there, found),
        equalised_x,
    )


def centre_symmetry_inner_profiles(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    radii_px: NDArray[np.float64],
    *,
    max_first_ring: int = MAX_FIRST_RING,
    normalise: Normaliser | None = None,
) -> NDArray[np.float64]:
    """(N, K, 36) the rings :func:`centre_symmetry_check` reads first for every point.

    Read once and handed to a plain and an equalised check of the same points (its
    ``inner_profiles``), they are not read twice: the samples are per point, so
    the same bit for bit however the points are batched.
    """
    radii = radii_px[: _inner_rings(len(radii_px), max_first_ring)]
    profiles: NDArray[np.float64] = in_blocks(
        functools.partial(annular_profiles, image, radii_px=radii, normalise=normalise),
        _CHECK_BLOCK,
        xy,
    )
    return profiles


def _inner_rings(n_rings: int, max_first_ring: int) -> int:
    """How many of the innermost rings :func:`centre_symmetry_check` reads for every point."""
    return min(n_rings, max_first_ring + _RINGS_READ_BEYOND_START)


def _centre_symmetry_check(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    inner_profiles: NDArray[np.float64] | None = None,
    *,
    radii_px: NDArray[np.float64],
    options: tuple[float, float, float, int],
    normalise: Normaliser | None,
    equalise: bool,
) -> SymmetryCheck:
    """:func:`centre_symmetry_check` of the points ``xy``; ``options`` are its four limits."""

    def rings(
        points: NDArray[np.float64],
        radii: NDArray[np.float64],
        profiles: NDArray[np.float64] | None = None,
    ) -> RingAnalysis:
        if profiles is None:
            profiles = annular_profiles(image, points, radii, normalise)
        # Neither the equalising nor the analysis writes to the profiles: given ones
        # serve another check unchanged.
        return analyse_rings(equalise_bright_sectors(profiles) if equalise else profiles)

    max_first_ring = options[3]
    n, n_rings = len(xy), len(radii_px)
    if n == 0:
        return SymmetryCheck(
            np.zeros(0, bool), np.zeros(0), np.zeros(0), np.zeros((0, 2)), np.zeros(0)
        )
    # A run that ends before the last ring read is final: the outer rings cannot join
    # it. Texture's runs end within the first rings, so the outer rings are read only
    # for the candidates whose run goes on to the last of those.
    first_read = _inner_rings(n_rings, max_first_ring)
    inner = rings(xy, radii_px[:first_read], inner_profiles)
    check, going_on = _ring_runs(inner, radii_px[:first_read], *options)
    if first_read == n_rings or not going_on.any():
        return check
    further = np.flatnonzero(going_on)
    outer = rings(xy[further], radii_px[first_read:])
    joined = RingAnalysis(
        *(np.concatenate([a[further], b], axis=1) for a, b in zip(inner, outer, strict=True))
    )
    full, _ = _ring_runs(joined, radii_px, *options)
    return check.with_rows(further, full)


def blurred_contrast_share(radii_px: NDArray[np.float64]) -> NDArray[np.float64]:
    """(J,) the share of an X's contrast a ring of each radius keeps under the widest blur.

    On a ring of radius rho about an X of two perpendicular lines blurred by a
    Gaussian of sigma, the brightest and darkest samples lie midway between the
    lines, at erf(rho / (2 sigma))^2 of the paint's levels either side of their
    mean: at :data:`RING_BLUR_SIGMA_PX`, 0.27 at 2 px, 0.47 at 2.8, 0.71 at 4. A
    junction of texture whose centre is flat keeps less: its blobs' edges do not
    run on to the centre (measured: docs/accuracy-journal.md, "A faint X's innermost rings,
    dimmed by its blur").
    """
    return cast(
        "NDArray[np.float64]", special.erf(np.asarray(radii_px) / (2.0 * RING_BLUR_SIGMA_PX)) ** 2
    )


def _past_a_dim_ring(good: NDArray[np.bool_], contrast: NDArray[np.float64]) -> NDArray[np.bool_]:
    """(N, J) the rings past a dim one, where a run of good rings must end.

    A good ring is dim under :data:`RING_CONTRAST_FRACTION` of the brightest good
    ring inside it. A marker's rings see its paint's contrast out to its outline;
    the ring along the outline sees the ground too, dims, and may be the run's last.
    Rings past it that still show an X read the dark quadrants going on into dark
    ground: on a steeply seen marker a fifth to a quarter of its contrast, out to
    rings well past its shortest reach, where the template of that extent does not
    match it (docs/accuracy-journal.md, "The rings' run ends at a dim ring").
    """
    brightest = np.maximum.accumulate(np.where(good, contrast, 0.0), axis=1)
    dim = good & (contrast < RING_CONTRAST_FRACTION * brightest)
    past = np.zeros_like(dim)
    past[:, 1:] = np.logical_or.accumulate(dim[:, :-1], axis=1)
    return past


def _ring_runs(
    rings: RingAnalysis,
    radii_px: NDArray[np.float64],
    min_contrast: float,
    min_symmetry: float,
    max_angle_drift_rad: float,
    max_first_ring: int,
) -> tuple[SymmetryCheck, NDArray[np.bool_]]:
    """:func:`centre_symmetry_check` from the analysis of the rings ``radii_px`` alone.

    Returns:
        The check, and (N,) True where a candidate's run goes on to the last ring.
    """
    n, n_rings = rings.contrast.shape
    ring_index = np.arange(n_rings)[None, :]
    shape = rings.good(0.0, min_symmetry)
    plain = shape & (rings.contrast >= min_contrast)
    # The X's contrast is its brightest ring's at the floor; blur dims its innermost
    # rings to a share of it, not texture's blurred junctions to less.
    x_contrast = np.where(plain, rings.contrast, 0.0).max(axis=1, keepdims=True)
    blurred = shape & (rings.contrast >= blurred_contrast_share(radii_px) * x_contrast)
    blurred &= (ring_index < max_first_ring) & (x_contrast > 0.0)
    # A run starts at a ring the blur dims only where no ring at the floor starts one:
    # a run's score reads its innermost rings, and a dimmed ring's is the lower.
    good = plain | (blurred & ~plain[:, :max_first_ring].any(axis=1, keepdims=True))
    good &= ~_past_a_dim_ring(good, rings.contrast)
    first = np.argmax(good[:, :max_first_ring], axis=1)
    has_first = good[np.arange(n), first] & good[:, :max_first_ring].any(axis=1)
    reference = rings.line_angles[np.arange(n), first]  # (N, 2)
    # Lines may come out in either order on different rings: compare both pairings.
    drift_same, drift_swap = _pairing_differences(rings.line_angles, reference[:, None, :])
    good &= np.minimum(drift_same, drift_swap) <= max_angle_drift_rad
    after_first = ring_index >= first[:, None]
    # The run continues while rings stay good: the first bad ring after `first` ends it.
    broken = np.cumsum(~good & after_first, axis=1) > 0
    in_run = good & after_first & ~broken & has_first[:, None]
    run_length = in_run.sum(axis=1)
    accepted = run_length >= 2
    last = np.where(in_run.any(axis=1), n_rings - 1 - np.argmax(in_run[:, ::-1], axis=1), 0)
    # The score uses the three innermost rings of the run: outer rings of a large marker
    # meet its plate boundary, which perspective leaves less symmetric than the X itself.
    inner = in_run & (np.cumsum(in_run, axis=1) <= 3)
    score = np.where(accepted, (rings.symmetry * inner).sum(1) / np.maximum(inner.sum(1), 1), 0.0)
    # Outer rings fix the line directions best (more pixels per degree): average the
    # doubled angles over the run, weighted by ring radius. The run's last ring runs
    # along the marker's own edge (a quarter disk's arc), which bends its boundaries,
    # so it is left out when the run has more than two rings.
    outermost = ring_index == last[:, None]
    weight = (in_run & ~(outermost & (run_length[:, None] > 2))) * radii_px[None, :]
    aligned = np.where(
        (drift_same <= drift_swap)[..., None], rings.line_angles, rings.line_angles[..., ::-1]
    )
    mean_cos = (weight[..., None] * np.cos(2.0 * aligned)).sum(axis=1)
    mean_sin = (weight[..., None] * np.sin(2.0 * aligned)).sum(axis=1)
    line_angles = np.where(
        accepted[:, None], (np.arctan2(mean_sin, mean_cos) / 2.0) % np.pi, reference
    )
    contrast = rings.contrast[np.arange(n), first]
    return SymmetryCheck(accepted, score, radii_px[last], line_angles, contrast), in_run[:, -1]


class EdgePhaseRings(NamedTuple):
    """Per-ring measurements of :func:`analyse_ring_edges`, each (N, J).

    Attributes:
        good: True where the ring shows an X: two lines through the centre, each a
            pair of edges about 180 degrees apart with opposite image-gradient
            polarity, the two lines of opposite sense, no clutter.
        line_angles: (N, J, 2) directions in [0, pi) of the two lines.
        strength: weakest of the four paired edges over the strongest edge on the
            ring, in (0, 1] (0 where not good).
        contrast: bright minus dark level of the smoothed ring, in image units.
        edges: number of significant edges (derivative extrema) on the ring.
        crossings: (N, J, 2, 2) phases in radians (angle from +x towards +y) of
            where each line crosses the ring, both ends.
    """

    good: NDArray[np.bool_]
    line_angles: NDArray[np.float64]
    strength: NDArray[np.float64]
    contrast: NDArray[np.float64]
    edges: NDArray[np.float64]
    crossings: NDArray[np.float64]


def ring_derivative(
    profiles: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The ring profiles Gaussian-smoothed and differentiated along the angle.

    The binomial [1, 4, 6, 4, 1] / 16 (sigma 1 sample, 10 degrees) and a central
    difference: the paper's first-order differentiation with Gaussian filtering, so
    that the edges are the extrema of the result and the zero crossings of its own
    difference.

    Args:
        profiles: (..., 36) ring samples, no NaN.

    Returns:
        (smoothed, derivative), each (..., 36); derivative k is d/d(angle) at
        sample k, per sample.
    """
    reach = len(_DERIVATIVE_KERNEL) // 2
    wrapped = np.concatenate([profiles[..., -reach:], profiles, profiles[..., :reach]], axis=-1)
    smoothed = sum(
        w * wrapped[..., reach - 2 + i : reach - 2 + i + N_ANGLES]
        for i, w in enumerate(_SMOOTHING_KERNEL)
    )
    derivative = sum(
        w * wrapped[..., i : i + N_ANGLES] for i, w in enumerate(_DERIVATIVE_KERNEL) if w
    )
    return smoothed, derivative


def analyse_ring_edges(
    profiles: NDArray[np.float64],
    *,
    min_contrast: float,
    edge_fraction: float = EDGE_FRACTION,
    max_phase_error_rad: float = MAX_PHASE_ERROR_RAD,
    min_line_angle_rad: float = MIN_LINE_ANGLE_RAD,
    max_edges: int = MAX_RING_EDGES,
) -> EdgePhaseRings:
    """The paper's annular check on each ring: edge phases and polarities (section 3.2, check 1).

    Edges are the extrema of the ring's angular derivative (:func:`ring_derivative`),
    at sub-sample phase (a parabola through the extremum and its neighbours), that
    reach ``edge_fraction`` of the ring's strongest. A line through the centre
    crosses the ring twice, 180 degrees apart, and an X's sectors alternate, so at
    the two crossings the image gradient points in opposite directions: opposite
    gradient polarity. The ring's tangent also turns by 180 degrees between them, so
    in the angular derivative both crossings carry the same sign, where a straight
    edge (a half-plane, an L or T corner's bar) gives opposite signs. An X has one
    such line of each sign. A ring is good when it has both, ``min_line_angle_rad``
    apart or more, at most ``max_edges`` significant edges (more is clutter: a plus
    sign, texture) and at least ``min_contrast``.

    Args:
        profiles: (N, J, 36) from :func:`annular_profiles`; rings with NaN fail.
        min_contrast: minimum bright-minus-dark level of the smoothed ring.
        edge_fraction: an extremum is an edge from this fraction of the strongest.
        max_phase_error_rad: largest departure of a crossing pair from 180 degrees.
        min_line_angle_rad: smallest angle between the two lines.
        max_edges: most significant edges a good ring may have.

    Returns:
        :class:`EdgePhaseRings`.
    """
    shape = profiles.shape[:-1]
    flat = profiles.reshape(-1, N_ANGLES)
    missing = np.isnan(flat).any(axis=-1)
    smoothed, derivative = ring_derivative(np.where(np.isnan(flat), 0.0, flat))
    contrast = np.where(missing, 0.0, smoothed.max(axis=-1) - smoothed.min(axis=-1))
    magnitude = np.abs(derivative)
    # Extrema of the derivative: zero crossings of its difference, ties to the first.
    before, after = derivative[:, _PREVIOUS], derivative[:, _NEXT]
    maximum = (derivative > 0) & (derivative >= before) & (derivative > after)
    minimum = (derivative < 0) & (derivative <= before) & (derivative < after)
    strongest = magnitude.max(axis=-1)
    edge = (maximum | minimum) & (magnitude >= edge_fraction * strongest[:, None])
    n_edges = edge.sum(axis=-1)
    line_angles = np.zeros((len(flat), 2))
    ends = np.zeros((len(flat), 2, 2))
    weakest_line = np.zeros(len(flat))
    # Only rings that can pass are paired (most texture rings fail here already).
    viable = np.flatnonzero(
        ~missing & (contrast >= min_contrast) & (n_edges >= 4) & (n_edges <= max_edges)
    )
    if len(viable):
        lines = _pair_edges(
            derivative[viable], magnitude[viable], edge[viable], max_edges, max_phase_error_rad
        )
        ends[viable], weakest_line[viable] = lines
        line_angles[viable] = (np.angle(np.exp(2j * lines[0]).sum(axis=-1)) / 2.0) % np.pi
    good = (weakest_line > 0) & (
        _angle_difference(line_angles[:, 0], line_angles[:, 1]) >= min_line_angle_rad
    )
    strength = np.where(good, weakest_line / np.maximum(strongest, 1e-12), 0.0)
    return EdgePhaseRings(
        good.reshape(shape),
        line_angles.reshape(*shape, 2),
        strength.reshape(shape),
        contrast.reshape(shape),
        n_edges.reshape(shape),
        ends.reshape(*shape, 2, 2),
    )


def _pair_edges(
    derivative: NDArray[np.float64],
    magnitude: NDArray[np.float64],
    edge: NDArray[np.float64],
    max_edges: int,
    max_phase_error_rad: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Each ring's strongest line of each sign: two same-sign edges about 180 degrees apart.

    Args:
        derivative: (R, 36) angular derivatives.
        magnitude: (R, 36) their absolute values.
        edge: (R, 36) True at the significant extrema, at most ``max_edges`` per ring.
        max_edges: the most edges of a ring.
        max_phase_error_rad: largest departure of a pair from 180 degrees.

    Returns:
        (ends, weakest): (R, 2, 2) phases of the (+, -) lines' two crossings, and (R,)
        the weaker line's weaker edge (0 where a line is missing).
    """
    n_rings = len(edge)
    offset = parabolic_offset(magnitude[:, _PREVIOUS], magnitude, magnitude[:, _NEXT])
    # The edges of each ring side by side, padded with zero magnitude.
    ring, sample = np.nonzero(edge)
    slot = np.arange(len(ring)) - np.searchsorted(ring, ring)
    phase = np.zeros((n_rings, max_edges))
    sign = np.zeros((n_rings, max_edges))
    size = np.zeros((n_rings, max_edges))
    phase[ring, slot] = (sample + offset[ring, sample]) * (2.0 * np.pi / N_ANGLES)
    sign[ring, slot] = np.sign(derivative[ring, sample])
    size[ring, slot] = magnitude[ring, sample]
    # All pairs (i, j) of a ring: same sign, 180 degrees apart within the tolerance.
    error = np.abs((phase[:, None, :] - phase[:, :, None]) % (2.0 * np.pi) - np.pi)
    partner = np.where(
        (sign[:, None, :] == sign[:, :, None]) & (error <= max_phase_error_rad),
        size[:, None, :],
        0.0,
    )
    best = np.argmax(partner, axis=2)
    rows = np.arange(n_rings)[:, None]
    line_strength = np.minimum(size, partner[rows, np.arange(max_edges), best])
    ends = np.zeros((n_rings, 2, 2))
    weakest = []
    for line, polarity in enumerate((1, -1)):
        strength = np.where(sign == polarity, line_strength, 0.0)
        k = np.argmax(strength, axis=1)
        weakest.append(strength[rows[:, 0], k])
        ends[:, line, 0] = phase[rows[:, 0], k]
        ends[:, line, 1] = phase[rows[:, 0], best[rows[:, 0], k]]
    return ends, np.minimum(*weakest)


def chord_crossing(
    xy: NDArray[np.float64], radii_px: NDArray[np.float64], crossings: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Where the two lines found on each ring cross: the X centre the ring saw.

    Each line is the chord between its two crossings of the ring; off the centre, the
    chords of an X's lines still cross at its centre.

    Args:
        xy: (N, 2) ring centres.
        radii_px: (J,) ring radii.
        crossings: (N, J, 2, 2) from :attr:`EdgePhaseRings.crossings`.

    Returns:
        (N, J, 2) crossing points (NaN where the chords are parallel).
    """
    ends = xy[:, None, None, None, :] + radii_px[None, :, None, None, None] * np.stack(
        [np.cos(crossings), np.sin(crossings)], axis=-1
    )  # (N, J, line, end, 2)
    a, b = ends[..., 0, 0, :], ends[..., 0, 1, :]
    c, d = ends[..., 1, 0, :], ends[..., 1, 1, :]
    u, v, w = b - a, d - c, c - a
    cross = u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
    parallel = np.abs(cross) <= 1e-9
    t = (w[..., 0] * v[..., 1] - w[..., 1] * v[..., 0]) / np.where(parallel, 1.0, cross)
    return np.where(parallel[..., None], np.nan, a + t[..., None] * u)


class EdgePhaseCheck(NamedTuple):
    """Result of :func:`edge_phase_check` for N candidates.

    Attributes:
        accepted: (N,) bool.
        xy: (N, 2) the centres the rings were finally read at (moved to where the
            lines cross; the input where no ring found two lines).
        score: (N,) mean ring strength over the run's three innermost rings (0 where
            rejected).
        radius_px: (N,) largest ring of the run: the marker's extent.
        line_angles: (N, 2) directions in [0, pi) of the marker's two lines.
        contrast: (N,) bright-minus-dark level on the run's first ring.
    """

    accepted: NDArray[np.bool_]
    xy: NDArray[np.float64]
    score: NDArray[np.float64]
    radius_px: NDArray[np.float64]
    line_angles: NDArray[np.float64]
    contrast: NDArray[np.float64]


def _edge_rings(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    radii_px: NDArray[np.float64],
    min_contrast: float,
    max_phase_error_rad: float,
    normalise: Normaliser | None,
    profiles: NDArray[np.float64] | None = None,
) -> EdgePhaseRings:
    """:func:`analyse_ring_edges` of the rings of ``radii_px`` around ``xy``.

    ``profiles``: those rings as :func:`annular_profiles` read them with ``normalise``;
    None reads them.
    """
    if profiles is None:
        profiles = annular_profiles(image, xy, radii_px, normalise)
    return analyse_ring_edges(
        profiles, min_contrast=min_contrast, max_phase_error_rad=max_phase_error_rad
    )


def line_crossing_centres(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    radii_px: NDArray[np.float64],
    *,
    min_contrast: float,
    recentre_px: float = RECENTRE_MAX_PX,
    normalise: Normaliser | None = None,
    profiles: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Candidates moved to where the lines found on their rings cross.

    The rings' edges are paired leniently (:data:`RECENTRE_PHASE_ERROR_RAD`: a line
    1 px off the centre meets a ring of 3 px ~40 degrees from opposite); the chords
    of an X's lines cross at its centre wherever the ring is
    (:func:`chord_crossing`), and the median over the rings that found two lines is
    the estimate. Only edges' phases are read, never grey levels across the centre:
    a dull bright quadrant or a shadow edge, which pull a fit of grey-level symmetry
    off the centre, leave the lines where they are.

    Args:
        image: (H, W) image.
        xy: (N, 2) candidate centres.
        radii_px: (J,) ring radii, px: the innermost, which the X must reach.
        min_contrast: minimum ring contrast in image units (after ``normalise``).
        recentre_px: largest move, px; a candidate that would move further stays.
        normalise: applied to the ring samples.
        profiles: (N, J, 36) the rings of ``radii_px`` around ``xy`` as
            :func:`annular_profiles` read them with ``normalise`` (a check's inner
            rings); None reads them.

    Returns:
        (N, 2) the centres, and (N,) True where a ring found two lines.
    """
    rings = _edge_rings(
        image, xy, radii_px, min_contrast, RECENTRE_PHASE_ERROR_RAD, normalise, profiles
    )
    crossing = np.where(
        rings.good[..., None], chord_crossing(xy, radii_px, rings.crossings), np.nan
    )
    # Rows where no ring found lines stay NaN. (A warnings filter is no way to keep
    # nanmedian quiet about them: it is process-wide, and the node's workers are threads.)
    found = np.isfinite(crossing).any(axis=1).all(axis=1)
    estimate = np.full((len(xy), 2), np.nan)
    estimate[found] = nan_median(crossing[found])
    move = np.isfinite(estimate).all(axis=1) & (
        np.linalg.norm(estimate - xy, axis=1) <= recentre_px
    )
    found_lines = cast("NDArray[np.bool_]", rings.good.any(axis=1))
    return np.where(move[:, None], estimate, xy), found_lines


def edge_phase_check(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    radii_px: NDArray[np.float64],
    *,
    min_contrast: float,
    max_angle_drift_rad: float = MAX_LINE_DRIFT_RAD,
    max_first_ring: int = MAX_FIRST_RING,
    max_phase_error_rad: float = MAX_PHASE_ERROR_RAD,
    recentre_px: float = RECENTRE_MAX_PX,
    normalise: Normaliser | None = None,
) -> EdgePhaseCheck:
    """The paper's annular centre-symmetry check by edge phase and polarity (section 3.2).

    Rings every 10 degrees (:func:`annular_profiles`) at radii across the expected
    marker sizes (the paper's adaptive radius: the largest ring that still shows the
    X is the marker's extent), each analysed by :func:`analyse_ring_edges`. A
    candidate off the centre sees the crossings of each line less than 180 degrees
    apart; the rings are therefore read twice: once at the candidate, then where the
    lines found on its innermost rings cross (:func:`line_crossing_centres`). The
    lines of an X pass through its centre, so their angles must agree from ring to
    ring (a bar's two edges, which also pair up on one ring, spread with the
    radius). A candidate passes when a run of at least two consecutive good rings
    with consistent line angles starts at one of the ``max_first_ring`` innermost
    rings.

    Unlike :func:`centre_symmetry_check` it never compares grey levels across the
    centre: one bright sector duller than the other leaves the edges' phases and
    polarities as they are.

    Args:
        image: (H, W) image.
        xy: (N, 2) candidate centres.
        radii_px: (J,) ring radii, increasing (see :func:`ring_radii`).
        min_contrast: minimum ring contrast in image units (after ``normalise``).
        max_angle_drift_rad: largest change of a line angle from the run's first ring.
        max_first_ring: the run must start at a ring index below this.
        max_phase_error_rad: largest departure of a crossing pair from 180 degrees
            (:func:`analyse_ring_edges`).
        recentre_px: largest move to the lines' crossing.
        normalise: applied to the ring samples (e.g. the dynamic gamma).

    Returns:
        :class:`EdgePhaseCheck`.
    """
    n, n_rings = len(xy), len(radii_px)
    if n == 0:
        return EdgePhaseCheck(
            np.zeros(0, bool),
            np.zeros((0, 2)),
            np.zeros(0),
            np.zeros(0),
            np.zeros((0, 2)),
            np.zeros(0),
        )

    # A ring that fails the lenient pairing of the recentring fails the strict one.
    xy, found_lines = line_crossing_centres(
        image,
        xy,
        radii_px[: max_first_ring + 1],
        min_contrast=min_contrast,
        recentre_px=recentre_px,
        normalise=normalise,
    )
    hopeful = np.flatnonzero(found_lines)
    strict = _edge_rings(image, xy[hopeful], radii_px, min_contrast, max_phase_error_rad, normalise)
    rings = EdgePhaseRings(
        *(
            _scatter(np.zeros((n, *np.shape(part)[1:]), part.dtype), hopeful, part)
            for part in strict
        )
    )
    # An X crosses every ring with its full contrast; the tails of a bar's or blob's
    # blurred edges give the rings inside it a fraction of what the outer ones see.
    good = rings.good & (
        rings.contrast
        >= RING_CONTRAST_FRACTION * (rings.contrast * rings.good).max(axis=1, keepdims=True)
    )
    in_run, swapped = _longest_run(good, rings.line_angles, max_first_ring, max_angle_drift_rad)
    first = np.argmax(in_run, axis=1)
    accepted = in_run.sum(axis=1) >= 2
    last = np.where(in_run.any(axis=1), n_rings - 1 - np.argmax(in_run[:, ::-1], axis=1), 0)
    inner = in_run & (np.cumsum(in_run, axis=1) <= 3)
    score = np.where(accepted, (rings.strength * inner).sum(1) / np.maximum(inner.sum(1), 1), 0.0)
    aligned = np.where(swapped[..., None], rings.line_angles[..., ::-1], rings.line_angles)
    mean_doubled = (in_run[..., None] * radii_px[None, :, None] * np.exp(2j * aligned)).sum(1)
    line_angles = np.where(
        accepted[:, None],
        (np.angle(mean_doubled) / 2.0) % np.pi,
        rings.line_angles[np.arange(n), first],
    )
    contrast = rings.contrast[np.arange(n), first]
    return EdgePhaseCheck(accepted, xy, score, radii_px[last], line_angles, contrast)


def _longest_run(
    good: NDArray[np.bool_],
    line_angles: NDArray[np.float64],
    max_first_ring: int,
    max_drift_rad: float,
) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """The longest run of consecutive good rings whose lines stay within ``max_drift_rad``.

    A run starts at one of the ``max_first_ring`` innermost rings and its first ring's
    line angles are the reference (an innermost ring a few degrees off does not cut
    a run that starts on the next one).

    Args:
        good: (N, J) good rings.
        line_angles: (N, J, 2) their line angles.
        max_first_ring: the run starts at a ring index below this.
        max_drift_rad: largest difference from the run's first ring.

    Returns:
        (in_run, swapped): (N, J) bool, and (N, J) True where a ring lists the two
        lines in the other order than the run's first ring.
    """
    n_rings = good.shape[1]
    ring_index = np.arange(n_rings)[None, :]
    best = np.zeros(good.shape, dtype=bool)
    best_swap = np.zeros(good.shape, dtype=bool)
    for first in range(min(max_first_ring, n_rings)):
        reference = line_angles[:, first, None, :]
        same, swap = _pairing_differences(line_angles, reference)
        steady = good & (np.minimum(same, swap) <= max_drift_rad) & (ring_index >= first)
        broken = np.cumsum(~steady & (ring_index >= first), axis=1) > 0
        in_run = steady & ~broken & good[:, first, None]
        longer = in_run.sum(axis=1) > best.sum(axis=1)
        best[longer] = in_run[longer]
        best_swap[longer] = (swap < same)[longer]
    return best, best_swap


def _scatter(
    full: NDArray[Any], index: NDArray[np.integer[Any]], part: NDArray[Any]
) -> NDArray[Any]:
    """A copy of ``full`` with the rows ``index`` replaced by ``part``."""
    out = full.copy()
    out[index] = part
    return out


class LineCheck(NamedTuple):
    """Result of :func:`double_line_check` for N candidates.

    Attributes:
        accepted: (N,) bool: two extended segments of different direction cross
            within the distance threshold.
        line_angles: (N, 2) directions in [0, pi) of the two lines (NaN if rejected).
        distance_px: (N,) distance of the crossing from the candidate (inf if none).
    """

    accepted: NDArray[np.bool_]
    line_angles: NDArray[np.float64]
    distance_px: NDArray[np.float64]


@functools.lru_cache(maxsize=64)
def _pairs_of(count: int) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """(i, j) of every pair i < j of ``count`` segments, as ``np.triu_indices`` orders them.

    Cached (read-only): a frame's batches come in a few sizes, and building the
    indices cost a tenth of the crossings' time.
    """
    i, j = np.triu_indices(count, 1)
    i.flags.writeable = j.flags.writeable = False
    return i, j


def _segment_intersections(
    segments: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.intp], NDArray[np.intp], NDArray[np.bool_]]:
    """Pairwise intersections of infinite lines through segments (x1, y1, x2, y2).

    Args:
        segments: (G, M, 4) M segments for each of G candidates.

    Returns:
        (points (G, P, 2), i (P,), j (P,), crossing (G, P)) for the P pairs i < j;
        ``crossing`` is False for parallel pairs, whose point is meaningless.
    """
    p = segments[..., :2]
    d = segments[..., 2:] - segments[..., :2]
    i, j = _pairs_of(segments.shape[1])
    cross = d[:, i, 0] * d[:, j, 1] - d[:, i, 1] * d[:, j, 0]
    crossing = np.abs(cross) > 1e-9
    w = p[:, j] - p[:, i]
    t = (w[..., 0] * d[:, j, 1] - w[..., 1] * d[:, j, 0]) / np.where(crossing, cross, 1.0)
    return p[:, i] + t[..., None] * d[:, i], i, j, crossing


def _nearest_crossings(
    segments: list[NDArray[np.float64]],
    xy: NDArray[np.float64],
    extend_px: float,
    min_angle_rad: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Eq. (9) for every candidate: the crossing of two extended segments nearest to it.

    Candidates are batched by their number of segments rounded up to a power of
    two, each batch padded to its longest with NaN segments (no crossing): the loop
    runs over a few sizes, not over the candidates, and the pairs of a candidate's
    own segments keep their order, so the nearest crossing found first is the same.

    Args:
        segments: per candidate, its (M_k, 4) LSD segments in image coordinates.
        xy: (N, 2) candidate centres.
        extend_px: Delta s of Eq. (9).
        min_angle_rad: smallest angle between the two segments' directions.

    Returns:
        (distance, line_angles): (N,) distance of that crossing from the candidate
        (inf if none) and (N, 2) the two segments' directions in [0, pi) (NaN if none).
    """
    n = len(xy)
    distance = np.full(n, np.inf)
    angles = np.full((n, 2), np.nan)
    count = np.array([len(found) for found in segments], dtype=np.intp)
    size = 1 << np.ceil(np.log2(np.maximum(count, 1))).astype(np.intp)
    for m in np.unique(size[count >= 2]):
        members = np.flatnonzero((size == m) & (count >= 2))
        batch = np.full((len(members), count[members].max(), 4), np.nan)
        for row, k in enumerate(members):
            batch[row, : count[k]] = segments[k]
        direction = batch[..., 2:] - batch[..., :2]
        length = np.linalg.norm(direction, axis=-1)
        unit = direction / np.maximum(length, 1e-9)[..., None]
        extended = np.concatenate(
            [batch[..., :2] - extend_px * unit, batch[..., 2:] + extend_px * unit], axis=-1
        )
        points, i, j, crossing = _segment_intersections(extended)
        seg_angle = np.arctan2(direction[..., 1], direction[..., 0]) % np.pi
        apart = _angle_difference(seg_angle[:, i], seg_angle[:, j]) >= min_angle_rad
        within = _on_segments(points, extended, i, j)
        dist = np.linalg.norm(points - xy[members, None, :], axis=-1)
        usable = crossing & apart & within
        best = np.argmin(np.where(usable, dist, np.inf), axis=1)
        found = usable.any(axis=1)
        rows = np.arange(len(members))[found]
        best = best[found]
        distance[members[found]] = dist[rows, best]
        angles[members[found]] = np.stack(
            [seg_angle[rows, i[best]], seg_angle[rows, j[best]]], axis=1
        )
    return distance, angles


#: Farthest a half-line may pass from the candidate, in ``max_distance_px``, to be paired
#: with its other half in :func:`_midline_crossing`: clipping moves a blurred edge by up
#: to about its blur, and the halves of a rendered board three times over-exposed pass
#: 1.3-2.1 px from their true centre.
_HALF_LINE_MAX_OFFSETS = 2.0


def _midline_crossing(
    segments: NDArray[np.float64],
    centre: NDArray[np.float64],
    max_distance_px: float,
    min_angle_rad: float,
) -> tuple[float, NDArray[np.float64]]:
    """Eq. (9) for an X whose white clips: where the lines midway between each line's halves cross.

    Where the white paint clips, each edge's blurred step is cut off at white and the
    edge LSD finds moves to its dark side: the two halves of one line move apart in
    opposite senses, as the X's point symmetry has it, and become two parallel
    segments on either side of the centre. Halves of different lines then cross
    sqrt 2 times that offset from the centre (2.1-2.3 px at the true centres of a
    rendered board three times over-exposed), while the line midway between the two
    halves of each line passes through it again. Taken as one line's halves: two
    segments closer to parallel than half ``min_angle_rad`` (nearer each other than
    any two lines of an X), on either side of the centre along their direction,
    each passing within :data:`_HALF_LINE_MAX_OFFSETS` times ``max_distance_px`` of
    it.

    Args:
        segments: (M, 4) one candidate's LSD segments in image coordinates.
        centre: (2,) the candidate.
        max_distance_px: as in :func:`double_line_check`.
        min_angle_rad: as in :func:`double_line_check`.

    Returns:
        (distance, line_angles): the distance of the crossing nearest the centre (inf
        if none) and the two midlines' directions in [0, pi) (NaN if none).
    """
    middle = 0.5 * (segments[:, :2] + segments[:, 2:])
    direction = segments[:, 2:] - segments[:, :2]
    unit = direction / np.maximum(np.linalg.norm(direction, axis=1), 1e-9)[:, None]
    offset = unit[:, 0] * (centre[1] - middle[:, 1]) - unit[:, 1] * (centre[0] - middle[:, 0])
    near = np.abs(offset) <= _HALF_LINE_MAX_OFFSETS * max_distance_px
    middle, unit = middle[near], unit[near]
    i, j = np.triu_indices(len(unit), 1)
    # LSD orients a segment by its gradient's polarity, which an X's line reverses
    # at the centre: the halves of one line come out pointing opposite ways.
    sense = np.where(np.sum(unit[i] * unit[j], axis=1) < 0.0, -1.0, 1.0)
    parallel = np.abs(unit[i, 0] * unit[j, 1] - unit[i, 1] * unit[j, 0]) <= np.sin(
        0.5 * min_angle_rad
    )
    along_i = np.sum(unit[i] * (middle[i] - centre), axis=1)
    along_j = np.sum(unit[i] * (middle[j] - centre), axis=1)
    halves = parallel & (along_i * along_j < 0.0)
    mid_unit = unit[i[halves]] + sense[halves, None] * unit[j[halves]]
    mid_point = 0.5 * (middle[i[halves]] + middle[j[halves]])
    if len(mid_point) < 2:
        return np.inf, np.full(2, np.nan)
    midlines = np.concatenate([mid_point, mid_point + mid_unit], axis=1)[None]
    points, a, b, crossing = _segment_intersections(midlines)
    mid_angle = np.arctan2(mid_unit[:, 1], mid_unit[:, 0]) % np.pi
    apart = _angle_difference(mid_angle[a], mid_angle[b]) >= min_angle_rad
    distance = np.where(crossing[0] & apart, np.linalg.norm(points[0] - centre, axis=1), np.inf)
    best = int(np.argmin(distance))
    if not np.isfinite(distance[best]):
        return np.inf, np.full(2, np.nan)
    return float(distance[best]), np.array([mid_angle[a[best]], mid_angle[b[best]]])


def double_line_check(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    *,
    extend_px: float,
    max_distance_px: float,
    min_angle_rad: float = LINE_MIN_ANGLE_RAD,
    full_scale: float = 255.0,
    stretch: NDArray[np.float64] | None = None,
) -> LineCheck:
    """LSD double-line intersection check, Eq. (9) (section 3.2, invariant 2).

    LSD runs on a window of 1.25 marker radii around each candidate; small
    windows are upsampled first so that the segments of a 3-5 px marker are long
    enough for LSD. Segments are extended by ``extend_px`` (Eq. 9, in full-image
    pixels) at both ends, and the candidate passes when two of them with
    directions at least ``min_angle_rad`` apart cross within ``max_distance_px``
    of it and within both extended segments. The edges of an X change polarity at
    the centre, so LSD returns up to four half-lines; any two of different
    direction suffice. Where none cross near enough and the window holds a clipped
    level (:data:`image.CLIPPED_SHARE` of white), the lines midway between each
    line's two halves are crossed instead (:func:`_midline_crossing` says why).

    LSD reads the raw window, not the dynamic gamma of Eq. (2): with one local
    mean per window that gamma is a monotonic map of the grey levels, which
    leaves the gradient directions LSD groups unchanged (measured: the same
    recall on every rendered family, for a quarter of the verification time).

    Args:
        image: (H, W) grey image, native dtype.
        xy: (N, 2) candidate centres.
        radius_px: (N,) marker radii (window half-size).
        extend_px: Delta s of Eq. (9).
        max_distance_px: largest distance of the crossing from the candidate.
        min_angle_rad: smallest angle between the two lines.
        full_scale: the value of white in ``image``; LSD reads 8-bit windows.
        stretch: (N,) factor each window's grey levels are multiplied by before
            LSD, or None: LSD's gradient threshold is in grey levels, so a marker
            in deep shadow needs its levels brought up as the pipeline's other raw
            floors come down (the shadow gain).

    Returns:
        :class:`LineCheck`.
    """
    n = len(xy)
    segments: list[NDArray[np.float64]] = [np.zeros((0, 4))] * n
    lsd = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD)
    height, width = image.shape
    windows, zooms, corners = [], [], []
    clipped_window: list[bool] = []
    # A loop over candidates (not pixels): each runs LSD on its own small window.
    for k in range(n):
        half = int(np.ceil(max(LSD_WINDOW_RADII * radius_px[k], _LSD_MIN_HALF_WINDOW_PX)))
        cx, cy = int(round(xy[k, 0])), int(round(xy[k, 1]))
        x0, y0 = max(cx - half, 0), max(cy - half, 0)
        x1, y1 = min(cx + half + 1, width), min(cy + half + 1, height)
        window = image[y0:y1, x0:x1]
        gain = 1.0 if stretch is None else float(stretch[k])
        if window.dtype != np.uint8 or gain != 1.0:
            levels = window * (gain * 255.0 / full_scale) + 0.5
            window = np.clip(levels, 0, 255).astype(np.uint8)
        windows.append(window)
        clipped_window.append(bool(clipped(window, 255.0).any()))
        zooms.append(max(1, int(np.ceil(_LSD_MIN_WINDOW_PX / max(min(window.shape), 1)))))
        corners.append((x0, y0))
    for k, (window, zoom, (x0, y0)) in enumerate(
        zip(upsampled(windows, zooms), zooms, corners, strict=True)
    ):
        found = lsd.detect(window)[0]
        if found is None or len(found) < 2:
            continue
        # Back to full-image coordinates: the resize maps pixel centres by (u + 0.5) / s - 0.5.
        # LSD gives (N, 1, 4) in OpenCV 4 and (N, 4) in OpenCV 5.
        segments[k] = (
            (found.reshape(-1, 4).astype(np.float64) + 0.5) / zoom
            - 0.5
            + np.array([x0, y0, x0, y0], dtype=np.float64)
        )
    distance, angles = _nearest_crossings(segments, xy, extend_px, min_angle_rad)
    for k in np.flatnonzero((distance > max_distance_px) & np.array(clipped_window, bool)):
        mid_distance, mid_angles = _midline_crossing(
            segments[k], xy[k], max_distance_px, min_angle_rad
        )
        if mid_distance < distance[k]:
            distance[k], angles[k] = mid_distance, mid_angles
    accepted = distance <= max_distance_px
    angles[~accepted] = np.nan
    return LineCheck(accepted, angles, distance)


#: Rows either side of a window that bicubic interpolation reads (its taps reach one
#: pixel back and two on).
_CUBIC_REACH_PX = 2


def upsampled(windows: list[NDArray[np.uint8]], zooms: list[int]) -> list[NDArray[np.uint8]]:
    """Each window enlarged ``zoom`` times by OpenCV's bicubic resize (zoom 1: as it is).

    The windows of one shape doubled (the zoom of every full-size window) are
    enlarged in one call, stacked with their edge rows repeated in between as far
    as the kernel reaches, so that each comes out as alone (where the resize
    repeats them too): a call costs ~45 us however small the window, ten times a
    13 px window's share of a stack. Other zooms (windows the frame's border cuts)
    take a call each: their rows' positions round differently down a stack.

    Args:
        windows: (h_k, w_k) uint8 images.
        zooms: their integer zoom factors.
    """
    result = list(windows)
    doubled: dict[tuple[int, ...], list[int]] = {}
    for k, (window, zoom) in enumerate(zip(windows, zooms, strict=True)):
        if zoom == 2:
            doubled.setdefault(window.shape, []).append(k)
        elif zoom > 1:
            result[k] = cast(
                "NDArray[np.uint8]",
                cv2.resize(window, None, fx=zoom, fy=zoom, interpolation=cv2.INTER_CUBIC),
            )
    reach = _CUBIC_REACH_PX
    for (rows, _), members in doubled.items():
        stack = np.vstack(
            [
                cv2.copyMakeBorder(windows[k], reach, reach, 0, 0, cv2.BORDER_REPLICATE)
                for k in members
            ]
        )
        enlarged = cv2.resize(stack, None, fx=2, fy=2, interpolation=cv2.INTER_CUBIC)
        for place, k in enumerate(members):
            top = 2 * (place * (rows + 2 * reach) + reach)
            result[k] = cast("NDArray[np.uint8]", enlarged[top : top + 2 * rows])
    return result


def _on_segments(
    points: NDArray[np.float64],
    segments: NDArray[np.float64],
    i: NDArray[np.intp],
    j: NDArray[np.intp],
    slack_px: float = 0.5,
) -> NDArray[np.bool_]:
    """True where each point (G, P, 2) projects inside both its segments, with a little slack.

    ``segments`` (G, M, 4); the point of pair p is tested against the segments ``i[p]``
    and ``j[p]``. Each segment's direction, length and slack are taken once, not once
    for every pair it is in (the same values).
    """
    start = segments[..., :2]
    d = segments[..., 2:] - start
    squared = np.maximum(np.einsum("...j,...j->...", d, d), 1e-12)
    slack = slack_px / np.maximum(np.linalg.norm(d, axis=-1), 1e-12)
    inside: NDArray[np.bool_] = np.ones(points.shape[:-1], dtype=bool)
    for k in (i, j):
        t = np.einsum("...j,...j->...", points - start[:, k], d[:, k]) / squared[:, k]
        inside &= (t >= -slack[:, k]) & (t <= 1.0 + slack[:, k])
    return inside


class SectorOrder(NamedTuple):
    """Result of :func:`sector_order` for N rings, each (N,).

    Attributes:
        strength: edge strength of the weaker of the two antipodal edge pairs
            (image units per 10 degrees); below 0 where the ring leaves the image.
        rising: index k (0-17) of the pair of rising edges (dark to bright going
            round), at 10 k and 10 k + 180 degrees.
        falling: index of the pair of falling edges.
    """

    strength: NDArray[np.float64]
    rising: NDArray[np.float64]
    falling: NDArray[np.float64]


def sector_order(profiles: NDArray[np.float64]) -> SectorOrder:
    """The order of dark and bright sectors on rings, from their edges alone.

    Going round an X, the grey level rises into each bright quadrant and falls
    out of it, and the edges come in antipodal pairs: the two lines through the
    centre cross every ring twice, 180 degrees apart, and both crossings of one
    line rise (or both fall). This reads the edges from the profile's derivative
    (the paper's annular scan turns extrema into zero crossings the same way) and
    scores the weaker edge of the best rising pair and of the best falling pair,
    within one sample of antipodal. It needs neither equal grey levels on the two
    bright quadrants (a dull one keeps its edges, only weaker) nor their absence
    elsewhere (a shadow edge across the ring adds edges, it removes none), which a
    grey-level self-correlation does: that is what makes it robust to uneven light.

    Args:
        profiles: (..., 36) ring samples, NaN where the ring leaves the image.

    Returns:
        :class:`SectorOrder` over the leading axes.
    """
    missing = np.isnan(profiles).any(axis=-1)
    f = _circular_smooth(np.where(np.isnan(profiles), 0.0, profiles))
    slope = 0.5 * (f[..., _NEXT] - f[..., _PREVIOUS])
    opposite = slope[..., _OPPOSITE]
    # Antipodal within one sample (10 degrees) either way.
    opposite_high = np.maximum(opposite, np.maximum(opposite[..., _NEXT], opposite[..., _PREVIOUS]))
    opposite_low = np.minimum(opposite, np.minimum(opposite[..., _NEXT], opposite[..., _PREVIOUS]))
    rising = np.minimum(slope, opposite_high)[..., :_HALF_TURN]
    falling = np.minimum(-slope, -opposite_low)[..., :_HALF_TURN]
    strength = np.minimum(rising.max(axis=-1), falling.max(axis=-1))
    return SectorOrder(
        np.where(missing, -1.0, strength), rising.argmax(axis=-1), falling.argmax(axis=-1)
    )


def ring_edge_noise(noise_std: NDArray[np.float64] | float) -> NDArray[np.float64] | float:
    """Std of :func:`sector_order`'s slope for ring samples of noise std ``noise_std``.

    The slope (f[k+2] + 2 f[k+1] - 2 f[k-1] - f[k-2]) / 8 of the [1, 2, 1]-smoothed
    profile has std sqrt(10) / 8 of the samples' when they are independent.
    """
    return cast("NDArray[np.float64] | float", np.sqrt(10.0) / 8.0 * noise_std)


def prescreen_sector_order(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    radii_px: NDArray[np.float64],
    min_strength: NDArray[np.float64],
    max_angle_drift: int = 2,
) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """Cascaded sector-order test on nearest-pixel rings, for many candidates.

    A candidate passes when every ring (of its own radii) shows the X's edge pairs
    stronger than ``min_strength`` at directions that agree from ring to ring
    within ``max_angle_drift`` samples (the lines through the centre are straight),
    and its two dark sectors agree (:func:`dark_paint_agrees`); rings are read one
    radius at a time, only for the candidates still alive.

    Args:
        image: (H, W) grey image, native dtype.
        xy: (N, 2) candidates.
        radii_px: (N, J) each candidate's ring radii.
        min_strength: (N,) smallest edge strength (image units per 10 degrees).
        max_angle_drift: largest change of an edge pair's direction between rings,
            in samples of 10 degrees.

    Returns:
        (passed, line_angles): (N,) bool, and (N, 2) the directions (radians) of the
        rising and the falling edge pair on the first ring: the two lines.
    """
    n = len(xy)
    alive = np.arange(n)
    first: SectorOrder | None = None
    for j in range(radii_px.shape[1]):
        ring = _nearest_ring(image, xy[alive], radii_px[alive, j]).astype(np.float64)
        order = sector_order(ring)
        keep = (order.strength >= min_strength[alive]) & dark_paint_agrees(ring, order)
        if first is None:
            first = order
            first_rising, first_falling = order.rising, order.falling
        else:
            keep &= (_index_gap(order.rising, first_rising) <= max_angle_drift) & (
                _index_gap(order.falling, first_falling) <= max_angle_drift
            )
        alive, first_rising, first_falling = alive[keep], first_rising[keep], first_falling[keep]
    passed = np.zeros(n, dtype=bool)
    passed[alive] = True
    angles: NDArray[np.float64] = np.zeros((n, 2))
    if first is not None:
        angles = np.stack([first.rising, first.falling], axis=1) * (2.0 * np.pi / N_ANGLES)
    return passed, angles


#: The two dark sectors of a ring may differ by at most this share of its contrast:
#: black paint stays black (a dull, worn or wet quadrant is a bright one; a shadow
#: darkens black paint by a fraction of little), while the dark gaps between stones
#: or leaves differ as much as the stones do.
_DARK_PAIR_TOLERANCE = 0.3
#: The duller bright sector must stand above the darker pair by at least this share
#: of the ring's contrast: a bright quadrant 0.45 as bright as the other does, in a
#: shadow too.
_BRIGHT_MARGIN = 0.05


def dark_paint_agrees(profiles: NDArray[np.float64], order: SectorOrder) -> NDArray[np.float64]:
    """(N,) whether a ring's two dark sectors match and both bright ones stand above them.

    The sectors lie between the edges :func:`sector_order` found (rising at k and
    k + 18, falling at the other pair); each sector's level is the mean of its
    samples. Of the two pairs of opposite sectors the darker pair is the dark paint.

    Args:
        profiles: (N, 36) ring samples.
        order: their sector order.

    Returns:
        (N,) bool.
    """
    edges = np.sort(
        np.stack(
            [order.rising, order.falling, order.rising + _HALF_TURN, order.falling + _HALF_TURN],
            axis=1,
        )
        % N_ANGLES,
        axis=1,
    )
    # Sector s runs from edge s to edge s + 1 (the samples before the first edge close
    # the last sector round the ring).
    sector = (np.arange(N_ANGLES)[None, :, None] >= edges[:, None, :]).sum(axis=2) % 4
    members = sector[..., None] == np.arange(4)  # (N, 36, 4)
    count = members.sum(axis=1)
    level = np.einsum("nk,nks->ns", np.nan_to_num(profiles), members) / np.maximum(count, 1)
    first, second = level[:, [0, 2]], level[:, [1, 3]]
    first_dark = first.mean(axis=1) < second.mean(axis=1)
    dark = np.where(first_dark[:, None], first, second)
    bright = np.where(first_dark[:, None], second, first)
    contrast = bright.max(axis=1) - dark.mean(axis=1)
    return cast(
        "NDArray[np.float64]",
        (np.abs(dark[:, 0] - dark[:, 1]) <= _DARK_PAIR_TOLERANCE * contrast)
        & (bright.min(axis=1) - dark.max(axis=1) >= _BRIGHT_MARGIN * contrast)
        & (count > 0).all(axis=1),
    )


def _index_gap(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance of two half-turn sample indices (0-17), modulo a half turn."""
    gap = np.abs(a - b) % _HALF_TURN
    return cast("NDArray[np.float64]", np.minimum(gap, _HALF_TURN - gap))


def reaches_extent(
    radius_px: NDArray[np.float64], min_extent_fraction: float, min_radius_px: float
) -> NDArray[np.bool_]:
    """(N,) True where the X extends to ``min_extent_fraction`` of the smallest marker radius.

    Small texture saddles stop short; a marker tilted by 60 degrees still reaches
    0.7 of its radius.

    Args:
        radius_px: (N,) extents of the X found by the annular scan, px.
        min_extent_fraction: the share of ``min_radius_px`` the X must reach.
        min_radius_px: the smallest expected marker radius, px.
    """
    return radius_px >= min_extent_fraction * min_radius_px - _EXTENT_SLACK_PX


def template_radius(radius_px: NDArray[np.float64], max_radius_px: float) -> NDArray[np.float64]:
    """(N,) radius of the disk over which the adaptive template's NCC is read, px.

    :data:`TEMPLATE_RADIUS_FRACTION` of the X's extent, at least
    :data:`TEMPLATE_MIN_RADIUS_PX` and at most the largest expected marker radius.
    """
    return np.clip(TEMPLATE_RADIUS_FRACTION * radius_px, TEMPLATE_MIN_RADIUS_PX, max_radius_px)


def agreed_line_angles(
    line_angles: NDArray[np.float64], ring_angles: NDArray[np.float64]
) -> NDArray[np.float64]:
    """(N, 2) the LSD pair's line directions where they agree with the rings', else the rings'.

    The LSD pair's angles are the more precise (Eq. 9's straight lines), but the pair
    crossing nearest the centre is at times a plate edge (up to 53 degrees off on
    family (a)): the rings' angles stand then.

    Args:
        line_angles: (N, 2) directions of the LSD pair, radians.
        ring_angles: (N, 2) directions from the annular scan, radians.
    """
    agree = line_pair_difference(line_angles, ring_angles) <= LINE_ANGLE_AGREEMENT_RAD
    return np.where(agree[:, None], line_angles, ring_angles)


def modulation_gate(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    offset_px: NDArray[np.float64],
    min_radius_px: float,
    min_modulation: float,
) -> NDArray[np.bool_]:
    """(N,) True where the sectors' raw grey levels modulate enough, or say nothing.

    The modulation (bright - dark) / (bright + dark) of the sector pairs' grey levels
    (:func:`template.sample_grey_levels`, 3x3 windows on the bisectors ``offset_px``
    from the centre) does not change with illumination: printed black and white keep
    it high, ground-texture saddles (gravel gaps) low. Levels closer than
    :data:`MODULATION_MIN_OFFSET_PX` to the centre are mixed by the blur, so the
    levels of markers with an extent under ~4 px say little about their paint: they
    are tested only when they also fall short of the expected radius, as texture
    saddles do (a small marker in a frame of small markers is not suspect). X's
    wider than texture's rings reach even equalised (:data:`EQUALISED_MIN_EXTENT_PX`)
    are not tested: dim real boards (black level, haze) modulate as little as
    markers of the lowest contrast the renderers draw, under the gate; tested up to
    :data:`TEXTURE_EXTENT_PX` instead, the gate loses markers and keeps out no
    false point more (docs/accuracy-journal.md, "What the geometric checks' constants rest
    on").

    Args:
        image: (H, W) grey image, raw levels.
        xy: (N, 2) centres.
        line_angles: (N, 2) line directions, radians.
        radius_px: (N,) extents of the X, px.
        offset_px: (N,) distance of the level windows from the centre, px.
        min_radius_px: the smallest expected marker radius, px.
        min_modulation: the lowest modulation of a measurable marker.
    """
    levels = template.sample_grey_levels(image, xy, line_angles, offset_px)
    bright = np.maximum(levels.positive, levels.negative)
    dark = np.minimum(levels.positive, levels.negative)
    modulation = (bright - dark) / np.maximum(bright + dark, 1e-12)
    measurable = (
        (offset_px >= MODULATION_MIN_OFFSET_PX)
        & ((radius_px < min_radius_px) | (offset_px >= MODULATION_FREE_OFFSET_PX))
        & (radius_px < EQUALISED_MIN_EXTENT_PX)
    )
    return cast("NDArray[np.bool_]", ~measurable | (modulation >= min_modulation))


#: Rings beyond an X's measured extent, in extents, where a marker's X has ended:
#: its quadrants stop at its radius, on its plate or on the ground. Ground
#: texture's saddles measured as small X's go on beyond (stones, their gaps).
X_END_RINGS = (1.5, 1.75, 2.0)
#: ... against the ring at this share of the extent, inside the X.
X_END_INSIDE = 0.6
#: Largest modulation of the X's sectors on :data:`X_END_RINGS` over that inside it
#: (:func:`modulation_beyond_extent`) of an X that has ended: over nearly every tiny
#: marker's, under half of real marker-free ground's texture saddles'.
MAX_MODULATION_BEYOND = 0.5
#: An X that has clearly ended, at most this (:func:`modulation_beyond_extent`), may
#: score up to :data:`ENDED_SCORE_ALLOWANCE` under its floor: most tiny markers end
#: this clearly, few of ground texture's saddles.
CLEARLY_ENDED = 0.15
#: ... how far under, set on the benchmark's (b) frames and real aerial ground, whose
#: false points it leaves as they were (measured: docs/method.md, "A small X must end
#: where its extent does").
ENDED_SCORE_ALLOWANCE = 0.02
#: X's measured under this extent, px, are asked to end (:func:`x_must_end`): the
#: texture saddles of real ground that reach the score floors are no wider. Wider X's
#: are not asked: a dull quadrant or a tilt of 60 degrees leaves a marker's rings at
#: half its radius, its X going on beyond them.
X_END_MAX_EXTENT_PX = 4.5
#: Samples on each of those rings: 5 degrees apart.
_X_END_SAMPLES = 72


def x_must_end(radius_px: NDArray[np.float64], min_radius_px: float) -> NDArray[np.bool_]:
    """(N,) True for X's of ground texture's saddles' size, measured whole.

    Under :data:`X_END_MAX_EXTENT_PX`, and not under the smallest expected radius:
    an X measured smaller than any expected marker is a larger one seen
    foreshortened (its rings stop at the minor axis while its lines go on), whose
    X does not end where its rings do; so a tighter, correct radius range asks
    this of fewer X's, never of more.
    """
    return (radius_px < X_END_MAX_EXTENT_PX) & (radius_px >= min_radius_px)


def x_ends(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    min_radius_px: float,
    max_radius_px: float,
    under_floor: NDArray[np.bool_],
) -> NDArray[np.bool_]:
    """(N,) False for X's :func:`x_must_end` asks whose sector pattern does not end.

    An X whose modulation beyond its extent (:func:`modulation_beyond_extent`)
    exceeds :data:`MAX_MODULATION_BEYOND` is ground texture's saddle, not a
    marker; one ``under_floor`` (scoring under its floor by up to
    :data:`ENDED_SCORE_ALLOWANCE`) passes only where its X has clearly ended
    (:data:`CLEARLY_ENDED`). X's not asked pass where they are not under the floor.

    The rings read an extent up to a rung (:data:`RING_STEP`) short of the X's
    reach, more in clutter or under a tilt, so an X that goes on at its extent is
    read once more a rung out, where that reach is wider than texture's saddles
    (:data:`X_END_MAX_EXTENT_PX`) and a marker could reach that far
    (``max_radius_px``). Measured: docs/accuracy-journal.md, "An X whose rings stop short
    of its reach" and "Figures the fit's and the detector's docstrings carried".

    Args:
        image: (H, W) grey image, raw levels.
        xy: (N, 2) centres.
        radius_px: (N,) extents of the X, px.
        line_angles: (N, 2) line directions, radians.
        min_radius_px: the smallest expected marker radius, px.
        max_radius_px: the largest, px.
        under_floor: (N,) which score under their floor.
    """
    ended = ~under_floor
    limit = np.where(under_floor, CLEARLY_ENDED, MAX_MODULATION_BEYOND)
    asked = np.flatnonzero(x_must_end(radius_px, min_radius_px))
    for reach in (1.0, RING_STEP):
        if not len(asked):
            break
        beyond = modulation_beyond_extent(
            image, xy[asked], reach * radius_px[asked], line_angles[asked]
        )
        ended[asked] = beyond <= limit[asked]
        going_on = asked[~ended[asked]]
        asked = going_on[reaches_a_rung_out(radius_px[going_on], max_radius_px)]
    return ended


def reaches_a_rung_out(radius_px: NDArray[np.float64], max_radius_px: float) -> NDArray[np.bool_]:
    """(N,) where an X read at ``radius_px`` may be a marker that reaches a rung further.

    That reach (:data:`RING_STEP` times the extent) is wider than texture's saddles
    (:data:`X_END_MAX_EXTENT_PX`) and within ``max_radius_px``.
    """
    further = RING_STEP * radius_px
    return (further >= X_END_MAX_EXTENT_PX) & (further <= max_radius_px)


def modulation_beyond_extent(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    line_angles: NDArray[np.float64],
) -> NDArray[np.float64]:
    """(N,) how much of an X's sector pattern goes on beyond its measured extent.

    On each ring, the mean raw grey level of one opposite pair of the four sectors
    the lines make less that of the other pair is the X's modulation there; on
    :data:`X_END_RINGS` it is averaged and divided by that on the ring
    :data:`X_END_INSIDE` of the extent out, inside the X. A marker's X ends at its
    radius: its plate or the ground beyond take no sign from its lines (rendered
    tiny markers: 0.12, median). A texture saddle's goes on (real aerial
    ground's: 0.54; the false points on rendered tiny markers' frames: 0.85). Raw
    levels serve: a smooth light scales both rings alike.

    Args:
        image: (H, W) grey image, raw levels.
        xy: (N, 2) centres.
        radius_px: (N,) extents of the X, px.
        line_angles: (N, 2) line directions, radians.
    """
    modulation = np.abs(
        _sector_modulation(image, xy, radius_px, line_angles, (X_END_INSIDE, *X_END_RINGS))
    )
    return cast(
        "NDArray[np.float64]",
        modulation[:, 1:].mean(axis=1) / np.maximum(modulation[:, 0], 1e-12),
    )


def _sector_modulation(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    factors: tuple[float, ...],
) -> NDArray[np.float64]:
    """(N, F) one opposite pair of the X's sectors less the other on rings at ``factors`` extents.

    Mean raw grey levels on each ring: lines not at right angles give the pairs
    unequal arcs, so a signed mean over the ring would carry its mean level.
    """
    theta = np.linspace(0.0, 2.0 * np.pi, _X_END_SAMPLES, endpoint=False)
    sign = template.sector_sign(np.cos(theta)[None], np.sin(theta)[None], line_angles)
    rho = radius_px[:, None, None] * np.asarray(factors)[None, :, None]
    levels, valid = bilinear(
        image,
        xy[:, 0, None, None] + rho * np.cos(theta),
        xy[:, 1, None, None] + rho * np.sin(theta),
    )
    pair_means = [
        (levels * weight).sum(axis=2) / np.maximum(weight.sum(axis=2), 1.0)
        for weight in (valid & (sign[:, None, :] > 0), valid & (sign[:, None, :] < 0))
    ]
    return cast("NDArray[np.float64]", pair_means[0] - pair_means[1])


#: Offsets from an X, in extents, where :func:`disk_recurrence` seeks copies of its
#: disk: from where a copy no longer overlaps the X's own disk (a lone X on flat
#: grey reads 0.05 from 2, 0.45 from 1.2) out to a lattice's third period when its
#: discs are an extent or two across.
RECURRENCE_REACH = (2.0, 3.2)
#: Radius of the disk :func:`disk_recurrence` correlates, px: a wider X's
#: neighbourhood is area-reduced to it (its copies lie as many extents away), so
#: each X costs about the same; 8 px holds some 300 pixels, enough for an NCC.
_RECURRENCE_RADIUS_PX = 8.0


def disk_recurrence(
    image: NDArray[Any], xy: NDArray[np.float64], radius_px: NDArray[np.float64]
) -> NDArray[np.float64]:
    """(N,) how well each X's disk recurs on both sides of it: a lattice's period.

    The NCC of the square of the X's extent about its centre with the image at
    each offset :data:`RECURRENCE_REACH` extents away; at each offset the lower of
    it and the NCC at the opposite offset (to a pixel), and the highest of those.
    A lattice repeats its saddles in opposite pairs along its rows, and a
    marker's ground does not repeat its X. Offsets whose copy leaves the image
    are not read; 0 where none is left.

    By the frame's border most offsets' opposite copies are cut off, and a
    lattice's saddle read on the few offsets left (along the border) passes for a
    marker. Where an offset's opposite copy is cut off, the copy one period
    further on the side in view (at twice the offset, to a pixel) stands in for
    it: two copies in a row, as two opposite ones are. One copy alone is what a
    marker's ground makes by chance (docs/accuracy-journal.md, "A lattice cut by the
    frame's border").

    Args:
        image: (H, W) grey image, raw levels.
        xy: (N, 2) centres.
        radius_px: (N,) extents of the X's, px.
    """
    height, width = image.shape[:2]
    recurrence = np.zeros(len(xy))
    far = RECURRENCE_REACH[1]
    for k, ((x, y), radius) in enumerate(zip(xy, radius_px, strict=True)):
        shrink = min(1.0, _RECURRENCE_RADIUS_PX / radius)
        extent = float(radius * shrink)
        column, row = round(x * shrink), round(y * shrink)
        reach = round((far + 1.0) * extent)
        low, end = _recurrence_window((column, row), reach, shrink)
        cut = min(low) < 0 or end[0] > width or end[1] > height
        if cut:
            reach = round((2.0 * far + 1.0) * extent)
        read = _recurrence_map(image, (column, row), reach, max(1, round(extent)), shrink)
        if read is None:
            continue
        ncc, inside = read
        span = ncc.shape[0] // 2
        rows, columns, here, opposite = _recurrence_offsets(span, extent)
        # A copy's partner may lie a pixel off where it is expected: a lattice is warped.
        # (Where no partner was read the map holds -1, and so does its dilation.)
        partner = cv2.dilate(ncc, _OPPOSITE_SLACK)
        pairs = partner[opposite]
        if cut:
            partner_read = cv2.dilate(inside, _OPPOSITE_SLACK) > 0
            # Offsets whose double lies off the map have no copy one period further.
            on_map = 2 * np.maximum(np.abs(rows), np.abs(columns)) <= span
            twice = (
                np.where(on_map, span + 2 * rows, span),
                np.where(on_map, span + 2 * columns, span),
            )
            further = np.where(on_map, partner[twice], -1.0)
            pairs = np.where(partner_read[opposite], pairs, further)
        copies = np.minimum(ncc[here], pairs)
        recurrence[k] = max(float(copies.max(initial=0.0)), 0.0)
    return recurrence


def _recurrence_window(
    centre: tuple[int, int], reach: int, shrink: float
) -> tuple[tuple[int, int], tuple[int, int]]:
    """Where :func:`_recurrence_map` reads, before the image's border cuts it.

    ``centre`` and ``reach`` in the area-reduced image's pixels. Returns the
    window's first column and row there, and its end (exclusive) in the image's own
    pixels.
    """
    column, row = centre
    # In Python's floats, a few per X: numpy's calls cost more than the arithmetic.
    end = (math.ceil((column + reach + 1) / shrink), math.ceil((row + reach + 1) / shrink))
    return (column - reach, row - reach), end


def _recurrence_map(
    image: NDArray[Any], centre: tuple[int, int], reach: int, disk: int, shrink: float
) -> tuple[NDArray[np.float32], NDArray[np.uint8]] | None:
    """The NCC of an X's disk about it, on a square map centred on it, and where it was read.

    ``centre``, ``reach`` and ``disk`` are in the area-reduced image's pixels
    (``shrink`` of the image's): the map's offsets go out to ``reach`` less ``disk``
    either way, as far as the image goes, -1 (and not read) beyond it. None where
    the X's own disk leaves the image.
    """
    height, width = image.shape[:2]
    column, row = centre
    # The neighbourhood area-reduced about the X's centre, as far as the image goes.
    unclipped, end = _recurrence_window(centre, reach, shrink)
    low = (max(0, unclipped[0]), max(0, unclipped[1]))
    corner = (math.floor(low[0] / shrink), math.floor(low[1] / shrink))
    crop = image[corner[1] : min(end[1], height), corner[0] : min(end[0], width)]
    window: NDArray[Any] = crop.astype(np.float32)
    if shrink < 1.0:
        size = (round(crop.shape[1] * shrink), round(crop.shape[0] * shrink))
        window = cv2.resize(window, size, interpolation=cv2.INTER_AREA)
    inner = (column - low[0], row - low[1])
    if not (
        disk <= inner[0] < window.shape[1] - disk and disk <= inner[1] < window.shape[0] - disk
    ):
        return None
    patch = window[inner[1] - disk : inner[1] + disk + 1, inner[0] - disk : inner[0] + disk + 1]
    ncc = cv2.matchTemplate(window, patch, cv2.TM_CCOEFF_NORMED)
    # Not finite only where the window is not (the check's one pass costs less than
    # nan_to_num's three).
    if not np.isfinite(ncc).all():
        ncc = np.nan_to_num(ncc, copy=False, nan=-1.0)
    # On a square about the X's own position, so that an offset's opposite is its
    # mirror through the centre.
    span = reach - disk
    full = np.full((2 * span + 1, 2 * span + 1), -1.0, np.float32)
    inside = np.zeros(full.shape, np.uint8)
    top, left = span - (inner[1] - disk), span - (inner[0] - disk)
    rows, columns = (
        min(ncc.shape[0], full.shape[0] - top),
        min(ncc.shape[1], full.shape[1] - left),
    )
    full[top : top + rows, left : left + columns] = ncc[:rows, :columns]
    inside[top : top + rows, left : left + columns] = 1
    return full, inside


#: The opposite offset's reach, a pixel either way: a lattice is warped.
_OPPOSITE_SLACK = np.ones((3, 3), np.uint8)


class _RecurrenceOffsets(NamedTuple):
    """A (2 span + 1)^2 map's offsets :data:`RECURRENCE_REACH` extents out.

    ``rows`` and ``columns`` (M,) from the map's centre; ``here`` and ``opposite`` the
    map's indices of each offset and of its mirror through the centre.
    """

    rows: NDArray[np.intp]
    columns: NDArray[np.intp]
    here: tuple[NDArray[np.intp], NDArray[np.intp]]
    opposite: tuple[NDArray[np.intp], NDArray[np.intp]]


@functools.lru_cache(maxsize=256)
def _recurrence_offsets(span: int, extent: float) -> _RecurrenceOffsets:
    """:class:`_RecurrenceOffsets` of a map of ``span``, for an X of ``extent``, px."""
    offset = np.hypot(*(np.mgrid[: 2 * span + 1, : 2 * span + 1] - span)) / extent
    near, far = RECURRENCE_REACH
    ring_rows, ring_columns = np.nonzero((offset >= near) & (offset <= far))
    here = (ring_rows, ring_columns)
    rows, columns = ring_rows - span, ring_columns - span
    offsets = _RecurrenceOffsets(rows, columns, here, (span - rows, span - columns))
    # Shared by every caller through the cache (and every thread): read-only.
    for index in (rows, columns, *here, *offsets.opposite):
        index.flags.writeable = False
    return offsets


#: Reach along each of an X's four half-lines, beyond its extent, where
#: :func:`line_continuation` reads the step across it, in extents.
CONTINUATION_REACH = (1.1, 1.9)
#: Places along each half-line over :data:`CONTINUATION_REACH` where the step across it
#: is read: every tenth of the extent.
_CONTINUATION_SAMPLES = 9
#: Distance of the two samples either side of the line, px: clear of a blurred
#: edge's middle, within a pixel or two of the line a small angle error moves ...
_CONTINUATION_SIDE_PX = 1.5
#: ... and, further out, within the angle a measured line's direction may be off (the
#: median is under a degree) or a bent board's edge bends away from it: beyond 29
#: px along the line the samples lie this angle either side of it.
_CONTINUATION_SIDE_ANGLE_RAD = np.deg2rad(3.0)
#: Half-lines of a chessboard's corner that go on as edges, at least: all four
#: inside the board, three on its outer rows, two at its outermost inner corners. A
#: lattice's saddle may have one, along a row of discs (docs/accuracy-journal.md, "A board's
#: corner goes on along two half-lines").
CONTINUING_HALF_LINES = 2


def line_continuation(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    line_angles: NDArray[np.float64],
) -> NDArray[np.float64]:
    """(N,) how far an X's lines go on as edges beyond its extent: a chessboard's do.

    On each of the four half-lines, the median absolute step across it at
    :data:`CONTINUATION_REACH` extents, over the X's modulation inside
    (:data:`X_END_INSIDE`); the second largest of the four
    (:data:`CONTINUING_HALF_LINES`). A chessboard's corners are joined by straight
    edges; a marker's lines end on its plate, and the outlines of a lattice's discs
    bend away from the lines their saddles show.

    Args:
        image: (H, W) grey image, raw levels.
        xy: (N, 2) centres.
        radius_px: (N,) extents of the X's, px.
        line_angles: (N, 2) line directions, radians.
    """
    inside = np.abs(_sector_modulation(image, xy, radius_px, line_angles, (X_END_INSIDE,))[:, 0])
    directions = np.concatenate([line_angles, line_angles + np.pi], axis=1)[:, :, None]
    along = np.cos(directions), np.sin(directions)
    rho = (
        radius_px[:, None, None]
        * np.linspace(*CONTINUATION_REACH, _CONTINUATION_SAMPLES)[None, None, :]
    )
    x, y = xy[:, 0, None, None] + rho * along[0], xy[:, 1, None, None] + rho * along[1]
    side = np.maximum(_CONTINUATION_SIDE_PX, np.tan(_CONTINUATION_SIDE_ANGLE_RAD) * rho)
    side_x, side_y = -side * along[1], side * along[0]
    left, _ = bilinear(image, x + side_x, y + side_y)
    right, _ = bilinear(image, x - side_x, y - side_y)
    steps = np.sort(np.median(np.abs(left - right), axis=2), axis=1)
    step = steps[:, -CONTINUING_HALF_LINES]
    return cast("NDArray[np.float64]", step / np.maximum(inside, 1e-12))


def texture_score_floor(radius_px: NDArray[np.float64], min_score: float) -> NDArray[np.float64]:
    """(N,) the lowest score of a detection of each extent, by ground texture's saddles.

    ``min_score``, raised below :data:`TEXTURE_EXTENT_PX` to the floor of
    :data:`TEXTURE_SCORE_FLOORS` for its extent.

    Args:
        radius_px: (N,) extents of the X, px.
        min_score: the configured lowest score of a marker wider than texture's saddles.
    """
    threshold = np.full(len(radius_px), min_score)
    for extent, floor in reversed(TEXTURE_SCORE_FLOORS):
        threshold[radius_px < extent] = max(min_score, floor)
    return threshold


def small_marker(radius_px: NDArray[np.float64], min_radius_px: float) -> NDArray[np.bool_]:
    """(N,) True for X's no larger than the smallest expected marker, and texture-sized.

    Such detections are in the regime of ground texture's saddles (stones meeting),
    and need ``min_score_small`` (:func:`minimum_score`). Texture's size bounds the
    rule, so from a smallest radius of :data:`SMALL_EXTENT_MAX_RADIUS_PX` on a larger
    ``min_radius_px`` asks no more of the same marker; under it the rule moves with
    the range (read at 4-40 px as 3.2-50 reads it, it changes none of the markers
    (d)'s seeds 0-23 find: docs/accuracy-journal.md, "Item 5 on every family").

    Args:
        radius_px: (N,) extents of the X, px.
        min_radius_px: the smallest expected marker radius, px.
    """
    return radius_px < SMALL_EXTENT_FACTOR * min(min_radius_px, SMALL_EXTENT_MAX_RADIUS_PX)


def minimum_score(
    radius_px: NDArray[np.float64], min_score: float, min_score_small: float, min_radius_px: float
) -> NDArray[np.float64]:
    """(N,) the score a detection of each extent needs to be accepted.

    ``min_score_small`` for a :func:`small_marker`, else its
    :func:`texture_score_floor`.
    """
    return np.where(
        small_marker(radius_px, min_radius_px),
        min_score_small,
        texture_score_floor(radius_px, min_score),
    )


def prescreen_ring_radii(
    scale_px: NDArray[np.float64], min_radius_px: float
) -> NDArray[np.float64]:
    """(N, 3) the prescreen's ring radii around candidates of each scale, px.

    :data:`PRESCREEN_RINGS` times the scale, at least :data:`PRESCREEN_MIN_RING_PX`
    or :data:`PRESCREEN_MIN_RING_FRACTION` of the smallest expected radius,
    whichever is less; and no ring smaller than the smallest one of the scale of
    the level that found the candidate (:func:`screening.level_scale`).

    That last floor is :data:`PRESCREEN_MIN_RING_PX`'s reason at a coarser level:
    a candidate lies as far off a marker's centre as its level's pixels allow,
    however small the range made its scale. From a smallest radius of 6 px the
    half-resolution level's candidates are given 6 px, not 8: the inner ring of
    :data:`PRESCREEN_RINGS` at 6 px (2.1 px) failed on strong tilted markers whose
    candidate lay up to 0.9 px off, where the one at the level's own 8 px (2.8 px)
    shows their X (docs/accuracy-journal.md, "The prescreen's rings at the level's own
    scale").

    Args:
        scale_px: (N,) the candidates' scales, px.
        min_radius_px: the smallest expected marker radius, px.
    """
    floor_px = min(PRESCREEN_MIN_RING_PX, PRESCREEN_MIN_RING_FRACTION * min_radius_px)
    rings = np.array(PRESCREEN_RINGS)
    radii = np.maximum(scale_px[:, None] * rings, floor_px)
    return cast(
        "NDArray[np.float64]",
        np.maximum(radii, rings.min() * level_scale(scale_px)[:, None]),
    )


def prescreen_line_directions(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    scale_px: NDArray[np.float64],
    min_radius_px: float,
) -> NDArray[np.float64]:
    """(N, 2) the directions of the edge pairs on each point's first prescreen ring, radians.

    What :func:`prescreen_sector_order` reads on the innermost of
    :func:`prescreen_ring_radii`, with no test of their strength: the line
    directions of a point no ring test has passed (a tracked seed, a candidate
    read again with a shadow's edge).
    """
    radii = prescreen_ring_radii(scale_px, min_radius_px)[:, :1]
    _, angles = prescreen_sector_order(image, xy, radii, np.full(len(xy), -np.inf))
    return angles


def prescreen_symmetry(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    radii_px: NDArray[np.float64],
    min_contrast: float | NDArray[np.float64],
    equalise: bool = False,
    first_ring: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """(N,) True where all :data:`PRESCREEN_GOOD_RINGS` rings show the X; the first rings read.

    A three-ring centre-symmetry test before any fit, lenient per ring
    (:data:`PRESCREEN_SYMMETRY`; raw grey levels) but strict over the rings
    (:func:`count_symmetric_rings`).

    Args:
        image: (H, W) grey image, raw levels.
        xy: (N, 2) candidate positions.
        radii_px: (N, 3) ring radii (:func:`prescreen_ring_radii`), px.
        min_contrast: smallest bright-minus-dark level of a good ring, raw grey levels;
            or (N,) one per candidate.
        equalise: read each ring after :func:`equalise_bright_sectors`.
        first_ring: (N, 36) the samples of each point's first ring that a previous
            call returned for the same points and radii, reused instead of read
            again; None reads them.

    Returns:
        (passed, first_ring): (N,) bool, and the (N, 36) first-ring samples.
    """
    count = count_symmetric_rings(
        image,
        xy,
        radii_px,
        min_contrast=min_contrast,
        min_symmetry=PRESCREEN_SYMMETRY,
        min_good=PRESCREEN_GOOD_RINGS,
        equalise=equalise,
        first_ring=first_ring,
    )
    return count.good >= PRESCREEN_GOOD_RINGS, count.first_ring
