"""What a pass of the detector gives back, and where a tracking pass searches.

:class:`Detection` is one marker centre; :class:`DetectionResult` a frame's
detections with what each stage counted, timed and left standing;
:class:`SearchPlan` the regions, known markers and seeds of a tracking pass.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from marker_localizer.core import decision

#: The counts of :class:`DetectionResult` that say what the caps cut, the price of a
#: bounded worst case (``max_candidates`` after screening,
#: :data:`symmetry_path.MAX_VERIFIED` after the prescreen,
#: :data:`symmetry_path.MAX_CONFIRMED` after the template,
#: :data:`acceptance.MAX_PLATE_ASKED` at the plate's test,
#: :data:`acceptance.MAX_VOUCH_PLATES` for the modulation gate's rejects; on the other paths
#: :data:`template_path.MAX_GROWN` and :data:`paper_path.MAX_LOCATED`): the node's
#: diagnostics show their sum.
CAP_COUNTS = (
    "dropped_over_cap",
    "dropped_over_verification_cap",
    "plate_asked_over_cap",
    "vouch_over_cap",
)
#: The counts of :class:`DetectionResult` that say what the second readings' caps left
#: unread: candidates the checks rejected, read again another way, at most so many a
#: frame (:meth:`~marker_localizer.core.symmetry_path.SymmetryPath._recentre_lost`, its
#: shadow reading, :data:`subpixel.MAX_MODELLED`, the plates of texture's size,
#: :data:`second_reading.MAX_DULL_READ`). Busy ground fills them on every frame; the
#: node's diagnostics show their sum apart.
SECOND_READING_CAP_COUNTS = (
    "recentring_over_cap",
    "shadow_over_cap",
    "uneven_over_cap",
    "plate_over_cap",
    "dull_over_cap",
)
#: The :class:`Detection` fields of :meth:`DetectionResult.as_array`, one column each in
#: this order (``evidence`` is not one): the one place the table's layout is written.
#: Code outside this module reads a frame's detections by field, through
#: :func:`positions`, :func:`scores`, :func:`sigmas`, :func:`line_directions` and
#: :func:`extents`, not the table by column number.
TABLE_COLUMNS = ("x", "y", "score", "sigma", "angle1", "angle2", "radius_px")


@dataclass(frozen=True)
class Detection:
    """One marker centre.

    Attributes:
        x: column position in pixels, (0, 0) = centre of the top-left pixel.
        y: row position in pixels.
        score: confidence in [0, 1] (centre symmetry times fit quality; with
            ``refinement="template"`` :func:`decision.confidence` of the decision's
            score, 0.5 at the threshold).
        sigma: 1-sigma radial position uncertainty in pixels, from the fit's
            covariance: sqrt(var_x + var_y).
        angle1: direction of the first line through the centre, radians in [0, pi);
            on the default path, measured from the edges on X's of
            :data:`subpixel.MEASURED_MIN_EXTENT_PX` and more (median error
            0.6-1.4 degrees on the renderer's (a), (c), (d), (g), against the
            ring check's 1.9-3.4).
        angle2: direction of the second line, radians in [0, pi).
        radius_px: extent of the X pattern found by the annular scan.
        evidence: the verification's part of the score (ring symmetry x template
            NCC); ``score`` is ``evidence`` x (1 - relative symmetry residual of the
            fit). :meth:`Detector.locate` takes it back to confirm a tracked marker.
            With ``refinement="template"`` it equals ``score``: that decision reads
            every frame's evidence afresh.
    """

    x: float
    y: float
    score: float
    sigma: float
    angle1: float
    angle2: float
    radius_px: float
    evidence: float = 1.0


# Compared by identity: a dataclass's == would compare the survivors' arrays, which
# have no one truth value.
@dataclass(eq=False)
class DetectionResult:
    """Detections of one frame, with per-stage counts and timings.

    Iterating over a result yields its :class:`Detection` objects.

    Attributes:
        detections: accepted markers, strongest first (:func:`strongest_first`).
        counts: how many points entered or left each stage (``candidates``,
            ``after_suppression``, ``dropped_over_cap``, ``skipped_known``,
            ``rejected_prescreen``, ``dropped_over_verification_cap``,
            ``rejected_centring``,
            ``rejected_symmetry``, ``rejected_template``, ``rejected_lines``,
            ``rejected_refinement``, ``rejected_score``, ``rejected_x_end``,
            ``rejected_misfit``, ``rejected_quartic``
            (:meth:`acceptance.MarkerModel.plate_not_worse`; of them
            ``plate_asked_over_cap`` unread, over :data:`acceptance.MAX_PLATE_ASKED`),
            ``rejected_lattice``
            (:meth:`acceptance.MarkerModel.stands_alone`), ``rejected_chroma`` (on a
            colour frame, small X's drawn in colour, :func:`chroma.coloured_x`; on
            every path),
            ``merged_duplicates``, ``recentred``, ``found_recentred``,
            ``kept_faint`` and ``kept_under_floor`` (X's the modulation gate or
            the fit's score floor rejected that the marker's model vouches for,
            :meth:`acceptance.MarkerModel.vouches`), ``kept_standing_out`` (the
            detections that a score floor, the ring symmetry's, the template's or the
            fit's, would have rejected and that passed it because their saddle stands
            out of their ground, :func:`acceptance.stands_out`; once each, at however
            many floors; the first reading's and a tracked pass's, as the other counts
            of the checks), ``dull_read`` and ``kept_dull`` (X's
            the ring check rejected that were read again from the light slope's
            centre, and those of them it took, :func:`second_reading.read_dull`;
            ``dull_over_cap`` those over :data:`second_reading.MAX_DULL_READ`),
            ``recentring_over_cap`` (:meth:`SymmetryPath._recentre_lost`), ``shadow_read``,
            ``found_shadowed``, ``located_in_shadow``, ``shadow_over_cap``
            (:meth:`SymmetryPath._reread_shadowed`),
            ``uneven_over_cap`` (X's located by their levels' fit, not their model, for
            :data:`subpixel.MAX_MODELLED`),
            ``plate_read``, ``found_plate``, ``plate_over_cap`` (X's of texture's size
            that found no marker judged by their plate, those it added, those over the
            reading's cap,
            :meth:`SymmetryPath._read_plates`),
            ``accepted``;
            with ``refinement="template"``,
            ``rejected_<reason>`` for each of :data:`decision.REASONS` instead of
            the centring, symmetry, template, refinement and score counts).
            ``dropped_over_cap`` counts every candidate that ``max_candidates``
            cut, including those the screening found and left out early as too
            weak to pass it (:meth:`screening.CellCap.floor`);
            ``unexamined_below_floor`` the pixels whose saddle response passed
            the threshold but not the bound the floor sets, which the screening
            never compared with their neighbours (on busy ground most of them,
            about one in six a 3x3 peak on real sand; none of them could pass the
            cap);
            ``dropped_over_verification_cap`` those over :data:`symmetry_path.MAX_VERIFIED` after
            the prescreen and over :data:`symmetry_path.MAX_CONFIRMED` after the template;
            on the other paths those over :data:`template_path.MAX_GROWN` and
            :data:`paper_path.MAX_LOCATED`;
            ``plate_asked_over_cap`` the located X's rejected unread at the
            plate's test; ``vouch_over_cap`` the modulation gate's rejects whose
            plate the marker's model left unread, over
            :data:`acceptance.MAX_VOUCH_PLATES`; :data:`CAP_COUNTS` are the caps' cuts.
        timings_ms: wall time per stage in milliseconds.
        verdicts: with ``refinement="template"``, every candidate the decision saw:
            where its fit ended, whether it was accepted and why not, its score and
            evidence; None otherwise.
        survivors: (test, (K, 2) positions of the candidates that passed it), in
            the order the tests ran: where a marker was lost is the first test
            after which no candidate is left near it. The default path records
            every test (:data:`symmetry_path.SURVIVOR_TESTS`); the paper's and the
            template path the screening and the prescreen. References to arrays the
            stages make anyway: no copies.
    """

    detections: list[Detection] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)
    timings_ms: dict[str, float] = field(default_factory=dict)
    verdicts: decision.Verdicts | None = None
    survivors: list[tuple[str, NDArray[np.float64]]] = field(default_factory=list)

    def __iter__(self) -> Iterator[Detection]:
        return iter(self.detections)

    def __len__(self) -> int:
        return len(self.detections)

    def __getitem__(self, index: int) -> Detection:
        return self.detections[index]

    def as_array(self) -> NDArray[np.float64]:
        """(N, 7) float64: x, y, score, sigma, angle1, angle2, radius_px (:data:`TABLE_COLUMNS`)."""
        return _fields(self.detections, TABLE_COLUMNS)


@dataclass(frozen=True, eq=False)  # arrays: compared and hashed by identity
class SearchPlan:
    """Where :meth:`Detector.detect` searches on one frame: tracking mode's seam.

    Arrays are copied and validated on construction.

    Attributes:
        regions: (K, 4) int windows (x0, y0, x1, y1), end-exclusive, to search
            instead of the whole frame; the detector samples the whole image, a
            window only bounds where candidates are screened. Snapped to
            :attr:`Detector.region_lattice_px` they read the same local means as a
            full-frame pass.
        known: (M, 2) centres of markers already located on this frame (by
            :meth:`Detector.locate`): screening candidates closer than
            ``min_peak_separation_px`` to one are that marker's and are not verified
            again (counted as ``skipped_known``).
        seeds: (S, 2) positions that join the screening candidates (markers whose
            plate the frame border cuts, where the fit alone cannot tell what a full
            pass would accept). They take every stage after the prescreen, at the
            first pyramid level's scale.
    """

    regions: NDArray[np.int64] = field(default_factory=lambda: np.zeros((0, 4), np.int64))
    known: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))
    seeds: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))

    def __post_init__(self) -> None:
        for name, columns in (("regions", 4), ("known", 2), ("seeds", 2)):
            value = np.asarray(getattr(self, name))
            if value.size and (value.ndim > 2 or value.shape[-1] != columns):
                raise ValueError(f"SearchPlan.{name} of shape {value.shape} is not (N, {columns})")
            if name != "regions" and not np.isfinite(value).all():
                raise ValueError(f"SearchPlan.{name} holds a NaN or infinite position")
            dtype = np.int64 if name == "regions" else np.float64
            object.__setattr__(self, name, value.astype(dtype).reshape(-1, columns))


def _fields(detections: Iterable[Detection], names: tuple[str, ...]) -> NDArray[np.float64]:
    """(N, len(names)) float64: the named fields of each detection, a row each."""
    return np.array(
        [[getattr(d, name) for name in names] for d in detections], dtype=np.float64
    ).reshape(-1, len(names))


def positions(detections: Iterable[Detection]) -> NDArray[np.float64]:
    """(N, 2) the detections' centres, ``x`` and ``y``, px."""
    return _fields(detections, ("x", "y"))


