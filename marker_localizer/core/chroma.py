"""Whether a small X is drawn in luminance alone: a marker's paint is black and white.

A marker's quadrants are neutral paint, so under any light its bright and dark
quadrants share one chromaticity (the light's): a colour frame shows its X in
luminance and not in colour. The saddles natural ground makes are X's of
materials, and materials that differ in brightness differ in hue or saturation
too (dark brown grains between pale sand, shaded and sunlit patches under blue sky
and yellow sun). On a colour frame each detection's X is read in the logarithm of
its pixels' channels: their mean over the channels is its luminance, what is left
its chromaticity. The difference between the two pairs of opposite quadrants'
means is the X's contrast in each; a neutral X's chromatic contrast is a small
share of its luminance's (:func:`x_chroma_share`). The share depends neither on the
channels' order (BGR or RGB) nor, but for a small offset that steadies the dark
levels, on a gain or a gamma common to the channels.

A colour camera samples each colour at some of its pixels only (a Bayer mosaic: red
and blue every second pixel of every second row), and its demosaicing colours the
pixels along a neutral edge. The chromaticity is therefore read at the colour
samples' resolution (:data:`CHROMA_SMOOTHING`), and X's too small to reach past
that colour (:data:`CHROMA_MIN_EXTENT_PX`) are not asked.

The check is asked only of X's of texture's size (:data:`CHROMA_MAX_EXTENT_PX`):
larger X's are judged by their plate and their lines, and a chessboard printed in a
colour on white (pycbd's flare board, blue) is X's drawn in colour on purpose. A
grey frame is not asked. Measured: docs/accuracy-journal.md, "A marker's X is neutral: the
colour of small X's on real colour frames" and "A colour camera's demosaicing".
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from marker_localizer.core import template, verification
from marker_localizer.core.sampling import pixels_at_offsets, square_offsets

#: X's under this extent, px, are asked: the extent up to which ground texture makes
#: X's that pass the rings (:data:`verification.TEXTURE_EXTENT_PX`).
CHROMA_MAX_EXTENT_PX = verification.TEXTURE_EXTENT_PX
#: ... and from this one, px: twice the spacing of a colour sensor's red and blue
#: samples. A smaller X lies within a sample or two of its lines everywhere, where a
#: camera's demosaicing colours a neutral X as much as two materials colour theirs.
CHROMA_MIN_EXTENT_PX = 4.0
#: The disk read, as a share of the X's extent: the paint, short of the plate's edge
#: where a ring ladder's extent overshoots it.
DISK_SHARE = 0.8
#: The smallest disk read, px: a tiny X's quadrants keep a few pixels each.
MIN_DISK_PX = 2.0
#: Pixels nearer than this to either line are left out, px: an edge's pixels mix
#: the two pairs of quadrants.
LINE_MARGIN_PX = 0.75
#: Added to every channel before its logarithm, as a share of white: a dark quadrant's
#: chromaticity is otherwise its noise's (2 levels of 255).
DARK_OFFSET_SHARE = 2.0 / 255.0
#: Fewest pixels each pair of opposite quadrants must keep for a reading.
MIN_QUADRANT_PIXELS = 2
#: The chromaticity is read through this binomial along rows and columns: a colour
#: camera's sensor samples red and blue 2 px apart, so what a frame shows of colour
#: above a quarter cycle a pixel is its demosaicing's false colour along edges, not the
#: scene's. The 3-tap filter passes half of it at that quarter cycle and none at the
#: pixel's half cycle; the luminance is read as it is.
CHROMA_SMOOTHING = np.array([0.25, 0.5, 0.25])


def is_colour(image: NDArray[Any]) -> bool:
    """Whether ``image`` has colour channels (3 or 4) to read, not one grey plane."""
    return image.ndim == 3 and image.shape[2] >= 3


def x_chroma_share(
    colour: NDArray[Any],
    full_scale: float,
    xy: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    line_angles: NDArray[np.float64],
) -> NDArray[np.float64]:
    """(N,) each X's chromatic contrast over its luminance contrast, on a colour frame.

    Over the pixels within :data:`DISK_SHARE` of the extent (at least
    :data:`MIN_DISK_PX`) and :data:`LINE_MARGIN_PX` or more from both lines, with
    L_c = log(channel c + :data:`DARK_OFFSET_SHARE` white): luminance Y = mean_c L_c,
    chromaticity C_c = L_c - Y, smoothed along rows and columns by
    :data:`CHROMA_SMOOTHING`. With d(.) the mean over one pair of opposite quadrants
    less that over the other, the share is |d(C)| / |d(Y)|. NaN where the window leaves
    the frame, or a pair keeps under :data:`MIN_QUADRANT_PIXELS`.

    Args:
        colour: (H, W, C) the frame's colour planes, C >= 3 (a fourth, alpha, is left).
        full_scale: the frame's white, in its levels.
        xy: (N, 2) the X's centres, px.
        radius_px: (N,) their extents, px.
        line_angles: (N, 2) their lines' directions, radians.
    """
    share = np.full(len(xy), np.nan)
    if not len(xy):
        return share
    disk = np.maximum(DISK_SHARE * np.asarray(radius_px, np.float64), MIN_DISK_PX)
    half = int(np.ceil(disk.max())) + 1
    # Gathered the smoothing's reach wider all round, which the smoothing takes off.
    reach = len(CHROMA_SMOOTHING) // 2
    side = 2 * (half + reach) + 1
    pixels, inside = pixels_at_offsets(colour[..., :3], xy, square_offsets(half + reach))
    # A float frame's levels may undershoot 0 a little (image.FLOAT_OVERSHOOT), which
    # image.to_gray clips in the grey: clipped here too, or the log is NaN.
    levels = np.maximum(pixels, 0.0) + DARK_OFFSET_SHARE * full_scale
    logs = np.log(levels).reshape(len(xy), side, side, 3)
    luminance = logs.mean(axis=-1, keepdims=True)
    chromaticity = _smoothed(logs - luminance).reshape(len(xy), -1, 3)
    luminance = luminance[:, reach : side - reach, reach : side - reach, 0].reshape(len(xy), -1)
    offsets = square_offsets(half)
    # Offsets from the sub-pixel centres (a window the border clamps is not read).
    dx, dy = (np.rint(xy)[:, k, None] + offsets[:, k] - xy[:, k, None] for k in (0, 1))
    s1, s2 = template.line_distances(dx, dy, np.asarray(line_angles, np.float64))
    read = (np.hypot(dx, dy) <= disk[:, None]) & (
        np.minimum(np.abs(s1), np.abs(s2)) >= LINE_MARGIN_PX
    )
    pairs = [read & (s1 * s2 > 0), read & (s1 * s2 < 0)]
    counts = [pair.sum(axis=1) for pair in pairs]
    means = [
        (
            (luminance * pair).sum(axis=1) / np.maximum(count, 1),
            (chromaticity * pair[..., None]).sum(axis=1) / np.maximum(count, 1)[:, None],
        )
        for pair, count in zip(pairs, counts, strict=True)
    ]
    luminance_contrast = np.abs(means[0][0] - means[1][0])
    chroma_contrast = np.linalg.norm(means[0][1] - means[1][1], axis=1)
    readable = inside & (counts[0] >= MIN_QUADRANT_PIXELS) & (counts[1] >= MIN_QUADRANT_PIXELS)
    with np.errstate(divide="ignore", invalid="ignore"):
        share[readable] = (chroma_contrast / luminance_contrast)[readable]
    return share


def _smoothed(planes: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, h, w, C) planes through :data:`CHROMA_SMOOTHING` along both axes, less its reach."""
    for axis in (1, 2):
        length = planes.shape[axis] - len(CHROMA_SMOOTHING) + 1
        planes = sum(
            weight * planes.take(np.arange(k, k + length), axis=axis)
            for k, weight in enumerate(CHROMA_SMOOTHING)
        )
    return planes


def coloured_x(
    colour: NDArray[Any],
    full_scale: float,
    xy: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    max_share: float,
) -> NDArray[np.bool_]:
    """(N,) X's of texture's size drawn in colour: :func:`x_chroma_share` over ``max_share``.

    ``max_share`` is ``DetectorConfig.max_x_chroma_share``, which says what it rests
    on. Those under :data:`CHROMA_MIN_EXTENT_PX` or of :data:`CHROMA_MAX_EXTENT_PX`
    and more, and those :func:`x_chroma_share` cannot read, are not.
    """
    extent = np.asarray(radius_px)
    asked = np.flatnonzero((extent >= CHROMA_MIN_EXTENT_PX) & (extent < CHROMA_MAX_EXTENT_PX))
    coloured = np.zeros(len(xy), bool)
    if len(asked):
        share = x_chroma_share(colour, full_scale, xy[asked], extent[asked], line_angles[asked])
        coloured[asked] = share > max_share
    return coloured
