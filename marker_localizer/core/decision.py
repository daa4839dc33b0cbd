"""Whether a fitted candidate is a marker: one decision, from evidence that survives the field.

Every candidate that reaches this stage carries a fit of the adaptive template
over the whole X it shows (:func:`~marker_localizer.core.template_fit.fit_growing_template`).
The decision reads only what a worn, dirty or half-shadowed marker keeps:

* the geometry: two straight lines that cross at the centre and reach as far on
  either side of it (the ends of an X seen under any affine view lie on an
  ellipse about its centre), far enough for the expected marker size;
* the order of the sectors: going round, dark and bright alternate across all
  four edges, each edge's step significant against the noise;
* that the template explains the pixels: its residual is what the sensor noise
  (and a small share of the contrast, for the optics the template only
  approximates) leaves.

Grey-level equality of the two bright (or dark) quadrants is not asked for: a
dull quadrant, a wet one, a quadrant in shadow keep all three.

Each rejected candidate carries its reason (:data:`REASONS`), and the pipeline
counts them. What is left is ranked by one score, and its threshold follows from
a stated false-alarm rate (false points per megapixel of marker-free ground), by
the calibration in :data:`FALSE_ALARM_TAIL`.
"""

from __future__ import annotations

from typing import Any, NamedTuple, cast

import numpy as np
from numpy.typing import NDArray

from marker_localizer.core import template, verification
from marker_localizer.core.noise import NoiseModel
from marker_localizer.core.template_fit import GrownFit, TemplateFit

#: Why a candidate was rejected, in the order the tests run; the pipeline counts
#: each as ``rejected_<reason>``.
REASONS = ("fit", "sector_order", "extent", "optics", "score")
#: Smallest angle between the two lines, radians: nearer parallel, an "X" is a bar.
MIN_LINE_ANGLE_RAD = np.deg2rad(20.0)
#: Share of the contrast the template may miss on a real marker: the optics' blur is
#: not quite Gaussian, gamma bends the edge profile, JPEG rings at edges.
MODEL_MISMATCH = 0.05
#: Widest blur across a line an X may have, px: the optics' PSF and a 4 px motion
#: blur give under 2; soft texture saddles fit as wider.
MAX_BLUR_PX = 2.5
#: The shorter half of either line must reach at least this share of the longer: an X
#: seen under an affine view has equal halves, nearly so under perspective, blur and
#: the measurement, while a texture saddle's edges end where they please.
MIN_EXTENT_BALANCE = 0.75
#: The weakest edge's step must be at least this share of the strongest: a bright
#: quadrant 0.45 as bright as the other, in a shadow 65 % deep, still gives 0.15;
#: below, one of the four "edges" is no more than texture.
MIN_STEP_RATIO = 0.1
#: Largest change of the light across the X's reach, relative: sunlight and cloud
#: shadows vary over metres, not over a marker (a cast shadow's edge is modelled).
MAX_LIGHT_CHANGE = 0.5
#: A candidate's edges must alternate at least this significantly to grow on.
_GROW_MIN_EDGE_T = 2.0
#: ... and its blur and light change stay within this multiple of the decision's bounds.
_GROW_SLACK = 1.5
_EDGE_FIRST = tuple(a for a, _ in template.QUADRANT_EDGES)
_EDGE_SECOND = tuple(b for _, b in template.QUADRANT_EDGES)
#: Every edge's step must reach this many standard errors: at 3, chance alone
#: gives four alternating ones about once in 10^4 candidates.
MIN_EDGE_T = 3.0
#: Logs of the score's features are taken of at least this.
_MIN_LOG_ARGUMENT = 0.05
#: What :func:`marker_score` weighs, in the order of :func:`score_features`.
SCORE_FEATURES = (
    "ln edge_t",
    "extent_balance",
    "ln blur_px",
    "light_change",
    "ln fit_ratio",
    "step_ratio",
    "shadow_depth",
    "ln extent / min radius",
    "point_symmetry",
)
#: The logistic weights of :data:`SCORE_FEATURES` and the bias: the first fit, on the
#: package's rendered families and the real aerial frames at radius 6-40 px.
#: ``marker-localizer bench calibrate`` refits them (markers against texture at both
#: radius ranges) and prints the result; its refit of 2026-11-24 separates the
#: training data better but, at the threshold its own tail gives, finds fewer markers
#: on the package's evaluation frames, so these stay (measured: docs/accuracy.md,
#: "Figures the fit's and the detector's docstrings carried").
SCORE_WEIGHTS = (1.795, 4.074, -1.564, -2.291, -0.968, 2.328, -1.567, 2.506, 4.015)
SCORE_BIAS = -14.775
#: The tail of ground texture's scores under these weights, from
#: ``marker-localizer bench calibrate`` at a radius range of 3-30 px (the smallest
#: the package is asked to find): (score s0, false points per megapixel at or
#: above it, scale beta); above s0 the rate falls as exp(-(s - s0) / beta).
#: Measured on each kind of real ground without markers, the strictest kept
#: (2026-12-01, since the template fit holds its box, f8a79fc): the real boards'
#: backgrounds (11 MP, threshold 2.07 at 0.025 / MP), this one; real aerial frames
#: of sand, kerbs and shadows (24 MP, 1.98). Before: aerial 2.22, boards 2.18.
FALSE_ALARM_TAIL = (-3.004, 2.2765, 1.124)


