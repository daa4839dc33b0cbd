"""A tiny marker's plate: a likelihood ratio of the marker model against smooth saddles.

Under a blur sigma the X of a marker of radius r is, inside its own disk, a smooth
saddle. With 100 DN of contrast under 3 DN of noise, a quartic surface explains the
blurred X of a 2.5-3.5 px marker over its disk (21-37 pixels) to within 0-9 noise
variances where r / sigma is under 2.5, a quadratic one to within 0-17 where r /
sigma is under 2. No test on the X's own disk (its template's correlation, the
straightness of its lines, its grey-level symmetry) can then part it from a texture
saddle of that size. What the marker has and a saddle has not lies around the X:
the plate that carries it. The paint pair ends at the radius in a plate of the
other paint, the plate's square ends at 1.25-1.3 radii (both renderers), and the
ground goes on beyond. Over 1.6 radii the blurred marker leaves the quartic 50-700
noise variances at r / sigma 2-2.5, 540-5500 at 3-5 (1-35 under 1.7: out of reach).

:func:`plate_evidence` fits that model (two quarter disks of paint in a square
plate, on a ground with a linear light, blurred: the levels by linear least
squares, the shape by a search over the radii along each line and the blur) and
compares what it leaves with what a quadratic and a quartic surface leave on the
same pixels: a generalised likelihood ratio of two Gaussian models with one noise,
read as the ratio of their residual sums of squares. :func:`centre_saddle` asks
the centre to be a saddle (a blurred blob's is an extremum: the plate model fits a
small elongated blob as two paint lobes merged by the blur).

On the candidates of tiny markers the default rejects, the plate model with the
saddle keeps more than half, and almost no texture saddle (:func:`read_plates`). The plain X with
four quadrant levels, the same comparison without the plate, explains markers no
better than texture. Measured: docs/accuracy-journal.md, "The tiny markers' plate".

A marker of 6-9 px seen 50-60 degrees from face on has an X of texture's size
too: the ring ladder reads its extent up to a rung short of its shortest reach,
and along its lines it measures up to twice that, beyond the tiny markers'
radii. Where the tiny model comes near (its coarse search leaves room for the full
one) and does not explain such an X, its plate is read a rung out at the X's
scale (:func:`explains_at`), as the wider X's are. Measured: docs/accuracy-journal.md,
"A small tilted X's plate read a rung out". What the constants here rest on:
docs/accuracy-journal.md, "What the plate reading's constants and the paths' caps rest on".
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from marker_localizer.core import screening, verification
from marker_localizer.core.normal import tabulated_cdf
from marker_localizer.core.sampling import pixels_at_offsets, square_offsets

#: Half-side of the square plate that carries a marker, in marker radii: 1.25 on the
#: package's renderer, 1.25-1.3 on the independent one.
PLATE_HALF_SIDE = 1.25
#: The models' radii along each line, px: a marker of 2.5-5 px, tilted up to 60
#: degrees, measures 1.25-5 px along a line; below 2.25 px the blur of 0.5-1.5 px
#: merges its quarter disks (resolution under 2, out of reach: see the module).
MODEL_RADII_PX = (2.25, 3.0, 3.75, 4.5, 5.25)
#: The models' blurs (Gaussian sigma), px: across the optics' 0.5-1.5 px and JPEG.
MODEL_BLURS_PX = (0.7, 1.0, 1.3, 1.6)
#: The steepest view of a plate the models take, radians from face on: the 60 degrees
#: the detector is built for (the renderers' and the design's limit). A shape of
#: radii r1, r2 along lines that no circle seen at most this steeply makes is left
#: out (:func:`seen_within_max_tilt`): elongated texture fits it, a marker cannot.
MAX_TILT_RAD = np.deg2rad(60.0)
#: The extent of the X, px, that :data:`MODEL_RADII_PX` are set for: the tiny markers'
#: rungs of the ring ladder, 3-4.24 px. Read at a larger extent with
#: ``scale_with_extent``, the radii (and :data:`COARSE_RADII_PX`) scale with it.
MODEL_EXTENT_PX = 3.5
#: A coarser search first, which spares the full one most texture: 18 shapes, not 100.
COARSE_RADII_PX = (2.25, 3.75, 5.25)
COARSE_BLURS_PX = (0.8, 1.4)
#: Most the coarse search may leave of the quadratic's residual for the full search to
#: run: over what the candidates the full search explains leave, under what most
#: saddles of texture do.
COARSE_MAX_TO_QUADRATIC = 0.4
#: Most pixels a window is read at. A larger window (an X wider than 6 px: its
#: plate reaches 12 px and more) is read on a grid of every k-th pixel, the least k
#: that keeps within this: the models' residual sums are compared on the same
#: pixels, so their ratio keeps its expectation, and the search costs what a 6 px
#: X's does (its window, 2 extents, 441 pixels, is read whole).
MAX_WINDOW_PIXELS = 480
#: The window the models are compared on, in extents of the X (the ring check's):
#: the plate's corners lie at 1.77 radii, and a marker's extent reads up to a rung
#: (sqrt 2) short of its radius.
WINDOW_EXTENTS = 2.0
#: Most the plate model may leave of what the best quadratic surface leaves: over
#: what most tiny markers leave, well under texture saddles.
MAX_TO_QUADRATIC = 0.2
#: ... and of what the best quartic leaves (a quartic bends with the ground).
MAX_TO_QUARTIC = 0.6
#: Most of the quartic's residual the plate model may leave on any detection of
#: texture's size, whatever found it: the plate model holds the marker, a smooth
#: surface does not, so a plate no better than a quartic is no marker's (the tiny
#: markers' and texture's ratios: docs/accuracy-journal.md, "A plate that leaves most of a
#: quartic's residual near the floor").
MAX_TO_QUARTIC_ANY = 1.0
#: Least ratio of the weaker to the stronger curvature at the centre, of opposite
#: signs: an X's centre is a saddle, and the blobs of texture and look-alikes the
#: plate model would keep are not.
MIN_SADDLE = 0.2
#: Tiny X's whose plate :func:`read_plates` reads per frame at most (1-2 ms each), the
#: strongest ring symmetry first, spread over the frame as Eq. (7)'s thinning spreads
#: them: over what a frame of tiny markers offers, under what real ground does.
MAX_PLATE_READ = 64
#: Radius of the disk whose quadratic surface gives the centre's curvatures, px.
_SADDLE_DISK_PX = 2.0
#: Variance of a pixel's box over its area, px^2: it adds to the blur's.
_PIXEL_BOX_VARIANCE = 1.0 / 12.0
#: Candidates fitted at a time: (16, 100 shapes, up to 227 pixels) arrays stay small.
_BLOCK = 16
#: Line pairs closer to parallel than this |sin| of their angle have no X to model.
_MIN_CROSSING_SIN = 0.3


class PlateEvidence(NamedTuple):
    """What the plate model says of each candidate (NaN where it cannot be read).

    Attributes:
        to_quadratic: (N,) the plate model's residual sum of squares over the best
            quadratic surface's, on the same pixels.
        to_quartic: (N,) ... over the best quartic's.
    """

    to_quadratic: NDArray[np.float64]
    to_quartic: NDArray[np.float64]


def _disk_offsets(radius_px: float) -> NDArray[np.int64]:
    """(n, 2) integer (dx, dy) offsets within ``radius_px`` of the origin."""
    square = square_offsets(int(np.ceil(radius_px)))
    return square[np.hypot(square[:, 0], square[:, 1]) <= radius_px]


# The windows, their bases and the saddle's fit depend on the radius alone, and a frame
# asks for a few rungs of the extents' ladder, each many times: built once (~2 ms a
# 12 MP frame). Shared by every caller through the caches (and every thread): read-only.
@functools.lru_cache(maxsize=256)
def _window_offsets(radius_px: float) -> NDArray[np.int64]:
    """The disk's offsets (:func:`_disk_offsets`), every k-th row and column of them.

    k is the least that leaves at most :data:`MAX_WINDOW_PIXELS` (1 for windows that
    small).
    """
    offsets = _disk_offsets(radius_px)
    stride = 1
    while True:
        on_grid = offsets[np.all(offsets % stride == 0, axis=1)]
        if len(on_grid) <= MAX_WINDOW_PIXELS:
            on_grid.flags.writeable = False
            return on_grid
        stride += 1


@functools.lru_cache(maxsize=256)
def _polynomial_basis(radius_px: float, degree: int) -> NDArray[np.float64]:
    """(n, m) an orthonormal basis of the polynomials of ``degree`` on :func:`_window_offsets`.

    A polynomial of the offsets from the rounded centre spans the same surfaces as
    one of the offsets from the sub-pixel centre, so one basis serves every centre.
    """
    offsets = _window_offsets(radius_px)
    dx, dy = offsets[:, 0].astype(np.float64), offsets[:, 1].astype(np.float64)
    design = np.stack([dx**i * dy**j for i in range(degree + 1) for j in range(degree + 1 - i)], 1)
    basis: NDArray[np.float64] = np.linalg.qr(design)[0]
    basis.flags.writeable = False
    return basis


def _polynomial_residual(
    values: NDArray[np.float64], basis: NDArray[np.float64]
) -> NDArray[np.float64]:
    """(N,) residual sum of squares of each row's best surface in ``basis``'s span.

    ``values`` (N, n) and the orthonormal ``basis`` (n, m) (:func:`_polynomial_basis`).
    """
    explained = values @ basis
    residual: NDArray[np.float64] = np.sum(values**2, axis=1) - np.sum(explained**2, axis=1)
    return residual


def centre_saddle(image: NDArray[Any], xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N,) the weaker over the stronger principal curvature at each centre, signs opposed.

    From the quadratic surface over the pixels within :data:`_SADDLE_DISK_PX` of
    the rounded centre (its curvatures do not depend on where in the pixel the
    centre lies): in (0, 1] for a saddle (1: a right-angled X), <= 0 for an extremum
    or a ridge. NaN where the disk leaves the image.
    """
    offsets, fit = _saddle_fit()
    values, inside = pixels_at_offsets(image, xy, offsets)
    coefficients = values @ fit.T
    hxx, hxy, hyy = 2.0 * coefficients[:, 3], coefficients[:, 4], 2.0 * coefficients[:, 5]
    half_trace, root = 0.5 * (hxx + hyy), np.hypot(0.5 * (hxx - hyy), hxy)
    low, high = half_trace - root, half_trace + root
    strongest = np.maximum(np.maximum(np.abs(low), np.abs(high)), 1e-12)
    ratio: NDArray[np.float64] = np.where(inside, -low * high / strongest**2, np.nan)
    return ratio


