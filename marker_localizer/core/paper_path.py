"""The paper's checks and location (sections 3.2-3.3) after its curvature screening.

``candidate_detector="curvature"``: the annular check by edge phase and
polarity, the template's NCC with the annular score, the LSD double line, then
the location ``refinement`` names: the paper's adaptive template NCC surface
(``"ncc"``), the default's fit and gates (``"symmetry"``,
:class:`~marker_localizer.core.symmetry_path.SymmetryPath`), or the template fit
and its calibrated decision (``"template"``,
:class:`~marker_localizer.core.template_path.TemplatePath`).
"""

from __future__ import annotations

import numpy as np

from marker_localizer.config import DetectorConfig
from marker_localizer.core import screening, subpixel, template, verification
from marker_localizer.core.frame import Frame
from marker_localizer.core.noise import NoiseModel
from marker_localizer.core.result import DetectionResult, detections_of, strongest_first
from marker_localizer.core.screening import Candidates
from marker_localizer.core.symmetry_path import SymmetryPath
from marker_localizer.core.template_path import TemplatePath

#: The most candidates of a frame that pass the paper's checks and go on to be
#: located (the default's fit, 0.3-0.5 ms each on one core; the NCC surface; the
#: template's growth): over it, the lowest scores of each cell are cut, spread over
#: the frame as Eq. (7)'s thinning spreads them (:func:`screening.even_cap_index`),
#: and counted. Over what real images reach, under what a chessboard of small squares
#: passes.
MAX_LOCATED = 800


class PaperPath:
    """The paper's checks of one detector's config, and the location it names; build once."""

    def __init__(
        self, config: DetectorConfig, symmetry: SymmetryPath, template_fit: TemplatePath
    ) -> None:
        self.config = config
        self._symmetry = symmetry
        self._template_fit = template_fit

    def confirm(
        self, frame: Frame, noise: NoiseModel | None, candidates: Candidates
    ) -> DetectionResult:
        """The paper's checks and location (sections 3.2-3.3) for the curvature path.

        The annular check by edge phase and polarity (which also moves each
        candidate to where its lines cross), the template's NCC with the annular
        score (:func:`template.template_evidence`), the LSD double line (its angles
        feed the template where they agree with the rings'), then with
        ``refinement="ncc"`` the adaptive template's NCC surface and its quadratic
        extremum, accepted where the surface peaks at :data:`subpixel.NCC_PEAK_MIN`
        or more; with ``refinement="symmetry"`` the default's fit and gates, with
        ``refinement="template"`` the template fit and the calibrated decision. At
        most :data:`MAX_LOCATED` go on to be located; the rest are cut and counted.
        """
        cfg = self.config
        gray, result, timer = frame.gray, frame.result, frame.timer
        counts = result.counts
        counts["rejected_centring"] = 0
        with timer("verification"):
            check = verification.edge_phase_check(
                gray,
                candidates.xy,
                self._symmetry.ring_radii_px,
                min_contrast=self.config.min_contrast_share,
                normalise=frame.gamma,
            )
            keep = check.accepted & verification.reaches_extent(
                check.radius_px, cfg.min_extent_fraction, cfg.marker_radius_min_px
            )
            counts["rejected_symmetry"] = int((~keep).sum())
            xy, radius = check.xy[keep], check.radius_px[keep]
            survivors = frame.result.survivors
            survivors.append(("symmetry", xy))
            angles, score = check.line_angles[keep], check.score[keep]
            unique = screening.non_maximum_suppression(xy, score, self.config.merge_radius_px)
            counts["merged_duplicates"] = int((~unique).sum())
            xy, radius, angles, score = xy[unique], radius[unique], angles[unique], score[unique]
            ncc = template.template_correlation(
                gray,
                xy,
                angles,
                verification.template_radius(radius, cfg.marker_radius_max_px),
                normalise=frame.gamma,
            ).ncc
            ok = template.template_evidence(score, ncc, cfg.template_ncc_min)
            counts["rejected_template"] = int((~ok).sum())
            xy, radius, angles = xy[ok], radius[ok], angles[ok]
            survivors.append(("template", xy))
            # The default fit's score floors were set on its ring symmetry x NCC; the
            # annular score of edge phases runs lower on markers, so the fit takes the
            # template NCC alone as the checks' evidence.
            score = (score[ok] if cfg.refinement == "ncc" else 1.0) * ncc[ok]
            if cfg.line_check and len(xy):
                lines = verification.double_line_check(
                    gray,
                    xy,
                    radius,
                    extend_px=cfg.line_extend_px,
                    max_distance_px=cfg.line_max_distance_px,
                    full_scale=frame.full_scale,
                )
                ok = lines.accepted
                counts["rejected_lines"] = int((~ok).sum())
                xy, radius, angles, score = xy[ok], radius[ok], angles[ok], score[ok]
                angles = verification.agreed_line_angles(lines.line_angles[ok], angles)
                survivors.append(("lines", xy))
            else:
                counts["rejected_lines"] = 0
            capped = screening.even_cap_index(xy, score, MAX_LOCATED, cfg.entropy_cell_px)
            counts["dropped_over_verification_cap"] = (
                counts.get("dropped_over_verification_cap", 0) + len(xy) - len(capped)
            )
            xy, radius, angles, score = xy[capped], radius[capped], angles[capped], score[capped]
            survivors.append(("fit_cap", xy))
        if noise is not None:
            start = self._template_fit.fit_start(radius)
            self._template_fit.fit_and_decide(gray, noise, xy, angles, start, result, timer)
            return result
        with timer("subpixel"):
            if cfg.refinement != "ncc":
                result.detections = self._symmetry.locate(frame, xy, radius, angles, score)
                counts["accepted"] = len(result.detections)
                return result
            fit = subpixel.ncc_refine(
                gray,
                xy,
                radius,
                angles,
                offset_px=cfg.template_offset_px,
                search_px=cfg.ncc_search_px,
            )
            located, matched = subpixel.ncc_gates(fit)
            counts["rejected_refinement"] = int((~located).sum())
            counts["rejected_score"] = int((located & ~matched).sum())
            survivors.append(("refinement", fit.offset[located]))
            survivors.append(("score", fit.offset[matched]))
            order = strongest_first(np.flatnonzero(matched), score)
            result.detections = detections_of(
                fit.offset[order],
                score[order],
                fit.sigma[order],
                angles[order],
                radius[order],
                score[order],
            )
        counts["accepted"] = len(result.detections)
        return result