class Evidence(NamedTuple):
    """What the decision reads, per candidate; each (N,).

    Attributes:
        converged: the fit grew to the whole X (:func:`worth_growing`) and ended
            where it started (within its reach).
        line_angle_rad: angle between the two lines, in [0, pi / 2].
        edge_t: the weakest of the four edges' steps, in standard errors, signed:
            negative where the quadrants do not alternate.
        extent_px: how far the X reaches: the geometric mean of the two lines'
            shorter halves.
        extent_balance: the shorter over the longer half of the less balanced line
            (1 for an X seen under an affine view).
        fit_ratio: the fit's RMS residual over what noise and model mismatch explain.
        contrast: the weakest edge's step, image units.
        blur_px: the wider of the two edges' blur, px.
        light_change: the relative change of the light across the X's reach.
        step_ratio: the weakest edge's step over the strongest's: 1 for even paint,
            down to a fifth or so for a dull quadrant, lower for texture.
        shadow_depth: the share of the light a fitted cast shadow takes (0: none).
        point_symmetry: the grey levels' 180-degree self-correlation on rings inside
            the X (1 for even paint).
    """

    converged: NDArray[np.bool_]
    line_angle_rad: NDArray[np.float64]
    edge_t: NDArray[np.float64]
    extent_px: NDArray[np.float64]
    extent_balance: NDArray[np.float64]
    fit_ratio: NDArray[np.float64]
    contrast: NDArray[np.float64]
    blur_px: NDArray[np.float64]
    light_change: NDArray[np.float64]
    step_ratio: NDArray[np.float64]
    shadow_depth: NDArray[np.float64]
    point_symmetry: NDArray[np.float64]