@functools.lru_cache(maxsize=1)
def _saddle_fit() -> tuple[NDArray[np.int64], NDArray[np.floating[Any]]]:
    """The offsets :func:`centre_saddle` reads and (6, n) the pseudo-inverse of their quadratic."""
    offsets = _disk_offsets(_SADDLE_DISK_PX)
    dx, dy = offsets[:, 0].astype(np.float64), offsets[:, 1].astype(np.float64)
    design = np.stack([np.ones_like(dx), dx, dy, dx * dx, dx * dy, dy * dy], 1)
    fit = np.linalg.pinv(design)
    offsets.flags.writeable = fit.flags.writeable = False
    return offsets, fit


def _plate_residual(
    values: NDArray[np.float64],
    dx: NDArray[np.float64],
    dy: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    radii_px: tuple[float, ...],
    blurs_px: tuple[float, ...],
    quadrant_levels: bool,
    tilt_allowance_px: float,
) -> NDArray[np.float64]:
    """(N,) the least residual sum of squares of the blurred plate model over its shapes.

    ``dx``, ``dy`` (N, n) are the pixels' offsets from the sub-pixel centres. Along
    the lines' oblique coordinates (alpha, beta) a point is alpha e1 + beta e2, and
    a step across the line alpha = a, blurred by s, is Phi((alpha - a) |sin| / s)
    (|sin| that of the lines' angle). The model: the ground (a level and a linear
    light) outside the plate's blurred square, the plate's level inside it, and the
    paint's step on two opposite quadrants inside the ellipse u^2 + v^2 <= 1
    (u = alpha / r1, v = beta / r2: the image of the quarter disks' circle), each
    blurred edge a product of blurred steps (the blurred ellipse by its signed
    distance). Levels by least squares; r1, r2, the blur and which quadrant pair
    holds the paint by search, over the shapes a plate seen within
    :data:`MAX_TILT_RAD` of face on makes (:func:`seen_within_max_tilt`, each radius
    standing for those within ``tilt_allowance_px`` of it; inf where none does).
    With ``quadrant_levels`` each of the other pair's quarter disks has a level of
    its own too (a dull bright quadrant: wear, dirt, sheen).
    """
    cos, sin = np.cos(line_angles), np.sin(line_angles)
    det = cos[:, 0] * sin[:, 1] - cos[:, 1] * sin[:, 0]
    crossing = np.abs(det)
    safe = np.where(crossing < _MIN_CROSSING_SIN, 1.0, det)
    # Inverse of the columns (e1, e2): oblique coordinates of an offset. The shapes'
    # arrays are float32 (half the memory traffic; the least squares stay float64), the
    # levels less their mean (the model spans a constant) so that little cancels.
    alpha = ((sin[:, 1, None] * dx - cos[:, 1, None] * dy) / safe[:, None]).astype(np.float32)
    beta = ((-sin[:, 0, None] * dx + cos[:, 0, None] * dy) / safe[:, None]).astype(np.float32)
    dx, dy = dx.astype(np.float32), dy.astype(np.float32)
    values = (values - values.mean(axis=1, keepdims=True)).astype(np.float32)
    # Axes (N, r1, r2, blur, n): candidates, the radius along each line, blurs, pixels.
    # Steps along one line depend on its radius and the blur alone: computed once per
    # pair, they broadcast (only the ellipse's edge needs every shape).
    radii = np.asarray(radii_px, np.float32)
    spread = np.sqrt(np.square(blurs_px) + _PIXEL_BOX_VARIANCE).astype(np.float32)
    gain = crossing[:, None, None].astype(np.float32) / spread[None, :, None]  # (N, blur, 1)
    a = alpha[:, None, None, None, :]
    b = beta[:, None, None, None, :]
    r1 = radii[None, :, None, None, None]
    r2 = radii[None, None, :, None, None]
    g = gain[:, None, None, :, :]
    side_a = PLATE_HALF_SIDE * r1
    side_b = PLATE_HALF_SIDE * r2
    plate = (tabulated_cdf((a + side_a) * g) - tabulated_cdf((a - side_a) * g)) * (
        tabulated_cdf((b + side_b) * g) - tabulated_cdf((b - side_b) * g)
    )
    # The ellipse's signed distance depends on the radii alone: once per (r1, r2).
    u, v = a[..., 0, :] / r1[..., 0, :], b[..., 0, :] / r2[..., 0, :]
    rho = np.sqrt(u * u + v * v) + np.float32(1e-12)
    # The image gradient of rho: the inverse transpose of (e1, e2) on d rho / d(alpha, beta).
    d_alpha, d_beta = u / r1[..., 0, :] / rho, v / r2[..., 0, :] / rho
    s0, s1 = ((sin[:, k] / safe)[:, None, None, None].astype(np.float32) for k in (0, 1))
    c0, c1 = ((cos[:, k] / safe)[:, None, None, None].astype(np.float32) for k in (0, 1))
    # At the very centre rho's gradient vanishes (a cone's tip): deep inside, the edge far.
    slope = np.hypot(s1 * d_alpha - s0 * d_beta, c0 * d_beta - c1 * d_alpha)
    distance = (1.0 - rho) / np.maximum(slope, np.float32(1e-6))
    disk = tabulated_cdf(distance[..., None, :] / spread[None, None, None, :, None])
    step_a, step_b = tabulated_cdf(a * g), tabulated_cdf(b * g)
    # Least squares on the columns ground, ground x, ground y, plate, paint (and each
    # other quarter disk): the Gram matrix entry by entry (the first four are the same
    # for both quadrant pairs).
    ground = 1.0 - plate
    columns = [ground, ground * dx[:, None, None, None, :], ground * dy[:, None, None, None, :]]
    columns.append(plate)
    size = 7 if quadrant_levels else 5
    shape = plate.shape
    normal = np.empty((*shape[:-1], size, size))
    projected = np.empty((*shape[:-1], size))
    for i in range(4):
        projected[..., i] = _dot(columns[i], values[:, None, None, None, :])
        for j in range(i + 1):
            normal[..., i, j] = normal[..., j, i] = _dot(columns[i], columns[j])
    total = np.sum(np.square(values, dtype=np.float64), axis=1)[:, None, None, None]
    possible = seen_within_max_tilt(radii, crossing, tilt_allowance_px)[..., None]
    best = np.full(len(values), np.inf)
    quarters = (
        (step_a * step_b, (1.0 - step_a) * (1.0 - step_b)),
        (step_a * (1.0 - step_b), (1.0 - step_a) * step_b),
    )
    for painted, other in (quarters, quarters[::-1]):
        paint = [(painted[0] + painted[1]) * disk]
        if quadrant_levels:
            paint += [other[0] * disk, other[1] * disk]
        for i, column in enumerate(paint, start=4):
            projected[..., i] = _dot(column, values[:, None, None, None, :])
            for j, earlier in enumerate(columns + paint[: i - 3]):
                normal[..., i, j] = normal[..., j, i] = _dot(column, earlier)
        levels = np.linalg.solve(normal + 1e-6 * np.eye(size), projected[..., None])[..., 0]
        residual = np.where(possible, total - np.sum(levels * projected, axis=-1), np.inf)
        best = np.minimum(best, residual.reshape(len(values), -1).min(axis=1))
    return np.where(crossing < _MIN_CROSSING_SIN, np.nan, best)


