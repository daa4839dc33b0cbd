"""The colour check: a marker's X is drawn in luminance, texture's in its materials' colours."""

import cv2
import numpy as np
import pytest
from scenes import through_demosaicing

from marker_localizer.config import DetectorConfig
from marker_localizer.core import chroma
from marker_localizer.synthetic import MarkerPlacement, render_markers

MAX_SHARE = DetectorConfig().max_x_chroma_share

#: BGR gains of a light that is not white (a warm evening sun seen by a camera
#: balanced for daylight, red 1.5 times blue): a neutral paint takes them all, dark
#: and bright alike.
WARM_LIGHT = (0.8, 1.0, 1.2)
#: BGR tints of two materials: dark brown grains, pale yellow sand.
BROWN, PALE = (0.55, 1.0, 1.45), (0.85, 1.0, 1.1)


def _grey_x(levels=(60.0, 200.0), size=41, blur=1.0) -> np.ndarray:
    """(size, size) float grey X centred between pixels at (20, 20), lines along the axes."""
    grid = np.arange(size) - (size - 1) / 2.0
    x, y = np.meshgrid(grid, grid)
    image = np.where(x * y > 0, levels[1], levels[0])
    return cv2.GaussianBlur(image, (0, 0), blur)


def _tinted(grey: np.ndarray, dark_tint, bright_tint) -> np.ndarray:
    """uint8 BGR of ``grey``, each pixel tinted between two tints by its level."""
    share = (grey - grey.min()) / (grey.max() - grey.min())
    tint = np.asarray(dark_tint) + share[..., None] * (np.asarray(bright_tint) - dark_tint)
    return np.clip(np.rint(grey[..., None] * tint), 0, 255).astype(np.uint8)


def _share(colour: np.ndarray, radius_px: float = 6.0) -> float:
    centre = (colour.shape[1] - 1) / 2.0
    share = chroma.x_chroma_share(
        colour,
        255.0,
        np.array([[centre, centre]]),
        np.array([radius_px]),
        np.array([[0.0, np.pi / 2]]),
    )
    return float(share[0])


def test_a_neutral_x_under_a_coloured_light_shows_next_to_no_colour():
    assert _share(_tinted(_grey_x(), WARM_LIGHT, WARM_LIGHT)) < 0.02


@pytest.mark.parametrize("radius_px", [3.0, 4.0, 6.0])
def test_a_tiny_neutral_x_through_a_colour_jpeg_under_a_warm_light_stays_under_the_bar(radius_px):
    """The JPEG's halved, quantised chroma gives a tiny neutral X about the light's cast."""
    ok, encoded = cv2.imencode(
        ".jpg", _tinted(_grey_x(), WARM_LIGHT, WARM_LIGHT), [cv2.IMWRITE_JPEG_QUALITY, 75]
    )
    assert ok
    assert _share(cv2.imdecode(encoded, cv2.IMREAD_COLOR), radius_px) < 0.8 * MAX_SHARE


@pytest.mark.parametrize(
    "demosaicing",
    [cv2.COLOR_BayerBG2BGR, cv2.COLOR_BayerBG2BGR_VNG, cv2.COLOR_BayerBG2BGR_EA],
    ids=["bilinear", "vng", "edge-aware"],
)
@pytest.mark.parametrize("extent_px", [chroma.CHROMA_MIN_EXTENT_PX, 6.0, 8.5])
def test_a_small_neutral_x_through_a_cameras_demosaicing_stays_well_under_the_bar(
    demosaicing, extent_px
):
    """A raw mosaic (a raw sensor's colour gains) demosaiced by OpenCV, uncompressed."""
    shares = []
    for k in range(16):
        centre = (16.0 + 0.25 * (k % 4), 16.0 + 0.25 * (k // 4))
        # A marker wider than the X read, so that only its lines are in the disk.
        marker = MarkerPlacement(*centre, radius_px=14.0, rotation_rad=0.2 + 0.37 * k)
        scene = render_markers((33, 33), [marker], 0, reflectances=(0.16, 0.78), blur_sigma_px=0.8)
        share = chroma.x_chroma_share(
            through_demosaicing(scene.image, demosaicing),
            255.0,
            np.array([centre]),
            np.array([extent_px]),
            np.array([scene.markers[0].angles]),
        )
        shares.append(float(share[0]))
    assert max(shares) < 0.5 * MAX_SHARE


def test_an_x_of_two_materials_shows_its_colours_through_a_jpeg_too():
    colour = _tinted(_grey_x((90.0, 160.0)), BROWN, PALE)
    ok, encoded = cv2.imencode(".jpg", colour, [cv2.IMWRITE_JPEG_QUALITY, 75])
    assert ok
    assert _share(colour) > 2 * MAX_SHARE
    assert _share(cv2.imdecode(encoded, cv2.IMREAD_COLOR), 4.0) > 1.2 * MAX_SHARE


def test_the_share_does_not_depend_on_the_channels_order_or_a_common_gain():
    bgr = _tinted(_grey_x((90.0, 160.0)), BROWN, PALE)
    dimmer = np.rint(bgr * 0.6).astype(np.uint8)
    assert _share(bgr[..., ::-1].copy()) == pytest.approx(_share(bgr), rel=1e-12)
    assert _share(dimmer) == pytest.approx(_share(bgr), rel=0.15)


def test_an_x_whose_window_leaves_the_frame_is_not_read():
    colour = _tinted(_grey_x((90.0, 160.0)), BROWN, PALE)
    share = chroma.x_chroma_share(
        colour, 255.0, np.array([[2.0, 20.0]]), np.array([6.0]), np.array([[0.0, np.pi / 2]])
    )
    assert np.isnan(share).all()


def test_only_xs_of_textures_size_and_larger_than_the_colour_samples_reach_are_asked():
    colour = np.zeros((81, 81, 3), np.uint8)
    colour[:, :] = _tinted(_grey_x((90.0, 160.0), size=81), BROWN, PALE)
    centre = np.array([[40.0, 40.0]] * 4)
    radius = np.array(
        [
            chroma.CHROMA_MIN_EXTENT_PX - 0.5,
            chroma.CHROMA_MIN_EXTENT_PX,
            chroma.CHROMA_MAX_EXTENT_PX - 1.0,
            chroma.CHROMA_MAX_EXTENT_PX,
        ]
    )
    lines = np.array([[0.0, np.pi / 2]] * 4)
    assert (chroma.x_chroma_share(colour, 255.0, centre, radius, lines) > MAX_SHARE).all()
    assert chroma.coloured_x(colour, 255.0, centre, radius, lines, MAX_SHARE).tolist() == [
        False,
        True,
        True,
        False,
    ]
    empty = chroma.coloured_x(colour, 255.0, centre[:0], radius[:0], lines[:0], MAX_SHARE)
    assert empty.shape == (0,)


@pytest.mark.parametrize(
    ("shape", "colour"),
    [((8, 8), False), ((8, 8, 1), False), ((8, 8, 3), True), ((8, 8, 4), True)],
)
def test_a_frame_is_colour_when_it_has_three_or_four_channels(shape, colour):
    assert chroma.is_colour(np.zeros(shape, np.uint8)) is colour
