"""Peer detectors behind one small interface, so the benchmarks treat every one alike.

A :class:`PointDetector` has a ``name`` and ``detect(image_u8, radius_range)``
returning (N, 2) float64 points; a :class:`PointRefiner` (``cv2.cornerSubPix``)
has ``refine(image_u8, starts)``. Every peer returns points in this project's
convention, (0, 0) = centre of the top-left pixel; where a peer uses another
one, its adapter converts and says so.

Peers that need an optional package (``chess-corners`` from PyPI, the
``mrgingham`` binary from Debian) are built by :func:`point_detectors` only when
that package is there; :func:`unavailable_peers` names the missing ones with the
reason, which the benchmarks print as "not installed".
"""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from marker_localizer.config import DetectorConfig
from marker_localizer.core.pipeline import Detector
from marker_localizer.core.result import line_directions, positions, sigmas

RadiusRange = tuple[float, float]


def range_text(radius_range: RadiusRange) -> str:
    """A radius range as the benchmarks' tables and JSON keys name it: ``"6-40"``."""
    return f"{radius_range[0]:g}-{radius_range[1]:g}"


#: cornerSubPix stops after this many iterations or when a step is below
#: _SUBPIX_EPS_PX; OpenCV's own samples use (30, 0.001), we iterate a bit longer.
_SUBPIX_MAX_ITER = 40
_SUBPIX_EPS_PX = 1e-3
#: Smallest and largest cornerSubPix half-window, px: below 2 the gradient
#: sums are too few, above 10 the window leaves all but the largest markers.
_SUBPIX_HALF_MIN, _SUBPIX_HALF_MAX = 2, 10


def subpix_half_window(radius_range: RadiusRange) -> int:
    """Half-window of cornerSubPix a user would pick for this marker radius range, px.

    The window must stay inside the smallest marker (past its edge the
    plate-to-ground edges pull the solution), so it is 0.7 of the smallest
    radius, clipped to [2, 10] px.
    """
    half = round(0.7 * radius_range[0])
    return int(np.clip(half, _SUBPIX_HALF_MIN, _SUBPIX_HALF_MAX))


def corner_subpix(image_u8: np.ndarray, starts: np.ndarray, half_window: int) -> np.ndarray:
    """``cv2.cornerSubPix`` on (N, 2) starts; both in pixel-centre coordinates (OpenCV's).

    Args:
        image_u8: (H, W) uint8 image.
        starts: (N, 2) start points, px.
        half_window: half side of the search window, px.

    Returns:
        (N, 2) refined points, px; starts too close to the border come back NaN.
    """
    pts = np.asarray(starts, dtype=np.float32).reshape(-1, 1, 2)
    height, width = image_u8.shape[:2]
    margin = half_window + 1
    inside = (
        (pts[:, 0, 0] >= margin)
        & (pts[:, 0, 0] < width - 1 - margin)
        & (pts[:, 0, 1] >= margin)
        & (pts[:, 0, 1] < height - 1 - margin)
    )
    out = np.full((len(pts), 2), np.nan)
    if not inside.any():
        return out
    criteria = (
        cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER,
        _SUBPIX_MAX_ITER,
        _SUBPIX_EPS_PX,
    )
    refined = cv2.cornerSubPix(
        image_u8, pts[inside].copy(), (half_window, half_window), (-1, -1), criteria
    )
    out[inside] = refined.reshape(-1, 2)
    return out


class PointDetector(Protocol):
    """Something that finds X-corner points in a grey image."""

    name: str

    def detect(self, image_u8: np.ndarray, radius_range: RadiusRange) -> np.ndarray:
        """Return (N, 2) float64 points (x, y), px, pixel-centre convention."""
        ...


class PointRefiner(Protocol):
    """Something that moves coarse start points onto the nearby X-corner."""

    name: str

    def refine(self, image_u8: np.ndarray, starts: np.ndarray) -> np.ndarray:
        """Return (N, 2) refined points (NaN where it failed), px."""
        ...


@dataclass
class CornerSubPixRefiner:
    """``cv2.cornerSubPix`` from given starts: the refinement-only peer.

    Attributes:
        half_window: half side of the window, px (see :func:`subpix_half_window`).
        name: row label in the tables.
    """

    half_window: int
    name: str = "cv2.cornerSubPix"

    def refine(self, image_u8: np.ndarray, starts: np.ndarray) -> np.ndarray:
        """Refine (N, 2) starts, px."""
        return corner_subpix(image_u8, starts, self.half_window)


