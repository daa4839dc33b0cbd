"""The continuous adaptive template (section 3.3.1 in closed form) and its least-squares fit."""

import numpy as np
import pytest
from scipy.optimize import least_squares

from marker_localizer.core import template, template_fit
from marker_localizer.synthetic import MarkerPlacement, render_markers
from marker_localizer.synthetic.scene import CastShadow


def _shape(**changes: np.ndarray) -> template.TemplateShape:
    shape = template.TemplateShape(
        np.array([[0.3, -0.2]]),
        np.array([[0.4, 1.9]]),
        np.array([[0.8, 1.3]]),
        np.array([[0.01, -0.02]]),
        np.array([[2.1, 0.7, 0.5, 1.2]]),
    )
    return shape._replace(**changes)


def _model(shape: template.TemplateShape, pixels: np.ndarray, levels: np.ndarray) -> np.ndarray:
    terms = template.template_terms(pixels - shape.xy[:, None, :], shape)
    return (template.quadrant_weights(terms) @ levels[..., None])[..., 0]


def test_the_template_jacobian_matches_finite_differences_of_every_parameter():
    pixels = np.random.default_rng(0).uniform(-5, 5, (1, 80, 2))
    levels = np.array([[200.0, 30.0, 150.0, 40.0]])
    shape = _shape()
    terms = template.template_terms(pixels - shape.xy[:, None, :], shape)
    jacobian = template.template_jacobian(terms, shape, levels)
    params = template.shape_parameters(shape)[0]
    for k in range(template.SHAPE_PARAMETERS):
        step = np.zeros_like(params)
        step[k] = 1e-6
        plus = _model(template.shape_from_parameters((params + step)[None]), pixels, levels)
        minus = _model(template.shape_from_parameters((params - step)[None]), pixels, levels)
        np.testing.assert_allclose(jacobian[..., k], (plus - minus) / 2e-6, atol=2e-6)


def test_the_quadrant_weights_sum_to_the_light_everywhere():
    pixels = np.random.default_rng(1).uniform(-6, 6, (1, 50, 2))
    shape = _shape()
    terms = template.template_terms(pixels - shape.xy[:, None, :], shape)
    np.testing.assert_allclose(template.quadrant_weights(terms).sum(axis=-1), terms.gain)


def test_each_half_line_lies_between_the_quadrants_its_sides_name():
    # Line 1 along +x (s1 = -y), line 2 along +y (s2 = x).
    sides = template.half_line_quadrants(np.array([[0.0, np.pi / 2]]))[0]
    for k, direction in enumerate([(1, 0), (0, 1), (-1, 0), (0, -1)]):
        line = k % 2
        normal = np.array([(0.0, -1.0), (1.0, 0.0)][line])
        for column, sign in enumerate((1, -1)):
            point = 5.0 * np.array(direction) + sign * 0.5 * normal
            s = (-point[1], point[0])
            quadrant = template.QUADRANT_SIDES[sides[k, column]]
            assert (np.sign(s[0]), np.sign(s[1])) == quadrant


def _rendered(placement: MarkerPlacement, **kwargs: object) -> np.ndarray:
    return render_markers(
        (80, 80), [placement], 0, reflectances=(0.1, 0.85), blur_sigma_px=0.9, **kwargs
    ).image


def _fit(
    image: np.ndarray,
    xy: np.ndarray,
    angles: np.ndarray,
    radius: float = 12.0,
    noise: float | None = None,
) -> template_fit.GrownFit:
    start = template.TemplateShape.start(xy[None], angles[None], 1.0)
    return template_fit.fit_growing_template(
        image,
        start,
        np.array([4.0]),
        radius,
        noise_std=None if noise is None else np.array([noise]),
    )


