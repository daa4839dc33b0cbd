"""The marker-localizer dispatcher: the commands it lists, and how their errors end."""

import importlib
import re
import runpy
import subprocess
import sys

import cv2
import numpy as np
import pytest

from marker_localizer.cli import BENCHMARKS, COMMANDS, main
from marker_localizer.errors import ConfigError
from marker_localizer.node import main as node_main


def test_bench_help_lists_the_benchmarks_and_exits_0(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["bench", "--help"])
    assert exit_info.value.code == 0
    assert "{accuracy,bound,calibrate,exposure,paper,speed,throughput}" in capsys.readouterr().out


def test_help_lists_every_command_and_an_unknown_one_exits_2(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    listed = capsys.readouterr().out
    assert all(name in listed for name in [*COMMANDS, "bench"])
    with pytest.raises(SystemExit) as exit_info:
        main(["survey"])
    assert exit_info.value.code == 2
    assert "invalid choice: 'survey'" in capsys.readouterr().err


ENTRIES = [(c.module, c.function) for c in COMMANDS.values()]
ENTRIES += [(module, "main") for module in BENCHMARKS.values()]


@pytest.mark.parametrize(("module", "function"), ENTRIES, ids=[m for m, _ in ENTRIES])
def test_every_registered_command_and_benchmark_names_a_function_that_exists(module, function):
    if module.endswith((".bag", ".demo", ".throughput")):  # the ones that need ROS
        pytest.importorskip("rclpy")
    assert callable(getattr(importlib.import_module(module), function))


@pytest.mark.parametrize("param", ["marker_radius_min_px", "=3", " =3"])
def test_a_package_error_is_one_line_and_status_1(capsys, param):
    assert main(["detect", "any.png", "--param", param]) == 1
    err = capsys.readouterr().err
    assert err == f"marker-localizer: error: --param expects key=value, got {param!r}\n"


def test_a_demo_folder_that_cannot_be_made_is_one_line(tmp_path, capsys):
    pytest.importorskip("rclpy")  # the demo records and replays a bag
    taken = tmp_path / "afile"
    taken.write_text("")
    assert main(["demo", "--out", str(taken)]) == 1
    assert capsys.readouterr().err == (
        f"marker-localizer: error: --out {taken}: cannot create the folder (File exists)\n"
    )


def test_a_demo_replaces_its_own_bags_and_refuses_to_remove_anything_else(tmp_path, capsys):
    pytest.importorskip("rclpy")
    from marker_localizer.cli import demo  # noqa: PLC0415 - needs ROS

    assert demo.run(tmp_path, frames=1, width=320, height=240) == 0
    assert demo.run(tmp_path, frames=1, width=320, height=240) == 0  # its bags replaced
    mine = tmp_path / "mine"
    (mine / "flight").mkdir(parents=True)
    (mine / "flight" / "keep.txt").write_text("the user's")
    with pytest.raises(ConfigError, match=r"mine/flight is not a bag the demo wrote"):
        demo.run(mine, frames=1, width=320, height=240)
    assert (mine / "flight" / "keep.txt").read_text() == "the user's"
    assert not (mine / "markers").exists()


@pytest.fixture
def modules():
    """A monkeypatch for ``sys.modules`` that leaves our packages whole when undone.

    Undoing puts back the modules a test took out, but not their packages' attributes,
    which the modules imported afresh in the test replaced, nor does it drop the modules
    first imported in the test. Left so, ``marker_localizer.bag.play`` could sit in
    ``sys.modules`` while ``marker_localizer.bag`` had no attribute ``play``, and a later
    test's ``monkeypatch.setattr("marker_localizer.bag.play.BagReader", ...)`` failed.
    """
    before = set(sys.modules)
    with pytest.MonkeyPatch.context() as patch:
        yield patch
    ours = [name for name in sys.modules if name.startswith("marker_localizer.")]
    for name in ours:
        if name not in before:
            del sys.modules[name]
        elif sys.modules[name] is not None:
            package, _, child = name.rpartition(".")
            setattr(sys.modules[package], child, sys.modules[name])


def _without_ros(modules):
    """This process as a pip venv without ROS: importing rclpy or a message package fails,
    and what imported them is imported afresh."""
    for name in [n for n in sys.modules if re.match(_ROS_MODULE, n)]:
        modules.delitem(sys.modules, name)
    for top in ("rclpy", "builtin_interfaces", "std_msgs", "sensor_msgs", "rcl_interfaces"):
        modules.setitem(sys.modules, top, None)


#: Our modules that import a benchmark's or the bag tools' packages.
_OURS = r"marker_localizer\.(bag|bench|synthetic|cli\.bag|cli\.demo)(\.|$)"

#: ROS's modules (as test_packaging finds them), and ours that import them.
_ROS_MODULE = (
    r"(rclpy|\w+_msgs|\w+_interfaces)(\.|$)"
    r"|marker_localizer\.(bag|ros|cli\.bag|cli\.demo|bench\.throughput)(\.|$)"
)


@pytest.mark.parametrize(
    ("command", "label"),
    [
        ("replay", "marker-localizer replay"),
        ("play", "marker-localizer play"),
        ("simulate", "marker-localizer simulate"),
        ("demo", "marker-localizer"),  # as detect: its messages never named it
        ("bench throughput", "marker-localizer bench throughput"),
    ],
)
def test_a_command_that_needs_ros_says_what_to_install_where_it_is_missing(
    command, label, modules, capsys
):
    """As after a plain ``pip install .``: one line, naming the command, not a traceback."""
    _without_ros(modules)
    assert main([*command.split(), "--help"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith(f"{label}: error: needs ROS 2 Jazzy's Python packages (")
    assert "pip install ros-jazzy-rclpy ros-jazzy-common-interfaces" in err


@pytest.mark.parametrize(
    ("command", "module", "distribution"),
    [
        ("bench accuracy", "skimage", "scikit-image"),
        ("replay", "rosbags", "rosbags"),
    ],
)
def test_a_command_missing_another_package_names_that_package_not_ros(
    command, module, distribution, modules, capsys
):
    """As where rosdep could not pip install rosbags: installing ROS would not help."""
    if command == "replay":
        pytest.importorskip("rclpy")  # without it, the first module replay misses is rclpy
    for name in [n for n in sys.modules if re.match(rf"{module}(\.|$)|{_OURS}", n)]:
        modules.delitem(sys.modules, name)
    modules.setitem(sys.modules, module, None)
    assert main([*command.split(), "--help"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith(f"marker-localizer {command}: error: needs the Python package ")
    assert err.endswith(f"pip install {distribution}\n")


def test_a_params_file_without_pyyaml_names_pyyaml(tmp_path, monkeypatch, capsys):
    """The core's commands need no ROS; a params file needs PyYAML, which pip gives."""
    image, params = tmp_path / "flat.png", tmp_path / "params.yaml"
    cv2.imwrite(str(image), np.full((40, 50), 80, np.uint8))
    params.write_text("marker_localizer:\n  ros__parameters:\n    detector: {}\n")
    monkeypatch.setitem(sys.modules, "yaml", None)
    assert main(["detect", str(image), "--params-file", str(params)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith("marker-localizer: error: needs the Python package PyYAML (")


def test_the_node_says_what_to_install_where_ros_is_missing(modules, capsys):
    _without_ros(modules)
    assert node_main() == 1
    assert capsys.readouterr().err.startswith(
        "marker_localizer_node: error: needs ROS 2 Jazzy's Python packages"
    )


def test_python_m_parameters_says_what_to_install_where_ros_is_missing(modules, capsys):
    """``python -m marker_localizer.ros.parameters`` (runpy is what ``-m`` runs) in a venv
    without ROS: one line and status 1, not the traceback of its imports."""
    _without_ros(modules)
    with pytest.raises(SystemExit) as exit_info:
        runpy.run_module("marker_localizer.ros.parameters", run_name="__main__")
    assert exit_info.value.code == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith(
        "marker_localizer.ros.parameters: error: needs ROS 2 Jazzy's Python packages ("
    )
    assert "pip install ros-jazzy-rclpy ros-jazzy-common-interfaces" in err


def test_a_command_line_argparse_refuses_exits_2_naming_the_command(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["detect"])
    assert exit_info.value.code == 2
    assert "marker-localizer detect: error: the following arguments are required: IMAGE" in (
        capsys.readouterr().err
    )


def test_python_m_runs_the_same_command_line():
    result = subprocess.run(
        [sys.executable, "-m", "marker_localizer.cli", "detect", "--help"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert result.returncode == 0
    assert result.stdout.startswith("usage: marker-localizer detect")


def test_output_whose_reader_went_away_ends_quietly_with_141(tmp_path):
    """``detect ... | head -1``: no traceback, the status a shell gives a process SIGPIPE ends."""
    board = np.kron((np.indices((12, 12)).sum(axis=0) % 2) * 170 + 40, np.ones((24, 24)))
    path = tmp_path / "board.png"
    cv2.imwrite(str(path), cv2.GaussianBlur(board.astype(np.uint8), (0, 0), 1.0))
    # Eight records of 121 corners each fill more than a pipe holds (64 KiB), so the
    # command is still writing when the reader goes away.
    command = [sys.executable, "-m", "marker_localizer.cli", "detect", *[str(path)] * 8, "--json"]
    with subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE) as process:
        assert process.stdout is not None and process.stderr is not None
        assert process.stdout.readline().startswith(b'{"image"')
        process.stdout.close()
        err = process.stderr.read()
        assert process.wait(timeout=120) == 141
    assert err == b""


def test_an_option_a_command_lacks_is_refused_not_read_as_one_it_begins(capsys):
    # Abbreviated, "--param" was taken for replay's "--params-file" (before replay had
    # a --param), and the override for a file that could not be read.
    pytest.importorskip("rclpy")
    with pytest.raises(SystemExit) as exit_info:
        main(["replay", "flight", "--out", "out", "--work", "2"])
    assert exit_info.value.code == 2
    assert "unrecognized arguments: --work 2" in capsys.readouterr().err
