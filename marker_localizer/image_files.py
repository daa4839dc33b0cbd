"""Encoded images (files, compressed messages) to arrays, with their size checked first.

A few hundred kilobytes of PNG can claim 30000x30000 pixels and take 12 GB to
decode, so the size is read from the header and checked against
``DetectorConfig.max_pixels`` before any pixel is decoded. Headers are parsed
here for PNG, JPEG, TIFF (BigTIFF included), BMP, WebP and the PNM family (PBM,
PGM, PPM, PFM); other formats OpenCV reads (OpenEXR, Radiance HDR, JPEG 2000,
Sun raster) are checked after decoding, within OpenCV's own limit of 2**30
pixels; a PNG whose header chunk fails its checksum is left to libpng to name. A
TIFF of more than one page is refused, as OpenCV would give its first page
alone, and so is an animated PNG, WebP or GIF (OpenCV gives one frame), a
truncated JPEG or PNG, which libjpeg or libpng would report on stderr without
naming it, a progressive JPEG cut between two scans (decoded blurred, without a
word), and a JPEG that libjpeg finds corrupt while decoding it (decoded with
grey or smeared blocks). Every failure, an OpenCV exception included, becomes
one :class:`ImageError` naming the source; what OpenCV, libjpeg and libpng would
print on stderr is kept off it (see :func:`decode_image`).

Pixels come in the order the file stores them: neither an EXIF Orientation (JPEG,
PNG, WebP) nor a TIFF's own Orientation tag turns them, so a marker's pixel
coordinates are the sensor's, as a camera's calibration and ROS's image
messages have them.
"""

from __future__ import annotations

import contextlib
import mmap
import os
import re
import stat
import struct
import sys
import tempfile
import threading
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, NamedTuple

import cv2
import numpy as np

from marker_localizer.errors import ImageError, shorten

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: The type of the chunk that closes every PNG.
_PNG_END_CHUNK = b"IEND"
#: A PNG's largest width or height (its specification: 2**31 - 1).
_PNG_MAX_SIDE = (1 << 31) - 1
#: Chunks of a PNG read at most for an animation's control chunk (acTL), which comes
#: before the image data: a crafted file of many empty chunks costs no more than this.
_PNG_MAX_HEADER_CHUNKS = 4096
#: GIF's signatures, and the bytes that open each of its blocks: an image (one
#: frame), an extension, the trailer.
_GIF_SIGNATURES = (b"GIF87a", b"GIF89a")
_GIF_IMAGE, _GIF_EXTENSION, _GIF_TRAILER = 0x2C, 0x21, 0x3B
#: A WebP's extended header's flag for an animation.
_WEBP_ANIMATED = 0x02
#: JPEG start-of-frame markers (baseline, progressive, lossless, arithmetic); they carry the size.
_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
#: Start-of-frame markers of a progressive JPEG (Huffman, arithmetic coded): each scan
#: sends a band of coefficients, or one more bit of them.
_JPEG_PROGRESSIVE = frozenset({0xC2, 0xCA})
#: Start-of-frame markers of a sequential or lossless JPEG: each scan sends whole components.
_JPEG_SEQUENTIAL = frozenset({0xC0, 0xC1, 0xC3, 0xC9, 0xCB})
#: Coefficients of a JPEG block (8x8).
_JPEG_COEFFICIENTS = 64
#: JPEG markers without a length field: TEM, RSTn, SOI.
_JPEG_STANDALONE = frozenset({0x01, *range(0xD0, 0xD9)})
_JPEG_SOI, _JPEG_EOI, _JPEG_SOS = b"\xff\xd8", b"\xff\xd9", 0xDA
#: The first marker after a scan's entropy-coded data: FF followed by neither a stuffed
#: 00, a restart marker (D0-D7) nor another FF (fill).
_JPEG_MARKER_AFTER_SCAN = re.compile(rb"\xff[^\x00\xd0-\xd7\xff]")
_TIFF_SUBFILE_TYPE, _TIFF_WIDTH, _TIFF_LENGTH, _TIFF_ORIENTATION = 254, 256, 257, 274
#: Directories a TIFF's page count follows at most: the time a crafted chain of them
#: can take stays a fraction of a second.
_TIFF_MAX_DIRECTORIES = 65535
#: Entries of a directory read at most: a classic TIFF's own limit, which a BigTIFF's
#: 64-bit count could otherwise pass by far.
_TIFF_MAX_ENTRIES = 65535
#: NewSubfileType bits of a directory that is not a page: reduced resolution, transparency mask.
_TIFF_NOT_A_PAGE = 0b101
#: Orientation values that turn or mirror the image (1 is as stored).
_TIFF_TURNED = range(2, 9)
_TIFF_SIGNATURES = (b"II*\x00", b"MM\x00*")
#: BigTIFF (version 43): 64-bit offsets, for files over 4 GB.
_BIGTIFF_SIGNATURES = (b"II+\x00", b"MM\x00+")
#: Struct codes of the values a TIFF entry holds within itself: SHORT, LONG, LONG8 (BigTIFF).
_TIFF_VALUE_FORMATS = {3: "H", 4: "I", 16: "Q"}
_PNM_HEADER = re.compile(rb"^P[1-6fF](?:\s+|#[^\n]*\n)+(\d+)(?:\s+|#[^\n]*\n)+(\d+)")

