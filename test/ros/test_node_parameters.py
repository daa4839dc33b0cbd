"""The node's parameters: live changes, validation, descriptors, the params file."""

import multiprocessing
import re
import threading

import pytest
import yaml
from node_testing import (
    NODE_MODULE,
    PARAMS_FILE,
    REPO,
    holding,
    run_to_exit,
    serving,
    wait_until,
    x_marker_64,
)
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import (
    DescribeParameters,
    SetParameters,
)
from rclpy.parameter import Parameter
from rclpy.qos import ReliabilityPolicy
from sensor_msgs.msg import Image, PointCloud2

from marker_localizer.cli import main as cli_main
from marker_localizer.config import DetectorConfig, TrackerConfig
from marker_localizer.errors import ConfigError
from marker_localizer.ros.node import MarkerLocalizerNode
from marker_localizer.ros.parameters import NodeConfig, params_yaml

# --------------------------------------------------------------------------- parameters


def test_accepted_parameter_change_takes_effect_on_the_next_frame(localizer, tester):
    tester.listen("cam1/marker_points", PointCloud2)
    image = x_marker_64()

    def markers_in_next_frame():
        frame = tester.frame(image)
        tester.publish("cam1/image_raw", frame)
        return tester.result_for("cam1/marker_points", frame.header).width

    assert markers_in_next_frame() == 1
    (result,) = tester.set_parameters(
        "/inproc/marker_localizer", [("detector.min_contrast_dn", 255.0)]
    )
    assert result.successful, result.reason
    assert tester.get_parameter("/inproc/marker_localizer", "detector.min_contrast_dn") == 255.0
    assert markers_in_next_frame() == 0  # no marker has 255 DN between its quadrants
    (result,) = tester.set_parameters(
        "/inproc/marker_localizer",
        [("detector.min_contrast_dn", DetectorConfig().min_contrast_dn)],
        atomically=True,
    )
    assert result.successful, result.reason
    assert markers_in_next_frame() == 1


def test_a_change_during_a_frame_in_flight_applies_from_the_next_frame(ros):
    """A frame a worker took finishes with the settings it was taken with.

    The held detector stands in for what comes between the take and the detection
    (decoding a compressed frame: 40-150 ms at 12 MP).
    """
    processor_class, release = holding("cam0")
    settings = {"cameras": ["cam0"], "workers": 1, "worker_processes": False}
    with serving("in_flight", settings, processor_class) as (node, peer):
        try:
            peer.listen("cam0/marker_points", PointCloud2)
            peer.listen("cam0/marker_overlay", Image)
            held = peer.frame(x_marker_64())
            peer.publish("cam0/image_raw", held)
            wait_until(lambda: node.processor.in_flight() == ["cam0"], "the frame in flight")
            changes = [("detector.min_contrast_dn", 255.0), ("publish_overlay", True)]
            results = peer.set_parameters("/in_flight/in_flight_localizer", changes)
            assert all(r.successful for r in results), results
            release.set()
            assert peer.result_for("cam0/marker_points", held.header).width == 1
            following = peer.frame(x_marker_64())
            peer.publish("cam0/image_raw", following)
            # No marker has 255 DN between its quadrants.
            assert peer.result_for("cam0/marker_points", following.header).width == 0
            peer.result_for("cam0/marker_overlay", following.header)
            assert [m.header for m in peer.messages("cam0/marker_overlay")] == [following.header]
        finally:
            release.set()


@pytest.mark.parametrize(
    ("name", "value", "reason"),
    [
        ("detector.marker_radius_min_px", 0.5, "out of range"),
        (
            "detector.marker_radius_min_px",
            50.0,
            "detector.marker_radius_min_px=50.0 is larger than detector.marker_radius_max_px=40.0",
        ),
        ("detector.refinement", "magic", "refinement='magic' must be one of symmetry, ncc"),
        ("detector.marker_radius_max_px", "big", "Wrong parameter type"),
        ("detector.ncc_search_px", 2.5, "Wrong parameter type"),
        ("max_frame_age_s", -1.0, "out of range"),
        ("tracker.match_px", 0.0, "out of range"),
        ("tracker.full_frame_every", 2.5, "Wrong parameter type"),
        ("workers", 4, "read-only"),
        ("worker_processes", False, "read-only"),
        ("cameras", ["cam0"], "read-only"),
    ],
)
def test_invalid_parameter_values_are_rejected_with_a_reason(
    localizer, tester, name, value, reason
):
    before = tester.get_parameter("/inproc/marker_localizer", name)
    (result,) = tester.set_parameters("/inproc/marker_localizer", [(name, value)])
    assert not result.successful
    assert reason in result.reason
    assert tester.get_parameter("/inproc/marker_localizer", name) == before


