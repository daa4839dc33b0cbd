"""FrameProcessor, the node's and replay's worker pool: mailboxes, order, age, failures, stop."""

import array
import contextlib
import errno
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from encoded_images import compressed_message, transport_encoded
from node_testing import (
    TIMEOUT_S,
    Collector,
    clock_at,
    mapped_shared_memory_blocks,
    serving,
    shared_memory_blocks,
    stamped,
    wait_until,
    worker_process_ids,
    x_marker_64,
)
from scenes import panning_frames

from marker_localizer.config import DetectorConfig, TrackerConfig
from marker_localizer.core.result import DetectionResult
from marker_localizer.errors import ImageError, WorkerError
from marker_localizer.ros import processing
from marker_localizer.ros.diagnostics import DiagnosticThresholds
from marker_localizer.ros.processing import FrameProcessor

# --------------------------------------------------------------------------- FrameProcessor


def test_mailbox_keeps_only_the_newest_frame_and_counts_the_replaced_ones():
    collect = Collector()
    processor = FrameProcessor(
        ["cam0"], DetectorConfig(), collect, workers=1, clock_ns=clock_at(10)
    )
    try:
        collect.release.clear()
        processor.submit("cam0", stamped(1))
        wait_until(collect.entered.is_set, "the worker to take frame 1")
        processor.submit("cam0", stamped(2))
        processor.submit("cam0", stamped(3))  # replaces frame 2
        collect.release.set()
        assert processor.wait_idle(TIMEOUT_S)
    finally:
        processor.shutdown()
    assert collect.results == [("cam0", 1, 1), ("cam0", 3, 1)]
    snap = processor.snapshots()["cam0"]
    assert (snap.received, snap.processed, snap.dropped_mailbox) == (3, 2, 1)


def test_camera_waiting_longest_is_served_first_even_if_its_frame_was_replaced():
    collect = Collector()
    now = [0]
    processor = FrameProcessor(
        ["a", "b", "c"], DetectorConfig(), collect, workers=1, clock_ns=lambda: now[0]
    )
    try:
        collect.release.clear()
        processor.submit("a", stamped(1))
        wait_until(collect.entered.is_set, "the worker to take a's frame")
        for camera, sec in [("b", 2), ("c", 3), ("a", 4), ("b", 5)]:  # b's frame 2 replaced
            now[0] += 1
            processor.submit(camera, stamped(sec))
        collect.release.set()
        assert processor.wait_idle(TIMEOUT_S)
    finally:
        processor.shutdown()
    assert [(c, s) for c, s, _ in collect.results] == [("a", 1), ("b", 5), ("c", 3), ("a", 4)]


class OneAtATime(Collector):
    """Result callback that holds each frame's worker until :meth:`let_one_go`."""

    def __init__(self):
        super().__init__()
        self._permits = threading.Semaphore(0)
        self._entered = threading.Condition()

    def __call__(self, camera, cloud):
        with self._entered:
            self.results.append((camera, cloud.header.stamp.sec, cloud.width))
            self._entered.notify_all()
        self._permits.acquire(timeout=TIMEOUT_S)

    def let_one_go(self):
        self._permits.release()

    def wait_for(self, count):
        with self._entered:
            assert self._entered.wait_for(lambda: len(self.results) >= count, TIMEOUT_S)


def test_the_camera_served_least_recently_goes_first_though_its_frame_arrived_later():
    """Synchronised cameras' frames arrive in one order; served in it, the first gain.

    a is served, then b, then c; b's next frame arrives before a's. a has waited
    since its last turn longer than b has: a goes first.
    """
    collect = OneAtATime()
    now = [0]
    processor = FrameProcessor(
        ["a", "b", "c"], DetectorConfig(), collect, workers=1, clock_ns=lambda: now[0]
    )

    def submit(camera, sec):
        now[0] += 1
        processor.submit(camera, stamped(sec))

    try:
        submit("a", 1)
        collect.wait_for(1)
        submit("b", 2)
        submit("c", 3)
        for served in (2, 3):
            collect.let_one_go()
            collect.wait_for(served)
        submit("b", 4)
        submit("a", 5)
        for _ in range(5):
            collect.let_one_go()
        assert processor.wait_idle(TIMEOUT_S)
    finally:
        processor.shutdown()
    assert [(c, s) for c, s, _ in collect.results] == [
        ("a", 1),
        ("b", 2),
        ("c", 3),
        ("a", 5),
        ("b", 4),
    ]


