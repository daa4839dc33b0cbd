"""Encoded images (files, compressed messages) to arrays, with their size checked first.

A few hundred kilobytes of PNG can claim 30000x30000 pixels and take 12 GB to
decode, so the size is read from the header and checked against
``DetectorConfig.max_pixels`` before any pixel is decoded. Headers are parsed
here for PNG, JPEG, TIFF, BMP, WebP and the PNM family (PBM, PGM, PPM, PFM);
other formats OpenCV reads (OpenEXR, Radiance HDR, JPEG 2000, Sun raster) are
checked after decoding, within OpenCV's own limit of 2**30 pixels. A TIFF of
more than one page is refused, as OpenCV would give its first page alone, and
so is a truncated JPEG or PNG, which libjpeg or libpng would report on stderr
without naming it. Every failure, an OpenCV exception included, becomes one
:class:`ImageError` naming the source.
"""

from __future__ import annotations

import mmap
import re
import struct
from collections.abc import Callable, Iterator
from pathlib import Path

import cv2
import numpy as np

from marker_localizer.errors import ImageError

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: The type of the chunk that closes every PNG.
_PNG_END_CHUNK = b"IEND"
#: JPEG start-of-frame markers (baseline, progressive, lossless, arithmetic); they carry the size.
_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
#: JPEG markers without a length field: TEM, RSTn, SOI.
_JPEG_STANDALONE = frozenset({0x01, *range(0xD0, 0xD9)})
_JPEG_SOI, _JPEG_EOI, _JPEG_SOS = b"\xff\xd8", b"\xff\xd9", 0xDA
_TIFF_SUBFILE_TYPE, _TIFF_WIDTH, _TIFF_LENGTH = 254, 256, 257
#: Directories a TIFF's page count follows at most: the time a crafted chain of them
#: can take stays a fraction of a second.
_TIFF_MAX_DIRECTORIES = 65535
#: NewSubfileType bits of a directory that is not a page: reduced resolution, transparency mask.
_TIFF_NOT_A_PAGE = 0b101
_TIFF_SIGNATURES = (b"II*\x00", b"MM\x00*")
_PNM_HEADER = re.compile(rb"^P[1-6fF](?:\s+|#[^\n]*\n)+(\d+)(?:\s+|#[^\n]*\n)+(\d+)")


#: Encoded bytes in memory, or a file mapped read-only (its pages are read only where looked at).
Encoded = bytes | mmap.mmap


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


def _png_size(data: Encoded) -> tuple[int, int]:
    width, height = struct.unpack(">II", data[16:24])  # IHDR, always the first chunk
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


def _tiff_size(data: Encoded) -> tuple[int, int] | None:
    order = "<" if data[:2] == b"II" else ">"
    (ifd,) = struct.unpack(order + "I", data[4:8])
    (entries,) = struct.unpack(order + "H", data[ifd : ifd + 2])
    found: dict[int, int] = {}
    for k in range(entries):
        entry = data[ifd + 2 + 12 * k : ifd + 14 + 12 * k]
        tag, kind = struct.unpack(order + "HH", entry[:4])
        if tag in (_TIFF_WIDTH, _TIFF_LENGTH):
            fmt = "H" if kind == 3 else "I"  # SHORT or LONG, stored in the entry
            found[tag] = struct.unpack(order + fmt, entry[8 : 10 if kind == 3 else 12])[0]
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
        data: the encoded TIFF (little- or big-endian; not BigTIFF).
    """
    order = "<" if data[:2] == b"II" else ">"
    pages, seen = 0, set[int]()
    try:
        (ifd,) = struct.unpack_from(order + "I", data, 4)
        while ifd and ifd not in seen and len(seen) < _TIFF_MAX_DIRECTORIES:
            seen.add(ifd)
            # Entries are sorted by tag and NewSubfileType's is the lowest TIFF
            # defines: where it is present it is the first, so a directory costs
            # the same whatever number of entries it claims.
            entries, tag, kind = struct.unpack_from(order + "HHH", data, ifd)
            fmt = "H" if kind == 3 else "I"  # SHORT or LONG, stored in the entry
            (subfile_type,) = struct.unpack_from(order + fmt, data, ifd + 10)
            pages += not (tag == _TIFF_SUBFILE_TYPE and subfile_type & _TIFF_NOT_A_PAGE)
            (ifd,) = struct.unpack_from(order + "I", data, ifd + 2 + 12 * entries)
    except struct.error:
        pass  # a directory cut short: the pages before it are counted
    return pages


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
    **dict.fromkeys(_TIFF_SIGNATURES, _tiff_size),
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

    Args:
        data: the encoded bytes (PNG, JPEG, TIFF, ... as OpenCV reads them).
        source: what to name in an error (file path, topic).
        max_pixels: largest width x height accepted, px.

    Returns:
        The image as :func:`cv2.imdecode` with ``IMREAD_UNCHANGED`` gives it.

    Raises:
        ImageError: too large, not an image, empty, a TIFF of more than one
            page, a truncated JPEG, or OpenCV failed on it.
    """
    if not len(data):
        raise ImageError(f"{source}: no data (0 bytes)")
    size = image_size(data)
    if size is not None:
        check_pixel_count(*size, max_pixels, source)
    _check_whole(data, source)
    buffer = np.frombuffer(data, np.uint8)
    try:
        image = cv2.imdecode(buffer, cv2.IMREAD_UNCHANGED)
    except cv2.error as err:
        raise ImageError(f"{source}: OpenCV cannot decode it ({err.err})") from err
    finally:
        del buffer  # a mapped file cannot close while a view of it lives
    if image is None:
        raise ImageError(f"{source}: not a readable image")
    if image.size == 0:
        raise ImageError(f"{source}: empty image")
    check_pixel_count(image.shape[1], image.shape[0], max_pixels, source)
    return image


def _check_whole(data: Encoded, source: str) -> None:
    """Refuse a file OpenCV would decode only part of, without a word on what it left out."""
    if data[:4] in _TIFF_SIGNATURES and (pages := tiff_pages(data)) > 1:
        raise ImageError(
            f"{source}: a TIFF of {pages} pages; only one-page TIFFs are read (split it "
            "into one file a page)"
        )
    # Refused before decoding: OpenCV's readers differ on a cut JPEG (4.12's imdecode
    # gives nothing; its imread lets libjpeg print a line naming no file and pads the
    # missing rows grey), and none says what is wrong.
    if data[:2] == _JPEG_SOI and _jpeg_truncated(data):
        raise ImageError(
            f"{source}: truncated JPEG: its data stop before the end-of-image marker (FF D9)"
        )
    # libpng prints "PNG input buffer is incomplete", naming no file, beside OpenCV's
    # failure. The chunk's type could occur by chance in compressed data, and a file cut
    # after it then goes on to OpenCV as before; a whole PNG always ends in it.
    if data[:8] == _PNG_SIGNATURE and data.rfind(_PNG_END_CHUNK) < 0:
        raise ImageError(f"{source}: truncated PNG: its data stop before the end chunk (IEND)")


def read_image_file(path: str | Path, max_pixels: int) -> np.ndarray:
    """Read an image file as stored; see :func:`decode_image`.

    Raises:
        ImageError: naming the file: missing, unreadable, too large, not an image.
    """
    try:
        with Path(path).open("rb") as file:
            if not Path(path).stat().st_size:
                raise ImageError(f"{path}: empty file")
            with mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ) as data:
                return decode_image(data, str(path), max_pixels)
    except FileNotFoundError as err:
        raise ImageError(f"{path}: no such file") from err
    except OSError as err:
        raise ImageError(f"{path}: cannot read it ({err.strerror})") from err
