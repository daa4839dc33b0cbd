"""Section 3.3.1 of the paper: adaptive template generation.

From the two line angles phi1, phi2 of the verification stage, the template is
an X whose lines have those directions (so it is built once per marker instead
of matching a bank of rotated and scaled templates). Its grey levels are sampled
from the image with 3x3 windows on the bisectors of the four sectors, it is
blurred with the defocus sigma_b estimated from the edge spread, and of the two
polarities the one closer to the image patch in L1 is kept (Eq. 10).
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.special import erf

from marker_localizer.core.image import clipped
from marker_localizer.core.noise import NoiseModel
from marker_localizer.core.normal import tabulated_erf
from marker_localizer.core.sampling import Normaliser, bilinear, nan_median, pad_patterns

_SUPERSAMPLING = 4  # template pixels are area-integrated from 4x4 sub-samples
#: Paper path: annular score a template NCC above its minimum is worth, per unit of
#: NCC: markers and the ground-texture saddles that pass the annular check overlap in
#: either alone, and together this trade parts them best.
NCC_EVIDENCE_WEIGHT = 8.0
#: (low, high) clip of the defocus sigma_b read from an edge's slope
#: (:func:`estimate_defocus_sigma`), px: an edge imaged by pixels is never sharper
#: than a pixel's own spread, 1/sqrt(12) = 0.29 px, and a blur over 5 px is wider than
#: the half-size of the smallest templates (3 px), whose edges it would leave flat.
DEFOCUS_SIGMA_LIMITS_PX = (0.3, 5.0)
#: sigma_b where an edge shows neither contrast nor slope (0 / 0), px: the template
#: then has no contrast to blur, so any value within the limits gives the same one.
_DEFOCUS_SIGMA_UNREAD_PX = 1.0
#: The defocus blurs :func:`template_correlation` tries, px, each about 1.6 times the
#: last: from twice a pixel's own spread to 2.5 px. The match is the best over them, so
#: a blur between two of them reads a little low.
CORRELATION_BLURS_PX = (0.6, 1.0, 1.6, 2.5)
#: Samples of the disk :func:`template_correlation` and :func:`template_misfit` read at
#: most per point: a disk of radius under sqrt(this / 4 pi) px (about 4.9) is read every
#: half pixel, one under sqrt(this / pi) px (about 9.8) every pixel or closer, a wider
#: one on a grid coarse enough to keep this cost.
DISK_MAX_SAMPLES = 300
#: Sine of the lines' crossing angle :func:`_first_clear_of_other_line` takes at least
#: (sin 11.5 degrees, under the double-line check's
#: :data:`~marker_localizer.core.verification.LINE_MIN_ANGLE_RAD`): it bounds the
#: distance at 6 side offsets for lines nearer parallel than an X's.
_MIN_CROSSING_SINE = 0.2


def line_distances(
    x: NDArray[np.float64], y: NDArray[np.float64], line_angles: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Signed distances (s1, s2) of positions from two lines through the origin, px.

    Args:
        x: (..., K) positions relative to the centre.
        y: same shape as ``x``.
        line_angles: (..., 2) line directions in radians, broadcast against x[..., :1].

    Returns:
        Two arrays of the shape of ``x``; s_i is positive left of line i's direction
        (image coordinates, y down).
    """
    a1, a2 = line_angles[..., 0:1], line_angles[..., 1:2]
    return np.sin(a1) * x - np.cos(a1) * y, np.sin(a2) * x - np.cos(a2) * y


def sector_sign(
    x: NDArray[np.float64], y: NDArray[np.float64], line_angles: NDArray[np.float64]
) -> NDArray[np.float64]:
    """+1 / -1 for the two pairs of opposite sectors between two lines through the origin.

    Args:
        x: (..., K) positions relative to the centre.
        y: same shape as ``x``.
        line_angles: (..., 2) line directions in radians, broadcast against x[..., :1].

    Returns:
        float array of the shape of ``x``: the product of the signed distances to
        both lines, as a sign. Sectors facing each other across the centre share a sign.
    """
    side1, side2 = line_distances(x, y, line_angles)
    return np.sign(side1 * side2)


class GreyLevels(NamedTuple):
    """Levels sampled on the sector bisectors; each (N,).

    Attributes:
        positive: mean level of the two sectors where :func:`sector_sign` is +1.
        negative: mean level of the two sectors where it is -1.
    """

    positive: NDArray[np.float64]
    negative: NDArray[np.float64]


def sample_grey_levels(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    offset_px: NDArray[np.float64],
) -> GreyLevels:
    """Grey level of each sector pair from 3x3 windows on the bisectors (section 3.3.1).

    The paper samples 5 px along theta / 2 from the centre; here the four
    bisector directions of the two lines are used, at ``offset_px`` per marker
    (5 px, or less for markers smaller than that).

    Args:
        image: (H, W) float image.
        xy: (N, 2) centres.
        line_angles: (N, 2) line directions.
        offset_px: (N,) sampling distance from the centre.

    Returns:
        :class:`GreyLevels`.
    """
    a1, a2 = line_angles[:, 0], line_angles[:, 1]
    # The bisectors of a line pair: their mean direction and its perpendicular, both ways.
    mid = np.angle(np.exp(1j * a1) + np.exp(1j * a2))
    directions = mid[:, None] + np.array([0.0, np.pi / 2, np.pi, 3 * np.pi / 2])[None, :]
    wx, wy = np.meshgrid(np.arange(-1, 2), np.arange(-1, 2))
    px = (
        xy[:, 0, None, None] + offset_px[:, None, None] * np.cos(directions)[..., None] + wx.ravel()
    )
    py = (
        xy[:, 1, None, None] + offset_px[:, None, None] * np.sin(directions)[..., None] + wy.ravel()
    )
    values, _ = bilinear(image, px, py)
    means = values.mean(axis=-1)  # (N, 4)
    bis_x = np.cos(directions)
    bis_y = np.sin(directions)
    sign = sector_sign(bis_x, bis_y, line_angles)
    positive = np.where(sign > 0, means, 0.0).sum(1) / np.maximum((sign > 0).sum(1), 1)
    negative = np.where(sign < 0, means, 0.0).sum(1) / np.maximum((sign < 0).sum(1), 1)
    return GreyLevels(positive, negative)


