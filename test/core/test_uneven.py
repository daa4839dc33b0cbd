"""The X whose quadrants' levels differ, located through the tone curve (core/uneven.py)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.special import ndtr
from scipy.stats import multivariate_normal

from marker_localizer.core import subpixel, uneven
from marker_localizer.core.shadow import ShadowEdges
from marker_localizer.synthetic.scene import CastShadow, MarkerPlacement, render_markers


@pytest.mark.parametrize(("h", "k", "rho"), [(0.3, -0.7, 0.6), (-1.2, 0.4, -0.4), (0.0, 0.0, 0.9)])
def test_the_wedge_correction_is_the_bivariate_normal_less_the_product(h, k, rho):
    value, *_ = uneven.wedge_correction(np.array([h]), np.array([k]), rho)
    exact = multivariate_normal(mean=[0.0, 0.0], cov=[[1.0, rho], [rho, 1.0]]).cdf([h, k])
    assert value[0] == pytest.approx(exact - ndtr(h) * ndtr(k), abs=1e-5)


@pytest.mark.parametrize(
    ("h", "r"),
    [((0.3, -0.5, 0.8), (0.4, -0.3, 0.2)), ((-1.0, 0.2, 0.1), (-0.6, 0.7, -0.5))],
)
def test_the_trivariate_normal_is_scipys_and_its_derivatives_are_its_slopes(h, r):
    covariance = np.array([[1.0, r[0], r[1]], [r[0], 1.0, r[2]], [r[1], r[2], 1.0]])
    exact = multivariate_normal.cdf(h, np.zeros(3), covariance, abseps=1e-9, releps=1e-9)

    def value(limits, correlations):
        return uneven.trivariate_normal(tuple(np.array([x]) for x in limits), *correlations)[0][0]

    phi3, by_h, by_r = uneven.trivariate_normal(tuple(np.array([x]) for x in h), *r)
    assert phi3[0] == pytest.approx(exact, abs=1e-5)
    step = 1e-5
    for i in range(3):
        up, down = np.array(h, float), np.array(h, float)
        up[i] += step
        down[i] -= step
        assert by_h[i][0] == pytest.approx((value(up, r) - value(down, r)) / (2 * step), abs=1e-4)
        up, down = np.array(r, float), np.array(r, float)
        up[i] += step
        down[i] -= step
        assert by_r[i][0] == pytest.approx((value(h, up) - value(h, down)) / (2 * step), abs=1e-4)


@pytest.mark.parametrize("shadowed", [False, True])
def test_the_models_jacobian_is_its_derivative(shadowed):
    rng = np.random.default_rng(0)
    shape = (2, 200)
    pixels = uneven._Pixels(
        rng.uniform(-6, 6, shape),
        rng.uniform(-6, 6, shape),
        rng.uniform(0, 1, shape),
        np.ones(shape, dtype=bool),
    )
    # Two X's: centre, lines, ln blur, slope, tone; four levels; the shadow's edge.
    params = np.array(
        [
            [0.2, -0.1, 0.3, 1.5, np.log(0.9), 0.01, -0.02, 0.8, 0.2, 0.7, 0.25, 0.5],
            [-0.1, 0.3, 0.9, 2.3, np.log(1.2), -0.01, 0.02, 1.1, 0.6, 0.1, 0.45, 0.15],
        ]
    )
    if shadowed:
        params = np.hstack([params, [[0.7, 1.0, 0.5, np.log(0.5)], [2.0, -1.0, 0.3, np.log(0.3)]]])
    _, jacobian = uneven._model(params, pixels, shadowed)
    step = 1e-6
    for j in range(params.shape[1]):
        moved = np.zeros_like(params)
        moved[:, j] = step
        numeric = (
            uneven._model(params + moved, pixels, shadowed)[0]
            - uneven._model(params - moved, pixels, shadowed)[0]
        ) / (2 * step)
        np.testing.assert_allclose(jacobian[..., j], numeric, atol=1e-4)


def _dull_marker(seed: int, gamma: float):
    """A tilted X of 16 px, one bright quadrant 0.6 as bright as the other, under a gamma."""
    rng = np.random.default_rng(seed)
    placement = MarkerPlacement(
        48 + rng.uniform(0, 1),
        48 + rng.uniform(0, 1),
        16.0,
        rotation_rad=rng.uniform(0, np.pi),
        tilt_deg=30.0,
        tilt_axis_rad=rng.uniform(0, np.pi),
        dull_factor=0.6,
    )
    return render_markers(
        (96, 96),
        [placement],
        seed,
        reflectances=(0.1, 0.8),
        blur_sigma_px=1.0,
        noise_sigma_dn=2.0,
        gamma=gamma,
        crlb=True,
    )


@pytest.mark.parametrize("gamma", [0.8, 1.25])
def test_a_dull_quadrant_under_a_gamma_is_located_within_a_few_bounds(gamma):
    errors, symmetric, bounds = [], [], []
    for seed in range(8):
        scene = _dull_marker(seed, gamma)
        marker = scene.markers[0]
        start = scene.centres + 0.3
        radius = np.array([marker.foreshortened_radius_px])
        fit = uneven.locate_uneven(scene.image, start, np.array([marker.angles]), radius, 255.0)
        assert fit.located[0]
        errors.append(np.linalg.norm(fit.xy[0] - scene.centres[0]))
        symmetry = subpixel.refine_point_symmetry(scene.image, start, radius)
        symmetric.append(np.linalg.norm(symmetry.xy[0] - scene.centres[0]))
        bounds.append(marker.crlb_mean_abs_error_px)
    # Measured: 3.2-3.3x the bound; grey-level symmetry is pulled 0.3-0.4 px off.
    assert np.mean(errors) < 4.0 * np.mean(bounds)
    assert np.mean(symmetric) > 10 * np.mean(errors)


def test_a_model_is_located_only_where_it_leaves_no_more_than_its_misfit_ratio():
    # Two copies of one dull X: against a reference residual of 2 DN (the noise) it
    # is located; against 0.05 DN, which the model's 2 DN exceed 40-fold, it is not.
    scene = _dull_marker(0, 1.0)
    marker = scene.markers[0]
    start = np.repeat(scene.centres + 0.3, 2, axis=0)
    fit = uneven.locate_uneven(
        scene.image,
        start,
        np.repeat([marker.angles], 2, axis=0),
        np.full(2, marker.foreshortened_radius_px),
        255.0,
        reference_rms=np.array([2.0, 0.05]),
    )
    assert fit.located.tolist() == [True, False]
    np.testing.assert_array_equal(fit.xy[1], start[1])


@pytest.mark.parametrize(
    ("min_centre_chi2", "located_from_the_centre"),
    [(subpixel.MODEL_MIN_CENTRE_CHI2, 0), (0.0, 8), (None, 8)],
)
def test_a_model_asked_to_reject_its_start_takes_it_only_where_the_start_is_off(
    min_centre_chi2, located_from_the_centre
):
    # Held at the true centre, the model leaves 1-13 more chi-square than free (its
    # 2 degrees of freedom, the renderer's quantisation, the model's own mismatch); held
    # 0.36 px off, 1 200-1 700. The 0.1 % point (13.8) rejects only the latter; 0
    # rejects neither (a fit never ends worse than its start held, unless it slid).
    from_centre = from_off = 0
    for seed in range(8):
        scene = _dull_marker(seed, 1.0)
        marker = scene.markers[0]
        fit = uneven.locate_uneven(
            scene.image,
            np.vstack([scene.centres[0], scene.centres[0] + [0.3, -0.2]]),
            np.repeat([marker.angles], 2, axis=0),
            np.full(2, marker.foreshortened_radius_px),
            255.0,
            min_centre_chi2=min_centre_chi2,
        )
        from_centre += int(fit.located[0])
        from_off += int(fit.located[1])
    assert from_centre == located_from_the_centre
    assert from_off == 8


def _even_marker_pixels():
    """The model's pixels of an X of even paint (:func:`_dull_marker` at 1.0), and its lines."""
    scene = _dull_marker(0, 1.0)
    marker = scene.markers[0]
    radius = uneven.RADIUS_FRACTION * marker.foreshortened_radius_px
    lines = np.array([marker.angles])
    pixels = uneven._pixels(scene.image, scene.centres[0], radius, lines[0], 255.0)
    assert pixels is not None
    return pixels, lines


