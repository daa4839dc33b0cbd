"""The adaptive template's least-squares fit (section 3.3.1 in closed form).

``refinement="template"``'s location: the continuous template of
:mod:`~marker_localizer.core.template` (two blurred lines through the centre, a
level per quadrant, the light's slope and a cast shadow's edge) fitted to the
pixels of each X by Levenberg-Marquardt (:func:`fit_template`), on regions grown
from the X's centre outwards while the X goes on (:func:`fit_growing_template`),
and once more on every pixel of the X for the markers the decision accepts
(:func:`refit_on_every_pixel`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple, cast

import numpy as np
from numpy.typing import NDArray

from marker_localizer.core import template, uneven
from marker_localizer.core.sampling import pad_patterns, size_batches

#: Levenberg-Marquardt iterations of :func:`refit_on_every_pixel`, from the
#: decision's fit.
_REFIT_ITERATIONS = 20

#: Levenberg-Marquardt damping: start, and factor per rejected / accepted step.
_LM_START, _LM_UP, _LM_DOWN = 1e-2, 10.0, 0.3
#: Damping beyond which a point has stopped moving: its fit is final.
_LM_GIVE_UP = 1e6
#: A fit whose last accepted step moved the centre less than this has settled, px:
#: a tenth of the error of the least precise markers; a last step that large is still
#: a search.
_SETTLED_PX = 1e-2
#: Narrowest blur the fit may take, px: sharper than the pixel itself cannot be told.
_MIN_BLUR_PX = 0.25
#: Widest blur, px: beyond it an X of the smallest expected size is a blob.
_MAX_BLUR_PX = 6.0
#: Largest share of the light a cast shadow takes: a darker one leaves nothing to fit.
_MAX_SHADOW_DEPTH = 0.95
#: Pull of the levels towards the pixels' mean, relative to the trace of their normal
#: equations: a thousandth, which moves a level the region covers by no measurable amount.
_LEVEL_REGULARISATION = 1e-3
#: Largest illumination gradient, per px: 10 % of the light over a pixel is more than
#: any shadow's penumbra gives; beyond it the gain would turn the template over.
_MAX_GAIN_PER_PX = 0.1


class TemplateFit(NamedTuple):
    """Result of :func:`fit_template` for N points.

    Attributes:
        shape: the fitted :class:`~marker_localizer.core.template.TemplateShape`.
        levels: (N, 4) grey level of each quadrant (image units), in the order of
            :data:`~marker_localizer.core.template.QUADRANT_SIDES`.
        level_covariance: (N, 4, 4) covariance of the levels.
        covariance: (N, 2, 2) covariance of the centre, px^2.
        residual_rms: (N,) RMS residual of the fit, image units.
        n_pixels: (N,) pixels the fit used.
        converged: (N,) True where the fit stopped with a step below the tolerance.
    """

    shape: template.TemplateShape
    levels: NDArray[np.float64]
    level_covariance: NDArray[np.float64]
    covariance: NDArray[np.float64]
    residual_rms: NDArray[np.float64]
    n_pixels: NDArray[np.float64]
    converged: NDArray[np.bool_]

    def take(self, rows: NDArray[np.integer[Any] | np.bool_]) -> TemplateFit:
        """The fits of ``rows`` (indices or a mask) only."""
        return TemplateFit(self.shape.take(rows), *(part[rows] for part in self[1:]))

    def with_rows(
        self, rows: NDArray[np.integer[Any] | np.bool_], part: TemplateFit
    ) -> TemplateFit:
        """A copy with the fits of ``rows`` (indices or a mask) replaced by ``part``'s."""
        shape = template.TemplateShape(
            *(
                _with_rows(whole, rows, new)
                for whole, new in zip(self.shape, part.shape, strict=True)
            )
        )
        return TemplateFit(
            shape,
            *(_with_rows(whole, rows, new) for whole, new in zip(self[1:], part[1:], strict=True)),
        )