def scores(detections: Iterable[Detection]) -> NDArray[np.float64]:
    """(N,) the detections' ``score``."""
    return _fields(detections, ("score",)).reshape(-1)


def sigmas(detections: Iterable[Detection]) -> NDArray[np.float64]:
    """(N,) the detections' ``sigma``, px."""
    return _fields(detections, ("sigma",)).reshape(-1)


def extents(detections: Iterable[Detection]) -> NDArray[np.float64]:
    """(N,) the detections' ``radius_px``."""
    return _fields(detections, ("radius_px",)).reshape(-1)


def line_directions(detections: Iterable[Detection]) -> NDArray[np.float64]:
    """(N, 2) the detections' line directions, ``angle1`` and ``angle2``, radians."""
    return _fields(detections, ("angle1", "angle2"))


def strongest_first(rows: NDArray[np.intp], score: NDArray[np.float64]) -> NDArray[np.intp]:
    """``rows`` (indices into ``score``) by their score, highest first; ties in their given order.

    The order of :attr:`DetectionResult.detections`, on every path and in tracking.
    The sort is stable so that equal scores come out in one order whatever sort
    algorithm numpy picks for the array's length.
    """
    ordered: NDArray[np.intp] = rows[np.argsort(-score[rows], kind="stable")]
    return ordered


def detections_of(
    xy: NDArray[np.float64],
    score: NDArray[np.float64],
    sigma: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    evidence: NDArray[np.float64],
) -> list[Detection]:
    """One :class:`Detection` per row of the arrays, in their order.

    Args:
        xy: (N, 2) centres, px.
        score: (N,) scores.
        sigma: (N,) radial position uncertainties, px.
        line_angles: (N, 2) line directions, radians.
        radius_px: (N,) extents of the X, px.
        evidence: (N,) the verification's part of each score.
    """
    return [
        Detection(float(x), float(y), float(s), float(e), float(a1), float(a2), float(r), float(v))
        for (x, y), s, e, (a1, a2), r, v in zip(
            xy, score, sigma, line_angles, radius_px, evidence, strict=True
        )
    ]
