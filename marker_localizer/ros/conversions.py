"""sensor_msgs <-> numpy, written small because cv_bridge and sensor_msgs_py are not wheels.

Everything here works on rclpy message classes (``sensor_msgs.msg``), the same
classes ``rclpy.serialization.deserialize_message`` returns for bag bytes, so the
node and bag replay share one conversion path.

Marker point cloud layout (:func:`detections_to_cloud`): ``height`` 1, ``width``
N markers, little-endian, ``is_dense`` True, ``point_step`` 48 bytes, six
float64 fields in this order:

====== ====== =====================================================================
offset field  meaning
====== ====== =====================================================================
0      x      column of the centre, px; (0, 0) is the centre of the top-left pixel
8      y      row of the centre, px (y down)
16     sigma  1-sigma radial position uncertainty, px
24     score  confidence in [0, 1]
32     angle1 direction of the first line through the centre, rad in [0, pi)
40     angle2 direction of the second line, rad in [0, pi)
====== ====== =====================================================================

Angles are atan2(dy, dx) in pixel coordinates (y down: clockwise as the image is
shown); which line comes first is not fixed. An empty cloud keeps the fields.

A truth cloud (``simulate``'s ``marker_points_truth``: :func:`detections_to_cloud`
given ``marker_ids``) adds one field after these, and its ``point_step`` is 56 bytes:

====== ========= ==================================================================
offset field     meaning
====== ========= ==================================================================
48     marker_id uint32: which marker of the flight this is, the same in every
                 frame and camera that sees it (``FlightSimulator.markers``' index)
====== ========= ==================================================================

and 4 bytes of padding, so that every point's float64 start on an 8-byte boundary.
"""

from __future__ import annotations

import array
import re
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Literal, cast

import cv2
import numpy as np
from rclpy.exceptions import InvalidTopicNameException
from rclpy.validate_full_topic_name import validate_full_topic_name
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2, PointField
from std_msgs.msg import Header

from marker_localizer.core.image import BAYER_PATTERNS, bayer_to_grey
from marker_localizer.core.result import Detection
from marker_localizer.errors import ImageError, shorten
from marker_localizer.image_files import check_pixel_count, decode_image

#: The depths of the Bayer mosaics camera drivers publish raw ...
_BAYER_BITS = (8, 16)


def bayer_encoding(pattern: str, bits: int) -> str:
    """The ROS encoding of a raw Bayer mosaic of ``pattern`` (``"rggb"``...) and depth."""
    return f"bayer_{pattern}{bits}"


#: ... each encoding's pattern, read as grey (:func:`~marker_localizer.core.image.bayer_to_grey`).
BAYER_ENCODINGS: dict[str, str] = {
    bayer_encoding(pattern, bits): pattern for pattern in BAYER_PATTERNS for bits in _BAYER_BITS
}

#: Packed YUV 4:2:2 encodings (USB and V4L2 cameras; two bytes a pixel, its luma and
#: one chroma sample of its pair, sensor_msgs' ``uyvy`` and ``yuyv`` and their
#: deprecated names): the byte that holds the luma. Luma is the grey the detector
#: reads, as cv_bridge's mono conversion of ``yuv422`` and ``yuv422_yuy2`` takes it
#: (OpenCV's ``COLOR_YUV2GRAY_UYVY`` and ``_YUY2``), with no filter across pixels to
#: move an X's centre.
YUV422_LUMA_BYTE: dict[str, int] = {"uyvy": 1, "yuv422": 1, "yuyv": 0, "yuv422_yuy2": 0}
#: Semi-planar YUV 4:2:0 encodings (DepthAI's OAK cameras publish nv12): a plane of
#: ``height`` luma rows, then one row of interleaved chroma for every two (sensor_msgs'
#: height scaling of 1.5), each ``step`` bytes. The luma plane is the grey, read in
#: place.
SEMIPLANAR_YUV420 = ("nv12", "nv21")
#: The chroma byte of a grey pixel.
_NEUTRAL_CHROMA = 128