def _with_rows(
    whole: NDArray[Any], rows: NDArray[np.integer[Any] | np.bool_], part: NDArray[Any]
) -> NDArray[Any]:
    """A copy of ``whole`` with ``rows`` replaced by ``part``."""
    out = whole.copy()
    out[rows] = part
    return out


def fit_template(
    image: NDArray[Any],
    start: template.TemplateShape,
    regions: list[NDArray[np.float64]],
    *,
    iterations: int = 20,
    tolerance_px: float = 1e-4,
    max_shift_px: NDArray[np.float64] | float = np.inf,
) -> TemplateFit:
    """Least-squares fit of the adaptive template to the pixels of each marker.

    The paper locates a marker by the NCC surface of its adaptive template (Eqs.
    11-14), whose extremum is tied to the pixel grid. This fits the same template,
    in the closed form of :func:`~marker_localizer.core.template.quadrant_weights`,
    to every pixel of the marker by Levenberg-Marquardt over its geometry (centre,
    line angles, blur across each line, illumination gradient, and a shadow's edge
    where ``start`` has one), the four quadrant levels being solved linearly at
    each step (variable projection). The pixels are read once, at their centres,
    with no interpolation; a model of the whole X over the whole marker is what
    approaches the Cramer-Rao bound (docs/accuracy-journal.md, "What the Cramer-Rao bound asks
    of the fit").

    Args:
        image: (H, W) grey image, native dtype.
        start: starting geometry, N points; a shadow of depth 0 stays out of the fit.
        regions: per point, (K_i, 2) integer offsets from ``round(start.xy)`` of the
            pixels to fit (e.g. from :func:`template.template_region`).
        iterations: Levenberg-Marquardt iterations at most.
        tolerance_px: a point whose centre step falls below this has converged.
        max_shift_px: (N,) or scalar: a step that takes the centre farther than this
            from its start is refused (the region was chosen around the start).

    Returns:
        :class:`TemplateFit`.
    """
    n = len(start.xy)
    if n == 0:
        empty = template.TemplateShape.start(np.zeros((0, 2)), np.zeros((0, 2)), 1.0)
        return TemplateFit(
            empty,
            np.zeros((0, 4)),
            np.zeros((0, 4, 4)),
            np.zeros((0, 2, 2)),
            np.zeros(0),
            np.zeros(0),
            np.zeros(0, bool),
        )
    reach = np.broadcast_to(np.asarray(max_shift_px, dtype=np.float64), (n,))
    batches = size_batches([len(region) for region in regions], _BATCH_SIZE_RATIO)
    if len(batches) == 1:
        return _fit_template_batch(image, start, regions, iterations, tolerance_px, reach)
    order = np.concatenate(batches)
    parts = [
        _fit_template_batch(
            image,
            start.take(rows),
            [regions[k] for k in rows],
            iterations,
            tolerance_px,
            reach[rows],
        )
        for rows in batches
    ]
    shape = template.TemplateShape(
        *(np.concatenate(field) for field in zip(*(part.shape for part in parts), strict=True))
    )
    joined = TemplateFit(
        shape, *(np.concatenate(field) for field in zip(*(part[1:] for part in parts), strict=True))
    )
    return joined.take(np.argsort(order))


