"""Section 3.1 of the paper: noise suppression, illumination normalisation, structure map.

All three stages are built from box filters (``cv2.boxFilter``), so their cost
per pixel does not depend on the window size. Images are float32 in [0, 1].

References:
    Kou, Chen, Wen, Li, "Gradient Domain Guided Image Filtering", IEEE TIP 24(11), 2015
    (the GDWGIF the paper cites as Tao et al.).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, TypeVar, cast

import cv2
import numpy as np
from numpy.typing import NDArray

from marker_localizer.core.sampling import corners, interpolate

FloatImage = NDArray[np.float32]  # (H, W)
#: float32 or float64: Eq. (2) keeps the precision it is given.
_Float = TypeVar("_Float", np.float32, np.float64)

#: The local mean of Eq. (2) is measured on the frame reduced by this fraction of the
#: window's side: the mean over a window is smooth at that scale.
_LOCAL_MEAN_REDUCTION = 8
#: (low, high) clip of Eq. (2)'s gamma. The paper sets none; a clip keeps black ground
#: from collapsing to a flat field (gamma -> 0). The low end is a square root, the power
#: under which shot noise is even across the levels (read noise is even under a power
#: of 1): a camera's noise lies between the two, and a power under 1/2 magnifies the
#: dark quadrants' noise past the bright ones' whatever the camera. At 1/4 (the clip
#: until 2026-12-06) a marker's black paint at 0-10 DN under a dark surround read
#: 0.03-0.44 of white: a DN of noise there weighed 6 times one on the white paint (3.4
#: times at 1/2), and its rings failed (docs/accuracy-journal.md, "Eq. (2)'s gamma no stronger
#: than a square root").
GAMMA_LIMITS = (0.5, 4.0)
#: Standard deviation of a normal distribution per unit of median absolute deviation.
MAD_TO_STD = 1.4826
#: :meth:`StructureComponents.quantile` reads every this-many-th pixel in each direction:
#: a 16th of the frame fixes a quantile of its structure to well under a percent.
STRUCTURE_SAMPLE_STEP_PX = 4


def box_mean(image: FloatImage, diameter: int) -> FloatImage:
    """Mean over a ``diameter`` x ``diameter`` window (replicated border)."""
    return cast(
        FloatImage,
        cv2.boxFilter(image, cv2.CV_32F, (diameter, diameter), borderType=cv2.BORDER_REFLECT),
    )


def local_std(image: FloatImage, diameter: int) -> FloatImage:
    """Standard deviation over a ``diameter`` x ``diameter`` window, sigma_{d,k} of Eq. (3)."""
    mean = box_mean(image, diameter)
    mean_sq = box_mean(image * image, diameter)
    std: FloatImage = np.sqrt(np.maximum(mean_sq - mean * mean, 0.0))
    return std


def noise_sigma(image: NDArray[Any]) -> float:
    """Standard deviation of the pixel noise, from the median absolute horizontal difference.

    Differences of neighbouring pixels are the noise (times sqrt 2) wherever the
    image is smooth, which is most of it; the median ignores the edges.
    Measured on every other row and column (a quarter of the pixels suffice).

    Args:
        image: (H, W) image.

    Returns:
        sigma in the image's units; 0 for an image under 3 px wide, which holds no
        such pair.
    """
    sample = np.asarray(image[::2, ::2], dtype=np.float32)
    difference = np.abs(sample[:, 1:] - sample[:, :-1])
    if difference.size == 0:
        return 0.0
    return MAD_TO_STD * float(np.median(difference)) / float(np.sqrt(2.0))


def gdwgif(image: FloatImage, radius_px: int, regularisation: float) -> FloatImage:
    """Self-guided gradient-domain weighted guided filter, Eq. (1).

    Minimises, per window Omega_k, sum (a_k I_i + b_k - q_i)^2 + lambda / T(k) (a_k - psi_k)^2
    with the edge-aware weight T(k) from the product of the 3x3 and (2r+1)^2 local
    standard deviations and the gradient-domain target psi_k (a sigmoid of that
    product), so edges keep a_k close to 1 while flat noisy ground is averaged.

    Args:
        image: (H, W) float32 intensities in [0, 1]; it is also the guide.
        radius_px: window radius r; the window is (2r+1) x (2r+1).
        regularisation: lambda of Eq. (1).

    Returns:
        (H, W) float32 filtered image.
    """
    diameter = 2 * radius_px + 1
    mean = box_mean(image, diameter)
    variance = np.maximum(box_mean(image * image, diameter) - mean * mean, 0.0)
    # chi(k): product of fine and window-scale std, the edge indicator of Kou et al.
    chi = local_std(image, 3) * np.sqrt(variance)
    eps = np.float32(1e-6)  # (0.001 L)^2 with L = 1, as in Kou et al.
    edge_weight = (chi + eps) * np.mean(1.0 / (chi + eps), dtype=np.float64).astype(np.float32)
    chi_mean = float(chi.mean())
    eta = 4.0 / max(chi_mean - float(chi.min()), 1e-12)
    psi = 1.0 - 1.0 / (1.0 + np.exp(np.clip(eta * (chi - chi_mean), -60.0, 60.0)))
    reg = np.float32(regularisation) / edge_weight
    a = (variance + reg * psi) / (variance + reg)
    b = mean - a * mean
    return (box_mean(a, diameter) * image + box_mean(b, diameter)).astype(np.float32)


def dynamic_gamma(
    image: FloatImage,
    alpha: float,
    window_px: int,
    gamma_limits: tuple[float, float] = GAMMA_LIMITS,
) -> FloatImage:
    """Per-pixel gamma correction driven by the local mean luminance, Eq. (2).

    L' = L ** gamma with gamma = alpha * mu(k): dark surroundings get gamma < 1
    (brightened), bright ones gamma > 1. The gamma is clipped to ``gamma_limits``
    (:data:`GAMMA_LIMITS`).

    Args:
        image: (H, W) float32 in [0, 1], the illumination layer L.
        alpha: contrast-adaptive scale alpha.
        window_px: side of the box measuring mu(k).
        gamma_limits: (low, high) clip of the per-pixel gamma.

    Returns:
        (H, W) float32 in [0, 1].
    """
    mu = box_mean(image, window_px)
    return apply_gamma(image, mu, alpha, gamma_limits).astype(np.float32)


def apply_gamma(
    luminance: NDArray[_Float],
    mean: NDArray[_Float],
    alpha: float,
    gamma_limits: tuple[float, float],
    out: NDArray[_Float] | None = None,
) -> NDArray[_Float]:
    """Eq. (2) itself: L ** clip(alpha * mu) for intensities in [0, 1] (broadcasting).

    ``out``: where to write the result (``luminance`` itself may be given).
    """
    floored = np.maximum(luminance, 1e-6, out=out)
    # Clipped by the method: np.clip's wrapper costs microseconds a call, and the rings
    # and disks of a few points are normalised call by call.
    return cast(NDArray[_Float], np.power(floored, (alpha * mean).clip(*gamma_limits), out=out))


def structure_map(
    image: FloatImage, diameters_px: tuple[int, ...] = (3, 5, 9), *, xi: float, t: float
) -> FloatImage:
    """Multi-scale structural component map, Eq. (3).

    s_k = 1 - exp(-(sigma_{d,k} / xi) ** t), taken as the maximum over the
    neighbourhood diameters d so that both 3 px and large markers register.

    Args:
        image: (H, W) float32 in [0, 1].
        xi: scale of the local standard deviation.
        t: structural sensitivity exponent.
        diameters_px: neighbourhood diameters d.

    Returns:
        (H, W) float32 in [0, 1).
    """
    sigma = np.maximum.reduce([local_std(image, d) for d in diameters_px])
    structure: FloatImage = (1.0 - np.exp(-np.power(sigma / np.float32(xi), np.float32(t)))).astype(
        np.float32
    )
    return structure


class StructureComponents:
    """Eq. (3) evaluated where it is used: at points, and on a grid for its quantiles.

    The local standard deviations sigma_{d,k} come from integral images of the
    intensity and its square (four lookups per window), so no full-frame map of
    s_k is built: the paper path needs s_k only at its candidates and its
    distribution over the frame (:meth:`quantile`, from every
    :data:`STRUCTURE_SAMPLE_STEP_PX`-th pixel). Windows are clipped at the border.

    Args:
        image: (H, W) float32 in [0, 1].
        xi: scale of the local standard deviation.
        t: structural sensitivity exponent.
        diameters_px: neighbourhood diameters d (odd).
    """

    def __init__(
        self,
        image: FloatImage,
        diameters_px: tuple[int, ...] = (3, 5, 9),
        *,
        xi: float,
        t: float,
    ) -> None:
        sums = cv2.integral2(image, sdepth=cv2.CV_64F)
        self._sum, self._square_sum = cast(tuple[NDArray[np.float64], NDArray[np.float64]], sums)
        self._shape = image.shape
        self._diameters = diameters_px
        self._xi, self._t = xi, t

    def sigma_at(
        self, rows: NDArray[np.integer[Any]], cols: NDArray[np.integer[Any]]
    ) -> NDArray[np.float64]:
        """Largest sigma_{d,k} over the diameters at integer pixels (rows, cols)."""
        height, width = self._shape
        best = np.zeros(np.shape(rows))
        for diameter in self._diameters:
            half = diameter // 2
            r0, r1 = np.clip(rows - half, 0, height), np.clip(rows + half + 1, 0, height)
            c0, c1 = np.clip(cols - half, 0, width), np.clip(cols + half + 1, 0, width)
            area = (r1 - r0) * (c1 - c0)

            def window(table: NDArray[np.float64]) -> NDArray[np.float64]:
                total: NDArray[np.float64] = (
                    table[r1, c1] - table[r0, c1] - table[r1, c0] + table[r0, c0]  # noqa: B023
                )
                return total

            mean = window(self._sum) / area
            variance = np.maximum(window(self._square_sum) / area - mean * mean, 0.0)
            np.maximum(best, np.sqrt(variance), out=best)
        return best

    def at(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """s_k of Eq. (3) at (N, 2) points (their nearest pixels)."""
        pixel = np.round(xy).astype(np.intp)
        height, width = self._shape
        rows, cols = pixel[:, 1], pixel[:, 0]
        sigma = self.sigma_at(np.clip(rows, 0, height - 1), np.clip(cols, 0, width - 1))
        return self.from_sigma(sigma)

    def from_sigma(self, sigma: NDArray[np.float64]) -> NDArray[np.float64]:
        """Eq. (3): s = 1 - exp(-(sigma / xi) ** t)."""
        structure: NDArray[np.float64] = 1.0 - np.exp(-np.power(sigma / self._xi, self._t))
        return structure

    def quantile(self, q: float) -> float:
        """The ``q`` quantile of s_k over the frame (every few pixels)."""
        height, width = self._shape
        step = STRUCTURE_SAMPLE_STEP_PX
        # At least one sample where the frame is narrower than half a step.
        first_row, first_col = min(step // 2, height - 1), min(step // 2, width - 1)
        rows, cols = np.mgrid[first_row:height:step, first_col:width:step]
        return float(np.quantile(self.from_sigma(self.sigma_at(rows, cols)), q))


#: The largest factor :func:`area_reduced` sums blocks for itself: a block of 16 x 16
#: 16-bit pixels sums to under 2^24, exact in OpenCV's float32 sums as in its own, and
#: one of 8-bit pixels to under 2^16.
_MAX_BLOCK_SUM_FACTOR = 16


def area_reduced(image: NDArray[Any], size: tuple[int, int]) -> NDArray[Any]:
    """``cv2.resize(image, size, interpolation=cv2.INTER_AREA)``, bit for bit.

    Where an 8- or 16-bit image shrinks by one whole factor above 2 in both
    directions, OpenCV sums each block in scalar code (~3 ms for a 12 MP frame by
    8); adding the block's rows and then its columns as strided views gives the
    same sums in about two thirds of the time, and they are rounded as OpenCV
    rounds them: the sum times the float32 reciprocal of the block's area, to
    nearest even.

    Args:
        image: (H, W) image.
        size: (width, height) of the result.
    """
    height, width = image.shape
    factor = height // size[1]
    if (
        image.dtype not in (np.uint8, np.uint16)
        or not 2 < factor <= _MAX_BLOCK_SUM_FACTOR
        or (width, height) != (size[0] * factor, size[1] * factor)
    ):
        return cast(NDArray[Any], cv2.resize(image, size, interpolation=cv2.INTER_AREA))
    # 16-bit sums of 8-bit pixels: half the memory to pass over of 32-bit ones.
    rows: NDArray[np.unsignedinteger[Any]] = image[::factor].astype(
        np.uint16 if image.dtype == np.uint8 else np.uint32
    )
    for row in range(1, factor):
        rows += image[row::factor]
    sums = rows[:, ::factor].copy()
    for col in range(1, factor):
        sums += rows[:, col::factor]
    mean = sums.astype(np.float32) * (np.float32(1.0) / np.float32(factor * factor))
    return cast(NDArray[Any], np.rint(mean).astype(image.dtype))


def local_mean_lattice_px(window_px: int) -> int:
    """Grid of the local-mean map of Eq. (2), px: the frame reduced by an eighth of the window.

    :class:`LocalGamma` measures the local mean on that reduced frame and aligns
    every region to its grid, so regions snapped to it change no score.
    """
    return max(1, window_px // _LOCAL_MEAN_REDUCTION)


def point_windows(xy: NDArray[np.float64]) -> NDArray[np.int64]:
    """(N, 4) windows (x0, y0, x1, y1), end-exclusive, of the 2 x 2 pixels around each point.

    Given to :class:`LocalGamma` as ``regions``, they are where it reads the local
    means of Eq. (2) at (N, 2) points ``xy`` and nowhere else.
    """
    corner = np.floor(xy).astype(np.int64)
    return np.hstack([corner, corner + 2])


def regions_and_points(
    regions: NDArray[np.integer[Any]] | None, xy: NDArray[np.float64]
) -> NDArray[np.integer[Any]] | None:
    """:class:`LocalGamma`'s ``regions`` where a pass searches ``regions`` and reads at ``xy``.

    A tracking pass's seeds (:attr:`~marker_localizer.core.result.SearchPlan.seeds`)
    lie anywhere; the local means of Eq. (2) are looked up at each one's centre, so
    their :func:`point_windows` join the regions. None (the whole frame) stays None.
    """
    if regions is None or not len(xy):
        return regions
    return np.vstack([np.reshape(regions, (-1, 4)), point_windows(xy)])


class LocalGamma:
    """Eq. (2) evaluated only where the detector samples the image.

    The local mean luminance mu(k) of Eq. (2) varies slowly (its window is larger
    than a marker), so it is measured once on a reduced image and the gamma
    L' = L ** (alpha * mu) is applied to the samples of each candidate instead of
    to every pixel of the frame: the same values, at a fraction of the cost on
    12-megapixel frames. With ``regions`` only those windows (plus the mean's
    margin) are read, which is what makes tracking mode independent of the frame
    size.

    Args:
        image: (H, W) grey image in its native dtype.
        full_scale: the value of white in ``image`` (255 for uint8).
        alpha: contrast-adaptive scale alpha of Eq. (2).
        window_px: side of the box measuring mu(k).
        gamma_limits: (low, high) clip of the gamma.
        regions: optional (K, 4) windows (x0, y0, x1, y1), end-exclusive; points
            are then only looked up inside them.
    """

    def __init__(
        self,
        image: NDArray[Any],
        full_scale: float,
        alpha: float,
        window_px: int,
        gamma_limits: tuple[float, float] = GAMMA_LIMITS,
        regions: NDArray[np.integer[Any]] | None = None,
    ) -> None:
        self._reduction = local_mean_lattice_px(window_px)
        self._diameter = max(1, round(window_px / self._reduction)) | 1
        self._alpha = alpha
        self._limits = gamma_limits
        self._full_scale = full_scale
        height, width = image.shape
        if regions is None:
            boxes = np.array([[0, 0, width, height]])
        else:
            margin = window_px // 2 + self._reduction
            boxes = np.asarray(regions, dtype=np.int64).reshape(-1, 4) + [
                -margin,
                -margin,
                margin,
                margin,
            ]
            # Align both ends to the reduction grid: every map then averages the same
            # blocks as the full frame's (a region whose size is off the grid would be
            # reduced by a non-integer factor, its means, and so the scores, shifted).
            boxes[:, :2] -= boxes[:, :2] % self._reduction
            boxes[:, 2:] += -boxes[:, 2:] % self._reduction
            boxes = np.clip(boxes, 0, [width, height, width, height])
            boxes = boxes[(boxes[:, 2] > boxes[:, 0]) & (boxes[:, 3] > boxes[:, 1])]
            if not len(boxes):
                boxes = np.array([[0, 0, width, height]])
        self._boxes = boxes
        maps = [self._mean_map(image[y0:y1, x0:x1]) for x0, y0, x1, y1 in boxes]
        # The maps raveled one after the other (no padding: a wide band and a tall one
        # would each be padded to both sizes), so a lookup is one gather for all points.
        self._map_shapes = np.array([m.shape for m in maps], dtype=np.int64)
        # The first region and its map's shape as Python numbers, for one map's lookups.
        self._box = tuple(int(v) for v in boxes[0])
        self._map_shape = tuple(int(v) for v in self._map_shapes[0])
        sizes = self._map_shapes.prod(axis=1)
        self._map_starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        # float64, which the interpolation takes: its gathers then need no conversion.
        self._maps = np.concatenate([m.ravel() for m in maps]).astype(np.float64)
        # Each map row's lowest mean, for the darkest mean along an image row.
        self._darkest_in_row = np.concatenate([m.min(axis=1) for m in maps])
        # With one map, the darkest of the four means each map cell interpolates between
        # (the cell's own and those right of and below it).
        self._darkest_near = (
            cv2.erode(maps[0], np.ones((2, 2), np.uint8), anchor=(0, 0)) if len(maps) == 1 else None
        )
        #: The lowest local mean luminance in the measured area, in [0, 1].
        self.darkest_mean = float(self._darkest_in_row.min())

    def _mean_map(self, crop: NDArray[Any]) -> FloatImage:
        height, width = crop.shape
        small = area_reduced(
            crop, (max(2, width // self._reduction), max(2, height // self._reduction))
        ).astype(np.float32) / np.float32(self._full_scale)
        return box_mean(small, self._diameter)

    def darkest_mean_on_rows(self, y: NDArray[np.float64]) -> NDArray[np.float64]:
        """(N,) the lowest local mean mu(k) in [0, 1] along each of the image rows ``y``.

        A bound on :meth:`mean_at` at any point of the row: the lower of the two map
        rows it interpolates between, the lowest over all regions where several
        are measured (0.5 where none is).
        """
        if len(self._boxes) > 1:
            return np.full(len(y), self.darkest_mean)
        (y0, y1), rows = self._boxes[0, 1::2], int(self._map_shapes[0, 0])
        first = self._map_cell(y, y0, rows)
        darkest = np.minimum(self._darkest_in_row[first], self._darkest_in_row[first + 1])
        return np.where((y >= y0) & (y < y1), darkest, 0.5)

    def darkest_mean_on_spans(
        self, y: NDArray[np.float64], x_first: NDArray[np.float64], x_last: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """(N, S) the lowest local mean mu(k) along each image row ``y`` within each span.

        The spans are columns ``x_first`` to ``x_last`` (S,), inclusive. A bound on
        :meth:`mean_at` at any point of the span, tighter than the whole row's where
        the light changes across it: the darkest of the four means each point there
        interpolates between, where one map is measured; the row's
        (:meth:`darkest_mean_on_rows`) where several are.
        """
        if self._darkest_near is None:
            return np.repeat(self.darkest_mean_on_rows(y)[:, None], len(x_first), axis=1)
        x0, y0, x1, y1 = self._boxes[0]
        rows, cols = self._map_shapes[0]
        first, last = self._map_cell(x_first, x0, cols), self._map_cell(x_last, x0, cols)
        # Each span's map columns, its last one repeated to the longest span's count.
        columns = np.minimum(
            first[:, None] + np.arange(int((last - first).max()) + 1), last[:, None]
        )
        map_rows, row_of = np.unique(self._map_cell(y, y0, rows), return_inverse=True)
        darkest = self._darkest_near[map_rows][:, columns].min(axis=2)[row_of]
        # Outside the measured region mean_at is 0.5.
        beyond = (x_first < x0) | (x_last >= x1)
        darkest[:, beyond] = np.minimum(darkest[:, beyond], 0.5)
        return np.where(((y >= y0) & (y < y1))[:, None], darkest, 0.5)

    def _map_cell(self, position: NDArray[np.float64], origin: int, size: int) -> NDArray[np.intp]:
        """The map cell, along one axis, whose mean a point's interpolates from.

        As :meth:`_map_position` places it: image ``position`` in a region starting at
        ``origin``, on a map ``size`` cells long.
        """
        local = np.clip((position - origin + 0.5) / self._reduction - 0.5, 0.0, size - 1.001)
        return np.floor(local).astype(np.intp)

    def mean_at(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """Local mean luminance mu(k) in [0, 1] at (N, 2) points (0.5 outside every region)."""
        start, cols, x, y, inside = self._map_position(xy)
        x0, y0 = np.floor(x), np.floor(y)
        base = start + y0.astype(np.int64) * cols + x0.astype(np.int64)
        mean = interpolate(*corners(self._maps, base, cols), x - x0, y - y0)
        return np.where(inside, mean, 0.5)

    def _map_position(
        self, xy: NDArray[np.float64]
    ) -> tuple[
        NDArray[np.int64] | int,
        NDArray[np.int64] | int,
        NDArray[np.float64],
        NDArray[np.float64],
        NDArray[np.bool_],
    ]:
        """Where each of (N, 2) points is looked up, on the map of the region it lies in.

        Returns:
            The start of the point's map in the raveled maps, the map's row length,
            (N,) x and y on it, and (N,) whether the point lies in a region. Outside
            every region the point is given the first map.
        """
        boxes = self._boxes
        if len(boxes) == 1:
            # One map (the whole frame): its origin and shape are Python numbers for
            # every point, where the points' (N, 1) tests and gathers of them took half
            # of a lookup of a few points, and the whole row length reads the corners
            # as views (sampling.corners).
            (x_start, y_start, x_end, y_end), (rows, cols) = self._box, self._map_shape
            inside = (
                (xy[:, 0] >= x_start)
                & (xy[:, 0] < x_end)
                & (xy[:, 1] >= y_start)
                & (xy[:, 1] < y_end)
            )
            start: NDArray[np.int64] | int = 0
            origin = boxes[0, :2]
        else:
            in_box = (
                (xy[:, None, 0] >= boxes[:, 0])
                & (xy[:, None, 0] < boxes[:, 2])
                & (xy[:, None, 1] >= boxes[:, 1])
                & (xy[:, None, 1] < boxes[:, 3])
            )
            inside = cast("NDArray[np.bool_]", in_box.any(axis=1))
            owner = np.argmax(in_box, axis=1)
            origin = boxes[owner, :2]
            rows, cols = self._map_shapes[owner].T
            start = self._map_starts[owner]
        # INTER_AREA maps x to (x + 0.5) / f - 0.5 on the reduced grid.
        local = (xy - origin + 0.5) / self._reduction - 0.5
        # Maps are at least 2 x 2, so the four corners stay inside the point's own map.
        x = local[:, 0].clip(0.0, cols - 1.001)
        y = local[:, 1].clip(0.0, rows - 1.001)
        return start, cols, x, y, inside

    def __call__(self, values: NDArray[np.float64], xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """Apply Eq. (2) to raw samples ``values`` (N, ...) taken around the points ``xy``."""
        mean = self.mean_at(xy).reshape((-1,) + (1,) * (values.ndim - 1))
        luminance = values / self._full_scale
        return apply_gamma(luminance, mean, self._alpha, self._limits, out=luminance)


#: Most a raw contrast floor is lowered under dark surroundings
#: (:meth:`ShadowedContrast.gain`): 4 takes the default 20 DN to 5 DN for the screening
#: and 2.5 DN for the rings and the fit, above an 8-bit camera's quantisation and JPEG
#: noise (1-2 DN); darker still, ground 6 DN dark, is beyond what is sought.
MAX_SHADOW_GAIN = 4.0


@dataclass(frozen=True)
class ShadowedContrast:
    """How far the raw contrast floors follow the light down into a shadow (Weber).

    A print's contrast scales with the light on it: a marker of modulation m under a
    mean level L has contrast 2 m L. After Eq. (2) such a marker keeps its contrast,
    which the symmetry check measures; in raw grey levels, which the screening, the
    prescreen and the fit's floor read, it does not. So the floors follow the light
    down (:meth:`gain`), and the screening's caps rank saddles by their contrast
    over their light (:meth:`weight`), not by their raw response, in which bright
    ground's texture outweighs a marker under dim light.

    Attributes:
        min_contrast: the contrast floor in the open, a share of white.
        min_modulation: the modulation the checks ask of a marker.
    """

    min_contrast: float
    min_modulation: float

    def weight(self, mean: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """How much a contrast under the local mean ``mean`` weighs against the floor's.

        The floor over 2 m L: a print's contrast over what the least modulation gives
        under that light (Weber), at most :data:`MAX_SHADOW_GAIN`. Over 1 where the
        light is dim (a mean under 33 DN at the defaults), under 1 where it is bright.
        """
        weber = 2.0 * self.min_modulation * np.asarray(mean, np.float64)
        with np.errstate(divide="ignore"):
            weight = self.min_contrast / weber
        return np.minimum(weight, MAX_SHADOW_GAIN)

    def gain(self, mean: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """How far the raw contrast floors are lowered where the local mean is ``mean``.

        Where 2 m L falls below the floor (a mean under 33 DN at the defaults) the
        floors follow it down, at most :data:`MAX_SHADOW_GAIN`-fold: the :meth:`weight`
        there; elsewhere they stay (gain 1), and with them the time on ordinary ground.
        """
        return np.maximum(self.weight(mean), 1.0)

    def weight_on_spans(
        self,
        gamma: LocalGamma,
        y: NDArray[np.float64],
        x_first: NDArray[np.float64],
        x_last: NDArray[np.float64],
    ) -> NDArray[np.float64]:
        """(N, S) a bound on :meth:`weight` along each row ``y`` within each span of columns.

        From :meth:`LocalGamma.darkest_mean_on_spans`: the weight falls as the mean
        rises, so the darkest mean bounds it from above.
        """
        return self.weight(gamma.darkest_mean_on_spans(y, x_first, x_last))

    def gain_at(self, gamma: LocalGamma, xy: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """(N,) :meth:`gain` at ``xy``; None where no surroundings are that dark.

        Looked up only for the points on rows that hold such a mean: on real ground
        a shadow takes a few rows, and the prescreen asks for 20 000 points.
        """
        if self.gain(gamma.darkest_mean) == 1.0:
            return None
        gain = np.ones(len(xy))
        dark = np.flatnonzero(self.gain(gamma.darkest_mean_on_rows(xy[:, 1])) > 1.0)
        gain[dark] = self.gain(gamma.mean_at(xy[dark]))
        return gain
