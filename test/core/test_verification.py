"""Section 3.2, geometric checks: annular centre symmetry and LSD double line."""

import cv2
import numpy as np
import pytest

from marker_localizer.config import DetectorConfig
from marker_localizer.core import verification
from marker_localizer.core.screening import Candidates
from marker_localizer.synthetic import MarkerPlacement, render_markers

CENTRE = np.array([[64.3, 63.6]])


def _render(
    kind: str, radius: float = 20.0, rotation: float = 0.3, tilt: float = 0.0, blur: float = 1.0
) -> np.ndarray:
    scene = render_markers(
        (128, 128),
        [MarkerPlacement(*CENTRE[0], radius, rotation, tilt, 0.7, kind)],
        0,
        blur_sigma_px=blur,
        noise_sigma_dn=2.0,
    )
    return scene.image.astype(np.float32) / 255.0


def _check(image: np.ndarray) -> verification.SymmetryCheck:
    return verification.centre_symmetry_check(
        image, CENTRE, verification.ring_radii((3.0, 40.0)), min_contrast=20 / 255, min_symmetry=0.8
    )


@pytest.mark.parametrize("kind", ["quarter_disks", "checker"])
@pytest.mark.parametrize("tilt", [0.0, 55.0])
def test_symmetry_check_accepts_a_blurred_tilted_x(kind, tilt):
    check = _check(_render(kind, tilt=tilt, blur=1.4))
    assert check.accepted[0]
    assert check.score[0] > 0.9
    assert check.radius_px[0] >= 8.0


@pytest.mark.parametrize(
    "kind", ["l_corner", "quarter_disk", "t_junction", "plus", "blob", "triangle"]
)
def test_symmetry_check_rejects_look_alikes(kind):
    assert not _check(_render(kind)).accepted[0]


def _x_fading_at(
    outline_px: float,
    contrast_past: float,
    contrast_inside: float = 0.6,
    blur_px: float = 1.0,
    mean: float = 0.5,
) -> np.ndarray:
    """An X about ``mean``: ``contrast_inside`` to ``outline_px``, ``contrast_past`` beyond."""
    y, x = np.mgrid[:128, :128] - CENTRE[0, ::-1, None, None]
    sign = np.sign(np.cos(2.0 * (np.arctan2(y, x) - 0.3)))
    contrast = np.where(np.hypot(x, y) <= outline_px, contrast_inside, contrast_past)
    return cv2.GaussianBlur((mean + 0.5 * contrast * sign).astype(np.float32), (0, 0), blur_px)


def test_an_xs_run_of_rings_ends_at_its_first_dim_ring():
    # A marker's dark quadrants on dark ground: its X goes on past the outline at a
    # fifth of its contrast. The ring along the outline may end the run; the dim
    # rings past it do not carry it on, as rings of the full contrast do.
    radii = verification.ring_radii((6.0, 24.0))
    extent = {
        past: verification.centre_symmetry_check(
            _x_fading_at(7.0, past), CENTRE, radii, min_contrast=20 / 255, min_symmetry=0.8
        ).radius_px[0]
        for past in (0.12, 0.6)
    }
    assert extent[0.12] == radii[radii > 7.0][0]
    assert extent[0.6] == radii[-1]


def _faint_x(blur_px: float, centre_share: float = 1.0) -> np.ndarray:
    """An X of contrast 0.14 (under twice the 20 DN floor), within 3.5 px ``centre_share`` of it."""
    return _x_fading_at(3.5, 0.14, centre_share * 0.14, blur_px, mean=0.3)


def test_a_faint_xs_innermost_rings_dimmed_by_its_blur_still_start_its_run():
    # Blurred by 1.8 px, the X's rings at 2 and 2.8 px, where a run must start,
    # keep 0.3 and 0.5 of its contrast, under the floor; the rings past them clear it.
    image = _faint_x(1.8)
    radii = verification.ring_radii((4.0, 40.0))
    contrast = verification.analyse_rings(
        verification.annular_profiles(image, CENTRE, radii[:3])
    ).contrast[0]
    assert (contrast[:2] < 20 / 255).all() and contrast[2] > 20 / 255
    check = verification.centre_symmetry_check(
        image, CENTRE, radii, min_contrast=20 / 255, min_symmetry=0.8
    )
    assert check.accepted[0]
    assert check.radius_px[0] == radii[-1]


def test_a_junction_whose_centre_is_fainter_than_blur_makes_it_starts_no_run():
    # Texture's blurred junctions: four blobs meet round a flat centre, softer than
    # the widest blur leaves an X's (verification.blurred_contrast_share).
    accepted = {
        share: verification.centre_symmetry_check(
            _faint_x(1.0, share),
            CENTRE,
            verification.ring_radii((4.0, 40.0)),
            min_contrast=20 / 255,
            min_symmetry=0.8,
        ).accepted[0]
        for share in (0.0, 1.0)
    }
    assert accepted == {0.0: False, 1.0: True}


def test_symmetry_check_measures_the_line_angles():
    rotation = 0.3
    check = _check(_render("checker", rotation=rotation, blur=0.8))
    expected = np.sort(np.array([rotation, rotation + np.pi / 2]) % np.pi)
    np.testing.assert_allclose(np.sort(check.line_angles[0]), expected, atol=np.deg2rad(1.5))


