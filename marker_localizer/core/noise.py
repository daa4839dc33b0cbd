"""The frame's sensor noise, so that every decision reads in noise units.

A marker's evidence (the contrast of its edges, how well the template fits it)
means something only against the noise it is measured in: 10 DN of contrast is a
clear X in a clean dark frame and nothing in a noisy bright one. The package's
decisions therefore use noise-relative statistics, and this module measures the
noise once per frame.

Sensors add Poisson-Gaussian noise, so the variance grows with the signal:
sigma^2(I) = read^2 + gain * I. Both terms are estimated from the frame itself
with Immerkaer's Laplacian-difference operator (Immerkaer 1996), whose response
to any locally linear image is zero, evaluated on a fixed sparse lattice of
pixels (a few tens of thousands, whatever the frame size), and read only where
the image is smooth: texture and edges answer the operator too, and would be
taken for noise.

References:
    J. Immerkaer, "Fast Noise Variance Estimation", Computer Vision and Image
    Understanding 64(2), 1996.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from marker_localizer.core.sampling import nearest_pixels

#: Pixels of the sparse lattice the noise is measured on: enough for a 1 % estimate
#: per brightness bin, a fixed cost on any frame size.
_LATTICE_PIXELS = 40_000
#: Immerkaer's mask [[1, -2, 1], [-2, 4, -2], [1, -2, 1]] has this L2 norm: its
#: response to white noise of std sigma has std 6 sigma.
_MASK_NORM = 6.0
#: Share of the lattice, by ascending local gradient, that counts as smooth. Texture
#: and edges raise the operator's response; the smoothest third of a frame is
#: ground texture's flattest parts on real aerial frames and the plates and quadrants
#: on rendered ones.
_SMOOTH_SHARE = 1.0 / 3.0
#: Brightness bins of the signal-dependent fit sigma^2 = read^2 + gain * I.
_LEVEL_BINS = 6
#: Fewest pixels of a bin whose smoothest share gives its robust std; a bin with
#: fewer (a frame's few brightest or darkest pixels) is left out of the fit.
_MIN_BIN_PIXELS = 50
#: |N(0, 1)| has this mean, sqrt(2 / pi): a bin's std is its mean |response| over it
#: (Immerkaer's estimator; a median would be quantised by 8-bit data). The response is
#: even in the neighbours and the gradient odd, so on white noise the two are
#: uncorrelated and picking the smoothest pixels does not lower the response.
_HALF_NORMAL_MEAN = float(np.sqrt(2.0 / np.pi))
#: Smallest noise std reported, in grey levels of an 8-bit frame: the quantisation of
#: a noise-free 8-bit frame (1 / sqrt(12) DN) keeps every statistic finite.
_QUANTISATION_STD_DN = 1.0 / np.sqrt(12.0)
#: Half-width of the square around each point whose pixels give the frame's grey step
#: (:func:`grey_step`), px: an X's two lines cross there, so a 9 x 9 square holds some
#: 30 pixels of its blurred edges, whose levels lie between the paints'.
_STEP_WINDOW_HALF_PX = 4
#: Widest range of an integer frame's five-pixel sums over the lattice that the
#: quantiles take from histograms (:func:`_smooth_bins_counted`): 8-bit frames and
#: 16-bit ones of up to ~13 bits of range; wider ones partition as before.
_MAX_COUNTED_RANGE = 2**16


class NoiseModel(NamedTuple):
    """Signal-dependent noise of one frame, in the image's own grey units.

    Attributes:
        read_variance: variance at zero signal (read noise and quantisation).
        gain: variance added per grey level of signal (shot noise).
        floor_std: smallest std the model reports (the quantisation).
    """

    read_variance: float
    gain: float
    floor_std: float

    def std(self, level: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Noise std at grey ``level`` (any shape), image units."""
        variance = self.read_variance + self.gain * np.maximum(level, 0.0)
        std: NDArray[np.float64] = np.maximum(np.sqrt(np.maximum(variance, 0.0)), self.floor_std)
        return std


