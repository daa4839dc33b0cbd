"""Rendered scenes, and the scoring against their truth, that the tests share."""

from collections.abc import Iterable

import cv2
import numpy as np
from scipy.spatial import cKDTree

from marker_localizer.core.result import Detection, positions
from marker_localizer.synthetic import MarkerPlacement, RenderedScene, SceneConfig, render_markers
from marker_localizer.synthetic.scene import bayer_gain

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


def jittered_grid(
    rng: np.random.Generator,
    count: int,
    columns: int,
    pitch_px: float,
    jitter_px: float,
    radius_px: tuple[float, float],
    tilt_deg: tuple[float, float],
) -> list[MarkerPlacement]:
    """``count`` quarter-disk markers on a grid of ``columns``, ``pitch_px`` apart.

    Each is moved up to ``jitter_px`` either way, with a radius, rotation, tilt and
    tilt axis drawn uniformly (from ``radius_px``, [0, pi), ``tilt_deg``, [0, pi)),
    in that order from ``rng``.
    """
    margin = pitch_px / 2
    return [
        MarkerPlacement(
            margin + pitch_px * (i % columns) + rng.uniform(-jitter_px, jitter_px),
            margin + pitch_px * (i // columns) + rng.uniform(-jitter_px, jitter_px),
            rng.uniform(*radius_px),
            rng.uniform(0, np.pi),
            rng.uniform(*tilt_deg),
            rng.uniform(0, np.pi),
            "quarter_disks",
        )
        for i in range(count)
    ]


def faint_tilted_markers(seed: int) -> RenderedScene:
    """A frame of 15 faint markers of 7-8.5 px tilted 45-55 degrees on ground texture.

    Paint 0.5 and 0.75 (a modulation of 0.2, under the modulation gate's 0.3); the
    rings measure the X's shortest reach, 4-8.5 px, mostly under the smallest radius
    of the range 6-40 px.
    """
    rng = np.random.default_rng(seed)
    placements = jittered_grid(rng, 15, 5, 200.0, 20.0, (7.0, 8.5), (45.0, 55.0))
    return render_markers(
        (640, 1040),
        placements,
        seed,
        background="texture",
        reflectances=(0.5, 0.75),
        blur_sigma_px=1.0,
        noise_sigma_dn=2.0,
    )


#: ``refinement="template"`` with the X reaching 0.6 of the smallest radius.
TEMPLATE_DECISION = {"refinement": "template", "min_extent_fraction": 0.6}


def panning_frames(n_frames: int) -> list[np.ndarray]:
    """340x260 textured ground with three 12 px markers, moving 5 px right and 2 px up a frame.

    A steady flight that tracking follows: after the first frame's full pass, every
    frame until the next scheduled pass is tracked.
    """
    frames = []
    for k in range(n_frames):
        placements = [
            MarkerPlacement(x + 5 * k, y - 2 * k, 12.0, 0.4 * i, 15.0, 0.5)
            for i, (x, y) in enumerate([(90.3, 80.6), (220.8, 150.1), (140.2, 200.7)])
        ]
        scene = render_markers((260, 340), placements, k, background="texture", noise_sigma_dn=2.0)
        frames.append(scene.image)
    return frames


def checker_2x2(size: int = 64, blur: float = 1.0) -> np.ndarray:
    """A 2x2 checkerboard whose corner lies exactly between the four middle pixels."""
    image = np.full((size, size), 200.0, np.float32)
    image[: size // 2, : size // 2] = 30.0
    image[size // 2 :, size // 2 :] = 30.0
    return cv2.GaussianBlur(image, (0, 0), blur).round().astype(np.uint8)


def found_false_errors(
    detections: Iterable[Detection], truth: np.ndarray
) -> tuple[int, int, np.ndarray]:
    """Markers found within 1.5 px, false points, and the found detections' errors, px."""
    distance, index = cKDTree(truth).query(positions(detections))
    hit = distance <= 1.5
    return len(np.unique(index[hit])), int((~hit).sum()), distance[hit]


def neutral_and_coloured_xs() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(BGR frame, its grey, (8, 2) centres) of eight small X's of 6 px.

    The first four are neutral paint under a warm light, the others two materials
    (dark brown and pale yellow, as sand's grains): the grey detector finds all eight.
    """
    places = [
        MarkerPlacement(40.0 + 60 * (k % 4) + 0.3 * k, 40.0 + 70 * (k // 4) + 0.2 * k, 6.0, 0.2 * k)
        for k in range(8)
    ]
    scene = render_markers(
        (180, 280), places, 3, reflectances=(0.3, 0.7), blur_sigma_px=0.9, noise_sigma_dn=1.0
    )
    grey = scene.image.astype(np.float64)
    tint = np.broadcast_to(np.array([0.85, 1.0, 1.15]), (*grey.shape, 3)).copy()
    rows, cols = np.mgrid[: grey.shape[0], : grey.shape[1]]
    share = (grey - grey.min()) / np.ptp(grey)
    brown, pale = np.array([0.55, 1.0, 1.45]), np.array([0.85, 1.0, 1.1])
    for x, y in scene.centres[4:]:
        plate = np.hypot(cols - x, rows - y) <= 10.0
        tint[plate] = brown + share[plate, None] * (pale - brown)
    colour = np.clip(np.rint(grey[..., None] * tint), 0, 255).astype(np.uint8)
    return colour, cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY), scene.centres


def through_demosaicing(grey: np.ndarray, demosaicing: int) -> np.ndarray:
    """BGR of a grey scene as a colour camera sends it uncompressed: its raw mosaic
    (``rggb``, a raw sensor's colour gains) demosaiced by OpenCV (``COLOR_BayerBG2BGR*``)."""
    raw = np.clip(np.rint(grey * bayer_gain(grey.shape, "rggb")), 0, 255).astype(np.uint8)
    return cv2.cvtColor(raw, demosaicing)
