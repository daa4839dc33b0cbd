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
  with the tone curve in the model (40 renders, ``docs/accuracy.md``).
* **The wedges' blur.** Under a Gaussian blur a point's distances from the two
  lines are jointly normal with the cosine of the lines' angle as their
  correlation, so a quadrant's blurred weight is a bivariate normal
  distribution, not the product of two steps
  (:func:`~marker_localizer.core.template.blurred_x` has the symmetric X). The
  product's error cancels between opposite quadrants of equal levels, not
  otherwise: the same X tilted by 50 degrees is located to 6.4x the bound with
  the product, 3.4x with the exact wedges.

:func:`locate_uneven` fits that model, with the light's linear slope and,
where :func:`shadow.find_edges` saw one, the cast shadow's edge, on the pixels
themselves (no interpolation) by Levenberg-Marquardt.
"""

from __future__ import annotations

from typing import Any, Literal, NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.special import ndtr

from marker_localizer.core.shadow import ShadowEdges
from marker_localizer.core.template import PIXEL_VARIANCE_PX2, line_distances

#: The disk fitted, as a share of the X's extent: beyond ~0.85 the plate's end
#: (the quarter disks' arcs, the checker squares' outer edges, blurred) enters the
#: disk, which the model of two infinite lines does not have.
RADIUS_FRACTION = 0.8
#: ... and never less than this, px: the fit needs a few pixels of each quadrant.
MIN_RADIUS_PX = 2.5
#: The tone exponent's plausible range: gamma 0.4-2.5 spans every camera curve's
#: local slope over a marker (sRGB's is 0.42-1.0 in exponent) with room; a fit
#: outside it has traded the tone for the levels and is not taken.
TONE_RANGE = (0.4, 2.5)
#: Largest move from the start, px: the start is the symmetry fit's centre, which a
#: dull quadrant pulls 0.2-0.5 px; farther, the fit has slid onto something else.
MAX_SHIFT_PX = 1.0
#: A fit that leaves more than this many times the image's noise (RMS) models
#: something else than one X: a chessboard corner, whose disk takes in the next
#: squares (every one of the renderer's (e) boards' corners the model was asked
#: about left 3x or more, and was located 5x worse than by point symmetry), or
#: clutter. Half the dull-quadrant markers of (g) leave under 1.2x, where the model
#: halves the error; those a shadow's edge crosses leave 1.5-5x and gain little.
MAX_MISFIT_NOISE = 2.0
#: A cast shadow's edge is a few tenths of a pixel of penumbra seen through the
#: optics: its blur starts here, px, and is fitted.
SHADOW_START_BLUR_PX = 0.8
#: A shadow's edge is kept where it takes at least this much of the residual's sum
#: of squares, in units of the noise it leaves: chi-square of 4 degrees of freedom
#: (its parameters) beyond 1e-4 of chance.
SHADOW_MIN_CHI2 = 23.5
#: The last fit leaves out pixels within this many blur widths (the optics' and the
#: penumbra's together) of the shadow's edge: there the blurred product the model
#: has is not the blurred scene.
SHADOW_BAND_BLURS = 2.5
#: Gauss-Legendre nodes for the wedges' correction term (Sheppard's integral over
#: the angle): 8 give the bivariate normal to 1e-7 for lines 25 degrees apart.
_NODES, _NODE_WEIGHTS = np.polynomial.legendre.leggauss(8)
#: The blur the fit starts from, px (the renderers' and most lenses' 0.5-1.5).
_START_BLUR_PX = 1.0
#: Paint times light below this share of white is taken as this (the tone
#: curve's power needs a positive base; no marker's level is that dark).
_MIN_SIGNAL = 1e-4
#: Geometry: centre (2), line angles (2), ln blur, light slope (2), tone exponent.
_GEOMETRY = 8
#: ln of the shadow edge's blur is held within ln 0.2 - ln 5 px: a sharper or softer
#: edge is no cast shadow's, and the step's slope would overflow.
_SHADOW_LOG_BLUR = (float(np.log(0.2)), float(np.log(5.0)))
#: ln of the X's blur is held within ln 0.1 - ln 10 px, and a shadow's depth (-ln of
#: the light it keeps) within -1 - 5: beyond, Levenberg-Marquardt has wandered off
#: any marker (and the exponentials would overflow).
_LOG_BLUR = (float(np.log(0.1)), float(np.log(10.0)))
_DEPTH = (-1.0, 5.0)
#: ... and the tone exponent within 0.1 - 10 while it searches (:data:`TONE_RANGE`
#: judges the result).
_TONE_GUARD = (0.1, 10.0)
#: Levenberg-Marquardt's step tolerance, relative to the parameters' norm (2-4: the
#: line angles, the levels): steps end under about a thousandth of a pixel.
_TOLERANCE = 2.5e-4


#: How :func:`_model` takes a cast shadow: none, a blurred edge, or a step of light.
_ShadowModel = Literal["none", "edge", "step"]
_SQRT_2PI = float(np.sqrt(2.0 * np.pi))


class UnevenFit(NamedTuple):
    """What :func:`locate_uneven` gives for N points.

    Attributes:
        xy: (N, 2) fitted centres, px (the start where ``located`` is False).
        covariance: (N, 2, 2) the centre's covariance from the fit, px^2.
        tone: (N,) the fitted tone exponent (signal = light ** tone).
        residual_rms: (N,) the fit's RMS residual, as a share of white.
        located: (N,) where the fit converged within :data:`MAX_SHIFT_PX` of its
            start and :data:`TONE_RANGE`.
    """

    xy: NDArray[np.float64]
    covariance: NDArray[np.float64]
    tone: NDArray[np.float64]
    residual_rms: NDArray[np.float64]
    located: NDArray[np.bool_]


def wedge_correction(
    h: NDArray[np.float64], k: NDArray[np.float64], rho: float
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Phi2(h, k; rho) - Phi(h) Phi(k), and its derivatives by h, k and rho.

    The bivariate normal distribution by Sheppard's integral,
    Phi2 = Phi(h) Phi(k) + (1 / 2 pi) int_0^asin(rho) exp(-(h^2 + k^2 - 2 h k sin t)
    / (2 cos^2 t)) dt, read at :data:`_NODES`; its derivative by rho is the
    bivariate normal density.

    Args:
        h: standardised distances from line 1.
        k: the same from line 2.
        rho: their correlation, the cosine of the lines' angle.

    Returns:
        (T, dT/dh, dT/dk, dT/drho), each of the shape of ``h``.
    """
    span = float(np.arcsin(np.clip(rho, -1.0, 1.0)))
    t = 0.5 * span * (1.0 + _NODES)
    sine, cos2 = np.sin(t), np.cos(t) ** 2
    shape = (-1,) + (1,) * np.ndim(h)
    sine, cos2, weights = (np.reshape(a, shape) for a in (sine, cos2, _NODE_WEIGHTS))
    integrand = np.exp(-(h**2 + k**2 - 2.0 * h * k * sine) / (2.0 * cos2))
    scale = 0.5 * span / (2.0 * np.pi)
    value = scale * (weights * integrand).sum(axis=0)
    by_h = scale * (weights * integrand * (k * sine - h) / cos2).sum(axis=0)
    by_k = scale * (weights * integrand * (h * sine - k) / cos2).sum(axis=0)
    one_less = max(1.0 - rho * rho, 1e-12)
    by_rho = np.exp(-(h * h - 2.0 * rho * h * k + k * k) / (2.0 * one_less)) / (
        2.0 * np.pi * np.sqrt(one_less)
    )
    return value, by_h, by_k, by_rho