#: cv::utils::logging::LOG_LEVEL_SILENT.
_OPENCV_LOG_SILENT = 0
#: OpenCV's log level, read and set: ``cv2.utils.logging`` from OpenCV 5, ``cv2`` before.
_OPENCV_LOGGING = getattr(cv2.utils, "logging", cv2)
#: What libjpeg and libpng print on stderr by themselves, naming no file: libjpeg's
#: warnings (jerror.h's JWRN_ messages; its errors OpenCV keeps quiet) and libpng's
#: warnings and errors. Lines that match neither are another thread's and are passed on.
_LIBJPEG_LINE = re.compile(
    r"Corrupt JPEG data|Premature end of JPEG file|Inconsistent progression sequence"
    r"|Invalid SOS parameters|Unknown Adobe color transform|Warning: unknown JFIF revision"
    r"|Application transferred too (?:many|few) scanlines"
)
_LIBPNG_LINE = re.compile(r"libpng (?:warning|error): ")
#: Of those, the ones that say the pixels decoded are not all the file's: corrupt or missing
#: scan data (not a bad ICC profile, which OpenCV does not use), and an image data chunk
#: (IDAT) libpng found wrong but went on with.
_DAMAGE_LINE = re.compile(
    r"libjpeg: (?:Corrupt JPEG data: (?!bad ICC marker)|Premature end of JPEG file"
    r"|Inconsistent progression sequence|Invalid SOS parameters)"
    r"|libpng warning: IDAT: "
)

#: Held while a decode has OpenCV's log level and stderr's file descriptor, which are the
#: process's, not the thread's: decodes take turns, and a fork waits for the one under
#: way (see :func:`_decoders_quietened`); reentrant, so that a fork from a signal handler
#: of the thread that holds it does not wait for itself.
_DECODER_OUTPUT_LOCK = threading.RLock()
os.register_at_fork(
    before=_DECODER_OUTPUT_LOCK.acquire,
    after_in_parent=_DECODER_OUTPUT_LOCK.release,
    after_in_child=_DECODER_OUTPUT_LOCK.release,
)


#: Encoded bytes in memory, or a file mapped read-only (its pages are read only where looked at).
Encoded = bytes | bytearray | mmap.mmap


