"""Specification of the Cramer-Rao bound of rendered markers (marker_localizer.synthetic.crlb)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.special import ndtr

from marker_localizer.synthetic import CastShadow, MarkerPlacement, MarkerTruth, render_markers
from marker_localizer.synthetic.crlb import (
    centre_bound,
    crlb_mean_abs_error,
    expected_radial_error,
    fisher_information,
    parameter_information,
)

DARK, BRIGHT = 0.1, 0.8


def edge_information_per_row(blur_px: float, edge_x: float, columns: np.ndarray) -> float:
    """Sum over pixels of (d mu / d edge_x)^2 for a unit step blurred by a Gaussian and
    integrated over each pixel's width: exact, per row, per unit contrast^2."""
    derivative = ndtr((columns + 0.5 - edge_x) / blur_px) - ndtr((columns - 0.5 - edge_x) / blur_px)
    return float(np.sum(derivative**2))


def test_expected_radial_error_is_rayleighs_mean_for_isotropic_and_half_normals_for_a_line():
    assert expected_radial_error(np.diag([4.0, 4.0])) == pytest.approx(2.0 * math.sqrt(math.pi / 2))
    assert expected_radial_error(np.diag([4.0, 0.0])) == pytest.approx(2.0 * math.sqrt(2 / math.pi))


def test_expected_radial_error_matches_the_mean_over_angles_of_the_error_ellipse():
    rotation = np.array([[math.cos(0.7), -math.sin(0.7)], [math.sin(0.7), math.cos(0.7)]])
    covariance = rotation @ np.diag([9.0, 1.0]) @ rotation.T
    # e = rho * (3 cos t, sin t) in the principal frame, rho Rayleigh (mean sqrt(pi/2)).
    angles = np.linspace(0.0, 2.0 * math.pi, 20001)[:-1]
    quadrature = math.sqrt(math.pi / 2) * np.mean(np.hypot(3.0 * np.cos(angles), np.sin(angles)))
    assert expected_radial_error(covariance) == pytest.approx(quadrature, rel=1e-9)


def test_fisher_information_of_a_blurred_straight_edge_is_its_analytic_value():
    blur, contrast, variance, rows = 0.8, 120.0, 6.0, 40
    columns = np.arange(60.0)
    edge_x = 30.3
    profile = ndtr((columns + 0.5 - edge_x) / blur) - ndtr((columns - 0.5 - edge_x) / blur)
    d_mu_dx = np.tile(-contrast * profile, (rows, 1))
    information = fisher_information(
        d_mu_dx,
        np.zeros_like(d_mu_dx),
        np.full(d_mu_dx.shape, variance),
        np.ones(d_mu_dx.shape, bool),
    )
    expected = rows * contrast**2 / variance * edge_information_per_row(blur, edge_x, columns)
    # Continuous limit: J = 1 / (2 sqrt(pi) sigma) per unit length, sigma^2 = blur^2 + 1/12.
    continuous = rows * contrast**2 / variance / (2 * math.sqrt(math.pi * (blur**2 + 1 / 12)))
    assert information[0, 0] == pytest.approx(expected, rel=1e-12)
    assert information[0, 0] == pytest.approx(continuous, rel=0.01)
    assert information[1, 1] == 0.0
    assert crlb_mean_abs_error(information) == math.inf


def rendered_truth(
    marker: MarkerPlacement, size: int, noise: float, blur: float = 1.0
) -> MarkerTruth:
    """The truth of one marker rendered alone on a flat ground, its bound and SNR with it."""
    scene = render_markers(
        (size, size),
        [marker],
        0,
        reflectances=(DARK, BRIGHT),
        blur_sigma_px=blur,
        noise_sigma_dn=noise,
        crlb=True,
    )
    return scene.markers[0]


def crlb_of(
    radius: float = 30.0, noise: float = 2.0, centre: float = 50.0, size: int = 101
) -> float:
    marker = MarkerPlacement(centre, centre, radius, kind="checker")
    return rendered_truth(marker, size, noise).crlb_mean_abs_error_px


