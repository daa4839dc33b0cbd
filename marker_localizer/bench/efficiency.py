"""Whether the Cramer-Rao bound of the X's pixels can be beaten: a Monte Carlo check.

The renderer's bound (:func:`~marker_localizer.synthetic.scene.render_markers` with
``crlb=True``), like the independent renderer's ``truth.json``, sums the Fisher
information over the pixels of the X alone. It bounds estimators that read those
pixels; the arcs and the plate's outline against the ground carry information too.
This check renders one marker, takes its bound, and estimates its centre on noisy
frames by Gauss-Newton maximum likelihood with everything but the centre known (the
bound's own model), once over the X's pixels and once over the whole window. An
efficient estimator's mean error equals the bound of the pixels it reads::

    python -m marker_localizer.bench.efficiency 8 30 0.8 3 400

(radius px, tilt degrees, blur px, read noise DN, draws). Measured on 2026-12-07
(docs/accuracy-journal.md, "The Cramer-Rao bound is the X's pixels'"): over the X,
1.01-1.05 of the bound; over the whole window, 0.71-0.82 of it.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass

import numpy as np

from marker_localizer.synthetic import scene
from marker_localizer.synthetic.crlb import crlb_mean_abs_error, fisher_information

#: The command's one-line description.
DESCRIPTION = "Whether the Cramer-Rao bound of the X's pixels can be beaten: a Monte Carlo check."
#: The marker's paints (dark, plate), the renderer's usual contrast.
PAINTS = (0.10, 0.80)
#: Supersampling of the renders, per axis: the renderer's default for the bound.
SUPERSAMPLING = 16
#: Gauss-Newton steps at most, and the step under which it stops, px.
MAX_STEPS = 4
CONVERGED_PX = 1e-4
#: The window's margin around the marker's plate, px: room for the blur.
MARGIN_PX = 12
#: The marker's offset from the window's central pixel, px: off the pixel grid.
OFFSET_PX = (0.31, -0.17)


@dataclass(frozen=True)
class EfficiencyCheck:
    """One marker's bound and what maximum likelihood reaches, px.

    Attributes:
        bound_px: the renderer's bound (the X's pixels).
        window_bound_px: the bound of the whole window's pixels.
        x_mean_error_px: the fit over the X's pixels: mean Euclidean error.
        window_mean_error_px: the fit over the whole window: mean Euclidean error.
        draws: noisy frames fitted.
    """

    bound_px: float
    window_bound_px: float
    x_mean_error_px: float
    window_mean_error_px: float
    draws: int


def check_efficiency(
    radius_px: float,
    tilt_deg: float,
    blur_px: float,
    noise_dn: float,
    draws: int,
    seed: int = 7,
) -> EfficiencyCheck:
    """Render one quarter-disk marker and fit its centre on ``draws`` noisy frames.

    Args:
        radius_px: the marker's radius, px.
        tilt_deg: its plane's tilt, degrees.
        blur_px: the optics' Gaussian blur, px.
        noise_dn: read noise, DN (shot noise at the renderer's default gain).
        draws: noisy frames to fit (0: the bounds alone).
        seed: seed of the noise.
    """
    size = int(4 * radius_px + 2 * MARGIN_PX)
    placement = scene.MarkerPlacement(
        x=size / 2 + OFFSET_PX[0],
        y=size / 2 + OFFSET_PX[1],
        radius_px=radius_px,
        rotation_rad=0.4,
        tilt_deg=tilt_deg,
        tilt_axis_rad=1.0,
    )
    imaging = scene.ImagingConditions(
        blur_sigma_px=blur_px,
        noise_sigma_dn=noise_dn,
        shot_noise_gain_dn=scene.DEFAULT_SHOT_NOISE_GAIN_DN,
    )
    rendered = scene.render_markers(
        (size, size),
        [placement],
        0,
        reflectances=PAINTS,
        blur_sigma_px=blur_px,
        noise_sigma_dn=noise_dn,
        shot_noise_gain_dn=scene.DEFAULT_SHOT_NOISE_GAIN_DN,
        supersampling=SUPERSAMPLING,
        crlb=True,
    )
    pattern = scene.PATTERNS["quarter_disks"]
    target = scene.PlanarTarget(scene.marker_homography(placement), pattern, *PAINTS)
    ground = np.full((size, size), scene.FLAT_BACKGROUND_LEVEL, np.float32)

    def signal(dx: float, dy: float) -> np.ndarray:
        radiance = ground.copy()
        scene.composite_target(radiance, target.translated(dx, dy), SUPERSAMPLING)
        return scene.expose(radiance, imaging, None, None).astype(np.float64)

    step = 1.0 / SUPERSAMPLING

    def gradients(x: float, y: float) -> tuple[np.ndarray, np.ndarray]:
        return (
            (signal(x + step, y) - signal(x - step, y)) / (2 * step),
            (signal(x, y + step) - signal(x, y - step)) / (2 * step),
        )

    still = signal(0.0, 0.0)
    variance = imaging.pixel_variance_dn2(still)
    masks = {"x": _x_pixels(target, size), "window": np.ones((size, size), dtype=bool)}
    window_bound = crlb_mean_abs_error(
        fisher_information(*gradients(0.0, 0.0), variance, masks["window"])
    )
    rng = np.random.default_rng(seed)
    errors: dict[str, list[float]] = {"x": [], "window": []}
    for _ in range(draws):
        frame = scene.record(still.astype(np.float32), imaging, rng).astype(np.float64)
        for name, mask in masks.items():
            centre = np.zeros(2)
            for _ in range(MAX_STEPS):
                d_x, d_y = gradients(*centre)
                jacobian = np.stack([d_x[mask], d_y[mask]], axis=1)
                weighted = jacobian / variance[mask, None]
                move = np.linalg.solve(
                    weighted.T @ jacobian, weighted.T @ (frame - signal(*centre))[mask]
                )
                centre += move
                if np.abs(move).max() < CONVERGED_PX:
                    break
            errors[name].append(float(np.hypot(*centre)))
    return EfficiencyCheck(
        bound_px=rendered.markers[0].crlb_mean_abs_error_px,
        window_bound_px=window_bound,
        x_mean_error_px=float(np.mean(errors["x"])) if draws else math.nan,
        window_mean_error_px=float(np.mean(errors["window"])) if draws else math.nan,
        draws=draws,
    )


def _x_pixels(target: scene.PlanarTarget, size: int) -> np.ndarray:
    """(size, size) the pixels whose centres lie inside the target's X, as the bound sums."""
    y, x = np.mgrid[0:size, 0:size].astype(np.float64)
    u, v = scene.to_plane(np.linalg.inv(target.homography), x, y)
    inside = target.pattern.x_extent
    assert inside is not None, "a marker kind's pattern has an X"
    return np.asarray(inside(u, v), dtype=bool)


def main(argv: list[str] | None = None) -> int:
    """Print one marker's bounds and the two fits' mean errors over the renderer's bound."""
    parser = argparse.ArgumentParser(description=DESCRIPTION)
    for name in ("radius_px", "tilt_deg", "blur_px", "noise_dn"):
        parser.add_argument(name, type=float)
    parser.add_argument("draws", type=int)
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args(argv)
    check = check_efficiency(
        args.radius_px, args.tilt_deg, args.blur_px, args.noise_dn, args.draws, args.seed
    )
    sys.stdout.write(
        f"radius {args.radius_px:g} px, tilt {args.tilt_deg:g} deg, blur {args.blur_px:g} px, "
        f"noise {args.noise_dn:g} DN: the X's bound {check.bound_px:.5f} px, the whole "
        f"window's {check.window_bound_px:.5f} px ({check.window_bound_px / check.bound_px:.3f})\n"
        f"maximum likelihood over {check.draws} frames, mean error over the X's bound: "
        f"over the X {check.x_mean_error_px / check.bound_px:.3f}, over the window "
        f"{check.window_mean_error_px / check.bound_px:.3f}\n"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
