"""Input normalisation: any supported image to float32 grey levels in [0, 1]."""

from __future__ import annotations

from typing import Any, cast

import cv2
import numpy as np
from numpy.typing import NDArray

from marker_localizer.errors import ImageError

_CHANNEL_CONVERSIONS = {3: cv2.COLOR_BGR2GRAY, 4: cv2.COLOR_BGRA2GRAY}
#: How far a float image's levels may lie outside [0, 1] and be clipped, as a share of
#: white: the ringing of interpolation and sharpening overshoots a step by a few tenths
#: of its contrast at most, where a float image holding 8- or 16-bit levels reaches 255
#: or 65535 and would be clipped to a white frame without a word (scikit-image's
#: ``img_as_*`` refuse such floats too).
FLOAT_OVERSHOOT = 0.5
#: A 16-bit image whose brightest level stays under this share of white holds, most
#: likely, the words of a shallower sensor read at a deeper ``bit_depth``: a 12-bit
#: sensor's levels in 16-bit words reach 1/16 of white at most, where a frame exposed
#: for its markers puts their bright paint over a third of white. Its grey-level
#: thresholds then ask 16 times the contrast, and most markers are lost.
SHALLOW_PEAK_SHARE = 1.0 / 16.0
#: Most of a 16-bit frame's levels (read on :func:`peak_level`'s grid) that may lie
#: above white at its ``bit_depth``: hot pixels and glints are a few pixels, where a
#: sensor's bits left-aligned in 16-bit words put every level over 1/16 of white
#: above it, most of a frame exposed for its markers.
MAX_ABOVE_WHITE_SHARE = 0.5
#: :data:`SHALLOW_PEAK_SHARE` as the warnings write it.
SHALLOW_PEAK_TEXT = f"1/{round(1.0 / SHALLOW_PEAK_SHARE)}"
#: A frame whose brightest level stays under this share of white is underexposed for
#: its markers: their white paint is the brightest thing a frame exposed for them
#: holds. Under it the detector loses markers, most of them to the noise, which only
#: the camera's exposure or gain brings back (docs/accuracy-journal.md, "Underexposed
#: frames").
DIM_PEAK_SHARE = 1.0 / 2.0
#: :data:`DIM_PEAK_SHARE` as the warnings write it.
DIM_PEAK_TEXT = f"1/{round(1.0 / DIM_PEAK_SHARE)}"
#: A level at or above this share of white is taken as clipped: the sensor or its
#: encoder stopped there, and what the scene held beyond is lost. Not 1: a JPEG's
#: ringing and a demosaicing's weights leave a clipped region a level or two under
#: white (255 becomes 253-255).
CLIPPED_SHARE = 0.99
#: OpenCV's demosaicing to grey for each Bayer pattern as ROS names it (the colours of
#: the 2 x 2 cell in raster order). OpenCV names a pattern by the second and third
#: pixels of its second row, so ROS's ``rggb`` is its ``BayerBG``, as cv_bridge maps them.
_BAYER_TO_GREY = {
    "rggb": cv2.COLOR_BayerBG2GRAY,
    "bggr": cv2.COLOR_BayerRG2GRAY,
    "gbrg": cv2.COLOR_BayerGR2GRAY,
    "grbg": cv2.COLOR_BayerGB2GRAY,
}
#: The Bayer patterns :func:`bayer_to_grey` reads.
BAYER_PATTERNS: tuple[str, ...] = tuple(_BAYER_TO_GREY)
#: :func:`peak_level` reads every this many rows and columns: a marker's bright paint
#: spans more, and a 12 MP frame costs 0.75 M reads.
_PEAK_STRIDE = 4


def bit_depth_scale(dtype: np.dtype[Any], bit_depth: int = 16) -> float:
    """Full-scale value (white) of an integer image, from its type and bit depth.

    255 for uint8; 2**bit_depth - 1 for uint16 (a 12-bit sensor in 16-bit words:
    4095). Never from the frame's content, so one camera's thresholds hold still
    from frame to frame.
    """
    if dtype == np.uint8:
        return 255.0
    return float(2**bit_depth - 1)


