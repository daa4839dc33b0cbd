"""Accuracy benchmark: this detector and its peers on rendered families and real images.

``marker-localizer bench accuracy`` (or ``python -m marker_localizer.bench.accuracy``)
prints one table per scenario family of the renderer, then tables for the sets
in ``<repo>/../shared/data`` (skipped when absent):

* rendered families (exact truth): recall, false positives per frame, error
  mean / RMS / p95 / max / share within 0.1 px, share within 2 reported sigma,
  the mean Cramer-Rao bound of the markers each detector found and its mean
  error over that bound ("err/CRLB"; 1 is efficient for an estimator that reads
  the X's pixels alone, and one that reads the whole window can go under it), and
  each peer's mean error over ours ("peer/ours", ours = the default
  ``refinement="symmetry"`` variant). Every detector gets the family's true radius range;
  ``cv2.cornerSubPix`` starts from the truth moved by a random offset of up to
  1 px (seeded) and measures refinement only. The bound is the renderer's own
  (:mod:`marker_localizer.synthetic.crlb`).
* the independent renderer's frames (``independent/``, exact truth and bound
  in its ``truth.json``): the same table per family, every detector given each
  frame's ``radius_range_px``. A validation split: nothing is tuned on it.
* real chessboards: recall of the reference corners, boards with every corner
  found, the paper's Table 1 deviation from OpenCV's refined corners, and the
  reference-free row/column residuals (straight line and projective spacing).
* cirn_uas: both ground targets found per frame, false positives per frame.
* rendered markers on real ground: family (a)'s markers and look-alikes, and
  family (b)'s tiny ones (radius 2.5-5 px, the paper's markers 3-5 px wide over
  real terrain), drawn on crops of the real frames without a diagonal marker
  (:func:`real_ground_family`), scored as rendered families: recall on ground no
  renderer made.
* aerial_negatives: real ground without any marker; false points per frame and
  per megapixel; and the same frames seen from half the height
  (:func:`closer_frames`), for the reference row. Beside them, a rendered lattice
  of bright discs (the ``coins`` photograph at a quarter to half its size, shaded
  or flat), the ground whose saddles pass for X's.

A detection matches a truth point within :data:`evaluation.DEFAULT_GATE_PX` (2 px).
"""

from __future__ import annotations

import argparse
import functools
import itertools
import math
import time
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, NamedTuple

import cv2
import numpy as np

from marker_localizer import evaluation
from marker_localizer.bench import dull, metrics, peers, real_data
from marker_localizer.bench.peers import OurDetector, PointDetector, RadiusRange, range_text
from marker_localizer.bench.runner import add_json_option, run_and_save
from marker_localizer.cli.arguments import comma_keys, count_type, seed_type
from marker_localizer.core import symmetry_path
from marker_localizer.errors import ConfigError
from marker_localizer.evaluation import INTERVAL_HEADING, DetectionTally
from marker_localizer.synthetic import RenderedScene, SceneConfig, render_checkerboard, render_scene
from marker_localizer.synthetic.crlb import X_SNR_BANDS
from marker_localizer.synthetic.scene import MAX_ILLUMINATION_STRENGTH
from marker_localizer.synthetic.textures import GROUND_REFLECTANCE_LIMITS, warped_texture

#: The row every peer is compared with ("peer/ours" = peer mean error / this row's).
REFERENCE_ROW = "ours (symmetry)"
#: Largest offset of cornerSubPix's start from the truth, px.
SUBPIX_START_PX = 1.0
#: Issue 12, item 5 (a tighter, correct radius range never lowers recall): the
#: reference row also reads each frame at its radius range this much wider either
#: way, a range still correct, as a user unsure of the altitude gives it ((d)'s
#: 4-40 px becomes 3.2-50).
WIDER_RANGE_FACTOR = 1.25
#: Our detector's radius range per real set, px (centre to the end of the X).
#: ValidationBoof / libcbdetect: square sides from 11 to 110 px; a chessboard
#: corner's X ends at the neighbouring corners, and 40 px of it is plenty.
#: pycbd: 65 to 215 px squares in 1 to 12 MP frames. cirn_uas: the targets are
#: about 30 px across, so their X's reach 12 to 15 px.
REAL_RADIUS_RANGES: dict[str, RadiusRange] = {
    "validationboof": (5.0, 40.0),
    "libcbdetect": (5.0, 40.0),
    "pycbd": (10.0, 80.0),
    "cirn_uas": (6.0, 24.0),
    "aerial_negatives": (3.0, 30.0),
}


class CirnReading(NamedTuple):
    """One radius range cirn_uas is read at, and whose range it is (for the table's title)."""

    radius_range: RadiusRange
    whose: str


#: The ranges cirn_uas is read at: the one its targets ask, and the one real aerial
#: ground is held to (aerial_negatives'). Its ground away from the two targets is real
#: ground too, and texture X's of 2-4 px show there only from the smaller radii
#: (docs/accuracy-journal.md, "The coarse plate search held to the full grid's tilt").
CIRN_RANGES: dict[str, CirnReading] = {
    "cirn_uas": CirnReading(REAL_RADIUS_RANGES["cirn_uas"], "its targets'"),
    "cirn_uas_ground_range": CirnReading(
        REAL_RADIUS_RANGES["aerial_negatives"], "real aerial ground's, as aerial_negatives'"
    ),
}
#: What ``--families`` can choose: the rendered families, markers with a dull
#: quadrant alone at several radius ranges (:mod:`~marker_localizer.bench.dull`), the
#: rendered markers of (a) and (b) on real ground, the independent renderer's frames,
#: the real sets with reference points, the real negatives, the held-out frames of the
#: rendered families (:func:`run_heldout`).
FAMILY_KEYS = (
    "a",
    "b",
    "c",
    "d",
    "e",
    "g",
    "dull",
    "ground",
    "ground_b",
    "independent",
    "real",
    "negatives",
    "heldout",
)
#: The held-out frames of a rendered family are those of seeds ``seed * 1000 +
#: HELDOUT_SEED_OFFSET + i``: far from the family tables' ``seed * 1000 + i``.
HELDOUT_SEED_OFFSET = 500
#: Held-out frames per family: a false point in them reads 0.04 a frame, under
#: issue 12's budget of 0.05 (the family tables' 8-12 frames read one as 0.08-0.12).
HELDOUT_FRAMES = 24
#: The independent renderer's families (its data README), in table order.
INDEPENDENT_FAMILIES: dict[str, str] = {
    "a": "radius 6-40 px, tilt up to 60 deg, no look-alikes",
    "b": "tiny markers, radius 2.5-5 px, 30 per frame",
    "c": "motion blur up to 4 px",
    "d": "clutter: 60 look-alikes, radius 4-30 px, strong light gradient",
    "g": "uneven light: one dull bright quadrant on every marker, a hard shadow edge "
    "across half of them, 20 look-alikes",
}


# --------------------------------------------------------------------------- families


@dataclass(frozen=True)
class RecallSplit:
    """Classes of a family's markers by what makes them hard, for a recall table.

    Attributes:
        title: the table's heading.
        labels: the classes' names, in the table's order.
        classify: rendered frame -> (N,) each marker's class, an index into ``labels``.
    """

    title: str
    labels: tuple[str, ...]
    classify: Callable[[RenderedScene], np.ndarray]


@dataclass(frozen=True)
class Family:
    """A rendered scenario family.

    Attributes:
        key: short name used by ``--families`` (several families may share one).
        title: table heading.
        radius_range: true marker radius range, px (what a user would configure).
        frames: default number of frames; ``--quick`` uses ``quick_frames``.
        quick_frames: frames in a quick run.
        render: seed -> rendered frame with exact truth.
        board_pattern: (columns, rows) for chessboard families (board peers run), else None.
        splits: the family's recall tables, each by a condition of its markers.
        variant: what tells it from another family of the same key, for the summary.
        scene: what its frames are drawn from; None: not a :class:`SceneConfig`'s
            (the chessboards).
    """

    key: str
    title: str
    radius_range: RadiusRange
    frames: int
    quick_frames: int
    render: Callable[[int], RenderedScene]
    board_pattern: tuple[int, int] | None = None
    splits: tuple[RecallSplit, ...] = ()
    variant: str = ""
    scene: SceneConfig | None = None

    @property
    def label(self) -> str:
        """Short name in the summary table."""
        return f"rendered ({self.key}){' ' + self.variant if self.variant else ''}"


def _scene(**fields: Any) -> dict[str, Any]:
    """A rendered family's ``render`` and ``scene``: frames drawn with each marker's bound."""
    config = SceneConfig(**fields)
    return {"render": lambda seed: render_scene(config, seed, crlb=True), "scene": config}


#: What every rendered marker family draws from: at least the independent
#: renderer's documented ranges (contrast 0.35-0.9 of full scale, white at
#: 70-100 % of 255, read noise 0.5-4 DN plus shot noise up to 0.05 x signal,
#: ground photographs at 0.25-2.5 px per texture px, gamma 0.8-1.25, the
#: renderer's default), and half the frames written as JPEG at quality 70-95.
_BASE = {
    "radius_px": (6.0, 40.0),
    "blur_sigma_px": (0.5, 1.5),
    "noise_sigma_dn": (0.5, 4.0),
    "max_tilt_deg": 60.0,
    "contrast": (0.35, 0.9),
    "peak_level": (0.7, 1.0),
    "shot_noise_gain_dn": (0.0, 0.05),
    "texture_scale": (0.25, 2.5),
    "jpeg_probability": 0.5,
}
#: One line for the tables: what the families share.
BASE_CONDITIONS = (
    "rendered families: blur 0.5-1.5 px, read noise 0.5-4 DN + shot noise "
    "<= 0.05 x signal, contrast 0.35-0.9, white at 70-100 % of 255, gamma "
    "0.8-1.25, tilt <= 60 deg, ground photographs at 0.25-2.5 px per texture "
    "px, half the frames JPEG (quality 70-95)"
)
#: Radius of family (d)'s markers, px: down to the independent renderer's clutter
#: family's 4 px (its documented 4-30), up to the other families' 40.
CLUTTER_RADIUS_PX = (4.0, 40.0)
_CLUTTER = {"illumination_strength": 1.0, "n_shadows": 4, "radius_px": CLUTTER_RADIUS_PX}
#: Family (g): every marker has a dull bright quadrant, half a hard cast shadow.
_UNEVEN_LIGHT = {"dull_probability": 1.0, "shadow_probability": 0.5}
#: Square sides of the rendered chessboards before tilt, px.
BOARD_SQUARE_PX = (24.0, 44.0)
#: Largest out-of-plane tilt of the rendered chessboards, degrees.
BOARD_MAX_TILT_DEG = 50.0


