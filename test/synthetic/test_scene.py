"""Specification of the ground-truth renderer (marker_localizer.synthetic).

Coordinates: x right, y down, (0, 0) at the centre of the top-left pixel.
"""

from __future__ import annotations

import dataclasses
import logging
import math

import cv2
import numpy as np
import pytest

from marker_localizer.synthetic import (
    NEGATIVE_KINDS,
    PATTERNS,
    TEXTURE_NAMES,
    CastShadow,
    ImagingConditions,
    MarkerPlacement,
    PlanarTarget,
    SceneConfig,
    apply_imaging,
    composite_target,
    load_texture,
    marker_homography,
    motion_blur_kernel,
    project,
    render_checkerboard,
    render_markers,
    render_scene,
    texture_background,
)
from marker_localizer.synthetic.scene import (
    MAX_ILLUMINATION_STRENGTH,
    illumination_field,
    shadow_field,
)
from marker_localizer.synthetic.textures import periodic_component

DARK, BRIGHT = 0.1, 0.9
SMALL_SCENE = SceneConfig(
    width=320, height=240, n_markers=3, radius_px=(6.0, 20.0), n_hard_negatives=5
)


def symmetry_residual(
    image: np.ndarray,
    centre: tuple[float, float],
    radius: float,
    interpolation: int = cv2.INTER_LINEAR,
) -> float:
    """Mean |I - I rotated 180 degrees about centre| over a disk, in DN."""
    cx, cy = centre
    rotation = np.array([[-1.0, 0.0, 2 * cx], [0.0, -1.0, 2 * cy]])
    image = image.astype(np.float32)
    rotated = cv2.warpAffine(image, rotation, image.shape[::-1], flags=interpolation)
    rows, cols = np.mgrid[: image.shape[0], : image.shape[1]]
    disk = np.hypot(cols - cx, rows - cy) <= radius
    return float(np.abs(image - rotated)[disk].mean())


def plate_radius(truth) -> float:
    """Largest distance from a marker's centre to its plate corners, px."""
    corners = project(truth.homography, 1.25 * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]))
    return float(np.max(np.hypot(corners[:, 0] - truth.x, corners[:, 1] - truth.y)))


# ----------------------------------------------------------------- exact geometry


@pytest.mark.parametrize("kind", ["quarter_disks", "checker"])
def test_sharp_marker_at_half_integer_centre_is_exactly_point_symmetric_about_truth(kind):
    # 2 * centre is integral, so the 180-degree rotation permutes pixels: no interpolation.
    centre = (40.5, 41.0)
    scene = render_markers(
        (83, 81),
        [MarkerPlacement(*centre, 20.0, rotation_rad=0.3, kind=kind)],
        0,
        reflectances=(DARK, BRIGHT),
    )
    assert symmetry_residual(scene.image, centre, 22.0) < 0.05
    assert symmetry_residual(scene.image, (40.75, 41.0), 22.0) > 3.0
    assert symmetry_residual(scene.image, (40.5, 41.25), 22.0) > 3.0


@pytest.mark.parametrize("centre", [(40.25, 40.75), (40.5, 40.25), (39.8, 40.3)])
def test_marker_at_quarter_position_is_point_symmetric_about_truth_not_a_quarter_pixel_off(centre):
    # A little blur makes cubic interpolation of the rotated image accurate.
    scene = render_markers(
        (81, 81),
        [MarkerPlacement(*centre, 20.0, rotation_rad=0.3)],
        0,
        reflectances=(DARK, BRIGHT),
        blur_sigma_px=1.0,
    )
    at_truth = symmetry_residual(scene.image, centre, 22.0, cv2.INTER_CUBIC)
    assert at_truth < 1.0
    for dx, dy in [(0.25, 0.0), (0.0, 0.25), (-0.25, 0.0), (0.0, -0.25)]:
        shifted = (centre[0] + dx, centre[1] + dy)
        assert symmetry_residual(scene.image, shifted, 22.0, cv2.INTER_CUBIC) > 4 * at_truth


