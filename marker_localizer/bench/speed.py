"""Speed benchmark: full-frame detection time and memory, ours against peers, on one core.

``marker-localizer bench speed`` (or ``python -m marker_localizer.bench.speed``)
renders three cluttered 4096 x 3000 frames once (24 markers of radius 6-40 px,
400 hard negatives, strong light gradient, shadows: the accuracy benchmark's
family (d)), then runs every subject in a fresh subprocess on those same frames:

* this detector (default ``refinement="symmetry"``, and ``"ncc"``; radius range
  6-40 px), with its per-stage times from ``DetectionResult.timings_ms``;
* the OpenCV Hessian-saddle + cornerSubPix detector and chess-corners (ChESS,
  Radon) from :mod:`marker_localizer.bench.peers`;
* tracking mode (``marker_localizer.core.tracking.MarkerTracker``) on whole
  4096 x 3000 views panning over a ground of the same clutter with 20 markers
  (the issue's target is for 10-20 markers in view).

A second table times this detector and the peers on real ground, the flight
simulator's and two worst cases, at radius 3-30 and 6-40 px
(:mod:`marker_localizer.bench.ground`).

Each subprocess runs with ``OMP_NUM_THREADS`` / ``OPENBLAS_NUM_THREADS`` /
``MKL_NUM_THREADS`` = 1 set before numpy loads and ``cv2.setNumThreads(1)``: the
"one core" figure. The subjects are timed in rounds: each worker, warmed up
(one untimed detection per frame), times one frame when asked, and every frame
of a round goes to every subject in turn before the next frame, so a change in
the shared host's load falls on all of them alike. Times are the median and
95th percentile over every (frame, round) pair; ``ours/peer`` is the median,
over those pairs, of our time over the peer's on the same frame in the same
round (:func:`workers.paired_ratio`).

Peak memory: in the fresh subprocess, after the frames are loaded and the
detector is built, the kernel's peak-RSS mark is reset (``/proc/self/clear_refs``)
and the warm-up detections run; the growth is VmHWM after minus VmRSS before:
the detector's peak working memory, whole process (numpy, OpenCV and native
allocations alike). Where the mark cannot be reset it falls back to the growth
of ``resource.getrusage(RUSAGE_SELF).ru_maxrss``.
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from marker_localizer.bench import workers
from marker_localizer.bench.runner import add_json_option, run_and_save
from marker_localizer.cli.arguments import comma_keys, count_type, seed_type

#: Subjects in table order, by the short key ``--subjects`` takes; "ours (symmetry)"
#: is the row every ratio divides by. "paper" (the paper's pipeline end to end, seconds
#: per frame) runs only when asked for.
SUBJECTS = {
    "symmetry": "ours (symmetry)",
    "ncc": "ours (ncc, paper)",
    "paper": "ours (paper: curvature+ncc)",
    "tracking": "ours (tracking)",
    "hessian": "OpenCV Hessian+cornerSubPix",
    "chess": "chess-corners chess",
    "radon": "chess-corners radon",
}
REFERENCE_SUBJECT = "ours (symmetry)"
#: The peer of the issue's ratio target.
HESSIAN_SUBJECT = SUBJECTS["hessian"]
#: The issue's targets for the "one core" figure.
TARGET_MEDIAN_MS = 200.0
TARGET_RATIO_TO_HESSIAN = 0.5
TARGET_TRACKING_MS = 20.0
#: Marker radius range given to our detector and the peers, px (family (d)).
RADIUS_RANGE = (6.0, 40.0)
FRAME_WIDTH, FRAME_HEIGHT = 4096, 3000


def cluttered_scene(width: int = FRAME_WIDTH, height: int = FRAME_HEIGHT) -> Any:
    """The SceneConfig of the timed frames: the accuracy benchmark's family (d)."""
    from marker_localizer.synthetic import SceneConfig  # noqa: PLC0415

    return SceneConfig(
        width=width,
        height=height,
        n_markers=24,
        radius_px=RADIUS_RANGE,
        blur_sigma_px=(0.5, 1.5),
        noise_sigma_dn=(0.0, 4.0),
        max_tilt_deg=60.0,
        n_hard_negatives=400,
        illumination_strength=1.0,
        n_shadows=4,
    )


