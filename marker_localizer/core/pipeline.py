"""The detector: the paper's three stages chained, built once from a config.

preprocess (3.1) -> screen candidates (3.2) -> centre them -> verify the two
invariants (3.2) -> sub-pixel location (3.3). Every stage is a function of its
own module; this one only chains them, counts what each stage removes and times
it, so that nothing disappears without a counter.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from marker_localizer.config import DetectorConfig
from marker_localizer.core import (
    acceptance,
    decision,
    plate,
    preprocessing,
    screening,
    second_reading,
    subpixel,
    template,
    verification,
)
from marker_localizer.core.image import to_gray
from marker_localizer.core.noise import NoiseModel, estimate_noise
from marker_localizer.core.sampling import nearest_pixels
from marker_localizer.core.screening import Candidates

#: The most prescreened candidates of a frame that go on to the centring, verification
#: and fit (0.25-0.5 ms each on one core), spread over the frame as Eq. (7) spreads
#: them: a safety net above every real frame measured, which bounds pathological ones
#: (a 12 MP tiling of X's, whose 20 000 candidates all pass the prescreen, took 12.6 s).
#: The busiest real ground, aerial_negatives' sand (8 MP), leaves up to 3193, 4216 and
#: 2354 at radius 3-30, 4-40 and 6-40 px; libcbdetect's e5 1571 for its 503 corners.
#: A cap of 2000 lost one of 233 markers planted on aerial_negatives and cirn_uas.
_MAX_VERIFIED = 5000
#: The most candidates of a frame that pass the ring checks, the template NCC, the
#: modulation gate and their score floor and go on to the double-line check and the fit
#: (0.3-0.5 ms each on one core); the template is matched cell by cell, the best ring
#: symmetry first, only until this many have passed (:meth:`Detector._match_templates`).
#: Real ground never reaches it: at most 531 passed on the 50 real board images
#: (libcbdetect's e5, 503 corners), the rendered families, the independent frames,
#: cirn_uas and aerial_negatives (up to 266 on sand at radius 2-30 px); a 12 MP tiling
#: of X's passes all 5000 of the prescreen's cap (2.5 s per frame without this cap).
_MAX_CONFIRMED = 800
#: Fewest candidates matched at once while the cap is not reached: fewer calls.
_MIN_TEMPLATE_BATCH = 256
#: The counts of :class:`DetectionResult` that say what the caps cut, the price of a
#: bounded worst case (``max_candidates`` after screening, :data:`_MAX_VERIFIED` after
#: the prescreen, :data:`_MAX_CONFIRMED` after the template, and
#: :data:`acceptance.MAX_PLATE_ASKED` at the plate's test): the node's diagnostics
#: show their sum.
CAP_COUNTS = ("dropped_over_cap", "dropped_over_verification_cap", "plate_asked_over_cap")
#: ``min_contrast_dn`` is in 8-bit grey levels, of which white is this: the thresholds
#: in grey levels are its share of white times the image's white (``full_scale``).
_WHITE_DN = 255.0
#: The prescreen's rings, and every detection's fit, need this share of
#: ``min_contrast_dn`` in raw (not gamma-corrected) grey levels: lenient, as the rings
#: may sit off the centre and gamma stretches dark ground.
_RAW_CONTRAST_SHARE = 0.5
#: :data:`SURVIVOR_TESTS`' names of :meth:`acceptance.MarkerModel.judge`'s tests, in
#: the order of :data:`acceptance.JUDGED_REASONS`.
_JUDGED_TESTS = ("floor", "x_end", "misfit", "quartic")
#: The tests of the default path in the order :attr:`DetectionResult.survivors` lists
#: them (``floor``, the score floor, runs on the ring symmetry, on it times the
#: template's NCC, and on the fitted score; ``cap`` is a cap on the candidates;
#: ``x_end``, that a small X ends where its extent does (:func:`verification.x_ends`);
#: ``misfit``, that the blurred X explains the detection
#: (:meth:`acceptance.MarkerModel.explains`); ``quartic``, that the plate model of a
#: tiny X, or of one that barely clears its floor, explains it no worse than a smooth
#: surface (:meth:`acceptance.MarkerModel.plate_not_worse`); ``lattice``, after the
#: last suppression, that the ground does not repeat the detection
#: (:meth:`acceptance.MarkerModel.stands_alone`);
#: ``recentring``, the detections once the lost wide candidates are centred again,
#: and ``shadow``, once they are read again with a shadow's edge divided out: the
#: two tests that add, :meth:`Detector._recentre_lost` and
#: :meth:`Detector._reread_shadowed`; ``plate``, once tiny X's are read with their
#: plate, :meth:`Detector._read_plates`).
SURVIVOR_TESTS = (
    "screening",
    "prescreen",
    "cap",
    "centring",
    "symmetry",
    "floor",
    "modulation",
    "template",
    "floor",
    "cap",
    "fit",
    "floor",
    "x_end",
    "misfit",
    "quartic",
    "lines",
    "merging",
    "lattice",
    "recentring",
    "shadow",
    "plate",
)
#: Candidates centred closer than this to a stronger one have found its X, px.
_CENTRED_DUPLICATE_PX = 1.5
#: Context screened around a search region: the filters of the coarsest pyramid level
#: reach 2 level pixels (5x5 Sobel), plus the halving alignment; this many of that
#: level's pixels, plus :data:`_REGION_MARGIN_PX` full-resolution ones, suffice.
_REGION_MARGIN_LEVEL_PX = 4
_REGION_MARGIN_PX = 4
#: A search region with its context narrower than this holds no candidate, px: the
#: screening's 5x5 filters need that much image.
_REGION_MIN_PX = 8
#: ``refinement="template"``: a sector-order prescreen ring's edge pairs must exceed
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


@dataclass
class DetectionResult:
    """Detections of one frame, with per-stage counts and timings.

    Iterating over a result yields its :class:`Detection` objects.

    Attributes:
        detections: accepted markers, strongest first.
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
            (:meth:`acceptance.MarkerModel.stands_alone`),
            ``merged_duplicates``, ``recentred``, ``found_recentred``,
            ``kept_faint`` and ``kept_under_floor`` (X's the modulation gate or
            the fit's score floor rejected that the marker's model vouches for,
            :meth:`acceptance.MarkerModel.vouches`), ``dull_read`` and ``kept_dull`` (X's
            the ring check rejected that were read again from the light slope's
            centre, and those of them it took, :func:`second_reading.read_dull`),
            ``recentring_over_cap`` (:meth:`Detector._recentre_lost`), ``shadow_read``,
            ``found_shadowed``, ``located_in_shadow``, ``shadow_over_cap``
            (:meth:`Detector._reread_shadowed`),
            ``uneven_over_cap`` (X's located by their levels' fit, not their model, for
            :data:`subpixel.MAX_MODELLED`),
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
            ``dropped_over_verification_cap`` those over :data:`_MAX_VERIFIED` after
            the prescreen and over :data:`_MAX_CONFIRMED` after the template;
            ``plate_asked_over_cap`` the located X's rejected unread at the
            plate's test; :data:`CAP_COUNTS` are the caps' cuts.
        timings_ms: wall time per stage in milliseconds.
        verdicts: with ``refinement="template"``, every candidate the decision saw:
            where its fit ended, whether it was accepted and why not, its score and
            evidence; None otherwise.
        survivors: (test, (K, 2) positions of the candidates that passed it), in
            the order the tests ran: where a marker was lost is the first test
            after which no candidate is left near it. The default path records
            every test (:data:`SURVIVOR_TESTS`); the paper's and the template path
            the screening and the prescreen. References to arrays the stages
            make anyway: no copies.
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
        """(N, 7) float64: x, y, score, sigma, angle1, angle2, radius_px."""
        return np.array(
            [
                [d.x, d.y, d.score, d.sigma, d.angle1, d.angle2, d.radius_px]
                for d in self.detections
            ],
            dtype=np.float64,
        ).reshape(-1, 7)


