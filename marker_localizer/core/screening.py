"""Section 3.2 of the paper, first layers: candidate points and their suppression.

Two candidate generators share one output type:

* :func:`curvature_candidates`, the paper's contour-curvature corners (Eq. 4)
  with the dual threshold and the structural percentile;
* :func:`saddle_candidates`, a scale-normalised Hessian saddle response on an
  image pyramid, which keeps 3 px markers whose quadrants merge when binarised.

Both feed :func:`density_mean_shift` (Eqs. 5-6) and :func:`grid_entropy_thinning`
(Eq. 7). Coordinates are full-resolution pixels, (0, 0) at the centre of the
top-left pixel.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np
from scipy.spatial import cKDTree

from marker_localizer.core.preprocessing import box_mean


class Candidates(NamedTuple):
    """Candidate marker centres.

    Attributes:
        xy: (N, 2) float64 positions (x, y) in pixels.
        strength: (N,) float64 response, larger is more marker-like.
        scale_px: (N,) float64 characteristic radius at which the point responded.
    """

    xy: np.ndarray
    strength: np.ndarray
    scale_px: np.ndarray

    @classmethod
    def empty(cls) -> Candidates:
        """Return a set of zero candidates."""
        return cls(np.zeros((0, 2)), np.zeros(0), np.zeros(0))

    @classmethod
    def concat(cls, parts: list[Candidates]) -> Candidates:
        """Join several candidate sets into one."""
        if not parts:
            return cls.empty()
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in cls._fields))

    def take(self, index: np.ndarray) -> Candidates:
        """Return the candidates selected by a boolean mask or index array."""
        return Candidates(self.xy[index], self.strength[index], self.scale_px[index])

    def __len__(self) -> int:
        return int(self.strength.shape[0])


def parabolic_offset(minus: np.ndarray, centre: np.ndarray, plus: np.ndarray) -> np.ndarray:
    """Sub-sample vertex of a parabola through three samples, clipped to half a sample."""
    curvature = minus - 2.0 * centre + plus
    with np.errstate(divide="ignore", invalid="ignore"):
        offset = np.where(curvature < 0, 0.5 * (minus - plus) / curvature, 0.0)
    return np.clip(offset, -0.5, 0.5)


#: Gain of OpenCV's 5x5 Sobel second-derivative kernels (f_xx, f_yy, f_xy alike):
#: [1 0 -2 0 1] (4 f'') times the [1 4 6 4 1] smoothing (16).
_SOBEL5_GAIN = 64.0
#: Saddle strength of a blurred X per unit contrast: f_xy = C / (pi sigma_t^2) at
#: its centre, sigma_t^2 = 1 px^2 (the 5x5 kernel's smoothing) + sigma_b^2 (the blur).
_SADDLE_PER_CONTRAST = 1.0 / np.pi
#: The optics blur the markers are expected to carry (full-resolution px): at level L
#: it is 2**L times smaller, so the expected response grows with the level.
_EXPECTED_BLUR_PX = 1.5


#: Farthest apart two saddle peaks of a split response may be, in units of the level's
#: candidate scale: a 6 px marker tilted 48 degrees shows its peaks 10.6 px apart at
#: scale 6; 2.5 scales keeps the like of it at every first level.
_SPLIT_PEAK_DISTANCE = 2.5
#: Largest strength ratio of such a pair: the two peaks of a point-symmetric response
#: are equal but for noise.
_SPLIT_PEAK_RATIO = 1.5


#: Smallest half-width (level px) of a foreshortened marker at the first level searched:
#: below ~1.5 px the 5x5 Sobel kernels' smoothing mixes the quadrants with the plate.
MIN_LEVEL_RADIUS_PX = 1.5


def saddle_response(image: np.ndarray) -> np.ndarray:
    """Squared saddle strength f_xy^2 - f_xx f_yy (= -det H) from 5x5 Sobel derivatives.

    The 5x5 Sobel kernels smooth with a binomial of variance 1 px^2, so no
    separate Gaussian pass is needed. The response is in the image's own grey
    units per px^2 (times the kernels' gain), so a threshold in DN of contrast
    applies directly, with no per-pixel normalisation pass.

    Args:
        image: (H, W) uint8, uint16 or float32 image.

    Returns:
        (H, W) float32 response, positive at saddles (squared grey units).
    """
    dxx = cv2.Sobel(image, cv2.CV_32F, 2, 0, ksize=5)
    dyy = cv2.Sobel(image, cv2.CV_32F, 0, 2, ksize=5)
    dxy = cv2.Sobel(image, cv2.CV_32F, 1, 1, ksize=5)
    # In place with OpenCV: numpy temporaries would double the passes over 12 MP.
    cv2.multiply(dxx, dyy, dst=dxx)
    cv2.multiply(dxy, dxy, dst=dxy)
    cv2.subtract(dxy, dxx, dst=dxy)
    return dxy


def _sparse_maxima(response: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of 3x3 local maxima above ``threshold``, away from the border.

    Only pixels above the threshold (a small share of a frame) are compared with
    their eight neighbours, instead of dilating the whole frame.
    """
    height, width = response.shape
    flat_index = np.flatnonzero(response > threshold)
    rows, cols = np.divmod(flat_index, width)
    inner = (rows > 0) & (rows < height - 1) & (cols > 0) & (cols < width - 1)
    flat_index, rows, cols = flat_index[inner], rows[inner], cols[inner]
    flat = response.reshape(-1)
    centre = flat[flat_index]
    is_max = np.ones(len(flat_index), dtype=bool)
    for offset in (-width - 1, -width, -width + 1, -1, 1, width - 1, width, width + 1):
        neighbour = flat[flat_index + offset]
        # Ties go to the first pixel in raster order, so a plateau yields one peak.
        is_max &= (centre > neighbour) | ((centre == neighbour) & (offset > 0))
    return rows[is_max], cols[is_max]


def split_peak_midpoints(candidates: Candidates, max_distance_px: float,
                         max_ratio: float = _SPLIT_PEAK_RATIO) -> Candidates:
    """Midpoints of candidate pairs that may be the two halves of one split saddle peak.

    A marker narrower than the Sobel kernels' smoothing (a tilted marker near the
    smallest expected radius) gives no saddle at its centre: the response peaks
    on either side of it instead. The response of a point-symmetric pattern is
    point-symmetric too, so such peaks come in pairs of equal strength about the
    centre, and their midpoint is a candidate there (the prescreen and the
    centring that follow decide as for any other).

    Args:
        candidates: one level's candidates.
        max_distance_px: farthest apart two peaks of a pair may be.
        max_ratio: largest ratio of their strengths.

    Returns:
        One candidate per pair, with the weaker strength and the first's scale.
    """
    if len(candidates) < 2:
        return Candidates.empty()
    pairs = cKDTree(candidates.xy).query_pairs(max_distance_px, output_type="ndarray")
    if len(pairs) == 0:
        return Candidates.empty()
    first, second = candidates.strength[pairs[:, 0]], candidates.strength[pairs[:, 1]]
    alike = np.maximum(first, second) <= max_ratio * np.minimum(first, second)
    i, j = pairs[alike, 0], pairs[alike, 1]
    return Candidates(
        0.5 * (candidates.xy[i] + candidates.xy[j]),
        np.minimum(candidates.strength[i], candidates.strength[j]),
        candidates.scale_px[i],
    )


def saddle_levels(radius_range_px: tuple[float, float]) -> range:
    """Pyramid levels searched for markers of the given radius range.

    Level L (image reduced by 2**L) answers best to markers of radius ~2-6 px at
    that level (2**L * (2..6) px in the frame). The first level is the coarsest
    at which the smallest marker, foreshortened to half its radius by a 60-degree
    tilt, still spans :data:`MIN_LEVEL_RADIUS_PX`, so only frames of markers
    under ~6 px are searched at full resolution (the other levels together cost
    a third of that one). At least two levels are searched: a response peaking
    between two levels, as chessboard corners crowded by their neighbours do,
    is then seen at the finer one.
    """
    r_min, r_max = radius_range_px
    foreshortened = 0.5 * r_min
    last = max(0, int(np.ceil(np.log2(max(r_max, 1.0) / 6.0))))
    first = max(0, int(np.floor(np.log2(max(foreshortened, 1.0) / MIN_LEVEL_RADIUS_PX))))
    return range(min(first, max(last - 1, 0)), last + 1)


#: Level pixels a peak must lie inside a cropped response for it to equal the whole
#: image's: the 5x5 kernels' reach (2), the 3x3 maximum and the parabola (1 more).
_RESPONSE_REACH_PX = 3


def _level_window(
    window: tuple[int, int, int, int] | None, level: int, shape: tuple[int, ...]
) -> tuple[int, int, int, int]:
    """(u0, v0, u1, v1): the part of a level's image whose response finds ``window``'s peaks.

    Full-resolution x maps to level u = (x + 0.5) / 2**L - 0.5; the window is grown
    by the filters' reach, and one more pixel than that lets a peak on the edge of
    the crop be compared with its neighbours.
    """
    height, width = shape[:2]
    if window is None:
        return 0, 0, width, height
    x0, y0, x1, y1 = window
    scale = 2.0**level
    grow = _RESPONSE_REACH_PX + 1
    u0 = max(int(np.floor((x0 + 0.5) / scale - 0.5)) - grow, 0)
    v0 = max(int(np.floor((y0 + 0.5) / scale - 0.5)) - grow, 0)
    u1 = min(int(np.ceil((x1 + 0.5) / scale - 0.5)) + grow + 1, width)
    v1 = min(int(np.ceil((y1 + 0.5) / scale - 0.5)) + grow + 1, height)
    return u0, v0, max(u1, u0), max(v1, v0)


def candidate_scale(level: int, radius_range_px: tuple[float, float]) -> float:
    """``scale_px`` of the candidates found at pyramid ``level``: 4 * 2**L px.

    The first level searched also holds markers smaller than its typical radius,
    down to the smallest expected: their centre checks must fit inside them.
    """
    scale = 4.0 * 2**level
    if level == saddle_levels(radius_range_px).start:
        scale = min(scale, max(radius_range_px[0], 4.0))
    return scale


def saddle_candidates(
    image: np.ndarray,
    radius_range_px: tuple[float, float],
    min_contrast: float,
    *,
    relative_threshold: float = 1.5,
    window: tuple[int, int, int, int] | None = None,
) -> Candidates:
    """Saddle points over an image pyramid covering the expected marker radii.

    A peak is kept when its response exceeds ``relative_threshold`` times what an
    X of contrast ``min_contrast`` blurred by 1.5 px would give at that level, so
    the threshold follows the user's contrast in grey levels. Peaks are refined to
    sub-sample precision with a parabola per axis. At the first level, the
    midpoints of peak pairs that may be one split peak join them
    (:func:`split_peak_midpoints`).

    Args:
        image: (H, W) grey image, native dtype (uint8, uint16 or float32).
        radius_range_px: (min, max) expected marker radius in the frame.
        min_contrast: smallest marker contrast, in the image's grey units.
        relative_threshold: fraction of that expected response kept (tilt, motion
            and perspective weaken real markers further).
        window: (x0, y0, x1, y1), image pixels: only the peaks inside are wanted.
            Each level's response is then computed over the window and the reach
            of its filters alone (the pyramid still reduces the whole image, so
            every level keeps the full-image grid); the peaks inside are those of
            the whole image, and some just outside come too.

    Returns:
        Candidates in full-resolution coordinates; ``scale_px`` is 4 * 2**L and
        ``strength`` the response relative to the expected one.
    """
    levels = saddle_levels(radius_range_px)
    parts = []
    level_image = image
    for level in range(levels.stop):
        if level > 0:
            height, width = level_image.shape
            if min(height, width) < 32:
                break
            # An even crop makes INTER_AREA average exact 2 x 2 blocks; from an odd
            # size it would stretch the grid, and windows would see other pixels than
            # the full frame does.
            level_image = cv2.resize(
                level_image[: height - height % 2, : width - width % 2],
                (width // 2, height // 2),
                interpolation=cv2.INTER_AREA,
            )
        if level < levels.start:
            continue
        blur_sq = (_EXPECTED_BLUR_PX / 2**level) ** 2
        expected = _SOBEL5_GAIN * _SADDLE_PER_CONTRAST * min_contrast / (1.0 + blur_sq)
        threshold = relative_threshold * expected
        u0, v0, u1, v1 = _level_window(window, level, level_image.shape)
        response = saddle_response(level_image[v0:v1, u0:u1])
        rows, cols = _sparse_maxima(response, threshold**2)
        dx = parabolic_offset(
            response[rows, cols - 1], response[rows, cols], response[rows, cols + 1]
        )
        dy = parabolic_offset(
            response[rows - 1, cols], response[rows, cols], response[rows + 1, cols]
        )
        # INTER_AREA halving maps level coordinate u to full-resolution (u + 0.5) 2**L - 0.5.
        xy = (np.stack([cols + u0 + dx, rows + v0 + dy], axis=1) + 0.5) * 2**level - 0.5
        strength = np.sqrt(response[rows, cols].astype(np.float64)) / expected
        scale = candidate_scale(level, radius_range_px)
        found = Candidates(xy, strength, np.full(len(rows), scale))
        parts.append(found)
        if level == levels.start:
            # Markers below the level's typical radius live here, and only here can
            # their peak split (coarser levels see larger markers).
            parts.append(split_peak_midpoints(found, _SPLIT_PEAK_DISTANCE * scale))
    return Candidates.concat(parts)


def contour_curvature(contour: np.ndarray, window_px: int) -> np.ndarray:
    """Curvature of every point of a closed contour, Eq. (4).

    kappa = 1 - <v_prev, v_next> / (|v_prev| |v_next| + eps), with
    v_prev = p_k - p_{k-r} and v_next = p_{k+r} - p_k: 0 on straight runs,
    1 at a right angle, 2 at a spike.

    Args:
        contour: (M, 2) float points of a closed contour, in order.
        window_px: r, the index distance of the displacement vectors.

    Returns:
        (M,) float64 curvature.
    """
    v_prev = contour - np.roll(contour, window_px, axis=0)
    v_next = np.roll(contour, -window_px, axis=0) - contour
    dot = np.einsum("ij,ij->i", v_prev, v_next)
    norms = np.linalg.norm(v_prev, axis=1) * np.linalg.norm(v_next, axis=1)
    return 1.0 - dot / (norms + 1e-9)


def curvature_candidates(
    image: np.ndarray,
    structure: np.ndarray,
    radius_range_px: tuple[float, float],
    threshold_std: float = 3.0,
    separation_px: float = 5.0,
    keep_fraction: float = 0.7,
) -> Candidates:
    """The paper's primary screening: curvature peaks of binarised contours (section 3.2).

    The image is binarised against its local mean (window 4 x the largest radius),
    contours are traced, and contour points become candidates when (1) their
    curvature (Eq. 4) exceeds mean + ``threshold_std`` std over all contour points
    and is a local peak along the contour, (2) no stronger peak lies within
    ``separation_px``, (3) the structure map there is in the top ``keep_fraction``,
    and (4) their region is not an anomaly: regions smaller than a quarter of the
    smallest marker's quadrant are noise.

    Args:
        image: (H, W) float32 preprocessed image in [0, 1].
        structure: (H, W) float32 structure map of Eq. (3).
        radius_range_px: (min, max) expected marker radius.
        threshold_std: the dual threshold's k in mean + k std.
        separation_px: minimum spacing of peaks.
        keep_fraction: top fraction of the structure map kept.

    Returns:
        Candidates; ``scale_px`` is 2.5 times the smallest marker radius (at least 8 px):
        contour corners sit up to a pixel off the centre, so the later stages look
        around them at that scale.
    """
    r_min, r_max = radius_range_px
    window = 2 * int(2 * r_max) + 1
    binary = (image > box_mean(image, window)).astype(np.uint8)
    contours, _ = cv2.findContours(binary, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    min_area = 0.25 * (np.pi / 4.0) * r_min**2
    window_px = max(1, int(round(min(r_min, 3.0))))
    kept = [
        c[:, 0, :].astype(np.float64)
        for c in contours
        if len(c) > 2 * window_px + 2 and cv2.contourArea(c) >= min_area
    ]
    if not kept:
        return Candidates.empty()
    curvatures = [contour_curvature(c, window_px) for c in kept]
    peaks = [(k >= np.roll(k, 1)) & (k >= np.roll(k, -1)) for k in curvatures]
    points = np.concatenate(kept)
    kappa = np.concatenate(curvatures)
    is_peak = np.concatenate(peaks)
    is_peak &= kappa > kappa.mean() + threshold_std * kappa.std()
    points, kappa = points[is_peak], kappa[is_peak]
    cols, rows = points[:, 0].astype(int), points[:, 1].astype(int)
    s_threshold = np.quantile(structure, 1.0 - keep_fraction)
    in_structure = structure[rows, cols] >= s_threshold
    points, kappa = points[in_structure], kappa[in_structure]
    keep = non_maximum_suppression(points, kappa, separation_px)
    return Candidates(points[keep], kappa[keep], np.full(int(keep.sum()), max(8.0, 2.5 * r_min)))


def non_maximum_suppression(xy: np.ndarray, strength: np.ndarray, radius_px: float) -> np.ndarray:
    """Boolean mask keeping points with no stronger point within ``radius_px``."""
    if len(xy) == 0:
        return np.zeros(0, dtype=bool)
    tree = cKDTree(xy)
    pairs = tree.query_pairs(radius_px, output_type="ndarray")
    keep = np.ones(len(xy), dtype=bool)
    if len(pairs):
        i, j = pairs[:, 0], pairs[:, 1]
        weaker = np.where(strength[i] < strength[j], i, j)
        tie = strength[i] == strength[j]
        weaker = np.where(tie, np.maximum(i, j), weaker)
        keep[weaker] = False
    return keep


def curvature_density(xy: np.ndarray, weight: np.ndarray, sigma_px: float) -> np.ndarray:
    """Curvature-weighted spatial density rho(p_i), Eq. (5), over neighbours within 3 sigma."""
    tree = cKDTree(xy)
    distances = tree.sparse_distance_matrix(tree, 3.0 * sigma_px, output_type="coo_matrix")
    kernel = np.exp(-(distances.data**2) / (2.0 * sigma_px**2))
    density = np.bincount(distances.row, weights=weight[distances.col] * kernel, minlength=len(xy))
    return density + weight  # the diagonal (distance 0) is not stored in the sparse matrix


def density_mean_shift(
    candidates: Candidates,
    sigma_px: float = 2.0,
    h_px: float = 2.0,
    iterations: int = 3,
    merge_px: float = 2.0,
) -> Candidates:
    """Curvature-density mean shift and merging of converged points, Eqs. (5)-(6).

    Each point moves to the weighted mean of its neighbours,
    p_i <- sum w_j p_j / sum w_j with w_j = rho(p_j) exp(-|p_j - p_i| / h), so
    duplicates of one corner (two contour corners, several pyramid levels) fall
    together; points then closer than ``merge_px`` are merged into the strongest.

    Args:
        candidates: points with ``strength`` as the normalised curvature kappa.
        sigma_px: density kernel width of Eq. (5).
        h_px: attenuation h of Eq. (6).
        iterations: mean-shift iterations.
        merge_px: points that end closer than this are one point.

    Returns:
        The merged candidates; the merged point keeps the largest strength and scale.
    """
    if len(candidates) < 2:
        return candidates
    kappa = candidates.strength / max(float(candidates.strength.max()), 1e-12)
    rho = curvature_density(candidates.xy, kappa, sigma_px)
    xy = candidates.xy.copy()
    for _ in range(iterations):
        tree = cKDTree(xy)
        pairs = tree.sparse_distance_matrix(tree, 3.0 * h_px, output_type="coo_matrix")
        w = rho[pairs.col] * np.exp(-pairs.data / h_px)
        # Self terms (distance 0) are not stored: add them explicitly.
        w_sum = np.bincount(pairs.row, weights=w, minlength=len(xy)) + rho
        new_xy = (
            np.stack(
                [
                    np.bincount(pairs.row, weights=w * xy[pairs.col, k], minlength=len(xy))
                    + rho * xy[:, k]
                    for k in range(2)
                ],
                axis=1,
            )
            / w_sum[:, None]
        )
        xy = new_xy
    keep = non_maximum_suppression(xy, candidates.strength, merge_px)
    tree = cKDTree(xy[keep])
    _, owner = tree.query(xy)
    kept_index = np.flatnonzero(keep)
    scale = np.zeros(int(keep.sum()))
    np.maximum.at(scale, owner, candidates.scale_px)
    return Candidates(xy[kept_index], candidates.strength[kept_index], scale)


def grid_entropy(xy: np.ndarray, cell_px: int) -> float:
    """Spatial grid entropy H = -sum P(n) ln P(n) of the points, Eq. (7)."""
    if len(xy) == 0:
        return 0.0
    _, counts = np.unique(np.floor(xy / cell_px).astype(np.int64), axis=0, return_counts=True)
    p = counts / counts.sum()
    return float(-(p * np.log(p)).sum())


def grid_entropy_thinning(candidates: Candidates, cell_px: int, max_per_cell: int) -> Candidates:
    """Greedy entropy-increasing removal of redundant points, Eq. (7).

    Removing a point from the most crowded cell is the removal with the largest
    entropy gain, so the paper's greedy loop amounts to trimming every cell to a
    common count, weakest points first; the stopping threshold is expressed as
    that count (``max_per_cell``) because a count is what a user can reason about.

    Args:
        candidates: points to thin.
        cell_px: grid cell size.
        max_per_cell: the most points a cell keeps.

    Returns:
        The kept candidates (original order).
    """
    if len(candidates) == 0:
        return candidates
    cells = np.floor(candidates.xy / cell_px).astype(np.int64)
    cell_id = cells[:, 0] * 1_000_003 + cells[:, 1]
    order = np.lexsort((-candidates.strength, cell_id))
    sorted_cells = cell_id[order]
    starts = np.flatnonzero(np.r_[True, sorted_cells[1:] != sorted_cells[:-1]])
    run_start = np.repeat(starts, np.diff(np.r_[starts, len(order)]))
    rank = np.arange(len(order)) - run_start
    keep = np.zeros(len(candidates), dtype=bool)
    keep[order[rank < max_per_cell]] = True
    return candidates.take(keep)
