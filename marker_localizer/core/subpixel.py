"""Section 3.3.2 of the paper: sub-pixel location.

The paper's path: an NCC surface between the adaptive template and the image,
computed as one matrix product over an im2col expansion (Eqs. 11-12), then a
weighted least-squares quadratic surface (Eq. 13) whose extremum (Eq. 14) is
the sub-pixel offset.

The default path continues from there with :func:`refine_point_symmetry`, a
Gauss-Newton fit of the centre of point symmetry over the whole marker. A
diagonal marker is point-symmetric about its centre under any homography
(180-degree rotation maps each line through the centre onto itself and each
quadrant onto its opposite twin), and stays so under any symmetric blur and any
monotonic grey-level change, which a template with a fixed edge profile does
not. Using the whole marker is what brings the error towards the Cramer-Rao
bound (docs/accuracy-journal.md, "What the Cramer-Rao bound asks of the fit"). The
markers that fit judges to be markers are fitted once more along their two lines
(:func:`refine_along_lines`), where the centre's information is.

What the constants here rest on, measured: docs/accuracy-journal.md, "What the fit's
constants rest on".
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, NamedTuple, cast

import cv2
import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray

from marker_localizer.core import shadow, template, uneven
from marker_localizer.core.image import clipped
from marker_localizer.core.noise import grey_step
from marker_localizer.core.sampling import (
    bilinear,
    bilinear_with_gradient,
    in_blocks,
    pad_patterns,
)
from marker_localizer.core.verification import (
    TEMPLATE_RADIUS_FRACTION,
    X_END_MAX_EXTENT_PX,
    annular_profiles,
    bright_sector_balance,
)

#: Template half-size of :func:`ncc_refine`, px: the marker's radius, at least 3 (a
#: 7 x 7 template still holds the four sectors of a 3 px marker) and at most 15 (the
#: matrix product grows with the square; 31 x 31 pixels fix the centre well enough).
_NCC_MIN_HALF_PX = 3
_NCC_MAX_HALF_PX = 15
#: Paper path: smallest NCC (Eq. 12) at the peak of the adaptive template's surface for
#: a marker: under nearly every marker's peak, over most of the ground-texture saddles
#: that pass every check before it.
NCC_PEAK_MIN = 0.93
#: Ratio of the observed error to the WLS fit's sigma of the NCC extremum, measured on
#: the renderer's families (a), (c), (d) with the paper's pipeline: the errors of the
#: paper's location are mostly its template's mismatch, which the 3 x 3 surface's
#: residuals see only in part; with it 95 % of the errors lie within 2 sigma.
NCC_SIGMA_CALIBRATION = 4.4
#: ... and within that range 0.7 of the radius: the square template's corners then stay
#: inside the X (a quarter-disk marker is plate beyond its radius, not X).
_NCC_HALF_RADIUS_FRACTION = 0.7
#: Ratio of the observed to the fit-predicted error of the point-symmetry fit on the
#: renderer's family (a) frames: neighbouring bilinear samples share pixels, so the
#: fit's covariance counts more independent residuals than there are. Measured with
#: ``marker-localizer bench accuracy``: with it, 96 % of the errors on family (a) fall
#: within 2 sigma (:func:`calibrated_sigma`).
SIGMA_CALIBRATION = 2.0
#: Coarse centring (:func:`coarse_centre`): Gauss-Newton iterations, samples per
#: candidate and step tolerance (px): a few tenths of a pixel suffice there.
_COARSE_ITERATIONS = 3
_COARSE_SAMPLES = 40
_COARSE_TOLERANCE_PX = 0.05
#: Smallest disk radius of the coarse centring, px: the candidate's scale, but a disk
#: of 2 px still holds the four sectors of the smallest marker.
_COARSE_MIN_RADIUS_PX = 2.0
#: Points a fit without uncertainty (the coarse centring) takes at a time
#: (:func:`~marker_localizer.core.sampling.in_blocks`): their (points, samples)
#: temporaries stay in a core's cache.
_COARSE_BLOCK = 512
#: X's whose line directions :func:`_edge_directions` measures at a time: each holds
#: some ten (points, samples) arrays of up to 2 x 10 100 samples
#: (:data:`_LINE_FIT_MAX_SAMPLES`), 1.1 GiB for the 652 X's of one extent on a
#: 12 MP frame of chessboards under flare, 110 MiB for 64.
_DIRECTION_BLOCK = 64
#: A candidate moves at most this share of its disk's radius, plus
#: :data:`COARSE_SHIFT_PX`, to the centre it is fitted to: farther, the fit has found
#: another X, or none.
COARSE_SHIFT_SCALE = 0.5
COARSE_SHIFT_PX = 1.0
#: The final point-symmetry fit (:func:`locate_markers`) reads a disk of this share of
#: the X's extent, at least :data:`_FINAL_MIN_RADIUS_PX`: inside the X, clear of the
#: plate's outline, whose blurred edge is not point-symmetric about the centre.
_FINAL_RADIUS_FRACTION = 0.9
_FINAL_MIN_RADIUS_PX = 2.0
#: The line fit reads an X as far as it reaches all round (:func:`template.line_reaches`),
#: and along each line as far as that line reaches, each at most this many times the
#: extent its rings found: one rung of the ring ladder, whose rungs sit at or under the
#: X's radius ...
REACH_MAX_GAIN = float(np.sqrt(2.0))
#: ... in steps of this share of an octave (rounded down), so that X's of one step
#: share a call: reading to each X's own reach gains no more on the development seeds.
_REACH_STEPS_PER_OCTAVE = 8
#: Step tolerance of the final fit, px: a tenth of the precision aimed at.
_FINAL_TOLERANCE_PX = 1e-3
#: A final fit that ends farther than this from its start has not found the X it was
#: started on, px (the coarse centring leaves a few tenths of a pixel).
_FINAL_MAX_SHIFT_PX = 1.5
#: Smallest residual std of the final fits, in grey steps q of the frame
#: (:func:`~marker_localizer.core.noise.grey_step`): what rounding alone leaves in a
#: residual, so that a noise-free or thresholded frame does not claim a sigma near 0.
#: A pixel rounded to a step q is off by an error uniform over it, variance q^2 / 12;
#: a bilinear sample at a uniformly distributed position weighs its four pixels with
#: squared weights that sum to (2 / 3)^2 on average (per axis, the integral of
#: (1 - u)^2 + u^2 over a pixel), so it carries 4 / 9 of that, and a pair's difference,
#: rounded independently, twice: 2 q^2 / 27. On thresholded and 4-16 level frames the
#: errors then spread as on noisy ones (docs/accuracy.md, "Sigma on quantised and
#: thresholded frames").
RESIDUAL_ROUNDING_STEPS = float(np.sqrt(2.0 / 27.0))
#: Smallest contrast the relative residual divides by, grey levels.
_MIN_CONTRAST = 1e-6
#: :func:`refine_along_lines` weighs each sample by exp(-s^2 / (2 b^2)), s its distance
#: from the nearer of the X's two lines and b this, px. A marker's centre is known from
#: its blurred edges (blur sigma 0.5-1.5 px); inside a quadrant a pair of samples holds
#: only noise, which the bilinear interpolant turns into a cost that wanders with the
#: centre, more so the larger the marker. 2.5 px also covers the verification's line
#: directions being a degree off (0.5 px at 30 px); a narrower band reads too few of
#: the edges' pairs.
LINE_BAND_PX = 2.5
#: Samples of :func:`refine_along_lines` farther than this many :data:`LINE_BAND_PX`
#: from both lines weigh under 5 % and are left out.
_LINE_BAND_REACH = 2.5
#: Samples per point :func:`refine_along_lines` may read before its grid coarsens from
#: half a pixel: enough for a half disk of 40 px (pi 40^2 / 2 / 0.5^2 = 10 053). A
#: coarser grid loses a third of the precision.
_LINE_FIT_MAX_SAMPLES = 10_100
#: ... so the pairs read out to an X's ellipse stay within this radius, px: the largest
#: half disk whose half-pixel grid holds no more samples.
_HALF_PIXEL_MAX_RADIUS_PX = float(np.sqrt(_LINE_FIT_MAX_SAMPLES * 0.5**2 * 2.0 / np.pi))
#: Pairs per point :func:`refine_along_lines` fits at most: those nearest the lines.
#: The time is the pairs' (about 0.5 us per pair and iteration): every pair of the
#: band costs frames of many large corners a lot, and fewer pairs cost precision.
_LINE_FIT_MAX_PAIRS = 1000
#: Gauss-Newton iterations of :func:`refine_along_lines` at most: from the gating
#: fit's centre it stops after 2-4.
_LINE_FIT_ITERATIONS = 10
#: Farther than this from the gating fit's centre, px, the line-weighted fit has
#: slipped (a line direction far off): the gating fit's centre stays.
_LINE_FIT_MAX_SHIFT_PX = 0.5
#: Blur of the edge steps in :func:`refine_along_lines`'s model of an X whose
#: quadrants have levels of their own, px: the middle of the blurs met (0.5-1.5 px);
#: the steps shape only the pairs within a blur width of a line, and a step blur a
#: fifth off fits an X about as well.
EDGE_STEP_BLUR_PX = 1.0
#: The blurs among which :func:`_step_blur` picks the steps of the quadrants' own
#: levels in :func:`refine_along_lines`, px: across the optics' 0.5-1.5 px met.
EDGE_STEP_BLURS_PX = (0.6, 0.8, 1.0, 1.2, 1.5)
#: The score statistic of the bright pair's own level (:func:`_bright_pair_step`,
#: chi-square with 1 degree of freedom where the noise alone moves it) from which
#: :func:`locate_markers` judges an X by the residual that level leaves: over what
#: X's of even paint give (on the renderer's (a), (c), (d) 17-22 at the 99th
#: percentile and 37-142 at most, the model's errors adding to the noise's), and the
#: bar both pairs' levels had. Lower bars find more of the renderer's dull markers
#: (12 of 1 152 (g) markers at 45, which score 54-94), and let in the gaps of a
#: lattice of discs of unequal brightness (8-62), most of those the lattice test
#: rejects but by the frame's border (docs/accuracy-journal.md, "The gating score's bright
#: pair", "A lattice cut by the frame's border").
LEVELLED_MIN_CHI2 = 100.0
#: The score statistic (chi-square, 2 degrees of freedom) of the quadrants' own
#: levels (:func:`_edge_steps`) from which :func:`refine_along_lines` fits them: with
#: the lines' directions measured afresh (:func:`_edge_directions`) the levels cost a
#: marker of even paint nothing measured down to it, and markers a shadow edge
#: crosses, which the symmetric fit leaves tenths of a pixel off, score about as low
#: (measured: docs/accuracy-journal.md, "Figures the fit's and the detector's docstrings
#: carried").
LEVELS_REFIT_MIN_CHI2 = 45.0
#: The same statistic from which :func:`refine_along_lines` fits the quadrants' own
#: levels under :data:`LEVELS_REFIT_MIN_CHI2` too, and moves the symmetric fit's
#: centre towards theirs by the share of their difference that is bias, not noise
#: (:func:`_blended_with_levels`): the chi-square's 0.1 % point, where chance alone
#: passes once in a thousand (measured: docs/accuracy-journal.md, "The levels' fit weighed in
#: by its bias").
LEVELS_BLEND_MIN_CHI2 = 13.8
#: Where the rings across an X's disk read a dull bright sector (:func:`_dull_sector`),
#: the quadrants' own levels are fitted from this much of their statistic, its 5 %
#: point, not from :data:`LEVELS_REFIT_MIN_CHI2`. On a small X the symmetric fit moves
#: its centre towards the brighter side and the light's slope takes the rest of a dull
#: quadrant (the insides of an X of 8 px lie 4-6 px out, where a level and a slope look
#: alike), so the statistic scores quadrants that lead the dark paint by 0.5-0.7 of
#: the other's lead 10-44 on the renderer's (g), and the blend leaves them 0.15-0.5 px
#: off. The rings read the sectors' levels whole (measured: docs/accuracy-journal.md,
#: "A dull bright sector read on the rings").
DULL_SECTOR_MIN_CHI2 = 5.99
#: ... a dull sector: the median ring's :func:`verification.bright_sector_balance`
#: under this. X's of one paint read 0.98 by the median and fall under it once in 50
#: on the renderer's (a), (c), (d); (g)'s dull quadrants read 0.60 (measured: as
#: above).
DULL_SECTOR_MAX_BALANCE = 0.85
#: ... on rings at these shares of the disk's radius: inside the X, clear of its
#: centre, where the ring samples each sector on a few of its 36 angles.
_BALANCE_RING_FRACTIONS = (0.45, 0.6, 0.75, 0.9)
#: Where the levels' statistic does not say alone that the levels differ (under
#: :data:`LEVELS_REFIT_MIN_CHI2`), an X of :data:`MEASURED_MIN_EXTENT_PX` and more on
#: which the pairs show a cast shadow's edge (:func:`shadow.find_edges` as it asks of a
#: candidate) is fitted by its model too, and the model's centre replaces the line
#: fit's only where the model rejects that centre: refitted with its centre held
#: there, it leaves this much more chi-square (2 degrees of freedom, in units of its
#: own residual) than free, the 0.1 % point, where chance alone passes once in a
#: thousand. The symmetric fit is the more efficient where the levels are even (the
#: model reads 0.8 of the extent, not 0.9, and pays for the light's slope), so it
#: stays wherever the model cannot tell it is biased. A shadow's edge that the levels'
#: statistic misses pulls it 0.1-0.4 px (the rings stop short at the edge, the disk
#: read is small, and the pairs show no step that is the quadrants' own). Measured:
#: docs/accuracy-journal.md, "The model where it rejects the line fit's centre".
MODEL_MIN_CENTRE_CHI2 = 13.8
#: X's of one call that :func:`refine_along_lines` locates by their model at most,
#: those whose levels' statistic is highest first: a frame holds 10-20 markers, while
#: a chessboard photographed under a flare has a hundred corners whose levels differ,
#: each fitted in ~3 ms (measured: docs/speed.md, "The worst frame: a chessboard under
#: a flare"). The others keep the levels' fit, and are counted.
MAX_MODELLED = 32
#: :func:`refine_along_lines` fits the light's slope (the gain gradient of
#: :func:`refine_point_symmetry`) where it reads a disk of at least this radius, px.
#: Across a smaller disk the light changes little, and the slope's two columns,
#: d (I(c + d) + I(c - d)) with short lever arms, share much of what the centre's
#: say: they cost more precision than the bias they take away. From 8 px on, the
#: markers whose quadrants' levels differ lose: they need the slope (measured:
#: docs/accuracy-journal.md, "Figures the fit's and the detector's docstrings carried").
GAIN_MIN_RADIUS_PX = 6.0
#: :func:`_light_inside` reads the quadrants' insides from this distance to both
#: lines, px: twice the widest blur sigma met (1.5 px), where an edge has levelled out.
INSIDE_LINE_DISTANCE_PX = 3.0
#: Pairs per point :func:`_light_inside` reads at most: its grid coarsens from half a
#: pixel beyond a disk of 17 px (the light is smooth; the pairs' number, not their
#: spacing, fixes the slope).
_INSIDE_MAX_SAMPLES = 2000
#: Farther than this from the gating fit's centre, px, a fit with the quadrants' own
#: levels has slipped: the gating fit is point-symmetric in grey levels, and a dull
#: bright quadrant pulls it by less than this.
EDGE_STEP_MAX_SHIFT_PX = 1.0
#: Largest RMS residual, as a share of the contrast, that the gating fit may leave
#: with the quadrants' own levels for those levels to judge a candidate
#: (:func:`locate_markers`): an X whose quadrants differ must then be as clean as
#: one of even paint, and the gaps between look-alike discs of unequal brightness,
#: whose edges curve, are not.
LEVELLED_MAX_RESIDUAL = 0.07
#: :func:`_edge_directions` reads each line's gradient energy within this angle of
#: it, radians: wide enough for the ring check's directions, a few degrees off, more
#: on a dull tilted X; narrow enough to leave the other line out.
_DIRECTION_WEDGE_RAD = float(np.radians(15.0))
#: ... beyond this distance from the centre, px: nearer, the two lines' blurred
#: edges overlap (blur sigma up to 1.5 px).
_DIRECTION_INNER_PX = 2.0
#: ... in this many passes, each centring the wedges on the last directions.
_DIRECTION_ITERATIONS = 2
#: :func:`refine_along_lines` measures the lines' directions from the edges, before
#: anything else, on X's of this extent and more, px, and only these X's are located
#: by their model (:func:`uneven.locate_uneven`, with a cast shadow's edge tried;
#: :func:`locate_in_shadow`). The edges' directions are the more precise there; off,
#: the lines' band holds the wrong pairs, and the quadrants' levels' statistic
#: (:data:`LEVELS_REFIT_MIN_CHI2`) does not see a dull quadrant or a shadow. On tiny
#: markers the edges' directions are worse than the rings' and their model takes
#: shadows' edges where there are none. Under it the model reads its tone curve and
#: wedges on too few pixels. Measured: docs/accuracy-journal.md, "The
#: lines measured from the edges, and the shadow's edge tried in the model" and "The
#: model wherever it converges on a marker found in a shadow, and never under 6 px".
MEASURED_MIN_EXTENT_PX = 6.0
#: ... there the gradient is read on a grid of this step, px: at half a pixel, as
#: the quadrants' levels' fit reads it (:func:`_levels_fit`), it costs the final fit
#: several times more.
_MEASURED_DIRECTION_STEP_PX = 1.0
#: Ratio of the observed error of :func:`refine_along_lines` to its covariance's
#: prediction, measured like :data:`SIGMA_CALIBRATION`: with it some 95 % of the
#: errors fall within 2 sigma.
LINE_FIT_SIGMA_CALIBRATION = 2.0


def ncc_surface(
    image: NDArray[Any],
    centres: NDArray[np.integer[Any]],
    template: NDArray[np.float64],
    search_px: int,
) -> NDArray[np.float64]:
    """NCC of a template at every integer shift around each centre, Eqs. (11)-(12).

    The image around each centre is expanded im2col-style into a matrix whose
    rows are the (2r+1)^2 windows at every shift, so the whole surface is one
    matrix product with the zero-mean, unit-norm template vector.

    Args:
        image: (H, W) float image.
        centres: (N, 2) integer (x, y) positions; windows must lie inside the image.
        template: (N, T, T) templates (T odd), one per centre.
        search_px: S; shifts run over [-S, S] in x and y.

    Returns:
        (N, 2S+1, 2S+1) NCC values in [-1, 1]; element [n, j, i] is the shift
        (dx, dy) = (i - S, j - S).
    """
    n, size, _ = template.shape
    half = size // 2
    span = 2 * (half + search_px) + 1
    offsets = np.arange(span) - (half + search_px)
    rows = centres[:, 1, None, None] + offsets[None, :, None]
    cols = centres[:, 0, None, None] + offsets[None, None, :]
    regions = image[rows, cols]  # (N, span, span)
    # Eq. (11): the expanded tensor F~, one row per shift, (2r+1)^2 columns.
    # numpy's stubs do not admit a tuple axis, which sliding_window_view accepts.
    windows = sliding_window_view(regions, (size, size), axis=(1, 2))  # type: ignore[call-overload]
    expanded = windows.reshape(n, -1, size * size).astype(np.float64)
    expanded -= expanded.mean(axis=2, keepdims=True)
    expanded /= np.linalg.norm(expanded, axis=2, keepdims=True) + 1e-12
    flat_template = template.reshape(n, -1).astype(np.float64)
    flat_template = flat_template - flat_template.mean(axis=1, keepdims=True)
    flat_template /= np.linalg.norm(flat_template, axis=1, keepdims=True) + 1e-12
    # Eq. (12): R = F~_tar . F~_ref / (|F~_tar| |F~_ref|), as one batched product.
    surface: NDArray[np.float64] = np.matmul(expanded, flat_template[:, :, None])[..., 0]
    return surface.reshape(n, 2 * search_px + 1, 2 * search_px + 1)


def fit_quadratic_surface(
    values: NDArray[np.float64], weights: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Weighted least-squares fit of c(x, y) = a x^2 + b y^2 + c xy + d x + e y + f, Eq. (13).

    Args:
        values: (N, K, K) samples on the integer grid centred on 0 (K odd).
        weights: (N, K, K) non-negative weights.

    Returns:
        (N, 6) coefficients (a, b, c, d, e, f).
    """
    k = values.shape[1]
    grid = np.arange(k) - k // 2
    y, x = np.meshgrid(grid, grid, indexing="ij")
    design = np.stack([x * x, y * y, x * y, x, y, np.ones_like(x)], axis=-1).reshape(-1, 6)
    w = weights.reshape(len(values), -1)
    normal = np.einsum("nk,ki,kj->nij", w, design, design)
    rhs = np.einsum("nk,ki,nk->ni", w, design, values.reshape(len(values), -1))
    return np.linalg.solve(normal + 1e-12 * np.eye(6), rhs[..., None])[..., 0]