def image_size(data: Encoded) -> tuple[int, int] | None:
    """(width, height) from an encoded image's header, without decoding it.

    Args:
        data: the encoded image (a TIFF's size may sit at its end).

    Returns:
        The size in pixels, or None for a format whose header is not parsed
        here or a header that is cut short.
    """
    for signature, parse in _HEADER_PARSERS.items():
        if data[: len(signature)] == signature:
            try:
                return parse(data)
            except (struct.error, IndexError):
                return None
    return None


def _png_size(data: Encoded) -> tuple[int, int] | None:
    """The size in IHDR, always the first chunk; None where that chunk is damaged.

    A damaged header is left to libpng to name: a flipped bit in a width would
    otherwise be read as an image too large for ``max_pixels``.
    """
    length, kind = struct.unpack(">I4s", data[8:16])
    if kind != b"IHDR" or length != 13:
        return None
    (crc,) = struct.unpack(">I", data[29:33])
    if zlib.crc32(data[12:29]) != crc:
        return None
    width, height = struct.unpack(">II", data[16:24])
    if not (0 < width <= _PNG_MAX_SIDE and 0 < height <= _PNG_MAX_SIDE):
        return None
    return width, height


def _pnm_size(data: Encoded) -> tuple[int, int] | None:
    match = _PNM_HEADER.match(data[:1024])
    return (int(match[1]), int(match[2])) if match else None


def _jpeg_markers(data: Encoded) -> Iterator[tuple[int, int]]:
    """(marker, offset) of each marker of a JPEG's header, to its first scan's (SOS) included."""
    at = 2
    while at + 4 <= len(data) and data[at] == 0xFF:
        marker = data[at + 1]
        if marker == 0xFF:  # fill byte
            at += 1
            continue
        yield marker, at
        if marker == _JPEG_SOS:
            return
        at += 2 if marker in _JPEG_STANDALONE else 2 + struct.unpack_from(">H", data, at + 2)[0]


def _jpeg_size(data: Encoded) -> tuple[int, int] | None:
    for marker, at in _jpeg_markers(data):
        if marker in _JPEG_SOF:
            height, width = struct.unpack_from(">HH", data, at + 5)
            return (width, height) if height else None  # 0: height set later (DNL)
    return None  # cut short, or scan data before any frame header


def _jpeg_truncated(data: Encoded) -> bool:
    """Whether a JPEG's data stop before the end-of-image marker (FF D9) that closes its scans.

    The marker is looked for after the last header marker read, the first
    scan's or where the header breaks off: an EXIF thumbnail, in a segment
    before it, ends in one of its own. Within scan data FF is never followed by
    D9, so one found there is the image's.
    """
    last = max((at for _marker, at in _jpeg_markers(data)), default=0)
    return data.rfind(_JPEG_EOI, last) < 0


def _jpeg_scans(data: Encoded, sos: int) -> Iterator[tuple[set[int], int, int, int]]:
    """(component ids, first and last coefficient, low bit) of each scan of a JPEG.

    From the scan whose SOS marker is at ``sos`` to the end-of-image marker or
    the end of the data: each scan's entropy-coded data is skipped to the first
    marker after it, and the segments between two scans (tables, restart
    interval) by their length.
    """
    at = sos
    while True:
        length, count = struct.unpack_from(">HB", data, at + 2)
        components = {data[at + 5 + 2 * k] for k in range(count)}
        first, last, bits = struct.unpack_from(">BBB", data, at + 5 + 2 * count)
        yield components, first, last, bits & 0x0F
        at += 2 + length
        while (found := _JPEG_MARKER_AFTER_SCAN.search(data, at)) is not None:
            marker, at = data[found.start() + 1], found.start()
            if marker == _JPEG_SOS:
                break
            if marker == _JPEG_EOI[1]:
                return
            at += 2
            if marker not in _JPEG_STANDALONE:
                at += struct.unpack_from(">H", data, at)[0]
        else:
            return