def render_frames(n_frames: int, seed: int) -> list[np.ndarray]:
    """Render the cluttered 4096 x 3000 frames every subject is timed on (uint8)."""
    from marker_localizer.synthetic import render_scene  # noqa: PLC0415

    config = cluttered_scene()
    return [render_scene(config, seed * 1000 + i).image for i in range(n_frames)]


# --------------------------------------------------------------------------- worker side


def _as_given(frame: np.ndarray) -> np.ndarray:
    return frame


@dataclass(frozen=True)
class Subject:
    """What a worker times: ``run`` on the image that ``prepare`` makes from a frame.

    ``prepare`` is not timed: it stands for the camera delivering the frame.
    ``run`` returns the stage timings in ms (empty for peers).
    """

    run: Callable[[np.ndarray], dict[str, float]]
    prepare: Callable[[np.ndarray], np.ndarray] = _as_given


def _make_subject(name: str) -> Subject:
    """Build the subject called ``name``."""
    from marker_localizer.bench import peers  # noqa: PLC0415 - after the thread settings

    if name.startswith("ours"):
        if name == "ours (tracking)":
            return _make_tracking_subject()
        variant = next(v for v in peers.our_variants() if v.name == name)
        detector = variant.detector(RADIUS_RANGE)
        return Subject(lambda image: dict(detector.detect(image).timings_ms))
    chosen = next((p for p in peers.point_detectors() if p.name == name), None)
    if chosen is None:
        raise RuntimeError(f"{name}: {'; '.join(peers.unavailable_peers())}")

    def run_peer(image: np.ndarray) -> dict[str, float]:
        chosen.detect(image, RADIUS_RANGE)
        return {}

    return Subject(run_peer)


#: Image motion per frame of the tracking-mode sequence, px (x, y).
TRACKING_STEP_PX = (3, 2)
#: Frames of the tracking sequence before it starts over (a fresh tracker).
TRACKING_SEQUENCE = 32
#: Markers on the ground the tracking sequence pans over: the issue's target is for
#: 10-20 markers in view, and this is its upper end (the full-frame scene has 24).
TRACKING_MARKERS = 20


def render_tracking_base(seed: int) -> np.ndarray:
    """The ground the tracking sequence pans over: the timed frames' clutter, 20 markers.

    Larger than a frame by the sequence's motion, so that every view is a whole
    4096 x 3000 frame.
    """
    from marker_localizer.synthetic import render_scene  # noqa: PLC0415

    dx, dy = TRACKING_STEP_PX
    scene = replace(
        cluttered_scene(
            FRAME_WIDTH + TRACKING_SEQUENCE * dx, FRAME_HEIGHT + TRACKING_SEQUENCE * dy
        ),
        n_markers=TRACKING_MARKERS,
    )
    return render_scene(scene, seed * 1000 + 999).image


def tracking_view(base: np.ndarray, step: int) -> np.ndarray:
    """Frame ``step`` of a camera panning over ``base``: a crop moved by TRACKING_STEP_PX.

    Every crop has the same size (the base less TRACKING_SEQUENCE steps of
    motion), so markers enter and leave across the border as in flight.
    """
    dx, dy = TRACKING_STEP_PX
    height, width = base.shape[:2]
    k = step % TRACKING_SEQUENCE
    return base[
        k * dy : height - TRACKING_SEQUENCE * dy + k * dy,
        k * dx : width - TRACKING_SEQUENCE * dx + k * dx,
    ]