def quadratic_extremum(coefficients: NDArray[np.float64]) -> NDArray[np.float64]:
    """Stationary point of the fitted quadratic surface, Eq. (14).

    Setting the gradient to zero gives
    dx = (2 b d - c e) / (c^2 - 4 a b), dy = (2 a e - c d) / (c^2 - 4 a b).
    (The paper prints 2bc in the first numerator; 2bd is what the gradient gives.)

    Args:
        coefficients: (N, 6) from :func:`fit_quadratic_surface`.

    Returns:
        (N, 2) offsets (dx, dy); NaN where the surface has no unique extremum.
    """
    a, b, c, d, e = (coefficients[:, i] for i in range(5))
    det = c * c - 4.0 * a * b
    with np.errstate(divide="ignore", invalid="ignore"):
        dx = (2.0 * b * d - c * e) / det
        dy = (2.0 * a * e - c * d) / det
    singular = np.abs(det) < 1e-12
    return np.where(singular[:, None], np.nan, np.stack([dx, dy], axis=1))


class NccPeak(NamedTuple):
    """Sub-pixel peaks of NCC surfaces, from :func:`ncc_subpixel`.

    Attributes:
        offset: (N, 2) shift (dx, dy) of the peak from the window centre, px (NaN
            where the fitted surface has no maximum within 1 px of the best shift).
        peak: (N,) the best NCC value on the integer grid.
        sigma: (N,) 1-sigma radial uncertainty of the offset, px, from the residuals
            of the weighted least-squares fit (how far the surface is from a quadratic).
    """

    offset: NDArray[np.float64]
    peak: NDArray[np.float64]
    sigma: NDArray[np.float64]


def ncc_subpixel(surface: NDArray[np.float64]) -> NccPeak:
    """Sub-pixel NCC peaks: WLS quadratic on the 3x3 around the best shift, Eqs. (13)-(14).

    Args:
        surface: (N, 2S+1, 2S+1) from :func:`ncc_surface`.

    Returns:
        :class:`NccPeak`.
    """
    n, k, _ = surface.shape
    flat = surface.reshape(n, -1)
    best = np.argmax(flat, axis=1)
    by, bx = np.unravel_index(best, (k, k))
    by = np.clip(by, 1, k - 2)
    bx = np.clip(bx, 1, k - 2)
    offsets = np.arange(-1, 2)
    rows = by[:, None, None] + offsets[None, :, None]
    cols = bx[:, None, None] + offsets[None, None, :]
    patch = surface[np.arange(n)[:, None, None], rows, cols]
    # Weights favour the higher-correlation samples near the peak.
    weights = np.clip(patch, 1e-3, None)
    coefficients = fit_quadratic_surface(patch, weights)
    delta = quadratic_extremum(coefficients)
    is_maximum = (coefficients[:, 0] < 0) & (coefficients[:, 1] < 0)
    delta[~is_maximum | (np.abs(delta) > 1.0).any(axis=1)] = np.nan
    centre = k // 2
    offset = np.stack([bx - centre, by - centre], axis=1) + delta
    sigma = _extremum_sigma(patch, weights, coefficients)
    return NccPeak(offset, flat[np.arange(n), best], sigma)


def _extremum_sigma(
    values: NDArray[np.float64], weights: NDArray[np.float64], coefficients: NDArray[np.float64]
) -> NDArray[np.float64]:
    """(N,) radial 1-sigma of the Eq. (14) extremum propagated from the WLS fit's covariance.

    cov(beta) = s^2 (A^T W A)^-1 with s^2 the weighted residual variance (3 degrees of
    freedom on a 3x3 patch); the extremum's Jacobian by central differences.
    """
    n, k, _ = values.shape
    grid = np.arange(k) - k // 2
    y, x = np.meshgrid(grid, grid, indexing="ij")
    design = np.stack([x * x, y * y, x * y, x, y, np.ones_like(x)], axis=-1).reshape(-1, 6)
    w = weights.reshape(n, -1)
    residual = values.reshape(n, -1) - coefficients @ design.T
    dof = design.shape[0] - design.shape[1]
    scale = (w * residual**2).sum(axis=1) / dof
    normal = np.einsum("nk,ki,kj->nij", w, design, design)
    covariance = scale[:, None, None] * np.linalg.inv(normal + 1e-12 * np.eye(6))
    jacobian = np.zeros((n, 2, 6))
    for i in range(5):  # f does not move the extremum
        step = 1e-6 * np.maximum(np.abs(coefficients[:, i]), 1e-3)
        plus, minus = coefficients.copy(), coefficients.copy()
        plus[:, i] += step
        minus[:, i] -= step
        jacobian[:, :, i] = (quadratic_extremum(plus) - quadratic_extremum(minus)) / (
            2.0 * step[:, None]
        )
    propagated = jacobian @ covariance @ jacobian.transpose(0, 2, 1)
    return cast(
        "NDArray[np.float64]", np.sqrt(np.maximum(np.trace(propagated, axis1=1, axis2=2), 0.0))
    )