def _dot(a: NDArray[np.floating[Any]], b: NDArray[np.floating[Any]]) -> NDArray[np.floating[Any]]:
    """Sum of the products along the last axis, the others broadcast.

    One pass without the product's temporary: a third less time for the plate
    model's Gram matrix than multiplying and summing (docs/speed.md, "The plate
    read at every range").
    """
    total: NDArray[np.floating[Any]] = np.einsum("...n,...n->...", a, b)
    return total


def seen_within_max_tilt(
    radii_px: NDArray[np.floating[Any]], crossing: NDArray[np.float64], half_step_px: float
) -> NDArray[np.bool_]:
    """(N, R, R) whether radii r1, r2 along each X's lines can be a circle's seen at most steeply.

    A marker's lines are the images of two perpendicular diameters of its plate's
    circle, so r1 e1 and r2 e2 (e1, e2 the lines' unit directions, crossing at
    |sin| ``crossing``) are conjugate semi-diameters of the circle's image, an
    ellipse whose axes a >= b satisfy a^2 + b^2 = r1^2 + r2^2 and a b = r1 r2 |sin|
    (Apollonius). So b / a + a / b = (k + 1 / k) / |sin|, k = r1 / r2, and a circle
    seen t from face on shows b / a = cos t: the shape is a marker's where that sum
    is at most cos t + 1 / cos t at :data:`MAX_TILT_RAD`. A model's radius stands for
    those within ``half_step_px`` of it (half the full grid's spacing, for the coarse
    search too: :func:`plate_evidence`), so k is taken as near 1 as that allows.
    (Over a plate of a few pixels the perspective is an affine map.)

    Args:
        radii_px: (R,) the models' radii along each line, px.
        crossing: (N,) |sin| of the angle between each X's lines.
        half_step_px: how far from each radius the radii it stands for reach, px.
    """
    radii = np.asarray(radii_px, np.float64)
    longer = np.maximum(radii[:, None], radii[None, :]) - half_step_px
    shorter = np.minimum(radii[:, None], radii[None, :]) + half_step_px
    k = np.maximum(longer / shorter, 1.0)
    cos_tilt = np.cos(MAX_TILT_RAD)
    sum_bound = cos_tilt + 1.0 / cos_tilt
    possible: NDArray[np.bool_] = (k + 1.0 / k)[None] <= sum_bound * np.asarray(
        crossing, np.float64
    )[:, None, None]
    return possible