def estimate_defocus_sigma(
    gradient_magnitude_peak: NDArray[np.float64], contrast: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Gaussian blur sigma_b of an edge from its contrast and steepest slope.

    A step of height C blurred by a Gaussian of sigma has slope C / (sqrt(2 pi) sigma)
    at the edge, so sigma_b = C / (sqrt(2 pi) * max |grad I|).

    Args:
        gradient_magnitude_peak: (N,) largest gradient magnitude across the edges.
        contrast: (N,) step height in the same units.

    Returns:
        (N,) sigma_b in pixels, clipped to :data:`DEFOCUS_SIGMA_LIMITS_PX`.
    """
    low, high = DEFOCUS_SIGMA_LIMITS_PX
    with np.errstate(divide="ignore", invalid="ignore"):
        sigma = np.abs(contrast) / (np.sqrt(2.0 * np.pi) * gradient_magnitude_peak)
    read = np.nan_to_num(sigma, nan=_DEFOCUS_SIGMA_UNREAD_PX, posinf=high)
    clipped: NDArray[np.float64] = np.clip(read, low, high)
    return clipped


def adaptive_template(
    line_angles: NDArray[np.float64],
    levels: GreyLevels,
    sigma_b: NDArray[np.float64],
    half_size: int,
) -> NDArray[np.float64]:
    """Render one X template per marker (section 3.3.1).

    Args:
        line_angles: (N, 2) line directions phi1, phi2 (theta = phi1 - phi2 is the
            angle between them).
        levels: sector grey levels.
        sigma_b: (N,) defocus blur of each marker in pixels.
        half_size: the templates are (2 half_size + 1) square.

    Returns:
        (N, T, T) float64 templates, T = 2 half_size + 1.
    """
    size = 2 * half_size + 1
    sub = (np.arange(size * _SUPERSAMPLING) + 0.5) / _SUPERSAMPLING - 0.5 - half_size
    sx, sy = np.meshgrid(sub, sub)
    sign = sector_sign(sx.ravel()[None, :], sy.ravel()[None, :], line_angles)
    fine = np.where(sign > 0, levels.positive[:, None], levels.negative[:, None])
    fine = fine.reshape(-1, size, _SUPERSAMPLING, size, _SUPERSAMPLING).mean(axis=(2, 4))
    templates: NDArray[np.float64] = np.empty_like(fine)
    for k in range(len(fine)):  # per marker (not per pixel): each has its own blur
        templates[k] = cv2.GaussianBlur(
            fine[k], (0, 0), float(sigma_b[k]), borderType=cv2.BORDER_REFLECT
        )
    return templates


def choose_polarity(
    patch: NDArray[np.float64], templates: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Pick, per marker, the template polarity closer to the image patch in L1, Eq. (10).

    Args:
        patch: (N, T, T) image windows at the coarse centres.
        templates: (N, T, T) templates; the alternative is the one with the two
            sector levels exchanged (mirrored about the mean level).

    Returns:
        (N, T, T) the chosen templates.
    """
    mean = templates.mean(axis=(1, 2), keepdims=True)
    swapped = 2.0 * mean - templates
    keep = np.abs(patch - templates).sum(axis=(1, 2)) <= np.abs(patch - swapped).sum(axis=(1, 2))
    return np.where(keep[:, None, None], templates, swapped)


class TemplateMatch(NamedTuple):
    """Result of :func:`template_correlation` for N points, each (N,).

    Attributes:
        ncc: the largest correlation over the candidate blurs (1 = a perfect X),
            the bright quadrants a level each (the NCC where they are equal).
        clipped: whether the disk holds a clipped level (``full_scale`` given): on
            raw levels, those samples were left out of ``ncc``.
    """

    ncc: NDArray[np.float64]
    clipped: NDArray[np.bool_]


@functools.lru_cache(maxsize=256)
def _disk_offsets(radius_px: float, max_samples: int) -> NDArray[np.float64]:
    """(K, 2) offsets of a square grid inside the disk, at most ~``max_samples`` of them.

    Cached and shared between calls: read-only.
    """
    step = max(0.5, np.sqrt(np.pi * radius_px**2 / max_samples))
    grid = np.arange(-radius_px, radius_px + 1e-9, step)
    gx, gy = np.meshgrid(grid, grid)
    inside = gx**2 + gy**2 <= radius_px**2
    offsets = np.stack([gx[inside], gy[inside]], axis=1)
    offsets.flags.writeable = False
    return offsets


def template_correlation(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    sigmas_px: tuple[float, ...] = CORRELATION_BLURS_PX,
    max_samples: int = DISK_MAX_SAMPLES,
    normalise: Normaliser | None = None,
    full_scale: float | None = None,
    leave_out_clipped: bool = False,
) -> TemplateMatch:
    """NCC between the image and the adaptive template at a sub-pixel centre (Eqs. 10-12).

    The template is the blurred X of section 3.3.1 in closed form, a function of
    each sample's signed distances s1, s2 from the two lines through the centre
    (:func:`blurred_x`). NCC is invariant to the grey levels, so only the angles and
    sigma_b matter; sigma_b is chosen from ``sigmas_px`` as the best match of the
    X at right angles, erf(s1 / (sqrt(2) sigma_b)) erf(s2 / (sqrt(2) sigma_b)) (the
    edge-spread estimate of the paper), and the match is then read with the X at
    its own crossing at that blur. The sign of the NCC is the polarity choice of
    Eq. (10).

    The product of two steps is the X only where the lines cross at right angles.
    A tilted marker's lines do not, and near the centre, where a small X is mostly,
    its blur differs from the product: a blurred X of 50 degrees matches the
    product over a disk of 3 px at 0.967, itself at 0.999. A smooth saddle, the
    quadratic surface ground texture makes between stones, matches the product at
    its centre whatever the angle (0.996 for zero lines 50 degrees apart), and the
    X at that angle at 0.910 (the figures on the families:
    docs/accuracy-journal.md, "The template's X at its own crossing angle").

    The paper's template has two grey levels; a dull bright quadrant (wear, dirt,
    sheen: 0.45-0.8 as bright as its opposite) makes three, and its NCC falls to
    0.85-0.93 on a perfect X. So the two bright quadrants get a level each, as the
    paper samples one per quadrant: the match is the multiple correlation of the
    patch with the template and the bright pair's difference (its lobes, + on one
    quadrant and - on the other), the square root of the share of the patch's
    variance the two explain; with equal bright quadrants it is the NCC. The dark
    pair keeps one level: black paint stays black, while the dark gaps of a texture
    saddle differ as its stones do. And the duller bright quadrant must still stand
    above the dark pair, or the second level is left out (an L corner is one bright
    quadrant of three dark ones, not an X with a quadrant dulled to black).
    Measured: docs/accuracy-journal.md, "Figures the fit's and the detector's docstrings
    carried".

    Given ``full_scale``, the match tells which disks hold a clipped level
    (:func:`~marker_localizer.core.image.clipped`, on the raw levels), and with
    ``leave_out_clipped`` leaves those samples out: where the white paint clips,
    the blurred X's bright side is cut off at white, which no level of the
    template follows, and the match would fall with the share of the disk that
    clips, however straight the lines.

    Args:
        image: (H, W) image (any numeric dtype).
        xy: (N, 2) centres (sub-pixel).
        line_angles: (N, 2) line directions.
        radius_px: (N,) disk radius over which to correlate.
        sigmas_px: candidate defocus sigmas.
        max_samples: cap on samples per point (the grid coarsens for big disks).
        normalise: applied to each point's samples before the NCC (e.g. the dynamic
            gamma).
        full_scale: the image's white level, where clipped levels are told.
        leave_out_clipped: leave the clipped samples out of the match (raw levels:
            needs ``full_scale`` and no ``normalise``).

    Returns:
        :class:`TemplateMatch`.

    Raises:
        ValueError: ``leave_out_clipped`` without ``full_scale`` or with ``normalise``.
    """
    n = len(xy)
    if n == 0:
        return TemplateMatch(np.zeros(0), np.zeros(0, dtype=bool))
    disk = _disk_samples(
        image, xy, line_angles, radius_px, max_samples, normalise, full_scale, leave_out_clipped
    )
    values, valid, s1, s2, present = disk.values, disk.valid, disk.s1, disk.s2, disk.present
    count = np.maximum(present.sum(axis=1, keepdims=True), 1)
    centred = (values - (values * present).sum(axis=1, keepdims=True) / count) * (valid & present)
    norm_i2 = (centred**2).sum(axis=1) + 1e-12
    best_ncc = np.zeros(n)
    best_sigma = np.full(n, sigmas_px[0])
    # The blur is the best of ``sigmas_px`` for the X at right angles, whose model is
    # a product of two steps (cheap), over whole rows as the X's below: the padding's
    # distances are its centre's, and the centring leaves out what is not present.
    for sigma in sigmas_px:
        model = edge_step(s1, sigma) * edge_step(s2, sigma)
        model_centred = _centred(model, present, count)
        model_norm2 = (model_centred**2).sum(axis=1) + 1e-12
        corr = np.abs((centred * model_centred).sum(axis=1)) / np.sqrt(norm_i2 * model_norm2)
        better = corr > best_ncc
        best_ncc[better] = corr[better]
        best_sigma[better] = sigma
    # At that blur, the X with its lines at their own angle.
    crossing = np.cos(line_angles[:, 0] - line_angles[:, 1])
    model = blurred_x(s1, s2, best_sigma[:, None], crossing[:, None])
    model_centred = _centred(model, present, count)
    model_norm2 = (model_centred**2).sum(axis=1) + 1e-12
    along = (centred * model_centred).sum(axis=1)
    ncc = np.abs(along) / np.sqrt(norm_i2 * model_norm2)
    # The bright pair's own difference at the chosen blur: the model's lobes on the
    # polarity's bright side, + on one quadrant and - on its opposite (s1 changes sign
    # between them, and the lobes vanish on the lines, where it does).
    bright = (model > 0.0) == (along > 0.0)[:, None]
    difference = _centred(np.where(bright, model * np.sign(s1), 0.0), present, count)
    overlap = (difference * model_centred).sum(axis=1) / model_norm2
    difference -= overlap[:, None] * model_centred
    projected = (centred * difference).sum(axis=1)
    difference_norm2 = (difference**2).sum(axis=1) + 1e-12
    # The fitted levels: the bright pair's half difference, and the half contrast
    # between the pairs. A dull quadrant is still bright paint: where the duller of
    # the pair would not stand above the dark pair (one bright quadrant of three
    # dark, an L corner), the second level explains no X and is left out.
    split = projected / difference_norm2
    contrast = along / model_norm2 - split * overlap
    extra = np.where(np.abs(split) < 2.0 * np.abs(contrast), projected**2 / difference_norm2, 0.0)
    ncc = np.sqrt(np.minimum(ncc**2 + extra / norm_i2, 1.0))
    return TemplateMatch(ncc, np.any(disk.clipped, axis=1))


def template_misfit(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    ncc: NDArray[np.float64],
    noise: NoiseModel,
    max_samples: int = DISK_MAX_SAMPLES,
    full_scale: float | None = None,
) -> NDArray[np.float64]:
    """(N,) share of the disk's variance the blurred X leaves unexplained beyond the noise.

    1 - NCC^2 of :func:`template_correlation` (raw levels) is the share of the
    samples' variance about their mean that the X, its bright quadrants a level
    each, leaves unexplained. Noise alone leaves its variance over the samples'
    variance; a bilinear sample carries ((1 - fx)^2 + fx^2) ((1 - fy)^2 + fy^2) of
    its pixels' noise variance, fx and fy its fractional position. What is left is
    shape that is not the X's: an X whose lines are straight, blurred, leaves next
    to none (rendered markers: median 0.003), while a saddle between round blobs
    (a lattice of discs, stones in rows) leaves the curvature of their outlines
    (0.06-0.12), whatever its contrast and however point-symmetric it is.

    Given ``full_scale``, the clipped samples are left out, as
    :func:`template_correlation` leaves them out of ``ncc``, and the share is of the
    whole disk's variance (clipped samples included): the samples left are mostly
    the dark paint and the edges, whose variance is a fraction of the disk's, and
    their misfit as a share of it would grow with the share of the disk that clips.

    Args:
        image: (H, W) image, raw levels.
        xy: (N, 2) centres (sub-pixel).
        line_angles: (N, 2) line directions, radians.
        radius_px: (N,) disk radius over which to read, px.
        ncc: (N,) :func:`template_correlation`'s match on these disks, raw levels, the
            same ``max_samples``.
        noise: the frame's noise (:func:`~marker_localizer.core.noise.estimate_noise`).
        max_samples: cap on samples per point (as :func:`template_correlation`).
        full_scale: the image's white level, where clipped samples are left out (as
            ``ncc`` left them out).
    """
    if len(xy) == 0:
        return np.zeros(0)
    disk = _disk_samples(
        image, xy, line_angles, radius_px, max_samples, None, full_scale, full_scale is not None
    )
    read = disk.valid & disk.present
    count = np.maximum(read.sum(axis=1), 1)
    variance = _variance(disk.values, read, count)
    position = xy[:, None, :] + disk.offsets
    fraction = position - np.floor(position)
    carried = np.prod(np.square(1.0 - fraction) + np.square(fraction), axis=-1)
    noise_variance = (np.square(noise.std(disk.values)) * carried * read).sum(axis=1) / count
    misfit: NDArray[np.float64] = (
        1.0 - np.square(ncc) - noise_variance / np.maximum(variance, 1e-12)
    )
    if disk.clipped.any():
        whole = disk.valid & (disk.present | disk.clipped)
        whole_count = np.maximum(whole.sum(axis=1), 1)
        whole_squares = _variance(disk.values, whole, whole_count) * whole_count
        misfit *= variance * count / np.maximum(whole_squares, 1e-12)
    return misfit


def _variance(
    values: NDArray[np.float64], read: NDArray[np.bool_], count: NDArray[np.int64]
) -> NDArray[np.float64]:
    """(N,) each row's variance of ``values`` about its mean over the ``read`` samples."""
    mean = (values * read).sum(axis=1) / count
    variance: NDArray[np.float64] = (np.square(values - mean[:, None]) * read).sum(axis=1) / count
    return variance


def blurred_x(
    s1: NDArray[np.float64],
    s2: NDArray[np.float64],
    blur_px: float | NDArray[np.float64],
    crossing_cos: float | NDArray[np.float64],
) -> NDArray[np.float64]:
    """The X of two lines at any angle, blurred: -1 to 1 at signed distances s1, s2 (Eq. 10).

    Under a Gaussian blur of variance w^2 (the optics' sigma^2 and the pixel's own,
    :data:`PIXEL_VARIANCE_PX2`) a point's distances from the two lines are jointly
    normal, with means s1, s2, variance w^2 each and correlation rho, the cosine of
    the angle between the lines. The X (+1 where both distances share a sign, -1
    where not) blurred is then 4 Phi2(h, k; rho) - 2 Phi(h) - 2 Phi(k) + 1, h = s1 / w
    and k = s2 / w, Phi2 the bivariate normal distribution: erf(h / sqrt 2)
    erf(k / sqrt 2), the X at right angles (:func:`edge_step` twice), and

        (2 / pi) int_0^asin(rho) exp(-(h^2 + k^2 - 2 h k sin t) / (2 cos^2 t)) dt

    (Sheppard's form of Phi2), read with :data:`_CROSSING_NODES`. In the distances
    u = (h + k) / sqrt 2 and v = (h - k) / sqrt 2 along the bisectors the exponent is
    u^2 / (2 (1 + sin t)) + v^2 / (2 (1 - sin t)). The term is largest at the centre,
    (2 / pi) asin(rho), and lies within a few blur widths of it: the product's error
    for a tilted marker, where a small X is mostly centre.

    Args:
        s1: (..., K) signed distances from line 1 (:func:`line_distances`), px.
        s2: the same from line 2.
        blur_px: the optics' blur sigma, px, broadcast against ``s1[..., :1]``.
        crossing_cos: cos(phi1 - phi2) of the lines' directions, the same way.
    """
    width = np.sqrt(np.square(blur_px) + PIXEL_VARIANCE_PX2)
    h, k = s1 / width, s2 / width
    product: NDArray[np.float64] = tabulated_erf(h / np.sqrt(2.0)) * tabulated_erf(k / np.sqrt(2.0))
    span = np.arcsin(np.clip(np.broadcast_to(crossing_cos, np.shape(h)[:-1] + (1,)), -1.0, 1.0))
    # The nodes first, so that every pass runs along the samples; in float32, whose
    # exponential costs half as much: the term keeps 4e-8 of the contrast.
    nodes = np.reshape(_CROSSING_NODES, (-1,) + (1,) * np.ndim(span))
    sine = np.sin(0.5 * span * (1.0 + nodes))
    exponent = (0.5 * (h + k) ** 2).astype(np.float32) * (-0.5 / (1.0 + sine)).astype(np.float32)
    exponent += (0.5 * (h - k) ** 2).astype(np.float32) * (-0.5 / (1.0 - sine)).astype(np.float32)
    np.exp(exponent, out=exponent)
    product += np.tensordot(_CROSSING_WEIGHTS.astype(np.float32), exponent, axes=1) * (span / np.pi)
    return product


def edge_step(
    distance_px: NDArray[np.float64], blur_px: float | NDArray[np.float64]
) -> NDArray[np.float64]:
    """erf(s / (sqrt(2) w)): a straight edge's blurred step, -1 to 1, at signed distances s.

    w^2 is the Gaussian blur's variance plus the pixel's own (:data:`PIXEL_VARIANCE_PX2`).

    Args:
        distance_px: signed distances from the edge, px.
        blur_px: the optics' blur sigma, px (or one per point, broadcast with the distances).
    """
    scale = 1.0 / np.sqrt(2.0 * (blur_px**2 + PIXEL_VARIANCE_PX2))
    step: NDArray[np.float64] = tabulated_erf(distance_px * scale)
    return step


def _centred(
    model: NDArray[np.float64], present: NDArray[np.bool_], count: NDArray[np.int64]
) -> NDArray[np.float64]:
    """Each row of ``model`` less its mean over the ``present`` samples (0 elsewhere)."""
    centred: NDArray[np.float64] = (
        model - (model * present).sum(axis=1, keepdims=True) / count
    ) * present
    return centred


class _DiskSamples(NamedTuple):
    """Each point's disk samples, padded to the longest pattern (:func:`_disk_samples`).

    Attributes:
        values: (N, K) samples.
        valid: (N, K) whether each was read inside the image.
        s1: (N, K) signed distances from line 1, px.
        s2: the same from line 2.
        present: (N, K) the point's own samples (False: the padding, and the clipped
            samples where they are left out).
        offsets: (N, K, 2) their offsets from the point, px (0 for the padding).
        clipped: (N, K) the point's own samples that clip, on the raw levels.
    """

    values: NDArray[np.float64]
    valid: NDArray[np.bool_]
    s1: NDArray[np.float64]
    s2: NDArray[np.float64]
    present: NDArray[np.bool_]
    offsets: NDArray[np.float64]
    clipped: NDArray[np.bool_]


def _disk_samples(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    max_samples: int,
    normalise: Normaliser | None,
    full_scale: float | None = None,
    leave_out_clipped: bool = False,
) -> _DiskSamples:
    """The samples of a disk of each point's radius, one pattern per rounded radius.

    Given ``full_scale`` (white, in raw levels), the clipped samples are told, and
    with ``leave_out_clipped`` (raw levels: no ``normalise``) left out of ``present``.
    """
    if leave_out_clipped and (full_scale is None or normalise is not None):
        raise ValueError("clipped samples are left out of raw levels, given their white")
    radius_key = np.round(np.asarray(radius_px, dtype=np.float64))
    keys, pattern_of = np.unique(radius_key, return_inverse=True)
    patterns = [_disk_offsets(float(radius), max_samples) for radius in keys]
    padded, in_pattern = pad_patterns(patterns)
    values, valid, s1, s2, at_white = _disk_reads(
        image, xy, line_angles, patterns, pattern_of, normalise, full_scale
    )
    present = in_pattern[pattern_of]
    at_white &= present
    if leave_out_clipped:
        present = present & ~at_white
    return _DiskSamples(values, valid, s1, s2, present, padded[pattern_of], at_white)


def _disk_reads(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    patterns: list[NDArray[np.float64]],
    pattern_of: NDArray[np.intp],
    normalise: Normaliser | None,
    full_scale: float | None = None,
) -> tuple[
    NDArray[np.float64],
    NDArray[np.bool_],
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.bool_],
]:
    """Samples, their validity, line distances and clipping at each point's pattern, padded.

    The (N, K) stack of :func:`~marker_localizer.core.sampling.pad_patterns`, point
    i at offsets ``patterns[pattern_of[i]]``: each pattern's points are read at
    their own offsets, and a shorter pattern's padding holds what its zero offsets
    would read, the sample and the distances at the centre. So sums over the stack
    are those of the padded offsets, without a read and a gamma per padded entry
    (most of them where the candidates' extents differ). Samples clip (the last
    array) where their raw level does (:func:`~marker_localizer.core.image.clipped`),
    none without ``full_scale``.
    """
    n, width = len(xy), max(len(pattern) for pattern in patterns)
    zero = np.zeros((n, 1))
    centre, centre_valid = bilinear(image, xy[:, 0, None] + zero, xy[:, 1, None] + zero)
    at_white = np.zeros((n, width), dtype=bool)
    if normalise is not None:
        centre = normalise(centre, xy)
    values, valid = np.repeat(centre, width, axis=1), np.repeat(centre_valid, width, axis=1)
    s1, s2 = (np.repeat(s, width, axis=1) for s in line_distances(zero, zero, line_angles))
    for index, pattern in enumerate(patterns):
        rows = np.flatnonzero(pattern_of == index)
        dx, dy = pattern.T
        read, inside = bilinear(image, xy[rows, 0, None] + dx, xy[rows, 1, None] + dy)
        if full_scale is not None:
            at_white[rows, : len(pattern)] = clipped(read, full_scale)
        if normalise is not None:
            read = normalise(read, xy[rows])
        values[rows, : len(pattern)], valid[rows, : len(pattern)] = read, inside
        distances = line_distances(dx, dy, line_angles[rows])
        s1[rows, : len(pattern)], s2[rows, : len(pattern)] = distances
    return values, valid, s1, s2, at_white