#: The depths of grey and colour pixels: a byte or a 16-bit word a channel.
_DEPTHS: dict[int, np.dtype] = {8: np.dtype(np.uint8), 16: np.dtype(np.uint16)}
#: Channels of the colour encodings by their names' stems (``bgr8``, ``rgba16``).
_COLOUR_CHANNELS = {"bgr": 3, "rgb": 3, "bgra": 4, "rgba": 4}

#: Encodings the node accepts: numpy dtype and channel count of each.
ENCODINGS: dict[str, tuple[np.dtype, int]] = {
    **{f"mono{bits}": (dtype, 1) for bits, dtype in _DEPTHS.items()},
    **{
        f"{stem}{bits}": (dtype, channels)
        for stem, channels in _COLOUR_CHANNELS.items()
        for bits, dtype in _DEPTHS.items()
    },
    **{name: (_DEPTHS[8], 2) for name in YUV422_LUMA_BYTE},
    **{name: (_DEPTHS[8], 1) for name in SEMIPLANAR_YUV420},
    **{
        bayer_encoding(pattern, bits): (_DEPTHS[bits], 1)
        for pattern in BAYER_PATTERNS
        for bits in _BAYER_BITS
    },
}


def _alternatives(names: Iterable[object]) -> str:
    """``{a,b,c}``: the parts that tell apart encodings whose names share the rest."""
    return "{" + ",".join(map(str, names)) + "}"


#: :data:`ENCODINGS` as the errors list them, those of one stem or pattern in one entry.
ENCODINGS_TEXT = ", ".join(
    [
        f"mono{_alternatives(_DEPTHS)}",
        f"{_alternatives(_COLOUR_CHANNELS)}{_alternatives(_DEPTHS)}",
        *YUV422_LUMA_BYTE,
        *SEMIPLANAR_YUV420,
        f"bayer_{_alternatives(BAYER_PATTERNS)}{_alternatives(_BAYER_BITS)}",
    ]
)

#: The node's ``image_transport`` choices: each camera's input topic (under ``<cam>/``)
#: and message type, named as image_transport names them.
IMAGE_TRANSPORTS: dict[str, tuple[str, type[Image] | type[CompressedImage]]] = {
    "raw": ("image_raw", Image),
    "compressed": ("image_raw/compressed", CompressedImage),
}
#: The node's other topics under ``<cam>/``: the markers found, the overlay drawn,
#: and the camera's calibration it reports.
POINTS_SUFFIX = "marker_points"
OVERLAY_SUFFIX = "marker_overlay"
CAMERA_INFO_SUFFIX = "camera_info"

#: Channel order that turns an RGB(A) image into the BGR(A) order the core reads.
_TO_BGR = {
    f"{stem}{bits}": order
    for stem, order in (("rgb", [2, 1, 0]), ("rgba", [2, 1, 0, 3]))
    for bits in _DEPTHS
}

#: Fields of the marker point cloud, in byte order; all float64.
CLOUD_FIELDS: tuple[str, ...] = ("x", "y", "sigma", "score", "angle1", "angle2")
#: Bytes per marker in the point cloud: six float64.
CLOUD_POINT_STEP = 8 * len(CLOUD_FIELDS)
#: The truth cloud's field after :data:`CLOUD_FIELDS`, uint32: the marker's identity in
#: the flight, so that an evaluation can tell a marker seen again from another one.
MARKER_ID_FIELD = "marker_id"
#: Bytes per marker in a truth cloud: :data:`CLOUD_POINT_STEP`, the uint32 identity and
#: 4 bytes of padding that keep the next point's float64 on an 8-byte boundary.
TRUTH_CLOUD_POINT_STEP = CLOUD_POINT_STEP + 8

#: numpy type of each sensor_msgs/PointField datatype.
_POINT_FIELD_DTYPES: dict[int, np.dtype] = {
    PointField.INT8: np.dtype(np.int8),
    PointField.UINT8: np.dtype(np.uint8),
    PointField.INT16: np.dtype(np.int16),
    PointField.UINT16: np.dtype(np.uint16),
    PointField.INT32: np.dtype(np.int32),
    PointField.UINT32: np.dtype(np.uint32),
    PointField.FLOAT32: np.dtype(np.float32),
    PointField.FLOAT64: np.dtype(np.float64),
}

_HOST_IS_BIGENDIAN = sys.byteorder == "big"