@pytest.mark.parametrize("edge_x", [50.1, 50.3, 50.45, 50.5, 50.77])
def test_pixel_straddling_a_straight_edge_holds_the_exact_area_fraction(edge_x):
    # Untilted quarter disks: the u = 0 edge is the vertical line x = edge_x. Row 40
    # lies above the centre (v < 0): dark to the left (quadrant 3), bright to the right.
    supersampling = 16
    scene = render_markers(
        (101, 101),
        [MarkerPlacement(edge_x, 50.7, 30.0)],
        0,
        reflectances=(DARK, BRIGHT),
        supersampling=supersampling,
    )
    column = round(edge_x)
    dark_area = min(max(edge_x - (column - 0.5), 0.0), 1.0)
    measured = (BRIGHT - scene.image[40, column] / 255.0) / (BRIGHT - DARK)
    rounding = 0.5 / 255.0 / (BRIGHT - DARK)
    assert abs(measured - dark_area) <= 1.0 / supersampling + rounding
    # The horizontal edge v = 0 at y = 50.7: row 51 has 0.2 of its area above it.
    left_of_centre = (BRIGHT - scene.image[51, 30] / 255.0) / (BRIGHT - DARK)
    assert abs(left_of_centre - 0.2) <= 1.0 / supersampling + rounding


def test_uniform_pixels_shortcut_equals_full_supersampling_for_every_pattern():
    rng = np.random.default_rng(3)
    for i, (name, pattern) in enumerate(PATTERNS.items()):
        placement = MarkerPlacement(
            30 + rng.uniform(-1, 1),
            30 + rng.uniform(-1, 1),
            rng.uniform(4, 18),
            rng.uniform(0, 6),
            rng.uniform(0, 70),
            rng.uniform(0, 3),
            name,
        )
        target = PlanarTarget(marker_homography(placement), pattern, DARK, BRIGHT, i % 2 == 0)
        fast = np.full((61, 61), 0.45, np.float32)
        exhaustive = fast.copy()
        composite_target(fast, target, 8)
        composite_target(exhaustive, target, 8, exhaustive=True)
        np.testing.assert_array_equal(fast, exhaustive, err_msg=name)


def test_truth_centre_is_the_homography_image_of_the_plane_origin():
    scene = render_scene(SMALL_SCENE, 11)
    assert len(scene.markers) == 3
    for truth in scene.markers:
        image_of_origin = truth.homography @ [0.0, 0.0, 1.0]
        assert image_of_origin[0] / image_of_origin[2] == truth.x
        assert image_of_origin[1] / image_of_origin[2] == truth.y
    np.testing.assert_array_equal(scene.centres, [(m.x, m.y) for m in scene.markers])


def test_tilted_marker_homography_has_true_perspective_and_exact_centre():
    placement = MarkerPlacement(
        123.456, 78.9, 40.0, rotation_rad=0.2, tilt_deg=60.0, tilt_axis_rad=0.7
    )
    h = marker_homography(placement)
    assert tuple(h @ [0.0, 0.0, 1.0]) == (123.456, 78.9, 1.0)
    assert np.hypot(h[2, 0], h[2, 1]) > 1e-3  # not affine
    # Foreshortening: the image direction across the tilt axis shrinks to ~cos(60) = 0.5.
    # The plane directions that land along / across it are rotated back by the in-plane 0.2.
    axis = np.array([math.cos(0.7 - 0.2), math.sin(0.7 - 0.2)])
    perpendicular = np.array([-axis[1], axis[0]])
    along = project(h, np.array([axis, -axis]))
    across = project(h, np.array([perpendicular, -perpendicular]))
    assert np.linalg.norm(along[0] - along[1]) / 80.0 == pytest.approx(1.0, abs=0.01)
    assert np.linalg.norm(across[0] - across[1]) / 80.0 == pytest.approx(0.5, abs=0.02)


