"""The README's main job: a simulated five-camera flight, recorded, replayed, evaluated.

Everything is generated on the fly (no downloads): the flight simulator renders a
five-camera oblique rig over textured ground with diagonal markers, the frames
are recorded into a rosbag2 exactly as a camera driver would publish them, the
bag is replayed through the node's processing code, and the result is compared
with the exact truth. A few frames are written with their detections drawn.
"""

from __future__ import annotations

import argparse
import shutil
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from marker_localizer.bag.io import BAG_FILE_SUFFIXES
from marker_localizer.bag.record import record_flight
from marker_localizer.bag.replay import format_report, replay_bag
from marker_localizer.cli.arguments import count_type, seed_type
from marker_localizer.cli.exits import PROG
from marker_localizer.config import DetectorConfig
from marker_localizer.core.pipeline import Detector
from marker_localizer.errors import ConfigError
from marker_localizer.overlay import draw_detections
from marker_localizer.synthetic.flight import FlightConfig, FlightSimulator

#: Marker radii the simulated rig produces (8.4-17.3 px; 15 at nadir), widened to the
#: default's smallest radius: the one input a user of the detector gives.
DEMO_RADIUS_RANGE_PX = (4.0, 30.0)


#: The demo's flight: frames per camera, and the seed of its world and noise.
DEMO_FRAMES, DEMO_SEED = 4, 7


def run(
    out_dir: Path,
    frames: int = DEMO_FRAMES,
    seed: int = DEMO_SEED,
    width: int = 1280,
    height: int = 960,
) -> int:
    """Simulate, record, replay, report and draw; every output lands in ``out_dir``.

    Raises:
        ConfigError: ``out_dir`` cannot be created (a file of that name, no permission),
            or holds a ``flight`` or ``markers`` that is not a bag (a second run
            replaces the bags of the first, nothing else).
    """
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ConfigError(f"--out {out_dir}: cannot create the folder ({err.strerror})") from err
    flight_bag, result_bag = out_dir / "flight", out_dir / "markers"
    # A second run replaces the bags of the first; anything else there is the user's.
    in_the_way = [p for p in (flight_bag, result_bag) if p.exists() and not _is_bag(p)]
    if in_the_way:
        raise ConfigError(
            f"--out {out_dir}: {in_the_way[0]} is not a bag the demo wrote; move it, or "
            "give another --out"
        )
    for path in (flight_bag, result_bag):
        shutil.rmtree(path, ignore_errors=True)
    simulator = FlightSimulator(
        FlightConfig(width=width, height=height, n_frames=frames), seed=seed
    )
    summary = record_flight(simulator, flight_bag)
    print(
        f"simulated {summary.frame_sets} x {len(summary.cameras)} cameras "
        f"({width}x{height}) with {summary.truth_markers} marker images -> {flight_bag}"
    )
    config = DetectorConfig(
        marker_radius_min_px=DEMO_RADIUS_RANGE_PX[0], marker_radius_max_px=DEMO_RADIUS_RANGE_PX[1]
    )
    report = replay_bag(flight_bag, result_bag, config=config)
    print(format_report(report))
    detector = Detector(config)
    first = simulator.render(0)
    for view in first.cameras:
        # Those the border cuts too: the report excuses their detections, and so
        # must the picture.
        truth = np.array([(m.x, m.y) for m in (*view.markers, *view.partial)]).reshape(-1, 2)
        drawn = draw_detections(view.image, detector.detect(view.image).detections, truth)
        path = out_dir / f"{view.camera.name}_frame0.png"
        cv2.imwrite(str(path), drawn)
    print(f"annotated frames: {out_dir}/cam*_frame0.png")
    return 0


def _is_bag(path: Path) -> bool:
    """Whether ``path`` is a closed rosbag2 folder: its metadata and storage files alone."""
    if not (path / "metadata.yaml").is_file():
        return False
    return all(
        child.is_file() and (child.name == "metadata.yaml" or child.suffix in BAG_FILE_SUFFIXES)
        for child in path.iterdir()
    )


def main(argv: Sequence[str]) -> int:
    """``marker-localizer demo``: the README's main job."""
    parser = argparse.ArgumentParser(
        allow_abbrev=False,
        prog=f"{PROG} demo",
        description="Render frames, detect, print accuracy, write overlays.",
    )
    parser.add_argument(
        "--out",
        default="out/demo",
        help="folder for the two bags and the annotated frames (default: %(default)s)",
    )
    parser.add_argument(
        "--frames",
        type=count_type,
        default=DEMO_FRAMES,
        help="frames per camera (default: %(default)s)",
    )
    parser.add_argument(
        "--seed",
        type=seed_type,
        default=DEMO_SEED,
        help="seed of the simulated world and its noise (default: %(default)s)",
    )
    args = parser.parse_args(argv)
    return run(Path(args.out), frames=args.frames, seed=args.seed)