def ncc_refine(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    *,
    offset_px: float,
    search_px: int,
) -> NccPeak:
    """The paper's sub-pixel location (section 3.3): adaptive template, NCC surface, extremum.

    Per marker: the grey levels of its sector pairs from 3x3 windows on the
    bisectors (:func:`template.sample_grey_levels`, ``offset_px`` from the centre or
    :data:`TEMPLATE_RADIUS_FRACTION` of the radius if less), the defocus sigma_b
    from the steepest gradient in the window (:func:`template.estimate_defocus_sigma`),
    the X template with the
    line angles phi1, phi2 (Eq. 10's two polarities, the closer in L1 kept), then
    the NCC at every integer shift within ``search_px`` as one matrix product
    (Eqs. 11-12) and the extremum of the WLS quadratic surface (Eqs. 13-14). The
    template's half-size is the marker's radius (3-15 px), so markers of one size
    share one matrix product.

    Args:
        image: (H, W) grey image.
        xy: (N, 2) coarse centres (rounded to the pixel the surface is centred on).
        radius_px: (N,) marker extents.
        line_angles: (N, 2) directions of the two lines.
        offset_px: distance of the grey-level windows along the bisectors.
        search_px: S, half-size of the search window.

    Returns:
        :class:`NccPeak` with ``offset`` replaced by the located centres (x, y),
        NaN where the window leaves the image or the surface has no maximum, and
        ``sigma`` calibrated (:data:`NCC_SIGMA_CALIBRATION`).
    """
    n = len(xy)
    located = np.full((n, 2), np.nan)
    peak = np.zeros(n)
    sigma = np.full(n, np.nan)
    if n == 0:
        return NccPeak(located, peak, sigma)
    half = np.clip(
        np.round(_NCC_HALF_RADIUS_FRACTION * radius_px), _NCC_MIN_HALF_PX, _NCC_MAX_HALF_PX
    ).astype(np.int64)
    centres = np.round(xy).astype(np.int64)
    height, width = image.shape
    margin = half + search_px
    inside = (
        (centres[:, 0] >= margin)
        & (centres[:, 0] < width - margin)
        & (centres[:, 1] >= margin)
        & (centres[:, 1] < height - margin)
    )
    gradient = np.hypot(
        cv2.Sobel(image, cv2.CV_32F, 1, 0, ksize=1, scale=0.5),
        cv2.Sobel(image, cv2.CV_32F, 0, 1, ksize=1, scale=0.5),
    )
    for size in np.unique(half[inside]):  # per template size, not per marker
        group = np.flatnonzero(inside & (half == size))
        c = centres[group]
        window = np.arange(-size, size + 1)
        rows = c[:, 1, None, None] + window[None, :, None]
        cols = c[:, 0, None, None] + window
        levels = template.sample_grey_levels(
            image,
            c.astype(np.float64),
            line_angles[group],
            np.minimum(offset_px, TEMPLATE_RADIUS_FRACTION * radius_px[group]),
        )
        peak_gradient = gradient[rows, cols].reshape(len(group), -1).max(axis=1)
        sigma_b = template.estimate_defocus_sigma(peak_gradient, levels.positive - levels.negative)
        templates = template.adaptive_template(line_angles[group], levels, sigma_b, int(size))
        templates = template.choose_polarity(image[rows, cols].astype(np.float64), templates)
        found = ncc_subpixel(ncc_surface(image, c, templates, search_px))
        located[group] = c + found.offset
        peak[group] = found.peak
        sigma[group] = NCC_SIGMA_CALIBRATION * found.sigma
    return NccPeak(located, peak, sigma)


class SymmetryFit(NamedTuple):
    """Result of :func:`refine_point_symmetry` for N points.

    Attributes:
        xy: (N, 2) refined centres.
        covariance: (N, 2, 2) covariance of the centre in px^2 from the fit.
        residual: (N,) RMS symmetry residual, in image units (0 = perfect symmetry).
        contrast: (N,) spread of the grey levels in the disk (90th - 10th percentile).
        converged: (N,) True where the last step was below tolerance and the
            point stayed within ``max_shift_px`` of its start.
        step_chi2: (N,) the score statistic of the bright pair's own level
            (:func:`_bright_pair_step`, :func:`_edge_step_chi2`); NaN unless the line
            directions were given.
        levelled_residual: (N,) the RMS residual that level would leave, image
            units; NaN unless the line directions were given.
    """

    xy: NDArray[np.float64]
    covariance: NDArray[np.float64]
    residual: NDArray[np.float64]
    contrast: NDArray[np.float64]
    converged: NDArray[np.bool_]
    step_chi2: NDArray[np.float64]
    levelled_residual: NDArray[np.float64]