def template_evidence(
    annular_score: NDArray[np.float64], ncc: NDArray[np.float64], ncc_min: float
) -> NDArray[np.bool_]:
    """The paper path's decision: the template fits, and with the annular check it adds up.

    A candidate is accepted when its template NCC (:func:`template_correlation`)
    reaches ``ncc_min`` and annular_score + NCC_EVIDENCE_WEIGHT (ncc - ncc_min)
    reaches 1: a perfect annular score needs only the minimum NCC, a closer template
    fit makes up for a less even ring (:data:`NCC_EVIDENCE_WEIGHT`).

    Args:
        annular_score: (N,) score of :func:`verification.edge_phase_check`, in [0, 1].
        ncc: (N,) template NCC.
        ncc_min: the smallest NCC accepted.

    Returns:
        (N,) bool.
    """
    return (ncc >= ncc_min) & (annular_score + NCC_EVIDENCE_WEIGHT * (ncc - ncc_min) >= 1.0)


#: Quadrants of the template, in the order of :func:`quadrant_weights`: the sides of
#: line 1 and line 2 (signs of the signed distances s1, s2) each one covers.
QUADRANT_SIDES = ((1, 1), (-1, 1), (-1, -1), (1, -1))
#: The four edges between neighbouring quadrants, as index pairs into
#: :data:`QUADRANT_SIDES`: an X alternates dark and bright across each of them.
QUADRANT_EDGES = ((0, 1), (1, 2), (2, 3), (3, 0))
#: Pixel integration adds the variance of a unit box, 1/12 px^2, to the optics' blur.
PIXEL_VARIANCE_PX2 = 1.0 / 12.0
#: Gauss-Legendre nodes on [-1, 1] and their weights for :func:`blurred_x`'s integral
#: over the angle: six give the X to 1e-5 of its contrast for lines 20 degrees apart
#: and to 3e-7 from 32 degrees.
_CROSSING_NODES, _CROSSING_WEIGHTS = np.polynomial.legendre.leggauss(6)
_SQRT_2PI = np.sqrt(2.0 * np.pi)
#: Quadrant index by (side of line 1, side of line 2), 0 = negative, 1 = positive.
_QUADRANT_OF = np.array([[2, 1], [3, 0]])