def _aging_processor(cameras, collect, now, **clocks):
    """One worker, frames older than 2 s dropped, on the injected clock ``now[0]`` (ns)."""
    return FrameProcessor(
        cameras,
        DetectorConfig(),
        collect,
        workers=1,
        max_frame_age_s=2.0,
        clock_ns=lambda: now[0],
        **clocks,
    )


def test_frames_that_waited_longer_than_max_age_in_the_node_are_dropped_whatever_their_stamp():
    collect = Collector()
    now = [100 * 10**9]
    processor = _aging_processor(["a", "b"], collect, now)
    try:
        collect.release.clear()
        processor.submit("a", stamped(1))  # stamped 99 s before it arrives: taken at once
        wait_until(collect.entered.is_set, "the worker to take a's frame")
        processor.submit("b", stamped(500))  # from the future; waits behind a's frame
        now[0] += 3 * 10**9  # the worker stays busy 3 s
        collect.release.set()
        assert processor.wait_idle(TIMEOUT_S)
        processor.submit("b", stamped(501), block=True)  # arrives now, taken at once
        assert processor.wait_idle(TIMEOUT_S)
    finally:
        processor.shutdown()
    assert collect.results == [("a", 1, 1), ("b", 501, 1)]
    snap = processor.snapshots()["b"]
    assert (snap.dropped_age, snap.processed) == (1, 1)


@pytest.mark.parametrize(("waited_s", "dropped"), [(3.0, True), (0.5, False)])
def test_a_frame_waiting_while_the_clock_goes_back_is_aged_by_its_real_wait(waited_s, dropped):
    """A bag played again with use_sim_time: on that clock the frame's wait is negative.

    It is measured on the steady clock instead, which the latency is measured on too,
    so that neither is negative nor the frame judged fresh however long it waited.
    """
    collect = Collector()
    now, steady = [1000 * 10**9], [0]
    processor = _aging_processor(["a", "b"], collect, now, steady_ns=lambda: steady[0])
    try:
        collect.release.clear()
        processor.submit("a", stamped(1000))
        wait_until(collect.entered.is_set, "the worker to take a's frame")
        processor.submit("b", stamped(1000))  # waits behind a's frame
        now[0] = 100 * 10**9  # played again from its start
        steady[0] += round(waited_s * 1e9)
        collect.release.set()
        assert processor.wait_idle(TIMEOUT_S)
    finally:
        processor.shutdown()
    snap = processor.snapshots()["b"]
    assert (snap.dropped_age, snap.processed) == ((1, 0) if dropped else (0, 1))
    if not dropped:
        assert snap.latency_p50_ms == pytest.approx(waited_s * 1e3)  # the steady clock stood
    assert snap.since_last_frame_s >= 0.0
    assert processor.snapshots()["a"].latency_p50_ms == pytest.approx(waited_s * 1e3)


def test_blocking_submit_processes_every_frame_in_order_per_camera():
    collect = Collector()
    processor = FrameProcessor(["a", "b"], DetectorConfig(), collect, workers=2)
    try:
        for sec in range(1, 9):
            for camera in ("a", "b"):
                assert processor.submit(camera, stamped(sec), block=True)
        assert processor.wait_idle(TIMEOUT_S)
    finally:
        processor.shutdown()
    for camera in ("a", "b"):
        assert [s for c, s, _ in collect.results if c == camera] == list(range(1, 9))
    assert all(s.dropped_mailbox == s.dropped_age == 0 for s in processor.snapshots().values())


def test_candidates_the_detectors_caps_cut_reach_the_cameras_diagnostics():
    collect = Collector()
    noise = np.random.default_rng(1).integers(0, 256, (64, 64), dtype=np.uint8)
    # The X gives 3 candidates, noise dozens: a cap of 3 cuts the noise's only.
    config = DetectorConfig(max_candidates=3)
    processor = FrameProcessor(
        ["cam0"], config, collect, workers=1, tracker_config=TrackerConfig(enabled=False)
    )
    try:
        assert processor.submit("cam0", stamped(1), block=True)
        assert processor.submit("cam0", stamped(2, noise), block=True)
        assert processor.wait_idle(TIMEOUT_S)
    finally:
        processor.shutdown()
    snap = processor.snapshots()["cam0"]
    assert snap.frames_capped == 1
    assert snap.candidates_capped > 10


