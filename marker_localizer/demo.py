"""The README's main job: render frames with exact truth, detect, report accuracy, draw.

Everything is generated on the fly (no downloads): cluttered 1280x960 frames from
the package's renderer with markers of radius 6-40 px, blur, noise, tilt,
shadows and hard negatives.
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from marker_localizer.config import DetectorConfig
from marker_localizer.core.pipeline import Detector
from marker_localizer.overlay import draw_detections
from marker_localizer.synthetic import SceneConfig, render_scene

#: A detection within this distance of a true centre counts as finding it.
MATCH_PX = 1.5


def run(out_dir: Path, frames: int = 4, seed: int = 7) -> int:
    """Render ``frames`` frames, detect, print accuracy, write annotated PNGs into ``out_dir``."""
    scene_config = SceneConfig()
    detector = Detector(
        DetectorConfig(
            marker_radius_min_px=scene_config.radius_px[0],
            marker_radius_max_px=scene_config.radius_px[1],
        )
    )
    out_dir.mkdir(parents=True, exist_ok=True)
    errors: list[float] = []
    n_truth = n_found = n_false = 0
    print(f"{'frame':>5} {'markers':>7} {'found':>5} {'false':>5} {'mean err px':>11} {'ms':>7}")
    for k in range(frames):
        scene = render_scene(scene_config, seed + k)
        start = time.perf_counter()
        result = detector.detect(scene.image)
        elapsed_ms = (time.perf_counter() - start) * 1000.0
        found = result.as_array()[:, :2]
        distance, index = (
            cKDTree(scene.centres).query(found) if len(found) else (np.zeros(0), np.zeros(0, int))
        )
        hit = distance <= MATCH_PX
        frame_errors = distance[hit]
        n_truth += len(scene.centres)
        n_found += len(np.unique(index[hit]))
        n_false += int((~hit).sum())
        errors.extend(frame_errors.tolist())
        mean = f"{frame_errors.mean():.4f}" if len(frame_errors) else "-"
        print(
            f"{k:>5} {len(scene.centres):>7} {len(np.unique(index[hit])):>5} "
            f"{int((~hit).sum()):>5} {mean:>11} {elapsed_ms:>7.0f}"
        )
        path = out_dir / f"frame_{k:02d}.png"
        cv2.imwrite(str(path), draw_detections(scene.image, result.detections, scene.centres))
    err = np.asarray(errors)
    print(
        f"\nrecall {n_found / max(n_truth, 1):.3f} ({n_found}/{n_truth}), "
        f"false positives {n_false / max(frames, 1):.2f} per frame"
    )
    if len(err):
        print(
            f"error: mean {err.mean():.4f} px, RMS {np.sqrt((err**2).mean()):.4f} px, "
            f"p95 {np.percentile(err, 95):.4f} px, max {err.max():.4f} px"
        )
    print(f"annotated frames: {out_dir}/frame_*.png")
    return 0
