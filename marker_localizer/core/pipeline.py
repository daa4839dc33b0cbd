"""The detector: the paper's three stages chained, built once from a config.

preprocess (3.1) -> screen candidates (3.2) -> the path the config names: the
default's grey-level symmetry checks and fit (:mod:`symmetry_path`), the paper's
checks after its curvature screening (:mod:`paper_path`), or the template fit
and its calibrated decision (:mod:`template_path`) -> on a colour frame, the
small X's drawn in colour left out (:mod:`chroma`). Every stage is a function or
class of its own module; this one only chains them, times the input, the
preprocessing and the screening, and routes a tracking pass's plan.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from marker_localizer.config import DetectorConfig, require_config
from marker_localizer.core import (
    chroma,
    paper_path,
    preprocessing,
    search,
    symmetry_path,
    template_path,
    verification,
)
from marker_localizer.core.frame import Frame, StageTimer
from marker_localizer.core.image import to_gray
from marker_localizer.core.noise import estimate_noise
from marker_localizer.core.paper_path import PaperPath
from marker_localizer.core.result import (
    DetectionResult,
    SearchPlan,
    extents,
    line_directions,
    positions,
)
from marker_localizer.core.screening import Candidates
from marker_localizer.core.search import CandidateSearch
from marker_localizer.core.symmetry_path import SymmetryPath
from marker_localizer.core.template_path import TemplatePath
from marker_localizer.errors import ImageError


class Detector:
    """Diagonal-marker detector; build once, call :meth:`detect` per frame.

    A detector keeps nothing from one call to the next: threads may share one (the
    node's worker threads do), each call giving what it gives alone (to the last bit
    but where a multithreaded BLAS, called from several threads at once, sums in
    another order): what its stages
    cache across calls is sample grids by radius, which no call changes. It
    pickles, so worker processes can take it
    (``ProcessPoolExecutor().map(detector.detect, images)``, with the fork, spawn or
    forkserver start method): the copy has the same :attr:`config` and gives the
    same results. Its stages are built for
    :attr:`config`, which is read-only: other settings take a new detector.

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
        """Build the detector's stages for ``config`` (None: the defaults).

        Raises:
            TypeError: ``config`` is not a :class:`DetectorConfig` instance (a mapping
                of settings, the class itself), which would otherwise be read as the
                defaults or fail on its first missing attribute.
        """
        if config is not None:
            require_config(config, DetectorConfig, "Detector")
        self._config = config if config is not None else DetectorConfig()
        self._search = CandidateSearch(self.config)
        self._symmetry = SymmetryPath(
            self.config, self._search.shadowed, self._search.seed_scale_px
        )
        self._template = TemplatePath(self.config)
        self._paper = PaperPath(self.config, self._symmetry, self._template)

    @property
    def config(self) -> DetectorConfig:
        """The settings this detector's stages were built with (read-only).

        Each stage keeps the config it was built with: a config assigned afterwards
        would reach some of them and not others. ``Detector(detector.config.replace(...))``
        gives a detector for other settings.
        """
        return self._config

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

    @property
    def max_fitted(self) -> int:
        """The most candidates one pass takes on to the sub-pixel fit: its path's cap.

        :data:`symmetry_path.MAX_CONFIRMED`, :data:`paper_path.MAX_LOCATED` or
        :data:`template_path.MAX_GROWN`, each above every real frame measured: a
        frame with more is a tiling of X's, and the rest are cut and counted.
        """
        if self.config.candidate_detector == "curvature":
            return paper_path.MAX_LOCATED
        if self.config.refinement == "template":
            return template_path.MAX_GROWN
        return symmetry_path.MAX_CONFIRMED

    def detect(
        self,
        image: NDArray[Any],
        plan: SearchPlan | None = None,
        *,
        colour: NDArray[Any] | None = None,
    ) -> DetectionResult:
        """Find and locate every diagonal marker in ``image``.

        Args:
            image: (H, W) uint8/uint16/float grey image, or BGR(A) colour.
            plan: where to search (tracking mode, :class:`SearchPlan`); None: the
                whole frame.
            colour: where ``image`` is the grey of a colour frame (a tracker converts
                it once), that frame's colour planes, for the check of
                :mod:`chroma`; a colour ``image`` is its own.

        Returns:
            :class:`DetectionResult` (iterable of :class:`Detection`).

        Raises:
            ImageError: the image is empty or of an unsupported type, or ``colour``
                is not the colour of a frame of ``image``'s size and dtype.
        """
        result = DetectionResult()
        timer = StageTimer(result.timings_ms)
        cfg = self.config
        with timer("input"):
            gray, full_scale = to_gray(image, bit_depth=cfg.bit_depth)
            colour = _colour_planes(image, gray, colour)
        return self._neutral_only(
            self._detect_grey(gray, full_scale, plan, result, timer), colour, full_scale, timer
        )

    def _detect_grey(
        self,
        gray: NDArray[Any],
        full_scale: float,
        plan: SearchPlan | None,
        result: DetectionResult,
        timer: StageTimer,
    ) -> DetectionResult:
        """:meth:`detect`'s stages on the frame's grey, up to the path's detections."""
        cfg = self.config
        noise = None
        if cfg.refinement == "template":
            with timer("noise"):
                noise = estimate_noise(gray, full_scale)
        regions = None if plan is None else plan.regions
        seeds = np.zeros((0, 2)) if plan is None else plan.seeds
        gamma = None
        with timer("preprocessing"):
            if noise is None or cfg.candidate_detector == "curvature":
                gamma = preprocessing.LocalGamma(
                    gray,
                    full_scale,
                    cfg.gamma_alpha,
                    cfg.illumination_window_px,
                    regions=preprocessing.regions_and_points(regions, seeds),
                )
        with timer("screening"):
            candidates = self._search.screen(gray, full_scale, result.counts, regions, gamma)
            result.counts["skipped_known"] = 0
            if plan is not None:
                near = search.near_known(candidates.xy, plan.known, cfg.min_peak_separation_px)
                result.counts["skipped_known"] = int(near.sum())
                candidates = candidates.take(~near)
            result.survivors.append(("screening", candidates.xy))
        # A seed is a tracked marker, perhaps a fraction of a pixel off: it joins the
        # candidates at the first pyramid level's scale, past the prescreen's test.
        seeded = Candidates.seeded(seeds, self._search.seed_scale_px)
        result.counts["rejected_prescreen"] = result.counts["dropped_over_verification_cap"] = 0
        if noise is not None and cfg.candidate_detector == "saddle":
            # The template path on the saddle screening reads the noise, not the local means.
            return self._template.confirm(
                gray, full_scale, noise, candidates, seeded, result, timer
            )
        assert gamma is not None
        frame = Frame(gray, full_scale, gamma, result, timer)
        if cfg.candidate_detector == "saddle":
            # Contour corners sit up to 2 px off the centre, too far for the
            # prescreen's small rings; the paper's path goes straight to centring.
            with timer("prescreen"):
                candidates = self._symmetry.prescreen(frame, candidates)
        if len(seeded):
            # The prescreen rejects texture saddles; a seed, perhaps a fraction of a
            # pixel off, is too far for those rings. Seeds win the centring's
            # suppression against screened candidates.
            candidates = Candidates.concat([candidates, seeded])
        if cfg.candidate_detector == "curvature":
            return self._paper.confirm(frame, noise, candidates)
        return self._symmetry.confirm(frame, candidates)

    def locate(
        self,
        image: NDArray[Any],
        xy: NDArray[np.float64],
        radius_px: NDArray[np.float64],
        line_angles: NDArray[np.float64],
        evidence: NDArray[np.float64],
        *,
        colour: NDArray[Any] | None = None,
    ) -> DetectionResult:
        """Markers known to be near ``xy``: :meth:`detect`'s stages from the centring on.

        Tracking mode confirms the markers of the last frame with this instead of
        screening the frame again. On the default path each is read as
        :meth:`detect` reads a candidate it screened there: the ring check measures
        its extent and line directions on this frame, and its template, the fit,
        their gates and the score follow
        (:meth:`~marker_localizer.core.symmetry_path.SymmetryPath.confirm_tracked`);
        on the paper's path (``candidate_detector=curvature``) its checks and
        location read it (:meth:`~marker_localizer.core.paper_path.PaperPath.confirm`).
        On both the extent, line angles and evidence given are not used. On
        ``refinement=template`` the given line angles and a start from the given
        extent
        (:meth:`~marker_localizer.core.template_path.TemplatePath.tracked_fit_start`)
        begin the grown fit. A position within a pixel or so of the centre gives the
        centre :meth:`detect` reports; a marker no longer there fails a check or the fit.
        The ground around a marker, its plate and the lattice test, is what the
        :meth:`detect` that found it judged, and is not read again. Each marker is
        read as a candidate of the first pyramid level, without the second readings:
        one that :meth:`detect` found as a wide candidate with a dull quadrant or a
        shadow's edge across it (by its equalised rings, the lines' crossing, the
        recentring or the shadow's reading) may fail here.
        :class:`~marker_localizer.core.tracking.MarkerTracker` searches a window
        around each marker this does not confirm with :meth:`detect`, which reads
        them as a full pass does (measured: docs/speed.md, "A tracked marker of a wide
        X read again as a full pass reads it").

        Args:
            image: the frame, as for :meth:`detect`.
            xy: (N, 2) predicted centres.
            radius_px: (N,) extents (``Detection.radius_px``): the template path's start.
            line_angles: (N, 2) line directions (``Detection.angle1``, ``angle2``): the
                template path's start.
            evidence: (N,) ``Detection.evidence`` (checked; not used).
            colour: as for :meth:`detect`.

        Returns:
            :class:`DetectionResult` of the confirmed markers.

        Raises:
            ImageError: as :meth:`detect`.
            ValueError: the four arrays do not describe the same N points, hold a
                NaN or an infinity, or an extent is not positive.
        """
        xy, radius_px, line_angles, evidence = _known_markers(xy, radius_px, line_angles, evidence)
        result = DetectionResult()
        timer = StageTimer(result.timings_ms)
        with timer("input"):
            gray, full_scale = to_gray(image, bit_depth=self.config.bit_depth)
            colour = _colour_planes(image, gray, colour)
        return self._neutral_only(
            self._locate_grey(gray, full_scale, xy, radius_px, line_angles, result, timer),
            colour,
            full_scale,
            timer,
        )

    def _locate_grey(
        self,
        gray: NDArray[Any],
        full_scale: float,
        xy: NDArray[np.float64],
        radius_px: NDArray[np.float64],
        line_angles: NDArray[np.float64],
        result: DetectionResult,
        timer: StageTimer,
    ) -> DetectionResult:
        """:meth:`locate`'s stages on the frame's grey, up to the path's detections."""
        if self.config.refinement == "template":
            with timer("noise"):
                noise = estimate_noise(gray, full_scale)
            start = self._template.tracked_fit_start(radius_px)
            self._template.fit_and_decide(gray, noise, xy, line_angles, start, result, timer)
            return result
        with timer("preprocessing"):
            # The local means of Eq. (2) at the markers alone, for the fit's contrast floor.
            gamma = preprocessing.LocalGamma(
                gray,
                full_scale,
                self.config.gamma_alpha,
                self.config.illumination_window_px,
                regions=preprocessing.point_windows(xy),
            )
        frame = Frame(gray, full_scale, gamma, result, timer)
        if self.config.candidate_detector == "curvature":
            # The paper's checks and location, as its full passes read the markers:
            # another estimator would give another sigma and score on tracked frames.
            return self._paper.confirm(
                frame, None, Candidates.seeded(xy, self._search.seed_scale_px)
            )
        return self._symmetry.confirm_tracked(frame, xy)

    def _neutral_only(
        self,
        result: DetectionResult,
        colour: NDArray[Any] | None,
        full_scale: float,
        timer: StageTimer,
    ) -> DetectionResult:
        """``result`` less its X's of texture's size drawn in colour (:func:`chroma.coloured_x`).

        Those over ``max_x_chroma_share``; counted as ``rejected_chroma`` (0 on a
        grey frame), the survivors recorded as ``chroma``.
        """
        result.counts["rejected_chroma"] = 0
        if colour is None or not result.detections:
            return result
        centres = positions(result.detections)
        with timer("chroma"):
            coloured = chroma.coloured_x(
                colour,
                full_scale,
                centres,
                extents(result.detections),
                line_directions(result.detections),
                self.config.max_x_chroma_share,
            )
        result.counts["rejected_chroma"] = int(coloured.sum())
        result.detections = [
            d for d, drop in zip(result.detections, coloured, strict=True) if not drop
        ]
        result.counts["accepted"] = len(result.detections)
        result.survivors.append(("chroma", centres[~coloured]))
        return result


