"""Cluttered ground backgrounds built from photographs shipped inside scikit-image.

Every texture comes from :mod:`skimage.data` files that are part of the
scikit-image wheel, so nothing is downloaded. A background is two of them,
each mirror-tiled (so it repeats without seams), randomly scaled, rotated and
contrast-varied, blended through a smooth random mask. All functions return
reflectance-like float32 images in [0, 1] of shape (height, width) and draw
every random number from the numpy Generator they are given.
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np
import scipy.fft
import skimage.data

from marker_localizer.errors import ConfigError

#: Photographs of the scikit-image wheel that load offline (checked against
#: scikit-image 0.26: ``brain``, ``lily``, ``skin``... need the network and are
#: left out). The first four look like ground; the rest add man-made clutter
#: (straight edges, corners, a lattice of crossing struts) a detector must reject.
TEXTURE_NAMES: tuple[str, ...] = (
    "grass",
    "gravel",
    "brick",
    "moon",
    "camera",
    "coins",
    "rocket",
    "coffee",
)
#: How often each of :data:`TEXTURE_NAMES` is drawn: ground twice as often as clutter.
TEXTURE_WEIGHTS: tuple[float, ...] = (2.0, 2.0, 2.0, 2.0, 1.0, 1.0, 1.0, 1.0)

#: Default range of the texture magnification, in frame pixels per texture pixel:
#: above 2.5 the photographs look blurred. Smaller scales (down to the 0.25 of
#: other renderers) are area-averaged first, so they shrink rather than alias.
TEXTURE_SCALE_RANGE: tuple[float, float] = (0.6, 2.5)
#: Range of the mean ground reflectance: dark soil to dry concrete.
GROUND_MEAN_RANGE: tuple[float, float] = (0.25, 0.6)
#: Range of the standard deviation of the ground reflectance around its mean.
GROUND_CONTRAST_RANGE: tuple[float, float] = (0.05, 0.18)
#: Reflectance limits: no real ground is perfectly black or white.
GROUND_REFLECTANCE_LIMITS: tuple[float, float] = (0.02, 0.98)
#: Size of the features of the blend mask, as a fraction of the larger frame side.
BLEND_CELL_FRACTION = 0.25


@functools.cache
def load_texture(name: str) -> np.ndarray:
    """Load one scikit-image photograph as a grayscale texture.

    Args:
        name: One of :data:`TEXTURE_NAMES`.

    Returns:
        Read-only float32 array of shape (rows, cols) with values in [0, 1];
        cached, so repeated calls cost nothing.

    Raises:
        ConfigError: If ``name`` is not one of :data:`TEXTURE_NAMES`.
    """
    if name not in TEXTURE_NAMES:
        raise ConfigError(f"unknown texture {name!r}; choose from {TEXTURE_NAMES}")
    image = np.asarray(getattr(skimage.data, name)())
    if image.ndim == 3:
        image = cv2.cvtColor(np.ascontiguousarray(image[..., :3]), cv2.COLOR_RGB2GRAY)
    texture = image.astype(np.float32) / np.float32(255.0)
    texture.setflags(write=False)
    return texture


@functools.cache
def _periodic_tile(name: str) -> tuple[np.ndarray, float, float]:
    """8-bit texture mirrored into a seamless 2x2 tile, with the tile's mean and std."""
    texture = np.rint(load_texture(name) * 255.0).astype(np.uint8)
    # Mirroring makes opposite borders equal, so repeating the tile shows no seam.
    tile = np.block([[texture, texture[:, ::-1]], [texture[::-1, :], texture[::-1, ::-1]]])
    tile.setflags(write=False)
    return tile, float(tile.mean()), max(float(tile.std()), 1e-6)


