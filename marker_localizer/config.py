"""The detector's one typed configuration, shared by the library, CLI, node and replay.

Every field carries its unit, range and the reason for its default in the
field's metadata; the ROS node generates its parameter descriptors from it and
the CLI parses ``--param key=value`` against it, so nothing is written twice.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import numbers
import re
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeVar, get_args, overload

import numpy as np

from marker_localizer.core.chroma import CHROMA_MIN_EXTENT_PX
from marker_localizer.core.preprocessing import MAX_SHADOW_GAIN
from marker_localizer.core.screening import EXPECTED_BLUR_PX
from marker_localizer.core.verification import (
    EQUALISED_MIN_EXTENT_PX,
    SMALL_EXTENT_MAX_RADIUS_PX,
    TEMPLATE_MIN_RADIUS_PX,
    TEMPLATE_RADIUS_FRACTION,
    TEXTURE_EXTENT_PX,
    TEXTURE_SCORE_FLOORS,
)
from marker_localizer.errors import ConfigError, missing_dependency, shorten

#: How candidates are found and checked (``candidate_detector``).
CandidateDetector = Literal["saddle", "curvature"]
#: How candidates are located and accepted (``refinement``).
Refinement = Literal["symmetry", "ncc", "template"]
#: The value type of each field annotation a configuration uses: a choice's
#: ``Literal`` alias takes a string.
_VALUE_TYPES: dict[str, type] = {
    "float": float,
    "int": int,
    "str": str,
    "bool": bool,
    "CandidateDetector": str,
    "Refinement": str,
}
#: White in the 8-bit grey levels ``min_contrast_dn`` is given in.
WHITE_DN = 255.0


@dataclass(frozen=True)
class ParamSpec:
    """What a user needs to know to set one configuration field."""

    description: str
    unit: str = ""
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] = ()

    def range_text(self) -> str:
        """``[low, high]``, each in full (``1073741824``, not ``1.07374e+09``); "" if unbounded."""
        if self.low is None or self.high is None:
            return ""
        return f"[{self.low:.{_RANGE_DIGITS}g}, {self.high:.{_RANGE_DIGITS}g}]"


#: Significant digits of a range's bounds as errors and the parameter file write them:
#: enough for 2**30, where ``:g``'s six round it.
_RANGE_DIGITS = 12


def _param(
    default: Any,
    description: str,
    unit: str = "",
    low: float | None = None,
    high: float | None = None,
    choices: tuple[str, ...] = (),
) -> Any:
    spec = ParamSpec(description=description, unit=unit, low=low, high=high, choices=choices)
    return field(default=default, metadata={"spec": spec})


def check_names(names: Iterable[Any], kind: type) -> None:
    """Refuse setting names that the configuration class ``kind`` has no field for.

    A name within a typo of a field's is answered with that field's name.

    Raises:
        ConfigError: ``unknown parameter(s): a, b`` with a ``did you mean`` for each
            close name, the same whether a config is built, replaced or read from a
            mapping.
    """
    known = [f.name for f in dataclasses.fields(kind)]
    unknown = sorted({str(name) for name in names} - set(known))
    if unknown:
        raise ConfigError(f"unknown parameter(s): {', '.join(guessed(n, known) for n in unknown)}")


def guessed(name: str, known: Iterable[str], prefix: str = "") -> str:
    """``name``, followed by the setting it is likely a typo of, where one is close.

    Args:
        name: the unknown name.
        known: the names it may be a typo of, without ``prefix``.
        prefix: the namespace both are under (``detector.``), which is no likeness.
    """
    close = difflib.get_close_matches(name.removeprefix(prefix), list(known), n=1)
    return f"{name} (did you mean {prefix}{close[0]}?)" if close else name


_Dataclass = TypeVar("_Dataclass")


def refuses_unknown_names(kind: type[_Dataclass]) -> type[_Dataclass]:
    """Make the dataclass ``kind``'s constructor refuse an unknown name as :class:`ConfigError`.

    The generated ``__init__`` raises a bare ``TypeError`` for one
    (``DetectorConfig(**values)`` with a misspelt key of a YAML file), where
    ``replace`` and :func:`from_mapping` raise :class:`ConfigError`: now each gives
    :func:`check_names`' error. The signature seen by ``help`` and IDEs is the
    generated one; a call of the wrong shape (too many positional values, a name
    given twice) is still the ``TypeError`` of any Python call.
    """
    generated = kind.__init__

    def checked_init(self: object, *args: Any, **values: Any) -> None:
        check_names(values, kind)
        generated(self, *args, **values)

    functools.update_wrapper(checked_init, generated)
    kind.__init__ = checked_init  # type: ignore[method-assign]
    return kind


#: What the default path's score gates say of the other paths, which do not read them.
_NOT_READ_BY_TEMPLATE_OR_PAPER = (
    "Not read by refinement='template' (its one decision) nor on the paper's path as "
    "published (candidate_detector='curvature' with refinement='ncc')."
)


@refuses_unknown_names
@dataclass(frozen=True)
class DetectorConfig:
    """Detector settings; validated on construction (raises :class:`ConfigError`).

    A name that is not a field's, a value of the wrong type or out of its range
    raises the same :class:`ConfigError` (a ``ValueError``) from the constructor,
    :meth:`replace` and :func:`from_mapping`.

    Only the expected marker radius range depends on the mission; every other
    default was chosen on the package's renderer (see README, "Parameters").
    """

    marker_radius_min_px: float = _param(
        4.0,
        "Smallest expected marker radius in the image (centre to the outer edge of the "
        "X). Below ~4 px a marker on textured ground looks like the ground's own "
        "saddles (stones meeting): set it lower only for markers that small (the "
        "detector resolves 2.5 px), and expect more false points on clutter.",
        unit="px",
        low=1.5,
        high=1000.0,
    )
    marker_radius_max_px: float = _param(
        40.0,
        "Largest expected marker radius in the image. Bounds the refinement "
        "window and the coarsest screening scale.",
        "px",
        1.5,
        1000.0,
    )
    bit_depth: int = _param(
        16,
        "Significant bits of a 16-bit image's pixels: white is 2**bit_depth - 1, so the "
        "grey-level thresholds mean the same for a 10-, 12- or 14-bit sensor in 16-bit "
        "words, from frame to frame. 16 = the whole word (ROS mono16). 8-bit images are "
        "white at 255 whatever this says.",
        "bit",
        8,
        16,
    )

    # Section 3.1: preprocessing.
    gdwgif_radius_px: int = _param(
        2,
        "Paper path (candidate_detector=curvature): window radius r of the gradient-domain "
        "weighted guided filter, Eq. (1): "
        "2 smooths sensor noise without merging the quadrants of a 3 px marker.",
        "px",
        1,
        8,
    )
    gdwgif_lambda: float = _param(
        0.01,
        "Paper path: regularisation lambda of Eq. (1) on intensities scaled to [0, 1]: "
        "flattens noise of a few DN while edges above ~25 DN survive.",
        "",
        1e-6,
        1.0,
    )
    gamma_alpha: float = _param(
        2.0,
        "Scale alpha of the dynamic gamma, Eq. (2): gamma = alpha * local mean; "
        "2 leaves mid-grey (mean 0.5) unchanged.",
        "",
        0.1,
        10.0,
    )
    illumination_window_px: int = _param(
        65,
        "Side of the box that measures the local mean luminance of Eq. (2). Near a "
        "marker's centre, where the checks and the fit read, a box of any size averages "
        "its four quadrants alike, so a marker does not correct itself; 65 px holds a "
        "marker of radius 32 px whole.",
        "px",
        3,
        1001,
    )
    structure_xi: float = _param(
        0.04,
        "Paper path: scale xi of the structural component map, Eq. (3), in normalised "
        "intensity: a local std of 0.04 (10 DN) maps to s = 0.63.",
        "",
        1e-3,
        1.0,
    )
    structure_t: float = _param(
        1.5,
        "Paper path: exponent t of Eq. (3); t > 1 sharpens the response to edges "
        "and suppresses flat noisy ground.",
        "",
        0.1,
        5.0,
    )
    structure_keep_fraction: float = _param(
        0.7,
        "Paper path: candidates are kept only where the structure map is in this top "
        "fraction of its values (the paper's 70 %).",
        "",
        0.05,
        1.0,
    )

    # Section 3.2: multi-layer point screening.
    candidate_detector: CandidateDetector = _param(
        "saddle",
        "How candidates are found and checked: 'curvature' is the paper's section 3.2 "
        "as published (contour curvature Eq. 4, density mean shift, grid-entropy "
        "thinning, the annular check by edge phase and polarity, LSD); 'saddle' is a "
        "Hessian saddle response on a pyramid with the grey-level symmetry checks.",
        choices=get_args(CandidateDetector),
    )
    saddle_threshold: float = _param(
        1.5,
        "Saddle screening keeps Hessian saddles stronger than this multiple of what an "
        f"X of contrast min_contrast_dn blurred by {EXPECTED_BLUR_PX:g} px gives. On the "
        "renderer every "
        "marker scored above 2.3 (3-5 px markers) and 3.2 (6-40 px, motion blur).",
        low=0.05,
        high=20.0,
    )
    curvature_threshold_std: float = _param(
        3.0,
        "Paper path: dual threshold of the curvature screening: a peak must exceed the mean "
        "by this many standard deviations (the paper's 3) of the curvature along the "
        "frame's edges.",
        "std",
        0.0,
        10.0,
    )
    min_peak_separation_px: float = _param(
        5.0,
        "Minimum distance between two candidate peaks on the paper's path (the paper's "
        "5 px). On the saddle path, detections closer than half of it are one marker, "
        "and a tracking pass skips the candidates this close to a marker it knows.",
        "px",
        1.0,
        100.0,
    )
    density_sigma_px: float = _param(
        2.0,
        "Paper path: Gaussian width sigma of the curvature-weighted density field, Eq. (5).",
        "px",
        0.5,
        50.0,
    )
    mean_shift_h_px: float = _param(
        2.0,
        "Paper path: attenuation h of the curvature-density mean shift, Eq. (6).",
        "px",
        0.5,
        50.0,
    )
    entropy_cell_px: int = _param(
        64, "Grid cell size of the spatial grid entropy, Eq. (7).", "px", 8, 4096
    )
    max_candidates_per_cell: int = _param(
        48,
        "Saddle path: greedy entropy thinning (Eq. 7) keeps at most this many candidates per "
        "entropy_cell_px cell, the strongest: clutter crowds a cell with hundreds of "
        "saddles, a distant chessboard (11 px squares) puts about 30 corners in it "
        "(12 lost a fifth of those corners on the real boards).",
        low=1,
        high=100000,
    )
    entropy_threshold: float = _param(
        0.95,
        "Paper path: the greedy grid-entropy thinning (Eq. 7) removes the weakest point "
        "of the most crowded entropy_cell_px cell until the grid entropy reaches this "
        "fraction of ln K (K occupied cells; ln K is their entropy when evenly filled). "
        "The candidates of the rendered and independent frames spread with 0.95-0.99 "
        "already, so 0.95 trims only cells that clutter crowds; 0.98 lost markers.",
        "",
        0.0,
        1.0,
    )
    symmetry_min: float = _param(
        0.8,
        "Minimum centre-symmetry score in [0, 1] of the annular scan: the "
        "correlation of the ring profile with itself shifted by 180 degrees.",
        "",
        0.0,
        1.0,
    )
    min_contrast_dn: float = _param(
        20.0,
        "Minimum grey-level difference between the bright and the dark quadrants "
        "(after gamma). Printed black/white markers keep 30 DN even in shadow; ground "
        "texture saddles mostly stay below 20 DN. The raw-level floors (screening, "
        "prescreen, fit, line detection) follow the light down where the local mean is "
        "too dark for a marker of min_modulation to reach it (under 33 DN at the "
        f"defaults), at most {MAX_SHADOW_GAIN:g}-fold. From 1 DN, a grey level: the "
        "screening measures each "
        "saddle against the response of an X of this contrast.",
        unit="DN",
        low=1.0,
        high=255.0,
    )
    min_modulation: float = _param(
        0.3,
        "Minimum modulation (bright - dark) / (bright + dark) of the raw sector grey "
        "levels, which illumination does not change. Printed black and white give "
        "0.7-0.8, partly shadowed markers on the renderer kept 0.31 and more, "
        "ground-texture saddles (gravel gaps) stayed below 0.38 and mostly below 0.3. "
        f"Tested on X's under {EQUALISED_MIN_EXTENT_PX:g} px only (texture's reach): dim "
        "real boards give 0.18, the faintest rendered markers 0.21.",
        low=0.0,
        high=1.0,
    )
    min_extent_fraction: float = _param(
        0.7,
        "The X must extend from the centre to at least this fraction of "
        "marker_radius_min_px in the annular scan: small texture saddles stop short, a "
        "marker tilted by 60 degrees still reaches 0.7 of its radius.",
        low=0.0,
        high=2.0,
    )
    template_ncc_min: float = _param(
        0.95,
        "Minimum NCC between the image and the adaptive template (the blurred X with the "
        f"measured line angles) over a disk of {TEMPLATE_RADIUS_FRACTION:g} of the X's extent "
        f"(at least {TEMPLATE_MIN_RADIUS_PX:g} px).",
        low=0.0,
        high=1.0,
    )
    min_score: float = _param(
        0.80,
        "Minimum detection score (ring symmetry x template NCC x (1 - relative symmetry "
        "residual)) of a marker wider than ground texture's saddles (extent "
        f"{TEXTURE_EXTENT_PX:g} px and more); smaller ones need at least "
        f"{TEXTURE_SCORE_FLOORS[1][1]:g} (under {TEXTURE_SCORE_FLOORS[0][0]:g} px: "
        f"{TEXTURE_SCORE_FLOORS[0][1]:g}), where the best texture saddles score 0.87-0.93. "
        "Real chessboard corners under lens blur score 0.80-1.0. " + _NOT_READ_BY_TEMPLATE_OR_PAPER,
        low=0.0,
        high=1.0,
    )
    min_score_small: float = _param(
        0.945,
        "Minimum score of a detection whose X extends no further than "
        f"marker_radius_min_px, nor than {SMALL_EXTENT_MAX_RADIUS_PX:g} px (texture's size, "
        "so that a tighter range "
        "never asks more of a marker): the regime of ground-texture saddles "
        "(stones meeting). "
        "On the simulated flights those scored up to 0.944 and markers of that extent "
        "0.946 and more (a thin margin: see the README). " + _NOT_READ_BY_TEMPLATE_OR_PAPER,
        low=0.0,
        high=1.0,
    )
    max_symmetry_residual: float = _param(
        0.1,
        "Largest RMS point-symmetry residual of the final fit, as a fraction of the "
        "marker contrast: markers stay below 0.03 with 4 DN noise, clutter rarely "
        "below 0.1. " + _NOT_READ_BY_TEMPLATE_OR_PAPER,
        low=0.0,
        high=1.0,
    )
    line_check: bool = _param(
        True, "Require the LSD double-line intersection of section 3.2 near the candidate."
    )
    line_extend_px: float = _param(
        5.0, "Delta s of Eq. (9): segments are extended by this much at both ends.", "px", 0.0, 50.0
    )
    line_max_distance_px: float = _param(
        2.0,
        "Largest distance between the extended lines' intersection and the candidate "
        "(LSD stops short of a blurred centre; lines extrapolated from there cross up to "
        "~2 px from it on rendered markers).",
        "px",
        0.1,
        20.0,
    )
    lattice_check: bool = _param(
        True,
        "refinement='symmetry': reject a detection whose X recurs on both sides of it, as "
        "the saddles between discs, studs or lids in rows do, unless its lines go on as a "
        "chessboard's. Markers laid out in rows are then found from 3.5 radii apart "
        "(centre to centre); turn it off for a tighter target array.",
    )
    max_x_chroma_share: float = _param(
        0.33,
        "On a colour frame, reject an X of texture's size (extent from "
        f"{CHROMA_MIN_EXTENT_PX:g} to under {TEXTURE_EXTENT_PX:g} px) whose chromatic "
        "contrast, read at a colour sensor's colour resolution, exceeds this share of its "
        "luminance contrast: a marker's paint is black and white, ground texture's X's "
        "are of coloured materials. Real black-and-white chessboards photographed in "
        "colour read at most 0.24, a neutral X through a JPEG under a light 1.9 times "
        "redder than blue about 0.23, small rendered markers through a camera's "
        "demosaicing, uncompressed, up to 0.28. Grey frames are not asked; the largest "
        "value turns the check off.",
        "",
        0.0,
        100.0,
    )

    # Section 3.3: sub-pixel location.
    refinement: Refinement = _param(
        "symmetry",
        "'ncc' is the paper's adaptive template + NCC + quadratic surface "
        "(Eqs. 10-14); 'symmetry' continues from it with a least-squares "
        "point-symmetry fit over the whole marker, unbiased by blur and gamma; "
        "'template' fits the blurred X with per-quadrant levels, its two lines and a "
        "shadow edge (Eq. 10 made a model) and replaces the prescreen, checks and gates "
        "by the sector order and one decision calibrated to false_points_per_mp: it "
        "keeps markers with a dull quadrant or a shadow edge, at several times the time.",
        choices=get_args(Refinement),
    )
    false_points_per_mp: float = _param(
        0.025,
        "refinement='template': the decision's threshold gives this many false points "
        "per megapixel on real ground without markers (measured on "
        "../shared/data/aerial_negatives by 'marker-localizer bench calibrate'). 0.025 "
        "is 0.2 per 8 MP aerial frame, the false-point budget of a pose estimator's "
        "outlier rejection.",
        "1/MP",
        0.0001,
        10.0,
    )
    template_offset_px: float = _param(
        5.0,
        "Distance along the bisectors at which the template's grey levels are "
        "sampled with 3x3 windows (the paper's 5 px; capped by the marker radius).",
        "px",
        1.0,
        50.0,
    )
    ncc_search_px: int = _param(
        2,
        "refinement='ncc': half-size of the NCC search window around the coarse position.",
        "px",
        1,
        10,
    )
    refinement_max_iterations: int = _param(
        12, "Gauss-Newton iterations of the symmetry fit; it converges in 3-5.", "", 1, 100
    )
    max_candidates: int = _param(
        20000,
        "Cap on candidates per frame after screening; the weakest over their light (the "
        "saddle response weighed by the local mean, as a print's contrast scales with the "
        "light on it) are cut and counted, which bounds the time of a frame full of clutter.",
        "",
        1,
        10_000_000,
    )
    max_pixels: int = _param(
        50_000_000,
        "CLI, node and replay: the largest image, width x height, accepted; the CLI reads "
        "it from the file's header before decoding. 50 MP is 4x the rig's 12 MP cameras, "
        "while a 0.9 MB PNG can claim 30000x30000 (900 MP, 12 GB to decode). OpenCV "
        "refuses to decode more than 2^30 pixels whatever this says.",
        "px",
        1,
        2**30,
    )

    def __post_init__(self) -> None:
        check_fields(self)
        if self.marker_radius_min_px > self.marker_radius_max_px:
            raise ConfigError(
                f"marker_radius_min_px={self.marker_radius_min_px} is larger than "
                f"marker_radius_max_px={self.marker_radius_max_px}"
            )

    @property
    def merge_radius_px(self) -> float:
        """Detections closer than this to a stronger one are its duplicates, px.

        Half of ``min_peak_separation_px``: the last suppression of every pass.
        """
        return self.min_peak_separation_px / 2.0

    @property
    def min_contrast_share(self) -> float:
        """``min_contrast_dn`` as a share of white.

        A threshold in an image's own grey levels is this times its white
        (``full_scale``).
        """
        return self.min_contrast_dn / WHITE_DN

    def replace(self, **changes: Any) -> DetectorConfig:
        """Return a validated copy with ``changes`` applied (unknown keys raise)."""
        return from_mapping(changes, base=self)


@refuses_unknown_names
@dataclass(frozen=True)
class TrackerConfig:
    """Tracking-mode settings (:class:`~marker_localizer.core.tracking.MarkerTracker`).

    Validated on construction (raises :class:`ConfigError`, as
    :class:`DetectorConfig`). The node and replay declare them as ``tracker.*``
    parameters.
    """

    enabled: bool = _param(
        True,
        "Node and replay: between full-frame passes, confirm the markers of the previous "
        "frames by the sub-pixel fit where the measured image motion puts them, and "
        "search the frame border for new ones (MarkerTracker). A lost marker triggers a "
        "full-frame pass on the same frame.",
    )
    full_frame_every: int = _param(
        10,
        "A full-frame pass at least every this many frames of a camera: 5 s at the rig's "
        "2 Hz, short enough to pick up markers that appear inside the frame (e.g. "
        "uncovered), not only across its border.",
        low=1,
        high=10000,
    )
    max_motion_px: float = _param(
        64.0,
        "Largest error of a constant-velocity prediction (the image motion between two "
        "frames that the velocity does not foresee): how far an anchor's patch is searched "
        "for (anchors lie this far plus their patch inside the frame, or in its central "
        "half where this exceeds a quarter frame), and how far a full pass's detection may "
        "lie from a track it continues. 64 px is a jolt of ~1 degree of attitude on the "
        "rig's 12 MP cameras.",
        "px",
        1.0,
        1000.0,
    )
    match_px: float = _param(
        1.5,
        "Largest error of a position mapped by the measured motion: a marker is confirmed "
        "by a detection this close to it, and the border is searched on the sides whose "
        "content may have moved inward by this much. The markers' homography maps them to "
        "a few tenths of a pixel; 1.5 px leaves room for a marker's own fit.",
        "px",
        0.1,
        50.0,
    )
    max_missed_frames: int = _param(
        2,
        "Consecutive frames a track whose marker is in view but rejected by the detector "
        "(one at the acceptance threshold) is still searched for before it is dropped: a "
        "marker that flickers at the threshold is found again when it comes back.",
        low=0,
        high=1000,
    )

    def __post_init__(self) -> None:
        check_fields(self)

    def replace(self, **changes: Any) -> TrackerConfig:
        """Return a validated copy with ``changes`` applied (unknown keys raise)."""
        return from_mapping(changes, base=self)


def param_specs(
    kind: type[DetectorConfig] | type[TrackerConfig] = DetectorConfig,
) -> dict[str, tuple[dataclasses.Field[Any], ParamSpec]]:
    """Return every field of ``kind`` with its :class:`ParamSpec`, in declaration order."""
    return {f.name: (f, f.metadata["spec"]) for f in dataclasses.fields(kind)}


def field_kind(f: dataclasses.Field[Any]) -> str:
    """The name of a configuration field's value type (``float``, ``str``, ``tuple[str, ...]``).

    A choice's ``Literal`` alias (:data:`CandidateDetector`, :data:`Refinement`)
    names ``str``: its values are strings, checked against the field's choices.
    """
    name = str(f.type)
    return _VALUE_TYPES[name].__name__ if name in _VALUE_TYPES else name


def require_config(config: object, kind: type, taker: str) -> None:
    """Refuse a ``config`` that is not a ``kind`` instance, for ``taker`` (who would read it).

    A mapping of settings or the class itself would otherwise be read as the
    defaults, or fail later on its first missing attribute.

    Raises:
        TypeError: naming ``taker`` and ``kind``, with how to build one from a mapping.
    """
    if not isinstance(config, kind):
        hint = f" ({kind.__name__}(**values) builds one)" if isinstance(config, Mapping) else ""
        raise TypeError(f"{taker} takes a {kind.__name__} instance, not {config!r:.80}{hint}")


def check_fields(config: Any) -> None:
    """Validate every field of a frozen configuration, each stored as its plain Python value.

    Its fields carry their :class:`ParamSpec` in ``metadata["spec"]``
    (:class:`DetectorConfig`, :class:`TrackerConfig`, the node's ``NodeConfig``).

    Raises:
        ConfigError: as :func:`checked_value`, for the first field that fails.
    """
    for f in dataclasses.fields(config):
        value = checked_value(f.name, field_kind(f), f.metadata["spec"], getattr(config, f.name))
        object.__setattr__(config, f.name, value)


def _as_kind(value: Any, kind: str) -> Any:
    """``value`` as a ``kind`` (:func:`field_kind`'s names), or None where it is not one.

    Numbers computed with numpy (``np.float32(6.0)``, ``np.int64(12)``) are numbers
    too; a bool is not a number here, nor a float an int; a sequence of strings is a
    ``tuple[str, ...]`` (ROS gives a list), a string is not.
    """
    if kind == "tuple[str, ...]":
        strings = isinstance(value, list | tuple) and all(isinstance(v, str) for v in value)
        return tuple(value) if strings else None
    if kind == "bool":
        return bool(value) if isinstance(value, bool | np.bool_) else None
    if isinstance(value, bool | np.bool_):
        return None
    if kind == "float":
        return float(value) if isinstance(value, numbers.Real) else None
    if kind == "int":
        return int(value) if isinstance(value, numbers.Integral) else None
    return value if isinstance(value, _VALUE_TYPES[kind]) else None


#: How errors name a value type whose Python name would puzzle a user (a ROS string array).
_KIND_TEXT = {"tuple[str, ...]": "list of strings"}


def checked_value(name: str, kind: str, spec: ParamSpec, value: Any) -> Any:
    """``value`` of setting ``name`` as its plain Python type, once its type and range hold.

    Args:
        name: the setting's name, as the error names it.
        kind: its type's name (:func:`field_kind`).
        spec: its range and choices.
        value: the value given.

    Raises:
        ConfigError: ``value`` is not of ``kind``, not one of the choices, or out of range.
    """
    checked = _as_kind(value, kind)
    if spec.choices and checked not in spec.choices:
        raise ConfigError(f"{name}={value!r} must be one of {', '.join(spec.choices)}")
    bounds = spec.range_text()
    allowed = f"{bounds} {spec.unit}".rstrip() if bounds else ""
    if checked is None:
        within = f" in {allowed}" if allowed else ""
        raise ConfigError(f"{name}={value!r} must be of type {_KIND_TEXT.get(kind, kind)}{within}")
    if spec.low is not None and spec.high is not None and not spec.low <= checked <= spec.high:
        raise ConfigError(f"{name}={checked!r} is outside {allowed}")
    return checked


def parse_value(name: str, text: str) -> Any:
    """The value ``text`` (``--param k=v``) spells, read as a parameters file reads it.

    A YAML scalar (:func:`_yaml_scalar`): ``--param`` and ``--params-file`` take and
    refuse the same spellings (``true``, ``6``, ``1e-6``), and the error names the
    setting's type, range and unit.

    Raises:
        ConfigError: an unknown name, or a value its setting refuses.
    """
    check_names([name], DetectorConfig)
    return _checked_setting(name, _yaml_scalar(text))


def _checked_setting(name: str, value: Any) -> Any:
    """:func:`checked_value` of the detector setting ``name`` (a known one)."""
    field, spec = param_specs()[name]
    return checked_value(name, field_kind(field), spec, value)


def _yaml() -> Any:
    """PyYAML, or the one line saying how to install it."""
    try:
        import yaml  # noqa: PLC0415 - only the parameters' text needs PyYAML
    except ModuleNotFoundError as err:
        raise missing_dependency(err) from err
    return yaml


#: The plain scalars ROS's parameter parser (rcl_yaml_param_parser, ``get_value``) reads
#: as booleans: YAML 1.1's words and the one-letter ``y`` and ``n``, each in three cases.
_RCL_TRUE, _RCL_FALSE = (
    frozenset(f(word) for word in words for f in (str.lower, str.capitalize, str.upper))
    for words in (("y", "yes", "true", "on"), ("n", "no", "false", "off"))
)
#: An integer as the parser's ``strtol(text, 0)`` reads it whole: decimal, ``0x`` hex or
#: ``0`` octal, no ``_`` between digits (YAML 1.1's ``50_000_000`` is a string there).
_RCL_INT = re.compile(r"[-+]?(?:0[xX][0-9a-fA-F]+|0[0-7]*|[1-9][0-9]*)")
#: A float as its ``strtod`` reads it whole: decimal with or without a point or an
#: exponent (``1e-6``, ``08``), ``inf``/``infinity``/``nan`` in any case and YAML's
#: ``.inf``/``.nan``; hexadecimal floats (``0x1p4``) are read by :func:`float.fromhex`.
_RCL_FLOAT = re.compile(r"[-+]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|inf(?:inity)?|nan)", re.I)
_RCL_HEX_FLOAT = re.compile(
    r"[-+]?0[xX](?:[0-9a-fA-F]+\.?[0-9a-fA-F]*|\.[0-9a-fA-F]+)(?:[pP][-+]?\d+)?"
)
#: YAML's spellings of infinity and NaN, which the parser reads before ``strtod``.
_RCL_YAML_FLOATS = frozenset(
    f"{sign}.{word}" for sign in ("", "+", "-") for word in ("inf", "Inf", "INF")
) | frozenset({".nan", ".NaN", ".NAN"})
#: The int64 a parameter holds: ``strtol`` overflows beyond it, and the text is read as a float.
_INT64_MIN, _INT64_MAX = -(2**63), 2**63 - 1
#: The tag this module's loader gives every scalar without one of its own (see
#: :func:`rcl_scalar`): YAML's own resolution (PyYAML's 1.1) reads many otherwise.
_RCL_SCALAR_TAG = "tag:marker_localizer,2026:rcl-scalar"
_YAML_STR_TAG = "tag:yaml.org,2002:str"


def rcl_scalar(text: str) -> bool | int | float | str:
    """The value an unquoted scalar ``text`` of a ROS 2 parameters file gives the node.

    As rcl_yaml_param_parser reads it (``get_value``): a boolean word (``y``, ``on``,
    ``false``), then a whole integer (``strtol``; ``0x10``, ``017``), then a whole float
    (``strtod``; ``1e-6``, ``inf``), else the text itself. YAML 1.1's other forms are
    strings to it: ``50_000_000``, ``1:30``, ``0b101``, ``null``, ``~``, ``2001-12-14``.
    A quoted scalar, or one tagged ``!!str``, is a string (not read here).
    """
    if text in _RCL_TRUE:
        return True
    if text in _RCL_FALSE:
        return False
    if _RCL_INT.fullmatch(text):
        digits = text.lstrip("+-")
        base = 16 if digits[:2] in ("0x", "0X") else 8 if digits[:1] == "0" else 10
        integer = int(text, base)
        if _INT64_MIN <= integer <= _INT64_MAX:  # beyond, strtol overflows and strtod reads it
            return integer
    if text in _RCL_YAML_FLOATS:
        return float(text.replace(".", ""))
    if _RCL_FLOAT.fullmatch(text) or _RCL_HEX_FLOAT.fullmatch(text):
        number = float(text) if _RCL_FLOAT.fullmatch(text) else float.fromhex(text)
        # strtod overflows (1e999) to an error, and the parser keeps the text.
        if not math.isinf(number) or "inf" in text.lower():
            return number
    return text


@functools.cache
def _ros_yaml_loader() -> type:
    """PyYAML's safe loader reading scalars and keys as ROS's parameters file does.

    Every scalar without a tag of its own goes to :func:`rcl_scalar` unless quoted
    (YAML 1.1's resolution would read ``y`` as a string and ``50_000_000`` as an int,
    where the node reads a bool and a string), a key is its text (``on:`` names a
    parameter ``on``), and an alias (``*name``) is refused, as the node refuses it.
    """
    yaml = _yaml()
    safe = yaml.SafeLoader

    def resolve(loader: Any, kind: Any, value: str, implicit: tuple[bool, bool]) -> str:
        if kind is yaml.ScalarNode:
            return _RCL_SCALAR_TAG
        return str(safe.resolve(loader, kind, value, implicit))

    def compose_node(loader: Any, parent: Any, index: Any) -> Any:
        if loader.check_event(yaml.AliasEvent):
            mark = loader.peek_event().start_mark
            problem = "an alias (*name), which ROS's parser refuses"
            raise yaml.composer.ComposerError(None, None, problem, mark)
        return safe.compose_node(loader, parent, index)

    def construct_mapping(loader: Any, node: Any, deep: bool = False) -> dict[Any, Any]:
        for key, _ in node.value:
            if isinstance(key, yaml.ScalarNode) and key.tag == _RCL_SCALAR_TAG:
                key.tag = _YAML_STR_TAG
        return dict(safe.construct_mapping(loader, node, deep=deep))

    def construct_rcl_scalar(loader: Any, node: Any) -> Any:
        text = loader.construct_scalar(node)
        return text if node.style in ("'", '"') else rcl_scalar(text)

    # A subclass of its own: the constructor would otherwise join every SafeLoader's.
    methods = {
        "resolve": resolve,
        "compose_node": compose_node,
        "construct_mapping": construct_mapping,
    }
    loader: type = type("RosYamlLoader", (safe,), methods)
    loader.add_constructor(_RCL_SCALAR_TAG, construct_rcl_scalar)  # type: ignore[attr-defined]
    return loader


def _yaml_scalar(text: str) -> Any:
    """The value a parameters file's scalar ``text`` gives: a bool, int, float or string."""
    yaml = _yaml()
    try:
        return yaml.load(text, _ros_yaml_loader())
    except yaml.YAMLError:
        return text


def _load_ros_yaml(text: str, path: str | Path) -> Any:
    """The document of a parameters file's ``text``, read as the node reads it.

    Raises:
        ConfigError: a value left empty (``key:`` with nothing after it), anywhere in
            the file, named with its line: the node refuses the whole file for it
            (rcl: "No value at line N").
        yaml.YAMLError: the text is not YAML.
    """
    loader = _ros_yaml_loader()(text)
    try:
        root = loader.get_single_node()
        if root is None:
            return None
        for name, line in _empty_values(root):
            # A parameter by the name the node gives it (detector.min_contrast_dn).
            named = name.partition("ros__parameters.")[2] or name
            raise ConfigError(
                f"{path}: line {line}: {named} has no value (give one, or delete the line)"
            )
        return loader.construct_document(root)
    finally:
        loader.dispose()


def _empty_values(node: Any, name: str = "") -> Iterator[tuple[str, int]]:
    """(name, line) of each unquoted scalar left empty under ``node``, named by its keys' path.

    The path from the file's top, keys joined by dots, a list item by its index:
    ``/**.ros__parameters.detector.min_contrast_dn``, ``other.ros__parameters.cameras[1]``.
    """
    yaml = _yaml()
    if isinstance(node, yaml.ScalarNode):
        if node.style is None and node.value == "":
            yield name, node.start_mark.line + 1
    elif isinstance(node, yaml.SequenceNode):
        for index, item in enumerate(node.value):
            yield from _empty_values(item, f"{name}[{index}]")
    elif isinstance(node, yaml.MappingNode):
        for key, value in node.value:
            text = str(key.value) if isinstance(key, yaml.ScalarNode) else "?"
            yield from _empty_values(value, f"{name}.{text}" if name else text)


_Config = TypeVar("_Config", DetectorConfig, TrackerConfig)


@overload
def from_mapping(values: Mapping[str, Any], base: None = None) -> DetectorConfig: ...
@overload
def from_mapping(values: Mapping[str, Any], base: _Config) -> _Config: ...
def from_mapping(
    values: Mapping[str, Any], base: DetectorConfig | TrackerConfig | None = None
) -> DetectorConfig | TrackerConfig:
    """Build a validated config from ``values`` over ``base`` (detector defaults if None).

    An unknown name is refused by the constructor :func:`dataclasses.replace` calls
    (:func:`refuses_unknown_names`).
    """
    return dataclasses.replace(base or DetectorConfig(), **values)


#: The node's name: its parameters' entry in a ROS 2 parameters file, which the
#: command line reads too (:func:`load_params_file`).
NODE_NAME = "marker_localizer"
DETECTOR_NAMESPACE = "detector"
TRACKER_NAMESPACE = "tracker"


def load_params_file(
    path: str | Path, node_name: str = NODE_NAME, namespace: str = DETECTOR_NAMESPACE
) -> dict[str, Any]:
    """Read the ``<namespace>.*`` parameters (``detector.*`` by default) of a ROS 2 YAML file.

    The file has the node's layout (``node_name: ros__parameters: detector: {...}``),
    beside other nodes' entries as a launch file's parameters have them. Every entry
    that names the node applies, as the node reads the file: ``node_name`` (bare,
    ``/node_name`` or ``/**/node_name``) and the wildcard ``/**``, a later entry's
    values over an earlier one's; where none names it, the file's only entry,
    whatever its name. Scalars are read as ROS reads them (``1e-6`` is a float).
    """
    yaml = _yaml()
    try:
        document = _load_ros_yaml(Path(path).read_text(encoding="utf-8"), path)
    except OSError as err:
        raise ConfigError(f"{path}: cannot read parameters file ({err.strerror})") from err
    except UnicodeDecodeError as err:
        # ROS reads parameter files as UTF-8 too.
        raise ConfigError(f"{path}: not valid YAML (not UTF-8 text)") from err
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = getattr(err, "problem", None) or " ".join(str(err).split())
        raise ConfigError(f"{path}: not valid YAML ({where}{problem})") from err
    if not isinstance(document, dict):
        raise ConfigError(f"{path}: expected a mapping of node names to ros__parameters")
    names = {node_name, f"/{node_name}", f"/**/{node_name}", "/**", "**"}
    entries = [e for key, e in document.items() if key in names and _holds_parameters(e)]
    if not entries and len(document) == 1:
        entries = [e for e in document.values() if _holds_parameters(e)]
    if not entries:
        raise ConfigError(f"{path}: no ros__parameters for node {node_name!r} or '/**'")
    prefix = f"{namespace}."
    values: dict[str, Any] = {}
    for entry in entries:
        flat = _flatten(entry["ros__parameters"] or {}, path)
        if namespace in flat:  # the node refuses a value for the section itself too
            raise ConfigError(
                f"{path}: ros__parameters.{namespace} must be a mapping of parameters,"
                f" got {shorten(repr(flat[namespace]))}"
            )
        values.update({k[len(prefix) :]: v for k, v in flat.items() if k.startswith(prefix)})
    return values


def _holds_parameters(entry: Any) -> bool:
    """Whether a parameters file's entry is a node's: a mapping with ``ros__parameters``."""
    return isinstance(entry, dict) and "ros__parameters" in entry


def detector_config(params_file: str | Path | None, overrides: Sequence[str]) -> DetectorConfig:
    """The detector's config from a node parameter YAML, then ``key=value`` overrides.

    What the command line's ``--params-file`` and ``--param`` give (``detect``,
    ``replay``): the file's ``detector.*`` values, each override (in the detector's
    own names) over them, validated together.

    Raises:
        ConfigError: an unreadable file, an override not of the form ``key=value``,
            an unknown name or a value outside its range.
    """
    values: dict[str, Any] = {}
    if params_file:
        values.update(load_params_file(params_file))
        # Each value on its own here, named with its file; the settings together (a
        # minimum radius over the maximum) once the overrides are in, as the node does.
        try:
            check_names(values, DetectorConfig)
            for name, value in values.items():
                _checked_setting(name, value)
        except ConfigError as err:
            raise ConfigError(f"{params_file} ({DETECTOR_NAMESPACE}): {err}") from err
    for item in overrides:
        key, sep, text = item.partition("=")
        name = key.strip()
        if not sep or not name:
            raise ConfigError(f"--param expects key=value, got {item!r}")
        if name.startswith(f"{TRACKER_NAMESPACE}."):
            raise ConfigError(
                f"--param {name}: tracking settings are read from --params-file "
                f"(its {TRACKER_NAMESPACE}: section), not --param"
            )
        values[name] = parse_value(name, text)
    try:
        return from_mapping(values)
    except ConfigError as err:
        if not params_file:
            raise
        given = " and --param" if overrides else ""
        raise ConfigError(f"{params_file} ({DETECTOR_NAMESPACE}){given}: {err}") from err


def tracker_config(params_file: str | Path | None) -> TrackerConfig:
    """The tracker's config from a node parameter YAML's ``tracker.*`` values (``replay``).

    Raises:
        ConfigError: an unreadable file, an unknown name or a value outside its range.
    """
    if not params_file:
        return TrackerConfig()
    values = load_params_file(params_file, namespace=TRACKER_NAMESPACE)
    return _from_params_file(params_file, TRACKER_NAMESPACE, values, TrackerConfig())


def _from_params_file(
    path: str | Path, namespace: str, values: Mapping[str, Any], base: _Config
) -> _Config:
    """``values`` of a file's ``namespace`` section over ``base``; an error names both."""
    try:
        return from_mapping(values, base=base)
    except ConfigError as err:
        raise ConfigError(f"{path} ({namespace}): {err}") from err


def _flatten(params: Any, path: str | Path, prefix: str = "") -> dict[str, Any]:
    """Nested keys read as ROS reads them: ``{detector: {a: 1}}`` and ``detector.a: 1`` alike."""
    if not isinstance(params, dict):
        where = f"ros__parameters.{prefix.rstrip('.')}" if prefix else "ros__parameters"
        raise ConfigError(f"{path}: {where} must be a mapping")
    flat: dict[str, Any] = {}
    for key, value in params.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(_flatten(value, path, f"{name}."))
        else:
            flat[name] = value
    return flat