def _make_tracking_subject() -> Subject:
    """Tracking mode on a panning sequence over the ground it is given as its frame.

    The worker gives it :func:`render_tracking_base`. The k-th prepared image is
    :func:`tracking_view` (base, k), copied into its own buffer as a camera
    delivers it (the copy of a strided crop is not the tracker's work); it is
    tracked with a time stamp of k + 1 seconds. The warm-up calls let every track
    get a velocity, so the timed calls are the tracker's steady state (the fit
    confirming the tracked markers, and the border bands), with its full-frame
    passes (every ``tracker.full_frame_every`` frames, or when a marker is not
    confirmed) amortised in.
    """
    from marker_localizer.config import DetectorConfig  # noqa: PLC0415
    from marker_localizer.core.pipeline import Detector  # noqa: PLC0415
    from marker_localizer.core.tracking import MarkerTracker  # noqa: PLC0415

    config = DetectorConfig(
        marker_radius_min_px=RADIUS_RANGE[0], marker_radius_max_px=RADIUS_RANGE[1]
    )
    detector = Detector(config)
    state: dict[str, Any] = {"base": None, "step": 0, "tracker": None}

    def next_view(frame: np.ndarray) -> np.ndarray:
        if state["step"] % TRACKING_SEQUENCE == 0:
            state["base"] = frame if state["base"] is None else state["base"]
            state["tracker"] = MarkerTracker(detector)
        view = np.ascontiguousarray(tracking_view(state["base"], state["step"]))
        state["step"] += 1
        return view

    def track(view: np.ndarray) -> dict[str, float]:
        result = state["tracker"].update(view, float(state["step"]))
        return {"full_frame_passes": float(result.counts.get("full_frame", 0))}

    return Subject(track, next_view)


@dataclass
class WorkerResult:
    """What one subject's subprocess measured.

    Attributes:
        name: subject.
        times_ms: wall time of every timed detection, ms.
        kernel_ms: the kernel's processor time within each (system time: mostly the
            page faults of the fresh memory a detection writes; the kernel splits a
            process's time between it and user time in ticks of a few ms), ms.
        stages_ms: per-stage times of every timed detection (ours only), ms.
        rss_growth_mb: peak RSS growth around the warm-up detections, MiB.
        error: why the subject could not run ("" when it ran).
    """

    name: str
    times_ms: list[float] = field(default_factory=list)
    kernel_ms: list[float] = field(default_factory=list)
    stages_ms: list[dict[str, float]] = field(default_factory=list)
    rss_growth_mb: float = float("nan")
    error: str = ""


def _max_rss_mb() -> float:
    """Peak resident set size of this process so far, MiB (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _status_mb(key: str) -> float:
    """A ``/proc/self/status`` memory figure (``VmRSS``, ``VmHWM``), MiB; NaN if unreadable."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(f"{key}:"):
                return float(line.split()[1]) / 1024.0
    except OSError:
        pass
    return float("nan")


def _reset_peak_rss() -> bool:
    """Reset the kernel's peak-RSS mark (VmHWM) to the current RSS; False where unsupported."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        return False
    return True


def peak_growth_mb(work: Callable[[], object]) -> float:
    """Peak RSS growth while ``work`` runs, MiB.

    With a resettable peak (Linux >= 4.0): VmHWM after minus VmRSS before, after
    resetting VmHWM, so earlier peaks (imports, loading) do not hide it.
    Elsewhere: growth of ``ru_maxrss``, which misses peaks below earlier ones.
    """
    if _reset_peak_rss():
        before = _status_mb("VmRSS")
        work()
        return _status_mb("VmHWM") - before
    before = _max_rss_mb()
    work()
    return _max_rss_mb() - before


def _kernel_s() -> float:
    """System processor time of this process so far, s."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_stime


def _timed(subject: Subject, frame: np.ndarray) -> tuple[float, float, dict[str, float]]:
    """One timed detection: wall time and the kernel's time in it, ms; ``run``'s stage times."""
    image = subject.prepare(frame)
    kernel = _kernel_s()
    start = time.perf_counter()
    stages = subject.run(image)
    elapsed = time.perf_counter() - start
    return elapsed * 1000.0, (_kernel_s() - kernel) * 1000.0, stages