@pytest.mark.parametrize(
    ("name", "value", "expected"),
    [
        (
            "detector.min_contrast_dn",
            ParameterValue(type=ParameterType.PARAMETER_DOUBLE_ARRAY),
            "DOUBLE",
        ),
        (
            "detector.max_pixels",
            ParameterValue(type=ParameterType.PARAMETER_INTEGER_ARRAY),
            "INTEGER",
        ),
    ],
)
def test_an_empty_array_for_a_parameter_is_refused_and_the_node_serves_on(
    ros, name, value, expected
):
    """Rebuilt from its value, an empty double array raised in the executor and ended it."""
    with serving("empty_array", {"worker_processes": False}) as (_, peer):
        node = "/empty_array/empty_array_localizer"
        request = SetParameters.Request(parameters=[ParameterMsg(name=name, value=value)])
        (result,) = peer.call(SetParameters, f"{node}/set_parameters", request).results
        assert not result.successful
        assert expected in result.reason
        # The empty array is named as what it is, not as a byte array.
        assert "BYTE_ARRAY" not in result.reason
        assert peer.get_parameter(node, "detector.min_contrast_dn") == 20.0


def test_an_integer_is_taken_for_a_double_as_the_cli_takes_it(localizer, tester):
    name = "detector.marker_radius_max_px"
    (result,) = tester.set_parameters("/inproc/marker_localizer", [(name, 30)])
    try:
        assert result.successful, result.reason
        value = tester.get_parameter("/inproc/marker_localizer", name)
        assert (value, type(value)) == (30.0, float)
        assert localizer.processor.config.marker_radius_max_px == 30.0
    finally:
        tester.set_parameters("/inproc/marker_localizer", [(name, 40.0)])


PARAMS_ANY_NODE = """\
/**:
  ros__parameters:
    max_frame_age: 5.0
    detector:
      marker_radius_min_px: 5
      marker_radius_max_px: 30
"""


def test_a_params_file_keyed_for_any_node_applies_under_a_namespace_and_another_name(
    ros, tmp_path, capfd
):
    path = tmp_path / "params.yaml"
    path.write_text(PARAMS_ANY_NODE)
    node = MarkerLocalizerNode(
        "renamed", namespace="/uav1", cli_args=["--ros-args", "--params-file", str(path)]
    )
    try:
        config = node.processor.config
        assert (config.marker_radius_min_px, config.marker_radius_max_px) == (5.0, 30.0)
        assert node.get_parameter("detector.marker_radius_min_px").value == 5.0
        # A key no parameter has is named, not silently dropped.
        assert (
            "ignoring unknown parameter(s): max_frame_age (did you mean max_frame_age_s?)"
            in capfd.readouterr().err
        )
    finally:
        node.destroy_node()
    assert (
        cli_main(
            ["detect", str(REPO / "docs" / "detection.jpg"), "--params-file", str(path), "--json"]
        )
        == 0
    )


def test_a_node_config_built_in_python_refuses_an_unknown_name_as_the_detectors_does():
    """``NodeConfig(workres=2)``: the ConfigError ``DetectorConfig`` gives, not a TypeError."""
    with pytest.raises(
        ConfigError, match=r"^unknown parameter\(s\): workres \(did you mean workers\?\)$"
    ):
        NodeConfig(workres=2)
    assert NodeConfig(workers=2).workers == 2