@dataclass
class OurDetector:
    """This package's detector with a fixed variant, behind the peer interface.

    Attributes:
        name: row label in the tables.
        overrides: DetectorConfig fields other than the radius range.
    """

    name: str
    overrides: dict[str, object]

    def __post_init__(self) -> None:
        self._cache: dict[RadiusRange, Detector] = {}
        self.last_sigmas: np.ndarray = np.empty(0)
        self.last_line_angles: np.ndarray = np.empty((0, 2))
        self.last_timings_ms: dict[str, float] = {}
        self.last_survivors: list[tuple[str, np.ndarray]] = []

    def detector(self, radius_range: RadiusRange) -> Detector:
        """The :class:`Detector` for this radius range (built once, then reused)."""
        if radius_range not in self._cache:
            config = DetectorConfig(
                marker_radius_min_px=float(radius_range[0]),
                marker_radius_max_px=float(radius_range[1]),
            ).replace(**self.overrides)
            self._cache[radius_range] = Detector(config)
        return self._cache[radius_range]

    def detect(
        self,
        image_u8: np.ndarray,
        radius_range: RadiusRange,
        colour: np.ndarray | None = None,
    ) -> np.ndarray:
        """Detect; keeps the last call's sigmas, line directions, timings and survivors.

        ``colour``: the frame's colour planes where ``image_u8`` is their grey, as a
        colour file gives them to ``marker-localizer detect``.
        """
        result = self.detector(radius_range).detect(image_u8, colour=colour)
        self.last_sigmas = sigmas(result)
        self.last_line_angles = line_directions(result)
        self.last_timings_ms = dict(result.timings_ms)
        self.last_survivors = result.survivors
        return positions(result)


#: The paper's pipeline as published: its screening and checks, its sub-pixel location.
PAPER_PIPELINE: dict[str, object] = {"candidate_detector": "curvature", "refinement": "ncc"}
#: Its row in the benchmarks' tables.
PAPER_ROW = "ours (paper: curvature+ncc)"
#: The template fit with the calibrated decision. Its line extents end where the
#: edges fade (:func:`template.line_extents`), short of the annular scan's last ring:
#: at the default fraction 0.7 it loses small tilted markers the scan keeps.
TEMPLATE_DECISION: dict[str, object] = {"refinement": "template", "min_extent_fraction": 0.6}
#: Its row in the benchmarks' tables.
TEMPLATE_ROW = "ours (template decision)"


def our_variants(include_curvature: bool = True) -> list[OurDetector]:
    """The detector variants the benchmarks compare.

    The three refinements on the default screening (``template`` with the extent
    fraction its line extents were measured with, :data:`TEMPLATE_DECISION`), and
    with ``include_curvature`` the
    paper's screening and checks with the default fit, and the paper's pipeline end
    to end (:data:`PAPER_PIPELINE`).
    """
    variants = [
        OurDetector("ours (symmetry)", {"refinement": "symmetry"}),
        OurDetector("ours (ncc, paper)", {"refinement": "ncc"}),
        OurDetector(TEMPLATE_ROW, dict(TEMPLATE_DECISION)),
    ]
    if include_curvature:
        variants.append(OurDetector("ours (curvature)", {"candidate_detector": "curvature"}))
        variants.append(OurDetector(PAPER_ROW, dict(PAPER_PIPELINE)))
    return variants


