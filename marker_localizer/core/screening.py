"""Section 3.2 of the paper, first layers: candidate points and their suppression.

Two candidate generators share one output type:

* :func:`curvature_candidates`, the paper's contour-curvature corners (Eq. 4)
  with the dual threshold and the structural percentile;
* :func:`saddle_candidates`, a scale-normalised Hessian saddle response on an
  image pyramid, which keeps 3 px markers whose quadrants merge when binarised.

Both feed :func:`density_mean_shift` (Eqs. 5-6) and :func:`grid_entropy_thinning`
(Eq. 7). Coordinates are full-resolution pixels, (0, 0) at the centre of the
top-left pixel.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple, cast

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from marker_localizer.core.preprocessing import MAD_TO_STD, StructureComponents, noise_sigma


class Candidates(NamedTuple):
    """Candidate marker centres.

    Attributes:
        xy: (N, 2) float64 positions (x, y) in pixels.
        strength: (N,) float64 response, larger is more marker-like.
        scale_px: (N,) float64 characteristic radius at which the point responded.
    """

    xy: NDArray[np.float64]
    strength: NDArray[np.float64]
    scale_px: NDArray[np.float64]

    @classmethod
    def empty(cls) -> Candidates:
        """Return a set of zero candidates."""
        return cls(np.zeros((0, 2)), np.zeros(0), np.zeros(0))

    @classmethod
    def seeded(cls, xy: NDArray[np.float64], scale_px: float) -> Candidates:
        """Positions known to hold a marker (a tracked or seeded one), each at ``scale_px``.

        The strongest of candidates: they win every suppression against screened ones.
        """
        return cls(xy, np.full(len(xy), np.inf), np.full(len(xy), scale_px))

    @classmethod
    def concat(cls, parts: list[Candidates]) -> Candidates:
        """Join several candidate sets into one."""
        if not parts:
            return cls.empty()
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in cls._fields))

    def take(self, index: NDArray[np.integer[Any] | np.bool_]) -> Candidates:
        """Return the candidates selected by a boolean mask or index array."""
        # One scan of a mask for the three arrays, and gathers that do not branch on
        # it (a third of boolean indexing's time on 10^5 points).
        rows = cast("NDArray[np.intp]", np.flatnonzero(index) if index.dtype == np.bool_ else index)
        return Candidates(
            self.xy.take(rows, axis=0), self.strength.take(rows), self.scale_px.take(rows)
        )

    def moved(self, index: NDArray[np.intp], xy: NDArray[np.float64]) -> Candidates:
        """The same candidates with those ``index`` moved to ``xy`` (K, 2)."""
        positions = self.xy.copy()
        positions[index] = xy
        return Candidates(positions, self.strength, self.scale_px)

    def strongest(self, limit: int) -> Candidates:
        """The ``limit`` strongest candidates (all when there are no more), in their order.

        Of equally strong candidates at the limit, the first are kept.
        """
        if len(self) <= limit:
            return self
        if np.isnan(self.strength).any():
            return self.take(np.sort(np.argsort(-self.strength, kind="stable")[:limit]))
        # One selection instead of a sort of all (a tenth of its time on 45 000).
        rank = len(self) - limit
        weakest = np.partition(self.strength, rank)[rank]
        keep = self.strength > weakest
        keep[np.flatnonzero(self.strength == weakest)[: limit - np.count_nonzero(keep)]] = True
        return self.take(keep)

    def without_duplicates(self, radius_px: float) -> tuple[Candidates, int]:
        """One candidate per X: those with no stronger one within ``radius_px``.

        :func:`non_maximum_suppression`, each candidate merged into the nearest one kept,
        which takes the widest scale of those merged into it: the levels whose saddles
        fell together on one X all found it, and the widest says which readings it is
        owed (:func:`~marker_localizer.core.second_reading.screened_wide`). A marker of
        12 px with a dull bright quadrant, from a 6 px minimum, is screened at the first
        two levels searched, and the first level's candidate is the stronger and the
        narrower: it lost the equalised rings, and the marker (docs/accuracy-journal.md,
        "A duplicate merged at the centring keeps its widest level").

        Returns:
            The candidates kept, in their order, and how many were merged into them.
        """
        kept = self.take(non_maximum_suppression(self.xy, self.strength, radius_px))
        merged = len(self) - len(kept)
        if merged:
            _, owner = cKDTree(kept.xy).query(self.xy)
            scale = np.zeros(len(kept))
            np.maximum.at(scale, owner, self.scale_px)
            kept = Candidates(kept.xy, kept.strength, scale)
        return kept, merged

    def __len__(self) -> int:
        return int(self.strength.shape[0])


def parabolic_offset(
    minus: NDArray[np.floating[Any]],
    centre: NDArray[np.floating[Any]],
    plus: NDArray[np.floating[Any]],
) -> NDArray[np.floating[Any]]:
    """Sub-sample vertex of a parabola through three samples, clipped to half a sample."""
    curvature = minus - 2.0 * centre + plus
    with np.errstate(divide="ignore", invalid="ignore"):
        offset = np.where(curvature < 0, 0.5 * (minus - plus) / curvature, 0.0)
    return np.clip(offset, -0.5, 0.5)


#: (row, column) offsets of the eight neighbours a peak's refinement reads: left, right,
#: above and below first (the parabolas'), then the diagonals.
_NEIGHBOURS: tuple[tuple[int, int], ...] = (
    (0, -1),
    (0, 1),
    (-1, 0),
    (1, 0),
    (-1, -1),
    (-1, 1),
    (1, -1),
    (1, 1),
)
#: A peak whose lowest edge neighbour's response is at most this share of its own is
#: narrower than the grid samples (a Gaussian of sigma 0.6 px or less): a parabola
#: through three samples falls short of its vertex (by half of a 0.3 px offset at
#: sigma 0.5), the centroid of the positive response over the 3x3 much less.
NARROW_PEAK_SHARE = 0.25


def _neighbour_steps(width: int) -> list[int]:
    """Flat index steps to :data:`_NEIGHBOURS` in rows of ``width``."""
    return [d_row * width + d_col for d_row, d_col in _NEIGHBOURS]


def peak_offset(
    centre: NDArray[np.floating[Any]],
    neighbours: NDArray[np.floating[Any]],
    narrow_by_centroid: bool = True,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(dx, dy) sub-sample offsets of 3x3 response peaks, within half a sample.

    A parabola per axis where the peak is at least as wide as the grid; where an edge
    neighbour falls to :data:`NARROW_PEAK_SHARE` of the peak or under (and
    ``narrow_by_centroid``), the centroid of the positive response over the 3x3.

    Args:
        centre: (N,) the peaks' responses.
        neighbours: (N, 8) the responses at :data:`_NEIGHBOURS`.
        narrow_by_centroid: place narrow peaks at their centroid; False: parabolas
            for every peak.
    """
    left, right, up, down = neighbours[:, :4].T
    dx = parabolic_offset(left, centre, right).astype(np.float64)
    dy = parabolic_offset(up, centre, down).astype(np.float64)
    narrow = narrow_by_centroid & (neighbours[:, :4].min(axis=1) <= NARROW_PEAK_SHARE * centre)
    if narrow.any():
        weight = np.maximum(neighbours[narrow].astype(np.float64), 0.0)
        total = weight.sum(axis=1) + centre[narrow]
        columns = np.array([d_col for _, d_col in _NEIGHBOURS], np.float64)
        rows = np.array([d_row for d_row, _ in _NEIGHBOURS], np.float64)
        dx[narrow] = np.clip(weight @ columns / total, -0.5, 0.5)
        dy[narrow] = np.clip(weight @ rows / total, -0.5, 0.5)
    return dx, dy


#: Gain of OpenCV's 5x5 Sobel second-derivative kernels (f_xx, f_yy, f_xy alike):
#: [1 0 -2 0 1] (4 f'') times the [1 4 6 4 1] smoothing (16).
_SOBEL5_GAIN = 64.0
#: OpenCV's 5x5 Sobel kernels along one axis (:func:`cv2.getDerivKernels`): the second
#: derivative's [1 0 -2 0 1], the smoothing across it [1 4 6 4 1], the first derivative's
#: [-1 -2 0 2 1].
_SOBEL5_SECOND, _SOBEL5_SMOOTHING = cv2.getDerivKernels(2, 0, 5, ktype=cv2.CV_32F)
_SOBEL5_FIRST = cv2.getDerivKernels(1, 0, 5, ktype=cv2.CV_32F)[0]
#: Saddle strength of a blurred X per unit contrast: f_xy = C / (pi sigma_t^2) at
#: its centre, sigma_t^2 = 1 px^2 (the 5x5 kernel's smoothing) + sigma_b^2 (the blur).
_SADDLE_PER_CONTRAST = 1.0 / np.pi
#: The optics blur the markers are expected to carry (full-resolution px): at level L
#: it is 2**L times smaller, so the expected response grows with the level.
EXPECTED_BLUR_PX = 1.5


#: The shorter side of a pyramid level under which it is not reduced further, px: a
#: coarser level would hold a few of its filters' widths.
_MIN_REDUCED_SIDE_PX = 32
#: Farthest apart two saddle peaks of a split response may be, in units of the level's
#: candidate scale: a 6 px marker tilted 48 degrees shows its peaks 10.6 px apart at
#: scale 6; 2.5 scales keeps the like of it at every first level.
_SPLIT_PEAK_DISTANCE = 2.5
#: Largest strength ratio of such a pair: the two peaks of a point-symmetric response
#: are equal but for noise.
_SPLIT_PEAK_RATIO = 1.5


#: r of Eq. (4), in contour points (~px): the displacement vectors span 3 points either
#: side, short enough to stay on one edge of the smallest marker, long enough that
#: the turn of the sub-pixel level line is measured over more than its noise.
CURVATURE_WINDOW_PX = 3
#: Contour points the dual threshold's statistics read at most (a regular sample).
_STATISTICS_SAMPLE = 250_000
#: Longest Newton step of a contour pixel onto the level line, px: a pixel on the
#: boundary is within a pixel of it, and near the X centre (no gradient) the step
#: must not fly off.
_LEVEL_STEP_PX = 0.75
#: The dual threshold never asks for more than the curvature of a 60-degree turn: of
#: the two sectors meeting at an X centre one turns by 90 degrees or more (a 60-degree
#: tilt leaves 53-127 degree sectors), blurred apexes measure 0.5-1.0, and a frame
#: holding little but markers has statistics made of their own corners and arcs.
_MAX_CURVATURE_THRESHOLD = 1.0 - np.cos(np.deg2rad(60.0))
#: epsilon of Eq. (4): keeps the ratio finite where a displacement vector vanishes.
_CURVATURE_EPS = 1e-9
#: The contours' contrast floor in units of the frame's noise sigma, when that is
#: higher than the configured contrast: the noise-aware part of the connected-domain
#: check (a noisy frame would otherwise fill the statistics of Eq. 4 with noise).
_NOISE_CONTRAST_FACTOR = 6.0
#: Connected domains smaller than this fraction of the smallest marker's quadrant
#: (a quarter disk of radius r_min) are noise: a 60-degree tilt halves a quadrant.
_MIN_DOMAIN_QUADRANT_FRACTION = 0.25

