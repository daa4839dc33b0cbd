"""The node as a separate process, started as a user starts it: serve, stop on a signal, fail."""

import contextlib
import json
import os
import queue
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from node_testing import (
    NODE_MODULE,
    PARAMS_FILE,
    TIMEOUT_S,
    Peer,
    assert_matches_truth,
    mapped_shared_memory_blocks,
    points_xy,
    process_alive,
    run_to_exit,
    scene,
    shared_memory_blocks,
    values_of,
    wait_until,
    worker_process_ids,
    x_marker_64,
)
from sensor_msgs.msg import PointCloud2
from signalling import interrupt_while_importing

from marker_localizer.config import NODE_NAME
from marker_localizer.ros.node import logger_name

# --------------------------------------------------------------------------- separate process


def installed_script(name):
    """A console script where pip (beside the interpreter) or colcon (<prefix>/lib/<pkg>) put it."""
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    places = [
        Path(sys.executable).with_name(name),
        *(Path(p) / "lib" / "marker_localizer" / name for p in prefixes),
    ]
    return str(next((p for p in places if p.is_file()), places[0]))


#: The two ways a user starts the node: the console script setup.py declares, and -m.
CONSOLE_SCRIPT = [installed_script("marker_localizer_node")]
MODULE = NODE_MODULE


def node_command(launcher, *ros_args):
    return [*launcher, "--ros-args", "--params-file", str(PARAMS_FILE), *ros_args]