@dataclass
class HessianSaddleDetector:
    """What a user would write with OpenCV: Hessian-determinant saddles + cornerSubPix.

    The image is smoothed with a Gaussian of ``sigma = clip(0.5 * r_min, 1, 3)`` px
    (resolves the smallest marker, keeps the largest one's saddle), the
    scale-normalised response ``-sigma**4 * det(H)`` is positive at saddles;
    local maxima (non-maximum suppression in a (4 sigma + 1) px square) above a
    threshold are refined with :func:`corner_subpix`. The threshold corresponds to an ideal X of
    ``min_contrast_dn`` contrast: at its centre d2I/dxdy = C / (pi s**2) for a
    checker of contrast C (intensity in [0, 1]) blurred to total sigma s, so the
    normalised response is (C / pi)**2 when the smoothing dominates the blur.

    Attributes:
        min_contrast_dn: contrast of the weakest X to keep, DN. 60: on family (a)
            25 DN keeps ~1500 texture saddles per frame and every marker, 60 keeps
            ~80 and 96 % of the markers, 100 none and 92 %.
        name: row label in the tables.
    """

    min_contrast_dn: float = 60.0
    name: str = "OpenCV Hessian+cornerSubPix"

    def response(self, image_u8: np.ndarray, sigma_px: float) -> np.ndarray:
        """Scale-normalised saddle response -sigma**4 det(H), float32."""
        smooth = cv2.GaussianBlur(image_u8.astype(np.float32) / 255.0, (0, 0), sigma_px)
        # 3x3 Sobel derivatives carry a gain of 4 (smoothing [1, 2, 1] or two [-1, 0, 1]).
        dxx = cv2.Sobel(smooth, cv2.CV_32F, 2, 0, ksize=3, scale=0.25)
        dyy = cv2.Sobel(smooth, cv2.CV_32F, 0, 2, ksize=3, scale=0.25)
        dxy = cv2.Sobel(smooth, cv2.CV_32F, 1, 1, ksize=3, scale=0.25)
        return (sigma_px**4) * (dxy * dxy - dxx * dyy)

    def detect(self, image_u8: np.ndarray, radius_range: RadiusRange) -> np.ndarray:
        """Detect X-corners in an (H, W) uint8 image, px."""
        sigma = float(np.clip(0.5 * radius_range[0], 1.0, 3.0))
        response = self.response(image_u8, sigma)
        nms = 2 * round(2 * sigma) + 1
        peaks = response >= cv2.dilate(response, np.ones((nms, nms), np.uint8))
        threshold = (self.min_contrast_dn / 255.0 / np.pi) ** 2
        rows, cols = np.nonzero(peaks & (response > threshold))
        starts = np.column_stack([cols, rows]).astype(np.float64)
        refined = corner_subpix(image_u8, starts, subpix_half_window(radius_range))
        return refined[np.isfinite(refined).all(axis=1)]


#: ChESS response threshold. The package default (30) suits boards on flat
#: backgrounds; on textured ground it gives thousands of false corners per
#: 1280x960 frame (measured: 3700 at 30, 850 at 100, 4 at 300 with every
#: family (a) marker still found), so the adapter uses 200.
CHESS_THRESHOLD = 200.0


@dataclass
class ChessCornersDetector:
    """The ``chess-corners`` package (ChESS or Radon), configured for the radius range.

    Its points use the pixel-centre convention: checked on rendered boards,
    where the mean offset from the exact truth is below 0.02 px without any shift.
    Single scale (the pyramid variants lost a third of the 6-40 px markers on
    family (a)); markers below 5 px radius get a 2x upscale (the ChESS ring has
    radius 5 px). Radon keeps its default threshold.

    Attributes:
        method: ``"chess"`` or ``"radon"``.
        name: row label in the tables.
    """

    method: str
    name: str = ""

    def __post_init__(self) -> None:
        self.name = self.name or f"chess-corners {self.method}"
        self._cache: dict[RadiusRange, object] = {}

    def _detector(self, radius_range: RadiusRange) -> object:
        import chess_corners  # noqa: PLC0415 - optional peer package

        if radius_range not in self._cache:
            config_class = chess_corners.DetectorConfig
            if self.method == "chess":
                config = config_class.chess().with_threshold(CHESS_THRESHOLD)
            else:
                config = config_class.radon()
            if radius_range[0] < 5.0:
                config = config.with_upscale(chess_corners.UpscaleConfig.fixed(2))
            self._cache[radius_range] = chess_corners.Detector(config)
        return self._cache[radius_range]

    def detect(self, image_u8: np.ndarray, radius_range: RadiusRange) -> np.ndarray:
        """Detect X-corners in an (H, W) uint8 image, px."""
        detector = self._detector(radius_range)
        found = detector.detect(np.ascontiguousarray(image_u8))  # type: ignore[attr-defined]
        return np.asarray(found.xy, dtype=np.float64).reshape(-1, 2)