def test_shutdown_delivers_the_frame_in_flight_and_discards_waiting_ones():
    collect = Collector()
    processor = FrameProcessor(["cam0"], DetectorConfig(), collect, workers=1)
    collect.release.clear()
    processor.submit("cam0", stamped(1))
    wait_until(collect.entered.is_set, "the worker to take frame 1")
    processor.submit("cam0", stamped(2))  # still waiting in the mailbox at shutdown
    finished = []
    stopper = threading.Thread(target=lambda: finished.append(processor.shutdown()))
    stopper.start()
    wait_until(lambda: not processor.submit("cam0", stamped(3)), "the processor to refuse frames")
    collect.release.set()
    stopper.join(TIMEOUT_S)
    assert finished == [True]  # every worker ended
    assert collect.results == [("cam0", 1, 1)]


def test_failed_frame_is_counted_and_the_worker_goes_on():
    collect = Collector()
    failures = []
    processor = FrameProcessor(
        ["cam0"],
        DetectorConfig(),
        collect,
        workers=1,
        on_error=lambda camera, err: failures.append((camera, err)),
    )
    bad = stamped(1)
    bad.data = array.array("B", bytes(10))
    try:
        processor.submit("cam0", bad, block=True)
        processor.submit("cam0", stamped(2), block=True)
        assert processor.wait_idle(TIMEOUT_S)
    finally:
        processor.shutdown()
    assert collect.results == [("cam0", 2, 1)]
    ((camera, err),) = failures
    assert camera == "cam0"
    assert isinstance(err, ImageError)
    snap = processor.snapshots()["cam0"]
    assert snap.errors == 1
    assert snap.last_error.startswith("ImageError: data holds 10 B")


def test_frame_over_max_pixels_fails_and_the_next_smaller_one_is_served():
    collect = Collector()
    processor = FrameProcessor(["cam0"], DetectorConfig(max_pixels=64 * 64), collect, workers=1)
    try:
        processor.submit("cam0", stamped(1, np.zeros((64, 65), np.uint8)), block=True)
        processor.submit("cam0", stamped(2), block=True)
        assert processor.wait_idle(TIMEOUT_S)
    finally:
        processor.shutdown()
    assert collect.results == [("cam0", 2, 1)]
    snap = processor.snapshots()["cam0"]
    assert snap.last_error == "ImageError: image: 65x64 = 4160 px exceeds max_pixels=4096"


# --------------------------------------------------------------------------- worker processes


def test_worker_processes_find_what_threads_find_and_carry_each_cameras_tracks():
    config = DetectorConfig(marker_radius_min_px=6.0, marker_radius_max_px=20.0)
    frames = panning_frames(4)
    results = {}
    for processes in (False, True):
        processor = FrameProcessor(
            ["a", "b"], config, Collector(), workers=2, worker_processes=processes
        )
        try:
            results[processes] = [
                processor.detect(camera, frame, float(k + 1))
                for k, frame in enumerate(frames)
                for camera in ("a", "b")
            ]
        finally:
            assert processor.shutdown(TIMEOUT_S)
    for threaded, in_process in zip(results[False], results[True], strict=True):
        assert len(in_process.detections) == len(threaded.detections) == 3
        np.testing.assert_allclose(
            [(d.x, d.y) for d in in_process.detections],
            [(d.x, d.y) for d in threaded.detections],
            atol=1e-9,
        )
    # After each camera's first frame, its markers are confirmed by the tracks the
    # worker processes passed back, not found again by full passes.
    assert [r.counts["full_frame"] for r in results[True]] == [1, 1] + [0] * 6
    assert all(r.counts["tracked"] == 3 for r in results[True][2:])


@pytest.mark.parametrize("processes", [False, True], ids=["threads", "processes"])
def test_the_cameras_scheduled_full_passes_fall_on_different_frames(processes):
    """Two cameras started together, a pass every 4 frames: the second's comes 2 frames early."""
    config = DetectorConfig(marker_radius_min_px=6.0, marker_radius_max_px=20.0)
    processor = FrameProcessor(
        ["a", "b"],
        config,
        Collector(),
        workers=1,
        tracker_config=TrackerConfig(full_frame_every=4),
        worker_processes=processes,
    )
    passes: dict[str, list[int]] = {"a": [], "b": []}
    try:
        for k, frame in enumerate(panning_frames(7)):
            for camera in ("a", "b"):
                result = processor.detect(camera, frame, float(k + 1))
                passes[camera].append(result.counts["full_frame"])
    finally:
        assert processor.shutdown(TIMEOUT_S)
    assert passes == {"a": [1, 0, 0, 0, 1, 0, 0], "b": [1, 0, 1, 0, 0, 0, 1]}