def test_analyse_rings_counts_four_sectors_only_on_an_x():
    theta = np.deg2rad(np.arange(36) * 10.0)
    x_profile = np.sign(np.cos(2 * theta + 0.1))
    l_profile = np.where((theta > 0.1) & (theta < np.pi / 2 + 0.1), -1.0, 1.0)
    rings = verification.analyse_rings(np.stack([x_profile, l_profile])[:, None, :])
    assert rings.four_sectors[:, 0].tolist() == [True, False]
    assert rings.symmetry[0, 0] > 0.99 > rings.symmetry[1, 0]


#: The double line check as the detector runs it, at the configuration's defaults.
LINE_CHECK = {
    "extend_px": DetectorConfig().line_extend_px,
    "max_distance_px": DetectorConfig().line_max_distance_px,
}


def test_double_line_check_accepts_an_x_and_returns_its_two_lines():
    image = np.clip(_render("checker", rotation=0.3) * 255, 0, 255).astype(np.uint8)
    lines = verification.double_line_check(image, CENTRE, np.array([20.0]), **LINE_CHECK)
    assert lines.accepted[0]
    assert lines.distance_px[0] < 1.0
    expected = np.sort(np.array([0.3, 0.3 + np.pi / 2]) % np.pi)
    np.testing.assert_allclose(np.sort(lines.line_angles[0]), expected, atol=np.deg2rad(2.0))


@pytest.mark.parametrize("kind", ["quarter_disks", "checker"])
@pytest.mark.parametrize(("blur", "exposure"), [(1.4, 4.0), (2.0, 3.0)])
def test_double_line_check_finds_the_lines_of_an_x_whose_white_paint_clips(kind, blur, exposure):
    # Clipped at white, each blurred edge moves to its dark side, a line's two halves
    # to opposite sides: halves of different lines cross 2.1-2.6 px from the centre.
    # The lines midway between each line's halves cross at it.
    image = np.clip(np.round(exposure * _render(kind, blur=blur) * 255), 0, 255).astype(np.uint8)
    lines = verification.double_line_check(image, CENTRE, np.array([20.0]), **LINE_CHECK)
    assert lines.accepted[0]
    assert lines.distance_px[0] < 0.5
    expected = np.sort(np.array([0.3, 0.3 + np.pi / 2]) % np.pi)
    np.testing.assert_allclose(np.sort(lines.line_angles[0]), expected, atol=np.deg2rad(2.0))


def test_double_line_check_pairs_a_lines_halves_only_where_its_window_clips():
    # The same over-exposed X scaled under white: nothing says its edges were moved
    # by clipping, and halves that miss the centre by 2 px are no X's line.
    exposed = np.clip(np.round(3.0 * _render("quarter_disks", blur=2.0) * 255), 0, 255)
    dimmed = np.round(0.97 * exposed).astype(np.uint8)
    lines = verification.double_line_check(dimmed, CENTRE, np.array([20.0]), **LINE_CHECK)
    assert not lines.accepted[0]
    assert lines.distance_px[0] > 2.0


def test_double_line_check_rejects_a_single_straight_edge():
    image = np.full((128, 128), 40, np.uint8)
    image[:, 64:] = 200
    lines = verification.double_line_check(image, CENTRE, np.array([20.0]), **LINE_CHECK)
    assert not lines.accepted[0]


def _edge_check(image: np.ndarray, start: np.ndarray = CENTRE) -> verification.EdgePhaseCheck:
    return verification.edge_phase_check(
        image, start, verification.ring_radii((6.0, 40.0)), min_contrast=20 / 255
    )


@pytest.mark.parametrize("kind", ["quarter_disks", "checker"])
@pytest.mark.parametrize("tilt", [0.0, 55.0])
def test_the_papers_annular_check_accepts_an_x_and_moves_a_start_1_5_px_off_onto_it(kind, tilt):
    image = _render(kind, tilt=tilt, blur=1.4)
    check = _edge_check(image, CENTRE + [[1.2, -0.9]])
    assert check.accepted[0]
    assert np.linalg.norm(check.xy[0] - CENTRE[0]) < 0.5
    assert check.radius_px[0] >= 8.0


@pytest.mark.parametrize("dull_factor", [0.45, 0.6])
def test_the_lines_crossing_finds_the_centre_a_dull_quadrant_hides_from_grey_level_symmetry(
    dull_factor,
):
    # The rings' edges stay where the X's lines are, whatever the quadrants' levels:
    # started where a fit of grey-level symmetry ends, 1-3 px off, the candidate
    # moves back onto the centre; without lines it stays where it is.
    dull = MarkerPlacement(
        *CENTRE[0], 18.0, 0.3, 30.0, 0.7, "quarter_disks", dull_factor=dull_factor
    )
    scene = render_markers((128, 128), [dull], 0, blur_sigma_px=1.0, noise_sigma_dn=2.0)
    image = scene.image.astype(np.float32) / 255.0
    starts = CENTRE + np.array([[1.5, -1.0], [-2.0, 1.5]])
    moved, found = verification.line_crossing_centres(
        image, starts, verification.ring_radii((6.0, 40.0))[:3], min_contrast=20 / 255
    )
    assert found.all()
    assert np.linalg.norm(moved - scene.centres[0], axis=1).max() < 0.3
    flat = np.full_like(image, 0.5)
    stay, lines = verification.line_crossing_centres(
        flat, starts, verification.ring_radii((6.0, 40.0))[:3], min_contrast=20 / 255
    )
    assert not lines.any()
    np.testing.assert_array_equal(stay, starts)


