"""What the pixels allow: the centre's bound with the rest unknown, and the X's SNR.

``marker-localizer bench bound`` renders a rendered family's frames with each
marker's :class:`~marker_localizer.synthetic.crlb.BoundParts`, runs the default
detector on them and prints, per family, the mean of each bound over the markers
found, and the detector's mean error over each:

* the Cramer-Rao bound ``bench accuracy`` divides by: the centre alone unknown,
  every pixel of the X read;
* every parameter of the marker's image a fit must estimate beside the centre
  unknown (:data:`~marker_localizer.synthetic.crlb.BOUND_PARAMETERS`: the plane's
  homography, the paints and a dull quadrant's factor, the blur, the light's
  slope, a cast shadow's edge), without and with the perspective;
* the same from the pixels within :data:`INNER_SHARE` of the radius alone: about
  what the line fit reads (:func:`~marker_localizer.core.subpixel.refine_along_lines`
  reads 0.9 of the ring check's extent, a rung at or under the radius).

A fit's efficiency is its error over the bound of what it estimates from the
pixels it reads.

It also prints how many of the family's markers the detector finds, by their X's
signal-to-noise ratio (:func:`~marker_localizer.synthetic.crlb.x_snr`, in the bands
of :data:`~marker_localizer.synthetic.crlb.X_SNR_BANDS`): the evidence a matched
filter that knew everything but whether the X is there would have. A marker the
detector misses at a high ratio is lost to its tests or to the ground's texture,
not to the noise.

The frames are those of seeds ``first_seed`` on, which no table of
``bench accuracy`` renders (its seeds are ``seed * 1000 + i``).
"""

from __future__ import annotations

import argparse
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from marker_localizer import Detector, DetectorConfig
from marker_localizer.bench.accuracy import bin_labels, families, x_snr_band
from marker_localizer.bench.runner import Report, add_json_option, run_and_save
from marker_localizer.cli.arguments import comma_keys, count_type, seed_type
from marker_localizer.core.result import positions
from marker_localizer.evaluation import match_points
from marker_localizer.synthetic import render_scene
from marker_localizer.synthetic.crlb import X_SNR_BANDS, BoundParts

#: Share of a marker's radius whose pixels the inner bounds read (see the module).
INNER_SHARE = 0.8
#: First seed rendered, and frames per family: the development frames of the
#: measurements in docs/accuracy-journal.md.
FIRST_SEED = 100
FRAMES = 12
#: The heading of those bands' rows.
SNR_HEADING = "the X's signal-to-noise ratio"
#: The rows of the table: each bound's label, by its field of :class:`BoundParts`.
BOUND_LABELS = {
    "known": "Cramer-Rao bound: the centre alone unknown, the whole X",
    "affine": "all unknown but the perspective, the whole X",
    "projective": "all unknown, the whole X",
    "inner_affine": f"all unknown but the perspective, within {INNER_SHARE:g} of the radius",
    "inner_projective": f"all unknown, within {INNER_SHARE:g} of the radius",
}


@dataclass(frozen=True)
class FamilyBounds:
    """One family's markers: which the detector found, its errors and their bounds.

    Attributes:
        key: the family's key (``bench accuracy --families``).
        x_snr: (M,) the X's signal-to-noise ratio of every marker the frames hold.
        found: (M,) True for the markers the detector found.
        errors_px: (N,) the detector's error on each marker it found, px.
        parts: (N, 5) the bounds of those markers, columns in :class:`BoundParts`' order, px.
    """

    key: str
    x_snr: np.ndarray
    found: np.ndarray
    errors_px: np.ndarray
    parts: np.ndarray

    @property
    def markers(self) -> int:
        """How many markers the frames hold."""
        return len(self.x_snr)

    def by_snr(self) -> list[tuple[float, float, int, int]]:
        """Per band of ``X_SNR_BANDS`` (from, to), the markers in it and those found."""
        edges = (0.0, *X_SNR_BANDS, math.inf)
        band = x_snr_band(self.x_snr)
        return [
            (low, high, int((band == k).sum()), int((self.found & (band == k)).sum()))
            for k, (low, high) in enumerate(itertools.pairwise(edges))
        ]

    def row(self, column: int) -> tuple[float, float, int]:
        """A bound's mean (px) and the mean error over it, over the markers it bounds.

        A marker whose centre the bound leaves unidentifiable (a tiny X read within
        a share of its radius: a pixel or two) has an infinite bound; it is left
        out of both means and counted (the third value).
        """
        bounded = np.isfinite(self.parts[:, column])
        if not bounded.any():
            return math.nan, math.nan, int((~bounded).sum())
        mean = float(self.parts[bounded, column].mean())
        return mean, float(self.errors_px[bounded].mean()) / mean, int((~bounded).sum())

    def table(self) -> str:
        """The family's rows: each bound's mean, over the CRB, and the error over it."""
        found = len(self.errors_px)
        lines = [
            f"({self.key}): {found} of {self.markers} markers found, mean error "
            f"{self.errors_px.mean() if found else math.nan:.4f} px",
            f"  {'bound':72s} {'mean px':>8s} {'/ CRB':>6s} {'error / bound':>14s}",
        ]
        crb = self.row(0)[0]
        for column, label in enumerate(BOUND_LABELS.values()):
            mean, efficiency, unbounded = self.row(column)
            note = f"  ({unbounded} unbounded, left out)" if unbounded else ""
            lines.append(f"  {label:72s} {mean:8.4f} {mean / crb:6.2f} {efficiency:14.2f}{note}")
        lines.append(f"  {SNR_HEADING:32s} {'markers':>8s} {'found':>14s}")
        labels = bin_labels(X_SNR_BANDS)
        for label, (_, _, in_band, found_in_band) in zip(labels, self.by_snr(), strict=True):
            share = f"{found_in_band} ({found_in_band / in_band:.0%})" if in_band else "-"
            lines.append(f"  {label:32s} {in_band:8d} {share:>14s}")
        return "\n".join(lines)

    def figures(self) -> dict[str, Any]:
        """The JSON figures: counts, the mean error, each bound's row (:meth:`row`), the bands."""
        rows = {field: self.row(k) for k, field in enumerate(BoundParts._fields)}
        return {
            "markers": self.markers,
            "found": len(self.errors_px),
            "mean_error_px": float(self.errors_px.mean()) if len(self.errors_px) else None,
            "by_x_snr": [
                {"from": low, "to": high if math.isfinite(high) else None, "markers": m, "found": f}
                for low, high, m, f in self.by_snr()
            ],
            "bounds": {
                field: {"mean_px": mean, "error_over_bound": ratio, "unbounded": unbounded}
                for field, (mean, ratio, unbounded) in rows.items()
            },
        }


