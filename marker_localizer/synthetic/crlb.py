"""Cramer-Rao bound of a marker centre: Fisher information and the expected error it implies.

For an image whose pixel i has the noise-free value mu_i(x, y) (a function of
the marker centre (x, y), every other parameter known) and independent
Gaussian noise of variance var_i, the Fisher information of the centre is

    F = sum_i grad mu_i grad mu_i^T / var_i,

and F^-1 bounds the covariance of every unbiased estimator of (x, y) that reads
those pixels. The renderer (:func:`~marker_localizer.synthetic.scene.render_scene`
with ``crlb=True``) takes the gradients by central differences of the noise-free
frame with the marker moved, and sums over the pixels of the X alone: the
independent renderer's definition (its ``truth.json``), kept so that the two
compare. It is the bound of an estimator that reads the X's pixels, not of one
that reads the whole window: the arcs and the plate's outline against the ground
carry information too, and a maximum-likelihood fit of the whole window, every
parameter but the centre known, reached 0.71-0.82 of it on three markers (and
1.01-1.05 of it over the X's pixels; docs/accuracy-journal.md, "The Cramer-Rao
bound is the X's pixels'").

A bound is reported as the expected Euclidean error of an efficient unbiased
estimator of those pixels, E|e| for e ~ N(0, F^-1): with the eigenvalues
l1 >= l2 of F^-1,

    E|e| = sqrt(2 / pi) sqrt(l1) E(m),  m = 1 - l2 / l1,

where E is the complete elliptic integral of the second kind (parameter m):
the mean of the Rayleigh radius sqrt(pi / 2) times the mean of the ellipse's
radius over a uniform angle, (2 / pi) sqrt(l1) E(m).

That bound knows everything but the centre. A fit must also estimate the rest of
the marker's image: its plane's homography, the paints, the blur, the light.
With the information F of all of them, the centre's bound is the first 2 x 2
block of F^-1 (the Schur complement of the others): :func:`centre_bound`, and
:class:`BoundParts` for the parameters of :data:`BOUND_PARAMETERS`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from scipy.special import ellipe

#: Information matrices whose smaller eigenvalue is below this fraction of their
#: trace are singular: a bound of 1e6 times the other direction's says nothing.
_SINGULAR_RATIO = 1e-12
#: A direction of the parameters the pixels say nothing about must hold less than this
#: of the centre (a unit vector's component) for the centre to be bounded without it.
_CENTRE_IN_UNSEEN = 1e-3


#: The parameters of a marker's image whose information :class:`BoundParts` weighs, in
#: the order of its matrices: the centre; the plane's homography about it (the images
#: of its u and v axes, two components each, then its perspective along u and v);
#: the dark and the bright paint's reflectance and a dull quadrant's factor; the
#: optics' Gaussian blur; the light's slope across the marker along x and y; a cast
#: shadow's edge across it (its normal, its offset, the share of the light it takes).
#: A marker without a dull quadrant or a shadow has no information on them: they drop
#: out.
BOUND_PARAMETERS = (
    "x",
    "y",
    "u_x",
    "u_y",
    "v_x",
    "v_y",
    "perspective_u",
    "perspective_v",
    "dark",
    "bright",
    "dull",
    "blur",
    "light_slope_x",
    "light_slope_y",
    "shadow_normal",
    "shadow_offset",
    "shadow_darkening",
)
#: The parameters of an affine marker: a plane seen from far away, without perspective.
AFFINE_PARAMETERS = tuple(p for p in BOUND_PARAMETERS if not p.startswith("perspective"))


class BoundParts(NamedTuple):
    """A marker centre's bounds (E|e|, px) by what else is known and which pixels are read.

    Attributes:
        known: every other parameter known, the pixels of the whole X: the
            Cramer-Rao bound (``MarkerTruth.crlb_mean_abs_error_px``).
        affine: every parameter of :data:`AFFINE_PARAMETERS` unknown, the
            perspective known, the whole X.
        projective: every parameter of :data:`BOUND_PARAMETERS` unknown, the whole X.
        inner_affine: as ``affine``, from the pixels within a share of the radius.
        inner_projective: as ``projective``, from those pixels.
    """

    known: float
    affine: float
    projective: float
    inner_affine: float
    inner_projective: float

    @classmethod
    def of(cls, whole: np.ndarray, inner: np.ndarray) -> BoundParts:
        """The bounds of the information over :data:`BOUND_PARAMETERS` of both regions."""
        affine = [BOUND_PARAMETERS.index(p) for p in AFFINE_PARAMETERS]
        return cls(
            crlb_mean_abs_error(whole[:2, :2]),
            centre_bound(whole[np.ix_(affine, affine)]),
            centre_bound(whole),
            centre_bound(inner[np.ix_(affine, affine)]),
            centre_bound(inner),
        )


def centre_bound(information: np.ndarray) -> float:
    """E|e| of the centre, the first two parameters, with every other one estimated too, px.

    The first 2 x 2 block of the inverse information. Directions of the parameters
    that the pixels cannot tell apart (the X's scale along its lines, read where
    its arcs are not) are left out, as long as the centre takes no part in them:
    unidentifiable, they take nothing from the centre either.

    Args:
        information: (P, P) Fisher information, the centre (x, y) first.

    Returns:
        The expected Euclidean error, px (inf where the centre is not identifiable).
    """
    info = np.asarray(information, np.float64)
    scale = np.sqrt(np.maximum(np.diag(info), 0.0)) if np.isfinite(info).all() else np.zeros(1)
    if min(scale[:2], default=0.0) <= 0.0:
        return math.inf
    # Scaled to unit diagonal: the parameters' units differ by orders of magnitude. A
    # parameter with no information at all keeps a zero row, which is unseen below.
    scale[scale == 0.0] = 1.0
    values, vectors = np.linalg.eigh(info / np.outer(scale, scale))
    seen = values > _SINGULAR_RATIO * values[-1]
    if np.abs(vectors[:2, ~seen]).max(initial=0.0) > _CENTRE_IN_UNSEEN:
        return math.inf
    inverse = (vectors[:, seen] / values[seen]) @ vectors[:, seen].T
    return expected_radial_error(inverse[:2, :2] / np.outer(scale[:2], scale[:2]))


def fisher_information(
    d_mu_dx: np.ndarray, d_mu_dy: np.ndarray, variance: np.ndarray, mask: np.ndarray
) -> np.ndarray:
    """Fisher information of a position (x, y) from the pixels in ``mask``.

    Args:
        d_mu_dx: (H, W) derivative of the noise-free image along x, DN / px.
        d_mu_dy: (H, W) derivative along y, DN / px.
        variance: (H, W) noise variance of each pixel, DN^2 (> 0).
        mask: (H, W) bool, the pixels that take part.

    Returns:
        (2, 2) float64 information matrix, px^-2.
    """
    return parameter_information([d_mu_dx, d_mu_dy], variance, mask)


def parameter_information(
    derivatives: list[np.ndarray], variance: np.ndarray, mask: np.ndarray
) -> np.ndarray:
    """Fisher information of P parameters from the pixels in ``mask``.

    Args:
        derivatives: P (H, W) derivatives of the noise-free image, DN per unit.
        variance: (H, W) noise variance of each pixel, DN^2 (> 0).
        mask: (H, W) bool, the pixels that take part.

    Returns:
        (P, P) float64 information matrix.
    """
    columns = np.stack([np.asarray(d, np.float64)[mask] for d in derivatives], axis=1)
    weight = 1.0 / np.asarray(variance, np.float64)[mask]
    information: np.ndarray = (columns * weight[:, None]).T @ columns
    return information


def expected_radial_error(covariance: np.ndarray) -> float:
    """E|e| for a 2-D Gaussian error e ~ N(0, covariance), by the elliptic closed form.

    Args:
        covariance: (2, 2) symmetric positive semi-definite matrix, px^2.

    Returns:
        The expected Euclidean error, px.
    """
    smaller, larger = np.linalg.eigvalsh(np.asarray(covariance, np.float64))
    if larger <= 0:
        return 0.0
    return math.sqrt(2.0 / math.pi * larger) * float(ellipe(1.0 - max(smaller, 0.0) / larger))


def crlb_mean_abs_error(information: np.ndarray) -> float:
    """Expected Euclidean error of an efficient unbiased estimator given F, px (inf if singular).

    Args:
        information: (2, 2) Fisher information of the position, px^-2.
    """
    info = np.asarray(information, np.float64)
    smallest = np.linalg.eigvalsh(info)[0] if np.isfinite(info).all() else 0.0
    # An eigenvalue this far below the other is a direction the pixels say nothing about.
    if smallest <= _SINGULAR_RATIO * np.trace(info):
        return math.inf
    return expected_radial_error(np.linalg.inv(info))


#: Edges of the bands of the X's signal-to-noise ratio (:func:`x_snr`) that recall is
#: split by: octaves from 8, about where a matched filter searching a 12 MP frame for
#: an X of any position, lines and blur starts to find it at a fraction of a false
#: point a frame (its threshold on noise alone: docs/accuracy-journal.md, "What an ideal
#: detector could find").
X_SNR_BANDS = (8.0, 16.0, 32.0, 64.0, 128.0, 256.0, 512.0)


def x_snr(turned: Sequence[np.ndarray], variance: np.ndarray) -> float:
    """The signal-to-noise ratio of a marker's X: what an ideal detector has to go on.

    A diagonal marker turned a quarter in its plane is its own negative (its
    bright and dark quadrants trade places), while its plate and the ground are
    not changed by the turn. With ``turned[k]`` the noise-free image of the marker
    turned k quarters under the frame's own light, optics and gamma, the image's
    part that changes sign under the turn, X = (I0 - I1 + I2 - I3) / 4, is the X
    alone: the mean of the four turns, what the marker has in common with a plate
    without an X, drops out, and the light, which does not turn with the marker,
    scales the X where it falls (a shadow's half the less). A matched filter tells
    the marker from its plate without the X (the four turns' mean) at

        d' = sqrt(sum_i X_i^2 / var_i),

    the known-signal limit: a detector that estimates the X's position, lines and
    blur, or that must tell it from ground texture rather than from noise, needs
    more (docs/accuracy-journal.md, "What an ideal detector could find").

    Args:
        turned: Four (H, W) noise-free images of the marker turned 0, 1, 2 and 3
            quarters in its plane, DN.
        variance: (H, W) each pixel's noise variance, DN^2.
    """
    if len(turned) != 4:
        raise ValueError(f"x_snr needs the marker turned 0-3 quarters, got {len(turned)} images")
    x_part = (turned[0] - turned[1] + turned[2] - turned[3]) / 4.0
    return math.sqrt(float(np.sum(x_part**2 / variance)))