def _jpeg_scans_incomplete(data: Encoded) -> bool:
    """Whether a JPEG's scans end before they sent every component whole.

    A progressive JPEG sends its coefficients in bands and bits, scan after
    scan: cut between two scans and closed with an end-of-image marker, it
    decodes without a word from libjpeg, each block missing its last bands
    (blurred) or bits (coarse). Whole, every coefficient of every component
    has had a scan that sent its last bit (successive approximation's low bit
    0). A sequential JPEG's scans each send whole components, all of which must
    come. A file whose frame or scans cannot be read, or a hierarchical one, is
    left to the decoder.
    """
    frame = sos = None
    for marker, at in _jpeg_markers(data):
        if marker in _JPEG_SOF and frame is None:
            frame = marker, at
        elif marker == _JPEG_SOS:
            sos = at
    if frame is None or sos is None or frame[0] not in _JPEG_PROGRESSIVE | _JPEG_SEQUENTIAL:
        return False
    marker, at = frame
    progressive = marker in _JPEG_PROGRESSIVE
    try:
        unsent = {
            data[at + 10 + 3 * k]: set(range(_JPEG_COEFFICIENTS)) for k in range(data[at + 9])
        }
        for components, first, last, low_bit in _jpeg_scans(data, sos):
            # A sequential scan's Ss, Se and Al are fixed (a lossless one's are its predictor
            # and point transform): it sends its components whole.
            if not progressive:
                for component in components & unsent.keys():
                    unsent[component].clear()
            elif low_bit == 0:
                for component in components & unsent.keys():
                    unsent[component].difference_update(range(first, last + 1))
    except (struct.error, IndexError):
        return False
    return any(unsent.values())


class _TiffLayout(NamedTuple):
    """Where a classic TIFF (version 42) or a BigTIFF (43) keeps what is read here."""

    order: str  #: "<" (II) or ">" (MM)
    count_format: str  #: struct code of a directory's entry count
    offset_format: str  #: struct code of an offset: the first directory's, the next one's
    entry_size: int  #: bytes of an entry: tag, type, value count, value or its offset
    value_at: int  #: where in an entry a value that fits lies

    @property
    def first_directory(self) -> int:
        """Where the header holds the offset of the first directory."""
        return 4 if self.offset_format == "I" else 8

    def offset_at(self, data: Encoded, at: int) -> int:
        """The offset stored at ``at``."""
        return int(struct.unpack_from(self.order + self.offset_format, data, at)[0])

    def directory(self, data: Encoded, ifd: int) -> tuple[int, int, int]:
        """(entry count, first entry's offset, next directory's offset's offset) of ``ifd``."""
        (count,) = struct.unpack_from(self.order + self.count_format, data, ifd)
        first = ifd + struct.calcsize(self.count_format)
        return count, first, first + self.entry_size * count

    def entry(self, data: Encoded, at: int) -> tuple[int, int, int]:
        """(tag, type, value) of the entry at ``at``, for a value of one SHORT, LONG or LONG8."""
        tag, kind = struct.unpack_from(self.order + "HH", data, at)
        fmt = _TIFF_VALUE_FORMATS.get(kind, "I")
        return tag, kind, int(struct.unpack_from(self.order + fmt, data, at + self.value_at)[0])


def _tiff_layout(data: Encoded) -> _TiffLayout | None:
    """The layout of a TIFF or BigTIFF; None for other data."""
    head = data[:4]
    order = "<" if head[:2] == b"II" else ">"
    if head in _TIFF_SIGNATURES:
        return _TiffLayout(order, "H", "I", 12, 8)
    if head in _BIGTIFF_SIGNATURES:
        return _TiffLayout(order, "Q", "Q", 20, 12)
    return None


def _tiff_first_entries(data: Encoded) -> Iterator[tuple[int, int, int, int]]:
    """(tag, type, value, offset) of each entry of a TIFF's first directory (its image's)."""
    layout = _tiff_layout(data)
    if layout is None:
        return
    ifd = layout.offset_at(data, layout.first_directory)
    count, first, _ = layout.directory(data, ifd)
    for k in range(min(count, _TIFF_MAX_ENTRIES)):
        at = first + layout.entry_size * k
        yield (*layout.entry(data, at), at + layout.value_at)


