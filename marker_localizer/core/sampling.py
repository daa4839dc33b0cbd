"""Bilinear sampling of an image at arbitrary float64 positions.

``cv2.remap`` quantises sub-pixel positions to 1/32 px, which would cap the
refinement at ~0.03 px; this gathers the four neighbours in numpy instead.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, TypeVar, cast

import numpy as np
from numpy.typing import NDArray

#: Maps raw samples (N, ...) taken around points (N, 2) to normalised intensities,
#: e.g. :class:`~marker_localizer.core.preprocessing.LocalGamma`.
Normaliser = Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]]

_Result = TypeVar("_Result")
#: Rows and columns of the cell of pixels a bilinear sample reads.
_CELL_PX = 2


def corners(
    flat: NDArray[Any], base: NDArray[np.integer[Any]], stride: NDArray[np.integer[Any]] | int
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The four pixels (top-left, top-right, bottom-left, bottom-right) from ``base``.

    Args:
        flat: a raveled image, or several raveled images one after the other.
        base: flat index of each top-left pixel.
        stride: row length of the image each index lies in.

    Returns:
        Four float64 arrays: differences of uint8/uint16 samples would wrap around.
    """
    # The gathers are fresh arrays: a float64 image's need no copy.
    if not isinstance(stride, int):
        return (
            flat[base].astype(np.float64, copy=False),
            flat[base + 1].astype(np.float64, copy=False),
            flat[base + stride].astype(np.float64, copy=False),
            flat[base + stride + 1].astype(np.float64, copy=False),
        )
    # One row length: the other three pixels are those at ``base`` of the image
    # shifted by their offsets (views), without three passes of index arithmetic.
    return (
        flat[base].astype(np.float64, copy=False),
        flat[1:][base].astype(np.float64, copy=False),
        flat[stride:][base].astype(np.float64, copy=False),
        flat[stride + 1 :][base].astype(np.float64, copy=False),
    )