def blocks_mapped_here() -> set[str]:
    """The shared memory blocks this test process has mapped: its processors', none of
    the blocks another process on the machine makes and frees meanwhile."""
    return mapped_shared_memory_blocks(os.getpid())


def test_worker_processes_and_the_frames_shared_memory_are_gone_after_shutdown():
    before, mapped = worker_process_ids(), blocks_mapped_here()
    collect = Collector()
    processor = FrameProcessor(["a"], DetectorConfig(), collect, workers=2, worker_processes=True)
    workers = worker_process_ids() - before
    assert len(workers) == 2
    processor.submit("a", stamped(1), block=True)
    assert processor.wait_idle(TIMEOUT_S)
    (block,) = blocks_mapped_here() - mapped  # the block the frame went through
    assert processor.shutdown(TIMEOUT_S)
    assert collect.results == [("a", 1, 1)]
    assert block not in shared_memory_blocks()
    assert block not in blocks_mapped_here()
    wait_until(lambda: not workers & worker_process_ids(), "the worker processes to exit")


def test_a_larger_frame_gets_a_larger_shared_memory_block_and_the_smaller_one_is_unlinked():
    collect = Collector()
    mapped = blocks_mapped_here()
    processor = FrameProcessor(
        ["cam0"], DetectorConfig(), collect, workers=1, worker_processes=True
    )
    try:
        processor.submit("cam0", stamped(1), block=True)
        assert processor.wait_idle(TIMEOUT_S)
        (small,) = blocks_mapped_here() - mapped
        larger = np.pad(x_marker_64(), 32, mode="edge")  # 128 x 128, the X at (63.5, 63.5)
        processor.submit("cam0", stamped(2, larger), block=True)
        assert processor.wait_idle(TIMEOUT_S)
        (large,) = blocks_mapped_here() - mapped
        assert large != small
        assert small not in shared_memory_blocks()
        assert os.path.getsize(f"/dev/shm/{large}") >= larger.nbytes
    finally:
        processor.shutdown(TIMEOUT_S)
    assert collect.results == [("cam0", 1, 1), ("cam0", 2, 1)]
    assert processor.snapshots()["cam0"].errors == 0


def _one_worker_process(collect, failures):
    """A processor of camera cam0 with one worker process, and that process's id."""
    before = worker_process_ids()
    processor = FrameProcessor(
        ["cam0"],
        DetectorConfig(),
        collect,
        workers=1,
        worker_processes=True,
        on_error=lambda camera, err: failures.append(err),
    )
    (worker,) = worker_process_ids() - before
    return processor, worker


def test_a_killed_worker_process_fails_its_frame_and_a_fresh_one_serves_the_next():
    collect = Collector()
    failures = []
    processor, worker = _one_worker_process(collect, failures)
    try:
        os.kill(worker, signal.SIGKILL)  # as the kernel's out-of-memory killer would
        processor.submit("cam0", stamped(1), block=True)
        assert processor.wait_idle(TIMEOUT_S)
        processor.submit("cam0", stamped(2), block=True)
        assert processor.wait_idle(TIMEOUT_S)
    finally:
        processor.shutdown(TIMEOUT_S)
    assert collect.results == [("cam0", 2, 1)]
    (failure,) = failures
    assert isinstance(failure, WorkerError)  # one line in the node's log, no traceback
    assert "its worker process ended abruptly" in str(failure)
    snap = processor.snapshots()["cam0"]
    assert (snap.errors, snap.processed) == (1, 1)


