"""Loading the real image sets of ``<repo>/../shared/data`` and their reference points.

The images are test data, not part of the package: nothing here is copied into
the repository, and :func:`data_root` returns None when the folder is absent (a
user's fresh clone), so callers can skip cleanly.

Coordinates returned here follow the project's convention, (0, 0) = centre of
the top-left pixel; ValidationBoof's hand clicks (origin at the pixel's top-left
corner) are shifted by -0.5 px on load.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from marker_localizer.bench.metrics import line_residuals, order_grid
from marker_localizer.bench.peers import SB_RNG_SEED, corner_subpix
from marker_localizer.config import DetectorConfig
from marker_localizer.core.chroma import is_colour
from marker_localizer.core.image import to_gray
from marker_localizer.errors import ImageError
from marker_localizer.evaluation import DEFAULT_GATE_PX, nearest_distances
from marker_localizer.image_files import read_image_file

#: ValidationBoof boards: 5 x 7 squares, so 4 x 6 inner corners (columns, rows).
VALIDATIONBOOF_PATTERN = (4, 6)
#: ValidationBoof's hand clicks put (0, 0) at the top-left corner of the first pixel.
VALIDATIONBOOF_OFFSET_PX = -0.5
#: The two ground targets of the cirn_uas frames (x, y), px, good to a few pixels.
CIRN_TARGETS = np.array([[2705.0, 2060.0], [3770.0, 1798.0]])
#: A detection within this distance of a target finds it, px.
CIRN_FOUND_PX = 6.0
#: A detection farther than this from both targets is a false positive, px.
CIRN_FALSE_PX = 10.0
#: libcbdetect's e6 and e7 show deltille (triangle) boards: their junctions are
#: six-way, not X-corners, so they are left out of the chessboard sets.
SKIPPED_IMAGES = frozenset({"e6.png", "e7.png"})
#: Largest image side at which OpenCV's board search runs; larger frames are
#: searched downscaled and refined at full resolution (the search is quadratic-ish).
_SEARCH_MAX_SIDE_PX = 1600
#: At most this many boards are searched for per image (the busiest libcbdetect scene has 7).
_MAX_BOARDS = 8
#: Largest RMS straight-line residual of an OpenCV board, as a fraction of its corner
#: spacing, for it to serve as a reference (see :func:`_is_planar_grid`). Measured:
#: sound libcbdetect boards 0.2-1.1 %, pycbd flare 2.8 % (a phone lens over a whole
#: 12 MP board), boards joined across two planes or bent 3.6 % and more.
_MAX_BEND = 0.03


#: The environment variable that names the real data folder, where it is not
#: ``<repo>/../shared/data`` (a copy elsewhere, an installed package).
DATA_ENV = "MARKER_LOCALIZER_DATA"


def data_path(repo_root: Path | None = None) -> Path:
    """Where the real data folder is looked for: ``$MARKER_LOCALIZER_DATA``, or ``../shared/data``.

    The default is beside the repository this module is installed from.

    Args:
        repo_root: repository root; default: the one this module is installed from.
    """
    if os.environ.get(DATA_ENV):
        return Path(os.environ[DATA_ENV])
    root = repo_root or Path(__file__).resolve().parents[2]
    return (root.parent / "shared" / "data").resolve()


def data_root(repo_root: Path | None = None) -> Path | None:
    """The real data folder (:func:`data_path`), or None when it is absent."""
    candidate = data_path(repo_root)
    return candidate if candidate.is_dir() else None


def absent(what: str, folder: str = "") -> str:
    """The line a benchmark prints for a set it skips: its ``folder`` of the data is absent."""
    return f"{what}: {data_path() / folder} not found (set {DATA_ENV} to the data folder), skipped."


def read_gray(path: Path) -> np.ndarray:
    """Read an image file as (H, W) uint8 grey, as ``marker-localizer detect`` reads it.

    The command's own decoding (:func:`~marker_localizer.image_files.read_image_file`:
    pixels in stored order, whatever an EXIF Orientation says) and its reduction to
    grey (:func:`~marker_localizer.core.image.to_gray`: OpenCV's weights on the
    decoded colour), so that the benchmark's figures are the command's. A JPEG
    decoded straight to grey is libjpeg's luma instead, up to 13 levels off on the
    aerial frames.

    Raises:
        ImageError: naming the file: unreadable, not an image, or not 8 bits deep.
    """
    return read_frame(path)[0]


def read_frame(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """The image file's grey (:func:`read_gray`) and, for a colour file, its BGR(A) planes.

    What ``marker-localizer detect`` gives the detector is the colour image: its
    check of small X's drawn in colour (:mod:`~marker_localizer.core.chroma`) reads
    the planes, its stages the grey.

    Raises:
        ImageError: as :func:`read_gray`.
    """
    decoded = read_image_file(path, DetectorConfig().max_pixels)
    grey, _ = to_gray(decoded)
    if grey.dtype != np.uint8:
        raise ImageError(f"{path}: {grey.dtype} pixels; the real sets are 8-bit")
    return grey, decoded if is_colour(decoded) else None


@dataclass(frozen=True)
class BoardImage:
    """A real chessboard image with its reference corners.

    Attributes:
        set_name: ``"validationboof"``, ``"libcbdetect"`` or ``"pycbd"``.
        name: image name within the set (``folder/file``).
        image: (H, W) uint8 grey image.
        boards: one (rows, cols, 2) grid of reference corners per board, px:
            the hand clicks for ValidationBoof, OpenCV's boards for the others.
        opencv: OpenCV's refined corners of every board it finds (the paper's
            Table 1 reference), (N, 2) px.
        colour: the file's BGR(A) planes, None for a grey file (:func:`read_frame`).
    """

    set_name: str
    name: str
    image: np.ndarray
    boards: list[np.ndarray]
    opencv: np.ndarray
    colour: np.ndarray | None = None

    @property
    def reference(self) -> np.ndarray:
        """All reference corners of all boards, (N, 2) px."""
        return _stack(self.boards)


def _stack(grids: list[np.ndarray]) -> np.ndarray:
    """All valid corners of a list of grids as one (N, 2) array, px (NaN nodes left out)."""
    if not grids:
        return np.empty((0, 2))
    points = np.concatenate([g.reshape(-1, 2) for g in grids])
    return points[np.isfinite(points).all(axis=1)]


def load_hand_points(path: Path) -> np.ndarray:
    """Read a ValidationBoof ``.txt`` of hand clicks, converted to the project's convention."""
    return np.loadtxt(path, comments="#", dtype=np.float64).reshape(-1, 2) + (
        VALIDATIONBOOF_OFFSET_PX
    )