def estimate_noise(image: NDArray[Any], full_scale: float) -> NoiseModel:
    """Estimate the frame's Poisson-Gaussian noise sigma^2 = read^2 + gain * I.

    Args:
        image: (H, W) grey image, native dtype.
        full_scale: the value of white in ``image`` (255 for uint8).

    Returns:
        :class:`NoiseModel` in the image's grey units.
    """
    floor = _QUANTISATION_STD_DN * full_scale / 255.0
    height, width = image.shape
    if height < 3 or width < 3:
        return NoiseModel(floor**2, 0.0, floor)
    stride = max(1, int(np.sqrt((height - 2) * (width - 2) / _LATTICE_PIXELS)))

    def at(dy: int, dx: int) -> NDArray[np.float64]:
        # The lattice's pixels moved by (dy, dx), row by row: a strided view, which
        # spares forming a flat index per pixel and look-up (0.5 ms of 6 on 12 MP).
        rows = slice(1 + dy, height - 1 + dy, stride)
        cols = slice(1 + dx, width - 1 + dx, stride)
        samples: NDArray[np.float64] = image[rows, cols].astype(np.float64).reshape(-1)
        return samples

    north, south, west, east = at(-1, 0), at(1, 0), at(0, -1), at(0, 1)
    corners = at(-1, -1) + at(-1, 1) + at(1, -1) + at(1, 1)
    middle = at(0, 0)
    response = corners - 2.0 * (north + south + west + east) + 4.0 * middle
    gradient = np.abs(east - west) + np.abs(south - north)
    level_sum = middle + north + south + west + east
    level = level_sum / 5.0
    # Per brightness bin, the robust std of the response at the bin's smoothest
    # pixels; then the affine fit of the variance in the level (least squares, both
    # terms kept non-negative).
    counted = image.dtype.kind in "ui" and float(np.ptp(level_sum)) < _MAX_COUNTED_RANGE
    if counted:
        bin_of, smooth = _smooth_bins_counted(level_sum, gradient)
    else:
        edges = np.quantile(level, np.linspace(0.0, 1.0, _LEVEL_BINS + 1))
        bin_of = np.clip(np.searchsorted(edges, level, side="right") - 1, 0, _LEVEL_BINS - 1)
    means, variances = [], []
    for b in range(_LEVEL_BINS):
        members = np.flatnonzero(bin_of == b)
        if len(members) < _MIN_BIN_PIXELS:
            continue
        if counted:
            members = members[smooth[members]]
        else:
            members = members[gradient[members] <= np.quantile(gradient[members], _SMOOTH_SHARE)]
        std = np.mean(np.abs(response[members])) / (_HALF_NORMAL_MEAN * _MASK_NORM)
        means.append(level[members].mean())
        variances.append(std**2)
    if not variances:
        return NoiseModel(floor**2, 0.0, floor)
    means_a, variances_a = np.array(means), np.array(variances)
    if len(means_a) >= 2 and np.ptp(means_a) > 0:
        gain, read = np.polyfit(means_a, variances_a, 1)
        if gain < 0.0:
            gain, read = 0.0, float(np.median(variances_a))
        elif read < 0.0:
            gain, read = float(np.sum(means_a * variances_a) / np.sum(means_a**2)), 0.0
    else:
        gain, read = 0.0, float(variances_a[0])
    return NoiseModel(float(max(read, floor**2)), float(gain), floor)


def grey_step(image: NDArray[Any], xy: NDArray[np.float64]) -> float:
    """The frame's grey-level step q: the smallest difference of two levels around the points.

    A quantiser's step is at most the smallest difference of two levels it wrote:
    1 on an 8-bit frame of any noise (or on one whose blurred edges take
    neighbouring levels), 255 on a thresholded one (0 and 255), 85 on a frame of
    four levels. Read on the squares of :data:`_STEP_WINDOW_HALF_PX` around the
    points, where their X's edges take the levels between the paints': a frame's
    flat ground may hold few levels where its markers hold many.

    Args:
        image: (H, W) grey image, native dtype.
        xy: (N, 2) points (x, y), px.

    Returns:
        q in the image's grey units; 0 where the squares hold one level only (no
        step seen).
    """
    offsets = np.arange(-_STEP_WINDOW_HALF_PX, _STEP_WINDOW_HALF_PX + 1, dtype=np.float64)
    dx, dy = np.meshgrid(offsets, offsets)
    square = np.stack([dx.reshape(-1), dy.reshape(-1)], axis=1)
    around = (np.asarray(xy, np.float64)[:, None, :] + square[None, :, :]).reshape(-1, 2)
    steps = np.diff(np.unique(nearest_pixels(image, around)).astype(np.float64))
    return float(steps.min()) if len(steps) else 0.0