def test_a_fit_that_ends_off_its_best_rejects_its_start_by_a_negative_chi_square():
    # A fit stopped 0.4 px from where the model fits best (as one that slid into
    # another minimum is) fits worse than the same model held at a start on the X:
    # min_centre_chi2=0 turns it away.
    pixels, lines = _even_marker_pixels()
    batch = uneven._padded([pixels])
    best = uneven._solve(batch, uneven._start(batch, lines), shadowed=False)
    slid = best.params.copy()
    slid[:, :2] += [0.3, 0.25]
    cost = uneven._residual(slid, batch, shadowed=False)[2]
    ended_off = uneven._Solution(slid, cost, best.covariance, best.solved)
    chi2 = uneven._rejects_start(batch, ended_off, np.zeros(1), np.array([0]))
    assert chi2[0] < 0.0
    assert uneven._rejects_start(batch, best, np.zeros(1), np.array([0]))[0] >= 0.0


def test_a_fit_whose_model_turns_nan_is_left_unsolved_and_the_others_as_if_alone():
    # A model turns NaN where the wedges' trivariate normal meets a correlation of +-1
    # (here: from a start of NaN); the SVD that asked whether its normal matrix
    # inverts raised, and took every X of the call with it.
    pixels, lines = _even_marker_pixels()
    start = uneven._start(uneven._padded([pixels]), lines)
    both = uneven._solve(
        uneven._padded([pixels, pixels]), np.vstack([start, np.full_like(start, np.nan)]), False
    )
    alone = uneven._solve(uneven._padded([pixels]), start, shadowed=False)
    assert both.solved.tolist() == [True, False]
    np.testing.assert_array_equal(both.params[0], alone.params[0])


