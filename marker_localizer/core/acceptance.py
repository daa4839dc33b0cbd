"""Whether an X the rings passed is a marker: the default path's decisions, in one place.

The default path's gates (the modulation gate, the score floors of each extent,
:func:`~marker_localizer.core.verification.minimum_score`) are set by the saddles
ground texture makes at each extent of the ring ladder. A marker that reads small
(tilted, blurred, faint) falls among them. Where those gates reject an X, or pass it
by a thin margin, the model of a marker decides instead, from what texture lacks
(and every detection wider than texture's smallest X's must fit the blurred X):

* its X has ended where its extent says (:func:`verification.modulation_beyond_extent`);
* the blurred X explains its disk: the template's NCC on raw levels
  (:func:`template.template_correlation`) and what it leaves beyond the frame's
  noise (:func:`template.template_misfit`), unless a cast shadow's edge crosses it
  (:func:`shadow.find_edges`);
* the plate that carries a marker explains its window better than a smooth surface
  does (:func:`plate.plate_evidence`).

:class:`MarkerModel` reads these on one frame, and decides twice, each rejection
with its reason:

* :meth:`~MarkerModel.match`, on each X the rings passed: the paint's modulation
  (or the model), the blurred X's template, the score floor
  (:data:`MATCHED_REASONS`, :class:`TemplateGates`);
* :meth:`~MarkerModel.judge`, on each located X: the score floor of its extent
  (:class:`ScoreFloors`) or the model where the floor doubts, the X's end, the
  misfit and the plate (:data:`JUDGED_REASONS`).

The detector (:class:`~marker_localizer.core.pipeline.Detector`) chains them with
the fit between, caps, counts and records them.

What the constants here rest on, measured: docs/accuracy-journal.md, "What the marker
model's constants rest on".
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from marker_localizer.core import plate, screening, shadow, template, verification
from marker_localizer.core.noise import NoiseModel
from marker_localizer.core.sampling import Normaliser

#: Most of a detection's template disk the blurred X may leave unexplained beyond the
#: noise (:func:`template.template_misfit`): a marker leaves a few thousandths, and
#: the saddles of a lattice of discs several hundredths, up to 0.12. A cast shadow's
#: edge, which the X does not model, exempts a detection
#: (:meth:`MarkerModel.shadow_crosses`).
MAX_TEMPLATE_MISFIT = 0.08
#: Lowest recurrence (:func:`verification.disk_recurrence`) of a lattice's saddle: its
#: disk found again on both sides of it. A marker's ground does not repeat its X, and
#: a lattice's saddles mostly read over this (docs/accuracy-journal.md, "A marker stands
#: alone").
MIN_LATTICE_RECURRENCE = 0.75
#: Smallest continuation (:func:`verification.line_continuation`) of a chessboard
#: corner's lines beyond its extent, which a lattice's saddle does not reach: between
#: what real boards' corners read and what a disc lattice's saddles do.
MIN_BOARD_CONTINUATION = 0.3
#: A detection that clears its score floor by less than this must show its plate
#: (:meth:`MarkerModel.plate_not_worse`), unless it is a tiny X the tiny markers' plate
#: reading asks already: texture's false points clear their floors by little, and
#: markers whose plate the model misses (a shadow's edge across it) by more.
PLATE_DOUBT_MARGIN = 0.03
#: Most of the best quartic's residual the plate model may leave on such a detection
#: (:func:`plate.plate_evidence` at its extent or a rung out, the better of the two).
#: Near their floors, markers leave less unless a cast shadow's edge crosses them (the
#: model leaves shadows out), texture's false points more. Measured: docs/accuracy.md,
#: "A plate that leaves most of a quartic's residual near the floor".
PLATE_DOUBT_MAX_TO_QUARTIC = 0.8
#: Every other detection under this extent, px, shows a plate no worse than a quartic
#: (:data:`plate.MAX_TO_QUARTIC_ANY`), as the tiny markers' plate reading asks of
#: its own, whatever its score: texture makes saddles up to this extent
#: (:data:`verification.TEXTURE_EXTENT_PX`), and real sand blurred a little more
#: than the aerial frames' own makes them score 0.92-0.96, clear of every floor.
#: Measured: docs/accuracy-journal.md, "Real sand seen closer, and every X of texture's size
#: asked for its plate".
PLATE_ASKED_MAX_EXTENT_PX = verification.TEXTURE_EXTENT_PX
#: ... unless another detection lies within this many of its extents: a chessboard's
#: corner, whose squares go on where a plate would end, has its neighbours a square
#: away, a few extents; texture's false points have none this near.
BOARD_NEIGHBOUR_EXTENTS = 4.0
#: Detections whose plate one :meth:`MarkerModel.judge` reads at most (1-1.5 ms each,
#: up to four windows), spread over the frame's cells, those that clear their floor
#: by most first; the rest are rejected unread and counted (:attr:`Judgement.unread`).
#: Above what real and rendered frames ask, under what a frame tiled with X's does
#: (docs/speed.md, "The plate asked of a frame tiled with X's").
MAX_PLATE_ASKED = 128
#: X's whose plate :meth:`MarkerModel.vouches` reads, for the modulation gate's
#: rejects, in one pass of the checks at most (a frame's, or one of its second
#: readings'; 1-1.5 ms each), those of the strongest rings first;
#: the rest are not vouched for, and counted (:attr:`Match.unread`). Real, rendered and
#: the speed benchmark's frames ask for at most 4 a frame; a 12 MP chessboard of 4 px
#: squares asked for 4 772 (4.3 s of its 5.2 at 4-40 px).
MAX_VOUCH_PLATES = 128
#: A candidate of texture's size whose fitted score its floor does not vouch for
#: (:meth:`MarkerModel.vouches`) must match the blurred X at least this well, on raw
#: levels: faint and tilted markers match at 0.99 (median), texture the gate rejects
#: at most about this.
FAINT_MIN_NCC = 0.98
#: ... and leave at most this share of its disk beyond the noise
#: (:func:`template.template_misfit`): those markers leave about a hundredth, that
#: texture several.
FAINT_MAX_MISFIT = 0.02
#: The same two bars for an X the modulation gate alone doubts (:meth:`MarkerModel.match`):
#: its rings scored it over its floor already, so only its paint is in doubt (a grey
#: dark paint, haze), not its X. Looser than the floor's: small tilted markers of such
#: paint match at 0.95-0.997 and leave up to 0.04; with the X's end and the plate, no
#: texture candidate the gate rejected on the development frames passes them. The NCC
#: stays at 0.97: at 0.96 as many markers pass, and the plate, the costliest test, is
#: read for twice the texture (docs/accuracy-journal.md, "The gate's vouch at looser bars than
#: the floor's").
GATE_MIN_NCC = 0.97
GATE_MAX_MISFIT = 0.04
#: Least ratio of an X's saddle response to the mean saddle response of the ground
#: around it (:func:`screening.saddle_over_ground`) at which the score floors stand
#: aside for an X of texture's size (:func:`stands_out`). The floors are set by
#: texture's saddles, which are the ground's own: they stand out of it little, and a
#: marker, paint laid on the ground, stands out by its contrast. Set for 0.001 false
#: points per megapixel of real aerial ground, the issue's budget being 0.025: with the
#: floors out of the way, the texture X's of its 24 MP that pass every other test (53 at
#: 2.5-5 px, 54 at 3-30 px) read 46 at most, and an exponential fitted to their tail
#: over 15 (scale 5.7-6.5) puts 0.001 a megapixel at 56-62.
MIN_SADDLE_OVER_GROUND = 60.0


#: Why :meth:`MarkerModel.match` rejects an X the rings passed, in the order its tests
#: run; the detector counts the first two as ``rejected_template``, the last as
#: ``rejected_score``.
MATCHED_REASONS = ("modulation", "template", "score")
#: Why :meth:`MarkerModel.judge` rejects a located X, in the order its tests run; the
#: detector counts each as ``rejected_<reason>``.
JUDGED_REASONS = ("score", "x_end", "misfit", "quartic")
#: The reason of an accepted X (:class:`Match`, :class:`Judgement`).
ACCEPTED = -1
_MODULATION, _TEMPLATE, _MATCHED_SCORE = range(len(MATCHED_REASONS))
_SCORE, _X_END, _MISFIT, _QUARTIC = range(len(JUDGED_REASONS))


def stands_out(
    gray: NDArray[Any], xy: NDArray[np.float64], radius: NDArray[np.float64]
) -> NDArray[np.bool_]:
    """(N,) the X's of texture's size whose score floors stand aside: their saddle stands out.

    Under :data:`verification.X_END_MAX_EXTENT_PX`, where the floors are set by
    texture's saddles, an X whose saddle response is :data:`MIN_SADDLE_OVER_GROUND`
    times its ground's (:func:`screening.saddle_over_ground`) is not of that ground.

    Args:
        gray: (H, W) grey image, raw levels.
        xy: (N, 2) centres, px.
        radius: (N,) extents of the X's, px.
    """
    out = np.zeros(len(xy), dtype=bool)
    small = np.flatnonzero(radius < verification.X_END_MAX_EXTENT_PX)
    if len(small):
        out[small] = screening.saddle_over_ground(gray, xy[small]) >= MIN_SADDLE_OVER_GROUND
    return out


def _passed(reason: NDArray[np.int8], reasons: tuple[str, ...], test: str) -> NDArray[np.bool_]:
    """(N,) the X's whose ``reason`` says they passed ``test`` and every test before it."""
    passed: NDArray[np.bool_] = (reason == ACCEPTED) | (reason > reasons.index(test))
    return passed


