"""Second readings: screened candidates the first reading left without a marker, read again.

The checks and the fit read grey-level point symmetry. A light that changes across
an X (a cloud's shadow, a dull bright quadrant) or a cast shadow's edge across it
breaks that symmetry, not the X's geometry, and the first reading loses the X.
The candidates it lost are read again, by the same checks and fit, where the light
is taken into account:

* :func:`read_dull`: small X's with a dull quadrant, whose equalised rings showed
  them but short, read again from the light slope's centre (inside the first
  reading, before its template match);
* :func:`recentred`: centred once more with the light's slope fitted too;
* :func:`shadowed`: with a cast shadow's straight edge, found by
  :func:`shadow.find_edges`, divided out of a copy of the frame
  (:func:`shadow.divided_out`), and centred there with the light's slope; a marker
  found so is then located in the frame itself by its model with that edge
  (:func:`located_in_shadow`).

Which candidates the recentring and the shadow's reading take (:func:`lost_wide`):
those screened at :data:`WIDE_SCALE_PX` or wider that ended farther than the merge
radius from every detection, at most a cap of them, the strongest spread over the
frame. A marker a
second reading finds joins the detections unless it duplicates one
(:func:`new_points`); the detections already made stay as they were.

The detector (:class:`~marker_localizer.core.pipeline.Detector`) chains these with
its checks and fit, counts and times them. Measured: docs/method.md, "A second
centring, with the light's slope, for the wide candidates that found no marker" and
"A cast shadow's edge, found and divided out, for the wide candidates still lost";
docs/accuracy-journal.md, the run at 21bc646, "Evidence measured and not taken" and
"Figures the fit's and the detector's docstrings carried"; docs/speed.md, "Earlier
runs" and "The second readings on the speed frames, and a gate on the recentring".
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from marker_localizer.core import acceptance, screening, shadow, subpixel, verification
from marker_localizer.core.screening import Candidates

#: Candidates screened at this scale or wider, px (the saddle pyramid's second level
#: on where the search starts at the first; a range whose search starts at the second,
#: such as 6-40 px, labels that level's candidates with the smallest radius, under
#: this: docs/accuracy-journal.md, "(c)'s losses at the prescreen"; a small X with a
#: dull quadrant is lost there, and reading that level's candidates as wide reads the
#: ground's texture again at a high price: "Small markers with a dull quadrant from a
#: 6-8 px minimum"), get second readings where the first found no X: the plain rings'
#: rejects are read again with the bright sectors equalised, and where the X's lines cross
#: (:func:`verification.ring_check`); those that end as no marker are centred again
#: with the light's slope (:func:`recentred`) and read with a shadow's edge divided
#: out (:func:`shadowed`).
#: What counts is still the evidence each reading shows (the equalised rings' extent,
#: :data:`verification.EQUALISED_MIN_EXTENT_PX`); the scale only spares the cost:
#: texture responds at the first level (4 px), and on the real aerial and cirn_uas
#: frames this re-reads ~15 candidates a frame at 3-30 px, ~200 at 6-40 px (measured:
#: docs/accuracy-journal.md, "Figures the fit's and the detector's docstrings carried").
WIDE_SCALE_PX = 8.0
#: A lost wide candidate is read again (:func:`recentred`) where the light's slope
#: moves its centre this far, px: less moves the rings' crossings, read every 10
#: degrees from 3 px out, by under half a sample (4.8 degrees).
RECENTRE_MIN_SHIFT_PX = 0.25
#: Lost wide candidates centred again per frame at most, the strongest spread over the
#: frame as Eq. (7)'s thinning spreads them (:func:`screening.even_cap_index`): markers
#: are among a frame's strongest saddles, and each costs about 0.1-0.2 ms (measured:
#: docs/accuracy-journal.md, "Figures the fit's and the detector's docstrings carried";
#: docs/speed.md, "Real ground, the radius range and the worst case").
MAX_RECENTRED = 64
#: ... and those whose shadow's edge is sought after the recentring (:func:`shadowed`,
#: 0.1 ms each, and a reading again of those a shadow crosses): the 32 strongest hold
#: nearly every marker the 64 strongest give (measured: docs/accuracy-journal.md, "Figures the
#: fit's and the detector's docstrings carried").
MAX_SHADOW_READ = 32
#: A lost candidate's shadow edge is sought within this many of its screening scales,
#: px (:func:`shadow.find_edges`): a marker's X reaches about twice the scale its
#: saddle answers at ...
SHADOW_REACH_SCALES = 2.0
#: ... and divided out within this many reaches (:func:`shadow.divided_out`): the
#: checks' rings and the fit read the X out to its extent, and the X-end rings beyond.
SHADOW_DISK_REACHES = 1.5
#: Candidates :func:`read_dull` reads again per frame at most, the strongest spread
#: over the frame: most frames hold fewer (measured: docs/accuracy-journal.md, "Small X's with
#: a dull quadrant, read again from the light slope's centre" and "Figures the fit's
#: and the detector's docstrings carried").
MAX_DULL_READ = 64


class DullReading(NamedTuple):
    """What :func:`read_dull` read again, and what it kept.

    Attributes:
        read: (R,) rows of the candidates read again.
        xy: (R, 2) their centres with the light's slope.
        rings: their equalised rings there (R rows).
        kept: (K,) which of them replace the first reading, as positions in ``read``.
        over_cap: the candidates asked that :data:`MAX_DULL_READ` left unread.
    """

    read: NDArray[np.intp]
    xy: NDArray[np.float64]
    rings: verification.SymmetryCheck
    kept: NDArray[np.intp]
    over_cap: int = 0

    def moved(
        self, candidates: Candidates, ring: verification.SymmetryCheck
    ) -> tuple[Candidates, verification.SymmetryCheck]:
        """The candidates and their check with the kept ones replaced by this reading."""
        if not len(self.kept):
            return candidates, ring
        rows = self.read[self.kept]
        return (
            candidates.moved(rows, self.xy[self.kept]),
            ring.with_rows(rows, self.rings, self.kept),
        )


def read_dull(
    gray: NDArray[Any],
    candidates: Candidates,
    ring: verification.SymmetryCheck,
    equalised_x: NDArray[np.bool_],
    *,
    rings: verification.RingReader,
    floors: acceptance.ScoreFloors,
    model: acceptance.MarkerModel,
    max_radius_px: float,
    cell_px: float,
) -> DullReading:
    """Small X's with a dull quadrant, read again from the light slope's centre.

    At the true centre of a marker of 5-8 px with a dull bright quadrant the plain
    rings show no X at all, and the equalised rings show it out to 5 px; the
    centring, a fit of grey-level symmetry, leaves such a candidate 0.4-0.8 px
    towards the brighter side, where the equalised rings stop a rung short. So a
    candidate screened at :data:`WIDE_SCALE_PX` or wider whose equalised rings
    showed an X (``equalised_x``) but that the ring check rejected or left under
    its score floor is centred again with the light's slope
    (:func:`subpixel.coarse_centre`) and read equalised there, :data:`MAX_DULL_READ`
    of them at most, the strongest spread over the frame's cells of ``cell_px``.
    That reading replaces the first where it shows the X out to
    :data:`verification.DULL_MIN_EXTENT_PX`, clears the score floor of its extent,
    and the marker's model vouches for it (:meth:`acceptance.MarkerModel.vouches`,
    as for a faint X): at that extent, a rung under
    :data:`verification.EQUALISED_MIN_EXTENT_PX`, texture passes the rings too
    (measured: docs/accuracy-journal.md, "Small X's with a dull quadrant, read again from
    the light slope's centre").

    Args:
        gray: (H, W) grey image, raw levels.
        candidates: the centred candidates of the first reading.
        ring: their ring check.
        equalised_x: (N,) where their equalised rings showed an X of any extent.
        rings: the ring check as the detector reads rings; read equalised here.
        floors: the score floors of each extent.
        model: the marker's model on the frame.
        max_radius_px: the largest expected marker radius, px.
        cell_px: the cells the cap spreads the candidates over, px.

    Returns:
        :class:`DullReading`.
    """
    weak = ~ring.accepted | (ring.score < floors.floor(ring.radius_px))
    asked = np.flatnonzero(weak & equalised_x & screened_wide(candidates))
    read = asked[
        screening.even_cap_index(
            candidates.xy[asked], candidates.strength[asked], MAX_DULL_READ, cell_px
        )
    ]
    over_cap = len(asked) - len(read)
    if not len(read):
        nothing = verification.SymmetryCheck._make(field[read] for field in ring)
        return DullReading(read, np.zeros((0, 2)), nothing, read, over_cap)
    centred, inside = _centred_with_slope(gray, candidates.take(read), max_radius_px)
    xy = centred.xy
    there = rings(xy, equalise=True)
    kept = np.flatnonzero(
        inside
        & there.accepted
        & (there.radius_px >= verification.DULL_MIN_EXTENT_PX)
        & (there.score >= floors.floor(there.radius_px))
    )
    kept = kept[model.vouches(xy[kept], there.radius_px[kept], there.line_angles[kept])]
    return DullReading(read, xy, there, kept, over_cap)


def screened_wide(candidates: Candidates) -> NDArray[np.bool_]:
    """(N,) the candidates screened at :data:`WIDE_SCALE_PX` or wider."""
    return candidates.scale_px >= WIDE_SCALE_PX


def far_from(
    found_xy: NDArray[np.float64], xy: NDArray[np.float64], radius_px: float
) -> NDArray[np.intp]:
    """Indices of the points ``xy`` farther than ``radius_px`` from every point of ``found_xy``."""
    if not len(found_xy) or not len(xy):
        return np.arange(len(xy))
    distance, _ = cKDTree(found_xy).query(xy, distance_upper_bound=radius_px)
    return np.flatnonzero(~np.isfinite(distance))


def lost_wide(
    screened: Candidates,
    found_xy: NDArray[np.float64],
    merge_radius_px: float,
    cap: int,
    cell_px: float,
) -> tuple[NDArray[np.intp], int]:
    """The screened candidates a second reading takes, and how many its ``cap`` cut.

    Those screened at :data:`WIDE_SCALE_PX` or wider that ended farther than
    ``merge_radius_px`` from every detection (``found_xy``), at most ``cap`` of
    them, the strongest spread over the frame's cells of ``cell_px``
    (:func:`screening.even_cap_index`).

    Returns:
        (indices into ``screened``, how many lost wide candidates the cap cut).
    """
    wide = np.flatnonzero(screened_wide(screened))
    lost = wide[far_from(found_xy, screened.xy[wide], merge_radius_px)]
    if not len(lost):
        return lost, 0
    kept = screening.even_cap_index(screened.xy[lost], screened.strength[lost], cap, cell_px)
    return lost[kept], len(lost) - len(kept)


def new_points(
    found_xy: NDArray[np.float64],
    added_xy: NDArray[np.float64],
    added_score: NDArray[np.float64],
    merge_radius_px: float,
) -> NDArray[np.bool_]:
    """(M,) which of a second reading's points join the detections ``found_xy``.

    One within ``merge_radius_px`` of a detection, or of a stronger point added
    (``added_score``), is a duplicate.
    """
    joins = np.zeros(len(added_xy), dtype=bool)
    joins[far_from(found_xy, added_xy, merge_radius_px)] = True
    joins &= screening.non_maximum_suppression(added_xy, added_score, merge_radius_px)
    return joins


def recentred(
    gray: NDArray[Any],
    lost: Candidates,
    plain_xy: NDArray[np.float64],
    plain_found: NDArray[np.bool_],
    max_radius_px: float,
) -> Candidates:
    """The lost candidates centred with the light's slope, where that moves them.

    The coarse centring fits grey-level point symmetry alone. On an X under a light
    that changes across it (a cloud's shadow, a dull bright quadrant) it settles a
    few tenths of a pixel to a pixel towards the brighter side, where the rings,
    the template and the fit no longer see the X whole. Centred with the light's
    slope fitted too (:func:`subpixel.coarse_centre`, as the final fit takes it on
    disks of :data:`subpixel.GAIN_MIN_RADIUS_PX` and more), they do. Not every
    candidate is centred so: the rings are grey-level symmetry too, and see some
    markers under a light gradient best where the slope-free centring put them; so
    only the lost ones are, and those the slope moves by
    :data:`RECENTRE_MIN_SHIFT_PX` or more from their first centre (or whose first
    centring found none) are read again.

    Args:
        gray: (H, W) grey image, raw levels.
        lost: the lost candidates, as screened.
        plain_xy: (N, 2) their first, slope-free centres (:func:`subpixel.coarse_centre`).
        plain_found: (N,) where that centring found a centre.
        max_radius_px: the largest expected marker radius, px.

    Returns:
        The candidates to read again, at their slope-fitted centres.
    """
    centred, inside = _centred_with_slope(gray, lost, max_radius_px)
    # Where the slope leaves the centre where it was, the rings read it as before.
    shift = np.linalg.norm(centred.xy - plain_xy, axis=1)
    return centred.take(inside & (~plain_found | (shift >= RECENTRE_MIN_SHIFT_PX)))


def shadow_reach(lost: Candidates, max_radius_px: float) -> NDArray[np.float64]:
    """(N,) how far around each lost candidate its shadow's edge is sought, px."""
    return np.minimum(SHADOW_REACH_SCALES * lost.scale_px, max_radius_px)


class ShadowedReading(NamedTuple):
    """What :func:`shadowed` gives a second reading.

    Attributes:
        lit: the frame with the shadows found divided out (a copy where there are
            any; the frame itself where there are none).
        read: the lost candidates a shadow's edge crosses, as screened.
        edges: their shadows' edges (:class:`shadow.ShadowEdges`).
    """

    lit: NDArray[Any]
    read: Candidates
    edges: shadow.ShadowEdges


def shadowed(
    gray: NDArray[Any],
    lost: Candidates,
    line_angles: NDArray[np.float64],
    max_radius_px: float,
    full_scale: float,
) -> ShadowedReading:
    """The lost candidates a cast shadow's edge crosses, with the shadows divided out.

    A hard shadow across a marker breaks the grey-level symmetry every check reads,
    not the X's geometry. Where :func:`shadow.find_edges` finds a shadow's straight
    edge across a lost candidate (within :func:`shadow_reach`, on ``line_angles``),
    one copy of the frame gets those shadows divided out
    (:func:`shadow.divided_out`, within :data:`SHADOW_DISK_REACHES` reaches; of
    candidates whose disks overlap, the best explained edge,
    :func:`shadow.apart`). There the candidates are to be centred with the light's
    slope (:func:`slope_centred`): the shadow gone, a dull quadrant still pulls a
    slope-free centring off the X.

    Args:
        gray: (H, W) grey image, raw levels.
        lost: the lost candidates, as screened.
        line_angles: (N, 2) their line directions, radians (the first prescreen ring's).
        max_radius_px: the largest expected marker radius, px.
        full_scale: the image's white level.

    Returns:
        :class:`ShadowedReading`, with no candidate where no shadow's edge crosses one.
    """
    reach = shadow_reach(lost, max_radius_px)
    edges = shadow.find_edges(gray, lost.xy, reach, line_angles, full_scale)
    crossed = np.flatnonzero(edges.found)
    disk = SHADOW_DISK_REACHES * reach[crossed]
    kept = shadow.apart(lost.xy[crossed], disk, edges.explained[crossed])
    crossed, disk = crossed[kept], disk[kept]
    read, edges = lost.take(crossed), edges.take(crossed)
    if not len(crossed):
        return ShadowedReading(gray, read, edges)
    return ShadowedReading(shadow.divided_out(gray, read.xy, edges, disk, full_scale), read, edges)


def slope_centred(gray: NDArray[Any], candidates: Candidates, max_radius_px: float) -> Candidates:
    """The candidates centred with the light's slope, those the centring found a centre for."""
    centred, inside = _centred_with_slope(gray, candidates, max_radius_px)
    return centred.take(inside)


def _centred_with_slope(
    gray: NDArray[Any], candidates: Candidates, max_radius_px: float
) -> tuple[Candidates, NDArray[np.bool_]]:
    """Every candidate at its centre with the light's slope fitted too, and (N,) where found.

    :func:`subpixel.coarse_centre` with ``light_slope``, the one centring every second
    reading takes.
    """
    xy, inside = subpixel.coarse_centre(
        gray, candidates.xy, candidates.scale_px, max_radius_px, light_slope=True
    )
    return Candidates(xy, candidates.strength, candidates.scale_px), inside


def located_in_shadow(
    gray: NDArray[Any],
    xy: NDArray[np.float64],
    sigma: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    full_scale: float,
    reading: ShadowedReading,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """The markers a shadowed reading found, located in the frame itself with their edges.

    Each marker takes the edge of the candidate read nearest it (the disks divided out
    do not overlap), moved to its centre, and :func:`subpixel.locate_in_shadow` says
    where the model's centre replaces it.

    Args:
        gray: (H, W) the frame itself, raw levels (not ``reading.lit``).
        xy: (M, 2) the markers found in ``reading.lit``.
        sigma: (M,) their sigmas, px.
        line_angles: (M, 2) their line directions, radians.
        radius_px: (M,) their extents, px.
        full_scale: the image's white level.
        reading: the :class:`ShadowedReading` that found them.

    Returns:
        (xy, sigma, located): (M, 2) the centres, (M,) sigmas, and where the model's
        centre was taken.
    """
    read_xy = reading.read.xy
    nearest = cKDTree(read_xy).query(xy)[1]
    return subpixel.locate_in_shadow(
        gray,
        xy,
        sigma,
        line_angles,
        radius_px,
        full_scale,
        reading.edges.take(nearest).moved(read_xy[nearest], xy),
    )