def family_bounds(key: str, seeds: Sequence[int]) -> FamilyBounds:
    """Render family ``key``'s frames of ``seeds`` with their bounds and detect on them."""
    family = next(f for f in families() if f.key == key and f.scene is not None)
    assert family.scene is not None
    detector = Detector(
        DetectorConfig(
            marker_radius_min_px=family.radius_range[0],
            marker_radius_max_px=family.radius_range[1],
        )
    )
    snr: list[np.ndarray] = []
    found: list[np.ndarray] = []
    errors: list[np.ndarray] = []
    parts: list[np.ndarray] = []
    for seed in seeds:
        scene = render_scene(family.scene, seed, bound_parts_within=INNER_SHARE)
        detections = positions(detector.detect(scene.image))
        matching = match_points(detections, scene.centres)
        snr.append(np.array([m.x_snr for m in scene.markers], dtype=np.float64))
        found.append(np.isin(np.arange(len(scene.markers)), matching.truth_index))
        errors.append(matching.errors_px)
        parts.append(
            np.array([scene.markers[i].bound_parts for i in matching.truth_index]).reshape(
                -1, len(BoundParts._fields)
            )
        )
    return FamilyBounds(
        key,
        np.concatenate(snr),
        np.concatenate(found),
        np.concatenate(errors),
        np.concatenate(parts),
    )


def run(keys: Sequence[str], seeds: Sequence[int], report: Report) -> dict[str, Any]:
    """Print and return each family's bounds over ``seeds``."""
    report(
        f"seeds {seeds[0]}-{seeds[-1]}; the bounds' means over the markers found, the "
        "detector's mean error over each; the markers found by their X's signal-to-noise ratio"
    )
    figures = {}
    for key in keys:
        bounds = family_bounds(key, seeds)
        report(bounds.table())
        figures[key] = bounds.figures()
    return {"seeds": list(seeds), "inner_share": INNER_SHARE, "families": figures}


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    keys = sorted({f.key for f in families() if f.scene is not None})
    parser = argparse.ArgumentParser(
        allow_abbrev=False,
        prog="marker-localizer bench bound",
        description="The centre's bound with the marker's other parameters unknown, "
        "and the default's error over each; the markers it finds by their X's "
        "signal-to-noise ratio.",
    )
    parser.add_argument(
        "--families",
        type=comma_keys(keys, "families"),
        default="a,c,d",
        help=f"comma-separated rendered families, of {','.join(keys)} (default: a,c,d)",
    )
    parser.add_argument(
        "--first-seed",
        type=seed_type,
        default=FIRST_SEED,
        help="first seed rendered (default: %(default)s)",
    )
    parser.add_argument(
        "--frames", type=count_type, default=FRAMES, help="frames per family (default: %(default)s)"
    )
    add_json_option(parser)
    args = parser.parse_args(argv)
    seeds = range(args.first_seed, args.first_seed + args.frames)
    run_report: Callable[[Report], dict[str, Any]] = lambda report: run(  # noqa: E731
        args.families, list(seeds), report
    )
    return run_and_save("bound", run_report, args.json)
