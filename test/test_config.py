"""The typed configuration shared by library, CLI and node."""

import inspect

import numpy as np
import pytest

from marker_localizer.config import (
    TRACKER_NAMESPACE,
    DetectorConfig,
    TrackerConfig,
    detector_config,
    from_mapping,
    load_params_file,
    param_specs,
    parse_value,
    tracker_config,
)
from marker_localizer.errors import ConfigError


def test_defaults_are_valid_and_every_field_documents_itself():
    DetectorConfig()
    for name, (_, spec) in param_specs().items():
        assert spec.description, name
        assert (
            spec.choices
            or spec.low is not None
            or isinstance(getattr(DetectorConfig(), name), bool)
        ), name


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"marker_radius_min_px": 0.1}, r"marker_radius_min_px=0.1 is outside \[1.5, 1000\] px"),
        ({"refinement": "magic"}, "refinement='magic' must be one of symmetry, ncc"),
        ({"gdwgif_radius_px": 2.5}, "gdwgif_radius_px=2.5 must be of type int"),
        ({"line_check": 1}, "line_check=1 must be of type bool"),
        ({"marker_radius_min_px": 30.0, "marker_radius_max_px": 10.0}, "is larger than"),
        ({"nonsense": 1}, "unknown parameter"),
        ({"min_contrast_dn": 0.0}, r"min_contrast_dn=0.0 is outside \[1, 255\] DN"),
    ],
)
def test_invalid_values_are_rejected_with_the_value_named(change, message):
    with pytest.raises(ConfigError, match=message):
        from_mapping(change)


@pytest.mark.parametrize(
    ("kind", "change", "message"),
    [
        (DetectorConfig, {"foo": 1}, r"^unknown parameter\(s\): foo$"),
        (
            TrackerConfig,
            {"match": 1.0},
            r"^unknown parameter\(s\): match \(did you mean match_px\?\)$",
        ),
        (
            DetectorConfig,
            {"bit_depth": "8"},
            r"^bit_depth='8' must be of type int in \[8, 16\] bit$",
        ),
        (TrackerConfig, {"max_missed_frames": 2.0}, "max_missed_frames=2.0 must be of type int"),
        (DetectorConfig, {"bit_depth": 99}, r"^bit_depth=99 is outside \[8, 16\] bit$"),
        (TrackerConfig, {"match_px": 0.0}, r"^match_px=0.0 is outside \[0.1, 50\] px$"),
        (DetectorConfig, {"refinement": "magic"}, "^refinement='magic' must be one of symmetry, "),
        (DetectorConfig, {"line_check": 1}, "^line_check=1 must be of type bool$"),
        (DetectorConfig, {"marker_radius_min_px": 50.0}, "^marker_radius_min_px=50.0 is larger"),
        # An unknown name is named first, whatever else is wrong.
        (DetectorConfig, {"bit_depth": 99, "bogus": 1}, r"^unknown parameter\(s\): bogus$"),
    ],
)
def test_the_constructor_and_replace_refuse_a_setting_with_the_same_config_error(
    kind, change, message
):
    """``Config(**values)`` (a YAML file's, a ROS node's) is told what ``replace`` is told."""
    with pytest.raises(ConfigError, match=message) as built:
        kind(**change)
    with pytest.raises(ConfigError) as replaced:
        kind().replace(**change)
    with pytest.raises(ConfigError) as mapped:
        from_mapping(change, base=kind())
    assert str(built.value) == str(replaced.value) == str(mapped.value)
    assert isinstance(built.value, ValueError)


def test_a_misspelt_setting_is_answered_with_the_name_it_is_likely_a_typo_of():
    message = (
        r"^unknown parameter\(s\): bogus, marker_radius_mn_px "
        r"\(did you mean marker_radius_min_px\?\), min_scor \(did you mean min_score\?\)$"
    )
    for build in (DetectorConfig, DetectorConfig().replace, from_mapping):
        with pytest.raises(ConfigError, match=message):
            if build is from_mapping:
                build({"min_scor": 0.5, "bogus": 1, "marker_radius_mn_px": 3.0})
            else:
                build(min_scor=0.5, bogus=1, marker_radius_mn_px=3.0)
    with pytest.raises(ConfigError, match=r"min_scor \(did you mean min_score\?\)$"):
        parse_value("min_scor", "0.5")


def test_the_constructor_keeps_its_signature_and_takes_a_mapping_of_settings():
    values = {"marker_radius_min_px": 6.0, "refinement": "ncc", "line_check": False}
    assert DetectorConfig(**values) == from_mapping(values)
    assert DetectorConfig(6.0, 30.0) == DetectorConfig().replace(
        marker_radius_min_px=6.0, marker_radius_max_px=30.0
    )
    assert list(inspect.signature(DetectorConfig).parameters) == list(param_specs())
    # A call of the wrong shape is any Python call's TypeError, not a setting's error.
    with pytest.raises(TypeError, match="multiple values"):
        DetectorConfig(4.0, marker_radius_min_px=3.0)


