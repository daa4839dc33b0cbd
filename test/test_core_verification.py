"""Section 3.2, geometric checks: annular centre symmetry and LSD double line."""

import numpy as np
import pytest

from marker_localizer.core import verification
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


def test_double_line_check_accepts_an_x_and_returns_its_two_lines():
    image = np.clip(_render("checker", rotation=0.3) * 255, 0, 255).astype(np.uint8)
    lines = verification.double_line_check(image, CENTRE, np.array([20.0]))
    assert lines.accepted[0]
    assert lines.distance_px[0] < 1.0
    expected = np.sort(np.array([0.3, 0.3 + np.pi / 2]) % np.pi)
    np.testing.assert_allclose(np.sort(lines.line_angles[0]), expected, atol=np.deg2rad(2.0))


def test_double_line_check_rejects_a_single_straight_edge():
    image = np.full((128, 128), 40, np.uint8)
    image[:, 64:] = 200
    lines = verification.double_line_check(image, CENTRE, np.array([20.0]))
    assert not lines.accepted[0]