def plate_evidence(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    extent_px: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    scale_with_extent: bool = False,
    quadrant_levels: bool = False,
    enough_to_quartic: float | NDArray[np.float64] | None = None,
) -> PlateEvidence:
    """The plate model's residual over the quadratic's and the quartic's, per candidate.

    Args:
        image: (H, W) grey image, raw levels.
        xy: (N, 2) centres, px ((0, 0) the centre of the top-left pixel).
        extent_px: (N,) extents of the X (the ring check's), px; the models are
            compared within :data:`WINDOW_EXTENTS` of them.
        line_angles: (N, 2) the X's line directions, radians.
        scale_with_extent: the model's radii along the lines scaled by each
            extent over :data:`MODEL_EXTENT_PX`, for X's larger than the tiny
            markers' (a marker of 6-9 px tilted so that its rings reach 4-6 px
            measures 4-9 px along its lines); False: the tiny markers' radii.
        quadrant_levels: each bright quarter disk its own level (a dull quadrant,
            :func:`_plate_residual`).
        enough_to_quartic: scalar or (N,): where the coarse search already leaves
            at most this of the quartic's residual, the full search is spared (a
            test at that bar is decided); None: every candidate the coarse search
            leaves room for is searched in full.

    Returns:
        :class:`PlateEvidence`, the least residual over every shape searched; NaN
        where the window leaves the image or the lines are nearly parallel, inf
        where they cross too obliquely for any plate seen within
        :data:`MAX_TILT_RAD` (:func:`seen_within_max_tilt`). The full search runs
        only where the coarse one (:data:`COARSE_RADII_PX`, :data:`COARSE_BLURS_PX`)
        leaves at most :data:`COARSE_MAX_TO_QUADRATIC` of the quadratic's residual.
        Windows over :data:`MAX_WINDOW_PIXELS` pixels are read on a coarser grid.
    """
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    to_quadratic = np.full(len(xy), np.nan)
    to_quartic = np.full(len(xy), np.nan)
    window = WINDOW_EXTENTS * np.asarray(extent_px, np.float64)
    enough = np.broadcast_to(
        -np.inf if enough_to_quartic is None else np.asarray(enough_to_quartic, np.float64),
        len(xy),
    )
    # The ring check's extents are rungs of a ladder: one window, one basis per rung.
    for radius in np.unique(window):
        group = np.flatnonzero(window == radius)
        offsets = _window_offsets(float(radius))
        values, inside = pixels_at_offsets(image, xy[group], offsets)
        group, values = group[inside], values[inside]
        if not len(group):
            continue
        quadratic = _polynomial_residual(values, _polynomial_basis(float(radius), 2))
        shift = np.rint(xy[group]) - xy[group]
        dx = offsets[None, :, 0] + shift[:, 0, None]
        dy = offsets[None, :, 1] + shift[:, 1, None]
        angles = np.asarray(line_angles, np.float64)[group]
        scale = radius / WINDOW_EXTENTS / MODEL_EXTENT_PX if scale_with_extent else 1.0
        coarse_radii = tuple(scale * r for r in COARSE_RADII_PX)
        model_radii = tuple(scale * r for r in MODEL_RADII_PX)
        # Each of the full grid's radii stands for those within half its spacing. The
        # coarse search's least residual enters the reading (below), so its shapes are
        # held to the tilt as the full grid reads it, not with half its own spacing
        # (twice as wide), which takes plates the full grid refuses as too steep.
        allowance = 0.5 * float(np.diff(model_radii).max())
        coarse = np.concatenate(
            [
                _plate_residual(
                    values[s],
                    dx[s],
                    dy[s],
                    angles[s],
                    coarse_radii,
                    COARSE_BLURS_PX,
                    quadrant_levels,
                    allowance,
                )
                for s in _blocks(len(group))
            ]
        )
        quartic = _polynomial_residual(values, _polynomial_basis(float(radius), 4))
        to_quadratic[group], to_quartic[group] = coarse / quadratic, coarse / quartic
        with np.errstate(invalid="ignore"):
            full = np.flatnonzero(
                (coarse <= COARSE_MAX_TO_QUADRATIC * quadratic)
                & ~(coarse <= enough[group] * quartic)
            )
        if not len(full):
            continue
        plate = np.concatenate(
            [
                _plate_residual(
                    values[full[s]],
                    dx[full[s]],
                    dy[full[s]],
                    angles[full[s]],
                    model_radii,
                    MODEL_BLURS_PX,
                    quadrant_levels,
                    allowance,
                )
                for s in _blocks(len(full))
            ]
        )
        # The two grids' blurs differ: a coarse shape may fit better than every full one.
        plate = np.fmin(plate, coarse[full])
        to_quadratic[group[full]] = plate / quadratic[full]
        to_quartic[group[full]] = plate / quartic[full]
    return PlateEvidence(to_quadratic, to_quartic)