def worker_main(name: str, frames_path: Path) -> int:
    """Subprocess entry: warm up one subject, then time each frame asked for.

    Ready (:func:`workers.serve`): ``rss_growth_mb``, ``warm_up_s`` (a frame's) and
    ``error``; asked a frame index: its ``ms``, ``kernel_ms`` and ``stages``.
    """
    import cv2  # noqa: PLC0415

    cv2.setNumThreads(1)
    with np.load(frames_path) as archive:
        frames = [archive[key] for key in sorted(archive.files) if key.startswith("frame")]
        if name == SUBJECTS["tracking"]:
            frames = [archive["tracking_base"]] * len(frames)
    try:
        subject = _make_subject(name)
    except ImportError as err:
        workers.serve({"rss_growth_mb": float("nan"), "error": str(err)}, None)
        return 0
    start = time.perf_counter()
    grown = peak_growth_mb(lambda: [subject.run(subject.prepare(frame)) for frame in frames])
    warm_up_s = (time.perf_counter() - start) / len(frames)

    def answer(request: str) -> dict[str, Any]:
        elapsed_ms, kernel_ms, stages = _timed(subject, frames[int(request)])
        return {"ms": elapsed_ms, "kernel_ms": kernel_ms, "stages": stages}

    workers.serve({"rss_growth_mb": grown, "warm_up_s": warm_up_s, "error": ""}, answer)
    return 0


# --------------------------------------------------------------------------- driver side


def run_subjects(
    names: Sequence[str], frames_path: Path, n_frames: int, repeats: int
) -> list[WorkerResult]:
    """Time every subject in rounds, each in its own warmed-up subprocess.

    The workers start (and warm up) one after another; then each round gives
    every frame to every running subject in turn, the subjects' order rotating
    from one frame to the next, so that no subject always follows the same one.
    Subjects whose warm-up took over :data:`workers.IN_TURN_MAX_S` a frame run
    their rounds after the others', who take one untimed turn on the first frame
    before theirs (:func:`workers.settled_groups`).
    A worker that fails is reported with its error and left out of later rounds.
    """
    results = [WorkerResult(name) for name in names]
    with workers.started("marker_localizer.bench.speed", names, frames_path) as started:
        for worker, result in zip(started, results, strict=True):
            result.rss_growth_mb = float(worker.ready.get("rss_growth_mb", float("nan")))
        warm_up_s = [float(worker.ready.get("warm_up_s", float("nan"))) for worker in started]
        for group in workers.settled_groups(started, warm_up_s, "0"):
            for _ in range(repeats):
                for index in range(n_frames):
                    for position in workers.in_turn(started, index, group):
                        reply = started[position].ask(str(index))
                        if reply is not None:
                            result = results[position]
                            result.times_ms.append(float(reply["ms"]))
                            result.kernel_ms.append(float(reply["kernel_ms"]))
                            if reply["stages"]:
                                result.stages_ms.append(reply["stages"])
        for worker, result in zip(started, results, strict=True):
            result.error = worker.error
    return results


def available_subjects(include_ncc: bool = True) -> list[str]:
    """Subjects that can run here, in table order."""
    from marker_localizer.bench import peers  # noqa: PLC0415

    names = [REFERENCE_SUBJECT]
    if include_ncc:
        names.append("ours (ncc, paper)")
    names.append("ours (tracking)")
    return names + [p.name for p in peers.point_detectors()]


def _median(values: Sequence[float]) -> float:
    return float(np.median(values)) if len(values) else float("nan")


def _p95(values: Sequence[float]) -> float:
    return float(np.percentile(values, 95)) if len(values) else float("nan")


def stage_medians(stages: Sequence[dict[str, float]]) -> dict[str, float]:
    """Median time of every stage over the runs, ms, in the pipeline's order."""
    names = list(stages[0]) if stages else []
    return {stage: _median([s.get(stage, float("nan")) for s in stages]) for stage in names}


def _wall_times(result: WorkerResult) -> list[float]:
    """A subject's frame times on the wall clock, ms."""
    return result.times_ms


def _without_kernel(result: WorkerResult) -> list[float]:
    """A subject's frame times less the kernel's time within each, ms (at least 0)."""
    return [max(t - k, 0.0) for t, k in zip(result.times_ms, result.kernel_ms, strict=True)]


