"""The centre of an X whose quadrants' levels differ: exact wedges through the tone curve.

Grey-level point symmetry, I(c + d) = I(c - d), locates an X whose two bright
and two dark quadrants match whatever the blur and the camera's tone curve do
(:func:`subpixel.refine_along_lines`). A marker's daily life breaks it: a dull
bright quadrant (wear, dirt, wet paint, sheen), a cast shadow's edge across the
plate. A model that gives each quadrant its own level keeps the centre where
the lines cross, but only if the rest of the model is right, and two parts of
the usual one are not:

* **The tone curve.** The optics blur the scene's light, and the camera then
  encodes it through a tone curve (a gamma of 0.8-1.25 on the renderers, sRGB on
  most cameras). A blurred edge between two levels is no longer the mean of
  its sides at the line, and the shift differs between an edge of the dull
  quadrant and its opposite, which point symmetry would cancel: an X of 20 px
  with a quadrant 0.6 as bright as its opposite, blur 1 px, gamma 0.8, is
  located 0.057 px off by four linear levels, and to 2.2x the Cramer-Rao bound
  with the tone curve in the model (40 renders, ``docs/accuracy-journal.md``).
* **The wedges' blur.** Under a Gaussian blur a point's distances from the two
  lines are jointly normal with the cosine of the lines' angle as their
  correlation, so a quadrant's blurred weight is a bivariate normal
  distribution, not the product of two steps
  (:func:`~marker_localizer.core.template.blurred_x` has the symmetric X). The
  product's error cancels between opposite quadrants of equal levels, not
  otherwise: the same X tilted by 50 degrees is located to 6.4x the bound with
  the product, 3.4x with the exact wedges.

* **A cast shadow's edge** is blurred with the X, not after it: the optics blur
  the paint times the light, so the model's shadowed light comes from the
  trivariate normal of a blurred point's distances from the three lines
  (:func:`trivariate_normal`). The blurred X times a blurred half-plane is
  0.066 px off for an X of 16 px half in a shadow that keeps half the light.

:func:`locate_uneven` fits that model, with the light's linear slope and,
where :func:`shadow.find_edges` saw one, the cast shadow's edge, on the pixels
themselves (no interpolation) by Levenberg-Marquardt.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.special import ndtr

from marker_localizer.core.shadow import ShadowEdges
from marker_localizer.core.template import PIXEL_VARIANCE_PX2, line_distances, normal_density

#: The disk fitted, as a share of the X's extent: beyond ~0.85 the plate's end
#: (the quarter disks' arcs, the checker squares' outer edges, blurred) enters the
#: disk, which the model of two infinite lines does not have.
RADIUS_FRACTION = 0.8
#: ... and never less than this, px: the fit needs a few pixels of each quadrant.
MIN_RADIUS_PX = 2.5
#: Pixels within this distance of either line are all read, px: three widths of the
#: widest blur the renderers draw, where the lines' edges hold the centre ...
LINE_BAND_PX = 3.0
#: ... and of the quadrants' insides a lattice of about this many: enough for four
#: levels, the light's slope, the tone and a shadow's edge, and a large X's fit
#: costs no more than a small one's (a chessboard's corners at 5-40 px read up to
#: 3 200 pixels each, 11 ms a fit).
INSIDE_PIXELS = 300
#: The tone exponent's plausible range: gamma 0.4-2.5 spans every camera curve's
#: local slope over a marker (sRGB's is 0.42-1.0 in exponent) with room; a fit
#: outside it has traded the tone for the levels and is not taken.
TONE_RANGE = (0.4, 2.5)
#: Largest move from the start, px: the start is the symmetry fit's centre, which a
#: dull quadrant pulls 0.2-0.5 px; farther, the fit has slid onto something else.
MAX_SHIFT_PX = 1.0
#: A fit that leaves more than this many times the RMS residual per pixel that the
#: quadrants' levels' fit leaves at the same X (``reference_rms``,
#: :func:`~marker_localizer.core.subpixel.refine_along_lines`) models something else
#: than one X: a chessboard corner, whose disk takes in the next squares and is
#: located worse by the model than by point symmetry, or clutter. Markers leave a few
#: times less, their frames written as JPEG or not; the limit is the geometric middle
#: of the two kinds. It is read against the levels' fit, not the sensor's noise:
#: JPEG's error along the edges, which the noise measured on smooth ground does not
#: hold, would keep JPEG frames' markers from their model.
MAX_MISFIT_RATIO = 4.0
#: A cast shadow's edge has a penumbra of a few tenths of a pixel (the renderers'
#: 1 px from 10 to 90 %): it starts here, px, and is fitted.
SHADOW_START_PENUMBRA_PX = 0.4
#: A shadow's edge is kept where it takes at least this much of the residual's sum
#: of squares, in units of the noise it leaves: chi-square of 4 degrees of freedom
#: (its parameters) beyond 1e-4 of chance.
SHADOW_MIN_CHI2 = 23.5
#: Gauss-Legendre nodes on [0, 1] for Plackett's integral (:func:`trivariate_normal`):
#: 6 give the trivariate normal to 4e-6 (200 random limits and correlations up to
#: 0.9; 10 to 4e-7), a thousandth of the noise.
_LEGENDRE_NODES, _LEGENDRE_WEIGHTS = np.polynomial.legendre.leggauss(6)
_PLACKETT_NODES, _PLACKETT_WEIGHTS = 0.5 * (_LEGENDRE_NODES + 1.0), 0.5 * _LEGENDRE_WEIGHTS
#: 1 - rho^2 is held above this where it divides: correlations of +-1 (parallel
#: lines, a shadow's edge along one with no penumbra) are no X's.
_MIN_ONE_LESS = 1e-9
#: The wedge term's sign in the four quadrants (:data:`QUADRANT_SIDES`' order).
_ALTERNATE = (1.0, -1.0, 1.0, -1.0)
#: Gauss-Legendre nodes for the wedges' correction term (Sheppard's integral over
#: the angle): 6 give the bivariate normal to 1e-5 for lines 20 degrees apart
#: (:func:`template.blurred_x` reads the same integral at the same nodes).
_NODES, _NODE_WEIGHTS = np.polynomial.legendre.leggauss(6)
#: The blur the fit starts from, px (the renderers' and most lenses' 0.5-1.5).
_START_BLUR_PX = 1.0
#: Paint times light below this share of white is taken as this (the tone
#: curve's power needs a positive base; no marker's level is that dark).
_MIN_SIGNAL = 1e-4
#: Geometry: centre (2), line angles (2), ln blur, light slope (2), tone exponent.
_GEOMETRY = 8
#: A cast shadow's edge: normal, offset, depth, ln penumbra.
_SHADOW_EDGE = 4
#: ln of the shadow edge's penumbra is held within ln 0.2 - ln 5 px: a softer edge
#: is no cast shadow's, and a sharper one would make the blur's correlations 1.
_SHADOW_LOG_BLUR = (float(np.log(0.2)), float(np.log(5.0)))
#: ln of the X's blur is held within ln 0.1 - ln 10 px, and a shadow's depth (-ln of
#: the light it keeps) within -1 - 5: beyond, Levenberg-Marquardt has wandered off
#: any marker (and the exponentials would overflow).
_LOG_BLUR = (float(np.log(0.1)), float(np.log(10.0)))
_DEPTH = (-1.0, 5.0)
#: ... and the tone exponent within 0.1 - 10 while it searches (:data:`TONE_RANGE`
#: judges the result).
_TONE_GUARD = (0.1, 10.0)
#: Levenberg-Marquardt stops a point whose centre steps less than this, px ...
_TOLERANCE_PX = 1e-3
#: ... or whose cost falls by less than this share in a step (a millionth of the
#: noise's share over a thousand pixels: the centre then moves by less still) ...
_TOLERANCE_COST = 1e-6
#: (a cost is never taken as less than this, so a noise-free fit stops too)
_MIN_COST = 1e-12
#: ... or, from this many steps on, while it leaves more than :data:`_HOPELESS_MISFIT`
#: times what it may (:data:`MAX_MISFIT_RATIO`): on a board's corners the model never
#: gets there ...
_HOPELESS_AFTER = 3
_HOPELESS_MISFIT = 2.0
#: ... or after this many steps (3-12 on the renderers' uneven markers) ...
_ITERATIONS = 30
#: ... or once its damping has grown past this: no step lowers the cost.
_GIVE_UP_DAMPING = 1e8
#: The damping it starts with, times the normal matrix's diagonal (Marquardt) ...
_START_DAMPING = 1e-3
#: ... plus this times the identity, for parameters the pixels say nothing of.
_FLOOR_DAMPING = 1e-9


class UnevenFit(NamedTuple):
    """What :func:`locate_uneven` gives for N points.

    Attributes:
        xy: (N, 2) fitted centres, px (the start where ``located`` is False).
        covariance: (N, 2, 2) the centre's covariance from the fit, px^2.
        located: (N,) where the fit converged within :data:`MAX_SHIFT_PX` of its
            start and :data:`TONE_RANGE`.
        shadow_share: (N,) where the fit kept a cast shadow's edge, the share of the
            residual sum of squares of the fit without it that the edge takes; 0
            elsewhere.
    """

    xy: NDArray[np.float64]
    covariance: NDArray[np.float64]
    located: NDArray[np.bool_]
    shadow_share: NDArray[np.float64]


def wedge_correction(
    h: NDArray[np.float64], k: NDArray[np.float64], rho: float | NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Phi2(h, k; rho) - Phi(h) Phi(k), and its derivatives by h, k and rho.

    The bivariate normal distribution by Sheppard's integral,
    Phi2 = Phi(h) Phi(k) + (1 / 2 pi) int_0^asin(rho) exp(-(h^2 + k^2 - 2 h k sin t)
    / (2 cos^2 t)) dt, read at :data:`_NODES`; its derivative by rho is the
    bivariate normal density.

    Args:
        h: standardised distances from line 1.
        k: the same from line 2.
        rho: their correlation, the cosine of the lines' angle (broadcast with h).

    Returns:
        (T, dT/dh, dT/dk, dT/drho), each of the shape of ``h`` and ``rho`` broadcast.
    """
    scale, integrand, sine, cos2 = _sheppard_integrand(h, k, rho)
    value = scale * integrand.sum(axis=0)
    by_h = scale * (integrand * (k * sine - h) / cos2).sum(axis=0)
    by_k = scale * (integrand * (h * sine - k) / cos2).sum(axis=0)
    return value, by_h, by_k, _density2(h, k, rho)