def test_bound_of_an_upright_checker_is_that_of_its_straight_edges():
    # The renderer integrates each pixel's area, then blurs the pixel grid with a
    # sampled Gaussian. An edge through the middle of a pixel column moves only
    # that column's area: d mu / dx is the contrast times the sampled Gaussian.
    # Along x the X has its centre line (2r rows, the whole profile) and the outer
    # edges of its dark squares at u = +-1 (2r rows, the profile up to the edge).
    radius, noise = 30.0, 2.0
    contrast = 255 * (BRIGHT - DARK)
    offsets = np.arange(-6.0, 7.0)
    gaussian = np.exp(-0.5 * offsets**2)
    gaussian /= gaussian.sum()
    whole = float(np.sum(gaussian**2))
    up_to_edge = float(np.sum(gaussian[offsets <= 0] ** 2))
    information = contrast**2 / (noise**2 + 1 / 12) * 2 * radius * (whole + up_to_edge)
    # Near the centre crossing and the squares' corners the edges fade: ~ blur / radius.
    assert crlb_of(radius, noise) == pytest.approx(math.sqrt(math.pi / 2 / information), rel=0.05)


def test_bound_scales_with_the_noise_sigma_and_one_over_root_edge_length():
    base = crlb_of(20.0, 2.0, centre=60.5, size=121)
    assert crlb_of(20.0, 4.0, centre=60.5, size=121) == pytest.approx(
        base * math.sqrt((16 + 1 / 12) / (4 + 1 / 12)), rel=1e-6
    )
    assert crlb_of(40.0, 2.0, centre=60.5, size=121) == pytest.approx(base / math.sqrt(2), rel=0.03)


def test_a_parameter_uncorrelated_with_the_centre_costs_it_nothing():
    information = np.diag([4.0, 9.0, 100.0])
    assert centre_bound(information) == pytest.approx(crlb_mean_abs_error(information[:2, :2]))


def test_a_parameter_correlated_with_the_centre_takes_its_share_of_the_information():
    # x's information 4, of which a nuisance with information 2 and cross term 2 takes
    # 2^2 / 2 = 2: x keeps 2 (the Schur complement), y its 9.
    information = np.array([[4.0, 0.0, 2.0], [0.0, 9.0, 0.0], [2.0, 0.0, 2.0]])
    assert centre_bound(information) == pytest.approx(
        expected_radial_error(np.diag([1 / 2.0, 1 / 9.0])), rel=1e-12
    )


def test_a_nuisance_the_pixels_cannot_tell_from_the_centre_leaves_it_unbounded():
    rng = np.random.default_rng(0)
    d_mu_dx, d_mu_dy = rng.normal(size=(2, 8, 8))
    # A parameter that changes the image exactly as moving the marker along x does.
    information = parameter_information(
        [d_mu_dx, d_mu_dy, 3.0 * d_mu_dx], np.ones((8, 8)), np.ones((8, 8), bool)
    )
    assert centre_bound(information) == math.inf


def test_a_parameter_the_pixels_say_nothing_about_is_left_out():
    information = np.diag([4.0, 9.0, 0.0])
    assert centre_bound(information) == pytest.approx(crlb_mean_abs_error(information[:2, :2]))


#: A tilted marker of 20 px, off the pixel grid, for the bounds with the rest unknown.
TILTED = MarkerPlacement(60.3, 59.6, 20.0, rotation_rad=0.4, tilt_deg=35.0)


def truth_with_parts(
    marker: MarkerPlacement = TILTED,
    within: float = 0.8,
    shadows: tuple[CastShadow, ...] = (),
    light: float = 0.0,
) -> MarkerTruth:
    scene = render_markers(
        (121, 121),
        [marker],
        0,
        reflectances=(DARK, BRIGHT),
        blur_sigma_px=1.0,
        illumination_strength=light,
        noise_sigma_dn=2.0,
        cast_shadows=shadows,
        bound_parts_within=within,
    )
    assert scene.markers[0].bound_parts is not None
    return scene.markers[0]


def test_bound_parts_grow_as_less_is_known_and_fewer_pixels_are_read():
    truth = truth_with_parts(within=0.6, light=0.5)
    parts = truth.bound_parts
    assert parts is not None
    assert parts.known == pytest.approx(truth.crlb_mean_abs_error_px, rel=1e-9)
    assert parts.known < parts.affine < parts.projective
    assert parts.affine < parts.inner_affine <= parts.inner_projective
    # Within 0.6 of the radius no arc is read, so the X's scale along its lines is
    # unseen: left out, and the centre still bounded.
    assert math.isfinite(parts.inner_projective)
    # The light's slope and the perspective are odd about the centre, as its shift is:
    # knowing nothing else costs a marker read to its extent a tenth or more.
    assert parts.projective > 1.1 * parts.known