def _reference_times(
    results: Sequence[WorkerResult],
    times: Callable[[WorkerResult], list[float]] = _wall_times,
) -> list[float]:
    """Our detector's frame times (``times`` of its result), ms, in the order timed.

    Empty where it did not run.
    """
    return next((times(r) for r in results if r.name == REFERENCE_SUBJECT), [])


def _subject_times(
    results: Sequence[WorkerResult],
    times: Callable[[WorkerResult], list[float]] = _wall_times,
) -> dict[str, list[float]]:
    """Each subject's frame times (``times`` of its result), ms, in the order timed.

    Subjects that failed are left out.
    """
    return {r.name: times(r) for r in results if not r.error}


def speed_table(results: Sequence[WorkerResult]) -> str:
    """Format the timing table (ms, MiB) with ratios ours / peer."""
    ours = _reference_times(results)
    header = (
        f"{'subject':<32}{'median ms':>11}{'p95 ms':>10}{'kernel ms':>11}{'runs':>6}"
        f"{'RSS +MiB':>10}{'ours/peer':>11}"
    )
    lines = [header, "-" * len(header)]
    for r in results:
        if r.error:
            lines.append(f"{r.name:<32}  not run: {r.error}")
            continue
        median = _median(r.times_ms)
        # Ratios compare ours with peers; our own variants get none.
        ratio = (
            float("nan") if r.name.startswith("ours") else workers.paired_ratio(ours, r.times_ms)
        )
        lines.append(
            f"{r.name:<32}{median:>11.1f}{_p95(r.times_ms):>10.1f}"
            f"{_median(r.kernel_ms):>11.1f}{len(r.times_ms):>6}{r.rss_growth_mb:>10.1f}"
            f"{'-' if not np.isfinite(ratio) else f'{ratio:.2f}':>11}"
        )
    return "\n".join(lines)


def stages_table(results: Sequence[WorkerResult]) -> str:
    """Format the per-stage medians of our variants, ms."""
    ours = [r for r in results if r.stages_ms and r.name != SUBJECTS["tracking"]]
    if not ours:
        return ""
    stages = list(stage_medians(ours[0].stages_ms))
    width = max(22, *(len(r.name) + 2 for r in ours))
    header = f"{'stage (median ms)':<20}" + "".join(f"{r.name:>{width}}" for r in ours)
    lines = [header, "-" * len(header)]
    for stage in stages:
        cells = "".join(
            f"{stage_medians(r.stages_ms).get(stage, float('nan')):>{width}.1f}" for r in ours
        )
        lines.append(f"{stage:<20}{cells}")
    return "\n".join(lines)


def verdict(results: Sequence[WorkerResult]) -> str:
    """One line on the issue's targets: full frame, ratio to the Hessian peer, tracking."""
    times = _subject_times(results)
    by_name = {name: _median(values) for name, values in times.items()}
    ours = by_name.get(REFERENCE_SUBJECT, float("nan"))
    ratio = workers.paired_ratio(times.get(REFERENCE_SUBJECT, []), times.get(HESSIAN_SUBJECT, []))
    if not (np.isfinite(ours) and np.isfinite(ratio)):
        return "targets: not measured (ours or the Hessian peer did not run)"
    line = (
        f"targets: median {ours:.0f} ms (target <= {TARGET_MEDIAN_MS:.0f} ms: "
        f"{'met' if ours <= TARGET_MEDIAN_MS else 'missed'}); ours/Hessian "
        f"{ratio:.2f} (target <= {TARGET_RATIO_TO_HESSIAN}: "
        f"{'met' if ratio <= TARGET_RATIO_TO_HESSIAN else 'missed'})"
    )
    tracking = by_name.get(SUBJECTS["tracking"])
    if tracking is not None:
        line += (
            f"; tracking median {tracking:.0f} ms (target <= {TARGET_TRACKING_MS:.0f} ms: "
            f"{'met' if tracking <= TARGET_TRACKING_MS else 'missed'})"
        )
    return line


