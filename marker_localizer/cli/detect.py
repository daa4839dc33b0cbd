"""``marker-localizer detect``: markers in image files, as a table or JSON lines."""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from marker_localizer import config as config_module
from marker_localizer import evaluation
from marker_localizer.blas import single_thread_blas
from marker_localizer.cli.exits import EXIT_ERROR, EXIT_INCOMPLETE, PROG
from marker_localizer.core import symmetry_path
from marker_localizer.core.image import (
    BAYER_PATTERNS,
    SHALLOW_PEAK_TEXT,
    bayer_to_grey,
    bit_depth_hint,
    bit_depth_scale,
    peak_level,
    underexposed,
    underexposure_warning,
)
from marker_localizer.core.pipeline import Detector
from marker_localizer.core.result import DetectionResult, positions
from marker_localizer.errors import ConfigError, ImageError
from marker_localizer.image_files import read_image_file

#: A float image's brightest level under one 8-bit step of its white (1): no exposure
#: leaves every level there, so its levels were scaled for another white (0-1 levels
#: divided by 255 once more), and the detector reads a black frame.
_FLOAT_MIN_PEAK = 1.0 / 255.0
#: :data:`_FLOAT_MIN_PEAK` as the warning writes it.
_FLOAT_MIN_PEAK_TEXT = f"1/{round(1.0 / _FLOAT_MIN_PEAK)}"
#: White in a float image (core.image.to_gray), as the warnings name it.
_FLOAT_WHITE_TEXT = "1 in a float image, whose levels are read in [0, 1]"


def result_record(
    path: str, image: np.ndarray, result: DetectionResult, elapsed_ms: float
) -> dict[str, Any]:
    r"""The JSON-lines record of one image, the CLI's contract (README, "From the command line").

    ``image`` is the path as given, its bytes that are not UTF-8 written as ``\xNN``
    (:func:`printable_path`): JSON holds Unicode text, and the lone surrogates
    Python reads such bytes into are not text another reader can decode.
    Each marker's ``reading`` names the reading that added it (the first pass or a
    second reading, :data:`symmetry_path.READINGS`; :data:`evaluation.UNLISTED` on a
    path that closes none of them): where a point you did not expect came from.
    """
    added = evaluation.readings_that_added(
        result.survivors, positions(result), symmetry_path.READINGS
    )
    return {
        "image": printable_path(path),
        "width": int(image.shape[1]),
        "height": int(image.shape[0]),
        "elapsed_ms": round(elapsed_ms, 3),
        "markers": [
            {
                "x": d.x,
                "y": d.y,
                "score": d.score,
                "sigma": d.sigma,
                "angles": [d.angle1, d.angle2],
                "reading": reading,
            }
            for d, reading in zip(result, added, strict=True)
        ],
    }


def printable_path(path: str) -> str:
    r"""``path`` as Unicode text: the bytes of a file name that are not UTF-8 as ``\xNN``."""
    return path.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


#: ``lost_at`` of a point that lies outside the image: no test saw it.
OUTSIDE_THE_IMAGE = "outside the image"


def why_record(
    result: DetectionResult, points: np.ndarray, shape: tuple[int, ...]
) -> list[dict[str, Any]]:
    """For each point where a marker is expected: found, or the test that lost it.

    A point is found where a detection lies within the benchmark's matching gate
    (:data:`evaluation.DEFAULT_GATE_PX`); otherwise ``lost_at`` names the first test
    after which no candidate was left near it (:func:`evaluation.tests_that_lost`),
    or :data:`OUTSIDE_THE_IMAGE` for a point beyond the pixels of an image of
    ``shape`` (H, W, ...).
    """
    distance = evaluation.nearest_distances(points, positions(result))
    found = distance <= evaluation.DEFAULT_GATE_PX
    lost_at: list[str | None] = [None] * len(points)
    missed = np.flatnonzero(~found)
    tests = evaluation.tests_that_lost(result.survivors, points[missed])
    for k, test in zip(missed, tests, strict=True):
        lost_at[k] = test
    height, width = shape[:2]
    centre, half = np.array([width - 1, height - 1]) / 2.0, np.array([width, height]) / 2.0
    for k in missed[(np.abs(points[missed] - centre) > half).any(axis=1)]:
        lost_at[k] = OUTSIDE_THE_IMAGE
    return [
        {"x": float(x), "y": float(y), "found": bool(hit), "lost_at": test}
        for (x, y), hit, test in zip(points, found, lost_at, strict=True)
    ]


