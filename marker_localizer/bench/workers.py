"""Timing workers: each subject in its own single-threaded subprocess, timed in turn.

Both speed tables (:mod:`~marker_localizer.bench.speed`, :mod:`~marker_localizer.bench.ground`)
start one worker per subject, warm it up, then ask each in turn to time one frame:
every frame goes to every subject before the next frame, so that a change in the
shared host's load falls on all of them alike, and a ratio between two subjects is
taken pair by pair (:func:`paired_ratio`). Subjects whose warm-up took longer than
:data:`IN_TURN_MAX_S` are timed in the same way after the others
(:func:`paced_groups`), who take one untimed turn first (:func:`settle`). A
worker reads one request per line on its stdin and answers each with one JSON
line on its stdout (:func:`serve`); it prints one JSON line when it is ready,
with ``error`` empty or saying why it cannot run.
"""

from __future__ import annotations

import contextlib
import json
import os
import select
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np

#: The thread pools a worker limits to one thread: the "one core" figure.
THREAD_VARIABLES = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "NUMEXPR_NUM_THREADS",
)
#: Longest a subject's warm-up detection may take for it to be timed in turn with the
#: others, s. Between two detections of one subject pass the others' turns, and a
#: virtual machine's balloon takes back the guest's memory that stayed free for 2 s
#: (Linux's free page reporting): a subject that frees its whole-frame arrays after
#: each detection and allocates them again (the OpenCV Hessian peer, 490 MB a speed
#: frame) then faults them in from the hypervisor, its kernel time 2-4x. After a 1.7 s
#: turn of chess-corners' Radon it took 280-320 ms a speed frame, 190-200 ms
#: otherwise (docs/speed.md). A subject that slow is timed after the others, as a
#: camera's frames come: well within 2 s of each other.
IN_TURN_MAX_S = 1.0
#: How long a worker may take to answer once, s: the slowest subject's warm-up on the
#: busiest ground takes minutes.
WORKER_TIMEOUT_S = 3600


def single_thread_env() -> dict[str, str]:
    """This process's environment with every BLAS/OpenMP pool limited to one thread."""
    env = dict(os.environ)
    env.update(dict.fromkeys(THREAD_VARIABLES, "1"))
    return env


def save_frames(path: Path, arrays: Mapping[str, np.ndarray]) -> None:
    """Write the frames the workers read to one ``.npz`` file, each array under its name."""
    # numpy's stubs take a ``**`` mapping of arrays for savez's ``allow_pickle: bool``.
    named: dict[str, Any] = dict(arrays)
    np.savez(path, **named)


def paired_ratio(ours: Sequence[float], peer: Sequence[float]) -> float:
    """Median of our time over the peer's, pair by pair (the same frame, the same round).

    NaN where the two did not time the same number of detections (a failed worker).
    """
    if not len(ours) or len(ours) != len(peer):
        return float("nan")
    return float(np.median(np.asarray(ours, float) / np.asarray(peer, float)))


def paired_ratios_by_frame(
    ours: Sequence[float], peer: Sequence[float], n_frames: int
) -> list[float]:
    """Per frame, the median over the rounds of our time over the peer's.

    The times are in the order the drivers take them, round by round and frame by
    frame within a round. NaN for every frame where the two did not time the same
    whole rounds (a failed worker).
    """
    if not len(ours) or len(ours) != len(peer) or len(ours) % n_frames:
        return [float("nan")] * n_frames
    ratio = np.asarray(ours, float) / np.asarray(peer, float)
    return [float(np.median(ratio[frame::n_frames])) for frame in range(n_frames)]


def serve(ready: dict[str, Any], answer: Callable[[str], dict[str, Any]] | None) -> None:
    """The worker's loop: print ``ready``, then ``answer`` each request line until stdin ends.

    A worker that cannot run says why in ``ready["error"]`` and gives no ``answer``.
    """
    print(json.dumps(ready), flush=True)
    if answer is None:
        return
    for line in sys.stdin:
        print(json.dumps(answer(line.strip())), flush=True)