@dataclass(frozen=True)
class TemplateGates:
    """The paint's and the template's gates on an X the rings passed (:meth:`MarkerModel.match`).

    Attributes:
        offset_px: how far from the centre the modulation gate reads the sectors'
            levels, px (at most :data:`verification.TEMPLATE_RADIUS_FRACTION` of the
            extent).
        min_radius_px: the smallest expected marker radius, px.
        min_modulation: the least modulation of a marker's paint.
        min_ncc: the least NCC of the blurred X's template.
    """

    offset_px: float
    min_radius_px: float
    min_modulation: float
    min_ncc: float


class Match(NamedTuple):
    """What :meth:`MarkerModel.match` decided of each X the rings passed; each (N,).

    Attributes:
        reason: :data:`ACCEPTED`, or the index in :data:`MATCHED_REASONS` of the test
            that rejected it.
        faint: the modulation gate rejected it and the marker's model vouched for it
            (:meth:`MarkerModel.vouches`).
        stood_out: under the ``lowest`` score of its extent, of texture's size, its
            saddle stands out of its ground, and the floor stood aside (:func:`stands_out`).
        ncc: the template's NCC; NaN where the paint failed first.
        unread: the modulation gate rejected it, and its plate, which the model
            would have read, was over the pass's :data:`MAX_VOUCH_PLATES`.
        plates_read: how many plates the model read for the gate's rejects.
    """

    reason: NDArray[np.int8]
    faint: NDArray[np.bool_]
    stood_out: NDArray[np.bool_]
    ncc: NDArray[np.float64]
    unread: NDArray[np.bool_]
    plates_read: int

    def passed(self, test: str) -> NDArray[np.bool_]:
        """(N,) the X's that passed ``test`` (of :data:`MATCHED_REASONS`) and every one before."""
        return _passed(self.reason, MATCHED_REASONS, test)