class _Pixels(NamedTuple):
    """One point's pixels: offsets from the start, levels as a share of white.

    ``shaded``, where given, says which pixels lie on a cast shadow's side of its
    edge (the model's light is then a step there, see :func:`_model`).
    """

    dx: NDArray[np.float64]
    dy: NDArray[np.float64]
    level: NDArray[np.float64]
    shaded: NDArray[np.bool_] | None = None

    def take(self, keep: NDArray[np.bool_]) -> _Pixels:
        """The pixels ``keep``."""
        shaded = None if self.shaded is None else self.shaded[keep]
        return _Pixels(self.dx[keep], self.dy[keep], self.level[keep], shaded)


def _pixels(
    image: NDArray[Any], xy: NDArray[np.float64], radius_px: float, full_scale: float
) -> _Pixels | None:
    """The pixels whose centres lie within ``radius_px`` of ``xy``; None if the border cuts them."""
    height, width = image.shape
    reach = int(np.ceil(radius_px))
    x0, y0 = int(np.round(xy[0])), int(np.round(xy[1]))
    if x0 - reach < 0 or y0 - reach < 0 or x0 + reach >= width or y0 + reach >= height:
        return None
    ys, xs = np.mgrid[y0 - reach : y0 + reach + 1, x0 - reach : x0 + reach + 1]
    dx, dy = xs - xy[0], ys - xy[1]
    inside = dx * dx + dy * dy <= radius_px * radius_px
    return _Pixels(
        dx[inside], dy[inside], image[ys[inside], xs[inside]].astype(np.float64) / full_scale
    )