def _chroma_rows(encoding: str, height: int) -> int:
    """Rows of ``step`` bytes an image's data holds after its ``height`` rows of pixels."""
    return (height + 1) // 2 if encoding in SEMIPLANAR_YUV420 else 0


def image_to_array(msg: Image, max_pixels: int | None = None) -> np.ndarray:
    """View the pixels of a sensor_msgs/Image as a numpy array.

    Row padding (``step`` larger than ``width`` times the pixel size) is honoured
    without copying; big-endian 16-bit pixels are byte-swapped into a native copy.

    Args:
        msg: Image with one of the :data:`ENCODINGS`.
        max_pixels: refuse a larger width x height, px (None: no limit).

    Returns:
        (height, width) uint8/uint16 for mono and Bayer encodings (the mosaic as
        it is) and the luma plane of semi-planar YUV; (height, width, C)
        uint8/uint16 in the message's own channel (or byte) order for colour and
        packed YUV ones. The array shares memory with ``msg.data`` unless a byte
        swap was needed.

    Raises:
        ImageError: unsupported encoding, empty image, more than ``max_pixels``,
            ``step`` shorter than a row, or ``data`` length different from
            ``height * step`` (semi-planar YUV: with its chroma rows).
    """
    if msg.encoding not in ENCODINGS:
        raise unsupported_encoding(msg.encoding)
    dtype, channels = ENCODINGS[msg.encoding]
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    if height == 0 or width == 0:
        raise ImageError(f"empty image ({width}x{height})")
    if max_pixels is not None:
        check_pixel_count(width, height, max_pixels, "image")
    row_bytes = width * channels * dtype.itemsize
    if step < row_bytes:
        raise ImageError(
            f"step {step} B is shorter than one row of {width} {msg.encoding} pixels "
            f"({row_bytes} B)"
        )
    chroma = _chroma_rows(msg.encoding, height)
    if len(msg.data) != (height + chroma) * step:
        rows = f"(height {height} + {chroma} chroma rows)" if chroma else f"height {height}"
        raise ImageError(
            f"data holds {len(msg.data)} B but {rows} x step {step} = {(height + chroma) * step} B"
        )
    if dtype.itemsize > 1 and bool(msg.is_bigendian) != _HOST_IS_BIGENDIAN:
        dtype = dtype.newbyteorder()
    shape: tuple[int, ...] = (height, width) if channels == 1 else (height, width, channels)
    strides: tuple[int, ...] = (step, channels * dtype.itemsize, dtype.itemsize)[: len(shape)]
    pixels: np.ndarray = np.ndarray(
        shape, dtype=dtype, buffer=memoryview(msg.data), strides=strides
    )
    if not dtype.isnative:
        pixels = pixels.astype(dtype.newbyteorder("="))
    return pixels


def image_to_detector_input(msg: Image, max_pixels: int | None = None) -> np.ndarray:
    """Pixels of ``msg`` in the layout :meth:`Detector.detect` reads (grey or BGR(A)).

    Args:
        msg: Image with one of the :data:`ENCODINGS`.
        max_pixels: refuse a larger width x height, px (None: no limit).

    Returns:
        (H, W) uint8/uint16 or (H, W, 3|4) uint8/uint16 BGR(A); RGB(A) input is
        reordered, a Bayer mosaic demosaiced to grey
        (:func:`~marker_localizer.core.image.bayer_to_grey`, as cv_bridge does), packed
        YUV read as its luma (:data:`YUV422_LUMA_BYTE`, :data:`SEMIPLANAR_YUV420`):
        the markers are black and white, so the detector's stages read the grey,
        and a colour frame's planes only for whether a small X is drawn in colour
        (:mod:`~marker_localizer.core.chroma`), which a mosaic's or a YUV frame's
        luma does not ask.

    Raises:
        ImageError: as :func:`image_to_array`.
    """
    pixels = image_to_array(msg, max_pixels)
    if msg.encoding in BAYER_ENCODINGS:
        return bayer_to_grey(pixels, BAYER_ENCODINGS[msg.encoding])
    if msg.encoding in YUV422_LUMA_BYTE:
        # OpenCV's channel copy takes a third of numpy's strided one (4 ms at 12 MP).
        return cast("np.ndarray", cv2.extractChannel(pixels, YUV422_LUMA_BYTE[msg.encoding]))
    order = _TO_BGR.get(msg.encoding)
    return pixels if order is None else pixels[:, :, order]


