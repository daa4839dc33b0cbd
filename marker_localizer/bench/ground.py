"""Speed on real ground: time per frame, ours against peers, by ground and radius range.

Part of ``marker-localizer bench speed`` (its second table). The time per frame
grows with how many texture saddles pass the early stages, so a friendly
rendered ground says little about real ground. The grounds:

* real frames of ``<repo>/../shared/data`` (skipped, with a line saying so,
  when it is absent): ``aerial_negatives`` (3264 x 2448 sandbox aerials, no
  marker), ``cirn_uas`` (3840 x 2160 beach UAV frames, two targets) and
  ``pycbd/flare.jpg`` (a 4032 x 3024 chessboard under lens flare);
* the flight simulator's five 4096 x 3000 cameras (one frame set);
* two worst cases at 4096 x 3000: sensor noise of sigma 40 DN (a saddle at
  every few pixels) and a tiling of X's (8 px checker squares: every candidate
  passes the prescreen), which the detector's caps must bound.

Each subject (this detector's default and every installed point-detector peer)
runs in its own single-threaded worker (:mod:`~marker_localizer.bench.workers`),
over every ground and radius range (3-30 px: markers down to 3 px, screened from
full resolution; 6-40 px: the first table's range, screened from half
resolution). Per ground and range each subject makes one untimed warm-up
detection on its first frame, which measures the peak memory of the arrays it
allocates (tracemalloc); then every frame is timed once, by every subject in
turn before the next frame, and ``ours/peer`` is the median of the ratios frame
by frame (:func:`workers.paired_ratio`).
"""

from __future__ import annotations

import argparse
import time
import tracemalloc
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from marker_localizer.bench import real_data, workers
from marker_localizer.bench.peers import range_text
from marker_localizer.bench.speed import REFERENCE_SUBJECT

#: Radius ranges timed on every ground, px: markers from 3 px (the issue's real-ground
#: target) and the first table's 6-40.
RANGES: tuple[tuple[float, float], ...] = ((3.0, 30.0), (6.0, 40.0))
#: The issue's targets at radius 3-30 px, one core: median and slowest real 8 MP frame.
TARGET_REAL_MEDIAN_MS = 150.0
TARGET_REAL_WORST_MS = 400.0
#: ... and any 12 MP frame, however busy: time and peak memory growth.
TARGET_BOUND_MS = 1000.0
TARGET_BOUND_MB = 500.0
#: The real grounds whose frames are the 8 MP-class real frames of the targets.
REAL_8MP = ("aerial_negatives", "cirn_uas")
#: Worst-case frames: the sensor noise's sigma, DN (a saddle every few pixels at full
#: resolution), and the X tiling's square side, px (a corner every 8 px: 190 000 X's).
NOISE_SIGMA_DN = 40.0
TILING_SQUARE_PX = 8
#: The tiling's grey levels (DN) and optics blur (px): printed black and white, sharp.
_TILING_LEVELS_DN = (40, 200)
_TILING_BLUR_PX = 1.0
WORST_CASE_SHAPE = (3000, 4096)


@dataclass(frozen=True)
class Ground:
    """Frames of one kind of ground.

    Attributes:
        name: short name (the real set's folder, ``flight simulator``, ...).
        frames: (H, W) uint8 frames.
        worst_case: a constructed worst case (judged against the bound).
    """

    name: str
    frames: list[np.ndarray]
    worst_case: bool = False

    @property
    def label(self) -> str:
        """Table label: name and frame size."""
        height, width = self.frames[0].shape[:2]
        return f"{self.name} {width}x{height}"


def sensor_noise_frame(seed: int, shape: tuple[int, int] = WORST_CASE_SHAPE) -> np.ndarray:
    """Grey 128 plus Gaussian noise of :data:`NOISE_SIGMA_DN`, uint8."""
    noise = np.random.default_rng(seed).normal(128.0, NOISE_SIGMA_DN, shape)
    return np.clip(noise, 0, 255).astype(np.uint8)