def _colour_planes(
    image: NDArray[Any], gray: NDArray[Any], colour: NDArray[Any] | None
) -> NDArray[Any] | None:
    """The colour planes :meth:`Detector.detect` reads for :mod:`chroma`; None for a grey frame.

    ``image`` itself where it is colour; else ``colour``, checked against ``gray``.

    Raises:
        ImageError: ``colour`` is given beside a colour ``image``, has no three
            channels, or differs from ``gray`` in size or dtype.
    """
    if chroma.is_colour(image):
        if colour is not None:
            raise ImageError("colour is for a grey image's colour frame; this image is colour")
        return image
    if colour is None:
        return None
    if not isinstance(colour, np.ndarray) or not chroma.is_colour(colour):
        raise ImageError(
            f"colour must be an (H, W, 3|4) array, got {getattr(colour, 'shape', type(colour))}"
        )
    if colour.shape[:2] != gray.shape or _level_scale(colour.dtype) != _level_scale(gray.dtype):
        raise ImageError(
            f"colour {colour.shape} {colour.dtype} is not the colour of the grey image "
            f"{gray.shape} {gray.dtype}"
        )
    return colour


def _level_scale(dtype: np.dtype[Any]) -> np.dtype[Any]:
    """The dtype whose levels ``dtype``'s are read as: byte order aside, float32 as float64.

    :func:`image.to_gray` makes a frame's grey native and float32, its colour planes
    stay as given.
    """
    return np.dtype(np.float64) if dtype.kind == "f" else dtype.newbyteorder("=")