def test_truth_angles_are_the_image_directions_of_the_plane_axes():
    rotation = 0.4
    scene = render_markers((60, 60), [MarkerPlacement(30.0, 30.0, 10.0, rotation_rad=rotation)], 0)
    assert scene.markers[0].angles == pytest.approx((rotation, rotation + math.pi / 2))
    tilted = render_markers((60, 60), [MarkerPlacement(30.0, 30.0, 10.0, 2.0, 50.0, 1.0)], 0)
    truth = tilted.markers[0]
    for angle, axis in zip(truth.angles, ([1e-6, 0.0], [0.0, 1e-6]), strict=True):
        end = project(truth.homography, np.array([axis]))[0]
        assert math.atan2(end[1] - truth.y, end[0] - truth.x) % math.pi == pytest.approx(angle)


@pytest.mark.parametrize(("tilt_deg", "foreshortening"), [(0.0, 1.0), (60.0, 0.5)])
def test_foreshortened_radius_is_the_radius_times_cos_tilt(tilt_deg, foreshortening):
    scene = render_markers((80, 80), [MarkerPlacement(40.0, 40.0, 12.0, 0.3, tilt_deg, 1.1)], 0)
    truth = scene.markers[0]
    assert truth.foreshortened_radius_px == pytest.approx(12.0 * foreshortening, rel=0.02)


def test_inverted_marker_swaps_dark_and_bright_paint():
    placements = [
        MarkerPlacement(20.0, 20.0, 12.0),
        MarkerPlacement(60.0, 20.0, 12.0, inverted=True),
    ]
    image = render_markers((40, 80), placements, 0, reflectances=(DARK, BRIGHT)).image
    # Quadrant 1 (u > 0, v > 0) is down-right of the centre; the plate border is at 1.1 radii.
    assert image[25, 25] == round(255 * DARK) and image[25, 65] == round(255 * BRIGHT)
    assert image[20 + 13, 20] == round(255 * BRIGHT) and image[20 + 13, 60] == round(255 * DARK)


# ----------------------------------------------------------------- checkerboard


def test_checkerboard_truth_has_100_corners_that_are_point_symmetric_centres():
    square = 24.0
    scene = render_checkerboard(
        (400, 440),
        (10, 10),
        square,
        rotation_rad=0.15,
        background="flat",
        blur_sigma_px=1.0,
        noise_sigma_dn=0.0,
        seed=1,
    )
    assert len(scene.markers) == 100
    corners = scene.centres
    spacing = np.linalg.norm(np.diff(corners[:10], axis=0), axis=1)
    np.testing.assert_allclose(spacing, square, rtol=1e-9)
    residuals = [
        symmetry_residual(scene.image, (x, y), 0.8 * square, cv2.INTER_CUBIC)
        for x, y in corners[::7]
    ]
    shifted = [
        symmetry_residual(scene.image, (x + 0.25, y), 0.8 * square, cv2.INTER_CUBIC)
        for x, y in corners[::7]
    ]
    assert max(residuals) < 1.0
    assert min(shifted) > 4 * max(residuals)


def test_checkerboard_under_perspective_keeps_corners_on_the_board_homography():
    scene = render_checkerboard(
        (480, 640), (10, 10), 20.0, tilt_deg=40.0, tilt_axis_rad=0.3, seed=2
    )
    board = scene.markers[0].homography @ np.array([[1, 0, 4.5], [0, 1, 4.5], [0, 0, 1.0]])
    grid = np.array([(k - 4.5, m - 4.5) for m in range(10) for k in range(10)])
    np.testing.assert_allclose(scene.centres, project(board, grid), atol=1e-9)
    assert scene.image.shape == (480, 640)


def test_checkerboard_too_big_for_the_frame_raises():
    with pytest.raises(ValueError, match="does not fit"):
        render_checkerboard((100, 100), (10, 10), 20.0)


# ----------------------------------------------------------------- scenes


def test_render_scene_returns_uint8_frame_of_the_requested_shape():
    scene = render_scene(
        SceneConfig(width=333, height=211, n_markers=2, radius_px=(6.0, 15.0), n_hard_negatives=3),
        0,
    )
    assert scene.image.dtype == np.uint8
    assert scene.image.shape == (211, 333)


