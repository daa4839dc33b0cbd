"""The default path: grey-level symmetry checks, the point-symmetry fit, second readings.

After the saddle screening: a three-ring prescreen (:meth:`SymmetryPath.prescreen`),
the coarse centring, the ring check and its score floor, the paint's and the
template's gates, the sub-pixel fit of section 3.3 with its gates, the marker's
model (:mod:`acceptance`), the double-line check and the last suppression. Then
the second readings of what that lost (:mod:`second_reading`, :mod:`plate`):
wide candidates centred again with the light's slope, read again with a shadow's
edge divided out, and tiny X's judged by their plate. Also the fit and gates of
the paper's checks with ``refinement="symmetry"`` or ``"ncc"``
(:mod:`paper_path`), and of a tracking pass's known markers
(:meth:`SymmetryPath.confirm_tracked`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from marker_localizer.config import DetectorConfig
from marker_localizer.core import (
    acceptance,
    plate,
    preprocessing,
    screening,
    second_reading,
    subpixel,
    verification,
)
from marker_localizer.core.frame import Frame
from marker_localizer.core.result import (
    Detection,
    DetectionResult,
    detections_of,
    extents,
    line_directions,
    positions,
    scores,
    sigmas,
    strongest_first,
)
from marker_localizer.core.screening import Candidates

#: The most prescreened candidates of a frame that go on to the centring, verification
#: and fit (0.25-0.5 ms each on one core), spread over the frame as Eq. (7) spreads
#: them: a safety net above every real frame measured, which bounds pathological ones
#: (a 12 MP tiling of X's, whose candidates all pass the prescreen).
MAX_VERIFIED = 5000
#: The most candidates of a frame that pass the ring checks, the template NCC, the
#: modulation gate and their score floor and go on to the double-line check, the fit
#: and the judgement of the ground around them; the template is matched cell by cell,
#: the best ring symmetry first, only until this many have passed
#: (:meth:`SymmetryPath._match_templates`). Real ground never reaches it; a 12 MP tiling
#: of X's passes all of the prescreen's cap. What it bounds is 2-5 ms each on one core
#: for X's of 12-40 px (the fit over their disks, the lattice test): a 12 MP frame filled
#: with a chessboard of such squares, 800 corners, takes 2.4-4.7 s on a loaded host; an
#: aerial marker field holds far fewer, and a lower cap would cut a large one's.
MAX_CONFIRMED = 800
#: Fewest candidates matched at once while the cap is not reached: fewer calls.
_MIN_TEMPLATE_BATCH = 256
#: The prescreen's rings, and every detection's fit, need this share of
#: ``min_contrast_dn`` in raw (not gamma-corrected) grey levels: lenient, as the rings
#: may sit off the centre and gamma stretches dark ground.
_RAW_CONTRAST_SHARE = 0.5
#: The judged reasons whose test :data:`SURVIVOR_TESTS` names otherwise: the fitted
#: score's floor is the third of the floors.
_JUDGED_TEST_NAMES = {"score": "fit_floor"}
#: :data:`SURVIVOR_TESTS`' names of :meth:`acceptance.MarkerModel.judge`'s tests, one per
#: :data:`acceptance.JUDGED_REASONS`, in its order.
_JUDGED_TESTS = tuple(
    _JUDGED_TEST_NAMES.get(reason, reason) for reason in acceptance.JUDGED_REASONS
)
#: The tests of the default path in the order :attr:`DetectionResult.survivors` lists
#: them, each name once, so that where a marker was lost names one test
#: (:func:`~marker_localizer.evaluation.tests_that_lost`). ``prescreen_cap`` and
#: ``fit_cap`` cap the candidates the prescreen passes and those the fit takes (both
#: counted as ``dropped_over_verification_cap``); the score floor of an X's extent
#: (:class:`acceptance.ScoreFloors`) runs three times: ``symmetry_floor`` on the ring
#: symmetry, ``template_floor`` on it times the template's NCC and ``fit_floor`` on
#: the fitted score (all three counted as ``rejected_score``); ``x_end``, that a small
#: X ends where its extent does (:func:`verification.x_ends`); ``misfit``, that the
#: blurred X explains the detection (:meth:`acceptance.MarkerModel.explains`);
#: ``quartic``, that the plate model of a tiny X, or of one that barely clears its
#: floor, explains it no worse than a smooth surface
#: (:meth:`acceptance.MarkerModel.plate_not_worse`); ``lattice``, after the last
#: suppression, that the ground does not repeat the detection
#: (:meth:`acceptance.MarkerModel.stands_alone`); ``recentring``, the detections once
#: the lost wide candidates are centred again, and ``shadow``, once they are read
#: again with a shadow's edge divided out: the two tests that add,
#: :meth:`SymmetryPath._recentre_lost` and :meth:`SymmetryPath._reread_shadowed`;
#: ``plate``, once the X's of texture's size that found no marker are read with their
#: plate, :meth:`SymmetryPath._read_plates`).
SURVIVOR_TESTS = (
    "screening",
    "prescreen",
    "prescreen_cap",
    "centring",
    "symmetry",
    "symmetry_floor",
    "modulation",
    "template",
    "template_floor",
    "fit_cap",
    "fit",
    *_JUDGED_TESTS,
    "lines",
    "merging",
    "lattice",
    "recentring",
    "shadow",
    "plate",
)
#: The readings that add detections, by the survivor list that closes each, in the
#: order they run: the first pass ends with ``lattice``; the second readings each list
#: every detection once theirs have joined (:meth:`SymmetryPath._join`), and move none
#: of the earlier ones. :func:`~marker_localizer.evaluation.readings_that_added` finds
#: which of them added a detection.
READINGS = {
    "lattice": "first pass",
    "recentring": "recentring",
    "shadow": "shadow",
    "plate": "plate",
}
#: Candidates centred closer than this to a stronger one have found its X, px.
_CENTRED_DUPLICATE_PX = 1.5


class _RingPassed(NamedTuple):
    """Candidates the ring check passed, with what it measured.

    Attributes:
        xy: (N, 2) centres, px.
        radius_px: (N,) extents of the X, px.
        line_angles: (N, 2) line directions, radians.
        score: (N,) ring symmetry.
    """

    xy: NDArray[np.float64]
    radius_px: NDArray[np.float64]
    line_angles: NDArray[np.float64]
    score: NDArray[np.float64]


class SymmetryPath:
    """The default path's checks, fit and second readings of one detector's config; build once."""

    def __init__(
        self,
        config: DetectorConfig,
        shadowed: preprocessing.ShadowedContrast,
        seed_scale_px: float,
    ) -> None:
        """Build the path for ``config``.

        Args:
            config: the detector's parameters.
            shadowed: the screening's :attr:`~search.CandidateSearch.shadowed`: the
                prescreen's ring floor, the fit's contrast floor and the double-line
                check follow the light into a shadow as the screening's threshold does.
            seed_scale_px: the scale a seeded or tracked marker is centred at, as a
                candidate of the first pyramid level
                (:attr:`~search.CandidateSearch.seed_scale_px`), px.
        """
        self.config = config
        self._seed_scale_px = seed_scale_px
        #: The ring check's ladder of radii (:func:`verification.ring_radii`), px; the
        #: paper's annular check reads the same rings.
        self.ring_radii_px = verification.ring_radii(
            (config.marker_radius_min_px, config.marker_radius_max_px)
        )
        self._floors = acceptance.ScoreFloors(
            config.min_score, config.min_score_small, config.marker_radius_min_px
        )
        self._template_gates = acceptance.TemplateGates(
            config.template_offset_px,
            config.marker_radius_min_px,
            config.min_modulation,
            config.template_ncc_min,
        )
        self._shadowed = shadowed

    def prescreen(self, frame: Frame, candidates: Candidates) -> Candidates:
        """A three-ring centre-symmetry test at each candidate's own scale, before any fit.

        Lenient per ring (the candidate may sit a fraction of its scale off the
        centre; raw grey levels, half the contrast) but strict over the rings (all
        three), it removes ~95 % of the texture saddles for the price of at most
        108 nearest-pixel samples each (the cascade stops at the first bad ring).
        At most :data:`MAX_VERIFIED` of those that pass go on, spread over the
        frame as Eq. (7)'s thinning spreads them (:func:`screening.even_cap`); the
        rest are cut and counted. Candidates screened beyond texture's scale
        (:data:`second_reading.WIDE_SCALE_PX`) that fail are read again with the
        bright sectors equalised (:func:`verification.ring_check` says why and when).
        """
        gray, result = frame.gray, frame.result
        floor = self._raw_contrast_floor(frame.full_scale, frame.gamma, candidates.xy)
        radii = verification.prescreen_ring_radii(
            candidates.scale_px, self.config.marker_radius_min_px
        )
        keep, first_ring = verification.prescreen_symmetry(gray, candidates.xy, radii, floor)
        wide = np.flatnonzero(~keep & second_reading.screened_wide(candidates))
        # The equalised re-read takes the first rings the plain one gathered.
        keep[wide] = verification.prescreen_symmetry(
            gray, candidates.xy[wide], radii[wide], floor[wide], True, first_ring[wide]
        )[0]
        result.counts["rejected_prescreen"] = int((~keep).sum())
        passed = candidates.take(keep)
        capped = screening.even_cap(passed, MAX_VERIFIED, self.config.entropy_cell_px)
        result.counts["dropped_over_verification_cap"] = len(passed) - len(capped)
        result.survivors += [("prescreen", passed.xy), ("prescreen_cap", capped.xy)]
        return capped

    def confirm(self, frame: Frame, candidates: Candidates) -> DetectionResult:
        """Centre, verify and locate the candidates of the saddle path."""
        result = frame.result
        plain, centred = self._centring(frame, candidates)
        result.detections, tiny = self._verify_and_locate(frame, centred)
        self._recentre_lost(frame, candidates, plain)
        self._reread_shadowed(frame, candidates)
        self._read_plates(frame, tiny)
        result.counts["accepted"] = len(result.detections)
        return result

    def confirm_tracked(self, frame: Frame, xy: NDArray[np.float64]) -> DetectionResult:
        """Markers known to be near ``xy``, read again as :meth:`confirm` reads a candidate.

        Each from its centring on: the ring check measures its extent and line
        directions on this frame, its template and the fit follow, with their gates
        and score, and the double-line check where :meth:`confirm` asks it after the
        fit; tiny X's the fit's floors reject are asked for their plate
        (:meth:`_confirm_plates`). A tracked marker is then located and judged as a
        full pass would: with its extent and directions as they were when last
        measured, its centre moved by up to 0.05 px, and an X of texture that a pass
        let through stayed on the frames after it, where the rings and the template
        reject it (measured: docs/speed.md, "A tracked marker read again from its
        centring"). The screening and the prescreen are not asked: their saddle peaks
        and rings are for finding an X, not judging one found. The ground around each
        marker, its plate and whether it recurs as a lattice's saddle, is not read
        again: the pass that found it judged it, a camera's motion does not change
        it, and a full pass judges it again (measured: docs/speed.md, "What a tracked
        frame judges again").
        """
        result = frame.result
        _, centred = self._centring(frame, Candidates.seeded(xy, self._seed_scale_px))
        with frame.timer("verification"):
            centred, radius, angles, score, stood_out, tiny = self._verify(frame, centred)
        with frame.timer("subpixel"):
            result.detections = self.locate(
                frame,
                centred.xy,
                radius,
                angles,
                score,
                check_lines=self._lines_after_fit,
                read_ground=False,
                stood_out=stood_out,
            )
        self._confirm_plates(frame, tiny)
        result.counts["accepted"] = len(result.detections)
        return result

    def _confirm_plates(self, frame: Frame, known: _RingPassed) -> None:
        """Tracked tiny X's the fit's floors reject, confirmed by their plate.

        A full pass finds many tiny markers by their plate alone
        (:meth:`_read_plates`), under the score floors :meth:`locate` holds a
        tracked marker to, so that tracking alone loses markers a full pass finds
        (measured: docs/method.md, "A tiny X is judged by its plate"). The tracked X's
        of texture's size (``known``, :meth:`_verify`'s: none where plates are not
        read) that :meth:`locate` left without a marker are fitted
        (:meth:`_fit_plates`) and kept where the plate model explains them at the
        fitted centre (:func:`plate.explains_at`). Counted as ``found_plate``.
        """
        result = frame.result
        result.counts["found_plate"] = 0
        lost = self._far_from_detections(result, known.xy)
        if not len(lost):
            return
        with frame.timer("subpixel"):
            fitted = self._fit_plates(frame, known, lost)
        result.counts["found_plate"] = self._join(result, self._plated(frame, fitted))

    def _plated(self, frame: Frame, fitted: list[Detection]) -> list[Detection]:
        """The fitted tiny X's whose plate explains them at their fitted centre.

        :func:`plate.explains_at` on the fit's centres: a full pass and a tracked
        frame take the same decision at the same place, wherever their candidates
        started (a full pass's plate reading, at the ring check's centre, comes within
        a few hundredths of the bars on a few markers and reads otherwise there).
        """
        if not fitted:
            return []
        with frame.timer("plate"):
            explained = plate.explains_at(
                frame.gray,
                positions(fitted),
                extents(fitted),
                line_directions(fitted),
            )
        return [d for d, ok in zip(fitted, explained, strict=True) if ok]

    def _verify_and_locate(
        self, frame: Frame, candidates: Candidates
    ) -> tuple[list[Detection], _RingPassed]:
        """The checks, the template match and the fit of centred candidates: their markers.

        Also the tiny X's the ring check passed (:meth:`_verify`), for
        :meth:`_read_plates`.
        """
        with frame.timer("verification"):
            candidates, radius, angles, score, stood_out, tiny = self._verify(frame, candidates)
        with frame.timer("subpixel"):
            located = self.locate(
                frame,
                candidates.xy,
                radius,
                angles,
                score,
                check_lines=self._lines_after_fit,
                stood_out=stood_out,
            )
        return located, tiny

    def _recentre_lost(
        self,
        frame: Frame,
        screened: Candidates,
        plain: tuple[NDArray[np.float64], NDArray[np.bool_]],
    ) -> None:
        """Lost wide candidates centred again with the light's slope, and read once more.

        Those :func:`second_reading.lost_wide` gives, at most
        :data:`second_reading.MAX_RECENTRED`, are centred by
        :func:`second_reading.recentred`; those the slope moved go through the checks
        and the fit once more, and a marker they find joins the detections.
        ``plain`` is the first centring of every screened candidate (:meth:`_centre`'s
        fit: centres and where it found one).

        Counts ``recentred``, the candidates read again, ``found_recentred``, the
        markers they added, and ``recentring_over_cap``, the lost wide candidates
        over the cap; their second rejections are not counted again. The survivors
        end with ``recentring``: the detections then.
        """
        result = frame.result
        counts = result.counts
        lost, counts["recentring_over_cap"] = self._lost_wide(
            result, screened, second_reading.MAX_RECENTRED
        )
        counts["recentred"] = counts["found_recentred"] = 0
        if len(lost):
            with frame.timer("centring"):
                again = second_reading.recentred(
                    frame.gray,
                    screened.take(lost),
                    plain[0][lost],
                    plain[1][lost],
                    self.config.marker_radius_max_px,
                )
            counts["recentred"] = len(again.xy)
            counts["found_recentred"] = self._join(
                result, self._verify_and_locate(frame.reread(), again)[0]
            )
        result.survivors.append(("recentring", positions(result.detections)))

    def _reread_shadowed(self, frame: Frame, screened: Candidates) -> None:
        """Lost wide candidates a shadow's edge crosses, read again with it divided out.

        Those :func:`second_reading.lost_wide` gives after the recentring, at most
        :data:`second_reading.MAX_SHADOW_READ`, are read by
        :func:`second_reading.shadowed` on their first prescreen ring's line
        directions. The checks and the fit read those a shadow crosses in the frame
        with the shadows divided out; a marker found is located once more in the
        frame itself, by its model with the shadow's edge
        (:func:`second_reading.located_in_shadow`, X's of
        :data:`subpixel.MEASURED_MIN_EXTENT_PX` and more), and joins the detections.

        Counts ``shadow_read``, the candidates read again, ``found_shadowed``, the
        markers they added, ``located_in_shadow``, those of them the model located,
        and ``shadow_over_cap``, the lost wide candidates over the cap. The survivors
        end with ``shadow``: the detections then.
        """
        gray, result = frame.gray, frame.result
        counts = result.counts
        lost, counts["shadow_over_cap"] = self._lost_wide(
            result, screened, second_reading.MAX_SHADOW_READ
        )
        counts["shadow_read"] = counts["found_shadowed"] = counts["located_in_shadow"] = 0
        if len(lost):
            with frame.timer("shadow"):
                chosen = screened.take(lost)
                reading = second_reading.shadowed(
                    gray,
                    chosen,
                    verification.prescreen_line_directions(
                        gray, chosen.xy, chosen.scale_px, self.config.marker_radius_min_px
                    ),
                    self.config.marker_radius_max_px,
                    frame.full_scale,
                )
            counts["shadow_read"] = len(reading.read.xy)
            found: list[Detection] = []
            if len(reading.read.xy):
                with frame.timer("centring"):
                    centred = second_reading.slope_centred(
                        reading.lit, reading.read, self.config.marker_radius_max_px
                    )
                lit = replace(frame.reread(), gray=reading.lit)
                found = self._verify_and_locate(lit, centred)[0]
            if found:
                xy, sigma, located = second_reading.located_in_shadow(
                    gray,
                    positions(found),
                    sigmas(found),
                    line_directions(found),
                    extents(found),
                    frame.full_scale,
                    reading,
                )
                counts["located_in_shadow"] = int(located.sum())
                found = [
                    replace(d, x=float(x), y=float(y), sigma=float(e))
                    for d, (x, y), e in zip(found, xy, sigma, strict=True)
                ]
            counts["found_shadowed"] = self._join(result, found)
        result.survivors.append(("shadow", positions(result.detections)))

    def _lost_wide(
        self, result: DetectionResult, screened: Candidates, cap: int
    ) -> tuple[NDArray[np.intp], int]:
        """:func:`second_reading.lost_wide` of the screened candidates, against the detections."""
        return second_reading.lost_wide(
            screened,
            positions(result.detections),
            self.config.merge_radius_px,
            cap,
            self.config.entropy_cell_px,
        )

    def _far_from_detections(
        self, result: DetectionResult, xy: NDArray[np.float64]
    ) -> NDArray[np.intp]:
        """Indices of the points farther than the merge radius from every detection."""
        return second_reading.far_from(
            positions(result.detections), xy, self.config.merge_radius_px
        )

    def _join(self, result: DetectionResult, added: list[Detection]) -> int:
        """Add a second reading's markers to the detections; returns how many joined.

        A duplicate (:func:`second_reading.new_points`) is counted in
        ``merged_duplicates``.
        """
        if not added:
            return 0
        unique = second_reading.new_points(
            positions(result.detections),
            positions(added),
            scores(added),
            self.config.merge_radius_px,
        )
        result.counts["merged_duplicates"] += int((~unique).sum())
        joined = [d for d, keep in zip(added, unique, strict=True) if keep]
        result.detections = sorted(result.detections + joined, key=lambda d: -d.score)
        return len(joined)

    def _raw_contrast_floor(
        self, full_scale: float, gamma: preprocessing.LocalGamma, xy: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """(N,) :data:`_RAW_CONTRAST_SHARE` of the configured contrast in raw grey units at ``xy``.

        The prescreen's ring floor, which every detection's fit also meets; lowered
        in shadow (:class:`preprocessing.ShadowedContrast`) as the screening's threshold is.
        """
        floor = _RAW_CONTRAST_SHARE * self.config.min_contrast_share * full_scale
        gain = self._shadowed.gain_at(gamma, xy)
        return np.full(len(xy), floor) if gain is None else floor / gain

    def _centring(
        self, frame: Frame, candidates: Candidates
    ) -> tuple[tuple[NDArray[np.float64], NDArray[np.bool_]], Candidates]:
        """The centring stage: :func:`subpixel.coarse_centre`'s fit, and :meth:`_centre`'s."""
        with frame.timer("centring"):
            plain = subpixel.coarse_centre(
                frame.gray, candidates.xy, candidates.scale_px, self.config.marker_radius_max_px
            )
            return plain, self._centre(candidates, plain, frame.result)

    def _centre(
        self,
        candidates: Candidates,
        fit: tuple[NDArray[np.float64], NDArray[np.bool_]],
        result: DetectionResult,
    ) -> Candidates:
        """Each candidate at its local centre of point symmetry, those centred apart.

        ``fit`` is :func:`subpixel.coarse_centre` of the candidates: their centres, and
        where it found one. :meth:`_recentre_lost` reads it again. Candidates centred
        together are one, screened as widely as the widest of them
        (:meth:`Candidates.without_duplicates`).
        """
        xy, inside = fit
        result.counts["rejected_centring"] = int((~inside).sum())
        moved = Candidates(xy, candidates.strength, candidates.scale_px).take(inside)
        centred, merged = moved.without_duplicates(_CENTRED_DUPLICATE_PX)
        result.counts["merged_duplicates"] = merged
        result.survivors.append(("centring", centred.xy))
        return centred

    def _verify(
        self, frame: Frame, candidates: Candidates
    ) -> tuple[
        Candidates,
        NDArray[np.float64],
        NDArray[np.float64],
        NDArray[np.float64],
        NDArray[np.bool_],
        _RingPassed,
    ]:
        """Section 3.2, geometric checks, and the adaptive-template NCC of section 3.3.1.

        Returns the candidates that passed, their extents, line directions and
        scores, which of them the ring symmetry's or the template's floor stood
        aside for (:func:`acceptance.stands_out`), and the X's of texture's size
        (:data:`verification.X_END_MAX_EXTENT_PX`) that passed the ring check and
        its floor, for :meth:`_read_plates`.
        """
        cfg = self.config
        gray, result = frame.gray, frame.result
        counts = result.counts
        candidates, symmetry, equalised_x = self._ring_check(gray, candidates, frame.gamma)
        candidates, symmetry = self._read_dull(frame, candidates, symmetry, equalised_x)
        keep = symmetry.accepted & verification.reaches_extent(
            symmetry.radius_px, cfg.min_extent_fraction, cfg.marker_radius_min_px
        )
        counts["rejected_symmetry"] = int((~keep).sum())
        # A detection's score is this ring symmetry times factors of at most 1 (the
        # template's NCC, the fit's 1 - relative residual): a candidate already below
        # its floor stays below it, and is spared the costly checks and the fit.
        # Under its own floor, a candidate goes on only if its X has clearly ended: read
        # here on the rings' centre and lines, it spares the template match the ground's
        # saddles the allowance would let in.
        checked = np.flatnonzero(keep)
        weak = keep.copy()
        weak[checked] = ~self._floors.clears(
            gray,
            candidates.xy[checked],
            symmetry.radius_px[checked],
            symmetry.line_angles[checked],
            symmetry.score[checked],
            cfg.marker_radius_max_px,
        )
        # An X of texture's size under its floor whose saddle stands out of its ground
        # passes it; the template's floor and the fit's weigh it again where it falls
        # under them (MarkerModel.match, MarkerModel.judge).
        doubted = np.flatnonzero(weak)
        stood_out: NDArray[np.bool_] = np.zeros(len(weak), dtype=bool)
        stood_out[doubted] = acceptance.stands_out(
            gray, candidates.xy[doubted], symmetry.radius_px[doubted]
        )
        weak &= ~stood_out
        counts["rejected_score"] = int(weak.sum())
        result.survivors += [
            ("symmetry", candidates.xy[keep]),
            ("symmetry_floor", candidates.xy[keep & ~weak]),
        ]
        passed = keep & ~weak
        tiny = np.flatnonzero(
            passed & self._reads_plates & (symmetry.radius_px < verification.X_END_MAX_EXTENT_PX)
        )
        ring_passed = _RingPassed(
            candidates.xy[tiny],
            symmetry.radius_px[tiny],
            symmetry.line_angles[tiny],
            symmetry.score[tiny],
        )
        chosen, ncc, stood_out_of_template = self._match_templates(
            frame,
            candidates.xy,
            symmetry,
            self._floors.lowest(symmetry.radius_px),
            np.flatnonzero(passed),
        )
        candidates, radius, angles, score, stood_out = (
            candidates.take(chosen),
            symmetry.radius_px[chosen],
            symmetry.line_angles[chosen],
            symmetry.score[chosen] * ncc,
            stood_out[chosen] | stood_out_of_template,
        )
        if not self._lines_after_fit:
            ok, angles = self._double_lines(frame, candidates.xy, radius, angles)
            candidates, radius, angles, score, stood_out = (
                candidates.take(ok),
                radius[ok],
                angles[ok],
                score[ok],
                stood_out[ok],
            )
        return candidates, radius, angles, score, stood_out, ring_passed

    @property
    def _expects_tiny(self) -> bool:
        """Whether the smallest expected marker is of texture's size.

        Under :data:`verification.X_END_MAX_EXTENT_PX`: the marker's model then leaves
        an X of that size under its floor to the plate reading (:meth:`_read_plates`)
        rather than vouching for it, and holds every detection of that size to the
        tiny markers' plate (:attr:`acceptance.MarkerModel.expects_tiny`).
        """
        return (
            self._reads_plates
            and self.config.marker_radius_min_px < verification.X_END_MAX_EXTENT_PX
        )

    @property
    def _reads_plates(self) -> bool:
        """Whether X's of texture's size that found no marker are read with their plate.

        At every radius range (:meth:`_read_plates`, :meth:`_confirm_plates`): a
        marker of 6-9 px seen 50-60 degrees from face on has an X of texture's size
        too, which a range from 6 px expects, and the reading a rung out
        (:func:`plate.explains_at`) finds it where the X's own tests lose it
        (measured: docs/accuracy-journal.md, "A small tilted X's plate read a rung out, at
        every range").
        """
        return self.config.refinement == "symmetry"

    def _model(self, frame: Frame) -> acceptance.MarkerModel:
        """The marker's model on ``frame``, which the gates set by texture defer to."""
        return acceptance.MarkerModel(
            frame.gray,
            frame.full_scale,
            frame.noise,
            self.config.marker_radius_max_px,
            self._expects_tiny,
            frame.gamma,
        )

    def _read_plates(self, frame: Frame, tiny: _RingPassed) -> None:
        """Tiny X's that found no marker, judged by their plate (:func:`plate.read_plates`).

        The X's of texture's size the ring check passed (``tiny``) that ended farther
        than the merge radius from every detection; those the plate explains are
        fitted as every detection is (the fit's own gates, not the score floors,
        which the plate's evidence replaces) and join the detections where the plate
        explains them at their fitted centre too (:meth:`_plated`).

        Counts ``plate_read``, the candidates compared, ``found_plate``, the markers
        they added, and ``plate_over_cap``, the saddles over the cap. The survivors
        end with ``plate``: the detections then.
        """
        result = frame.result
        counts = result.counts
        counts["plate_read"] = counts["found_plate"] = counts["plate_over_cap"] = 0
        lost = self._far_from_detections(result, tiny.xy)
        if len(lost):
            with frame.timer("plate"):
                reading = plate.read_plates(
                    frame.gray,
                    tiny.xy[lost],
                    tiny.score[lost],
                    tiny.radius_px[lost],
                    tiny.line_angles[lost],
                    self.config.entropy_cell_px,
                )
            counts["plate_over_cap"] = reading.over_cap
            counts["plate_read"] = len(reading.read)
            explained = lost[reading.explained]
            if len(explained):
                with frame.timer("subpixel"):
                    fitted = self._fit_plates(frame, tiny, explained)
                counts["found_plate"] = self._join(result, self._plated(frame, fitted))
        result.survivors.append(("plate", positions(result.detections)))

    def _fit_plates(
        self, frame: Frame, tiny: _RingPassed, chosen: NDArray[np.intp]
    ) -> list[Detection]:
        """The sub-pixel fit of the tiny X's their plate explains, with its own gates only."""
        xy, radius, angles = tiny.xy[chosen], tiny.radius_px[chosen], tiny.line_angles[chosen]
        evidence = tiny.score[chosen]
        fit = self._gating_fit(frame, xy, radius, angles, evidence)
        ok = np.flatnonzero(fit.accepted)
        return self._detections(
            frame, fit.xy[ok], fit.sigma[ok], fit.score[ok], radius[ok], angles[ok], evidence[ok]
        )

    def _ring_check(
        self, gray: NDArray[Any], candidates: Candidates, gamma: preprocessing.LocalGamma
    ) -> verification.RingReading:
        """:func:`verification.ring_check` of the centred candidates, as this detector reads."""
        return verification.ring_check(
            self._ring_reader(gray, gamma),
            candidates,
            second_reading.screened_wide(candidates),
            self._floors.floor,
        )

    def _ring_reader(
        self, gray: NDArray[Any], gamma: preprocessing.LocalGamma
    ) -> verification.RingReader:
        """The ring check on ``gray`` as this detector reads rings: its ladder, floor, threshold."""
        return verification.RingReader(
            gray,
            self.ring_radii_px,
            self.config.min_contrast_share,
            self.config.symmetry_min,
            gamma,
        )

    def _read_dull(
        self,
        frame: Frame,
        candidates: Candidates,
        ring: verification.SymmetryCheck,
        equalised_x: NDArray[np.bool_],
    ) -> tuple[Candidates, verification.SymmetryCheck]:
        """Small X's with a dull quadrant, read again from the light slope's centre.

        :func:`second_reading.read_dull`, in the first reading alone: a second one's
        candidates are centred with the light's slope already. Counts ``dull_read``,
        ``kept_dull`` and ``dull_over_cap``.

        Returns:
            The candidates (those read again and kept moved) and their check.
        """
        counts = frame.result.counts
        for key in ("dull_read", "kept_dull", "dull_over_cap"):
            counts.setdefault(key, 0)
        if frame.slope_centred:
            return candidates, ring
        reading = second_reading.read_dull(
            frame.gray,
            candidates,
            ring,
            equalised_x,
            rings=self._ring_reader(frame.gray, frame.gamma),
            floors=self._floors,
            model=self._model(frame),
            max_radius_px=self.config.marker_radius_max_px,
            cell_px=self.config.entropy_cell_px,
        )
        counts["dull_read"] += len(reading.read)
        counts["kept_dull"] += len(reading.kept)
        counts["dull_over_cap"] += reading.over_cap
        return reading.moved(candidates, ring)

    @property
    def _lines_after_fit(self) -> bool:
        """Whether the double-line check runs on the fit's survivors (:meth:`locate`).

        The NCC location reads the line directions the check refines, so it runs
        before that fit; the point-symmetry fit does not, and LSD (~0.15 ms a
        candidate) then sees only the few the fit and its floor leave.
        """
        return self.config.refinement == "symmetry"

    def _double_lines(
        self,
        frame: Frame,
        xy: NDArray[np.float64],
        radius: NDArray[np.float64],
        angles: NDArray[np.float64],
    ) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
        """The double-line check (Eq. 9) where ``line_check`` asks for it.

        Returns:
            (N,) which points pass, and (N, 2) their line directions, refined by the
            lines' where both agree (:func:`verification.agreed_line_angles`).
        """
        cfg = self.config
        ok: NDArray[np.bool_] = np.ones(len(xy), dtype=bool)
        if cfg.line_check and len(xy):
            lines = verification.double_line_check(
                frame.gray,
                xy,
                radius,
                extend_px=cfg.line_extend_px,
                max_distance_px=cfg.line_max_distance_px,
                full_scale=frame.full_scale,
                stretch=self._shadowed.gain_at(frame.gamma, xy),
            )
            ok = lines.accepted
            angles = angles.copy()
            angles[ok] = verification.agreed_line_angles(lines.line_angles[ok], angles[ok])
        frame.result.counts["rejected_lines"] = int((~ok).sum())
        frame.result.survivors.append(("lines", xy[ok]))
        return ok, angles

    def _match_templates(
        self,
        frame: Frame,
        xy: NDArray[np.float64],
        symmetry: verification.SymmetryCheck,
        lowest: NDArray[np.float64],
        passed: NDArray[np.intp],
    ) -> tuple[NDArray[np.intp], NDArray[np.float64], NDArray[np.bool_]]:
        """The paint's and the template's gates, and the score floor, up to the cap.

        The candidates ``passed`` (indices into ``xy``) are matched in the order
        :func:`screening.even_order` gives them (cell by cell, the best ring symmetry
        first), a batch at a time, until :data:`MAX_CONFIRMED` have passed: where
        fewer pass, as on all real ground measured, every candidate is matched;
        where all pass (a tiling of X's) only the first are. The rest are counted
        in ``dropped_over_verification_cap``. The modulation gate, a few grey levels
        a candidate, runs first: the NCC reads a disk of up to 300 samples at four
        blurs, and on cluttered ground most candidates fail the gate (measured:
        docs/speed.md, "The modulation gate before the template"). Each batch is
        decided by :meth:`acceptance.MarkerModel.match`; this counts and records its
        reasons.

        Returns:
            The indices (ascending) of the candidates that pass, their NCC, and which of
            them the floor stood aside for (:attr:`acceptance.Match.stood_out`).
        """
        cfg = self.config
        result = frame.result
        counts = result.counts
        order = passed[
            screening.even_order(xy[passed], symmetry.score[passed], cfg.entropy_cell_px)
        ]
        matched: list[NDArray[np.intp]] = []
        matched_ncc: list[NDArray[np.float64]] = []
        matched_stood_out: list[NDArray[np.bool_]] = []
        # Indices passing the modulation gate, and the NCC too, for the survivors.
        modulated: list[NDArray[np.intp]] = []
        correlated_too: list[NDArray[np.intp]] = []
        found = start = 0
        counts.setdefault("rejected_template", 0)
        counts.setdefault("kept_faint", 0)
        counts.setdefault("vouch_over_cap", 0)
        model = self._model(frame)
        plate_budget = acceptance.MAX_VOUCH_PLATES
        while start < len(order) and found < MAX_CONFIRMED:
            batch = order[start : start + max(MAX_CONFIRMED - found, _MIN_TEMPLATE_BATCH)]
            start += len(batch)
            match = model.match(
                xy[batch],
                symmetry.radius_px[batch],
                symmetry.line_angles[batch],
                symmetry.score[batch],
                lowest[batch],
                self._template_gates,
                plate_budget,
            )
            plate_budget -= match.plates_read
            counts["kept_faint"] += int(match.faint.sum())
            counts["vouch_over_cap"] += int(match.unread.sum())
            counts["rejected_template"] += int((~match.passed("template")).sum())
            counts["rejected_score"] += int(
                (match.reason == acceptance.MATCHED_REASONS.index("score")).sum()
            )
            accepted = match.reason == acceptance.ACCEPTED
            modulated.append(batch[match.passed("modulation")])
            correlated_too.append(batch[match.passed("template")])
            matched.append(batch[accepted])
            matched_ncc.append(match.ncc[accepted])
            matched_stood_out.append(match.stood_out[accepted])
            found += int(accepted.sum())
        chosen = np.concatenate([np.zeros(0, np.intp), *matched])[:MAX_CONFIRMED]
        ncc = np.concatenate([np.zeros(0), *matched_ncc])[:MAX_CONFIRMED]
        stood_out = np.concatenate([np.zeros(0, bool), *matched_stood_out])[:MAX_CONFIRMED]
        counts["dropped_over_verification_cap"] = (
            counts.get("dropped_over_verification_cap", 0)
            + len(order)
            - start
            + found
            - len(chosen)
        )
        for test, kept in (
            ("modulation", modulated),
            ("template", correlated_too),
            ("template_floor", matched),
        ):
            result.survivors.append((test, xy[np.concatenate([np.zeros(0, np.intp), *kept])]))
        result.survivors.append(("fit_cap", xy[chosen]))
        ascending = np.argsort(chosen)
        return chosen[ascending], ncc[ascending], stood_out[ascending]

    def locate(
        self,
        frame: Frame,
        xy: NDArray[np.float64],
        radius: NDArray[np.float64],
        angles: NDArray[np.float64],
        score: NDArray[np.float64],
        check_lines: bool = False,
        read_ground: bool = True,
        stood_out: NDArray[np.bool_] | None = None,
    ) -> list[Detection]:
        """Section 3.3: sub-pixel centres and final gates (:func:`subpixel.locate_markers`).

        Then the marker's model judges them (:meth:`acceptance.MarkerModel.judge`),
        with ``check_lines`` the double-line check (:meth:`_double_lines`: LSD, ~0.15 ms
        a candidate, so on the few the fit and the floor leave), and the last
        suppression of duplicates, strongest first. Without ``read_ground`` the
        ground around each X, its plate and the lattice test
        (:meth:`_standing_alone`), is not read: markers a pass has judged there.
        ``stood_out``: (N,) the X's a floor before the fit (the ring symmetry's, the
        template's) stood aside for (:func:`acceptance.stands_out`); None: none. The
        detections that one of those floors or the fit's would have rejected but for
        their standing out are counted once each in ``kept_standing_out``.
        """
        result = frame.result
        counts = result.counts
        counts.setdefault("kept_standing_out", 0)
        if len(xy) == 0:
            counts["rejected_refinement"] = 0
            counts.setdefault("rejected_score", 0)
            return []
        fit = self._gating_fit(frame, xy, radius, angles, score)
        ok = fit.accepted
        counts["rejected_refinement"] = int((~ok).sum())
        located = np.flatnonzero(ok)
        judged = self._model(frame).judge(
            fit.xy[located],
            radius[located],
            angles[located],
            fit.score[located],
            self._floors,
            self.config.entropy_cell_px,
            read_plates=read_ground,
        )
        counts["kept_under_floor"] = counts.get("kept_under_floor", 0) + int(judged.vouched.sum())
        aside = np.zeros(len(xy), dtype=bool) if stood_out is None else stood_out.copy()
        aside[located] |= judged.stood_out
        counts["plate_asked_over_cap"] = counts.get("plate_asked_over_cap", 0) + int(
            judged.unread.sum()
        )
        for index, reason in enumerate(acceptance.JUDGED_REASONS):
            counts[f"rejected_{reason}"] = counts.get(f"rejected_{reason}", 0) + int(
                (judged.reason == index).sum()
            )
        result.survivors.append(("fit", fit.xy[ok]))
        for test, reason in zip(_JUDGED_TESTS, acceptance.JUDGED_REASONS, strict=True):
            result.survivors.append((test, fit.xy[located[judged.passed(reason)]]))
        keep = located[judged.reason == acceptance.ACCEPTED]
        if check_lines:
            # At the verified centres, where the checks before the fit looked.
            straight, lined = self._double_lines(frame, xy[keep], radius[keep], angles[keep])
            angles = angles.copy()
            angles[keep] = lined
            keep = keep[straight]
        unique = screening.non_maximum_suppression(
            fit.xy[keep], fit.score[keep], self.config.merge_radius_px
        )
        counts["merged_duplicates"] += int((~unique).sum())
        keep = keep[unique]
        result.survivors.append(("merging", fit.xy[keep]))
        keep = strongest_first(keep, fit.score)
        detections = self._detections(
            frame,
            fit.xy[keep],
            fit.sigma[keep],
            fit.score[keep],
            radius[keep],
            angles[keep],
            score[keep],
        )
        alone = self._standing_alone(frame, detections, read_ground)
        counts["kept_standing_out"] += int((aside[keep] & alone).sum())
        return [detection for detection, kept in zip(detections, alone, strict=True) if kept]

    def _standing_alone(
        self, frame: Frame, detections: list[Detection], read_ground: bool
    ) -> NDArray[np.bool_]:
        """(N,) which detections' ground does not repeat them, at their final centres and lines.

        :meth:`acceptance.MarkerModel.stands_alone`, where ``lattice_check`` asks for it
        and ``read_ground`` (see :meth:`locate`); counts ``rejected_lattice``. Read
        along the lines the default path's final fit measured from the edges: a
        chessboard's go on beyond the corner within a pixel or two, where the checks'
        directions, which the paper's refinement reports, may miss them by more.
        """
        alone: NDArray[np.bool_] = np.ones(len(detections), dtype=bool)
        lattice_asked = self.config.refinement == "symmetry" and self.config.lattice_check
        if lattice_asked and read_ground and detections:
            alone = self._model(frame).stands_alone(
                positions(detections), extents(detections), line_directions(detections)
            )
        counts = frame.result.counts
        counts["rejected_lattice"] = counts.get("rejected_lattice", 0) + int((~alone).sum())
        frame.result.survivors.append(("lattice", positions(detections)[alone]))
        return alone

    def _gating_fit(
        self,
        frame: Frame,
        xy: NDArray[np.float64],
        radius: NDArray[np.float64],
        angles: NDArray[np.float64],
        evidence: NDArray[np.float64],
    ) -> subpixel.MarkerLocation:
        """The fit whose gates every detection passes (:func:`subpixel.locate_markers`)."""
        cfg = self.config
        # The prescreen's contrast floor holds for every detection, those the
        # prescreen never saw too (a tracked or seeded marker).
        return subpixel.locate_markers(
            frame.gray,
            xy,
            radius,
            angles,
            evidence,
            max_radius_px=cfg.marker_radius_max_px,
            iterations=cfg.refinement_max_iterations,
            min_contrast=self._raw_contrast_floor(frame.full_scale, frame.gamma, xy),
            max_symmetry_residual=cfg.max_symmetry_residual,
            ncc_offset_px=cfg.template_offset_px if cfg.refinement == "ncc" else None,
            ncc_search_px=cfg.ncc_search_px,
        )

    def _detections(
        self,
        frame: Frame,
        xy: NDArray[np.float64],
        sigma: NDArray[np.float64],
        score: NDArray[np.float64],
        radius: NDArray[np.float64],
        angles: NDArray[np.float64],
        evidence: NDArray[np.float64],
    ) -> list[Detection]:
        """The located markers as detections, at their final centres.

        The default path (``refinement="symmetry"``) fits them once more along
        their lines (:func:`subpixel.refine_along_lines`), and reports the lines'
        directions that fit measured from the edges; the others report the gating
        fit's centres and the checks' directions.
        """
        if self.config.refinement == "symmetry":
            frame.result.counts.setdefault("uneven_over_cap", 0)
            xy, sigma, angles = subpixel.refine_along_lines(
                frame.gray,
                xy,
                sigma,
                radius,
                angles,
                max_radius_px=self.config.marker_radius_max_px,
                full_scale=frame.full_scale,
                tally=frame.result.counts,
            )
        return detections_of(xy, score, sigma, angles, radius, evidence)
