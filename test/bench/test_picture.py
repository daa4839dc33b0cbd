"""The README's picture: both panels drawn, and the figures its caption quotes."""

import numpy as np
import pytest

from marker_localizer.bench.picture import PANEL_HEIGHT_PX, main, render_picture
from marker_localizer.synthetic import SceneConfig

SMALL_SCENE = SceneConfig(
    width=320, height=240, n_markers=3, radius_px=(8.0, 16.0), n_hard_negatives=2, supersampling=4
)


def _share(panel, colour_bgr):
    """Share of ``panel``'s pixels within 60 levels of ``colour_bgr`` in every channel."""
    near = np.abs(panel.astype(int) - np.array(colour_bgr)).max(axis=2) < 60
    return near.mean()


@pytest.fixture(scope="module")
def picture():
    return render_picture(SMALL_SCENE, seed=3)


def test_the_picture_is_the_frame_beside_one_zoomed_marker_each_drawn_on(picture):
    image, _ = picture
    frame_width = round(SMALL_SCENE.width * PANEL_HEIGHT_PX / SMALL_SCENE.height)
    assert image.shape == (PANEL_HEIGHT_PX, frame_width + PANEL_HEIGHT_PX, 3)
    frame, zoom = image[:, :frame_width], image[:, frame_width:]
    for panel in (frame, zoom):
        assert _share(panel, (0, 255, 0)) > 0  # the detections' lines
        assert _share(panel, (0, 255, 255)) > 0  # their extents
        assert _share(panel, (255, 0, 255)) > 0  # the true centres
    # The zoomed marker's figures, written along the zoom's bottom edge.
    assert _share(zoom[-30:], (255, 255, 255)) > 0


def test_the_figures_are_the_scenes_and_the_zoomed_markers(picture):
    _, figures = picture
    assert (figures.markers, figures.look_alikes) == (3, 2)
    assert 1 <= figures.found <= 3
    assert 0 <= figures.zoomed_error_px < 0.1 and figures.zoomed_sigma_px > 0
    assert figures.text().startswith(f"markers: {figures.found} of 3 found, ")


def test_the_command_writes_the_picture_and_prints_its_caption_figures(tmp_path, capsys):
    out = tmp_path / "detection.jpg"
    assert main([str(out)]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[0] == f"{out}: 1120x480, seed 1"
    assert printed[1].startswith("markers: ")
    assert 0 < out.stat().st_size < 250_000
