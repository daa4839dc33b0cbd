"""Rendered scenes the benchmark tests share."""

from marker_localizer.synthetic import SceneConfig

#: A small frame with four 8-16 px markers tilted at most 30 degrees and four
#: look-alikes: every benchmark path runs on it in a fraction of a second.
SMALL_SCENE = SceneConfig(
    width=480,
    height=360,
    n_markers=4,
    radius_px=(8.0, 16.0),
    blur_sigma_px=(0.8, 1.0),
    noise_sigma_dn=(1.0, 2.0),
    max_tilt_deg=30.0,
    n_hard_negatives=4,
)