def test_rendering_is_deterministic_for_a_seed():
    first, again = render_scene(SMALL_SCENE, 7), render_scene(SMALL_SCENE, 7)
    np.testing.assert_array_equal(first.image, again.image)
    np.testing.assert_array_equal(first.centres, again.centres)
    assert first.negatives == again.negatives
    other = render_scene(SMALL_SCENE, 8)
    assert not np.array_equal(first.image, other.image)


def test_markers_overlap_neither_each_other_nor_the_frame_border():
    config = SceneConfig(
        width=480,
        height=360,
        n_markers=25,
        radius_px=(6.0, 25.0),
        n_hard_negatives=0,
        background="flat",
    )
    scene = render_scene(config, 5)
    radii = np.array([plate_radius(m) for m in scene.markers])
    centres = scene.centres
    assert np.all(centres - radii[:, None] >= -0.5)
    assert np.all(centres + radii[:, None] <= (config.width - 0.5, config.height - 0.5))
    distance = np.hypot(*(centres[:, None, :] - centres[None, :, :]).transpose(2, 0, 1))
    clearance = distance - radii[:, None] - radii[None, :]
    np.fill_diagonal(clearance, np.inf)
    assert clearance.min() > 0


def test_hard_negatives_are_drawn_clear_of_the_markers():
    marker = MarkerPlacement(100.0, 100.0, 20.0)
    scene = render_markers(
        (200, 300), [marker], 0, n_hard_negatives=8, negative_radius_px=(6.0, 15.0)
    )
    assert len(scene.negatives) == 8
    assert {kind for kind, _, _ in scene.negatives} <= set(NEGATIVE_KINDS)
    marker_reach = plate_radius(scene.markers[0])
    for _, x, y in scene.negatives:
        assert math.hypot(x - 100.0, y - 100.0) > marker_reach
    # They are painted: the frame is no longer flat away from the marker.
    away = np.hypot(*np.mgrid[:200, :300][::-1] - np.array([100, 100])[:, None, None]) > 40
    assert np.count_nonzero(scene.image[away] != round(255 * 0.45)) > 100


def test_hard_negatives_that_do_not_fit_are_counted_in_a_logged_warning_not_on_stdout(
    caplog, capsys
):
    """A benchmark's tables are its stdout: the count goes to the log (stderr), not among them."""
    marker = MarkerPlacement(100.0, 100.0, 20.0)
    with caplog.at_level(logging.WARNING, logger="marker_localizer.synthetic.scene"):
        scene = render_markers(
            (200, 300), [marker], 0, n_hard_negatives=200, negative_radius_px=(6.0, 15.0)
        )
    assert capsys.readouterr().out == ""
    [record] = caplog.records
    assert record.levelno == logging.WARNING
    assert record.getMessage() == (
        f"placed only {len(scene.negatives)} of 200 hard negatives in a 300x200 frame"
    )


def test_default_scene_holds_many_kinds_of_hard_negatives():
    config = SceneConfig(
        width=640, height=480, n_markers=4, radius_px=(6.0, 20.0), n_hard_negatives=20
    )
    scene = render_scene(config, 3)
    assert len(scene.negatives) == 20
    assert len({kind for kind, _, _ in scene.negatives}) >= 5


def test_more_markers_than_fit_raise_a_clear_value_error():
    config = SceneConfig(width=200, height=200, n_markers=40, radius_px=(30.0, 40.0))
    with pytest.raises(ValueError, match=r"could not place marker \d+ of 40"):
        render_scene(config, 0)


@pytest.mark.parametrize(
    "bad",
    [
        {"radius_px": (40.0, 6.0)},
        {"max_tilt_deg": 85.0},
        {"marker_kinds": ("circle",)},
        {"background": "sky"},
        {"n_markers": -1},
        {"illumination_strength": 2.0},
    ],
)
def test_bad_configuration_values_raise_value_error_naming_the_field(bad):
    name = next(iter(bad))
    with pytest.raises(ValueError, match=name):
        SceneConfig(**bad)