def _tiff_size(data: Encoded) -> tuple[int, int] | None:
    found = {tag: value for tag, _, value, _ in _tiff_first_entries(data)}
    if _TIFF_WIDTH in found and _TIFF_LENGTH in found:
        return found[_TIFF_WIDTH], found[_TIFF_LENGTH]
    return None


def tiff_pages(data: Encoded) -> int:
    """How many full-size images (pages) a TIFF holds; OpenCV decodes only the first.

    Reduced-resolution copies (thumbnails, a GeoTIFF's overviews) and
    transparency masks are not pages. The count stops at a directory that is
    cut short or points back to one already read, and at
    :data:`_TIFF_MAX_DIRECTORIES`.

    Args:
        data: the encoded TIFF (little- or big-endian, classic or BigTIFF); 0
            for other data.
    """
    layout = _tiff_layout(data)
    if layout is None:
        return 0
    pages, seen = 0, set[int]()
    try:
        ifd = layout.offset_at(data, layout.first_directory)
        while ifd and ifd not in seen and len(seen) < _TIFF_MAX_DIRECTORIES:
            seen.add(ifd)
            # Entries are sorted by tag and NewSubfileType's is the lowest TIFF
            # defines: where it is present it is the first, so a directory costs
            # the same whatever number of entries it claims.
            _, first, next_at = layout.directory(data, ifd)
            tag, _, subfile_type = layout.entry(data, first)
            pages += not (tag == _TIFF_SUBFILE_TYPE and subfile_type & _TIFF_NOT_A_PAGE)
            ifd = layout.offset_at(data, next_at)
    except struct.error:
        pass  # a directory cut short: the pages before it are counted
    return pages


def animation_frames(data: Encoded) -> int:
    """How many frames an animated PNG, WebP or GIF holds; OpenCV decodes one of them.

    An animated PNG says so in its animation control chunk (acTL) before its
    image data, an animated WebP in its extended header's flags and one ANMF
    chunk a frame; a GIF's frames are its image blocks. A count stops where the
    data are cut short.

    Args:
        data: the encoded image; 1 for a still one and for other formats.
    """
    try:
        if data[:8] == _PNG_SIGNATURE:
            return _apng_frames(data)
        if data[:4] == b"RIFF" and data[8:16] == b"WEBPVP8X" and data[20] & _WEBP_ANIMATED:
            return _webp_frames(data)
        if data[:6] in _GIF_SIGNATURES:
            return _gif_frames(data)
    except (struct.error, IndexError):
        pass
    return 1


def _apng_frames(data: Encoded) -> int:
    at = len(_PNG_SIGNATURE)
    for _ in range(_PNG_MAX_HEADER_CHUNKS):
        length, kind = struct.unpack_from(">I4s", data, at)
        if kind == b"acTL":
            return max(1, struct.unpack_from(">I", data, at + 8)[0])
        if kind in (b"IDAT", _PNG_END_CHUNK):
            break
        at += 12 + length  # length, type, data, CRC
    return 1


def _webp_frames(data: Encoded) -> int:
    frames, at = 0, 12
    while at + 8 <= len(data):
        kind, size = struct.unpack_from("<4sI", data, at)
        frames += kind == b"ANMF"
        at += 8 + size + (size & 1)  # chunks are padded to an even size
    return max(frames, 1)


def _gif_frames(data: Encoded) -> int:
    """The image blocks of a GIF, up to its trailer (GIF89a's specification, sections 17-27)."""
    at = 13 + _gif_colour_table_bytes(data[10])  # the global colour table
    frames = 0
    with contextlib.suppress(IndexError):  # cut short: the frames before are counted
        while data[at] != _GIF_TRAILER:
            if data[at] == _GIF_IMAGE:
                frames += 1
                at += 10 + _gif_colour_table_bytes(data[at + 9])  # and its local table
                at += 1  # the LZW code size
            elif data[at] == _GIF_EXTENSION:
                at += 2
            else:
                break
            while data[at]:  # data sub-blocks, each led by its size, to an empty one
                at += 1 + data[at]
            at += 1
    return max(frames, 1)