@dataclass(frozen=True)
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
            if value.size % columns:
                raise ValueError(f"SearchPlan.{name} of shape {value.shape} is not (N, {columns})")
            if name != "regions" and not np.isfinite(value).all():
                raise ValueError(f"SearchPlan.{name} holds a NaN or infinite position")
            dtype = np.int64 if name == "regions" else np.float64
            object.__setattr__(self, name, value.astype(dtype).reshape(-1, columns))


class Detector:
    """Diagonal-marker detector; build once, call :meth:`detect` per frame.

    Example:
        >>> import cv2, numpy as np
        >>> from marker_localizer import Detector, DetectorConfig
        >>> image = np.full((64, 64), 200, np.uint8)
        >>> image[:32, :32] = image[32:, 32:] = 30     # an X centred between pixels
        >>> image = cv2.GaussianBlur(image, (0, 0), 1.0)  # real optics blur
        >>> [(round(d.x, 3), round(d.y, 3)) for d in Detector(DetectorConfig()).detect(image)]
        [(31.5, 31.5)]
    """

    def __init__(self, config: DetectorConfig | None = None) -> None:
        self.config = config or DetectorConfig()
        self._radius_range = (self.config.marker_radius_min_px, self.config.marker_radius_max_px)
        self._radii = verification.ring_radii(self._radius_range)
        self._threshold = decision.threshold_for_rate(self.config.false_points_per_mp)
        self._floors = acceptance.ScoreFloors(
            self.config.min_score, self.config.min_score_small, self.config.marker_radius_min_px
        )
        self._template_gates = acceptance.TemplateGates(
            self.config.template_offset_px,
            self.config.marker_radius_min_px,
            self.config.min_modulation,
            self.config.template_ncc_min,
        )
        #: ``min_contrast_dn`` as a share of white.
        self._min_contrast = self.config.min_contrast_dn / _WHITE_DN
        self._shadowed = preprocessing.ShadowedContrast(
            self._min_contrast, self.config.min_modulation
        )
        first_level = screening.saddle_levels(self._radius_range).start
        self._seed_scale = screening.candidate_scale(first_level, self._radius_range)

    @property
    def merge_radius_px(self) -> float:
        """Detections closer than this to a stronger one are its duplicates, px.

        Half of ``min_peak_separation_px``: the last suppression of every pass.
        """
        return self.config.min_peak_separation_px / 2.0

    @property
    def region_lattice_px(self) -> int:
        """Grid of :class:`SearchPlan` regions that changes no score, px.

        That of the local-mean map of Eq. (2)
        (:func:`preprocessing.local_mean_lattice_px`): regions snapped to it read the
        same local means as a full-frame pass.
        """
        return preprocessing.local_mean_lattice_px(self.config.illumination_window_px)

    @property
    def support_radii(self) -> float:
        """How far around a marker its acceptance reads the image, in marker radii.

        The double-line check's window (:data:`verification.LSD_WINDOW_RADII`), the
        widest of the checks: where the frame border cuts less than this from a
        marker's centre, what a full pass accepts depends on the cut.
        """
        return verification.LSD_WINDOW_RADII

    def detect(self, image: NDArray[Any], plan: SearchPlan | None = None) -> DetectionResult:
        """Find and locate every diagonal marker in ``image``.

        Args:
            image: (H, W) uint8/uint16/float grey image, or BGR(A) colour.
            plan: where to search (tracking mode, :class:`SearchPlan`); None: the
                whole frame.

        Returns:
            :class:`DetectionResult` (iterable of :class:`Detection`).

        Raises:
            ImageError: the image is empty or of an unsupported type.
        """
        result = DetectionResult()
        timer = _StageTimer(result.timings_ms)
        cfg = self.config
        with timer("input"):
            gray, full_scale = to_gray(image, bit_depth=self.config.bit_depth)
        noise = None
        if cfg.refinement == "template":
            with timer("noise"):
                noise = estimate_noise(gray, full_scale)
        regions = None if plan is None else plan.regions
        seeds = np.zeros((0, 2)) if plan is None else plan.seeds
        gamma = None
        with timer("preprocessing"):
            measured = regions
            if regions is not None and len(seeds):
                # The local means of Eq. (2) are looked up at each candidate's centre.
                corner = np.floor(seeds).astype(np.int64)
                seed_boxes = np.hstack([corner, corner + 2])
                measured = np.vstack([np.reshape(regions, (-1, 4)), seed_boxes])
            if noise is None or cfg.candidate_detector == "curvature":
                gamma = preprocessing.LocalGamma(
                    gray,
                    full_scale,
                    cfg.gamma_alpha,
                    cfg.illumination_window_px,
                    regions=measured,
                )
        # What the default and the paper's checks read of the frame (the template
        # path on the saddle screening reads the noise instead).
        frame = None if gamma is None else _Frame(gray, full_scale, gamma, result, timer)
        with timer("screening"):
            candidates = self._screen(gray, full_scale, result.counts, regions, gamma)
            result.counts["skipped_known"] = 0
            if plan is not None and len(plan.known) and len(candidates):
                distance, _ = cKDTree(plan.known).query(
                    candidates.xy, distance_upper_bound=cfg.min_peak_separation_px
                )
                near = np.isfinite(distance)
                result.counts["skipped_known"] = int(near.sum())
                candidates = candidates.take(~near)
            result.survivors.append(("screening", candidates.xy))
        with timer("prescreen"):
            result.counts["rejected_prescreen"] = result.counts["dropped_over_verification_cap"] = 0
            if noise is not None and cfg.candidate_detector == "saddle":
                candidates, angles = self._order_prescreen(
                    gray, full_scale, noise, candidates, result.counts
                )
                result.survivors.append(("prescreen", candidates.xy))
            elif cfg.candidate_detector == "saddle":
                # Contour corners sit up to 2 px off the centre, too far for the
                # prescreen's small rings; the paper's path goes straight to centring.
                assert frame is not None
                candidates = self._prescreen(frame, candidates)
        if noise is not None and cfg.candidate_detector == "saddle":
            if cfg.line_check:
                with timer("verification"):
                    candidates, angles = self._straight_edges(
                        gray, full_scale, candidates, angles, result.counts
                    )
            if len(seeds):
                # A seed is a tracked marker, perhaps a fraction of a pixel off: it
                # skips the prescreen's test and takes its line directions only.
                scale = np.full(len(seeds), self._seed_scale)
                seeded = Candidates(seeds, np.full(len(seeds), np.inf), scale)
                candidates = Candidates.concat([candidates, seeded])
                angles = np.vstack([angles, self._line_directions(gray, seeded)])
            start = self._fit_start(candidates.scale_px)
            self._fit_and_decide(gray, noise, candidates.xy, angles, start, result, timer)
            return result
        if len(seeds):
            # The prescreen rejects texture saddles; a seed is a tracked marker, perhaps
            # a fraction of a pixel off, too far for those rings. Seeds win the
            # centring's suppression against screened candidates.
            strength = np.full(len(seeds), np.inf)
            scale = np.full(len(seeds), self._seed_scale)
            candidates = Candidates.concat([candidates, Candidates(seeds, strength, scale)])
        assert frame is not None
        if cfg.candidate_detector == "curvature":
            return self._confirm_paper(frame, noise, candidates)
        return self._confirm(frame, candidates)

    def locate(
        self,
        image: NDArray[Any],
        xy: NDArray[np.float64],
        radius_px: NDArray[np.float64],
        line_angles: NDArray[np.float64],
        evidence: NDArray[np.float64],
    ) -> DetectionResult:
        """Section 3.3 alone: sub-pixel centres and final gates of markers known to be there.

        Tracking mode confirms the markers of the last frame with this instead of
        screening and verifying them again: the fit, its gates and the score are
        those of :meth:`detect`, with the extent, line angles and verification
        evidence the marker had when it was last detected. A position within a
        pixel or so of the centre converges to the centre :meth:`detect` reports
        (to the fit's tolerance, 0.001 px); a marker no longer there fails the
        fit's residual gate or moves too far.

        Args:
            image: the frame, as for :meth:`detect`.
            xy: (N, 2) predicted centres.
            radius_px: (N,) extents (``Detection.radius_px``).
            line_angles: (N, 2) line directions (``Detection.angle1``, ``angle2``).
            evidence: (N,) ``Detection.evidence``.

        Returns:
            :class:`DetectionResult` of the confirmed markers.

        Raises:
            ImageError: as :meth:`detect`.
            ValueError: the four arrays do not describe the same N points, or hold a
                NaN or an infinity.
        """
        xy, radius_px, line_angles, evidence = _known_markers(xy, radius_px, line_angles, evidence)
        result = DetectionResult()
        timer = _StageTimer(result.timings_ms)
        with timer("input"):
            gray, full_scale = to_gray(image, bit_depth=self.config.bit_depth)
        if self.config.refinement == "template":
            with timer("noise"):
                noise = estimate_noise(gray, full_scale)
            self._fit_and_decide(
                gray, noise, xy, line_angles, self._fit_start(radius_px), result, timer
            )
            return result
        counts = result.counts
        counts["merged_duplicates"] = 0
        with timer("preprocessing"):
            # The local means of Eq. (2) at the markers alone, for the fit's contrast floor.
            corner = np.floor(xy).astype(np.int64)
            gamma = preprocessing.LocalGamma(
                gray,
                full_scale,
                self.config.gamma_alpha,
                self.config.illumination_window_px,
                regions=np.hstack([corner, corner + 2]),
            )
        frame = _Frame(gray, full_scale, gamma, result, timer)
        known = _RingPassed(xy, radius_px, line_angles, evidence)
        with timer("subpixel"):
            result.detections = self._locate(
                frame, known.xy, known.radius_px, known.line_angles, known.score
            )
        self._confirm_plates(frame, known)
        counts["accepted"] = len(result.detections)
        return result

    def _confirm_plates(self, frame: _Frame, known: _RingPassed) -> None:
        """Tracked tiny X's the fit's floors reject, confirmed by their plate.

        A full pass finds many tiny markers by their plate alone
        (:meth:`_read_plates`), under the score floors :meth:`_locate` holds a
        tracked marker to, so that tracking alone loses markers a full pass finds
        (measured: docs/method.md, "A tiny X is judged by its plate"). Where plates are
        read, the tracked X's of texture's size that :meth:`_locate` left without a
        marker are fitted (:meth:`_fit_plates`) and kept where the plate model
        explains them at the fitted centre (:func:`plate.plate_explains`).
        Counted as ``found_plate``.
        """
        result = frame.result
        result.counts["found_plate"] = 0
        if not self._reads_plates:
            return
        lost = self._far_from_detections(result, known.xy)
        lost = lost[known.radius_px[lost] < verification.X_END_MAX_EXTENT_PX]
        if not len(lost):
            return
        with frame.timer("subpixel"):
            fitted = self._fit_plates(frame, known, lost)
        if not fitted:
            return
        with frame.timer("plate"):
            xy = _positions(fitted)
            extent = np.array([d.radius_px for d in fitted])
            angles = np.array([[d.angle1, d.angle2] for d in fitted])
            explained = plate.explained_at(frame.gray, xy, extent, angles)
        result.counts["found_plate"] = self._join(
            result, [d for d, ok in zip(fitted, explained, strict=True) if ok]
        )

    def _confirm(self, frame: _Frame, candidates: Candidates) -> DetectionResult:
        """Centre, verify and locate the candidates of the saddle path."""
        result = frame.result
        with frame.timer("centring"):
            plain = subpixel.coarse_centre(
                frame.gray, candidates.xy, candidates.scale_px, self.config.marker_radius_max_px
            )
            centred = self._centre(candidates, plain, result)
        result.detections, tiny = self._verify_and_locate(frame, centred)
        self._recentre_lost(frame, candidates, plain)
        self._reread_shadowed(frame, candidates)
        self._read_plates(frame, tiny)
        result.counts["accepted"] = len(result.detections)
        return result

    def _verify_and_locate(
        self, frame: _Frame, candidates: Candidates
    ) -> tuple[list[Detection], _RingPassed]:
        """The checks, the template match and the fit of centred candidates: their markers.

        Also the tiny X's the ring check passed (:meth:`_verify`), for
        :meth:`_read_plates`.
        """
        with frame.timer("verification"):
            candidates, radius, angles, score, tiny = self._verify(frame, candidates)
        with frame.timer("subpixel"):
            located = self._locate(
                frame, candidates.xy, radius, angles, score, check_lines=self._lines_after_fit
            )
        return located, tiny

    def _recentre_lost(
        self,
        frame: _Frame,
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
        result.survivors.append(("recentring", _positions(result.detections)))

    def _reread_shadowed(self, frame: _Frame, screened: Candidates) -> None:
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
                    self._line_directions(gray, chosen),
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
                    _positions(found),
                    np.array([d.sigma for d in found]),
                    np.array([(d.angle1, d.angle2) for d in found]),
                    np.array([d.radius_px for d in found]),
                    frame.full_scale,
                    reading,
                )
                counts["located_in_shadow"] = int(located.sum())
                found = [
                    replace(d, x=float(x), y=float(y), sigma=float(e))
                    for d, (x, y), e in zip(found, xy, sigma, strict=True)
                ]
            counts["found_shadowed"] = self._join(result, found)
        result.survivors.append(("shadow", _positions(result.detections)))

    def _lost_wide(
        self, result: DetectionResult, screened: Candidates, cap: int
    ) -> tuple[NDArray[np.intp], int]:
        """:func:`second_reading.lost_wide` of the screened candidates, against the detections."""
        return second_reading.lost_wide(
            screened,
            _positions(result.detections),
            self.merge_radius_px,
            cap,
            self.config.entropy_cell_px,
        )

    def _far_from_detections(
        self, result: DetectionResult, xy: NDArray[np.float64]
    ) -> NDArray[np.intp]:
        """Indices of the points farther than the merge radius from every detection."""
        return second_reading.far_from(_positions(result.detections), xy, self.merge_radius_px)

    def _join(self, result: DetectionResult, added: list[Detection]) -> int:
        """Add a second reading's markers to the detections; returns how many joined.

        A duplicate (:func:`second_reading.new_points`) is counted in
        ``merged_duplicates``.
        """
        if not added:
            return 0
        unique = second_reading.new_points(
            _positions(result.detections),
            _positions(added),
            np.array([d.score for d in added]),
            self.merge_radius_px,
        )
        result.counts["merged_duplicates"] += int((~unique).sum())
        joined = [d for d, keep in zip(added, unique, strict=True) if keep]
        result.detections = sorted(result.detections + joined, key=lambda d: -d.score)
        return len(joined)

    def _confirm_paper(
        self, frame: _Frame, noise: NoiseModel | None, candidates: Candidates
    ) -> DetectionResult:
        """The paper's checks and location (sections 3.2-3.3) for the curvature path.

        The annular check by edge phase and polarity (which also moves each
        candidate to where its lines cross), the template's NCC with the annular
        score (:func:`template.template_evidence`), the LSD double line (its angles
        feed the template where they agree with the rings'), then with
        ``refinement="ncc"`` the adaptive template's NCC surface and its quadratic
        extremum, accepted where the surface peaks at :data:`subpixel.NCC_PEAK_MIN`
        or more; with ``refinement="symmetry"`` the default's fit and gates, with
        ``refinement="template"`` the template fit and the calibrated decision.
        """
        cfg = self.config
        gray, result, timer = frame.gray, frame.result, frame.timer
        counts = result.counts
        counts["rejected_centring"] = 0
        with timer("verification"):
            check = verification.edge_phase_check(
                gray,
                candidates.xy,
                self._radii,
                min_contrast=self._min_contrast,
                normalise=frame.gamma,
            )
            keep = check.accepted & verification.reaches_extent(
                check.radius_px, cfg.min_extent_fraction, cfg.marker_radius_min_px
            )
            counts["rejected_symmetry"] = int((~keep).sum())
            xy, radius = check.xy[keep], check.radius_px[keep]
            angles, score = check.line_angles[keep], check.score[keep]
            unique = screening.non_maximum_suppression(xy, score, self.merge_radius_px)
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
            else:
                counts["rejected_lines"] = 0
        if noise is not None:
            start = self._fit_start(radius)
            self._fit_and_decide(gray, noise, xy, angles, start, result, timer)
            return result
        with timer("subpixel"):
            if cfg.refinement != "ncc":
                result.detections = self._locate(frame, xy, radius, angles, score)
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
            order = np.flatnonzero(matched)
            order = order[np.argsort(-score[order])]
            result.detections = [
                Detection(
                    float(fit.offset[k, 0]),
                    float(fit.offset[k, 1]),
                    float(score[k]),
                    float(fit.sigma[k]),
                    float(angles[k, 0]),
                    float(angles[k, 1]),
                    float(radius[k]),
                    float(score[k]),
                )
                for k in order
            ]
        counts["accepted"] = len(result.detections)
        return result

    def _screen(
        self,
        gray: NDArray[Any],
        full_scale: float,
        counts: dict[str, int],
        regions: NDArray[np.integer[Any]] | None = None,
        gamma: preprocessing.LocalGamma | None = None,
    ) -> Candidates:
        """Section 3.2, first layers: candidates, suppression, grid-entropy thinning, cap.

        With ``gamma``, the saddle screening's threshold is lowered in shadow
        (:class:`preprocessing.ShadowedContrast`).
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
    ) -> Candidates:
        """Screening candidates; ``window`` (x0, y0, x1, y1) bounds where they are wanted.

        ``origin_px`` is where ``gray``'s pixel (0, 0) lies in the frame; ``cut``
        counts what the saddle screening's caps cut (:func:`screening.saddle_candidates`);
        ``gamma``, if given, lowers its threshold in shadow.
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
                self._min_contrast,
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
            self._min_contrast * full_scale,
            relative_threshold=cfg.saddle_threshold,
            window=window,
            cell_cap=screening.CellCap(
                cfg.entropy_cell_px, cfg.max_candidates_per_cell, cfg.max_candidates, origin_px
            ),
            tally=cut,
            shadow=None if gamma is None else self._screening_shadow(gamma, origin_px),
        )

    def _find_in_regions(
        self,
        gray: NDArray[Any],
        full_scale: float,
        regions: NDArray[np.float64],
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
            # Windows start on the coarsest level's pixel grid, so every level sees the
            # same pixels as in a full-frame pass and finds the same candidates.
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
            )
            xy = found.xy + [cx0, cy0]
            inside = (xy[:, 0] >= x0) & (xy[:, 0] < x1) & (xy[:, 1] >= y0) & (xy[:, 1] < y1)
            parts.append(Candidates(xy, found.strength, found.scale_px).take(inside))
        return Candidates.concat(parts)

    def _prescreen(self, frame: _Frame, candidates: Candidates) -> Candidates:
        """A three-ring centre-symmetry test at each candidate's own scale, before any fit.

        Lenient per ring (the candidate may sit a fraction of its scale off the
        centre; raw grey levels, half the contrast) but strict over the rings (all
        three), it removes ~95 % of the texture saddles for the price of at most
        108 nearest-pixel samples each (the cascade stops at the first bad ring).
        At most :data:`_MAX_VERIFIED` of those that pass go on, spread over the
        frame as Eq. (7)'s thinning spreads them (:func:`screening.even_cap`); the
        rest are cut and counted. Candidates screened beyond texture's scale
        (:data:`second_reading.WIDE_SCALE_PX`) that fail are read again with the
        bright sectors equalised (:func:`verification.ring_check` says why and when).
        """
        gray, result = frame.gray, frame.result
        floor = self._raw_contrast_floor(frame.full_scale, frame.gamma, candidates.xy)
        radii = self._prescreen_radii(candidates)
        keep, first_ring = verification.prescreen_symmetry(gray, candidates.xy, radii, floor)
        wide = np.flatnonzero(~keep & second_reading.screened_wide(candidates))
        # The equalised re-read takes the first rings the plain one gathered.
        keep[wide] = verification.prescreen_symmetry(
            gray, candidates.xy[wide], radii[wide], floor[wide], True, first_ring[wide]
        )[0]
        result.counts["rejected_prescreen"] = int((~keep).sum())
        passed = candidates.take(keep)
        capped = screening.even_cap(passed, _MAX_VERIFIED, self.config.entropy_cell_px)
        result.counts["dropped_over_verification_cap"] = len(passed) - len(capped)
        result.survivors += [("prescreen", passed.xy), ("cap", capped.xy)]
        return capped

    def _order_prescreen(
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
        grey-level symmetry of :meth:`_prescreen`, a dull quadrant or a shadow edge
        across the marker leave the sector order standing
        (:func:`verification.sector_order`).

        Returns:
            The candidates that pass and (N, 2) their line directions.
        """
        level = nearest_pixels(gray, candidates.xy)
        min_strength = np.maximum(
            _ORDER_NOISE_SIGMAS * verification.ring_edge_noise(noise.std(level)),
            _ORDER_CONTRAST_SHARE * self.config.min_contrast_dn / _WHITE_DN * full_scale,
        )
        passed, angles = verification.prescreen_sector_order(
            gray, candidates.xy, self._prescreen_radii(candidates), min_strength
        )
        counts["rejected_prescreen"] = int((~passed).sum())
        return candidates.take(passed), angles[passed]

    def _straight_edges(
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

    def _prescreen_radii(self, candidates: Candidates) -> NDArray[np.float64]:
        """(N, 3) the prescreen's ring radii for each candidate, px."""
        return verification.prescreen_ring_radii(
            candidates.scale_px, self.config.marker_radius_min_px
        )

    def _line_directions(self, gray: NDArray[Any], candidates: Candidates) -> NDArray[np.float64]:
        """(N, 2) the directions of the edge pairs on each candidate's first prescreen ring."""
        radii = self._prescreen_radii(candidates)[:, :1]
        _, angles = verification.prescreen_sector_order(
            gray, candidates.xy, radii, np.full(len(candidates), -np.inf)
        )
        return angles

    def _fit_start(self, scale_px: NDArray[np.float64]) -> NDArray[np.float64]:
        """The template fit's first region radius for candidates of this scale, px."""
        return np.clip(
            _FIT_START_SCALE * scale_px, _FIT_MIN_START_PX, self.config.marker_radius_max_px
        )

    def _fit_and_decide(
        self,
        gray: NDArray[Any],
        noise: NoiseModel,
        xy: NDArray[np.float64],
        angles: NDArray[np.float64],
        start_radius: NDArray[np.float64],
        result: DetectionResult,
        timer: _StageTimer,
    ) -> None:
        """``refinement="template"``: grown template fits, the decision, the markers.

        Fills ``result``'s detections, counts and verdicts. Each candidate's
        template grows from inside its X out to where the lines end
        (:func:`subpixel.fit_growing_template`); :func:`decision.decide` reads the
        evidence and accepts at the threshold of ``false_points_per_mp``; the
        accepted are fitted again on every pixel of their X for their position.
        """
        cfg = self.config
        counts = result.counts
        with timer("subpixel"):
            shape = template.TemplateShape.start(xy, angles, _FIT_START_BLUR_PX)
            level = nearest_pixels(gray, xy)
            grown = subpixel.fit_growing_template(
                gray,
                shape,
                start_radius,
                cfg.marker_radius_max_px,
                max_pixels=_DECISION_PIXELS,
                noise_std=noise.std(level.astype(np.float64)),
                keep=decision.worth_growing,
            )
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
        with timer("subpixel"):
            accepted = verdict.accepted
            fit = subpixel.refit_on_every_pixel(gray, grown, accepted, cfg.marker_radius_max_px)
            position = fit.shape.xy
            sigma = np.sqrt(np.maximum(fit.covariance[:, 0, 0] + fit.covariance[:, 1, 1], 0.0))
            keep = np.flatnonzero(accepted)
            unique = screening.non_maximum_suppression(
                position[keep], verdict.score[keep], self.merge_radius_px
            )
            counts["merged_duplicates"] = counts.get("merged_duplicates", 0) + int((~unique).sum())
            keep = keep[unique]
            keep = keep[np.argsort(-verdict.score[keep])]
            counts["accepted"] = len(keep)
            confidence = decision.confidence(verdict.score)
            line_angles = fit.shape.line_angles
            result.detections = [
                Detection(
                    float(position[k, 0]),
                    float(position[k, 1]),
                    float(confidence[k]),
                    float(sigma[k]),
                    float(line_angles[k, 0]),
                    float(line_angles[k, 1]),
                    float(evidence.extent_px[k]),
                    float(confidence[k]),
                )
                for k in keep
            ]

    def _raw_contrast_floor(
        self, full_scale: float, gamma: preprocessing.LocalGamma, xy: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """(N,) :data:`_RAW_CONTRAST_SHARE` of the configured contrast in raw grey units at ``xy``.

        The prescreen's ring floor, which every detection's fit also meets; lowered
        in shadow (:class:`preprocessing.ShadowedContrast`) as the screening's threshold is.
        """
        floor = _RAW_CONTRAST_SHARE * self._min_contrast * full_scale
        gain = self._shadowed.gain_at(gamma, xy)
        return np.full(len(xy), floor) if gain is None else floor / gain

    def _screening_shadow(
        self, gamma: preprocessing.LocalGamma, origin_px: tuple[int, int]
    ) -> screening.ShadowGain:
        """The shadow's gain for screening an image whose pixel (0, 0) is ``origin_px``.

        :meth:`preprocessing.ShadowedContrast.gain` of the local mean there.
        """
        origin = np.asarray(origin_px, np.float64)
        gain = self._shadowed.gain
        # The gain falls as the mean rises: the darkest means bound it from above.
        return screening.ShadowGain(
            lambda xy: gain(gamma.mean_at(xy + origin)),
            lambda y: gain(gamma.darkest_mean_on_rows(y + origin[1])),
            lambda xy: gain(gamma.darkest_mean_near(xy + origin)),
        )

    def _centre(
        self,
        candidates: Candidates,
        fit: tuple[NDArray[np.float64], NDArray[np.bool_]],
        result: DetectionResult,
    ) -> Candidates:
        """Each candidate at its local centre of point symmetry, those centred apart.

        ``fit`` is :func:`subpixel.coarse_centre` of the candidates: their centres, and
        where it found one. :meth:`_recentre_lost` reads it again.
        """
        xy, inside = fit
        result.counts["rejected_centring"] = int((~inside).sum())
        moved = Candidates(xy, candidates.strength, candidates.scale_px).take(inside)
        keep = screening.non_maximum_suppression(moved.xy, moved.strength, _CENTRED_DUPLICATE_PX)
        result.counts["merged_duplicates"] = int((~keep).sum())
        centred = moved.take(keep)
        result.survivors.append(("centring", centred.xy))
        return centred

    def _verify(
        self, frame: _Frame, candidates: Candidates
    ) -> tuple[
        Candidates, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], _RingPassed
    ]:
        """Section 3.2, geometric checks, and the adaptive-template NCC of section 3.3.1.

        Also returns the X's of texture's size (:data:`verification.X_END_MAX_EXTENT_PX`)
        that passed the ring check and its floor, where such markers are expected,
        for :meth:`_read_plates`.
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
        counts["rejected_score"] = int(weak.sum())
        result.survivors += [
            ("symmetry", candidates.xy[keep]),
            ("floor", candidates.xy[keep & ~weak]),
        ]
        passed = keep & ~weak
        tiny = np.flatnonzero(passed & self._model(frame).read_as_tiny(symmetry.radius_px))
        ring_passed = _RingPassed(
            candidates.xy[tiny],
            symmetry.radius_px[tiny],
            symmetry.line_angles[tiny],
            symmetry.score[tiny],
        )
        chosen, ncc = self._match_templates(
            frame,
            candidates.xy,
            symmetry,
            self._floors.lowest(symmetry.radius_px),
            np.flatnonzero(passed),
        )
        candidates, radius, angles, score = (
            candidates.take(chosen),
            symmetry.radius_px[chosen],
            symmetry.line_angles[chosen],
            symmetry.score[chosen] * ncc,
        )
        if not self._lines_after_fit:
            ok, angles = self._double_lines(frame, candidates.xy, radius, angles)
            candidates, radius, angles, score = (
                candidates.take(ok),
                radius[ok],
                angles[ok],
                score[ok],
            )
        return candidates, radius, angles, score, ring_passed

    @property
    def _reads_plates(self) -> bool:
        """Whether tiny X's are read with their plate (:meth:`_read_plates`).

        Where the smallest expected marker is of texture's size
        (:data:`verification.X_END_MAX_EXTENT_PX`): a larger one whose X reads that
        small is seen foreshortened, and its plate lies beyond the models' radii.
        """
        return (
            self.config.refinement == "symmetry"
            and self.config.marker_radius_min_px < verification.X_END_MAX_EXTENT_PX
        )

    def _model(self, frame: _Frame) -> acceptance.MarkerModel:
        """The marker's model on ``frame``, which the gates set by texture defer to."""
        return acceptance.MarkerModel(
            frame.gray,
            frame.full_scale,
            frame.noise,
            self.config.marker_radius_max_px,
            self._reads_plates,
            frame.gamma,
        )

    def _read_plates(self, frame: _Frame, tiny: _RingPassed) -> None:
        """Tiny X's that found no marker, judged by their plate (:func:`plate.read_plates`).

        The X's of texture's size the ring check passed (``tiny``) that ended farther
        than the merge radius from every detection; those the plate explains are
        fitted as every detection is (the fit's own gates, not the score floors,
        which the plate's evidence replaces) and join the detections.

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
                    counts["found_plate"] = self._join(
                        result, self._fit_plates(frame, tiny, explained)
                    )
        result.survivors.append(("plate", _positions(result.detections)))

    def _fit_plates(
        self, frame: _Frame, tiny: _RingPassed, chosen: NDArray[np.intp]
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
            gray, self._radii, self._min_contrast, self.config.symmetry_min, gamma
        )

    def _read_dull(
        self,
        frame: _Frame,
        candidates: Candidates,
        ring: verification.SymmetryCheck,
        equalised_x: NDArray[np.bool_],
    ) -> tuple[Candidates, verification.SymmetryCheck]:
        """Small X's with a dull quadrant, read again from the light slope's centre.

        :func:`second_reading.read_dull`, in the first reading alone: a second one's
        candidates are centred with the light's slope already. Counts ``dull_read``
        and ``kept_dull``.

        Returns:
            The candidates (those read again and kept moved) and their check.
        """
        counts = frame.result.counts
        counts["dull_read"] = counts.get("dull_read", 0)
        counts["kept_dull"] = counts.get("kept_dull", 0)
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
        return reading.moved(candidates, ring)

    @property
    def _lines_after_fit(self) -> bool:
        """Whether the double-line check runs on the fit's survivors (:meth:`_locate`).

        The NCC location reads the line directions the check refines, so it runs
        before that fit; the point-symmetry fit does not, and LSD (~0.15 ms a
        candidate) then sees only the few the fit and its floor leave.
        """
        return self.config.refinement == "symmetry"

    def _double_lines(
        self,
        frame: _Frame,
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
                max_distance_px=max(cfg.line_max_distance_px, 0.0),
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
        frame: _Frame,
        xy: NDArray[np.float64],
        symmetry: verification.SymmetryCheck,
        lowest: NDArray[np.float64],
        passed: NDArray[np.intp],
    ) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        """The paint's and the template's gates, and the score floor, up to the cap.

        The candidates ``passed`` (indices into ``xy``) are matched in the order
        :func:`screening.even_order` gives them (cell by cell, the best ring symmetry
        first), a batch at a time, until :data:`_MAX_CONFIRMED` have passed: where
        fewer pass, as on all real ground measured, every candidate is matched;
        where all pass (a tiling of X's) only the first are. The rest are counted
        in ``dropped_over_verification_cap``. The modulation gate, a few grey levels
        a candidate, runs first: the NCC reads a disk of up to 300 samples at four
        blurs, and on cluttered ground most candidates fail the gate (measured:
        docs/speed.md, "The modulation gate before the template"). Each batch is
        decided by :meth:`acceptance.MarkerModel.match`; this counts and records its
        reasons.

        Returns:
            The indices (ascending) of the candidates that pass, and their NCC.
        """
        cfg = self.config
        result = frame.result
        counts = result.counts
        order = passed[
            screening.even_order(xy[passed], symmetry.score[passed], cfg.entropy_cell_px)
        ]
        matched: list[NDArray[np.intp]] = []
        matched_ncc: list[NDArray[np.float64]] = []
        # Indices passing the modulation gate, and the NCC too, for the survivors.
        modulated: list[NDArray[np.intp]] = []
        correlated_too: list[NDArray[np.intp]] = []
        found = start = 0
        counts.setdefault("rejected_template", 0)
        counts.setdefault("kept_faint", 0)
        model = self._model(frame)
        while start < len(order) and found < _MAX_CONFIRMED:
            batch = order[start : start + max(_MAX_CONFIRMED - found, _MIN_TEMPLATE_BATCH)]
            start += len(batch)
            match = model.match(
                xy[batch],
                symmetry.radius_px[batch],
                symmetry.line_angles[batch],
                symmetry.score[batch],
                lowest[batch],
                self._template_gates,
            )
            counts["kept_faint"] += int(match.faint.sum())
            counts["rejected_template"] += int((~match.passed("template")).sum())
            counts["rejected_score"] += int(
                (match.reason == acceptance.MATCHED_REASONS.index("score")).sum()
            )
            accepted = match.reason == acceptance.ACCEPTED
            modulated.append(batch[match.passed("modulation")])
            correlated_too.append(batch[match.passed("template")])
            matched.append(batch[accepted])
            matched_ncc.append(match.ncc[accepted])
            found += int(accepted.sum())
        chosen = np.concatenate([np.zeros(0, np.intp), *matched])[:_MAX_CONFIRMED]
        ncc = np.concatenate([np.zeros(0), *matched_ncc])[:_MAX_CONFIRMED]
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
            ("floor", matched),
        ):
            result.survivors.append((test, xy[np.concatenate([np.zeros(0, np.intp), *kept])]))
        result.survivors.append(("cap", xy[chosen]))
        ascending = np.argsort(chosen)
        return chosen[ascending], ncc[ascending]

    def _locate(
        self,
        frame: _Frame,
        xy: NDArray[np.float64],
        radius: NDArray[np.float64],
        angles: NDArray[np.float64],
        score: NDArray[np.float64],
        check_lines: bool = False,
    ) -> list[Detection]:
        """Section 3.3: sub-pixel centres and final gates (:func:`subpixel.locate_markers`).

        Then the marker's model judges them (:meth:`acceptance.MarkerModel.judge`),
        with ``check_lines`` the double-line check (:meth:`_double_lines`: LSD, ~0.15 ms
        a candidate, so on the few the fit and the floor leave), and the last
        suppression of duplicates, strongest first.
        """
        result = frame.result
        counts = result.counts
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
        )
        counts["kept_under_floor"] = counts.get("kept_under_floor", 0) + int(judged.vouched.sum())
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
            fit.xy[keep], fit.score[keep], self.merge_radius_px
        )
        counts["merged_duplicates"] += int((~unique).sum())
        keep = keep[unique]
        result.survivors.append(("merging", fit.xy[keep]))
        keep = keep[np.argsort(-fit.score[keep])]
        return self._standing_alone(
            frame,
            self._detections(
                frame,
                fit.xy[keep],
                fit.sigma[keep],
                fit.score[keep],
                radius[keep],
                angles[keep],
                score[keep],
            ),
        )

    def _standing_alone(self, frame: _Frame, detections: list[Detection]) -> list[Detection]:
        """The detections whose ground does not repeat them, at their final centres and lines.

        :meth:`acceptance.MarkerModel.stands_alone`, where ``lattice_check`` asks for it;
        counts ``rejected_lattice``. Read
        along the lines the default path's final fit measured from the edges: a
        chessboard's go on beyond the corner within a pixel or two, where the checks'
        directions, which the paper's refinement reports, may miss them by more.
        """
        alone: NDArray[np.bool_] = np.ones(len(detections), dtype=bool)
        if self.config.refinement == "symmetry" and self.config.lattice_check and detections:
            table = np.array([(d.x, d.y, d.radius_px, d.angle1, d.angle2) for d in detections])
            alone = self._model(frame).stands_alone(table[:, :2], table[:, 2], table[:, 3:])
        counts = frame.result.counts
        counts["rejected_lattice"] = counts.get("rejected_lattice", 0) + int((~alone).sum())
        kept = [detection for detection, keep in zip(detections, alone, strict=True) if keep]
        frame.result.survivors.append(("lattice", _positions(kept)))
        return kept

    def _gating_fit(
        self,
        frame: _Frame,
        xy: NDArray[np.float64],
        radius: NDArray[np.float64],
        angles: NDArray[np.float64],
        evidence: NDArray[np.float64],
    ) -> subpixel.MarkerLocation:
        """The fit whose gates every detection passes (:func:`subpixel.locate_markers`)."""
        cfg = self.config
        # The prescreen's contrast floor holds for every detection; it matters for a
        # tracked marker confirmed by the fit alone (see :meth:`locate`), which no ring
        # has measured on this frame.
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
        frame: _Frame,
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
        return [
            Detection(
                float(xy[j, 0]),
                float(xy[j, 1]),
                float(score[j]),
                float(sigma[j]),
                float(angles[j, 0]),
                float(angles[j, 1]),
                float(radius[j]),
                float(evidence[j]),
            )
            for j in range(len(xy))
        ]


class _StageTimer:
    """Context manager factory that records the wall time of a stage in ms."""

    def __init__(self, timings: dict[str, float]) -> None:
        self._timings = timings

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            elapsed_ms = (time.perf_counter() - start) * 1000.0
            self._timings[stage] = self._timings.get(stage, 0.0) + elapsed_ms


def _known_markers(
    xy: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    evidence: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """:meth:`Detector.locate`'s arrays as (N, 2), (N,), (N, 2), (N,) float64, checked.

    Raises:
        ValueError: they do not describe the same N points, or hold a NaN or an infinity.
    """
    arrays = {
        "xy": np.asarray(xy, np.float64).reshape(-1, 2),
        "radius_px": np.asarray(radius_px, np.float64).reshape(-1),
        "line_angles": np.asarray(line_angles, np.float64).reshape(-1, 2),
        "evidence": np.asarray(evidence, np.float64).reshape(-1),
    }
    counts = {name: len(array) for name, array in arrays.items()}
    if len(set(counts.values())) > 1:
        raise ValueError(f"locate needs one row per marker in each array, got {counts}")
    for name, array in arrays.items():
        if not np.isfinite(array).all():
            raise ValueError(f"locate's {name} holds a NaN or an infinity")
    return arrays["xy"], arrays["radius_px"], arrays["line_angles"], arrays["evidence"]


def _positions(detections: list[Detection]) -> NDArray[np.float64]:
    """(N, 2) the detections' centres."""
    return np.array([[d.x, d.y] for d in detections], dtype=np.float64).reshape(-1, 2)


@dataclass(frozen=True)
class _Frame:
    """One frame as the default and the paper's checks read it, and where they report.

    Attributes:
        gray: (H, W) grey image, raw levels.
        full_scale: its white, in its own grey levels.
        gamma: the local means of Eq. (2), which normalise the rings and lower the
            contrast floors in shadow.
        result: where the stages write their counts, survivors and detections.
        timer: where they record their wall time.
        measured_noise: the frame's noise once :meth:`noise` has measured it (a
            second reading's frame holds the same list).
        slope_centred: whether the candidates read were centred with the light's
            slope (a second reading's, :meth:`reread`).
    """

    gray: NDArray[Any]
    full_scale: float
    gamma: preprocessing.LocalGamma
    result: DetectionResult
    timer: _StageTimer
    measured_noise: list[NoiseModel] = field(default_factory=list)
    slope_centred: bool = False

    def noise(self) -> NoiseModel:
        """The frame's noise (:func:`estimate_noise`), measured on first use.

        A second reading (:meth:`reread`, a shadow divided out) shares it.
        """
        if not self.measured_noise:
            self.measured_noise.append(estimate_noise(self.gray, self.full_scale))
        return self.measured_noise[0]

    def reread(self) -> _Frame:
        """The same frame reporting to a fresh result, its counts at zero, for a second reading.

        A second reading's counts describe candidates the first reading has counted;
        its candidates are centred with the light's slope (:meth:`Detector._recentre_lost`,
        :meth:`Detector._reread_shadowed`).
        """
        return replace(
            self,
            result=DetectionResult(counts=dict.fromkeys(self.result.counts, 0)),
            slope_centred=True,
        )