def interpolate(
    v00: NDArray[np.float64],
    v01: NDArray[np.float64],
    v10: NDArray[np.float64],
    v11: NDArray[np.float64],
    fx: NDArray[np.float64],
    fy: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Bilinear interpolation between four corner values at fractions (fx, fy)."""
    top = v00 + (v01 - v00) * fx
    bottom = v10 + (v11 - v10) * fx
    return top + (bottom - top) * fy


def pad_patterns(
    patterns: Sequence[NDArray[np.float64]],
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Stack (K_i, ...) sample patterns as one (P, K, ...) array, zero-padded to the longest.

    Points whose patterns differ in size (one per marker radius) then take one set
    of array operations: for a few dozen points the calls, not the samples, are
    the cost.

    Returns:
        (stack, present): the padded float64 stack and the (P, K) mask of its real
        entries.
    """
    length = max(len(pattern) for pattern in patterns)
    stack = np.zeros((len(patterns), length) + np.shape(patterns[0])[1:])
    present = np.zeros((len(patterns), length), dtype=bool)
    for k, pattern in enumerate(patterns):
        stack[k, : len(pattern)] = pattern
        present[k, : len(pattern)] = True
    return stack, present


def size_batches(lengths: Sequence[int], ratio: float) -> list[NDArray[np.intp]]:
    """Indices of the patterns in batches whose lengths lie within ``ratio`` of each other.

    Every point of a :func:`pad_patterns` stack pays for its longest pattern: in
    such batches a large marker does not make the small ones costly.
    """
    size_class = np.floor(np.log(np.maximum(lengths, 1)) / np.log(ratio))
    return [np.flatnonzero(size_class == size) for size in np.unique(size_class)]


def nan_median(values: NDArray[np.float64]) -> NDArray[np.float64]:
    """``np.nanmedian(values, axis=1)``, bit for bit, where each has one value or more.

    Along axis 1 of (M, J) values, or of (M, J, ...) with the trailing axes kept
    (the rings' crossings, :func:`~marker_localizer.core.verification.line_crossing_centres`).

    For a few rows numpy takes the median through a masked array (``np.ma.median``:
    ~0.6 ms a call of ~0.05 ms of arithmetic); its arithmetic is this: the values
    sorted (NaN last, as the mask's fill puts them), the two middle ones of those
    present (the one twice where their count is odd) summed and halved.
    """
    ordered = np.sort(values, axis=1)
    present = np.count_nonzero(~np.isnan(values), axis=1)[:, None]
    high = present // 2
    low = np.where(present % 2 == 1, high, high - 1)
    pair = np.take_along_axis(ordered, np.concatenate([low, high], axis=1), axis=1)
    # The pair summed as the masked median sums it (a reduction over the axis, which
    # gives +0.0 for two -0.0, where pair[:, 0] + pair[:, 1] would give -0.0).
    median: NDArray[np.float64] = pair.sum(axis=1) / 2.0
    return median


def in_blocks(function: Callable[..., _Result], block: int, *per_point: NDArray[Any]) -> _Result:
    """``function`` over consecutive blocks of ``block`` points, its outputs concatenated.

    For work whose result for a point depends on that point alone: a few hundred
    points' (points, samples) temporaries stay in the processor's cache across
    numpy's passes, where those of 10^4 points go out to memory on every pass.

    Args:
        function: takes the ``per_point`` arrays (their first axis the points) and
            returns an array or a tuple (or NamedTuple) of arrays, each with the
            points along its first axis.
        block: points per call.
        per_point: arrays sliced along their first axis.
    """
    count = len(per_point[0])
    if count <= block:
        return function(*per_point)
    parts = [
        function(*(array[start : start + block] for array in per_point))
        for start in range(0, count, block)
    ]
    if isinstance(parts[0], np.ndarray):
        return cast("_Result", np.concatenate(cast("list[NDArray[Any]]", parts)))
    fields = [np.concatenate(field) for field in zip(*parts, strict=True)]
    return cast("_Result", getattr(type(parts[0]), "_make", tuple)(fields))


def _neighbours(
    image: NDArray[Any], x: NDArray[np.float64], y: NDArray[np.float64]
) -> tuple[
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.bool_],
]:
    """The four pixels around each (x, y) as float64, the fractions, and validity.

    ``x`` and ``y`` broadcast against each other and are read as float64: the floors
    and fractions below are fresh arrays of their common shape, written in place.
    """
    height, width = image.shape
    if height < _CELL_PX or width < _CELL_PX:
        # A row or a column alone (a crop at a frame's edge) holds no cell: it is read
        # with its edge repeated, as the clamp reads the border, and no sample is valid.
        cell = ((0, max(_CELL_PX - height, 0)), (0, max(_CELL_PX - width, 0)))
        v00, v01, v10, v11, fx, fy, valid = _neighbours(np.pad(image, cell, "edge"), x, y)
        return v00, v01, v10, v11, fx, fy, valid & False
    # Broadcast, and clamped by the method, only as needed: numpy's wrappers cost a
    # few microseconds a call, a tenth of a call's time on a fit's few hundred samples.
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    if x.shape != y.shape:
        x, y = np.broadcast_arrays(x, y)
    x0 = np.floor(x)
    y0 = np.floor(y)
    column = x0.clip(0, width - _CELL_PX)
    row = y0.clip(0, height - _CELL_PX).astype(np.float64, copy=False)
    # A pixel is inside where the clamp left it; a NaN's clamp is NaN, unequal too.
    valid = column == x0
    valid &= row == y0
    # The flat index formed in float64 (exact below 2^53): one conversion to integers.
    row *= width
    row += column
    v00, v01, v10, v11 = corners(image.reshape(-1), row.astype(np.intp), width)
    # The fractions over the floors, which are done with (arrays but for a 0-d x).
    if x0.ndim:
        return v00, v01, v10, v11, np.subtract(x, x0, out=x0), np.subtract(y, y0, out=y0), valid
    return v00, v01, v10, v11, x - x0, y - y0, valid


def nearest_pixels(image: NDArray[Any], xy: NDArray[np.float64]) -> NDArray[Any]:
    """(N,) the pixels nearest to (N, 2) points (x, y), clamped to the image, native dtype."""
    height, width = image.shape[:2]
    return image[
        np.clip(np.round(xy[:, 1]).astype(np.intp), 0, height - 1),
        np.clip(np.round(xy[:, 0]).astype(np.intp), 0, width - 1),
    ]