class _Vouched(NamedTuple):
    """What :meth:`MarkerModel._vouch` decided: vouched for, left unread over the cap; (N,)."""

    kept: NDArray[np.bool_]
    unread: NDArray[np.bool_]
    plates_read: int


@dataclass(frozen=True)
class ScoreFloors:
    """The lowest fitted score of an X of each extent, set by ground texture's saddles.

    Attributes:
        min_score: the lowest score of an X wider than texture's saddles.
        min_score_small: that of an X no larger than the smallest expected marker
            and of texture's size (:func:`verification.small_marker`).
        min_radius_px: the smallest expected marker radius, px.
    """

    min_score: float
    min_score_small: float
    min_radius_px: float

    def floor(self, radius: NDArray[np.float64]) -> NDArray[np.float64]:
        """(N,) the lowest score a detection of extent ``radius`` (px) may have.

        :func:`verification.minimum_score`: ``min_score``, raised to the texture
        floors below their extents, and ``min_score_small`` for small markers.
        """
        return verification.minimum_score(
            radius, self.min_score, self.min_score_small, self.min_radius_px
        )

    def lowest(self, radius: NDArray[np.float64]) -> NDArray[np.float64]:
        """(N,) the lowest score with which a candidate of extent ``radius`` (px) goes on.

        Its :meth:`floor`, less :data:`verification.ENDED_SCORE_ALLOWANCE` for the
        X's asked to end (:func:`verification.x_must_end`): one that has clearly
        ended may score that much under its floor (:func:`verification.x_ends`).
        """
        asked = verification.x_must_end(radius, self.min_radius_px)
        return self.floor(radius) - verification.ENDED_SCORE_ALLOWANCE * asked

    def clears(
        self,
        gray: NDArray[Any],
        xy: NDArray[np.float64],
        radius: NDArray[np.float64],
        angles: NDArray[np.float64],
        score: NDArray[np.float64],
        max_radius_px: float,
    ) -> NDArray[np.bool_]:
        """(N,) where a score clears its floor, or its :meth:`lowest` with the X clearly ended.

        Whether an X under its floor has ended is read only for those
        (:func:`verification.x_ends`), the few the allowance concerns.

        Args:
            gray: (H, W) grey image, raw levels.
            xy: (N, 2) centres, px.
            radius: (N,) extents of the X's, px.
            angles: (N, 2) their lines' directions, radians.
            score: (N,) their scores.
            max_radius_px: the largest expected marker radius, px.
        """
        # "Not under", as :meth:`MarkerModel.judge` reads it: a NaN score is no evidence against.
        cleared = ~(score < self.floor(radius))
        under = np.flatnonzero(~cleared & ~(score < self.lowest(radius)))
        if len(under):
            cleared[under] = verification.x_ends(
                gray,
                xy[under],
                radius[under],
                angles[under],
                self.min_radius_px,
                max_radius_px,
                np.ones(len(under), dtype=bool),
            )
        return cleared


class Judgement(NamedTuple):
    """What :meth:`MarkerModel.judge` decided of each located X; each (N,).

    Attributes:
        reason: :data:`ACCEPTED`, or the index in :data:`JUDGED_REASONS` of the test
            that rejected it.
        vouched: under its score floor, the marker's model vouched for it
            (:meth:`MarkerModel.vouches`).
        stood_out: its score floor, with the allowance for an X that has clearly
            ended, would have rejected it (:meth:`ScoreFloors.clears`), and, of
            texture's size, its saddle stands out of its ground: the floors stood
            aside (:func:`stands_out`).
        unread: asked for its plate over :data:`MAX_PLATE_ASKED`, and rejected at
            that test (``quartic``) unread.
    """

    reason: NDArray[np.int8]
    vouched: NDArray[np.bool_]
    stood_out: NDArray[np.bool_]
    unread: NDArray[np.bool_]

    def passed(self, test: str) -> NDArray[np.bool_]:
        """(N,) the X's that passed ``test`` (of :data:`JUDGED_REASONS`) and every one before it."""
        return _passed(self.reason, JUDGED_REASONS, test)