def ratio_by_frame(results: Sequence[WorkerResult], n_frames: int) -> str:
    """One line: ours over the Hessian peer frame by frame, each the median over the rounds.

    The table's ours/peer is the median over every pair; a frame whose ground
    passes many more candidates to the checks shows apart here.
    """
    times = _subject_times(results)
    if REFERENCE_SUBJECT not in times or HESSIAN_SUBJECT not in times:
        return ""
    ratios = workers.paired_ratios_by_frame(
        times[REFERENCE_SUBJECT], times[HESSIAN_SUBJECT], n_frames
    )
    cells = " / ".join("-" if not np.isfinite(r) else f"{r:.2f}" for r in ratios)
    return f"ours/Hessian frame by frame (median over the rounds): {cells}"


def ratio_without_kernel(results: Sequence[WorkerResult]) -> str:
    """One line: ours over the Hessian peer with each side's kernel time taken out.

    The kernel's time in a detection is mostly the page faults of the memory it
    allocates afresh, which a shared host serves at a cost that moves from run to
    run, and the Hessian's 12 MP float arrays take most of it: so the wall clock's
    ratio, the target's, moves with the host on code that does not change
    (measured: docs/speed.md, "Two runs on unchanged code"). This one shows by how
    much.
    """
    times = _subject_times(results, _without_kernel)
    if REFERENCE_SUBJECT not in times or HESSIAN_SUBJECT not in times:
        return ""
    ratio = workers.paired_ratio(times[REFERENCE_SUBJECT], times[HESSIAN_SUBJECT])
    return (
        f"ours/Hessian with each side's kernel time left out: {ratio:.2f} "
        "(the target is the wall clock's ratio above)"
    )


@dataclass(frozen=True)
class Options:
    """What one run measures.

    Attributes:
        frames: rendered frames (all subjects use the same ones).
        repeats: timed passes over the frames per subject.
        seed: rendering seed.
        subjects: subjects to run (None: every available one).
        ground: also time the real-ground table (ours and the peers among the subjects).
    """

    frames: int = 3
    repeats: int = 3
    seed: int = 0
    subjects: tuple[str, ...] | None = None
    ground: bool = True


def run(options: Options, report: Callable[[str], None] = print) -> dict[str, Any]:
    """Render once, measure every subject in its own subprocess, report the tables."""
    from marker_localizer.bench import ground, peers  # noqa: PLC0415

    for line in peers.unavailable_peers():
        report(line)
    names = list(options.subjects) if options.subjects else available_subjects()
    frames = render_frames(options.frames, options.seed)
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as folder:
        frames_path = Path(folder) / "frames.npz"
        arrays = {f"frame{i:02d}": f for i, f in enumerate(frames)}
        if SUBJECTS["tracking"] in names:
            arrays["tracking_base"] = render_tracking_base(options.seed)
        workers.save_frames(frames_path, arrays)
        results = run_subjects(names, frames_path, len(frames), options.repeats)
    report_load(load_before, report)
    report(
        f"Full-frame detection, {options.frames} rendered {FRAME_WIDTH}x{FRAME_HEIGHT} "
        f"cluttered frames x {options.repeats} repeats, one core (cv2.setNumThreads(1), "
        f"OMP/OPENBLAS/MKL threads = 1), radius range {RADIUS_RANGE[0]:g}-"
        f"{RADIUS_RANGE[1]:g} px; kernel ms = median system time within a detection "
        "(mostly page faults on memory it allocates afresh); RSS + = peak RSS growth "
        "(VmHWM) in a fresh subprocess; subjects timed in turn, frame by frame, those "
        f"over {workers.IN_TURN_MAX_S:g} s a frame after the others; ours/peer = median "
        "of the paired ratios"
    )
    report(speed_table(results))
    stages = stages_table(results)
    if stages:
        report(stages)
    for r in results:
        if r.name == SUBJECTS["tracking"] and r.stages_ms:
            full = sum(s.get("full_frame_passes", 0.0) for s in r.stages_ms)
            report(
                f"ours (tracking): {full:.0f} of {len(r.stages_ms)} timed frames needed a "
                f"full-frame pass (panning over {TRACKING_MARKERS} markers, "
                f"{TRACKING_STEP_PX} px per frame)"
            )
    report(verdict(results))
    for line in (ratio_by_frame(results, len(frames)), ratio_without_kernel(results)):
        if line:
            report(line)
    on_ground: dict[str, Any] = {}
    if options.ground:
        others = [n for n in names if not n.startswith("ours")]
        load_before = os.getloadavg()[0]
        with tempfile.TemporaryDirectory() as folder:
            on_ground = ground.run([REFERENCE_SUBJECT, *others], options.seed, Path(folder), report)
        report_load(load_before, report)
    # Each subject's "ours_over" is the median of ours over its time, frame by frame
    # (workers.paired_ratio): the table's ours/peer; "ours_over_by_frame" the same per
    # frame, over the rounds (workers.paired_ratios_by_frame); "ours_over_without_kernel"
    # the first with each side's kernel time taken out (ratio_without_kernel).
    ours = _reference_times(results)
    ours_user = _reference_times(results, _without_kernel)
    return {
        "frames": options.frames,
        "repeats": options.repeats,
        "seed": options.seed,
        "ground": on_ground,
        "subjects": {
            r.name: {
                "median_ms": _median(r.times_ms),
                "ours_over": workers.paired_ratio(ours, r.times_ms),
                "ours_over_by_frame": workers.paired_ratios_by_frame(ours, r.times_ms, len(frames)),
                "ours_over_without_kernel": workers.paired_ratio(ours_user, _without_kernel(r)),
                "p95_ms": _p95(r.times_ms),
                "times_ms": r.times_ms,
                "kernel_ms": r.kernel_ms,
                "rss_growth_mb": r.rss_growth_mb,
                "stages_median_ms": stage_medians(r.stages_ms),
                "error": r.error,
            }
            for r in results
        },
    }