def test_the_fit_finds_an_untilted_marker_to_a_hundredth_of_a_pixel_from_a_pixel_off():
    placement = MarkerPlacement(40.3, 39.6, 12.0, rotation_rad=0.3)
    image = _rendered(placement)
    grown = _fit(image, np.array([41.0, 39.0]), np.array([0.2, 1.9]))
    assert np.hypot(*(grown.fit.shape.xy[0] - (40.3, 39.6))) < 0.01
    # The lines are the images of the plate's axes: rotated by 0.3 rad.
    found = np.sort(grown.fit.shape.line_angles[0])
    np.testing.assert_allclose(found, np.sort([0.3, 0.3 + np.pi / 2]), atol=0.01)
    # The X reaches its radius along every half-line (to the blur and the sampling).
    np.testing.assert_allclose(grown.extents[0], 12.0, atol=1.5)


def test_a_dull_quadrant_keeps_its_own_level_and_moves_the_centre_by_nothing():
    sharp = MarkerPlacement(40.3, 39.6, 12.0, rotation_rad=0.3)
    dull = MarkerPlacement(40.3, 39.6, 12.0, rotation_rad=0.3, dull_factor=0.5)
    levels = []
    for placement in (sharp, dull):
        grown = _fit(_rendered(placement), np.array([41.0, 39.0]), np.array([0.2, 1.9]))
        assert np.hypot(*(grown.fit.shape.xy[0] - (40.3, 39.6))) < 0.01
        levels.append(np.sort(grown.fit.levels[0]))
    # The sharp marker's two bright quadrants are alike; the dull one's is half as bright.
    assert levels[0][3] == pytest.approx(levels[0][2], rel=0.02)
    assert levels[1][2] == pytest.approx(0.5 * levels[1][3], rel=0.03)


def test_a_cast_shadow_across_the_marker_is_found_and_leaves_the_centre_unbiased():
    placement = MarkerPlacement(40.3, 39.6, 12.0, rotation_rad=0.3)
    shadow = CastShadow(40.3, 39.6, normal_rad=2.0, offset_px=3.0, darkening=0.55, reach_px=30.0)
    image = _rendered(placement, cast_shadows=[shadow])
    plain = _fit(image, np.array([41.0, 39.0]), np.array([0.2, 1.9]))
    shaded = _fit(image, np.array([41.0, 39.0]), np.array([0.2, 1.9]), noise=1.0)
    error_plain = np.hypot(*(plain.fit.shape.xy[0] - (40.3, 39.6)))
    error_shaded = np.hypot(*(shaded.fit.shape.xy[0] - (40.3, 39.6)))
    assert error_shaded < 0.02 < error_plain
    normal, offset, depth, _ = shaded.fit.shape.shadow[0]
    assert np.cos(normal - 2.0) > 0.99
    assert offset == pytest.approx(3.0, abs=0.3)
    assert depth == pytest.approx(0.55, abs=0.05)


def test_a_tilted_marker_s_lines_reach_equally_far_on_both_sides_of_its_centre():
    placement = MarkerPlacement(
        40.3, 39.6, 14.0, rotation_rad=0.2, tilt_deg=50.0, tilt_axis_rad=0.9
    )
    image = _rendered(placement)
    grown = _fit(image, np.array([40.0, 40.0]), np.array([0.3, 1.6]), radius=16.0)
    extents = grown.extents[0]
    np.testing.assert_allclose(extents[:2], extents[2:], atol=1.0)
    assert np.hypot(*(grown.fit.shape.xy[0] - (40.3, 39.6))) < 0.02


