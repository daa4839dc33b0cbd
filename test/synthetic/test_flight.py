"""Specification of the flight simulator (marker_localizer.synthetic.flight).

World ENU (x east, y north, z up, ground z = 0), body x forward / y left / z up,
camera optical x right / y down / z forward; image coordinates x right, y down,
(0, 0) at the centre of the top-left pixel.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np
import pytest

from marker_localizer.errors import ConfigError
from marker_localizer.synthetic.flight import (
    CAMERA_NAMES,
    FlightConfig,
    FlightSimulator,
    _wrapped_pyr_down,
    camera_in_world,
    camera_rig,
    ground_homography,
    image_to_ground,
)
from marker_localizer.synthetic.scene import PLATE_HALF_SIDE, bayer_gain, project

SMALL = FlightConfig(width=320, height=240, n_frames=2)
#: A clean frame: no noise, blur, motion, jitter or light variation.
CLEAN = FlightConfig(
    width=320,
    height=240,
    n_frames=1,
    n_cameras=1,
    attitude_jitter_deg=0.0,
    exposure_s=0.0,
    blur_sigma_px=0.0,
    noise_sigma_dn=0.0,
    full_well_e=None,
    vignetting=0.0,
    illumination_strength=0.0,
    n_shadows=0,
    frame_gain_range=(1.0, 1.0),
    supersampling=16,
)

#: Points of the ground near the mosaic's corner, px: how asymmetric the texture is there.
SHIFTS_PX = np.array([[30.0, 0.0], [-30.0, 0.0], [0.0, 30.0], [0.0, -30.0], [25.0, 25.0]])


@pytest.fixture(scope="module")
def small_flight():
    simulator = FlightSimulator(SMALL, seed=3)
    return simulator, simulator.render(1)


def pinhole_project(camera, pose, world_xyz):
    """Independent projection: rotate and translate into the camera, then divide."""
    rotation, centre = camera_in_world(camera, pose)
    p = rotation.T @ (np.asarray(world_xyz, dtype=np.float64) - centre)
    return camera.fx_px * p[0] / p[2] + camera.cx_px, camera.fy_px * p[1] / p[2] + camera.cy_px


def symmetry_residual(image, centre, radius):
    """Mean |I - I rotated 180 degrees about centre| over a disk, in DN (cubic interpolation)."""
    cx, cy = centre
    rotation = np.array([[-1.0, 0.0, 2 * cx], [0.0, -1.0, 2 * cy]])
    image = image.astype(np.float32)
    rotated = cv2.warpAffine(image, rotation, image.shape[::-1], flags=cv2.INTER_CUBIC)
    rows, cols = np.mgrid[: image.shape[0], : image.shape[1]]
    disk = np.hypot(cols - cx, rows - cy) <= radius
    return float(np.abs(image - rotated)[disk].mean())


# --------------------------------------------------------------------------- rig and geometry


def test_rig_has_a_nadir_camera_and_four_tilted_towards_front_back_left_right():
    rig = camera_rig(FlightConfig(tilt_deg=30.0))
    assert [c.name for c in rig] == list(CAMERA_NAMES)
    axes = np.array([c.rotation_body_camera[:, 2] for c in rig])  # optical axes in the body
    np.testing.assert_allclose(axes[0], [0.0, 0.0, -1.0], atol=1e-12)
    s, c = math.sin(math.radians(30.0)), math.cos(math.radians(30.0))
    expected = [[s, 0, -c], [-s, 0, -c], [0, s, -c], [0, -s, -c]]  # fwd, back, left, right
    np.testing.assert_allclose(axes[1:], expected, atol=1e-12)
    for camera in rig:
        r = camera.rotation_body_camera
        np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
        assert np.linalg.det(r) == pytest.approx(1.0)
    # The top of every image looks towards the nose: image -y is body +x for the nadir camera.
    np.testing.assert_allclose(rig[0].rotation_body_camera[:, 1], [-1.0, 0.0, 0.0], atol=1e-12)


def test_default_config_shows_half_metre_markers_at_15_px_at_nadir_for_any_frame_size():
    for width, height in [(4096, 3000), (320, 240)]:
        config = FlightConfig(width=width, height=height)
        assert config.focal_px == pytest.approx(0.5 * width / math.tan(math.radians(30.0)))
        radius_px = config.marker_radius_m * config.focal_px / config.flight_altitude_m
        assert radius_px == pytest.approx(15.0)
    assert FlightConfig().flight_altitude_m == pytest.approx(118.2, abs=0.1)
    assert FlightConfig(altitude_m=50.0).flight_altitude_m == 50.0


def test_ground_homography_agrees_with_a_full_pinhole_projection_and_gives_depth(small_flight):
    simulator, frame = small_flight
    points = [(3.0, -2.0, 0.0), (-7.5, 4.25, 0.0), (0.1, 0.2, 0.0)]
    for camera in simulator.rig:
        h = ground_homography(camera, frame.pose)
        for point in points:
            mapped = h @ [point[0], point[1], 1.0]
            expected = pinhole_project(camera, frame.pose, point)
            np.testing.assert_allclose(mapped[:2] / mapped[2], expected, atol=1e-9)
            rotation, centre = camera_in_world(camera, frame.pose)
            depth = (rotation.T @ (np.array(point) - centre))[2]
            assert mapped[2] == pytest.approx(depth)


def test_image_to_ground_inverts_the_homography_and_rejects_rays_above_the_horizon():
    simulator = FlightSimulator(FlightConfig(width=320, height=240, n_frames=1), seed=0)
    camera, pose = simulator.rig[1], simulator.poses[0]
    h = ground_homography(camera, pose)
    ground = image_to_ground(h, np.array([[10.0, 20.0], [300.0, 200.0]]))
    back = project(h, ground)
    np.testing.assert_allclose(back, [[10.0, 20.0], [300.0, 200.0]], atol=1e-9)
    # A pixel far above the top edge of the forward camera looks at the sky.
    assert np.isnan(image_to_ground(h, np.array([[160.0, -5000.0]]))).all()


# --------------------------------------------------------------------------- truth


def test_truth_is_the_projection_of_each_markers_world_origin(small_flight):
    simulator, frame = small_flight
    assert sum(len(view.markers) for view in frame.cameras) > 20
    for view in frame.cameras:
        for truth, marker_id in zip(view.markers, view.marker_ids, strict=True):
            marker = simulator.markers[marker_id]
            expected = pinhole_project(view.camera, frame.pose, (marker.x_m, marker.y_m, 0.0))
            assert truth.x == pytest.approx(expected[0], abs=1e-9)
            assert truth.y == pytest.approx(expected[1], abs=1e-9)


def test_truth_lists_only_markers_whose_plate_is_wholly_inside_the_frame(small_flight):
    _, frame = small_flight
    plate = PLATE_HALF_SIDE * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=float)
    limits = np.array([SMALL.width - 0.5, SMALL.height - 0.5])
    for view in frame.cameras:
        for truth in view.markers:
            corners = project(truth.homography, plate)
            assert (corners >= -0.5).all() and (corners <= limits).all()
        assert view.partial, "a frame over a marker grid always cuts some markers"
        for truth in view.partial:
            corners = project(truth.homography, plate)
            inside = ((corners >= -0.5) & (corners <= limits)).all(axis=1)
            assert not inside.all()


def test_partly_drawn_markers_are_those_whose_plate_meets_the_frame():
    """Low over the ground plates are large and tilted: the box of one reached into the
    frame where the plate did not (4 of 75 listed, up to 38 px off the frame)."""
    config = FlightConfig(width=640, height=480, n_frames=4, altitude_m=3.0)
    simulator = FlightSimulator(config, seed=0)
    plate = PLATE_HALF_SIDE * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=float)
    w, h = config.width - 0.5, config.height - 0.5
    frame_rectangle = np.array([[-0.5, -0.5], [w, -0.5], [w, h], [-0.5, h]], np.float32)
    listed = 0
    for index in range(config.n_frames):
        for view in simulator.render(index).cameras:
            for truth in view.partial:
                corners = project(truth.homography, plate).astype(np.float32)
                overlap, _ = cv2.intersectConvexConvex(corners, frame_rectangle)
                assert overlap > 0
                listed += 1
    assert listed > 50


def test_markers_appear_with_radii_of_4_to_30_px_in_every_camera(small_flight):
    _, frame = small_flight
    radii = [t.radius_px for view in frame.cameras for t in view.markers]
    assert min(radii) >= 4.0
    assert max(radii) <= 30.0
    nadir = [t.radius_px for t in frame.cameras[0].markers]
    assert np.median(nadir) == pytest.approx(15.0, rel=0.1)


def test_clean_nadir_frame_is_point_symmetric_about_each_truth_centre():
    # A little blur makes the cubic interpolation of the rotated frame accurate.
    config = FlightConfig(**{**CLEAN.__dict__, "blur_sigma_px": 1.0})
    view = FlightSimulator(config, seed=5).render(0).cameras[0]
    assert view.markers
    for truth in view.markers:
        radius = 0.9 * truth.radius_px
        at_truth = symmetry_residual(view.image, (truth.x, truth.y), radius)
        assert at_truth < 1.5  # DN; interpolation and 8-bit rounding
        for dx, dy in [(0.3, 0.0), (0.0, 0.3)]:
            shifted = symmetry_residual(view.image, (truth.x + dx, truth.y + dy), radius)
            assert shifted > 3.0 * at_truth


# --------------------------------------------------------------------------- rendering


def test_same_seed_gives_the_same_pixels_in_any_render_order():
    first = FlightSimulator(SMALL, seed=9)
    second = FlightSimulator(SMALL, seed=9)
    late = second.render(1)
    early = first.render(1)
    for a, b in zip(early.cameras, late.cameras, strict=True):
        np.testing.assert_array_equal(a.image, b.image)
    other = FlightSimulator(SMALL, seed=10).render(1)
    assert not np.array_equal(other.cameras[0].image, early.cameras[0].image)


def test_frames_are_stamped_at_the_frame_rate_and_the_aircraft_moves_along_its_course():
    config = FlightConfig(width=320, height=240, n_frames=3, course_deg=90.0, speed_mps=5.0)
    simulator = FlightSimulator(config, seed=0)
    stamps = [p.stamp_ns for p in simulator.poses]
    assert np.diff(stamps).tolist() == [500_000_000, 500_000_000]
    step = simulator.poses[1].position_m - simulator.poses[0].position_m
    np.testing.assert_allclose(step, [0.0, 2.5, 0.0], atol=1e-12)  # north at 5 m/s for 0.5 s


def test_motion_blur_is_the_ground_travel_during_the_exposure_along_the_image_vertical():
    config = FlightConfig(width=320, height=240, n_frames=1, attitude_jitter_deg=0.0)
    frame = FlightSimulator(config, seed=0).render(0)
    view = frame.cameras[0]
    height_m = camera_in_world(view.camera, frame.pose)[1][2]  # the lens hangs below the body
    expected_px = config.speed_mps * config.exposure_s * config.focal_px / height_m
    assert view.imaging.motion_blur_px == pytest.approx(expected_px, rel=0.01)
    # Flying forward, the ground moves down the nadir image (+y).
    assert abs(abs(view.imaging.motion_blur_angle_rad) - math.pi / 2) < 1e-6


def test_ground_texture_is_the_same_ground_in_overlapping_cameras():
    config = FlightConfig(
        width=320, height=240, n_frames=1, n_cameras=2, tilt_deg=20.0, marker_spacing_m=1000.0
    )
    clean = {
        f: getattr(CLEAN, f)
        for f in (
            "exposure_s",
            "blur_sigma_px",
            "noise_sigma_dn",
            "full_well_e",
            "vignetting",
            "illumination_strength",
            "n_shadows",
            "frame_gain_range",
        )
    }
    simulator = FlightSimulator(FlightConfig(**{**config.__dict__, **clean}), seed=2)
    frame = simulator.render(0)
    nadir, forward = frame.cameras
    # Ground points seen by both: compare 5x5 means (the two views sample the
    # texture from different pyramid levels).
    ground = image_to_ground(
        nadir.homography, np.array([[160.0, 30.0], [100.0, 60.0], [220.0, 40.0]])
    )
    in_forward = project(forward.homography, ground)
    assert ((in_forward > 10) & (in_forward < [310, 230])).all()
    for (xa, ya), (xb, yb) in zip([[160, 30], [100, 60], [220, 40]], in_forward, strict=True):
        a = nadir.image[ya - 2 : ya + 3, xa - 2 : xa + 3].mean()
        b = cv2.getRectSubPix(forward.image, (5, 5), (float(xb), float(yb))).mean()
        assert abs(a - b) < 12.0, (a, b)


def test_the_ground_repeats_without_mirrors_so_no_join_is_a_point_of_symmetry():
    # Mirrored about its borders, the ground mosaic was point-symmetric about its corner
    # (half a ground sample from the world's origin, under every flight): an exact X
    # to a detector that reads grey-level point symmetry.
    config = dataclasses.replace(CLEAN, marker_spacing_m=1000.0)
    view = FlightSimulator(config, seed=5).render(0).cameras[0]
    corner = project(view.homography, np.full((1, 2), -0.5 * config.ground_sample_m))[0]
    markers = np.array([(m.x, m.y) for m in view.markers]).reshape(-1, 2)
    assert np.all(np.hypot(*(markers - corner).T) > 40.0)
    elsewhere = [symmetry_residual(view.image, corner + shift, 12.0) for shift in SHIFTS_PX]
    assert symmetry_residual(view.image, corner, 12.0) > 0.5 * np.median(elsewhere)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"width": 0}, "width"),
        # The altitude follows from the width: a 1 px frame flew over thousands of markers.
        ({"width": 1}, "must hold a marker's plate at nadir, 37.5 px"),
        ({"height": 30}, "must hold a marker's plate at nadir, 37.5 px"),
        # OpenCV's warp failed on it without saying why ('Insufficient memory').
        ({"width": 100_000, "height": 100_000}, "over the 50000000 px the detector takes"),
        ({"n_cameras": 6}, "n_cameras"),
        ({"tilt_deg": 60.0}, "tilt_deg"),
        ({"altitude_m": -1.0}, "altitude_m"),
        ({"marker_spacing_m": 0.5}, "marker_spacing_m"),
        ({"marker_kinds": ("triangle",)}, "marker_kinds"),
        ({"frame_gain_range": (0.0, 1.0)}, "frame_gain_range"),
        ({"vignetting": 1.5}, "vignetting"),
        ({"bayer_pattern": "rgbg"}, "bayer_pattern"),
        # Not finite: a flight at infinite speed left the renderer an empty ground.
        ({"speed_mps": float("inf")}, "speed_mps=inf"),
        ({"exposure_s": float("nan")}, "exposure_s=nan"),
        ({"frame_rate_hz": float("inf")}, "frame_rate_hz=inf"),
        # Stamps are whole nanoseconds: at 3e9 Hz two frame sets shared one.
        ({"frame_rate_hz": 3e9}, "frame_rate_hz=3000000000.0 must be at most 1e9"),
        ({"altitude_m": float("inf")}, "altitude_m=inf"),
        # The cameras hang 0.1 m below the body: at 0.05 m the ground extent was an
        # empty array's minimum, at 0.1 m a motion-blur kernel of 74 GiB.
        ({"altitude_m": 0.05}, "flight altitude 0.05 m must exceed the cameras' 0.1 m"),
        ({"altitude_m": 0.1}, "flight altitude 0.1 m must exceed"),
        ({"width": 320, "height": 240, "marker_radius_m": 0.001}, "marker_radius_m=0.001"),
    ],
)
def test_invalid_flight_config_raises_config_error_naming_the_field(changes, message):
    with pytest.raises(ConfigError, match=message):
        FlightConfig(**changes)


def test_rendering_a_frame_outside_the_flight_raises():
    with pytest.raises(ConfigError, match="frame index 2"):
        FlightSimulator(FlightConfig(width=64, height=48, n_frames=2), seed=0).render(2)


def test_every_level_of_the_ground_pyramid_lies_where_the_full_resolution_one_does():
    # A ramp of the ground's x in metres as the mosaic: each level's pixel shows the
    # x of the ground it is warped onto, if the levels are registered.
    simulator = FlightSimulator(SMALL, seed=1)
    mosaic = simulator._mosaic
    sample = mosaic.sample_m
    ramp = np.tile(np.arange(256, dtype=np.float32) * np.float32(sample), (256, 1))
    mosaic.levels = [ramp]
    for _ in range(3):
        mosaic.levels.append(_wrapped_pyr_down(mosaic.levels[-1]))
    for level in range(4):
        scale_m = sample * 2**level  # one image pixel per level-L mosaic pixel
        x0 = 2.0  # m, the ground's x at the image's column 0, clear of the ramp's wrap
        homography = np.array(
            [[1 / scale_m, 0.0, -x0 / scale_m], [0.0, 1 / scale_m, 0.0], [0, 0, 1]]
        )
        view = mosaic.warp(homography, (16, 16))
        ground_x = x0 + scale_m * np.arange(16)
        np.testing.assert_allclose(view[8], ground_x, atol=1e-3 * sample)


def test_a_bayer_camera_writes_the_monochrome_signal_through_its_filters_gains():
    mono = FlightSimulator(CLEAN, seed=2).render(0).cameras[0].image
    raw = FlightSimulator(dataclasses.replace(CLEAN, bayer_pattern="gbrg"), seed=2)
    mosaic = raw.render(0).cameras[0].image
    # Green, blue / red, green: the blue pixels at 0.75 of green, the red at 0.55.
    expected = mono * bayer_gain(mono.shape, "gbrg")
    assert mosaic.dtype == np.uint8
    assert np.abs(mosaic - expected).max() <= 1.0
    np.testing.assert_array_equal(mosaic[::2, ::2], mono[::2, ::2])