def _model(
    params: NDArray[np.float64], pixels: _Pixels, shadow: _ShadowModel
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The X's levels at the pixels (signal, share of white) and their Jacobian (K, P).

    signal = (light * sum_q level_q w_q) ** tone, w_q the quadrants' blurred wedges
    (the product of the two lines' steps and :func:`wedge_correction`), the light a
    linear slope times the shadow's shade: with ``"edge"`` a blurred half-plane
    (normal, offset, depth, ln blur), with ``"step"`` the depth alone on the
    ``pixels.shaded`` side.
    """
    cx, cy, a1, a2, log_blur, gx, gy, tone = params[:_GEOMETRY]
    levels = params[_GEOMETRY : _GEOMETRY + 4]
    dx, dy = pixels.dx - cx, pixels.dy - cy
    s1, s2 = line_distances(dx, dy, np.array([a1, a2]))
    blur2 = np.exp(2.0 * np.clip(log_blur, *_LOG_BLUR))
    width = np.sqrt(blur2 + PIXEL_VARIANCE_PX2)
    h, k = s1 / width, s2 / width
    p1, p2 = ndtr(h), ndtr(k)
    density_h = np.exp(-0.5 * h * h) / _SQRT_2PI
    density_k = np.exp(-0.5 * k * k) / _SQRT_2PI
    rho = float(np.cos(a1 - a2))
    wedge, wedge_h, wedge_k, wedge_rho = wedge_correction(h, k, rho)
    l0, l1, l2, l3 = levels
    alternating = l0 - l1 + l2 - l3
    weights = np.stack(
        [
            p1 * p2 + wedge,
            (1 - p1) * p2 - wedge,
            (1 - p1) * (1 - p2) + wedge,
            p1 * (1 - p2) - wedge,
        ],
        axis=-1,
    )
    paint = weights @ levels
    paint_h = ((l0 - l1) * p2 + (l3 - l2) * (1 - p2)) * density_h + alternating * wedge_h
    paint_k = ((l0 - l3) * p1 + (l1 - l2) * (1 - p1)) * density_k + alternating * wedge_k
    paint_rho = alternating * wedge_rho
    slope = 1.0 + gx * dx + gy * dy
    d_light = np.zeros(dx.shape + (len(params),))
    d_light[:, 0], d_light[:, 1] = -gx, -gy
    d_light[:, 5], d_light[:, 6] = dx, dy
    shade = _shade(params[_GEOMETRY + 4 :], pixels, dx, dy, shadow, slope, d_light)
    light = slope * shade
    linear = np.maximum(paint * light, _MIN_SIGNAL)
    signal = linear ** np.clip(tone, *_TONE_GUARD)
    # d(signal)/d(linear), the tone curve's slope, scales every term of the light.
    slope_of_tone = np.clip(tone, *_TONE_GUARD) * signal / linear
    d_linear = paint[:, None] * d_light
    d_paint = np.zeros_like(d_linear)
    d_paint[:, 0] = -(paint_h * np.sin(a1) + paint_k * np.sin(a2)) / width
    d_paint[:, 1] = (paint_h * np.cos(a1) + paint_k * np.cos(a2)) / width
    d_paint[:, 2] = paint_h * (np.cos(a1) * dx + np.sin(a1) * dy) / width
    d_paint[:, 2] -= paint_rho * np.sin(a1 - a2)
    d_paint[:, 3] = paint_k * (np.cos(a2) * dx + np.sin(a2) * dy) / width
    d_paint[:, 3] += paint_rho * np.sin(a1 - a2)
    d_paint[:, 4] = -(paint_h * h + paint_k * k) * blur2 / width**2
    d_paint[:, _GEOMETRY : _GEOMETRY + 4] = weights
    d_linear += light[:, None] * d_paint
    jacobian = slope_of_tone[:, None] * d_linear
    jacobian[:, 7] = signal * np.log(linear)
    return signal, jacobian


def _shade(
    params: NDArray[np.float64],
    pixels: _Pixels,
    dx: NDArray[np.float64],
    dy: NDArray[np.float64],
    shadow: _ShadowModel,
    slope: NDArray[np.float64],
    d_light: NDArray[np.float64],
) -> NDArray[np.float64]:
    """The shadow's factor on the light at the pixels; adds its terms to ``d_light`` (K, P).

    ``d_light`` comes with the slope's derivatives and leaves with the light's.
    """
    if shadow == "none":
        return np.ones_like(dx)
    base = _GEOMETRY + 4
    if shadow == "step":
        assert pixels.shaded is not None
        kept = np.exp(-np.clip(params[0], *_DEPTH))
        shade: NDArray[np.float64] = np.where(pixels.shaded, kept, 1.0)
        d_light *= shade[:, None]
        d_light[:, base] = slope * np.where(pixels.shaded, -kept, 0.0)
        return shade
    normal, offset, depth, log_shadow_blur = params
    shadow_blur = np.exp(np.clip(log_shadow_blur, *_SHADOW_LOG_BLUR))
    cos_n, sin_n = np.cos(normal), np.sin(normal)
    z = (cos_n * dx + sin_n * dy - offset) / shadow_blur
    kept = np.exp(-np.clip(depth, *_DEPTH))
    shade = 1.0 - (1.0 - kept) * ndtr(z)
    shade_z = -(1.0 - kept) * np.exp(-0.5 * z * z) / _SQRT_2PI * slope
    d_light *= shade[:, None]
    d_light[:, 0] -= shade_z * cos_n / shadow_blur
    d_light[:, 1] -= shade_z * sin_n / shadow_blur
    d_light[:, base] = shade_z * (cos_n * dy - sin_n * dx) / shadow_blur
    d_light[:, base + 1] = -shade_z / shadow_blur
    d_light[:, base + 2] = -slope * kept * ndtr(z)
    d_light[:, base + 3] = -shade_z * z
    return shade


class _CachedModel:
    """:func:`_model` for one point's pixels, evaluated once per parameter vector.

    Levenberg-Marquardt asks for the residual and then the Jacobian at the same
    parameters; both come from one evaluation.
    """

    def __init__(self, pixels: _Pixels, shadow: _ShadowModel) -> None:
        self._pixels = pixels
        self._shadow = shadow
        self._params: NDArray[np.float64] | None = None
        self._value: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None

    def _evaluate(
        self, params: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        if self._value is None or self._params is None or not np.array_equal(params, self._params):
            self._params = params.copy()
            self._value = _model(params, self._pixels, self._shadow)
        return self._value

    def residual(self, params: NDArray[np.float64]) -> NDArray[np.float64]:
        """Model less the pixels' levels."""
        return self._evaluate(params)[0] - self._pixels.level

    def jacobian(self, params: NDArray[np.float64]) -> NDArray[np.float64]:
        """The residual's Jacobian (K, P)."""
        return self._evaluate(params)[1]


class _Solution(NamedTuple):
    """One Levenberg-Marquardt fit: parameters, sum of squared residuals, Jacobian."""

    params: NDArray[np.float64]
    cost: float
    jacobian: NDArray[np.float64]


def _solve(pixels: _Pixels, start: NDArray[np.float64], shadow: _ShadowModel) -> _Solution | None:
    """Levenberg-Marquardt from ``start``; None where it fails or slides off.

    Off: beyond :data:`MAX_SHIFT_PX` of the start, or the tone out of :data:`TONE_RANGE`.
    """
    if len(pixels.level) <= len(start):
        return None
    model = _CachedModel(pixels, shadow)
    solution = least_squares(
        model.residual, start, jac=model.jacobian, method="lm", xtol=_TOLERANCE
    )
    x = solution.x
    if not (
        solution.success
        and np.hypot(x[0], x[1]) <= MAX_SHIFT_PX
        and TONE_RANGE[0] <= x[7] <= TONE_RANGE[1]
    ):
        return None
    return _Solution(x, float(solution.fun @ solution.fun), solution.jac)


def locate_uneven(
    image: NDArray[Any],
    xy: NDArray[np.float64],
    line_angles: NDArray[np.float64],
    radius_px: NDArray[np.float64],
    full_scale: float,
    shadows: ShadowEdges | None = None,
    noise_std: NDArray[np.float64] | None = None,
) -> UnevenFit:
    """Centres of X's with four quadrant levels, through the tone curve, with a shadow's edge.

    Each X is fitted first without a shadow. Where ``shadows`` found an edge, it is
    fitted again with the edge as a blurred half-plane, which is kept where it
    explains more than its four parameters would by chance
    (:data:`SHADOW_MIN_CHI2`). The blur acts on the shadowed scene, not on the
    image of the X times the blurred shadow as that model has it, which errs where
    the shadow's edge crosses the X's lines, a few blur widths from the centre (an
    X of 16 px half in a shadow taking half the light, blur 1 px: 0.08 px off).
    So the last fit leaves out the band along the edge
    (:data:`SHADOW_BAND_BLURS`), and the shadow is a step of light across it.

    Args:
        image: (H, W) grey image, raw levels.
        xy: (N, 2) starting centres, px.
        line_angles: (N, 2) the lines' directions there, radians.
        radius_px: (N,) the X's extents, px; the disk fitted is
            :data:`RADIUS_FRACTION` of it.
        full_scale: the image's white level.
        shadows: (N) a cast shadow's edge about each start
            (:func:`shadow.find_edges`); tried where ``found``.
        noise_std: (N,) the image's noise at each X, image units; where given, a fit
            that leaves more than :data:`MAX_MISFIT_NOISE` times it is not located.

    Returns:
        :class:`UnevenFit`.
    """
    n = len(xy)
    centre = np.array(xy, dtype=np.float64).reshape(-1, 2)
    covariance = np.full((n, 2, 2), np.nan)
    tone = np.ones(n)
    residual_rms = np.full(n, np.nan)
    located = np.zeros(n, dtype=bool)
    for i in range(n):
        pixels = _pixels(
            image, centre[i], max(RADIUS_FRACTION * float(radius_px[i]), MIN_RADIUS_PX), full_scale
        )
        if pixels is None:
            continue
        edge = None
        if shadows is not None and shadows.found[i]:
            edge = (shadows.normal[i], shadows.offset[i], shadows.depth[i])
        solution = _locate_one(pixels, line_angles[i], edge)
        if solution is None:
            continue
        dof = max(len(solution.jacobian) - solution.jacobian.shape[1], 1)
        try:
            inverse = np.linalg.inv(solution.jacobian.T @ solution.jacobian)
        except np.linalg.LinAlgError:
            continue
        centre[i] += solution.params[:2]
        covariance[i] = inverse[:2, :2] * solution.cost / dof
        rms = float(np.sqrt(solution.cost / len(solution.jacobian)))
        if noise_std is not None and rms * full_scale > MAX_MISFIT_NOISE * noise_std[i]:
            continue
        tone[i] = solution.params[7]
        residual_rms[i] = rms
        located[i] = True
    return UnevenFit(centre, covariance, tone, residual_rms, located)


def _locate_one(
    pixels: _Pixels,
    line_angles: NDArray[np.float64],
    edge: tuple[float, float, float] | None,
) -> _Solution | None:
    """One X's fit: without a shadow, and with one where ``edge`` proposes it and it explains."""
    start = _start(pixels, line_angles)
    plain = _solve(pixels, start, "none")
    if edge is None:
        return plain
    normal, offset, depth = edge
    shadowed_start = np.concatenate(
        [
            start if plain is None else plain.params,
            [normal, offset, depth, np.log(SHADOW_START_BLUR_PX)],
        ]
    )
    shadowed = _solve(pixels, shadowed_start, "edge")
    dof = len(pixels.level) - len(shadowed_start)
    if shadowed is None or dof <= 0:
        return plain
    if plain is not None and (plain.cost - shadowed.cost) / (shadowed.cost / dof) < SHADOW_MIN_CHI2:
        return plain
    normal, offset, depth, log_blur = shadowed.params[_GEOMETRY + 4 :]
    cx, cy = shadowed.params[:2]
    across = np.cos(normal) * (pixels.dx - cx) + np.sin(normal) * (pixels.dy - cy) - offset
    band = SHADOW_BAND_BLURS * np.hypot(
        np.exp(np.clip(log_blur, *_SHADOW_LOG_BLUR)), np.exp(shadowed.params[4])
    )
    clear = np.abs(across) > band
    stepped = pixels._replace(shaded=across > 0).take(clear)
    step_start = np.concatenate([shadowed.params[: _GEOMETRY + 4], [depth]])
    return _solve(stepped, step_start, "step") or shadowed


def _start(pixels: _Pixels, line_angles: NDArray[np.float64]) -> NDArray[np.float64]:
    """The fit's start: the given lines, linear tone, the levels that fit them best."""
    geometry = np.array(
        [0.0, 0.0, line_angles[0], line_angles[1], np.log(_START_BLUR_PX), 0.0, 0.0, 1.0]
    )
    _, jacobian = _model(np.concatenate([geometry, np.ones(4)]), pixels, "none")
    # At tone 1 the signal is linear in the levels: their columns are the wedges' weights.
    weights = jacobian[:, _GEOMETRY : _GEOMETRY + 4]
    levels, *_ = np.linalg.lstsq(weights, pixels.level, rcond=None)
    return np.concatenate([geometry, np.maximum(levels, _MIN_SIGNAL)])