def smooth_random_field(
    shape: tuple[int, int], rng: np.random.Generator, cell_px: float
) -> np.ndarray:
    """Smooth random field of features about ``cell_px`` wide, rescaled to [0, 1].

    A coarse grid of uniform random values is upsampled bicubically, which
    costs one resize however large the frame is.

    Args:
        shape: (height, width) of the output in pixels.
        rng: Source of randomness.
        cell_px: Spacing of the random control values in pixels (> 0).

    Returns:
        float32 array of the given shape, minimum 0 and maximum 1 (constant 0.5
        if the field happens to be flat).
    """
    height, width = shape
    rows = max(2, math.ceil(height / cell_px) + 1)
    cols = max(2, math.ceil(width / cell_px) + 1)
    coarse = rng.random((rows, cols), dtype=np.float32)
    field: np.ndarray = cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC)
    low, high = float(field.min()), float(field.max())
    if high - low < 1e-6:
        return np.full(shape, 0.5, dtype=np.float32)
    field -= low
    field *= np.float32(1.0 / (high - low))
    return field


def warped_texture(
    name: str,
    shape: tuple[int, int],
    rng: np.random.Generator,
    scale_range: tuple[float, float] = TEXTURE_SCALE_RANGE,
) -> np.ndarray:
    """One texture covering the frame at a random scale, rotation, flip and offset.

    A scale below 1 first shrinks the tile by area averaging (each frame pixel
    the mean of the texture it covers), then warps it at a scale near 1:
    bilinear sampling alone would keep one texture pixel in 1/scale^2 and
    alias the photograph into noise.

    Args:
        name: One of :data:`TEXTURE_NAMES`.
        shape: (height, width) of the output in pixels.
        rng: Source of randomness.
        scale_range: (min, max) magnification, frame px per texture px.

    Returns:
        float32 array of the given shape, roughly zero mean and at most unit
        std (area averaging removes the finest detail's share).
    """
    tile, mean, std = _periodic_tile(name)
    scale = rng.uniform(*scale_range)
    if scale < 1.0:
        size = (max(2, round(tile.shape[1] * scale)), max(2, round(tile.shape[0] * scale)))
        scale /= size[0] / tile.shape[1]
        tile = cv2.resize(tile, size, interpolation=cv2.INTER_AREA)
    angle = rng.uniform(0.0, 2.0 * math.pi)
    flip = rng.choice((-1.0, 1.0))
    period = np.array(tile.shape[::-1], dtype=np.float64)
    cos, sin = math.cos(angle) / scale, math.sin(angle) / scale
    # Inverse map frame pixel -> texture pixel.
    inverse = np.array([[cos, -sin * flip, 0.0], [sin, cos * flip, 0.0]])
    inverse[:, 2] = rng.uniform(0.0, 1.0, size=2) * period
    # Repeat the tile over the frame's footprint so every source pixel is in range:
    # OpenCV's fast path, several times quicker than BORDER_WRAP at 4096 x 3000.
    corners = (
        np.array(
            [[0, 0, 1], [shape[1], 0, 1], [0, shape[0], 1], [shape[1], shape[0], 1]],
            dtype=np.float64,
        )
        @ inverse.T
    )
    inverse[:, 2] -= np.floor(corners.min(axis=0) / period) * period
    reps = np.ceil((corners.max(axis=0) - corners.min(axis=0)) / period).astype(int) + 2
    canvas = np.tile(tile, (reps[1], reps[0]))
    warped = cv2.warpAffine(
        canvas,
        inverse,
        (shape[1], shape[0]),
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_REFLECT,
    )
    result = warped.astype(np.float32)
    result -= np.float32(mean)
    result *= np.float32(1.0 / std)
    return result


