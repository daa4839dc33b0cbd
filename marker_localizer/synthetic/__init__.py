"""Rendered frames with exact ground truth: diagonal markers, hard negatives, checkerboards.

Coordinates: float64 pixels, x right, y down, (0, 0) at the centre of the
top-left pixel. A marker's truth is the image of its plane origin under its
plane -> image homography, so it is exact under any tilt and perspective.
"""

from marker_localizer.synthetic.scene import (
    MARKER_KINDS,
    NEGATIVE_KINDS,
    PATTERNS,
    CastShadow,
    ImagingConditions,
    MarkerPlacement,
    MarkerTruth,
    Pattern,
    PlanarTarget,
    RenderedScene,
    SceneConfig,
    apply_imaging,
    checkerboard_pattern,
    composite_target,
    marker_homography,
    motion_blur_kernel,
    project,
    render_checkerboard,
    render_markers,
    render_scene,
    render_targets,
)
from marker_localizer.synthetic.textures import TEXTURE_NAMES, load_texture, texture_background

__all__ = [
    "MARKER_KINDS",
    "NEGATIVE_KINDS",
    "PATTERNS",
    "TEXTURE_NAMES",
    "CastShadow",
    "ImagingConditions",
    "MarkerPlacement",
    "MarkerTruth",
    "Pattern",
    "PlanarTarget",
    "RenderedScene",
    "SceneConfig",
    "apply_imaging",
    "checkerboard_pattern",
    "composite_target",
    "load_texture",
    "marker_homography",
    "motion_blur_kernel",
    "project",
    "render_checkerboard",
    "render_markers",
    "render_scene",
    "render_targets",
    "texture_background",
]