#: ``scale_px`` of the full-resolution level's candidates, px; level L's is 2**L times it.
LEVEL_SCALE_PX = 4.0
#: Smallest half-width (level px) of a foreshortened marker at the first level searched:
#: below ~1.5 px the 5x5 Sobel kernels' smoothing mixes the quadrants with the plate.
MIN_LEVEL_RADIUS_PX = 1.5
#: Largest half-width (level px) a level answers to best: the last level searched is
#: the first at which the largest marker is no wider.
MAX_LEVEL_RADIUS_PX = 6.0


def saddle_response(image: NDArray[Any]) -> NDArray[np.float32]:
    """Squared saddle strength f_xy^2 - f_xx f_yy (= -det H) from 5x5 Sobel derivatives.

    The 5x5 Sobel kernels smooth with a binomial of variance 1 px^2, so no
    separate Gaussian pass is needed. The response is in the image's own grey
    units per px^2 (times the kernels' gain), so a threshold in DN of contrast
    applies directly, with no per-pixel normalisation pass.

    Args:
        image: (H, W) uint8, uint16 or float32 image.

    Returns:
        (H, W) float32 response, positive at saddles (squared grey units).
    """
    if image.dtype.kind in "ui" and image.dtype.itemsize <= 2:
        # The kernels' two passes read the integer image itself, which costs half of
        # Sobel's passes over a float32 copy. Every sum is an integer below 2^24, exact
        # in float32, so the derivatives are Sobel's bit for bit.
        minus_dxx = cv2.sepFilter2D(image, cv2.CV_32F, -_SOBEL5_SECOND, _SOBEL5_SMOOTHING)
        dyy = cv2.sepFilter2D(image, cv2.CV_32F, _SOBEL5_SMOOTHING, _SOBEL5_SECOND)
        dxy = cv2.sepFilter2D(image, cv2.CV_32F, _SOBEL5_FIRST, _SOBEL5_FIRST)
    else:
        minus_dxx = cv2.Sobel(image, cv2.CV_32F, 2, 0, ksize=5, scale=-1.0)
        dyy = cv2.Sobel(image, cv2.CV_32F, 0, 2, ksize=5)
        dxy = cv2.Sobel(image, cv2.CV_32F, 1, 1, ksize=5)
    # In place with OpenCV: numpy temporaries would double the passes over 12 MP, and
    # adding the product of -f_xx and f_yy saves the subtraction's pass.
    cv2.multiply(dxy, dxy, dst=dxy)
    cv2.accumulateProduct(minus_dxx, dyy, dxy)
    return cast("NDArray[np.float32]", dxy)


#: The ground's square ring about a point whose saddle response :func:`saddle_over_ground`
#: averages: inner and outer half-sides, px. Past the plate of an X of texture's size (a
#: marker of 5 px and its plate reach 7-8 px), and wide enough for some 3 800 pixels of
#: ground.
GROUND_RING_HALF_SIDES_PX = (10, 32)
#: The rows and columns the 5x5 derivatives of :func:`saddle_response` read beyond the
#: pixel they are at, px.
_SADDLE_KERNEL_REACH_PX = 2
#: Points whose windows :func:`saddle_over_ground` lays into one image: under 1 MiB for
#: each of the response's float32 derivatives, which stay in a core's own cache from one
#: filter pass to the next (a frame of real aerial ground asks over a thousand points;
#: laid 256 at a time, 5 MiB an array, they cost 1.6 times as much).
_GROUND_WINDOWS_PER_PASS = 48


def saddle_over_ground(gray: NDArray[Any], xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N,) each point's saddle response over the mean saddle response of its ground.

    With R the saddle response (:func:`saddle_response`) and (x, y) the point's nearest
    pixel, the ratio is

        max_{|dx|, |dy| <= 1} R(x + dx, y + dy)  /  mean_{(u, v) in ring} max(R(u, v), 0)

    where the ring is the square annulus r_in < max(|u - x|, |v - y|) <= r_out of
    :data:`GROUND_RING_HALF_SIDES_PX`. R is a squared contrast, so the ratio is one of
    squared contrasts, which the light and the exposure do not change: a local
    constant-false-alarm-rate reading of the saddle against the ground it lies on.
    Infinite where the ground is flat and the point is not. Not a number where the ring
    or the kernels' reach about it leaves the frame: the frame shows only part of that
    ground, and of an X there, and a mirror image would repeat the X's own
    neighbourhood in place of the rest.

    Each point's window (its ring and the kernels' reach) is cut from the frame and the
    windows are laid side by side into one image of the window's height, whose response
    is computed in one pass: the pixels a window reads at its centre and on its ring lie
    within it, so its neighbours do not reach them. The ring's sum is that of its outer
    box less its inner one, each from the column sums over the box's rows.

    Args:
        gray: (H, W) grey image, raw levels (uint8, uint16 or float).
        xy: (N, 2) points, px.
    """
    inner, outer = GROUND_RING_HALF_SIDES_PX
    reach = outer + _SADDLE_KERNEL_REACH_PX
    side = 2 * reach + 1
    height, width = gray.shape
    corner = np.rint(np.asarray(xy, np.float64).reshape(-1, 2)).astype(np.int64) - reach
    seen = np.flatnonzero(
        (corner[:, 0] >= 0)
        & (corner[:, 1] >= 0)
        & (corner[:, 0] + side <= width)
        & (corner[:, 1] + side <= height)
    )
    ratio = np.full(len(corner), np.nan)
    if len(seen) == 0:
        return ratio
    view = np.lib.stride_tricks.sliding_window_view(gray, (side, side))
    at = slice(reach - 1, reach + 2)
    ring_area = (2 * outer + 1) ** 2 - (2 * inner + 1) ** 2
    for first in range(0, len(seen), _GROUND_WINDOWS_PER_PASS):
        part = seen[first : first + _GROUND_WINDOWS_PER_PASS]
        count = len(part)
        laid = view[corner[part, 1], corner[part, 0]].transpose(1, 0, 2).reshape(side, -1)
        response = saddle_response(laid.astype(np.float32) if gray.dtype.kind == "f" else laid)
        peak = response[at].reshape(3, count, side)[:, :, at].max(axis=(0, 2))
        ground = np.maximum(response, 0.0, out=response)
        box_sums = []
        for half_side in (outer, inner):
            box = slice(reach - half_side, reach + half_side + 1)
            columns = ground[box].sum(axis=0).reshape(count, side)
            box_sums.append(columns[:, box].sum(axis=1, dtype=np.float64))
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio[part] = peak * ring_area / (box_sums[0] - box_sums[1])
    return ratio


#: Share of a level's pixels above the threshold from which its 3x3 maxima are found
#: with one dilation of the whole level instead of eight neighbour look-ups per pixel
#: above it (a gather costs ~10x a dilated pixel, measured on 8 MP). On real sand at
#: radius 3-30 px a third of the full-resolution level is above it, in a friendly frame
#: under a hundredth.
_DENSE_MAXIMA_SHARE = 1.0 / 16.0
#: (row, column) offsets of the neighbours that come before a pixel in raster order (a
#: tie with one of them goes to it), and of those after it.
_PRECEDING_NEIGHBOURS: tuple[tuple[int, int], ...] = ((-1, -1), (-1, 0), (-1, 1), (0, -1))
_FOLLOWING_NEIGHBOURS: tuple[tuple[int, int], ...] = ((0, 1), (1, -1), (1, 0), (1, 1))
_MAXIMUM_KERNEL = np.ones((3, 3), np.uint8)


def _local_maxima(
    response: NDArray[np.floating[Any]], threshold: float | NDArray[np.floating[Any]]
) -> tuple[NDArray[np.intp], NDArray[np.floating[Any]]]:
    """Flat indices and values of the 3x3 local maxima above ``threshold``, off the border.

    ``threshold`` is one value, an (H, 1) column of one per row, or (H, W) one per pixel.

    Ties go to the first pixel in raster order, so a plateau yields one peak. When
    few pixels are above the threshold (a friendly frame) only they are compared
    with their eight neighbours; when many are (busy ground, noise) one dilation
    finds the pixels no neighbour exceeds, and only the ties with the neighbours
    before them are looked up. Both give the same peaks.
    """
    return _maxima_among(response, response > threshold)


def _maxima_among(
    response: NDArray[np.floating[Any]], above: NDArray[np.bool_]
) -> tuple[NDArray[np.intp], NDArray[np.floating[Any]]]:
    """:func:`_local_maxima` of the pixels ``above`` the threshold.

    ``above`` is the response's mask over the threshold; its border is cleared here.
    """
    width = response.shape[1]
    # Border pixels lack neighbours: none is a peak.
    above[0] = above[-1] = False
    above[:, 0] = above[:, -1] = False
    dense = np.count_nonzero(above) > _DENSE_MAXIMA_SHARE * response.size
    if dense:
        above &= response >= cv2.dilate(response, _MAXIMUM_KERNEL)
    flat_index = np.flatnonzero(above)
    flat = response.reshape(-1)
    centre = flat[flat_index]
    # No neighbour before the pixel equals it (those after it may not exceed it).
    is_max = np.ones(len(flat_index), dtype=bool)
    for d_row, d_col in _PRECEDING_NEIGHBOURS:
        neighbour = flat[flat_index + (d_row * width + d_col)]
        is_max &= centre > neighbour
    if not dense:
        for d_row, d_col in _FOLLOWING_NEIGHBOURS:
            is_max &= centre >= flat[flat_index + (d_row * width + d_col)]
    return cast("NDArray[np.intp]", flat_index[is_max]), centre[is_max]


#: Image rows whose saddle response and maxima are found at a time: a strip's
#: temporaries (three derivative images and the dilation, up to 1 MiB each for
#: 4096-px rows, and the masks) stay in the processor's cache between the passes and
#: are reused, where whole-level ones (32 MiB each at 8 MP) go through memory and
#: fresh pages on every pass. 64-128 rows screen 8 MP real frames fastest.
_STRIP_ROWS = 64
#: Fewest pixels of a strip, 64 rows of 512 px: each strip pays a few dozen calls
#: (~0.1 ms), which a narrow image's strips of 64 rows do not outweigh (a tracked
#: frame's side bands). Wider images keep their 64 rows: the strips a level's
#: strongest peaks are first sought in (:func:`saddle_peaks`) are then those of the
#: full-frame passes measured.
_STRIP_MIN_PIXELS = 64 * 512
#: Rows beyond a strip that its response and maxima read: the maxima compare with one
#: row of response either side, which the 5x5 kernels compute from two more.
_STRIP_HALO_ROWS = 3
#: Columns of a level (or its window) that share one threshold lowered by the shadow's
#: gain, px: the gain's bound over such a span (:attr:`LightWeight.on_spans`) instead
#: of over the whole row. Where the light falls across the frame every row holds a
#: dark stretch: speed frame 2's first level listed 53 218 peaks to keep 3 040 with
#: one threshold a row, 4 422 with one a span of 64 px.
_SHADOW_SPAN_PX = 64


def _spread(threshold: float | NDArray[np.float32], width: int) -> float | NDArray[np.float32]:
    """A threshold as a response ``width`` px wide compares with it.

    A scalar or an (h, 1) column as it is; (h, S) spans of :data:`_SHADOW_SPAN_PX`
    columns as (h, width).
    """
    if np.ndim(threshold) == 2 and np.shape(threshold)[1] > 1:
        # One broadcast copy, a fifth faster than np.repeat's copy of each value.
        rows, spans = np.shape(threshold)
        spread = np.empty((rows, spans, _SHADOW_SPAN_PX), np.asarray(threshold).dtype)
        spread[...] = np.asarray(threshold)[:, :, None]
        return spread.reshape(rows, -1)[:, :width]
    return threshold


def _limit(
    threshold: float | NDArray[np.float32],
    bound: float,
    lift: NDArray[np.float32] | None = None,
) -> float | NDArray[np.float32]:
    """What a response must exceed to pass ``threshold`` and reach ``bound`` (0: none).

    ``threshold`` is one value, a column of one per row, or one per row and span.
    ``lift``: (h, S) a bound on the squared weight of the light on each row and span
    (:class:`LightWeight`), or None (1): ``bound`` is on the weighed response, which
    a raw one reaches from ``bound`` over that weight up.
    """
    if np.ndim(threshold) and threshold.min() == threshold.max():  # type: ignore[union-attr]
        # Rows of one bound (in the open, or evenly dark) compare with a scalar.
        threshold = float(threshold[0, 0])  # type: ignore[index]
    if bound <= 0:
        return threshold
    # At least the bound is more than the float32 just below it.
    below = float(np.nextafter(np.float32(bound), np.float32(0)))
    if lift is not None:
        weighed = (below * _LIFT_BOUND_SLACK / lift).astype(np.float32)
        return np.maximum(threshold, weighed)
    return (
        np.maximum(threshold, below) if np.ndim(threshold) else max(cast(float, threshold), below)
    )


def _unexamined(
    response: NDArray[np.float32],
    threshold: float | NDArray[np.float32],
    bound: float,
    lift: NDArray[np.float32] | None = None,
    examined: int | None = None,
) -> int:
    """Pixels of ``response`` above ``threshold`` (per row, or row and span) but below ``bound``.

    ``lift`` as for :func:`_limit`; ``examined``, the pixels over the bound where the
    caller has counted them already.
    """
    if bound <= 0:
        return 0
    width = response.shape[1]
    if examined is None:
        examined = np.count_nonzero(response > _spread(_limit(threshold, bound, lift), width))
    return int(np.count_nonzero(response > _spread(threshold, width)) - examined)


class _Strip(NamedTuple):
    """The peaks of one strip of a level's saddle response (:func:`_strip_peaks`).

    Attributes:
        flat_index: (N,) ascending flat indices in the level of the peaks of at
            least the bound.
        values: (N,) their responses.
        neighbours: (N, 8) float32 responses of the pixels around each, in the
            order of :data:`_NEIGHBOURS`.
        unexamined: the strip's pixels above the threshold but below the bound.
        response: the strip's own rows of response, where kept (a sampled strip's,
            to count them again); None: dropped, so that the next strip reuses the
            memory while it is in the cache.
        lift: (N,) the bound on the light's squared weight at each peak, which the
            bound is compared with its value times; None: 1 (:func:`saddle_peaks`).
    """

    flat_index: NDArray[np.intp]
    values: NDArray[np.float32]
    neighbours: NDArray[np.float32]
    unexamined: int
    response: NDArray[np.float32] | None
    lift: NDArray[np.float32] | None = None

    def weighed(self) -> NDArray[np.float32]:
        """(N,) the peaks' responses times their ``lift``: what bounds are compared with."""
        return self.values if self.lift is None else self.values * self.lift

    def above(
        self,
        bound: float,
        threshold: float | NDArray[np.float32],
        lift: NDArray[np.float32] | None = None,
    ) -> _Strip:
        """These peaks of at least ``bound`` (the response kept).

        ``threshold`` and ``lift`` are the strip's rows' (:func:`_strip_peaks`).
        """
        strong = self.weighed() >= bound
        return _Strip(
            self.flat_index[strong],
            self.values[strong],
            self.neighbours[strong],
            _unexamined(cast("NDArray[np.float32]", self.response), threshold, bound, lift),
            None,
            None if self.lift is None else self.lift[strong],
        )


