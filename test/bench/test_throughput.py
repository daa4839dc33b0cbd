"""bench throughput: the panning cameras; short runs, 1 and 2 worker processes, 2 threads."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from marker_localizer.bench import throughput
from marker_localizer.cli import main as cli_main

# --------------------------------------------------------------------------- benchmark


def test_benchmark_cameras_pan_at_a_constant_step_and_turn_back_at_the_end_of_their_ground():
    dx, dy = throughput.PAN_STEP_PX
    frames = throughput.PAN_FRAMES
    ground = np.arange(50 + frames * dy)[:, None] * 1000 + np.arange(60 + frames * dx)
    views = [throughput.camera_view(ground, k) for k in range(2 * frames + 2)]
    assert {v.shape for v in views} == {(50, 60)}
    origins = [(int(v[0, 0]) % 1000, int(v[0, 0]) // 1000) for v in views]
    assert origins[:3] == [(0, 0), (dx, dy), (2 * dx, 2 * dy)]
    assert origins[frames] == (frames * dx, frames * dy)  # the far end of the ground
    assert origins[frames + 1] == ((frames - 1) * dx, (frames - 1) * dy)  # turned back
    assert origins[2 * frames] == (0, 0)


def test_the_process_table_reads_each_processs_parent_and_the_cpu_time_it_used():
    # The child spins 0.3 s of its own CPU time, says so, and waits to be told to end.
    spin = (
        "import sys, time\n"
        "start = time.process_time()\n"
        "while time.process_time() - start < 0.3: pass\n"
        "print('spun', flush=True)\n"
        "sys.stdin.readline()\n"
    )
    child = subprocess.Popen(
        [sys.executable, "-c", spin], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert child.stdout is not None and child.stdout.readline() == "spun\n"
        table = throughput.process_table()
        assert table[os.getpid()].parent == os.getppid()
        assert table[child.pid].parent == os.getpid()
        assert table[child.pid].cpu_s >= 0.25
    finally:
        child.communicate("\n")


def test_throughput_benchmark_measures_one_and_two_workers_on_small_frames(ros, tmp_path):
    grounds = throughput.render_grounds(320, 240, directory=tmp_path, markers=1)
    results = [throughput.run_once(grounds, n, seconds=1.0, rate_hz=10.0) for n in (1, 2)]
    results.append(
        throughput.run_once(grounds, 2, seconds=1.0, rate_hz=10.0, worker_processes=False)
    )
    for result in results:
        assert result.processed > 0
        assert result.frames_per_s > 0
        assert result.published == 5 * 10
        assert result.dropped_mailbox + result.dropped_age + result.processed <= result.received
        assert result.latency_p95_ms >= result.latency_p50_ms > 0
        # Tracking: each camera's first frame at least is searched whole.
        assert 0 < result.full_frame_passes <= result.processed
        assert result.cpu_ms_per_frame > 0
    table = throughput.format_table(results).splitlines()
    assert table[0].split()[:3] == ["workers", "kind", "frames/s"]
    assert "cameras %" in table[0]  # the camera process's CPU apart
    assert "full" in table[0].split() and "CPU ms/fr" in table[0]
    assert [row.split()[:2] for row in table[2:]] == [
        ["1", "processes"],
        ["2", "processes"],
        ["2", "threads"],
    ]


def test_without_tracking_every_frame_processed_is_a_full_frame_pass(ros, tmp_path):
    grounds = throughput.render_grounds(320, 240, directory=tmp_path, markers=1)
    result = throughput.run_once(grounds, 1, seconds=1.0, rate_hz=10.0, tracking=False)
    assert result.processed > 0
    assert result.full_frame_passes == result.processed


def test_json_saves_the_figures_the_benchmark_prints(tmp_path):
    """Before, ``bench throughput`` alone of the benchmarks had no ``--json``."""
    path = tmp_path / "throughput.json"
    # A process of its own: the command starts rclpy and sets its DDS profile there.
    command = [sys.executable, "-m", "marker_localizer.cli", "bench", "throughput"]
    options = ["--width", "640", "--height", "480", "--workers", "1", "--seconds", "0.5"]
    printed = subprocess.run(
        [*command, *options, "--json", str(path)], capture_output=True, text=True, check=True
    ).stdout
    figures = json.loads(path.read_text())
    assert (figures["cameras"], figures["width"], figures["height"]) == (5, 640, 480)
    assert (figures["seconds"], figures["tracking"], figures["ground"]) == (0.5, True, "cluttered")
    assert figures["scaling_2_over_1"] is None  # one worker count: no ratio printed either
    [run] = figures["runs"]
    [row] = [line.split() for line in printed.splitlines() if line.startswith("      1 ")]
    assert row[:5] == [
        "1",
        "processes",
        f"{run['frames_per_s']:.3f}",
        str(run["processed"]),
        str(run["published"]),
    ]
    assert row[5] == str(run["dropped_in_transport"])
    assert "elapsed_s" in figures


def test_a_radius_range_the_node_refuses_is_refused_before_the_grounds_are_rendered(capsys):
    assert cli_main(["bench", "throughput", "--radius-range", "40", "6", "--seconds", "1"]) == 1
    captured = capsys.readouterr()
    assert "rendering" not in captured.out
    assert "marker_radius_min_px=40.0 is larger than marker_radius_max_px=6.0" in captured.err


def test_the_cameras_publish_jpeg_the_node_reads_with_compressed_transport(ros, tmp_path):
    grounds = throughput.render_grounds(320, 240, directory=tmp_path, markers=1)
    for processes, encoding in ((True, "bgr8"), (False, "mono8")):
        result = throughput.run_once(
            grounds, 2, seconds=1.0, rate_hz=10.0, worker_processes=processes, compressed=encoding
        )
        assert result.published == 5 * 10
        assert result.processed > 0
        assert result.dropped_mailbox + result.dropped_age + result.processed <= result.received


@pytest.mark.parametrize(
    ("module", "profile"),
    [
        ("repo/marker_localizer/bench/throughput.py", "repo/config"),
        (
            "prefix/lib/python3.12/site-packages/marker_localizer/bench/throughput.py",
            "prefix/share/marker_localizer/config",
        ),
    ],
    ids=["checkout or editable install", "wheel or colcon install"],
)
def test_the_dds_profile_is_found_beside_the_sources_or_under_the_install_prefix(
    tmp_path, module, profile
):
    """A wheel puts config/ under PREFIX/share: looked for beside the sources alone, missed."""
    (tmp_path / module).parent.mkdir(parents=True)
    (tmp_path / module).touch()
    assert throughput.fastdds_profile(tmp_path / module) is None
    (tmp_path / profile).mkdir(parents=True)
    (tmp_path / profile / throughput.FASTDDS_PROFILE_NAME).touch()
    assert throughput.fastdds_profile(tmp_path / module) == (
        tmp_path / profile / throughput.FASTDDS_PROFILE_NAME
    )


def test_the_dds_profile_of_the_package_under_test_is_found():
    assert throughput.fastdds_profile() is not None