def test_node_and_cli_refuse_an_unknown_detector_key_and_name_it(ros, tmp_path, capsys):
    path = tmp_path / "params.yaml"
    path.write_text(PARAMS_ANY_NODE.replace("marker_radius_max_px", "marker_radius_maximum_px"))
    with pytest.raises(
        ConfigError,
        match=r"unknown parameter\(s\): detector.marker_radius_maximum_px "
        r"\(did you mean detector.marker_radius_max_px\?\)$",
    ):
        MarkerLocalizerNode("typo", cli_args=["--ros-args", "--params-file", str(path)])
    assert (
        cli_main(["detect", str(REPO / "docs" / "detection.jpg"), "--params-file", str(path)]) == 1
    )
    assert "unknown parameter(s): marker_radius_maximum_px" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("name", "value", "message"),
    [
        # A string for the camera list read as five cameras, f, r, o, n, t.
        ("cameras", "front", r"cameras='front' must be of type list of strings$"),
        ("cameras", [], r"cameras=\[\] must list at least one value"),
        ("workers", "two", r"workers='two' must be of type int in \[1, 64\]$"),
        ("workers", 2.0, r"workers=2.0 must be of type int in \[1, 64\]$"),
        ("workers", 0, r"workers=0 is outside \[1, 64\]"),
        (
            "detector.marker_radius_min_px",
            "five",
            r"marker_radius_min_px='five' must be of type float in \[1.5, 1000\] px$",
        ),
        ("detector.refinement", 1, r"refinement=1 must be one of symmetry, ncc, template$"),
        # The bound in full, not as :g's 1.07374e+09.
        ("detector.max_pixels", 2**31, r"max_pixels=2147483648 is outside \[1, 1073741824\] px$"),
        ("max_frame_age_s", True, "max_frame_age_s=True must be of type float"),
        # Declared with it, the parameter was an integer one that refused false later.
        ("publish_overlay", 1, "publish_overlay=1 must be of type bool"),
        ("detector.line_check", "no", "detector.line_check='no' must be of type bool"),
        ("tracker.bogus", 1, r"unknown parameter\(s\): tracker.bogus$"),
        (
            "tracker.match",
            1.0,
            r"unknown parameter\(s\): tracker.match \(did you mean tracker.match_px\?\)$",
        ),
        # The namespace itself given a value, as a YAML file that lost its indentation does.
        ("detector", 5, r"unknown parameter\(s\): detector$"),
        # A parameter rclpy declares itself, before the node's own.
        ("use_sim_time", 1, r"'use_sim_time' to '1' of type 'INTEGER', expecting type 'BOOL'"),
    ],
)
def test_a_start_value_of_the_wrong_type_or_range_is_refused_naming_it(ros, name, value, message):
    with pytest.raises(ConfigError, match=message):
        MarkerLocalizerNode("typed", parameter_overrides=[Parameter(name, value=value)])


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        # rcl reads an empty list as a parameter of no type, no value.
        (["-p", "cameras:=[]"], r"^cameras=\[\] must list at least one value$"),
        (
            ["-p", "detector.marker_radius_min_px:=[]"],
            r"^detector.marker_radius_min_px=\[\] must be of type float in \[1.5, 1000\] px$",
        ),
    ],
)
def test_an_empty_list_on_the_command_line_is_named_as_given(ros, arguments, message):
    with pytest.raises(ConfigError, match=message):
        MarkerLocalizerNode("empty", cli_args=["--ros-args", *arguments])


@pytest.mark.parametrize(
    ("policy", "value", "message"),
    [
        (
            "reliability",
            "best-effort",
            r"reliability='best-effort' must be one of system_default, reliable, best_effort",
        ),
        ("reliability", "unknown", r"reliability='unknown' must be one of"),
        ("reliability", 1, r"reliability=1 must be one of"),
        ("history", "keep-last", r"history='keep-last' must be one of system_default, keep_last"),
        ("depth", -1, r"depth=-1 must be an integer >= 0$"),
        ("depth", "1", r"depth='1' must be an integer >= 0$"),
    ],
)
def test_a_qos_override_rclpy_cannot_read_is_refused_naming_it_before_the_workers_start(
    ros, policy, value, message
):
    """rclpy reads them as it subscribes, after the workers start, and raised a traceback."""
    subscription = "qos_overrides./qos/cam0/image_raw.subscription."
    overrides = [Parameter(subscription + policy, value=value)]
    workers_before = _workers()
    with pytest.raises(ConfigError, match=f"^{re.escape(subscription)}{message}"):
        MarkerLocalizerNode("typed", namespace="/qos", parameter_overrides=overrides)
    assert _workers() <= workers_before  # other modules' nodes may still be stopping theirs


def _workers():
    """The worker processes and threads of every node of this process."""
    threads = {t for t in threading.enumerate() if t.name.startswith("marker_worker_")}
    return set(multiprocessing.active_children()) | threads