def texture_background(
    shape: tuple[int, int],
    rng: np.random.Generator,
    names: tuple[str, ...] | None = None,
    scale_range: tuple[float, float] = TEXTURE_SCALE_RANGE,
) -> np.ndarray:
    """Cluttered ground: two random textures blended through a smooth random mask.

    Args:
        shape: (height, width) of the frame in pixels; any size (4096 x 3000
            takes about half a second).
        rng: Source of randomness.
        names: Textures to draw the two layers from (uniformly); default: all
            of :data:`TEXTURE_NAMES`, weighted by :data:`TEXTURE_WEIGHTS`.
        scale_range: (min, max) magnification of each layer, frame px per texture px.

    Returns:
        float32 reflectance image of the given shape, values in
        :data:`GROUND_REFLECTANCE_LIMITS`.
    """
    if names is None:
        names, weights = TEXTURE_NAMES, np.array(TEXTURE_WEIGHTS) / sum(TEXTURE_WEIGHTS)
    else:
        weights = np.full(len(names), 1.0 / len(names))
    first, second = rng.choice(len(names), size=2, p=weights)
    layer_a = warped_texture(names[first], shape, rng, scale_range)
    layer_b = warped_texture(names[second], shape, rng, scale_range)
    layer_a *= np.float32(rng.uniform(*GROUND_CONTRAST_RANGE))
    layer_b *= np.float32(rng.uniform(*GROUND_CONTRAST_RANGE))
    # A logistic of random steepness gives anything from gradual to crisp
    # boundaries; it is smooth, so it is computed at 1/8 resolution and enlarged.
    coarse = (max(2, shape[0] // 8), max(2, shape[1] // 8))
    mask = smooth_random_field(coarse, rng, BLEND_CELL_FRACTION * max(coarse))
    mask = 1.0 / (1.0 + np.exp(rng.uniform(4.0, 20.0) * (0.5 - mask)))
    mask = cv2.resize(mask.astype(np.float32), (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR)
    # background = mean + mask * a + (1 - mask) * b, computed in place: frames are large.
    layer_a -= layer_b
    layer_a *= mask
    layer_a += layer_b
    layer_a += np.float32(rng.uniform(*GROUND_MEAN_RANGE))
    np.clip(layer_a, *GROUND_REFLECTANCE_LIMITS, out=layer_a)
    return layer_a


def periodic_component(image: np.ndarray) -> np.ndarray:
    """The part of ``image`` that repeats without a seam: Moisan's periodic component.

    An image repeated side by side jumps at every join where its opposite borders
    differ; mirrored instead, it does not jump but is symmetric about every join,
    and where two joins cross it is point-symmetric: a saddle there is an exact
    X to a detector that looks for grey-level point symmetry. The periodic
    component (L. Moisan, "Periodic plus smooth image decomposition", J. Math.
    Imaging Vision 39, 2011) is the image less the smooth field whose Laplacian
    takes up the jumps across the borders: it keeps the detail and repeats with
    no seam and no symmetry.

    Args:
        image: (rows, cols) float image.

    Returns:
        float32 array of the same shape.
    """
    u = np.asarray(image, dtype=np.float32)
    rows, cols = u.shape
    jumps = np.zeros_like(u)
    row_jump, col_jump = u[-1] - u[0], u[:, -1] - u[:, 0]
    jumps[0] += row_jump
    jumps[-1] -= row_jump
    jumps[:, 0] += col_jump
    jumps[:, -1] -= col_jump
    spectrum = scipy.fft.rfft2(jumps)
    # The discrete Laplacian's eigenvalues; its zero (the mean) stays the image's own.
    laplacian = (
        2.0 * np.cos(2.0 * np.pi * np.arange(rows) / rows)[:, None]
        + 2.0 * np.cos(2.0 * np.pi * np.arange(cols // 2 + 1) / cols)[None, :]
        - 4.0
    )
    laplacian[0, 0] = 1.0
    spectrum /= laplacian
    spectrum[0, 0] = 0.0
    smooth = scipy.fft.irfft2(spectrum, s=(rows, cols))
    return (u - smooth).astype(np.float32)


def flat_background(shape: tuple[int, int], level: float) -> np.ndarray:
    """Uniform grey ground of reflectance ``level`` (float32, shape (height, width))."""
    return np.full(shape, level, dtype=np.float32)