def test_a_point_s_fit_does_not_depend_on_the_sizes_of_the_regions_fitted_beside_it():
    """Points are fitted in batches of like region sizes; the batching changes nothing."""
    placement = MarkerPlacement(40.3, 39.6, 12.0, rotation_rad=0.3)
    image = _rendered(placement)
    start = template.TemplateShape.start(
        np.array([[41.0, 39.0], [40.0, 40.0]]), np.array([[0.2, 1.9], [0.4, 1.8]]), 1.0
    )
    small, large = template_fit.disk_region(3.0), template_fit.disk_region(10.0)
    together = template_fit.fit_template(image, start, [small, large])
    for row, region in enumerate((small, large)):
        alone = template_fit.fit_template(image, start.take(np.array([row])), [region])
        np.testing.assert_allclose(together.shape.xy[row], alone.shape.xy[0], atol=1e-12)
        np.testing.assert_allclose(together.levels[row], alone.levels[0], atol=1e-9)


def test_a_refit_on_every_pixel_changes_only_the_accepted_markers():
    image = _rendered(MarkerPlacement(40.3, 39.6, 12.0, rotation_rad=0.3))
    start = template.TemplateShape.start(
        np.array([[41.0, 39.0], [41.0, 39.0]]), np.array([[0.2, 1.9], [0.2, 1.9]]), 1.0
    )
    grown = template_fit.fit_growing_template(
        image, start, np.array([4.0, 4.0]), 12.0, max_pixels=30
    )
    refit = template_fit.refit_on_every_pixel(image, grown, np.array([True, False]), 12.0)
    np.testing.assert_array_equal(refit.shape.xy[1], grown.fit.shape.xy[1])
    assert np.hypot(*(refit.shape.xy[0] - (40.3, 39.6))) < 0.01
    assert not np.array_equal(refit.shape.xy[0], grown.fit.shape.xy[0])


def test_an_x_reaches_its_radius_all_round_however_its_rings_read_it():
    # A dull quadrant and a shadow across the plate stop the rings short; the step
    # across each line, taken against its own inside, fades at the plate's end (11.5
    # px on each half-line of this blurred 12 px X without them), and where the
    # shadow's edge runs between the two sides a half-line reads a pixel short.
    placement = MarkerPlacement(40.3, 39.6, 12.0, rotation_rad=0.3, dull_factor=0.5)
    shadow = CastShadow(40.3, 39.6, normal_rad=2.0, offset_px=3.0, darkening=0.55, reach_px=30.0)
    image = _rendered(placement, cast_shadows=[shadow])
    angles = np.array([[0.3, 0.3 + np.pi / 2]])
    reach = template.line_reaches(image, np.array([[40.3, 39.6]]), angles, np.array([8.49]), 20.0)
    assert 10.0 <= reach[0] <= 12.0


@pytest.mark.filterwarnings("error")
def test_an_x_with_no_step_inside_reaches_nowhere_without_a_warning():
    # White clipped over the X's inside (where each half-line's step is taken as the
    # reference) leaves no step to compare the paint beyond with: every half-line
    # has faded where the reading starts (3 px, the first distance past 0.3 extents).
    placement = MarkerPlacement(40.3, 39.6, 16.0, rotation_rad=0.3)
    image = _rendered(placement)
    rows, cols = np.mgrid[: image.shape[0], : image.shape[1]]
    image[np.hypot(cols - 40.3, rows - 39.6) < 9.0] = image.max()
    angles = np.array([[0.3, 0.3 + np.pi / 2]])
    reach = template.line_reaches(image, np.array([[40.3, 39.6]]), angles, np.array([8.49]), 20.0)
    assert reach[0] <= 3.0


def test_a_tilted_x_reaches_all_round_as_far_as_its_ellipse_s_smaller_semi_axis():
    # Tilted 50 degrees, the plate's circle is an ellipse of semi-axes 14 and 14 cos 50;
    # the lines (its conjugate diameters) reach farther than the smaller one.
    placement = MarkerPlacement(
        40.3, 39.6, 14.0, rotation_rad=0.2, tilt_deg=50.0, tilt_axis_rad=0.9
    )
    image = _rendered(placement)
    grown = _fit(image, np.array([40.0, 40.0]), np.array([0.3, 1.6]), radius=16.0)
    angles = grown.fit.shape.line_angles
    reach = template.line_reaches(image, grown.fit.shape.xy, angles, np.array([6.0]), 20.0)
    assert grown.extents[0].min() > 10.0
    assert reach[0] == pytest.approx(14.0 * np.cos(np.deg2rad(50.0)), abs=1.0)