def test_a_killed_worker_process_fails_its_own_frame_not_the_other_workers():
    """Both workers hold a frame (stopped, SIGSTOP); one is killed, the other goes on.

    With one pool for both processes, the death broke the pool: the other camera's
    frame failed too, and both cameras showed ERROR (a soak, 2026-12-06).
    """
    collect, failures = Collector(), []
    before = worker_process_ids()
    processor = FrameProcessor(
        ["cam0", "cam1"],
        DetectorConfig(),
        collect,
        workers=2,
        worker_processes=True,
        on_error=lambda camera, err: failures.append((camera, err)),
    )
    killed, going_on = sorted(worker_process_ids() - before)
    try:
        for worker in (killed, going_on):
            os.kill(worker, signal.SIGSTOP)
        processor.submit("cam0", stamped(1))
        processor.submit("cam1", stamped(1))
        wait_until(lambda: processor.in_flight() == ["cam0", "cam1"], "a frame in each worker")
        os.kill(killed, signal.SIGKILL)
        os.kill(going_on, signal.SIGCONT)
        assert processor.wait_idle(TIMEOUT_S)
        assert going_on in worker_process_ids()  # the other process was not replaced
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(going_on, signal.SIGCONT)
        processor.shutdown(TIMEOUT_S)
    ((failed, failure),) = failures
    assert isinstance(failure, WorkerError)
    (other,) = {"cam0", "cam1"} - {failed}
    assert [result[:2] for result in collect.results] == [(other, 1)]


def test_shutdown_names_the_cameras_whose_waiting_frame_it_discarded():
    collect = Collector()
    processor = FrameProcessor(["a", "b", "c"], DetectorConfig(), collect, workers=1)
    collect.release.clear()
    processor.submit("a", stamped(1))
    wait_until(collect.entered.is_set, "the worker to take a's frame")
    processor.submit("c", stamped(2))
    processor.submit("a", stamped(3))
    assert processor.discarded == []
    finished = []
    stopper = threading.Thread(target=lambda: finished.append(processor.shutdown(TIMEOUT_S)))
    stopper.start()
    wait_until(lambda: processor.discarded == ["a", "c"], "the shutdown to discard them")
    collect.release.set()
    stopper.join(TIMEOUT_S)
    assert finished == [True]
    assert collect.results == [("a", 1, 1)]


def test_a_frame_still_in_a_worker_process_at_the_timeout_is_abandoned_with_its_process():
    """Left alone, the process would finish the frame first, and the node's exit wait for it.

    A stopped worker (SIGSTOP) stands for a frame longer than any timeout.
    """
    collect = Collector()
    failures = []
    processor, worker = _one_worker_process(collect, failures)
    try:
        os.kill(worker, signal.SIGSTOP)
        processor.submit("cam0", stamped(1))
        wait_until(lambda: processor.in_flight() == ["cam0"], "the frame to reach its worker")
        finished = []
        stopper = threading.Thread(
            target=lambda: finished.append(processor.shutdown(0.1)), daemon=True
        )
        stopper.start()
        stopper.join(TIMEOUT_S)
        assert finished == [False]
        assert worker not in worker_process_ids()
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(worker, signal.SIGKILL)
    assert collect.results == []
    assert failures == []  # abandoned, which the shutdown reports, not failed


