"""Markers with a dull quadrant, alone and strong, read at several radius ranges.

Part of ``marker-localizer bench accuracy`` (``--families dull``; issue 12, items 3
and 5). Family (g) paints a dull quadrant on every marker, but gives every
detector its own range, 5-30 px, so no family asks what a dull quadrant does where
the range starts at 6-7 px, as (a)'s, the speed benchmark's and a rig's 6-24 px do.
This grid asks it with nothing else in the way: markers far apart on the ground
photographs, clearly visible (:data:`PAINT` on :data:`BLUR_PX` of blur and
:data:`NOISE_DN` of read noise, :data:`TILT_DEG` from face on), one radius and one
dull quadrant's factor a cell, every frame read at each range of :data:`RANGES_PX`.
Even paint is the control: it is found at every radius and range.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import Any

import numpy as np

from marker_localizer import evaluation
from marker_localizer.bench.peers import PointDetector, RadiusRange, range_text
from marker_localizer.synthetic import MarkerPlacement, RenderedScene, render_markers

#: Marker radii of the grid, px: from the smallest a range of 6 px reads to where a
#: marker's rings reach past the first level searched.
RADII_PX = (6.0, 7.0, 8.0, 10.0, 14.0)
#: Brightness of the dull quadrant over its opposite's: even paint (the control),
#: then duller; at 0.6 the quadrant still leads the dark paint by 0.31 of the bright
#: paint (an X: family (g) calls a lead under 0.2 an L corner).
DULL_FACTORS = (1.0, 0.8, 0.7, 0.6)
#: Radius ranges every frame is read at, px, each correct for every radius of the
#: grid: the default's smallest radius, one from 5 px and one from 6 px (the first
#: level searched the half-resolution one).
RANGES_PX: tuple[RadiusRange, ...] = ((4.0, 40.0), (5.0, 40.0), (6.0, 40.0))
#: Reflectance of the dark and the bright paint: a contrast of 0.6.
PAINT = (0.25, 0.85)
#: Optics blur (px), read noise (DN) and tilt from face on (degrees) of every frame.
BLUR_PX = 0.8
NOISE_DN = 2.0
TILT_DEG = 20.0
#: Frame size (height, width), px, and markers a frame.
FRAME_SHAPE = (960, 1280)
MARKERS_PER_FRAME = 12
#: Frames per cell: 24 markers at each radius, factor and range.
FRAMES = 2
#: A quick run's grid: one frame of markers of 8 px (lost from 6 px at 0.7), even and at 0.7.
QUICK_RADII_PX = (8.0,)
QUICK_DULL_FACTORS = (1.0, 0.7)
#: Neighbouring markers' centres lie four radii and this much apart, px: each stands alone.
_GAP_PX = 20.0
#: Markers' centres lie this far inside the frame, px: the ground the checks read about an
#: X (out to :data:`~marker_localizer.core.screening.GROUND_RING_HALF_SIDES_PX`'s outer
#: half-side and the kernels' reach beyond it) lies in the frame, as it does about nearly
#: every marker of a 12 MP frame; along the frame's edge small markers read otherwise.
_BORDER_PX = 48.0


def dull_frame(radius_px: float, dull_factor: float, seed: int) -> RenderedScene:
    """:data:`MARKERS_PER_FRAME` markers of ``radius_px``, each with a dull quadrant.

    On sites of a grid (:data:`_GAP_PX`) spread over the frame inside its border
    (:data:`_BORDER_PX`), each turned and tilted its own way and a fraction of a pixel
    off its site, on the ground photographs.
    """
    rng = np.random.default_rng(seed)
    height, width = FRAME_SHAPE
    step = 4.0 * radius_px + _GAP_PX
    grid = list(
        itertools.product(
            np.arange(_BORDER_PX, width - _BORDER_PX, step),
            np.arange(_BORDER_PX, height - _BORDER_PX, step),
        )
    )
    spread = np.linspace(0, len(grid) - 1, MARKERS_PER_FRAME).round().astype(int)
    sites = [grid[k] for k in spread]
    placements = [
        MarkerPlacement(
            float(x) + rng.uniform(-0.5, 0.5),
            float(y) + rng.uniform(-0.5, 0.5),
            radius_px,
            rotation_rad=rng.uniform(0.0, np.pi),
            tilt_deg=TILT_DEG,
            tilt_axis_rad=rng.uniform(0.0, np.pi),
            dull_factor=dull_factor,
            dull_quadrant=int(rng.integers(2)),
        )
        for x, y in sites
    ]
    return render_markers(
        FRAME_SHAPE,
        placements,
        rng,
        background="texture",
        reflectances=PAINT,
        blur_sigma_px=BLUR_PX,
        noise_sigma_dn=NOISE_DN,
    )


def measure(
    detector: PointDetector,
    seed: int,
    frames: int = FRAMES,
    radii_px: Sequence[float] = RADII_PX,
    dull_factors: Sequence[float] = DULL_FACTORS,
    ranges_px: Sequence[RadiusRange] = RANGES_PX,
) -> dict[str, Any]:
    """Markers found, and false points, of every cell at every range.

    Returns:
        ``{"frames": all cells', "markers": per cell, "found": {range: per cell},
        "false": {range: total}}``, a range keyed ``"4-40"``, a cell ``"<radius>/<factor>"``.
    """
    found: dict[str, dict[str, int]] = {range_text(r): {} for r in ranges_px}
    false = dict.fromkeys(found, 0)
    markers: dict[str, int] = {}
    for index, (radius, factor) in enumerate(itertools.product(radii_px, dull_factors)):
        cell = f"{radius:g}/{factor:g}"
        # Each cell on ground of its own: one texture X does not count in every cell.
        first = seed * 1000 + index * frames
        scenes = [dull_frame(radius, factor, first + k) for k in range(frames)]
        markers[cell] = sum(len(s.markers) for s in scenes)
        for radius_range in ranges_px:
            key = range_text(radius_range)
            found[key][cell] = 0
            for scene in scenes:
                points = detector.detect(scene.image, radius_range)
                matching = evaluation.match_points(points[:, :2], scene.centres)
                found[key][cell] += len(matching.truth_index)
                false[key] += len(matching.unmatched_detections)
    return {"frames": frames * len(markers), "markers": markers, "found": found, "false": false}


def table(figures: dict[str, Any]) -> str:
    """The grid as text: a row per radius and dull factor, a column per range."""
    keys = list(figures["found"])
    lines = [
        "Markers with a dull quadrant, alone on the ground photographs, "
        f"{MARKERS_PER_FRAME} a {FRAME_SHAPE[1]}x{FRAME_SHAPE[0]} frame (paint "
        f"{PAINT[0]:g} and {PAINT[1]:g}, blur {BLUR_PX:g} px, read noise {NOISE_DN:g} DN, "
        f"tilted {TILT_DEG:g} deg): markers found at each radius range (issue 12, items "
        "3 and 5: a tighter correct range should find as many)",
        f"{'radius px':>9}  {'dull':>5}  {'markers':>7}"
        + "".join(f"  {key + ' px':>9}" for key in keys),
        "-" * (27 + 11 * len(keys)),
    ]
    for cell, count in figures["markers"].items():
        radius, factor = cell.split("/")
        lines.append(
            f"{radius:>9}  {factor:>5}  {count:>7}"
            + "".join(f"  {figures['found'][key][cell]:>9}" for key in keys)
        )
    lines.append(
        f"{'false points in the ' + str(figures['frames']) + ' frames':>25}  "
        + "".join(f"  {figures['false'][key]:>9}" for key in keys)
    )
    return "\n".join(lines)
