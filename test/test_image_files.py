"""Image files: the size is read from the header before decoding, every failure names the file."""

import io
import json
import os
import re
import struct
import subprocess
import sys
import zlib
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
import pytest
from encoded_images import (
    cut_mid_scan_and_closed,
    exif_orientation,
    noise_jpeg,
    tiff_entries,
    tiff_of,
    webp_with_exif_orientation,
    with_exif_orientation,
    with_tiff_orientation,
    zeroed_mid_scan,
)

from marker_localizer.cli import main
from marker_localizer.config import DetectorConfig
from marker_localizer.errors import ImageError
from marker_localizer.image_files import (
    animation_frames,
    decode_image,
    image_size,
    read_image_file,
    tiff_pages,
)

#: Peak memory a decompression bomb may cost the CLI, KiB (ru_maxrss): the issue's 2 GB.
BOMB_PEAK_LIMIT_KIB = 2 * 1024 * 1024


def png_chunk(kind, body):
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def png_header(width, height):
    """The signature and IHDR of a grey 8-bit PNG: all that is read of a file too large."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", ihdr)


def png_of_zeros(width, height):
    """A valid grey 8-bit PNG of zeros: tiny on disk, width x height bytes once decoded."""
    deflate = zlib.compressobj(9)
    rows = 1000
    block = bytes((width + 1) * rows)  # each row: filter byte 0, then the pixels
    idat = [deflate.compress(block) for _ in range(height // rows)]
    idat += [deflate.compress(bytes((width + 1) * (height % rows))), deflate.flush()]
    return png_header(width, height) + png_chunk(b"IDAT", b"".join(idat)) + png_chunk(b"IEND", b"")


@pytest.fixture(scope="module")
def bomb(tmp_path_factory):
    """The issue's bomb: a 0.9 MB PNG that decodes to 30000x30000 (12 GB through detect)."""
    path = tmp_path_factory.mktemp("bomb") / "bomb.png"
    path.write_bytes(png_of_zeros(30000, 30000))
    return path


@pytest.fixture
def good(tmp_path):
    image = np.full((64, 64), 200, np.uint8)
    image[:32, :32] = image[32:, 32:] = 30
    path = tmp_path / "good.png"
    cv2.imwrite(str(path), cv2.GaussianBlur(image, (0, 0), 1.0))
    return path


@pytest.mark.parametrize(
    ("suffix", "channels", "dtype", "params"),
    [
        ("png", 1, np.uint16, []),
        ("jpg", 3, np.uint8, []),
        ("jpg", 1, np.uint8, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1]),
        ("tiff", 1, np.float32, []),
        ("bmp", 3, np.uint8, []),
        ("pgm", 1, np.uint16, []),
        ("ppm", 3, np.uint8, []),
        ("pfm", 3, np.float32, []),
        ("webp", 3, np.uint8, []),
        ("webp", 4, np.uint8, [cv2.IMWRITE_WEBP_QUALITY, 101]),  # lossless
    ],
)
def test_the_header_gives_the_size_of_every_parsed_format(
    tmp_path, suffix, channels, dtype, params
):
    path = tmp_path / f"image.{suffix}"
    assert cv2.imwrite(str(path), np.zeros((37, 53, channels), dtype).squeeze(), params)
    assert image_size(path.read_bytes()) == (53, 37)


def test_a_cut_header_or_an_unknown_format_gives_no_size(tmp_path):
    path = tmp_path / "image.png"
    cv2.imwrite(str(path), np.zeros((37, 53), np.uint8))
    assert image_size(path.read_bytes()[:20]) is None
    assert image_size(b"#?RADIANCE\n") is None


