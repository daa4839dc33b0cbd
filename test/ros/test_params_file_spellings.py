"""A params file's scalars read by the node (rcl's parser) and by ``detect``/``replay`` alike.

The node here is started in this process from the file, as ``--params-file``
starts it; test/test_config.py holds the file's side of each spelling alone.
"""

import pytest

from marker_localizer.config import detector_config, load_params_file
from marker_localizer.errors import ConfigError
from marker_localizer.ros.node import MarkerLocalizerNode


def _params_file(tmp_path, name, spelling):
    path = tmp_path / "params.yaml"
    path.write_text(f"/**:\n  ros__parameters:\n    detector:\n      {name}: {spelling}\n")
    return path


def _node_value(path, name):
    """The node's value of ``detector.<name>`` started from ``path``."""
    arguments = ["--ros-args", "--params-file", str(path)]
    arguments += ["-p", "worker_processes:=false", "-p", "cameras:=[cam0]"]
    node = MarkerLocalizerNode("spelling", cli_args=arguments)
    try:
        return node.get_parameter(f"detector.{name}").value
    finally:
        node.destroy_node()


@pytest.mark.parametrize(
    ("name", "spelling"),
    [
        ("line_check", "y"),
        ("line_check", "n"),
        ("line_check", "yes"),
        ("line_check", "on"),
        ("max_pixels", "017"),
        ("min_contrast_dn", "0x1p4"),
    ],
)
def test_a_value_the_node_takes_is_the_value_detect_reads(ros, tmp_path, name, spelling):
    path = _params_file(tmp_path, name, spelling)
    value = _node_value(path, name)
    assert load_params_file(path) == {name: value}
    assert getattr(detector_config(path, []), name) == value


@pytest.mark.parametrize(
    ("name", "spelling"),
    [("max_pixels", "50_000_000"), ("min_contrast_dn", "null"), ("max_pixels", "1:30")],
)
def test_a_value_the_node_refuses_detect_refuses_in_the_same_words(ros, tmp_path, name, spelling):
    path = _params_file(tmp_path, name, spelling)
    with pytest.raises(ConfigError) as node_refusal:
        _node_value(path, name)
    with pytest.raises(ConfigError) as cli_refusal:
        detector_config(path, [])
    # The node names the parameter detector.<name>; detect names the section first.
    assert str(node_refusal.value) == f"detector.{str(cli_refusal.value).split(': ', 1)[1]}"


def test_an_empty_value_stops_the_node_and_detect_at_its_line(ros, tmp_path):
    path = _params_file(tmp_path, "min_contrast_dn", "")
    with pytest.raises(RuntimeError, match=r"No value at line 4"):  # rclpy's RCLError
        _node_value(path, "min_contrast_dn")
    with pytest.raises(ConfigError, match=r"line 4: detector\.min_contrast_dn has no value"):
        detector_config(path, [])