def _blocks(count: int) -> list[slice]:
    """Slices of at most :data:`_BLOCK` over ``count`` rows."""
    return [slice(start, start + _BLOCK) for start in range(0, count, _BLOCK)]


def plate_explains(evidence: PlateEvidence, saddle: NDArray[np.float64]) -> NDArray[np.bool_]:
    """(N,) where the plate model explains a candidate as a marker.

    It leaves at most :data:`MAX_TO_QUADRATIC` of the quadratic's residual and
    :data:`MAX_TO_QUARTIC` of the quartic's, and the centre is a saddle
    (:func:`centre_saddle` at least :data:`MIN_SADDLE`). NaN reads as no.
    """
    with np.errstate(invalid="ignore"):
        explained: NDArray[np.bool_] = (
            (evidence.to_quadratic <= MAX_TO_QUADRATIC)
            & (evidence.to_quartic <= MAX_TO_QUARTIC)
            & (saddle >= MIN_SADDLE)
        )
    return explained


def explains_at(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    extent_px: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    saddle: NDArray[np.float64] | None = None,
) -> NDArray[np.bool_]:
    """(N,) where the plate model explains an X of texture's size as a marker.

    The tiny markers' model at the X's extent (:func:`plate_explains`) or, where
    that model's coarse search came within :data:`COARSE_MAX_TO_QUADRATIC` and the
    full one explained nothing, the model a ring rung out at the X's scale, each
    bright quadrant its own level: a larger marker seen foreshortened, whose extent
    the ring ladder reads short (the module says why).

    Args:
        image: (H, W) grey image, raw levels.
        xy: (N, 2) the X's centres, px.
        extent_px: (N,) their extents (the ring check's), px.
        line_angles: (N, 2) their line directions, radians.
        saddle: (N,) :func:`centre_saddle` at ``xy`` where the caller has it.
    """
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    extent_px = np.asarray(extent_px, np.float64)
    line_angles = np.asarray(line_angles, np.float64)
    if saddle is None:
        saddle = centre_saddle(image, xy)
    evidence = plate_evidence(image, xy, extent_px, line_angles)
    explained = plate_explains(evidence, saddle)
    with np.errstate(invalid="ignore"):
        near = evidence.to_quadratic <= COARSE_MAX_TO_QUADRATIC
    short = np.flatnonzero(~explained & near)
    if len(short):
        further = plate_evidence(
            image,
            xy[short],
            verification.RING_STEP * extent_px[short],
            line_angles[short],
            scale_with_extent=True,
            quadrant_levels=True,
        )
        explained[short] = plate_explains(further, saddle[short])
    return explained


