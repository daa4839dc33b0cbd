"""``refinement="template"``: the sector order, the straight edges, the template fit, the decision.

The option whose one decision (:mod:`decision`) reads a grown template fit of
every candidate and accepts at the threshold of a stated false-alarm rate
(``false_points_per_mp``). Its prescreen reads the order of the sectors, and
its line check the straight edges, before any fit: a dull quadrant or a shadow's
edge across a marker leave both standing, where grey-level symmetry does not.
On the saddle screening it reads the noise, not the local means; on the paper's
curvature screening (:mod:`paper_path`) it takes over after the paper's checks.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from marker_localizer.config import DetectorConfig
from marker_localizer.core import decision, screening, template, template_fit, verification
from marker_localizer.core.frame import StageTimer
from marker_localizer.core.noise import NoiseModel
from marker_localizer.core.result import DetectionResult, detections_of, strongest_first
from marker_localizer.core.sampling import nearest_pixels
from marker_localizer.core.screening import Candidates

#: A sector-order prescreen ring's edge pairs must exceed
#: the noise of its slope this many times: lenient (the decision comes later); the
#: prescreen only spares the fit most texture.
_ORDER_NOISE_SIGMAS = 3.0
#: ... and this share of ``min_contrast_dn``: an X's edge of that contrast, blurred,
#: rises by about a tenth of it per 10 degrees of even the smallest ring.
_ORDER_CONTRAST_SHARE = 0.1
#: First region of the template fit, in units of the candidate's scale (at least
#: :data:`_FIT_MIN_START_PX`, whose 29 pixels pin the template's 12 parameters):
#: inside the X of any marker the level answers to.
_FIT_START_SCALE = 0.5
_FIT_MIN_START_PX = 3.0
#: Blur the fit starts from, px: the middle of what optics give.
_FIT_START_BLUR_PX = 1.0
#: A fit may end this share of its first region (plus :data:`_FIT_SHIFT_PX`) from
#: where it started and still be the candidate's own X.
_FIT_SHIFT_SCALE = 0.5
_FIT_SHIFT_PX = 1.0
#: Pixels each decision fit reads at most (a lattice of them on large markers): the
#: decision needs the X's shape, not its last hundredth of a pixel; the markers it
#: accepts are fitted again on every pixel.
_DECISION_PIXELS = 300
#: Smallest half-size of the double-line check's window, px: LSD needs segments a
#: few pixels long (the check upsamples small windows).
_LINE_WINDOW_MIN_PX = 3.0
#: The most candidates of a frame whose template fit grows past its first disk
#: (:func:`template_fit.fit_growing_template`: 3-10 ms each on one core, where texture
#: stops at the first disk for about 0.2 ms). Over it, those whose weakest edge
#: stands out least are cut, spread over the frame as Eq. (7)'s thinning spreads
#: them (:class:`_CappedGrowth`), and counted. Twice what real ground grows; a frame
#: tiled with X's grows every one without it.
MAX_GROWN = 5000


class TemplatePath:
    """The template fit and decision of one detector's config; build once."""

    def __init__(self, config: DetectorConfig) -> None:
        self.config = config
        self._threshold = decision.threshold_for_rate(config.false_points_per_mp)

    def confirm(
        self,
        gray: NDArray[Any],
        full_scale: float,
        noise: NoiseModel,
        candidates: Candidates,
        seeded: Candidates,
        result: DetectionResult,
        timer: StageTimer,
    ) -> DetectionResult:
        """The saddle screening's candidates, and a tracking pass's ``seeded`` ones, decided.

        The sector order (:meth:`prescreen`) and, where ``line_check`` asks for it,
        the straight edges (:meth:`straight_edges`) before the fit and the decision
        (:meth:`fit_and_decide`). A seed is a tracked marker, perhaps a fraction of a
        pixel off: it skips the prescreen's test and takes its line directions only.
        """
        with timer("prescreen"):
            candidates, angles = self.prescreen(gray, full_scale, noise, candidates, result.counts)
            result.survivors.append(("prescreen", candidates.xy))
        if self.config.line_check:
            with timer("verification"):
                candidates, angles = self.straight_edges(
                    gray, full_scale, candidates, angles, result.counts
                )
                result.survivors.append(("lines", candidates.xy))
        if len(seeded):
            candidates = Candidates.concat([candidates, seeded])
            angles = np.vstack(
                [
                    angles,
                    verification.prescreen_line_directions(
                        gray, seeded.xy, seeded.scale_px, self.config.marker_radius_min_px
                    ),
                ]
            )
        start = self.fit_start(candidates.scale_px)
        self.fit_and_decide(gray, noise, candidates.xy, angles, start, result, timer)
        return result

    def prescreen(
        self,
        gray: NDArray[Any],
        full_scale: float,
        noise: NoiseModel,
        candidates: Candidates,
        counts: dict[str, int],
    ) -> tuple[Candidates, NDArray[np.float64]]:
        """``refinement="template"``: the order of the sectors on the prescreen's rings.

        Lenient per ring (edges a few noise widths strong, or a tenth of the
        configured contrast) but strict over the rings (all three, their edge
        directions agreeing), it spares the fit most texture saddles. Unlike the
        grey-level symmetry of :meth:`SymmetryPath.prescreen`, a dull quadrant or a shadow edge
        across the marker leave the sector order standing
        (:func:`verification.sector_order`).

        Returns:
            The candidates that pass and (N, 2) their line directions.
        """
        level = nearest_pixels(gray, candidates.xy)
        min_strength = np.maximum(
            _ORDER_NOISE_SIGMAS * verification.ring_edge_noise(noise.std(level)),
            _ORDER_CONTRAST_SHARE * self.config.min_contrast_share * full_scale,
        )
        passed, angles = verification.prescreen_sector_order(
            gray,
            candidates.xy,
            verification.prescreen_ring_radii(
                candidates.scale_px, self.config.marker_radius_min_px
            ),
            min_strength,
        )
        counts["rejected_prescreen"] = int((~passed).sum())
        return candidates.take(passed), angles[passed]

    def straight_edges(
        self,
        gray: NDArray[Any],
        full_scale: float,
        candidates: Candidates,
        angles: NDArray[np.float64],
        counts: dict[str, int],
    ) -> tuple[Candidates, NDArray[np.float64]]:
        """``refinement="template"``: the double-line check (Eq. 9) before any fit.

        Straight edges crossing at the candidate are geometry, which a dull
        quadrant or a shadow leaves standing, while the dark gaps between stones
        and pebbles curve. Measured on the renderer's families (a), (d) and (g),
        three frames each: every marker the sector order kept stays, and 3-10x
        fewer texture saddles go on to the (costly) template fit.
        """
        lines = verification.double_line_check(
            gray,
            candidates.xy,
            np.clip(candidates.scale_px, _LINE_WINDOW_MIN_PX, self.config.marker_radius_max_px),
            extend_px=self.config.line_extend_px,
            max_distance_px=self.config.line_max_distance_px,
            full_scale=full_scale,
        )
        counts["rejected_lines"] = int((~lines.accepted).sum())
        return candidates.take(lines.accepted), angles[lines.accepted]

    def fit_start(self, scale_px: NDArray[np.float64]) -> NDArray[np.float64]:
        """The template fit's first region radius for candidates of this scale, px."""
        return np.clip(
            _FIT_START_SCALE * scale_px, _FIT_MIN_START_PX, self.config.marker_radius_max_px
        )

    def tracked_fit_start(self, extent_px: NDArray[np.float64]) -> NDArray[np.float64]:
        """The fit's first region radius for a tracked marker of this extent, px.

        That of a candidate of the pyramid level whose scale is the largest not over
        the extent, as a full pass screens such a marker. From the extent itself, the
        region started wider than any candidate's, and under sharp optics the fit
        found a second minimum 0.08-0.18 px off on tracked frames (mean error 0.020-
        0.027 px against the full passes' 0.005-0.011 on the same frames; from the
        level's scale 0.005-0.009: docs/reliability.md).
        """
        return self.fit_start(screening.level_scale_within(extent_px))

    def fit_and_decide(
        self,
        gray: NDArray[Any],
        noise: NoiseModel,
        xy: NDArray[np.float64],
        angles: NDArray[np.float64],
        start_radius: NDArray[np.float64],
        result: DetectionResult,
        timer: StageTimer,
    ) -> None:
        """``refinement="template"``: grown template fits, the decision, the markers.

        Fills ``result``'s detections, counts and verdicts. Each candidate's
        template grows from inside its X out to where the lines end
        (:func:`template_fit.fit_growing_template`); :func:`decision.decide` reads the
        evidence and accepts at the threshold of ``false_points_per_mp``; the
        accepted are fitted again on every pixel of their X for their position.
        """
        cfg = self.config
        counts = result.counts
        with timer("subpixel"):
            shape = template.TemplateShape.start(xy, angles, _FIT_START_BLUR_PX)
            level = nearest_pixels(gray, xy)
            growth = _CappedGrowth(MAX_GROWN, cfg.entropy_cell_px)
            grown = template_fit.fit_growing_template(
                gray,
                shape,
                start_radius,
                cfg.marker_radius_max_px,
                max_pixels=_DECISION_PIXELS,
                noise_std=noise.std(level.astype(np.float64)),
                keep=growth,
            )
            cut = int(growth.cut.sum())
            counts["dropped_over_verification_cap"] = (
                counts.get("dropped_over_verification_cap", 0) + cut
            )
            if cut:
                kept = ~growth.cut
                grown = template_fit.GrownFit(
                    grown.fit.take(kept), grown.extents[kept], grown.grown[kept]
                )
                xy, start_radius = xy[kept], start_radius[kept]
        with timer("decision"):
            evidence = decision.gather_evidence(
                gray, grown, xy, _FIT_SHIFT_SCALE * start_radius + _FIT_SHIFT_PX, noise
            )
            verdict = decision.decide(
                evidence,
                min_radius_px=cfg.marker_radius_min_px,
                min_extent_fraction=cfg.min_extent_fraction,
                threshold=self._threshold,
            )
            for index, reason in enumerate(decision.REASONS):
                counts[f"rejected_{reason}"] = int((verdict.reason == index).sum())
            result.verdicts = decision.Verdicts(grown.fit.shape.xy, verdict, evidence)
            result.survivors.append(("decision", grown.fit.shape.xy[verdict.accepted]))
        with timer("subpixel"):
            accepted = verdict.accepted
            fit = template_fit.refit_on_every_pixel(gray, grown, accepted, cfg.marker_radius_max_px)
            position = fit.shape.xy
            sigma = np.sqrt(np.maximum(fit.covariance[:, 0, 0] + fit.covariance[:, 1, 1], 0.0))
            keep = np.flatnonzero(accepted)
            unique = screening.non_maximum_suppression(
                position[keep], verdict.score[keep], self.config.merge_radius_px
            )
            counts["merged_duplicates"] = counts.get("merged_duplicates", 0) + int((~unique).sum())
            keep = keep[unique]
            keep = strongest_first(keep, verdict.score)
            counts["accepted"] = len(keep)
            confidence = decision.confidence(verdict.score)
            line_angles = fit.shape.line_angles
            result.detections = detections_of(
                position[keep],
                confidence[keep],
                sigma[keep],
                line_angles[keep],
                evidence.extent_px[keep],
                confidence[keep],
            )