def _edge_steps(levels: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, 4) the level steps across the four edges, in the order of ``QUADRANT_EDGES``."""
    return levels[:, list(_EDGE_FIRST)] - levels[:, list(_EDGE_SECOND)]


def weakest_edge_t(fit: TemplateFit) -> NDArray[np.float64]:
    """(N,) the weakest edge's step in standard errors, negative where the X's order breaks.

    An X alternates across its four edges: their steps have signs s, -s, s, -s going
    round. Each step's significance comes from the fit's level covariance.
    """
    first, second = list(_EDGE_FIRST), list(_EDGE_SECOND)
    step = _edge_steps(fit.levels)
    cov = fit.level_covariance
    variance = cov[:, first, first] + cov[:, second, second] - 2.0 * cov[:, first, second]
    t = step / np.sqrt(np.maximum(variance, 1e-12))
    alternation = np.sign(step[:, :1]) * np.array([1.0, -1.0, 1.0, -1.0])
    return cast("NDArray[np.float64]", (t * alternation).min(axis=1))


def worth_growing(fit: TemplateFit, extents: NDArray[np.float64]) -> NDArray[np.bool_]:
    """(N,) which candidates grow on: those whose fit on a small region is still an X.

    The tests of :func:`decide` that a small region can already answer, leniently
    (a few pixels pin the blur and the light loosely): the four edges alternate
    (:data:`_GROW_MIN_EDGE_T`), the blur is an optics' and the light changes
    smoothly (:data:`MAX_BLUR_PX`, :data:`MAX_LIGHT_CHANGE`, with
    :data:`_GROW_SLACK`).
    """
    reach = np.maximum(extents.mean(axis=1), 1.0)
    return cast(
        "NDArray[np.bool_]",
        (weakest_edge_t(fit) >= _GROW_MIN_EDGE_T)
        & (fit.shape.blur_px.max(axis=1) <= _GROW_SLACK * MAX_BLUR_PX)
        & (np.linalg.norm(fit.shape.gain, axis=1) * reach <= _GROW_SLACK * MAX_LIGHT_CHANGE),
    )


def gather_evidence(
    image: NDArray[Any],
    grown: GrownFit,
    start_xy: NDArray[np.float64],
    max_shift_px: NDArray[np.float64],
    noise: NoiseModel,
) -> Evidence:
    """Read the decision's evidence off a grown template fit.

    Args:
        image: (H, W) the frame the fits were made on.
        grown: the fits, N candidates.
        start_xy: (N, 2) where each fit started.
        max_shift_px: (N,) farthest a fit may end from its start and still be the
            candidate's own X.
        noise: the frame's noise.

    Returns:
        :class:`Evidence`.
    """
    fit = grown.fit
    step = _edge_steps(fit.levels)
    angles = fit.shape.line_angles
    between = np.abs(np.angle(np.exp(2j * (angles[:, 0] - angles[:, 1])))) / 2.0
    ext = grown.extents
    shorter = np.minimum(ext[:, :2], ext[:, 2:])
    longer = np.maximum(ext[:, :2], ext[:, 2:])
    mean_level = fit.levels.mean(axis=1)
    contrast = np.abs(step).min(axis=1)
    expected = np.hypot(noise.std(mean_level), MODEL_MISMATCH * np.abs(step).max(axis=1))
    shift = np.linalg.norm(fit.shape.xy - start_xy, axis=1)
    return Evidence(
        converged=(shift <= max_shift_px) & grown.grown,
        line_angle_rad=between,
        edge_t=weakest_edge_t(fit),
        extent_px=np.sqrt(shorter[:, 0] * shorter[:, 1]),
        extent_balance=(shorter / np.maximum(longer, 1e-9)).min(axis=1),
        fit_ratio=fit.residual_rms / np.maximum(expected, 1e-12),
        contrast=contrast,
        blur_px=fit.shape.blur_px.max(axis=1),
        light_change=np.linalg.norm(fit.shape.gain, axis=1) * np.maximum(ext.mean(axis=1), 1.0),
        step_ratio=contrast / np.maximum(np.abs(step).max(axis=1), 1e-12),
        shadow_depth=fit.shape.shadow[:, 2],
        point_symmetry=_ring_symmetry(image, fit.shape.xy, np.sqrt(shorter[:, 0] * shorter[:, 1])),
    )


#: Rings of :func:`_ring_symmetry`, in units of the X's reach: inside the X, clear of
#: the blurred centre.
_SYMMETRY_RINGS = (0.35, 0.55, 0.75)


def _ring_symmetry(
    image: NDArray[Any], xy: NDArray[np.float64], reach_px: NDArray[np.float64]
) -> NDArray[np.float64]:
    """(N,) the grey levels' 180-degree self-correlation on rings inside the X, averaged.

    Even paint makes an X's rings point-symmetric (1), a dull quadrant or a shadow
    less so; a texture saddle's rings rarely are.
    """
    if not len(xy):
        return np.zeros(0)
    radii = np.maximum(reach_px[:, None] * np.array(_SYMMETRY_RINGS), 1.0)
    symmetry = np.stack(
        [
            verification.ring_symmetry(verification.annular_profiles_at(image, xy, radii[:, j]))
            for j in range(radii.shape[1])
        ],
        axis=1,
    )
    return cast("NDArray[np.float64]", symmetry.mean(axis=1))


class Decision(NamedTuple):
    """The decision on N candidates.

    Attributes:
        accepted: (N,) bool.
        reason: (N,) index into :data:`REASONS` of why a candidate was rejected
            (-1 where accepted).
        score: (N,) the ranking score (larger is more marker-like).
    """

    accepted: NDArray[np.bool_]
    reason: NDArray[np.integer[Any]]
    score: NDArray[np.float64]


class Verdicts(NamedTuple):
    """Every candidate the decision saw, accepted or not.

    What a user debugging a miss, and the false-alarm calibration, read.

    Attributes:
        xy: (N, 2) where each candidate's fit ended.
        decision: the :class:`Decision` on each.
        evidence: the :class:`Evidence` it was taken on.
    """

    xy: NDArray[np.float64]
    decision: Decision
    evidence: Evidence

    def reasons(self) -> list[str]:
        """Each candidate's reason for rejection (a name of :data:`REASONS`), or "accepted"."""
        return ["accepted" if r < 0 else REASONS[r] for r in self.decision.reason]


