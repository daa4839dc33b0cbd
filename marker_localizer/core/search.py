"""Section 3.2's first layers as the detector runs them: on the frame or in regions.

Candidates (:mod:`screening`'s saddle or curvature screening), their suppression,
the grid-entropy thinning of Eq. (7) and the cap, on the whole frame or inside a
tracking pass's regions (:class:`~marker_localizer.core.result.SearchPlan`), each
screened with the context its filters need so that it finds what a full-frame
pass finds there. Two exceptions, both among texture's points: a peak just
outside a region's border that the refinement moves just inside it, and a
crowded cell whose cap falls among equally strong points, where the order the
points come in decides which are kept.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from marker_localizer.config import DetectorConfig
from marker_localizer.core import preprocessing, screening
from marker_localizer.core.screening import Candidates

#: Context screened around a search region: the filters of the coarsest pyramid level
#: reach 2 level pixels (5x5 Sobel), plus the halving alignment; this many of that
#: level's pixels, plus :data:`_REGION_MARGIN_PX` full-resolution ones, suffice.
_REGION_MARGIN_LEVEL_PX = 4
_REGION_MARGIN_PX = 4
#: A search region with its context narrower than this holds no candidate, px: the
#: screening's 5x5 filters need that much image.
_REGION_MIN_PX = 8


def near_known(
    xy: NDArray[np.float64], known: NDArray[np.float64], separation_px: float
) -> NDArray[np.bool_]:
    """(N,) the candidates at ``xy`` closer than ``separation_px`` to a known marker.

    A tracking pass knows the markers it has located
    (:attr:`~marker_localizer.core.result.SearchPlan.known`); a screening candidate
    that near one is that marker's, and is not verified again.

    Args:
        xy: (N, 2) candidate positions, px.
        known: (M, 2) the known markers' centres, px.
        separation_px: ``min_peak_separation_px``.
    """
    if not len(known) or not len(xy):
        return np.zeros(len(xy), dtype=bool)
    distance, _ = cKDTree(known).query(xy, distance_upper_bound=separation_px)
    near: NDArray[np.bool_] = np.isfinite(distance)
    return near


class CandidateSearch:
    """The screening of one detector's config; build once, :meth:`screen` per frame."""

    def __init__(self, config: DetectorConfig) -> None:
        self.config = config
        self._radius_range = (config.marker_radius_min_px, config.marker_radius_max_px)
        #: How far the raw contrast floors follow the light into a shadow: the
        #: screening's threshold, and the later stages' floors (:class:`SymmetryPath`).
        self.shadowed = preprocessing.ShadowedContrast(
            config.min_contrast_share, config.min_modulation
        )
        first_level = screening.saddle_levels(self._radius_range).start
        #: The scale a tracking seed is given (:attr:`SearchPlan.seeds`): the first
        #: pyramid level's, px.
        self.seed_scale_px = screening.candidate_scale(first_level, self._radius_range)

    def screen(
        self,
        gray: NDArray[Any],
        full_scale: float,
        counts: dict[str, int],
        regions: NDArray[np.integer[Any]] | None = None,
        gamma: preprocessing.LocalGamma | None = None,
    ) -> Candidates:
        """Section 3.2, first layers: candidates, suppression, grid-entropy thinning, cap.

        With ``gamma``, the saddle screening weighs each peak by its light and lowers
        its threshold in shadow (:class:`preprocessing.ShadowedContrast`).
        """
        cfg = self.config
        # Cut inside the screening by the same caps as below, before any work per point.
        cut = {"cut_in_cells": 0, "cut_below_floor": 0, "unexamined": 0}
        if regions is None:
            found = self._find_candidates(gray, full_scale, cut=cut, gamma=gamma)
        else:
            found = self._find_in_regions(
                gray, full_scale, np.asarray(regions, np.int64), cut, gamma
            )
        counts["candidates"] = len(found) + cut["cut_in_cells"] + cut["cut_below_floor"]
        counts["unexamined_below_floor"] = cut["unexamined"]
        if cfg.candidate_detector == "curvature":
            thinned = screening.greedy_entropy_thinning(
                found, cfg.entropy_cell_px, cfg.entropy_threshold
            )
        else:
            thinned = screening.grid_entropy_thinning(
                found, cfg.entropy_cell_px, cfg.max_candidates_per_cell
            )
        counts["after_suppression"] = len(thinned) + cut["cut_below_floor"]
        capped = thinned.strongest(cfg.max_candidates)
        counts["dropped_over_cap"] = counts["after_suppression"] - len(capped)
        return capped

    def _find_candidates(
        self,
        gray: NDArray[Any],
        full_scale: float,
        window: tuple[int, int, int, int] | None = None,
        origin_px: tuple[int, int] = (0, 0),
        cut: dict[str, int] | None = None,
        gamma: preprocessing.LocalGamma | None = None,
        frame_shape: tuple[int, int] | None = None,
    ) -> Candidates:
        """Screening candidates; ``window`` (x0, y0, x1, y1) bounds where they are wanted.

        ``origin_px`` is where ``gray``'s pixel (0, 0) lies in the frame, of
        ``frame_shape`` (H, W) (default: ``gray``'s); ``cut``
        counts what the saddle screening's caps cut (:func:`screening.saddle_candidates`);
        ``gamma``, if given, weighs its peaks by their light and lowers its threshold
        in shadow.
        """
        cfg = self.config
        if cfg.candidate_detector == "curvature":
            # The paper's path: GDWGIF and dynamic gamma on the whole frame, Eq. (3) where used.
            frame = gray.astype(np.float32) / np.float32(full_scale)
            denoised = preprocessing.gdwgif(frame, cfg.gdwgif_radius_px, cfg.gdwgif_lambda)
            corrected = preprocessing.dynamic_gamma(
                denoised, cfg.gamma_alpha, cfg.illumination_window_px
            )
            structure = preprocessing.StructureComponents(
                corrected, xi=cfg.structure_xi, t=cfg.structure_t
            )
            return screening.curvature_candidates(
                corrected,
                structure,
                self._radius_range,
                self.config.min_contrast_share,
                cfg.curvature_threshold_std,
                cfg.min_peak_separation_px,
                cfg.structure_keep_fraction,
                cfg.density_sigma_px,
                cfg.mean_shift_h_px,
            )
        # The Hessian's own 5x5 smoothing replaces GDWGIF, and the threshold in grey
        # levels replaces the structure percentile: no full-frame float passes (those
        # cost seconds on 12 MP); both paths' recall is in the README's tables.
        return screening.saddle_candidates(
            gray,
            self._radius_range,
            self.config.min_contrast_share * full_scale,
            relative_threshold=cfg.saddle_threshold,
            window=window,
            cell_cap=screening.CellCap(
                cfg.entropy_cell_px, cfg.max_candidates_per_cell, cfg.max_candidates, origin_px
            ),
            tally=cut,
            light=None if gamma is None else self._screening_light(gamma, origin_px),
            frame_shape=frame_shape,
        )

    def _find_in_regions(
        self,
        gray: NDArray[Any],
        full_scale: float,
        regions: NDArray[np.int64],
        cut: dict[str, int],
        gamma: preprocessing.LocalGamma | None,
    ) -> Candidates:
        """Candidates inside each window, found on the window plus a margin for the filters.

        ``cut`` and ``gamma`` as for :meth:`_find_candidates`.
        """
        height, width = gray.shape
        coarsest = 2 ** (screening.saddle_levels(self._radius_range).stop - 1)
        margin = _REGION_MARGIN_LEVEL_PX * coarsest + _REGION_MARGIN_PX
        parts = []
        for x0, y0, x1, y1 in regions:
            # A region wholly beyond the frame's border (a track leaving the view)
            # holds no pixel to search.
            if min(x1, width) <= max(x0, 0) or min(y1, height) <= max(y0, 0):
                continue
            # Windows start on the coarsest level's pixel grid, so every level sees the
            # same pixels as in a full-frame pass and finds the same peaks.
            cx0, cy0 = max(int(x0) - margin, 0), max(int(y0) - margin, 0)
            cx0, cy0 = cx0 - cx0 % coarsest, cy0 - cy0 % coarsest
            cx1, cy1 = min(int(x1) + margin, width), min(int(y1) + margin, height)
            if cx1 - cx0 < _REGION_MIN_PX or cy1 - cy0 < _REGION_MIN_PX:
                continue
            found = self._find_candidates(
                gray[cy0:cy1, cx0:cx1],
                full_scale,
                (int(x0) - cx0, int(y0) - cy0, int(x1) - cx0, int(y1) - cy0),
                (cx0, cy0),
                cut,
                gamma,
                (height, width),
            )
            xy = found.xy + [cx0, cy0]
            inside = (xy[:, 0] >= x0) & (xy[:, 0] < x1) & (xy[:, 1] >= y0) & (xy[:, 1] < y1)
            parts.append(Candidates(xy, found.strength, found.scale_px).take(inside))
        return Candidates.concat(parts)

    def _screening_light(
        self, gamma: preprocessing.LocalGamma, origin_px: tuple[int, int]
    ) -> screening.LightWeight:
        """The light's weight for screening an image whose pixel (0, 0) is ``origin_px``.

        :meth:`preprocessing.ShadowedContrast.weight` of the local mean there.
        """
        origin = np.asarray(origin_px, np.float64)
        shadowed = self.shadowed
        return screening.LightWeight(
            lambda xy: shadowed.weight(gamma.mean_at(xy + origin)),
            lambda y, x_first, x_last: shadowed.weight_on_spans(
                gamma, y + origin[1], x_first + origin[0], x_last + origin[0]
            ),
        )