def iter_validationboof(root: Path, limit_per_folder: int | None = None) -> Iterator[BoardImage]:
    """ValidationBoof images whose hand clicks form the 4 x 6 grid, folder by folder.

    The reference grid is the hand clicks (good to ~0.2 px), arranged into rows
    and columns by :func:`order_grid`.
    """
    if not (root / "validationboof").is_dir():
        return
    for folder in sorted((root / "validationboof").iterdir()):
        if not folder.is_dir():
            continue
        for path in sorted(folder.glob("*.txt"))[:limit_per_folder]:
            image_path = path.with_suffix(".jpg")
            points = load_hand_points(path)
            grid = order_grid(points, VALIDATIONBOOF_PATTERN)
            if grid is None or not image_path.exists():
                continue
            image, colour = read_frame(image_path)
            yield BoardImage(
                "validationboof",
                f"{folder.name}/{image_path.name}",
                image,
                [grid],
                opencv_pattern_corners(image, VALIDATIONBOOF_PATTERN),
                colour,
            )


def iter_unlabelled_boards(
    root: Path, set_name: str, limit: int | None = None
) -> Iterator[BoardImage]:
    """Images of the libcbdetect or pycbd set, with OpenCV's boards as the reference."""
    if not (root / set_name).is_dir():
        return
    paths = sorted(
        p
        for p in (root / set_name).iterdir()
        if p.suffix.lower() in (".png", ".jpg") and p.name not in SKIPPED_IMAGES
    )
    for path in paths[:limit]:
        image, colour = read_frame(path)
        boards = opencv_boards(image)
        yield BoardImage(set_name, path.name, image, boards, _stack(boards), colour)


def opencv_pattern_corners(image: np.ndarray, pattern: tuple[int, int]) -> np.ndarray:
    """OpenCV's refined corners of a board of known size (the paper's Table 1 reference).

    ``findChessboardCorners`` + ``cornerSubPix`` as the paper did, falling back
    to ``findChessboardCornersSB`` where the classic detector fails.

    Args:
        image: (H, W) uint8 grey image.
        pattern: (columns, rows) of inner corners.

    Returns:
        (N, 2) corners, px; empty when OpenCV finds no board.
    """
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(image, pattern, flags=flags)
    if not found:
        cv2.setRNGSeed(SB_RNG_SEED)
        found, corners = cv2.findChessboardCornersSB(image, pattern, flags=cv2.CALIB_CB_ACCURACY)
    if not found:
        return np.empty((0, 2))
    grid = corners.reshape(pattern[1], pattern[0], 2).astype(np.float64)
    return _refine_grid(image, grid).reshape(-1, 2)