def test_a_dull_quadrant_and_a_cast_shadow_unknown_cost_the_centre_more():
    shadow = CastShadow(60.3, 59.6, normal_rad=1.0, offset_px=4.0, darkening=0.5, reach_px=40.0)
    ratios = []
    for truth in (
        truth_with_parts(),
        truth_with_parts(replace(TILTED, dull_factor=0.6), shadows=(shadow,)),
    ):
        assert truth.bound_parts is not None
        ratios.append(truth.bound_parts.projective / truth.bound_parts.known)
    assert ratios[1] > ratios[0] * 1.05


def x_snr_of(marker: MarkerPlacement, noise: float = 4.0, blur: float = 0.0) -> float:
    return rendered_truth(marker, 81, noise, blur).x_snr


def test_a_sharp_checkers_x_snr_is_half_its_contrast_over_the_noise_summed_over_its_square():
    # Centred on a pixel corner with a whole radius, every pixel of the X's square
    # lies in one quadrant: the X's part is +-contrast / 2 on each of its (2 r)^2.
    radius, noise = 12.0, 4.0
    contrast = 255 * (BRIGHT - DARK)
    expected = contrast / 2 * 2 * radius / math.sqrt(noise**2 + 1 / 12)
    marker = MarkerPlacement(40.5, 40.5, radius, kind="checker")
    assert x_snr_of(marker, noise) == pytest.approx(expected, rel=1e-6)


def test_a_dull_quadrant_leaves_the_x_the_mean_of_the_two_bright_quadrants_leads():
    # The X's part is the quadrants' levels alternated, (q0 - q1 + q2 - q3) / 4: a dull
    # bright quadrant of lead m (of the other's) leaves (1 + m) / 2 of it everywhere.
    plain = MarkerPlacement(40.5, 40.5, 12.0, kind="checker")
    dull = rendered_truth(replace(plain, dull_factor=0.6), 81, 4.0, blur=0.0)
    expected = (1 + dull.dull_margin) / 2
    assert dull.x_snr / x_snr_of(plain) == pytest.approx(expected, rel=1e-6)


def test_the_x_snr_falls_with_the_noise_the_tilt_and_the_blur_the_more_so_for_a_small_x():
    # A tilt shrinks the X's area by cos(tilt), and the SNR, a root of that area, by its
    # root; the blur takes the X's energy along its edges, which hold more of a small X.
    face_on = MarkerPlacement(40.3, 40.6, 14.0, rotation_rad=0.3)
    sharp = x_snr_of(face_on)
    assert x_snr_of(face_on, noise=8.0) == pytest.approx(sharp / 2, rel=0.01)
    assert x_snr_of(replace(face_on, tilt_deg=60.0)) == pytest.approx(
        sharp * math.sqrt(0.5), rel=0.05
    )
    small = replace(face_on, radius_px=4.0)
    lost_large = 1 - x_snr_of(face_on, blur=1.0) / sharp
    lost_small = 1 - x_snr_of(small, blur=1.0) / x_snr_of(small)
    assert 0 < lost_large < lost_small


def test_a_shadow_over_half_the_x_dims_its_half_of_the_x_energy():
    # The light does not turn with the marker: in the half a shadow taking half the
    # light covers, the X is half as strong, its energy a quarter, (1 + 1/4) / 2 in all.
    marker = MarkerPlacement(40.5, 40.5, 12.0, kind="checker")
    half = CastShadow(40.5, 40.5, normal_rad=0.3, offset_px=0.0, darkening=0.5, reach_px=30.0)
    scene = render_markers(
        (81, 81),
        [marker],
        0,
        reflectances=(DARK, BRIGHT),
        noise_sigma_dn=4.0,
        cast_shadows=(half,),
        crlb=True,
    )
    shadowed = scene.markers[0].x_snr
    assert shadowed / x_snr_of(marker) == pytest.approx(math.sqrt((1 + 0.25) / 2), rel=0.02)