def test_an_x_beyond_the_frame_border_is_not_located():
    scene = _dull_marker(0, 1.0)
    marker = scene.markers[0]
    fit = uneven.locate_uneven(
        scene.image, np.array([[3.0, 48.0]]), np.array([marker.angles]), np.array([16.0]), 255.0
    )
    assert not fit.located[0]
    np.testing.assert_array_equal(fit.xy, [[3.0, 48.0]])


def test_a_shadows_edge_across_the_x_is_modelled_where_the_blur_acts_on_the_shadowed_scene():
    # Noise-free, the X half in a shadow that keeps half the light, blur 1 px: the
    # blurred X times a blurred half-plane was 0.066 px off; the blurred product
    # leaves the quantisation.
    errors = []
    for seed in range(4):
        rng = np.random.default_rng(seed)
        x, y = 48 + rng.uniform(0, 1), 48 + rng.uniform(0, 1)
        rotation = rng.uniform(0, np.pi)
        normal, offset = rng.uniform(0, 2 * np.pi), rng.uniform(-4, 4)
        scene = render_markers(
            (96, 96),
            [MarkerPlacement(x, y, 16.0, rotation_rad=rotation)],
            seed,
            reflectances=(0.1, 0.8),
            blur_sigma_px=1.0,
            cast_shadows=[CastShadow(x, y, normal, offset, 0.5, 40.0)],
        )
        edges = ShadowEdges(
            np.array([normal]),
            np.array([offset]),
            np.array([np.log(2.0)]),
            np.ones(1),
            np.ones(1),
            np.array([True]),
        )
        marker = scene.markers[0]
        fit = uneven.locate_uneven(
            scene.image, scene.centres, np.array([marker.angles]), np.array([16.0]), 255.0, edges
        )
        errors.append(np.linalg.norm(fit.xy[0] - scene.centres[0]))
    assert max(errors) < 0.015


def _shadowed_dull_marker(seed: int, shadow_depth: float, radius_px: float = 16.0):
    """A tilted X, a dull quadrant, a shadow's edge across it taking ``shadow_depth``."""
    rng = np.random.default_rng(seed)
    x, y = 48 + rng.uniform(0, 1), 48 + rng.uniform(0, 1)
    normal, offset = rng.uniform(0, 2 * np.pi), rng.choice((-1, 1)) * rng.uniform(2, 4)
    scene = render_markers(
        (96, 96),
        [
            MarkerPlacement(
                x, y, radius_px, rotation_rad=rng.uniform(0, np.pi), tilt_deg=30.0, dull_factor=0.7
            )
        ],
        seed,
        reflectances=(0.1, 0.8),
        blur_sigma_px=1.0,
        noise_sigma_dn=2.0,
        cast_shadows=[CastShadow(x, y, normal, offset, shadow_depth, 40.0)] if shadow_depth else [],
    )
    edge = ShadowEdges(
        np.array([normal]),
        np.array([offset]),
        np.array([-np.log(1.0 - max(shadow_depth, 0.5))]),
        np.ones(1),
        np.ones(1),
        np.array([True]),
    )
    return scene, edge