@dataclass
class OpenCVChessboard:
    """``cv2.findChessboardCorners`` + ``cornerSubPix`` (11x11), for a known pattern.

    Attributes:
        pattern: (columns, rows) of inner corners.
        name: row label in the tables.
    """

    pattern: tuple[int, int]
    name: str = "cv2.findChessboardCorners+cSP"

    def detect(self, image_u8: np.ndarray, radius_range: RadiusRange) -> np.ndarray:
        """Return the board's corners row by row, px (empty when not found)."""
        del radius_range  # the pattern size is this detector's only input
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        found, corners = cv2.findChessboardCorners(image_u8, self.pattern, flags=flags)
        if not found:
            return np.empty((0, 2))
        return corner_subpix(image_u8, corners.reshape(-1, 2), 5)


#: Seed of OpenCV's global random generator before each sector-based board search
#: (``findChessboardCornersSB*`` draws from it): unseeded, the search found 2 or 3
#: boards in pycbd's 3 images from one call to the next, within one process.
SB_RNG_SEED = 0


@dataclass
class OpenCVChessboardSB:
    """``cv2.findChessboardCornersSB`` (sector-based, sub-pixel by itself) for a known pattern.

    Attributes:
        pattern: (columns, rows) of inner corners.
        name: row label in the tables.
    """

    pattern: tuple[int, int]
    name: str = "cv2.findChessboardCornersSB"

    def detect(self, image_u8: np.ndarray, radius_range: RadiusRange) -> np.ndarray:
        """Return the board's corners row by row, px (empty when not found)."""
        del radius_range
        flags = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
        cv2.setRNGSeed(SB_RNG_SEED)
        found, corners = cv2.findChessboardCornersSB(image_u8, self.pattern, flags=flags)
        if not found:
            return np.empty((0, 2))
        return corners.reshape(-1, 2).astype(np.float64)


@dataclass
class Mrgingham:
    """The ``mrgingham`` command-line chessboard detector (square N x N grids only).

    Its output uses the pixel-centre convention (checked on rendered 10x10
    boards: mean offset from the exact truth below 0.02 px without a shift), so
    no conversion is applied.

    Attributes:
        gridn: inner corners per side.
        name: row label in the tables.
    """

    gridn: int = 10
    name: str = "mrgingham"

    def detect(self, image_u8: np.ndarray, radius_range: RadiusRange) -> np.ndarray:
        """Return the board's corners, px (empty when not found)."""
        del radius_range
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / "frame.png"
            cv2.imwrite(str(path), image_u8)
            output = subprocess.run(
                ["mrgingham", "--gridn", str(self.gridn), str(path)],
                capture_output=True,
                text=True,
                check=False,
                timeout=300,
            ).stdout
        return parse_mrgingham(output)


def parse_mrgingham(output: str) -> np.ndarray:
    """Parse mrgingham's vnlog (``filename x y level``) into (N, 2) points, px."""
    rows = []
    for line in output.splitlines():
        fields = line.split()
        if len(fields) < 3 or line.startswith("#") or fields[1] == "-":
            continue
        rows.append((float(fields[1]), float(fields[2])))
    return np.array(rows, dtype=np.float64).reshape(-1, 2)


def chess_corners_available() -> bool:
    """Whether the optional ``chess-corners`` package is importable."""
    return importlib.util.find_spec("chess_corners") is not None


def mrgingham_available() -> bool:
    """Whether the ``mrgingham`` binary is on PATH."""
    return shutil.which("mrgingham") is not None


def point_detectors(min_contrast_dn: float = 60.0) -> list[PointDetector]:
    """Every installed general-purpose peer X-corner detector (no board model)."""
    peers: list[PointDetector] = [HessianSaddleDetector(min_contrast_dn)]
    if chess_corners_available():
        peers += [ChessCornersDetector("chess"), ChessCornersDetector("radon")]
    return peers


def board_detectors(pattern: tuple[int, int]) -> list[PointDetector]:
    """Every installed chessboard detector for a (columns, rows) pattern of inner corners."""
    peers: list[PointDetector] = [OpenCVChessboard(pattern), OpenCVChessboardSB(pattern)]
    if mrgingham_available() and pattern[0] == pattern[1]:
        peers.append(Mrgingham(pattern[0]))
    return peers


def unavailable_peers() -> list[str]:
    """Names of the peers that are not installed, with the install hint."""
    missing = []
    if not chess_corners_available():
        missing.append("chess-corners: not installed (pip install -r requirements-bench.txt)")
    if not mrgingham_available():
        missing.append("mrgingham: not installed (apt-get install mrgingham)")
    return missing
