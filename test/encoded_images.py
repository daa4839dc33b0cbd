"""Encoded images written byte by byte, damaged or tagged as cameras and tools leave them.

For the tests of image files (test_image_files.py), of ``detect`` (cli/test_detect.py,
which also runs against the lowest and newest OpenCV, without ROS) and of the
compressed frames the node and replay read (:func:`compressed_message`).
"""

import struct

import cv2
import numpy as np

#: JPEG quality of image_transport's compressed plugin by default.
TRANSPORT_JPEG_QUALITY = 95


def transport_encoded(kind, pixels):
    """``pixels`` as image_transport's compressed plugin encodes them: ``jpeg`` or ``png``."""
    ok, data = cv2.imencode(
        ".jpg" if kind == "jpeg" else ".png",
        pixels,
        [cv2.IMWRITE_JPEG_QUALITY, TRANSPORT_JPEG_QUALITY] if kind == "jpeg" else [],
    )
    assert ok
    return data.tobytes()


def compressed_message(kind, sec, data, frame_id=""):
    """What image_transport's compressed plugin publishes for a mono8 camera: ``data``
    (:func:`transport_encoded`, or bytes cut or damaged), stamped ``sec``."""
    # Here, not at the top: the detect tests import this module where ROS is not installed.
    from builtin_interfaces.msg import Time  # noqa: PLC0415
    from sensor_msgs.msg import CompressedImage  # noqa: PLC0415
    from std_msgs.msg import Header  # noqa: PLC0415

    return CompressedImage(
        header=Header(stamp=Time(sec=sec), frame_id=frame_id),
        format=f"mono8; {kind} compressed mono8",
        data=data,
    )


def noise_jpeg(params=(), shape=(240, 320)):
    """A JPEG of smooth noise: its scan data fill many blocks, so a damage lands in one."""
    noise = np.random.default_rng(5).integers(0, 256, shape, dtype=np.uint8)
    ok, encoded = cv2.imencode(".jpg", cv2.GaussianBlur(noise, (0, 0), 2.0), list(params))
    assert ok
    return encoded.tobytes()


def cut_mid_scan_and_closed(data):
    """``data`` cut halfway through its scan data, and an end-of-image marker (FF D9) appended."""
    scan = data.index(b"\xff\xda")
    return data[: (scan + len(data)) // 2] + b"\xff\xd9"


def zeroed_mid_scan(data):
    """``data`` with 400 bytes in the middle of its scan data set to 0: whole to its end."""
    middle = (data.index(b"\xff\xda") + len(data)) // 2
    return data[:middle] + bytes(400) + data[middle + 400 :]


def with_exif_orientation(jpeg, orientation):
    """A JPEG with an EXIF segment (APP1) whose one entry is Orientation (274)."""
    exif = b"Exif\x00\x00" + exif_orientation(orientation)
    return jpeg[:2] + b"\xff\xe1" + struct.pack(">H", 2 + len(exif)) + exif + jpeg[2:]


def webp_with_exif_orientation(webp, width, height, orientation):
    """An extended WebP (VP8X) of ``webp``'s image with an EXIF chunk holding Orientation."""

    def chunk(kind, body):
        return kind + struct.pack("<I", len(body)) + body + bytes(len(body) % 2)

    header = bytes([0x08, 0, 0, 0]) + (width - 1).to_bytes(3, "little")  # 0x08: has EXIF
    header += (height - 1).to_bytes(3, "little")
    body = (
        b"WEBP" + chunk(b"VP8X", header) + webp[12:] + chunk(b"EXIF", exif_orientation(orientation))
    )
    return b"RIFF" + struct.pack("<I", len(body)) + body


def exif_orientation(orientation):
    """EXIF's TIFF structure with one entry: Orientation, e.g. 6 (turn 90 degrees clockwise)."""
    return b"II*\x00" + struct.pack("<IHHHIHHI", 8, 1, 274, 3, 1, orientation, 0, 0)


def tiff_entries(data):
    """Offsets of the entries of a little-endian TIFF's first directory."""
    (ifd,) = struct.unpack_from("<I", data, 4)
    (count,) = struct.unpack_from("<H", data, ifd)
    return [ifd + 2 + 12 * k for k in range(count)]


def with_tiff_orientation(data, orientation):
    """A little-endian TIFF with an Orientation entry (274) added to its first directory.

    The directory is written anew at the end of the file, its entries sorted by tag.
    """
    data = bytearray(data)
    entries = [bytes(data[at : at + 12]) for at in tiff_entries(data)]
    (ifd,) = struct.unpack_from("<I", data, 4)
    (after,) = struct.unpack_from("<I", data, ifd + 2 + 12 * len(entries))
    entries.append(struct.pack("<HHIHH", 274, 3, 1, orientation, 0))
    entries.sort(key=lambda entry: struct.unpack_from("<H", entry)[0])
    data += bytes(len(data) % 2)  # a directory starts on a word boundary
    struct.pack_into("<I", data, 4, len(data))
    return bytes(
        data + struct.pack("<H", len(entries)) + b"".join(entries) + struct.pack("<I", after)
    )


def tiff_of(pages, *, big=False, order="<", first_entries=(), claimed=None):
    """A grey 8-bit TIFF of ``pages``, byte by byte: a BigTIFF (version 43) with ``big``.

    cv2.imwrite writes no BigTIFF. ``first_entries`` are (tag, value) pairs added to the
    first page's directory, e.g. (254, 1) to make the page a thumbnail; ``claimed`` is
    the (width, height) it states in place of the first page's.
    """
    header = struct.pack(order + "HHHQ", 43, 8, 0, 0) if big else struct.pack(order + "HI", 42, 0)
    out = bytearray((b"II" if order == "<" else b"MM") + header)
    count, offset, value = ("Q", "Q", "8s") if big else ("H", "I", "4s")
    pointer = 8 if big else 4  # where the next directory's offset goes
    for k, page in enumerate(pages):
        at = len(out)
        out += page.tobytes() + bytes(page.size % 2)
        width, height = claimed if k == 0 and claimed else page.shape[::-1]
        entries = sorted(
            [*(first_entries if k == 0 else ()), (256, width), (257, height), (258, 8)]
            + [(259, 1), (262, 1), (273, at), (277, 1), (278, height), (279, page.size)]
        )
        struct.pack_into(order + offset, out, pointer, len(out))
        out += struct.pack(order + count, len(entries))
        for tag, v in entries:
            kind, fmt = (3, "H") if v < 2**16 else (4, "I")
            out += struct.pack(
                order + "HH" + offset + value, tag, kind, 1, struct.pack(order + fmt, v)
            )
        pointer = len(out)
        out += struct.pack(order + offset, 0)
    return bytes(out)