@pytest.mark.parametrize(
    "kind", ["l_corner", "quarter_disk", "t_junction", "bar", "blob", "plus", "triangle"]
)
def test_the_papers_annular_check_rejects_look_alikes(kind):
    assert not _edge_check(_render(kind)).accepted[0]


def test_the_papers_annular_check_measures_the_line_angles():
    rotation = 0.3
    check = _edge_check(_render("checker", rotation=rotation, blur=0.8))
    expected = np.sort(np.array([rotation, rotation + np.pi / 2]) % np.pi)
    np.testing.assert_allclose(np.sort(check.line_angles[0]), expected, atol=np.deg2rad(1.5))


def _sector_profile(levels: list[float], edges_deg: list[float]) -> np.ndarray:
    """A ring of 36 samples (sample k at 10 k degrees): ``levels[i]`` from ``edges_deg[i]`` on."""
    theta = np.arange(36) * 10.0
    sector = np.searchsorted(np.array(edges_deg), theta) % len(edges_deg) - 1
    return np.array(levels)[sector]


def test_an_x_ring_has_a_line_of_each_sign_and_a_straight_edge_ring_has_none():
    rings = np.stack(
        [
            _sector_profile([1.0, 0.1, 1.0, 0.1], [25, 115, 205, 295]),  # X
            _sector_profile([1.0, 0.1], [25, 205]),  # a straight edge through the centre
            _sector_profile([1.0, 0.1], [25, 115]),  # an L corner
            _sector_profile([1.0, 0.1, 0.5], [25, 205, 295]),  # a T junction
        ]
    )[:, None, :]
    found = verification.analyse_ring_edges(rings, min_contrast=0.1)
    assert found.good[:, 0].tolist() == [True, False, False, False]
    np.testing.assert_allclose(
        np.sort(np.rad2deg(found.line_angles[0, 0])), [25.0, 115.0], atol=1.0
    )


def test_a_dull_bright_sector_and_a_shadow_edge_keep_the_edge_phases_not_the_grey_symmetry():
    """Issue 13, item 4: what survives uneven light is the edges' phase and polarity."""
    dull = _sector_profile([1.0, 0.1, 0.45, 0.1], [25, 115, 205, 295])
    # A shadow edge crossing the ring inside the bright sector, 50 % darker beyond it.
    shadowed = _sector_profile([1.0, 0.5, 0.05, 0.5, 0.05], [25, 65, 115, 205, 295])
    rings = np.stack([dull, shadowed])[:, None, :]
    assert verification.analyse_ring_edges(rings, min_contrast=0.1).good[:, 0].all()
    assert (verification.analyse_rings(rings).symmetry[:, 0] < 0.8).all()


def test_the_chords_of_an_xs_lines_cross_at_its_centre_seen_from_off_centre():
    centre = np.array([10.0, 20.0])
    ring_centre = centre + [0.8, -0.6]
    radius = 6.0
    ends = []
    for angle in (0.4, 1.9):  # two lines through the true centre
        direction = np.array([np.cos(angle), np.sin(angle)])
        # where the line meets the ring around ring_centre: |centre + t d - ring_centre| = r
        w = centre - ring_centre
        b, c = w @ direction, w @ w - radius**2
        t = np.array([-b + np.sqrt(b * b - c), -b - np.sqrt(b * b - c)])
        points = centre + t[:, None] * direction - ring_centre
        ends.append(np.arctan2(points[:, 1], points[:, 0]))
    crossings = np.array(ends)[None, None]  # (1, 1, line, end)
    found = verification.chord_crossing(ring_centre[None], np.array([radius]), crossings)
    np.testing.assert_allclose(found[0, 0], centre, atol=1e-9)


def _ring(levels: list[float], edges_deg: list[float]) -> np.ndarray:
    """A 36-sample ring profile: ``levels[k]`` from edge k to edge k + 1 (degrees)."""
    angles = np.arange(36) * 10.0 + 5.0
    profile = np.full(36, levels[-1])
    for level, start, end in zip(levels, edges_deg, edges_deg[1:] + [360.0], strict=True):
        profile[(angles >= start) & (angles < end)] = level
    return profile


def test_sector_order_sees_an_x_with_a_dull_bright_quadrant_and_names_its_two_lines():
    # Bright, dark, dull bright (0.45 of the other), dark: rising at 0/180, falling at 70/250.
    ring = _ring([200.0, 20.0, 90.0, 20.0], [0.0, 70.0, 180.0, 250.0])
    order = verification.sector_order(ring[None])
    assert order.strength[0] > 10.0
    # Within a sample (10 degrees) of the true directions.
    assert order.rising[0] in (0, 17) and order.falling[0] in (6, 7)


def test_sector_order_keeps_an_x_that_a_shadow_edge_crosses():
    # The X of the dull test, darkened by half from 120 to 160 degrees.
    ring = _ring([200.0, 20.0, 10.0, 90.0, 20.0], [0.0, 70.0, 120.0, 180.0, 250.0])
    ring[(np.arange(36) * 10 + 5 >= 120) & (np.arange(36) * 10 + 5 < 180)] *= 0.5
    assert verification.sector_order(ring[None]).strength[0] > 5.0