def _smooth_bins_counted(
    level_sum: NDArray[np.float64], gradient: NDArray[np.float64]
) -> tuple[NDArray[np.intp], NDArray[np.bool_]]:
    """Each lattice pixel's brightness bin and whether it is among its bin's smoothest.

    What :func:`estimate_noise` reads with :func:`numpy.quantile` on a float frame,
    taken bit for bit from counts on an integer one: there the five-pixel sums and
    the gradients are integers, so their order statistics come from histograms
    (one pass, where the quantiles partition the lattice seven times and each bin
    once more: 2.5 of the estimate's ~5 ms on 12 MP), and the quantiles' own
    interpolation is numpy's (:func:`_quantiles_from`).

    Args:
        level_sum: (P,) the five-pixel sums, integer-valued (range below
            :data:`_MAX_COUNTED_RANGE`).
        gradient: (P,) the lattice's gradients, integer-valued (range below twice it).

    Returns:
        (P,) the bins (as ``searchsorted`` on the level's quantiles gives them) and
        (P,) True where the gradient is at most its bin's :data:`_SMOOTH_SHARE`
        quantile.
    """
    sums = level_sum.astype(np.intp)
    lowest = int(sums.min())
    sums -= lowest
    counts = np.cumsum(np.bincount(sums))
    n = len(sums)

    def level_at(rank: NDArray[np.intp]) -> NDArray[np.float64]:
        # The rank-th smallest sum, as the level it is: sum / 5 in float64, as
        # estimate_noise divides it.
        value: NDArray[np.float64] = (np.searchsorted(counts, rank, side="right") + lowest) / 5.0
        return value

    edges = _quantiles_from(
        level_at, np.full(_LEVEL_BINS + 1, n), np.linspace(0.0, 1.0, _LEVEL_BINS + 1)
    )
    # The bin of every possible sum, looked up: the same comparisons of the same
    # float64 levels as searchsorted on the lattice.
    possible = (np.arange(len(counts)) + lowest) / 5.0
    bin_of_sum = np.clip(np.searchsorted(edges, possible, side="right") - 1, 0, _LEVEL_BINS - 1)
    bin_of: NDArray[np.intp] = bin_of_sum[sums]
    steps = gradient.astype(np.intp)
    width = int(steps.max()) + 1
    in_bin = np.cumsum(
        np.bincount(bin_of * width + steps, minlength=_LEVEL_BINS * width).reshape(
            _LEVEL_BINS, width
        ),
        axis=1,
    )
    members = in_bin[:, -1]

    def gradient_at(rank: NDArray[np.intp]) -> NDArray[np.float64]:
        # The rank-th smallest gradient of each bin (rank one per bin).
        found = [np.searchsorted(in_bin[b], r, side="right") for b, r in enumerate(rank)]
        return np.array(found, dtype=np.float64)

    threshold = _quantiles_from(
        gradient_at, np.maximum(members, 1), np.full(_LEVEL_BINS, _SMOOTH_SHARE)
    )
    smooth: NDArray[np.bool_] = gradient <= threshold[bin_of]
    return bin_of, smooth


def _quantiles_from(
    ranked: Callable[[NDArray[np.intp]], NDArray[np.float64]],
    n: NDArray[np.int64],
    q: NDArray[np.floating[Any]],
) -> NDArray[np.float64]:
    """``numpy.quantile`` (linear) of K sets of values from their order statistics, bit for bit.

    numpy places quantile ``q`` of n values at (n - 1) q, between the order
    statistics below and above it, and interpolates by its own lerp; the lerp is
    numpy's here too: the quantile of each pair at its fraction, one call for all
    K pairs (the diagonal of their K x K quantiles).

    Args:
        ranked: the k-th smallest value of each set, k (K,) zero-based.
        n: (K,) each set's size (>= 1).
        q: (K,) the quantile of each set.
    """
    position = (n - 1) * q
    below = np.floor(position)
    rank = below.astype(np.intp)
    pairs = np.stack([ranked(rank), ranked(np.minimum(rank + 1, n - 1))])
    values: NDArray[np.float64] = np.diagonal(np.quantile(pairs, position - below, axis=0)).copy()
    return values
