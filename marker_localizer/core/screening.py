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

from marker_localizer.core.preprocessing import box_mean, local_std


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

    def take(self, index: np.ndarray) -> Candidates:
        """Return the candidates selected by a boolean mask or index array."""
        return Candidates(self.xy[index], self.strength[index], self.scale_px[index])

    def __len__(self) -> int:
        return int(self.strength.shape[0])


def _concat(parts: list[Candidates]) -> Candidates:
    if not parts:
        return Candidates.empty()
    return Candidates(*(np.concatenate([getattr(p, f) for p in parts]) for f in Candidates._fields))


def local_maxima(response: np.ndarray, threshold: float, separation_px: float) -> np.ndarray:
    """Return (N, 2) integer (row, col) of maxima above ``threshold`` with the given spacing."""
    size = 2 * int(np.ceil(separation_px)) + 1
    dilated = cv2.dilate(response, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size)))
    return np.argwhere((response >= dilated) & (response > threshold))


def _parabolic_offset(minus: np.ndarray, centre: np.ndarray, plus: np.ndarray) -> np.ndarray:
    """Sub-sample vertex of a parabola through three samples, clipped to half a sample."""
    curvature = minus - 2.0 * centre + plus
    with np.errstate(divide="ignore", invalid="ignore"):
        offset = np.where(curvature < 0, 0.5 * (minus - plus) / curvature, 0.0)
    return np.clip(offset, -0.5, 0.5)


def saddle_response(image: np.ndarray, sigma_px: float, contrast_floor: float) -> np.ndarray:
    """Scale-normalised saddle strength of a diagonal marker at scale ``sigma_px``.

    sqrt(max(-det H, 0)) * sigma^2, with H the Hessian of the image smoothed by
    ``sigma_px``, divided by the local contrast (2 x local std), so the response
    is independent of illumination and near 1/(2 pi) at the centre of an ideal X.

    Args:
        image: (H, W) float32 in [0, 1].
        sigma_px: Gaussian derivative scale.
        contrast_floor: smallest contrast divided by, so flat noise stays small.

    Returns:
        (H, W) float32 response, 0 where the Hessian is not a saddle.
    """
    smooth = cv2.GaussianBlur(image, (0, 0), sigma_px)
    dxx = cv2.Sobel(smooth, cv2.CV_32F, 2, 0, ksize=3, scale=0.25)
    dyy = cv2.Sobel(smooth, cv2.CV_32F, 0, 2, ksize=3, scale=0.25)
    dxy = cv2.Sobel(smooth, cv2.CV_32F, 1, 1, ksize=3, scale=0.25)
    saddle = np.sqrt(np.maximum(dxy * dxy - dxx * dyy, 0.0)) * np.float32(sigma_px**2)
    window = 2 * int(round(2.5 * sigma_px)) + 1
    contrast = np.maximum(2.0 * local_std(image, window), np.float32(contrast_floor))
    return saddle / contrast


def saddle_candidates(
    image: np.ndarray,
    radius_range_px: tuple[float, float],
    contrast_floor: float,
    threshold: float = 0.04,
    separation_px: float = 5.0,
) -> Candidates:
    """Saddle points over an image pyramid covering the expected marker radii.

    Level L (image reduced by 2**L with ``cv2.pyrDown``) is searched at sigma 1.2 px,
    which answers best to markers of radius ~3-6 px at that level. Peaks are
    refined to sub-sample precision with a parabola per axis.

    Args:
        image: (H, W) float32 in [0, 1] (the preprocessed image).
        radius_range_px: (min, max) expected marker radius.
        contrast_floor: see :func:`saddle_response` (intensity units).
        threshold: minimum normalised response.
        separation_px: minimum distance between peaks at one level (level pixels).

    Returns:
        Candidates in full-resolution coordinates; ``scale_px`` is 4 * 2**L.
    """
    r_min, r_max = radius_range_px
    top_level = max(0, int(np.floor(np.log2(max(r_max, 1.0) / 4.0)) + 1))
    first_level = max(0, int(np.floor(np.log2(max(r_min, 1.0) / 6.0))))
    parts = []
    level_image = image
    for level in range(top_level + 1):
        if level > 0:
            level_image = cv2.pyrDown(level_image)
        if level < first_level or min(level_image.shape) < 16:
            continue
        response = saddle_response(level_image, 1.2, contrast_floor)
        peaks = local_maxima(response, threshold, max(1.0, separation_px / 2**level))
        inner = (
            (peaks[:, 0] > 0)
            & (peaks[:, 0] < response.shape[0] - 1)
            & (peaks[:, 1] > 0)
            & (peaks[:, 1] < response.shape[1] - 1)
        )
        rows, cols = peaks[inner, 0], peaks[inner, 1]
        dx = _parabolic_offset(
            response[rows, cols - 1], response[rows, cols], response[rows, cols + 1]
        )
        dy = _parabolic_offset(
            response[rows - 1, cols], response[rows, cols], response[rows + 1, cols]
        )
        # pyrDown keeps sample i of a level on sample 2**L * i of the full image.
        xy = np.stack([cols + dx, rows + dy], axis=1).astype(np.float64) * 2**level
        parts.append(
            Candidates(
                xy, response[rows, cols].astype(np.float64), np.full(len(rows), 4.0 * 2**level)
            )
        )
    return _concat(parts)


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
        Candidates with ``scale_px`` equal to the curvature window.
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
    return Candidates(points[keep], kappa[keep], np.full(int(keep.sum()), float(window_px)))


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