@pytest.mark.parametrize(
    "levels, edges",
    [
        ([200.0, 20.0], [0.0, 90.0]),  # an L corner: one dark quadrant
        ([200.0, 20.0], [0.0, 180.0]),  # a straight edge
        ([200.0, 20.0, 200.0, 20.0], [0.0, 30.0, 180.0, 270.0]),  # edges not antipodal
    ],
)
def test_sector_order_rejects_what_is_not_an_x(levels, edges):
    assert verification.sector_order(_ring(levels, edges)[None]).strength[0] <= 0.0


def test_the_prescreen_passes_an_x_on_three_rings_and_names_its_line_directions():
    image = _render("quarter_disks", rotation=0.3) * 255.0
    passed, angles = verification.prescreen_sector_order(
        image, CENTRE, np.array([[5.0, 3.5, 6.0]]), np.array([5.0])
    )
    assert passed[0]
    lines = np.sort(angles[0] % np.pi)
    np.testing.assert_allclose(lines, np.sort([0.3, 0.3 + np.pi / 2]), atol=np.deg2rad(10.0))


def test_a_point_no_ring_test_passed_still_takes_its_line_directions_from_the_first_ring():
    # A dim X, weaker than any prescreen would ask: its directions are read all the same.
    image = 100.0 + 10.0 * _render("quarter_disks", rotation=0.3)
    scale = np.array([8.0])
    angles = verification.prescreen_line_directions(image, CENTRE, scale, 6.0)
    passed, _ = verification.prescreen_sector_order(
        image, CENTRE, verification.prescreen_ring_radii(scale, 6.0), np.array([1e3])
    )
    assert not passed[0]
    lines = np.sort(angles[0] % np.pi)
    np.testing.assert_allclose(lines, np.sort([0.3, 0.3 + np.pi / 2]), atol=np.deg2rad(10.0))


def test_an_x_reaches_the_required_extent_only_from_that_share_of_the_smallest_radius():
    reached = verification.reaches_extent(np.array([2.7, 2.8, 2.8 - 1e-6]), 0.7, 4.0)
    assert reached.tolist() == [False, True, False]


def test_the_template_disk_is_a_share_of_the_extent_within_its_bounds():
    radius = verification.template_radius(np.array([1.0, 10.0, 100.0]), max_radius_px=40.0)
    np.testing.assert_array_equal(
        radius,
        [verification.TEMPLATE_MIN_RADIUS_PX, verification.TEMPLATE_RADIUS_FRACTION * 10, 40],
    )


def test_the_lsd_lines_replace_the_rings_only_where_both_agree():
    rings = np.array([[0.3, 1.9], [0.3, 1.9]])
    close = rings[0] + np.deg2rad(4.0)
    far = rings[1] + np.deg2rad([6.0, 0.0])
    agreed = verification.agreed_line_angles(np.array([close, far]), rings)
    np.testing.assert_array_equal(agreed, [close, rings[1]])


def test_the_modulation_gate_rejects_a_dim_small_x_and_never_tests_a_large_one():
    dim = 0.4 + 0.2 * _render("quarter_disks", radius=6.0)  # modulation ~0.2 at most
    angles = _check(_render("quarter_disks", radius=6.0)).line_angles
    gate = {
        (contrast, radius): verification.modulation_gate(
            image, CENTRE, angles, np.array([radius]), np.array([3.0]), 4.0, 0.3
        )[0]
        for contrast, image in (("full", _render("quarter_disks", radius=6.0)), ("dim", dim))
        for radius in (6.0, verification.TEXTURE_EXTENT_PX)
    }
    assert gate == {
        ("full", 6.0): True,
        ("dim", 6.0): False,
        ("full", verification.TEXTURE_EXTENT_PX): True,
        ("dim", verification.TEXTURE_EXTENT_PX): True,
    }


def test_the_modulation_gate_does_not_test_levels_the_blur_mixes():
    dim = 0.4 + 0.2 * _render("quarter_disks", radius=6.0)
    angles = _check(_render("quarter_disks", radius=6.0)).line_angles
    # Nearer the centre than MODULATION_MIN_OFFSET_PX, or (a marker of the expected
    # size) than MODULATION_FREE_OFFSET_PX, the levels are not judged.
    for offset, radius in ((2.4, 3.0), (2.8, 6.0)):
        assert verification.modulation_gate(
            dim, CENTRE, angles, np.array([radius]), np.array([offset]), 4.0, 0.3
        ).all()


def test_texture_sized_detections_need_the_floor_of_their_extent():
    radius = np.array([5.9, 6.0, 8.9, verification.TEXTURE_EXTENT_PX, 20.0])
    floors = verification.texture_score_floor(radius, min_score=0.8)
    np.testing.assert_array_equal(floors, [0.92, 0.88, 0.88, 0.8, 0.8])
    # A configured score above a floor wins.
    assert verification.texture_score_floor(radius, min_score=0.9).tolist() == [
        0.92,
        0.9,
        0.9,
        0.9,
        0.9,
    ]


def test_a_small_marker_is_no_larger_than_the_smallest_expected_nor_than_texture_makes():
    extents = np.array([2.0, 2.83, 4.0, 4.24, 5.66, 6.0, 12.0])
    small = verification.small_marker(extents, min_radius_px=4.0)
    assert small.tolist() == [True, True, True, False, False, False, False]
    assert verification.small_marker(extents, min_radius_px=2.5).sum() == 1
    # Texture's extent bounds the rule: larger expected markers ask no more of one.
    for min_radius_px in (6.0, 10.0, 20.0):
        np.testing.assert_array_equal(verification.small_marker(extents, min_radius_px), small)


