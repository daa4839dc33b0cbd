"""Second readings: which lost candidates are read again, where, and what joins."""

import numpy as np
import pytest

from marker_localizer.config import DetectorConfig
from marker_localizer.core import acceptance, preprocessing, second_reading, subpixel, verification
from marker_localizer.core.noise import estimate_noise
from marker_localizer.core.screening import Candidates
from marker_localizer.synthetic import MarkerPlacement, render_markers
from marker_localizer.synthetic.scene import CastShadow

CENTRE = (64.3, 63.6)
RADIUS_PX = 14.0
MAX_RADIUS_PX = 30.0
#: Where the screening leaves the candidate: a pixel or so off the centre, at the
#: pyramid's second level.
SCREENED = Candidates(np.array([[CENTRE[0] + 0.6, CENTRE[1] - 0.5]]), np.ones(1), np.array([8.0]))


def _marker(
    dull: float = 1.0, cast: tuple[CastShadow, ...] = (), radius_px: float = RADIUS_PX
) -> tuple[np.ndarray, tuple[float, float]]:
    placement = MarkerPlacement(*CENTRE, radius_px, 0.4, 20.0, 0.3, dull_factor=dull)
    scene = render_markers(
        (128, 128),
        [placement],
        0,
        blur_sigma_px=1.0,
        noise_sigma_dn=1.0,
        cast_shadows=list(cast),
    )
    return scene.image, scene.markers[0].angles


def _shadowed_marker() -> tuple[np.ndarray, tuple[float, float]]:
    return _marker(0.7, (CastShadow(*CENTRE, 0.7, 3.0, 0.5, 2 * RADIUS_PX),))


def _error(xy: np.ndarray) -> float:
    return float(np.hypot(*(np.asarray(xy) - CENTRE)))


def test_points_within_the_radius_of_a_found_one_are_not_far():
    found = np.array([[10.0, 10.0], [50.0, 50.0]])
    xy = np.array([[10.5, 10.0], [30.0, 30.0], [50.0, 52.5], [90.0, 10.0]])
    assert second_reading.far_from(found, xy, 2.0).tolist() == [1, 2, 3]
    assert second_reading.far_from(np.zeros((0, 2)), xy, 2.0).tolist() == [0, 1, 2, 3]


def test_only_wide_candidates_far_from_every_detection_are_lost_and_the_cap_is_counted():
    wide = second_reading.WIDE_SCALE_PX
    screened = Candidates(
        np.array([[10.0, 10.0], [40.0, 10.0], [70.0, 10.0], [100.0, 10.0], [130.0, 10.0]]),
        np.array([5.0, 4.0, 3.0, 2.0, 1.0]),
        np.array([wide / 2, wide, wide, 2 * wide, 4 * wide]),
    )
    found = np.array([[40.5, 10.0]])
    lost, over = second_reading.lost_wide(screened, found, 2.0, cap=10, cell_px=1000.0)
    # The first is texture's scale, the second has found a marker.
    assert sorted(lost.tolist()) == [2, 3, 4]
    assert over == 0
    lost, over = second_reading.lost_wide(screened, found, 2.0, cap=2, cell_px=1000.0)
    assert len(lost) == 2 and over == 1
    # The strongest are kept.
    assert sorted(lost.tolist()) == [2, 3]


def test_a_second_readings_point_near_a_detection_or_a_stronger_point_is_a_duplicate():
    found = np.array([[10.0, 10.0]])
    added = np.array([[11.0, 10.0], [40.0, 40.0], [41.0, 40.0], [80.0, 80.0]])
    score = np.array([0.99, 0.9, 0.95, 0.9])
    joins = second_reading.new_points(found, added, score, 2.0)
    assert joins.tolist() == [False, False, True, True]
    assert second_reading.new_points(np.zeros((0, 2)), added, score, 2.0).tolist() == [
        True,
        False,
        True,
        True,
    ]