class Worker:
    """One subject's single-threaded subprocess (``python -m module --worker name``).

    Attributes:
        ready: what the worker printed when ready (empty where it failed).
        error: why it cannot run or stopped ("" while it runs).
    """

    def __init__(self, module: str, name: str, frames_path: Path, stderr: IO[str]) -> None:
        """Start the worker and wait until it is ready (warmed up, where it warms up).

        ``stderr``: an open file for the worker's errors (not a pipe: nobody reads it
        while the worker runs).
        """
        self._stderr = stderr
        self._process = subprocess.Popen(
            [sys.executable, "-m", module, "--worker", name, "--frames-file", str(frames_path)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=stderr,
            text=True,
            env=single_thread_env(),
        )
        self.error = ""
        self.ready = self._reply() or {}
        if self.ready.get("error"):
            self.error = str(self.ready["error"])

    @property
    def running(self) -> bool:
        """Whether the worker still answers."""
        return not self.error

    def ask(self, request: str) -> dict[str, Any] | None:
        """Its answer to one request; None where it failed (see :attr:`error`)."""
        assert self._process.stdin is not None
        try:
            self._process.stdin.write(request + "\n")
            self._process.stdin.flush()
        except BrokenPipeError:
            self._fail()
            return None
        return self._reply()

    def close(self) -> None:
        """End the worker: the end of its stdin, or a kill where it does not stop."""
        if self._process.stdin is not None and not self._process.stdin.closed:
            with contextlib.suppress(BrokenPipeError):
                self._process.stdin.close()
        try:
            self._process.wait(timeout=WORKER_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()

    def _reply(self) -> dict[str, Any] | None:
        stdout = self._process.stdout
        assert stdout is not None
        # A worker writes one line an answer, so nothing waits in the pipe's buffer
        # once a line is read, and the pipe itself says when the next one is there.
        answered, _, _ = select.select([stdout], [], [], WORKER_TIMEOUT_S)
        if not answered:
            self._process.kill()
            self._process.wait()
            self._fail(f"no answer within {WORKER_TIMEOUT_S} s")
            return None
        line = stdout.readline()
        if not line:
            self._fail()
            return None
        reply: dict[str, Any] = json.loads(line)
        return reply

    def _fail(self, why: str = "") -> None:
        """Record why the worker stopped: ``why``, or the last line of its stderr."""
        self._process.wait(timeout=WORKER_TIMEOUT_S)
        if not why:
            self._stderr.seek(0)
            why = (self._stderr.read().strip().splitlines() or ["no output"])[-1]
        self.error = f"worker failed: {why}"


def paced_groups(warm_up_s: Sequence[float]) -> list[list[int]]:
    """The subjects' positions in the groups timed one after the other.

    Those whose warm-up took at most :data:`IN_TURN_MAX_S` (``warm_up_s``, one a
    subject; NaN for a worker that failed), then the slower ones, each group frame
    by frame in turn (:func:`in_turn`). Empty groups are left out.
    """
    seconds = np.asarray(warm_up_s, float)
    slow = seconds > IN_TURN_MAX_S
    groups = [np.flatnonzero(~slow).tolist(), np.flatnonzero(slow).tolist()]
    return [group for group in groups if group]


def settle(workers: Sequence[Worker], group: Sequence[int], request: str) -> None:
    """One untimed turn of the workers of ``group``, each asked ``request``.

    The workers warm up one after another, and the slower subjects' warm-ups (a
    few seconds each) may run after those of the group timed first: its subjects
    then take one turn before their timed ones, so that none is timed after such
    a wait (:data:`IN_TURN_MAX_S`).
    """
    for position in in_turn(workers, 0, group):
        workers[position].ask(request)


def settled_groups(
    workers: Sequence[Worker], warm_up_s: Sequence[float], request: str
) -> list[list[int]]:
    """The groups to time one after the other (:func:`paced_groups`), the first settled.

    The first group's workers are asked ``request`` once, untimed (:func:`settle`),
    before the caller times its turns.
    """
    groups = paced_groups(warm_up_s)
    if groups:
        settle(workers, groups[0], request)
    return groups


def in_turn(workers: Sequence[Worker], index: int, group: Sequence[int] | None = None) -> list[int]:
    """The positions of the running workers of ``group`` in the order they time frame ``index``.

    Rotated by one a frame, so that no subject always follows the same one (the
    cache it leaves, the turbo it wakes). ``group``: positions in ``workers``
    (:func:`paced_groups`); None: every worker.
    """
    members = list(range(len(workers))) if group is None else list(group)
    turn = index % max(len(members), 1)
    order = [*members[turn:], *members[:turn]]
    return [position for position in order if workers[position].running]


@contextlib.contextmanager
def started(module: str, names: Sequence[str], frames_path: Path) -> Iterator[list[Worker]]:
    """The workers of ``names``, started one after another, closed after.

    One after another, so that no two warm-ups overlap.
    """
    with contextlib.ExitStack() as stack:
        workers = []
        for name in names:
            stderr = stack.enter_context(tempfile.TemporaryFile("w+"))
            worker = Worker(module, name, frames_path, stderr)
            stack.callback(worker.close)
            workers.append(worker)
        yield workers