def test_integers_are_accepted_for_float_fields():
    assert from_mapping({"marker_radius_max_px": 50}).marker_radius_max_px == 50.0


def test_numbers_computed_with_numpy_are_accepted_and_kept_as_python_numbers():
    config = DetectorConfig(
        marker_radius_min_px=np.int64(6),
        marker_radius_max_px=np.float32(30.5),
        bit_depth=np.int64(12),
    )
    values = (config.marker_radius_min_px, config.marker_radius_max_px, config.bit_depth)
    assert values == (6.0, 30.5, 12)
    assert [type(v) for v in values] == [float, float, int]
    with pytest.raises(ConfigError, match="must be of type int"):
        DetectorConfig(bit_depth=np.float64(12.0))
    with pytest.raises(ConfigError, match="must be of type float"):
        DetectorConfig(marker_radius_min_px=np.bool_(True))


def test_the_derived_settings_follow_the_fields_they_come_from():
    config = DetectorConfig(min_peak_separation_px=7.0, min_contrast_dn=51.0)
    assert config.merge_radius_px == 3.5
    assert config.min_contrast_share == pytest.approx(0.2)


def test_replace_returns_a_validated_copy():
    config = DetectorConfig().replace(min_score=0.5)
    assert config.min_score == 0.5
    with pytest.raises(ConfigError):
        config.replace(min_score=2.0)


@pytest.mark.parametrize(
    ("name", "text", "value"),
    [
        ("marker_radius_min_px", "4", 4.0),
        ("line_check", "false", False),
        ("gdwgif_radius_px", "3", 3),
        ("refinement", "ncc", "ncc"),
        ("gdwgif_lambda", "1e-6", 1e-6),  # a float to ROS's parameters file, not to YAML 1.1
        ("min_score", "8e-1", 0.8),
        ("line_check", "yes", True),
    ],
)
def test_parse_value_reads_command_line_text_as_a_parameters_file_reads_it(name, text, value):
    parsed = parse_value(name, text)
    assert parsed == value and type(parsed) is type(value)


@pytest.mark.parametrize(
    ("name", "text", "refused"),
    [
        ("gdwgif_radius_px", "two", r"gdwgif_radius_px='two' must be of type int in \[1, 8\] px"),
        ("gdwgif_radius_px", "2.0", r"must be of type int"),
        ("line_check", "1", r"line_check=1 must be of type bool"),  # as the file, the node
        ("min_score", "1.5", r"min_score=1.5 is outside \[0, 1\]"),
    ],
)
def test_parse_value_refuses_what_the_file_and_the_node_refuse_naming_type_and_range(
    name, text, refused
):
    with pytest.raises(ConfigError, match=refused):
        parse_value(name, text)


def test_every_entry_naming_the_node_applies_a_later_ones_values_over_an_earlier_ones(tmp_path):
    # As rcl applies a launch file's merged parameters: the wildcard and the node's name.
    path = tmp_path / "params.yaml"
    path.write_text(
        "marker_localizer:\n  ros__parameters:\n    detector:\n"
        "      min_score: 0.6\n      min_contrast_dn: 30.0\n"
        "other_node:\n  ros__parameters:\n    detector:\n      min_score: 0.1\n"
        "/**:\n  ros__parameters:\n    detector:\n"
        "      min_score: 0.5\n      marker_radius_max_px: 60.0\n"
    )
    assert load_params_file(path) == {
        "min_score": 0.5,
        "min_contrast_dn": 30.0,
        "marker_radius_max_px": 60.0,
    }


def test_a_files_values_are_checked_together_with_the_command_lines_overrides(tmp_path):
    path = tmp_path / "params.yaml"
    path.write_text("/**:\n  ros__parameters:\n    detector:\n      marker_radius_min_px: 50.0\n")
    config = detector_config(path, ["marker_radius_max_px=60"])
    assert (config.marker_radius_min_px, config.marker_radius_max_px) == (50.0, 60.0)
    with pytest.raises(
        ConfigError,
        match=r"params\.yaml \(detector\): marker_radius_min_px=50\.0 is larger than",
    ):
        detector_config(path, [])
    with pytest.raises(ConfigError, match=r"params\.yaml \(detector\) and --param: "):
        detector_config(path, ["marker_radius_max_px=45"])


def test_a_tracking_setting_given_as_a_param_names_the_file_it_belongs_in():
    with pytest.raises(ConfigError, match=r"tracker\.enabled: tracking settings are read from"):
        detector_config(None, ["tracker.enabled=false"])