def marker_score(evidence: Evidence, min_radius_px: float) -> NDArray[np.float64]:
    """The decision's score: a marker's log-odds against ground texture.

    A logistic model, linear in features that each say, on its own, how much a
    candidate looks like a marker rather than like texture (:data:`SCORE_WEIGHTS`):
    how significant its weakest edge is, how evenly its lines reach either side of
    the centre, how sharp its edges are, how much of the pixels the template
    explains, how evenly its paint alternates, how far it reaches for the expected
    size, how much light it needs to borrow from a gradient or a shadow. The
    weights come from ``marker-localizer bench calibrate`` (the package's rendered
    markers against ground texture: rendered look-alikes and real marker-free
    aerial frames); the threshold from the false-alarm rate the user states.

    Args:
        evidence: per candidate.
        min_radius_px: the smallest expected marker radius.

    Returns:
        (N,) log-odds; :func:`threshold_for_rate` says where to cut.
    """
    return cast(
        "NDArray[np.float64]",
        score_features(evidence, min_radius_px) @ np.array(SCORE_WEIGHTS) + SCORE_BIAS,
    )


def score_features(evidence: Evidence, min_radius_px: float) -> NDArray[np.float64]:
    """(N, F) the F features :func:`marker_score` weighs, in the order of :data:`SCORE_FEATURES`."""
    return np.stack(
        [
            np.log(np.clip(evidence.edge_t, 1.0, None)),
            evidence.extent_balance,
            np.log(np.clip(evidence.blur_px, _MIN_LOG_ARGUMENT, None)),
            evidence.light_change,
            np.log(np.clip(evidence.fit_ratio, _MIN_LOG_ARGUMENT, None)),
            evidence.step_ratio,
            evidence.shadow_depth,
            np.log(np.clip(evidence.extent_px / min_radius_px, _MIN_LOG_ARGUMENT, None)),
            evidence.point_symmetry,
        ],
        axis=1,
    )


def confidence(score: NDArray[np.float64]) -> NDArray[np.float64]:
    """The score as a probability-like number in (0, 1): the logistic of the log-odds."""
    return 1.0 / (1.0 + np.exp(-np.clip(score, -50.0, 50.0)))


def threshold_for_rate(
    false_points_per_mp: float, tail: tuple[float, float, float] = FALSE_ALARM_TAIL
) -> float:
    """The score above which ground texture gives ``false_points_per_mp`` false points.

    The exponential ``tail`` (score, rate per MP at it, scale; by default
    :data:`FALSE_ALARM_TAIL`) solved for the score: real ground's few highest
    texture scores fix the rate far beyond what a count of them could (peaks over
    threshold).
    """
    start, rate, scale = tail
    return float(start + scale * np.log(rate / false_points_per_mp))


def decide(
    evidence: Evidence,
    *,
    min_radius_px: float,
    min_extent_fraction: float,
    threshold: float,
) -> Decision:
    """Accept or reject each candidate, with the reason for each rejection.

    Args:
        evidence: per candidate.
        min_radius_px: the smallest expected marker radius.
        min_extent_fraction: the X must reach at least this share of it.
        threshold: the score a marker needs (:func:`threshold_for_rate`).

    Returns:
        :class:`Decision`.
    """
    n = len(evidence.edge_t)
    score = marker_score(evidence, min_radius_px)
    failed = [
        ~evidence.converged | (evidence.line_angle_rad < MIN_LINE_ANGLE_RAD),
        (evidence.edge_t < MIN_EDGE_T) | (evidence.step_ratio < MIN_STEP_RATIO),
        (evidence.extent_px < min_extent_fraction * min_radius_px)
        | (evidence.extent_balance < MIN_EXTENT_BALANCE),
        (evidence.blur_px > MAX_BLUR_PX) | (evidence.light_change > MAX_LIGHT_CHANGE),
        score < threshold,
    ]
    reason = np.full(n, -1, dtype=np.intp)
    for index, failing in reversed(list(enumerate(failed))):
        reason[failing] = index
    return Decision(reason < 0, reason, score)