class TemplateShape(NamedTuple):
    """The geometric parameters of the continuous adaptive template, each (N, ...).

    Attributes:
        xy: (N, 2) centre, where the two lines cross.
        line_angles: (N, 2) line directions phi1, phi2, radians.
        blur_px: (N, 2) Gaussian blur across line 1 and across line 2, px (an
            anisotropic PSF or motion blur widens the two edges differently).
        gain: (N, 2) relative illumination gradient g: the template is multiplied
            by 1 + g . d at offset d from the centre.
        shadow: (N, 4) a cast shadow's straight edge across the marker: the
            direction of its normal (radians, pointing into the shadow), its signed
            distance from the centre (px), the share of the light it takes (0: no
            shadow) and its penumbra's width (px). The template is multiplied by
            1 - depth * Phi((n . d - offset) / width).
    """

    xy: NDArray[np.float64]
    line_angles: NDArray[np.float64]
    blur_px: NDArray[np.float64]
    gain: NDArray[np.float64]
    shadow: NDArray[np.float64]

    @classmethod
    def start(
        cls, xy: NDArray[np.float64], line_angles: NDArray[np.float64], blur_px: float
    ) -> TemplateShape:
        """A starting shape: blur ``blur_px`` across both lines, even light, no shadow."""
        n = len(xy)
        shadow = np.zeros((n, 4))
        shadow[:, 3] = 1.0
        return cls(xy, line_angles, np.full((n, 2), blur_px), np.zeros((n, 2)), shadow)

    def take(self, index: NDArray[np.integer[Any] | np.bool_]) -> TemplateShape:
        """The shapes selected by a boolean mask or an index array."""
        return TemplateShape(*(part[index] for part in self))