@dataclass(frozen=True)
class EncodedFrame:
    """A sensor_msgs/CompressedImage's bytes and format, decoded where the detector runs.

    A worker process decodes its frames itself (:meth:`decode`): the decoders'
    output is caught per process (:mod:`marker_localizer.image_files`), so
    decodes in one process take turns, and in several they do not.

    Attributes:
        data: the encoded image (JPEG, PNG, ...).
        format: the message's ``format`` (``"bgr8; jpeg compressed bgr8"``).
    """

    data: bytes
    format: str

    @classmethod
    def of(cls, msg: CompressedImage) -> EncodedFrame:
        """The message's bytes and format."""
        return cls(bytes(msg.data), str(msg.format))

    def decode(self, max_pixels: int) -> np.ndarray:
        """The pixels as :func:`compressed_to_detector_input` gives them.

        Raises:
            ImageError: as :func:`compressed_to_detector_input`.
        """
        pixels = decode_image(
            self.data, f"compressed image ({shorten(repr(self.format))})", max_pixels
        )
        pattern = _compressed_bayer_pattern(self.format)
        if pattern is None or pixels.ndim != 2:
            return pixels
        return bayer_to_grey(pixels, pattern)


def compressed_to_detector_input(msg: CompressedImage, max_pixels: int) -> np.ndarray:
    """Decode a sensor_msgs/CompressedImage (JPEG or PNG) into the layout the detector reads.

    image_transport's compressed plugin encodes colour as BGR and keeps 16-bit
    grey in PNG, and OpenCV decodes to the same: grey, BGR or 16-bit grey. A
    camera's raw Bayer mosaic it converts to grey for JPEG
    (``"bayer_rggb8; jpeg compressed mono8"``) but keeps as it is in PNG
    (``"bayer_rggb8; png compressed "``: no target encoding): that mosaic is
    demosaiced to grey as the raw image's is (:func:`image_to_detector_input`).

    Args:
        msg: the message; ``format`` (``"bgr8; jpeg compressed bgr8"``) tells a
            kept Bayer mosaic and is named in errors; otherwise the data's own
            header says what it is.
        max_pixels: refuse a larger width x height, px, before decoding.

    Raises:
        ImageError: the data is not an image OpenCV decodes, empty, or too large.
    """
    return EncodedFrame.of(msg).decode(max_pixels)


def _compressed_bayer_pattern(compressed_format: str) -> str | None:
    """The Bayer pattern of a CompressedImage whose data is its camera's raw mosaic; else None.

    image_transport writes ``"<encoding>; <codec> compressed <target>"``, the target
    empty where it compressed the pixels as they were.
    """
    encoding, _, codec = compressed_format.partition(";")
    encoding = encoding.strip()
    target = codec.partition("compressed")[2].strip()
    if encoding in BAYER_ENCODINGS and target in ("", encoding):
        return BAYER_ENCODINGS[encoding]
    return None


def message_to_detector_input(msg: Image | CompressedImage, max_pixels: int) -> np.ndarray:
    """Pixels of either input message, as :meth:`Detector.detect` reads them.

    Raises:
        ImageError: as :func:`image_to_detector_input` or
            :func:`compressed_to_detector_input`.
    """
    if isinstance(msg, CompressedImage):
        return compressed_to_detector_input(msg, max_pixels)
    return image_to_detector_input(msg, max_pixels)