def _point(text: str) -> tuple[float, float]:
    """``X,Y`` in pixels, for ``--why``."""
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y in pixels, got {text!r}") from None
    if not (np.isfinite(x) and np.isfinite(y)):
        raise argparse.ArgumentTypeError(f"expected finite X,Y in pixels, got {text!r}")
    return x, y


def _why_values_joined(argv: Sequence[str]) -> list[str]:
    """``--why X,Y`` as ``--why=X,Y``: argparse takes a value starting with ``-`` for an option.

    A point in the first half pixel of a row or column, or beyond the top or left
    edge, has a negative coordinate (0 is the centre of the first pixel).
    """
    joined: list[str] = []
    values = iter(argv)
    for arg in values:
        value = next(values, None) if arg == "--why" else None
        joined.append(arg if value is None else f"--why={value}")
    return joined


def _write_table(record: dict[str, Any]) -> None:
    print(
        f"{record['image']}: {len(record['markers'])} marker(s), "
        f"{record['width']}x{record['height']}, {record['elapsed_ms']:.1f} ms"
    )
    for m in record["markers"]:
        print(
            f"  x={m['x']:10.4f}  y={m['y']:10.4f}  sigma={m['sigma']:.4f} px  "
            f"score={m['score']:.3f}  reading={m['reading']}"
        )
    for w in record.get("why", []):
        if w["found"]:
            verdict = "found"
        elif w["lost_at"] == evaluation.ASTRAY:
            verdict = (
                "every test kept a candidate near it, but the detection is over "
                f"{evaluation.DEFAULT_GATE_PX:g} px away"
            )
        elif w["lost_at"] == OUTSIDE_THE_IMAGE:
            verdict = OUTSIDE_THE_IMAGE
        else:
            verdict = f"lost at the {w['lost_at']} test"
        print(f"  expected at ({w['x']:g}, {w['y']:g}): {verdict}")


def build_parser() -> argparse.ArgumentParser:
    """Arguments of ``marker-localizer detect``."""
    parser = argparse.ArgumentParser(
        allow_abbrev=False, prog=f"{PROG} detect", description="Detect markers in image files."
    )
    parser.add_argument("images", nargs="+", metavar="IMAGE")
    parser.add_argument("--json", action="store_true", help="one JSON object per image per line")
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a detector parameter (repeatable), e.g. marker_radius_min_px=4",
    )
    parser.add_argument(
        "--params-file",
        metavar="YAML",
        help="the node's parameter file (its detector: section is used)",
    )
    parser.add_argument(
        "--overlay",
        metavar="DIR",
        help="write annotated PNGs into DIR as <name>_markers.png (a name already used in "
        "this run gets _2, _3, ... in command-line order)",
    )
    parser.add_argument(
        "--bayer",
        type=str.lower,
        choices=BAYER_PATTERNS,
        metavar="PATTERN",
        help="the files hold a camera's raw Bayer mosaic of this pattern (8 or 16 bits): "
        f"demosaiced to grey as cv_bridge does; one of {', '.join(BAYER_PATTERNS)}, "
        "in either case",
    )
    parser.add_argument(
        "--why",
        action="append",
        default=[],
        type=_point,
        metavar="X,Y",
        help="a marker expected at X,Y (px): found, or the first test after which no "
        f"candidate was left within {evaluation.LOSS_RADIUS_PX:g} px of it (repeatable; "
        "every test on the default path, the screening and prescreen on the others)",
    )
    return parser


def main(argv: Sequence[str]) -> int:
    """``detect``: one result per image; unreadable images are reported and skipped.

    Returns:
        0; :data:`EXIT_INCOMPLETE` when an image could not be read or its overlay
        written, but others gave results; :data:`EXIT_ERROR` when none did.
    """
    args = build_parser().parse_args(_why_values_joined(argv))
    detector = Detector(config_module.detector_config(args.params_file, args.param))
    # BLAS's threads spin beside the detector's small products: as fast on one, at half
    # the processor time, and detect commands run side by side do not compete.
    single_thread_blas()
    overlays = _overlay_paths(args.images, args.overlay) if args.overlay else {}
    failed = printed = 0
    for path in args.images:
        try:
            image = read_image_file(path, detector.config.max_pixels)
            if args.bayer:
                image = _bayer_to_grey(image, args.bayer, path)
            start = time.perf_counter()
            result = _detect_file(detector, image, path)
            elapsed_ms = (time.perf_counter() - start) * 1000.0
        except ImageError as err:
            failed += 1
            print(f"{PROG}: error: {err}", file=sys.stderr)
            continue
        _warn_of_levels(path, image, detector.config.bit_depth)
        record = result_record(path, image, result, elapsed_ms)
        if args.why:
            record["why"] = why_record(result, np.array(args.why, dtype=np.float64), image.shape)
        if args.json:
            print(json.dumps(record), flush=True)
        else:
            _write_table(record)
        printed += 1
        if path in overlays and not _write_overlay(overlays[path], image, result, detector):
            failed += 1
            print(f"{PROG}: error: {overlays[path]}: cannot write the overlay", file=sys.stderr)
    if not failed:
        return 0
    return EXIT_INCOMPLETE if printed else EXIT_ERROR