class TemplateTerms(NamedTuple):
    """The closed-form template's terms at N x K pixel offsets.

    Its weights and its derivatives share them.

    Attributes:
        dx, dy: (N, K) offsets d of the pixels from the centre.
        s1, s2: (N, K) signed distances from line 1 and line 2.
        width1, width2: (N, 1) blur across each line including the pixel's area, px.
        side1, side2: (N, K) Phi(s1 / width1), Phi(s2 / width2): how much of a pixel
            lies on the positive side of each line.
        light: (N, K) the illumination gradient's factor 1 + g . d.
        shadow_z: (N, K) distance into the shadow in penumbra widths.
        shade: (N, K) the shadow's factor 1 - depth Phi(shadow_z).
    """

    dx: NDArray[np.float64]
    dy: NDArray[np.float64]
    s1: NDArray[np.float64]
    s2: NDArray[np.float64]
    width1: NDArray[np.float64]
    width2: NDArray[np.float64]
    side1: NDArray[np.float64]
    side2: NDArray[np.float64]
    light: NDArray[np.float64]
    shadow_z: NDArray[np.float64]
    shade: NDArray[np.float64]

    @property
    def gain(self) -> NDArray[np.float64]:
        """(N, K) everything the light does to the paint: gradient times shadow."""
        return self.light * self.shade


def _phi(z: NDArray[np.float64]) -> NDArray[np.float64]:
    """The standard normal's distribution function."""
    phi: NDArray[np.float64] = 0.5 * (1.0 + erf(z / np.sqrt(2.0)))
    return phi


def normal_density(z: NDArray[np.float64]) -> NDArray[np.float64]:
    """The standard normal's density."""
    density: NDArray[np.float64] = np.exp(-0.5 * z**2) / _SQRT_2PI
    return density


def template_terms(offsets: NDArray[np.float64], shape: TemplateShape) -> TemplateTerms:
    """Evaluate the template's terms at offsets d (N, K, 2) from ``shape.xy``."""
    dx, dy = offsets[..., 0], offsets[..., 1]
    s1, s2 = line_distances(dx, dy, shape.line_angles)
    blur2 = shape.blur_px**2
    width1 = np.sqrt(blur2[:, 0:1] + PIXEL_VARIANCE_PX2)
    width2 = np.sqrt(blur2[:, 1:2] + PIXEL_VARIANCE_PX2)
    light = 1.0 + shape.gain[:, 0:1] * dx + shape.gain[:, 1:2] * dy
    normal, offset, depth, width = (shape.shadow[:, k : k + 1] for k in range(4))
    shadow_z = (np.cos(normal) * dx + np.sin(normal) * dy - offset) / width
    shade = 1.0 - depth * _phi(shadow_z)
    return TemplateTerms(
        dx, dy, s1, s2, width1, width2, _phi(s1 / width1), _phi(s2 / width2), light, shadow_z, shade
    )