def _refine_grid(image: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Refine a grid with cornerSubPix, window 0.4 of the corner spacing (2 to 5 px)."""
    half = int(np.clip(round(0.4 * _median_spacing(grid)), 2, 5))
    return corner_subpix(image, grid.reshape(-1, 2), half).reshape(grid.shape)


def opencv_boards(image: np.ndarray, max_boards: int = _MAX_BOARDS) -> list[np.ndarray]:
    """Every chessboard OpenCV's sector-based detector finds, as refined grids.

    ``findChessboardCornersSBWithMeta`` with ``CALIB_CB_LARGER`` returns a whole
    board of any size from a 3 x 3 seed; found boards are painted over with
    their mean grey and the search repeats. Corners are refined with
    ``cornerSubPix`` at full resolution (the paper's "OpenCV refined corners").
    Boards that are not planar grids (joined across two boards, or bent) are
    left out. The search draws from OpenCV's random generator, seeded
    (:data:`peers.SB_RNG_SEED`): the reference is the same from run to run.

    Args:
        image: (H, W) uint8 grey image.
        max_boards: most boards to look for.

    Returns:
        (rows, cols, 2) grids, px; empty when OpenCV finds none.
    """
    scale = min(1.0, _SEARCH_MAX_SIDE_PX / max(image.shape))
    search = (
        image
        if scale == 1.0
        else cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    )
    search = search.copy()
    flags = cv2.CALIB_CB_LARGER | cv2.CALIB_CB_ACCURACY
    boards: list[np.ndarray] = []
    cv2.setRNGSeed(SB_RNG_SEED)
    for _ in range(max_boards):
        found, corners, meta = cv2.findChessboardCornersSBWithMeta(search, (3, 3), flags)
        if not found:
            break
        rows, cols = meta.shape
        small = corners.reshape(rows, cols, 2).astype(np.float64)
        _paint_over(search, small)
        # Pixel-centre convention: x_full + 0.5 = (x_small + 0.5) / scale.
        grid = _refine_grid(image, (small + 0.5) / scale - 0.5)
        if _is_planar_grid(grid) and not _repeats_a_board(grid, boards):
            boards.append(grid)
    return boards


def _repeats_a_board(grid: np.ndarray, boards: list[np.ndarray]) -> bool:
    """Whether most corners of ``grid`` coincide (within 2 px) with an already found board's.

    Painting over a found board leaves its margin, where the search can find
    part of the same board again.
    """
    if not boards:
        return False
    points = grid.reshape(-1, 2)
    near = nearest_distances(points, _stack(boards)) <= DEFAULT_GATE_PX
    return bool(near.mean() > 0.5)


def _is_planar_grid(grid: np.ndarray) -> bool:
    """Whether a found grid's rows and columns are straight to :data:`_MAX_BEND` of its spacing.

    ``CALIB_CB_LARGER`` sometimes joins two boards that meet at an edge (libcbdetect
    e2), and pycbd's warped board is physically bent: neither is a reference
    for corner precision. Lens distortion over a whole 12 MP board (pycbd flare)
    stays below 3 % of the spacing.
    """
    # The plain RMS, uncorrected for the lines' fitted parameters: the bend measured
    # to set _MAX_BEND.
    residuals = line_residuals(grid)
    return bool(residuals.straight_plain_rms_px <= _MAX_BEND * _median_spacing(grid))


def _median_spacing(grid: np.ndarray) -> float:
    """Median distance between neighbouring corners of a grid, px."""
    steps = np.concatenate(
        [
            np.linalg.norm(np.diff(grid, axis=0), axis=2).ravel(),
            np.linalg.norm(np.diff(grid, axis=1), axis=2).ravel(),
        ]
    )
    return float(np.nanmedian(steps))


def _paint_over(image: np.ndarray, grid: np.ndarray) -> None:
    """Fill a found board (its corners' hull, grown by one square) with flat grey, in place."""
    pts = grid.reshape(-1, 2)
    centre = pts.mean(axis=0)
    spacing = _median_spacing(grid)
    hull = cv2.convexHull(pts.astype(np.float32)).reshape(-1, 2)
    direction = hull - centre
    norm = np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-9)
    grown = hull + 1.5 * spacing * direction / norm
    mask = np.zeros(image.shape, np.uint8)
    cv2.fillConvexPoly(mask, np.round(grown).astype(np.int32), 255)
    image[mask > 0] = int(image[mask > 0].mean()) if (mask > 0).any() else 128


#: A board's area reaches this many squares beyond its outer corners: its outer
#: squares (one) and its white margin.
BOARD_MARGIN_SQUARES = 1.5
#: Vertices of the polygon that stands for the circle of the area's growth: its
#: chords stay within 2 % of the margin.
_MARGIN_VERTICES = 16


def board_mask(shape: tuple[int, ...], grid: np.ndarray) -> np.ndarray:
    """(H, W) bool: a board's area, its corners' hull grown by :data:`BOARD_MARGIN_SQUARES`.

    The growth is the same distance in every direction (the hull's Minkowski sum
    with a disc), so the outer squares are inside along every side.
    """
    pts = grid.reshape(-1, 2)
    pts = pts[np.isfinite(pts).all(axis=1)]
    margin = BOARD_MARGIN_SQUARES * _median_spacing(grid)
    turn = np.linspace(0.0, 2.0 * np.pi, _MARGIN_VERTICES, endpoint=False)
    disc = margin * np.stack([np.cos(turn), np.sin(turn)], axis=1)
    grown = cv2.convexHull((pts[:, None, :] + disc[None]).reshape(-1, 2).astype(np.float32))
    mask = np.zeros(shape[:2], np.uint8)
    cv2.fillConvexPoly(mask, np.round(grown.reshape(-1, 2)).astype(np.int32), 255)
    return mask > 0


@dataclass(frozen=True)
class UasFrame:
    """One real aerial frame (cirn_uas, aerial_negatives).

    Attributes:
        name: file name.
        image: (H, W) uint8 grey image.
        colour: its BGR(A) planes, None for a grey file (:func:`read_frame`).
    """

    name: str
    image: np.ndarray
    colour: np.ndarray | None = None


def iter_cirn_uas(root: Path, limit: int | None = None) -> Iterator[UasFrame]:
    """The cirn_uas frames (3840 x 2160 JPEG, two ground targets each)."""
    for path in sorted((root / "cirn_uas").glob("*.jpg"))[:limit]:
        yield UasFrame(path.name, *read_frame(path))


@dataclass(frozen=True)
class IndependentFrame:
    """One frame of the independent renderer (``independent/``), with its exact truth.

    Attributes:
        name: file name.
        family: the family key (``a``, ``b``, ``c``, ``d``, ``g``).
        image: (H, W) uint8 grey image.
        truth: (N, 2) marker centres, px (this project's convention).
        crlb_px: (N,) each marker's Cramer-Rao bound as the expected |error|, px.
        radius_range: (min, max) marker radius a user would give, px.
        radius_px: (N,) each marker's radius, px (centre to the end of its X).
    """

    name: str
    family: str
    image: np.ndarray
    truth: np.ndarray
    crlb_px: np.ndarray
    radius_range: tuple[float, float]
    radius_px: np.ndarray


#: What a benchmark's line (:func:`absent`) names when the independent renderer's
#: frames are absent.
INDEPENDENT_SET = "Independent renderer (its independent/ folder)"


def has_independent(root: Path | None) -> bool:
    """Whether the data folder ``root`` holds the independent renderer's frames."""
    return root is not None and (root / "independent" / "truth.json").is_file()


def iter_independent(
    root: Path, limit_per_family: int | None = None, families: tuple[str, ...] | None = None
) -> Iterator[IndependentFrame]:
    """The independent renderer's frames in file-name order, as ``truth.json`` describes them.

    Args:
        root: the shared data folder.
        limit_per_family: at most this many frames of each family; None: all.
        families: family keys to read; None: every one.
    """
    folder = root / "independent"
    truth = json.loads((folder / "truth.json").read_text())
    taken: dict[str, int] = {}
    for name in sorted(truth):
        record = truth[name]
        family = str(record["family"])
        if families is not None and family not in families:
            continue
        if limit_per_family is not None and taken.get(family, 0) >= limit_per_family:
            continue
        taken[family] = taken.get(family, 0) + 1
        markers = record["markers"]
        low, high = record["radius_range_px"]
        yield IndependentFrame(
            name,
            family,
            read_gray(folder / name),
            np.array([(m["x"], m["y"]) for m in markers], dtype=np.float64).reshape(-1, 2),
            np.array([m["crlb_mean_abs_error_px"] for m in markers], dtype=np.float64),
            (float(low), float(high)),
            np.array([m["radius_px"] for m in markers], dtype=np.float64),
        )


def iter_aerial_negatives(root: Path, limit: int | None = None) -> Iterator[UasFrame]:
    """The aerial frames without any marker (3264 x 2448 JPEG): every detection is false."""
    for path in sorted((root / "aerial_negatives").glob("*.jpg"))[:limit]:
        yield UasFrame(path.name, *read_frame(path))
