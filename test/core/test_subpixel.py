"""Sections 3.3.1-3.3.2: adaptive template, NCC by matrix product, quadratic extremum,
and the point-symmetry refinement."""

import tracemalloc
from collections.abc import Callable

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

from marker_localizer import Detector, DetectorConfig
from marker_localizer.core import shadow, subpixel, template, verification
from marker_localizer.core.acceptance import MAX_TEMPLATE_MISFIT
from marker_localizer.core.noise import NoiseModel
from marker_localizer.core.result import positions, sigmas
from marker_localizer.synthetic import MarkerPlacement, render_markers
from marker_localizer.synthetic.scene import CastShadow


def test_ncc_surface_by_matrix_product_equals_direct_ncc():
    rng = np.random.default_rng(3)
    image = rng.random((40, 40))
    tmpl = rng.random((1, 7, 7))
    centre = np.array([[20, 18]])
    surface = subpixel.ncc_surface(image, centre, tmpl, search_px=2)
    for j, dy in enumerate(range(-2, 3)):
        for i, dx in enumerate(range(-2, 3)):
            window = image[18 + dy - 3 : 18 + dy + 4, 20 + dx - 3 : 20 + dx + 4]
            a = window - window.mean()
            b = tmpl[0] - tmpl[0].mean()
            direct = (a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum())
            assert surface[0, j, i] == pytest.approx(direct, abs=1e-12)


def test_quadratic_fit_and_extremum_recover_a_known_subpixel_peak():
    peak = np.array([0.31, -0.27])
    grid = np.arange(-1, 2)
    y, x = np.meshgrid(grid, grid, indexing="ij")
    # c(x, y) = -(x - x0)^2 - 2 (y - y0)^2 + 0.5 (x - x0)(y - y0) + 3
    values = (
        -((x - peak[0]) ** 2) - 2 * (y - peak[1]) ** 2 + 0.5 * (x - peak[0]) * (y - peak[1]) + 3
    )[None]
    coefficients = subpixel.fit_quadratic_surface(values, np.ones_like(values))
    np.testing.assert_allclose(subpixel.quadratic_extremum(coefficients)[0], peak, atol=1e-10)


def test_quadratic_extremum_is_nan_for_a_degenerate_surface():
    flat = np.zeros((1, 6))
    assert np.isnan(subpixel.quadratic_extremum(flat)).all()


def test_the_extremum_of_an_exact_quadratic_has_no_uncertainty_and_a_noisy_one_some():
    grid = np.arange(-2, 3)
    y, x = np.meshgrid(grid, grid, indexing="ij")
    exact = (0.9 - 0.05 * (x - 0.2) ** 2 - 0.08 * (y + 0.3) ** 2)[None]
    rng = np.random.default_rng(0)
    noisy = exact + rng.normal(0, 0.005, exact.shape)
    found = subpixel.ncc_subpixel(np.concatenate([exact, noisy]))
    np.testing.assert_allclose(found.offset[0], [0.2, -0.3], atol=1e-9)
    assert found.peak[0] == pytest.approx(exact.max())
    assert found.sigma[0] < 1e-6 < 0.01 < found.sigma[1] < 0.5


def _x_image(
    x: float,
    y: float,
    *,
    blur: float = 1.0,
    gamma: float = 1.0,
    light: float = 0.0,
    noise: float = 0.0,
    seed: int = 0,
) -> np.ndarray:
    scene = render_markers(
        (96, 96),
        [MarkerPlacement(x, y, 24.0, 0.4, 30.0, 1.0, "checker")],
        seed,
        blur_sigma_px=blur,
        gamma=gamma,
        noise_sigma_dn=noise,
        illumination_strength=light,
    )
    return scene, scene.image.astype(np.float64) / 255.0


def test_point_symmetry_refinement_recovers_the_exact_centre_of_a_blurred_tilted_x():
    scene, image = _x_image(47.37, 48.81)
    truth = scene.centres[0]
    fit = subpixel.refine_point_symmetry(image, truth[None] + [0.6, -0.5], np.array([18.0]))
    assert fit.converged[0]
    assert np.linalg.norm(fit.xy[0] - truth) < 0.01


def test_point_symmetry_refinement_absorbs_gamma_and_uneven_light_with_its_gain_term():
    scene, image = _x_image(47.62, 48.13, gamma=0.6, light=0.5, seed=4)
    truth = scene.centres[0]
    start = np.round(truth)[None]
    with_gain = subpixel.refine_point_symmetry(image, start, np.array([18.0]))
    without = subpixel.refine_point_symmetry(image, start, np.array([18.0]), model_gain=False)
    error = np.linalg.norm(with_gain.xy[0] - truth)
    assert error < 0.02
    assert np.linalg.norm(without.xy[0] - truth) > 2 * error


def test_a_fit_started_at_its_own_result_reports_the_same_residual_and_sigma():
    """Tracking starts the fit where the last frame's centre maps, often to 0.001 px."""
    scene, image = _x_image(47.62, 48.13, gamma=0.6, light=0.5, noise=2.0, seed=4)
    radius = np.array([18.0])
    first = subpixel.refine_point_symmetry(image, np.round(scene.centres[0])[None], radius)
    again = subpixel.refine_point_symmetry(image, first.xy, radius)
    assert again.converged[0]
    assert np.linalg.norm(again.xy[0] - first.xy[0]) < 1e-3
    assert again.residual[0] == pytest.approx(first.residual[0], rel=0.01)
    assert np.trace(again.covariance[0]) == pytest.approx(np.trace(first.covariance[0]), rel=0.02)


def test_point_symmetry_covariance_grows_with_noise():
    _, clean = _x_image(47.5, 48.5, noise=1.0)
    _, noisy = _x_image(47.5, 48.5, noise=8.0)
    start = np.array([[47.5, 48.5]])
    quiet = subpixel.refine_point_symmetry(clean, start, np.array([18.0])).covariance[0]
    loud = subpixel.refine_point_symmetry(noisy, start, np.array([18.0])).covariance[0]
    assert np.trace(loud) > 10 * np.trace(quiet)


def test_template_has_the_sampled_levels_in_opposite_sectors():
    angles = np.array([[0.2, 0.2 + np.pi / 2]])
    levels = template.GreyLevels(np.array([0.9]), np.array([0.1]))
    tmpl = template.adaptive_template(angles, levels, np.array([0.3]), half_size=10)[0]
    far = 8.0
    along = 0.2 + np.pi / 4  # a bisector
    p = np.round(10 + far * np.array([np.cos(along), np.sin(along)])).astype(int)
    q = np.round(10 - far * np.array([np.cos(along), np.sin(along)])).astype(int)
    assert tmpl[p[1], p[0]] == pytest.approx(tmpl[q[1], q[0]], abs=0.02)
    assert {round(tmpl[p[1], p[0]], 1), round(tmpl[10 + (10 - p[1]) % 21 - 10, p[0]], 1)} <= {
        0.1,
        0.9,
    }