def render_board_frame(seed: int) -> RenderedScene:
    """A 10 x 10 inner-corner chessboard under random perspective, 1280 x 960, exact truth.

    Draws square size, rotation, tilt (up to :data:`BOARD_MAX_TILT_DEG`), blur
    (0.5-1.5 px) and noise (0-4 DN); redraws when the board leaves the frame.
    """
    rng = np.random.default_rng(seed)
    for _ in range(50):
        square = float(rng.uniform(*BOARD_SQUARE_PX))
        try:
            return render_checkerboard(
                (960, 1280),
                (10, 10),
                square,
                centre=(float(rng.uniform(560, 720)), float(rng.uniform(400, 560))),
                rotation_rad=float(rng.uniform(0, np.pi)),
                tilt_deg=float(rng.uniform(0, BOARD_MAX_TILT_DEG)),
                tilt_axis_rad=float(rng.uniform(0, np.pi)),
                blur_sigma_px=float(rng.uniform(0.5, 1.5)),
                noise_sigma_dn=float(rng.uniform(0.0, 4.0)),
                gamma=float(rng.uniform(0.8, 1.25)),
                seed=rng,
            )
        except ConfigError:
            continue
    raise ConfigError(f"no chessboard pose fits the frame for seed {seed}")


#: Edges of family (b)'s recall-by-resolution table: a 2.5-5 px marker tilted up to
#: 60 degrees under 0.5-1.5 px of blur spans resolutions of about 1 to 10.
_TINY_RESOLUTION_BINS = (2.0, 3.0, 4.0)


def marker_resolution(scene: RenderedScene) -> np.ndarray:
    """(N,) each marker's foreshortened radius over the frame's blur sigma.

    How many PSF widths the X spans in its narrowest direction: below about 3 the
    blur merges the quadrants of a tilted tiny marker into a blob.
    """
    sigma = max(scene.imaging.blur_sigma_px, 1e-6)
    return np.array([m.foreshortened_radius_px / sigma for m in scene.markers])


def bin_labels(edges: Sequence[float]) -> tuple[str, ...]:
    """The labels of the bins ``np.digitize`` puts values in, given their inner ``edges``."""
    return (
        f"< {edges[0]:g}",
        *(f"{a:g}-{b:g}" for a, b in itertools.pairwise(edges)),
        f">= {edges[-1]:g}",
    )


def resolution_split(edges: Sequence[float]) -> RecallSplit:
    """Recall by :func:`marker_resolution`, in bins with these inner ``edges``."""
    return RecallSplit(
        "recall by resolution: foreshortened radius over blur sigma",
        bin_labels(edges),
        lambda scene: np.digitize(marker_resolution(scene), edges),
    )


def x_snr_band(x_snr: np.ndarray) -> np.ndarray:
    """(N,) each X signal-to-noise ratio's band of ``X_SNR_BANDS``; -1 where it is unknown."""
    return np.where(np.isfinite(x_snr), np.digitize(x_snr, X_SNR_BANDS), -1)


def _x_snr_class(scene: RenderedScene) -> np.ndarray:
    """(N,) each marker's band of the X's signal-to-noise ratio (:func:`x_snr_band`)."""
    return x_snr_band(np.array([m.x_snr for m in scene.markers], dtype=np.float64))


#: Recall by what an ideal detector has to go on: the X's signal-to-noise ratio
#: (:func:`~marker_localizer.synthetic.crlb.x_snr`). A marker missed at a high ratio
#: is lost to the detector's tests or to the ground, not to the noise.
X_SNR_SPLIT = RecallSplit(
    "recall by the X's signal-to-noise ratio", bin_labels(X_SNR_BANDS), _x_snr_class
)

#: First seed of the rendered frames each family's :class:`XSnrModel` is fitted on
#: (:func:`x_snr_model`; no table renders seeds under 1000) ...
X_SNR_MODEL_SEED = 300
#: ... and how many: 144-288 markers give its coefficients to a few percent ...
X_SNR_MODEL_FRAMES = 12
#: ... or in a quick run, where the bound's share is fitted well and the radius's is not.
X_SNR_MODEL_QUICK_FRAMES = 2


class XSnrModel(NamedTuple):
    """A marker's X signal-to-noise ratio from its Cramer-Rao bound and its radius.

    Another renderer's truth may give each marker's bound and radius but not its X
    (the independent renderer's ``truth.json``). Both follow the X's contrast over
    the noise, the bound inversely: log SNR = c0 + c1 log bound + c2 log radius,
    fitted on this renderer's markers of the same family, holds them to within a
    fifth (``residual_sd``, in the log; measured: docs/accuracy-journal.md, "What an ideal
    detector could find"). Recall on those frames can then be split by the SNR
    their markers would have.

    Attributes:
        coefficients: (c0, c1, c2).
        residual_sd: the fit's residual standard deviation, in the log.
    """

    coefficients: tuple[float, float, float]
    residual_sd: float

    @classmethod
    def fit(cls, x_snr: np.ndarray, bound_px: np.ndarray, radius_px: np.ndarray) -> XSnrModel:
        """Least squares in the logs, over the markers with a finite, positive SNR and bound."""
        usable = (x_snr > 0) & (bound_px > 0) & np.isfinite(x_snr) & np.isfinite(bound_px)
        design = np.column_stack(
            [np.ones(int(usable.sum())), np.log(bound_px[usable]), np.log(radius_px[usable])]
        )
        target = np.log(x_snr[usable])
        c0, c1, c2 = np.linalg.lstsq(design, target, rcond=None)[0]
        residual = target - design @ np.array([c0, c1, c2])
        return cls((float(c0), float(c1), float(c2)), float(residual.std()))

    def predict(self, bound_px: np.ndarray, radius_px: np.ndarray) -> np.ndarray:
        """(N,) the SNR markers of these bounds and radii have (NaN where the bound is not)."""
        c0, c1, c2 = self.coefficients
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.exp(c0 + c1 * np.log(bound_px) + c2 * np.log(radius_px))


def x_snr_model(family: Family, frames: int) -> XSnrModel:
    """:class:`XSnrModel` fitted on ``frames`` of a rendered family, from ``X_SNR_MODEL_SEED``."""
    snr, bound, radius = [], [], []
    for i in range(frames):
        scene = family.render(X_SNR_MODEL_SEED + i)
        snr += [m.x_snr for m in scene.markers]
        bound += [m.crlb_mean_abs_error_px for m in scene.markers]
        radius += [m.radius_px for m in scene.markers]
    return XSnrModel.fit(np.array(snr), np.array(bound), np.array(radius))


#: Inner edges of family (g)'s classes by the dull quadrant's lead over the dark paint
#: (:attr:`MarkerTruth.dull_margin`): under 0.2 of the other bright quadrant's lead,
#: the dull quadrant's two edges are within a fifth of the X's contrast, of the
#: ground's texture (the X is nearly an L-corner on its plate); from 0.5 on, as in
#: the family's definition, dullness alone.
DULL_MARGIN_EDGES = (0.2, 0.5)


def _uneven_light_class(scene: RenderedScene) -> np.ndarray:
    margin = np.digitize([m.dull_margin for m in scene.markers], DULL_MARGIN_EDGES)
    return margin + (len(DULL_MARGIN_EDGES) + 1) * scene.shadow_crossed


#: Family (g)'s recall table: by the dull quadrant's lead over the dark paint, without
#: and with a cast shadow's edge across the marker.
UNEVEN_LIGHT_SPLIT = RecallSplit(
    "recall by the dull quadrant's lead over the dark paint (a share of the other bright "
    "quadrant's), without and with a shadow's edge across",
    tuple(
        f"{label}{' shadow' if shadowed else ''}"
        for shadowed in (False, True)
        for label in bin_labels(DULL_MARGIN_EDGES)
    ),
    _uneven_light_class,
)


def families() -> list[Family]:
    """The scenario families of issues 6 and 12, in table order."""
    return [
        Family(
            "a",
            "(a) radius 6-40 px, 12 per 1280x960 frame, 20 look-alikes",
            (6.0, 40.0),
            12,
            2,
            **_scene(**_BASE),
            splits=(X_SNR_SPLIT,),
        ),
        Family(
            "b",
            "(b) tiny markers, radius 2.5-5 px (otherwise as (a)), 24 per frame",
            (2.5, 5.0),
            8,
            1,
            **_scene(**{**_BASE, "radius_px": (2.5, 5.0), "n_markers": 24}),
            splits=(resolution_split(_TINY_RESOLUTION_BINS), X_SNR_SPLIT),
        ),
        Family(
            "c",
            "(c) motion blur 0-4 px (otherwise as (a))",
            (6.0, 40.0),
            8,
            1,
            **_scene(**_BASE, motion_blur_px=(0.0, 4.0)),
            splits=(X_SNR_SPLIT,),
        ),
        Family(
            "d",
            "(d) cluttered 1280x960: radius 4-40 px, 110 hard negatives, strong light "
            "gradient, 4 shadows",
            CLUTTER_RADIUS_PX,
            8,
            1,
            **_scene(**{**_BASE, **_CLUTTER}, n_hard_negatives=110),
            splits=(X_SNR_SPLIT,),
        ),
        Family(
            "d",
            "(d) cluttered 4096x3000: radius 4-40 px, 400 hard negatives, strong light "
            "gradient, 4 shadows, 24 markers",
            CLUTTER_RADIUS_PX,
            3,
            1,
            **_scene(
                **{**_BASE, **_CLUTTER},
                width=4096,
                height=3000,
                n_markers=24,
                n_hard_negatives=400,
            ),
            splits=(X_SNR_SPLIT,),
            variant="4096x3000",
        ),
        Family(
            "d",
            "(d) cluttered 1280x960 in the independent renderer's light: (d)'s frames with "
            f"the light's gain {1.0 - MAX_ILLUMINATION_STRENGTH / 2:g}-1 across a frame (its "
            "blurred light 4-10 to 1, the independent clutter frames' 6-20 to 1)",
            CLUTTER_RADIUS_PX,
            8,
            1,
            **_scene(
                **{**_BASE, **_CLUTTER, "illumination_strength": MAX_ILLUMINATION_STRENGTH},
                n_hard_negatives=110,
            ),
            splits=(X_SNR_SPLIT,),
            variant="strong light",
        ),
        Family(
            "g",
            "(g) uneven light: one bright quadrant 0.45-0.8 as bright as the other on "
            "every marker, a hard shadow edge (40-65 % darker) within 0.6 radii of the centre "
            "of half of them, radius 5-30 px, 20 look-alikes",
            (5.0, 30.0),
            8,
            1,
            **_scene(**{**_BASE, **_UNEVEN_LIGHT, "radius_px": (5.0, 30.0)}),
            splits=(UNEVEN_LIGHT_SPLIT, X_SNR_SPLIT),
        ),
        Family(
            "e",
            "(e) chessboards 10x10 inner corners, squares 24-44 px, tilt <= 50 deg "
            "(not the family conditions: blur 0.5-1.5, noise <= 4 DN, no bound computed)",
            BOARD_SQUARE_PX,
            8,
            1,
            render_board_frame,
            board_pattern=(10, 10),
        ),
    ]


