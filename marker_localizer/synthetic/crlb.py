"""Cramer-Rao bound of a marker centre: Fisher information and the expected error it implies.

For an image whose pixel i has the noise-free value mu_i(x, y) (a function of
the marker centre (x, y), every other parameter known) and independent
Gaussian noise of variance var_i, the Fisher information of the centre is

    F = sum_i grad mu_i grad mu_i^T / var_i,

and F^-1 bounds the covariance of every unbiased estimator of (x, y). The
renderer (:func:`~marker_localizer.synthetic.scene.render_scene` with
``crlb=True``) takes the gradients by central differences of the noise-free
frame with the marker moved, and sums over the pixels of the X.

A bound is reported as the expected Euclidean error of an efficient unbiased
estimator, E|e| for e ~ N(0, F^-1): with the eigenvalues l1 >= l2 of F^-1,

    E|e| = sqrt(2 / pi) sqrt(l1) E(m),  m = 1 - l2 / l1,

where E is the complete elliptic integral of the second kind (parameter m):
the mean of the Rayleigh radius sqrt(pi / 2) times the mean of the ellipse's
radius over a uniform angle, (2 / pi) sqrt(l1) E(m).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import ellipe

#: Information matrices whose smaller eigenvalue is below this fraction of their
#: trace are singular: a bound of 1e6 times the other direction's says nothing.
_SINGULAR_RATIO = 1e-12


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
    gx = np.asarray(d_mu_dx, np.float64)[mask]
    gy = np.asarray(d_mu_dy, np.float64)[mask]
    weight = 1.0 / np.asarray(variance, np.float64)[mask]
    xy = float(np.sum(weight * gx * gy))
    return np.array([[np.sum(weight * gx * gx), xy], [xy, np.sum(weight * gy * gy)]])


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
    """The expected Euclidean error of an efficient unbiased estimator, px (inf if F is singular).

    Args:
        information: (2, 2) Fisher information of the position, px^-2.
    """
    info = np.asarray(information, np.float64)
    smallest = np.linalg.eigvalsh(info)[0] if np.isfinite(info).all() else 0.0
    # An eigenvalue this far below the other is a direction the pixels say nothing about.
    if smallest <= _SINGULAR_RATIO * np.trace(info):
        return math.inf
    return expected_radial_error(np.linalg.inv(info))