class _CappedGrowth:
    """:func:`decision.worth_growing`, for at most ``limit`` of a frame's candidates.

    :func:`template_fit.fit_growing_template` asks it first about every candidate. Of
    those worth growing, the ``limit`` it keeps are taken cell by cell, those whose
    weakest edge stands out most first (:func:`screening.even_cap_index`); the rest
    are marked in :attr:`cut`. Later steps ask about the kept alone.
    """

    def __init__(self, limit: int, cell_px: float) -> None:
        self.limit = limit
        self.cell_px = cell_px
        #: (N,) True where a candidate worth growing was cut by the cap (empty before
        #: the first call).
        self.cut: NDArray[np.bool_] = np.zeros(0, dtype=bool)
        self._asked = False

    def __call__(
        self, fit: template_fit.TemplateFit, extents: NDArray[np.float64]
    ) -> NDArray[np.bool_]:
        grow = decision.worth_growing(fit, extents)
        if self._asked:
            return grow
        self._asked = True
        self.cut = np.zeros(len(grow), dtype=bool)
        rows = np.flatnonzero(grow)
        if len(rows) > self.limit:
            strength = decision.weakest_edge_t(fit)[rows]
            kept = screening.even_cap_index(fit.shape.xy[rows], strength, self.limit, self.cell_px)
            self.cut[np.delete(rows, kept)] = True
        return grow & ~self.cut
