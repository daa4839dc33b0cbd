"""``marker-localizer detect``: the JSON-lines contract, overlays and error handling."""

import json
import os
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from blas_threads import openblas_threads, two_threaded_openblas
from encoded_images import (
    cut_mid_scan_and_closed,
    noise_jpeg,
    tiff_entries,
    with_exif_orientation,
    with_tiff_orientation,
)

from marker_localizer import Detector, DetectorConfig
from marker_localizer.cli import main
from marker_localizer.synthetic.scene import bayer_gain


@pytest.fixture
def x_image(tmp_path):
    image = np.full((64, 64), 200.0, np.float32)
    image[:32, :32] = image[32:, 32:] = 30.0
    image = cv2.GaussianBlur(image, (0, 0), 1.0).round().astype(np.uint8)
    path = tmp_path / "x.png"
    cv2.imwrite(str(path), image)
    return path, image


def test_detect_json_prints_one_object_per_image_with_the_contract_keys(x_image, tmp_path, capsys):
    path, _image = x_image
    flat = tmp_path / "flat.png"
    cv2.imwrite(str(flat), np.full((40, 50), 80, np.uint8))
    assert main(["detect", str(path), str(flat), "--json"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    first, second = (json.loads(line) for line in lines)
    assert set(first) == {"image", "width", "height", "elapsed_ms", "markers"}
    assert (first["width"], first["height"]) == (64, 64)
    marker = first["markers"][0]
    assert set(marker) == {"x", "y", "score", "sigma", "angles", "reading"}
    assert marker["x"] == pytest.approx(31.5, abs=1e-3) and len(marker["angles"]) == 2
    assert marker["reading"] == "first pass"
    assert second["markers"] == []


def test_a_file_name_that_is_not_utf8_is_written_as_text_with_its_bytes_escaped(
    x_image, tmp_path, capsys
):
    """JSON holds Unicode text: a lone surrogate in "image" is no name a reader can decode."""
    path, _image = x_image
    renamed = os.fsdecode(os.fsencode(tmp_path) + b"/bad\xff.png")
    os.rename(path, renamed)
    assert main(["detect", renamed, "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["image"].endswith("bad\\xff.png")
    record["image"].encode("utf-8")
    assert len(record["markers"]) == 1


def test_the_table_names_each_markers_reading(x_image, capsys):
    path, _image = x_image
    assert main(["detect", str(path)]) == 0
    printed = capsys.readouterr().out
    assert "1 marker(s), 64x64" in printed and "reading=first pass" in printed


def test_detect_runs_on_one_blas_thread(x_image, capsys):
    """BLAS's threads would spin beside the detector's small products (marker_localizer.blas)."""
    path, _image = x_image
    threaded = two_threaded_openblas()
    assert main(["detect", str(path)]) == 0
    assert [openblas_threads()[library] for library in threaded] == [1] * len(threaded)


def test_colour_and_16_bit_files_are_converted(x_image, tmp_path, capsys):
    _, image = x_image
    colour = tmp_path / "colour.png"
    deep = tmp_path / "deep.png"
    cv2.imwrite(str(colour), cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
    cv2.imwrite(str(deep), image.astype(np.uint16) * 257)
    assert main(["detect", str(colour), str(deep), "--json"]) == 0
    records = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [len(r["markers"]) for r in records] == [1, 1]


def test_unreadable_files_give_one_line_naming_the_file_and_exit_3(x_image, tmp_path, capsys):
    path, _ = x_image
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"not an image")
    assert main(["detect", str(tmp_path / "missing.png"), str(junk), str(path), "--json"]) == 3
    captured = capsys.readouterr()
    errors = captured.err.strip().splitlines()
    assert errors == [
        f"marker-localizer: error: {tmp_path / 'missing.png'}: no such file",
        f"marker-localizer: error: {junk}: not a readable image",
    ]
    assert "Traceback" not in captured.err
    assert len(captured.out.strip().splitlines()) == 1  # the good image is still processed


def test_damaged_files_are_one_line_each_and_nothing_from_opencv_or_the_decoders(
    x_image, tmp_path, capfd
):
    """A damaged frame is refused, not detected on: libjpeg decodes this JPEG with grey blocks.

    libjpeg, libpng and OpenCV would each print a line of their own naming no file;
    what they say varies with the version, so only whose lines these are is checked.
    """
    path, _ = x_image
    grey = np.full((30, 40), 90, np.uint8)
    tiff = bytearray(cv2.imencode(".tiff", grey)[1].tobytes())
    (photometric,) = (at for at in tiff_entries(tiff) if tiff[at : at + 2] == b"\x06\x01")
    tiff[photometric + 8 : photometric + 10] = b"\xff\xff"  # no PhotometricInterpretation known
    png = bytearray(cv2.imencode(".png", grey)[1].tobytes())
    png[png.index(b"IDAT") + 8] ^= 0xFF  # its data no longer match their checksum
    progressive = noise_jpeg([cv2.IMWRITE_JPEG_PROGRESSIVE, 1])
    damaged = {
        "scan.jpg": cut_mid_scan_and_closed(noise_jpeg()),
        "progressive.jpg": progressive[: progressive.rindex(b"\xff\xda")] + b"\xff\xd9",
        "photometric.tiff": tiff,
        "idat.png": png,
        "header.webp": cv2.imencode(".webp", cv2.merge([grey] * 3))[1].tobytes()[:34],
    }
    for name, data in damaged.items():
        (tmp_path / name).write_bytes(data)
    assert main(["detect", *(str(tmp_path / name) for name in damaged), str(path), "--json"]) == 3
    captured = capfd.readouterr()
    errors = captured.err.splitlines()
    assert [line.split(": ")[:3] for line in errors] == [
        ["marker-localizer", "error", str(tmp_path / name)] for name in damaged
    ]
    assert errors[0].endswith(
        ": damaged JPEG (libjpeg: Corrupt JPEG data: premature end of data segment)"
    )
    assert ": truncated JPEG: " in errors[1]
    assert [json.loads(line)["image"] for line in captured.out.splitlines()] == [str(path)]


def test_marker_coordinates_are_in_the_files_stored_order_whatever_its_orientation_tag(
    tmp_path, capsys
):
    """An EXIF or TIFF Orientation tag (6: turn 90 degrees clockwise to view) is not applied.

    Coordinates are in the sensor's rows and columns, as a camera's calibration has them.
    """
    image = np.full((64, 96), 200.0, np.float32)
    image[:32, :32] = image[32:, 32:] = 30.0
    image = cv2.GaussianBlur(image, (0, 0), 1.0).round().astype(np.uint8)
    jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 98])[1].tobytes()
    tiff = cv2.imencode(".tiff", image)[1].tobytes()
    files = {
        "plain.jpg": jpeg,
        "turned.jpg": with_exif_orientation(jpeg, 6),
        "plain.tiff": tiff,
        "turned.tiff": with_tiff_orientation(tiff, 6),
    }
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    assert main(["detect", *(str(tmp_path / name) for name in files), "--json"]) == 0
    records = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [(r["width"], r["height"]) for r in records] == [(96, 64)] * 4
    plain_jpeg, turned_jpeg, plain_tiff, turned_tiff = (
        [m["x"], m["y"]] for r in records for m in r["markers"]
    )
    assert plain_jpeg == turned_jpeg and plain_tiff == turned_tiff
    assert plain_tiff == pytest.approx([31.5, 31.5], abs=0.05)


def test_images_of_one_row_one_column_and_2_x_2_pixels_give_no_marker_on_the_papers_path_too(
    tmp_path, capsys
):
    # Noisy ground across a shadow's edge: the paper's path finds candidates on the row.
    row = np.random.default_rng(0).normal(128.0, 40.0, (1, 300)).clip(0, 255).astype(np.uint8)
    row[:, :150] //= 4
    paths = [str(tmp_path / f"{name}.png") for name in ("row", "column", "cell")]
    for path, image in zip(paths, [row, row.T, row[:, 149:151].repeat(2, axis=0)], strict=True):
        cv2.imwrite(path, image)
    for params in ([], ["--param", "candidate_detector=curvature"]):
        assert main(["detect", *paths, "--json", *params]) == 0
        records = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
        assert [(r["width"], r["height"], r["markers"]) for r in records] == [
            (300, 1, []),
            (1, 300, []),
            (2, 2, []),
        ]


def test_no_image_giving_a_result_is_exit_1(tmp_path, capsys):
    assert main(["detect", str(tmp_path / "missing.png")]) == 1
    assert capsys.readouterr().out == ""


def test_a_12_bit_png_read_at_16_bits_is_processed_with_a_warning_naming_its_depth(
    x_image, tmp_path, capsys
):
    _, image = x_image
    deep = tmp_path / "deep.png"
    cv2.imwrite(str(deep), image.astype(np.uint16) * 16)  # 12-bit levels, right-aligned
    assert main(["detect", str(deep), "--json"]) == 0
    captured = capsys.readouterr()
    assert captured.err.strip().splitlines() == [
        f"marker-localizer: warning: {deep}: its brightest level, 3200, is under 1/16 of white "
        "(65535 at bit_depth 16); a 12-bit image wants --param bit_depth=12"
    ]
    assert main(["detect", str(deep), "--json", "--param", "bit_depth=12"]) == 0
    captured = capsys.readouterr()
    assert captured.err == ""
    assert len(json.loads(captured.out)["markers"]) == 1


def test_an_underexposed_image_is_processed_with_a_warning(x_image, tmp_path, capsys):
    _, image = x_image
    dim = tmp_path / "dim.png"
    cv2.imwrite(str(dim), image // 3)  # quadrants at 10 and 66 of 255
    assert main(["detect", str(dim), "--json"]) == 0
    captured = capsys.readouterr()
    assert captured.err.strip().splitlines() == [
        f"marker-localizer: warning: {dim}: frames underexposed: the brightest level is "
        "26 % of white, under 1/2, where markers are lost: raise the exposure or the gain"
    ]
    assert len(json.loads(captured.out)["markers"]) == 1


def test_a_float_tiff_of_8_bit_levels_is_one_line_not_a_blank_frame(x_image, tmp_path, capsys):
    _, image = x_image
    unit, levels = tmp_path / "unit.tiff", tmp_path / "levels.tiff"
    cv2.imwrite(str(unit), image.astype(np.float32) / 255.0)
    cv2.imwrite(str(levels), image.astype(np.float32))
    assert main(["detect", str(unit), str(levels), "--json"]) == 3
    captured = capsys.readouterr()
    assert captured.err.strip().splitlines() == [
        f"marker-localizer: error: {levels}: float image levels span 30 to 200, beyond [0, 1] "
        "(white 1): divide them by the camera's white level (255 for 8-bit levels, 4095 "
        "for 12-bit, 65535 for 16-bit)"
    ]
    (record,) = (json.loads(line) for line in captured.out.splitlines())
    assert record["image"] == str(unit) and len(record["markers"]) == 1


@pytest.mark.parametrize(
    ("scale", "warning"),
    [
        (
            1.0 / 255.0**2,  # 0-1 levels divided by 255 once more
            "its brightest level, 0.00307574, is under 1/255 of white (1 in a float image, "
            "whose levels are read in [0, 1]): scale them so that white is 1",
        ),
        (
            1.2 / 200.0,  # clipped within the overshoot core.image allows
            "its brightest level, 1.2, is over white (1 in a float image, whose levels are "
            "read in [0, 1]): the levels above it are clipped to it",
        ),
        (
            0.4 / 200.0,
            "frames underexposed: the brightest level is 40 % of white, under 1/2, where "
            "markers are lost: raise the exposure or the gain",
        ),
    ],
    ids=["scaled-twice", "over-white", "underexposed"],
)
def test_a_float_tiff_whose_levels_cannot_be_right_is_processed_with_a_warning(
    x_image, tmp_path, capsys, scale, warning
):
    _, image = x_image
    path = tmp_path / "float.tiff"
    cv2.imwrite(str(path), image.astype(np.float32) * np.float32(scale))
    assert main(["detect", str(path), "--json"]) == 0
    captured = capsys.readouterr()
    assert captured.err.strip().splitlines() == [f"marker-localizer: warning: {path}: {warning}"]
    assert json.loads(captured.out)["image"] == str(path)


def test_a_float_tiff_of_levels_in_0_1_is_read_without_a_word(x_image, tmp_path, capsys):
    _, image = x_image
    path = tmp_path / "unit.tiff"
    cv2.imwrite(str(path), image.astype(np.float32) / np.float32(255.0))
    assert main(["detect", str(path), "--json"]) == 0
    captured = capsys.readouterr()
    assert captured.err == ""
    assert len(json.loads(captured.out)["markers"]) == 1


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
@pytest.mark.parametrize("json_lines", [True, False], ids=["--json", "table"])
def test_an_output_that_cannot_be_written_is_one_line_and_status_1(
    x_image, monkeypatch, capsys, json_lines
):
    # /dev/full fails every write as a full disk does: `detect --json > results.jsonl`.
    path, _ = x_image
    with open("/dev/full", "w") as full:
        monkeypatch.setattr(sys, "stdout", full)
        assert main(["detect", str(path), *(["--json"] if json_lines else [])]) == 1
    assert capsys.readouterr().err == (
        "marker-localizer: error: cannot write the output (No space left on device)\n"
    )


def test_param_overrides_and_params_file_are_validated(x_image, tmp_path, capsys):
    path, _ = x_image
    assert main(["detect", str(path), "--param", "min_score=1.5"]) == 1
    assert "min_score=1.5 is outside" in capsys.readouterr().err
    params = tmp_path / "node.yaml"
    params.write_text(
        "marker_localizer:\n  ros__parameters:\n    detector:\n      marker_radius_min_px: 5.0\n"
    )
    assert (
        main(
            [
                "detect",
                str(path),
                "--params-file",
                str(params),
                "--param",
                "marker_radius_max_px=30",
            ]
        )
        == 0
    )


def test_overlay_writes_an_annotated_png(x_image, tmp_path):
    path, _ = x_image
    assert main(["detect", str(path), "--overlay", str(tmp_path / "out")]) == 0
    drawn = cv2.imread(str(tmp_path / "out" / "x_markers.png"))
    assert drawn.shape == (64, 64, 3)


def test_overlays_of_float_and_16_bit_colour_files_are_8_bit_with_their_levels(x_image, tmp_path):
    _, image = x_image
    files = {
        "float.tiff": image.astype(np.float32) / 255.0,
        "deep_colour.png": np.dstack([image.astype(np.uint16) * 257] * 3),
    }
    for name, pixels in files.items():
        cv2.imwrite(str(tmp_path / name), pixels)
    out = tmp_path / "out"
    assert main(["detect", *(str(tmp_path / n) for n in files), "--overlay", str(out)]) == 0
    for name in files:
        drawn = cv2.imread(str(out / f"{Path(name).stem}_markers.png"), cv2.IMREAD_UNCHANGED)
        assert drawn.dtype == np.uint8 and drawn.shape == (64, 64, 3)
        # Away from the lines drawn, the frame's own levels (they were black, or 16-bit).
        np.testing.assert_allclose(drawn[2, 2], [image[2, 2]] * 3, atol=1)


def test_overlays_of_images_with_the_same_name_do_not_overwrite_each_other(x_image, tmp_path):
    path, _ = x_image
    other = tmp_path / "b" / "x.png"  # no marker: its overlay is the image itself
    other.parent.mkdir()
    cv2.imwrite(str(other), np.full((64, 64), 80, np.uint8))
    out = tmp_path / "out"
    assert main(["detect", str(path), str(other), "--overlay", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["x_2_markers.png", "x_markers.png"]
    np.testing.assert_array_equal(cv2.imread(str(out / "x_2_markers.png")), 80)
    assert (cv2.imread(str(out / "x_markers.png")) != cv2.imread(str(path))).any()  # drawn


@pytest.mark.parametrize("make", ["file", "missing_parent_root"])
def test_an_overlay_folder_that_cannot_be_made_is_one_line(x_image, tmp_path, capsys, make):
    path, _ = x_image
    folder = tmp_path / "taken"
    if make == "file":
        folder.write_text("a file where the folder should go")
    else:
        folder = Path("/proc/no_folder_here")
    assert main(["detect", str(path), "--overlay", str(folder)]) == 1
    captured = capsys.readouterr()
    assert captured.err.startswith(f"marker-localizer: error: --overlay {folder}: cannot create")
    assert len(captured.err.strip().splitlines()) == 1 and "Traceback" not in captured.err


def test_why_says_a_marker_was_found_or_which_test_lost_it(x_image, capsys):
    path, _ = x_image
    args = ["detect", str(path), "--why", "31.5,31.5", "--why", "5,58", "--json"]
    assert main(args) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["why"] == [
        {"x": 31.5, "y": 31.5, "found": True, "lost_at": None},
        {"x": 5.0, "y": 58.0, "found": False, "lost_at": "screening"},
    ]
    assert main(["detect", str(path), "--why", "5,58"]) == 0
    assert "expected at (5, 58): lost at the screening test" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("params", "lost_at"),
    [
        (["template_ncc_min=0.9999"], "template"),
        (["candidate_detector=curvature", "refinement=ncc", "template_ncc_min=0.9999"], "template"),
    ],
    ids=["default", "paper's path"],
)
def test_why_names_the_test_that_lost_a_marker_on_every_path(x_image, capsys, params, lost_at):
    # The paper's and the template's paths listed no survivor after their first test:
    # a marker a later test rejected read "every test kept a candidate near it".
    path, _ = x_image
    args = ["detect", str(path), "--why", "31.5,31.5", "--json"]
    assert main([*args, *(arg for p in params for arg in ("--param", p))]) in (0, 1)
    (why,) = json.loads(capsys.readouterr().out)["why"]
    assert why == {"x": 31.5, "y": 31.5, "found": False, "lost_at": lost_at}


def test_the_template_decisions_path_lists_what_passed_each_of_its_tests(x_image):
    found = Detector(DetectorConfig(refinement="template")).detect(x_image[1])
    assert [test for test, _ in found.survivors] == ["screening", "prescreen", "lines", "decision"]
    assert len(found) == 1  # two candidates passed the decision, merged into one marker


def test_why_takes_a_point_off_the_top_left_edge_with_negative_coordinates(x_image, capsys):
    path, _ = x_image
    assert main(["detect", str(path), "--why", "-0.5,0", "--why", "-0.6,-5", "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["why"] == [
        {"x": -0.5, "y": 0.0, "found": False, "lost_at": "screening"},  # the first pixel's edge
        {"x": -0.6, "y": -5.0, "found": False, "lost_at": "outside the image"},
    ]
    assert main(["detect", str(path), "--why", "1e9,1e9"]) == 0
    assert "expected at (1e+09, 1e+09): outside the image" in capsys.readouterr().out


def test_why_with_a_malformed_point_is_a_usage_error(x_image, capsys):
    path, _ = x_image
    with pytest.raises(SystemExit) as exit_info:
        main(["detect", str(path), "--why", "1,2,3"])
    assert exit_info.value.code == 2
    assert "--why: expected X,Y in pixels, got '1,2,3'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["detect", str(path), "--why", "nan,3"])
    assert "--why: expected finite X,Y in pixels, got 'nan,3'" in capsys.readouterr().err


@pytest.mark.parametrize("pattern", ["rggb", "RGGB"])
def test_a_raw_bayer_file_is_demosaiced_with_bayer_and_a_colour_one_is_refused(
    pattern, x_image, tmp_path, capsys
):
    """``--bayer`` takes the pattern as ROS encodings write it, or as camera SDKs do."""
    _, image = x_image
    # An RGGB sensor's raw sites, before white balance.
    mosaic = image * bayer_gain(image.shape, "rggb").astype(np.float64)
    raw, colour = tmp_path / "raw.png", tmp_path / "colour.png"
    cv2.imwrite(str(raw), mosaic.round().astype(np.uint8))
    cv2.imwrite(str(colour), cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
    assert main(["detect", str(raw), str(colour), "--bayer", pattern, "--json"]) == 3
    captured = capsys.readouterr()
    (record,) = (json.loads(line) for line in captured.out.splitlines())
    assert record["image"] == str(raw)
    (marker,) = record["markers"]
    assert np.hypot(marker["x"] - 31.5, marker["y"] - 31.5) < 0.02
    assert f"{colour}: a Bayer mosaic is one channel of 8- or 16-bit pixels, not 64x64x3 uint8" in (
        captured.err
    )
