"""A cast shadow's straight edge across a marker: found, then divided out.

A marker half in a shadow (a mast, a wing, a building's edge) is no longer
point-symmetric in its grey levels, and the default's checks, all of grey-level
symmetry, lose it. Its geometry stands, and so does the shadow's: the light it
takes away multiplies the raw levels (a camera's gamma keeps a product a
product), so in their logarithm the point pairs (c + d, c - d) the edge parts
differ by its depth and the others not at all, whatever the X's own levels.
That is the evidence :func:`find_edges` reads, on the quadrants' insides where
the X's own edges are not; :func:`divided_out` then gives the checks the frame
with the shadow taken back out of it. The division must be close: a pixel or a few
degrees off, it loses much of what an exact one gives back (measured:
docs/accuracy-journal.md, "Evidence measured and not taken").
"""

from __future__ import annotations

from typing import Any, NamedTuple, cast

import numpy as np
from numpy.typing import NDArray
from scipy.special import ndtr

from marker_localizer.core.sampling import bilinear
from marker_localizer.core.template import line_distances

#: The pairs read: rings from this share of the reach to the reach ...
_INNERMOST_RING = 0.12
_RINGS = 8
#: ... each of this many pairs over a half turn (a pair holds both ends).
_PAIRS_PER_RING = 32
#: Pairs this close to either of the X's lines are left out, px: there the X's own
#: blurred edges part the pair, a centre a pixel off included. (The line fit's slope
#: prior, :data:`subpixel.INSIDE_LINE_DISTANCE_PX`, keeps 3 px: its pairs must hold
#: no edge at all, these only no edge the quadrants' levels cannot take.)
_CLEAR_OF_LINES_PX = 2.0
#: The edge's directions tried first (normals over a half turn; the depth's sign
#: says which side is in shadow) ...
_COARSE_DIRECTIONS = 36
#: ... and its distances from the candidate, in reaches, 0 to this in steps of
#: :data:`_COARSE_OFFSET_STEP` (the renderer draws edges within 0.6 of a marker's
#: foreshortened radius of its centre, and the reach is about twice a marker's scale).
_MAX_OFFSET = 0.8
_COARSE_OFFSET_STEP = 0.05
#: Gauss-Newton iterations that refine the best coarse edge (direction, distance
#: and depth with the quadrants' levels): 1-2 px and 5 degrees to a few tenths and
#: a degree or two on the renderer's shadowed markers.
_REFINE_ITERATIONS = 4
#: The blur of the edge as the fit models it, px: a sharp cast shadow's penumbra
#: (the renderer's 1 px 10-90 % width, sigma 0.4) seen through optics of 0.5-1.5 px
#: gives 0.6-1.6; the fit takes the low middle (not tuned).
EDGE_BLUR_PX = 0.8
#: The log step across each candidate line is read this far to either side of
#: it, px: beyond the edge's blur.
_STEP_READ_PX = 1.5
#: ... at this many points along it, within the reach.
_STEP_SAMPLES = 41
#: Least share of the pairs' variance, the quadrants' own levels taken out, that
#: the edge must explain: under what a shadowed marker's edge explains; texture's
#: asymmetry often fits a half-plane about as well, hence the depth and the step
#: after this one.
MIN_EXPLAINED = 0.5
#: Deepest shadow the fit allows, log of the raw levels: 95 % of the light taken, a
#: marker's white under it as dark as its black in the open.
_MAX_DEPTH = 3.0
#: Least depth of the shadow, in the log of the raw levels: a shadow taking a
#: quarter of the light (the renderer's take 40-65 %, 0.4-1.3 after gamma).
MIN_DEPTH = 0.3
#: The raw levels must step by the fitted depth across the edge found, within
#: this share of it: a shadow's edge is a straight step in the image itself,
#: where a half-plane fitted to texture's pairs is not.
STEP_TOLERANCE = 0.5
#: A candidate's edge is refined where the best sharp edge already explains this share
#: of :data:`MIN_EXPLAINED` with this share of :data:`MIN_DEPTH`: the refinement
#: costs most of the time, and most texture candidates show no edge at all.
_PROMISING = 0.8
#: The log reads levels of at least this share of white: one 8-bit grey level,
#: under which a level is its quantisation.
_DARKEST_SHARE = 1.0 / 255.0
#: Fewest pairs on the insides for a fit of five parameters to mean anything.
_MIN_PAIRS = 20


