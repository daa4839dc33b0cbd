"""Annotated frames: detections (and optionally the truth) drawn on a copy of the image.

Shared by the CLI, the demo and the node's ``marker_overlay`` topic; needs only OpenCV.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from marker_localizer.core.image import bit_depth_scale
from marker_localizer.core.result import Detection

_LINE_BGR = (0, 255, 0)
_EXTENT_BGR = (0, 255, 255)
_TRUTH_BGR = (255, 0, 255)
#: Half the size of a true centre's tilted cross, px: cv2.drawMarker's size 7.
TRUTH_HALF_PX = 3.0
#: Fixed-point bits for cv2 drawing, so sub-pixel centres are drawn where they are.
_DRAW_SHIFT = 4
#: Farthest from the frame a drawn line's end or a circle's radius may reach, px:
#: cv2 takes 32-bit fixed-point coordinates (2**27 px at 4 fractional bits), a
#: quarter of that leaves room for the frame and the rounding.
_DRAWABLE_REACH_PX = float(1 << (31 - _DRAW_SHIFT - 2))
#: Margin around the frame within which a drawn circle or line may still touch
#: its pixels (antialiased lines spread a pixel), px.
_VISIBLE_MARGIN_PX = 2.0


def _fixed(point: np.ndarray) -> tuple[int, int]:
    scale = 1 << _DRAW_SHIFT
    # cv2 draws pixel centres at integers, like the package's convention.
    return round(float(point[0]) * scale), round(float(point[1]) * scale)


def _shows(canvas: np.ndarray, x: float, y: float, reach_px: float) -> bool:
    """Whether a drawing within ``reach_px`` of (x, y) can touch ``canvas``'s pixels."""
    height, width = canvas.shape[:2]
    reach = reach_px + _VISIBLE_MARGIN_PX
    return -reach <= x <= width - 1 + reach and -reach <= y <= height - 1 + reach


def _drawable(canvas: np.ndarray, d: Detection, index: int) -> bool:
    """Whether detection ``index`` shows on ``canvas``: one off the frame draws nothing.

    Raises:
        ValueError: its centre, line angles or extent is a NaN or an infinity, its
            extent is negative or beyond what OpenCV can draw: no drawing means it.
    """
    values = {name: getattr(d, name) for name in ("x", "y", "angle1", "angle2", "radius_px")}
    bad = [f"{name}={float(value)!r}" for name, value in values.items() if not math.isfinite(value)]
    if bad:
        raise ValueError(
            f"draw_detections: detection {index} has {', '.join(bad)}: its centre, "
            "line angles and extent must be finite"
        )
    if not 0.0 <= d.radius_px <= _DRAWABLE_REACH_PX:
        raise ValueError(
            f"draw_detections: detection {index} has radius_px={float(d.radius_px)!r}: "
            f"an extent in [0, {_DRAWABLE_REACH_PX:g}] px is drawn"
        )
    return _shows(canvas, d.x, d.y, d.radius_px)


def _truth_points(canvas: np.ndarray, truth: np.ndarray | None, half_px: float) -> np.ndarray:
    """``truth`` as (N, 2) float64, less the points off ``canvas`` (they draw nothing).

    Raises:
        ValueError: ``truth`` is not (N, 2), or a point holds a NaN or an infinity.
    """
    if truth is None:
        return np.zeros((0, 2))
    points = np.asarray(truth, np.float64)
    if points.size == 0:
        return np.zeros((0, 2))
    if points.ndim != 2 or points.shape[1] != 2:
        raise ValueError(f"draw_detections: truth of shape {points.shape} is not (N, 2)")
    bad = np.flatnonzero(~np.isfinite(points).all(axis=1))
    if len(bad):
        raise ValueError(
            f"draw_detections: truth row {bad[0]} is {tuple(points[bad[0]].tolist())}: "
            "a true centre must be finite"
        )
    shown = [_shows(canvas, x, y, half_px) for x, y in points]
    return points[np.array(shown, dtype=bool)]


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
        return np.array(colour, order="C")  # cv2 draws on C order only (RGB reordered is not)
    return cv2.cvtColor(colour, cv2.COLOR_GRAY2BGR) if colour.ndim == 2 else colour


def draw_detections(
    pixels: np.ndarray,
    detections: Sequence[Detection],
    truth: np.ndarray | None = None,
    bit_depth: int = 16,
    truth_half_px: float = TRUTH_HALF_PX,
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
        truth_half_px: half the size of a true centre's cross, px (larger on a
            magnified frame, where the default is a fraction of a frame pixel).

    A marker or true centre off the frame draws nothing, however far off.

    Returns:
        (H, W, 3) uint8 BGR image.

    Raises:
        ValueError: naming the first detection whose centre, line angle or extent is
            a NaN or an infinity (or whose extent is negative), or the first row of
            ``truth`` that is, or ``truth`` not (N, 2); checked before anything is
            drawn.
    """
    canvas = to_bgr(pixels, bit_depth)
    truth_shown = _truth_points(canvas, truth, truth_half_px)
    shown = [d for index, d in enumerate(detections) if _drawable(canvas, d, index)]
    for d in shown:
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
    for point in truth_shown:
        # A tilted cross as cv2.drawMarker's, at the sub-pixel point (drawMarker rounds).
        for corner in ((truth_half_px, truth_half_px), (truth_half_px, -truth_half_px)):
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