def quadrant_weights(terms: TemplateTerms) -> NDArray[np.float64]:
    """The adaptive template of section 3.3.1 in closed form, one grey level per quadrant.

    The paper's template is an X with the measured line angles phi1, phi2, its grey
    levels sampled from the image and blurred by the defocus sigma_b (Eq. 10). In
    closed form, quadrant q (the sides (e1, e2) of the two lines it lies on, see
    :data:`QUADRANT_SIDES`) is w_q(d) = Phi(e1 s1 / b1) Phi(e2 s2 / b2) L(d), with
    s_i the signed distance of the offset d from line i through the centre,
    b_i^2 = sigma_i^2 + 1/12 (the optics' blur and the pixel's area) and L(d) the
    light: an illumination gradient times a cast shadow's edge, if any. The weights
    of the four quadrants sum to the light, so the template sum_q l_q w_q(d) is
    exact for perpendicular lines under a Gaussian PSF and close otherwise. Each
    quadrant keeps its own level l_q: a dull quadrant, worn or dirty paint, does
    not bend it; nor does a shadow, which the light takes.

    Args:
        terms: from :func:`template_terms`.

    Returns:
        (N, K, 4) w_q(d).
    """
    p1, p2 = terms.side1, terms.side2
    unlit = np.stack([p1 * p2, (1.0 - p1) * p2, (1.0 - p1) * (1.0 - p2), p1 * (1.0 - p2)], -1)
    return unlit * terms.gain[..., None]


#: Parameters of the template's geometry, in the order of :func:`template_jacobian`:
#: centre (2), line angles (2), ln blurs (2), gain (2), shadow edge (4).
SHAPE_PARAMETERS = 12


def shape_parameters(shape: TemplateShape) -> NDArray[np.float64]:
    """(N, 12) the parameter vector :func:`template_jacobian` differentiates by."""
    shadow = shape.shadow.copy()
    shadow[:, 3] = np.log(shadow[:, 3])
    return np.hstack([shape.xy, shape.line_angles, np.log(shape.blur_px), shape.gain, shadow])


def shape_from_parameters(params: NDArray[np.float64]) -> TemplateShape:
    """The inverse of :func:`shape_parameters`."""
    shadow = params[:, 8:12].copy()
    shadow[:, 3] = np.exp(shadow[:, 3])
    return TemplateShape(
        params[:, :2], params[:, 2:4], np.exp(params[:, 4:6]), params[:, 6:8], shadow
    )