@dataclass(frozen=True)
class MarkerModel:
    """The marker's model read on one frame, for the X's a gate set by texture doubts.

    Attributes:
        gray: (H, W) grey image, raw levels.
        full_scale: its white, in its own grey levels.
        noise: the frame's noise (:func:`~marker_localizer.core.noise.estimate_noise`),
            asked for only where a candidate has passed every other test (measuring
            it takes 3-6 ms on 12 MP; the detector's frame measures it once).
        max_radius_px: the largest expected marker radius, px: the template's disk,
            a shadow's reach and a reading a rung out stay within it.
        expects_tiny: whether the smallest expected marker is of texture's size
            (under :data:`verification.X_END_MAX_EXTENT_PX`): then an X of that
            size under its floor is left to the plate reading that follows the pass
            (:func:`plate.read_plates`), and every detection of that size must show
            the tiny markers' plate.
        normalise: what the checks read the frame's levels through (Eq. (2)'s local
            gamma), for the template's NCC in :meth:`match`; None: raw levels.
    """

    gray: NDArray[Any]
    full_scale: float
    noise: Callable[[], NoiseModel]
    max_radius_px: float
    expects_tiny: bool
    normalise: Normaliser | None = None

    def match(
        self,
        xy: NDArray[np.float64],
        radius: NDArray[np.float64],
        angles: NDArray[np.float64],
        ring_score: NDArray[np.float64],
        lowest: NDArray[np.float64],
        gates: TemplateGates,
        plate_budget: int = MAX_VOUCH_PLATES,
    ) -> Match:
        """Whether the paint and the blurred X bear out each X the rings passed (Sec. 3.3.1).

        In order:

        * ``modulation``: its sectors' raw levels modulate like paint
          (:func:`verification.modulation_gate`), or the marker's model vouches for
          it (:meth:`vouches`: a faint or small tilted marker);
        * ``template``: the blurred X's template matches it
          (:func:`template.template_correlation`, at least ``gates.min_ncc``), on
          the levels the checks read, or where its disk holds clipped levels, on raw
          levels without them: a marker whose white paint clips is cut off at
          white, which the template does not model (chessboards at two and a half
          times their exposure: 694 of 800 corners found, 647 with the first alone;
          docs/accuracy-journal.md, "The template's match without the clipped samples");
        * ``score``: its ring symmetry times that NCC, which the fit's score can only
          lower, reaches the ``lowest`` score of its extent
          (:meth:`ScoreFloors.lowest`), or its saddle stands out of its ground
          (:func:`stands_out`).

        Args:
            xy: (N, 2) centres, px.
            radius: (N,) extents of the X's, px.
            angles: (N, 2) their lines' directions, radians.
            ring_score: (N,) their ring symmetry.
            lowest: (N,) the lowest score of each extent.
            gates: the gates' settings.
            plate_budget: plates the model may still read in this pass of the checks
                for the modulation gate's rejects (:data:`MAX_VOUCH_PLATES` a pass), for
                the X's of the strongest rings first (``ring_score``).

        Returns:
            :class:`Match`.
        """
        gray = self.gray
        reason = np.full(len(xy), ACCEPTED, dtype=np.int8)
        modulates = verification.modulation_gate(
            gray,
            xy,
            angles,
            radius,
            np.minimum(gates.offset_px, verification.TEMPLATE_RADIUS_FRACTION * radius),
            gates.min_radius_px,
            gates.min_modulation,
        )
        faint = np.zeros(len(xy), dtype=bool)
        unread = np.zeros(len(xy), dtype=bool)
        doubted = np.flatnonzero(~modulates)
        doubted = doubted[np.argsort(-ring_score[doubted], kind="stable")]
        vouched = self._vouch(
            xy[doubted], radius[doubted], angles[doubted], over_floor=True, plate_cap=plate_budget
        )
        faint[doubted], unread[doubted] = vouched.kept, vouched.unread
        read = modulates | faint
        reason[~read] = _MODULATION
        ncc = np.full(len(xy), np.nan)
        rows = np.flatnonzero(read)
        disk = verification.template_radius(radius[rows], self.max_radius_px)
        matched = template.template_correlation(
            gray, xy[rows], angles[rows], disk, normalise=self.normalise, full_scale=self.full_scale
        )
        ncc[rows] = matched.ncc
        clip = np.flatnonzero(matched.clipped)
        ncc[rows[clip]] = np.fmax(
            ncc[rows[clip]],
            template.template_correlation(
                gray,
                xy[rows[clip]],
                angles[rows[clip]],
                disk[clip],
                full_scale=self.full_scale,
                leave_out_clipped=True,
            ).ncc,
        )
        with np.errstate(invalid="ignore"):
            fits = ncc >= gates.min_ncc
        reason[read & ~fits] = _TEMPLATE
        under = np.flatnonzero(fits & (ring_score * ncc < lowest))
        stood_out = np.zeros(len(xy), dtype=bool)
        stood_out[under] = stands_out(gray, xy[under], radius[under])
        reason[under[~stood_out[under]]] = _MATCHED_SCORE
        return Match(reason, faint, stood_out, ncc, unread, vouched.plates_read)

    def judge(
        self,
        xy: NDArray[np.float64],
        radius: NDArray[np.float64],
        angles: NDArray[np.float64],
        score: NDArray[np.float64],
        floors: ScoreFloors,
        cell_px: float,
        read_plates: bool = True,
    ) -> Judgement:
        """Whether each located X is a marker: the default path's last decision.

        In order:

        * ``score``: the fitted score reaches the :meth:`~ScoreFloors.lowest` of its
          extent, or its saddle stands out of its ground and both floors stand aside
          (:func:`stands_out`), or the marker's model vouches for it
          (:meth:`vouches`). Where tiny markers are expected (:attr:`expects_tiny`), one
          of texture's size under its floor is left to the plate reading instead: on
          texture the model vouches for such X's too.
        * ``x_end``: its X ends where its extent says (:func:`verification.x_ends`).
          One under its :meth:`~ScoreFloors.floor` that neither stood out nor the model
          vouched for must have clearly ended, and fails the floor (``score``) if not.
        * ``misfit``: the blurred X explains it (:meth:`explains`).
        * ``quartic``: its plate explains it (:meth:`plate_not_worse`), a vouched X
          having shown its plate already; of those it asks (:meth:`plate_asked`), at
          most :data:`MAX_PLATE_ASKED` are read, spread over the frame's cells of
          ``cell_px``, those that clear their floor by most first
          (:func:`screening.even_cap_index`). Without ``read_plates`` no plate is
          asked here: the plate is the ground around the X, which the pass that
          found a tracked marker has judged (the vouch still reads it, as the
          evidence that stands in for a score under the floor).

        Args:
            xy: (N, 2) fitted centres, px.
            radius: (N,) extents of the X's, px.
            angles: (N, 2) their lines' directions, radians.
            score: (N,) fitted scores.
            floors: the score floors of each extent.
            cell_px: the cells the plate's cap spreads its readings over, px.
            read_plates: ask the plates (``quartic``); False for markers whose plate
                a pass has judged.

        Returns:
            :class:`Judgement`.
        """
        reason = np.full(len(xy), ACCEPTED, dtype=np.int8)
        floor = floors.floor(radius)
        lowest = floors.lowest(radius)
        doubted = np.flatnonzero(score < floor)
        stood_out = np.zeros(len(xy), dtype=bool)
        stood_out[doubted] = stands_out(self.gray, xy[doubted], radius[doubted])
        floor[stood_out] = lowest[stood_out] = -np.inf
        # Of those, the ones the floor would have passed as clearly ended did not need it.
        aside = np.flatnonzero(stood_out)
        stood_out[aside] = ~floors.clears(
            self.gray, xy[aside], radius[aside], angles[aside], score[aside], self.max_radius_px
        )
        weak = score < lowest
        vouched = np.zeros(len(xy), dtype=bool)
        held = np.flatnonzero(weak & ~self.read_as_tiny(radius))
        vouched[held] = self.vouches(xy[held], radius[held], angles[held])
        weak &= ~vouched
        reason[weak] = _SCORE
        keep = np.flatnonzero(~weak)
        under = (score[keep] < floor[keep]) & ~vouched[keep]
        ended = verification.x_ends(
            self.gray,
            xy[keep],
            radius[keep],
            angles[keep],
            floors.min_radius_px,
            self.max_radius_px,
            under,
        )
        reason[keep[~ended]] = np.where(under[~ended], _SCORE, _X_END)
        keep = keep[ended]
        explained = self.explains(xy[keep], radius[keep], angles[keep])
        reason[keep[~explained]] = _MISFIT
        keep = keep[explained]
        unread = np.zeros(len(xy), dtype=bool)
        if not read_plates:
            return Judgement(reason, vouched, stood_out, unread)
        margin = np.where(vouched, np.inf, score - floor)
        asked = self.plate_asked(xy[keep], radius[keep], margin[keep])
        rows = np.flatnonzero(asked)
        read = screening.even_cap_index(
            xy[keep[rows]], margin[keep[rows]], MAX_PLATE_ASKED, cell_px
        )
        over = np.delete(rows, read)
        asked[over] = False
        unread[keep[over]] = True
        smooth = ~self.plate_not_worse(xy[keep], radius[keep], angles[keep], margin[keep], asked)
        reason[keep[smooth]] = _QUARTIC
        reason[unread] = _QUARTIC
        return Judgement(reason, vouched, stood_out, unread)

    def vouches(
        self,
        xy: NDArray[np.float64],
        radius: NDArray[np.float64],
        angles: NDArray[np.float64],
        *,
        over_floor: bool = False,
    ) -> NDArray[np.bool_]:
        """(N,) where the marker's model vouches for X's a gate set by texture rejected.

        The modulation gate and the score floors are set by ground texture's
        saddles of each extent, and a small tilted marker's rings measure its
        shortest reach, so its extent reads as texture's; the faintest markers
        modulate under ``min_modulation``. Where the paint or the score cannot vouch
        for a candidate, the marker's model must, tested in order of cost:

        * its X has ended at its extent
          (:func:`verification.modulation_beyond_extent` within
          :data:`verification.MAX_MODULATION_BEYOND`; not also a rung out, as
          :func:`verification.x_ends` reads it: that would read the gate's many faint
          rejects for a few markers);
        * the blurred X matches it on raw levels (:data:`FAINT_MIN_NCC`);
        * the marker on its plate, at the X's scale and each bright quadrant with its
          own level (a dull one's), explains its window better than a smooth surface
          does (:func:`plate.plate_evidence` within :data:`plate.MAX_TO_QUARTIC`, the
          bound at which that model adds a tiny marker): a texture X that the blurred
          X explains has no plate;
        * the blurred X explains its disk up to the noise (:data:`FAINT_MAX_MISFIT`).

        ``over_floor``: the X's rings scored it over its floor, and only its paint is
        doubted (the modulation gate's): the blurred X is held to the looser
        :data:`GATE_MIN_NCC` and :data:`GATE_MAX_MISFIT`.
        """
        return self._vouch(xy, radius, angles, over_floor=over_floor).kept

    def _vouch(
        self,
        xy: NDArray[np.float64],
        radius: NDArray[np.float64],
        angles: NDArray[np.float64],
        *,
        over_floor: bool = False,
        plate_cap: int | None = None,
    ) -> _Vouched:
        """:meth:`vouches`; the plate read for the first ``plate_cap`` X's that get so far.

        Those after them are not vouched for, and marked unread; None: no cap.
        """
        min_ncc, max_misfit = (
            (GATE_MIN_NCC, GATE_MAX_MISFIT) if over_floor else (FAINT_MIN_NCC, FAINT_MAX_MISFIT)
        )
        gray = self.gray
        kept = np.zeros(len(xy), dtype=bool)
        unread = np.zeros(len(xy), dtype=bool)
        beyond = verification.modulation_beyond_extent(gray, xy, radius, angles)
        passing = np.flatnonzero(beyond <= verification.MAX_MODULATION_BEYOND)
        disk = verification.template_radius(radius[passing], self.max_radius_px)
        ncc = template.template_correlation(gray, xy[passing], angles[passing], disk).ncc
        matched = ncc >= min_ncc
        passing, disk, ncc = passing[matched], disk[matched], ncc[matched]
        if plate_cap is not None and len(passing) > plate_cap:
            unread[passing[plate_cap:]] = True
            passing, disk, ncc = passing[:plate_cap], disk[:plate_cap], ncc[:plate_cap]
        plates_read = len(passing)
        plated = self.plate_at_scale(
            xy[passing], radius[passing], angles[passing], plate.MAX_TO_QUARTIC
        )
        with np.errstate(invalid="ignore"):
            held = plated <= plate.MAX_TO_QUARTIC
        passing, disk, ncc = passing[held], disk[held], ncc[held]
        # The frame's noise, which the misfit needs, is measured last, where a
        # candidate has passed every other test (3-6 ms on 12 MP).
        if len(passing):
            misfit = template.template_misfit(
                gray, xy[passing], angles[passing], disk, ncc, self.noise()
            )
            kept[passing] = misfit <= max_misfit
        return _Vouched(kept, unread, plates_read)

    def explains(
        self,
        xy: NDArray[np.float64],
        radius: NDArray[np.float64],
        angles: NDArray[np.float64],
    ) -> NDArray[np.bool_]:
        """(N,) where the blurred X explains a detection's disk up to the noise.

        Its misfit (:func:`template.template_misfit`, over the template's disk) is
        at most :data:`MAX_TEMPLATE_MISFIT`, or a cast shadow's straight edge crosses
        it, which the X does not model. X's of texture's size (under
        :data:`verification.X_END_MAX_EXTENT_PX`) are not asked: their disk is the
        template's smallest, a few pixels a quadrant, and whether they end where
        their extent does (:func:`verification.x_ends`) is what parts them from
        texture (asked, it fails tiny markers and takes no false point). 1 - NCC^2
        bounds the misfit from above, so the frame's noise is estimated only where a
        detection could fail. Both leave clipped samples out (``full_scale``): a
        marker whose white paint clips is cut off at white, which the X does not
        model either (chessboards at twice their exposure: 0.11 at their true
        corners and lines, median, 0.004 without them).
        """
        doubtful = np.flatnonzero(radius >= verification.X_END_MAX_EXTENT_PX)
        disk = verification.template_radius(radius, self.max_radius_px)
        if len(doubtful):
            ncc = template.template_correlation(
                self.gray,
                xy[doubtful],
                angles[doubtful],
                disk[doubtful],
                full_scale=self.full_scale,
                leave_out_clipped=True,
            ).ncc
            could_fail = 1.0 - np.square(ncc) > MAX_TEMPLATE_MISFIT
            doubtful, ncc = doubtful[could_fail], ncc[could_fail]
        if len(doubtful):
            misfit = template.template_misfit(
                self.gray,
                xy[doubtful],
                angles[doubtful],
                disk[doubtful],
                ncc,
                self.noise(),
                full_scale=self.full_scale,
            )
            doubtful = doubtful[misfit > MAX_TEMPLATE_MISFIT]
        if len(doubtful):
            doubtful = doubtful[
                ~self.shadow_crosses(xy[doubtful], radius[doubtful], angles[doubtful])
            ]
        explained = np.ones(len(xy), dtype=bool)
        explained[doubtful] = False
        return explained

    def shadow_crosses(
        self,
        xy: NDArray[np.float64],
        radius: NDArray[np.float64],
        angles: NDArray[np.float64],
    ) -> NDArray[np.bool_]:
        """(N,) where a cast shadow's straight edge crosses a detection (:func:`shadow.find_edges`).

        Sought within :data:`shadow.DETECTION_REACH_EXTENTS` of its extent, at most the
        largest expected radius.
        """
        reach = np.minimum(shadow.DETECTION_REACH_EXTENTS * radius, self.max_radius_px)
        return shadow.find_edges(self.gray, xy, reach, angles, self.full_scale).found

    def plate_a_rung_out(
        self,
        xy: NDArray[np.float64],
        radius: NDArray[np.float64],
        angles: NDArray[np.float64],
    ) -> NDArray[np.bool_]:
        """(N,) where a tiny X is a larger marker read short, and shows its plate there.

        Its pattern goes on beyond its extent, where a marker could reach a rung out
        (:func:`verification.reaches_a_rung_out`; :func:`verification.x_ends` has
        found it ended there), and the plate
        model at that reach, at the X's scale and each bright quadrant with its own
        level, leaves no more than a quartic does. The tiny markers' plate model
        (radii of 2.25-5.25 px) misses such a marker's plate.
        """
        gray = self.gray
        shown = np.zeros(len(xy), dtype=bool)
        short = np.flatnonzero(verification.reaches_a_rung_out(radius, self.max_radius_px))
        beyond = verification.modulation_beyond_extent(
            gray, xy[short], radius[short], angles[short]
        )
        short = short[beyond > verification.MAX_MODULATION_BEYOND]
        if len(short):
            further = verification.RING_STEP * radius[short]
            plated = self.plate_at_scale(
                xy[short], further, angles[short], plate.MAX_TO_QUARTIC_ANY
            )
            with np.errstate(invalid="ignore"):
                shown[short] = ~(plated > plate.MAX_TO_QUARTIC_ANY)
        return shown

    def plate_at_scale(
        self,
        xy: NDArray[np.float64],
        extent: NDArray[np.float64],
        angles: NDArray[np.float64],
        bar: float | NDArray[np.float64] | None = None,
    ) -> NDArray[np.float64]:
        """(N,) the plate model's residual over a quartic's, read for an X of ``extent``.

        :func:`plate.plate_evidence` with its radii at the X's scale and each bright
        quadrant its own level (a dull quadrant): the plate every test of a marker
        wider than a tiny one reads. The test's ``bar`` (scalar or (N,)) spares the
        full search where the coarse one already clears it. NaN where no window can
        be read.
        """
        return plate.plate_evidence(
            self.gray,
            xy,
            extent,
            angles,
            scale_with_extent=True,
            quadrant_levels=True,
            enough_to_quartic=bar,
        ).to_quartic

    def stands_alone(
        self,
        xy: NDArray[np.float64],
        radius: NDArray[np.float64],
        angles: NDArray[np.float64],
    ) -> NDArray[np.bool_]:
        """(N,) where the ground around an X does not repeat it as a lattice would.

        A marker stands alone on its plate. The saddles between the rows of a
        lattice (discs, studs, lids) score and fit as X's do, but the X's disk
        recurs on both sides of each (:data:`MIN_LATTICE_RECURRENCE`). A
        chessboard repeats its corners too, and is spared: its lines go on as edges
        beyond the corner (:data:`MIN_BOARD_CONTINUATION`).
        """
        alone = np.ones(len(xy), dtype=bool)
        repeated = np.flatnonzero(
            verification.disk_recurrence(self.gray, xy, radius) >= MIN_LATTICE_RECURRENCE
        )
        if len(repeated):
            continued = verification.line_continuation(
                self.gray, xy[repeated], radius[repeated], angles[repeated]
            )
            alone[repeated] = continued >= MIN_BOARD_CONTINUATION
        return alone

    def _plate_worse(
        self,
        xy: NDArray[np.float64],
        scale: NDArray[np.float64],
        angles: NDArray[np.float64],
        bar: NDArray[np.float64],
        unread_passes: bool = True,
    ) -> NDArray[np.bool_]:
        """(N,) where :meth:`plate_at_scale` leaves more than ``bar`` of a quartic at both reads.

        Read at ``scale`` and, where that leaves more, a ring rung out: the ring ladder
        reads an X's extent up to a rung short of its shortest reach, and a window
        at the extent cuts such a plate short. A window off the image (NaN) passes
        where ``unread_passes``.
        """
        worse: NDArray[np.bool_] = np.ones(len(xy), dtype=bool)
        for rung in (1.0, verification.RING_STEP):
            rows = np.flatnonzero(worse)
            if len(rows):
                plated = self.plate_at_scale(xy[rows], rung * scale[rows], angles[rows], bar[rows])
                with np.errstate(invalid="ignore"):
                    worse[rows] = plated > bar[rows] if unread_passes else ~(plated <= bar[rows])
        return worse

    def read_as_tiny(self, radius: NDArray[np.float64]) -> NDArray[np.bool_]:
        """(N,) the X's the tiny markers' plate reading judges, not the model's vouch.

        Where tiny markers are expected (:attr:`expects_tiny`), those of
        texture's size (under :data:`verification.X_END_MAX_EXTENT_PX`).
        """
        tiny: NDArray[np.bool_] = self.expects_tiny & (radius < verification.X_END_MAX_EXTENT_PX)
        return tiny

    def plate_asked(
        self,
        xy: NDArray[np.float64],
        radius: NDArray[np.float64],
        margin: NDArray[np.float64],
    ) -> NDArray[np.bool_]:
        """(N,) the detections whose plate :meth:`plate_not_worse` reads (it says who is asked).

        A board's corner is spared before any plate is read: on a chessboard every
        corner is, and the plate is the costliest reading. ``xy`` holds every
        detection of the call, the neighbours among them.
        """
        read_tiny = self.read_as_tiny(radius)
        doubted = margin < PLATE_DOUBT_MARGIN
        asked = ~read_tiny & (doubted | (radius < PLATE_ASKED_MAX_EXTENT_PX))
        rows = np.flatnonzero(asked)
        if len(rows):
            # Every detection is within 0 of itself: a neighbour makes the count 2.
            near = cKDTree(xy).query_ball_point(
                xy[rows], BOARD_NEIGHBOUR_EXTENTS * radius[rows], return_length=True
            )
            asked[rows[near >= 2]] = False
        return read_tiny | asked

    def plate_not_worse(
        self,
        xy: NDArray[np.float64],
        radius: NDArray[np.float64],
        angles: NDArray[np.float64],
        margin: NDArray[np.float64],
        asked: NDArray[np.bool_] | None = None,
    ) -> NDArray[np.bool_]:
        """(N,) False for detections whose plate model, where asked, leaves more than a quartic.

        What a marker has and texture has not is the plate around its X. Asked are
        (:meth:`plate_asked`):

        * where tiny markers are expected (:attr:`expects_tiny`), every
          detection of texture's size (under :data:`verification.X_END_MAX_EXTENT_PX`):
          the model of a marker on its plate (:func:`plate.plate_evidence`) must explain it at
          least as well as the best quartic (:data:`plate.MAX_TO_QUARTIC_ANY`),
          or, where its X goes on to a rung out, that of a larger marker there
          (:meth:`plate_a_rung_out`);
        * every other detection of texture's size (under
          :data:`PLATE_ASKED_MAX_EXTENT_PX`: a marker tilted to that shortest
          reach, or a saddle of blurred sand): the same, with the model at the X's
          scale and each bright quadrant's own level (a dull quadrant) (:meth:`plate_at_scale`);
        * every detection that clears its score floor by less than
          :data:`PLATE_DOUBT_MARGIN` (``margin``: its score less its floor), where
          ground texture's false points score: so read, within
          :data:`PLATE_DOUBT_MAX_TO_QUARTIC` of the quartic's residual.

        Both read the plate at the X's extent and a ring rung out; the first, where
        the X reaches farther along its lines (:func:`template.line_reaches`: rings
        that stopped short of a larger marker), at that reach and a rung out too.
        Each passes at the best of these, or where another detection lies within
        :data:`BOARD_NEIGHBOUR_EXTENTS` of its extent (a chessboard's corner).

        NaN (no window) passes at the extent and a rung out, not at the reach.
        ``xy`` holds every detection of the call, the neighbours among them.
        ``asked``: (N,) which to read, where the caller has settled it already;
        None: :meth:`plate_asked`.
        """
        kept: NDArray[np.bool_] = np.ones(len(xy), dtype=bool)
        if asked is None:
            asked = self.plate_asked(xy, radius, margin)
        read_tiny = asked & self.read_as_tiny(radius)
        tiny = np.flatnonzero(read_tiny)
        if len(tiny):
            evidence = plate.plate_evidence(
                self.gray,
                xy[tiny],
                radius[tiny],
                angles[tiny],
                enough_to_quartic=plate.MAX_TO_QUARTIC_ANY,
            )
            with np.errstate(invalid="ignore"):
                kept[tiny] = ~(evidence.to_quartic > plate.MAX_TO_QUARTIC_ANY)
            failed = tiny[~kept[tiny]]
            kept[failed] = self.plate_a_rung_out(xy[failed], radius[failed], angles[failed])
        doubted = margin < PLATE_DOUBT_MARGIN
        unheld = np.flatnonzero(asked & ~read_tiny)
        if not len(unheld):
            return kept
        bar = np.where(doubted[unheld], PLATE_DOUBT_MAX_TO_QUARTIC, plate.MAX_TO_QUARTIC_ANY)
        worse = self._plate_worse(xy[unheld], radius[unheld], angles[unheld], bar)
        unheld, bar = unheld[worse], bar[worse]
        # Rings that stop short of a larger marker's X leave its plate beyond a rung
        # out: one asked for its size alone is read again at the X's own reach along
        # its lines.
        for_size = np.flatnonzero(~doubted[unheld])
        if len(for_size):
            rows = unheld[for_size]
            reach = template.line_reaches(
                self.gray, xy[rows], angles[rows], radius[rows], self.max_radius_px
            )
            with np.errstate(invalid="ignore"):
                farther = np.flatnonzero(reach > verification.RING_STEP * radius[rows])
            worse = np.ones(len(unheld), dtype=bool)
            # Only a plate read there spares it: an X whose lines run on out of the
            # frame has shown none.
            worse[for_size[farther]] = self._plate_worse(
                xy[rows[farther]],
                reach[farther],
                angles[rows[farther]],
                bar[for_size[farther]],
                unread_passes=False,
            )
            unheld = unheld[worse]
        kept[unheld] = False
        return kept