def test_load_params_file_reads_the_detector_section_of_a_node_yaml(tmp_path):
    path = tmp_path / "params.yaml"
    path.write_text(
        "marker_localizer:\n  ros__parameters:\n    workers: 2\n"
        "    detector:\n      marker_radius_min_px: 4.0\n      line_check: false\n"
    )
    assert load_params_file(path, "marker_localizer") == {
        "marker_radius_min_px": 4.0,
        "line_check": False,
    }


def test_load_params_file_finds_the_nodes_entry_beside_other_nodes(tmp_path):
    # A launch file's parameters: one file, an entry per node.
    path = tmp_path / "launch.yaml"
    path.write_text(
        "camera_driver:\n  ros__parameters:\n    fps: 4.0\n"
        "marker_localizer:\n  ros__parameters:\n    detector:\n      marker_radius_min_px: 6.0\n"
    )
    assert load_params_file(path) == {"marker_radius_min_px": 6.0}
    path.write_text(
        "camera_driver:\n  ros__parameters:\n    fps: 4.0\n"
        "/**/marker_localizer:\n  ros__parameters:\n    detector.line_check: false\n"
    )
    assert load_params_file(path) == {"line_check": False}


def test_a_bad_value_in_a_params_file_names_the_file(tmp_path):
    path = tmp_path / "node.yaml"
    path.write_text("marker_localizer:\n  ros__parameters:\n    detector:\n      bogus: 1\n")
    with pytest.raises(
        ConfigError, match=f"^{path} \\(detector\\): unknown parameter\\(s\\): bogus$"
    ):
        detector_config(path, [])
    # Built straight from the file's values: the same error, not a bare TypeError.
    with pytest.raises(ConfigError, match=r"^unknown parameter\(s\): bogus$"):
        DetectorConfig(**load_params_file(path))


def test_load_params_file_reads_the_tracker_section_as_the_node_declares_it(tmp_path):
    path = tmp_path / "params.yaml"
    path.write_text(
        "/**:\n  ros__parameters:\n    detector:\n      line_check: false\n"
        "    tracker.match_px: 2.0\n    tracker:\n      enabled: false\n"
    )
    values = load_params_file(path, namespace=TRACKER_NAMESPACE)
    assert values == {"match_px": 2.0, "enabled": False}
    tracking = from_mapping(values, base=TrackerConfig())
    assert (tracking.enabled, tracking.match_px, tracking.max_missed_frames) == (False, 2.0, 2)


def test_a_tracker_setting_out_of_its_range_is_refused_with_its_name():
    with pytest.raises(ConfigError, match=r"match_px=0.0 is outside \[0.1, 50\] px"):
        TrackerConfig(match_px=0.0)
    with pytest.raises(ConfigError, match="unknown parameter"):
        TrackerConfig().replace(plate_px=3.0)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("a: [", "not valid YAML"),
        ("- 1\n- 2\n", "expected a mapping"),
        ("other:\n  x: 1\n", "no ros__parameters"),
        ("/**:\n  ros__parameters:\n    detector: 5\n", "ros__parameters.detector must be a map"),
        ("/**:\n  ros__parameters:\n    detector:\n", "line 3: detector has no value"),
    ],
)
def test_load_params_file_explains_what_is_wrong(tmp_path, text, message):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_params_file(path)


def test_a_params_file_that_is_not_utf8_text_is_refused_as_such(tmp_path):
    path = tmp_path / "latin1.yaml"
    path.write_bytes("/**:\n  ros__parameters:\n    detector: {}  # café\n".encode("latin-1"))
    with pytest.raises(ConfigError, match=r"not valid YAML \(not UTF-8 text\)"):
        load_params_file(path)


def test_a_bad_tracker_value_in_a_params_file_names_the_file_and_its_section(tmp_path):
    path = tmp_path / "node.yaml"
    path.write_text("/**:\n  ros__parameters:\n    tracker:\n      enabled: 0\n      foo: 1\n")
    with pytest.raises(ConfigError, match=f"^{path} \\(tracker\\): unknown parameter\\(s\\): foo"):
        tracker_config(path)
    path.write_text("/**:\n  ros__parameters:\n    tracker:\n      match_px: 2.0\n")
    assert tracker_config(path).match_px == 2.0
    assert tracker_config(None) == TrackerConfig()


def test_load_params_file_names_a_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="cannot read parameters file"):
        load_params_file(tmp_path / "missing.yaml")


# The spellings below were read by the node itself (python -m marker_localizer.node
# --ros-args --params-file f.yaml, its get_parameters service or its fatal line;
# rclpy 7.1.5, Jazzy, 2026-12-07); test/ros/test_params_file_spellings.py starts it.