def test_the_minimum_score_is_min_score_small_for_small_markers_else_the_texture_floor():
    radius = np.array([4.1, 5.0, 20.0])
    needed = verification.minimum_score(radius, 0.8, 0.945, min_radius_px=4.0)
    np.testing.assert_array_equal(needed, [0.945, 0.92, 0.8])


@pytest.mark.parametrize(
    ("radius_range", "first"), [((4.0, 40.0), 2.0), ((6.0, 24.0), 3.0), ((2.5, 5.0), 1.5)]
)
def test_the_ring_ladder_steps_by_root_two_from_half_the_smallest_radius(radius_range, first):
    # 2.5-5 px starts at the ladder's 1.5 px floor, not at 1.25.
    radii = verification.ring_radii(radius_range)
    assert radii[0] == pytest.approx(first)
    np.testing.assert_allclose(radii[1:] / radii[:-1], verification.RING_STEP)
    # It ends at its last rung within the largest expected radius (to rounding: 6-24 px
    # ends at 16.97, its next rung 24.000000000000004).
    slack = 1.0 + 1e-9
    assert radii[-1] <= radius_range[1] * slack
    assert radius_range[1] < radii[-1] * verification.RING_STEP * slack


def test_the_prescreen_rings_scale_with_the_candidate_above_a_floor():
    radii = verification.prescreen_ring_radii(np.array([4.0, 16.0]), min_radius_px=6.0)
    np.testing.assert_allclose(radii[1], 16.0 * np.array(verification.PRESCREEN_RINGS))
    assert radii[0].min() == verification.PRESCREEN_MIN_RING_PX
    # Below twice the floor's radius the smallest expected marker bounds it.
    small = verification.prescreen_ring_radii(np.array([1.0]), min_radius_px=2.5)
    assert small.min() == verification.PRESCREEN_MIN_RING_FRACTION * 2.5


def test_a_capped_candidates_prescreen_rings_are_no_smaller_than_its_levels_own():
    # From a 6 px minimum the half-resolution level's candidates are given 6 px, not 8:
    # their outer rings shrink to fit the smallest marker, the inner one stays at 8 px's.
    capped, own = verification.prescreen_ring_radii(np.array([6.0, 8.0]), min_radius_px=6.0)
    np.testing.assert_allclose(capped, [3.0, 2.8, 3.6])
    np.testing.assert_allclose(own, 8.0 * np.array(verification.PRESCREEN_RINGS))


@pytest.mark.parametrize(
    "kind", ["quarter_disks", "checker", "l_corner", "quarter_disk", "t_junction", "plus"]
)
def test_the_symmetry_prescreen_passes_an_x_and_no_shape_without_its_symmetry(kind):
    image = _render(kind)
    radii = verification.prescreen_ring_radii(np.array([16.0]), min_radius_px=4.0)
    passed, _ = verification.prescreen_symmetry(image, CENTRE, radii, min_contrast=10 / 255)
    assert passed.tolist() == [kind in ("quarter_disks", "checker")]


def test_windows_enlarged_together_are_those_enlarged_one_by_one():
    rng = np.random.default_rng(5)
    shapes = [(13, 13), (13, 13), (9, 13), (13, 13), (5, 7), (9, 13), (25, 25), (6, 9), (6, 9)]
    windows = [rng.integers(0, 256, shape, dtype=np.uint8) for shape in shapes]
    zooms = [2, 2, 3, 2, 5, 3, 1, 4, 4]
    for window, zoom, together in zip(
        windows, zooms, verification.upsampled(windows, zooms), strict=True
    ):
        alone = cv2.resize(window, None, fx=zoom, fy=zoom, interpolation=cv2.INTER_CUBIC)
        np.testing.assert_array_equal(together, alone if zoom > 1 else window)


def test_equalising_the_bright_sectors_restores_a_dull_quadrants_symmetry_and_nothing_else():
    dull = _sector_profile([1.0, 0.1, 0.45, 0.1], [25, 115, 205, 295])
    even = _sector_profile([1.0, 0.1, 1.0, 0.1], [25, 115, 205, 295])
    # Texture: bright sectors that differ in width, or dark ones that differ in level.
    uneven_widths = _sector_profile([1.0, 0.1, 0.45, 0.1], [25, 65, 205, 295])
    uneven_darks = _sector_profile([1.0, 0.1, 0.45, 0.5], [25, 115, 205, 295])
    rings = np.stack([dull, even, uneven_widths, uneven_darks])[:, None, :]
    plain = verification.analyse_rings(rings)
    equalised = verification.analyse_rings(verification.equalise_bright_sectors(rings))
    assert plain.symmetry[0, 0] < 0.5 and not plain.four_sectors[0, 0]
    assert equalised.symmetry[0, 0] > 0.99 and equalised.four_sectors[0, 0]
    np.testing.assert_array_equal(verification.equalise_bright_sectors(even), even)
    assert (equalised.symmetry[2:, 0] < 0.5).all()
    assert not equalised.four_sectors[2:, 0].any()