# ----------------------------------------------------------------- imaging chain


def test_read_noise_std_in_a_flat_region_matches_the_requested_sigma():
    scene = render_markers((200, 200), [], 0, noise_sigma_dn=3.0)
    # Rounding to integers adds a variance of 1/12 DN^2.
    assert scene.image.std() == pytest.approx(math.sqrt(9.0 + 1 / 12), rel=0.03)
    assert scene.image.mean() == pytest.approx(255 * 0.45, abs=0.1)


def test_shot_noise_grows_with_the_signal_as_poisson_predicts():
    full_well = 2000.0
    for level in (0.2, 0.7):
        image = render_markers(
            (200, 200), [], 1, background_level=level, shot_noise_gain_dn=255 / full_well
        ).image
        expected = 255 * math.sqrt(level / full_well)
        assert image.std() == pytest.approx(math.sqrt(expected**2 + 1 / 12), rel=0.04)


def test_gamma_encodes_radiance_as_radiance_to_the_power_one_over_gamma():
    frame = apply_imaging(
        np.full((4, 4), 0.25, np.float32), ImagingConditions(gamma=2.0), np.random.default_rng(0)
    )
    assert np.all(frame == round(255 * 0.5))


@pytest.mark.parametrize(("length", "angle"), [(1.0, 0.0), (3.7, 0.6), (8.0, 2.0)])
def test_motion_blur_kernel_is_normalised_centred_and_as_long_as_asked(length, angle):
    kernel = motion_blur_kernel(length, angle)
    size = kernel.shape[0]
    assert kernel.shape == (size, size) and size % 2 == 1
    assert kernel.sum() == pytest.approx(1.0, abs=1e-6)
    np.testing.assert_array_equal(kernel, kernel[::-1, ::-1])
    offsets = np.arange(size) - size // 2
    dy, dx = np.meshgrid(offsets, offsets, indexing="ij")
    along = dx * math.cos(angle) + dy * math.sin(angle)
    # A uniform segment of length L has variance L^2 / 12; bilinear splatting adds
    # f * (1 - f) <= 1/4 for a sample at fractional offset f.
    variance = float((kernel * along**2).sum())
    assert length**2 / 12 <= variance + 1e-6 <= length**2 / 12 + 1 / 4


def test_light_fields_are_smooth_gains_in_their_documented_ranges():
    rng = np.random.default_rng(0)
    light = illumination_field((120, 160), 1.0, rng)
    assert light.min() >= 0.5 - 1e-6 and light.max() <= 1.0 + 1e-6
    assert light.max() - light.min() > 0.2
    assert np.abs(np.diff(light, axis=1)).max() < 0.05
    shadows = shadow_field((240, 320), 3, rng)
    assert shadows.min() >= 0.4**3 - 1e-6 and shadows.max() <= 1.0 + 1e-6
    assert shadows.min() < 0.75


def test_the_strongest_light_spans_up_to_ten_to_one_as_the_independent_clutter_frames_do():
    # The independent renderer's clutter frames: light 6-20 to 1 across a frame.
    gains = [
        illumination_field((120, 160), MAX_ILLUMINATION_STRENGTH, np.random.default_rng(seed))
        for seed in range(8)
    ]
    assert min(g.min() for g in gains) >= 1.0 - MAX_ILLUMINATION_STRENGTH / 2 - 1e-6
    assert max(g.max() for g in gains) <= 1.0 + 1e-6
    spans = sorted(float(g.max() / g.min()) for g in gains)
    assert spans[0] > 3.0 and spans[-1] > 9.0
    with pytest.raises(ValueError, match="illumination_strength"):
        SceneConfig(illumination_strength=MAX_ILLUMINATION_STRENGTH + 0.05)


def test_uniform_light_leaves_the_scene_untouched():
    scene = render_markers(
        (50, 50),
        [MarkerPlacement(25.0, 25.0, 10.0)],
        0,
        reflectances=(DARK, BRIGHT),
        illumination_strength=0.0,
    )
    assert scene.image[25 + 4, 25 + 4] == round(255 * DARK)