def x_tiling_frame(seed: int, shape: tuple[int, int] = WORST_CASE_SHAPE) -> np.ndarray:
    """A checkerboard of :data:`TILING_SQUARE_PX` squares, blurred, with 2 DN of noise, uint8."""
    import cv2  # noqa: PLC0415

    rows, cols = np.indices(shape)
    dark, bright = _TILING_LEVELS_DN
    board = np.where((rows // TILING_SQUARE_PX + cols // TILING_SQUARE_PX) % 2, bright, dark)
    blurred = cv2.GaussianBlur(board.astype(np.float32), (0, 0), _TILING_BLUR_PX)
    noisy = blurred + np.random.default_rng(seed).normal(0.0, 2.0, shape)
    return np.clip(noisy, 0, 255).astype(np.uint8)


def flight_frames(seed: int) -> list[np.ndarray]:
    """One frame set of the flight simulator's default rig: five 4096 x 3000 cameras."""
    from marker_localizer.synthetic.flight import FlightConfig, FlightSimulator  # noqa: PLC0415

    frame_set = FlightSimulator(FlightConfig(n_frames=1), seed=seed).render(0)
    return [camera.image for camera in frame_set.cameras]


def grounds(root: Path | None, seed: int, report: Callable[[str], None]) -> list[Ground]:
    """Every ground of the table; the real ones only where ``root`` (shared data) exists."""
    found: list[Ground] = []
    if root is None:
        report(real_data.absent("Real ground (only the simulated and worst-case grounds timed)"))
    else:
        found.append(
            Ground("aerial_negatives", [f.image for f in real_data.iter_aerial_negatives(root)])
        )
        found.append(Ground("cirn_uas", [f.image for f in real_data.iter_cirn_uas(root)]))
        flare = root / "pycbd" / "flare.jpg"
        if flare.is_file():
            found.append(Ground("pycbd flare", [real_data.read_gray(flare)]))
    found.append(Ground("flight simulator", flight_frames(seed)))
    found.append(
        Ground(f"sensor noise {NOISE_SIGMA_DN:g} DN", [sensor_noise_frame(seed)], worst_case=True)
    )
    found.append(Ground(f"X tiling {TILING_SQUARE_PX} px", [x_tiling_frame(seed)], worst_case=True))
    return [g for g in found if g.frames]


# --------------------------------------------------------------------------- worker side


@dataclass
class GroundTiming:
    """One subject on one ground at one radius range.

    Attributes:
        times_ms: wall time of every frame, ms.
        points: points returned per frame.
        peak_mb: peak memory of the arrays the warm-up detection allocated, MiB.
    """

    times_ms: list[float] = field(default_factory=list)
    points: list[int] = field(default_factory=list)
    peak_mb: float = float("nan")


def peak_traced_mb(work: Callable[[], object]) -> float:
    """Peak memory that ``work`` allocates through Python and numpy, MiB (tracemalloc).

    OpenCV returns its results as numpy arrays, so they count too; a process's
    peak RSS would show only what exceeds the memory an earlier call left mapped.
    """
    tracemalloc.start()
    try:
        work()
        return tracemalloc.get_traced_memory()[1] / 2**20
    finally:
        tracemalloc.stop()


def _point_detector(name: str) -> Any:
    from marker_localizer.bench import peers  # noqa: PLC0415 - after the thread settings

    everyone = [*peers.our_variants(include_curvature=False), *peers.point_detectors()]
    return next(d for d in everyone if d.name == name)


def _ground_frames(frames_path: Path) -> list[list[np.ndarray]]:
    """The grounds' frames as :func:`save_grounds` wrote them: [ground][frame]."""
    with np.load(frames_path) as archive:
        count = int(archive["ground_count"])
        return [
            [archive[key] for key in sorted(archive.files) if key.startswith(f"ground{g:02d}_")]
            for g in range(count)
        ]


def worker_main(name: str, frames_path: Path) -> int:
    """Subprocess entry: one subject, asked for its warm-ups and timings (:func:`workers.serve`).

    ``warm G K``: the warm-up detection on ground G's first frame at range K, its
    time ``s``, and the ``peak_mb`` of another (traced, which slows it); ``time G
    K I``: frame I of ground G at range K, its ``ms`` and ``points``.
    """
    import cv2  # noqa: PLC0415

    cv2.setNumThreads(1)
    ground_frames = _ground_frames(frames_path)
    detector = _point_detector(name)

    def answer(request: str) -> dict[str, Any]:
        verb, *numbers = request.split()
        g, k, *rest = (int(n) for n in numbers)
        radius_range = RANGES[k]
        if verb == "warm":
            start = time.perf_counter()
            detector.detect(ground_frames[g][0], radius_range)
            warm_up_s = time.perf_counter() - start
            return {
                "s": warm_up_s,
                "peak_mb": peak_traced_mb(
                    partial(detector.detect, ground_frames[g][0], radius_range)
                ),
            }
        start = time.perf_counter()
        points = detector.detect(ground_frames[g][rest[0]], radius_range)
        return {"ms": (time.perf_counter() - start) * 1000.0, "points": len(points)}

    workers.serve({"error": ""}, answer)
    return 0


# --------------------------------------------------------------------------- driver side


@dataclass
class SubjectTimings:
    """What one subject's worker measured: [ground][range], or why it could not run."""

    name: str
    timings: list[list[GroundTiming]] = field(default_factory=list)
    error: str = ""


def run_subjects(
    names: Sequence[str], frames_path: Path, frame_counts: Sequence[int]
) -> list[SubjectTimings]:
    """Time every subject on every ground and range, frame by frame in turn.

    ``frame_counts``: how many frames each ground of ``frames_path`` has
    (:func:`save_grounds`). Per ground and range every subject warms up, then each
    frame goes to every running subject in turn (:func:`workers.in_turn`) before
    the next; subjects whose warm-up there took over :data:`workers.IN_TURN_MAX_S`
    after the others, who take one untimed turn on the first frame before theirs
    (:func:`workers.settled_groups`). A subject whose worker fails is reported
    with its error and no timings.
    """
    results = [
        SubjectTimings(name, [[GroundTiming() for _ in RANGES] for _ in frame_counts])
        for name in names
    ]
    with workers.started("marker_localizer.bench.ground", names, frames_path) as started:
        for g, count in enumerate(frame_counts):
            for k in range(len(RANGES)):
                warm_up_s = [float("nan")] * len(started)
                for position in workers.in_turn(started, 0):
                    reply = started[position].ask(f"warm {g} {k}")
                    if reply is not None:
                        results[position].timings[g][k].peak_mb = float(reply["peak_mb"])
                        warm_up_s[position] = float(reply["s"])
                for group in workers.settled_groups(started, warm_up_s, f"time {g} {k} 0"):
                    for i in range(count):
                        for position in workers.in_turn(started, i, group):
                            reply = started[position].ask(f"time {g} {k} {i}")
                            if reply is not None:
                                timing = results[position].timings[g][k]
                                timing.times_ms.append(float(reply["ms"]))
                                timing.points.append(int(reply["points"]))
        for worker, result in zip(started, results, strict=True):
            if worker.error:
                result.error, result.timings = worker.error, []
    return results


def save_grounds(found: Sequence[Ground], path: Path) -> None:
    """Write the grounds' frames to one ``.npz`` file the workers read."""
    arrays: dict[str, np.ndarray] = {"ground_count": np.array(len(found))}
    for g, ground in enumerate(found):
        for i, frame in enumerate(ground.frames):
            arrays[f"ground{g:02d}_{i:02d}"] = frame
    workers.save_frames(path, arrays)


def ground_table(found: Sequence[Ground], results: Sequence[SubjectTimings]) -> str:
    """Median and slowest frame per ground and range, ms; ours over each peer, frame by frame."""
    ours = next((r for r in results if r.name == REFERENCE_SUBJECT and not r.error), None)
    peers_run = [r for r in results if r.name != REFERENCE_SUBJECT and not r.error]
    header = (
        f"{'ground':<30}{'frames':>7}{'radius px':>11}{'median ms':>11}{'worst ms':>10}"
        f"{'peak MiB':>10}{'pts/frame':>10}"
    )
    header += "".join(
        f"{f'peer{i} median':>14}{'pts/frame':>10}{'ours/peer':>11}"
        for i in range(1, len(peers_run) + 1)
    )
    lines = [
        f"ours = {REFERENCE_SUBJECT}"
        + "".join(f"; peer{i} = {p.name}" for i, p in enumerate(peers_run, 1)),
        header,
        "-" * len(header),
    ]
    for g, ground in enumerate(found):
        for k, radius_range in enumerate(RANGES):
            row = f"{ground.label:<30}{len(ground.frames):>7}{range_text(radius_range):>11}"
            if ours is None:
                row += f"{'not run':>11}"
            else:
                mine = ours.timings[g][k]
                row += (
                    f"{np.median(mine.times_ms):>11.0f}{max(mine.times_ms):>10.0f}"
                    f"{mine.peak_mb:>10.0f}{np.mean(mine.points):>10.1f}"
                )
            for peer in peers_run:
                theirs = peer.timings[g][k]
                ratio = (
                    workers.paired_ratio(ours.timings[g][k].times_ms, theirs.times_ms)
                    if ours is not None
                    else float("nan")
                )
                row += (
                    f"{np.median(theirs.times_ms):>14.0f}{np.mean(theirs.points):>10.1f}"
                    f"{ratio:>11.2f}"
                )
            lines.append(row)
    for r in results:
        if r.error:
            lines.append(f"{r.name}: not run: {r.error}")
    return "\n".join(lines)


def _judged(value: float, target: float) -> str:
    return f"(target <= {target:.0f}: {'met' if value <= target else 'missed'})"


def verdict(found: Sequence[Ground], results: Sequence[SubjectTimings]) -> str:
    """The issue's targets at radius 3-30 px: real 8 MP frames, and the bounded worst case."""
    ours = next((r for r in results if r.name == REFERENCE_SUBJECT and not r.error), None)
    if ours is None:
        return "real-ground targets: not measured (ours did not run)"
    k = RANGES.index((3.0, 30.0))
    real = [
        t
        for g, ground in enumerate(found)
        if ground.name in REAL_8MP
        for t in ours.timings[g][k].times_ms
    ]
    lines = []
    if real:
        median, worst = float(np.median(real)), max(real)
        lines.append(
            f"real 8 MP frames at 3-30 px ({len(real)}): median {median:.0f} ms "
            f"{_judged(median, TARGET_REAL_MEDIAN_MS)}, slowest {worst:.0f} ms "
            f"{_judged(worst, TARGET_REAL_WORST_MS)}"
        )
    bound = [
        (ground, ours.timings[g][j])
        for g, ground in enumerate(found)
        for j in range(len(RANGES))
        if ground.frames[0].size >= 12_000_000
    ]
    if bound:
        worst_ms = max(max(t.times_ms) for _, t in bound)
        worst_mb = max(t.peak_mb for _, t in bound)
        lines.append(
            f"every 12 MP frame, both ranges: slowest {worst_ms:.0f} ms "
            f"{_judged(worst_ms, TARGET_BOUND_MS)}, peak memory growth "
            f"{worst_mb:.0f} MiB {_judged(worst_mb, TARGET_BOUND_MB)}"
        )
    return "\n".join(lines)


def run(
    subjects: Sequence[str], seed: int, folder: Path, report: Callable[[str], None]
) -> dict[str, Any]:
    """Time the subjects on every ground; report the table and the targets; return figures."""
    found = grounds(real_data.data_root(), seed, report)
    frames_path = folder / "grounds.npz"
    save_grounds(found, frames_path)
    results = run_subjects(subjects, frames_path, [len(ground.frames) for ground in found])
    report(
        "Real ground: time per frame on one core, one detection per frame after a warm-up "
        "per ground and range, the subjects in turn frame by frame; ours/peer = median of the "
        "paired ratios;\nworst = slowest frame; peak MiB = the warm-up detection's "
        "peak of allocated arrays (tracemalloc); pts/frame = points returned"
    )
    report(ground_table(found, results))
    report(verdict(found, results))
    return {
        r.name: {
            "error": r.error,
            "grounds": {
                ground.label: {
                    range_text(rr): r.timings[g][k].__dict__ for k, rr in enumerate(RANGES)
                }
                for g, ground in enumerate(found)
            }
            if not r.error
            else {},
        }
        for r in results
    }


def main(argv: list[str] | None = None) -> int:
    """Worker entry point (the driver is ``bench speed``)."""
    parser = argparse.ArgumentParser(prog="python -m marker_localizer.bench.ground")
    parser.add_argument("--worker", required=True)
    parser.add_argument("--frames-file", type=Path, required=True)
    args = parser.parse_args(argv)
    return worker_main(args.worker, args.frames_file)


if __name__ == "__main__":
    raise SystemExit(main())