def array_to_image(pixels: np.ndarray, encoding: str, header: Header | None = None) -> Image:
    """Pack a numpy image into a sensor_msgs/Image (no row padding, host byte order).

    Args:
        pixels: (H, W) or (H, W, C) array whose dtype and channel count match
            ``encoding``; for semi-planar YUV, the luma plane (its chroma is
            written neutral).
        encoding: one of :data:`ENCODINGS`.
        header: copied into the message; an empty header if None.

    Returns:
        The image message.

    Raises:
        ImageError: unsupported encoding, or ``pixels`` does not fit it.
    """
    if encoding not in ENCODINGS:
        raise unsupported_encoding(encoding)
    dtype, channels = ENCODINGS[encoding]
    got_channels = 1 if pixels.ndim == 2 else pixels.shape[2] if pixels.ndim == 3 else -1
    if pixels.dtype != dtype or got_channels != channels:
        raise ImageError(
            f"a {encoding} image needs {channels} channel(s) of {dtype}, "
            f"got shape {pixels.shape} of {pixels.dtype}"
        )
    msg = Image()
    msg.header = header if header is not None else Header()
    msg.height, msg.width = int(pixels.shape[0]), int(pixels.shape[1])
    msg.encoding = encoding
    msg.is_bigendian = _HOST_IS_BIGENDIAN
    msg.step = msg.width * channels * dtype.itemsize
    # Semi-planar YUV's chroma rows follow its luma, neutral: the pixels are its grey.
    chroma = bytes([_NEUTRAL_CHROMA]) * (_chroma_rows(encoding, msg.height) * msg.step)
    # array.array('B', bytes) copies once through frombytes(); a list would be per-byte slow.
    msg.data = array.array("B", np.ascontiguousarray(pixels).tobytes() + chroma)
    return msg


def detections_to_cloud(
    header: Header, detections: Sequence[Detection], marker_ids: Sequence[int] | None = None
) -> PointCloud2:
    """Pack detections into the marker PointCloud2 (layout in the module docstring).

    Args:
        header: copied unchanged (stamp and frame_id of the input image).
        detections: markers of one frame; may be empty.
        marker_ids: for a truth cloud, each marker's identity in the flight, aligned
            with ``detections`` (the :data:`MARKER_ID_FIELD` field); None: the node's
            layout, without it.

    Returns:
        PointCloud2 with ``width`` = number of detections.

    Raises:
        ValueError: ``marker_ids`` not one per detection, or outside uint32.
    """
    fields = [(name, "<f8") for name in CLOUD_FIELDS]
    if marker_ids is not None:
        if len(marker_ids) != len(detections):
            raise ValueError(
                f"{len(marker_ids)} marker ids for {len(detections)} detections: one each"
            )
        if len(marker_ids) and not 0 <= min(marker_ids) <= max(marker_ids) <= 2**32 - 1:
            raise ValueError(
                f"marker ids {min(marker_ids)}-{max(marker_ids)} outside uint32 (0-{2**32 - 1})"
            )
        fields.append((MARKER_ID_FIELD, "<u4"))
    point_step = CLOUD_POINT_STEP if marker_ids is None else TRUTH_CLOUD_POINT_STEP
    points = np.zeros(
        len(detections),
        np.dtype(
            {
                "names": [name for name, _ in fields],
                "formats": [scalar for _, scalar in fields],
                "offsets": [8 * i for i in range(len(fields))],
                "itemsize": point_step,
            }
        ),
    )
    for name in CLOUD_FIELDS:
        points[name] = [getattr(d, name) for d in detections]
    if marker_ids is not None:
        points[MARKER_ID_FIELD] = marker_ids
    cloud = PointCloud2()
    cloud.header = header
    cloud.height = 1
    cloud.width = len(points)
    cloud.fields = [
        PointField(
            name=name,
            offset=8 * i,
            datatype=PointField.FLOAT64 if scalar == "<f8" else PointField.UINT32,
            count=1,
        )
        for i, (name, scalar) in enumerate(fields)
    ]
    cloud.is_bigendian = False
    cloud.point_step = point_step
    cloud.row_step = point_step * len(points)
    cloud.is_dense = True
    cloud.data = array.array("B", points.tobytes())
    return cloud