@functools.lru_cache(maxsize=256)
def symmetric_offsets(
    radius_px: float, max_samples: int = 400, min_step_px: float = 0.5
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Half-disk sample offsets d (one of each +d/-d pair) and taper weights.

    The grid spacing is a multiple of 0.5 px, so c + d and c - d always share the
    same fractional position: bilinear interpolation errors then cancel in the
    symmetry residual instead of biasing the centre. It is ``min_step_px`` (a
    multiple of 0.5), or coarser where that would take more than ``max_samples``.

    Returns:
        (offsets, weights): (K, 2) float64 and (K,) float64.
    """
    step = min_step_px
    while (np.pi * radius_px**2 / 2.0) / step**2 > max_samples:
        step += 0.5
    n = int(np.floor(radius_px / step))
    grid = np.arange(-n, n + 1) * step
    dx, dy = np.meshgrid(grid, grid)
    dx, dy = dx.ravel(), dy.ravel()
    r2 = dx * dx + dy * dy
    upper = (dy > 0) | ((dy == 0) & (dx > 0))
    inside = upper & (r2 <= radius_px**2)
    # Taper so that the marker's outer edge, where symmetry ends, carries little weight.
    weights = 1.0 - r2[inside] / radius_px**2
    offsets = np.stack([dx[inside], dy[inside]], axis=1)
    # Cached and shared between calls: read-only.
    offsets.flags.writeable = weights.flags.writeable = False
    return offsets, weights


@functools.lru_cache(maxsize=256)
def _grid_spacing(radius_px: float, max_samples: int) -> float:
    """The smallest step of :func:`symmetric_offsets`' grid along x or y, px, and at most 1."""
    offsets, _ = symmetric_offsets(radius_px, max_samples)
    return float(np.min(np.abs(offsets[offsets != 0]), initial=1.0))


def refine_point_symmetry(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    *,
    iterations: int = 10,
    tolerance_px: float = 1e-3,
    max_shift_px: NDArray[np.float64] | float = 2.0,
    model_gain: bool = True,
    max_samples: int = 400,
    noise_floor: float = 0.0,
    uncertainty: bool = True,
    line_angles: NDArray[np.float64] | None = None,
) -> SymmetryFit:
    """Gauss-Newton fit of each marker's centre of point symmetry.

    Minimises sum_d w(d) r(d)^2 over the half disk |d| <= radius with
    r(d) = I(c + d) - I(c - d) - (g . d) (I(c + d) + I(c - d)),
    where the optional gain gradient g absorbs a linear illumination slope across
    the marker. Samples and Jacobian come from the bilinear interpolant and its
    exact derivative.

    Args:
        image: (H, W) float image (raw intensities: no filtering, which would bias).
        xy: (N, 2) start positions.
        radius_px: (N,) radius of the disk used per point.
        iterations: Gauss-Newton iterations at most.
        tolerance_px: stop when every step is below this.
        max_shift_px: a point further than this from its start has not converged.
        model_gain: fit the gain gradient g (4 parameters instead of 2).
        max_samples: cap on the samples per point (the grid coarsens for big disks).
        noise_floor: smallest residual std assumed for the covariance (image units),
            e.g. the quantisation noise, so a noise-free frame does not claim sigma 0.
        uncertainty: estimate the covariance, the residual and the contrast (NaN
            otherwise: a coarse centring needs none, and for a few points they cost
            a third of the fit; the samples at the last step's end point, for the
            residual alone, a tenth more on busy ground).
        line_angles: (N, 2) the X's line directions, radians: with the uncertainty,
            also weigh the bright pair's own level at the end (:func:`_bright_pair_step`).

    Returns:
        :class:`SymmetryFit`.
    """
    n = len(xy)
    if n == 0:
        empty = np.zeros(0)
        return SymmetryFit(
            np.zeros((0, 2)), np.zeros((0, 2, 2)), empty, empty, np.zeros(0, bool), empty, empty
        )
    centre = xy.astype(np.float64)
    start = centre.copy()
    # Points sharing a radius share an offset pattern; the padding carries zero weight.
    radius_key = np.round(np.asarray(radius_px, dtype=np.float64) * 2.0) / 2.0
    keys, pattern_of = np.unique(radius_key, return_inverse=True)
    patterns = [symmetric_offsets(float(radius), max_samples) for radius in keys]
    offsets, present = pad_patterns([pattern for pattern, _ in patterns])
    tapers, _ = pad_patterns([taper for _, taper in patterns])
    spacing = np.array([_grid_spacing(float(radius), max_samples) for radius in keys])
    max_shift = np.broadcast_to(np.asarray(max_shift_px, dtype=np.float64), (n,))
    fit = functools.partial(
        _gauss_newton_symmetry,
        image,
        iterations=iterations,
        tolerance_px=tolerance_px,
        model_gain=model_gain,
        noise_floor=noise_floor,
        uncertainty=uncertainty,
    )
    per_point = (
        centre,
        offsets[pattern_of],
        tapers[pattern_of],
        present[pattern_of],
        spacing[pattern_of],
    )
    # Without the uncertainty a point's fit reads nothing of the others' (with it, the
    # last evaluation waits for the slowest point), so it may run in blocks.
    if not uncertainty:
        solution = in_blocks(fit, _COARSE_BLOCK, *per_point)
    elif line_angles is None:
        solution = fit(*per_point)
    else:
        disk = offsets[pattern_of]
        s1, s2 = template.line_distances(disk[..., 0], disk[..., 1], line_angles)
        solution = fit(
            *per_point, test_steps=_edge_steps(s1, s2, EDGE_STEP_BLUR_PX), bright_pair_only=True
        )
    moved = np.linalg.norm(solution.centre - start, axis=1)
    return SymmetryFit(
        solution.centre,
        solution.covariance,
        solution.residual_rms,
        solution.contrast,
        solution.converged & (moved <= max_shift),
        solution.step_chi2,
        solution.levelled_rms,
    )


def ncc_gates(peak: NccPeak) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """The paper path's acceptance of its NCC location (:func:`ncc_refine`).

    Returns:
        (located, matched): (N,) True where the surface has an extremum with a
        finite uncertainty, and where it also peaks at :data:`NCC_PEAK_MIN` or more.
    """
    located = np.isfinite(peak.offset).all(axis=1) & np.isfinite(peak.sigma)
    return located, located & (peak.peak >= NCC_PEAK_MIN)


def calibrated_sigma(
    covariance: NDArray[np.float64], discrepancy_px2: NDArray[np.float64] | None = None
) -> NDArray[np.float64]:
    """(N,) 1-sigma radial position uncertainty, px, from the symmetry fit's covariance.

    sqrt(var_x + var_y) times :data:`SIGMA_CALIBRATION`; with ``discrepancy_px2``
    (the squared distance of another estimate of the centre, the paper's NCC
    extremum, from the fit's) that distance is added in quadrature, as a direct
    measure of the other estimate's error.

    Args:
        covariance: (N, 2, 2) covariance of the fitted centres, px^2.
        discrepancy_px2: (N,) squared distances, px^2, or None.
    """
    variance = covariance[:, 0, 0] + covariance[:, 1, 1]
    if discrepancy_px2 is not None:
        variance = variance + discrepancy_px2 / SIGMA_CALIBRATION**2
    return cast("NDArray[np.float64]", SIGMA_CALIBRATION * np.sqrt(np.maximum(variance, 0.0)))


def coarse_centre(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    scale_px: NDArray[np.float64],
    max_radius_px: float,
    light_slope: bool = False,
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Move each candidate to its local centre of point symmetry (2 parameters, a few steps).

    The point-symmetry fit over a disk of the candidate's scale, within
    :data:`COARSE_SHIFT_SCALE` of that radius plus :data:`COARSE_SHIFT_PX` of the
    start; its centre is good to a few tenths of a pixel, enough for the rings of
    the verification.

    Args:
        image: (H, W) grey image, raw levels.
        xy: (N, 2) candidate positions.
        scale_px: (N,) the candidates' scales, px.
        max_radius_px: the largest expected marker radius, px.
        light_slope: fit the light's slope too (the gain gradient of
            :func:`refine_point_symmetry`, two parameters more): a light changing
            across the X, or a dull bright quadrant, no longer pulls the centre
            towards the brighter side.

    Returns:
        (centres, inside): (N, 2) fitted centres and (N,) True where the fit found
        a centre within reach of its start.
    """
    radius = np.clip(scale_px, _COARSE_MIN_RADIUS_PX, max_radius_px)
    reach = COARSE_SHIFT_SCALE * radius + COARSE_SHIFT_PX
    fit = refine_point_symmetry(
        image,
        xy,
        radius,
        iterations=_COARSE_ITERATIONS,
        tolerance_px=_COARSE_TOLERANCE_PX,
        max_shift_px=reach,
        model_gain=light_slope,
        max_samples=_COARSE_SAMPLES,
        uncertainty=False,
    )
    inside = np.isfinite(fit.xy).all(axis=1) & (np.linalg.norm(fit.xy - xy, axis=1) <= reach)
    return fit.xy, inside


class MarkerLocation(NamedTuple):
    """Sub-pixel centres of verified markers and what the final gates make of them.

    Attributes:
        xy: (N, 2) reported centres, px: the point-symmetry fit's, or the paper's
            NCC extremum (NaN where it has none).
        sigma: (N,) 1-sigma radial uncertainty, px (:func:`calibrated_sigma`).
        score: (N,) the evidence times (1 - the fit's relative symmetry residual).
        accepted: (N,) True where the fit converged near its start with a relative
            residual of at most the limit, a contrast of at least the floor, a
            finite sigma and (NCC) an extremum.
    """

    xy: NDArray[np.float64]
    sigma: NDArray[np.float64]
    score: NDArray[np.float64]
    accepted: NDArray[np.bool_]


def refine_along_lines(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    sigma: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    *,
    max_radius_px: float,
    full_scale: float,
    max_modelled: int = MAX_MODELLED,
    tally: dict[str, int] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Detections' final centres: the point-symmetry fit again, weighted along the X's lines.

    The gating fit of :func:`locate_markers` tapers its disk and, on large markers,
    reads a coarser grid than half a pixel; both are right for judging a candidate
    and cost precision on a marker. This fit reads the half-pixel pairs nearest
    the lines (at most :data:`_LINE_FIT_MAX_PAIRS`) within the same share of the
    X's reach all round, and of the ellipse its ends lie on, each line as far as it
    reaches (:func:`_line_band`), and weighs each by its distance from the nearer
    line (:data:`LINE_BAND_PX`): the edges carry the centre, the quadrants' insides
    only noise. The light's slope is fitted only on disks of
    :data:`GAIN_MIN_RADIUS_PX` and more (measured: docs/method.md,
    "Point-symmetry refinement").

    Where the quadrants' levels differ (a dull bright quadrant: wear, dirt, sheen;
    a shadow over two quadrants) the grey levels are not point-symmetric and this
    fit is pulled towards the brighter side, 0.2-0.5 px for a quadrant 0.7-0.5 as
    bright as its opposite. Each point's score statistic for the quadrants' own
    levels (:func:`_edge_step_chi2`, on the disk's pairs) says where: above
    :data:`LEVELS_REFIT_MIN_CHI2`, or above :data:`DULL_SECTOR_MIN_CHI2` where the rings
    across the disk read a dull bright sector (:func:`_dull_sector`; on disks of
    :data:`GAIN_MIN_RADIUS_PX` and more), the fit runs again with them (two more parameters,
    linear in :func:`_edge_steps`), along the lines' directions measured afresh from their edges
    (:func:`_edge_directions`: the levels' steps must lie on the lines, and the
    ring check's directions are a few degrees off), and may move up to
    :data:`EDGE_STEP_MAX_SHIFT_PX`. Under that threshold, from
    :data:`LEVELS_BLEND_MIN_CHI2`, the fit with the levels runs too, and the
    symmetric fit's centre moves towards it by the share of their difference that
    is bias (:func:`_blended_with_levels`), where it has not slipped.

    On disks of :data:`GAIN_MIN_RADIUS_PX` and more the light's slope is fitted
    with a prior from the quadrants' insides (:func:`_light_inside`), where the
    levels there do not differ; where they do (their statistic above
    :data:`LEVELS_REFIT_MIN_CHI2`, like the lines' own) the quadrants' own levels
    are fitted as above, from where the fit without the prior ends. The quadrants'
    own levels step with the blur that fits each X (:func:`_step_blur`).

    The levels' fit still rests on the pairs' difference of two blurred steps,
    which a camera's tone curve and a tilted X's wedges bend where the levels
    differ (:mod:`~marker_localizer.core.uneven` says how much); so where it ran,
    an X of :data:`MEASURED_MIN_EXTENT_PX` and more is located once more by its
    model, four levels through the tone curve, with a cast shadow's edge where
    :func:`shadow.find_edges` finds one
    (:func:`uneven.locate_uneven`), and the model's centre replaces the levels' where
    that fit converges and leaves no more than :data:`uneven.MAX_MISFIT_RATIO` times
    the levels' fit's residual at the same X (a chessboard corner, whose disk takes
    in the next squares, leaves more). Where the statistic does not say the levels
    differ (under :data:`LEVELS_REFIT_MIN_CHI2`, the blend's range included) the
    model is fitted only where the pairs show a shadow's edge, and its centre is
    taken only where it also rejects the line fit's (:data:`MODEL_MIN_CENTRE_CHI2`).
    The misfit is measured against the levels' fit, not the frame's noise: on
    frames written as JPEG the error along the edges exceeds the noise measured on
    smooth ground.

    Measured: docs/method.md, "Point-symmetry refinement"; docs/accuracy-journal.md, "The
    levels' fit weighed in by its bias", "The uneven X's model, and what bounds the
    fit", "The uneven model judged against the levels' fit, not the frame's noise"
    and "Figures the fit's and the detector's docstrings carried".

    Args:
        image: (H, W) grey image, raw levels.
        xy: (N, 2) the gating fit's centres.
        sigma: (N,) their sigmas, px.
        radius_px: (N,) extents of the X, px.
        line_angles: (N, 2) line directions, radians.
        max_radius_px: the largest expected marker radius, px.
        full_scale: the image's white level (:func:`~marker_localizer.core.image.to_gray`).
        max_modelled: the X's located by their model at most (:data:`MAX_MODELLED`).
        tally: where given, ``uneven_over_cap`` grows by the X's whose model was not
            fitted for ``max_modelled``.

    Returns:
        (xy, sigma, line_angles): the refined centres and their calibrated sigmas,
        the gating fit's where this fit did not converge or slipped
        (:data:`_LINE_FIT_MAX_SHIFT_PX`, :data:`EDGE_STEP_MAX_SHIFT_PX` with the
        quadrants' own levels); and the (N, 2) line directions it read along,
        radians in [0, pi): measured from the edges on X's of
        :data:`MEASURED_MIN_EXTENT_PX` and more, the given ones on the smaller.
    """
    if len(xy) == 0:
        return xy, sigma, line_angles
    line_angles = _measured_directions(image, xy, radius_px, line_angles, max_radius_px, full_scale)
    radius_px, along = _reach_all_round(image, xy, line_angles, radius_px, max_radius_px)
    radius = np.clip(_FINAL_RADIUS_FRACTION * radius_px, _FINAL_MIN_RADIUS_PX, max_radius_px)
    # Points sharing a radius (the ring ladder's rungs) share a half-disk; each keeps
    # its own pairs nearest its lines.
    centre = np.asarray(xy, np.float64).copy()
    covariance = np.zeros((len(xy), 2, 2))
    converged = np.zeros(len(xy), bool)
    reach = np.full(len(xy), _LINE_FIT_MAX_SHIFT_PX)
    fit = functools.partial(
        _gauss_newton_symmetry,
        image,
        iterations=_LINE_FIT_ITERATIONS,
        tolerance_px=_FINAL_TOLERANCE_PX,
        noise_floor=RESIDUAL_ROUNDING_STEPS * grey_step(image, xy),
        uncertainty=True,
        measure_contrast=False,
    )
    # Per rung, the X's its model locates once more: rows, lines, the levels' fit's
    # residual per pixel, the levels' statistic, and whether the model must reject the
    # centre it starts from (where the statistic does not say the levels differ).
    queued: list[tuple[NDArray[Any], ...]] = []
    rungs = [
        _line_rung(
            image, centre, float(key), rows, line_angles, _FINAL_RADIUS_FRACTION * along[rows]
        )
        for key in np.unique(radius)
        for rows in (np.flatnonzero(radius == key),)
    ]
    for (key, rows, band, sloped, prior, level_differ, dull_sector), symmetric in zip(
        rungs, _fit_rungs(fit, centre, rungs), strict=True
    ):
        centre[rows], covariance[rows], converged[rows] = (
            symmetric.centre,
            symmetric.covariance,
            symmetric.converged,
        )
        uneven_levels = (
            (symmetric.step_chi2 > LEVELS_REFIT_MIN_CHI2)
            | level_differ
            | (dull_sector & (symmetric.step_chi2 > DULL_SECTOR_MIN_CHI2))
        )
        differ = np.flatnonzero(symmetric.converged & uneven_levels)
        # A symmetric fit that slipped is not weighed in (the gating fit's centre stays).
        held = np.linalg.norm(symmetric.centre - xy[rows], axis=1) <= _LINE_FIT_MAX_SHIFT_PX
        even = symmetric.converged & held & ~uneven_levels
        blended = symmetric.step_chi2 > LEVELS_BLEND_MIN_CHI2
        leaning = np.flatnonzero(even & blended)
        plain = np.flatnonzero(even & ~blended & (radius_px[rows] >= MEASURED_MIN_EXTENT_PX))
        # A pair's residual is the difference of two pixels' noise.
        queued.append(
            (
                rows[plain],
                line_angles[rows[plain]],
                symmetric.levelled_rms[plain] / np.sqrt(2.0),
                symmetric.step_chi2[plain],
                np.ones(len(plain), bool),
            )
        )
        if len(differ):
            reach[rows[differ]] = EDGE_STEP_MAX_SHIFT_PX
            primed = differ[~level_differ[differ]] if sloped else differ[:0]
            if len(primed):
                # The levels' fit starts where the fit without the prior ends.
                centre[rows[primed]] = fit(
                    xy[rows[primed]],
                    band.offsets[primed],
                    band.weight[primed],
                    band.present[primed],
                    band.spacing[primed],
                    model_gain=True,
                ).centre
        # One levels' fit for both (for a few points a call's passes are the cost); the
        # prior stays out where the levels differ: zero information is none.
        levelled_rows = np.concatenate([differ, leaning])
        if not len(levelled_rows):
            continue
        slope_prior = None
        if prior is not None:
            slope_prior = (prior[0][levelled_rows], prior[1][levelled_rows])
            slope_prior[0][: len(differ)] = slope_prior[1][: len(differ)] = 0.0
        lines, levelled_fit = _levels_fit(
            fit,
            image,
            centre[rows[levelled_rows]],
            key,
            line_angles[rows[levelled_rows]],
            sloped,
            full_scale,
            slope_prior,
        )
        if len(differ):
            at = rows[differ]
            own = _SymmetrySolution._make(field[: len(differ)] for field in levelled_fit)
            centre[at], covariance[at], _, _, converged[at], _, _ = own
        if len(leaning):
            at = rows[leaning]
            centre[at], covariance[at], weight = _blended_with_levels(
                centre[at],
                covariance[at],
                _SymmetrySolution._make(field[len(differ) :] for field in levelled_fit),
            )
            reach[at[weight > 0]] = EDGE_STEP_MAX_SHIFT_PX
        at = rows[levelled_rows]
        wide = radius_px[at] >= MEASURED_MIN_EXTENT_PX
        queued.append(
            (
                at[wide],
                lines[wide],
                levelled_fit.residual_rms[wide] / np.sqrt(2.0),
                symmetric.step_chi2[levelled_rows][wide],
                (np.arange(len(at)) >= len(differ))[wide],
            )
        )
    at, lines, rms, statistic, tested = (np.concatenate(part) for part in zip(*queued, strict=True))
    reach_px = np.minimum(shadow.HYPOTHESIS_REACH_EXTENTS * radius_px[at], max_radius_px)
    asked = _asked_of_the_model(
        image, centre[at], lines, reach_px, statistic, tested, full_scale, max_modelled, tally
    )
    if len(asked):
        # One model fit for every radius: its points share nothing but the cost of a pass.
        at, lines, reach_px, rms, tested = (
            at[asked],
            lines[asked],
            reach_px[asked],
            rms[asked],
            tested[asked],
        )
        # The edge that fits best, for the model to keep where it explains.
        edges = shadow.find_edges(
            image, centre[at], reach_px, lines, full_scale, decided_by_pairs=False
        )
        modelled = uneven.locate_uneven(
            image,
            centre[at],
            lines,
            radius_px[at],
            full_scale,
            edges,
            rms,
            min_centre_chi2=np.where(tested, MODEL_MIN_CENTRE_CHI2, np.nan),
        )
        located = at[modelled.located]
        centre[located] = modelled.xy[modelled.located]
        covariance[located] = modelled.covariance[modelled.located]
        converged[located] = True
        # Each refit is bounded from where it starts; the model's from the levels'.
        reach[located] += uneven.MAX_SHIFT_PX
    refined = converged & (np.linalg.norm(centre - xy, axis=1) <= reach)
    line_sigma = _line_fit_sigma(covariance)
    refined &= np.isfinite(line_sigma)
    return (
        np.where(refined[:, None], centre, xy),
        np.where(refined, line_sigma, sigma),
        np.mod(line_angles, np.pi),
    )


def _asked_of_the_model(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    reach_px: NDArray[np.float64],
    statistic: NDArray[np.float64],
    tested: NDArray[np.bool_],
    full_scale: float,
    max_modelled: int,
    tally: dict[str, int] | None,
) -> NDArray[np.intp]:
    """The X's :func:`refine_along_lines` fits by their model, of those it queued (ascending).

    Those whose levels differ, all; the others (``tested``) where their pairs show a
    cast shadow's edge (:func:`shadow.find_edges` as it asks of a candidate, within
    ``reach_px``). At most ``max_modelled``, the highest levels' ``statistic`` first,
    then those without one (NaN), each tie in the queue's order; ``uneven_over_cap``
    in ``tally`` counts the rest.
    """
    asked = ~tested
    if tested.any():
        asked[tested] = shadow.find_edges(
            image, xy[tested], reach_px[tested], line_angles[tested], full_scale
        ).found
    rows = np.flatnonzero(asked)
    if len(rows) > max_modelled:
        # Ties in queue order, stably: the X's kept must not hang on the sort's build.
        first = np.argsort(-np.nan_to_num(statistic[rows], nan=-np.inf), kind="stable")
        over = rows[first[max_modelled:]]
        if tally is not None:
            tally["uneven_over_cap"] = tally.get("uneven_over_cap", 0) + len(over)
        asked[over] = False
    return np.flatnonzero(asked)


def _reach_all_round(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    extent_px: NDArray[np.float64],
    max_radius_px: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """How far the line fit reads each X: all round (N,), and along each of its lines (N, 2).

    All round, its rings' extent, or its reach (:func:`template.line_reaches`) where
    farther: taken up to :data:`REACH_MAX_GAIN` times the extent, on a ladder of
    :data:`_REACH_STEPS_PER_OCTAVE` steps an octave above it. Along the lines, each
    line's own reach (:func:`template.reaches_along_lines`, 0 where none was read).
    Neither past ``max_radius_px``.
    """
    along = template.reaches_along_lines(
        image, xy, line_angles, extent_px, REACH_MAX_GAIN * float(extent_px.max()) + 1.0
    )
    reach = template.smaller_semi_axis(along, line_angles)
    gain = np.clip(np.nan_to_num(reach / extent_px, nan=1.0), 1.0, REACH_MAX_GAIN)
    # The small epsilon keeps a full rung (sqrt 2) from rounding down a step.
    steps = np.floor(_REACH_STEPS_PER_OCTAVE * np.log2(gain) + 1e-9) / _REACH_STEPS_PER_OCTAVE
    # Each line no farther than REACH_MAX_GAIN times its X's own extent, which the reach
    # is read out to whatever the call's other X's: the same however they are batched.
    bound = np.minimum(REACH_MAX_GAIN * extent_px, max_radius_px)[:, None]
    return (
        np.minimum(extent_px * 2.0**steps, max_radius_px),
        np.minimum(np.nan_to_num(along, nan=0.0), bound),
    )


def _measured_directions(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    extent_px: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    max_radius_px: float,
    full_scale: float,
) -> NDArray[np.float64]:
    """(N, 2) the lines' directions measured from the edges (:func:`_edge_directions`).

    From the ring check's ``line_angles``, on X's of :data:`MEASURED_MIN_EXTENT_PX`
    and more, over the disk the line fit reads (those of one extent in one call);
    the smaller keep the rings' directions.
    """
    disk = np.clip(_FINAL_RADIUS_FRACTION * extent_px, _FINAL_MIN_RADIUS_PX, max_radius_px)
    measured = np.array(line_angles, dtype=np.float64)
    wide = extent_px >= MEASURED_MIN_EXTENT_PX
    for key in np.unique(disk[wide]):
        rows = np.flatnonzero(wide & (disk == key))
        measured[rows] = _edge_directions(
            image, xy[rows], float(key), measured[rows], full_scale, _MEASURED_DIRECTION_STEP_PX
        )
    return measured


def _levels_fit(
    fit: Callable[..., _SymmetrySolution],
    image: NDArray[Any],
    centre: NDArray[np.float64],
    radius_px: float,
    line_angles: NDArray[np.float64],
    sloped: bool,
    full_scale: float,
    slope_prior: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
) -> tuple[NDArray[np.float64], _SymmetrySolution]:
    """The line fit with the quadrants' own levels, along lines measured from the edges.

    ``fit`` is :func:`refine_along_lines`' :func:`_gauss_newton_symmetry`; the lines'
    directions are measured afresh at ``centre`` (:func:`_edge_directions`), the
    levels step with the blur that fits each X (:func:`_step_blur`), and the light's
    slope takes ``slope_prior`` where given (:func:`_light_inside`).

    Returns:
        (lines, solution): the (N, 2) directions measured, and the fit.
    """
    lines = _edge_directions(image, centre, radius_px, line_angles, full_scale)
    levelled = _line_band(radius_px, lines)
    blur = _step_blur(image, centre, levelled, sloped)
    solution = fit(
        centre,
        *levelled[:4],
        model_gain=sloped,
        edge_steps=levelled.steps(blur[:, None]),
        slope_prior=slope_prior,
    )
    return lines, solution


def _blended_with_levels(
    centre: NDArray[np.float64],
    covariance: NDArray[np.float64],
    levelled: _SymmetrySolution,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The symmetric fit's centres moved towards the levels' fit's by their bias's share.

    Where the quadrants' levels differ a little, the symmetric fit's centre c_s is
    pulled by a bias b, and the levels' fit c_l is unbiased but noisier. Their
    difference d = c_l - c_s has E|d|^2 = |b|^2 + var(d), so c_s + w d with
    w = max(0, 1 - var(d) / |d|^2) (positive-part shrinkage) takes the bias out where
    d says there is one and stays at c_s where d is what the noise makes. The two
    fits read the same pixels with different lines (the levels' are measured
    afresh) and models (under a light's slope the levels and the slope trade off),
    so their correlation is unknown, and var(d) is taken at its most,
    (s_l + s_s)^2, s each fit's calibrated sigma (:func:`_line_fit_sigma`: the
    covariances predict half the errors' spread): with var(d) from the covariances
    as they are, the levels and a light's slope trade off, and the slope then costs
    the centre precision (measured: docs/accuracy-journal.md, "The levels' fit weighed in by
    its bias"). w is 0 where the levels' fit did not converge or slipped
    (:data:`EDGE_STEP_MAX_SHIFT_PX`). The covariance becomes
    Cov(c_s) + w^2 (Cov(c_l) - Cov(c_s)).

    Args:
        centre: (N, 2) the symmetric fit's centres.
        covariance: (N, 2, 2) their covariances.
        levelled: the levels' fit from them (:func:`_levels_fit`).

    Returns:
        (centre, covariance, w).
    """
    difference = levelled.centre - centre
    squared = (difference**2).sum(axis=1)
    spread = levelled.covariance - covariance
    largest = (_line_fit_sigma(levelled.covariance) + _line_fit_sigma(covariance)) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        weight = 1.0 - largest / squared
    usable = levelled.converged & (squared <= EDGE_STEP_MAX_SHIFT_PX**2) & np.isfinite(weight)
    weight = np.where(usable, np.clip(weight, 0.0, 1.0), 0.0)
    return (
        centre + weight[:, None] * difference,
        covariance + weight[:, None, None] ** 2 * spread,
        weight,
    )


class _Rung(NamedTuple):
    """The points of one radius in :func:`refine_along_lines`, and their first fit's inputs.

    ``rows`` (M,) index the points; ``band`` is their pairs (:func:`_line_band`);
    ``sloped`` whether the light's slope is fitted (disks of
    :data:`GAIN_MIN_RADIUS_PX` and more), with ``prior`` from the quadrants' insides
    (:func:`_light_inside`), none where ``level_differ`` (M,) says their levels differ;
    ``dull_sector`` (M,) where the rings across the disk read a dull bright sector
    (:func:`_dull_sector`, on sloped disks).
    """

    key: float
    rows: NDArray[np.intp]
    band: _LineBand
    sloped: bool
    prior: tuple[NDArray[np.float64], NDArray[np.float64]] | None
    level_differ: NDArray[np.bool_]
    dull_sector: NDArray[np.bool_]


def _line_rung(
    image: NDArray[Any],
    centre: NDArray[np.float64],
    key: float,
    rows: NDArray[np.intp],
    line_angles: NDArray[np.float64],
    semi_diameters: NDArray[np.float64],
) -> _Rung:
    """:class:`_Rung` of the points ``rows`` fitted over a disk of radius ``key``, px.

    Their pairs reach out to their ellipses too (``semi_diameters`` (M, 2) along their
    lines, px: :func:`_line_band`).
    """
    band = _line_band(key, line_angles[rows], semi_diameters)
    sloped = bool(key >= GAIN_MIN_RADIUS_PX)
    if not sloped:
        even = np.zeros(len(rows), bool)
        return _Rung(key, rows, band, sloped, None, even, even)
    inside = _light_inside(image, centre[rows], key, line_angles[rows])
    # Quadrants whose levels differ tilt the insides' light: no prior there.
    level_differ = inside.level_chi2 > LEVELS_REFIT_MIN_CHI2
    prior = (
        np.where(level_differ[:, None], 0.0, inside.slope),
        np.where(level_differ[:, None, None], 0.0, inside.information),
    )
    return _Rung(
        key, rows, band, sloped, prior, level_differ, _dull_sector(image, centre[rows], key)
    )


def _dull_sector(
    image: NDArray[Any], centre: NDArray[np.float64], radius_px: float
) -> NDArray[np.bool_]:
    """(N,) where rings across each disk of ``radius_px`` read a dull bright sector.

    The median of :func:`verification.bright_sector_balance` on rings at
    :data:`_BALANCE_RING_FRACTIONS` of the radius is under
    :data:`DULL_SECTOR_MAX_BALANCE`; a flat ring, or one that leaves the image, reads as
    even.
    """
    rings = annular_profiles(image, centre, radius_px * np.array(_BALANCE_RING_FRACTIONS))
    balance = np.nan_to_num(bright_sector_balance(rings), nan=1.0)
    dull: NDArray[np.bool_] = np.median(balance, axis=1) < DULL_SECTOR_MAX_BALANCE
    return dull


def _fit_rungs(
    fit: Callable[..., _SymmetrySolution], centre: NDArray[np.float64], rungs: list[_Rung]
) -> list[_SymmetrySolution]:
    """Each rung's fit along its lines (``fit``: :func:`_gauss_newton_symmetry`), from ``centre``.

    Rungs whose bands have as many pairs (every radius whose half disk holds more than
    :data:`_LINE_FIT_MAX_PAIRS`) and the same model are fitted in one call, each
    ending as its own call would: for a few points a call's passes, not its pairs,
    are the cost (three rungs of 18 markers on a 12 MP frame: 2.7-2.9 ms in one call,
    4.1 in three).
    """
    batches: dict[tuple[bool, int], list[int]] = {}
    for k, rung in enumerate(rungs):
        batches.setdefault((rung.sloped, rung.band.offsets.shape[1]), []).append(k)
    solutions: list[_SymmetrySolution | None] = [None] * len(rungs)
    for batch in batches.values():
        members = [rungs[k] for k in batch]
        rows = np.concatenate([rung.rows for rung in members])
        band = _LineBand._make(
            np.concatenate(parts) for parts in zip(*(rung.band for rung in members), strict=True)
        )
        prior = None
        if members[0].prior is not None:
            prior = (
                np.concatenate([cast("tuple[Any, Any]", r.prior)[0] for r in members]),
                np.concatenate([cast("tuple[Any, Any]", r.prior)[1] for r in members]),
            )
        # The levels' statistic reads the disk's pairs alone, where its bars were set: out
        # along the lines, near a blurred X's ends, the steps fit less, and X's of even
        # paint would go to the levels' fit.
        solved = fit(
            centre[rows],
            *band[:4],
            model_gain=members[0].sloped,
            test_steps=band.steps(),
            test_within=np.concatenate([rung.band.within(rung.key) for rung in members]),
            slope_prior=prior,
            groups=np.repeat(np.arange(len(members)), [len(r.rows) for r in members]),
        )
        stops = np.cumsum([len(rung.rows) for rung in members])
        for k, start, stop in zip(
            batch, stops - [len(r.rows) for r in members], stops, strict=True
        ):
            solutions[k] = _SymmetrySolution._make(field[start:stop] for field in solved)
    return cast("list[_SymmetrySolution]", solutions)


def locate_in_shadow(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    sigma: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    full_scale: float,
    edges: shadow.ShadowEdges,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Markers found with a shadow divided out, located in the frame itself with its edge.

    The division (:func:`shadow.divided_out`, through the edge :func:`shadow.find_edges`
    proposed before any X was known) leaves some of the shadow, and the fits that
    found the marker on that copy are pulled by what is left: on the renderer's
    (g), 0.1-0.7 px for some of them. Here each X of :data:`MEASURED_MIN_EXTENT_PX`
    and more is fitted in the frame by its model with the shadow's edge
    (:func:`uneven.locate_uneven`, from ``edges``, one per point, about ``xy``),
    which keeps the edge where it explains, and its centre is taken where that fit
    converges and fits no worse than with its centre held at ``xy``
    (``min_centre_chi2`` 0): a fit that ends worse has slid into another minimum.
    The edge's share of the residual (:data:`shadow.MIN_EXPLAINED`, the share the
    edge must explain of the pairs to be proposed) is not asked: it turns away X's
    the model puts closer to the truth, and does not tell a slide from them. Under
    6 px the model reads its tone curve and wedges on too few pixels. Measured:
    docs/accuracy-journal.md, "The model wherever it converges on a marker found in a
    shadow, and never under 6 px" and "The model where it rejects the line fit's
    centre".

    Args:
        image: (H, W) grey image, raw levels.
        xy: (N, 2) the centres found on the divided copy, px.
        sigma: (N,) their sigmas, px.
        line_angles: (N, 2) their lines' directions, radians.
        radius_px: (N,) their X's extents, px.
        full_scale: the image's white level.
        edges: (N) the shadow's edge about each of ``xy``.

    Returns:
        (xy, sigma, located): the centres and sigmas, the model's where ``located``.
    """
    wide = np.flatnonzero(radius_px >= MEASURED_MIN_EXTENT_PX)
    modelled = uneven.locate_uneven(
        image,
        xy[wide],
        line_angles[wide],
        radius_px[wide],
        full_scale,
        edges.take(wide),
        min_centre_chi2=0.0,
    )
    at = wide[modelled.located]
    xy, sigma, located = xy.copy(), sigma.copy(), np.zeros(len(xy), bool)
    xy[at] = modelled.xy[modelled.located]
    sigma[at] = _line_fit_sigma(modelled.covariance[modelled.located])
    located[at] = True
    return xy, sigma, located


def _line_fit_sigma(covariance: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N,) the final centres' sigmas, px, from their (N, 2, 2) covariances.

    sqrt(var_x + var_y) times :data:`LINE_FIT_SIGMA_CALIBRATION`; NaN where the
    covariance is.
    """
    variance = covariance[:, 0, 0] + covariance[:, 1, 1]
    return cast(
        "NDArray[np.float64]", LINE_FIT_SIGMA_CALIBRATION * np.sqrt(np.maximum(variance, 0.0))
    )


class _LineBand(NamedTuple):
    """The half-pixel pairs :func:`refine_along_lines` reads around N points' lines.

    ``offsets`` (N, K, 2), ``weight`` and ``present`` (N, K) and ``spacing`` (N,)
    in :func:`_gauss_newton_symmetry`'s order; ``across`` (N, K, 2) the offsets'
    signed distances from the two lines (:func:`template.line_distances`).
    """

    offsets: NDArray[np.float64]
    weight: NDArray[np.float64]
    present: NDArray[np.bool_]
    spacing: NDArray[np.float64]
    across: NDArray[np.float64]

    def within(self, radius_px: float) -> NDArray[np.bool_]:
        """(N, K) the pairs within ``radius_px`` of the centre."""
        within: NDArray[np.bool_] = (self.offsets**2).sum(axis=-1) <= radius_px**2
        return within

    def steps(
        self, blur_px: float | NDArray[np.float64] = EDGE_STEP_BLUR_PX
    ) -> NDArray[np.float64]:
        """(N, K, 2) :func:`_edge_steps` at the offsets for an edge blur, px (or (N, 1) blurs)."""
        # Both lines' steps in one read of the table, ``across`` as it lies: the same
        # values as a read per line and their stack, in half the time.
        blur = blur_px if np.ndim(blur_px) == 0 else np.asarray(blur_px)[..., None]
        return template.edge_step(self.across, blur)


def _line_band(
    radius_px: float,
    line_angles: NDArray[np.float64],
    semi_diameters: NDArray[np.float64] | None = None,
) -> _LineBand:
    """Each point's pairs of the half disk of ``radius_px`` nearest its lines (N, 2).

    With ``semi_diameters`` (N, 2), px, also those of the ellipse whose conjugate
    semi-diameters run that far along the lines (:func:`template.within_ellipse`),
    within the half-pixel grid's largest disk (:data:`_HALF_PIXEL_MAX_RADIUS_PX`).
    A tilted X's ends lie on an ellipse whose smaller semi-axis is the disk's
    radius: the pairs out along its lines, past the disk, are the X's edges too
    (measured: docs/accuracy-journal.md, "The line fit read out to the X's ellipse").

    At most :data:`_LINE_FIT_MAX_PAIRS`, each weighed exp(-s^2 / 2) by its distance s
    from the nearer line in :data:`LINE_BAND_PX`, none beyond :data:`_LINE_BAND_REACH`.
    """
    # The grid and its pairs' count follow from the radius alone: each point's pairs,
    # and the order its sums take them in, are the same however the points are batched.
    outer = radius_px
    if semi_diameters is not None:
        outer = max(radius_px, min(REACH_MAX_GAIN * radius_px, _HALF_PIXEL_MAX_RADIUS_PX))
    disk, _ = symmetric_offsets(outer, _LINE_FIT_MAX_SAMPLES)
    s1, s2 = template.line_distances(disk[None, :, 0], disk[None, :, 1], line_angles)
    distance = np.minimum(np.abs(s1), np.abs(s2)) / LINE_BAND_PX
    if semi_diameters is not None and outer > radius_px:
        inside = ((disk**2).sum(axis=1) <= radius_px**2) | template.within_ellipse(
            s1, s2, semi_diameters, line_angles
        )
        distance = np.where(inside, distance, np.inf)
    if len(disk) > _LINE_FIT_MAX_PAIRS or outer > radius_px:
        nearest = _nearest_in_order(distance, min(_LINE_FIT_MAX_PAIRS, len(disk)))
        distance, s1, s2 = (np.take_along_axis(a, nearest, axis=1) for a in (distance, s1, s2))
        offsets = disk[nearest]
    else:
        # A half disk of no more pairs is every point's band as it is (a copy each: the
        # fit's arrays keep the offsets' memory order, and with it their sums' order).
        offsets = np.repeat(disk[None], len(line_angles), axis=0)
    present = distance <= _LINE_BAND_REACH
    return _LineBand(
        offsets,
        np.where(present, np.exp(-0.5 * distance**2), 0.0),
        present,
        np.full(len(line_angles), _grid_spacing(outer, _LINE_FIT_MAX_SAMPLES)),
        np.stack([s1, s2], axis=-1),
    )


def _nearest_in_order(distance: NDArray[np.float64], count: int) -> NDArray[np.intp]:
    """(N, count) indices of each row's ``count`` smallest ``distance``, ascending.

    Of distances tied at the last place, the first in the row. An argpartition's
    choice among such ties, and the order it leaves its picks in, which the fit's
    sums follow, differ between numpy's builds and SIMD targets.
    """
    kth = np.partition(distance, count - 1, axis=1)[:, count - 1 : count]
    chosen = distance < kth
    tied = distance == kth
    chosen |= tied & (np.cumsum(tied, axis=1) <= count - chosen.sum(axis=1, keepdims=True))
    return np.nonzero(chosen)[1].reshape(len(distance), count)


def _step_blur(
    image: NDArray[Any],
    centre: NDArray[np.float64],
    band: _LineBand,
    model_gain: bool,
) -> NDArray[np.float64]:
    """(N,) each X's edge blur for its quadrants' own levels, of :data:`EDGE_STEP_BLURS_PX`, px.

    The steps' shape decides where a dull quadrant's level ends and the centre's
    information begins, and one blur for every X (:data:`EDGE_STEP_BLUR_PX`) lets a
    dull quadrant's level bleed into the centre where the X is sharper or softer.
    From one reading of the pairs at ``centre``, the fit linearised there (centre,
    slope, and the two steps at each blur in turn) leaves a least-squares cost per
    blur; the blur of the least is taken (the cost's profile over the blur). Five
    full fits, one per blur, kept by their residual, cost five times the refit and
    do no better; eleven blurs 0.5-1.6 px by this profile neither (the more choices,
    the more the noise picks). Measured: docs/method.md,
    "Point-symmetry refinement"; docs/accuracy-journal.md, "Figures the fit's and the
    detector's docstrings carried".
    """
    residual, weight, jacobian, _, _ = _symmetry_terms(
        image, centre, np.zeros((len(centre), 4)), _both_ends(band.offsets), band.weight, model_gain
    )
    cost = []
    for blur in EDGE_STEP_BLURS_PX:
        design = np.concatenate([jacobian, -band.steps(blur)], axis=-1)
        weighted = design * weight[..., None]
        normal = weighted.transpose(0, 2, 1) @ design
        rhs = weighted.transpose(0, 2, 1) @ residual[..., None]
        solution = _damped_solve(normal, rhs)
        cost.append((weight * residual**2).sum(axis=1) - (rhs * solution)[..., 0].sum(axis=1))
    picked: NDArray[np.float64] = np.asarray(EDGE_STEP_BLURS_PX)[np.argmin(np.array(cost), axis=0)]
    return picked


def _edge_directions(
    image: NDArray[Any],
    centre: NDArray[np.float64],
    radius_px: float,
    line_angles: NDArray[np.float64],
    full_scale: float,
    step_px: float = 0.5,
) -> NDArray[np.float64]:
    """(N, 2) each X's line directions at ``centre``, from the gradient energy along its lines.

    Each line's direction is the principal axis of the second moment of the
    positions d within :data:`_DIRECTION_WEDGE_RAD` of it, weighed by
    |grad I(c + d)|^2 and taken about their own weighted mean, not about c: a dull
    quadrant weakens one half of a line, and about a centre that is itself off
    (the gating fit's, pulled towards the brighter side) that would turn the axis.
    The quadrants' levels of :func:`refine_along_lines` rest on these directions:
    3 degrees off, a rendered X with a quadrant 0.7 as bright as its opposite is
    located 0.12 px off, with these directions 0.01 px.

    Where the X's disk holds a clipped level (:func:`~marker_localizer.core.image.clipped`)
    its white paint is cut off at white, and each edge's gradient moves to its
    dark side: on the two halves of a line, either side of the centre, the dark
    quadrant lies on opposite sides, so the halves' ridges are parallel and offset
    in opposite senses, and one axis through both is turned (a chessboard at twice
    its exposure: 3.7 degrees, median). There each half is taken about its own
    mean, their moments pooled, and from the second pass each half's wedge is
    centred on its own offset from the line.

    Args:
        image: (H, W) grey image, raw levels.
        centre: (N, 2) the X's centres, px.
        radius_px: the disk read, px.
        line_angles: (N, 2) the directions to start from, radians.
        full_scale: the image's white level (:func:`~marker_localizer.core.image.to_gray`).
        step_px: the grid's step, px (:func:`symmetric_offsets`).
    """

    def directions(
        centre: NDArray[np.float64], line_angles: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        return _edge_directions_of(image, centre, radius_px, line_angles, full_scale, step_px)

    return in_blocks(directions, _DIRECTION_BLOCK, centre, line_angles)


def _edge_directions_of(
    image: NDArray[Any],
    centre: NDArray[np.float64],
    radius_px: float,
    line_angles: NDArray[np.float64],
    full_scale: float,
    step_px: float,
) -> NDArray[np.float64]:
    """:func:`_edge_directions` of the X's of one block."""
    disk, _ = symmetric_offsets(radius_px, _LINE_FIT_MAX_SAMPLES, step_px)
    offsets = np.concatenate([disk, -disk])
    values, gx, gy, valid = bilinear_with_gradient(
        image, centre[:, 0, None] + offsets[:, 0], centre[:, 1, None] + offsets[:, 1]
    )
    distance = np.hypot(offsets[:, 0], offsets[:, 1])
    energy = (gx**2 + gy**2) * (valid & (distance >= _DIRECTION_INNER_PX))
    wedge = np.sin(_DIRECTION_WEDGE_RAD) * distance
    powers = np.column_stack(
        [offsets, offsets[:, 0] ** 2, offsets[:, 0] * offsets[:, 1], offsets[:, 1] ** 2]
    )
    halved = np.flatnonzero((clipped(values, full_scale) & valid).any(axis=1))
    # (M, line, half): each half-line's offset from its line, ahead of the centre first.
    half_offsets = np.zeros((len(halved), 2, 2))
    angles = np.array(line_angles, np.float64)
    for _ in range(_DIRECTION_ITERATIONS):
        across = template.line_distances(offsets[None, :, 0], offsets[None, :, 1], angles)
        for i, s in enumerate(across):
            _, moment = _moment_about_mean(energy * (np.abs(s) <= wedge), powers)
            # A block without a clipped X (most: white paint seldom clips) skips the
            # halves' passes over no rows, two fifths of the measurement's time
            # (docs/speed.md, "The edge directions without the halves of no X").
            if len(halved):
                direction = angles[halved, i, None]
                ahead = np.cos(direction) * offsets[:, 0] + np.sin(direction) * offsets[:, 1] >= 0.0
                shifted = s[halved] - np.where(
                    ahead, half_offsets[:, i, :1], half_offsets[:, i, 1:]
                )
                means = []
                moment[halved] = 0.0
                for half in (ahead, ~ahead):
                    mean, half_moment = _moment_about_mean(
                        energy[halved] * (half & (np.abs(shifted) <= wedge)), powers
                    )
                    moment[halved] += half_moment
                    means.append(mean)
            _, axes = np.linalg.eigh(moment)
            angles[:, i] = np.arctan2(axes[:, 1, 1], axes[:, 0, 1])
            if len(halved):
                # An axis has no sense; the halved X's keep theirs, so that each half-line's
                # offset stays with its half from one pass to the next.
                turned = np.cos(angles[halved, i] - direction[:, 0]) < 0.0
                angles[halved[turned], i] += np.pi
                for h, mean in enumerate(means):
                    half_offsets[:, i, h] = template.line_distances(
                        mean[:, :1], mean[:, 1:], angles[halved]
                    )[i][:, 0]
    return angles


def _moment_about_mean(
    weight: NDArray[np.float64], powers: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(N, 2) weighted means and (N, 2, 2) second moments about them of S positions.

    From the sums of d and d d^T: one (N, S) x (S, 5) product, not the (N, S, 2)
    positions about each mean. ``weight`` is (N, S); ``powers`` (S, 5) holds each
    position's x, y, x^2, x y, y^2.
    """
    total = np.maximum(weight.sum(axis=1), 1e-12)
    sums = weight @ powers
    mean = sums[:, :2] / total[:, None]
    moment = np.empty((len(weight), 2, 2))
    moment[:, 0, 0] = sums[:, 2] - total * mean[:, 0] ** 2
    moment[:, 0, 1] = moment[:, 1, 0] = sums[:, 3] - total * mean[:, 0] * mean[:, 1]
    moment[:, 1, 1] = sums[:, 4] - total * mean[:, 1] ** 2
    return mean, moment


class _InsideLight(NamedTuple):
    """What :func:`_light_inside` reads of N points' quadrants, each with the points first.

    ``slope`` (N, 2) is the light's slope, ``information`` (N, 2, 2) its normal
    matrix (the quadrants' levels marginalised) per square pixel: each pair's term
    times the area it stands for, so that a fit on any grid can take it
    (:func:`_gauss_newton_symmetry`). ``level_chi2`` (N,) is the chi-square of the
    quadrants' own levels as fitted (Wald, 2 degrees of freedom, the slope unknown).
    """

    slope: NDArray[np.float64]
    information: NDArray[np.float64]
    level_chi2: NDArray[np.float64]


def _light_inside(
    image: NDArray[Any],
    centre: NDArray[np.float64],
    radius_px: float,
    line_angles: NDArray[np.float64],
) -> _InsideLight:
    """The light's slope across each X, from the pairs inside its quadrants.

    Pairs within a blur's reach of a line hold the centre and the slope alike: a
    centre moved across a line and a light brighter on one side both change
    I(c + d) - I(c - d) there, in proportion to the distance along the line. The
    pairs :data:`INSIDE_LINE_DISTANCE_PX` and more from both lines hold only the
    slope, g . d (I(c + d) + I(c - d)), and the quadrants' own levels, a E1 + b E2
    with E_i = +-1 there (:func:`_edge_steps`): one linear least-squares fit of the
    four. The slope's information (the levels unknown) then joins the line fit as a
    prior (:func:`_gauss_newton_symmetry`), whose centre no longer pays for the
    slope it fits: four rendered X's of 20 px, blur 1.2 px, 3 DN of noise, under a
    light changing 0.2 % a pixel, are located within 1.94x the Cramer-Rao bound
    with the slope from the lines alone, 1.65x with this prior
    (``test_the_light_slope_from_the_insides_costs_the_centre_little``).
    """
    disk, _ = symmetric_offsets(radius_px, _INSIDE_MAX_SAMPLES)
    s1, s2 = template.line_distances(disk[None, :, 0], disk[None, :, 1], line_angles)
    k = len(disk)
    both, valid = bilinear(image, *_pair_positions(centre, _both_ends(disk[None])))
    plus, minus = both[:, :k], both[:, k:]
    weight = (
        (np.minimum(np.abs(s1), np.abs(s2)) >= INSIDE_LINE_DISTANCE_PX)
        & valid[:, :k]
        & valid[:, k:]
    ).astype(np.float64)
    total = plus + minus
    # Each column written in place of the (N, K, 4) arrays, not stacked from temporaries.
    design = np.empty((*total.shape, 4))
    np.multiply(disk[:, 0], total, out=design[..., 0])
    np.multiply(disk[:, 1], total, out=design[..., 1])
    np.sign(s1, out=design[..., 2])
    np.sign(s2, out=design[..., 3])
    weighted = np.empty_like(design)
    for column in range(4):
        np.multiply(design[..., column], weight, out=weighted[..., column])
    normal = weighted.transpose(0, 2, 1) @ design + 1e-9 * np.eye(4)
    residual = plus - minus
    solution = cast(
        "NDArray[np.float64]",
        np.linalg.solve(normal, (weighted.transpose(0, 2, 1) @ residual[..., None]))[..., 0],
    )
    misfit = residual - (design @ solution[..., None])[..., 0]
    # Per pair, like the line fit's: pairs closer than a pixel are correlated.
    spacing = _grid_spacing(radius_px, _INSIDE_MAX_SAMPLES)
    variance = (weight * misfit**2).sum(axis=1) / np.maximum(weight.sum(axis=1) - 4, 1.0)
    variance = np.maximum(variance, 1e-12) / min(spacing, 1.0) ** 2
    slope_block, cross, level_block = normal[:, :2, :2], normal[:, :2, 2:], normal[:, 2:, 2:]
    levels = solution[:, 2:]
    level_information = level_block - cross.transpose(0, 2, 1) @ np.linalg.solve(slope_block, cross)
    level_chi2 = (levels[:, None, :] @ level_information @ levels[:, :, None])[:, 0, 0] / variance
    slope_information = slope_block - cross @ np.linalg.solve(level_block, cross.transpose(0, 2, 1))
    return _InsideLight(solution[:, :2], slope_information * spacing**2, level_chi2)


def locate_markers(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    evidence: NDArray[np.float64],
    *,
    max_radius_px: float,
    iterations: int,
    min_contrast: float | NDArray[np.float64],
    max_symmetry_residual: float,
    ncc_offset_px: float | None = None,
    ncc_search_px: int = 2,
) -> MarkerLocation:
    """Section 3.3: each marker's sub-pixel centre, its sigma, final score and gates.

    The point-symmetry fit (:func:`refine_point_symmetry`, with the gain gradient)
    over :data:`_FINAL_RADIUS_FRACTION` of each X's extent runs in every mode: it is
    the default position, and its residual gates and scores every point. Where the
    quadrants' levels differ (a dull bright quadrant, a shadow edge) the grey levels
    are not point-symmetric and that residual holds the difference; where the
    score statistic of the bright pair's own level (:func:`_bright_pair_step`)
    passes :data:`LEVELLED_MIN_CHI2` and that level leaves an X as clean as even
    paint (:data:`LEVELLED_MAX_RESIDUAL`), the residual it leaves gates and scores
    it instead. The dark pair keeps one level, as in the template's match: black
    paint stays black under wear, dirt or sheen, while the dark gaps of a texture
    saddle differ as its stones do. X's of texture's size
    (under :data:`verification.X_END_MAX_EXTENT_PX`) keep the plain residual: texture
    saddles of that size reach their floors with a level of their own, and where
    such an X ends is what judges it. The position stays the
    symmetric fit's (:func:`refine_along_lines` moves it). With
    ``ncc_offset_px`` the reported position is the paper's NCC extremum
    (:func:`ncc_refine`), and its distance from the symmetry centre is added to
    sigma.

    Args:
        image: (H, W) grey image, raw levels.
        xy: (N, 2) start positions (centred candidates, or tracked markers).
        radius_px: (N,) extents of the X, px.
        line_angles: (N, 2) line directions, radians (for the NCC template).
        evidence: (N,) the verification's score, in [0, 1].
        max_radius_px: the largest expected marker radius, px.
        iterations: Gauss-Newton iterations at most.
        min_contrast: lowest contrast of the fitted X, raw grey levels; or (N,) one
            per point.
        max_symmetry_residual: largest RMS symmetry residual, share of the contrast.
        ncc_offset_px: the NCC template's level offset, px; None: no NCC location.
        ncc_search_px: the NCC surface's half-size, px.
    """
    fit = refine_point_symmetry(
        image,
        xy,
        np.clip(_FINAL_RADIUS_FRACTION * radius_px, _FINAL_MIN_RADIUS_PX, max_radius_px),
        iterations=iterations,
        tolerance_px=_FINAL_TOLERANCE_PX,
        max_shift_px=_FINAL_MAX_SHIFT_PX,
        model_gain=True,
        noise_floor=RESIDUAL_ROUNDING_STEPS * grey_step(image, xy),
        line_angles=line_angles,
    )
    position = fit.xy
    located: NDArray[np.bool_] = np.ones(len(xy), bool)
    discrepancy = None
    if ncc_offset_px is not None:
        position = ncc_refine(
            image, xy, radius_px, line_angles, offset_px=ncc_offset_px, search_px=ncc_search_px
        ).offset
        located = cast("NDArray[np.bool_]", np.isfinite(position).all(axis=1))
        discrepancy = np.where(located, np.sum((position - fit.xy) ** 2, axis=1), 0.0)
    sigma = calibrated_sigma(fit.covariance, discrepancy)
    contrast = np.maximum(fit.contrast, _MIN_CONTRAST)
    levelled = (
        (fit.step_chi2 > LEVELLED_MIN_CHI2)
        & (radius_px >= X_END_MAX_EXTENT_PX)
        & (fit.levelled_residual <= LEVELLED_MAX_RESIDUAL * contrast)
    )
    relative_residual = np.where(levelled, fit.levelled_residual, fit.residual) / contrast
    score = evidence * np.clip(1.0 - relative_residual, 0.0, 1.0)
    faint = fit.contrast < min_contrast
    accepted = located & fit.converged & (relative_residual <= max_symmetry_residual) & ~faint
    accepted &= np.isfinite(sigma)
    return MarkerLocation(position, sigma, score, accepted)


class _Terms(NamedTuple):
    """What :func:`_symmetry_terms` reads at N points' centres, each with the points first.

    ``residual`` and ``weight`` (N, K); the ``jacobian`` (N, K, P) and its columns
    times the weight, ``weighted``; the ``samples`` (N, 2K), I(c + d) then I(c - d).
    """

    residual: NDArray[np.float64]
    weight: NDArray[np.float64]
    jacobian: NDArray[np.float64]
    weighted: NDArray[np.float64]
    samples: NDArray[np.float64]


def _symmetry_terms(
    image: NDArray[Any],
    centre: NDArray[np.float64],
    gain: NDArray[np.float64],
    ends: tuple[NDArray[np.float64], NDArray[np.float64]],
    taper: NDArray[np.float64],
    model_gain: bool,
    edge_steps: NDArray[np.float64] | None = None,
) -> _Terms:
    """Residuals r(d), weights, Jacobian and the samples I(c +- d) at ``centre``.

    ``ends`` are each point's pairs' offsets (:func:`_both_ends`) and ``taper`` (N, K)
    their weights. With ``edge_steps`` (N, K, 2), :func:`_edge_steps` at the offsets,
    r(d) also loses a E1(d) + b E2(d), a and b the last two of ``gain``'s four columns.
    """
    k = ends[0].shape[1] // 2
    dx, dy = ends[0][:, :k], ends[1][:, :k]
    both, gx, gy, valid = bilinear_with_gradient(image, *_pair_positions(centre, ends))
    plus, minus = both[:, :k], both[:, k:]
    residual = plus - minus
    weight = taper * (valid[:, :k] & valid[:, k:])
    columns = 2 + 2 * model_gain + 2 * (edge_steps is not None)
    # Each column written in place of the (N, K, P) arrays, not stacked from temporaries.
    jacobian = np.empty((*residual.shape, columns))
    np.subtract(gx[:, :k], gx[:, k:], out=jacobian[..., 0])
    np.subtract(gy[:, :k], gy[:, k:], out=jacobian[..., 1])
    if model_gain:
        total = plus + minus
        residual -= (gain[:, 0, None] * dx + gain[:, 1, None] * dy) * total
        # -d is the ends' second half (negation is exact).
        np.multiply(ends[0][:, k:], total, out=jacobian[..., 2])
        np.multiply(ends[1][:, k:], total, out=jacobian[..., 3])
    if edge_steps is not None:
        residual -= gain[:, 2, None] * edge_steps[..., 0] + gain[:, 3, None] * edge_steps[..., 1]
        np.negative(edge_steps, out=jacobian[..., -2:])
    # Column by column: a product broadcast along the short last axis costs 2-3x.
    weighted = np.empty_like(jacobian)
    for column in range(columns):
        np.multiply(jacobian[..., column], weight, out=weighted[..., column])
    return _Terms(residual, weight, jacobian, weighted, both)


def _damped_solve(normal: NDArray[np.float64], rhs: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, P, M) solutions of (N, P, P) normal equations, each damped by 1e-9 of its diagonal.

    A parameter the pairs say nothing about (a slope column at the frame's edge, a
    step the band misses) then stays put instead of making the system singular.
    """
    scale = np.maximum(normal.diagonal(axis1=1, axis2=2), 1e-12)
    damped = normal + 1e-9 * scale[:, :, None] * np.eye(normal.shape[-1])
    return cast("NDArray[np.float64]", np.linalg.solve(damped, rhs))


def _both_ends(
    offsets: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(x, y), each (N, 2K): the K offsets d (N, K, 2) of each point's pairs, then -d.

    Both ends of every pair in one gather: for a few dozen points the calls, not the
    samples, are the cost. A fit reads them at every step: formed once, c + (-d)
    is c - d to the bit.
    """
    dx, dy = offsets[..., 0], offsets[..., 1]
    return np.concatenate([dx, -dx], axis=1), np.concatenate([dy, -dy], axis=1)


def _pair_positions(
    centre: NDArray[np.float64], ends: tuple[NDArray[np.float64], NDArray[np.float64]]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(x, y), each (N, 2K): the positions c + d of the pairs' :func:`_both_ends`."""
    return centre[:, 0, None] + ends[0], centre[:, 1, None] + ends[1]


def _edge_steps(
    s1: NDArray[np.float64], s2: NDArray[np.float64], blur_px: float | NDArray[np.float64]
) -> NDArray[np.float64]:
    """(..., 2) the blurred steps E_i = erf(s_i / (sqrt(2) sigma)) across the X's two lines.

    An X whose four quadrants have levels of their own (a dull bright quadrant, a
    shadow over two of them) is not point-symmetric in its grey levels, but its
    symmetry residual is linear in these steps: with Phi_q the blurred indicator of
    quadrant q and a, b, c, d the quadrants in turn (c opposite a),
    I(c + d) - I(c - d) = (L_a - L_c)(Phi_a - Phi_c) + (L_b - L_d)(Phi_b - Phi_d),
    and for a blur that factors along the lines' normals Phi_a - Phi_c = (E1 + E2) / 2,
    Phi_b - Phi_d = (E1 - E2) / 2. The lines pass through the centre being fitted, so
    the steps are fixed in offset coordinates.

    Args:
        s1: signed distances from line 1 (:func:`template.line_distances`), px.
        s2: the same from line 2.
        blur_px: the edges' Gaussian blur, px (pixel integration is added).
    """
    return np.stack([template.edge_step(s1, blur_px), template.edge_step(s2, blur_px)], axis=-1)


def _bright_pair_step(
    steps: NDArray[np.float64], samples: NDArray[np.float64], weight: NDArray[np.float64]
) -> NDArray[np.float64]:
    """(N, K, 1) the step of the bright pair's own level among :func:`_edge_steps`' two.

    The pairs' residual is (L_a - L_c)(E1 + E2) / 2 + (L_b - L_d)(E1 - E2) / 2 for
    quadrants a, b, c, d in turn (:func:`_edge_steps`); the pair a, c lies where
    E1 E2 > 0. Which pair is the bright one is read from the pairs' sums
    I(c + d) + I(c - d) (``samples``, (N, 2K), at the fit's end), weighted by
    ``weight`` (N, K): their correlation with the blurred X E1 E2 is positive
    where a and c are bright.
    """
    k = steps.shape[1]
    x = steps[..., 0] * steps[..., 1]
    total = samples[:, :k] + samples[:, k:]
    mean = (weight * total).sum(axis=1, keepdims=True) / np.maximum(
        weight.sum(axis=1, keepdims=True), 1e-12
    )
    polarity = np.where((weight * (total - mean) * x).sum(axis=1) >= 0.0, 1.0, -1.0)
    return (0.5 * (steps[..., 0] + polarity[:, None] * steps[..., 1]))[..., None]


def _edge_step_chi2(
    residual: NDArray[np.float64],
    weight: NDArray[np.float64],
    weighted: NDArray[np.float64],
    normal: NDArray[np.float64],
    steps: NDArray[np.float64],
    cell: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(N,) score statistics of the levels of ``steps``, and the (N,) RMS residual they leave.

    Where a symmetric fit ended: the drop in the weighted squared residual that
    fitting the levels of ``steps`` (N, K, S) too would give, to first order (the
    steps orthogonalised against the fit's columns), over the residual variance
    with them: chi-square with S degrees of freedom where the quadrants match
    (:func:`_edge_steps`' two, or :func:`_bright_pair_step`'s one).
    ``residual``, ``weight`` (N, K), the ``weighted`` Jacobian (N, K, P) and the
    ``normal`` matrix are the fit's at its end; ``cell`` (N,) is the area a sample
    stands for, px^2 (samples closer than a pixel share their noise).
    """
    weighted_steps = steps * weight[..., None]
    cross = weighted.transpose(0, 2, 1) @ steps
    projected = np.linalg.solve(normal + 1e-9 * np.eye(normal.shape[-1]), cross)
    reduced = weighted_steps.transpose(0, 2, 1) @ steps - cross.transpose(0, 2, 1) @ projected
    gradient = (weighted.transpose(0, 2, 1) @ residual[..., None])[..., 0]
    score = (weighted_steps.transpose(0, 2, 1) @ residual[..., None])[..., 0]
    score -= (projected.transpose(0, 2, 1) @ gradient[..., None])[..., 0]
    drop = (score[:, None, :] @ np.linalg.pinv(reduced) @ score[..., None])[:, 0, 0]
    # The variance left with the levels fitted: the symmetric fit's own residual holds
    # the misfit of the levels it lacks.
    dof = np.maximum(weight.sum(axis=1) - weighted.shape[-1] - steps.shape[-1], 1.0)
    variance = np.maximum((weight * residual**2).sum(axis=1) - drop, 1e-12) / dof
    chi2: NDArray[np.float64] = drop / variance * cell
    return chi2, np.sqrt(variance)


class _SymmetrySolution(NamedTuple):
    """What :func:`_gauss_newton_symmetry` ends with, each with the points first.

    ``step_chi2`` and ``levelled_rms`` are :func:`_edge_step_chi2` of the
    ``test_steps`` it was given (NaN without them or without the uncertainty).
    """

    centre: NDArray[np.float64]
    covariance: NDArray[np.float64]
    residual_rms: NDArray[np.float64]
    contrast: NDArray[np.float64]
    converged: NDArray[np.bool_]
    step_chi2: NDArray[np.float64]
    levelled_rms: NDArray[np.float64]


def _gauss_newton_symmetry(
    image: NDArray[Any],
    centre: NDArray[np.float64],
    offsets: NDArray[np.float64],
    taper: NDArray[np.float64],
    present: NDArray[np.bool_],
    spacing: NDArray[np.float64],
    iterations: int,
    tolerance_px: float,
    model_gain: bool,
    noise_floor: float,
    uncertainty: bool,
    edge_steps: NDArray[np.float64] | None = None,
    test_steps: NDArray[np.float64] | None = None,
    slope_prior: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
    groups: NDArray[np.intp] | None = None,
    measure_contrast: bool = True,
    bright_pair_only: bool = False,
    test_within: NDArray[np.bool_] | None = None,
) -> _SymmetrySolution:
    # ``groups`` (N,): points fitted together that end as separate calls, one per
    # group, would (a group stops when all its steps do); None: one group. Without
    # ``measure_contrast`` the contrast is NaN: the line fit reads none, and its sort
    # of every sample cost a tenth of that fit. With ``bright_pair_only`` the
    # ``test_steps`` weigh the bright pair's level alone (:func:`_bright_pair_step`);
    # with ``test_within`` (N, K) their statistic reads those pairs alone.
    n_params = 2 + 2 * model_gain + 2 * (edge_steps is not None)
    # The slope's prior (:func:`_light_inside`: its mean, and its information per square
    # pixel) enters the normal equations as pairs on this fit's grid would.
    prior = np.zeros((len(centre), n_params, n_params))
    if slope_prior is not None:
        prior[:, 2:4, 2:4] = slope_prior[1] / spacing[:, None, None] ** 2
    n = len(centre)
    centre = centre.copy()
    gain = np.zeros((n, 4))
    if slope_prior is not None:
        gain[:, :2] = slope_prior[0]
    step_norm: NDArray[np.float64] = np.full(n, np.inf)
    # The points whose centre the last step moved: only their terms change. A point
    # whose step fell below the tolerance is evaluated once more, where it stopped.
    todo: NDArray[np.intp] = np.arange(n)
    # Only the uncertainty reads the terms where the last step ends: without it, that
    # step ends the fit.
    evaluations = iterations + 1 if uncertainty or iterations == 0 else iterations
    ends = _both_ends(offsets)
    for iteration in range(evaluations):
        # Where every point is read (the first pass, and while all move), views, not copies.
        rows = slice(None) if len(todo) == n else todo
        terms = _symmetry_terms(
            image,
            centre[rows],
            gain[rows],
            (ends[0][rows], ends[1][rows]),
            taper[rows],
            model_gain,
            None if edge_steps is None else edge_steps[rows],
        )
        # Batched matrix products: three-operand einsum has no BLAS path and cost 5x.
        moved_normal = terms.weighted.transpose(0, 2, 1) @ terms.jacobian
        if len(todo) == n:
            residual, weight, jacobian, weighted, samples = terms
            normal = moved_normal
        else:
            for full, part in zip(
                (residual, weight, jacobian, weighted, samples, normal),
                (*terms, moved_normal),
                strict=True,
            ):
                full[todo] = part
        active = np.flatnonzero(step_norm > tolerance_px)
        if iteration == iterations or not len(active):
            break
        stepping = slice(None) if len(active) == n else active
        rhs = (weighted[stepping].transpose(0, 2, 1) @ residual[stepping, :, None])[..., 0]
        system = normal[stepping] + prior[stepping]
        if slope_prior is not None:
            away = gain[stepping, :2] - slope_prior[0][stepping]
            rhs[:, 2:4] += (prior[stepping, 2:4, 2:4] @ away[..., None])[..., 0]
        step = -_damped_solve(system, rhs[..., None])[..., 0]
        # A Gauss-Newton step larger than a pixel is untrustworthy this far from the optimum.
        np.clip(step[:, :2], -1.0, 1.0, out=step[:, :2])
        centre[active] += step[:, :2]
        if model_gain:
            gain[active, :2] += step[:, 2:4]
        if edge_steps is not None:
            gain[active, 2:] += step[:, -2:]
        step_norm[active] = np.hypot(step[:, 0], step[:, 1])
        todo = active
        if iteration > 0 or n_params == 2:
            # The residuals and Jacobian a last step below the tolerance away serve the
            # covariance as well as those at the end point: one evaluation fewer. Not
            # after the first step with a gain: that one moves the gain from zero.
            still = step_norm[active] > tolerance_px
            if groups is not None:
                moving = np.zeros(int(groups.max()) + 1, dtype=bool)
                moving[groups[active[still]]] = True
                todo = active[moving[groups[active]]]
            elif not still.any():
                todo = active[:0]
            if not len(todo):
                break
    converged = step_norm <= tolerance_px
    if not uncertainty:
        nan = np.full(n, np.nan)
        return _SymmetrySolution(
            centre, np.full((n, 2, 2), np.nan), nan, nan.copy(), converged, nan.copy(), nan.copy()
        )
    # Sandwich covariance of the weighted fit; residuals sampled closer than a pixel
    # are correlated, so the effective count is that of pixels, not of samples.
    w_sum = weight.sum(axis=1)
    sigma2 = (weight * residual**2).sum(axis=1) / np.maximum(w_sum - n_params, 1.0)
    residual_rms = np.sqrt(sigma2)
    sigma2 = np.maximum(sigma2, noise_floor**2)
    meat = weighted.transpose(0, 2, 1) @ weighted + prior
    bread = np.linalg.pinv(normal + prior)
    cell = np.minimum(spacing, 1.0)[:, None, None] ** 2
    covariance = (sigma2[:, None, None] * bread @ meat @ bread / cell)[:, :2, :2]
    contrast: NDArray[np.float64] = np.full(n, np.nan)
    if measure_contrast:
        contrast = _row_spread(samples, np.concatenate([present, present], axis=1))
    step_chi2: NDArray[np.float64] = np.full(n, np.nan)
    levelled_rms: NDArray[np.float64] = np.full(n, np.nan)
    if test_steps is not None:
        # From the pairs alone, the prior left out: the statistic its thresholds were set on.
        if bright_pair_only:
            test_steps = _bright_pair_step(test_steps, samples, weight)
        tested = (weight, weighted, normal)
        if test_within is not None:
            within = weighted * test_within[..., None]
            tested = (weight * test_within, within, within.transpose(0, 2, 1) @ jacobian)
        step_chi2, levelled_rms = _edge_step_chi2(residual, *tested, test_steps, cell[:, 0, 0])
    return _SymmetrySolution(
        centre, covariance, residual_rms, contrast, converged, step_chi2, levelled_rms
    )


def _row_spread(values: NDArray[np.float64], present: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Per-row 90th minus 10th percentile over the ``present`` entries, from one sort.

    Each percentile follows ``np.percentile``'s linear rule.
    """
    ordered = np.sort(np.where(present, values, np.inf), axis=1)
    count = present.sum(axis=1)
    position = np.array([[0.9], [0.1]]) * (count - 1)  # (2, N)
    low = np.floor(position).astype(np.intp)
    high = np.minimum(low + 1, ordered.shape[1] - 1)
    fraction = position - low
    below = np.take_along_axis(ordered, low.T, axis=1).T
    above = np.take_along_axis(ordered, high.T, axis=1).T
    value = below + (np.where(fraction > 0, above, below) - below) * fraction
    return cast("NDArray[np.float64]", value[0] - value[1])