def _gif_colour_table_bytes(packed: int) -> int:
    """Bytes of the colour table a GIF descriptor's packed field announces (0: none)."""
    return 3 << ((packed & 0x07) + 1) if packed & 0x80 else 0


def _in_stored_order(data: Encoded) -> Encoded:
    """``data``, but a TIFF whose Orientation tag turns or mirrors it with the tag set to 1.

    OpenCV turns a TIFF by its own Orientation tag whatever it is asked
    (``IMREAD_UNCHANGED``, ``IMREAD_IGNORE_ORIENTATION``), where it leaves a
    JPEG's, PNG's or WebP's EXIF orientation alone with ``IMREAD_UNCHANGED``
    (OpenCV 4.6, 4.12, 5.1): with the tag set to 1 (as stored) in a copy of the
    data, every format gives its pixels as stored.
    """
    layout = _tiff_layout(data)
    if layout is None:
        return data
    try:
        for tag, kind, value, at in _tiff_first_entries(data):
            if tag == _TIFF_ORIENTATION:
                if value not in _TIFF_TURNED:
                    return data
                copy = bytearray(data)
                struct.pack_into(layout.order + _TIFF_VALUE_FORMATS.get(kind, "I"), copy, at, 1)
                return copy
    except struct.error:
        pass
    return data


def _bmp_size(data: Encoded) -> tuple[int, int]:
    (header_size,) = struct.unpack("<I", data[14:18])
    if header_size == 12:  # OS/2 BITMAPCOREHEADER
        width, height = struct.unpack("<HH", data[18:22])
        return width, height
    width, height = struct.unpack("<ii", data[18:26])
    return abs(width), abs(height)  # a negative height means rows top-down