def test_the_bomb_is_refused_from_its_header_and_the_next_image_still_runs(bomb, good):
    """In a fresh process, so that its peak memory is the command's own."""
    script = (
        "import resource, sys\n"
        "from marker_localizer.cli import main\n"
        "status = main(sys.argv[1:])\n"
        "print('peak', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr)\n"
        "sys.exit(status)\n"
    )
    run = subprocess.run(
        [sys.executable, "-c", script, "detect", str(bomb), str(good), "--json"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    errors = run.stderr.splitlines()
    assert run.returncode == 3  # one image gave a result, one did not
    assert errors[0] == (
        f"marker-localizer: error: {bomb}: 30000x30000 = 900000000 px exceeds "
        f"max_pixels={DetectorConfig().max_pixels}"
    )
    assert int(errors[1].split()[1]) < BOMB_PEAK_LIMIT_KIB
    assert len(errors) == 2
    (record,) = (json.loads(line) for line in run.stdout.splitlines())
    assert record["image"] == str(good) and len(record["markers"]) == 1


def test_an_image_over_opencvs_own_limit_is_one_line_and_the_rest_still_run(tmp_path, good, capsys):
    huge_png = tmp_path / "huge.png"
    huge_png.write_bytes(png_header(40000, 40000))
    # Radiance HDR: a format whose header is not parsed here, so OpenCV's own
    # size check raises a cv2.error inside imdecode.
    huge_hdr = tmp_path / "huge.hdr"
    huge_hdr.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 40000 +X 40000\n" + bytes(64))
    status = main(
        [
            "detect",
            str(huge_png),
            str(huge_hdr),
            str(good),
            "--json",
            "--param",
            f"max_pixels={2**30}",
        ]
    )
    captured = capsys.readouterr()
    assert status == 3
    assert captured.err.splitlines() == [
        f"marker-localizer: error: {huge_png}: 40000x40000 = 1600000000 px exceeds "
        f"max_pixels={2**30}",
        f"marker-localizer: error: {huge_hdr}: OpenCV cannot decode it "
        "(pixels <= CV_IO_MAX_IMAGE_PIXELS)",
    ]
    assert len(captured.out.splitlines()) == 1


def test_a_float_image_with_nan_names_the_file(tmp_path, good, capsys):
    pixels = np.full((64, 64), 0.5, np.float32)
    pixels[10, 20] = np.nan
    nan_file = tmp_path / "nan.tiff"
    cv2.imwrite(str(nan_file), pixels)
    assert main(["detect", str(nan_file), str(good), "--json"]) == 3
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [
        f"marker-localizer: error: {nan_file}: image contains NaN or infinite values"
    ]
    assert len(captured.out.splitlines()) == 1


def test_a_directory_and_an_empty_file_are_named_with_what_is_wrong(tmp_path):
    empty = tmp_path / "empty.png"
    empty.touch()
    with pytest.raises(ImageError, match=r"empty\.png: empty file"):
        read_image_file(empty, DetectorConfig().max_pixels)
    with pytest.raises(
        ImageError, match=rf"^{re.escape(str(tmp_path))}: cannot read it \(Is a dir"
    ):
        read_image_file(tmp_path, DetectorConfig().max_pixels)


def test_decoded_size_is_checked_for_formats_without_a_parsed_header():
    pixels = np.zeros((20, 30, 3), np.float32)
    ok, hdr = cv2.imencode(".hdr", pixels)
    assert ok
    assert decode_image(hdr.tobytes(), "small.hdr", 600).shape == (20, 30, 3)
    with pytest.raises(ImageError, match=r"small\.hdr: 30x20 = 600 px exceeds max_pixels=599"):
        decode_image(hdr.tobytes(), "small.hdr", 599)


@pytest.fixture
def two_page_tiff(tmp_path):
    """A 2-page TIFF as OpenCV writes one: each page's NewSubfileType says 'a page'."""
    path = tmp_path / "two.tiff"
    first = np.full((40, 50), 80, np.uint8)
    assert cv2.imwritemulti(str(path), [first, 255 - first])
    return path


def tiff_directories(data):
    """Offsets of a little-endian TIFF's directories (IFDs), as OpenCV writes them here."""
    offsets = [struct.unpack_from("<I", data, 4)[0]]
    while True:
        (entries,) = struct.unpack_from("<H", data, offsets[-1])
        (after,) = struct.unpack_from("<I", data, offsets[-1] + 2 + 12 * entries)
        if not after:
            return offsets
        offsets.append(after)


def tiff_with_thumbnail(data):
    """``data`` with its second directory's NewSubfileType (tag 254, first entry) set to 1."""
    data = bytearray(data)
    entry = tiff_directories(data)[1] + 2
    assert struct.unpack_from("<H", data, entry)[0] == 254
    struct.pack_into("<I", data, entry + 8, 1)
    return bytes(data)


def tiff_looping(data):
    """``data`` with its last directory pointing back to its first."""
    data = bytearray(data)
    first, *_, last = tiff_directories(data)
    (entries,) = struct.unpack_from("<H", data, last)
    struct.pack_into("<I", data, last + 2 + 12 * entries, first)
    return bytes(data)


def test_a_multi_page_tiff_is_refused_with_its_page_count_not_cut_to_its_first(
    two_page_tiff, good, capsys
):
    assert main(["detect", str(two_page_tiff), str(good), "--json"]) == 3
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [
        f"marker-localizer: error: {two_page_tiff}: a TIFF of 2 pages; only one-page TIFFs "
        "are read (split it into one file a page)"
    ]
    assert [json.loads(line)["image"] for line in captured.out.splitlines()] == [str(good)]
    with pytest.raises(ImageError, match=r"two\.tiff: a TIFF of 2 pages"):
        read_image_file(two_page_tiff, DetectorConfig().max_pixels)
    with pytest.raises(ImageError, match=r"^message: a TIFF of 2 pages"):
        decode_image(two_page_tiff.read_bytes(), "message", DetectorConfig().max_pixels)


def test_a_tiffs_pages_leave_out_reduced_resolution_copies_and_count_each_directory_once(
    tmp_path, two_page_tiff
):
    """A thumbnail or a GeoTIFF's overview after the image is not a page of its own."""
    data = two_page_tiff.read_bytes()
    single = tmp_path / "single.tiff"
    cv2.imwrite(str(single), np.zeros((8, 8), np.uint8))
    assert tiff_pages(single.read_bytes()) == 1
    assert tiff_pages(data) == 2
    assert tiff_pages(tiff_looping(data)) == 2
    assert tiff_pages(tiff_with_thumbnail(data)) == 1
    assert decode_image(tiff_with_thumbnail(data), "thumbnailed", 10**6).shape == (40, 50)


def jpeg_with_thumbnail(image, thumbnail):
    """A JPEG of ``image`` whose APP1 segment holds a JPEG of ``thumbnail``, as EXIF's does."""
    ok, encoded = cv2.imencode(".jpg", image)
    ok_thumbnail, small = cv2.imencode(".jpg", thumbnail)
    assert ok and ok_thumbnail
    body = b"Exif\x00\x00" + small.tobytes()
    app1 = b"\xff\xe1" + struct.pack(">H", 2 + len(body)) + body
    return encoded.tobytes()[:2] + app1 + encoded.tobytes()[2:]


def test_a_truncated_jpeg_is_one_line_of_ours_naming_the_file(tmp_path, good, capfd):
    """Cut in its EXIF thumbnail, in its header after the thumbnail's end, or in its scan data."""
    image = cv2.imread(str(good), cv2.IMREAD_GRAYSCALE)
    whole = jpeg_with_thumbnail(image, image[::8, ::8])
    scan = whole.rindex(b"\xff\xda")  # the image's; its thumbnail's comes first
    thumbnail_end = whole.index(b"\xff\xd9")
    cuts = {"thumbnail": thumbnail_end // 2, "header": scan - 10, "scan": (scan + len(whole)) // 2}
    paths = []
    for name, length in cuts.items():
        paths.append(tmp_path / f"cut_in_its_{name}.jpg")
        paths[-1].write_bytes(whole[:length])
    assert main(["detect", *map(str, paths), str(good), "--json"]) == 3
    captured = capfd.readouterr()  # libjpeg's and OpenCV's own lines included
    assert captured.err.splitlines() == [
        f"marker-localizer: error: {path}: truncated JPEG: its data stop before the "
        "end-of-image marker (FF D9)"
        for path in paths
    ]
    assert len(captured.out.splitlines()) == 1
    with pytest.raises(ImageError, match=r"^frame: truncated JPEG"):
        decode_image(whole[: cuts["scan"]], "frame", DetectorConfig().max_pixels)


def test_a_truncated_png_is_one_line_of_ours_naming_the_file(tmp_path, capfd):
    noise = np.random.default_rng(3).integers(0, 256, (120, 160), dtype=np.uint8)
    ok, encoded = cv2.imencode(".png", noise)
    assert ok
    whole = encoded.tobytes()
    cut = tmp_path / "cut.png"
    cut.write_bytes(whole[: len(whole) // 2])
    assert main(["detect", str(cut)]) == 1
    assert capfd.readouterr().err.splitlines() == [
        f"marker-localizer: error: {cut}: truncated PNG: its data stop before the end chunk (IEND)"
    ]
    assert decode_image(whole, "whole", DetectorConfig().max_pixels).shape == (120, 160)


@pytest.mark.parametrize(
    "params",
    [[], [cv2.IMWRITE_JPEG_PROGRESSIVE, 1], [cv2.IMWRITE_JPEG_RST_INTERVAL, 1]],
    ids=["baseline", "progressive", "restart markers"],
)
def test_a_whole_jpeg_is_read_with_or_without_a_thumbnail_and_trailing_bytes(params):
    image = np.full((48, 64), 90, np.uint8)
    ok, encoded = cv2.imencode(".jpg", image, params)
    assert ok
    for data in (
        encoded.tobytes(),
        jpeg_with_thumbnail(image, image[::8, ::8]),
        encoded.tobytes() + bytes(64),  # padding some cameras write after the image
    ):
        assert decode_image(data, "whole", DetectorConfig().max_pixels).shape == (48, 64)


def test_a_jpeg_damaged_in_its_scan_is_refused_in_one_line_naming_the_damage(tmp_path, good, capfd):
    """libjpeg decodes it with grey or smeared blocks and prints a line that names no file."""
    whole = noise_jpeg()
    paths = [tmp_path / "cut_and_closed.jpg", tmp_path / "zeroed.jpg"]
    paths[0].write_bytes(cut_mid_scan_and_closed(whole))
    paths[1].write_bytes(zeroed_mid_scan(whole))
    assert main(["detect", *map(str, paths), str(good), "--json"]) == 3
    captured = capfd.readouterr()  # libjpeg's own line would be here
    assert captured.err.splitlines() == [
        f"marker-localizer: error: {path}: damaged JPEG (libjpeg: Corrupt JPEG data: premature "
        "end of data segment)"
        for path in paths
    ]
    assert [json.loads(line)["image"] for line in captured.out.splitlines()] == [str(good)]
    with pytest.raises(ImageError, match=r"^frame: damaged JPEG \(libjpeg: Corrupt JPEG data: "):
        decode_image(cut_mid_scan_and_closed(whole), "frame", DetectorConfig().max_pixels)
    assert decode_image(whole, "whole", DetectorConfig().max_pixels).shape == (240, 320)


def test_a_progressive_jpeg_cut_between_scans_and_closed_is_refused(capfd):
    """libjpeg decodes it blurred, without a word: the scans it lacks are counted here."""
    whole = noise_jpeg([cv2.IMWRITE_JPEG_PROGRESSIVE, 1])
    scans = [m.start() for m in re.finditer(rb"\xff\xda", whole)]
    assert len(scans) > 2
    for scan in scans[1:]:  # cut where each later scan starts, closed
        with pytest.raises(ImageError, match=r"^frame: truncated JPEG: its end-of-image marker "):
            decode_image(whole[:scan] + b"\xff\xd9", "frame", DetectorConfig().max_pixels)
    assert capfd.readouterr().err == ""
    assert decode_image(whole, "whole", DetectorConfig().max_pixels).shape == (240, 320)


@pytest.mark.parametrize("suffix", [".png", ".webp", ".gif"])
def test_an_animation_is_refused_with_its_frame_count_not_cut_to_one_frame(tmp_path, suffix):
    image = pytest.importorskip("PIL.Image")
    # The markers may be in any frame but the one OpenCV gives.
    frames = [image.fromarray(np.full((24, 32), level, np.uint8)) for level in (40, 90, 160)]
    animated, still = tmp_path / f"animated{suffix}", tmp_path / f"still{suffix}"
    frames[0].save(animated, save_all=True, append_images=frames[1:], duration=100, loop=0)
    frames[0].save(still)
    assert animation_frames(animated.read_bytes()) == 3
    assert animation_frames(still.read_bytes()) == 1
    refused = rf"animated\{suffix}: an animation of 3 frames; only still images are read"
    with pytest.raises(ImageError, match=refused):
        read_image_file(animated, DetectorConfig().max_pixels)


def test_an_animation_cut_short_counts_the_frames_before_the_cut():
    image = pytest.importorskip("PIL.Image")
    frames = [image.fromarray(np.full((24, 32), level, np.uint8)) for level in (40, 90, 160)]
    gif = io.BytesIO()
    frames[0].save(gif, format="GIF", save_all=True, append_images=frames[1:])
    data = gif.getvalue()
    assert animation_frames(data[:-1]) == 3  # without its trailer
    assert animation_frames(data[: data.rindex(b"\x2c")]) == 2  # cut before the last frame


def test_a_png_whose_header_chunk_is_damaged_is_named_by_libpng_not_as_too_large(tmp_path, capfd):
    data = bytearray(cv2.imencode(".png", np.full((30, 40), 90, np.uint8))[1].tobytes())
    data[16] ^= 0x80  # the width's top bit: 2**31 + 40 px, if the header were believed
    assert image_size(bytes(data)) is None
    damaged = tmp_path / "damaged.png"
    damaged.write_bytes(data)
    assert main(["detect", str(damaged), "--param", "max_pixels=1073741824"]) == 1
    (line,) = capfd.readouterr().err.splitlines()
    assert "max_pixels" not in line
    assert re.fullmatch(
        rf"marker-localizer: error: {re.escape(str(damaged))}: not a readable image.*", line
    )


def test_an_image_given_through_a_pipe_is_read_whole(tmp_path):
    data = cv2.imencode(".png", np.full((30, 40), 90, np.uint8))[1].tobytes()
    fifo = tmp_path / "frame.png"
    os.mkfifo(fifo)
    with ThreadPoolExecutor(1) as writer:
        writer.submit(fifo.write_bytes, data)
        image = read_image_file(fifo, DetectorConfig().max_pixels)
    assert image.shape == (30, 40)
    assert (image == 90).all()


def test_a_damaged_png_is_one_line_with_libpngs_reason_in_it(tmp_path, capfd):
    data = bytearray(cv2.imencode(".png", np.full((30, 40), 90, np.uint8))[1].tobytes())
    data[data.index(b"IDAT") + 8] ^= 0xFF  # the image's data no longer match its checksum
    damaged = tmp_path / "damaged.png"
    damaged.write_bytes(data)
    assert main(["detect", str(damaged)]) == 1
    (line,) = capfd.readouterr().err.splitlines()  # libpng's reason depends on its version
    assert re.fullmatch(
        rf"marker-localizer: error: {re.escape(str(damaged))}: not a readable image "
        r"\(libpng error: IDAT: [\w ]+\)",
        line,
    )


def test_stderr_and_opencvs_log_level_are_put_back_whatever_the_decode_gave(tmp_path):
    stderr_file = os.fstat(2)
    logging = getattr(cv2.utils, "logging", cv2)  # OpenCV 5 moved it
    level = logging.getLogLevel()
    hdr = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 40000 +X 40000\n" + bytes(64)
    damaged = [cut_mid_scan_and_closed(noise_jpeg()), hdr, b"\x89PNG\r\n\x1a\nIEND", b"junk"]
    for data in damaged:  # refused by libjpeg's line, by a cv2.error, by OpenCV, unknown
        with pytest.raises(ImageError):
            decode_image(data, "frame", 2**30)
        assert (os.fstat(2).st_dev, os.fstat(2).st_ino) == (stderr_file.st_dev, stderr_file.st_ino)
        assert logging.getLogLevel() == level


def test_what_others_write_to_stderr_during_a_decode_is_passed_on(monkeypatch, capfd):
    """A line another thread (the node's logger, DDS) writes meanwhile is late, not lost."""
    decode = cv2.imdecode

    def decode_beside_a_logger(buffer, flags):
        os.write(2, b"[WARN] [camera_driver]: frame late\n")
        return decode(buffer, flags)

    monkeypatch.setattr(cv2, "imdecode", decode_beside_a_logger)
    with pytest.raises(ImageError, match=r"damaged JPEG \(libjpeg: Corrupt JPEG data"):
        decode_image(cut_mid_scan_and_closed(noise_jpeg()), "frame", DetectorConfig().max_pixels)
    assert capfd.readouterr().err == "[WARN] [camera_driver]: frame late\n"


def test_threads_decoding_at_once_each_get_their_own_verdict(capfd):
    """stderr's descriptor is the process's: decodes that caught it at once would mix lines."""
    whole = noise_jpeg()
    frames = [whole, cut_mid_scan_and_closed(whole), zeroed_mid_scan(whole)] * 64

    def verdict(data):
        try:
            return decode_image(data, "frame", DetectorConfig().max_pixels).shape
        except ImageError as err:
            return str(err)

    with ThreadPoolExecutor(8) as pool:
        verdicts = list(pool.map(verdict, frames))
    damaged = "frame: damaged JPEG (libjpeg: Corrupt JPEG data: premature end of data segment)"
    assert verdicts == [(240, 320), damaged, damaged] * 64
    assert capfd.readouterr().err == ""


def test_opencvs_warnings_on_a_corrupt_tiff_webp_or_png_header_are_not_printed(tmp_path, capfd):
    """OpenCV would print "[ WARN:0@...] global grfmt_tiff.cpp ..." or an [ERROR] line."""
    grey = np.full((30, 40), 90, np.uint8)
    tiff = bytearray(cv2.imencode(".tiff", grey)[1].tobytes())
    (entry,) = (at for at in tiff_entries(tiff) if struct.unpack_from("<H", tiff, at)[0] == 262)
    struct.pack_into("<H", tiff, entry + 8, 0xFFFF)  # PhotometricInterpretation: none known
    png = bytearray(cv2.imencode(".png", grey)[1].tobytes())
    png[12:16] = b"IHDX"  # the first chunk is not IHDR
    webp = cv2.imencode(".webp", cv2.merge([grey] * 3))[1].tobytes()
    paths = []
    for name, data in [("bad.tiff", tiff), ("bad.png", png), ("cut.webp", webp[:34])]:
        paths.append(tmp_path / name)
        paths[-1].write_bytes(data)
    assert main(["detect", *map(str, paths)]) == 1
    lines = capfd.readouterr().err.splitlines()
    assert lines[0] == f"marker-localizer: error: {paths[0]}: not a readable image"
    assert lines[1] in {  # OpenCV 4.12 finds it before libpng; 4.6 lets libpng say it
        f"marker-localizer: error: {paths[1]}: not a readable image",
        f"marker-localizer: error: {paths[1]}: not a readable image "
        "(libpng error: IHDX: CRC error)",
    }
    assert lines[2:] == [f"marker-localizer: error: {paths[2]}: not a readable image"]


@pytest.mark.parametrize("order", ["<", ">"])
def test_a_bigtiff_is_read_its_pages_counted_and_its_size_checked_from_its_header(order):
    first = np.arange(40 * 50, dtype=np.uint8).reshape(40, 50)
    single = tiff_of([first], big=True, order=order)
    assert single[:4] == (b"II+\x00" if order == "<" else b"MM\x00+")
    assert image_size(single) == (50, 40)
    assert tiff_pages(single) == 1
    np.testing.assert_array_equal(decode_image(single, "big", 10**6), first)
    two = tiff_of([first, 255 - first], big=True, order=order)
    assert tiff_pages(two) == 2
    with pytest.raises(ImageError, match=r"^big: a TIFF of 2 pages"):
        decode_image(two, "big", 10**6)
    thumbnailed = tiff_of([first[::4, ::4], first], big=True, order=order, first_entries=[(254, 1)])
    assert tiff_pages(thumbnailed) == 1
    # A classic TIFF written the same way reads the same.
    assert tiff_pages(tiff_of([first, first], order=order)) == 2
    np.testing.assert_array_equal(decode_image(tiff_of([first], order=order), "tiff", 10**6), first)


def test_a_bigtiff_bomb_is_refused_from_its_header():
    bomb = tiff_of([np.zeros((1, 1), np.uint8)], big=True, claimed=(30000, 30000))
    assert image_size(bomb) == (30000, 30000)
    with pytest.raises(ImageError, match=r"^bomb: 30000x30000 = 900000000 px exceeds"):
        decode_image(bomb, "bomb", DetectorConfig().max_pixels)


@pytest.fixture
def corner_block():
    """A 40x60 image, bright in its top-left 10x20: its stored order shows."""
    image = np.zeros((40, 60), np.uint8)
    image[:10, :20] = 250
    return image


def test_an_exif_orientation_is_not_applied_to_a_jpeg_png_or_webp_from_file_or_bytes(
    tmp_path, corner_block
):
    """Pixels stay in stored order, as the sensor gave them (imread's default would turn them)."""
    variants = {}
    for name, image in [("grey", corner_block), ("colour", cv2.merge([corner_block] * 3))]:
        variants[f"{name}.jpg"] = with_exif_orientation(cv2.imencode(".jpg", image)[1].tobytes(), 6)
    for name, image in [("8bit", corner_block), ("16bit", corner_block.astype(np.uint16) * 257)]:
        png = cv2.imencode(".png", image)[1].tobytes()
        end = png.rindex(b"IEND") - 4
        variants[f"{name}.png"] = png[:end] + png_chunk(b"eXIf", exif_orientation(6)) + png[end:]
    webp = cv2.imencode(".webp", cv2.merge([corner_block] * 3))[1].tobytes()
    for data in variants.values():  # as cv2.imread's default would (a WebP too from OpenCV 5)
        assert cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR).shape[:2] == (60, 40)
    variants["colour.webp"] = webp_with_exif_orientation(webp, 60, 40, 6)
    for name, data in variants.items():
        (tmp_path / name).write_bytes(data)
        for image in (
            decode_image(data, name, DetectorConfig().max_pixels),
            read_image_file(tmp_path / name, DetectorConfig().max_pixels),
        ):
            assert image.shape[:2] == (40, 60), name
            assert image[:10, :20].min() > 200 and image[10:, 20:].max() < 50, name


@pytest.mark.parametrize(
    "image",
    [
        np.arange(6 * 10, dtype=np.uint8).reshape(6, 10),
        np.arange(6 * 10, dtype=np.uint16).reshape(6, 10) * 1000,
        np.dstack([np.arange(6 * 10, dtype=np.uint8).reshape(6, 10) + c for c in range(3)]),
    ],
    ids=["grey", "16-bit", "colour"],
)
def test_a_tiffs_orientation_tag_is_not_applied_either(image):
    """OpenCV turns a TIFF by its own tag even when asked for it unchanged; not here."""
    stored = cv2.imencode(".tiff", image)[1].tobytes()
    for orientation in range(1, 9):
        data = with_tiff_orientation(stored, orientation)
        opencvs = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        assert opencvs.shape[:2] == ((10, 6) if orientation > 4 else (6, 10))
        np.testing.assert_array_equal(decode_image(data, "tiff", 10**6), image)


def test_a_bigtiffs_orientation_tag_is_not_applied():
    image = np.arange(6 * 10, dtype=np.uint8).reshape(6, 10)
    turned = tiff_of([image], big=True, first_entries=[(274, 6)])
    assert cv2.imdecode(np.frombuffer(turned, np.uint8), cv2.IMREAD_UNCHANGED).shape == (10, 6)
    np.testing.assert_array_equal(decode_image(turned, "bigtiff", 10**6), image)