# ----------------------------------------------------------------- textures


def test_every_texture_loads_offline_as_a_grayscale_image():
    for name in TEXTURE_NAMES:
        texture = load_texture(name)
        assert texture.ndim == 2 and texture.dtype == np.float32
        assert 0.0 <= texture.min() < texture.max() <= 1.0


def test_texture_background_is_cluttered_reflectance_of_any_size():
    for shape in [(37, 53), (240, 320)]:
        ground = texture_background(shape, np.random.default_rng(4))
        assert ground.shape == shape and ground.dtype == np.float32
        assert ground.min() > 0.0 and ground.max() < 1.0
    assert ground.std() > 0.02
    assert np.abs(np.diff(ground, axis=1)).mean() > 0.005  # texture, not a smooth ramp


def test_the_periodic_component_repeats_without_a_seam_and_keeps_the_detail():
    rows, cols = np.mgrid[:96, :128]
    # Ground on a ramp: repeated as it is, it jumps by the ramp at every join.
    image = texture_background((96, 128), np.random.default_rng(2)) + 0.004 * cols + 0.002 * rows
    periodic = periodic_component(image)
    assert periodic.shape == image.shape and periodic.dtype == np.float32
    across = np.abs(np.diff(periodic, axis=1)).mean()
    down = np.abs(np.diff(periodic, axis=0)).mean()
    assert np.abs(image[:, 0] - image[:, -1]).mean() > 2.0 * across
    assert np.abs(periodic[:, 0] - periodic[:, -1]).mean() < 1.5 * across
    assert np.abs(periodic[0] - periodic[-1]).mean() < 1.5 * down
    # What it takes away is smooth, harmonic inside the borders, and the mean stays.
    smooth = image.astype(np.float64) - periodic
    laplacian = smooth[:-2, 1:-1] + smooth[2:, 1:-1] + smooth[1:-1, :-2] + smooth[1:-1, 2:]
    assert np.abs(laplacian - 4.0 * smooth[1:-1, 1:-1]).max() < 1e-5
    assert periodic.mean() == pytest.approx(image.mean(), abs=1e-5)


def test_texture_scene_keeps_truth_exact_on_clutter():
    scene = render_markers(
        (120, 120),
        [MarkerPlacement(60.5, 60.0, 25.0, rotation_rad=0.5)],
        2,
        background="texture",
        reflectances=(DARK, BRIGHT),
    )
    # Inside the plate the ground is hidden: still exactly point-symmetric.
    assert symmetry_residual(scene.image, (60.5, 60.0), 28.0) < 0.05


# ----------------------------------------------------------------- field conditions


@pytest.mark.parametrize("inverted", [False, True])
def test_a_dull_quadrant_scales_one_bright_quadrant_and_nothing_else(inverted):
    dark, bright = (BRIGHT, DARK) if inverted else (DARK, BRIGHT)
    marker = MarkerPlacement(
        40.0, 40.0, 20.0, kind="checker", inverted=inverted, dull_factor=0.5, dull_quadrant=0
    )
    image = render_markers((81, 81), [marker], 0, reflectances=(DARK, BRIGHT)).image
    dull = (30, 50) if not inverted else (50, 50)  # (x, y) of quadrant 0: u < 0 < v
    other = (50, 30) if not inverted else (30, 30)  # the other bright quadrant
    lit = max(dark, bright)
    assert image[dull[1], dull[0]] == round(255 * 0.5 * lit)
    assert image[other[1], other[0]] == round(255 * lit)
    # The plate outside the X keeps its paint.
    assert image[40 + 23, 40 - 23] == round(255 * bright)