#: A crop of a cirn_uas frame keeps its two targets this far outside it, px: their
#: plates (about 30 px across) and the blur around them.
REAL_GROUND_TARGET_CLEARANCE_PX = 60.0
#: Crops drawn before a frame's targets are declared in the way of every one.
_REAL_GROUND_TRIES = 100
#: The families drawn on real ground: ``--families`` key -> (the rendered family
#: whose scene is drawn, its markers in the table's title). (b)'s tiny markers on
#: real terrain are the paper's regime; the renderer's ground is calmer around them.
REAL_GROUND_FAMILIES: dict[str, tuple[str, str]] = {
    "ground": ("a", "markers"),
    "ground_b": ("b", "tiny markers (radius 2.5-5 px, 24 a frame)"),
}


def real_ground_family(root: Path, key: str = "ground") -> Family | None:
    """A rendered family's markers on real ground; None where no marker-free real frame is found.

    The scene (markers, look-alikes, light, blur, noise, JPEG) of the family
    :data:`REAL_GROUND_FAMILIES` gives for ``key``, drawn on a crop of a real
    frame in place of the renderer's ground photographs: the aerial frames
    without markers, and cirn_uas's frames away from their two targets. Frame
    ``seed`` crops real frame ``seed`` modulo their number, where a stream of its
    own draws (:func:`real_ground_frame`). Its false points are the real ground's
    and the look-alikes'.
    """
    drawn, markers = REAL_GROUND_FAMILIES[key]
    grounds = _real_grounds(root)
    if not grounds:
        return None
    family = next(f for f in families() if f.key == drawn and not f.variant)
    scene = family.scene
    if scene is None:
        raise ConfigError(f"family ({drawn}) is not drawn from a SceneConfig")

    def render(seed: int) -> RenderedScene:
        return real_ground_frame(scene, grounds, seed)

    return replace(
        family,
        key=key,
        title=f"({key}) family ({drawn})'s {markers} and look-alikes drawn on real ground: "
        f"{scene.width}x{scene.height} crops of the {len(grounds)} real frames without a "
        "diagonal marker (aerial_negatives, cirn_uas away from its targets), their grey "
        "levels as the ground's reflectance",
        render=render,
    )


@functools.lru_cache(maxsize=1)
def _real_grounds(root: Path) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """(grey frame, (K, 2) points a crop keeps clear of) of every marker-free real frame.

    Read once a run: the family tables and the held-out frames both build the families.
    """
    grounds: list[tuple[np.ndarray, np.ndarray]] = [
        (f.image, np.zeros((0, 2))) for f in real_data.iter_aerial_negatives(root)
    ]
    if (root / "cirn_uas").is_dir():
        grounds += [(f.image, real_data.CIRN_TARGETS) for f in real_data.iter_cirn_uas(root)]
    return tuple(grounds)


def real_ground_frame(
    scene: SceneConfig, grounds: Sequence[tuple[np.ndarray, np.ndarray]], seed: int
) -> RenderedScene:
    """``scene`` rendered on a crop of ``grounds[seed % len(grounds)]``, of its frame's size.

    The crop's corner is drawn from its own stream (``[seed, 1]``), so the scene
    draws its markers as :func:`render_scene` does from ``seed``; it keeps
    :data:`REAL_GROUND_TARGET_CLEARANCE_PX` from the frame's points to avoid.

    Raises:
        ConfigError: where no crop of the frame keeps clear of its points.
    """
    image, avoid = grounds[seed % len(grounds)]
    height, width = scene.height, scene.width
    rng = np.random.default_rng([seed, 1])
    margin = REAL_GROUND_TARGET_CLEARANCE_PX
    for _ in range(_REAL_GROUND_TRIES):
        top = int(rng.integers(0, image.shape[0] - height + 1))
        left = int(rng.integers(0, image.shape[1] - width + 1))
        inside = (
            (avoid[:, 0] > left - margin)
            & (avoid[:, 0] < left + width + margin)
            & (avoid[:, 1] > top - margin)
            & (avoid[:, 1] < top + height + margin)
        )
        if not inside.any():
            break
    else:
        raise ConfigError(f"no {width}x{height} crop of real frame {seed % len(grounds)} is clear")
    crop = image[top : top + height, left : left + width].astype(np.float32) / 255.0
    ground = np.clip(crop, *GROUND_REFLECTANCE_LIMITS)
    return render_scene(scene, seed, crlb=True, ground=ground)


# --------------------------------------------------------------------------- evaluation


@dataclass
class Row:
    """One detector's totals in one table.

    Attributes:
        name: detector label.
        tally: recall / FP / error totals.
        refiner: True for a refinement-only peer (no FP figure).
        extra: further figures of real-data tables, by column name.
        lost_at: for this package's detector, how many of the markers it missed
            each test lost (:func:`evaluation.tests_that_lost`).
        found_by: for this package's detector, how many of the markers it found
            each reading added (:data:`symmetry_path.READINGS`' names).
        false_by: ... and how many of its false points.
        range_checked: for the reference row, whether each frame was read at the
            wider range too (:data:`WIDER_RANGE_FACTOR`, :func:`_compare_wider_range`).
        found_only_wider: markers found at the wider range and not at the frame's own.
        found_only_own: markers found at the frame's own range and not at the wider.
        false_wider: false points at the wider range.
    """

    name: str
    tally: DetectionTally = field(default_factory=DetectionTally)
    refiner: bool = False
    extra: dict[str, float] = field(default_factory=dict)
    lost_at: Counter[str] = field(default_factory=Counter)
    found_by: Counter[str] = field(default_factory=Counter)
    false_by: Counter[str] = field(default_factory=Counter)
    range_checked: bool = False
    found_only_wider: int = 0
    found_only_own: int = 0
    false_wider: int = 0


def wider_range(radius_range: RadiusRange) -> RadiusRange:
    """``radius_range`` :data:`WIDER_RANGE_FACTOR` wider either way, px."""
    low, high = radius_range
    return (low / WIDER_RANGE_FACTOR, high * WIDER_RANGE_FACTOR)


def _timed_detect(
    detector: PointDetector,
    image: np.ndarray,
    radius_range: RadiusRange,
    colour: np.ndarray | None = None,
) -> tuple[np.ndarray, float]:
    """The points ``detector`` finds, and its seconds.

    ``colour``, a colour file's planes, goes to ours alone: the peers read the grey,
    as OpenCV users give it them.
    """
    start = time.perf_counter()
    if isinstance(detector, OurDetector) and colour is not None:
        points = detector.detect(image, radius_range, colour)
    else:
        points = detector.detect(image, radius_range)
    return points, time.perf_counter() - start


def _sigmas(detector: PointDetector) -> np.ndarray | None:
    return detector.last_sigmas if isinstance(detector, OurDetector) else None


def _line_angles(detector: PointDetector) -> np.ndarray | None:
    return detector.last_line_angles if isinstance(detector, OurDetector) else None


def _count_losses(
    row: Row, detector: PointDetector, matching: evaluation.Matching, truth: np.ndarray
) -> None:
    """Add to ``row.lost_at`` the tests that lost the markers ``detector`` missed."""
    if isinstance(detector, OurDetector):
        missed = np.setdiff1d(np.arange(len(truth)), matching.truth_index)
        row.lost_at.update(evaluation.tests_that_lost(detector.last_survivors, truth[missed]))


def _readings(detector: PointDetector, points: np.ndarray) -> list[str]:
    """The reading that added each of the points ``detector`` just found; none for a peer."""
    if not isinstance(detector, OurDetector):
        return []
    return evaluation.readings_that_added(detector.last_survivors, points, symmetry_path.READINGS)


def _count_readings(
    row: Row, detector: PointDetector, matching: evaluation.Matching, points: np.ndarray
) -> None:
    """Add to ``row.found_by`` / ``row.false_by`` the readings that added the points found."""
    labels = _readings(detector, points)
    if labels:
        row.found_by.update(labels[k] for k in matching.detection_index)
        row.false_by.update(labels[k] for k in matching.unmatched_detections)


def _compare_wider_range(
    row: Row, detector: PointDetector, frame: LabelledFrame, matching: evaluation.Matching
) -> None:
    """Add to ``row`` the markers the reference row finds at only one of the two ranges.

    ``matching``: its detections at the frame's own range. The detector reads the
    frame again at :func:`wider_range`; run it last, for it replaces what the
    detector keeps of its last call.
    """
    if not (isinstance(detector, OurDetector) and detector.name == REFERENCE_ROW):
        return
    at_wider = evaluation.match_points(
        detector.detect(frame.image, wider_range(frame.radius_range)), frame.truth
    )
    own, wider = set(matching.truth_index.tolist()), set(at_wider.truth_index.tolist())
    row.range_checked = True
    row.found_only_wider += len(wider - own)
    row.found_only_own += len(own - wider)
    row.false_wider += at_wider.n_false_positives


