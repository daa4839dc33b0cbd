"""A cast shadow's edge across a marker: found where it is, divided out, nowhere else."""

import numpy as np
import pytest

from marker_localizer.core import shadow, uneven
from marker_localizer.synthetic import MarkerPlacement, render_markers
from marker_localizer.synthetic.scene import CastShadow

CENTRE = (64.3, 63.6)
RADIUS_PX = 16.0
#: Where the candidate sits: a pixel or so off the centre, as the screening leaves it.
CANDIDATE = np.array([[CENTRE[0] + 0.5, CENTRE[1] - 0.4]])


def _marker(cast: list[CastShadow], dull: float = 0.7, noise: float = 2.0):
    placement = MarkerPlacement(*CENTRE, RADIUS_PX, 0.4, 20.0, 0.3, dull_factor=dull)
    return render_markers(
        (128, 128), [placement], 0, blur_sigma_px=1.0, noise_sigma_dn=noise, cast_shadows=cast
    )


def _edges(
    scene, image: np.ndarray | None = None, white: float = 255.0, *, hypotheses: bool = False
) -> shadow.ShadowEdges:
    return shadow.find_edges(
        scene.image if image is None else image,
        CANDIDATE,
        np.array([RADIUS_PX]),
        np.array([scene.markers[0].angles]),
        white,
        decided_by_pairs=not hypotheses,
    )


@pytest.mark.parametrize(
    ("normal", "offset", "darkening"), [(0.7, 3.0, 0.5), (2.5, -4.0, 0.6), (4.0, 1.0, 0.45)]
)
def test_a_shadows_straight_edge_across_a_marker_is_found_where_it_is(normal, offset, darkening):
    edges = _edges(_marker([CastShadow(*CENTRE, normal, offset, darkening, 2 * RADIUS_PX)]))
    assert edges.found[0]
    turned = (edges.normal[0] - normal + np.pi) % (2 * np.pi) - np.pi
    assert abs(turned) < np.radians(3.0)
    # Its offset from the candidate, not from the centre.
    moved = (CANDIDATE[0] - CENTRE) @ [np.cos(normal), np.sin(normal)]
    assert abs(edges.offset[0] - (offset - moved)) < 0.5
    assert edges.depth[0] == pytest.approx(-np.log(1 - darkening), abs=0.15)


def test_the_edge_is_the_same_in_any_images_grey_levels():
    scene = _marker([CastShadow(*CENTRE, 0.7, 3.0, 0.5, 2 * RADIUS_PX)])
    eight_bit = _edges(scene)
    for image, white in (
        (scene.image.astype(np.uint16) * 257, 65535.0),
        (scene.image.astype(np.float32) / 255.0, 1.0),
    ):
        edges = _edges(scene, image, white)
        assert edges.found[0]
        np.testing.assert_allclose(
            [edges.normal[0], edges.offset[0], edges.depth[0]],
            [eight_bit.normal[0], eight_bit.offset[0], eight_bit.depth[0]],
            atol=1e-3,
        )


@pytest.mark.parametrize("dull", [1.0, 0.5])
def test_a_marker_in_even_light_shows_no_shadow_whatever_its_quadrants_levels(dull):
    # A dull quadrant is the quadrants' own levels, which the fit takes out first.
    assert not _edges(_marker([], dull=dull)).found[0]


@pytest.mark.parametrize("dull", [1.0, 0.7, 0.5])
def test_the_model_of_a_marker_in_even_light_keeps_no_edge_it_is_offered(dull):
    # The best edge of a dull X's pairs can be deep enough to try (one at its rim, where
    # the ground begins); the X's model, which reads the X alone, does not keep it.
    scene = _marker([], dull=dull)
    fit = uneven.locate_uneven(
        scene.image,
        CANDIDATE,
        np.array([scene.markers[0].angles]),
        np.array([RADIUS_PX]),
        255.0,
        _edges(scene, hypotheses=True),
    )
    assert fit.located[0]
    assert fit.shadow_share[0] == 0.0


def test_a_located_x_is_offered_the_edge_its_pairs_alone_would_turn_away():
    # In 6 DN of noise a shadow taking 40 % of the light explains 0.39 of the pairs'
    # variance, under MIN_EXPLAINED: no edge for a candidate, the edge for the model
    # of an X already located, which decides by what it explains of the X.
    normal, offset, darkening = 0.7, 3.0, 0.4
    scene = _marker([CastShadow(*CENTRE, normal, offset, darkening, 2 * RADIUS_PX)], noise=6.0)
    assert not _edges(scene).found[0]
    edges = _edges(scene, hypotheses=True)
    assert edges.found[0]
    assert edges.explained[0] < shadow.MIN_EXPLAINED
    turned = (edges.normal[0] - normal + np.pi) % (2 * np.pi) - np.pi
    assert abs(turned) < np.radians(3.0)
    moved = (CANDIDATE[0] - CENTRE) @ [np.cos(normal), np.sin(normal)]
    assert abs(edges.offset[0] - (offset - moved)) < 0.5
    assert edges.depth[0] == pytest.approx(-np.log(1 - darkening), abs=0.15)


def test_the_shadow_divided_out_gives_the_marker_its_light_back():
    cast = CastShadow(*CENTRE, 0.7, 3.0, 0.5, 2 * RADIUS_PX)
    shaded, lit = _marker([cast], noise=0.0), _marker([], noise=0.0)
    given = shaded.image.copy()
    restored = shadow.divided_out(given, CANDIDATE, _edges(shaded), np.array([20.0]), 255.0)
    assert restored.dtype == given.dtype
    np.testing.assert_array_equal(given, shaded.image)  # a copy: the frame stays
    rows, cols = np.mgrid[:128, :128]
    across = (cols - CENTRE[0]) * np.cos(0.7) + (rows - CENTRE[1]) * np.sin(0.7) - 3.0
    within = (cols - CENTRE[0]) ** 2 + (rows - CENTRE[1]) ** 2 <= 18.0**2
    in_shadow = within & (across > 2.0)
    before = np.abs(shaded.image.astype(float) - lit.image)[in_shadow].mean()
    after = np.abs(restored.astype(float) - lit.image)[in_shadow].mean()
    assert before > 20.0 and after < 0.1 * before
    # Beyond its disk the frame is as it was.
    beyond = (cols - CANDIDATE[0, 0]) ** 2 + (rows - CANDIDATE[0, 1]) ** 2 > 21.0**2
    assert (restored[beyond] == shaded.image[beyond]).all()


def test_of_overlapping_candidates_the_best_explained_edge_is_divided_out():
    xy = np.array([[0.0, 0.0], [10.0, 0.0], [50.0, 0.0], [25.0, 0.0]])
    kept = shadow.apart(xy, np.full(4, 6.0), np.array([0.6, 0.9, 0.7, 0.8]))
    # 1 beats 0 (10 px apart, disks of 6); 3 is clear of 1 (15 px) and of 2 (25 px).
    assert kept.tolist() == [False, True, True, True]