def _sheppard_integrand(
    h: NDArray[np.float64], k: NDArray[np.float64], rho: float | NDArray[np.float64]
) -> tuple[Any, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Sheppard's integral of :func:`wedge_correction` at its nodes.

    Returns:
        (the integral's scale, the weighted integrand at each node, sin t, cos^2 t):
        the correction is the scale times the integrand's sum over the nodes.
    """
    span = np.arcsin(np.clip(rho, -1.0, 1.0))
    nodes = np.reshape(_NODES, (-1,) + (1,) * max(np.ndim(h), np.ndim(span)))
    weights = np.reshape(_NODE_WEIGHTS, nodes.shape)
    t = 0.5 * span * (1.0 + nodes)
    sine, cos2 = np.sin(t), np.cos(t) ** 2
    integrand = weights * np.exp(-(h**2 + k**2 - 2.0 * h * k * sine) / (2.0 * cos2))
    return 0.5 * span / (2.0 * np.pi), integrand, sine, cos2


class _Pixels(NamedTuple):
    """Points' pixels: offsets from each start, levels as a share of white.

    One point's are 1-d; N points' (N, K), ``present`` marking the padding out.
    """

    dx: NDArray[np.float64]
    dy: NDArray[np.float64]
    level: NDArray[np.float64]
    present: NDArray[np.bool_]


def _pixels(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    radius_px: float,
    line_angles: NDArray[np.float64],
    full_scale: float,
) -> _Pixels | None:
    """The pixels the fit reads within ``radius_px`` of ``xy``; None if the border cuts them.

    Every pixel within :data:`LINE_BAND_PX` of either line, where the centre's
    information lies, and of the quadrants' insides, which hold the levels, the
    light and the tone, a lattice of at most about :data:`INSIDE_PIXELS`.
    """
    height, width = image.shape
    reach = int(np.ceil(radius_px))
    x0, y0 = int(np.round(xy[0])), int(np.round(xy[1]))
    if x0 - reach < 0 or y0 - reach < 0 or x0 + reach >= width or y0 + reach >= height:
        return None
    ys, xs = np.mgrid[y0 - reach : y0 + reach + 1, x0 - reach : x0 + reach + 1]
    dx, dy = xs - xy[0], ys - xy[1]
    s1, s2 = line_distances(dx, dy, line_angles)
    near = np.minimum(np.abs(s1), np.abs(s2)) <= LINE_BAND_PX
    inside = dx * dx + dy * dy <= radius_px * radius_px
    stride = max(1, int(np.ceil(np.sqrt((inside & ~near).sum() / INSIDE_PIXELS))))
    lattice = ((ys - y0) % stride == 0) & ((xs - x0) % stride == 0)
    keep = inside & (near | lattice)
    level = image[ys[keep], xs[keep]].astype(np.float64) / full_scale
    return _Pixels(dx[keep], dy[keep], level, np.ones(len(level), dtype=bool))


def _bivariate(
    x: NDArray[np.float64], y: NDArray[np.float64], rho: float | NDArray[np.float64]
) -> NDArray[np.float64]:
    """Phi2(x, y; rho), the bivariate normal distribution."""
    # Without the wedge's derivatives, which :func:`wedge_correction` adds.
    scale, integrand, _, _ = _sheppard_integrand(x, y, rho)
    value: NDArray[np.float64] = ndtr(x) * ndtr(y) + scale * integrand.sum(axis=0)
    return value


def _density2(
    x: NDArray[np.float64], y: NDArray[np.float64], rho: float | NDArray[np.float64]
) -> NDArray[np.float64]:
    """The bivariate normal density phi2(x, y; rho)."""
    one_less = np.maximum(1.0 - rho * rho, _MIN_ONE_LESS)
    density: NDArray[np.float64] = np.exp(
        -(x * x - 2.0 * rho * x * y + y * y) / (2.0 * one_less)
    ) / (2.0 * np.pi * np.sqrt(one_less))
    return density


def _bivariate_with_derivatives(
    x: NDArray[np.float64], y: NDArray[np.float64], rho: float | NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Phi2(x, y; rho) and its derivatives by x, y and rho.

    By x, phi(x) times Phi of y given x; by rho, the density phi2.
    """
    one_less = np.sqrt(np.maximum(1.0 - rho * rho, _MIN_ONE_LESS))
    by_x = normal_density(x) * ndtr((y - rho * x) / one_less)
    by_y = normal_density(y) * ndtr((x - rho * y) / one_less)
    return _bivariate(x, y, rho), by_x, by_y, _density2(x, y, rho)


_Correlation = float | NDArray[np.float64]


def _conditional(
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    z: NDArray[np.float64],
    r_xy: _Correlation,
    r_xz: _Correlation,
    r_yz: _Correlation,
) -> NDArray[np.float64]:
    """(z - E[Z | X = x, Y = y]) / sd[Z | X, Y] for standard normals of those correlations."""
    one_less = np.maximum(1.0 - r_xy * r_xy, _MIN_ONE_LESS)
    mean = (r_xz * (x - r_xy * y) + r_yz * (y - r_xy * x)) / one_less
    variance = 1.0 - (r_xz * r_xz - 2.0 * r_xy * r_xz * r_yz + r_yz * r_yz) / one_less
    standardised: NDArray[np.float64] = (z - mean) / np.sqrt(np.maximum(variance, _MIN_ONE_LESS))
    return standardised


def trivariate_normal(
    h: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
    r12: _Correlation,
    r13: _Correlation,
    r23: _Correlation,
) -> tuple[NDArray[np.float64], list[NDArray[np.float64]], list[NDArray[np.float64]]]:
    """Phi3(h1, h2, h3; r12, r13, r23), and its derivatives by the h's and the r's.

    Plackett's reduction: along the correlations (t r12, t r13, r23), t from 0 to 1,
    Phi3 grows from Phi(h1) Phi2(h2, h3; r23) by the integral of r_1j times
    dPhi3 / dr_1j = phi2(h1, hj; t r_1j) Phi(the third given those two), read at
    :data:`_PLACKETT_NODES`. Its derivative by h_i is phi(h_i) times Phi2 of the
    other two given h_i; by r_ij, phi2(h_i, h_j; r_ij) times Phi of the third given
    them.

    Args:
        h: the three upper limits (arrays of one shape).
        r12: correlation of the first two (a number, or an array broadcast with h).
        r13: the first and third's.
        r23: the second and third's.

    Returns:
        (Phi3, [dPhi3/dh1, dPhi3/dh2, dPhi3/dh3], [dPhi3/dr12, dPhi3/dr13, dPhi3/dr23]).
    """
    h1, h2, h3 = h
    nodes = np.reshape(_PLACKETT_NODES, (-1,) + (1,) * max(np.ndim(h1), np.ndim(r12)))
    weights = np.reshape(_PLACKETT_WEIGHTS, nodes.shape)
    a, b = nodes * r12, nodes * r13
    growth = r12 * _density2(h1, h2, a) * ndtr(_conditional(h1, h2, h3, a, b, r23))
    growth += r13 * _density2(h1, h3, b) * ndtr(_conditional(h1, h3, h2, b, a, r23))
    value = ndtr(h1) * _bivariate(h2, h3, r23) + (weights * growth).sum(axis=0)
    by_h = []
    for hi, hj, hk, r_ij, r_ik, r_jk in (
        (h1, h2, h3, r12, r13, r23),
        (h2, h1, h3, r12, r23, r13),
        (h3, h1, h2, r13, r23, r12),
    ):
        s_ij, s_ik = np.sqrt(1.0 - r_ij * r_ij), np.sqrt(1.0 - r_ik * r_ik)
        partial = (r_jk - r_ij * r_ik) / (s_ij * s_ik)
        by_h.append(
            normal_density(hi)
            * _bivariate((hj - r_ij * hi) / s_ij, (hk - r_ik * hi) / s_ik, partial)
        )
    by_r = [
        _density2(h1, h2, r12) * ndtr(_conditional(h1, h2, h3, r12, r13, r23)),
        _density2(h1, h3, r13) * ndtr(_conditional(h1, h3, h2, r13, r12, r23)),
        _density2(h2, h3, r23) * ndtr(_conditional(h2, h3, h1, r23, r12, r13)),
    ]
    return value, by_h, by_r


def _model(
    params: NDArray[np.float64], pixels: _Pixels, shadowed: bool
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """N X's levels at their pixels (signal, share of white) and their Jacobians.

    signal = (slope * scene) ** tone: the scene is sum_q level_q w_q, w_q the
    quadrants' blurred wedges (the product of the two lines' steps and
    :func:`wedge_correction`); ``shadowed``, a cast shadow's edge (normal, offset,
    depth, ln penumbra) takes exp(-depth) of the light beyond it before the blur,
    which removes (1 - exp(-depth)) sum_q level_q T_q, T_q the probability that a
    blurred point lies in quadrant q and beyond the edge (:func:`trivariate_normal`).

    Args:
        params: (N, P) each X's parameters.
        pixels: (N, K) their pixels.
        shadowed: whether the parameters end with a shadow's edge.

    Returns:
        (N, K) signal and (N, K, P) its derivatives.
    """
    cx, cy, a1, a2, log_blur, gx, gy, tone = (params[:, j : j + 1] for j in range(_GEOMETRY))
    levels = params[:, _GEOMETRY : _GEOMETRY + 4]
    dx, dy = pixels.dx - cx, pixels.dy - cy
    s1, s2 = line_distances(dx, dy, np.hstack([a1, a2]))
    blur2 = np.exp(2.0 * np.clip(log_blur, *_LOG_BLUR))
    width2 = blur2 + PIXEL_VARIANCE_PX2
    width = np.sqrt(width2)
    h1, h2 = s1 / width, s2 / width
    r12 = np.cos(a1 - a2)
    p1, p2 = ndtr(h1), ndtr(h2)
    d1, d2 = normal_density(h1), normal_density(h2)
    wedge, wedge_h1, wedge_h2, wedge_r = wedge_correction(h1, h2, r12)
    alternate = np.array(_ALTERNATE)
    weights = np.stack([p1 * p2, (1 - p1) * p2, (1 - p1) * (1 - p2), p1 * (1 - p2)], axis=-1)
    weights += wedge[..., None] * alternate
    by_h1 = np.stack([d1 * p2, -d1 * p2, -d1 * (1 - p2), d1 * (1 - p2)], axis=-1)
    by_h1 += wedge_h1[..., None] * alternate
    by_h2 = np.stack([p1 * d2, (1 - p1) * d2, -(1 - p1) * d2, -p1 * d2], axis=-1)
    by_h2 += wedge_h2[..., None] * alternate
    per_level = levels[:, None, :]
    scene = (weights * per_level).sum(axis=-1)
    # The scene's derivatives by the parameters, through h1, h2 and r12 first.
    d_scene = np.zeros(dx.shape + (params.shape[1],))
    scene_h1, scene_h2 = (by_h1 * per_level).sum(axis=-1), (by_h2 * per_level).sum(axis=-1)
    scene_r12 = wedge_r * (levels @ alternate)[:, None]
    sin1, cos1, sin2, cos2 = np.sin(a1), np.cos(a1), np.sin(a2), np.cos(a2)
    d_scene[..., 0] = (-sin1 * scene_h1 - sin2 * scene_h2) / width
    d_scene[..., 1] = (cos1 * scene_h1 + cos2 * scene_h2) / width
    d_scene[..., 2] = scene_h1 * (cos1 * dx + sin1 * dy) / width - scene_r12 * np.sin(a1 - a2)
    d_scene[..., 3] = scene_h2 * (cos2 * dx + sin2 * dy) / width + scene_r12 * np.sin(a1 - a2)
    d_scene[..., 4] = -(scene_h1 * h1 + scene_h2 * h2) * blur2 / width2
    d_scene[..., _GEOMETRY : _GEOMETRY + 4] = weights
    if shadowed:
        scene = scene + _shadow_terms(params, dx, dy, (h1, h2), (width2, blur2), d_scene)
    slope = 1.0 + gx * dx + gy * dy
    linear = np.maximum(scene * slope, _MIN_SIGNAL)
    exponent = np.clip(tone, *_TONE_GUARD)
    signal = linear**exponent
    d_linear = d_scene * slope[..., None]
    d_linear[..., 0] -= scene * gx
    d_linear[..., 1] -= scene * gy
    d_linear[..., 5], d_linear[..., 6] = scene * dx, scene * dy
    # d(signal)/d(linear), the tone curve's slope, scales every term.
    jacobian = (exponent * signal / linear)[..., None] * d_linear
    jacobian[..., 7] = signal * np.log(linear)
    return signal, jacobian


def _shadow_terms(
    params: NDArray[np.float64],
    dx: NDArray[np.float64],
    dy: NDArray[np.float64],
    h12: tuple[NDArray[np.float64], NDArray[np.float64]],
    widths2: tuple[NDArray[np.float64], NDArray[np.float64]],
    d_scene: NDArray[np.float64],
) -> NDArray[np.float64]:
    """The light a shadow's edge takes from the blurred scene; adds its derivatives to ``d_scene``.

    Under the blur, a point's distances from the two lines and from the shadow's
    edge (less the penumbra's own spread) are jointly normal: standardised h1, h2,
    h3 = u / S with S^2 = w^2 + p^2 (blur and penumbra), correlated by the cosines
    of the normals, n1 . n2 and n_i . n w / S.
    """
    a1, a2 = params[:, 2:3], params[:, 3:4]
    levels = params[:, _GEOMETRY : _GEOMETRY + 4]
    normal, offset, depth, log_penumbra = (
        params[:, _GEOMETRY + 4 + j : _GEOMETRY + 5 + j] for j in range(4)
    )
    width2, blur2 = widths2
    penumbra2 = np.exp(2.0 * np.clip(log_penumbra, *_SHADOW_LOG_BLUR))
    spread2 = width2 + penumbra2
    spread = np.sqrt(spread2)
    share = np.sqrt(width2) / spread
    h1, h2 = h12
    cos_n, sin_n = np.cos(normal), np.sin(normal)
    h3 = (cos_n * dx + sin_n * dy - offset) / spread
    r12 = np.cos(a1 - a2)
    r13, r23 = np.sin(a1 - normal) * share, np.sin(a2 - normal) * share
    # One trivariate normal gives all four quadrants: with F = Phi3(h1, h2, h3),
    # A = Phi2(h1, h3), B = Phi2(h2, h3), C = Phi(h3), the quadrants beyond the
    # edge are F, B - F, C - A - B + F and A - F (:data:`QUADRANT_SIDES`' order).
    # Four trivariate normals, one a quadrant, took 4x as long for the same sums.
    whole, whole_h, whole_r = trivariate_normal((h1, h2, h3), r12, r13, r23)
    along1, along1_h1, along1_h3, along1_r = _bivariate_with_derivatives(h1, h3, r13)
    along2, along2_h2, along2_h3, along2_r = _bivariate_with_derivatives(h2, h3, r23)
    below = ndtr(h3)
    beyond = np.stack(
        [whole, along2 - whole, below - along1 - along2 + whole, along1 - whole], axis=-1
    )
    # Each quadrant's level weighs its share; the derivatives by the unsigned h's and
    # r's follow from F's, A's, B's and C's.
    level = [levels[:, q : q + 1] for q in range(4)]
    c_whole = level[0] - level[1] + level[2] - level[3]
    c_along1, c_along2 = level[3] - level[2], level[1] - level[2]
    t_h1 = c_whole * whole_h[0] + c_along1 * along1_h1
    t_h2 = c_whole * whole_h[1] + c_along2 * along2_h2
    t_h3 = (
        c_whole * whole_h[2]
        + c_along1 * along1_h3
        + c_along2 * along2_h3
        + level[2] * normal_density(h3)
    )
    t_r12 = c_whole * whole_r[0]
    t_r13 = c_whole * whole_r[1] + c_along1 * along1_r
    t_r23 = c_whole * whole_r[2] + c_along2 * along2_r
    kept = np.exp(-np.clip(depth, *_DEPTH))
    dark = 1.0 - kept
    width = np.sqrt(width2)
    # d(share)/d ln blur and / d ln penumbra; h3's the same way through S.
    share_blur = share * (blur2 / width2 - blur2 / spread2)
    share_penumbra = -share * penumbra2 / spread2
    base = _GEOMETRY + 4
    d_beyond = np.zeros_like(d_scene)
    d_beyond[..., 0] = (-np.sin(a1) * t_h1 - np.sin(a2) * t_h2) / width - cos_n * t_h3 / spread
    d_beyond[..., 1] = (np.cos(a1) * t_h1 + np.cos(a2) * t_h2) / width - sin_n * t_h3 / spread
    d_beyond[..., 2] = t_h1 * (np.cos(a1) * dx + np.sin(a1) * dy) / width
    d_beyond[..., 2] += -t_r12 * np.sin(a1 - a2) + t_r13 * np.cos(a1 - normal) * share
    d_beyond[..., 3] = t_h2 * (np.cos(a2) * dx + np.sin(a2) * dy) / width
    d_beyond[..., 3] += t_r12 * np.sin(a1 - a2) + t_r23 * np.cos(a2 - normal) * share
    d_beyond[..., 4] = -(t_h1 * h1 + t_h2 * h2) * blur2 / width2 - t_h3 * h3 * blur2 / spread2
    d_beyond[..., 4] += (t_r13 * np.sin(a1 - normal) + t_r23 * np.sin(a2 - normal)) * share_blur
    d_beyond[..., _GEOMETRY : _GEOMETRY + 4] = beyond
    d_beyond[..., base] = t_h3 * (cos_n * dy - sin_n * dx) / spread
    d_beyond[..., base] -= (t_r13 * np.cos(a1 - normal) + t_r23 * np.cos(a2 - normal)) * share
    d_beyond[..., base + 1] = -t_h3 / spread
    d_beyond[..., base + 3] = -t_h3 * h3 * penumbra2 / spread2
    d_beyond[..., base + 3] += (
        t_r13 * np.sin(a1 - normal) + t_r23 * np.sin(a2 - normal)
    ) * share_penumbra
    taken = (beyond * levels[:, None, :]).sum(axis=-1)
    d_scene -= dark[..., None] * d_beyond
    d_scene[..., base + 2] = -kept * taken
    removed: NDArray[np.float64] = -dark * taken
    return removed


class _Solution(NamedTuple):
    """N Levenberg-Marquardt fits.

    Attributes:
        params: (N, P) the parameters reached.
        cost: (N,) their sum of squared residuals.
        covariance: (N, 2, 2) the centre's, from the Jacobian and the residual.
        solved: (N,) converged within :data:`MAX_SHIFT_PX` of the start and
            :data:`TONE_RANGE`, the covariance finite.
    """

    params: NDArray[np.float64]
    cost: NDArray[np.float64]
    covariance: NDArray[np.float64]
    solved: NDArray[np.bool_]


def _residual(
    params: NDArray[np.float64], pixels: _Pixels, shadowed: bool, held_centre: bool = False
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Residuals (N, K), Jacobian (N, K, P) and cost (N,), the padding at zero.

    ``held_centre``: the centre's columns are zero, so that no step moves it.
    """
    signal, jacobian = _model(params, pixels, shadowed)
    residual = np.where(pixels.present, signal - pixels.level, 0.0)
    jacobian *= pixels.present[..., None]
    if held_centre:
        jacobian[..., :2] = 0.0
    return residual, jacobian, np.square(residual).sum(axis=1)


def _solve(
    pixels: _Pixels,
    start: NDArray[np.float64],
    shadowed: bool,
    hopeless_cost: NDArray[np.float64] | None = None,
    held_centre: bool = False,
) -> _Solution:
    """Levenberg-Marquardt from ``start`` (N, P), all N at once.

    Marquardt's scaling of the damping by the normal matrix's diagonal; a point
    stops when its centre's step falls under :data:`_TOLERANCE_PX`, its cost no
    longer falls, after :data:`_ITERATIONS`, or, from :data:`_HOPELESS_AFTER`
    steps on, while its cost exceeds ``hopeless_cost`` (N,): no X fits there.
    The blur, tone, and shadow's depth and penumbra stay in the box the model
    holds them to (:func:`_bounds`): a step is cut at the box, and a parameter on
    its bound that the step would take out of it is held there for that step.
    Beyond the box the model is flat, and a Jacobian that still read the slope
    there sent the rest of the step astray (a shadowed fit 18 steps long).
    ``held_centre``: the centre stays where it starts, the rest is fitted (only the
    cost is then read: the covariance of a held centre is none).
    """
    n, n_params = start.shape
    params = start.copy()
    residual, jacobian, cost = _residual(params, pixels, shadowed, held_centre)
    damping = np.full(n, _START_DAMPING)
    done = np.zeros(n, dtype=bool)
    eye = np.eye(n_params)
    lower, upper = _bounds(n_params)
    for iteration in range(_ITERATIONS):
        if hopeless_cost is not None and iteration >= _HOPELESS_AFTER:
            done |= cost > hopeless_cost
        active = np.flatnonzero(~done)
        if not len(active):
            break
        # Batched matrix products (BLAS): einsum's loop took 17x as long on 30 X's.
        gradient = (jacobian[active].transpose(0, 2, 1) @ residual[active, :, None])[..., 0]
        held = held_on_bounds(params[active], gradient, lower, upper)
        free = jacobian[active] * ~held[:, None, :]
        normal = free.transpose(0, 2, 1) @ free
        gradient *= ~held
        damped = normal + damping[active, None, None] * (normal * eye + _FLOOR_DAMPING * eye)
        step = -np.linalg.solve(damped, gradient[..., None])[..., 0]
        trial = np.clip(params[active] + step, lower, upper)
        t_residual, t_jacobian, t_cost = _residual(
            trial, _take(pixels, active), shadowed, held_centre
        )
        better = np.isfinite(t_cost) & (t_cost < cost[active])
        gained = (cost[active] - t_cost) / np.maximum(cost[active], _MIN_COST)
        took = active[better]
        params[took], residual[took], jacobian[took], cost[took] = (
            trial[better],
            t_residual[better],
            t_jacobian[better],
            t_cost[better],
        )
        damping[active] = np.where(better, damping[active] / 3.0, damping[active] * 3.0)
        # A held centre never steps: its fit stops by the cost alone.
        still = (np.hypot(step[:, 0], step[:, 1]) < _TOLERANCE_PX) & (not held_centre)
        settled = better & (still | (gained < _TOLERANCE_COST))
        done[active[settled | (damping[active] > _GIVE_UP_DAMPING)]] = True
    present = pixels.present.sum(axis=1)
    dof = np.maximum(present - n_params, 1)
    normal = jacobian.transpose(0, 2, 1) @ jacobian
    # A fit whose model turned NaN (a wedge or shadow term at a correlation of +-1)
    # is not solved: the SVD of a NaN matrix does not converge, it raises.
    invertible = np.asarray(np.isfinite(normal).all(axis=(1, 2)))
    invertible[invertible] = np.linalg.cond(normal[invertible]) < 1.0 / np.finfo(np.float64).eps
    covariance = np.full((n, 2, 2), np.nan)
    if invertible.any():
        inverse = np.linalg.inv(normal[invertible])
        covariance[invertible] = (
            inverse[:, :2, :2] * (cost[invertible] / dof[invertible])[:, None, None]
        )
    solved = (
        (present > n_params)
        & np.isfinite(cost)
        & np.isfinite(covariance).all(axis=(1, 2))
        & (np.hypot(params[:, 0], params[:, 1]) <= MAX_SHIFT_PX)
        & (params[:, 7] >= TONE_RANGE[0])
        & (params[:, 7] <= TONE_RANGE[1])
    )
    return _Solution(params, cost, covariance, solved)


def _bounds(n_params: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(P,) lower and upper bounds of the parameters: the box :func:`_model` holds them to."""
    lower, upper = np.full(n_params, -np.inf), np.full(n_params, np.inf)
    lower[4], upper[4] = _LOG_BLUR
    lower[7], upper[7] = _TONE_GUARD
    if n_params > _GEOMETRY + 4:
        lower[_GEOMETRY + 6], upper[_GEOMETRY + 6] = _DEPTH
        lower[_GEOMETRY + 7], upper[_GEOMETRY + 7] = _SHADOW_LOG_BLUR
    return lower, upper


def held_on_bounds(
    params: NDArray[np.float64],
    gradient: NDArray[np.float64],
    lower: NDArray[np.float64],
    upper: NDArray[np.float64],
) -> NDArray[np.bool_]:
    """(N, P) the parameters on a bound of their box that descent would take out of it.

    A bounded Levenberg-Marquardt step holds them (zero Jacobian column and
    gradient) for that step: a step cut at the box is not the step the normal
    equations solved for, and the other parameters' share of it goes astray.

    Args:
        params: (N, P) the parameters, inside the box.
        gradient: (N, P) the cost's gradient; descent is along ``-gradient``.
        lower: (P,) the box's lower bounds (-inf: none).
        upper: (P,) its upper bounds (inf: none).
    """
    held: NDArray[np.bool_] = ((params <= lower) & (gradient > 0)) | (
        (params >= upper) & (gradient < 0)
    )
    return held


def _take(pixels: _Pixels, rows: NDArray[np.intp]) -> _Pixels:
    """The pixels of the points ``rows``."""
    return _Pixels(pixels.dx[rows], pixels.dy[rows], pixels.level[rows], pixels.present[rows])


def locate_uneven(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    full_scale: float,
    shadows: ShadowEdges | None = None,
    reference_rms: NDArray[np.float64] | None = None,
    min_centre_chi2: float | NDArray[np.float64] | None = None,
) -> UnevenFit:
    """Centres of X's with four quadrant levels, through the tone curve, with a shadow's edge.

    Each X is fitted first without a shadow. Where ``shadows`` found an edge, it is
    fitted again with the edge (its normal, offset, depth and penumbra), which is
    kept where it explains more than its four parameters would by chance
    (:data:`SHADOW_MIN_CHI2`). The optics blur the shadowed scene, so the model
    blurs the X's paint times the shadow's light together (:func:`_model`): the
    blurred X times a blurred half-plane errs where the shadow's edge crosses the
    X's lines, a few blur widths from the centre (an X of 16 px half in a shadow
    taking half the light, blur 1 px: 0.066 px off from the true start).

    Args:
        image: (H, W) grey image, raw levels.
        xy: (N, 2) starting centres, px.
        line_angles: (N, 2) the lines' directions there, radians.
        radius_px: (N,) the X's extents, px; the disk fitted is
            :data:`RADIUS_FRACTION` of it.
        full_scale: the image's white level.
        shadows: (N) a cast shadow's edge about each start
            (:func:`shadow.find_edges`); tried where ``found``.
        reference_rms: (N,) the RMS residual per pixel that a model of one X leaves
            at each (the quadrants' levels' fit's), image units; where given, a fit
            that leaves more than :data:`MAX_MISFIT_RATIO` times it is not located.
        min_centre_chi2: where given (one, or (N,) one per point, NaN for none), a
            fit is located only where it rejects its start as the centre by at least
            this chi-square (:func:`_rejects_start`); 0: where it fits no worse
            than with its centre held at the start.

    Returns:
        :class:`UnevenFit`.
    """
    n = len(xy)
    centre = np.array(xy, dtype=np.float64).reshape(-1, 2)
    covariance = np.full((n, 2, 2), np.nan)
    located = np.zeros(n, dtype=bool)
    shadow_share = np.zeros(n)
    read = [
        _pixels(
            image,
            centre[i],
            max(RADIUS_FRACTION * float(radius_px[i]), MIN_RADIUS_PX),
            line_angles[i],
            full_scale,
        )
        for i in range(n)
    ]
    rows = np.array([i for i, part in enumerate(read) if part is not None], dtype=np.intp)
    if not len(rows):
        return UnevenFit(centre, covariance, located, shadow_share)
    pixels = _padded([part for part in read if part is not None])
    start = _start(pixels, line_angles[rows])
    present = pixels.present.sum(axis=1)
    # The RMS residual a fit may leave, as a share of white, and the cost past which
    # it is given up.
    limit: NDArray[np.float64] = np.full(len(rows), np.inf)
    hopeless = None
    if reference_rms is not None:
        limit = MAX_MISFIT_RATIO * reference_rms[rows] / full_scale
        hopeless = present * np.square(_HOPELESS_MISFIT * limit)
    fit = _solve(pixels, start, shadowed=False, hopeless_cost=hopeless)
    share: NDArray[np.float64] = np.zeros(len(rows))
    if shadows is not None and shadows.found[rows].any():
        fit, share = _with_shadow(pixels, start, fit, shadows.take(rows), hopeless)
    taken = fit.solved & (np.sqrt(fit.cost / present) <= limit)
    asked = np.broadcast_to(np.nan if min_centre_chi2 is None else min_centre_chi2, (n,))[rows]
    tested = np.flatnonzero(taken & ~np.isnan(asked))
    if len(tested):
        taken[tested] = _rejects_start(pixels, fit, share, tested) >= asked[tested]
    at = rows[taken]
    centre[at] += fit.params[taken, :2]
    covariance[at] = fit.covariance[taken]
    located[at] = True
    shadow_share[at] = share[taken]
    return UnevenFit(centre, covariance, located, shadow_share)


def _rejects_start(
    pixels: _Pixels, fit: _Solution, share: NDArray[np.float64], tested: NDArray[np.intp]
) -> NDArray[np.float64]:
    """(M,) the chi-square by which the fits ``tested`` reject their start as the centre.

    Each is fitted again with its centre held at the start and everything else free
    (the shadow's edge where the fit kept one, ``share`` above 0), from where it
    ended: the cost it gains, in units of its own residual per degree of freedom, is
    a likelihood ratio's chi-square of 2 degrees of freedom where the start is the
    centre.
    """
    chi2 = np.zeros(len(tested))
    for shadowed in (False, True):
        part = np.flatnonzero((share[tested] > 0) == shadowed)
        if not len(part):
            continue
        points = tested[part]
        n_params = _GEOMETRY + 4 + _SHADOW_EDGE * shadowed
        start = fit.params[points, :n_params].copy()
        start[:, :2] = 0.0
        held = _solve(_take(pixels, points), start, shadowed=shadowed, held_centre=True)
        dof = np.maximum(pixels.present[points].sum(axis=1) - n_params, 1)
        noise = np.maximum(fit.cost[points] / dof, _MIN_COST)
        chi2[part] = (held.cost - fit.cost[points]) / noise
    return chi2


def _with_shadow(
    pixels: _Pixels,
    start: NDArray[np.float64],
    plain: _Solution,
    edges: ShadowEdges,
    hopeless_cost: NDArray[np.float64] | None,
) -> tuple[_Solution, NDArray[np.float64]]:
    """The fits again with the shadow's edge where one was found; kept where it explains.

    The shadowed fit replaces the plain one where the plain one failed, or where
    the edge takes more of the residual than its four parameters would by chance.
    Returns the plain fits' parameters padded to the shadowed ones' length, and
    (:class:`UnevenFit`'s ``shadow_share``) the share of the plain fit's residual
    sum of squares the edge takes where it was kept, 0 elsewhere.
    """
    tried = np.flatnonzero(edges.found)
    first = np.where(plain.solved[tried, None], plain.params[tried], start[tried])
    edge = np.column_stack(
        [
            edges.normal[tried],
            edges.offset[tried],
            edges.depth[tried],
            np.full(len(tried), np.log(SHADOW_START_PENUMBRA_PX)),
        ]
    )
    shadowed = _solve(
        _take(pixels, tried),
        np.hstack([first, edge]),
        shadowed=True,
        hopeless_cost=None if hopeless_cost is None else hopeless_cost[tried],
    )
    dof = np.maximum(pixels.present[tried].sum(axis=1) - shadowed.params.shape[1], 1)
    explains = (plain.cost[tried] - shadowed.cost) / (shadowed.cost / dof) >= SHADOW_MIN_CHI2
    better = shadowed.solved & (~plain.solved[tried] | explains)
    params = np.hstack([plain.params, np.zeros((len(plain.params), edge.shape[1]))])
    chosen = tried[better]
    params[chosen] = shadowed.params[better]
    cost, covariance, solved = plain.cost.copy(), plain.covariance.copy(), plain.solved.copy()
    cost[chosen], covariance[chosen], solved[chosen] = (
        shadowed.cost[better],
        shadowed.covariance[better],
        True,
    )
    share = np.zeros(len(plain.params))
    share[chosen] = 1.0 - shadowed.cost[better] / np.maximum(plain.cost[chosen], _MIN_COST)
    return _Solution(params, cost, covariance, solved), share


def _padded(parts: list[_Pixels]) -> _Pixels:
    """N points' pixels as (N, K) arrays, padded with absent pixels at the origin."""
    width = max(len(part.level) for part in parts)
    arrays = np.zeros((3, len(parts), width))
    present = np.zeros((len(parts), width), dtype=bool)
    for i, part in enumerate(parts):
        k = len(part.level)
        arrays[:, i, :k] = part.dx, part.dy, part.level
        present[i, :k] = True
    return _Pixels(arrays[0], arrays[1], arrays[2], present)


def _start(pixels: _Pixels, line_angles: NDArray[np.float64]) -> NDArray[np.float64]:
    """The fits' start (N, P): the given lines, linear tone, the levels that fit them best."""
    n = len(line_angles)
    geometry = np.zeros((n, _GEOMETRY))
    geometry[:, 2:4] = line_angles
    geometry[:, 4] = np.log(_START_BLUR_PX)
    geometry[:, 7] = 1.0
    _, jacobian = _model(np.hstack([geometry, np.ones((n, 4))]), pixels, shadowed=False)
    # At tone 1 the signal is linear in the levels: their columns are the wedges' weights.
    weights = jacobian[..., _GEOMETRY : _GEOMETRY + 4] * pixels.present[..., None]
    moved = weights.transpose(0, 2, 1)
    normal = moved @ weights + _FLOOR_DAMPING * np.eye(4)
    levels = np.linalg.solve(normal, moved @ pixels.level[..., None])
    return np.hstack([geometry, np.maximum(levels[..., 0], _MIN_SIGNAL)])