def _fit_template_batch(
    image: NDArray[Any],
    start: template.TemplateShape,
    regions: list[NDArray[np.float64]],
    iterations: int,
    tolerance_px: float,
    reach: NDArray[np.float64],
) -> TemplateFit:
    """:func:`fit_template` on points whose regions differ little in size."""
    n = len(start.xy)
    offsets, present = pad_patterns(regions)
    pixels = np.round(start.xy)[:, None, :] + offsets
    height, width = image.shape
    inside = (
        (pixels[..., 0] >= 0)
        & (pixels[..., 1] >= 0)
        & (pixels[..., 0] < width)
        & (pixels[..., 1] < height)
    )
    weight = (present & inside).astype(np.float64)
    cols = np.clip(pixels[..., 0], 0, width - 1).astype(np.intp)
    rows = np.clip(pixels[..., 1], 0, height - 1).astype(np.intp)
    values = image[rows, cols].astype(np.float64)
    lower, upper = _template_bounds()
    params = np.clip(template.shape_parameters(start), lower, upper)
    # Without a shadow its four parameters are undetermined: they stay where they are.
    free = np.ones((n, template.SHAPE_PARAMETERS), dtype=bool)
    free[:, _SHADOW] = (start.shadow[:, 2] > 0)[:, None]
    state = _template_residuals(values, weight, pixels, params, free)
    last_move = np.full(n, np.inf)
    damping = np.full(n, _LM_START)
    active = np.ones(n, dtype=bool)
    converged = np.zeros(n, dtype=bool)
    eye = np.eye(template.SHAPE_PARAMETERS)
    for _ in range(iterations):
        if not active.any():
            break
        # Levenberg-Marquardt on the active points only: the others are final.
        idx = np.flatnonzero(active)
        residual, jacobian = state.residual[idx], state.jacobian[idx]
        weighted = jacobian * weight[idx, :, None]
        gradient = (weighted.transpose(0, 2, 1) @ residual[..., None])[..., 0]
        # The step descends along +gradient; a parameter on its bound that it would
        # take out of the box is held there for this step, as a frozen one is.
        moving = free[idx] & ~uneven.held_on_bounds(params[idx], -gradient, lower, upper)
        weighted = weighted * moving[:, None, :]
        normal = weighted.transpose(0, 2, 1) @ (jacobian * moving[:, None, :])
        gradient *= moving
        # Frozen and held parameters get a unit diagonal and no gradient: a zero step.
        scale = np.where(moving, np.maximum(normal.diagonal(axis1=1, axis2=2), 1e-12), 1.0)
        ridge = damping[idx, None] * scale + ~moving
        damped = normal + ridge[:, :, None] * eye
        step = np.linalg.solve(damped, gradient[..., None])[..., 0]
        trial = np.clip(params[idx] + step, lower, upper)
        new = _template_residuals(values[idx], weight[idx], pixels[idx], trial, free[idx])
        within = np.hypot(*(trial[:, :2] - start.xy[idx]).T) <= reach[idx]
        better = (new.cost < state.cost[idx]) & within
        take = idx[better]
        params[take] = trial[better]
        for name, field_value in zip(state._fields, new, strict=True):
            getattr(state, name)[take] = field_value[better]
        damping[idx] = np.where(better, damping[idx] * _LM_DOWN, damping[idx] * _LM_UP)
        moved = np.hypot(step[:, 0], step[:, 1])
        last_move[take] = moved[better]
        small = moved < tolerance_px
        converged[idx] |= better & small
        active[idx] &= ~((better & small) | (damping[idx] > _LM_GIVE_UP))
    # A point no step improves any more sits at its optimum (stalled), and one whose
    # last steps are a small fraction of a pixel has settled, iterations left or not.
    converged |= (damping > _LM_GIVE_UP) | (last_move < _SETTLED_PX)
    n_pixels = weight.sum(axis=1)
    dof = np.maximum(n_pixels - free.sum(axis=1) - 4, 1.0)
    variance = state.cost / dof
    weighted = state.jacobian * weight[..., None]
    normal = weighted.transpose(0, 2, 1) @ state.jacobian
    normal += (~free)[:, :, None] * np.eye(template.SHAPE_PARAMETERS)
    parameter_covariance = np.linalg.pinv(normal) * variance[:, None, None]
    level_covariance = np.linalg.pinv(state.level_normal) * variance[:, None, None]
    shape = template.shape_from_parameters(params)
    shape = shape._replace(line_angles=shape.line_angles % np.pi)
    return TemplateFit(
        shape,
        state.levels,
        level_covariance,
        parameter_covariance[:, :2, :2],
        np.sqrt(variance),
        n_pixels,
        converged & np.isfinite(params).all(axis=1),
    )


#: Points whose regions' pixel counts lie within this factor are fitted as one batch.
_BATCH_SIZE_RATIO = 2.0
#: Columns of the shadow edge's parameters in :func:`template.shape_parameters`.
_SHADOW = slice(8, 12)