#: A detection's shadow edge is looked for within this many extents of its centre
#: (:func:`find_edges`' reach): the renderers' edges cross within 0.6 foreshortened
#: radii of the centre, and the disk holds the plate on both sides of them.
DETECTION_REACH_EXTENTS = 1.5
#: A located X's model tries the edge :func:`find_edges` fits best within this many
#: of its extents (the line fit's reach, ``subpixel._reach_all_round``): the ground
#: beyond the plate bends the fit of the edge in the pairs, and the model, which
#: reads the X alone, is what decides (measured: docs/accuracy-journal.md, "Figures the fit's
#: and the detector's docstrings carried").
HYPOTHESIS_REACH_EXTENTS = 1.0


class ShadowEdges(NamedTuple):
    """Where :func:`find_edges` puts a shadow's edge across N candidates.

    The shadow covers ``cos(normal) (x - x0) + sin(normal) (y - y0) > offset`` about
    each candidate (x0, y0), where the raw levels are ``exp(-depth)`` of the light's.

    Attributes:
        normal: (N,) direction from the edge into the shadow, radians.
        offset: (N,) signed distance of the edge from the candidate, px.
        depth: (N,) the shadow's depth, log of the raw levels (>= 0).
        explained: (N,) share of the pairs' variance (the quadrants' own levels
            taken out) that the edge explains.
        step: (N,) the log step across the edge in the image, over ``depth``.
        found: (N,) where the evidence says a shadow's edge crosses the marker.
    """

    normal: NDArray[np.float64]
    offset: NDArray[np.float64]
    depth: NDArray[np.float64]
    explained: NDArray[np.float64]
    step: NDArray[np.float64]
    found: NDArray[np.bool_]

    def take(self, rows: NDArray[np.intp]) -> ShadowEdges:
        """The edges of the candidates ``rows``."""
        return ShadowEdges._make(field[rows] for field in self)

    def moved(self, origin: NDArray[np.float64], to: NDArray[np.float64]) -> ShadowEdges:
        """The same edges described about the points ``to`` (N, 2) instead of ``origin``."""
        shift = np.cos(self.normal) * (to[:, 0] - origin[:, 0]) + np.sin(self.normal) * (
            to[:, 1] - origin[:, 1]
        )
        return self._replace(offset=self.offset - shift)


def _unit_pairs() -> NDArray[np.float64]:
    """(K, 2) the pairs' offsets for a reach of 1, over a half turn."""
    rho = np.linspace(_INNERMOST_RING, 1.0, _RINGS)
    phi = np.arange(_PAIRS_PER_RING) * (np.pi / _PAIRS_PER_RING)
    return np.stack([np.outer(rho, np.cos(phi)).ravel(), np.outer(rho, np.sin(phi)).ravel()], 1)


_PAIRS = _unit_pairs()


def _coarse_patterns() -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The coarse edges' pair patterns for a reach of 1, and their normals and offsets.

    A pair (d, -d) is parted by the edge u = o (u = n . d) where |u| > |o|; its log
    ratio is then the depth with the sign of -u. A sharp step suffices to rank the
    coarse edges; the refinement models the blur.
    """
    normals = np.arange(_COARSE_DIRECTIONS) * (np.pi / _COARSE_DIRECTIONS)
    offsets = np.arange(0.0, _MAX_OFFSET + 1e-9, _COARSE_OFFSET_STEP)
    u = (
        np.cos(normals)[:, None] * _PAIRS[None, :, 0]
        + np.sin(normals)[:, None] * _PAIRS[None, :, 1]
    )
    parted = np.abs(u)[:, None, :] > offsets[None, :, None]
    patterns = (-np.sign(u)[:, None, :] * parted).reshape(-1, len(_PAIRS))
    return (
        patterns,
        np.repeat(normals, len(offsets)),
        np.tile(offsets, _COARSE_DIRECTIONS),
    )


_PATTERNS, _PATTERN_NORMALS, _PATTERN_OFFSETS = _coarse_patterns()
_PATTERN_POWER = _PATTERNS**2


def _log_levels(
    image: NDArray[Any], x: NDArray[np.float64], y: NDArray[np.float64], floor: float
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Log of the raw levels at (x, y) (bilinear; at least ``floor``), and validity."""
    values, valid = bilinear(image, x, y)
    return np.log(np.maximum(values, floor)), valid