def to_gray(
    image: NDArray[Any], *, rgb: bool = False, bit_depth: int = 16
) -> tuple[NDArray[np.float64], float]:
    """Reduce a grey or colour image to one channel, keeping its dtype.

    The detector samples the frame in its native dtype (a 12-megapixel uint8
    frame is never copied to float), so this only drops channels and validates.

    Args:
        image: (H, W), (H, W, 1), (H, W, 3) or (H, W, 4) array of uint8, uint16,
            float32 or float64. Colour is BGR(A) unless ``rgb``. Float images hold
            levels in [0, 1] (white 1); within :data:`FLOAT_OVERSHOOT` of it they are
            clipped to it.
        rgb: the channels are RGB(A) instead of BGR(A).
        bit_depth: significant bits of uint16 pixels (see :func:`bit_depth_scale`).
            Byte order is any: a big-endian array is read in the machine's.

    Returns:
        (grey, full_scale): the (H, W) image and the value of white in it
        (see :func:`bit_depth_scale`; 1.0 for float images).

    Raises:
        ImageError: empty image, unsupported shape or dtype, non-finite values, float
            levels beyond :data:`FLOAT_OVERSHOOT` of [0, 1], over
            :data:`MAX_ABOVE_WHITE_SHARE` of the 16-bit levels above white at
            ``bit_depth`` (read on :func:`peak_level`'s grid).
    """
    if image is None:
        # What cv2.imread gives for a file it cannot read, without a word.
        raise ImageError(
            "expected a numpy array, got None (cv2.imread's answer to a file it cannot read)"
        )
    if not isinstance(image, np.ndarray):
        raise ImageError(f"expected a numpy array, got {type(image).__name__}")
    if image.size == 0:
        raise ImageError(f"empty image (shape {image.shape})")
    if not image.dtype.isnative:
        # A big-endian buffer (a FITS file, a message with is_bigendian): the same levels.
        image = image.astype(image.dtype.newbyteorder("="))
    if image.dtype not in (np.uint8, np.uint16, np.float32, np.float64):
        raise ImageError(f"unsupported dtype {image.dtype} (expected uint8, uint16 or float)")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 3:
        if image.shape[2] not in _CHANNEL_CONVERSIONS:
            raise ImageError(f"unsupported channel count {image.shape[2]} (shape {image.shape})")
        if rgb:
            image = image[:, :, [2, 1, 0, 3][: image.shape[2]]]
        if image.dtype == np.float64:
            image = image.astype(np.float32)
        image = cv2.cvtColor(np.ascontiguousarray(image), _CHANNEL_CONVERSIONS[image.shape[2]])
    if image.ndim != 2:
        raise ImageError(f"expected a 2-D grey or 3-D colour image, got shape {image.shape}")
    if image.dtype.kind == "f":
        # NaN and infinities carry into the extremes: two reductions check all three.
        darkest, brightest = float(image.min()), float(image.max())
        if not (np.isfinite(darkest) and np.isfinite(brightest)):
            raise ImageError("image contains NaN or infinite values")
        if darkest < -FLOAT_OVERSHOOT or brightest > 1.0 + FLOAT_OVERSHOOT:
            # Levels above white are a camera's counts; levels under black a signed
            # (zero-centred) image, whose white no division finds.
            advice = (
                "shift and scale them into it"
                if darkest < -FLOAT_OVERSHOOT
                else "divide them by the camera's white level (255 for 8-bit levels, 4095 "
                "for 12-bit, 65535 for 16-bit)"
            )
            raise ImageError(
                f"float image levels span {darkest:g} to {brightest:g}, beyond [0, 1] "
                f"(white 1): {advice}"
            )
        return np.ascontiguousarray(np.clip(image, 0.0, 1.0), dtype=np.float32), 1.0
    white = bit_depth_scale(image.dtype, bit_depth)
    if image.dtype == np.uint16 and bit_depth < 16:
        sample = _peak_grid(image)
        above = np.count_nonzero(sample > white) / sample.size
        if above > MAX_ABOVE_WHITE_SHARE:
            # Every threshold would read a frame of saturated levels, and find nothing.
            raise ImageError(
                f"{above:.0%} of the levels lie above white at bit_depth {bit_depth} "
                f"({white:g}), up to {float(sample.max()):g}: the pixels hold more than "
                f"{bit_depth} bits (a sensor's bits left-aligned in 16-bit words hold 16); "
                "set bit_depth to the bits they hold"
            )
    return np.ascontiguousarray(image), white