def test_a_qos_override_applies_to_its_camera_alone_in_any_case(ros):
    """rclpy wrote the override into the profile it was given, which the cameras after shared."""
    overrides = [
        Parameter("cameras", value=["cam0", "cam1", "cam2"]),
        Parameter(
            "qos_overrides./qos/cam1/image_raw.subscription.reliability", value="Best_Effort"
        ),
        Parameter("worker_processes", value=False),
    ]
    node = MarkerLocalizerNode("typed", namespace="/qos", parameter_overrides=overrides)
    try:
        reliability = {
            camera: node.get_subscriptions_info_by_topic(f"/qos/{camera}/image_raw")[
                0
            ].qos_profile.reliability
            for camera in ("cam0", "cam1", "cam2")
        }
        assert reliability == {
            "cam0": ReliabilityPolicy.RELIABLE,
            "cam1": ReliabilityPolicy.BEST_EFFORT,
            "cam2": ReliabilityPolicy.RELIABLE,
        }
    finally:
        node.destroy_node()


PARAMS_FOR = """\
{key}:
  ros__parameters:
    worker_processes: false
    detector:
      marker_radius_max_px: 30
"""


@pytest.mark.parametrize(
    ("key", "namespace", "radius_max_px"),
    [
        ("marker_localizer", "/", 30.0),
        # A name without its namespace is the root namespace's node, as rcl reads it.
        ("marker_localizer", "/uav1", 40.0),
        ("/uav1/marker_localizer", "/uav1", 30.0),
        ("/**/marker_localizer", "/uav1", 30.0),
        ("/uav1/*", "/uav1", 30.0),
        ("/uav2/marker_localizer", "/uav1", 40.0),  # another namespace's node: the default
    ],
)
def test_a_params_file_keyed_by_the_nodes_name_or_namespace_applies_to_it_alone(
    ros, tmp_path, key, namespace, radius_max_px
):
    path = tmp_path / "params.yaml"
    path.write_text(PARAMS_FOR.format(key=key))
    node = MarkerLocalizerNode(
        namespace=namespace,
        cli_args=["--ros-args", "--params-file", str(path), "-p", "worker_processes:=false"],
    )
    try:
        assert node.processor.config.marker_radius_max_px == radius_max_px
    finally:
        node.destroy_node()


def test_a_value_given_with_p_after_the_params_file_wins(ros, tmp_path):
    path = tmp_path / "params.yaml"
    path.write_text(PARAMS_FOR.format(key="/**"))
    arguments = ["--params-file", str(path), "-p", "detector.marker_radius_max_px:=35"]
    node = MarkerLocalizerNode("later", cli_args=["--ros-args", *arguments])
    try:
        assert node.processor.config.marker_radius_max_px == 35.0
        assert node.get_parameter("detector.marker_radius_max_px").value == 35.0
    finally:
        node.destroy_node()


@pytest.mark.parametrize(
    ("parameters", "message"),
    [
        (
            "qos_overrides:\n      /cam0/image_raw:\n        subscription:\n"
            "          reliability: best-effort",
            "qos_overrides./cam0/image_raw.subscription.reliability='best-effort' must be one of",
        ),
        ("use_sim_time: 1", "Trying to set parameter 'use_sim_time' to '1' of type 'INTEGER'"),
        (
            "detector:\n      marker_radius_min_px: five",
            "detector.marker_radius_min_px='five' must be of type float in [1.5, 1000] px",
        ),
    ],
    ids=["qos-override", "rclpy-parameter", "detector-setting"],
)
def test_node_process_refuses_a_bad_params_file_value_in_one_line(tmp_path, parameters, message):
    path = tmp_path / "params.yaml"
    path.write_text(f"/**:\n  ros__parameters:\n    {parameters}\n")
    result = run_to_exit([*NODE_MODULE, "--ros-args", "--params-file", str(path)])
    assert result.returncode == 1
    (line,) = result.stderr.splitlines()
    assert f"invalid configuration: {message}" in line


def test_a_start_value_of_a_double_may_be_an_integer(ros):
    overrides = [Parameter("max_frame_age_s", value=3), Parameter("worker_processes", value=False)]
    node = MarkerLocalizerNode("typed", parameter_overrides=overrides)
    try:
        assert node.get_parameter("max_frame_age_s").type_ == Parameter.Type.DOUBLE
        assert node.get_parameter("max_frame_age_s").value == 3.0
    finally:
        node.destroy_node()