def subpix_starts(
    truth: np.ndarray, rng: np.random.Generator, max_offset_px: float = SUBPIX_START_PX
) -> np.ndarray:
    """Truth moved by a random offset: direction uniform, length uniform in [0, max] px."""
    angle = rng.uniform(0.0, 2.0 * np.pi, len(truth))
    length = rng.uniform(0.0, max_offset_px, len(truth))
    return truth + np.column_stack([np.cos(angle), np.sin(angle)]) * length[:, None]


@dataclass
class FamilyResult:
    """A family's rows and what is known about each truth point.

    Attributes:
        rows: one :class:`Row` per detector, then the cornerSubPix row, then the
            board peers' rows for chessboard families.
        split_class: (N, S) per truth point, in the order of every tally's ``found``:
            its class in each of the family's S :class:`RecallSplit` (-1: none).
    """

    rows: list[Row]
    split_class: np.ndarray


@dataclass(frozen=True)
class LabelledFrame:
    """A frame with exact truth, from this package's renderer or another.

    Attributes:
        image: (H, W) uint8 frame.
        truth: (N, 2) marker centres, px.
        crlb_px: (N,) each marker's Cramer-Rao bound (expected |error|), px; NaN: unknown.
        radius_range: (min, max) marker radius given to every detector, px.
        split_class: (N, S) each marker's class in each of its family's S
            :class:`RecallSplit` (-1: none).
        truth_line_angles: (N, 2) each marker's line directions at its centre,
            radians; NaN: unknown (the independent renderer's truth has none).
    """

    image: np.ndarray
    truth: np.ndarray
    crlb_px: np.ndarray
    radius_range: RadiusRange
    split_class: np.ndarray
    truth_line_angles: np.ndarray

    @classmethod
    def rendered(
        cls,
        scene: RenderedScene,
        radius_range: RadiusRange,
        splits: Sequence[RecallSplit] = (),
    ) -> LabelledFrame:
        """A frame of this package's renderer, its markers classed by each of ``splits``."""
        classes = np.array([split.classify(scene) for split in splits], dtype=np.int64)
        classes = classes.reshape(len(splits), len(scene.markers)).T
        angles = np.array([m.angles for m in scene.markers], np.float64).reshape(-1, 2)
        return cls(scene.image, scene.centres, scene.crlb_px, radius_range, classes, angles)

    @classmethod
    def independent(
        cls, frame: real_data.IndependentFrame, x_snr: XSnrModel | None = None
    ) -> LabelledFrame:
        """A frame of the independent renderer, with its own radius range and bound.

        With ``x_snr``, its markers are classed by :data:`X_SNR_SPLIT` on the SNR the
        model gives them.
        """
        classes: np.ndarray = np.zeros((len(frame.truth), 0), np.int64)
        if x_snr is not None:
            classes = x_snr_band(x_snr.predict(frame.crlb_px, frame.radius_px))[:, None]
        return cls(
            frame.image,
            frame.truth,
            frame.crlb_px,
            frame.radius_range,
            classes,
            np.full((len(frame.truth), 2), np.nan),
        )


def evaluate_frames(
    frames: Iterable[LabelledFrame],
    seed: int,
    detectors: Sequence[PointDetector],
    board_pattern: tuple[int, int] | None = None,
) -> FamilyResult:
    """Score every detector and cornerSubPix on frames with exact truth.

    Args:
        frames: the frames, each with its radius range.
        seed: seed of cornerSubPix's start offsets.
        detectors: point detectors to score (ours and peers).
        board_pattern: (columns, rows) of a chessboard family: its board peers run too.
    """
    board = peers.board_detectors(board_pattern) if board_pattern else []
    everyone = [*detectors, *board]
    rows = {d.name: Row(d.name) for d in everyone}
    refiner_row = Row(f"{peers.CornerSubPixRefiner.name} (start <= 1 px)", refiner=True)
    rng = np.random.default_rng(seed)
    classes = []
    for frame in frames:
        classes.append(frame.split_class)
        for detector in everyone:
            points, seconds = _timed_detect(detector, frame.image, frame.radius_range)
            matching = evaluation.match_points(points, frame.truth)
            row = rows[detector.name]
            row.tally.add(
                matching,
                _sigmas(detector),
                seconds,
                frame.crlb_px,
                _line_angles(detector),
                frame.truth_line_angles,
            )
            _count_losses(row, detector, matching, frame.truth)
            _count_readings(row, detector, matching, points)
            _compare_wider_range(row, detector, frame, matching)
        refiner = peers.CornerSubPixRefiner(peers.subpix_half_window(frame.radius_range))
        start = time.perf_counter()
        refined = refiner.refine(frame.image, subpix_starts(frame.truth, rng))
        refiner_row.tally.add(
            evaluation.match_points(refined, frame.truth),
            seconds=time.perf_counter() - start,
            truth_crlb_px=frame.crlb_px,
        )
    ordered = [rows[d.name] for d in detectors]
    return FamilyResult(
        [*ordered, refiner_row, *(rows[d.name] for d in board)],
        np.concatenate(classes) if classes else np.zeros((0, 0), dtype=np.int64),
    )


def evaluate_family(
    family: Family, n_frames: int, seed: int, detectors: Sequence[PointDetector]
) -> FamilyResult:
    """Render ``n_frames`` of a family (seeds ``seed * 1000 + i``) and score them.

    Args:
        family: what to render.
        n_frames: frames to render.
        seed: base seed (rendering and cornerSubPix's start offsets).
        detectors: point detectors to score (ours and peers).
    """
    frames = (
        LabelledFrame.rendered(family.render(seed * 1000 + i), family.radius_range, family.splits)
        for i in range(n_frames)
    )
    return evaluate_frames(frames, seed, detectors, family.board_pattern)


# --------------------------------------------------------------------------- real images


def evaluate_boards(
    images: Sequence[real_data.BoardImage],
    detectors: Sequence[PointDetector],
    radius_range: RadiusRange,
) -> list[Row]:
    """Score detectors on real chessboards against their reference corners.

    Figures per detector (``Row.extra``): ``boards_complete`` (share of boards
    with every reference corner found), ``t1_max`` / ``t1_mean`` / ``t1_fine``
    (the paper's Table 1: deviation from OpenCV's refined corners, px, and share
    within 0.1 px), ``line_rms`` / ``spacing_rms`` / ``lens_rms`` / ``line_points``
    (row/column residuals and the residual about each board's lens model,
    :func:`metrics.lens_model_residuals`, over the detector's own corners, px)
    and the same on the corners every detector with recall >=
    :data:`COMMON_MIN_RECALL` found (``common_line_rms``, ``common_spacing_rms``,
    ``common_lens_rms``, ``common_points``): only there do detectors compare on
    the same points. ``Row.tally`` holds recall against the reference corners.
    """
    rows, placed = [], {}
    image_shapes = _board_image_shapes(images)
    for detector in detectors:
        row, grids = _score_boards(images, image_shapes, detector, radius_range)
        rows.append(row)
        placed[detector.name] = grids
    _add_common_residuals(rows, placed, image_shapes)
    return rows


def _board_image_shapes(images: Sequence[real_data.BoardImage]) -> list[tuple[int, ...]]:
    """Each board's image shape, in the order the boards' grids are listed."""
    return [item.image.shape for item in images for _ in item.boards]


#: Detectors below this recall on a set are left out of its common-corner comparison
#: (otherwise one weak detector would leave no common corners).
COMMON_MIN_RECALL = 0.5


def _score_boards(
    images: Sequence[real_data.BoardImage],
    image_shapes: list[tuple[int, ...]],
    detector: PointDetector,
    radius_range: RadiusRange,
) -> tuple[Row, list[np.ndarray]]:
    """One detector on every board: its row and its corners placed in each reference grid."""
    row = Row(detector.name)
    complete, t1_errors, grids = 0, [], []
    for item in images:
        points, seconds = _timed_detect(detector, item.image, radius_range, item.colour)
        row.tally.add(evaluation.match_points(points, item.reference), seconds=seconds)
        t1_errors.append(evaluation.match_points(points, item.opencv).errors_px)
        for grid in item.boards:
            placed = metrics.grid_positions(grid, points)
            valid = np.isfinite(grid).all(axis=2)
            complete += int(np.isfinite(placed).all(axis=2)[valid].all())
            grids.append(placed)
    t1 = evaluation.ErrorStats.from_errors(np.concatenate(t1_errors) if t1_errors else [])
    own = metrics.pool_line_residuals([metrics.line_residuals(g) for g in grids])
    row.extra = {
        "boards_complete": complete / len(grids) if grids else math.nan,
        "t1_max": t1.max,
        "t1_mean": t1.mean,
        "t1_fine": t1.within_fine,
        "line_rms": own.straight_rms_px,
        "spacing_rms": own.spacing_rms_px,
        "lens_rms": metrics.pool_lens_model_residuals(grids, image_shapes).rms_px,
        "line_points": float(own.n_points),
    }
    return row, grids


def _add_common_residuals(
    rows: Sequence[Row], placed: dict[str, list[np.ndarray]], image_shapes: list[tuple[int, ...]]
) -> None:
    """Residuals of every qualifying detector on the corners all of them found."""
    members = [r for r in rows if r.tally.recall >= COMMON_MIN_RECALL]
    for row in rows:
        row.extra.update(
            common_line_rms=math.nan,
            common_spacing_rms=math.nan,
            common_lens_rms=math.nan,
            common_points=0.0,
        )
    if not members:
        return
    n_boards = len(placed[members[0].name])
    masks = [
        np.logical_and.reduce([np.isfinite(placed[r.name][b]).all(axis=2) for r in members])
        for b in range(n_boards)
    ]
    for row in members:
        grids = [
            np.where(mask[..., None], g, np.nan)
            for mask, g in zip(masks, placed[row.name], strict=True)
        ]
        common = metrics.pool_line_residuals([metrics.line_residuals(g) for g in grids])
        row.extra.update(
            common_line_rms=common.straight_rms_px,
            common_spacing_rms=common.spacing_rms_px,
            common_lens_rms=metrics.pool_lens_model_residuals(grids, image_shapes).rms_px,
            common_points=float(common.n_points),
        )