def _webp_size(data: Encoded) -> tuple[int, int] | None:
    if data[8:12] != b"WEBP":
        return None
    kind = data[12:16]
    if kind == b"VP8 ":
        width, height = struct.unpack("<HH", data[26:30])
        return width & 0x3FFF, height & 0x3FFF
    if kind == b"VP8L":
        (bits,) = struct.unpack("<I", data[21:25])
        return (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
    if kind == b"VP8X":
        width = int.from_bytes(data[24:27], "little") + 1
        height = int.from_bytes(data[27:30], "little") + 1
        return width, height
    return None


#: Leading bytes of each format -> its header parser.
_HEADER_PARSERS: dict[bytes, Callable[[Encoded], tuple[int, int] | None]] = {
    _PNG_SIGNATURE: _png_size,
    _JPEG_SOI: _jpeg_size,
    **dict.fromkeys(_TIFF_SIGNATURES + _BIGTIFF_SIGNATURES, _tiff_size),
    b"BM": _bmp_size,
    b"RIFF": _webp_size,
    b"P": _pnm_size,
}


def check_pixel_count(width: int, height: int, max_pixels: int, source: str) -> None:
    """Refuse an image of more than ``max_pixels`` pixels before anything is allocated for it.

    Raises:
        ImageError: naming ``source`` and both figures.
    """
    if width * height > max_pixels:
        raise ImageError(
            f"{source}: {width}x{height} = {width * height} px exceeds max_pixels={max_pixels}"
        )


def decode_image(data: Encoded, source: str, max_pixels: int) -> np.ndarray:
    """Decode an encoded image as stored (grey, colour, 16-bit or float), size checked first.

    Pixels come in stored order: no EXIF or TIFF Orientation tag is applied.
    While OpenCV decodes, its log is silenced and, for a JPEG or PNG, what
    libjpeg or libpng print on stderr is caught (:func:`_decoders_quietened`):
    a line of theirs becomes part of the error, and a JPEG that libjpeg found
    corrupt but decoded anyway (grey or smeared blocks where its data went
    wrong) is refused, not detected on. Damage that no decoder notices (a JPEG
    or WebP has no checksum) is not found.

    Args:
        data: the encoded bytes (PNG, JPEG, TIFF, ... as OpenCV reads them).
        source: what to name in an error (file path, topic).
        max_pixels: largest width x height accepted, px.

    Returns:
        The image as :func:`cv2.imdecode` with ``IMREAD_UNCHANGED`` gives it.

    Raises:
        ImageError: too large, not an image, empty, a TIFF of more than one
            page, a truncated or damaged JPEG, or OpenCV failed on it.
    """
    if not len(data):
        raise ImageError(f"{source}: no data (0 bytes)")
    size = image_size(data)
    if size is not None:
        check_pixel_count(*size, max_pixels, source)
    _check_whole(data, source)
    buffer = np.frombuffer(_in_stored_order(data), np.uint8)
    codec = "JPEG" if data[:2] == _JPEG_SOI else "PNG" if data[:8] == _PNG_SIGNATURE else None
    try:
        with _decoders_quietened(catch_stderr=codec is not None) as printed:
            image = cv2.imdecode(buffer, cv2.IMREAD_UNCHANGED)
    except cv2.error as err:
        raise ImageError(f"{source}: OpenCV cannot decode it ({err.err})") from err
    finally:
        del buffer  # a mapped file cannot close while a view of it lives
    if image is None:
        said = f" ({shorten(printed[-1])})" if printed else ""
        raise ImageError(f"{source}: not a readable image{said}")
    if damage := next(filter(_DAMAGE_LINE.match, printed), None):
        raise ImageError(f"{source}: damaged {codec} ({shorten(damage)})")
    if image.size == 0:
        raise ImageError(f"{source}: empty image")
    check_pixel_count(image.shape[1], image.shape[0], max_pixels, source)
    return image


@contextlib.contextmanager
def _decoders_quietened(catch_stderr: bool) -> Iterator[list[str]]:
    """OpenCV's log silenced and, with ``catch_stderr``, libjpeg's and libpng's lines caught.

    libjpeg's warnings and libpng's messages go to stderr's file descriptor,
    naming no file, and OpenCV offers no way to have them: the descriptor is
    pointed at a temporary file for the decode and put back in ``finally``.
    Both it and OpenCV's log level are the process's, so decodes take turns
    (:data:`_DECODER_OUTPUT_LOCK`, which a fork also waits for); whatever
    another thread writes to stderr meanwhile is written on to it afterwards,
    late by the decode's time but whole. A process another thread starts
    without :func:`os.fork` (``subprocess``) during a decode would inherit the
    file as its stderr. OpenCV's own lines of other threads are lost while the
    log is silenced.

    Yields:
        A list that holds, once the block is left, the decoders' lines, each
        named by its library (``libjpeg: Corrupt JPEG data: ...``,
        ``libpng error: ...``).
    """
    printed: list[str] = []
    with _DECODER_OUTPUT_LOCK:
        level = _OPENCV_LOGGING.getLogLevel()
        _OPENCV_LOGGING.setLogLevel(_OPENCV_LOG_SILENT)
        try:
            redirected = _stderr_to_file() if catch_stderr else None
            try:
                yield printed
            finally:
                if redirected is not None:
                    printed += _stderr_restored(*redirected)
        finally:
            _OPENCV_LOGGING.setLogLevel(level)


def _stderr_to_file() -> tuple[int, IO[bytes]] | None:
    """Point stderr's file descriptor at a new temporary file: (the saved descriptor, the file).

    None where it cannot (no stderr, no room for a temporary file): the
    decoders then print as they would.
    """
    with contextlib.suppress(AttributeError, OSError, ValueError):
        sys.stderr.flush()  # what Python wrote before goes where it was meant to
    try:
        sink = tempfile.TemporaryFile()  # noqa: SIM115 - closed by _stderr_restored
    except OSError:
        return None
    try:
        saved = os.dup(2)
    except OSError:
        sink.close()
        return None
    try:
        os.dup2(sink.fileno(), 2)
    except OSError:
        os.close(saved)
        sink.close()
        return None
    return saved, sink


def _stderr_restored(saved: int, sink: IO[bytes]) -> list[str]:
    """Put stderr back; the decoders' lines caught, what others wrote passed on to stderr."""
    try:
        os.dup2(saved, 2)
    finally:
        os.close(saved)
    with sink:
        sink.seek(0)
        caught = sink.read()
    decoders: list[str] = []
    others = bytearray()
    for raw in caught.splitlines(keepends=True):
        line = raw.decode(errors="replace").rstrip("\r\n")
        if _LIBJPEG_LINE.match(line):
            decoders.append(f"libjpeg: {line}")
        elif _LIBPNG_LINE.match(line):
            decoders.append(line)
        else:
            others += raw
    with contextlib.suppress(OSError):
        while others:
            del others[: os.write(2, others)]
    return decoders


def _check_whole(data: Encoded, source: str) -> None:
    """Refuse a file OpenCV would decode only part of, without a word on what it left out."""
    if (pages := tiff_pages(data)) > 1:
        raise ImageError(
            f"{source}: a TIFF of {pages} pages; only one-page TIFFs are read (split it "
            "into one file a page)"
        )
    if (frames := animation_frames(data)) > 1:
        raise ImageError(
            f"{source}: an animation of {frames} frames; only still images are read (OpenCV "
            "would give one frame alone: save the frame wanted as a still image)"
        )
    # Refused before decoding: OpenCV's readers differ on a cut JPEG (4.12's imdecode
    # gives nothing; its imread lets libjpeg print a line naming no file and pads the
    # missing rows grey), and none says what is wrong.
    if data[:2] == _JPEG_SOI:
        if _jpeg_truncated(data):
            raise ImageError(
                f"{source}: truncated JPEG: its data stop before the end-of-image marker (FF D9)"
            )
        if _jpeg_scans_incomplete(data):
            raise ImageError(
                f"{source}: truncated JPEG: its end-of-image marker (FF D9) comes before its "
                "scans have sent the whole image"
            )
    # libpng prints "PNG input buffer is incomplete", naming no file, beside OpenCV's
    # failure. The chunk's type could occur by chance in compressed data, and a file cut
    # after it then goes on to OpenCV as before; a whole PNG always ends in it.
    if data[:8] == _PNG_SIGNATURE and data.rfind(_PNG_END_CHUNK) < 0:
        raise ImageError(f"{source}: truncated PNG: its data stop before the end chunk (IEND)")


def read_image_file(path: str | Path, max_pixels: int) -> np.ndarray:
    """Read an image file as stored; see :func:`decode_image`.

    Its dtype and levels are the file's: a float TIFF's samples are not rescaled
    (the detector reads a float image's white at 1, :func:`~marker_localizer.core.image.to_gray`).

    Raises:
        ImageError: naming the file: missing, unreadable, too large, not an image.
    """
    try:
        with Path(path).open("rb") as file:
            info = os.fstat(file.fileno())
            if not stat.S_ISREG(info.st_mode):
                # A pipe or a device (`detect <(...)`, /dev/stdin): it has no size and
                # cannot be mapped, so it is read whole.
                return decode_image(file.read(), str(path), max_pixels)
            if not info.st_size:
                raise ImageError(f"{path}: empty file")
            with mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ) as data:
                return decode_image(data, str(path), max_pixels)
    except FileNotFoundError as err:
        raise ImageError(f"{path}: no such file") from err
    except OSError as err:
        raise ImageError(f"{path}: cannot read it ({err.strerror})") from err
