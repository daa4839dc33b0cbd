"""The README's picture, ``docs/detection.jpg``, rendered again from a fixed seed.

``python -m marker_localizer.bench.picture docs/detection.jpg`` renders the
synthetic scene of :class:`~marker_localizer.synthetic.SceneConfig`'s defaults
(1280x960, 12 markers of radius 6-40 px, 20 look-alikes on textured ground) from
:data:`SEED`, detects with the default :class:`~marker_localizer.DetectorConfig`,
and writes two panels side by side: the frame at half size with the detections
and the true centres drawn (:func:`~marker_localizer.overlay.draw_detections`),
and one marker's centre at :data:`ZOOM` times. It prints the caption's figures:
markers found of those rendered, look-alikes and false positives, and the zoomed
marker's error against the exact truth. The same seed and detector give the same
picture; a change to the detector shows in its figures.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from marker_localizer.cli.arguments import seed_type
from marker_localizer.config import DetectorConfig
from marker_localizer.core.pipeline import Detector
from marker_localizer.core.result import Detection, positions
from marker_localizer.evaluation import match_points
from marker_localizer.overlay import draw_detections
from marker_localizer.synthetic import SceneConfig, render_scene

#: The scene's seed: the README's picture is this one.
SEED = 1
#: Magnification of the zoomed marker: one frame pixel becomes a ZOOM x ZOOM block,
#: so its sub-pixel centre and the truth's, 0.01-0.05 px apart, are told apart.
ZOOM = 16
#: Side of the zoomed window around the marker's centre, frame px: its centre and
#: the two lines through it, not its whole extent (up to 80 px across).
ZOOM_WINDOW_PX = 30
#: Each panel's height in the picture, px: the frame at half size beside the zoom.
PANEL_HEIGHT_PX = ZOOM * ZOOM_WINDOW_PX
#: Half the size of the truth's cross on the zoomed marker, px: one frame pixel across.
_ZOOM_TRUTH_HALF_PX = ZOOM / 2
#: JPEG quality of the written picture: about 110 kB at 1120x480.
JPEG_QUALITY = 90
#: Where and how large the zoomed marker's figures are written on its panel, px.
_LABEL_MARGIN_PX = 10
_LABEL_SCALE = 0.5
_LABEL_BGR = (255, 255, 255)


@dataclass(frozen=True)
class PictureFigures:
    """What the caption says of the picture.

    Attributes:
        markers: markers rendered.
        found: of them, found (matched one-to-one within the evaluation's gate).
        look_alikes: hard negatives rendered (bars, squares, crosses, corners).
        false_positives: detections that matched no marker.
        zoomed_error_px: distance of the zoomed marker's detection from its truth, px.
        zoomed_sigma_px: its 1-sigma uncertainty from the fit, px.
        zoomed_radius_px: its extent, px.
    """

    markers: int
    found: int
    look_alikes: int
    false_positives: int
    zoomed_error_px: float
    zoomed_sigma_px: float
    zoomed_radius_px: float

    def text(self) -> str:
        """The figures as the command prints them."""
        return (
            f"markers: {self.found} of {self.markers} found, {self.false_positives} false "
            f"positive(s); look-alikes: {self.look_alikes}; zoomed marker (radius "
            f"{self.zoomed_radius_px:.1f} px): error {self.zoomed_error_px:.3f} px, "
            f"sigma {self.zoomed_sigma_px:.3f} px"
        )


def render_picture(
    scene_config: SceneConfig | None = None, seed: int = SEED
) -> tuple[np.ndarray, PictureFigures]:
    """The picture (BGR uint8, :data:`PANEL_HEIGHT_PX` high) and its caption's figures.

    The zoomed marker is the found one of median error among those whose window
    lies inside the frame: a typical one, not the best.

    Raises:
        ValueError: no marker was found whose window lies inside the frame.
    """
    scene = render_scene(scene_config or SceneConfig(), seed)
    detections = Detector(DetectorConfig()).detect(scene.image).detections
    found = positions(detections)
    matching = match_points(found, scene.centres)
    half = ZOOM_WINDOW_PX / 2
    height, width = scene.image.shape[:2]
    inside = [
        k
        for k in range(matching.n_matched)
        if half <= found[matching.detection_index[k], 0] <= width - 1 - half
        and half <= found[matching.detection_index[k], 1] <= height - 1 - half
    ]
    if not inside:
        raise ValueError("no marker found whose zoom window lies inside the frame")
    median = sorted(inside, key=lambda k: matching.errors_px[k])[len(inside) // 2]
    zoomed = detections[matching.detection_index[median]]
    truth = scene.centres[matching.truth_index[median]]
    frame_panel = _frame_panel(scene.image, detections, scene.centres)
    zoom_panel = _zoom_panel(scene.image, zoomed, truth, float(matching.errors_px[median]))
    figures = PictureFigures(
        markers=len(scene.markers),
        found=matching.n_matched,
        look_alikes=len(scene.negatives),
        false_positives=matching.n_false_positives,
        zoomed_error_px=float(matching.errors_px[median]),
        zoomed_sigma_px=zoomed.sigma,
        zoomed_radius_px=zoomed.radius_px,
    )
    return np.hstack([frame_panel, zoom_panel]), figures


def _scaled(point: np.ndarray, scale: float, origin: np.ndarray) -> np.ndarray:
    """Where frame points (x, y) land in the frame from ``origin`` resized by ``scale``.

    A pixel's centre is its coordinate (the package's convention), so the pixel
    edges, not the centres, scale: x' = (x - origin + 0.5) * scale - 0.5.
    """
    return (np.asarray(point, dtype=np.float64) - origin + 0.5) * scale - 0.5


def _scaled_detection(d: Detection, scale: float, origin: np.ndarray) -> Detection:
    """Detection ``d`` as drawn on the frame from ``origin`` resized by ``scale``."""
    x, y = _scaled(np.array([d.x, d.y]), scale, origin)
    return dataclasses.replace(d, x=float(x), y=float(y), radius_px=d.radius_px * scale)


def _frame_panel(
    image: np.ndarray, detections: Sequence[Detection], truth: np.ndarray
) -> np.ndarray:
    """The frame resized to :data:`PANEL_HEIGHT_PX`, detections and truth drawn on it.

    Drawn after the resize, so the lines stay one pixel wide and sharp.
    """
    scale = PANEL_HEIGHT_PX / image.shape[0]
    size = (round(image.shape[1] * scale), PANEL_HEIGHT_PX)
    small = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    origin = np.zeros(2)
    drawn = [_scaled_detection(d, scale, origin) for d in detections]
    return draw_detections(small, drawn, _scaled(truth, scale, origin))


def _zoom_panel(
    image: np.ndarray, marker: Detection, truth: np.ndarray, error_px: float
) -> np.ndarray:
    """The :data:`ZOOM_WINDOW_PX` window around ``marker`` at :data:`ZOOM` times, drawn on."""
    corner = np.floor(np.array([marker.x, marker.y]) - ZOOM_WINDOW_PX / 2 + 0.5).astype(int)
    x0, y0 = int(corner[0]), int(corner[1])
    window = image[y0 : y0 + ZOOM_WINDOW_PX, x0 : x0 + ZOOM_WINDOW_PX]
    # Nearest neighbour: each frame pixel a ZOOM x ZOOM block, as the detector sees it.
    big = cv2.resize(window, None, fx=ZOOM, fy=ZOOM, interpolation=cv2.INTER_NEAREST)
    origin = corner.astype(np.float64)
    panel = draw_detections(
        big,
        [_scaled_detection(marker, ZOOM, origin)],
        _scaled(truth[None], ZOOM, origin),
        truth_half_px=_ZOOM_TRUTH_HALF_PX,
    )
    label = f"error {error_px:.3f} px, sigma {marker.sigma:.3f} px"
    cv2.putText(
        panel,
        label,
        (_LABEL_MARGIN_PX, PANEL_HEIGHT_PX - _LABEL_MARGIN_PX),
        cv2.FONT_HERSHEY_SIMPLEX,
        _LABEL_SCALE,
        _LABEL_BGR,
        1,
        cv2.LINE_AA,
    )
    return panel


def main(argv: Sequence[str] | None = None) -> int:
    """Render the picture to the path given and print its caption's figures."""
    parser = argparse.ArgumentParser(
        prog="python -m marker_localizer.bench.picture",
        description="Render the README's detection picture from a fixed seed.",
    )
    parser.add_argument("out", type=Path, help="the JPEG to write (docs/detection.jpg)")
    parser.add_argument("--seed", type=seed_type, default=SEED, help=f"default {SEED}")
    args = parser.parse_args(argv)
    picture, figures = render_picture(seed=args.seed)
    if not cv2.imwrite(str(args.out), picture, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY]):
        parser.exit(1, f"{parser.prog}: error: {args.out}: cannot write the picture\n")
    print(f"{args.out}: {picture.shape[1]}x{picture.shape[0]}, seed {args.seed}")
    print(figures.text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