def reference_residual_row(images: Sequence[real_data.BoardImage], label: str) -> Row:
    """Row/column and lens-model residuals of the reference grids (hand clicks or OpenCV)."""
    row = Row(label)
    grids = [g for item in images for g in item.boards]
    pooled = metrics.pool_line_residuals([metrics.line_residuals(g) for g in grids])
    row.extra = {
        "line_rms": pooled.straight_rms_px,
        "spacing_rms": pooled.spacing_rms_px,
        "lens_rms": metrics.pool_lens_model_residuals(grids, _board_image_shapes(images)).rms_px,
        "line_points": float(pooled.n_points),
        "common_line_rms": math.nan,
        "common_spacing_rms": math.nan,
        "common_lens_rms": math.nan,
        "common_points": 0.0,
    }
    return row


def evaluate_uas(
    frames: Sequence[real_data.UasFrame],
    detectors: Sequence[PointDetector],
    radius_range: RadiusRange,
) -> list[Row]:
    """Score detectors on the cirn_uas frames: both targets found, false positives.

    ``Row.extra``: ``both_found`` (share of frames with both targets within
    6 px), ``found_1`` / ``found_2`` (share per target), ``fp_per_frame``
    (detections farther than 10 px from both), ``seconds``.
    """
    rows = []
    for detector in detectors:
        found = np.zeros((len(frames), 2), bool)
        false_positives, seconds = 0, 0.0
        for i, frame in enumerate(frames):
            points, dt = _timed_detect(detector, frame.image, radius_range, frame.colour)
            seconds += dt
            to_target = evaluation.nearest_distances(real_data.CIRN_TARGETS, points)
            found[i] = to_target <= real_data.CIRN_FOUND_PX
            false_positives += int(
                (
                    evaluation.nearest_distances(points, real_data.CIRN_TARGETS)
                    > real_data.CIRN_FALSE_PX
                ).sum()
            )
        n = max(len(frames), 1)
        rows.append(
            Row(
                detector.name,
                extra={
                    "both_found": float(found.all(axis=1).mean()) if len(frames) else math.nan,
                    "found_1": float(found[:, 0].mean()) if len(frames) else math.nan,
                    "found_2": float(found[:, 1].mean()) if len(frames) else math.nan,
                    "fp_per_frame": false_positives / n,
                    "seconds": seconds / n,
                },
            )
        )
    return rows


def evaluate_negatives(
    frames: Sequence[real_data.UasFrame],
    detectors: Sequence[PointDetector],
    radius_range: RadiusRange,
) -> list[Row]:
    """Score detectors on real frames without any marker: every detection is false.

    ``Row.extra``: ``fp_per_frame`` and its interval (``fp_per_frame_low``,
    ``fp_per_frame_high``: :func:`evaluation.frame_rate_interval`, widened by the
    frames' spread), ``fp_per_megapixel``
    (over all the frames' pixels), ``seconds`` (per frame); for this package's
    detector, ``Row.false_by``: the false points by the reading that added them.
    """
    megapixels = sum(f.image.size for f in frames) / 1e6
    rows = []
    for detector in detectors:
        per_frame, seconds = [], 0.0
        false_by: Counter[str] = Counter()
        for frame in frames:
            points, dt = _timed_detect(detector, frame.image, radius_range, frame.colour)
            per_frame.append(len(points))
            seconds += dt
            false_by.update(_readings(detector, points))
        n, false_points = max(len(frames), 1), sum(per_frame)
        low, high = evaluation.frame_rate_interval(per_frame)
        rows.append(
            Row(
                detector.name,
                extra={
                    "fp_per_frame": false_points / n,
                    "fp_per_frame_low": low,
                    "fp_per_frame_high": high,
                    "fp_per_megapixel": false_points / megapixels if megapixels else math.nan,
                    "seconds": seconds / n,
                },
                false_by=false_by,
            )
        )
    return rows


# --------------------------------------------------------------------------- tables


def _fmt(value: float, digits: int = 3) -> str:
    return "-" if value is None or not np.isfinite(value) else f"{value:.{digits}f}"


def _pct(value: float) -> str:
    return "-" if not np.isfinite(value) else f"{100.0 * value:.1f}%"


def family_table(title: str, rows: Sequence[Row]) -> str:
    """Format a family's table (errors and bounds in px)."""
    ours = next((r.tally.stats.mean for r in rows if r.name == REFERENCE_ROW), math.nan)
    header = (
        f"{'detector':<34}{'recall':>8}{'FP/fr':>8}{'mean':>8}{'RMS':>8}{'p95':>8}"
        f"{'max':>8}{'<=0.1':>8}{'in 2sig':>8}{'CRLB':>8}{'err/CRLB':>9}"
        f"{'peer/ours':>10}{'s/frame':>9}"
    )
    lines = [title, header, "-" * len(header)]
    for row in rows:
        t, s = row.tally, row.tally.stats
        ratio = s.mean / ours if row.name != REFERENCE_ROW and ours > 0 else math.nan
        lines.append(
            f"{row.name:<34}{_pct(t.recall):>8}"
            f"{'-' if row.refiner else _fmt(t.fp_per_frame, 2):>8}"
            f"{_fmt(s.mean):>8}{_fmt(s.rms):>8}{_fmt(s.p95):>8}{_fmt(s.max):>8}"
            f"{_pct(s.within_fine):>8}{_pct(t.within_two_sigma):>8}"
            f"{_fmt(t.mean_crlb_px, 4):>8}{_fmt(t.error_over_crlb, 2):>9}{_fmt(ratio, 2):>10}"
            f"{_fmt(t.seconds / max(t.frames, 1), 2):>9}"
        )
    return "\n".join(lines)


@dataclass(frozen=True)
class SplitRecall:
    """Each detector's recall per class of a :class:`RecallSplit` (detectors, not refiners).

    Attributes:
        bins: class labels, e.g. ``"2-3"``.
        markers: truth points per class.
        recall: detector name -> recall per class (NaN for an empty class).
    """

    bins: list[str]
    markers: list[int]
    recall: dict[str, list[float]]

    def record(self) -> dict[str, dict[str, float | None]]:
        """The JSON figures: detector -> class -> recall (None for an empty class)."""
        return {
            name: {
                b: (r if math.isfinite(r) else None) for b, r in zip(self.bins, recall, strict=True)
            }
            for name, recall in self.recall.items()
        }


def split_recall(result: FamilyResult, labels: Sequence[str], split: int = 0) -> SplitRecall:
    """Split every detector's recall by the classes of ``result.split_class[:, split]``."""
    index = result.split_class[:, split]
    counts = np.bincount(index[index >= 0], minlength=len(labels))
    recall = {}
    for row in result.rows:
        if row.refiner:
            continue
        found = np.asarray(row.tally.found, dtype=bool)
        recall[row.name] = [
            float(found[index == k].mean()) if counts[k] else math.nan for k in range(len(labels))
        ]
    return SplitRecall(list(labels), counts.tolist(), recall)


def split_table(title: str, split: SplitRecall) -> str:
    """Format a :class:`SplitRecall`."""
    columns = [f"{name} ({count})" for name, count in zip(split.bins, split.markers, strict=True)]
    width = max(14, *(len(c) + 2 for c in columns))
    header = f"{'detector':<34}" + "".join(f"{c:>{width}}" for c in columns)
    lines = [title, header, "-" * len(header)]
    for name, recall in split.recall.items():
        lines.append(f"{name:<34}" + "".join(f"{_pct(r):>{width}}" for r in recall))
    return "\n".join(lines)


def boards_table(title: str, rows: Sequence[Row]) -> str:
    """Format a real chessboard set's table (errors and residuals in px)."""
    header = (
        f"{'detector':<34}{'recall':>8}{'boards':>8}{'T1 max':>8}{'T1 mean':>8}"
        f"{'T1<=0.1':>8}{'line':>7}{'spacing':>8}{'lens':>7}{'pts':>6}{'line=':>7}{'spac=':>7}"
        f"{'lens=':>7}{'pts=':>6}{'s/img':>7}"
    )
    lines = [title, header, "-" * len(header)]
    for row in rows:
        e, t = row.extra, row.tally
        lines.append(
            f"{row.name:<34}{_pct(t.recall):>8}{_pct(e.get('boards_complete', math.nan)):>8}"
            f"{_fmt(e.get('t1_max', math.nan), 2):>8}{_fmt(e.get('t1_mean', math.nan)):>8}"
            f"{_pct(e.get('t1_fine', math.nan)):>8}{_fmt(e['line_rms']):>7}"
            f"{_fmt(e['spacing_rms']):>8}{_fmt(e['lens_rms']):>7}{int(e['line_points']):>6}"
            f"{_fmt(e['common_line_rms']):>7}{_fmt(e['common_spacing_rms']):>7}"
            f"{_fmt(e['common_lens_rms']):>7}{int(e['common_points']):>6}"
            f"{_fmt(t.seconds / t.frames if t.frames else math.nan, 2):>7}"
        )
    return "\n".join(lines)


def uas_table(title: str, rows: Sequence[Row]) -> str:
    """Format the cirn_uas table."""
    header = (
        f"{'detector':<34}{'both':>8}{'target1':>9}{'target2':>9}{'FP/frame':>10}{'s/frame':>9}"
    )
    lines = [title, header, "-" * len(header)]
    for row in rows:
        e = row.extra
        lines.append(
            f"{row.name:<34}{_pct(e['both_found']):>8}{_pct(e['found_1']):>9}"
            f"{_pct(e['found_2']):>9}{_fmt(e['fp_per_frame'], 2):>10}"
            f"{_fmt(e['seconds'], 2):>9}"
        )
    return "\n".join(lines)


