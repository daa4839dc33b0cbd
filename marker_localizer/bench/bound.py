"""What the Cramer-Rao bound asks of a fit: the bound with the marker's other parameters unknown.

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

The frames are those of seeds ``first_seed`` on, which no table of
``bench accuracy`` renders (its seeds are ``seed * 1000 + i``).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from marker_localizer import Detector, DetectorConfig
from marker_localizer.bench.accuracy import families
from marker_localizer.bench.runner import Report, run_and_save
from marker_localizer.evaluation import match_points
from marker_localizer.synthetic import render_scene
from marker_localizer.synthetic.crlb import BoundParts

#: Share of a marker's radius whose pixels the inner bounds read (see the module).
INNER_SHARE = 0.8
#: First seed rendered, and frames per family: the development frames of the
#: measurements in docs/accuracy.md.
FIRST_SEED = 100
FRAMES = 12
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
    """One family's markers found: the detector's errors and their bounds.

    Attributes:
        key: the family's key (``bench accuracy --families``).
        markers: how many markers the frames hold.
        errors_px: (N,) the detector's error on each marker it found, px.
        parts: (N, 5) the bounds of those markers, columns in :class:`BoundParts`' order, px.
    """

    key: str
    markers: int
    errors_px: np.ndarray
    parts: np.ndarray

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
        return "\n".join(lines)

    def figures(self) -> dict[str, Any]:
        """The JSON figures: counts, the mean error, and each bound's row (:meth:`row`)."""
        rows = {field: self.row(k) for k, field in enumerate(BoundParts._fields)}
        return {
            "markers": self.markers,
            "found": len(self.errors_px),
            "mean_error_px": float(self.errors_px.mean()) if len(self.errors_px) else None,
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
    errors: list[np.ndarray] = []
    parts: list[np.ndarray] = []
    markers = 0
    for seed in seeds:
        scene = render_scene(family.scene, seed, bound_parts_within=INNER_SHARE)
        found = detector.detect(scene.image).as_array()[:, :2]
        matching = match_points(found, scene.centres)
        markers += len(scene.markers)
        errors.append(matching.errors_px)
        parts.append(
            np.array([scene.markers[i].bound_parts for i in matching.truth_index]).reshape(
                -1, len(BoundParts._fields)
            )
        )
    return FamilyBounds(key, markers, np.concatenate(errors), np.concatenate(parts))


def run(keys: Sequence[str], seeds: Sequence[int], report: Report) -> dict[str, Any]:
    """Print and return each family's bounds over ``seeds``."""
    report(
        f"seeds {seeds[0]}-{seeds[-1]}; the bounds' means over the markers found, the "
        "detector's mean error over each"
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
        prog="marker-localizer bench bound",
        description="The centre's bound with the marker's other parameters unknown, "
        "and the default's error over each.",
    )
    parser.add_argument(
        "--families",
        default="a,c,d",
        help=f"comma-separated rendered families, of {','.join(keys)} (default: a,c,d)",
    )
    parser.add_argument("--first-seed", type=int, default=FIRST_SEED, help="first seed rendered")
    parser.add_argument("--frames", type=int, default=FRAMES, help="frames per family")
    parser.add_argument("--json", type=Path, default=None, help="also save the figures here")
    args = parser.parse_args(argv)
    chosen = [k.strip() for k in args.families.split(",") if k.strip()]
    unknown = sorted(set(chosen) - set(keys))
    if unknown or not chosen:
        parser.error(f"--families: unknown {', '.join(unknown) or '(none given)'}; of {keys}")
    if args.frames < 1:
        parser.error("--frames must be at least 1")
    seeds = range(args.first_seed, args.first_seed + args.frames)
    run_report: Callable[[Report], dict[str, Any]] = lambda report: run(  # noqa: E731
        chosen, list(seeds), report
    )
    return run_and_save("bound", run_report, args.json)