def test_the_rings_balance_reads_a_dull_bright_sectors_share_and_an_even_x_as_one():
    dull = _sector_profile([1.0, 0.1, 0.55, 0.1], [25, 115, 205, 295])
    even = _sector_profile([1.0, 0.1, 1.0, 0.1], [25, 115, 205, 295])
    flat = np.full(36, 0.5)
    cut = even.copy()
    cut[3] = np.nan  # the ring leaves the image
    balance = verification.bright_sector_balance(np.stack([[dull, even], [flat, cut]]))
    np.testing.assert_allclose(balance[0], [0.5, 1.0])
    assert np.isnan(balance[1]).all()


def test_the_rings_balance_of_a_rendered_x_reads_its_dull_quadrant_not_a_lights_slope():
    # A 16 px X tilted 20 degrees, the ring at half its radius: a dull quadrant reads
    # its lead over the dark paint as a share of the other's (the renderer's dull
    # margin); even paint under a light whose gain spans 0.7-1 across the 96 px frame
    # reads near 1.
    def reading(dull_factor: float, light: float) -> tuple[float, float]:
        placement = MarkerPlacement(47.6, 48.3, 16.0, 0.5, 20.0, dull_factor=dull_factor)
        scene = render_markers(
            (96, 96),
            [placement],
            0,
            blur_sigma_px=1.0,
            noise_sigma_dn=1.0,
            illumination_strength=light,
        )
        rings = verification.annular_profiles(scene.image, scene.centres, np.array([8.0]))
        return float(verification.bright_sector_balance(rings)[0, 0]), scene.markers[0].dull_margin

    for dull_factor in (0.6, 0.8):
        balance, margin = reading(dull_factor, 0.0)
        assert abs(balance - margin) < 0.03
    assert reading(1.0, 0.6)[0] > 0.93


def _two_edges_crossing(blur_px: float = 0.0) -> np.ndarray:
    """An X without an end: two straight edges crossing a 64 px window at (31.5, 31.5)."""
    crossing = np.full((64, 64), 200.0, np.float32)
    crossing[:32, :32] = crossing[32:, 32:] = 40.0
    return cv2.GaussianBlur(crossing, (0, 0), blur_px) if blur_px else crossing