def test_choose_polarity_picks_the_template_matching_the_patch_in_l1():
    angles = np.array([[0.0, np.pi / 2]])
    levels = template.GreyLevels(np.array([0.9]), np.array([0.1]))
    tmpl = template.adaptive_template(angles, levels, np.array([0.5]), half_size=6)
    inverted = 1.0 - tmpl
    chosen = template.choose_polarity(inverted, tmpl)
    np.testing.assert_allclose(chosen, inverted, atol=1e-12)


def test_template_correlation_is_near_one_on_an_x_and_low_on_an_l_corner():
    scene, image = _x_image(47.4, 48.6, noise=1.0)
    x = scene.markers[0]
    match = template.template_correlation(
        image, scene.centres, np.array([x.angles]), np.array([12.0])
    )
    assert match.ncc[0] > 0.97
    l_scene = render_markers(
        (96, 96), [MarkerPlacement(47.4, 48.6, 24.0, 0.4, kind="l_corner")], 0, blur_sigma_px=1.0
    )
    l_image = l_scene.image.astype(np.float64) / 255.0
    match_l = template.template_correlation(
        l_image, np.array([[47.4, 48.6]]), np.array([[0.4, 0.4 + np.pi / 2]]), np.array([12.0])
    )
    assert match_l.ncc[0] < 0.8


_FOUR_LEVEL_CENTRE = (47.3, 48.6)
_FOUR_LEVEL_ANGLES = np.array([0.3, 1.7])


def _blurred(
    sharp: Callable[[np.ndarray, np.ndarray], np.ndarray],
    angles: np.ndarray,
    noise_dn: float = 0.0,
    seed: int = 0,
) -> np.ndarray:
    """A 96 x 96 image: ``sharp(s1, s2)`` of the signed distances from lines of ``angles``
    through its centre, area-averaged from 8 x 8 sub-pixels, blurred by 1 px, with
    Gaussian noise of ``noise_dn``."""
    fine = (np.arange(96 * 8) + 0.5) / 8 - 0.5
    y, x = np.meshgrid(fine, fine, indexing="ij")
    cx, cy = _FOUR_LEVEL_CENTRE
    s1, s2 = template.line_distances(x - cx, y - cy, angles)
    area = cv2.resize(sharp(s1, s2), (96, 96), interpolation=cv2.INTER_AREA)
    image = cv2.GaussianBlur(area, (0, 0), 1.0)
    return image + np.random.default_rng(seed).normal(0.0, noise_dn, image.shape)


def _blurred_match(
    sharp: Callable[[np.ndarray, np.ndarray], np.ndarray], angles: np.ndarray, disk_px: float
) -> float:
    """The template match at the centre of :func:`_blurred` (no noise)."""
    match = template.template_correlation(
        _blurred(sharp, angles), np.array([_FOUR_LEVEL_CENTRE]), angles[None], np.array([disk_px])
    )
    return float(match.ncc[0])


def _four_level_match(levels: list[float]) -> float:
    """The template match at the centre of a blurred X with a grey level per quadrant,
    in the order (s1 > 0, s2 > 0), (s1 > 0, s2 < 0), (s1 < 0, s2 < 0), (s1 < 0, s2 > 0)."""

    def sharp(s1: np.ndarray, s2: np.ndarray) -> np.ndarray:
        quadrant = np.where(s1 > 0, np.where(s2 > 0, 0, 1), np.where(s2 < 0, 2, 3))
        return np.asarray(levels)[quadrant]

    return _blurred_match(sharp, _FOUR_LEVEL_ANGLES, 12.0)


@pytest.mark.parametrize(
    "levels", [[0.9, 0.1, 0.45, 0.1], [0.1, 0.9, 0.1, 0.45]], ids=["dull", "dull-inverted"]
)
def test_a_dull_bright_quadrant_keeps_the_template_match_of_a_perfect_x(levels):
    # The paper's two-level template matches this X at 0.85; a level per bright
    # quadrant restores the match (0.993).
    assert _four_level_match(levels) > 0.98


def test_a_bright_quadrant_as_dark_as_the_dark_ones_is_no_dull_x():
    # One bright quadrant of three dark ones (an L corner) would fit the template
    # with its bright pair split at 0.98; the duller must stand above the dark pair.
    assert _four_level_match([0.9, 0.1, 0.05, 0.1]) < 0.6


def test_dark_quadrants_that_differ_still_lower_the_template_match():
    # Texture saddles' dark gaps differ as their stones do; black paint does not.
    assert _four_level_match([0.9, 0.1, 0.9, 0.5]) < 0.92


@pytest.mark.parametrize("kind", ["checker", "quarter_disks"])
def test_the_papers_template_ncc_locates_a_blurred_tilted_x_to_a_few_hundredths(kind):
    truth = np.array([[48.37, 47.71]])
    scene = render_markers(
        (96, 96),
        [MarkerPlacement(*truth[0], 20.0, 0.4, 30.0, 1.0, kind)],
        0,
        blur_sigma_px=1.0,
        noise_sigma_dn=1.0,
    )
    angles = np.array([scene.markers[0].angles])
    start = truth + [[0.8, -0.6]]
    found = subpixel.ncc_refine(
        scene.image, start, np.array([20.0]), angles, offset_px=5.0, search_px=2
    )
    assert np.linalg.norm(found.offset[0] - truth[0]) < 0.03
    assert found.peak[0] > 0.9


def test_sigma_is_the_calibrated_radial_deviation_of_the_covariance():
    covariance = np.array([[[0.01, 0.002], [0.002, 0.03]], [[-1.0, 0.0], [0.0, 0.0]]])
    np.testing.assert_allclose(
        subpixel.calibrated_sigma(covariance), [subpixel.SIGMA_CALIBRATION * 0.2, 0.0]
    )
    # Another estimate's distance from the fit adds in quadrature, uncalibrated.
    with_ncc = subpixel.calibrated_sigma(covariance[:1], np.array([0.09]))
    np.testing.assert_allclose(with_ncc, np.hypot(subpixel.SIGMA_CALIBRATION * 0.2, 0.3))


def test_ncc_gates_locate_finite_extrema_and_match_peaks_from_the_threshold():
    peak = subpixel.NccPeak(
        offset=np.array([[0.1, 0.2], [np.nan, 0.0], [0.1, 0.1], [0.0, 0.0]]),
        peak=np.array([0.99, 0.99, subpixel.NCC_PEAK_MIN - 1e-6, subpixel.NCC_PEAK_MIN]),
        sigma=np.array([0.01, 0.01, 0.01, 0.01]),
    )
    located, matched = subpixel.ncc_gates(peak)
    assert located.tolist() == [True, False, True, True]
    assert matched.tolist() == [True, False, False, True]


def _blurred_x(centre: tuple[float, float], radius: float = 12.0) -> np.ndarray:
    scene = render_markers(
        (96, 96),
        [MarkerPlacement(*centre, radius, 0.4, 0.0, 0.7)],
        2,
        blur_sigma_px=1.0,
        noise_sigma_dn=1.0,
    )
    return scene.image