def bayer_to_grey(mosaic: NDArray[Any], pattern: str) -> NDArray[Any]:
    """The grey levels of a camera's raw Bayer mosaic, as cv_bridge gives them (mono8/16).

    OpenCV's demosaicing to grey (``COLOR_Bayer*2GRAY``): each colour interpolated
    bilinearly, then weighed as BT.601 weighs it. Its weights change from one pixel
    of the cell to the next, so it moves a sharp X's centre: 0.01-0.02 px with equal
    channel gains. A filter that weighs the colours alike
    everywhere (the 3 x 3 binomial, the luminance of a linear demosaicing) moves no
    centre, but its blur lets ground texture pass as X's: re-mosaicked real aerial
    ground gave 27 false points in 3 frames against this one's 6 (docs/accuracy-journal.md,
    "A camera's raw Bayer mosaic").

    Args:
        mosaic: (H, W) uint8 or uint16 raw mosaic.
        pattern: the colours of its 2 x 2 cell in raster order, as ROS encodings name
            them: one of :data:`BAYER_PATTERNS`.

    Returns:
        (H, W) grey levels of the same dtype: white stays white.

    Raises:
        ImageError: ``mosaic`` is not one channel of uint8 or uint16 pixels, smaller
            than one 2 x 2 cell, or the pattern is not one of :data:`BAYER_PATTERNS`.
    """
    if mosaic.ndim != 2 or mosaic.dtype not in (np.uint8, np.uint16):
        raise ImageError(
            "a Bayer mosaic is one channel of 8- or 16-bit pixels, "
            f"not {'x'.join(map(str, mosaic.shape))} {mosaic.dtype}"
        )
    if min(mosaic.shape) < 2:
        # OpenCV demosaics a row or a column to zeros, which would read as a black frame.
        height, width = mosaic.shape
        raise ImageError(f"a Bayer mosaic holds at least one 2x2 cell, not {width}x{height} pixels")
    if pattern not in _BAYER_TO_GREY:
        raise ImageError(f"unknown Bayer pattern {pattern!r} (expected one of {BAYER_PATTERNS})")
    if not mosaic.flags.aligned:
        # OpenCV takes rows a whole number of pixels apart; a 16-bit message's rows
        # padded by an odd number of bytes are not.
        mosaic = np.ascontiguousarray(mosaic)
    return cast("NDArray[Any]", cv2.cvtColor(mosaic, _BAYER_TO_GREY[pattern]))


def peak_level(image: NDArray[Any]) -> float:
    """The brightest level of an image, read on every fourth row and column (any colour plane)."""
    return float(_peak_grid(image).max())


def _peak_grid(image: NDArray[Any]) -> NDArray[Any]:
    """The levels :func:`peak_level` reads: every :data:`_PEAK_STRIDE`-th row and column.

    Of a colour image's colour planes: an alpha plane, opaque at white, says nothing
    of the exposure, and the grey the detector reads leaves it out too.
    """
    grid = image[::_PEAK_STRIDE, ::_PEAK_STRIDE]
    return grid[..., :3] if grid.ndim == 3 and grid.shape[2] == 4 else grid


def underexposed(peak_share: float) -> bool:
    """Whether a brightest level of ``peak_share`` of white leaves a frame too dim for its markers.

    Under :data:`DIM_PEAK_SHARE`; a NaN share (nothing read) is not.
    """
    return peak_share < DIM_PEAK_SHARE


def underexposure_warning(peak_share: float) -> str:
    """The warning for frames whose brightest level is ``peak_share`` of white, too dim.

    Given where :func:`underexposed` says so.
    """
    return (
        f"frames underexposed: the brightest level is {100.0 * peak_share:.0f} % of white, "
        f"under {DIM_PEAK_TEXT}, where markers are lost: raise the exposure or the gain"
    )


def bit_depth_hint(peak: float, bit_depth: int) -> int | None:
    """The bit depth a 16-bit image's levels fit, where ``bit_depth`` makes them dim; else None.

    Where the brightest level ``peak`` stays under :data:`SHALLOW_PEAK_SHARE` of
    white at ``bit_depth``, the fewest bits (8 at least) that hold it: the sensor's
    depth if the frame is exposed at all. Advice only: white is never taken from
    the frame's content (:func:`bit_depth_scale`).
    """
    if peak >= SHALLOW_PEAK_SHARE * bit_depth_scale(np.dtype(np.uint16), bit_depth):
        return None
    return max(8, int(np.ceil(np.log2(peak + 1.0))))


def clipped(values: NDArray[Any], full_scale: float) -> NDArray[np.bool_]:
    """Where grey ``values`` (white ``full_scale``) clip: :data:`CLIPPED_SHARE` of white on."""
    at_white: NDArray[np.bool_] = np.asarray(values) >= CLIPPED_SHARE * full_scale
    return at_white
