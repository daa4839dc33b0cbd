"""Annotated frames: detections (and optionally the truth) drawn on a copy of the image.

Shared by the CLI, the demo and the node's ``marker_overlay`` topic; needs only OpenCV.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from marker_localizer.core.image import bit_depth_scale
from marker_localizer.core.result import Detection

_LINE_BGR = (0, 255, 0)
_EXTENT_BGR = (0, 255, 255)
_TRUTH_BGR = (255, 0, 255)
#: Half the size of a true centre's tilted cross, px.
_TRUTH_HALF_PX = 3.0
#: Fixed-point bits for cv2 drawing, so sub-pixel centres are drawn where they are.
_DRAW_SHIFT = 4


def _fixed(point: np.ndarray) -> tuple[int, int]:
    scale = 1 << _DRAW_SHIFT
    # cv2 draws pixel centres at integers, like the package's convention.
    return round(float(point[0]) * scale), round(float(point[1]) * scale)


def to_bgr(pixels: np.ndarray, bit_depth: int = 16) -> np.ndarray:
    """An 8-bit BGR copy of a grey or BGR(A) frame, its white at 255.

    White is 255 in uint8, ``2**bit_depth - 1`` in uint16 and 1 in a float frame
    (:func:`~marker_localizer.core.image.to_gray`'s), so that the colours drawn on
    the copy show on every kind.
    """
    colour = pixels[:, :, :3] if pixels.ndim == 3 else pixels
    if colour.ndim == 3 and colour.shape[2] == 1:
        # (H, W, 1) is grey, as to_gray reads it: else an 8-bit one came back one channel.
        colour = colour[:, :, 0]
    if colour.dtype != np.uint8:
        white = 1.0 if colour.dtype.kind == "f" else bit_depth_scale(colour.dtype, bit_depth)
        colour = cv2.convertScaleAbs(np.ascontiguousarray(colour), alpha=255.0 / white)
    elif colour.ndim == 3:
        # Drawn on next: never the caller's frame (nor a view of it).
        return np.array(colour)
    return cv2.cvtColor(colour, cv2.COLOR_GRAY2BGR) if colour.ndim == 2 else colour


def draw_detections(
    pixels: np.ndarray,
    detections: Sequence[Detection],
    truth: np.ndarray | None = None,
    bit_depth: int = 16,
) -> np.ndarray:
    """Draw each marker's two lines and extent circle through its sub-pixel centre.

    Args:
        pixels: (H, W) or (H, W, 1) grey or (H, W, 3|4) BGR(A) frame: uint8,
            uint16 or float (white 1).
        detections: markers to draw (pixel coordinates, (0, 0) = centre of the
            top-left pixel).
        truth: optional (N, 2) true centres, drawn as small magenta crosses
            through each (sub-pixel) centre.
        bit_depth: significant bits of uint16 pixels (white at 2**bit_depth - 1).

    Returns:
        (H, W, 3) uint8 BGR image.
    """
    canvas = to_bgr(pixels, bit_depth)
    for d in detections:
        centre = np.array([d.x, d.y])
        for angle in (d.angle1, d.angle2):
            reach = d.radius_px * np.array([np.cos(angle), np.sin(angle)])
            cv2.line(
                canvas,
                _fixed(centre - reach),
                _fixed(centre + reach),
                _LINE_BGR,
                1,
                cv2.LINE_AA,
                _DRAW_SHIFT,
            )
        cv2.circle(
            canvas,
            _fixed(centre),
            round(d.radius_px * (1 << _DRAW_SHIFT)),
            _EXTENT_BGR,
            1,
            cv2.LINE_AA,
            _DRAW_SHIFT,
        )
    for point in np.asarray(truth if truth is not None else np.zeros((0, 2))):
        # cv2.drawMarker's tilted cross of size 7, at the sub-pixel point (it rounds).
        for corner in ((_TRUTH_HALF_PX, _TRUTH_HALF_PX), (_TRUTH_HALF_PX, -_TRUTH_HALF_PX)):
            cv2.line(
                canvas,
                _fixed(point - np.array(corner)),
                _fixed(point + np.array(corner)),
                _TRUTH_BGR,
                1,
                cv2.LINE_AA,
                _DRAW_SHIFT,
            )
    return canvas
