"""The node as a separate process, started as a user starts it: serve, stop on a signal, fail."""

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from node_testing import (
    PARAMS_FILE,
    TIMEOUT_S,
    Peer,
    assert_matches_truth,
    points_xy,
    scene,
)
from sensor_msgs.msg import PointCloud2

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
MODULE = [sys.executable, "-m", "marker_localizer.node"]


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
    result = subprocess.run(
        node_command(MODULE, "-p", "detector.marker_radius_min_px:=50.0"),
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        check=False,
    )
    assert result.returncode == 1
    assert "invalid configuration: marker_radius_min_px=50.0 is larger than" in result.stderr
    assert "Traceback" not in result.stderr


def test_node_process_with_a_params_file_that_is_not_yaml_exits_1_in_one_line(tmp_path):
    broken = tmp_path / "broken.yaml"
    broken.write_text("marker_localizer:\n  ros__parameters:\n    workers: [oops\n")
    result = subprocess.run(
        [*MODULE, "--ros-args", "--params-file", str(broken)],
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        check=False,
    )
    assert result.returncode == 1
    (line,) = result.stderr.splitlines()
    assert "invalid ROS arguments: " in line and "Couldn't parse params file" in line