@pytest.mark.parametrize(
    ("launcher", "stop_signal"),
    [(CONSOLE_SCRIPT, signal.SIGINT), (MODULE, signal.SIGTERM)],
    ids=["console-script-SIGINT", "python-m-SIGTERM"],
)
def test_node_process_serves_a_frame_and_stops_cleanly_on_signal(ros, launcher, stop_signal):
    process = subprocess.Popen(
        node_command(
            launcher,
            "-p",
            "cameras:=[cam0,cam1]",
            "-p",
            "workers:=1",
            "-r",
            "cam0/marker_points:=cam0/points_remapped",
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=os.environ.copy(),
    )
    tester = Peer(f"process_tester_{stop_signal.name.lower()}", "/")
    try:
        rendered = scene(1280, 960, 3, 12)
        tester.listen("/cam0/points_remapped", PointCloud2)
        frame = tester.frame(rendered.image, frame_id="cam0_optical")
        tester.publish("/cam0/image_raw", frame)
        cloud = tester.result_for("/cam0/points_remapped", frame.header, timeout_s=60.0)
        assert cloud.header == frame.header
        assert_matches_truth(points_xy(cloud), rendered.centres)
    finally:
        process.send_signal(stop_signal)
        stdout, stderr = process.communicate(timeout=TIMEOUT_S)
        tester.stop()
    assert process.returncode == 0, stderr
    assert "Traceback" not in stderr + stdout
    assert "stopped" in stderr + stdout


#: The node's main() in a process that first gives every OpenBLAS two threads and, at
#: exit, prints their thread counts as given and as the node left them.
_BLAS_REPORTING_NODE = f"""
import atexit, json, sys
sys.path.insert(0, {str(Path(__file__).resolve().parents[1])!r})
from blas_threads import openblas_threads, set_openblas_threads
set_openblas_threads(2)
given = openblas_threads()
atexit.register(lambda: print(json.dumps({{"given": given, "left": openblas_threads()}})))
from marker_localizer.ros.node import main
sys.exit(main())
"""


def test_node_process_serves_worker_threads_on_one_blas_thread(ros):
    """With worker_processes:=false the detector runs in the node's own process."""
    process = subprocess.Popen(
        node_command(
            [sys.executable, "-c", _BLAS_REPORTING_NODE],
            "-p",
            "cameras:=[cam0]",
            "-p",
            "workers:=1",
            "-p",
            "worker_processes:=false",
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    tester = Peer("blas_tester", "/")
    try:
        rendered = scene(1280, 960, 3, 12)
        tester.listen("/cam0/marker_points", PointCloud2)
        frame = tester.frame(rendered.image, frame_id="cam0_optical")
        tester.publish("/cam0/image_raw", frame)
        assert_matches_truth(
            points_xy(tester.result_for("/cam0/marker_points", frame.header, timeout_s=60.0)),
            rendered.centres,
        )
    finally:
        process.send_signal(signal.SIGINT)
        stdout, stderr = process.communicate(timeout=TIMEOUT_S)
        tester.stop()
    assert process.returncode == 0, stderr
    threads = json.loads(stdout.strip().splitlines()[-1])
    threaded = [library for library, count in threads["given"].items() if count == 2]
    if not threaded:
        pytest.skip("no OpenBLAS here takes a second thread")
    assert [threads["left"][library] for library in threaded] == [1] * len(threaded)


def test_node_process_exits_with_status_1_on_invalid_configuration():
    result = run_to_exit(node_command(MODULE, "-p", "detector.marker_radius_min_px:=50.0"))
    assert result.returncode == 1
    assert (
        "invalid configuration: detector.marker_radius_min_px=50.0 is larger than" in result.stderr
    )
    assert "Traceback" not in result.stderr


@pytest.mark.parametrize(
    "remaps",
    [
        [],
        ["-r", "__ns:=/uav1", "-r", "__node:=front"],
        ["--remap", "__ns:=/uav1/left", "-r", "__name:=front"],
        ["-r", "marker_localizer:__node:=front", "-r", "other:__node:=rear"],
        ["-r", "__node:=front", "-r", "__node:=rear", "--ros-args", "-r", "__ns:=/uav2"],
        ["-p", "workers:=1", "-r", "__ns:=/"],
        ["-r", "__ns:=/uav1", "--", "-r", "__node:=rear"],
    ],
    ids=[
        "none",
        "node-and-namespace",
        "nested-namespace",
        "by-name",
        "first-wins",
        "root",
        "deprecated-rule-outside-ros-args",
    ],
)
def test_the_logger_named_before_the_node_exists_is_the_one_rclpy_gives_it(remaps):
    args = ["marker_localizer_node", "--ros-args", *remaps]
    context = rclpy.Context()
    rclpy.init(args=args, context=context)
    try:
        node = rclpy.create_node(NODE_NAME, context=context)
        assert logger_name(args) == node.get_logger().name
        node.destroy_node()
    finally:
        context.try_shutdown()


def test_a_refused_start_value_is_logged_under_the_remapped_node_name():
    """The fatal line comes before the node exists, whose logger rclpy would name."""
    result = run_to_exit(
        [*MODULE, "--ros-args", "-r", "__ns:=/uav1", "-r", "__node:=front", "-p", "workers:=0"]
    )
    assert result.returncode == 1
    assert "[uav1.front]: invalid configuration: workers=0 is outside [1, 64]" in result.stderr


def test_node_process_with_a_params_file_that_is_not_yaml_exits_1_in_one_line(tmp_path):
    broken = tmp_path / "broken.yaml"
    broken.write_text("marker_localizer:\n  ros__parameters:\n    workers: [oops\n")
    result = run_to_exit([*MODULE, "--ros-args", "--params-file", str(broken)])
    assert result.returncode == 1
    (line,) = result.stderr.splitlines()
    assert "invalid ROS arguments: " in line and "Couldn't parse params file" in line


def test_node_process_with_an_unknown_ros_argument_exits_1_in_one_line():
    # --param-file for --params-file: rclpy's UnknownROSArgsError was a traceback.
    result = run_to_exit([*MODULE, "--ros-args", "--param-file", "x.yaml"])
    assert result.returncode == 1
    (line,) = result.stderr.splitlines()
    assert "unknown ROS arguments ['--param-file', 'x.yaml'] (after --ros-args: " in line


@pytest.mark.parametrize("module", ["numpy", "rclpy"])
def test_ctrl_c_while_the_node_still_imports_is_one_line_and_status_130(module):
    """Right after start: the detector's imports and ROS's take a second or more."""
    status, stdout, stderr = interrupt_while_importing(
        module, "marker_localizer.node:main", "--ros-args", "-p", "cameras:=[cam0]"
    )
    assert (status, stdout) == (130, "")
    assert stderr == "marker_localizer_node: interrupted by SIGINT\n"


class _Lines:
    """The lines a process writes to one of its pipes, read as they come."""

    def __init__(self, pipe):
        self.lines = queue.Queue()
        self.seen = []
        self._thread = threading.Thread(target=self._read, args=(pipe,), daemon=True)
        self._thread.start()

    def _read(self, pipe):
        for line in pipe:
            self.lines.put(line)

    def wait_for(self, text):
        """The first line (from where the last wait stopped) that holds ``text``."""
        while True:
            line = self.lines.get(timeout=TIMEOUT_S)
            self.seen.append(line)
            if text in line:
                return line

    def rest(self):
        """Every line after the last one waited for, once the pipe is closed."""
        self._thread.join(TIMEOUT_S)
        while not self.lines.empty():
            self.seen.append(self.lines.get())
        return "".join(self.seen)


def _one_worker_node(launcher, namespace, **popen_options):
    """A node of one camera and one worker process that waits 600 s for a frame in flight."""
    return subprocess.Popen(
        node_command(
            launcher,
            "-p",
            "cameras:=[cam0]",
            "-p",
            "workers:=1",
            "-p",
            "shutdown_timeout_s:=600.0",
            "-p",
            "diagnostics_period_s:=0.1",
            "-r",
            f"__ns:={namespace}",
        ),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        **popen_options,
    )


def _frame_in_flight(tester):
    return any(
        values_of(status).get("frames in flight") == "1"
        for array_msg in tester.messages("/diagnostics")
        for status in array_msg.status
    )


def test_a_second_ctrl_c_abandons_the_frame_in_flight_and_says_so_in_one_line(ros):
    """A stopped worker process (SIGSTOP) stands for a frame longer than the drain's wait.

    The first Ctrl-C starts the drain; the second ends it at once: the worker
    process killed, the frame's shared memory unlinked (nothing left for Python's
    resource tracker to warn about), one line, status 130.
    """
    process = _one_worker_node(CONSOLE_SCRIPT, "/twice")
    err = _Lines(process.stderr)
    tester = Peer("twice_tester", "/twice")
    try:
        assert err.wait_for("serving cameras cam0").rstrip().endswith("with 1 worker process")
        (worker,) = worker_process_ids(process.pid)
        os.kill(worker, signal.SIGSTOP)
        tester.listen("/diagnostics", DiagnosticArray)
        tester.publish("cam0/image_raw", tester.frame(x_marker_64()))
        wait_until(lambda: _frame_in_flight(tester), "the frame in its worker process")
        (block,) = mapped_shared_memory_blocks(process.pid)  # the frame's
        process.send_signal(signal.SIGINT)
        err.wait_for("stopping: waiting up to 600 s for the frames in flight (cam0)")
        process.send_signal(signal.SIGINT)
        process.wait(TIMEOUT_S)
    finally:
        process.kill()
        tester.stop()
    assert process.returncode == 130
    assert err.rest().splitlines()[-1] == "marker_localizer_node: interrupted by SIGINT"
    assert "Traceback" not in "".join(err.seen)
    assert "Warning" not in "".join(err.seen)  # the resource tracker's, of leaked memory
    wait_until(lambda: not process_alive(worker), "the worker process to end")
    assert block not in shared_memory_blocks()


@pytest.mark.parametrize("stop_signal", [signal.SIGHUP, signal.SIGTERM], ids=lambda s: s.name)
def test_a_stop_signal_to_the_process_group_drains_the_frame_in_flight_as_quietly_as_ctrl_c(
    ros, stop_signal
):
    """A closed terminal's SIGHUP, a service manager's SIGTERM: to the node, its fork
    server and the resource tracker alike. A stopped worker process (SIGSTOP) holds a
    frame until the drain has begun.

    The tracker ignores SIGINT and SIGTERM but died of SIGHUP; a fresh one, started by
    the node's first unlink, wrote a KeyError traceback for each block and semaphore
    the node then unlinked. The fork server ignores SIGINT alone and died of either:
    the pool, which learns of its worker's end through it, took the living worker for
    dead, and the frame in flight failed instead of being published.
    """
    process = _one_worker_node(
        MODULE,  # this checkout's code: the console script runs the installed one
        f"/group_{stop_signal.name.lower()}",
        start_new_session=True,  # its own process group, as a terminal's
    )
    err = _Lines(process.stderr)
    tester = Peer(f"group_{stop_signal.name.lower()}_tester", f"/group_{stop_signal.name.lower()}")
    workers = set()
    try:
        err.wait_for("serving cameras cam0")
        workers = worker_process_ids(process.pid)
        (worker,) = workers
        os.kill(worker, signal.SIGSTOP)
        tester.listen("/diagnostics", DiagnosticArray)
        tester.listen("cam0/marker_points", PointCloud2)
        frame = tester.frame(x_marker_64())
        tester.publish("cam0/image_raw", frame)
        wait_until(lambda: _frame_in_flight(tester), "the frame in its worker process")
        (block,) = mapped_shared_memory_blocks(process.pid)  # the frame's
        os.killpg(process.pid, stop_signal)
        err.wait_for("stopping: waiting up to 600 s for the frames in flight (cam0)")
        os.kill(worker, signal.SIGCONT)
        tester.result_for("cam0/marker_points", frame.header)
        process.wait(TIMEOUT_S)
    finally:
        process.kill()
        for stopped in workers:  # stopped, it would not see its node end
            with contextlib.suppress(ProcessLookupError):
                os.kill(stopped, signal.SIGCONT)
        tester.stop()
    assert process.returncode == 0
    lines = err.rest()
    assert "stopped" in lines
    for word in ("frame failed", "Traceback", "KeyError", "relaunching"):
        assert word not in lines
    assert block not in shared_memory_blocks()