def _warn_of_levels(path: str, image: np.ndarray, bit_depth: int) -> None:
    """One line on stderr where a file's levels look shallower, scaled otherwise, or dim.

    A 16-bit file under 1/16 of white is named with the depth its levels fit
    (:func:`~marker_localizer.core.image.bit_depth_hint`); a float file, white at 1,
    whose brightest level is under :data:`_FLOAT_MIN_PEAK` or over 1 (clipped to it)
    is named as scaled for another white; otherwise one under
    :data:`~marker_localizer.core.image.DIM_PEAK_SHARE` of white is underexposed
    (:func:`~marker_localizer.core.image.underexposed`). Levels as
    :func:`~marker_localizer.core.image.peak_level` reads them.
    """
    peak = peak_level(image)
    if image.dtype.kind == "f":
        _warn_of_float_levels(path, peak)
        return
    white = bit_depth_scale(image.dtype, bit_depth)
    hint = bit_depth_hint(peak, bit_depth) if image.dtype == np.uint16 else None
    if hint is not None:
        print(
            f"{PROG}: warning: {path}: its brightest level, {peak:g}, is under "
            f"{SHALLOW_PEAK_TEXT} of white "
            f"({white:g} at bit_depth {bit_depth}); a {hint}-bit image wants "
            f"--param bit_depth={hint}",
            file=sys.stderr,
        )
    elif underexposed(peak / white):
        print(f"{PROG}: warning: {path}: {underexposure_warning(peak / white)}", file=sys.stderr)


def _warn_of_float_levels(path: str, peak: float) -> None:
    """:func:`_warn_of_levels` for a float file whose brightest level is ``peak`` (white 1)."""
    if peak < _FLOAT_MIN_PEAK:
        problem = f"under {_FLOAT_MIN_PEAK_TEXT} of white ({_FLOAT_WHITE_TEXT})"
        advice = "scale them so that white is 1"
    elif peak > 1.0:
        problem = f"over white ({_FLOAT_WHITE_TEXT})"
        advice = "the levels above it are clipped to it"
    elif underexposed(peak):
        print(f"{PROG}: warning: {path}: {underexposure_warning(peak)}", file=sys.stderr)
        return
    else:
        return
    print(
        f"{PROG}: warning: {path}: its brightest level, {peak:g}, is {problem}: {advice}",
        file=sys.stderr,
    )


def _overlay_paths(images: Sequence[str], folder: str) -> dict[str, Path]:
    """Each image's overlay file in ``folder``, created here; same-named images get _2, _3...

    Raises:
        ConfigError: ``folder`` cannot be created (a file of that name, no permission).
    """
    try:
        Path(folder).mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ConfigError(f"--overlay {folder}: cannot create the folder ({err.strerror})") from err
    paths: dict[str, Path] = {}
    taken: set[str] = set()
    for image in dict.fromkeys(images):
        stem, n = Path(image).stem, 1
        name = f"{stem}_markers.png"
        while name in taken:
            n += 1
            name = f"{stem}_{n}_markers.png"
        taken.add(name)
        paths[image] = Path(folder) / name
    return paths


def _write_overlay(
    out: Path, image: np.ndarray, result: DetectionResult, detector: Detector
) -> bool:
    from marker_localizer.overlay import draw_detections  # noqa: PLC0415 - only on request

    drawn = draw_detections(image, result.detections, bit_depth=detector.config.bit_depth)
    try:
        return bool(cv2.imwrite(str(out), drawn))
    except cv2.error:
        return False


def _bayer_to_grey(image: np.ndarray, pattern: str, path: str) -> np.ndarray:
    """A decoded file's Bayer mosaic as grey; a file that holds none names itself."""
    try:
        return bayer_to_grey(image, pattern)
    except ImageError as err:
        raise ImageError(f"{path}: {err}") from err


def _detect_file(detector: Detector, image: np.ndarray, path: str) -> DetectionResult:
    """Detect in one decoded file; its errors, OpenCV's included, name the file."""
    try:
        return detector.detect(image)
    except ImageError as err:
        raise ImageError(f"{path}: {err}") from err
    except cv2.error as err:
        raise ImageError(f"{path}: OpenCV failed on it ({err.err})") from err