def _strip_rows(width: int) -> int:
    """Rows of a strip of an image ``width`` px wide: :data:`_STRIP_ROWS`, or more when narrow."""
    return max(_STRIP_ROWS, _STRIP_MIN_PIXELS // width)


def _strip_peaks(
    image: NDArray[Any],
    rows: slice,
    threshold: float | NDArray[np.float32],
    bound: float,
    keep_response: bool = False,
    lift: NDArray[np.float32] | None = None,
) -> _Strip:
    """The saddle response of a strip of ``image``, its ``rows``, and its peaks.

    Args:
        image: (H, W) image.
        rows: the strip's rows (a slice with its start and stop).
        threshold: the squared saddle strength a peak exceeds; or an (H, 1) column, or
            (H, S) one per row and span of :data:`_SHADOW_SPAN_PX` columns.
        bound: only the peaks of at least this response (times ``lift``) are wanted
            (0: all).
        keep_response: keep the strip's response in the result.
        lift: (H, S) the bound on the light's squared weight on each row and span
            (:class:`LightWeight`); None: 1.
    """
    height, width = image.shape
    start, stop = rows.start, min(rows.stop, height)
    first, last = max(start - _STRIP_HALO_ROWS, 0), min(stop + _STRIP_HALO_ROWS, height)
    strip = saddle_response(image[first:last])
    # The strip's response with one row either side (none at the image's edges).
    above, below = max(start - 1, 0), min(stop + 1, height)
    compared = threshold if np.ndim(threshold) == 0 else threshold[above:below]  # type: ignore[index]
    near = None if lift is None else lift[above:below]
    limit = _spread(_limit(compared, bound, near), width)
    searched = strip[above - first : below - first]
    over_limit = searched > limit
    # The strip's own rows' pixels over the limit, counted before the border is cleared,
    # so that _unexamined need not compare them with it again.
    examined = np.count_nonzero(over_limit[start - above : stop - above]) if bound > 0 else 0
    local, value = _maxima_among(searched, over_limit)
    # The neighbours the peaks' sub-pixel refinement reads, while the strip is at hand.
    flat = strip[above - first :].reshape(-1)
    neighbours = np.stack([flat[local + step] for step in _neighbour_steps(width)], axis=1)
    own = threshold if np.ndim(threshold) == 0 else threshold[start:stop]  # type: ignore[index]
    peak_lift = None
    if near is not None:
        row, column = np.divmod(local, width)
        peak_lift = near[row, column // _SHADOW_SPAN_PX]
    response = strip[start - first : stop - first]
    return _Strip(
        local + above * width,
        value,
        neighbours,
        _unexamined(response, own, bound, examined=examined),
        response.copy() if keep_response else None,
        peak_lift,
    )


#: Every how many-th strip of a level is searched for all its peaks first when only
#: its strongest are wanted (:func:`saddle_peaks`): their responses set the bound.
_SAMPLE_STRIP_STRIDE = 8
#: The bound is the response of the peak this many times the wanted share down the
#: sample's ranks: a sample richer in strong peaks than the level still leaves
#: enough above it.
_SAMPLE_RANK_MARGIN = 1.5


class SaddlePeaks(NamedTuple):
    """What :func:`saddle_peaks` finds on one image.

    Attributes:
        shape: (H, W) of the image.
        flat_index: (N,) ascending flat indices of the peaks listed.
        values: (N,) their responses.
        neighbours: (N, 8) float32 responses of the pixels around each, in the
            order of :data:`_NEIGHBOURS`.
        bound: every peak of at least this response (times the ``lift`` it was
            listed with, :func:`saddle_peaks`) is listed (0: every peak).
        unexamined: pixels above the threshold but below the bound, never
            compared with their neighbours.
    """

    shape: tuple[int, int]
    flat_index: NDArray[np.intp]
    values: NDArray[np.float32]
    neighbours: NDArray[np.float32]
    bound: float
    unexamined: int


def saddle_peaks(
    image: NDArray[Any],
    threshold: float | NDArray[np.float32],
    *,
    strongest: int | None = None,
    at_least: float = 0.0,
    lift: NDArray[np.float32] | None = None,
) -> SaddlePeaks:
    """The saddle response of ``image`` and its 3x3 maxima above ``threshold``.

    Equal to :func:`saddle_response` and :func:`_local_maxima` over the whole
    image, found strip by strip: each strip is filtered with the rows its
    kernels reach beyond it, so no strip edge is treated as an image border.

    Where only the strongest peaks are wanted, every eighth strip is searched
    first; the response of the peak ranked 1.5 ``strongest`` / 8 among theirs
    becomes the bound, and the other strips are searched above it alone: a pixel
    below it is not compared with its neighbours (on busy ground most pixels
    above the threshold are). Every peak of at least the bound is listed, so the
    strongest are among them however the sample ranks them.

    Args:
        image: (H, W) uint8, uint16 or float32 image.
        threshold: the smallest squared saddle strength of a peak, exclusive; or
            (H,) one per row, or (H, S) one per row and span of :data:`_SHADOW_SPAN_PX`
            columns.
        strongest: how many of the strongest peaks are wanted (about 1.5 times as
            many are listed); None: all.
        at_least: only peaks of at least this response are wanted.
        lift: (H, S) a bound on the light's squared weight on each row and span of
            :data:`_SHADOW_SPAN_PX` columns (:class:`LightWeight`): the strongest
            peaks and ``at_least`` are those of the responses times it; None: 1.

    Returns:
        :class:`SaddlePeaks` (the response itself is not kept: the refinement of
        the peaks reads their neighbours alone, and a level's worth of it costs
        a write of 32 MiB on 8 MP).
    """
    height, width = image.shape
    if np.ndim(threshold):
        threshold = np.asarray(threshold, np.float32).reshape(height, -1)
    if lift is not None:
        lift = np.asarray(lift, np.float32).reshape(height, -1)
    step = _strip_rows(width)
    strip_rows = [slice(start, min(start + step, height)) for start in range(0, height, step)]
    found = {}
    bound = at_least
    if strongest is not None:
        sampled = range(0, len(strip_rows), _SAMPLE_STRIP_STRIDE)
        found = {
            k: _strip_peaks(image, strip_rows[k], threshold, bound, True, lift) for k in sampled
        }
        values = np.concatenate([np.zeros(0, np.float32), *(found[k].weighed() for k in sampled)])
        # At least the sample's strongest, however few are wanted of a frame.
        rank = max(1, int(_SAMPLE_RANK_MARGIN * strongest * len(sampled) / len(strip_rows)))
        if len(values) > rank:
            bound = max(bound, float(np.partition(values, len(values) - rank)[len(values) - rank]))
            for k in sampled:
                rows = strip_rows[k]
                own = threshold if np.ndim(threshold) == 0 else threshold[rows]  # type: ignore[index]
                found[k] = found[k].above(bound, own, None if lift is None else lift[rows])
    strips = [
        found[k] if k in found else _strip_peaks(image, rows, threshold, bound, lift=lift)
        for k, rows in enumerate(strip_rows)
    ]
    return SaddlePeaks(
        (height, width),
        np.concatenate([np.zeros(0, np.intp), *(strip.flat_index for strip in strips)]),
        np.concatenate([np.zeros(0, np.float32), *(strip.values for strip in strips)]),
        np.concatenate(
            [np.zeros((0, len(_NEIGHBOURS)), np.float32), *(strip.neighbours for strip in strips)]
        ),
        bound,
        sum(strip.unexamined for strip in strips),
    )


def split_peak_midpoints(
    candidates: Candidates, max_distance_px: float, max_ratio: float = _SPLIT_PEAK_RATIO
) -> Candidates:
    """Midpoints of candidate pairs that may be the two halves of one split saddle peak.

    A marker narrower than the Sobel kernels' smoothing (a tilted marker near the
    smallest expected radius) gives no saddle at its centre: the response peaks
    on either side of it instead. The response of a point-symmetric pattern is
    point-symmetric too, so such peaks come in pairs of equal strength about the
    centre, and their midpoint is a candidate there (the prescreen and the
    centring that follow decide as for any other).

    Args:
        candidates: one level's candidates.
        max_distance_px: farthest apart two peaks of a pair may be.
        max_ratio: largest ratio of their strengths.

    Returns:
        One candidate per pair, with the weaker strength and the first's scale.
    """
    if len(candidates) < 2:
        return Candidates.empty()
    pairs = cKDTree(candidates.xy).query_pairs(max_distance_px, output_type="ndarray")
    if len(pairs) == 0:
        return Candidates.empty()
    # Gathers by index (take), each array once: tens of thousands of pairs on busy ground.
    i, j = pairs.T
    first, second = candidates.strength.take(i), candidates.strength.take(j)
    alike = np.flatnonzero(np.maximum(first, second) <= max_ratio * np.minimum(first, second))
    i, j = i.take(alike), j.take(alike)
    midpoints = candidates.xy.take(i, axis=0)
    midpoints += candidates.xy.take(j, axis=0)
    midpoints *= 0.5
    return Candidates(
        midpoints,
        np.minimum(first.take(alike), second.take(alike)),
        candidates.scale_px.take(i),
    )


def saddle_levels(radius_range_px: tuple[float, float]) -> range:
    """Pyramid levels searched for markers of the given radius range.

    Level L (image reduced by 2**L) answers best to markers of radius ~2-6 px at
    that level (2**L * (2..6) px in the frame). The first level is the coarsest
    at which the smallest marker, foreshortened to half its radius by a 60-degree
    tilt, still spans :data:`MIN_LEVEL_RADIUS_PX`, so only frames of markers
    under ~6 px are searched at full resolution (the other levels together cost
    a third of that one). At least two levels are searched where the largest
    marker is wider than the full-resolution level answers to best
    (:data:`MAX_LEVEL_RADIUS_PX`): a response peaking between two levels, as
    chessboard corners crowded by their neighbours do, is then seen at the finer
    one. A range of tiny markers (a largest radius of 6 px or less) is searched at
    full resolution only: level 1 as well finds 3 more of family (b)'s 1 152
    markers on development frames, and takes 60-75 % longer on real aerial ground
    at 2.5-5 px (docs/accuracy-journal.md, "Item 5 on every family").
    """
    r_min, r_max = radius_range_px
    foreshortened = 0.5 * r_min
    last = max(0, int(np.ceil(np.log2(max(r_max, 1.0) / MAX_LEVEL_RADIUS_PX))))
    first = max(0, int(np.floor(np.log2(max(foreshortened, 1.0) / MIN_LEVEL_RADIUS_PX))))
    return range(min(first, max(last - 1, 0)), last + 1)


#: Level pixels a peak must lie inside a cropped response for it to equal the whole
#: image's: the 5x5 kernels' reach (2), the 3x3 maximum and the parabola (1 more).
_RESPONSE_REACH_PX = 3


def _level_window(
    window: tuple[int, int, int, int] | None, level: int, shape: tuple[int, ...]
) -> tuple[int, int, int, int]:
    """(u0, v0, u1, v1): the part of a level's image whose response finds ``window``'s peaks.

    Full-resolution x maps to level u = (x + 0.5) / 2**L - 0.5; the window is grown
    by the filters' reach, and one more pixel than that lets a peak on the edge of
    the crop be compared with its neighbours.
    """
    height, width = shape[:2]
    if window is None:
        return 0, 0, width, height
    x0, y0, x1, y1 = window
    scale = 2.0**level
    grow = _RESPONSE_REACH_PX + 1
    u0 = max(int(np.floor((x0 + 0.5) / scale - 0.5)) - grow, 0)
    v0 = max(int(np.floor((y0 + 0.5) / scale - 0.5)) - grow, 0)
    u1 = min(int(np.ceil((x1 + 0.5) / scale - 0.5)) + grow + 1, width)
    v1 = min(int(np.ceil((y1 + 0.5) / scale - 0.5)) + grow + 1, height)
    return u0, v0, max(u1, u0), max(v1, v0)


def candidate_scale(level: int, radius_range_px: tuple[float, float]) -> float:
    """``scale_px`` of the candidates found at pyramid ``level``: 4 * 2**L px.

    The first level searched also holds markers smaller than its typical radius,
    down to the smallest expected: their centre checks must fit inside them.
    """
    scale = LEVEL_SCALE_PX * 2**level
    if level == saddle_levels(radius_range_px).start:
        scale = min(scale, max(radius_range_px[0], LEVEL_SCALE_PX))
    return cast("float", scale)


def level_scale_within(extent_px: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N,) the scale 4 * 2**L of the coarsest level whose scale is not over ``extent_px``, px.

    Where a full pass screens a marker of that extent (an extent under the full
    resolution's scale: that scale).
    """
    octaves = np.floor(np.log2(np.maximum(extent_px, LEVEL_SCALE_PX) / LEVEL_SCALE_PX))
    return cast("NDArray[np.float64]", LEVEL_SCALE_PX * 2.0**octaves)


def level_scale(scale_px: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N,) the scale 4 * 2**L of the level that found candidates of ``scale_px``, px.

    :func:`candidate_scale` caps the first level's scale at the smallest expected
    radius, which is at least 3/4 of it (that level still spans the radius
    foreshortened by a 60-degree tilt), so the level's own scale is the next at or
    above. A scale under the full resolution's (no level gives one) is its own.
    """
    octaves = np.ceil(np.log2(np.maximum(scale_px, LEVEL_SCALE_PX) / LEVEL_SCALE_PX))
    return cast(
        "NDArray[np.float64]",
        np.where(scale_px > LEVEL_SCALE_PX, LEVEL_SCALE_PX * 2.0**octaves, scale_px),
    )


class CellCap(NamedTuple):
    """Eq. (7)'s thinning as a cap per grid cell (:func:`grid_entropy_thinning`).

    Attributes:
        cell_px: grid cell size, px.
        max_per_cell: the most points a cell keeps, the strongest.
        max_total: the cap that follows on all cells' points together, the
            strongest (``max_candidates``); None: none.
        origin_px: (x, y) position in the frame of the image's pixel (0, 0) (a
            window's corner), so that the cells are the frame's.
    """

    cell_px: float
    max_per_cell: int
    max_total: int | None = None
    origin_px: tuple[float, float] = (0.0, 0.0)

    def keep(
        self, xy: NDArray[np.float64], strength: NDArray[np.floating[Any]]
    ) -> NDArray[np.bool_]:
        """(N,) bool: the points at ``xy`` (N, 2) of ``strength`` (N,) the cap keeps."""
        return cell_cap_mask(
            xy + np.asarray(self.origin_px), strength, self.cell_px, self.max_per_cell
        )

    def kept_count(
        self,
        grid_xy: tuple[NDArray[np.float64], NDArray[np.float64]],
        cols: NDArray[np.intp],
        rows: NDArray[np.intp],
    ) -> int:
        """How many points of a pixel grid the cap keeps, whatever their strengths.

        Args:
            grid_xy: (W,) x of the grid's columns and (H,) y of its rows, px.
            cols: (N,) the points' columns.
            rows: (N,) the points' rows.
        """
        if len(cols) == 0:
            return 0
        column, row = (
            _grid_coordinate(position + origin, self.cell_px)
            for position, origin in zip(grid_xy, self.origin_px, strict=True)
        )
        cell = row[rows] * (int(column.max()) + 1) + column[cols]
        per_cell = np.bincount(cell)
        return int(np.minimum(per_cell, self.max_per_cell).sum())

    def floor(self, candidates: Candidates) -> float:
        """A strength below which no point passes both caps, from some of the points.

        When the cell cap keeps more than ``max_total`` of ``candidates``, the
        weakest of its ``max_total`` strongest is such a floor for any set that
        holds them: each cell of that set keeps at least as many points as strong
        (Eq. 7's cap keeps a cell's strongest), so at least ``max_total`` points
        that strong reach the second cap. 0 when it keeps no more.
        """
        if self.max_total is None:
            return 0.0
        kept = self.kept_strengths(candidates)
        if len(kept) <= self.max_total:
            return 0.0
        return float(np.partition(kept, len(kept) - self.max_total)[len(kept) - self.max_total])

    def kept_strengths(self, candidates: Candidates) -> NDArray[np.float64]:
        """(M,) the strengths of the ``candidates`` the cell cap keeps."""
        return candidates.strength[self.keep(candidates.xy, candidates.strength)]


#: How many of a busy level's strongest peaks, in units of the frame's cap
#: (``max_total``), are capped and refined first to find its floor: on real sand and
#: beach the floor lies at the 1.1-1.25 ``max_total``-th strongest peak of the first
#: level, so the few hundred thousand weaker ones cost one comparison each. When these
#: do not reach the floor, all peaks are taken, with the same result.
_FLOOR_SEARCH_SHARE = 2.0
#: Every how many-th peak the first bound is estimated from.
_FLOOR_SAMPLE_STRIDE = 4
#: Relative margin of the floor turned into a bound on the squared response, below
#: float rounding: the bound may take a few more peaks, never fewer.
_FLOOR_BOUND_MARGIN = 1e-6


#: Relative slack of a bound turned into a raw response over the light's weight: the
#: float32 division may round up, and the bound must list a few more peaks, never fewer.
_LIFT_BOUND_SLACK = 1.0 - 1e-6


class LightWeight(NamedTuple):
    """The light's weight on the saddle screening (:meth:`preprocessing.ShadowedContrast.weight`).

    A print's contrast scales with the light on it, and so does an X's saddle
    response, by the square. Each peak's response counts times its weight squared
    wherever peaks are ranked (the cells' and the frame's caps, their floors, the
    candidates' ``strength``): a marker under dim light weighs as one in the open,
    and bright ground texture no more than its contrast over its light. The
    threshold is lowered by the gain, the weight where it is over 1 (under dark
    surroundings), so that the contrast floor holds after Eq. (2) as in the checks
    that follow.

    Attributes:
        at: (N,) the weight at (N, 2) points of the screened image.
        on_spans: (N, S) a bound on it from above on each of the (N,) rows y of the
            image within each of the spans of columns x_first to x_last (S,), inclusive.
    """

    at: Callable[[NDArray[np.float64]], NDArray[np.float64]]
    on_spans: Callable[
        [NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]
    ]


class _LevelPeaks(NamedTuple):
    """The 3x3 maxima of one pyramid level's saddle response, before they are refined.

    Attributes:
        peaks: the peaks listed on the level (or on its window).
        level: pyramid level L.
        offset: (u0, v0) level pixel of the window's pixel (0, 0).
        expected: the response's square root for an X of the smallest contrast.
        scale_px: ``scale_px`` of the level's candidates.
    """

    peaks: SaddlePeaks
    level: int
    offset: tuple[int, int]
    expected: float
    scale_px: float

    def weighed_by_light(self, threshold: float, light: LightWeight) -> _LevelPeaks:
        """The peaks above ``threshold`` over their own gain, each weighed by its light.

        Listed with the threshold lowered by the gain's bound on each span, and the
        bounds compared with the weight's bound (:class:`LightWeight`); here each
        peak's own weight at its pixel decides. Its response and its neighbours',
        which refine it, are weighed alike: the refinement reads their ratios.
        """
        peaks = self.peaks
        weight = light.at(self.pixel_xy()).astype(np.float32)
        squared = weight * weight
        keep = np.flatnonzero(
            peaks.values * np.maximum(squared, np.float32(1.0)) > np.float32(threshold**2)
        )
        # Only the peaks kept are weighed (tens of thousands listed on busy ground).
        kept = squared.take(keep)
        neighbours = peaks.neighbours.take(keep, axis=0)
        neighbours *= kept[:, None]
        return self._replace(
            peaks=peaks._replace(
                flat_index=peaks.flat_index.take(keep),
                values=peaks.values.take(keep) * kept,
                neighbours=neighbours,
            )
        )

    def capped_count(self, cap: CellCap) -> int:
        """How many of the peaks ``cap`` keeps in the cells of their pixels."""
        height, width = self.peaks.shape
        grid_xy = self._to_frame(np.arange(max(height, width)), np.arange(max(height, width)))
        rows, cols = np.divmod(self.peaks.flat_index, width)
        return cap.kept_count((grid_xy[:width, 0], grid_xy[:height, 1]), cols, rows)

    def pixel_xy(self, index: NDArray[np.intp] | None = None) -> NDArray[np.float64]:
        """(N, 2) full-resolution position of the pixels of the peaks ``index`` (all: None)."""
        rows, cols = np.divmod(
            self.peaks.flat_index if index is None else index, self.peaks.shape[1]
        )
        return self._to_frame(cols, rows)

    def _to_frame(
        self,
        cols: NDArray[np.intp],
        rows: NDArray[np.intp],
        dx: NDArray[np.floating[Any]] | float = 0.0,
        dy: NDArray[np.floating[Any]] | float = 0.0,
    ) -> NDArray[np.float64]:
        """(N, 2) full-resolution (x, y) of level pixels (``cols``, ``rows``) + (``dx``, ``dy``)."""
        # INTER_AREA halving maps level coordinate u to full-resolution (u + 0.5) 2**L - 0.5.
        u0, v0 = self.offset
        return cast(
            "NDArray[np.float64]",
            (np.stack([cols + u0 + dx, rows + v0 + dy], axis=1) + 0.5) * 2**self.level - 0.5,
        )

    def refined(self, chosen: NDArray[np.intp] | None) -> Candidates:
        """Candidates at the listed peaks ``chosen`` (all: None), refined (:func:`peak_offset`)."""
        listed = slice(None) if chosen is None else chosen
        peak = self.peaks.flat_index[listed]
        centre = self.peaks.values[listed]
        rows, cols = np.divmod(peak, self.peaks.shape[1])
        # Centroids only on a level whose scale the range capped (:func:`candidate_scale`),
        # which holds markers narrower than its own. On the others they lost markers
        # with a dull quadrant, whose lopsided response pulls the centroid (docs/
        # accuracy.md, "The saddle peaks' centroid").
        capped = self.scale_px < LEVEL_SCALE_PX * 2**self.level
        dx, dy = peak_offset(centre, self.peaks.neighbours[listed], capped)
        xy = self._to_frame(cols, rows, dx, dy)
        strength = np.sqrt(centre.astype(np.float64)) / self.expected
        return Candidates(xy, strength, np.full(len(peak), self.scale_px))

    def over_floor(self, cap: CellCap, floor: float) -> tuple[Candidates, float] | None:
        """The peaks ``cap`` keeps in their cells, refined, at or above the floor.

        The floor rises to :meth:`CellCap.floor` of this level's capped peaks.
        Both are found from the strongest peaks alone where they suffice: the cell
        cap keeps a cell's strongest, so on the peaks above any response bound it
        keeps exactly the capped peaks above that bound, and when more than
        ``max_total`` of those are kept again in the cells of their refined
        positions, the ``max_total``-th strongest is the level's floor. So the
        result is that of capping, refining and flooring every peak.

        Args:
            cap: the cell cap and the frame's cap.
            floor: the floor the previous levels set (0: none).

        Returns:
            (the candidates, the new floor); None where peaks weaker than those
            listed decide (the cell cap cut most of the strongest).
        """
        values = self.peaks.values
        total = cap.max_total
        bounds = []
        if total is not None:
            lowest = _floor_bound(floor, self.expected)
            search = _floor_search(total)
            if 0 < search < np.count_nonzero(values >= lowest):
                # Any bound at which every peak is listed will do (all peaks decide
                # where it is too high): that of a regular sample of the peaks costs a
                # fraction of an exact rank.
                sample = values[::_FLOOR_SAMPLE_STRIDE]
                # At least the sample's strongest, however few the frame's cap keeps.
                rank = max(len(sample) - max(search // _FLOOR_SAMPLE_STRIDE, 1), 0)
                strongest = max(float(np.partition(sample, rank)[rank]), self.peaks.bound)
                if strongest > lowest:
                    bounds.append(strongest)
            if floor > 0:
                bounds.append(lowest)
        for bound in bounds:
            if bound < self.peaks.bound:
                return None
            above = np.flatnonzero(values >= bound)
            found = self.refined(
                above[cap.keep(self.pixel_xy(self.peaks.flat_index[above]), values[above])]
            )
            kept = cap.kept_strengths(found)
            if len(kept) > cast("int", total):
                rank = len(kept) - cast("int", total)
                floor = max(floor, float(np.partition(kept, rank)[rank]))
            elif bound > lowest or len(kept) == total:
                # The floor may lie below the bound; or it is this weakest kept one,
                # unless the cap keeps no more than these: only all peaks tell.
                continue
            return found.take(found.strength >= floor), floor
        if self.peaks.bound > 0:
            return None
        found = self.refined(np.flatnonzero(cap.keep(self.pixel_xy(), values)))
        floor = max(floor, cap.floor(found))
        return found.take(found.strength >= floor), floor


def _floor_bound(floor: float, expected: float) -> float:
    """The squared response of a peak of relative strength ``floor``, less the margin."""
    known = floor * expected
    return known * known * (1.0 - _FLOOR_BOUND_MARGIN)


def _floor_search(max_total: int) -> int:
    """How many of a level's strongest peaks its floor is sought among first."""
    return int(_FLOOR_SEARCH_SHARE * max_total)


def _level_peaks(
    image: NDArray[Any],
    threshold: float | NDArray[np.float32],
    place: tuple[int, tuple[int, int], float, float],
    light: tuple[float, LightWeight, NDArray[np.float32]] | None,
    strongest: int | None,
    at_least: float,
) -> tuple[_LevelPeaks, int]:
    """A level's peaks (:func:`saddle_peaks`) and its pixels left unexamined.

    Args:
        image: the level's image (or its window).
        threshold: the squared response a peak exceeds, or (h, S) one per row and
            span of :data:`_SHADOW_SPAN_PX` columns.
        place: the level's ``level``, ``offset``, ``expected`` and ``scale_px``
            (:class:`_LevelPeaks`).
        light: (the threshold in the open, the light's weight, (h, S) its bound
            squared on each row and span), or None: every peak weighs 1.
        strongest: how many of the strongest peaks are wanted (None: all).
        at_least: only peaks of at least this response (weighed) are wanted.
    """
    lift = None if light is None else light[2]
    found = saddle_peaks(image, threshold, strongest=strongest, at_least=at_least, lift=lift)
    peaks = _LevelPeaks(found, *place)
    if light is not None:
        peaks = peaks.weighed_by_light(light[0], light[1])
    return peaks, found.unexamined


def saddle_candidates(
    image: NDArray[Any],
    radius_range_px: tuple[float, float],
    min_contrast: float,
    *,
    relative_threshold: float,
    window: tuple[int, int, int, int] | None = None,
    cell_cap: CellCap | None = None,
    tally: dict[str, int] | None = None,
    light: LightWeight | None = None,
    frame_shape: tuple[int, int] | None = None,
) -> Candidates:
    """Saddle points over an image pyramid covering the expected marker radii.

    A peak is kept when its response exceeds ``relative_threshold`` times what an
    X of contrast ``min_contrast`` blurred by 1.5 px would give at that level, so
    the threshold follows the user's contrast in grey levels. Peaks are refined to
    sub-sample precision (:func:`peak_offset`). At the first level, the
    midpoints of peak pairs that may be one split peak join them
    (:func:`split_peak_midpoints`).

    Args:
        image: (H, W) grey image, native dtype (uint8, uint16 or float32).
        radius_range_px: (min, max) expected marker radius in the frame.
        min_contrast: smallest marker contrast, in the image's grey units.
        relative_threshold: fraction of that expected response kept (tilt, motion
            and perspective weaken real markers further).
        window: (x0, y0, x1, y1), image pixels: only the peaks inside are wanted.
            Each level's response is then computed over the window and the reach
            of its filters alone (the pyramid still reduces the whole image, so
            every level keeps the full-image grid); the peaks inside are those of
            the whole image, and some just outside come too.
        cell_cap: Eq. (7)'s cap, applied to each level's peaks (by the cell of
            their pixel) before they are refined and their split-peak pairs are
            sought. A point that the cap on all levels' candidates keeps is among
            the strongest of its cell at its own level too, so the later cap keeps
            nearly the same points (all but a split-peak midpoint whose halves a
            crowded neighbouring cell cut, or a peak within half a level pixel of
            a cell edge: 2 % of those kept on sensor noise, no detection on the
            benchmarks' frames), while busy ground no longer costs seconds: the
            first level of a 12 MP frame of noise holds 1.4 million peaks, whose
            pairs ran to 17 million candidates (30 s and 1.7 GB at radius 3-30 px).
            With its ``max_total``, candidates weaker than its :meth:`CellCap.floor`
            are left out as soon as a level sets one: the two caps that follow
            keep the same points.
        tally: where the caps' cuts are counted, if given: ``"cut_in_cells"``
            (peaks beyond a cell's ``max_per_cell`` at their level),
            ``"cut_below_floor"`` (candidates below the floor) and
            ``"unexamined"`` (pixels above the threshold that the floor's bound
            spared the look for peaks, :func:`saddle_peaks`) are added to.
            Split-peak midpoints are formed from the peaks kept only.
        light: if given, each peak's response is weighed by its light, and
            under dark surroundings the threshold is divided by the gain there, so
            that ``min_contrast`` holds after Eq. (2) as in the checks that follow
            (:class:`LightWeight`).
        frame_shape: (H, W) of the frame ``image`` is cut from (a tracking
            window's crop): the pyramid goes as deep as the frame's. Default:
            ``image``'s.

    Returns:
        Candidates in full-resolution coordinates; ``scale_px`` is 4 * 2**L and
        ``strength`` the response relative to the expected one (weighed by its
        light, with ``light``).
    """
    levels = saddle_levels(radius_range_px)
    parts = []
    floor = 0.0
    cut_in_cells = cut_below_floor = unexamined = 0
    level_image = image
    frame_side = min(frame_shape or image.shape[:2])
    for level in range(levels.stop):
        if level > 0:
            height, width = level_image.shape
            # The frame's size, not a crop's, decides how deep the pyramid goes: a
            # tracking window is screened at every level the frame is.
            if frame_side < _MIN_REDUCED_SIDE_PX:
                break
            frame_side //= 2
            # An even crop makes INTER_AREA average exact 2 x 2 blocks; from an odd
            # size it would stretch the grid, and windows would see other pixels than
            # the full frame does.
            level_image = cv2.resize(
                level_image[: height - height % 2, : width - width % 2],
                (width // 2, height // 2),
                interpolation=cv2.INTER_AREA,
            )
        if level < levels.start:
            continue
        blur_sq = (EXPECTED_BLUR_PX / 2**level) ** 2
        expected = _SOBEL5_GAIN * _SADDLE_PER_CONTRAST * min_contrast / (1.0 + blur_sq)
        threshold = relative_threshold * expected
        u0, v0, u1, v1 = _level_window(window, level, level_image.shape)
        squared: float | NDArray[np.float32] = threshold**2
        weighing = None
        if light is not None:
            # Rows and spans of columns of the level (window) at full resolution, as
            # _LevelPeaks maps them.
            first = np.arange(u0, u1, _SHADOW_SPAN_PX)
            last = np.minimum(first + _SHADOW_SPAN_PX, u1) - 1
            weight = light.on_spans(
                (np.arange(v0, v1) + 0.5) * 2**level - 0.5,
                (first + 0.5) * 2**level - 0.5,
                (last + 0.5) * 2**level - 0.5,
            )
            gain = np.maximum(weight, 1.0)
            if (gain > 1.0).any():
                # float32 as the response: lit spans keep exactly the scalar's bound.
                squared = np.float32(threshold**2) / (gain * gain).astype(np.float32)
            weighing = (threshold, light, (weight * weight).astype(np.float32))
        level_peaks = functools.partial(
            _level_peaks,
            level_image[v0:v1, u0:u1],
            squared,
            (level, (u0, v0), expected, candidate_scale(level, radius_range_px)),
            weighing,
        )
        if cell_cap is None:
            peaks, _ = level_peaks(None, 0.0)
            found = peaks.refined(None)
        else:
            # Only the strongest peaks are looked for: on busy ground the first level
            # alone fills the frame's cap, and what is weaker cannot pass it, nor the
            # midpoints of pairs it belongs to.
            wanted = None if cell_cap.max_total is None else _floor_search(cell_cap.max_total)
            peaks, left = level_peaks(wanted, _floor_bound(floor, expected))
            result = peaks.over_floor(cell_cap, floor)
            if result is None:
                peaks, left = level_peaks(None, 0.0)
                result = cast("tuple[Candidates, float]", peaks.over_floor(cell_cap, floor))
            unexamined += left
            # The listed peaks the cell cap keeps, by the cells of their pixels.
            capped = peaks.capped_count(cell_cap)
            cut_in_cells += len(peaks.peaks.flat_index) - capped
            found, floor = result
            cut_below_floor += capped - len(found)
        parts.append(found)
        if level == levels.start:
            # Markers below the level's typical radius live here, and only here can
            # their peak split (coarser levels see larger markers).
            parts.append(split_peak_midpoints(found, _SPLIT_PEAK_DISTANCE * peaks.scale_px))
    found = Candidates.concat(parts)
    strong = found.strength >= floor
    if tally is not None:
        tally["cut_in_cells"] = tally.get("cut_in_cells", 0) + cut_in_cells
        tally["unexamined"] = tally.get("unexamined", 0) + unexamined
        tally["cut_below_floor"] = (
            tally.get("cut_below_floor", 0) + cut_below_floor + len(found) - int(strong.sum())
        )
    return found.take(strong)


class ContourSet(NamedTuple):
    """Closed contours stored one after another, with each point's place on its contour.

    Attributes:
        points: (M, 2) float64 contour points (x, y), px, in tracing order.
        start: (M,) int64 index in ``points`` of the first point of each point's contour.
        length: (M,) int64 number of points of each point's contour.
    """

    points: NDArray[np.float64]
    start: NDArray[np.int64]
    length: NDArray[np.int64]

    @classmethod
    def from_list(cls, contours: Sequence[NDArray[Any]]) -> ContourSet:
        """Join (M_i, 2) closed contours into one set."""
        if not contours:
            return cls(np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0, np.int64))
        lengths = np.array([len(c) for c in contours], dtype=np.int64)
        first = np.cumsum(lengths) - lengths
        return cls(
            np.concatenate(contours).reshape(-1, 2).astype(np.float64),
            np.repeat(first, lengths),
            np.repeat(lengths, lengths),
        )

    @classmethod
    def concat(cls, parts: list[ContourSet]) -> ContourSet:
        """Join several contour sets into one."""
        if not parts:
            return cls.from_list([])
        offsets = np.cumsum([0] + [len(p) for p in parts[:-1]])
        return cls(
            np.concatenate([p.points for p in parts]).reshape(-1, 2),
            np.concatenate([p.start + o for p, o in zip(parts, offsets, strict=True)]),
            np.concatenate([p.length for p in parts]).astype(np.int64),
        )

    def along(self, steps: int) -> NDArray[np.float64]:
        """(M,) index of the point ``steps`` further along each point's closed contour."""
        position = np.arange(len(self.points)) - self.start
        return cast(
            "NDArray[np.float64]", self.start + (position + steps) % np.maximum(self.length, 1)
        )

    def __len__(self) -> int:
        return len(self.points)


def contour_curvature(
    contours: ContourSet | NDArray[np.float64], window_px: int
) -> NDArray[np.float64]:
    """Curvature of every point of closed contours, Eq. (4).

    kappa = 1 - <v_prev, v_next> / (|v_prev| |v_next| + eps), with
    v_prev = p_k - p_{k-r} and v_next = p_{k+r} - p_k: 0 on straight runs,
    1 at a right angle, 2 at a spike. All contours at once, by index arithmetic.

    Args:
        contours: a :class:`ContourSet`, or the (M, 2) points of one closed contour.
        window_px: r, the index distance of the displacement vectors.

    Returns:
        (M,) float64 curvature.
    """
    if not isinstance(contours, ContourSet):
        contours = ContourSet.from_list([np.asarray(contours, np.float64)])
    points = contours.points
    v_prev = points - points[contours.along(-window_px)]
    v_next = points[contours.along(window_px)] - points
    dot = np.einsum("ij,ij->i", v_prev, v_next)
    norms = np.linalg.norm(v_prev, axis=1) * np.linalg.norm(v_next, axis=1)
    return cast("NDArray[np.float64]", 1.0 - dot / (norms + _CURVATURE_EPS))


def trace_contours(mask: NDArray[np.bool_], min_points: int) -> ContourSet:
    """Every boundary of the 4-connected regions of ``mask`` with at least ``min_points`` points.

    Regions that touch only at a pixel corner are traced apart (OpenCV traces
    8-connected regions, so one pixel of each such diagonal pair is left out first):
    the two sectors of an X that meet at its centre then each end in a sharp apex
    there, where one 8-connected contour would only bend through a diagonal step.

    Args:
        mask: (H, W) bool image.
        min_points: shorter contours are left out (Eq. 4 needs 2 r + 1 distinct points).

    Returns:
        :class:`ContourSet` of pixel-centre points.
    """
    region = np.array(mask, dtype=bool)
    # 2 x 2 blocks set on one diagonal only: clear the top-left / top-right pixel.
    top, bottom = region[:-1], region[1:]
    falling = top[:, :-1] & bottom[:, 1:] & ~top[:, 1:] & ~bottom[:, :-1]
    rising = top[:, 1:] & bottom[:, :-1] & ~top[:, :-1] & ~bottom[:, 1:]
    top[:, :-1] &= ~falling
    top[:, 1:] &= ~rising
    found, _ = cv2.findContours(region.astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    return ContourSet.from_list([c[:, 0, :] for c in found if len(c) >= min_points])


def robust_mean_std(
    values: NDArray[np.float64], weights: NDArray[np.float64] | None = None
) -> tuple[float, float]:
    """Mean and standard deviation of the bulk of ``values``: (weighted) median and 1.4826 x MAD.

    Equal to the sample mean and std for normally distributed values, and not
    dragged up by a heavy tail (here: the corners themselves).

    Args:
        values: (M,) samples.
        weights: (M,) non-negative weights (None: all equal).

    Returns:
        (mean, std).
    """
    if len(values) == 0:
        return 0.0, 0.0
    if weights is None:
        weights = np.ones(len(values))
    median = _weighted_median(values, weights)
    return median, MAD_TO_STD * _weighted_median(np.abs(values - median), weights)


def _weighted_median(values: NDArray[np.float64], weights: NDArray[np.float64]) -> float:
    # Stable: tied values' weights summed in one order, so the half falls on one side.
    order = np.argsort(values, kind="stable")
    cumulative = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])


def local_threshold(
    image: NDArray[Any], diameters_px: tuple[int, ...], min_contrast: float
) -> NDArray[np.float32]:
    """The contours' level at every pixel: the local mid-range of ``image`` (section 3.2).

    The level is (max + min) / 2 over the smallest window of ``diameters_px``
    (each about twice the last) that spans at least ``min_contrast``: inside a
    marker that is the level between its dark and bright sectors whatever the light
    around it, so the level line runs through the X centre; deep inside a large
    sector a larger window still sees the neighbouring sectors, so the sector stays
    one clean region. Where no window finds that much contrast (flat or faint
    ground) the level is NaN, and such pixels take part in no contour. The first
    window is exact; the k-th reads the image max- and min-pooled over 2^k x 2^k
    blocks (a window of its size, aligned to the blocks), at a 4^k-th of the cost.

    Args:
        image: (H, W) float32 preprocessed image.
        diameters_px: window sides (odd), from the smallest marker's diameter, each
            about twice the previous (:func:`threshold_diameters`).
        min_contrast: smallest max - min of a window whose pixels take part.

    Returns:
        (H, W) float32 level, NaN where there is none.
    """
    first = diameters_px[0]
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (first, first))
    height, width = image.shape
    level = np.full(image.shape, np.nan, np.float32)
    pooled_high, pooled_low = image, image
    for k in range(len(diameters_px)):
        if k:
            pooled_high, pooled_low = _pool(pooled_high, np.maximum), _pool(pooled_low, np.minimum)
            if min(pooled_high.shape) < 2:
                break
        high, low = cv2.dilate(pooled_high, kernel), cv2.erode(pooled_low, kernel)
        coarse = np.where(high - low >= min_contrast, 0.5 * (high + low), np.nan)
        # Back to full resolution: each coarse pixel covers a 2^k x 2^k block.
        block = 2**k
        full = np.repeat(np.repeat(coarse, block, axis=0), block, axis=1)[:height, :width]
        np.copyto(level, full, where=np.isnan(level))
    return level


def _pool(image: NDArray[Any], reduce: np.ufunc) -> NDArray[np.float64]:
    """``image`` reduced by ``reduce`` over 2 x 2 blocks (an odd last row / column is kept)."""
    height, width = image.shape
    padded = np.pad(image, ((0, height % 2), (0, width % 2)), mode="edge")
    return cast(
        "NDArray[np.float64]",
        reduce(
            reduce(padded[0::2, 0::2], padded[1::2, 0::2]),
            reduce(padded[0::2, 1::2], padded[1::2, 1::2]),
        ),
    )


def onto_level_line(
    contours: ContourSet, image: NDArray[Any], level: NDArray[np.float32]
) -> tuple[ContourSet, NDArray[np.float64]]:
    """Contour pixels moved onto the level line I = level by one Newton step along the gradient.

    p <- p - (I(p) - level(p)) grad I / |grad I|^2, at most :data:`_LEVEL_STEP_PX`:
    the pixel staircase becomes the sub-pixel level line, whose turns Eq. (4)
    measures without the quantisation of pixel steps.

    Returns:
        (contours on the level line, (M,) gradient magnitude |grad I| at each point
        in image units per px: the strength of the edge the contour runs along).
    """
    if len(contours) == 0:
        return contours, np.zeros(0)
    cols = contours.points[:, 0].astype(np.intp)
    rows = contours.points[:, 1].astype(np.intp)
    gx = cv2.Sobel(image, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)[rows, cols].astype(np.float64)
    gy = cv2.Sobel(image, cv2.CV_32F, 0, 1, ksize=3, scale=0.125)[rows, cols].astype(np.float64)
    excess = image[rows, cols] - level[rows, cols]
    step = -excess / (gx * gx + gy * gy + 1e-12)
    shift = np.stack([gx * step, gy * step], axis=1)
    length = np.linalg.norm(shift, axis=1, keepdims=True)
    shift *= np.minimum(1.0, _LEVEL_STEP_PX / np.maximum(length, 1e-12))
    moved = ContourSet(contours.points + np.nan_to_num(shift), contours.start, contours.length)
    return moved, np.hypot(gx, gy)


def connected_domain_check(mask: NDArray[np.bool_], min_area_px: float) -> NDArray[np.bool_]:
    """``mask`` without its 8-connected domains smaller than ``min_area_px`` (section 3.2).

    Args:
        mask: (H, W) bool.
        min_area_px: smallest area of a domain kept, px.

    Returns:
        (H, W) bool.
    """
    _, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    keep = stats[:, cv2.CC_STAT_AREA] >= min_area_px
    keep[0] = False  # the background label
    return cast("NDArray[np.bool_]", keep[labels])


def threshold_diameters(radius_range_px: tuple[float, float]) -> tuple[int, ...]:
    """Window sides of :func:`local_threshold`: the smallest marker's diameter, doubling.

    The last covers the largest marker's diameter, so that the middle of its
    largest sector still sees a neighbouring one.
    """
    r_min, r_max = radius_range_px
    diameters = [2 * int(round(r_min)) + 1]
    while diameters[-1] < 2 * r_max:
        diameters.append(2 * diameters[-1] + 1)
    return tuple(diameters)


def curvature_candidates(
    image: NDArray[Any],
    structure: StructureComponents,
    radius_range_px: tuple[float, float],
    min_contrast: float,
    threshold_std: float,
    separation_px: float,
    keep_fraction: float,
    density_sigma_px: float,
    mean_shift_h_px: float,
) -> Candidates:
    """The paper's primary screening: curvature peaks of contours (section 3.2, Eq. 4).

    Contours (the paper does not say how it extracts them) are the boundaries of
    the sets above and below the local level of :func:`local_threshold`, both sets,
    traced 4-connected (:func:`trace_contours`) and moved onto the sub-pixel level
    line (:func:`onto_level_line`): at an X centre each sector of either set ends in
    an apex. The noise-aware connected-domain check keeps only pixels whose window
    spans ``min_contrast`` or six noise sigmas (:func:`preprocessing.noise_sigma`),
    whichever is more, and only domains of at least a quarter of the smallest
    marker's quadrant (:func:`connected_domain_check`). A contour point becomes a
    candidate when (1) its curvature (Eq. 4) is a peak along the contour and exceeds
    mean + ``threshold_std`` std of the curvature, the dual threshold's first part;
    the statistics are those of the frame's edges, every contour point weighted by
    its gradient magnitude and estimated from the bulk (:func:`robust_mean_std`):
    unweighted, the wiggles of faint ground outnumber the edges, and the sample
    moments of a heavy-tailed distribution put a right angle below mean + 3 std;
    the threshold is capped at a 60-degree turn (:data:`_MAX_CURVATURE_THRESHOLD`);
    (2) no stronger peak of the same contour lies within ``separation_px``, its
    second part; (3) the structure s_k (Eq. 3) there is in the frame's top
    ``keep_fraction``. The peaks of all contours then gather by the
    curvature-density mean shift (Eqs. 5-6, :func:`density_mean_shift`): an X
    centre is where the apexes of its four sectors meet.

    Args:
        image: (H, W) float32 preprocessed image in [0, 1].
        structure: the structural components of ``image``, Eq. (3).
        radius_range_px: (min, max) expected marker radius.
        min_contrast: smallest marker contrast, in ``image`` units.
        threshold_std: the dual threshold's k in mean + k std.
        separation_px: minimum spacing of peaks of one contour.
        keep_fraction: top fraction of the structure map kept.
        density_sigma_px: sigma of Eq. (5).
        mean_shift_h_px: h of Eq. (6).

    Returns:
        Candidates (up to ~1.5 px from the X centre); ``strength`` is the largest
        local standard deviation of Eq. (3), sigma_{d,k}, at the candidate (the
        structure before its saturating map, so that strong edges still rank:
        markers' printed contrast ranks them in the top fifth of the candidates),
        ``scale_px`` the smallest radius.
    """
    r_min = radius_range_px[0]
    sigma = noise_sigma(image)
    floor = max(min_contrast, _NOISE_CONTRAST_FACTOR * sigma)
    min_area = _MIN_DOMAIN_QUADRANT_FRACTION * (np.pi / 4.0) * r_min**2
    level = local_threshold(image, threshold_diameters(radius_range_px), floor)
    with np.errstate(invalid="ignore"):
        masks = (image > level, image < level)
    contours = ContourSet.concat(
        [
            trace_contours(connected_domain_check(m, min_area), 2 * CURVATURE_WINDOW_PX + 2)
            for m in masks
        ]
    )
    if len(contours) == 0:
        return Candidates.empty()
    contours, edge_strength = onto_level_line(contours, image, level)
    kappa = contour_curvature(contours, CURVATURE_WINDOW_PX)
    # Peaks along the contour; a plateau yields its first point.
    is_peak = (kappa >= kappa[contours.along(-1)]) & (kappa > kappa[contours.along(1)])
    # The statistics of a regular sample of the contour points (all of them on small
    # frames): a quarter of a million fix a median to well under a percent.
    stride = max(1, len(kappa) // _STATISTICS_SAMPLE)
    mean, std = robust_mean_std(kappa[::stride], edge_strength[::stride])
    is_peak &= kappa > min(mean + threshold_std * std, _MAX_CURVATURE_THRESHOLD)
    points, kappa, contour = contours.points[is_peak], kappa[is_peak], contours.start[is_peak]
    in_structure = structure.at(points) >= structure.quantile(1.0 - keep_fraction)
    points, kappa, contour = points[in_structure], kappa[in_structure], contour[in_structure]
    # Adjacent peaks of one contour: the X centre's apexes on other contours (the
    # other sectors, the other set) stay, for the density mean shift to gather.
    keep = non_maximum_suppression(points, kappa, separation_px, group=contour)
    peaks = Candidates(points[keep], kappa[keep], np.full(int(keep.sum()), float(r_min)))
    merged = density_mean_shift(peaks, density_sigma_px, mean_shift_h_px)
    pixel = np.round(merged.xy).astype(np.intp)
    height, width = image.shape
    rows, cols = np.clip(pixel[:, 1], 0, height - 1), np.clip(pixel[:, 0], 0, width - 1)
    return Candidates(merged.xy, structure.sigma_at(rows, cols), merged.scale_px)


def non_maximum_suppression(
    xy: NDArray[np.float64],
    strength: NDArray[np.float64],
    radius_px: float,
    group: NDArray[np.integer[Any]] | None = None,
) -> NDArray[np.bool_]:
    """Boolean mask keeping points with no stronger point within ``radius_px``.

    With ``group`` (N,) labels, a point only suppresses points of its own group.
    """
    if len(xy) == 0:
        return np.zeros(0, dtype=bool)
    tree = cKDTree(xy)
    pairs = tree.query_pairs(radius_px, output_type="ndarray")
    if group is not None and len(pairs):
        pairs = pairs[group[pairs[:, 0]] == group[pairs[:, 1]]]
    keep = np.ones(len(xy), dtype=bool)
    if len(pairs):
        i, j = pairs[:, 0], pairs[:, 1]
        weaker = np.where(strength[i] < strength[j], i, j)
        tie = strength[i] == strength[j]
        weaker = np.where(tie, np.maximum(i, j), weaker)
        keep[weaker] = False
    return keep


def curvature_density(
    xy: NDArray[np.float64], weight: NDArray[np.float64], sigma_px: float
) -> NDArray[np.float64]:
    """Curvature-weighted spatial density rho(p_i), Eq. (5), over neighbours within 3 sigma."""
    tree = cKDTree(xy)
    distances = tree.sparse_distance_matrix(tree, 3.0 * sigma_px, output_type="coo_matrix")
    kernel = np.exp(-(distances.data**2) / (2.0 * sigma_px**2))
    density = np.bincount(distances.row, weights=weight[distances.col] * kernel, minlength=len(xy))
    return density + weight  # the diagonal (distance 0) is not stored in the sparse matrix


def density_mean_shift(
    candidates: Candidates,
    sigma_px: float = 2.0,
    h_px: float = 2.0,
    iterations: int = 3,
    merge_px: float = 2.0,
) -> Candidates:
    """Curvature-density mean shift and merging of converged points, Eqs. (5)-(6).

    Each point moves to the weighted mean of its neighbours,
    p_i <- sum w_j p_j / sum w_j with w_j = rho(p_j) exp(-|p_j - p_i| / h), so
    duplicates of one corner (two contour corners, several pyramid levels) fall
    together; points then closer than ``merge_px`` are merged into the strongest.

    Args:
        candidates: points with ``strength`` as the normalised curvature kappa.
        sigma_px: density kernel width of Eq. (5).
        h_px: attenuation h of Eq. (6).
        iterations: mean-shift iterations.
        merge_px: points that end closer than this are one point.

    Returns:
        The merged candidates; the merged point keeps the largest strength and scale.
    """
    if len(candidates) < 2:
        return candidates
    kappa = candidates.strength / max(float(candidates.strength.max()), 1e-12)
    rho = curvature_density(candidates.xy, kappa, sigma_px)
    xy = candidates.xy.copy()
    for _ in range(iterations):
        tree = cKDTree(xy)
        pairs = tree.sparse_distance_matrix(tree, 3.0 * h_px, output_type="coo_matrix")
        w = rho[pairs.col] * np.exp(-pairs.data / h_px)
        # Self terms (distance 0) are not stored: add them explicitly.
        w_sum = np.bincount(pairs.row, weights=w, minlength=len(xy)) + rho
        new_xy = (
            np.stack(
                [
                    np.bincount(pairs.row, weights=w * xy[pairs.col, k], minlength=len(xy))
                    + rho * xy[:, k]
                    for k in range(2)
                ],
                axis=1,
            )
            / w_sum[:, None]
        )
        xy = new_xy
    merged, _ = Candidates(xy, candidates.strength, candidates.scale_px).without_duplicates(
        merge_px
    )
    return merged


def grid_entropy(xy: NDArray[np.float64], cell_px: int) -> float:
    """Spatial grid entropy H = -sum P(n) ln P(n) of the points, Eq. (7)."""
    if len(xy) == 0:
        return 0.0
    _, counts = np.unique(np.floor(xy / cell_px).astype(np.int64), axis=0, return_counts=True)
    p = counts / counts.sum()
    return float(-(p * np.log(p)).sum())


def greedy_entropy_thinning(candidates: Candidates, cell_px: int, evenness: float) -> Candidates:
    """The paper's greedy thinning by spatial grid entropy, to an entropy threshold, Eq. (7).

    Each step removes the point whose removal raises H = -sum P(n) ln P(n) the most:
    the weakest point of the most crowded cell (ties: the cell first in raster
    order). Steps go on until H reaches ``evenness`` x ln K, K the number of occupied
    cells (ln K is the entropy of the same cells equally filled), or until no
    removal raises H. H after k removals is ln(N - k) - (S - sum of the removals'
    changes of S) / (N - k) with S = sum n ln n, so the whole greedy sequence is
    evaluated at once.

    Args:
        candidates: points to thin; ``strength`` orders the removals within a cell.
        cell_px: grid cell size, px.
        evenness: the entropy threshold as a fraction of ln K, in [0, 1].

    Returns:
        The kept candidates (original order).
    """
    if len(candidates) < 2:
        return candidates
    cells = np.floor(candidates.xy / cell_px).astype(np.int64)
    _, cell, counts = np.unique(cells, axis=0, return_inverse=True, return_counts=True)
    cell = cell.ravel()
    target = evenness * np.log(len(counts))
    # Removal m of cell i takes it from counts[i] - m to counts[i] - m - 1 points; the
    # greedy order is by the count before the removal, largest first, then by cell.
    owner = np.repeat(np.arange(len(counts)), counts - 1)
    if len(owner) == 0:
        return candidates
    first_removal = np.repeat(np.cumsum(counts - 1) - (counts - 1), counts - 1)
    level = (counts[owner] - (np.arange(len(owner)) - first_removal)).astype(np.float64)
    order = np.lexsort((owner, -level))
    level, owner = level[order], owner[order]
    total = len(candidates)
    s = float(np.sum(counts * np.log(counts)))
    # H = ln N - S / N; a removal at count n lowers S by n ln n - (n - 1) ln(n - 1).
    change = level * np.log(level) - (level - 1) * np.log(np.maximum(level - 1, 1))
    remaining = total - np.arange(1, len(level) + 1)
    entropy = np.r_[
        np.log(total) - s / total, np.log(remaining) - (s - np.cumsum(change)) / remaining
    ]
    # The greedy loop stops at the threshold, or where no removal raises H any more.
    falling = np.flatnonzero(np.diff(entropy) <= 0)
    last = falling[0] if len(falling) else len(level)
    reached = np.flatnonzero(entropy[: last + 1] >= target)
    removals = int(reached[0]) if len(reached) else last
    removed_per_cell = np.bincount(owner[:removals], minlength=len(counts))
    # Within a cell, the weakest points go first.
    rank = np.empty(total, np.int64)
    by_cell = np.lexsort((candidates.strength, cell))
    first_of_cell = np.searchsorted(cell[by_cell], cell[by_cell])
    rank[by_cell] = np.arange(total) - first_of_cell
    return candidates.take(rank >= removed_per_cell[cell])


def grid_entropy_thinning(candidates: Candidates, cell_px: int, max_per_cell: int) -> Candidates:
    """Greedy entropy-increasing removal of redundant points, Eq. (7).

    Removing a point from the most crowded cell is the removal with the largest
    entropy gain, so the paper's greedy loop amounts to trimming every cell to a
    common count, weakest points first; the stopping threshold is expressed as
    that count (``max_per_cell``) because a count is what a user can reason about.

    Args:
        candidates: points to thin.
        cell_px: grid cell size.
        max_per_cell: the most points a cell keeps.

    Returns:
        The kept candidates (original order).
    """
    return candidates.take(cell_cap_mask(candidates.xy, candidates.strength, cell_px, max_per_cell))


def even_cap(candidates: Candidates, limit: int, cell_px: float) -> Candidates:
    """The ``limit`` candidates that Eq. (7)'s thinning to that count keeps.

    Removing the weakest point of the most crowded cell raises the grid entropy
    the most (:func:`grid_entropy_thinning`), so the thinning keeps the points
    round by round: every cell's strongest, then every cell's second strongest,
    and so on, the strongest first within the last round. A marker on busy ground
    thus competes with its own cell's points, not with the whole frame's.

    Args:
        candidates: points to cap.
        limit: the most points kept.
        cell_px: grid cell size, px.

    Returns:
        The kept candidates (original order).
    """
    if len(candidates) <= limit:
        return candidates
    return candidates.take(even_cap_index(candidates.xy, candidates.strength, limit, cell_px))


def even_cap_index(
    xy: NDArray[np.float64], strength: NDArray[np.float64], limit: int, cell_px: float
) -> NDArray[np.intp]:
    """Indices (ascending) of the ``limit`` points :func:`even_cap` keeps, by ``strength``.

    Args:
        xy: (N, 2) points, px.
        strength: (N,) what ranks the points within a cell (larger first).
        limit: the most points kept.
        cell_px: grid cell size, px.
    """
    if len(xy) <= limit:
        return np.arange(len(xy))
    return np.sort(even_order(xy, strength, cell_px)[:limit])


def even_order(
    xy: NDArray[np.float64], strength: NDArray[np.float64], cell_px: float
) -> NDArray[np.intp]:
    """(N,) the points in the order :func:`even_cap` keeps them: a cap to K keeps the first K.

    Round by round (every cell's strongest, then every cell's second strongest, ...),
    the strongest first within a round; of equally strong points, the first first.

    Args:
        xy: (N, 2) points, px.
        strength: (N,) what ranks the points within a cell (larger first).
        cell_px: grid cell size, px.
    """
    if len(xy) == 0:
        return np.zeros(0, np.intp)
    cell = grid_cells(xy, cell_px)
    per_cell = np.bincount(cell)
    # Of equally strong points of a cell the first ranks first, as in cell_cap_mask.
    order = stable_order(strongest_first_in_cell(cell, strength))
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order)) - (np.cumsum(per_cell) - per_cell)[cell[order]]
    return cast("NDArray[np.intp]", np.lexsort((-strength, rank)))


def cell_cap_mask(
    xy: NDArray[np.float64],
    strength: NDArray[np.floating[Any]],
    cell_px: float,
    max_per_cell: int,
) -> NDArray[np.bool_]:
    """(N,) bool: the ``max_per_cell`` strongest points of every ``cell_px`` grid cell.

    Of equally strong points the first keeps its place, so that the cap keeps the
    same points of a set and of any part of it that holds the strongest.
    """
    keep = np.ones(len(xy), dtype=bool)
    if len(xy) == 0:
        return keep
    cell = grid_cells(xy, cell_px)
    per_cell = np.bincount(cell)
    if per_cell.max() <= max_per_cell:
        return keep
    # Only the points of crowded cells are ranked (a half to an eighth of them on busy
    # ground); a stable sort of a subset keeps its points' order.
    crowded_count = np.where(per_cell > max_per_cell, per_cell, 0)
    crowded = np.flatnonzero(crowded_count[cell])
    order = crowded[stable_order(strongest_first_in_cell(cell[crowded], strength[crowded]))]
    rank = np.arange(len(order)) - (np.cumsum(crowded_count) - crowded_count)[cell[order]]
    keep[order[rank >= max_per_cell]] = False
    return keep


def stable_order(keys: NDArray[np.int64]) -> NDArray[np.intp]:
    """``np.argsort(keys, kind="stable")`` of non-negative keys, from one plain sort.

    Each key carries its index in the bits below it, where they fit, so that all
    keys differ and a plain sort of the values (vectorised; a fifth to a tenth of
    the stable argsort's time on 20 000-40 000 keys of a level, many tied: integer
    responses) puts equal keys in index order, as the stable sort does.
    """
    bits = max(len(keys) - 1, 1).bit_length()
    if len(keys) == 0 or int(keys.max()) >= 1 << (63 - bits):
        return np.argsort(keys, kind="stable")
    tagged = keys << bits
    tagged |= np.arange(len(keys))
    tagged.sort()
    return cast("NDArray[np.intp]", tagged & ((1 << bits) - 1))


def grid_cells(xy: NDArray[np.float64], cell_px: float) -> NDArray[np.int64]:
    """(N,) int64 index of each point's ``cell_px`` grid cell, dense from 0, row by row."""
    # Column by column: reductions over an (N, 2) array's first axis cost several times more.
    column = _grid_coordinate(xy[:, 0], cell_px)
    row = _grid_coordinate(xy[:, 1], cell_px)
    return row * (int(column.max()) + 1) + column


def _grid_coordinate(position: NDArray[np.float64], cell_px: float) -> NDArray[np.int64]:
    """(N,) int64 grid column (or row) of each ``position``, px, counted from the first used."""
    cell = np.floor(position / cell_px).astype(np.int64)
    cell -= cell.min()
    return cell


def strongest_first_in_cell(
    cell: NDArray[np.int64], strength: NDArray[np.floating[Any]]
) -> NDArray[np.int64]:
    """(N,) int64 keys that sort points by cell, then by strength, strongest first.

    One integer sort instead of a two-key lexsort (a ninth of its time on the half
    million peaks of a busy 8 MP level): the cell in the high 32 bits, the strength,
    rounded to float32, as its order-preserving bit pattern in the low 32.

    Args:
        cell: (N,) int64 cell indices in [0, 2**31).
        strength: (N,) float strengths.
    """
    bits = strength.astype(np.float32).view(np.int32).astype(np.int64)
    ascending = np.where(bits >= 0, bits, bits ^ 0x7FFFFFFF)
    return cast("NDArray[np.int64]", (cell << 32) | (0x7FFFFFFF - ascending))