def _template_bounds() -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(12,) lower and upper bounds of :func:`template.shape_parameters`: what is physical.

    The blurs across the lines and the shadow's penumbra, the light's gradient and
    the shadow's depth; the centre, the lines and the shadow's edge are free.
    """
    lower, upper = (
        np.full(template.SHAPE_PARAMETERS, -np.inf),
        np.full(template.SHAPE_PARAMETERS, np.inf),
    )
    lower[[4, 5, 11]], upper[[4, 5, 11]] = np.log(_MIN_BLUR_PX), np.log(_MAX_BLUR_PX)
    lower[6:8], upper[6:8] = -_MAX_GAIN_PER_PX, _MAX_GAIN_PER_PX
    lower[10], upper[10] = 0.0, _MAX_SHADOW_DEPTH
    return lower, upper


class _TemplateState(NamedTuple):
    residual: NDArray[np.float64]  # (N, K)
    jacobian: NDArray[np.float64]  # (N, K, 12): of the model at the solved levels
    levels: NDArray[np.float64]  # (N, 4)
    level_normal: NDArray[np.float64]  # (N, 4, 4)
    cost: NDArray[np.float64]  # (N,)


def _template_residuals(
    values: NDArray[np.float64],
    weight: NDArray[np.float64],
    pixels: NDArray[np.float64],
    params: NDArray[np.float64],
    free: NDArray[np.bool_],
) -> _TemplateState:
    """Residuals of the template at ``params`` with its levels solved by least squares.

    The Jacobian's columns of the parameters not ``free`` are zero.
    """
    shape = template.shape_from_parameters(params)
    finite = cast("NDArray[np.bool_]", np.isfinite(params).all(axis=1))
    terms = template.template_terms(pixels - shape.xy[:, None, :], shape)
    basis = np.where(finite[:, None, None], template.quadrant_weights(terms), 0.0)
    weighted = basis * weight[..., None]
    level_normal = weighted.transpose(0, 2, 1) @ basis
    # A weak pull of each level towards the pixels' mean: a quadrant the region barely
    # covers cannot run off to levels no paint has.
    ridge = _LEVEL_REGULARISATION * (1e-12 + np.trace(level_normal, axis1=1, axis2=2))
    mean = (weight * values).sum(axis=1) / np.maximum(weight.sum(axis=1), 1.0)
    level_normal += ridge[:, None, None] * np.eye(4)
    rhs = weighted.transpose(0, 2, 1) @ values[..., None] + (ridge * mean)[:, None, None]
    levels = np.linalg.solve(level_normal, rhs)[..., 0]
    residual = values - (basis @ levels[..., None])[..., 0]
    # Variable projection with Kaufman's Jacobian: the model's derivative with the
    # levels held, minus what re-solving the levels would absorb (its part in the
    # span of the basis); the term Kaufman leaves out vanishes at the optimum.
    held = template.template_jacobian(terms, shape, levels)
    absorbed = np.linalg.solve(level_normal, weighted.transpose(0, 2, 1) @ held)
    jacobian = np.where(finite[:, None, None] & free[:, None, :], held - basis @ absorbed, 0.0)
    cost = np.where(finite, (weight * residual**2).sum(axis=1), np.inf)
    return _TemplateState(residual, jacobian, levels, level_normal, cost)


#: Each growth step of :func:`fit_growing_template` at most doubles the region.
_GROWTH_FACTOR = 2.0
#: The first fit may move the centre by this share of its disk's radius (plus
#: :data:`_FIRST_SHIFT_PX`): a candidate lies that close to its X's centre.
_FIRST_SHIFT = 0.5
_FIRST_SHIFT_PX = 1.0
#: A growth step may move the centre by this share of its region's cap: the larger
#: region refines, it does not relocate.
_GROWTH_SHIFT = 0.25
#: Growth steps after the first fit: from a 3 px start, 3 doublings reach 24 px and
#: every step after the first refits what the last one found.
_GROWTH_STEPS = 3
#: Levenberg-Marquardt iterations per growth step: each starts from the last
#: step's fit, a fraction of a pixel from its optimum.
_GROWTH_ITERATIONS = 10


class GrownFit(NamedTuple):
    """Result of :func:`fit_growing_template`.

    Attributes:
        fit: each point's last :class:`TemplateFit`: over the region of its whole X,
            or where growing it stopped.
        extents: (N, 4) reach of the four half-lines (+e1, +e2, -e1, -e2), px,
            measured around that fit's geometry.
        grown: (N,) True where the region grew to the whole X (False: ``keep``
            stopped it).
    """

    fit: TemplateFit
    extents: NDArray[np.float64]
    grown: NDArray[np.bool_]


def disk_region(radius_px: float) -> NDArray[np.float64]:
    """(K, 2) integer offsets within ``radius_px`` of the origin."""
    half = int(np.floor(radius_px))
    grid = np.arange(-half, half + 1, dtype=np.float64)
    gx, gy = np.meshgrid(grid, grid)
    offsets = np.stack([gx.ravel(), gy.ravel()], axis=1)
    return cast("NDArray[np.float64]", offsets[(offsets**2).sum(axis=1) <= radius_px**2])


def fit_growing_template(
    image: NDArray[Any],
    start: template.TemplateShape,
    start_radius_px: NDArray[np.float64],
    max_radius_px: float,
    *,
    steps: int = _GROWTH_STEPS,
    max_pixels: int | None = None,
    noise_std: NDArray[np.float64] | None = None,
    keep: Callable[[TemplateFit, NDArray[np.float64]], NDArray[np.bool_]] | None = None,
    iterations: int = _GROWTH_ITERATIONS,
) -> GrownFit:
    """Fit the adaptive template over a region that grows to the whole X.

    A first fit on a small disk around the start finds the centre, lines and
    levels; the lines' reach (:func:`template.line_extents`) then sets the next
    region, the ellipse on which the X holds, at most twice as large, and so on:
    every step refits on more of the marker with a better geometry. ``keep``
    stops growing the points that are plainly no marker, so that most texture
    costs only the first, small fit.

    Args:
        image: (H, W) grey image, native dtype.
        start: starting geometry.
        start_radius_px: (N,) radius of the first disk.
        max_radius_px: largest expected marker radius.
        steps: growth steps after the first fit.
        max_pixels: fit at most about this many pixels per point (a lattice of them
            for large regions); None: every pixel.
        noise_std: (N,) the image's noise at each point; where the last fit leaves
            clearly more than that, a cast shadow's edge is tried
            (:func:`find_shadow_edges`) and kept if it explains enough more.
        keep: (fit, extents) -> (M,) bool for the M points of one step: which grow on;
            asked first about every point (their first fits), then about those growing.
        iterations: Levenberg-Marquardt iterations per step.

    Returns:
        :class:`GrownFit`.
    """
    keys = np.round(np.asarray(start_radius_px, dtype=np.float64) * 2.0) / 2.0
    disks = [disk_region(float(k)) for k in keys]
    fit = fit_template(
        image,
        start,
        disks,
        iterations=iterations,
        max_shift_px=_FIRST_SHIFT * keys + _FIRST_SHIFT_PX,
    )
    cap = keys.copy()
    extents = template.line_extents(image, fit.shape, fit.levels, max_radius_px)
    alive: NDArray[np.intp] = np.arange(len(keys))
    regions: list[NDArray[np.float64]] = list(disks)
    for _ in range(steps):
        if keep is not None:
            alive = alive[keep(fit.take(alive), extents[alive])]
        cap[alive] = np.minimum(_GROWTH_FACTOR * cap[alive], max_radius_px)
        grown = template.template_region(
            fit.shape.take(alive), extents[alive], cap[alive], max_pixels
        )
        for k, region in zip(alive, grown, strict=True):
            # A region never shrinks below the first disk: an X that ends sooner is
            # too small (the decision says so), and fewer pixels would not pin it.
            regions[k] = region if len(region) >= len(disks[k]) else disks[k]
        part = fit_template(
            image,
            fit.shape.take(alive),
            [regions[k] for k in alive],
            iterations=iterations,
            max_shift_px=_GROWTH_SHIFT * cap[alive],
        )
        fit = fit.with_rows(alive, part)
        extents[alive] = template.line_extents(image, part.shape, part.levels, max_radius_px)
    if noise_std is not None and steps > 0:
        fit = _with_shadow_edges(image, fit, regions, noise_std, _GROWTH_SHIFT * cap, alive)
    grew = np.zeros(len(keys), dtype=bool)
    grew[alive] = True
    return GrownFit(fit, extents, grew)


#: Parameters of the template fit without a shadow's edge (the centre, the lines, the
#: blurs, the light's gradient, the four quadrants' levels), and those the edge adds.
_PLAIN_FIT_PARAMETERS = 12
_SHADOW_EDGE_PARAMETERS = 4
#: A shadow's edge is tried where the fit without it leaves this many times the noise.
_SHADOW_TRY_RATIO = 1.3
#: ... and kept where it takes at least this share of the residual's sum of squares.
_SHADOW_MIN_GAIN = 0.2


def _with_shadow_edges(
    image: NDArray[Any],
    fit: TemplateFit,
    regions: list[NDArray[np.float64]],
    noise_std: NDArray[np.float64],
    max_shift_px: NDArray[np.float64],
    among: NDArray[np.integer[Any]],
) -> TemplateFit:
    """``fit``, with a cast shadow's edge where one explains enough of what it leaves.

    Only the points ``among`` (indices) whose fit leaves clearly more than the noise
    are tried.
    """
    tried = among[fit.residual_rms[among] > _SHADOW_TRY_RATIO * noise_std[among]]
    if not len(tried):
        return fit
    part = fit.take(tried)
    subset = [regions[k] for k in tried]
    shaded = fit_template(
        image, find_shadow_edges(image, part, subset), subset, max_shift_px=max_shift_px[tried]
    )
    # The shadow's four parameters must pay for themselves in the sum of squares.
    plain_ss = part.residual_rms**2 * np.maximum(part.n_pixels - _PLAIN_FIT_PARAMETERS, 1.0)
    shaded_ss = shaded.residual_rms**2 * np.maximum(
        shaded.n_pixels - (_PLAIN_FIT_PARAMETERS + _SHADOW_EDGE_PARAMETERS), 1.0
    )
    better = (shaded_ss < (1.0 - _SHADOW_MIN_GAIN) * plain_ss) & (shaded.shape.shadow[:, 2] > 0)
    return fit.with_rows(tried[better], shaded.take(better))


#: Directions of a shadow's edge tried by :func:`find_shadow_edges` (normals over a
#: full turn: the shadow lies on the normal's side).
_SHADOW_DIRECTIONS = 36
#: Each side of a shadow's edge holds at least this share of the marker's pixels.
_SHADOW_MIN_SIDE = 0.1
#: Penumbra width a shadow's fit starts from, px: a sharp cast shadow's.
_SHADOW_START_WIDTH_PX = 1.0


def find_shadow_edges(
    image: NDArray[Any], fit: TemplateFit, regions: list[NDArray[np.float64]]
) -> template.TemplateShape:
    """Where a cast shadow's straight edge would best explain what the template leaves.

    A shadow multiplies the light, so the image over the template fitted without
    it, r = I / T, is about 1 on the lit side and 1 - depth on the other. For each
    of :data:`_SHADOW_DIRECTIONS` directions, the marker's pixels are ordered along
    it and split where the two sides' ratios differ most (the largest
    between-class variance); the best split over all directions starts the edge.

    Args:
        image: (H, W) grey image.
        fit: fits without a shadow, N points.
        regions: their regions (as for :func:`fit_template`).

    Returns:
        ``fit.shape`` with each point's shadow started there (depth from the split;
        0 where no split darkens one side).
    """
    n = len(fit.shape.xy)
    if n == 0:
        return fit.shape
    offsets, present = pad_patterns(regions)
    pixels = np.round(fit.shape.xy)[:, None, :] + offsets
    height, width = image.shape
    present &= (
        (pixels[..., 0] >= 0)
        & (pixels[..., 1] >= 0)
        & (pixels[..., 0] < width)
        & (pixels[..., 1] < height)
    )
    cols = np.clip(pixels[..., 0], 0, width - 1).astype(np.intp)
    rows = np.clip(pixels[..., 1], 0, height - 1).astype(np.intp)
    values = image[rows, cols].astype(np.float64)
    d = pixels - fit.shape.xy[:, None, :]
    model = (
        template.quadrant_weights(template.template_terms(d, fit.shape)) @ fit.levels[..., None]
    )[..., 0]
    ratio = np.where(present, values / np.maximum(model, 1e-9 + 1e-3 * np.abs(model).max()), 0.0)
    count = present.sum(axis=1)
    best = np.full(n, -np.inf)
    start = fit.shape.shadow.copy()
    start[:, 3] = _SHADOW_START_WIDTH_PX
    for angle in np.arange(_SHADOW_DIRECTIONS) * (2.0 * np.pi / _SHADOW_DIRECTIONS):
        along = np.where(present, d[..., 0] * np.cos(angle) + d[..., 1] * np.sin(angle), np.inf)
        # Stable: pixels level along the direction (every column of the grid at 0 degrees)
        # enter the sums in one order, so the split found does not hang on the sort.
        order = np.argsort(along, axis=1, kind="stable")
        r = np.take_along_axis(ratio, order, axis=1)
        w = np.take_along_axis(present, order, axis=1).astype(np.float64)
        t = np.take_along_axis(along, order, axis=1)
        n_low = np.cumsum(w, axis=1)
        sum_low = np.cumsum(w * r, axis=1)
        n_high = count[:, None] - n_low
        mean_low = sum_low / np.maximum(n_low, 1.0)
        mean_high = (sum_low[:, -1:] - sum_low) / np.maximum(n_high, 1.0)
        # The shadow lies along +angle: the far side is the darker one.
        between = n_low * n_high * (mean_low - mean_high) ** 2 / np.maximum(count[:, None], 1.0)
        usable = (
            (n_low >= _SHADOW_MIN_SIDE * count[:, None])
            & (n_high >= _SHADOW_MIN_SIDE * count[:, None])
            & (mean_high < mean_low)
        )
        between = np.where(usable, between, -np.inf)
        split = np.argmax(between, axis=1)
        gain = between[np.arange(n), split]
        better = gain > best
        best[better] = gain[better]
        low, high = mean_low[np.arange(n), split], mean_high[np.arange(n), split]
        rows = np.arange(n)
        edge = 0.5 * (t[rows, split] + t[rows, np.minimum(split + 1, t.shape[1] - 1)])
        depth = np.clip(1.0 - high / np.maximum(low, 1e-9), 0.0, _MAX_SHADOW_DEPTH)
        start[better, 0] = angle
        start[better, 1] = edge[better]
        start[better, 2] = depth[better]
    start[~np.isfinite(best), 2] = 0.0
    return fit.shape._replace(shadow=start)


def refit_on_every_pixel(
    image: NDArray[Any], grown: GrownFit, accepted: NDArray[np.bool_], max_radius_px: float
) -> TemplateFit:
    """The ``accepted`` markers' template fits again, on every pixel of their X.

    The decision's fits read a lattice of pixels (``max_pixels`` of
    :func:`fit_growing_template`): enough for the X's shape, not for its last
    hundredth of a pixel. The others are returned as they are.

    Args:
        image: (H, W) grey image, raw levels.
        grown: the grown fits, N points.
        accepted: (N,) the points to fit again.
        max_radius_px: the largest expected marker radius, px.
    """
    fit = grown.fit
    if not accepted.any():
        return fit
    chosen = fit.shape.take(accepted)
    regions = template.template_region(
        chosen, grown.extents[accepted], np.full(int(accepted.sum()), max_radius_px)
    )
    final = fit_template(image, chosen, regions, iterations=_REFIT_ITERATIONS)
    return fit.with_rows(accepted, final)