@pytest.mark.parametrize("inverted", [False, True])
def test_the_truth_says_how_far_a_dull_quadrant_stands_above_the_dark_paint(inverted):
    def margin(dull_factor, paint):
        marker = MarkerPlacement(
            40.0, 40.0, 20.0, kind="checker", inverted=inverted, dull_factor=dull_factor
        )
        return render_markers((81, 81), [marker], 0, reflectances=paint).markers[0].dull_margin

    assert margin(1.0, (0.1, 0.9)) == pytest.approx(1.0)
    assert margin(0.5, (0.1, 0.9)) == pytest.approx((0.45 - 0.1) / 0.8)
    # Light-grey "dark" paint: the dull quadrant is darker than it, the X one bright quadrant.
    assert margin(0.5, (0.5, 0.9)) == pytest.approx((0.45 - 0.5) / 0.4)


def test_a_cast_shadow_darkens_its_half_plane_by_the_drawn_factor_within_its_reach():
    shadow = CastShadow(50.0, 50.0, normal_rad=0.0, offset_px=3.0, darkening=0.5, reach_px=30.0)
    image = render_markers(
        (101, 101), [], 0, background_level=0.8, cast_shadows=[shadow]
    ).image.astype(float)
    lit = 255 * 0.8
    assert image[50, 60] == pytest.approx(0.5 * lit, abs=0.6)  # x - 50 >= 3: shadow
    assert image[50, 45] == pytest.approx(lit, abs=0.6)  # the sunlit side
    assert image[50, 90] == pytest.approx(lit, abs=0.6)  # beyond its reach
    # A hard edge: the light changes within about a pixel of x = 53.
    assert image[50, 52] > 0.8 * lit and image[50, 54] < 0.6 * lit


def test_cast_shadows_of_a_scene_cross_their_markers_within_the_drawn_distance():
    config = SceneConfig(
        width=480,
        height=360,
        n_markers=4,
        radius_px=(8.0, 16.0),
        n_hard_negatives=0,
        shadow_probability=1.0,
    )
    scene = render_scene(config, 5)
    assert len(scene.imaging.cast_shadows) == 4
    for shadow, truth in zip(
        sorted(scene.imaging.cast_shadows, key=lambda s: s.x),
        sorted(scene.markers, key=lambda m: m.x),
        strict=True,
    ):
        assert (shadow.x, shadow.y) == (truth.x, truth.y)
        assert abs(shadow.offset_px) <= 0.6 * truth.foreshortened_radius_px
        assert 0.4 <= shadow.darkening <= 0.65


def test_jpeg_changes_the_frame_a_little_and_keeps_the_truth():
    plain = render_scene(SMALL_SCENE, 3)
    jpeg = render_scene(dataclasses.replace(SMALL_SCENE, jpeg_probability=1.0), 3)
    assert 70 <= jpeg.imaging.jpeg_quality <= 95
    difference = np.abs(plain.image.astype(float) - jpeg.image)
    assert 0.1 < difference.mean() < 4.0
    np.testing.assert_array_equal(plain.centres, jpeg.centres)


def test_field_conditions_left_off_keep_a_seeds_frame():
    config = dataclasses.replace(SMALL_SCENE, dull_factor=(0.5, 0.6), jpeg_quality=(80, 80))
    np.testing.assert_array_equal(render_scene(SMALL_SCENE, 8).image, render_scene(config, 8).image)


def test_peak_level_and_contrast_set_the_output_levels():
    scene = render_markers(
        (60, 60),
        [MarkerPlacement(30.0, 30.0, 12.0, kind="checker")],
        0,
        contrast=(0.4, 0.4),
        peak_level=0.7,
    )
    dark, bright = scene.image[26, 26], scene.image[26, 34]
    assert (float(bright) - float(dark)) == pytest.approx(0.4 * 0.7 * 255, abs=1.0)


def test_ground_at_quarter_scale_is_area_averaged_not_aliased_into_noise():
    # Bilinear sampling alone keeps 1 texture pixel in 16: gravel's neighbouring
    # pixels then correlate at 0.34; the area-averaged ground at 0.64.
    ground = texture_background(
        (240, 320), np.random.default_rng(1), names=("gravel",), scale_range=(0.25, 0.25)
    )
    neighbours = np.corrcoef(ground[:, :-1].ravel(), ground[:, 1:].ravel())[0, 1]
    assert neighbours > 0.5
