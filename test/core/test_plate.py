"""The tiny marker's plate model against smooth saddles (core/plate.py)."""

import cv2
import numpy as np
import pytest

from marker_localizer.core import plate
from marker_localizer.synthetic import MarkerPlacement, render_markers

#: The ring check's extent of a 3-4 px marker (a rung of its sqrt(2) ladder).
_EXTENT_PX = 3.0


def _tiny_marker(kind: str, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 3.5 px marker blurred by 1.3 px on a flat ground: image, centre, line angles."""
    placement = MarkerPlacement(40.3, 39.8, 3.5, 0.4 + seed, 20.0, kind=kind)
    scene = render_markers(
        (80, 80), [placement], seed, blur_sigma_px=1.3, noise_sigma_dn=2.0, background="flat"
    )
    return scene.image, scene.centres, np.array([scene.markers[0].angles])


def _smooth_saddle(seed: int) -> np.ndarray:
    """A quadratic saddle of 120 DN over 8 px with 2 DN of noise: texture's smooth X."""
    y, x = np.mgrid[:80, :80] - 40.0
    rng = np.random.default_rng(seed)
    surface = 128 + 120 * (x * x - y * y) / 64.0 / 2 + rng.normal(0, 2.0, x.shape)
    return np.clip(surface, 0, 255).round().astype(np.uint8)


@pytest.mark.parametrize("kind", ["quarter_disks", "checker"])
@pytest.mark.parametrize("seed", [0, 1])
def test_a_tiny_blurred_marker_is_explained_by_its_plate(kind, seed):
    image, centre, angles = _tiny_marker(kind, seed)
    evidence = plate.plate_evidence(image, centre, np.array([_EXTENT_PX]), angles)
    saddle = plate.centre_saddle(image, centre)
    assert evidence.to_quadratic[0] <= plate.MAX_TO_QUADRATIC
    assert evidence.to_quartic[0] <= plate.MAX_TO_QUARTIC
    assert saddle[0] >= plate.MIN_SADDLE
    assert plate.plate_explains(evidence, saddle)[0]


def test_a_smooth_saddle_is_no_plate_whatever_the_lines():
    image = _smooth_saddle(0)
    centre = np.array([[40.0, 40.0]])
    for angle in np.linspace(0.0, np.pi / 2, 4):
        evidence = plate.plate_evidence(
            image, centre, np.array([_EXTENT_PX]), np.array([[angle, angle + np.pi / 2]])
        )
        assert evidence.to_quadratic[0] > 0.9
        assert not plate.plate_explains(evidence, plate.centre_saddle(image, centre))[0]


def test_the_centre_of_an_x_is_a_saddle_and_that_of_a_blob_is_not():
    image, centre, _ = _tiny_marker("quarter_disks", 0)
    blob = np.zeros((80, 80), np.float32)
    cv2.ellipse(blob, (40, 40), (4, 2), 30.0, 0.0, 360.0, 200.0, -1)
    blob = cv2.GaussianBlur(blob, (0, 0), 1.3).round().astype(np.uint8)
    assert plate.centre_saddle(image, centre)[0] >= plate.MIN_SADDLE
    assert plate.centre_saddle(blob, np.array([[40.0, 40.0]]))[0] < 0.0


def test_windows_off_the_image_and_parallel_lines_read_as_nan_and_no():
    image, centre, angles = _tiny_marker("quarter_disks", 0)
    xy = np.array([[2.0, 40.0], centre[0]])
    lines = np.array([angles[0], [0.3, 0.3]])
    evidence = plate.plate_evidence(image, xy, np.full(2, _EXTENT_PX), lines)
    assert np.isnan(evidence.to_quadratic).all()
    assert np.isnan(plate.centre_saddle(image, np.array([[0.0, 0.0]])))[0]
    assert not plate.plate_explains(evidence, np.ones(2)).any()


def test_no_candidate_or_every_window_off_the_image_reads_nothing():
    image, _, angles = _tiny_marker("quarter_disks", 0)
    empty = plate.plate_evidence(image, np.zeros((0, 2)), np.zeros(0), np.zeros((0, 2)))
    assert len(empty.to_quadratic) == len(empty.to_quartic) == 0
    off = plate.plate_evidence(image, np.array([[1.0, 1.0]]), np.array([_EXTENT_PX]), angles)
    assert np.isnan(off.to_quadratic).all()


def test_a_smooth_saddle_leaves_the_plate_model_more_than_a_quartic():
    image = _smooth_saddle(1)
    centre = np.array([[40.0, 40.0]])
    evidence = plate.plate_evidence(
        image, centre, np.array([_EXTENT_PX]), np.array([[np.pi / 4, 3 * np.pi / 4]])
    )
    assert evidence.to_quartic[0] > plate.MAX_TO_QUARTIC_ANY


def _conjugate_radii(tilt_deg: float, phase: float) -> tuple[float, float, float]:
    """Radii along the images of two perpendicular diameters of a circle of 3 px seen
    ``tilt_deg`` from face on, and the |sin| of the angle between them."""
    squash = np.cos(np.deg2rad(tilt_deg))
    first = 3.0 * np.array([np.cos(phase), squash * np.sin(phase)])
    second = 3.0 * np.array([-np.sin(phase), squash * np.cos(phase)])
    r1, r2 = np.linalg.norm(first), np.linalg.norm(second)
    return r1, r2, abs(first[0] * second[1] - first[1] * second[0]) / (r1 * r2)


@pytest.mark.parametrize(
    ("tilt_deg", "possible"), [(0, True), (45, True), (59, True), (61, False), (75, False)]
)
def test_the_plate_shapes_are_those_of_a_circle_seen_at_most_sixty_degrees_from_face_on(
    tilt_deg, possible
):
    for phase in np.linspace(0.0, np.pi, 13):
        r1, r2, crossing = _conjugate_radii(tilt_deg, phase)
        shapes = plate.seen_within_max_tilt(np.array([r1, r2]), np.array([crossing]), 0.0)
        assert shapes[0, 0, 1] == possible


def test_a_model_shape_stands_for_the_radii_within_half_the_grid_spacing():
    # 2.25 and 5.25 px along lines at right angles: an ellipse of axis ratio 0.43, a
    # circle seen 65 degrees from face on; the shapes within half a step (0.375 px)
    # of it reach 2.625 and 4.875 px, 0.54: 57 degrees.
    radii, right_angle = np.array([2.25, 5.25]), np.array([1.0])
    assert not plate.seen_within_max_tilt(radii, right_angle, 0.0)[0, 0, 1]
    assert plate.seen_within_max_tilt(radii, right_angle, 0.375)[0, 0, 1]
    assert not plate.seen_within_max_tilt(radii, np.array([0.5]), 0.375)[0, 0, 1]


@pytest.mark.parametrize("tilt_deg", [55.0, 60.0])
@pytest.mark.parametrize("seed", range(3))
def test_a_tiny_marker_seen_up_to_sixty_degrees_from_face_on_is_explained_by_its_plate(
    tilt_deg, seed
):
    placement = MarkerPlacement(40.3, 39.8, 4.5, 0.4 + seed, tilt_deg, kind="quarter_disks")
    scene = render_markers(
        (80, 80), [placement], seed, blur_sigma_px=1.0, noise_sigma_dn=2.0, background="flat"
    )
    assert plate.explains_at(
        scene.image, scene.centres, np.array([_EXTENT_PX]), np.array([scene.markers[0].angles])
    )[0]


@pytest.mark.parametrize("seed", [0, 1])
def test_a_small_tilted_marker_is_explained_by_its_plate_read_at_its_scale(seed):
    # An 8 px marker tilted 50 degrees: its rings reach 6 px, and along its lines it
    # measures up to 8 px, beyond the tiny markers' radii (at most 5.25 px). At its
    # scale the model leaves 0.07 and 0.01 of the quartic's residual, at the tiny
    # markers' radii 0.49 and 0.68.
    placement = MarkerPlacement(60.3, 59.8, 8.0, 0.4 + seed, 50.0, kind="quarter_disks")
    scene = render_markers(
        (120, 120), [placement], seed, blur_sigma_px=1.0, noise_sigma_dn=2.0, background="flat"
    )
    angles = np.array([scene.markers[0].angles])
    extent = np.array([6.0])
    tiny = plate.plate_evidence(scene.image, scene.centres, extent, angles)
    scaled = plate.plate_evidence(
        scene.image, scene.centres, extent, angles, scale_with_extent=True
    )
    assert scaled.to_quartic[0] <= plate.MAX_TO_QUARTIC
    assert scaled.to_quartic[0] <= 0.5 * tiny.to_quartic[0]


@pytest.mark.parametrize("tilt_deg", [55.0, 60.0])
@pytest.mark.parametrize("seed", range(4))
def test_a_small_marker_seen_foreshortened_to_textures_size_is_explained_by_its_plate(
    tilt_deg, seed
):
    # A 7 px marker seen 55-60 degrees from face on reaches 3.5-4 px at its
    # shortest: the rings read an extent of 4 px, and along its lines it measures
    # 5-7 px, its plate out to 9. The tiny markers' radii (at most 5.25 px) leave
    # 0.52-0.82 of the quartic's residual on half of these; read a rung out at the
    # X's scale, 0.07-0.13.
    placement = MarkerPlacement(
        60.3, 59.8, 7.0, 0.4 + seed, tilt_deg, kind=("quarter_disks", "checker")[seed % 2]
    )
    scene = render_markers(
        (120, 120), [placement], seed, blur_sigma_px=1.0, noise_sigma_dn=2.0, background="flat"
    )
    angles = np.array([scene.markers[0].angles])
    assert plate.explains_at(scene.image, scene.centres, np.array([4.0]), angles)[0]
    reading = plate.read_plates(
        scene.image, scene.centres, np.ones(1), np.array([4.0]), angles, 1e3
    )
    assert reading.explained.tolist() == [0]


def test_a_smooth_saddle_read_a_rung_out_is_no_plate_either():
    image = _smooth_saddle(2)
    centre = np.array([[40.0, 40.0]])
    lines = np.array([[np.pi / 4, 3 * np.pi / 4]])
    for extent in (3.0, 4.0):
        further = plate.plate_evidence(
            image,
            centre,
            np.array([extent * 2**0.5]),
            lines,
            scale_with_extent=True,
            quadrant_levels=True,
        )
        assert not plate.plate_explains(further, plate.centre_saddle(image, centre))[0]
        assert not plate.explains_at(image, centre, np.array([extent]), lines)[0]


@pytest.mark.parametrize("seed", range(4))
def test_a_marker_with_a_dull_quadrant_is_explained_with_its_quadrants_own_levels(seed):
    # A 12 px marker, one bright quadrant half as bright as the other, on ground
    # texture: one level for both bright quadrants leaves 0.6-1.1 of the quartic's
    # residual, a level each 0.05-0.18.
    placement = MarkerPlacement(
        60.3,
        59.8,
        12.0,
        0.4 + seed,
        30.0,
        kind="quarter_disks",
        dull_factor=0.5,
        dull_quadrant=seed % 2,
    )
    scene = render_markers(
        (120, 120), [placement], seed, blur_sigma_px=1.0, noise_sigma_dn=2.0, background="texture"
    )
    angles = np.array([scene.markers[0].angles])
    extent = np.array([8.49])
    one = plate.plate_evidence(scene.image, scene.centres, extent, angles, scale_with_extent=True)
    own = plate.plate_evidence(
        scene.image, scene.centres, extent, angles, scale_with_extent=True, quadrant_levels=True
    )
    assert own.to_quartic[0] <= plate.MAX_TO_QUARTIC
    assert own.to_quartic[0] <= 0.5 * one.to_quartic[0]


def test_read_plates_compares_no_blob_and_explains_no_smooth_saddle():
    marker, centre, angles = _tiny_marker("quarter_disks", 0)
    saddle = _smooth_saddle(0)
    blob = np.zeros((80, 80), np.float32)
    cv2.ellipse(blob, (40, 40), (4, 2), 30.0, 0.0, 360.0, 200.0, -1)
    # Side by side: the marker, a smooth saddle and a blob, each read at its centre.
    image = np.hstack([marker, saddle, cv2.GaussianBlur(blob, (0, 0), 1.3).astype(np.uint8)])
    xy = np.array([centre[0], [120.0, 40.0], [200.0, 40.0]])
    reading = plate.read_plates(
        image, xy, np.ones(3), np.full(3, _EXTENT_PX), np.repeat(angles, 3, axis=0), 1000.0
    )
    # The blob's centre is no saddle: it is not compared.
    assert reading.read.tolist() == [0, 1]
    assert reading.explained.tolist() == [0]
    assert reading.over_cap == 0


def test_read_plates_compares_at_most_the_cap_spread_over_the_cells(monkeypatch):
    # Three tiny markers, two in one cell: a cap of two takes the strongest of that
    # cell and the one alone in the other, not the two strongest.
    marker, centre, angles = _tiny_marker("quarter_disks", 0)
    image = np.hstack([marker, marker])
    xy = np.array([centre[0], centre[0] + [0.5, 0.0], centre[0] + [80.0, 0.0]])
    monkeypatch.setattr(plate, "MAX_PLATE_READ", 2)
    reading = plate.read_plates(
        image,
        xy,
        np.array([0.99, 0.98, 0.9]),
        np.full(3, _EXTENT_PX),
        np.repeat(angles, 3, 0),
        60.0,
    )
    assert reading.read.tolist() == [0, 2]
    assert reading.over_cap == 1


@pytest.mark.parametrize(("tilt_deg", "explained"), [(60.0, True), (66.0, False)])
def test_a_plate_seen_more_steeply_than_sixty_degrees_takes_no_coarse_shape_either(
    tilt_deg, explained
):
    """The coarse search's least residual enters the reading, so its shapes are held to
    the tilt as the full grid reads it; with half its own spacing as each radius's reach
    it explained this 4.5 px marker seen 66 degrees from face on (0.18 of the quadratic)."""
    placement = MarkerPlacement(40.3, 39.8, 4.5, 1.2, tilt_deg, kind="quarter_disks")
    scene = render_markers(
        (80, 80), [placement], 3, blur_sigma_px=0.8, noise_sigma_dn=2.0, background="flat"
    )
    angles = np.array([scene.markers[0].angles])
    evidence = plate.plate_evidence(scene.image, scene.centres, np.array([_EXTENT_PX]), angles)
    assert (evidence.to_quadratic[0] <= plate.MAX_TO_QUADRATIC) == explained


def _markers_and_saddles() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Four tiny markers and two smooth saddles side by side: image, centres, line angles."""
    tiles, centres, angles = [], [], []
    for seed, kind in enumerate(("quarter_disks", "checker", "quarter_disks", "checker")):
        image, centre, lines = _tiny_marker(kind, seed)
        tiles.append(image)
        centres.append(centre[0] + [80.0 * seed, 0.0])
        angles.append(lines[0])
    for seed in range(2):
        tiles.append(_smooth_saddle(seed))
        centres.append([80.0 * len(centres) + 40.0, 40.0])
        angles.append([np.pi / 4, 3 * np.pi / 4])
    return np.hstack(tiles), np.array(centres), np.array(angles)


def test_the_full_search_reads_no_plate_worse_than_the_coarse_one():
    image, xy, angles = _markers_and_saddles()
    extent = np.full(len(xy), _EXTENT_PX)
    coarse = plate.plate_evidence(image, xy, extent, angles, enough_to_quartic=np.inf)
    searched = plate.plate_evidence(image, xy, extent, angles)
    assert np.all(searched.to_quartic <= coarse.to_quartic)
    # The markers are searched in full and read better; the saddles are not.
    assert np.all(searched.to_quartic[:4] < coarse.to_quartic[:4])
    assert np.array_equal(searched.to_quartic[4:], coarse.to_quartic[4:])


def test_a_bar_the_coarse_search_clears_spares_the_full_search_and_not_the_decision():
    image, xy, angles = _markers_and_saddles()
    extent = np.full(len(xy), _EXTENT_PX)
    searched = plate.plate_evidence(image, xy, extent, angles).to_quartic
    for bar in (0.1, plate.MAX_TO_QUARTIC, plate.MAX_TO_QUARTIC_ANY):
        spared = plate.plate_evidence(image, xy, extent, angles, enough_to_quartic=bar).to_quartic
        assert np.array_equal(spared <= bar, searched <= bar), bar
        assert np.all(spared >= searched)
    assert np.sum(searched[:4] <= plate.MAX_TO_QUARTIC) == 4


@pytest.mark.parametrize("seed", range(3))
def test_a_wide_window_read_on_a_coarser_grid_parts_a_marker_from_a_saddle_as_the_whole_does(
    seed, monkeypatch
):
    # A 12 px marker and a smooth saddle read at 8.49 px: a window of 17 px, 889
    # pixels, read on every other row and column (225) under the pixel budget.
    placement = MarkerPlacement(60.3, 59.8, 12.0, 0.4 + seed, 30.0, kind="quarter_disks")
    scene = render_markers(
        (120, 120), [placement], seed, blur_sigma_px=1.0, noise_sigma_dn=2.0, background="texture"
    )
    y, x = np.mgrid[:120, :120] - 60.0
    noise = np.random.default_rng(seed).normal(0, 2.0, x.shape)
    saddle = np.clip(128 + 60 * (x * x - y * y) / 289.0 + noise, 0, 255).round().astype(np.uint8)
    image = np.hstack([scene.image, saddle])
    xy = np.array([scene.centres[0], [180.0, 60.0]])
    angles = np.array([scene.markers[0].angles, [np.pi / 4, 3 * np.pi / 4]])
    extent = np.full(2, 8.49)

    def read() -> np.ndarray:
        return plate.plate_evidence(
            image, xy, extent, angles, scale_with_extent=True, quadrant_levels=True
        ).to_quartic

    budgeted = read()
    monkeypatch.setattr(plate, "MAX_WINDOW_PIXELS", 10**6)
    whole = read()
    for reading in (budgeted, whole):
        assert reading[0] <= plate.MAX_TO_QUARTIC
        assert reading[1] > plate.MAX_TO_QUARTIC_ANY