def negatives_table(title: str, rows: Sequence[Row]) -> str:
    """Format the table of real frames without markers (every detection is false).

    The last column gives this package's false points by the reading that added
    them (:data:`~marker_localizer.core.symmetry_path.READINGS`).
    """
    header = (
        f"{'detector':<34}{'FP/frame':>11}{INTERVAL_HEADING:>20}{'FP/MP':>10}{'s/frame':>9}"
        "  by reading"
    )
    lines = [title, header, "-" * len(header)]
    for row in rows:
        e = row.extra
        by_reading = ", ".join(f"{name} {count}" for name, count in row.false_by.items() if count)
        lines.append(
            f"{row.name:<34}{_fmt(e['fp_per_frame'], 2):>11}"
            f"{evaluation.interval_text((e['fp_per_frame_low'], e['fp_per_frame_high'])):>20}"
            f"{_fmt(e['fp_per_megapixel'], 3):>10}{_fmt(e['seconds'], 2):>9}"
            f"  {by_reading or '-'}"
        )
    return "\n".join(lines)


def summary_table(results: Sequence[tuple[str, Row]], title: str | None = None) -> str:
    """One line per family for the reference row: the figures issue 12's targets are about."""
    header = (
        f"{'family':<44}{'recall':>8}{INTERVAL_HEADING:>12}{'FP/fr':>8}{INTERVAL_HEADING:>12}"
        f"{'mean':>8}{'CRLB':>8}{'err/CRLB':>9}{'lines':>7}"
    )
    lines = [
        title
        or (
            f"Summary, {REFERENCE_ROW}: recall, false points per frame (each with its "
            f"{INTERVAL_HEADING} interval: Wilson's, exact Poisson, each widened by the "
            "spread between frames), mean error (px), "
            "mean Cramer-Rao bound of the markers found (px), their ratio, median error "
            "of the line directions reported (degrees; the larger of the two lines'; "
            "the independent renderer's truth has none)"
        ),
        header,
        "-" * len(header),
    ]
    for label, row in results:
        t = row.tally
        recall_interval = evaluation.interval_text(t.recall_interval, 1, 100.0)
        lines.append(
            f"{label:<44}{_pct(t.recall):>8}{recall_interval:>12}"
            f"{_fmt(t.fp_per_frame, 2):>8}{evaluation.interval_text(t.fp_per_frame_interval):>12}"
            f"{_fmt(t.stats.mean):>8}{_fmt(t.mean_crlb_px, 4):>8}"
            f"{_fmt(t.error_over_crlb, 2):>9}{_fmt(t.median_line_error_deg, 2):>7}"
        )
    return "\n".join(lines)


def losses_table(results: Sequence[tuple[str, Row]]) -> str:
    """One line per family: how many markers the reference row missed, by the test that lost them.

    The tests in the order they run (:data:`~marker_localizer.core.symmetry_path.SURVIVOR_TESTS`),
    then those that passed every test but ended off their marker
    (:data:`evaluation.ASTRAY`); each column as wide as its name.
    """
    tests = [*symmetry_path.SURVIVOR_TESTS, evaluation.ASTRAY]
    shown = [t for t in tests if any(row.lost_at[t] for _, row in results)]
    widths = [max(len(t), 8) + 1 for t in shown]
    header = f"{'family':<44}{'missed':>7}" + "".join(
        f"{t:>{w}}" for t, w in zip(shown, widths, strict=True)
    )
    lines = [
        f"Markers {REFERENCE_ROW} missed, by the test after which no candidate was left "
        f"within {evaluation.LOSS_RADIUS_PX:g} px of them",
        header,
        "-" * len(header),
    ]
    for label, row in results:
        missed = row.tally.n_truth - row.tally.n_matched
        lines.append(
            f"{label:<44}{missed:>7}"
            + "".join(f"{row.lost_at[t]:>{w}}" for t, w in zip(shown, widths, strict=True))
        )
    return "\n".join(lines)


def readings_table(results: Sequence[tuple[str, Row]], heading: str) -> str:
    """One line per family: the reference row's markers and false points by the reading adding them.

    The readings in the order they run (:data:`~marker_localizer.core.symmetry_path.READINGS`):
    what each second reading adds, and what it lets in with it. ``heading`` names
    the frames.
    """
    readings = [
        *symmetry_path.READINGS.values(),
        *sorted(
            {k for _, row in results for k in (*row.found_by, *row.false_by)}
            - set(symmetry_path.READINGS.values())
        ),
    ]
    header = f"{'family':<44}" + "".join(f"{name:>14}" for name in readings)
    lines = [
        f"{heading}: markers found / false points of {REFERENCE_ROW}, by the reading that "
        "added them",
        header,
        "-" * len(header),
    ]
    for label, row in results:
        cells = (f"{row.found_by[name]} / {row.false_by[name]}" for name in readings)
        lines.append(f"{label:<44}" + "".join(f"{cell:>14}" for cell in cells))
    return "\n".join(lines)


def wider_range_table(results: Sequence[tuple[str, Row]], heading: str) -> str:
    """One line per family the reference row read at both ranges: item 5's count.

    Markers found at the family's radius range :data:`WIDER_RANGE_FACTOR` wider either
    way and not at its own (item 5 asks for none), and the reverse; the false points
    at each range, for the trade. ``heading`` names the frames.
    """
    header = (
        f"{'family':<44}{'markers':>8}{'found':>7}{'only wider':>12}{'only own':>10}"
        f"{'FP own':>8}{'FP wider':>10}"
    )
    lines = [
        f"{heading}: markers {REFERENCE_ROW} found with each frame's radius range "
        f"{WIDER_RANGE_FACTOR:g} times wider either way (a range still correct) and not "
        "with its own (issue 12, item 5, asks for none), and the reverse; false points at each",
        header,
        "-" * len(header),
    ]
    for label, row in results:
        if row.range_checked:
            lines.append(
                f"{label:<44}{row.tally.n_truth:>8}{row.tally.n_matched:>7}"
                f"{row.found_only_wider:>12}{row.found_only_own:>10}"
                f"{row.tally.n_false_positives:>8}{row.false_wider:>10}"
            )
    return "\n".join(lines)


def _finite_pair(bounds: tuple[float, float]) -> list[float] | None:
    """An interval for JSON: [low, high], or None where it is undefined."""
    return [float(b) for b in bounds] if all(math.isfinite(b) for b in bounds) else None


def row_record(row: Row) -> dict[str, Any]:
    """JSON-ready figures of a row."""
    t, s = row.tally, row.tally.stats
    record: dict[str, Any] = {
        "frames": t.frames,
        "truth": t.n_truth,
        "found": t.n_matched,
        "recall": t.recall,
        "recall_interval": _finite_pair(t.recall_interval),
        "recall_design_effect": t.recall_design_effect,
        "fp_per_frame": None if row.refiner else t.fp_per_frame,
        "fp_per_frame_interval": None if row.refiner else _finite_pair(t.fp_per_frame_interval),
        "fp_dispersion": None if row.refiner else t.fp_dispersion,
        "mean_px": s.mean,
        "rms_px": s.rms,
        "p95_px": s.p95,
        "max_px": s.max,
        "within_0p1": s.within_fine,
        "within_2sigma": t.within_two_sigma,
        "crlb_mean_px": t.mean_crlb_px,
        "error_over_crlb": t.error_over_crlb,
        "median_line_error_deg": t.median_line_error_deg,
        "seconds_per_frame": t.seconds / t.frames if t.frames else None,
    }
    record.update(row.extra)
    if row.lost_at:
        record["lost_at"] = dict(row.lost_at)
    if row.found_by or row.false_by:
        record["found_by"], record["false_by"] = dict(row.found_by), dict(row.false_by)
    if row.range_checked:
        record["found_only_wider_range"] = row.found_only_wider
        record["found_only_own_range"] = row.found_only_own
        record["false_points_wider_range"] = row.false_wider
    return {
        k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in record.items()
    }


# --------------------------------------------------------------------------- driver


@dataclass(frozen=True)
class Options:
    """What one run does (parsed from the command line, or built by tests).

    Attributes:
        frames: frames per rendered family (None: each family's default, or quick count).
        quick: small run (a couple of frames per family, a subset of real images).
        seed: base seed of the rendering and of cornerSubPix's start offsets.
        families: keys of what to run (:data:`FAMILY_KEYS`).
        curvature: include ``candidate_detector="curvature"``.
        data_root: the shared data folder (None: skip the independent and real images).
    """

    frames: int | None = None
    quick: bool = False
    seed: int = 0
    families: tuple[str, ...] = FAMILY_KEYS
    curvature: bool = True
    data_root: Path | None = None


def frames_for(family: Family, options: Options) -> int:
    """Frames to render for a family under these options."""
    if options.frames is not None:
        return options.frames
    return family.quick_frames if options.quick else family.frames


def _families(options: Options) -> list[Family]:
    """The rendered families, and (a) and (b) on real ground where the real frames are."""
    root = options.data_root
    grounds = (
        [real_ground_family(root, key) for key in REAL_GROUND_FAMILIES] if root is not None else []
    )
    return families() + [g for g in grounds if g is not None]


def _detectors(options: Options) -> list[PointDetector]:
    return [*peers.our_variants(options.curvature), *peers.point_detectors()]


def reference_detectors() -> list[PointDetector]:
    """The reference row's detector alone, for the tables no peer's time is spent on."""
    return [d for d in peers.our_variants(False) if d.name == REFERENCE_ROW]


def _reference(rows: Sequence[Row]) -> Row:
    return next(r for r in rows if r.name == REFERENCE_ROW)


def run_synthetic(
    options: Options, report: Callable[[str], None], summary: list[tuple[str, Row]]
) -> dict[str, Any]:
    """Evaluate the rendered families; report each table as it is done.

    Appends (family label, our reference row) to ``summary``.
    """
    detectors = _detectors(options)
    results: dict[str, Any] = {}
    chosen = [f for f in _families(options) if f.key in options.families]
    for key, (drawn, _) in REAL_GROUND_FAMILIES.items():
        if key in options.families and not any(f.key == key for f in chosen):
            report(
                f"Family ({drawn}) on real ground: no real frame without markers found, skipped."
            )
    if chosen:
        report(f"Shared by the {BASE_CONDITIONS}")
    for family in chosen:
        result = evaluate_family(family, frames_for(family, options), options.seed, detectors)
        rows = result.rows
        frames = rows[0].tally.frames
        title = (
            f"Family {family.title}; {frames} frames, {rows[0].tally.n_truth} markers, "
            f"radius range given to every detector {family.radius_range[0]:g}-"
            f"{family.radius_range[1]:g} px"
        )
        report(family_table(title, rows))
        results[family.title] = {r.name: row_record(r) for r in rows}
        summary.append((family.label, _reference(rows)))
        for k, recall_split in enumerate(family.splits):
            split = split_recall(result, recall_split.labels, k)
            heading = f"Family ({family.key}) {recall_split.title} (markers per class)"
            report(split_table(heading, split))
            results[f"{family.title}: {recall_split.title}"] = split.record()
    return results