def cloud_to_array(cloud: PointCloud2) -> np.ndarray:
    """Read any PointCloud2 of scalar fields into a structured numpy array.

    Args:
        cloud: point cloud; every field must have ``count`` 1.

    Returns:
        (height * width,) structured array with one named column per field
        (for the marker cloud: x, y, sigma, score, angle1, angle2 as float64).
        Use ``numpy.lib.recfunctions.structured_to_unstructured`` for an
        (N, 6) array.

    Raises:
        ImageError: unknown field datatype, count other than 1, a field name
            given twice, a field that overruns ``point_step``, points of 0 B, or
            a data length that does not match the declared size.
    """
    order: Literal[">", "<"] = ">" if cloud.is_bigendian else "<"
    names: list[str] = []
    formats: list[np.dtype] = []
    offsets: list[int] = []
    for f in cloud.fields:
        if f.datatype not in _POINT_FIELD_DTYPES or f.count != 1:
            raise ImageError(
                f"point field {f.name!r}: datatype {f.datatype} x count {f.count} "
                "is not a supported scalar"
            )
        if f.name in names:
            raise ImageError(f"point field {f.name!r} is given twice")
        scalar = _POINT_FIELD_DTYPES[f.datatype]
        if f.offset + scalar.itemsize > cloud.point_step:
            raise ImageError(
                f"point field {f.name!r} ({scalar.itemsize} B at offset {f.offset}) "
                f"overruns point_step {cloud.point_step} B"
            )
        names.append(f.name)
        formats.append(scalar.newbyteorder(order))
        offsets.append(f.offset)
    dtype = np.dtype(
        {"names": names, "formats": formats, "offsets": offsets, "itemsize": cloud.point_step}
    )
    n_points = int(cloud.height) * int(cloud.width)
    if n_points and not cloud.point_step:
        raise ImageError(f"{n_points} points of point_step 0 B")
    if cloud.row_step < cloud.width * cloud.point_step or len(cloud.data) != (
        cloud.height * cloud.row_step
    ):
        raise ImageError(
            f"cloud data holds {len(cloud.data)} B, expected height {cloud.height} x "
            f"row_step {cloud.row_step} with row_step >= width {cloud.width} x "
            f"point_step {cloud.point_step}"
        )
    rows = np.frombuffer(memoryview(cloud.data), dtype=np.uint8).reshape(
        cloud.height, cloud.row_step
    )
    if not n_points:
        # An empty cloud may declare no layout at all (point_step 0), which no view takes.
        return np.zeros(0, dtype)
    packed = rows[:, : cloud.width * cloud.point_step].copy()
    return packed.view(dtype).reshape(n_points)


#: sensor_msgs' generic OpenCV types (``8UC1``, ``16UC1``, ``32FC1``, ``8UC3``...): arrays
#: whose values say nothing of grey or colour (depth images, most often), which
#: cv_bridge converts to no mono encoding either. The refusal says so.
_GENERIC_ENCODING = re.compile(r"(8U|8S|16U|16S|32S|32F|64F)C[0-9]+")


def unsupported_encoding(encoding: str) -> ImageError:
    """The error of an image whose ``encoding`` is not one of :data:`ENCODINGS`."""
    reason = (
        ": a generic type, whose values may be anything (depth, most often); a camera's "
        "grey is mono8 or mono16"
        if _GENERIC_ENCODING.fullmatch(encoding)
        else ""
    )
    return ImageError(
        f"unsupported encoding {shorten(repr(encoding))}{reason} (expected one of {ENCODINGS_TEXT})"
    )


def camera_info_image_size(info: CameraInfo) -> tuple[int, int] | None:
    """The (width, height) of the images ``info`` describes, px; None where it gives no size.

    Its ``width`` x ``height`` is the sensor's at calibration; a region of interest
    (``roi``, in those unbinned pixels) cuts the images to its size, and binning
    divides them (``binning_x`` 2: half as wide), as sensor_msgs/CameraInfo defines
    both (0 in each is the full sensor, unbinned). A driver of an uncalibrated camera
    publishes 0 x 0.
    """
    if not info.width or not info.height:
        return None
    width = info.roi.width or info.width
    height = info.roi.height or info.height
    return width // max(info.binning_x, 1), height // max(info.binning_y, 1)


def topic_name_problem(topic: str) -> str | None:
    """Why ROS 2 refuses ``topic`` as a fully qualified topic name; None where it takes it."""
    try:
        validate_full_topic_name(topic)
    except InvalidTopicNameException as err:
        # Its first line says why; the next two repeat the name and point into it.
        return shorten(str(err).splitlines()[0].removeprefix("Invalid topic name: ").rstrip(":"))
    return None