def test_the_coarse_centring_moves_a_candidate_onto_its_x_within_reach_only():
    image = _blurred_x((48.3, 47.6))
    start = np.array([[49.0, 47.0], [60.0, 60.0]])
    centres, inside = subpixel.coarse_centre(image, start, np.array([8.0, 2.0]), 40.0)
    assert inside.tolist() == [True, False]
    assert np.linalg.norm(centres[0] - [48.3, 47.6]) < 0.3


def _locate_x_near(image: np.ndarray, min_contrast: float) -> subpixel.MarkerLocation:
    """The final fit started 0.3 px off the X of :func:`_blurred_x`, evidence 0.9."""
    return subpixel.locate_markers(
        image,
        np.array([[48.5, 47.4]]),
        np.array([12.0]),
        np.array([[0.4, 0.4 + np.pi / 2]]),
        np.array([0.9]),
        max_radius_px=40.0,
        iterations=12,
        min_contrast=min_contrast,
        max_symmetry_residual=0.1,
    )


def test_located_markers_sit_on_the_centre_with_a_score_below_their_evidence():
    location = _locate_x_near(_blurred_x((48.3, 47.6)), min_contrast=10.0)
    assert location.accepted.tolist() == [True]
    assert np.linalg.norm(location.xy[0] - [48.3, 47.6]) < 0.05
    assert 0.8 < location.score[0] < 0.9
    assert 0.0 < location.sigma[0] < 0.05


def test_a_marker_fainter_than_the_contrast_floor_is_not_accepted():
    location = _locate_x_near(_blurred_x((48.3, 47.6)), min_contrast=255.0)
    assert location.accepted.tolist() == [False]


