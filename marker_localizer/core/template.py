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
from typing import NamedTuple

import cv2
import numpy as np
from scipy.special import erf

from marker_localizer.core.sampling import Normaliser, bilinear, pad_patterns

_SUPERSAMPLING = 4  # template pixels are area-integrated from 4x4 sub-samples
#: Paper path: annular score a template NCC above its minimum is worth, per unit of
#: NCC. Markers reach template NCCs of 0.95-1.00 with annular scores of 0.65-0.95;
#: ground-texture saddles that pass the annular check (extents of 4-12 px) reach
#: 0.95-0.98 with scores of 0.7-0.9: neither alone separates them, and trading 0.01
#: of NCC for 0.08 of score does best on the renderer's families (a), (c), (d).
NCC_EVIDENCE_WEIGHT = 8.0


def sector_sign(x: np.ndarray, y: np.ndarray, line_angles: np.ndarray) -> np.ndarray:
    """+1 / -1 for the two pairs of opposite sectors between two lines through the origin.

    Args:
        x: (..., K) positions relative to the centre.
        y: same shape as ``x``.
        line_angles: (..., 2) line directions in radians, broadcast against x[..., :1].

    Returns:
        float array of the shape of ``x``: the product of the signed distances to
        both lines, as a sign. Sectors facing each other across the centre share a sign.
    """
    a1, a2 = line_angles[..., 0:1], line_angles[..., 1:2]
    side1 = np.sin(a1) * x - np.cos(a1) * y
    side2 = np.sin(a2) * x - np.cos(a2) * y
    return np.sign(side1 * side2)


class GreyLevels(NamedTuple):
    """Levels sampled on the sector bisectors; each (N,).

    Attributes:
        positive: mean level of the two sectors where :func:`sector_sign` is +1.
        negative: mean level of the two sectors where it is -1.
    """

    positive: np.ndarray
    negative: np.ndarray


def sample_grey_levels(
    image: np.ndarray, xy: np.ndarray, line_angles: np.ndarray, offset_px: np.ndarray
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


def estimate_defocus_sigma(gradient_magnitude_peak: np.ndarray, contrast: np.ndarray) -> np.ndarray:
    """Gaussian blur sigma_b of an edge from its contrast and steepest slope.

    A step of height C blurred by a Gaussian of sigma has slope C / (sqrt(2 pi) sigma)
    at the edge, so sigma_b = C / (sqrt(2 pi) * max |grad I|).

    Args:
        gradient_magnitude_peak: (N,) largest gradient magnitude across the edges.
        contrast: (N,) step height in the same units.

    Returns:
        (N,) sigma_b in pixels, clipped to [0.3, 5].
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        sigma = np.abs(contrast) / (np.sqrt(2.0 * np.pi) * gradient_magnitude_peak)
    return np.clip(np.nan_to_num(sigma, nan=1.0, posinf=5.0), 0.3, 5.0)


def adaptive_template(
    line_angles: np.ndarray, levels: GreyLevels, sigma_b: np.ndarray, half_size: int
) -> np.ndarray:
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
    templates = np.empty_like(fine)
    for k in range(len(fine)):  # per marker (not per pixel): each has its own blur
        templates[k] = cv2.GaussianBlur(
            fine[k], (0, 0), float(sigma_b[k]), borderType=cv2.BORDER_REFLECT
        )
    return templates


def choose_polarity(patch: np.ndarray, templates: np.ndarray) -> np.ndarray:
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
        ncc: the largest |NCC| over the candidate blurs (1 = a perfect X).
        sigma_b: the defocus sigma achieving it, px.
    """

    ncc: np.ndarray
    sigma_b: np.ndarray


@functools.lru_cache(maxsize=256)
def _disk_offsets(radius_px: float, max_samples: int) -> np.ndarray:
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
    image: np.ndarray,
    xy: np.ndarray,
    line_angles: np.ndarray,
    radius_px: np.ndarray,
    sigmas_px: tuple[float, ...] = (0.6, 1.0, 1.6, 2.5),
    max_samples: int = 300,
    normalise: Normaliser | None = None,
) -> TemplateMatch:
    """NCC between the image and the adaptive template at a sub-pixel centre (Eqs. 10-12).

    The template is the blurred X of section 3.3.1 in closed form:
    T(p) = erf(s1 / (sqrt(2) sigma_b)) * erf(s2 / (sqrt(2) sigma_b)), with s1, s2 the
    signed distances of p to the two lines through the centre, exact for a Gaussian
    PSF on perpendicular lines. NCC is invariant to the grey levels, so only the
    angles and sigma_b matter; sigma_b is chosen from ``sigmas_px`` as the best
    match (the edge-spread estimate of the paper), and the sign of the NCC is the
    polarity choice of Eq. (10).

    Args:
        image: (H, W) image (any numeric dtype).
        xy: (N, 2) centres (sub-pixel).
        line_angles: (N, 2) line directions.
        radius_px: (N,) disk radius over which to correlate.
        sigmas_px: candidate defocus sigmas.
        max_samples: cap on samples per point (the grid coarsens for big disks).
        normalise: applied to each point's samples before the NCC (e.g. the dynamic
            gamma).

    Returns:
        :class:`TemplateMatch`.
    """
    n = len(xy)
    if n == 0:
        return TemplateMatch(np.zeros(0), np.zeros(0))
    # One disk pattern per rounded radius; the padding's samples are left out below.
    radius_key = np.round(np.asarray(radius_px, dtype=np.float64))
    keys, pattern_of = np.unique(radius_key, return_inverse=True)
    padded, in_pattern = pad_patterns(
        [_disk_offsets(float(radius), max_samples) for radius in keys]
    )
    dx, dy = padded[pattern_of, :, 0], padded[pattern_of, :, 1]
    present = in_pattern[pattern_of]
    values, valid = bilinear(image, xy[:, 0, None] + dx, xy[:, 1, None] + dy)
    if normalise is not None:
        values = normalise(values, xy)
    count = present.sum(axis=1, keepdims=True)
    a1, a2 = line_angles[:, 0:1], line_angles[:, 1:2]
    s1 = np.sin(a1) * dx - np.cos(a1) * dy
    s2 = np.sin(a2) * dx - np.cos(a2) * dy
    centred = (values - (values * present).sum(axis=1, keepdims=True) / count) * (valid & present)
    norm_i = np.linalg.norm(centred, axis=1) + 1e-12
    ncc = np.zeros(n)
    best_sigma = np.full(n, np.nan)
    for sigma in sigmas_px:
        # Pixel integration adds 1/12 px^2 to the Gaussian PSF variance.
        scale = 1.0 / np.sqrt(2.0 * (sigma**2 + 1.0 / 12.0))
        model = erf(s1 * scale) * erf(s2 * scale)
        model_centred = (model - (model * present).sum(axis=1, keepdims=True) / count) * present
        model_norm2 = (model_centred**2).sum(axis=1) + 1e-12
        corr = np.abs((centred * model_centred).sum(axis=1)) / (norm_i * np.sqrt(model_norm2))
        better = corr > ncc
        ncc[better] = corr[better]
        best_sigma[better] = sigma
    return TemplateMatch(ncc, best_sigma)


def template_evidence(annular_score: np.ndarray, ncc: np.ndarray, ncc_min: float) -> np.ndarray:
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