def test_worker_processes_end_with_a_node_that_was_killed():
    node_code = (
        "import os, sys\n"
        "from marker_localizer.config import DetectorConfig\n"
        "from marker_localizer.ros.processing import FrameProcessor\n"
        "FrameProcessor(['a'], DetectorConfig(), print, workers=2, worker_processes=True)\n"
        "print(os.getpid(), flush=True)\n"
        "sys.stdin.read()\n"
    )
    node = subprocess.Popen(
        [sys.executable, "-c", node_code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        workers = worker_process_ids(int(node.stdout.readline()))
        assert len(workers) == 2
    finally:
        node.kill()  # no shutdown: as a crash or the kernel's out-of-memory killer ends it
        node.communicate()
    wait_until(
        lambda: not any(Path(f"/proc/{pid}").exists() for pid in workers),
        "the worker processes to exit",
    )


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_worker_processes_leave_the_stop_signals_to_the_node(signum):
    collect = Collector()
    before = worker_process_ids()
    processor = FrameProcessor(
        ["cam0"], DetectorConfig(), collect, workers=1, worker_processes=True
    )
    try:
        (worker,) = worker_process_ids() - before
        # What a terminal's Ctrl-C sends to every process of the node's group, and a
        # service manager's stop to every process of its control group.
        os.kill(worker, signum)
        processor.submit("cam0", stamped(1), block=True)
        assert processor.wait_idle(TIMEOUT_S)
        assert worker in worker_process_ids()
    finally:
        processor.shutdown(TIMEOUT_S)
    assert collect.results == [("cam0", 1, 1)]
    assert processor.snapshots()["cam0"].errors == 0


class _Tmpfs:
    """``os.posix_fallocate`` patched: while ``full``, each reservation fails (ENOSPC).

    ``refused`` holds the names of the blocks whose reservation failed.
    """

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.full = True
        self.asked = 0
        self.refused: set[str] = set()
        reserve = os.posix_fallocate

        def fallocate(descriptor: int, offset: int, length: int) -> None:
            if not self.full:
                return reserve(descriptor, offset, length)
            self.asked += 1
            self.refused.add(Path(os.readlink(f"/proc/self/fd/{descriptor}")).name)
            raise OSError(errno.ENOSPC, "No space left on device")

        monkeypatch.setattr(os, "posix_fallocate", fallocate)


@pytest.fixture
def full_tmpfs(monkeypatch):
    # tmpfs out of room (a container's 64 MB /dev/shm that Fast DDS fills): writing
    # an unreserved page there would kill the node with SIGBUS.
    return _Tmpfs(monkeypatch)


def test_frames_shared_memory_has_no_room_for_go_pickled_and_are_counted(full_tmpfs):
    mapped = blocks_mapped_here()
    collect = Collector()
    processor = FrameProcessor(
        ["cam0"], DetectorConfig(), collect, workers=1, worker_processes=True
    )
    try:
        for sec in (1, 2):
            processor.submit("cam0", stamped(sec), block=True)
        assert processor.wait_idle(TIMEOUT_S)
        # The block whose pages tmpfs had no room for is gone, and no other was made.
        assert len(full_tmpfs.refused) == 1
        assert not full_tmpfs.refused & shared_memory_blocks()
        assert blocks_mapped_here() == mapped
    finally:
        processor.shutdown(TIMEOUT_S)
    assert collect.results == [("cam0", 1, 1), ("cam0", 2, 1)]
    assert processor.frames_pickled == 2
    # Each ask fills tmpfs for a moment, which Fast DDS shares: the next frames do not.
    assert full_tmpfs.asked == 1
    thresholds = DiagnosticThresholds(1000.0, 2.0, 10.0, 0.1, 0.0)
    (*_, node) = processor.diagnostics("loc", Time(), thresholds).status
    values = {v.key: v.value for v in node.values}
    assert values["frames pickled (no room in shared memory)"] == "2"


def test_a_worker_asks_shared_memory_for_room_again_after_some_frames(full_tmpfs, monkeypatch):
    monkeypatch.setattr(processing, "NO_ROOM_RETRY_FRAMES", 2)
    collect = Collector()
    processor = FrameProcessor(
        ["cam0"], DetectorConfig(), collect, workers=1, worker_processes=True
    )
    try:
        for sec in range(1, 6):
            processor.submit("cam0", stamped(sec), block=True)
            assert processor.wait_idle(TIMEOUT_S)
        asked_with_room_gone = full_tmpfs.asked
        full_tmpfs.full = False
        for sec in range(6, 9):
            processor.submit("cam0", stamped(sec), block=True)
            assert processor.wait_idle(TIMEOUT_S)
    finally:
        processor.shutdown(TIMEOUT_S)
    # Frames 1 and 4 ask (2 and 3 wait), 7 asks again and finds room: 8 follows it.
    assert asked_with_room_gone == 2
    assert processor.frames_pickled == 6
    assert [sec for _, sec, _ in collect.results] == list(range(1, 9))


# --------------------------------------------------------------------------- compressed frames


def compressed(sec, pixels=None, kind="jpeg"):
    """:func:`stamped`'s frame as image_transport's compressed plugin sends it."""
    pixels = x_marker_64() if pixels is None else pixels
    return compressed_message(kind, sec, transport_encoded(kind, pixels))


def _decodes_fail_here(monkeypatch):
    """Every decode in this process fails; a worker process's decodes are its own."""

    def refuse(*args, **kwargs):
        raise ImageError("decoded in the node's process")

    # In the namespace EncodedFrame.decode reads it from: another test may have had the
    # ROS modules imported afresh (test_main's "without ROS"), so not by the module's name.
    monkeypatch.setitem(processing.EncodedFrame.decode.__globals__, "decode_image", refuse)


@pytest.mark.parametrize("room", [True, False], ids=["shared memory", "pickled"])
def test_a_worker_process_decodes_its_compressed_frames_itself(monkeypatch, room):
    """Decodes in one process take turns (the decoders' stderr is the process's), in
    several they do not: the frame goes to the worker process as its bytes. Before, the
    node's process decoded every frame, one at a time (48 ms a 12 MP JPEG, with two
    threads as with one)."""
    _decodes_fail_here(monkeypatch)
    tmpfs = _Tmpfs(monkeypatch)
    tmpfs.full = not room
    collect = Collector()
    processor = FrameProcessor(
        ["cam0"], DetectorConfig(), collect, workers=1, worker_processes=True
    )
    try:
        processor.submit("cam0", compressed(1), block=True)
        processor.submit("cam0", compressed(2, kind="png"), block=True)
        assert processor.wait_idle(TIMEOUT_S)
        snap = processor.snapshots()["cam0"]
    finally:
        processor.shutdown(TIMEOUT_S)
    assert collect.results == [("cam0", 1, 1), ("cam0", 2, 1)]
    assert snap.errors == 0
    assert processor.frames_pickled == (0 if room else 2)
    # The frames' brightest level, read where they were decoded (the JPEG's a level off).
    assert snap.peak_share == pytest.approx(x_marker_64().max() / 255.0, abs=2 / 255)


def test_compressed_frames_are_decoded_in_the_nodes_process_where_worker_threads_detect_them(
    monkeypatch,
):
    _decodes_fail_here(monkeypatch)
    collect, failures = Collector(), []
    processor = FrameProcessor(
        ["cam0"],
        DetectorConfig(),
        collect,
        workers=1,
        on_error=lambda camera, err: failures.append(str(err)),
    )
    try:
        processor.submit("cam0", compressed(1), block=True)
        assert processor.wait_idle(TIMEOUT_S)
    finally:
        processor.shutdown(TIMEOUT_S)
    assert collect.results == []
    assert failures == ["decoded in the node's process"]


class SettingsRecorded(FrameProcessor):
    """A FrameProcessor that keeps every value its settings were given, and counts its
    :meth:`reconfigure` calls.

    A worker reads the settings once as it takes a frame, so a change made in two
    assignments lets a frame be taken between them; whether one is, depends on the
    threads' timing. The assignments themselves do not.
    """

    def __init__(self, *args, **kwargs):
        self.assigned = []
        self.reconfigured = 0
        super().__init__(*args, **kwargs)

    @property
    def _settings(self):
        return self._settings_now

    @_settings.setter
    def _settings(self, settings):
        self.assigned.append(settings)
        self._settings_now = settings

    def reconfigure(self, *args, **kwargs):
        self.reconfigured += 1
        super().reconfigure(*args, **kwargs)


def test_a_reconfiguration_is_swapped_in_whole_in_one_assignment():
    # The node applies an atomic parameter change (a detector and a tracker setting)
    # in one reconfigure, which must swap the settings in one assignment.
    processor = SettingsRecorded(
        ["cam0"],
        DetectorConfig(min_score=0.8),
        Collector(),
        workers=1,
        tracker_config=TrackerConfig(match_px=1.5),
    )
    try:
        processor.assigned.clear()
        change = (DetectorConfig(min_score=0.6), TrackerConfig(match_px=2.5))
        processor.reconfigure(*change)
        (settings,) = processor.assigned
        assert (settings.detector.config, settings.tracker_config) == change
        assert not settings.publish_overlay  # the setting not given is kept
        processor.submit("cam0", stamped(1), block=True)
        assert processor.wait_idle(TIMEOUT_S)
    finally:
        processor.shutdown(TIMEOUT_S)
    assert processor.snapshots()["cam0"].processed == 1


def test_one_atomic_parameter_request_reconfigures_the_processor_once_with_all_of_it(ros):
    """A detector.* and a tracker.* parameter set atomically through the parameter service."""
    settings = {"cameras": ["cam0"], "workers": 1, "worker_processes": False}
    with serving("atomic", settings, SettingsRecorded) as (node, peer):
        node.processor.assigned.clear()
        node.processor.reconfigured = 0
        change = [("detector.min_score", 0.6), ("tracker.match_px", 2.5)]
        (result,) = peer.set_parameters("/atomic/atomic_localizer", change, atomically=True)
        assert result.successful, result.reason
        # The service answers once its callbacks have run.
        reconfigured, assigned = node.processor.reconfigured, list(node.processor.assigned)
    assert reconfigured == 1
    (applied,) = assigned
    assert (applied.detector.config.min_score, applied.tracker_config.match_px) == (0.6, 2.5)


def test_a_frame_that_arrived_before_a_sim_time_clock_started_is_not_too_old_when_it_does():
    bag_start = 1_700_000_000 * 10**9
    now = [0]
    collect = Collector()
    processor = _aging_processor(["cam0"], collect, now)
    try:
        collect.release.clear()
        processor.submit("cam0", stamped(1))  # taken by the worker, held
        wait_until(collect.entered.is_set, "the worker to take frame 1")
        processor.submit("cam0", stamped(2))  # waits, at clock 0
        now[0] = bag_start  # the first /clock
        collect.release.set()
        assert processor.wait_idle(TIMEOUT_S)
        snap = processor.snapshots()["cam0"]
    finally:
        processor.shutdown(TIMEOUT_S)
    assert [sec for _, sec, _ in collect.results] == [1, 2]
    assert snap.dropped_age == 0
    assert np.isnan(snap.clock_offset_s)


def test_the_caps_cuts_and_the_second_readings_unread_are_summed_apart():
    class Capped(FrameProcessor):
        def detect(self, camera, frame, stamp_s):
            self._taken.levels = processing.InputLevels(255.0, False)
            counts = {"dropped_over_cap": 3, "vouch_over_cap": 1, "shadow_over_cap": 5}
            return DetectionResult([], {**counts, "dull_over_cap": 2}, {})

    processor = Capped(["cam0"], DetectorConfig(), Collector(), workers=1)
    try:
        for sec in (1, 2):
            processor.submit("cam0", stamped(sec), block=True)
        assert processor.wait_idle(TIMEOUT_S)
        snap = processor.snapshots()["cam0"]
    finally:
        processor.shutdown(TIMEOUT_S)
    assert (snap.frames_capped, snap.candidates_capped, snap.rereads_capped) == (2, 8, 14)


def test_the_overlay_is_drawn_after_the_cloud_is_out_and_its_failure_costs_only_itself(
    monkeypatch,
):
    # A worker process decodes the frame for the detector; the overlay, drawn in the
    # node's process, decodes it again there, after the frame's cloud is handed over.
    _decodes_fail_here(monkeypatch)
    events, failures = [], []
    processor = FrameProcessor(
        ["cam0"],
        DetectorConfig(),
        lambda camera, cloud: events.append(("cloud", cloud.header.stamp.sec)),
        workers=1,
        worker_processes=True,
        publish_overlay=True,
        on_overlay=lambda camera, overlay: events.append(("overlay", overlay.header.stamp.sec)),
        on_error=lambda camera, err: failures.append(str(err)),
    )
    try:
        processor.submit("cam0", compressed(1), block=True)
        assert processor.wait_idle(TIMEOUT_S)
        monkeypatch.undo()
        processor.submit("cam0", compressed(2), block=True)
        assert processor.wait_idle(TIMEOUT_S)
        snap = processor.snapshots()["cam0"]
    finally:
        processor.shutdown(TIMEOUT_S)
    assert events == [("cloud", 1), ("cloud", 2), ("overlay", 2)]
    assert failures == ["decoded in the node's process"]
    assert (snap.processed, snap.errors, snap.overlays_failed) == (2, 0, 1)
    assert snap.last_error == "its overlay failed: ImageError: decoded in the node's process"


def test_a_compressed_frame_a_worker_process_cannot_decode_fails_with_the_decoders_reason():
    collect, failures = Collector(), []
    processor = FrameProcessor(
        ["cam0"],
        DetectorConfig(max_pixels=64 * 64),
        collect,
        workers=1,
        worker_processes=True,
        on_error=lambda camera, err: failures.append(err),
    )
    cut = compressed(1)
    cut.data = cut.data[: len(cut.data) // 2]
    try:
        processor.submit("cam0", cut, block=True)
        processor.submit("cam0", compressed(2, np.zeros((64, 65), np.uint8)), block=True)
        processor.submit("cam0", compressed(3), block=True)
        assert processor.wait_idle(TIMEOUT_S)
        snap = processor.snapshots()["cam0"]
    finally:
        processor.shutdown(TIMEOUT_S)
    assert collect.results == [("cam0", 3, 1)]
    assert [type(err) for err in failures] == [ImageError, ImageError]
    assert "truncated JPEG" in str(failures[0]) or "damaged JPEG" in str(failures[0])
    assert str(failures[1]).endswith("65x64 = 4160 px exceeds max_pixels=4096")
    assert snap.errors == 2