def report_load(before: float, report: Callable[[str], None]) -> None:
    """Report the load average: other processes on the machine inflate every time."""
    report(
        f"load average (1 min) before / after the measurements: {before:.1f} / "
        f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs"
    )


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """Parse the command line (the driver's options and the hidden worker ones)."""
    parser = argparse.ArgumentParser(
        allow_abbrev=False,
        prog="marker-localizer bench speed",
        description="Full-frame detection time on one core: ours against peers.",
    )
    parser.add_argument("--frames", type=count_type, default=3, help="rendered frames (default 3)")
    parser.add_argument(
        "--repeats",
        type=count_type,
        default=None,
        help="timed passes over the frames (default 3; 1 with --quick)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="one timed pass, no ncc variant, no real-ground table (< 2 minutes)",
    )
    parser.add_argument(
        "--no-ground", action="store_true", help="leave out the real-ground table (several minutes)"
    )
    parser.add_argument(
        "--seed", type=seed_type, default=0, help="rendering seed (default: %(default)s)"
    )
    parser.add_argument(
        "--subjects",
        type=comma_keys(tuple(SUBJECTS), "subjects"),
        default=None,
        help=f"comma-separated subset of {','.join(SUBJECTS)}",
    )
    add_json_option(parser)
    parser.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--frames-file", type=Path, default=None, help=argparse.SUPPRESS)
    return parser.parse_args(argv)


def options_from(args: argparse.Namespace) -> Options:
    """Turn parsed arguments into :class:`Options`."""
    repeats = args.repeats if args.repeats is not None else (1 if args.quick else 3)
    subjects = None
    if args.subjects:
        subjects = tuple(SUBJECTS[key] for key in args.subjects)
    elif args.quick:
        subjects = tuple(available_subjects(include_ncc=False))
    return Options(
        frames=args.frames,
        repeats=repeats,
        seed=args.seed,
        subjects=subjects,
        ground=not (args.quick or args.no_ground),
    )


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    args = parse_args(argv)
    if args.worker is not None:
        return worker_main(args.worker, args.frames_file)
    return run_and_save(
        "speed benchmark", lambda report: run(options_from(args), report), args.json
    )


if __name__ == "__main__":
    raise SystemExit(main())