class PlateReading(NamedTuple):
    """What :func:`read_plates` read, and what the plate explains.

    Attributes:
        read: (R,) the rows compared with the plate model.
        explained: (K,) those it explains as markers, a subset of ``read``.
        over_cap: how many saddles :data:`MAX_PLATE_READ` left unread.
    """

    read: NDArray[np.intp]
    explained: NDArray[np.intp]
    over_cap: int


def read_plates(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    score: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    cell_px: float,
) -> PlateReading:
    """Tiny X's judged by their plate: the model of a marker against smooth surfaces.

    Under a blur that nearly merges its quadrants a tiny marker's X is a smooth
    saddle within its own disk, and the template's NCC, the score floors and the
    X's end reject many (the module says why). Of the X's of texture's size given,
    those whose centre is a saddle (:func:`centre_saddle`), at most
    :data:`MAX_PLATE_READ` of them (the strongest ring symmetry ``score`` first,
    spread over the frame's cells of ``cell_px``), are compared as a marker on its
    plate against smooth surfaces, and kept where it explains them
    (:func:`explains_at`).

    Args:
        image: (H, W) grey image, raw levels.
        xy: (N, 2) the X's centres, px.
        score: (N,) their ring symmetry.
        radius_px: (N,) their extents, px.
        line_angles: (N, 2) their line directions, radians.
        cell_px: the cells the cap spreads them over, px.

    Returns:
        :class:`PlateReading`.
    """
    saddle = centre_saddle(image, xy)
    with np.errstate(invalid="ignore"):
        rows = np.flatnonzero(saddle >= MIN_SADDLE)
    kept = screening.even_cap_index(xy[rows], score[rows], MAX_PLATE_READ, cell_px)
    over_cap = len(rows) - len(kept)
    rows = rows[kept]
    explained = explains_at(image, xy[rows], radius_px[rows], line_angles[rows], saddle[rows])
    return PlateReading(rows, rows[explained], over_cap)