def template_jacobian(
    terms: TemplateTerms, shape: TemplateShape, levels: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Derivatives of the template sum_q l_q w_q(d) with respect to its geometry.

    Args:
        terms: from :func:`template_terms` at ``shape``.
        shape: the geometry.
        levels: (N, 4) the quadrant levels l_q.

    Returns:
        (N, K, 12) derivatives with respect to :func:`shape_parameters` (x, y, phi1,
        phi2, ln sigma1, ln sigma2, g_x, g_y, and the shadow's normal, offset,
        depth, ln width), the pixels staying where they are.
    """
    p1, p2 = terms.side1, terms.side2
    l0, l1, l2, l3 = (levels[:, q : q + 1] for q in range(4))
    paint = l0 * p1 * p2 + l1 * (1.0 - p1) * p2 + l2 * (1.0 - p1) * (1.0 - p2)
    paint += l3 * p1 * (1.0 - p2)
    gain = terms.gain
    # d(paint)/d(side_i) times each side's density in s_i, times the light.
    d_s1 = ((l0 - l1) * p2 + (l3 - l2) * (1.0 - p2)) * normal_density(terms.s1 / terms.width1)
    d_s1 *= gain / terms.width1
    d_s2 = ((l0 - l3) * p1 + (l1 - l2) * (1.0 - p1)) * normal_density(terms.s2 / terms.width2)
    d_s2 *= gain / terms.width2
    a1, a2 = shape.line_angles[:, 0:1], shape.line_angles[:, 1:2]
    g = shape.gain
    blur2 = shape.blur_px**2
    normal, _, depth, width = (shape.shadow[:, k : k + 1] for k in range(4))
    # d(shade)/d(shadow_z) times paint and gradient: the shadow's own terms.
    d_shadow = -depth * normal_density(terms.shadow_z) * paint * terms.light
    jacobian = np.empty(terms.s1.shape + (SHAPE_PARAMETERS,))
    # Every offset d = p - c moves by -dc when the centre moves by +dc.
    jacobian[..., 0] = -(d_s1 * np.sin(a1) + d_s2 * np.sin(a2))
    jacobian[..., 0] -= paint * terms.shade * g[:, 0:1] + d_shadow * np.cos(normal) / width
    jacobian[..., 1] = d_s1 * np.cos(a1) + d_s2 * np.cos(a2)
    jacobian[..., 1] -= paint * terms.shade * g[:, 1:2] + d_shadow * np.sin(normal) / width
    jacobian[..., 2] = d_s1 * (np.cos(a1) * terms.dx + np.sin(a1) * terms.dy)
    jacobian[..., 3] = d_s2 * (np.cos(a2) * terms.dx + np.sin(a2) * terms.dy)
    # d width_i / d ln sigma_i = sigma_i^2 / width_i, and d Phi(s/w) / d w = -density s / w^2.
    jacobian[..., 4] = -d_s1 * terms.s1 * blur2[:, 0:1] / terms.width1**2
    jacobian[..., 5] = -d_s2 * terms.s2 * blur2[:, 1:2] / terms.width2**2
    jacobian[..., 6] = paint * terms.shade * terms.dx
    jacobian[..., 7] = paint * terms.shade * terms.dy
    jacobian[..., 8] = d_shadow * (np.cos(normal) * terms.dy - np.sin(normal) * terms.dx) / width
    jacobian[..., 9] = -d_shadow / width
    jacobian[..., 10] = -_phi(terms.shadow_z) * paint * terms.light
    jacobian[..., 11] = -d_shadow * terms.shadow_z
    return jacobian


#: Spacing of the samples along each line of :func:`line_extents`, px.
_EXTENT_STEP_PX = 0.5
#: The X ends where the step across a line falls below this share of its
#: expected height: halfway down a blurred end of the paint.
_EXTENT_FADE = 0.5
#: Samples beside a line sit this many blur widths from it (plus
#: :data:`_EXTENT_SIDE_PX`), clear of its blurred edge.
_EXTENT_SIDE_BLURS = 1.5
_EXTENT_SIDE_PX = 0.75
#: Smallest sum of the two sides a modulation divides by, as a share of the fitted
#: levels' sum: keeps black ground on both sides from dividing by its noise.
_EXTENT_MIN_SUM = 0.05
#: Farthest the samples reach, in largest expected marker radii: a plate's end and a
#: little beyond.
_EXTENT_REACH = 1.3
#: The region fitted keeps this many blur widths (plus :data:`_REGION_MARGIN_PX`)
#: inside the measured ends of the X, where the paint's outline blurs in.
_REGION_MARGIN_BLURS = 1.5
_REGION_MARGIN_PX = 0.5
#: Smallest conjugate semi-diameter of a region, px.
_REGION_MIN_PX = 1.5


def half_line_quadrants(line_angles: NDArray[np.float64]) -> NDArray[np.intp]:
    """(N, 4, 2) the quadrants on the positive and negative side of each half-line.

    Half-lines in the order +e1, +e2, -e1, -e2 (e_i the direction of line i); the
    positive side of line i is where its signed distance s_i is positive.
    """
    a1, a2 = line_angles[:, 0], line_angles[:, 1]
    # Along +e1 the signed distance from line 2 is sin(a2 - a1) t, and vice versa.
    other = np.stack([np.sin(a2 - a1), np.sin(a1 - a2)], axis=1)
    other_side = np.where(other >= 0, 1, 0)  # (N, 2): 1 = positive side
    # _QUADRANT_OF[side of line 1][side of line 2], sides as 0 (negative) / 1 (positive).
    out = np.empty((len(line_angles), 4, 2), dtype=np.intp)
    for k, (line, direction) in enumerate(((0, 1), (1, 1), (0, -1), (1, -1))):
        across = other_side[:, line] if direction > 0 else 1 - other_side[:, line]
        for column, side in enumerate((1, 0)):
            if line == 0:
                out[:, k, column] = _QUADRANT_OF[side, across]
            else:
                out[:, k, column] = _QUADRANT_OF[across, side]
    return out


def line_extents(
    image: NDArray[Any],
    shape: TemplateShape,
    levels: NDArray[np.float64],
    max_radius_px: float,
) -> NDArray[np.float64]:
    """How far each of the four half-lines of the X reaches from its centre, px.

    Along each half-line the image is sampled on both sides of it; the X goes on
    while the modulation of the two sides, (a - b) / (a + b), keeps the one the
    fitted quadrant levels predict, and ends where it fades to half of it (the end
    of the quarter disks or squares: a white plate or the ground on both sides).
    This is the adaptive radius of the paper's annular check, measured on the
    lines. It survives a dull quadrant (its levels predict its smaller step) and a
    shadow across the marker or any other change of the light (a modulation does
    not see a factor on both sides). For an X seen under any affine view the two
    halves of a line reach equally far.

    Args:
        image: (H, W) grey image.
        shape: fitted geometry, N points.
        levels: (N, 4) fitted quadrant levels.
        max_radius_px: the largest expected marker radius.

    Returns:
        (N, 4) reach of the half-lines +e1, +e2, -e1, -e2 (at least the first sample
        clear of the crossing; at most :data:`_EXTENT_REACH` x ``max_radius_px``).
    """
    n = len(shape.xy)
    distance = np.arange(_EXTENT_STEP_PX, _EXTENT_REACH * max_radius_px + 1.0, _EXTENT_STEP_PX)
    extents = np.empty((n, 4))
    if n == 0:
        return extents
    sides = half_line_quadrants(shape.line_angles)
    rows = np.arange(n)
    for k, (line, direction) in enumerate(_HALF_LINES):
        side = _EXTENT_SIDE_BLURS * np.sqrt(shape.blur_px[:, line] ** 2 + PIXEL_VARIANCE_PX2)
        side = side + _EXTENT_SIDE_PX
        plus, minus, valid = _beside_half_line(
            image, shape.xy, shape.line_angles, line, direction, side, distance
        )
        high, low = levels[rows, sides[:, k, 0]], levels[rows, sides[:, k, 1]]
        total = np.abs(high + low)[:, None]
        expected = (high - low)[:, None] / np.maximum(total, 1e-12)
        modulation = (plus - minus) / np.maximum(np.abs(plus + minus), _EXTENT_MIN_SUM * total)
        ratio = np.where(valid, modulation / np.where(expected == 0, 1e-12, expected), 0.0)
        first = _first_clear_of_other_line(shape.line_angles, side)
        extents[:, k] = _faded_end(ratio, distance, first)
    return extents


#: The four half-lines of an X, as (line, direction): +e1, +e2, -e1, -e2.
_HALF_LINES = ((0, 1), (1, 1), (0, -1), (1, -1))
#: :func:`line_reaches` reads beside each line this far from it, px: 1.5 widths of a
#: 0.8 px blur plus :data:`_EXTENT_SIDE_PX`, as :func:`line_extents` reads beside a
#: fitted X of that blur (the renderers' optics are 0.5-1.5 px).
_REACH_SIDE_PX = 2.0
#: ... and takes the step each line's sides show between these shares of the X's
#: extent (from where its samples clear the other line) as the step the X makes.
_REACH_REFERENCE = (0.3, 0.9)


def _beside_half_line(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    line: int,
    direction: int,
    side_px: NDArray[np.float64] | float,
    distance: NDArray[Any],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """(N, D) bilinear samples either side of one half-line at ``distance`` along it.

    Returns:
        (plus, minus, valid): the samples on the line's positive and negative side,
        and where both lie inside the image.
    """
    angle = line_angles[:, line]
    along = direction * np.stack([np.cos(angle), np.sin(angle)], axis=1)
    normal = np.stack([np.sin(angle), -np.cos(angle)], axis=1)
    on_line = xy[:, None, :] + distance[None, :, None] * along[:, None, :]
    beside = (
        np.broadcast_to(np.asarray(side_px, np.float64), (len(xy),))[:, None, None]
        * normal[:, None, :]
    )
    plus, valid_plus = bilinear(image, *np.moveaxis(on_line + beside, -1, 0))
    minus, valid_minus = bilinear(image, *np.moveaxis(on_line - beside, -1, 0))
    return plus, minus, valid_plus & valid_minus


def _first_clear_of_other_line(
    line_angles: NDArray[np.float64], side_px: NDArray[np.float64] | float
) -> NDArray[np.float64]:
    """(N,) the distance along a line from which samples ``side_px`` beside it clear the other."""
    sine = np.abs(np.sin(line_angles[:, 0] - line_angles[:, 1]))
    first: NDArray[np.float64] = side_px * (
        np.sqrt(np.maximum(1.0 - sine**2, 0.0)) / np.maximum(sine, _MIN_CROSSING_SINE) + 1.0
    )
    return first


def _faded_end(
    ratio: NDArray[np.float64], distance: NDArray[Any], first: NDArray[np.float64]
) -> NDArray[np.float64]:
    """(N,) where each half-line's step over the X's, ``ratio`` (N, D), first fades.

    Under :data:`_EXTENT_FADE`, three samples smoothed, from ``first`` on; the last
    distance where it never does.
    """
    smooth = ratio.copy()
    smooth[:, 1:-1] = (ratio[:, :-2] + ratio[:, 1:-1] + ratio[:, 2:]) / 3.0
    # NaN (no step to compare with) counts as faded.
    faded = ~(smooth >= _EXTENT_FADE) & (distance[None, :] >= first[:, None])
    end = np.where(faded.any(axis=1), np.argmax(faded, axis=1), len(distance) - 1)
    reach: NDArray[np.float64] = distance[end]
    return reach


def line_reaches(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    extent_px: NDArray[np.float64],
    max_distance_px: float,
) -> NDArray[np.float64]:
    """(N,) how far an X reaches all round: the smaller semi-axis of the ellipse of its ends.

    :func:`smaller_semi_axis` of :func:`reaches_along_lines`: the radius of the
    largest disk about the centre inside the X. Arguments as for
    :func:`reaches_along_lines`.
    """
    return smaller_semi_axis(
        reaches_along_lines(image, xy, line_angles, extent_px, max_distance_px), line_angles
    )


def reaches_along_lines(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    extent_px: NDArray[np.float64],
    max_distance_px: float,
) -> NDArray[np.float64]:
    """(N, 2) how far an X reaches along each of its lines: the shorter of the line's halves.

    :func:`line_extents` without a fit: each half-line's step across it, the
    modulation (a - b) / (a + b) of its two sides, is compared with the step it
    makes inside the X, its median between :data:`_REACH_REFERENCE` of the
    ``extent_px`` the rings found, and the half-line ends where that fades to
    half. The modulation takes no notice of a factor on both sides, so neither a
    dull quadrant (its own step is the reference) nor a light's slope or a shadow
    across the line shortens the reach, where either breaks the rings' grey-level
    symmetry short of the X's end. Under an affine view the X's ends lie on an
    ellipse whose conjugate semi-diameters run along the two lines, these reaches
    long (:func:`smaller_semi_axis`, :func:`within_ellipse`).

    Args:
        image: (H, W) grey image, raw levels.
        xy: (N, 2) centres.
        line_angles: (N, 2) line directions, radians.
        extent_px: (N,) the X's extent from its rings, px.
        max_distance_px: farthest reach read, px.
    """
    first = _first_clear_of_other_line(line_angles, _REACH_SIDE_PX)
    inner = np.maximum(first, _REACH_REFERENCE[0] * extent_px)
    outer = np.maximum(_REACH_REFERENCE[1] * extent_px, inner + 1.0)
    # The reference's samples are always read, however close the lines.
    farthest = max(max_distance_px, float(outer.max(initial=0.0)))
    distance = np.arange(_EXTENT_STEP_PX, farthest + _EXTENT_STEP_PX, _EXTENT_STEP_PX)
    reference = (distance[None, :] >= inner[:, None]) & (distance[None, :] <= outer[:, None])
    reach = np.empty((len(xy), 4))
    for k, (line, direction) in enumerate(_HALF_LINES):
        plus, minus, valid = _beside_half_line(
            image, xy, line_angles, line, direction, _REACH_SIDE_PX, distance
        )
        total = np.abs(plus + minus)
        typical = nan_median(np.where(reference, total, np.nan))
        modulation = (plus - minus) / np.maximum(total, _EXTENT_MIN_SUM * typical[:, None])
        step = nan_median(np.where(reference, modulation, np.nan))
        # No step inside (both sides clipped at white, say): nothing to compare with.
        ratio = np.where(valid, modulation / np.where(step != 0.0, step, np.nan)[:, None], 0.0)
        reach[:, k] = _faded_end(ratio, distance, inner)
    lines: NDArray[np.float64] = np.minimum(reach[:, :2], reach[:, 2:])
    return lines


def smaller_semi_axis(
    semi_diameters: NDArray[np.float64], line_angles: NDArray[np.float64]
) -> NDArray[np.float64]:
    """(N,) the smaller semi-axis B of ellipses given by conjugate semi-diameters along two lines.

    With p and q the semi-diameters' lengths (N, 2) and the lines' directions (N, 2),
    radians: A^2 + B^2 = p^2 + q^2 and A B = p q sin(angle between the lines).
    """
    squares = (semi_diameters**2).sum(axis=1)
    area = semi_diameters.prod(axis=1) * np.abs(np.sin(line_angles[:, 0] - line_angles[:, 1]))
    semi_axis: NDArray[np.float64] = np.sqrt(
        np.maximum(squares - np.sqrt(np.maximum(squares**2 - 4.0 * area**2, 0.0)), 0.0) / 2.0
    )
    return semi_axis


def within_ellipse(
    s1: NDArray[np.float64],
    s2: NDArray[np.float64],
    semi_diameters: NDArray[np.float64],
    line_angles: NDArray[np.float64],
) -> NDArray[np.bool_]:
    """(N, K) which offsets lie in the ellipse whose conjugate semi-diameters run along the lines.

    An offset a e1 + b e2 (e_i along line i) lies a |sin| from line 2 and b |sin|
    from line 1, sin that of the angle between the lines; it is inside where
    (a / p)^2 + (b / q)^2 <= 1, p and q the semi-diameters along lines 1 and 2.

    Args:
        s1: (N, K) signed distances of the offsets from line 1 (:func:`line_distances`), px.
        s2: the same from line 2.
        semi_diameters: (N, 2) p and q, px.
        line_angles: (N, 2) the lines' directions, radians.
    """
    p, q = semi_diameters[:, 0:1], semi_diameters[:, 1:2]
    sine = np.abs(np.sin(line_angles[:, 0:1] - line_angles[:, 1:2]))
    inside: NDArray[np.bool_] = (s2 * q) ** 2 + (s1 * p) ** 2 <= (p * q * sine) ** 2
    return inside


def template_region(
    shape: TemplateShape,
    extents: NDArray[np.float64],
    cap_px: NDArray[np.float64],
    max_pixels: int | None = None,
) -> list[NDArray[np.float64]]:
    """Pixels inside the X: the ellipse on the two lines' reaches, clear of its ends.

    Under an affine view the ends of the X lie on an ellipse whose conjugate
    semi-diameters run along the two lines (the images of the marker's axes), so
    the shorter half of each line (``extents``) and the two directions fix it. The
    ellipse is shrunk by the blur so that the blurred outline of the paint stays
    out, and capped at ``cap_px`` (a region grows step by step).

    Args:
        shape: fitted geometry, N points.
        extents: (N, 4) from :func:`line_extents`.
        cap_px: (N,) largest semi-diameter allowed.
        max_pixels: thin a larger region to every s-th row and column of the pixels
            (s the smallest stride that fits), a lattice symmetric about the
            centre; None keeps every pixel.

    Returns:
        Per point, (K_i, 2) integer offsets from ``round(shape.xy)`` (possibly empty).
    """
    reach = np.minimum(np.minimum(extents[:, :2], extents[:, 2:]), cap_px[:, None])
    margin = _REGION_MARGIN_BLURS * np.sqrt(shape.blur_px.max(axis=1) ** 2 + PIXEL_VARIANCE_PX2)
    semi = np.maximum(reach - (margin + _REGION_MARGIN_PX)[:, None], _REGION_MIN_PX)
    regions: list[NDArray[np.float64]] = []
    for k in range(len(shape.xy)):  # per point (not per pixel): each has its own ellipse
        a1, a2 = shape.line_angles[k]
        if abs(semi[k].prod() * np.sin(a2 - a1)) < 1e-9:  # parallel lines span no ellipse
            regions.append(np.zeros((0, 2)))
            continue
        half = int(np.ceil(semi[k].max())) + 1
        grid = np.arange(-half, half + 1, dtype=np.float64)
        gx, gy = np.meshgrid(grid, grid)
        offsets = np.stack([gx.ravel(), gy.ravel()], axis=1)
        d = offsets + np.round(shape.xy[k]) - shape.xy[k]
        angles = shape.line_angles[k : k + 1]
        s1, s2 = line_distances(d[None, :, 0], d[None, :, 1], angles)
        inside = offsets[within_ellipse(s1, s2, semi[k : k + 1], angles)[0]]
        if max_pixels is not None and len(inside) > max_pixels:
            stride = int(np.ceil(np.sqrt(len(inside) / max_pixels)))
            inside = inside[(inside % stride == 0).all(axis=1)]
        regions.append(inside)
    return regions