def test_an_ellipse_given_by_two_conjugate_semi_diameters_holds_their_ends_and_its_axes():
    # The ellipse x = 10 cos u, y = 5 sin u: the points at u and u + pi/2 are the ends
    # of two conjugate semi-diameters, along which an X's two lines would run.
    u = 0.5
    ends = np.array([[10.0 * np.cos(u), 5.0 * np.sin(u)], [-10.0 * np.sin(u), 5.0 * np.cos(u)]])
    semi_diameters = np.linalg.norm(ends, axis=1)[None]
    angles = np.arctan2(ends[:, 1], ends[:, 0])[None]
    assert template.smaller_semi_axis(semi_diameters, angles)[0] == pytest.approx(5.0)
    points = np.concatenate([ends * 0.99, ends * 1.01, [[0.0, 4.9], [0.0, 5.1], [9.9, 0.0]]])
    s1, s2 = template.line_distances(points[None, :, 0], points[None, :, 1], angles)
    inside = template.within_ellipse(s1, s2, semi_diameters, angles)[0]
    np.testing.assert_array_equal(inside, [True, True, False, False, True, False, True])


def _sharp_x_fit(seed: int) -> tuple[float, float]:
    """A sharp X's fit from a start off its centre and lines, and a bounded solver's least cost.

    Rendered with a blur of 0.05 px, under the fit's narrowest (0.25 px): both
    blurs end on their bound.
    """
    rng = np.random.default_rng(seed)
    x, y, rotation = 40 + rng.uniform(0, 1), 40 + rng.uniform(0, 1), rng.uniform(0, np.pi)
    image = render_markers(
        (80, 80),
        [MarkerPlacement(x, y, 12.0, rotation_rad=rotation, tilt_deg=30.0)],
        seed,
        reflectances=(0.1, 0.85),
        blur_sigma_px=0.05,
        noise_sigma_dn=2.0,
    ).image
    start = template.TemplateShape.start(
        np.array([[x + 0.4, y - 0.3]]), np.array([[rotation + 0.05, rotation + 1.53]]), 1.0
    )
    region = template_fit.disk_region(9.0)
    fit = template_fit.fit_template(image, start, [region])
    assert np.allclose(fit.shape.blur_px, template_fit._MIN_BLUR_PX)
    pixels = np.round(start.xy)[:, None, :] + region[None]
    values = image[pixels[0, :, 1].astype(int), pixels[0, :, 0].astype(int)][None].astype(float)
    weight = np.ones_like(values)
    # Without a shadow its four parameters stay out of the fit.
    free = np.arange(template.SHAPE_PARAMETERS) < 8
    lower, upper = template_fit._template_bounds()
    params = template.shape_parameters(start)[0]

    def state(geometry: np.ndarray) -> template_fit._TemplateState:
        return template_fit._template_residuals(
            values, weight, pixels, np.hstack([geometry, params[8:]])[None], free[None]
        )

    best = least_squares(
        lambda geometry: state(geometry).residual[0],
        np.clip(params[:8], lower[:8], upper[:8]),
        bounds=(lower[:8], upper[:8]),
        x_scale="jac",
    )
    return state(template.shape_parameters(fit.shape)[0, :8]).cost[0], state(best.x).cost[0]


def test_a_sharp_x_s_fit_holds_its_blur_on_the_bound_and_reaches_a_bounded_solvers_least_cost():
    # A step cut at the bound is not the step solved for: a fit that only clipped its
    # blur there stopped up to 1 % above the least cost.
    ratios = [cost / least for cost, least in map(_sharp_x_fit, range(8))]
    assert max(ratios) < 1.0001