@pytest.mark.parametrize("dull", [0.6, 0.45])
def test_a_dull_quadrant_pulls_the_plain_centring_off_and_the_lights_slope_brings_it_back(dull):
    image, _ = _marker(dull)
    plain, found = subpixel.coarse_centre(image, SCREENED.xy, SCREENED.scale_px, MAX_RADIUS_PX)
    again = second_reading.recentred(image, SCREENED, plain, found, MAX_RADIUS_PX)
    assert _error(plain[0]) > 0.9
    assert len(again.xy) == 1
    assert _error(again.xy[0]) < 0.7 * _error(plain[0])
    assert again.scale_px.tolist() == SCREENED.scale_px.tolist()


def test_a_candidate_the_slope_leaves_where_it_was_is_not_read_again_unless_it_was_never_centred():
    image, _ = _marker()
    plain, found = subpixel.coarse_centre(image, SCREENED.xy, SCREENED.scale_px, MAX_RADIUS_PX)
    sloped, _ = subpixel.coarse_centre(
        image, SCREENED.xy, SCREENED.scale_px, MAX_RADIUS_PX, light_slope=True
    )
    assert found[0]
    assert np.hypot(*(sloped[0] - plain[0])) < second_reading.RECENTRE_MIN_SHIFT_PX
    assert len(second_reading.recentred(image, SCREENED, plain, found, MAX_RADIUS_PX).xy) == 0
    assert len(second_reading.recentred(image, SCREENED, plain, ~found, MAX_RADIUS_PX).xy) == 1


def test_a_shadows_edge_across_a_lost_candidate_is_divided_out_around_it_alone():
    image, angles = _shadowed_marker()
    # The same saddle found twice, a pixel apart: their disks overlap, one is read.
    twice = Candidates(
        np.vstack([SCREENED.xy, SCREENED.xy + [1.0, 0.0]]), np.ones(2), np.full(2, 8.0)
    )
    reading = second_reading.shadowed(image, twice, np.array([angles] * 2), MAX_RADIUS_PX, 255.0)
    assert len(reading.read.xy) == 1 and reading.edges.found.all()
    changed_y, changed_x = np.nonzero(reading.lit != image)
    disk = second_reading.SHADOW_DISK_REACHES * second_reading.shadow_reach(
        reading.read, MAX_RADIUS_PX
    )
    reach = np.hypot(changed_x - reading.read.xy[0, 0], changed_y - reading.read.xy[0, 1])
    assert len(reach) and reach.max() <= disk[0]
    # The shadow's side is lit again, nothing darkened.
    assert (reading.lit.astype(int) >= image.astype(int)).all()
    # Centred in the lit copy with the light's slope, near the X's centre.
    centred = second_reading.slope_centred(reading.lit, reading.read, MAX_RADIUS_PX)
    assert len(centred.xy) == 1 and _error(centred.xy[0]) < 0.5


def test_without_a_shadows_edge_nothing_is_read_again_and_the_frame_is_not_copied():
    image, angles = _marker(0.7)
    reading = second_reading.shadowed(image, SCREENED, np.array([angles]), MAX_RADIUS_PX, 255.0)
    assert len(reading.read.xy) == 0 and reading.lit is image


def test_markers_found_with_their_shadows_divided_out_are_located_each_with_its_own_edge():
    # Two markers, each under its own shadow's edge: each found centre takes the edge of
    # the candidate read nearest it, whatever the order they were found in.
    centres = np.array([CENTRE, (CENTRE[0] + 128.0, CENTRE[1] + 2.0)])
    scene = render_markers(
        (128, 256),
        [
            MarkerPlacement(*centre, RADIUS_PX, rotation, 20.0, 0.3, dull_factor=0.7)
            for centre, rotation in zip(centres, (0.4, 0.9), strict=True)
        ],
        0,
        blur_sigma_px=1.0,
        noise_sigma_dn=1.0,
        cast_shadows=[
            CastShadow(*centres[0], 0.7, 3.0, 0.5, 2 * RADIUS_PX),
            CastShadow(*centres[1], 2.5, -4.0, 0.6, 2 * RADIUS_PX),
        ],
    )
    angles = np.array([m.angles for m in scene.markers])
    lost = Candidates(centres + [0.6, -0.5], np.ones(2), np.full(2, 8.0))
    reading = second_reading.shadowed(scene.image, lost, angles, MAX_RADIUS_PX, 255.0)
    assert len(reading.read.xy) == 2
    centred = second_reading.slope_centred(reading.lit, reading.read, MAX_RADIUS_PX)
    found = centred.xy[::-1]
    xy, sigma, located = second_reading.located_in_shadow(
        scene.image,
        found,
        np.full(2, 0.05),
        angles[::-1],
        np.full(2, 0.9 * RADIUS_PX),
        255.0,
        reading,
    )
    assert located.tolist() == [True, True]
    error = np.hypot(*(xy - centres[::-1]).T)
    assert (error < 0.05).all()
    assert (error < np.hypot(*(found - centres[::-1]).T)).all()
    assert np.isfinite(sigma).all()