def square_offsets(half: int) -> NDArray[np.int64]:
    """(n, 2) the integer offsets (dx, dy) of a square of side 2 ``half`` + 1, row by row.

    Row by row, so that pixels gathered at them (:func:`pixels_at_offsets`) reshape to
    (..., 2 half + 1, 2 half + 1) windows.
    """
    grid = np.arange(-half, half + 1, dtype=np.int64)
    return np.stack([a.ravel() for a in np.meshgrid(grid, grid)], axis=1)


def pixels_at_offsets(
    image: NDArray[Any], xy: NDArray[np.float64], offsets: NDArray[np.integer[Any]]
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """(N, n, ...) the pixels at integer ``offsets`` (n, 2) from each rounded centre, float64.

    The trailing axes are the image's channels, if any. Also (N,) which centres have
    every offset inside the image (the others read the clamped border).
    """
    centre = np.rint(xy).astype(np.int64)
    reach = np.abs(offsets).max(axis=0)
    height, width = image.shape[:2]
    inside = (
        (centre[:, 0] >= reach[0])
        & (centre[:, 0] < width - reach[0])
        & (centre[:, 1] >= reach[1])
        & (centre[:, 1] < height - reach[1])
    )
    cols = np.clip(centre[:, None, 0] + offsets[None, :, 0], 0, width - 1)
    rows = np.clip(centre[:, None, 1] + offsets[None, :, 1], 0, height - 1)
    return image[rows, cols].astype(np.float64), inside


def bilinear(
    image: NDArray[Any], x: NDArray[np.float64], y: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Sample ``image`` at (x, y) with bilinear interpolation.

    Args:
        image: (H, W) image of any numeric dtype, not empty. Of one row or one
            column, no sample is valid.
        x: column positions (any shape, read as float64), 0 = centre of column 0.
        y: row positions, broadcastable with ``x``.

    Returns:
        (values, valid): float64 samples of the shape of ``x`` and a boolean mask
        that is False where a sample needed pixels outside the image (its value
        is then taken from the clamped border and must not be trusted).
    """
    v00, v01, v10, v11, fx, fy, valid = _neighbours(image, x, y)
    if not v00.ndim:
        return interpolate(v00, v01, v10, v11, fx, fy), valid
    # interpolate's sums and products in the gathers' own arrays, fresh from _neighbours
    # (a + b is b + a to the bit): the same values without temporaries.
    top = np.subtract(v01, v00, out=v01)
    top *= fx
    top += v00
    bottom = np.subtract(v11, v10, out=v11)
    bottom *= fx
    bottom += v10
    bottom -= top
    bottom *= fy
    bottom += top
    return bottom, valid


def bilinear_with_gradient(
    image: NDArray[Any], x: NDArray[np.float64], y: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Bilinear samples and the exact derivatives of the bilinear interpolant.

    Using the interpolant's own derivative (not a finite-difference image sampled
    again) makes Gauss-Newton steps on interpolated samples exact Newton steps of
    the function actually being minimised.

    Returns:
        (values, d_dx, d_dy, valid), each of the shape of ``x``.
    """
    v00, v01, v10, v11, fx, fy, valid = _neighbours(image, x, y)
    # The differences along each row serve the samples and d/dx alike. Each result is
    # written over an array of _neighbours' (all fresh) that is done with: the same
    # sums and products (a + b is b + a to the bit), two new arrays instead of seven.
    top_step = np.subtract(v01, v00, out=v01)
    bottom_step = np.subtract(v11, v10, out=v11)
    top = top_step * fx
    top += v00
    bottom = bottom_step * fx
    bottom += v10
    d_dy = np.subtract(bottom, top, out=v10)
    value = np.multiply(d_dy, fy, out=bottom)
    value += top
    d_dx = np.multiply(top_step, np.subtract(1.0, fy, out=fx), out=top_step)
    d_dx += np.multiply(bottom_step, fy, out=v00)
    return value, d_dx, d_dy, valid