def _params_file(tmp_path, name, spelling):
    path = tmp_path / "params.yaml"
    path.write_text(f"/**:\n  ros__parameters:\n    detector:\n      {name}: {spelling}\n")
    return path


def test_an_integer_written_with_underscores_is_text_to_the_file_as_to_the_node(tmp_path):
    """``max_pixels: 50_000_000``: the node stops on ``detector.max_pixels='50_000_000' must
    be of type int in [1, 1073741824] px`` (rcl's strtol reads no underscores), where
    PyYAML's YAML 1.1 read 50000000 and ``detect`` ran."""
    path = _params_file(tmp_path, "max_pixels", "50_000_000")
    assert load_params_file(path) == {"max_pixels": "50_000_000"}
    with pytest.raises(
        ConfigError, match=r"max_pixels='50_000_000' must be of type int in \[1, 1073741824\] px$"
    ):
        detector_config(path, [])


@pytest.mark.parametrize(
    ("spelling", "value"),
    [
        ("y", True),
        ("Y", True),
        ("n", False),
        ("N", False),
        ("yes", True),
        ("on", True),
        ("off", False),
    ],
)
def test_yaml_1_1_booleans_are_booleans_to_the_file_as_to_the_node(tmp_path, spelling, value):
    """``line_check: y`` (and ``Y``, ``n``, ``N``): the node serves with ``detector.line_check``
    True (False for ``n``); PyYAML read ``y`` and ``n`` as strings, and ``detect`` refused
    them. ``yes``, ``on``, ``off`` were booleans to both, and still are."""
    path = _params_file(tmp_path, "line_check", spelling)
    assert load_params_file(path) == {"line_check": value}
    assert detector_config(path, []).line_check is value


def test_an_empty_value_stops_the_file_naming_the_parameter_as_it_stops_the_node(tmp_path):
    """``min_contrast_dn:`` with nothing: the node does not start (``Couldn't parse params
    file ... No value at line 4``), where PyYAML read None and the refusal was of a type."""
    path = _params_file(tmp_path, "min_contrast_dn", "")
    with pytest.raises(
        ConfigError, match=r"params\.yaml: line 4: detector\.min_contrast_dn has no value"
    ):
        load_params_file(path)
    # Anywhere in the file: the node refuses it for another node's empty value too.
    path.write_text(
        "camera:\n  ros__parameters:\n    fps:\n"
        "/**:\n  ros__parameters:\n    detector:\n      min_score: 0.5\n"
    )
    with pytest.raises(ConfigError, match=r"line 3: fps has no value"):
        load_params_file(path)


@pytest.mark.parametrize(
    ("name", "spelling", "value"),
    [
        ("min_contrast_dn", "~", "~"),  # PyYAML: None
        ("min_contrast_dn", "null", "null"),  # PyYAML: None
        ("max_pixels", "1:30", "1:30"),  # PyYAML: 90 (base 60)
        ("max_pixels", "0b101", "0b101"),  # PyYAML: 5
        ("refinement", "2001-12-14", "2001-12-14"),  # PyYAML: a date
        ("min_contrast_dn", "0x1p4", 16.0),  # strtod's hexadecimal float; PyYAML: text
        ("max_pixels", "08", 8.0),  # not octal, so strtod's float; PyYAML: 8.0 too
        ("max_pixels", "017", 15),  # octal to both
        ("min_contrast_dn", "'30'", "30"),  # quoted: text to both
        ("max_pixels", "!!str 5000", "5000"),
        ("max_pixels", "|-\n        5000", 5000),  # a block scalar is read as a plain one
    ],
)
def test_other_scalars_read_as_the_nodes_parser_reads_them(tmp_path, name, spelling, value):
    """Each as rcl's parser gave it to an rclpy node declaring the file's parameters."""
    parsed = load_params_file(_params_file(tmp_path, name, spelling))[name]
    assert parsed == value and type(parsed) is type(value)


def test_a_key_is_its_text_and_an_alias_is_refused_as_the_node_does(tmp_path):
    """rcl names a parameter ``on`` (PyYAML: True) and stops on ``*name`` (``Will not support
    aliasing at line 5``)."""
    path = _params_file(tmp_path, "on", "3")
    assert load_params_file(path) == {"on": 3}
    path.write_text(
        "/**:\n  ros__parameters:\n    detector:\n"
        "      max_pixels: &pixels 5000\n      max_candidates: *pixels\n"
    )
    with pytest.raises(ConfigError, match=r"line 5, column 23: an alias"):
        load_params_file(path)


def test_a_param_on_the_command_line_reads_y_as_the_file_does():
    assert parse_value("line_check", "y") is True
    with pytest.raises(ConfigError, match=r"max_pixels='50_000_000' must be of type int"):
        parse_value("max_pixels", "50_000_000")