def test_an_edge_described_about_another_point_bounds_the_same_half_plane():
    edge = ShadowEdges(*(np.array([v]) for v in (0.7, 1.5, 0.6, 0.8, 1.0)), np.array([True]))
    origin, to = np.array([[10.0, 20.0]]), np.array([[12.5, 18.0]])
    moved = edge.moved(origin, to)
    points = np.random.default_rng(0).uniform(0, 30, (200, 2))
    normal = np.array([np.cos(0.7), np.sin(0.7)])
    np.testing.assert_array_equal(
        (points - origin) @ normal > edge.offset[0], (points - to) @ normal > moved.offset[0]
    )


def _located_in_shadow(seed: int, shadow_depth: float, radius_px: float = 16.0):
    """:func:`subpixel.locate_in_shadow` from 0.3 px off, sigma 0.5, with the true edge."""
    scene, edge = _shadowed_dull_marker(seed, shadow_depth, radius_px)
    marker = scene.markers[0]
    start = scene.centres + 0.3
    located = subpixel.locate_in_shadow(
        scene.image,
        start,
        np.array([0.5]),
        np.array([marker.angles]),
        np.array([marker.foreshortened_radius_px]),
        255.0,
        edge.moved(scene.centres, start),
    )
    return scene, start, located


@pytest.mark.parametrize(
    "shadow_depth",
    [
        0.5,
        # The edge proposed explains nothing: the model leaves it out and locates
        # the dull X from its four levels.
        0.0,
    ],
    ids=["with the edge", "the shadow not there"],
)
def test_a_marker_found_in_a_shadow_is_located_in_the_frame_by_its_model(shadow_depth):
    # Started 0.3 px off, as the fit on a copy with the shadow divided out may end.
    for seed in range(4):
        scene, _, (xy, sigma, located) = _located_in_shadow(seed, shadow_depth)
        assert located[0]
        assert np.linalg.norm(xy[0] - scene.centres[0]) < 0.05
        assert sigma[0] < 0.5


def test_a_tiny_marker_found_in_a_shadow_keeps_the_centre_it_was_found_at():
    # Under subpixel.MEASURED_MIN_EXTENT_PX the model is not fitted.
    for seed in range(2):
        _, start, (xy, sigma, located) = _located_in_shadow(seed, 0.5, radius_px=5.0)
        assert not located[0]
        np.testing.assert_array_equal(xy, start)
        assert sigma[0] == 0.5


def _soft_shadow_fit(seed: int):
    """A shadowed X's fit from the edge's start, and the cost a bounded solver reaches.

    The shadow's edge is softer than the box allows (10-90 % over 12 px): the model
    holds its penumbra at ln 5 px and reads no slope beyond.
    """
    rng = np.random.default_rng(seed)
    x, y = 48 + rng.uniform(0, 1), 48 + rng.uniform(0, 1)
    normal, offset = rng.uniform(0, 2 * np.pi), rng.uniform(-3, 3)
    scene = render_markers(
        (96, 96),
        [MarkerPlacement(x, y, 16.0, rotation_rad=rng.uniform(0, np.pi), tilt_deg=30.0)],
        seed,
        reflectances=(0.1, 0.8),
        blur_sigma_px=1.0,
        noise_sigma_dn=2.0,
        cast_shadows=[CastShadow(x, y, normal, offset, 0.5, 40.0, penumbra_px=12.0)],
    )
    angles = np.array([scene.markers[0].angles])
    part = uneven._pixels(scene.image, scene.centres[0], 12.8, angles[0], 255.0)
    assert part is not None
    pixels = uneven._padded([part])
    edge = [[normal, offset, np.log(2.0), np.log(uneven.SHADOW_START_PENUMBRA_PX)]]
    start = np.hstack([uneven._start(pixels, angles), edge])
    fit = uneven._solve(pixels, start, shadowed=True)
    best = least_squares(
        lambda p: uneven._model(p[None], pixels, True)[0][0] - pixels.level[0],
        start[0],
        jac=lambda p: uneven._model(p[None], pixels, True)[1][0],
        bounds=uneven._bounds(start.shape[1]),
        x_scale="jac",
    )
    return fit, 2.0 * best.cost


def test_a_shadowed_fit_stays_in_the_models_box_and_reaches_a_bounded_solvers_least_cost():
    # A fit whose penumbra had wandered out of the box, where the model is flat,
    # was left with up to 4 times the least cost after 18 steps.
    lower, upper = uneven._bounds(uneven._GEOMETRY + 4 + uneven._SHADOW_EDGE)
    ratios = []
    for seed in range(6):
        fit, least = _soft_shadow_fit(seed)
        assert np.all((fit.params[0] >= lower) & (fit.params[0] <= upper))
        ratios.append(fit.cost[0] / least)
    assert np.median(ratios) < 1.01