def _large_noisy_x(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(image, truth): an untilted 30 px checker X at 4 DN of noise, lines at 0.3 and 0.3 + pi/2."""
    rng = np.random.default_rng(seed)
    x, y = 48.0 + rng.uniform(-0.5, 0.5, 2)
    scene = render_markers(
        (96, 96),
        [MarkerPlacement(x, y, 30.0, 0.3, 0.0, 0.0, "checker")],
        seed,
        blur_sigma_px=1.0,
        noise_sigma_dn=4.0,
    )
    return scene.image, scene.centres[0]


def _gated_and_refitted(
    image: np.ndarray,
    truth: np.ndarray,
    radius_px: float,
    angles: np.ndarray,
    max_radius_px: float,
    max_symmetry_residual: float,
) -> tuple[subpixel.MarkerLocation, np.ndarray, np.ndarray]:
    """The gating fit from the pixel nearest ``truth``, and the line fit from its centre.

    Returns:
        (the gating fit, the line fit's (1, 2) centre, its (1,) sigma).
    """
    radius = np.array([radius_px])
    gating = subpixel.locate_markers(
        image,
        np.round(truth)[None],
        radius,
        angles,
        np.array([0.9]),
        max_radius_px=max_radius_px,
        iterations=12,
        min_contrast=10.0,
        max_symmetry_residual=max_symmetry_residual,
    )
    refit, sigma, _ = subpixel.refine_along_lines(
        image,
        gating.xy,
        gating.sigma,
        radius,
        angles,
        full_scale=255.0,
        max_radius_px=max_radius_px,
    )
    return gating, refit, sigma


def test_the_line_weighted_refit_is_more_precise_than_the_gating_fit_on_large_markers():
    angles = np.array([[0.3, 0.3 + np.pi / 2]])
    gating_error, refit_error = [], []
    for seed in range(16):
        image, truth = _large_noisy_x(seed)
        gating, refit, sigma = _gated_and_refitted(image, truth, 30.0, angles, 40.0, 0.1)
        gating_error.append(np.linalg.norm(gating.xy[0] - truth))
        refit_error.append(np.linalg.norm(refit[0] - truth))
        assert 0.0 < sigma[0] < 0.1
    # Its half-pixel grid and its weight on the edges: a third of the error here
    # (0.008 against 0.022 px).
    assert np.mean(refit_error) < 0.6 * np.mean(gating_error)


def test_a_tiny_marker_is_located_within_one_and_a_half_times_its_cramer_rao_bound():
    # On a disk of 3.6 px the light's slope would cost more than it corrects
    # (1.7x the bound with it).
    errors, bounds = [], []
    for seed in range(16):
        rng = np.random.default_rng(seed)
        placement = MarkerPlacement(
            32 + rng.random(), 32 + rng.random(), 4.0, rng.uniform(0, np.pi), 30.0, 0.3, "checker"
        )
        scene = render_markers(
            (64, 64), [placement], seed, blur_sigma_px=0.8, noise_sigma_dn=3.0, crlb=True
        )
        truth, angles = scene.centres[0], np.array([scene.markers[0].angles])
        _, refit, _ = _gated_and_refitted(scene.image, truth, 4.0, angles, 10.0, 0.2)
        errors.append(np.linalg.norm(refit[0] - truth))
        bounds.append(scene.crlb_px[0])
    assert np.mean(errors) < 1.5 * np.mean(bounds)


def test_a_line_weighted_refit_that_slips_from_the_gating_centre_keeps_it():
    image, truth = _large_noisy_x(0)
    start = truth[None] + [[0.8, 0.0]]
    sigma = np.array([0.2])
    xy, kept, _ = subpixel.refine_along_lines(
        image,
        start,
        sigma,
        np.array([30.0]),
        np.array([[0.3, 0.3 + np.pi / 2]]),
        max_radius_px=40.0,
        full_scale=255.0,
    )
    np.testing.assert_array_equal(xy, start)
    np.testing.assert_array_equal(kept, sigma)


def _dull_x(
    seed: int,
    dull_factor: float,
    *,
    blur: float = 1.0,
    tilt_deg: float = 20.0,
    radius_px: float = 16.0,
    noise_dn: float = 1.0,
    contrast: tuple[float, float] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    placement = MarkerPlacement(
        48 + rng.random(),
        48 + rng.random(),
        radius_px,
        rng.uniform(0, np.pi),
        tilt_deg,
        0.3,
        "quarter_disks",
        dull_factor=dull_factor,
    )
    scene = render_markers(
        (96, 96),
        [placement],
        seed,
        contrast=contrast,
        blur_sigma_px=blur,
        noise_sigma_dn=noise_dn,
    )
    return scene.image, scene.centres[0], np.array([scene.markers[0].angles])


def _gate_and_refit(image, truth, angles, *, start=(0.3, -0.2), gating_px=12.0, extent_px=13.0):
    """The gating fit from ``start`` off a dull X (16 px by default), and the line fit after."""
    gating = subpixel.refine_point_symmetry(image, truth[None] + start, np.array([gating_px]))
    refit, _, _ = subpixel.refine_along_lines(
        image,
        gating.xy,
        np.array([0.1]),
        np.array([extent_px]),
        angles,
        full_scale=255.0,
        max_radius_px=30.0,
    )
    return gating.xy[0], refit[0]


@pytest.mark.parametrize("dull_factor", [0.5, 0.7])
def test_the_line_weighted_refit_gives_a_dull_quadrant_its_own_level(dull_factor):
    # Grey-level symmetry pulls the centre towards the brighter side; the quadrants'
    # own levels, fitted where they differ, put it back.
    gating_error, refit_error = [], []
    for seed in range(6):
        image, truth, angles = _dull_x(seed, dull_factor)
        gating, refit = _gate_and_refit(image, truth, angles)
        gating_error.append(np.linalg.norm(gating - truth))
        refit_error.append(np.linalg.norm(refit - truth))
    assert np.mean(gating_error) > 0.15
    assert np.mean(refit_error) < 0.03


@pytest.mark.parametrize("dull_factor", [0.5, 0.7])
def test_the_quadrants_own_levels_lie_on_the_lines_found_from_the_edges(dull_factor):
    # The ring check's directions are a few degrees off; levels stepping along them
    # put the centre 0.1-0.2 px off. The refit measures the directions again.
    refit_error = []
    for seed in range(6):
        image, truth, angles = _dull_x(seed, dull_factor)
        gating = subpixel.refine_point_symmetry(image, truth[None] + [0.3, -0.2], np.array([12.0]))
        for off_deg in ([3.0, -3.0], [-4.0, 2.0]):
            refit, _, _ = subpixel.refine_along_lines(
                image,
                gating.xy,
                np.array([0.1]),
                np.array([13.0]),
                angles + np.radians(off_deg),
                max_radius_px=30.0,
                full_scale=255.0,
            )
            refit_error.append(np.linalg.norm(refit[0] - truth))
    assert np.mean(refit_error) < 0.04


def test_a_slightly_dull_quadrant_gets_its_own_level_in_the_line_fit():
    # A bright quadrant 0.975 as bright scores 45-130: the refit gives it its level
    # (the symmetric fit leaves it 0.0075 px off on average).
    refit_error = []
    for seed in range(6):
        image, truth, angles = _dull_x(seed, 0.975)
        refit_error.append(np.linalg.norm(_gate_and_refit(image, truth, angles)[1] - truth))
    assert np.mean(refit_error) < 0.005


def test_the_levels_fit_is_weighed_in_by_the_share_of_the_difference_that_is_bias():
    # Covariance traces 0.001 and 0.004 px^2: the difference's variance is at most
    # (c (0.032 + 0.063))^2 = 0.009 c^2 px^2, c the fits' sigma calibration. Centres
    # 0.3 px apart: 1 - 0.1 c^2 of it is bias; 0.09 c px apart, within the noise's
    # reach: none. A levels' fit that did not converge weighs nothing.
    calibration = subpixel.LINE_FIT_SIGMA_CALIBRATION**2

    def levelled(shift, converged=True):
        return subpixel._SymmetrySolution(
            np.array([[10.0 + shift, 5.0]]),
            np.diag([0.002, 0.002])[None],
            np.zeros(1),
            np.array([np.nan]),
            np.array([converged]),
            np.array([np.nan]),
            np.array([np.nan]),
        )

    centre, covariance = np.array([[10.0, 5.0]]), np.diag([0.0005, 0.0005])[None]
    moved, spread, weight = subpixel._blended_with_levels(centre, covariance, levelled(0.3))
    share = 1.0 - 0.1 * calibration
    assert 0.0 < share < 1.0
    assert weight[0] == pytest.approx(share)
    np.testing.assert_allclose(moved, [[10.0 + 0.3 * share, 5.0]])
    np.testing.assert_allclose(spread[0], (0.0005 + share**2 * 0.0015) * np.eye(2))
    for shift, converged in ((0.09 * subpixel.LINE_FIT_SIGMA_CALIBRATION, True), (0.3, False)):
        moved, _, weight = subpixel._blended_with_levels(
            centre, covariance, levelled(shift, converged)
        )
        assert weight[0] == 0.0
        np.testing.assert_array_equal(moved, centre)


def _small_dull_x_refit(
    seed: int, dull_factor: float, noise_dn: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(truth, gating, refit): a dull X of 8 px of contrast 0.3, gated from 0.22 px off."""
    image, truth, angles = _dull_x(
        seed, dull_factor, radius_px=8.0, noise_dn=noise_dn, contrast=(0.3, 0.3)
    )
    gating, refit = _gate_and_refit(
        image, truth, angles, start=(0.2, -0.1), gating_px=6.4, extent_px=6.4
    )
    return truth, gating, refit


def _small_dull_x_error(dull_factor: float, noise_dn: float = 5.0) -> float:
    """Mean error of the line fit over 12 small dull X's (:func:`_small_dull_x_refit`), px."""
    errors = []
    for seed in range(12):
        truth, _, refit = _small_dull_x_refit(seed, dull_factor, noise_dn)
        errors.append(np.linalg.norm(refit - truth))
    return float(np.mean(errors))


def test_an_x_whose_rings_stop_short_is_read_out_to_its_reach(monkeypatch):
    # The small dull X's rings stop at 6.4 px of its 8; its lines reach on (the
    # modulation across them takes no notice of the dull quadrant), and the fit read
    # that far locates it better: 0.110 -> 0.088 px over these 12.
    read_to_reach = _small_dull_x_error(0.93)
    monkeypatch.setattr(subpixel, "REACH_MAX_GAIN", 1.0)
    read_to_extent = _small_dull_x_error(0.93)
    assert read_to_reach < 0.9 * read_to_extent


def _steep_x_error(seed: int) -> float:
    """The line fit's error on a 14 px X tilted 60 degrees at 3 DN, from 0.18 px off, px."""
    rng = np.random.default_rng(seed)
    placement = MarkerPlacement(
        48 + rng.random(),
        48 + rng.random(),
        14.0,
        rng.uniform(0, np.pi),
        60.0,
        rng.uniform(0, np.pi),
        "quarter_disks",
    )
    scene = render_markers((96, 96), [placement], seed, blur_sigma_px=1.0, noise_sigma_dn=3.0)
    truth, angles = scene.centres[0], np.array([scene.markers[0].angles])
    refit, _, _ = subpixel.refine_along_lines(
        scene.image,
        truth[None] + np.array([0.15, -0.1]),
        np.array([0.1]),
        np.array([7.0]),
        angles,
        full_scale=255.0,
        max_radius_px=20.0,
    )
    return float(np.linalg.norm(refit[0] - truth))


def test_a_steeply_tilted_x_is_read_along_its_lines_out_to_its_ellipse(monkeypatch):
    # Tilted 60 degrees, the X's ends lie on an ellipse of semi-axes 14 and 7 px: the
    # disk of the smaller one leaves out the edges its lines run on past 7 px
    # (0.021 -> 0.016 px over these 12).
    read_to_ellipse = np.mean([_steep_x_error(seed) for seed in range(12)])
    monkeypatch.setattr(subpixel, "_HALF_PIXEL_MAX_RADIUS_PX", 0.0)
    read_to_disk = np.mean([_steep_x_error(seed) for seed in range(12)])
    assert read_to_ellipse < 0.85 * read_to_disk


def test_a_noisy_faintly_dull_x_moves_by_the_bias_its_levels_show(monkeypatch):
    # An X of 8 px at 5 DN whose bright quadrant is 0.93 as bright as the other scores
    # mostly under the refit's threshold: where its statistic passes the chi-square's
    # 0.1 % point, the symmetric fit's centre moves towards the levels' fit by the share
    # of their difference that is bias (0.126 -> 0.110 px over these 12). On even
    # paint the difference is the noise's, and the centre stays where it was. Read at
    # the rings' extent (6.4 px): read out to its reach, this X's statistic clears
    # the refit's threshold or stays under the blend's.
    monkeypatch.setattr(subpixel, "REACH_MAX_GAIN", 1.0)
    assert subpixel.LEVELS_BLEND_MIN_CHI2 < subpixel.LEVELS_REFIT_MIN_CHI2
    blended = {factor: _small_dull_x_error(factor) for factor in (0.93, 1.0)}
    monkeypatch.setattr(subpixel, "LEVELS_BLEND_MIN_CHI2", np.inf)
    symmetric = {factor: _small_dull_x_error(factor) for factor in (0.93, 1.0)}
    assert blended[0.93] < 0.92 * symmetric[0.93]
    assert blended[1.0] == pytest.approx(symmetric[1.0], rel=0.02)


def _shadowed_x(seed: int, noise_dn: float, darkening: float):
    """An X of 16 px of even paint, a cast shadow's straight edge within 0.4 radii of its centre."""
    rng = np.random.default_rng(seed)
    x, y = 48 + rng.random(), 48 + rng.random()
    placement = MarkerPlacement(x, y, 16.0, rng.uniform(0, np.pi), 20.0, 0.3, "quarter_disks")
    cast = CastShadow(x, y, rng.uniform(0, 2 * np.pi), rng.uniform(-6.4, 6.4), darkening, 32.0)
    scene = render_markers(
        (96, 96),
        [placement],
        seed,
        blur_sigma_px=1.0,
        noise_sigma_dn=noise_dn,
        cast_shadows=[cast],
    )
    return scene.image, scene.centres[0], np.array([scene.markers[0].angles])


def _shadowed_x_error(noise_dn: float, darkening: float, off_deg=(0.0, 0.0)) -> float:
    """Mean error of the line fit over 8 shadowed X's (:func:`_shadowed_x`), the lines'
    directions given ``off_deg`` off, px."""
    errors = []
    for seed in range(8):
        image, truth, angles = _shadowed_x(seed, noise_dn, darkening)
        _, refit = _gate_and_refit(image, truth, angles + np.radians(off_deg))
        errors.append(np.linalg.norm(refit - truth))
    return float(np.mean(errors))


def test_an_xs_model_tries_the_shadows_edge_its_pairs_alone_would_turn_away(monkeypatch):
    # In 6 DN of noise a shadow taking 40 % of the light explains under half of the
    # pairs' variance on some of these X's; their model tries the edge that fits best
    # and keeps it where it explains (uneven.SHADOW_MIN_CHI2): 0.100 -> 0.038 px.
    tried = _shadowed_x_error(6.0, 0.4)
    find_edges = shadow.find_edges
    monkeypatch.setattr(shadow, "find_edges", lambda *args, **_: find_edges(*args))
    assert tried < 0.6 * _shadowed_x_error(6.0, 0.4)


def test_a_shadows_edge_the_levels_miss_is_located_by_the_model_that_rejects_the_line_fit(
    monkeypatch,
):
    # At 6 DN, a shadow taking half the light leaves some of these X's under the
    # levels' statistic, and the symmetric fit is pulled. Where the pairs show the
    # edge, the model is fitted, and its centre taken where it rejects the line fit's
    # (subpixel.MODEL_MIN_CENTRE_CHI2): 0.040 -> 0.027 px over these 8.
    modelled = _shadowed_x_error(6.0, 0.5)
    monkeypatch.setattr(subpixel, "MODEL_MIN_CENTRE_CHI2", np.inf)
    assert modelled < 0.8 * _shadowed_x_error(6.0, 0.5)


def test_an_x_is_read_along_the_lines_its_edges_show_not_its_rings(monkeypatch):
    # Along directions 6-7 degrees off, the lines' band holds the wrong pairs and the
    # quadrants' levels' statistic barely sees the shadow across the X: 0.048 px (0.023
    # since the model also runs in the blend's range), and 0.010 along the directions
    # measured from the edges.
    measured = _shadowed_x_error(2.0, 0.5, (7.0, -6.0))
    assert measured < 0.05
    monkeypatch.setattr(subpixel, "_measured_directions", lambda *args: args[3])
    assert measured < 0.6 * _shadowed_x_error(2.0, 0.5, (7.0, -6.0))


def _line_directions_read(image, truth, angles, extent_px):
    """The directions :func:`subpixel.refine_along_lines` reports for an X at ``truth``."""
    return subpixel.refine_along_lines(
        image,
        truth[None],
        np.array([0.1]),
        np.array([extent_px]),
        angles,
        full_scale=255.0,
        max_radius_px=30.0,
    )[2][0]


def test_the_line_fit_reports_the_directions_its_edges_show_not_its_rings():
    for seed in range(4):
        image, truth, angles = _dull_x(seed, 1.0)
        read = _line_directions_read(image, truth, angles + np.radians([7.0, -6.0]), 13.0)
        off = np.abs((read - angles[0] + np.pi / 2) % np.pi - np.pi / 2)
        assert np.degrees(off).max() < 1.0
        assert ((read >= 0.0) & (read < np.pi)).all()


def test_a_tiny_x_reports_the_directions_it_was_given():
    # Under MEASURED_MIN_EXTENT_PX the edges' directions are the worse (family (b)).
    image, truth, angles = _dull_x(0, 1.0)
    given = np.mod(angles + np.radians([7.0, -6.0]), np.pi)
    read = _line_directions_read(image, truth, given, subpixel.MEASURED_MIN_EXTENT_PX - 1.0)
    np.testing.assert_allclose(read, given[0])


def test_a_symmetric_fit_that_slipped_is_not_weighed_in_with_the_levels(monkeypatch):
    # At 8 DN with a bright quadrant 0.8 as bright (seed 6): the symmetric fit slips more
    # than half a pixel from the gating fit's centre, and that centre stays (0.21 px
    # off), where weighed in with the levels it would be 0.63 px off (read, as then,
    # at the rings' extent).
    monkeypatch.setattr(subpixel, "REACH_MAX_GAIN", 1.0)
    _, gating, refit = _small_dull_x_refit(6, 0.8, 8.0)
    np.testing.assert_array_equal(refit, gating)


def test_the_quadrant_level_statistic_follows_the_noise_where_the_quadrants_match():
    # Near a chi-square of 2 degrees of freedom on an even X (1-15 here: the model's
    # own errors add to the noise's), far above the line fit's threshold on a dull one.
    def statistic(image, centre, angles):
        band = subpixel._line_band(12.0, angles)
        fit = subpixel._gauss_newton_symmetry(
            image, centre[None], *band[:4], 10, 1e-3, True, 0.0, True, test_steps=band.steps()
        )
        return fit.step_chi2[0]

    even = [statistic(*_dull_x(seed, 1.0)) for seed in range(12)]
    dull = [statistic(*_dull_x(seed, 0.7)) for seed in range(12)]
    assert max(even) < subpixel.LEVELS_REFIT_MIN_CHI2
    assert min(dull) > subpixel.LEVELS_REFIT_MIN_CHI2


def _gate(image, start, angles, extent_px=13.0, max_symmetry_residual=0.1):
    return subpixel.locate_markers(
        image,
        start[None],
        np.array([extent_px]),
        angles,
        np.array([1.0]),
        max_radius_px=30.0,
        iterations=10,
        min_contrast=1.0,
        max_symmetry_residual=max_symmetry_residual,
    )


@pytest.mark.parametrize("dull_factor", [0.45, 0.6])
def test_the_gating_fit_judges_a_dull_quadrant_as_it_judges_even_paint(dull_factor):
    # A bright quadrant 0.45 as bright as its opposite leaves a grey-level symmetry
    # residual over a tenth of the contrast, which rejects it; the residual the
    # quadrants' own levels leave is that of even paint.
    for seed in range(4):
        image, truth, angles = _dull_x(seed, dull_factor)
        even_image, even_truth, even_angles = _dull_x(seed, 1.0)
        dull = _gate(image, truth + [0.3, -0.2], angles)
        even = _gate(even_image, even_truth + [0.3, -0.2], even_angles)
        assert dull.accepted[0]
        assert dull.score[0] > even.score[0] - 0.01


def test_the_quadrants_own_levels_judge_only_an_x_they_leave_as_clean_as_even_paint():
    # Noise the levels cannot explain: past subpixel.LEVELLED_MAX_RESIDUAL the plain
    # residual judges, levels or not.
    image, truth, angles = _dull_x(0, 0.5)
    noisy = image + np.random.default_rng(1).normal(0.0, 25.0, image.shape)
    start = truth + [0.3, -0.2]
    fit = subpixel.refine_point_symmetry(
        noisy, start[None], np.array([0.9 * 13.0]), max_shift_px=1.5, line_angles=angles
    )
    assert fit.step_chi2[0] > subpixel.LEVELLED_MIN_CHI2
    assert fit.levelled_residual[0] > subpixel.LEVELLED_MAX_RESIDUAL * fit.contrast[0]
    gate = _gate(noisy, start, angles)
    assert gate.score[0] == pytest.approx(1.0 - fit.residual[0] / fit.contrast[0])


def _grey_dark_quadrant(seed, lift):
    """An even X of 16 px with one dark quadrant ``lift`` of the contrast greyer, as a
    texture saddle's gaps differ; and its centre and lines."""
    image, truth, angles = _dull_x(seed, 1.0)
    rows, cols = np.mgrid[: image.shape[0], : image.shape[1]].astype(float)
    s1, s2 = template.line_distances(cols - truth[0], rows - truth[1], angles[0])
    e1, e2 = template.edge_step(s1, 1.0), template.edge_step(s2, 1.0)
    quadrants = [(1 + a * e1) * (1 + b * e2) / 4 for a in (1, -1) for b in (1, -1)]
    dark = min(quadrants, key=lambda q: (q * image).sum() / q.sum())
    inside = np.hypot(cols - truth[0], rows - truth[1]) < 14.0
    contrast = np.percentile(image[inside], 90) - np.percentile(image[inside], 10)
    return image + lift * contrast * dark * inside, truth, angles


def test_the_gating_fit_gives_the_bright_pair_its_own_level_not_the_dark_pair():
    # Black paint stays black: a dark quadrant greyer than its opposite is not read
    # as paint, and the plain residual, which the grey quadrant raises, scores it.
    for seed in range(3):
        image, truth, angles = _grey_dark_quadrant(seed, 0.4)
        start = truth + [0.3, -0.2]
        fit = subpixel.refine_point_symmetry(
            image, start[None], np.array([0.9 * 13.0]), max_shift_px=1.5, line_angles=angles
        )
        gate = _gate(image, start, angles)
        even = _gate(*_dull_x(seed, 1.0)[:1], start, angles)
        assert fit.step_chi2[0] < subpixel.LEVELLED_MIN_CHI2
        assert gate.score[0] == pytest.approx(1.0 - fit.residual[0] / fit.contrast[0])
        assert gate.score[0] < even.score[0] - 0.05


def test_an_x_of_textures_size_is_scored_by_its_plain_residual():
    # Under verification.X_END_MAX_EXTENT_PX the bright pair's level does not judge:
    # texture saddles that small reach their floors with a level of their own.
    image, truth, angles = _dull_x(0, 0.5)
    start = truth + [0.3, -0.2]
    extent = verification.X_END_MAX_EXTENT_PX - 0.5
    fit = subpixel.refine_point_symmetry(
        image, start[None], np.array([0.9 * extent]), max_shift_px=1.5, line_angles=angles
    )
    small = _gate(image, start, angles, extent, max_symmetry_residual=1.0)
    assert fit.step_chi2[0] > subpixel.LEVELLED_MIN_CHI2
    assert fit.levelled_residual[0] < fit.residual[0] / 2
    assert small.score[0] == pytest.approx(1.0 - fit.residual[0] / fit.contrast[0])


def _four_xs(seed, dull_factor=1.0):
    """Four large X's of 20 px, blur 1.2 px, noise-free; and their bounds at 3 DN of noise."""
    rng = np.random.default_rng(seed)
    placements = [
        MarkerPlacement(
            40 + 80 * i + rng.random(),
            40 + 80 * j + rng.random(),
            20.0,
            rng.uniform(0, np.pi),
            20.0,
            0.3,
            "quarter_disks",
            dull_factor=dull_factor,
        )
        for i in range(2)
        for j in range(2)
    ]
    clean = render_markers((160, 160), placements, seed, blur_sigma_px=1.2, noise_sigma_dn=0.0)
    bounds = render_markers(
        (160, 160), placements, seed, blur_sigma_px=1.2, noise_sigma_dn=3.0, crlb=True
    ).crlb_px
    return clean, np.array([m.angles for m in clean.markers]), bounds


def _linear_light(slope):
    y, x = np.mgrid[:160, :160]
    return 1.0 + slope[0] * (x - 80.0) + slope[1] * (y - 80.0)


def test_the_quadrants_insides_give_the_light_slope_and_tell_levels_of_their_own():
    clean, angles, _ = _four_xs(0)
    slope = np.array([2e-3, -1e-3])
    inside = subpixel._light_inside(clean.image * _linear_light(slope), clean.centres, 18.0, angles)
    # Relative to the light at each centre.
    local = slope[None] / (1.0 + (clean.centres - 80.0) @ slope)[:, None]
    off = np.linalg.norm(inside.slope - local, axis=1) / np.linalg.norm(local, axis=1)
    assert off.max() < 0.3

    rng = np.random.default_rng(1)
    even = subpixel._light_inside(
        clean.image + rng.normal(0.0, 2.0, clean.image.shape), clean.centres, 18.0, angles
    )
    dull, _, _ = _four_xs(0, dull_factor=0.8)
    uneven = subpixel._light_inside(
        dull.image + rng.normal(0.0, 2.0, clean.image.shape), clean.centres, 18.0, angles
    )
    assert even.level_chi2.max() < subpixel.LEVELS_REFIT_MIN_CHI2
    assert uneven.level_chi2.min() > 10 * subpixel.LEVELS_REFIT_MIN_CHI2


def test_the_light_slope_from_the_insides_costs_the_centre_little():
    # Fitted from the pairs along the lines alone, the slope takes a share of what
    # they say of the centre: 1.94x the bound here.
    clean, angles, bounds = _four_xs(0)
    light = _linear_light([2e-3, -1e-3])
    rng = np.random.default_rng(1)
    errors = []
    for _ in range(40):
        image = clean.image * light + rng.normal(0.0, 3.0, light.shape)
        start = clean.centres + rng.normal(0.0, 0.05, clean.centres.shape)
        xy, _, _ = subpixel.refine_along_lines(
            image,
            start,
            np.full(4, 0.1),
            np.full(4, 20.0),
            angles,
            full_scale=255.0,
            max_radius_px=40.0,
        )
        errors.append(np.linalg.norm(xy - clean.centres, axis=1))
    assert np.mean(errors) < 1.75 * np.mean(bounds)


@pytest.mark.parametrize("blur", [0.6, 1.4])
def test_the_quadrants_own_levels_step_with_the_blur_that_fits(blur):
    # With steps of 1 px the level of a dull quadrant bleeds into the centre: 0.02 px
    # off at a blur of 0.6 px, 0.08 px at 1.4 px.
    picked, errors = [], []
    for seed in range(8):
        image, truth, angles = _dull_x(seed, 0.6, blur=blur, tilt_deg=30.0)
        band = subpixel._line_band(0.9 * 13.0, angles)
        picked.append(subpixel._step_blur(image, truth[None], band, True)[0])
        errors.append(np.linalg.norm(_gate_and_refit(image, truth, angles)[1] - truth))
    assert np.median(picked) == pytest.approx(blur, abs=0.21)
    assert np.mean(errors) < 0.015


def test_the_blurred_x_at_right_angles_is_the_product_of_its_two_edge_steps():
    rng = np.random.default_rng(5)
    s1, s2 = rng.normal(0.0, 3.0, (2, 4, 50))
    blur = np.array([[0.6], [1.0], [1.6], [2.5]])
    np.testing.assert_allclose(
        template.blurred_x(s1, s2, blur, 0.0),
        template.edge_step(s1, blur) * template.edge_step(s2, blur),
        atol=1e-12,
    )


@pytest.mark.parametrize("crossing_deg", [25.0, 50.0, 130.0])
def test_the_blurred_x_at_any_angle_is_the_mean_of_the_sharp_x_under_the_blur(crossing_deg):
    # The sharp X is +1 where both signed distances share a sign; the blur moves the
    # point by a Gaussian of the optics' and the pixel's variance.
    angles = np.array([0.4, 0.4 + np.deg2rad(crossing_deg)])
    blur = 1.2
    width = np.sqrt(blur**2 + template.PIXEL_VARIANCE_PX2)
    rng = np.random.default_rng(6)
    shift = rng.normal(0.0, width, (400_000, 2))
    points = np.array([[0.0, 0.0], [0.7, -0.4], [-1.5, 1.1], [2.5, 0.3], [0.2, 3.0]])
    s1, s2 = template.line_distances(points[:, :1], points[:, 1:], angles[None])
    model = template.blurred_x(s1.T, s2.T, blur, np.cos(angles[0] - angles[1]))[0]
    for point, expected in zip(points, model, strict=True):
        d1, d2 = template.line_distances(point[0] + shift[:, 0], point[1] + shift[:, 1], angles)
        assert np.sign(d1 * d2).mean() == pytest.approx(expected, abs=0.005)


def _crossing_match(kind: str, crossing_deg: float, disk_px: float) -> float:
    """The template match at the centre of a blurred X, or of a smooth saddle with the
    same zero lines, whose lines cross at ``crossing_deg``."""

    def sharp(s1: np.ndarray, s2: np.ndarray) -> np.ndarray:
        if kind == "x":
            return np.where(s1 * s2 > 0, 0.9, 0.1)
        return np.clip(0.5 + 0.02 * s1 * s2, 0, 1)

    return _blurred_match(sharp, _crossing(crossing_deg), disk_px)


def _crossing(crossing_deg: float) -> np.ndarray:
    return np.array([0.3, 0.3 + np.deg2rad(crossing_deg)])


def _x_sharp(contrast: float) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    return lambda s1, s2: np.where(s1 * s2 > 0, 60.0 + contrast, 60.0)


@pytest.mark.parametrize("crossing_deg", [35.0, 50.0, 70.0])
def test_a_small_x_whose_lines_cross_at_any_angle_matches_its_template(crossing_deg):
    # The product of two steps matched the X of 35 degrees at 0.93 over this disk.
    assert _crossing_match("x", crossing_deg, 3.0) > 0.995


@pytest.mark.parametrize("disk_px", [3.0, 6.0])
def test_a_smooth_saddle_matches_the_template_of_an_x_with_its_zero_lines_less_well(disk_px):
    # Ground texture between stones is a quadratic surface near its saddle; the
    # product of two steps matched one whose zero lines are 50 degrees apart at 0.98-1.
    assert _crossing_match("saddle", 50.0, disk_px) < 0.93


def _misfit(image: np.ndarray, angles: np.ndarray, disk_px: float, noise_dn: float) -> float:
    noise = NoiseModel(max(noise_dn, 0.3) ** 2, 0.0, 0.3)
    centre, disk = np.array([_FOUR_LEVEL_CENTRE]), np.array([disk_px])
    ncc = template.template_correlation(image, centre, angles[None], disk).ncc
    return float(template.template_misfit(image, centre, angles[None], disk, ncc, noise)[0])


@pytest.mark.parametrize("contrast", [10.0, 20.0, 60.0, 160.0])
def test_an_x_leaves_only_its_noise_unexplained_however_faint(contrast):
    # At 10 DN under 3 DN of noise the X leaves 0.22 of the disk's variance
    # unexplained (1 - NCC^2), all of it the noise's.
    angles = _crossing(80.0)
    images = [_blurred(_x_sharp(contrast), angles, 3.0, seed) for seed in range(8)]
    misfits = [_misfit(image, angles, 4.8, 3.0) for image in images]
    assert abs(np.mean(misfits)) < 0.015
    assert max(misfits) < MAX_TEMPLATE_MISFIT / 2


@pytest.mark.parametrize("disk_px", [3.0, 4.8])
def test_a_smooth_saddle_leaves_more_unexplained_than_an_x_may(disk_px):
    # Ground texture between stones is a quadratic surface near its saddle: the X
    # with its zero lines explains it only in part, and noise accounts for none of it.
    angles = _crossing(50.0)
    saddle = _blurred(lambda s1, s2: np.clip(0.5 + 0.02 * s1 * s2, 0, 1) * 255.0, angles)
    assert _misfit(saddle, angles, disk_px, 0.0) > MAX_TEMPLATE_MISFIT


def test_the_model_is_fitted_to_at_most_max_modelled_xs_and_the_rest_are_counted():
    placements = [
        MarkerPlacement(48.3 + 96 * k, 47.6, 16.0, rotation_rad=0.3 + 0.2 * k, dull_factor=0.5)
        for k in range(3)
    ]
    scene = render_markers((96, 288), placements, 1, blur_sigma_px=1.0, noise_sigma_dn=1.0)
    angles = np.array([m.angles for m in scene.markers])

    def refit(max_modelled: int) -> tuple[np.ndarray, dict[str, int]]:
        tally: dict[str, int] = {}
        xy, _, _ = subpixel.refine_along_lines(
            scene.image,
            scene.centres + [0.3, -0.2],
            np.full(3, 0.1),
            np.full(3, 13.0),
            angles,
            max_radius_px=30.0,
            full_scale=255.0,
            max_modelled=max_modelled,
            tally=tally,
        )
        return xy, tally

    every, none_over = refit(3)
    capped, over = refit(1)
    assert none_over.get("uneven_over_cap", 0) == 0
    assert over["uneven_over_cap"] == 2
    # One X keeps its model's centre; the two over the cap keep the levels' fit's.
    same = np.all(np.isclose(every, capped, atol=1e-9), axis=1)
    assert same.sum() == 1


def test_the_line_band_takes_pairs_tied_at_its_edge_in_the_disk_order():
    # Lines along the pixel grid: many pairs of the half disk lie as near them as the
    # last the band has room for. It takes the nearest, of those tied at its edge the
    # first in the disk's order, and keeps them in that order, which the fit's sums
    # follow: the same pairs summed alike on every build of numpy.
    radius = 13.0
    disk, _ = subpixel.symmetric_offsets(radius, subpixel._LINE_FIT_MAX_SAMPLES)
    lines = np.array([[0.0, np.pi / 2]])
    band = subpixel._line_band(radius, lines)
    s1, s2 = template.line_distances(disk[:, 0], disk[:, 1], lines)
    distance = np.minimum(np.abs(s1), np.abs(s2))[0]
    room = len(band.offsets[0])
    edge = np.sort(distance)[room - 1]
    nearer, at_edge = np.flatnonzero(distance < edge), np.flatnonzero(distance == edge)
    assert len(nearer) + len(at_edge) > room  # the tie straddles the band's edge
    taken = np.sort(np.r_[nearer, at_edge[: room - len(nearer)]])
    np.testing.assert_array_equal(band.offsets[0], disk[taken])


def _kept_by_the_model_cap(statistic: np.ndarray, tested: np.ndarray, max_modelled: int):
    """The queued X's the model's cap keeps, and its tally, on a flat frame.

    A flat frame shows no cast shadow's edge: the X's ``tested`` for one are not asked.
    """
    count = len(statistic)
    tally: dict[str, int] = {}
    kept = subpixel._asked_of_the_model(
        np.full((64, 64), 128.0),
        np.full((count, 2), 32.0),
        np.tile([0.3, 1.9], (count, 1)),
        np.full(count, 10.0),
        statistic,
        tested,
        255.0,
        max_modelled,
        tally,
    )
    return kept, tally


def test_the_model_cap_keeps_tied_xs_in_the_order_they_were_queued():
    # Forty X's in four runs of ten, two runs tied at the lowest statistic: the cap
    # keeps the highest, and of the tie those queued first, whatever order a sort
    # would leave equal keys in.
    statistic = np.repeat([40.0, 20.0, 30.0, 20.0], 10)
    kept, tally = _kept_by_the_model_cap(statistic, np.zeros(40, dtype=bool), 25)
    np.testing.assert_array_equal(kept, [*range(15), *range(20, 30)])
    assert tally["uneven_over_cap"] == 15


def test_the_model_cap_fills_with_xs_without_a_statistic_before_it_counts_one_over():
    # X's 0-9 were tested for a shadow's edge and show none: they are not asked.
    # Of the thirty asked, ten have a statistic and twenty none (NaN): those ten
    # come first, then those without one in queue order, up to the cap.
    statistic = np.concatenate([np.full(20, 50.0), np.full(20, np.nan)])
    statistic[10:20] = np.arange(10.0)
    tested = np.arange(40) < 10
    kept, tally = _kept_by_the_model_cap(statistic, tested, 25)
    np.testing.assert_array_equal(kept, np.arange(10, 35))
    assert tally["uneven_over_cap"] == 5


def _thresholded_markers(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A noise-free frame of 15 blurred X's (8-24 px), thresholded at mid-grey; their centres."""
    rng = np.random.default_rng(seed)
    placements = [
        MarkerPlacement(
            70 + 130 * (i % 5) + rng.uniform(-10, 10),
            70 + 130 * (i // 5) + rng.uniform(-10, 10),
            rng.uniform(8.0, 24.0),
            rng.uniform(0, np.pi),
            rng.uniform(0, 40),
            rng.uniform(0, np.pi),
        )
        for i in range(15)
    ]
    scene = render_markers((400, 660), placements, seed, blur_sigma_px=rng.uniform(0.6, 1.4))
    threshold = 0.5 * (float(scene.image.min()) + float(scene.image.max()))
    binary = np.where(scene.image > threshold, 255, 0).astype(np.uint8)
    return binary, np.array([[m.x, m.y] for m in scene.markers])


@pytest.mark.parametrize("as_float", [False, True], ids=["uint8", "float"])
def test_sigma_on_a_thresholded_frame_covers_the_rounding_of_its_edges(as_float):
    """A 1-bit frame has no noise to measure: its error is the edges' rounding, which
    sigma must carry (a residual floor of the frame's grey step), or a pose estimator
    weighs such points hundreds of times too high."""
    detector = Detector(DetectorConfig(marker_radius_min_px=6.0, marker_radius_max_px=30.0))
    normalised = []
    for seed in range(4):
        binary, centres = _thresholded_markers(seed)
        image = binary.astype(np.float32) / 255.0 if as_float else binary
        result = detector.detect(image)
        distance, index = cKDTree(positions(result)).query(centres, distance_upper_bound=2.0)
        found = np.isfinite(distance)
        normalised += (distance[found] / sigmas(result)[index[found]]).tolist()
    assert len(normalised) >= 20
    assert np.mean(np.less_equal(normalised, 2.0)) >= 0.85
    assert max(normalised) < 5.0


def test_the_memory_the_line_directions_take_does_not_grow_with_the_number_of_xs():
    """Each X held some ten arrays of its 2 x 10 100 samples at once: 1.1 GiB for the
    652 X's of one extent on a 12 MP frame of chessboards under flare."""
    image = render_markers((200, 200), [MarkerPlacement(100.3, 100.6, 40.0, 0.4)], 1).image

    def peak_mib(count: int) -> float:
        centres = np.tile([[100.3, 100.6]], (count, 1))
        angles = np.tile([[0.4, 0.4 + np.pi / 2]], (count, 1))
        tracemalloc.start()
        try:
            directions = subpixel._edge_directions(image, centres, 36.0, angles, 255.0)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert np.ptp(directions, axis=0).max() == 0.0  # the same X, the same answer
        return peak / 2**20

    assert peak_mib(512) < 1.5 * peak_mib(64)
