"""Exposure benchmark: what white clipped at the sensor costs this detector and its peers.

``marker-localizer bench exposure`` multiplies each frame's grey levels by a gain,
rounds them and clips them at 255: a camera exposed for darker ground, whose white
paint and bright ground saturate. At each gain it counts, for this detector's
default and every installed point-detector peer, each given the set's radius range:

* this package's rendered chessboards (e) and markers (a) (the frames of ``bench
  accuracy``'s tables, exact truth): recall and false points per frame;
* the independent renderer's frames (``independent/``, a validation split): the same;
* the real boards' reference corners (ValidationBoof, libcbdetect): recall (the
  corners are references, not a board's every corner: no false points);
* cirn_uas: the share of frames with each target found, false points per frame;
* aerial_negatives: false points per frame (every detection is one).

A detection matches a truth point within :data:`evaluation.DEFAULT_GATE_PX` (2 px).
The sets of ``../shared/data`` are skipped, with a line saying so, where absent.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from marker_localizer.bench import peers, real_data
from marker_localizer.bench.accuracy import (
    INDEPENDENT_FAMILIES,
    REAL_RADIUS_RANGES,
    LabelledFrame,
    Row,
    evaluate_boards,
    evaluate_frames,
    evaluate_negatives,
    evaluate_uas,
    families,
    reference_detectors,
)
from marker_localizer.bench.peers import PointDetector, RadiusRange
from marker_localizer.bench.runner import add_json_option, run_and_save
from marker_localizer.cli.arguments import positive_float

#: Gains of the default run: as exposed, and twice over (most white paint clips).
GAINS = (1.0, 2.0)
#: The rendered families read: chessboards, whose white squares clip whole, and markers.
RENDERED_FAMILIES = ("e", "a")
#: White of the 8-bit frames every set holds.
WHITE_DN = 255
#: The real board sets read (pycbd's three boards are left out: two are flared already).
BOARD_SETS = ("validationboof", "libcbdetect")

Report = Callable[[str], None]
#: Figures of one detector on one set at one gain, by name.
Figures = dict[str, float]


def over_exposed(image: np.ndarray, gain: float) -> np.ndarray:
    """``image``'s levels times ``gain``, rounded and clipped at white (8-bit).

    Args:
        image: (H, W) uint8 frame.
        gain: exposure relative to the frame's own, > 0.

    Raises:
        ValueError: the frame is not 8-bit, or the gain not positive.
    """
    if image.dtype != np.uint8:
        raise ValueError(f"over_exposed takes 8-bit frames, not {image.dtype}")
    if not gain > 0.0:
        raise ValueError(f"gain must be positive, not {gain!r}")
    levels = np.rint(image.astype(np.float64) * gain)
    exposed: np.ndarray = np.clip(levels, 0, WHITE_DN).astype(np.uint8)
    return exposed


@dataclasses.dataclass(frozen=True)
class Options:
    """What one run does (parsed from the command line, or built by tests).

    Attributes:
        gains: exposure gains, each > 0.
        quick: a frame or two per set.
        data_root: the shared data folder (None: the rendered frames alone).
    """

    gains: tuple[float, ...] = GAINS
    quick: bool = False
    data_root: Path | None = None


class ExposureSet(NamedTuple):
    """One set of frames the benchmark reads at every gain.

    Attributes:
        label: the table's name for it.
        rows_at: its rows (one per detector, in the detectors' order) at a gain.
        figures: what of a row the table shows.
    """

    label: str
    rows_at: Callable[[float], list[Row]]
    figures: Callable[[Row], Figures]


def _with_truth(row: Row) -> Figures:
    return {"recall": row.tally.recall, "fp_per_frame": row.tally.fp_per_frame}


def _board_corners(row: Row) -> Figures:
    return {"recall": row.tally.recall}


def _targets(row: Row) -> Figures:
    return {key: row.extra[key] for key in ("found_1", "found_2", "fp_per_frame")}


def _false_points(row: Row) -> Figures:
    return {"fp_per_frame": row.extra["fp_per_frame"]}


def _exposed_frames(frames: Sequence[Any], gain: float) -> list[Any]:
    """Copies of the (frozen dataclass) frames, each image :func:`over_exposed` by ``gain``."""
    return [dataclasses.replace(f, image=over_exposed(f.image, gain)) for f in frames]


def _truth_rows(
    frames: Sequence[LabelledFrame], detectors: Sequence[PointDetector], gain: float
) -> list[Row]:
    return evaluate_frames(_exposed_frames(frames, gain), 0, detectors).rows[: len(detectors)]


def _real_rows(
    evaluate: Callable[[list[Any], Sequence[PointDetector], RadiusRange], list[Row]],
    frames: Sequence[Any],
    radius_range: RadiusRange,
    detectors: Sequence[PointDetector],
    gain: float,
) -> list[Row]:
    return evaluate(_exposed_frames(frames, gain), detectors, radius_range)


def exposure_sets(
    options: Options, detectors: Sequence[PointDetector], report: Report
) -> list[ExposureSet]:
    """Every set this run reads; a line reported for each that is absent."""
    sets = []
    for family in (f for f in families() if f.key in RENDERED_FAMILIES and not f.variant):
        count = family.quick_frames if options.quick else family.frames
        frames = [
            LabelledFrame.rendered(family.render(i), family.radius_range) for i in range(count)
        ]
        rows_at = partial(_truth_rows, frames, detectors)
        sets.append(ExposureSet(f"rendered ({family.key}), {count} frames", rows_at, _with_truth))
    root = options.data_root
    if root is None:
        report(real_data.absent("The independent and real sets"))
        return sets
    limit = 1 if options.quick else None
    if real_data.has_independent(root):
        for key in INDEPENDENT_FAMILIES:
            frames = [
                LabelledFrame.independent(f)
                for f in real_data.iter_independent(root, limit, (key,))
            ]
            if not frames:
                continue
            rows_at = partial(_truth_rows, frames, detectors)
            label = f"independent ({key}), {len(frames)} frames"
            sets.append(ExposureSet(label, rows_at, _with_truth))
    else:
        report(real_data.absent(real_data.INDEPENDENT_SET, "independent"))
    for name in BOARD_SETS:
        images = (
            list(real_data.iter_validationboof(root, limit))
            if name == "validationboof"
            else list(real_data.iter_unlabelled_boards(root, name, limit))
        )
        if not images:
            report(real_data.absent(name, name))
            continue
        rows_at = partial(_real_rows, evaluate_boards, images, REAL_RADIUS_RANGES[name], detectors)
        label = f"{name}, {sum(len(i.reference) for i in images)} corners"
        sets.append(ExposureSet(label, rows_at, _board_corners))
    for name, evaluate, read, figures in (
        ("cirn_uas", evaluate_uas, real_data.iter_cirn_uas, _targets),
        ("aerial_negatives", evaluate_negatives, real_data.iter_aerial_negatives, _false_points),
    ):
        uas = list(read(root, limit))
        if not uas:
            report(real_data.absent(name, name))
            continue
        rows_at = partial(_real_rows, evaluate, uas, REAL_RADIUS_RANGES[name], detectors)
        sets.append(ExposureSet(f"{name}, {len(uas)} frames", rows_at, figures))
    return sets


def _cell(figures: Figures) -> str:
    """A table cell: recall (false points a frame), targets found, or false points."""
    if "found_1" in figures:
        return (
            f"{figures['found_1']:.0%} / {figures['found_2']:.0%} ({figures['fp_per_frame']:.1f})"
        )
    if "recall" in figures:
        false = f" ({figures['fp_per_frame']:.2f})" if "fp_per_frame" in figures else ""
        return f"{figures['recall']:.1%}{false}"
    return f"({figures['fp_per_frame']:.2f})"


#: Widths of the table's columns: the set, the detector, each gain.
_SET_WIDTH, _DETECTOR_WIDTH, _GAIN_WIDTH = 34, 32, 22


def exposure_table(
    gains: Sequence[float], results: dict[str, dict[str, dict[float, Figures]]]
) -> str:
    """The table: a row per set and detector, a column per gain."""
    header = f"{'set':<{_SET_WIDTH}}{'detector':<{_DETECTOR_WIDTH}}" + "".join(
        f"{f'gain {g:g}':>{_GAIN_WIDTH}}" for g in gains
    )
    lines = [
        "Exposure: each frame's levels times a gain, rounded and clipped at 255; every "
        "detector given the set's radius range; a match within 2 px",
        "recall (false points per frame); real boards: recall of the reference corners; "
        "cirn_uas: frames with target 1 / target 2 (false points per frame); "
        "aerial_negatives: (false points per frame)",
        "",
        header,
        "-" * len(header),
    ]
    for label, by_detector in results.items():
        for k, (name, by_gain) in enumerate(by_detector.items()):
            cells = "".join(f"{_cell(by_gain[g]):>{_GAIN_WIDTH}}" for g in gains)
            lines.append(f"{label if k == 0 else '':<{_SET_WIDTH}}{name:<{_DETECTOR_WIDTH}}{cells}")
    return "\n".join(lines)


def run(options: Options, report: Report) -> dict[str, Any]:
    """Read every set at every gain; report the table; return the figures."""
    detectors = [*reference_detectors(), *peers.point_detectors()]
    results: dict[str, dict[str, dict[float, Figures]]] = {}
    for exposure_set in exposure_sets(options, detectors, report):
        by_detector: dict[str, dict[float, Figures]] = {}
        for gain in options.gains:
            for row in exposure_set.rows_at(gain):
                by_detector.setdefault(row.name, {})[gain] = exposure_set.figures(row)
        results[exposure_set.label] = by_detector
    report(exposure_table(options.gains, results))
    return {
        label: {name: {f"{g:g}": f for g, f in by_gain.items()} for name, by_gain in rows.items()}
        for label, rows in results.items()
    }


def _gains(text: str) -> tuple[float, ...]:
    """An argparse ``type``: comma-separated gains, each a finite number above 0."""
    return tuple(positive_float(g.strip()) for g in text.split(","))


def parse_args(argv: list[str] | None) -> tuple[Options, Path | None]:
    """The options of a run, and where to save its figures."""
    parser = argparse.ArgumentParser(
        allow_abbrev=False,
        prog="marker-localizer bench exposure",
        description="Recall and false points of this detector and its peers on over-exposed "
        "frames: each frame's levels times a gain, clipped at white.",
    )
    parser.add_argument(
        "--gains",
        type=_gains,
        default=GAINS,
        help="comma-separated exposure gains, each above 0 (default: 1,2)",
    )
    parser.add_argument("--quick", action="store_true", help="a frame or two per set")
    add_json_option(parser)
    args = parser.parse_args(argv)
    return Options(args.gains, args.quick, real_data.data_root()), args.json


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    options, json_path = parse_args(argv)
    return run_and_save("exposure benchmark", lambda report: run(options, report), json_path)


if __name__ == "__main__":
    raise SystemExit(main())