def _first_reading(image: np.ndarray) -> tuple[Candidates, verification.SymmetryCheck, np.ndarray]:
    """The first reading's slope-free centring of the screened candidate, and its rings."""
    plain, _ = subpixel.coarse_centre(image, SCREENED.xy, SCREENED.scale_px, MAX_RADIUS_PX)
    rings = _ring_reader(image)
    return (
        Candidates(plain, SCREENED.strength, SCREENED.scale_px),
        rings(plain),
        rings(plain, equalise=True).accepted,
    )


def _ring_reader(image: np.ndarray) -> verification.RingReader:
    return verification.RingReader(
        image,
        verification.ring_radii((5.0, MAX_RADIUS_PX)),
        DetectorConfig().min_contrast_dn / 255.0,
        DetectorConfig().symmetry_min,
    )


def _read_dull(
    image: np.ndarray,
    centred: Candidates,
    first: verification.SymmetryCheck,
    equalised_x: np.ndarray,
) -> second_reading.DullReading:
    config = DetectorConfig(marker_radius_min_px=5.0, marker_radius_max_px=MAX_RADIUS_PX)
    gamma = preprocessing.LocalGamma(
        image, 255.0, config.gamma_alpha, config.illumination_window_px
    )
    return second_reading.read_dull(
        image,
        centred,
        first,
        equalised_x,
        rings=_ring_reader(image),
        floors=acceptance.ScoreFloors(config.min_score, config.min_score_small, 5.0),
        model=acceptance.MarkerModel(
            image, 255.0, lambda: estimate_noise(image, 255.0), MAX_RADIUS_PX, False, gamma
        ),
        max_radius_px=MAX_RADIUS_PX,
        cell_px=config.entropy_cell_px,
    )


@pytest.mark.parametrize("radius_px", [7.0, 8.0])
def test_a_small_x_with_a_dull_quadrant_is_read_again_from_the_light_slopes_centre(radius_px):
    # The plain rings at the slope-free centre, 0.9-1 px towards the brighter side,
    # show no X; the equalised ones show it, short. From the slope's centre they
    # show it out to 5 px, and the marker's model vouches for it.
    image, _ = _marker(0.55, radius_px=radius_px)
    centred, first, equalised_x = _first_reading(image)
    assert not first.accepted[0] and equalised_x[0]
    reading = _read_dull(image, centred, first, equalised_x)
    assert reading.read.tolist() == [0] and reading.kept.tolist() == [0]
    assert _error(reading.xy[0]) < 0.6 * _error(centred.xy[0])
    # The reading replaces the first: the candidate moves, and its rings are these.
    moved, ring = reading.moved(centred, first)
    assert moved.xy.tolist() == reading.xy.tolist()
    assert ring.accepted[0] and ring.radius_px[0] >= verification.DULL_MIN_EXTENT_PX


def test_the_same_x_screened_at_textures_scale_is_not_read_again():
    image, _ = _marker(0.55, radius_px=7.0)
    centred, first, equalised_x = _first_reading(image)
    assert not first.accepted[0] and equalised_x[0]
    narrow = Candidates(centred.xy, centred.strength, np.array([second_reading.WIDE_SCALE_PX / 2]))
    reading = _read_dull(image, narrow, first, equalised_x)
    assert len(reading.read) == 0
    moved, ring = reading.moved(narrow, first)
    assert moved is narrow and ring is first


def test_an_x_the_plain_rings_show_whole_is_not_read_again():
    image, _ = _marker(1.0, radius_px=7.0)
    centred, first, equalised_x = _first_reading(image)
    assert first.accepted[0]
    assert len(_read_dull(image, centred, first, equalised_x).read) == 0