def _small_marker(seed: int, radius_px: float = 4.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    placement = MarkerPlacement(32.3, 31.6, radius_px, 0.4, 20.0)
    scene = render_markers((64, 64), [placement], seed, blur_sigma_px=0.8, noise_sigma_dn=2.0)
    return scene.image, scene.centres, np.array([scene.markers[0].angles])


def test_a_tiny_markers_x_ends_at_its_extent_where_a_crossing_of_two_edges_goes_on():
    extent = np.array([4.0])
    ended = []
    for seed in range(4):
        image, centre, angles = _small_marker(seed)
        ended.append(verification.modulation_beyond_extent(image, centre, extent, angles)[0])
    # The same X without its end.
    crossing = _two_edges_crossing(0.8)
    goes_on = verification.modulation_beyond_extent(
        crossing, np.array([[31.5, 31.5]]), extent, np.array([[0.0, np.pi / 2]])
    )[0]
    assert max(ended) < verification.MAX_MODULATION_BEYOND < 0.9 < goes_on


def test_only_xs_of_textures_size_not_under_the_smallest_radius_are_asked_to_end():
    extents = np.array([2.1, 3.0, 4.24, 5.0, 8.5])
    asked = verification.x_must_end(extents, 3.0)
    np.testing.assert_array_equal(asked, [False, True, True, False, False])
    # A tighter range asks fewer X's, never more: it cannot lose a marker this way.
    tighter = verification.x_must_end(extents, 4.0)
    assert not (tighter & ~asked).any() and tighter.sum() < asked.sum()


def test_an_x_the_gate_is_not_asked_about_always_passes():
    crossing = _two_edges_crossing()
    ends = verification.x_ends(
        crossing,
        np.array([[31.5, 31.5], [31.5, 31.5]]),
        np.array([4.0, 8.0]),
        np.array([[0.0, np.pi / 2], [0.0, np.pi / 2]]),
        min_radius_px=3.0,
        max_radius_px=30.0,
        under_floor=np.array([False, False]),
    )
    np.testing.assert_array_equal(ends, [False, True])


def test_an_x_read_a_rung_short_of_its_reach_ends_a_rung_further_out():
    # A marker of 8 px whose rings stopped at 4 px (clutter, a tilt) goes on beyond
    # its extent, and has ended a ring rung further out; two crossing edges have not.
    image, centre, angles = _small_marker(0, radius_px=8.0)
    extent = np.array([4.0])
    beyond = verification.modulation_beyond_extent(image, centre, extent, angles)[0]
    assert beyond > verification.MAX_MODULATION_BEYOND
    crossing = _two_edges_crossing(0.8)
    for picture, xy, lines, kept in (
        (image, centre, angles, True),
        (crossing, np.array([[31.5, 31.5]]), np.array([[0.0, np.pi / 2]]), False),
    ):
        ended = verification.x_ends(picture, xy, extent, lines, 3.0, 30.0, np.array([False]))
        assert ended[0] is np.True_ if kept else ended[0] is np.False_
    # Not where no expected marker reaches a rung out (tiny markers, 2.5-5 px).
    assert not verification.x_ends(image, centre, extent, angles, 2.5, 5.0, np.array([False]))[0]


def test_under_its_floor_only_an_x_that_has_clearly_ended_passes():
    image, centre, angles = _small_marker(0)
    extent = np.array([4.0])
    beyond = verification.modulation_beyond_extent(image, centre, extent, angles)[0]
    assert beyond <= verification.CLEARLY_ENDED
    crossing = _two_edges_crossing()
    for picture, xy, lines, kept in (
        (image, centre, angles, True),
        (crossing, np.array([[31.5, 31.5]]), np.array([[0.0, np.pi / 2]]), False),
    ):
        under = verification.x_ends(picture, xy, extent, lines, 3.0, 30.0, np.array([True]))
        assert under[0] is np.True_ if kept else under[0] is np.False_
    # Not asked (wider than texture's saddles), a candidate under its floor fails it.
    wide = verification.x_ends(image, centre, np.array([8.0]), angles, 3.0, 30.0, np.array([True]))
    assert not wide[0]


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_a_candidate_whose_rings_find_no_lines_stays_where_it_was_and_says_so_quietly():
    # Quietly: a warnings filter would be process-wide, and the node's workers are threads.
    flat = np.full((64, 64), 100.0)
    xy = np.array([[32.0, 32.0], [30.5, 33.5]])
    moved, found = verification.line_crossing_centres(
        flat, xy, np.array([3.0, 4.24, 6.0]), min_contrast=5.0
    )
    np.testing.assert_array_equal(moved, xy)
    assert not found.any()


def _checks(accepted, score, radius_px) -> verification.SymmetryCheck:
    n = len(accepted)
    return verification.SymmetryCheck(
        np.asarray(accepted, bool),
        np.asarray(score, float),
        np.asarray(radius_px, float),
        np.tile([0.2, 1.8], (n, 1)),
        np.full(n, 0.5),
    )


def test_the_equalised_rings_are_believed_out_to_texture_free_extents_and_never_widen_a_sound_x():
    wide = verification.EQUALISED_MIN_EXTENT_PX
    plain = _checks(
        accepted=[False, True, True, True, False],
        score=[0.0, 0.85, 0.95, 0.95, 0.0],
        radius_px=[4.0, 8.5, 8.5, 8.5, 4.0],
    )
    # Rows: rejected plain; plain under its floor; plain sound but equalised scores
    # higher and reads wider; plain sound and equalised lower; equalised too short.
    equalised = _checks(
        accepted=[True, True, True, True, True],
        score=[0.9, 0.93, 0.97, 0.90, 0.99],
        radius_px=[12.0, 12.0, 12.0, 12.0, wide - 1.0],
    )
    rows = np.arange(5)
    merged = verification.with_equalised(plain, rows, equalised, np.full(5, 0.9))
    assert merged.accepted.tolist() == [True, True, True, True, False]
    assert merged.score.tolist() == [0.9, 0.93, 0.97, 0.95, 0.0]
    # The sound X keeps its plain extent; under its floor or rejected, the equalised stands.
    assert merged.radius_px.tolist() == [12.0, 12.0, 8.5, 8.5, 4.0]


def _dull_x(dull: float) -> np.ndarray:
    placement = MarkerPlacement(*CENTRE[0], 16.0, 0.4, 20.0, 0.3, dull_factor=dull)
    scene = render_markers((128, 128), [placement], 0, blur_sigma_px=1.0, noise_sigma_dn=1.0)
    return scene.image


def _ring_check(image: np.ndarray, xy: np.ndarray, wide: bool) -> verification.RingReading:
    return verification.ring_check(
        verification.RingReader(image, verification.ring_radii((5.0, 30.0)), 20 / 255, 0.8),
        Candidates(xy, np.ones(len(xy)), np.full(len(xy), 8.0 if wide else 4.0)),
        np.array([wide]),
        lambda extent: np.full(np.shape(extent), 0.9),
    )


@pytest.mark.parametrize("dull", [0.6, 0.45])
def test_the_equalised_rings_show_a_wide_x_with_a_dull_quadrant_that_the_plain_ones_reject(dull):
    image, near = _dull_x(dull), CENTRE + [0.3, -0.3]
    plain = verification.centre_symmetry_check(
        image, near, verification.ring_radii((5.0, 30.0)), min_contrast=20 / 255, min_symmetry=0.8
    )
    assert not plain.accepted[0]
    wide = _ring_check(image, near, wide=True)
    assert wide.equalised_x[0] and wide.check.accepted[0]
    assert wide.check.radius_px[0] >= verification.EQUALISED_MIN_EXTENT_PX
    # Screened at texture's scale, and shown by no plain ring, it is not read equalised.
    narrow = _ring_check(image, near, wide=False)
    assert not narrow.equalised_x[0] and not narrow.check.accepted[0]


@pytest.mark.parametrize("offset", [(1.2, -0.2), (2.0, 0.5)])
def test_a_wide_candidate_left_off_its_x_moves_to_where_the_lines_cross(offset):
    image, off = _dull_x(0.45), CENTRE + offset
    wide = _ring_check(image, off, wide=True)
    assert wide.check.accepted[0]
    assert np.hypot(*(wide.candidates.xy[0] - CENTRE[0])) < 0.25
    narrow = _ring_check(image, off, wide=False)
    assert not narrow.check.accepted[0]
    assert narrow.candidates.xy.tolist() == off.tolist()


def test_an_x_of_textures_scale_that_the_plain_rings_show_wide_is_read_equalised_too():
    # Screened at texture's scale, but shown out to EQUALISED_MIN_EXTENT_PX by the
    # plain rings: the equalised reading may raise its score.
    image = _dull_x(0.9)
    reading = _ring_check(image, CENTRE + [0.3, -0.3], wide=False)
    assert reading.check.accepted[0]
    assert reading.check.radius_px[0] >= verification.EQUALISED_MIN_EXTENT_PX
    assert reading.equalised_x[0]


def _painted(paint: np.ndarray) -> np.ndarray:
    """A paint map (0 dark, 1 bright) as an image: levels 40-200, blurred by 1 px."""
    return cv2.GaussianBlur((40.0 + 160.0 * paint).astype(np.float32), (0, 0), 1.0)


def _corner_image(board: bool) -> np.ndarray:
    """An X of 16 px at (80, 80), its lines the axes: a chessboard's corner or a lone X."""
    y, x = np.mgrid[:161, :161] - 80.0
    if board:
        paint = (np.floor(x / 16.0) + np.floor(y / 16.0)) % 2
    else:
        paint = np.where(np.hypot(x, y) <= 16.0, (x * y > 0).astype(float), 0.5)
    return _painted(paint)


def test_a_boards_outermost_inner_corner_goes_on_along_two_half_lines_a_lone_edge_along_one():
    """A board's outermost inner corner continues on two half-lines: it counts as a board's.

    An X whose one half-line runs on as an edge (a lattice's saddle by a row of discs
    does this) does not: a chessboard's corner has at least two.
    """
    y, x = np.mgrid[:161, :161] - 80.0
    centre, extent, lines = np.array([[80.0, 80.0]]), np.array([16.0]), np.array([[0.0, np.pi / 2]])
    checker = (np.floor(x / 16.0) + np.floor(y / 16.0)) % 2
    # The board's squares start one square up and left of the corner: its margin beyond.
    board_corner = np.where((x >= -16.0) & (y >= -16.0), checker, 1.0)
    # A lone X, and one edge running on from it to the right: a band, dark above it.
    lone = np.where(np.hypot(x, y) <= 16.0, (x * y > 0).astype(float), 0.5)
    one_edge = np.where((x > 16.0) & (np.abs(y) <= 8.0), (y > 0).astype(float), lone)
    board, edge = (
        verification.line_continuation(_painted(paint), centre, extent, lines)[0]
        for paint in (board_corner, one_edge)
    )
    assert board > 0.5
    assert edge < 0.1


def test_a_large_boards_corner_goes_on_with_its_lines_read_three_degrees_off():
    """Far out along a board's line, samples 3 degrees either side still find its edge.

    A direction a degree or two off, or a bent board, moves the edge off samples a
    fixed 1.5 px either side of the line measured.
    """
    y, x = np.mgrid[:321, :321] - 160.0
    paint = (np.floor(x / 40.0) + np.floor(y / 40.0)) % 2
    board = _painted(paint)
    off = np.deg2rad(3.0)
    lines = np.array([[off, np.pi / 2 + off]])
    continuation = verification.line_continuation(
        board, np.array([[160.0, 160.0]]), np.array([40.0]), lines
    )
    assert continuation[0] > 0.5


def test_a_chessboard_repeats_its_corner_and_joins_it_by_its_lines_and_a_lone_x_neither():
    centre, extent, lines = np.array([[80.0, 80.0]]), np.array([16.0]), np.array([[0.0, np.pi / 2]])
    board, lone = _corner_image(board=True), _corner_image(board=False)
    assert verification.disk_recurrence(board, centre, extent)[0] > 0.9
    assert verification.disk_recurrence(lone, centre, extent)[0] < 0.3
    assert verification.line_continuation(board, centre, extent, lines)[0] > 0.5
    assert verification.line_continuation(lone, centre, extent, lines)[0] < 0.1
    # By the image's border it reads the copies whose opposite is inside too; an X
    # whose own disk leaves the image has none.
    assert verification.disk_recurrence(board, np.array([[20.0, 80.0]]), extent)[0] > 0.9
    assert verification.disk_recurrence(board, np.array([[4.0, 80.0]]), extent)[0] == 0.0


def test_by_the_border_a_lattice_recurs_twice_in_a_row_where_its_opposite_copies_are_cut_off():
    """Where the frame cuts an offset's opposite copy, the copy one period further stands in.

    At a board's corner two squares from the image's corner every offset's opposite
    copy is cut off; its copies at one and two periods inward are read. A lone X by
    the border whose ground repeats it once (one copy, nothing a period further) is
    no lattice: a marker's ground makes one copy by chance, not two in a row.
    """
    extent = np.array([16.0])
    board = _corner_image(board=True)
    assert verification.disk_recurrence(board, np.array([[32.0, 32.0]]), extent)[0] > 0.9
    y, x = np.mgrid[:161, :161] - 80.0

    def x_at(column: float, ground: np.ndarray | float) -> np.ndarray:
        """An X of 16 px centred at ``column`` on row 80, its lines the axes, on ``ground``."""
        dx = x - (column - 80.0)
        return np.where(np.hypot(dx, y) <= 16.0, (dx * y > 0).astype(float), ground)

    copied = x_at(64.0, x_at(24.0, 0.5))
    by_border = np.array([[24.0, 80.0]])
    assert verification.disk_recurrence(_painted(copied), by_border, extent)[0] < 0.3
    # The same X and copy with a second copy a period further: a row of three.
    row = x_at(104.0, copied)
    assert verification.disk_recurrence(_painted(row), by_border, extent)[0] > 0.9