def run_heldout(options: Options, report: Callable[[str], None]) -> dict[str, Any]:
    """The reference row alone on held-out frames of the rendered families; report the table.

    The family tables' 8-12 frames a family are few for false points: on the 12
    frames of seeds 100-111, 2-3 false points showed on (a), (c) and (d) and 9 on
    (g) (0.17-0.75 a frame) where the tables' frames showed 0-1. So each family of
    the chosen keys is rendered again at seeds no table renders
    (:data:`HELDOUT_SEED_OFFSET`), :data:`HELDOUT_FRAMES` frames of it (``--frames``
    if given, 2 with ``--quick``), and only the reference row reads them (no
    peer's time is spent). The 12 MP variant of (d) is read too: its table's three
    frames are fewer still, and its 400 look-alikes and grounds over 12 MP are
    where one ground photograph can bring hundreds (a lattice of discs: docs/
    accuracy.md, "The coins lattice at the renderer's other scales"). The
    chessboards (e) are left out: their table's eight boards hold 800 corners.
    """
    reference = reference_detectors()
    n_frames = options.frames or (2 if options.quick else HELDOUT_FRAMES)
    first = options.seed * 1000 + HELDOUT_SEED_OFFSET
    rows: list[tuple[str, Row]] = []
    for family in _families(options):
        if family.key not in options.families or family.board_pattern:
            continue
        frames = (
            LabelledFrame.rendered(family.render(first + i), family.radius_range)
            for i in range(n_frames)
        )
        rows.append((family.label, evaluate_frames(frames, options.seed, reference).rows[0]))
    if rows:
        report(
            summary_table(
                rows,
                f"Held-out frames, {REFERENCE_ROW} alone: {n_frames} frames a family of seeds "
                f"{first}-{first + n_frames - 1}, which no table above renders; recall, false "
                "points per frame, mean error (px), mean Cramer-Rao bound (px), their ratio, "
                "median error of the line directions reported (degrees)",
            )
        )
        report(readings_table(rows, "Held-out frames"))
        report(wider_range_table(rows, "Held-out frames"))
    else:
        report(
            "Held-out frames: none, as none of the rendered families they are drawn from "
            "was chosen (--families a,heldout reads (a)'s)."
        )
    return {label: row_record(row) for label, row in rows}


def run_independent(
    options: Options, report: Callable[[str], None], summary: list[tuple[str, Row]]
) -> dict[str, Any]:
    """Evaluate the independent renderer's frames family by family; report each table.

    Appends (family label, our reference row) to ``summary``.
    """
    root = options.data_root
    if root is None or not real_data.has_independent(root):
        report(real_data.absent(real_data.INDEPENDENT_SET, "independent"))
        return {}
    detectors = _detectors(options)
    results: dict[str, Any] = {}
    rendered = {f.key: f for f in families() if f.scene is not None and not f.variant}
    model_frames = X_SNR_MODEL_QUICK_FRAMES if options.quick else X_SNR_MODEL_FRAMES
    for key, description in INDEPENDENT_FAMILIES.items():
        frames = list(real_data.iter_independent(root, 1 if options.quick else None, (key,)))
        if not frames:
            continue
        model = x_snr_model(rendered[key], model_frames)
        result = evaluate_frames(
            (LabelledFrame.independent(f, model) for f in frames), options.seed, detectors
        )
        rows = result.rows
        ranges = sorted({f.radius_range for f in frames})
        title = (
            f"Independent renderer, family ({key}) {description}; {len(frames)} frames, "
            f"{rows[0].tally.n_truth} markers, radius range given to every detector "
            + ", ".join(range_text(r) for r in ranges)
            + " px (truth.json); CRLB: truth.json's"
        )
        report(family_table(title, rows))
        results[f"({key}) {description}"] = {r.name: row_record(r) for r in rows}
        summary.append((f"independent ({key})", _reference(rows)))
        split = split_recall(result, X_SNR_SPLIT.labels)
        report(
            split_table(
                f"Independent renderer, family ({key}) {X_SNR_SPLIT.title}, the SNR from each "
                f"marker's bound and radius (fitted on {model_frames} rendered frames of "
                f"({key}), residual sd {model.residual_sd:.2f} in the log; markers per class)",
                split,
            )
        )
        results[f"({key}) {description}: {X_SNR_SPLIT.title}"] = split.record()
    return results


def run_negatives(options: Options, report: Callable[[str], None]) -> dict[str, Any]:
    """Evaluate the real frames without markers; report the table."""
    root = options.data_root
    if root is None or not (root / "aerial_negatives").is_dir():
        report(real_data.absent("Real aerial frames without markers", "aerial_negatives"))
        return {}
    frames = list(real_data.iter_aerial_negatives(root, 1 if options.quick else None))
    megapixels = sum(f.image.size for f in frames) / 1e6
    shapes = sorted({f"{f.image.shape[1]}x{f.image.shape[0]}" for f in frames})
    return _run_frames_without_markers(
        f"Real aerial frames without markers: aerial_negatives; {len(frames)} frames "
        f"({', '.join(shapes)}, {megapixels:.1f} MP in all); every detection is a false point; "
        f"radius range {range_text(REAL_RADIUS_RANGES['aerial_negatives'])} px",
        frames,
        REAL_RADIUS_RANGES["aerial_negatives"],
        _detectors(options),
        report,
    )


#: The real aerial frames seen from half the height: resized this many times larger
#: (bicubic), so that the ground's texture spans twice the pixels and is a little
#: softer than the photographs' own, as a camera nearer the ground or a lens of twice
#: the focal length with the same optics would see it ...
CLOSER_MAGNIFICATION = 2.0
#: ... with this much read noise added, DN: the resized frame's noise is the
#: photograph's, smoothed; the nearer camera's own pixels add theirs.
CLOSER_READ_NOISE_DN = 2.0


def closer_frames(frames: Iterable[real_data.UasFrame], seed: int) -> Iterator[real_data.UasFrame]:
    """``frames`` seen from half the height (:data:`CLOSER_MAGNIFICATION`); noise from ``seed``."""
    rng = np.random.default_rng([seed, 2])
    for frame in frames:
        grey = _magnified(frame.image)
        noise = rng.normal(0.0, CLOSER_READ_NOISE_DN, grey.shape)
        # The colour planes take the grey's own noise: both show one frame.
        colour = None
        if frame.colour is not None:
            colour = _with_noise(_magnified(frame.colour[..., :3]), noise[..., None])
        yield real_data.UasFrame(frame.name, _with_noise(grey, noise), colour)


def _magnified(image: np.ndarray) -> np.ndarray:
    """``image`` magnified :data:`CLOSER_MAGNIFICATION` times (cubic), float32."""
    magnified: np.ndarray = cv2.resize(
        image.astype(np.float32),
        None,
        fx=CLOSER_MAGNIFICATION,
        fy=CLOSER_MAGNIFICATION,
        interpolation=cv2.INTER_CUBIC,
    )
    return magnified