def test_a_camera_name_too_long_for_a_topic_under_the_namespace_is_refused_naming_it(ros):
    """The names' own rule cannot see the namespace; rclpy's topic check does."""
    cameras = [Parameter("cameras", value=["c" * 200]), Parameter("worker_processes", value=False)]
    MarkerLocalizerNode("short_ns", namespace="/a", parameter_overrides=cameras).destroy_node()
    with pytest.raises(ConfigError, match=r"camera 'ccc.*topic length should not exceed"):
        MarkerLocalizerNode("long_ns", namespace="/" + "n" * 50, parameter_overrides=cameras)


def test_atomic_request_with_one_invalid_value_applies_nothing(localizer, tester):
    (result,) = tester.set_parameters(
        "/inproc/marker_localizer",
        [("detector.marker_radius_max_px", 60.0), ("detector.marker_radius_min_px", 70.0)],
        atomically=True,
    )
    assert not result.successful
    assert (
        "detector.marker_radius_min_px=70.0 is larger than detector.marker_radius_max_px=60.0"
        in result.reason
    )
    assert tester.get_parameter("/inproc/marker_localizer", "detector.marker_radius_max_px") == 40.0
    assert localizer.processor.config.marker_radius_max_px == 40.0


def test_non_atomic_request_applies_each_parameter_on_its_own_in_order(localizer, tester):
    """SetParameters validates and applies one parameter after the other (README)."""
    node = "/inproc/marker_localizer"
    try:
        first, second = tester.set_parameters(
            node, [("detector.marker_radius_max_px", 60.0), ("detector.marker_radius_min_px", 70.0)]
        )
        assert first.successful  # valid alone: applied before the second is looked at
        assert not second.successful
        assert (
            "detector.marker_radius_min_px=70.0 is larger than detector.marker_radius_max_px=60.0"
            in (second.reason)
        )
        assert tester.get_parameter(node, "detector.marker_radius_max_px") == 60.0
        assert tester.get_parameter(node, "detector.marker_radius_min_px") == 4.0
        assert localizer.processor.config.marker_radius_max_px == 60.0
        # Values that are valid one after the other all apply.
        results = tester.set_parameters(
            node, [("detector.marker_radius_max_px", 80.0), ("detector.marker_radius_min_px", 70.0)]
        )
        assert [r.successful for r in results] == [True, True]
        assert localizer.processor.config.marker_radius_min_px == 70.0
    finally:
        tester.set_parameters(
            node, [("detector.marker_radius_min_px", 4.0), ("detector.marker_radius_max_px", 40.0)]
        )
    assert localizer.processor.config.marker_radius_max_px == 40.0


def test_parameter_descriptors_state_unit_range_and_read_only(localizer, tester):
    names = ["detector.marker_radius_min_px", "detector.refinement", "workers", "max_frame_age_s"]
    request = DescribeParameters.Request(names=names)
    radius, refinement, workers, age = tester.call(
        DescribeParameters, "/inproc/marker_localizer/describe_parameters", request
    ).descriptors
    assert radius.description.endswith("[px]")
    assert radius.type == ParameterType.PARAMETER_DOUBLE
    assert (radius.floating_point_range[0].from_value, radius.floating_point_range[0].to_value) == (
        1.5,
        1000.0,
    )
    assert not radius.read_only
    assert refinement.additional_constraints == "one of: symmetry, ncc, template"
    assert workers.read_only
    assert workers.integer_range[0].from_value == 1
    assert age.description.endswith("[s]")


def test_the_tracker_settings_are_live_parameters_with_unit_and_range(localizer, tester):
    request = DescribeParameters.Request(names=["tracker.max_motion_px", "tracker.enabled"])
    motion, enabled = tester.call(
        DescribeParameters, "/inproc/marker_localizer/describe_parameters", request
    ).descriptors
    assert motion.description.endswith("[px]")
    assert motion.floating_point_range[0].to_value == 1000.0
    assert enabled.type == ParameterType.PARAMETER_BOOL and not enabled.read_only
    (result,) = tester.set_parameters("/inproc/marker_localizer", [("tracker.match_px", 2.5)])
    assert result.successful
    assert localizer.processor.tracker_config.match_px == 2.5


def test_parameter_file_lists_every_parameter_at_its_default():
    assert PARAMS_FILE.read_text() == params_yaml()
    params = yaml.safe_load(PARAMS_FILE.read_text())["/**"]["ros__parameters"]
    assert DetectorConfig(**params["detector"]) == DetectorConfig()
    assert TrackerConfig(**params["tracker"]) == TrackerConfig()