def _parting(
    d: NDArray[np.float64],
    normal: NDArray[np.float64],
    offset: NDArray[np.float64],
    depth: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The blurred shadow's part in each pair's log ratio, and its derivatives.

    The blur acts on the light, not on its log: an end at u = n . d (-u for the
    c - d end) keeps 1 - a Phi((u - o) / b) of it, a = 1 - exp(-depth), and its log
    level drops by -log of that. The ratio's part is the c + d end's log less the
    c - d end's.

    Returns:
        (N, K) the part, and (N, K, 3) its derivatives by depth, normal and offset.
    """
    cos, sin = np.cos(normal)[:, None], np.sin(normal)[:, None]
    u = cos * d[..., 0] + sin * d[..., 1]
    along = -sin * d[..., 0] + cos * d[..., 1]
    kept = np.exp(-depth)[:, None]
    share = 1.0 - kept
    parts, derivatives = [], []
    for sign in (1.0, -1.0):
        argument = (sign * u - offset[:, None]) / EDGE_BLUR_PX
        shaded = ndtr(argument)
        light = 1.0 - share * shaded
        density = np.exp(-0.5 * argument**2) / (np.sqrt(2.0 * np.pi) * EDGE_BLUR_PX)
        # d log(light) / d depth, / d normal, / d offset.
        by_depth = -kept * shaded / light
        by_position = -share * density / light
        parts.append(np.log(light))
        derivatives.append(np.stack([by_depth, by_position * sign * along, -by_position], -1))
    return parts[0] - parts[1], derivatives[0] - derivatives[1]


class _Reading(NamedTuple):
    """The pairs :func:`find_edges` reads around N candidates, with the candidates.

    ``xy`` (N, 2), ``reach`` (N,) and ``lines`` (N, 2) are the candidates; ``offsets``
    (N, K, 2) the pairs' d; ``ratio`` (N, K) log I(c + d) - log I(c - d); ``weight``
    (N, K) 1 on the quadrants' insides; ``sides`` (N, K, 2) the signs of d's
    distances from the two lines.
    """

    xy: NDArray[np.float64]
    reach: NDArray[np.float64]
    lines: NDArray[np.float64]
    offsets: NDArray[np.float64]
    ratio: NDArray[np.float64]
    weight: NDArray[np.float64]
    sides: NDArray[np.float64]

    def take(self, rows: NDArray[np.intp]) -> _Reading:
        """The reading of the candidates ``rows``."""
        return _Reading._make(field[rows] for field in self)


def _read_pairs(
    image: NDArray[Any],
    floor: float,
    xy: NDArray[np.float64],
    reach_px: NDArray[np.float64],
    line_angles: NDArray[np.float64],
) -> _Reading:
    """The pairs' log ratios around each candidate, and which lie on the insides."""
    d = reach_px[:, None, None] * _PAIRS[None]
    x, y = xy[:, 0, None], xy[:, 1, None]
    ahead, valid_ahead = _log_levels(image, x + d[..., 0], y + d[..., 1], floor)
    behind, valid_behind = _log_levels(image, x - d[..., 0], y - d[..., 1], floor)
    s1, s2 = line_distances(d[..., 0], d[..., 1], line_angles)
    weight = (
        (np.minimum(np.abs(s1), np.abs(s2)) >= _CLEAR_OF_LINES_PX) & valid_ahead & valid_behind
    ).astype(np.float64)
    sides = np.stack([np.sign(s1), np.sign(s2)], axis=-1)
    return _Reading(xy, reach_px, line_angles, d, ahead - behind, weight, sides)


def find_edges(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    reach_px: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    full_scale: float,
    *,
    decided_by_pairs: bool = True,
) -> ShadowEdges:
    """A cast shadow's straight edge across each candidate, where the evidence shows one.

    On pairs of the quadrants' insides within ``reach_px``, the log ratio of the
    pair's raw levels is fitted by the quadrants' own levels (a term in each line's
    side, as a dull quadrant makes) and a blurred half-plane of a depth: first the
    best of a coarse set of sharp edges by linear least squares, then direction,
    distance and depth together by Gauss-Newton. The pairs cannot tell an edge at
    +o from one at -o (both part the same pairs); the log step of the raw levels
    across each of the two lines says which is there. Found: the edge explains
    :data:`MIN_EXPLAINED` of the variance, the shadow is :data:`MIN_DEPTH` deep
    or more, and the image steps by that depth across its edge
    (:data:`STEP_TOLERANCE`).

    Those three decide for a candidate no check has passed yet, where a false edge
    brings a texture saddle in. An X already located is fitted again with the edge
    by its model, which keeps it only where it takes more of the residual than its
    four parameters would by chance (:data:`uneven.SHADOW_MIN_CHI2`); offered the
    edge without ``decided_by_pairs``, wherever the shadow is deep enough, it
    decides itself: the pairs' share and the step turn away the edges of shadowed
    markers that their model, fitted with those edges, locates better. The depth
    stays: a shallower shadow is a light's slope, which the model fits anyway, and
    X's under no cast shadow keep shallow edges, at a cost in time. Measured:
    docs/accuracy-journal.md, "The lines measured from the edges, and the shadow's edge
    tried in the model" and "Figures the fit's and the detector's docstrings
    carried".

    Args:
        image: (H, W) grey image, raw levels.
        xy: (N, 2) candidate centres (a pixel or two off is no matter).
        reach_px: (N,) radius of the disk read around each, px.
        line_angles: (N, 2) the X's line directions, radians.
        full_scale: the image's white (255 for uint8, 1 for float images in [0, 1]).
        decided_by_pairs: found only where the pairs and the step show the edge
            too; without, the edge that fits best, found where deep enough, for a
            located X's model to test.

    Returns:
        :class:`ShadowEdges`.
    """
    n = len(xy)
    floor = _DARKEST_SHARE * full_scale
    reading = _read_pairs(image, floor, xy, reach_px, line_angles)
    ratio, weight, sides = reading.ratio, reading.weight, reading.sides
    # The quadrants' levels projected out: what is left is the shadow's to explain.
    weighted_sides = sides * weight[..., None]
    levels_inverse = np.linalg.inv(weighted_sides.transpose(0, 2, 1) @ sides + 1e-9 * np.eye(2))
    levels = (levels_inverse @ (weighted_sides.transpose(0, 2, 1) @ ratio[..., None]))[..., 0]
    residual = ratio - (sides @ levels[..., None])[..., 0]
    total = (weight * residual**2).sum(axis=1)
    # Coarse: every pattern against every candidate as matrix products, the
    # candidates' two sides in one: (M, K) @ (K, 2N).
    correlation = (weight * residual) @ _PATTERNS.T
    pattern_sides = (
        (_PATTERNS @ weighted_sides.transpose(1, 0, 2).reshape(len(_PAIRS), -1))
        .reshape(len(_PATTERNS), n, 2)
        .transpose(1, 0, 2)
    )
    power = weight @ _PATTERN_POWER.T - ((pattern_sides @ levels_inverse) * pattern_sides).sum(-1)
    gain = correlation**2 / np.maximum(power, 1e-12)
    best = np.argmax(gain, axis=1)
    rows = np.arange(n)
    normal = _PATTERN_NORMALS[best]
    offset = _PATTERN_OFFSETS[best] * reach_px
    depth = correlation[rows, best] / np.maximum(power[rows, best], 1e-12)
    explained = gain[rows, best] / np.maximum(total, 1e-12)
    step = np.zeros(n)
    # Only where a sharp edge is already deep enough, and explains a share of the pairs
    # where they decide, is the edge refined.
    promising = np.abs(depth) >= _PROMISING * MIN_DEPTH
    if decided_by_pairs:
        promising &= explained >= _PROMISING * MIN_EXPLAINED
    refine = np.flatnonzero(promising & (weight.sum(axis=1) >= _MIN_PAIRS))
    if len(refine):
        normal[refine], offset[refine], depth[refine], explained[refine], step[refine] = _refine(
            image,
            floor,
            reading.take(refine),
            total[refine],
            levels[refine],
            (normal[refine], offset[refine], depth[refine]),
        )
    found = np.zeros(n, dtype=bool)
    found[refine] = depth[refine] >= MIN_DEPTH
    if decided_by_pairs:
        found[refine] &= (explained[refine] >= MIN_EXPLAINED) & (
            np.abs(step[refine] - 1.0) <= STEP_TOLERANCE
        )
    return ShadowEdges(normal % (2.0 * np.pi), offset, np.abs(depth), explained, step, found)


def _refine(
    image: NDArray[Any],
    floor: float,
    reading: _Reading,
    total: NDArray[np.float64],
    levels: NDArray[np.float64],
    coarse: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
) -> tuple[NDArray[np.float64], ...]:
    """:func:`find_edges`' coarse edges made exact: normal, offset, depth, explained, step.

    ``coarse`` is each edge's normal, distance and signed depth; ``total`` the
    pairs' variance and ``levels`` the quadrants' levels without a shadow. The
    pairs cannot tell an edge at +o from one at -o (both part the same pairs):
    the log step of the raw levels across each says which is there. Then the
    model ratio = levels . sides + the shadow's part (:func:`_parting`) is fitted
    by Gauss-Newton, all five parameters together.
    """
    normal, distance, depth = coarse
    normal = np.where(depth < 0, normal + np.pi, normal)
    depth = np.clip(np.nan_to_num(np.abs(depth)), 0.0, _MAX_DEPTH)
    plus = _edge_step(image, floor, reading, normal, distance, depth)
    minus = _edge_step(image, floor, reading, normal, -distance, depth)
    offset = np.where(np.abs(plus - 1.0) <= np.abs(minus - 1.0), distance, -distance)
    levels = levels.copy()
    bound = _MAX_OFFSET * reading.reach
    for _ in range(_REFINE_ITERATIONS):
        part, by_shadow = _parting(reading.offsets, normal, offset, depth)
        misfit = reading.ratio - (reading.sides @ levels[..., None])[..., 0] - part
        jacobian = np.concatenate([reading.sides, by_shadow], axis=-1)
        weighted = jacobian * reading.weight[..., None]
        normal_eq = weighted.transpose(0, 2, 1) @ jacobian + 1e-9 * np.eye(5)
        # Too few pairs make the system singular: no step.
        step = np.nan_to_num(
            np.linalg.solve(normal_eq, (weighted.transpose(0, 2, 1) @ misfit[..., None]))[..., 0]
        )
        levels += step[:, :2]
        depth = np.clip(depth + step[:, 2], 0.0, _MAX_DEPTH)
        normal = normal + step[:, 3]
        offset = np.clip(offset + step[:, 4], -bound, bound)
    part, _ = _parting(reading.offsets, normal, offset, depth)
    misfit = reading.ratio - (reading.sides @ levels[..., None])[..., 0] - part
    explained = 1.0 - (reading.weight * misfit**2).sum(axis=1) / np.maximum(total, 1e-12)
    return (
        normal,
        offset,
        depth,
        explained,
        _edge_step(image, floor, reading, normal, offset, depth),
    )


def _edge_step(
    image: NDArray[Any],
    floor: float,
    reading: _Reading,
    normal: NDArray[np.float64],
    offset: NDArray[np.float64],
    depth: NDArray[np.float64],
) -> NDArray[np.float64]:
    """(N,) the log step of the raw levels down across each edge, over ``depth``.

    The mean log difference of points :data:`_STEP_READ_PX` to either side of the
    edge, within the reach and on the quadrants' insides: 1 across a shadow's edge
    of that depth, about 0 across its mirror image through the candidate.
    """
    cos, sin = np.cos(normal)[:, None], np.sin(normal)[:, None]
    along = np.linspace(-1.0, 1.0, _STEP_SAMPLES)[None, :] * reading.reach[:, None]
    px, py = offset[:, None] * cos - along * sin, offset[:, None] * sin + along * cos
    x, y = reading.xy[:, 0, None] + px, reading.xy[:, 1, None] + py
    shaded, valid_shaded = _log_levels(
        image, x + _STEP_READ_PX * cos, y + _STEP_READ_PX * sin, floor
    )
    lit, valid_lit = _log_levels(image, x - _STEP_READ_PX * cos, y - _STEP_READ_PX * sin, floor)
    s1, s2 = line_distances(px, py, reading.lines)
    weight = (
        (np.minimum(np.abs(s1), np.abs(s2)) >= _CLEAR_OF_LINES_PX + _STEP_READ_PX)
        & valid_shaded
        & valid_lit
    ).astype(np.float64)
    mean_step = (weight * (lit - shaded)).sum(axis=1) / np.maximum(weight.sum(axis=1), 1.0)
    return cast("NDArray[np.float64]", mean_step / np.maximum(depth, 1e-9))


def divided_out(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    edges: ShadowEdges,
    disk_px: NDArray[np.float64],
    full_scale: float,
) -> NDArray[Any]:
    """A copy of ``image`` with each point's shadow divided out within ``disk_px`` of it.

    The disks must not overlap (:func:`apart`). The light the shadow keeps,
    1 - (1 - exp(-depth)) Phi(u / b) through the edge's modelled blur, is divided
    out; the levels keep the image's dtype (rounded, clipped to ``full_scale``).
    """
    out = image.copy()
    height, width = image.shape
    for (x0, y0), normal, offset, depth, disk in zip(
        xy, edges.normal, edges.offset, edges.depth, disk_px, strict=True
    ):
        rows = slice(max(int(y0 - disk), 0), min(int(y0 + disk) + 2, height))
        cols = slice(max(int(x0 - disk), 0), min(int(x0 + disk) + 2, width))
        yy, xx = np.mgrid[rows, cols]
        u = (xx - x0) * np.cos(normal) + (yy - y0) * np.sin(normal) - offset
        light = 1.0 - (1.0 - np.exp(-depth)) * ndtr(u / EDGE_BLUR_PX)
        inside = (xx - x0) ** 2 + (yy - y0) ** 2 <= disk**2
        patch = image[rows, cols].astype(np.float64) / np.where(inside, light, 1.0)
        if np.issubdtype(image.dtype, np.integer):
            patch = np.round(patch)
        out[rows, cols] = np.minimum(patch, full_scale).astype(image.dtype)
    return out


def apart(
    xy: NDArray[np.float64], disk_px: NDArray[np.float64], explained: NDArray[np.float64]
) -> NDArray[np.bool_]:
    """(N,) the points kept so that no two disks overlap, the best explained first.

    Two candidates whose disks overlap are mostly one marker's saddle found twice,
    or a marker and the texture beside it; the edge that explains more is the
    marker's. One copy of the frame then holds every kept shadow divided out.
    """
    keep = np.zeros(len(xy), dtype=bool)
    for i in np.argsort(-explained, kind="stable"):
        others = np.flatnonzero(keep)
        if (np.hypot(*(xy[others] - xy[i]).T) > disk_px[others] + disk_px[i]).all():
            keep[i] = True
    return keep