def _known_markers(
    xy: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    evidence: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """:meth:`Detector.locate`'s arrays as (N, 2), (N,), (N, 2), (N,) float64, checked.

    Raises:
        ValueError: they do not describe the same N points, hold a NaN or an infinity,
            or an extent is not positive.
    """
    arrays = {}
    for name, values, columns in (
        ("xy", xy, 2),
        ("radius_px", radius_px, 0),
        ("line_angles", line_angles, 2),
        ("evidence", evidence, 0),
    ):
        array = np.asarray(values, np.float64)
        # One point's (2,) row is taken; a (2, N) transpose is not.
        if array.ndim > (2 if columns else 1) or (columns and array.shape[-1] != columns):
            shape = f"(N, {columns})" if columns else "(N,)"
            raise ValueError(f"locate's {name} must be {shape}, got shape {array.shape}")
        arrays[name] = array.reshape(-1, columns) if columns else array.reshape(-1)
    counts = {name: len(array) for name, array in arrays.items()}
    if len(set(counts.values())) > 1:
        raise ValueError(f"locate needs one row per marker in each array, got {counts}")
    for name, array in arrays.items():
        if not np.isfinite(array).all():
            raise ValueError(f"locate's {name} holds a NaN or an infinity")
    if (arrays["radius_px"] <= 0).any():
        raise ValueError("locate's radius_px must be positive: a marker's extent, px")
    return arrays["xy"], arrays["radius_px"], arrays["line_angles"], arrays["evidence"]
