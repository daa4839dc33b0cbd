"""Frames the core's end-to-end tests share."""

import pytest

from marker_localizer.synthetic import SceneConfig, render_scene


@pytest.fixture(scope="session")
def cluttered_frames():
    """Three frames of the renderer's default clutter (1280x960, 12 markers each)."""
    return [render_scene(SceneConfig(), seed) for seed in (11, 12, 13)]