def _with_noise(image: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """``image`` plus ``noise``, rounded and clipped to 8 bits."""
    return np.clip(np.rint(image + noise), 0, 255).astype(np.uint8)


def run_closer_negatives(options: Options, report: Callable[[str], None]) -> dict[str, Any]:
    """The reference row alone on the real aerial frames seen closer; report the table.

    The aerial frames hold no marker and are 3 of them: a detector's floors may fit
    their ground at the one scale they show it. Seen from half the height, their sand
    spans twice the pixels and is a little softer: what a camera flying lower meets.
    Only the reference row reads them (the peers' points run to tens of thousands a
    frame there too, docs/accuracy-journal.md, "Real sand seen closer, and every X of
    texture's size asked for its plate").
    """
    root = options.data_root
    if root is None or not (root / "aerial_negatives").is_dir():
        return {}
    frames = list(
        closer_frames(
            real_data.iter_aerial_negatives(root, 1 if options.quick else None), options.seed
        )
    )
    megapixels = sum(f.image.size for f in frames) / 1e6
    return _run_frames_without_markers(
        f"The same real aerial frames seen from half the height ({REFERENCE_ROW} alone): "
        f"resized {CLOSER_MAGNIFICATION:g} times (bicubic), {CLOSER_READ_NOISE_DN:g} DN of "
        f"read noise added; {len(frames)} frames, {megapixels:.1f} MP in all; radius "
        f"range {range_text(REAL_RADIUS_RANGES['aerial_negatives'])} px",
        frames,
        REAL_RADIUS_RANGES["aerial_negatives"],
        reference_detectors(),
        report,
    )


def _run_frames_without_markers(
    title: str,
    frames: Sequence[real_data.UasFrame],
    radius_range: RadiusRange,
    detectors: Sequence[PointDetector],
    report: Callable[[str], None],
) -> dict[str, Any]:
    """``detectors`` on ``frames`` (no marker in them): the table reported, its figures."""
    rows = evaluate_negatives(frames, detectors, radius_range)
    report(negatives_table(title, rows))
    figures: dict[str, dict[str, Any]] = {
        r.name: {k: (v if math.isfinite(v) else None) for k, v in r.extra.items()} for r in rows
    }
    for row in rows:
        if row.false_by:
            figures[row.name]["false_by"] = dict(row.false_by)
    return figures


#: The disc lattice: the ``coins`` photograph (coins in rows on a dark cloth) shrunk
#: to this many frame px per photograph px, drawn per frame: the small end of the
#: scales the families draw their ground at, where its coins become a lattice of
#: bright discs 10-18 px apart.
DISC_LATTICE_SCALES = (0.25, 0.45)
#: Its contrast stretched this many times, drawn per frame, before the levels clip:
#: from coins shaded as the photograph has them to flat discs with hard edges
#: (painted studs, lids in rows), whose saddles score higher.
DISC_LATTICE_STRETCH = (1.0, 1.6)
#: Its grey levels (dark cloth, bright coins) and read noise, DN.
DISC_LATTICE_LEVELS = (40.0, 220.0)
DISC_LATTICE_NOISE_DN = 2.0
#: Frames of it in a run, and the radius range the detectors are given (family (a)'s).
#: Its false points come in bursts, by where the photograph is cut and by its scale.
DISC_LATTICE_FRAMES = 12
DISC_LATTICE_RADIUS_RANGE: RadiusRange = (6.0, 40.0)


def disc_lattice_frame(
    seed: int,
    shape: tuple[int, int] = (960, 1280),
    scales: tuple[float, float] = DISC_LATTICE_SCALES,
    stretch: tuple[float, float] = DISC_LATTICE_STRETCH,
) -> real_data.UasFrame:
    """A frame of the disc lattice (:data:`DISC_LATTICE_SCALES`): ground only, no marker.

    The stretch is drawn from a stream of its own: a frame at one stretch is the
    same lattice and noise at any other.
    """
    rng = np.random.default_rng(seed)
    ground = warped_texture("coins", shape, rng, scales)
    gain = np.random.default_rng([seed, 1]).uniform(*stretch)
    share = np.clip(gain * (ground - ground.min()) / max(float(np.ptp(ground)), 1e-9), 0.0, 1.0)
    dark, bright = DISC_LATTICE_LEVELS
    level = dark + (bright - dark) * share
    level += rng.normal(0.0, DISC_LATTICE_NOISE_DN, shape)
    return real_data.UasFrame(
        f"disc lattice {seed}", np.clip(np.round(level), 0, 255).astype(np.uint8)
    )


def run_disc_lattice(options: Options, report: Callable[[str], None]) -> dict[str, Any]:
    """Evaluate the rendered disc lattice without markers; report the table."""
    frames = [
        disc_lattice_frame(options.seed + k)
        for k in range(1 if options.quick else DISC_LATTICE_FRAMES)
    ]
    return _run_frames_without_markers(
        f"Rendered ground without markers: a lattice of bright discs (the coins photograph "
        f"at {DISC_LATTICE_SCALES[0]:g}-{DISC_LATTICE_SCALES[1]:g} px per photograph px, its "
        f"contrast stretched {DISC_LATTICE_STRETCH[0]:g}-{DISC_LATTICE_STRETCH[1]:g} times), "
        f"{len(frames)} frames "
        f"(1280x960); every detection is a false point; radius range "
        f"{range_text(DISC_LATTICE_RADIUS_RANGE)} px",
        frames,
        DISC_LATTICE_RADIUS_RANGE,
        _detectors(options),
        report,
    )


def run_dull(options: Options, report: Callable[[str], None]) -> dict[str, Any]:
    """Markers with a dull quadrant alone, read by ours at each range (:mod:`.dull`); the table.

    A quick run reads one frame a cell of :data:`dull.QUICK_RADII_PX` and
    :data:`dull.QUICK_DULL_FACTORS`.
    """
    detector = reference_detectors()[0]
    if options.quick:
        figures = dull.measure(
            detector, options.seed, 1, dull.QUICK_RADII_PX, dull.QUICK_DULL_FACTORS
        )
    else:
        figures = dull.measure(detector, options.seed)
    report(dull.table(figures))
    return figures


def run_real(options: Options, report: Callable[[str], None]) -> dict[str, Any]:
    """Evaluate the real sets (chessboards, cirn_uas); report each table as it is done."""
    root = options.data_root
    if root is None:
        report(real_data.absent("Real images"))
        return {}
    results: dict[str, Any] = {}
    limit = 1 if options.quick else None
    detectors = _detectors(options)
    board_sets = {
        "validationboof": list(real_data.iter_validationboof(root, limit)),
        "libcbdetect": list(
            real_data.iter_unlabelled_boards(root, "libcbdetect", 2 if options.quick else None)
        ),
        "pycbd": list(real_data.iter_unlabelled_boards(root, "pycbd", limit)),
    }
    for name, images in board_sets.items():
        if not images:
            report(real_data.absent(f"Real chessboards: {name}", name))
            continue
        rows = evaluate_boards(
            images, [*detectors, *_real_board_peers(name)], REAL_RADIUS_RANGES[name]
        )
        rows.append(
            reference_residual_row(
                images,
                "hand clicks (reference)"
                if name == "validationboof"
                else "OpenCV SB boards (reference)",
            )
        )
        n_corners = sum(len(i.reference) for i in images)
        n_boards = sum(len(i.boards) for i in images)
        report(
            boards_table(
                f"Real chessboards: {name}; {len(images)} images, {n_boards} "
                f"boards, {n_corners} reference corners; {_real_note(name)}\n"
                f"{_BOARD_LEGEND}",
                rows,
            )
        )
        results[name] = {r.name: row_record(r) for r in rows}
    frames = list(real_data.iter_cirn_uas(root, limit))
    if frames:
        results.update(run_uas(frames, detectors, report))
    else:
        report(real_data.absent("Real UAV frames: cirn_uas", "cirn_uas"))
    return results


def run_uas(
    frames: Sequence[real_data.UasFrame],
    detectors: Sequence[PointDetector],
    report: Callable[[str], None],
) -> dict[str, Any]:
    """The cirn_uas frames at each of :data:`CIRN_RANGES`: a table and a record each."""
    results: dict[str, Any] = {}
    for key, (radius_range, whose) in CIRN_RANGES.items():
        rows = evaluate_uas(frames, detectors, radius_range)
        report(
            uas_table(
                f"Real UAV frames: cirn_uas; {len(frames)} frames (3840x2160); targets "
                f"found within {real_data.CIRN_FOUND_PX:g} px, FP = farther than "
                f"{real_data.CIRN_FALSE_PX:g} px from both; radius range "
                f"{range_text(radius_range)} px ({whose})",
                rows,
            )
        )
        results[key] = {r.name: row_record(r) for r in rows}
    return results


_BOARD_LEGEND = (
    "recall: reference corners with a detection within 2 px; boards: share with every corner; "
    "T1: deviation from OpenCV's refined corners (paper's Table 1), px;\n"
    "line / spacing: RMS straight-line / projective-spacing residual of the board rows and "
    "columns over their degrees of freedom (n - 2, n - 3 a line: the corners' error per axis), "
    "px;\nlens: RMS residual about each board's homography through OpenCV's lens "
    "distortion (k1-k3, p1, p2; where the board is planar: the corners' error), px;\n"
    "over own corners (pts); "
    "line= / spac= / lens= / pts=: on the corners found by every detector with recall >= "
    f"{COMMON_MIN_RECALL:.0%}"
)


def _real_board_peers(set_name: str) -> list[PointDetector]:
    """Board-model peers for a real set: only where the board size is known (ValidationBoof)."""
    if set_name != "validationboof":
        return []
    return peers.board_detectors(real_data.VALIDATIONBOOF_PATTERN)


def _real_note(set_name: str) -> str:
    radius = f"{range_text(REAL_RADIUS_RANGES[set_name])} px"
    if set_name == "validationboof":
        return (
            f"reference = hand clicks - 0.5 px; radius range {radius}; "
            "mrgingham n/a (square grids only)"
        )
    return (
        f"reference = OpenCV findChessboardCornersSB boards (partial: only what it finds); "
        f"radius range {radius}"
    )


def run(options: Options, report: Callable[[str], None] = print) -> dict[str, Any]:
    """Run the benchmark; every table goes to ``report``; returns the figures for JSON."""
    for line in peers.unavailable_peers():
        report(line)
    results: dict[str, Any] = {"seed": options.seed, "quick": options.quick}
    summary: list[tuple[str, Row]] = []
    results["synthetic"] = run_synthetic(options, report, summary)
    if "dull" in options.families:
        results["dull"] = run_dull(options, report)
    if "heldout" in options.families:
        results["heldout"] = run_heldout(options, report)
    if "independent" in options.families:
        results["independent"] = run_independent(options, report, summary)
    if "real" in options.families:
        results["real"] = run_real(options, report)
    if "negatives" in options.families:
        results["aerial_negatives"] = run_negatives(options, report)
        results["aerial_negatives_closer"] = run_closer_negatives(options, report)
        results["disc_lattice"] = run_disc_lattice(options, report)
    if summary:
        report(summary_table(summary))
        report(losses_table(summary))
        report(readings_table(summary, "Rendered and independent frames"))
        report(wider_range_table(summary, "Rendered and independent frames"))
        results["summary"] = {label: row_record(row) for label, row in summary}
    return results


def parse_args(argv: list[str] | None) -> tuple[Options, Path | None]:
    """Parse the command line into :class:`Options` and the JSON output path."""
    parser = argparse.ArgumentParser(
        allow_abbrev=False,
        prog="marker-localizer bench accuracy",
        description="Accuracy of this detector and its peers on rendered and real images.",
    )
    parser.add_argument(
        "--frames",
        type=count_type,
        default=None,
        help="frames per rendered family (default: per family)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="small run (2-3 minutes on one core of the development host)",
    )
    parser.add_argument(
        "--seed", type=seed_type, default=0, help="base seed (default: %(default)s)"
    )
    parser.add_argument(
        "--families",
        type=comma_keys(FAMILY_KEYS, "families"),
        default=",".join(FAMILY_KEYS),
        help=f"comma-separated subset of {','.join(FAMILY_KEYS)}",
    )
    parser.add_argument(
        "--no-curvature",
        action="store_true",
        help="leave out the paper's curvature screening variant",
    )
    add_json_option(parser)
    args = parser.parse_args(argv)
    options = Options(
        frames=args.frames,
        quick=args.quick,
        seed=args.seed,
        families=args.families,
        curvature=not args.no_curvature,
        data_root=real_data.data_root(),
    )
    return options, args.json


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    options, json_path = parse_args(argv)
    return run_and_save("accuracy benchmark", lambda report: run(options, report), json_path)


if __name__ == "__main__":
    raise SystemExit(main())
