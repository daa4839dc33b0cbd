"""ROS parameters generated from the typed configurations, validated before they apply.

Three configurations back the node's parameters, none written twice:

* :class:`marker_localizer.config.DetectorConfig`, declared as ``detector.<field>``
  with descriptors generated from :func:`marker_localizer.config.param_specs`
  (description with unit, range, choices); all of them can change live.
* :class:`marker_localizer.config.TrackerConfig`, declared as ``tracker.<field>``
  in the same way; all of them can change live (the cameras' tracks start over).
* :class:`NodeConfig`, the node's own parameters; ``cameras``, ``image_transport``,
  ``workers``, ``worker_processes``, ``diagnostics_period_s`` and ``stats_window_s``
  are structural and read-only.

Start values (``-p``, ``--params-file``) are checked as :class:`LiveParameters`
declares them, before the node starts its workers: types, ranges, unknown
``detector.*`` and ``tracker.*`` names, and the QoS overrides of the image
subscriptions, which rclpy itself reads only as it subscribes.

:class:`LiveParameters` validates a change in the on-set callback by building
the new configurations (a :class:`ConfigError` rejects it with its text as the
reason, so cross-field rules such as ``marker_radius_min_px <=
marker_radius_max_px`` always hold), and applies it in the post-set callback.
rclpy itself checks types, ranges and read-only flags first. What one callback
sees is rclpy's choice: the whole request for ``SetParametersAtomically`` (all
or nothing), one parameter at a time for ``SetParameters``, which applies each
valid one before it looks at the next; change dependent values (both radius
bounds) atomically.
"""

from __future__ import annotations

if __name__ == "__main__":
    # ``python -m`` runs the imports below first: a missing rclpy would be their
    # traceback. Imported as a module instead, it is run_command's one line.
    import sys

    from marker_localizer.cli.exits import run_command
    from marker_localizer.errors import import_needing_ros

    def _print_params_yaml() -> int:
        module = import_needing_ros("marker_localizer.ros.parameters")
        sys.stdout.write(module.params_yaml())
        return 0

    sys.exit(run_command("marker_localizer.ros.parameters", _print_params_yaml))

import dataclasses
import re
import textwrap
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

import rclpy.utilities
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, ReliabilityPolicy

from marker_localizer.config import (
    DETECTOR_NAMESPACE,
    TRACKER_NAMESPACE,
    DetectorConfig,
    ParamSpec,
    TrackerConfig,
    check_fields,
    checked_value,
    field_kind,
    from_mapping,
    guessed,
    param_specs,
    refuses_unknown_names,
)
from marker_localizer.errors import ConfigError
from marker_localizer.ros.conversions import IMAGE_TRANSPORTS
from marker_localizer.ros.diagnostics import DiagnosticThresholds

_CAMERA_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
#: The typed configurations declared as namespaced parameters, and their namespaces.
_NAMESPACES: dict[type[DetectorConfig] | type[TrackerConfig], str] = {
    DetectorConfig: DETECTOR_NAMESPACE,
    TrackerConfig: TRACKER_NAMESPACE,
}
#: The start values of the QoS overrides the subscriptions read
#: (``qos_overrides.<topic>.subscription.<policy>``: rclpy's default policies, and a
#: camera_info's durability) that name a setting, and the names rclpy takes, in any
#: case. ``depth`` is a count.
_QOS_POLICY_NAMES: dict[str, tuple[str, ...]] = {
    policy: tuple(m.name.lower() for m in kind if m.name != "UNKNOWN")
    for policy, kind in (
        ("history", HistoryPolicy),
        ("reliability", ReliabilityPolicy),
        ("durability", DurabilityPolicy),
    )
}
_QOS_OVERRIDES = "qos_overrides."


def _node_param(
    default: Any,
    description: str,
    unit: str = "",
    low: float | None = None,
    high: float | None = None,
    *,
    choices: tuple[str, ...] = (),
    read_only: bool = False,
) -> Any:
    spec = ParamSpec(description=description, unit=unit, low=low, high=high, choices=choices)
    return field(default=default, metadata={"spec": spec, "read_only": read_only})


@refuses_unknown_names
@dataclass(frozen=True)
class NodeConfig:
    """The node's own settings; validated on construction (raises :class:`ConfigError`)."""

    cameras: tuple[str, ...] = _node_param(
        ("cam0", "cam1", "cam2", "cam3", "cam4"),
        "Camera names; the node subscribes <cam>/image_raw and <cam>/camera_info and "
        "publishes <cam>/marker_points. Default: the five cameras of the UAV rig.",
        read_only=True,
    )
    image_transport: str = _node_param(
        "raw",
        "How each camera's images arrive: 'raw' reads <cam>/image_raw (sensor_msgs/Image), "
        "'compressed' reads <cam>/image_raw/compressed (sensor_msgs/CompressedImage, JPEG or "
        "PNG), the names image_transport uses. Default raw: drivers publish it, and decoding "
        "costs a worker time per frame (a 4096x3000 grey frame, one core: JPEG ~40 ms, "
        "PNG ~150 ms).",
        choices=tuple(IMAGE_TRANSPORTS),
        read_only=True,
    )
    workers: int = _node_param(
        2,
        "Workers that run the detector; one frame per camera at a time. "
        "2 = one per core of the target computer.",
        "",
        1,
        64,
        read_only=True,
    )
    worker_processes: bool = _node_param(
        True,
        "Each worker runs the detector in a process of its own (the frame through shared "
        "memory, the camera's tracks pickled: 6 ms a 12 MP frame; a compressed frame is "
        "decoded there); false: in a thread of the node's process, whose decodes take turns. "
        "Default true: on the 2-core development machine two "
        "processes took 1.5x the frames a second of two threads, which wait for Python's "
        "GIL (five 12 MP cameras, full frames, bench throughput).",
        read_only=True,
    )
    max_frame_age_s: float = _node_param(
        2.0,
        "A frame that waited longer than this in the node (from its arrival to a worker "
        "taking it) is dropped: two periods of a 1 Hz mapping camera, past which a fresher "
        "frame is due and the old one is stale for navigation. Header stamps are not "
        "judged (they may come from another clock). 0 disables the check.",
        "s",
        0.0,
        3600.0,
    )
    publish_overlay: bool = _node_param(
        False,
        "Publish <cam>/marker_overlay (bgr8, detections drawn) for every processed "
        "frame, after its marker_points. Off by default: a 12 MP overlay costs a 36 MB "
        "copy, its drawing and a publish per frame in the node's process (0.2-0.6 s on "
        "two cores, a compressed frame decoded again there).",
    )
    latency_warn_ms: float = _node_param(
        1000.0,
        "Diagnostics WARN when the latency p95 (a frame's arrival to the publication of "
        "its points) exceeds this: about the state buffer of a navigation filter that "
        "fuses delayed measurements.",
        "ms",
        1.0,
        3_600_000.0,
    )
    input_timeout_s: float = _node_param(
        2.0,
        "Diagnostics ERROR when a camera sent no frame for this long: at least two "
        "missed frames of a camera running at 1 Hz or faster.",
        "s",
        0.01,
        3600.0,
    )
    diagnostics_period_s: float = _node_param(
        1.0,
        "Period of /diagnostics (diagnostic_updater's 1 Hz).",
        "s",
        0.05,
        60.0,
        read_only=True,
    )
    stats_window_s: float = _node_param(
        10.0,
        "Sliding window of the diagnostics' rates, drop fraction, latency percentiles "
        "and of how long a failed frame keeps a camera at ERROR.",
        "s",
        0.5,
        3600.0,
        read_only=True,
    )
    expected_rate_hz: float = _node_param(
        0.0,
        "Frame rate the cameras send: diagnostics WARN when the gaps between a camera's "
        "header stamps say more than 10 % of its frames never arrived (lost in DDS, the "
        "driver or the network). 0 measures each camera's rate from its stamps, which sees "
        "random loss but takes a camera that loses every other frame for one at half rate.",
        "Hz",
        0.0,
        1000.0,
    )
    shutdown_timeout_s: float = _node_param(
        4.0,
        "Longest wait at shutdown (SIGINT, SIGTERM) for the frames in flight to be "
        "published: a 12 MP frame takes 0.1-0.5 s, and ros2 launch sends SIGTERM 5 s "
        "after SIGINT (a second signal ends the node at once) and SIGKILL 5 s later.",
        "s",
        0.0,
        3600.0,
    )

    def __post_init__(self) -> None:
        check_fields(self)
        bad = [c for c in self.cameras if not _CAMERA_NAME.match(c)]
        if not self.cameras or bad or len(set(self.cameras)) != len(self.cameras):
            raise ConfigError(
                f"cameras={list(self.cameras)!r} must be non-empty, unique names of letters, "
                "digits and '_' starting with a letter"
            )


def diagnostic_thresholds(settings: NodeConfig) -> DiagnosticThresholds:
    """The limits of the diagnostics' levels that the node's settings give."""
    return DiagnosticThresholds(
        latency_warn_ms=settings.latency_warn_ms,
        input_timeout_s=settings.input_timeout_s,
        window_s=settings.stats_window_s,
        expected_rate_hz=settings.expected_rate_hz,
    )


def node_specs() -> dict[str, tuple[dataclasses.Field[Any], ParamSpec]]:
    """Every :class:`NodeConfig` field with its :class:`ParamSpec`, in declaration order."""
    return {f.name: (f, f.metadata["spec"]) for f in dataclasses.fields(NodeConfig)}


def descriptor(
    name: str, spec: ParamSpec, kind: str, *, read_only: bool = False
) -> ParameterDescriptor:
    """Build the ParameterDescriptor of one configuration field.

    Args:
        name: full parameter name (``detector.marker_radius_min_px``).
        spec: the field's description, unit, range and choices.
        kind: the field's Python type name (``float``, ``int``, ``str``, ``bool``, ...).
        read_only: structural parameter that cannot change after start.

    Returns:
        Descriptor whose description ends with the unit in brackets, with a
        FloatingPointRange or IntegerRange where the field has bounds and the
        choices in ``additional_constraints``.
    """
    unit = f" [{spec.unit}]" if spec.unit else ""
    result = ParameterDescriptor(
        name=name, description=f"{spec.description}{unit}", read_only=read_only
    )
    if spec.low is not None and spec.high is not None:
        if kind == "float":
            result.floating_point_range = [
                FloatingPointRange(from_value=float(spec.low), to_value=float(spec.high), step=0.0)
            ]
        elif kind == "int":
            result.integer_range = [
                IntegerRange(from_value=int(spec.low), to_value=int(spec.high), step=1)
            ]
    if spec.choices:
        result.additional_constraints = f"one of: {', '.join(spec.choices)}"
    return result


def _overrides(node: Node) -> dict[str, Parameter]:
    """The node's start values (``-p``, ``--params-file``, ``parameter_overrides``) by name.

    rclpy keeps them in this attribute and has no public accessor; the node needs
    them to name unknown keys and to take an integer for a double, as the CLI does.
    """
    return dict(getattr(node, "_parameter_overrides", {}))


def _start_value(override: Parameter) -> Any:
    """An override's value; ``[]`` where it has none (rcl reads an empty YAML list so)."""
    return [] if override.type_ == Parameter.Type.NOT_SET else override.value


def _check_qos_overrides(overrides: Mapping[str, Parameter]) -> None:
    """Refuse a QoS override of a subscription that rclpy could not read.

    rclpy reads them as it creates a subscription, after the workers started, and
    fails with a traceback: a name it does not know (``best-effort``), a value of
    another type, ``unknown`` or a negative depth (an RCLError from rcl).

    Raises:
        ConfigError: naming the parameter, its value and what it takes.
    """
    for name, override in overrides.items():
        if not name.startswith(_QOS_OVERRIDES):
            continue
        policy, value = name.rpartition(".")[2], _start_value(override)
        choices = _QOS_POLICY_NAMES.get(policy)
        if choices is not None and not (isinstance(value, str) and value.lower() in choices):
            raise ConfigError(f"{name}={value!r} must be one of {', '.join(choices)}")
        if policy == "depth" and not (type(value) is int and value >= 0):
            raise ConfigError(f"{name}={value!r} must be an integer >= 0")


def _declare(
    node: Node,
    name: str,
    f: dataclasses.Field[Any],
    default: Any,
    overrides: Mapping[str, Parameter],
) -> Any:
    """Declare one field as parameter ``name``; return its start value (override or default).

    A start value is checked as a setting first: declared with it, a parameter
    takes its type (``publish_overlay:=1`` an integer one, which refuses ``false``
    later; ``cameras:=front`` a string that reads as five cameras).

    Raises:
        ConfigError: the start value is of another type or out of range, or an empty array.
    """
    read_only = bool(f.metadata.get("read_only", False))
    kind = field_kind(f)
    described = descriptor(name, f.metadata["spec"], kind, read_only=read_only)
    start = default
    if name in overrides:
        start = checked_value(name, kind, f.metadata["spec"], _start_value(overrides[name]))
        if start == ():
            raise ConfigError(f"{name}=[] must list at least one value")
    # rclpy infers STRING_ARRAY from a list, not from a tuple.
    ros_start = list(start) if isinstance(start, tuple) else start
    value = node.declare_parameter(name, ros_start, described, ignore_override=True).value
    return tuple(value) if isinstance(default, tuple) else value


class LiveParameters:
    """Declare the node's parameters and keep both configurations in step with them.

    Args:
        node: the node to declare on; its overrides (``-p``, ``--params-file``)
            give the start values.
        on_change: called with (node config, detector config, tracker config)
            after an accepted change, from the executor thread that serves the
            parameter service.

    Raises:
        ConfigError: a start value is out of range, of the wrong type, breaks
            a cross-field rule, or is a ``detector.*`` or ``tracker.*`` key no
            setting has.
    """

    def __init__(
        self,
        node: Node,
        on_change: Callable[[NodeConfig, DetectorConfig, TrackerConfig], None],
    ) -> None:
        self._on_change = on_change
        self._names = {
            kind: {f"{namespace}.{name}": name for name in param_specs(kind)}
            for kind, namespace in _NAMESPACES.items()
        }
        self._kinds = {name: field_kind(f) for name, (f, _) in node_specs().items()}
        for kind, names in self._names.items():
            self._kinds.update(
                {full: field_kind(param_specs(kind)[name][0]) for full, name in names.items()}
            )
        overrides = _overrides(node)
        # A value for the namespace itself (``detector: 5``) is refused too, unguessed.
        unknown = sorted(
            guessed(name, self._names[kind].values(), f"{namespace}.")
            if name != namespace
            else name
            for name in overrides
            for kind, namespace in _NAMESPACES.items()
            if name.partition(".")[0] == namespace and name not in self._names[kind]
        )
        if unknown:
            raise ConfigError(f"unknown parameter(s): {', '.join(unknown)}")
        _check_qos_overrides(overrides)
        try:
            node_values = {
                name: _declare(node, name, f, f.default, overrides)
                for name, (f, _) in node_specs().items()
            }
            values = {
                kind: {
                    name: _declare(
                        node, full, param_specs(kind)[name][0], getattr(kind(), name), overrides
                    )
                    for full, name in names.items()
                }
                for kind, names in self._names.items()
            }
        except (InvalidParameterValueException, InvalidParameterTypeException) as err:
            raise ConfigError(str(err)) from err
        self.node_config = NodeConfig(**node_values)
        self.detector_config = _namespaced(values[DetectorConfig], DetectorConfig())
        self.tracker_config = _namespaced(values[TrackerConfig], TrackerConfig())
        node.add_pre_set_parameters_callback(self._coerce)
        node.add_on_set_parameters_callback(self._validate)
        node.add_post_set_parameters_callback(self._apply)

    def unknown(self, node: Node) -> list[str]:
        """Start values given for parameters the node never declared (typos, other nodes').

        Each is named with the parameter it is likely a typo of, where one is close.
        """
        return sorted(
            guessed(name, self._kinds) for name in _overrides(node) if not node.has_parameter(name)
        )

    def _coerce(self, parameters: list[Parameter]) -> list[Parameter]:
        """Integers set on double parameters become doubles (``ros2 param set ... 4``).

        Every other parameter passes as it came, its type kept: inferred again from
        its value, an empty array is a byte array, and an empty double array raises
        (in the executor, which it would end).
        """
        return [
            Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
            if p.type_ == Parameter.Type.INTEGER and self._kinds.get(p.name) == "float"
            else p
            for p in parameters
        ]

    def _merged(
        self, parameters: Sequence[Parameter]
    ) -> tuple[NodeConfig, DetectorConfig, TrackerConfig]:
        """The configurations that ``parameters`` would give (raises ConfigError)."""
        node_changes: dict[str, Any] = {}
        changes: dict[type, dict[str, Any]] = {kind: {} for kind in self._names}
        for p in parameters:
            for kind, names in self._names.items():
                if p.name in names:
                    changes[kind][names[p.name]] = p.value
            if p.name in node_specs():
                node_changes[p.name] = p.value
        return (
            dataclasses.replace(self.node_config, **node_changes),
            _namespaced(changes[DetectorConfig], self.detector_config),
            _namespaced(changes[TrackerConfig], self.tracker_config),
        )

    def _validate(self, parameters: list[Parameter]) -> SetParametersResult:
        try:
            self._merged(parameters)
        except ConfigError as err:
            return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)

    def _apply(self, parameters: list[Parameter]) -> None:
        self.node_config, self.detector_config, self.tracker_config = self._merged(parameters)
        self._on_change(self.node_config, self.detector_config, self.tracker_config)


_Config = TypeVar("_Config", DetectorConfig, TrackerConfig)


def _namespaced(changes: dict[str, Any], base: _Config) -> _Config:
    """:func:`from_mapping`, its error naming each setting as the node does (``detector.x``)."""
    try:
        return from_mapping(changes, base=base)
    except ConfigError as err:
        namespace = _NAMESPACES[type(base)]
        names = "|".join(re.escape(name) for name in param_specs(type(base)))
        raise ConfigError(re.sub(rf"\b({names})=", rf"{namespace}.\1=", str(err))) from err


_YAML_WIDTH = 96
_YAML_HEADER = """\
# Parameters of the marker_localizer node, every one at its default with its unit and
# the reason for the default (the descriptors the node declares carry the same text).
# Use: marker_localizer_node --ros-args --params-file config/marker_localizer.yaml
# Keyed /** so that it applies whatever the node's name and namespace.
# GENERATED from NodeConfig, DetectorConfig and TrackerConfig by
#   python -m marker_localizer.ros.parameters > config/marker_localizer.yaml
# (a test fails when it is stale). Doubles keep their decimal point, though the node
# (and the CLI) take an integer for a double as well.
"""


def params_yaml(node_name: str = "/**") -> str:
    """The node's parameter file: every parameter at its default, each with a comment.

    Args:
        node_name: top-level key: the node's name, or ``/**`` (default) for any
            node under any namespace.

    Returns:
        YAML text in the ``<node>: ros__parameters:`` layout, the detector
        settings under ``detector:``, the tracking settings under ``tracker:``.
    """
    lines = [_YAML_HEADER.rstrip("\n"), f"{node_name}:", "  ros__parameters:"]
    for name, (f, spec) in node_specs().items():
        lines += _yaml_entry(4, name, spec, f.default, bool(f.metadata.get("read_only")))
    for kind, namespace in _NAMESPACES.items():
        what = "Detector" if kind is DetectorConfig else "Tracking"
        lines += [
            f"    # {what} settings (marker_localizer.config.{kind.__name__}), all live-tunable.",
            f"    {namespace}:",
        ]
        defaults = kind()
        for name, (_, spec) in param_specs(kind).items():
            lines += _yaml_entry(6, name, spec, getattr(defaults, name), False)
    return "\n".join(lines) + "\n"


def _yaml_entry(indent: int, name: str, spec: ParamSpec, value: Any, read_only: bool) -> list[str]:
    notes = [spec.description]
    if spec.unit:
        notes.append(f"Unit: {spec.unit}.")
    if bounds := spec.range_text():
        notes.append(f"Range: {bounds}.")
    if spec.choices:
        notes.append(f"One of: {', '.join(spec.choices)}.")
    if read_only:
        notes.append("Read-only.")
    pad = " " * indent
    comment = textwrap.wrap(" ".join(notes), _YAML_WIDTH - indent - 2)
    return [f"{pad}# {line}" for line in comment] + [f"{pad}{name}: {_yaml_scalar(value)}"]


def _yaml_scalar(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, tuple):
        return "[" + ", ".join(_yaml_scalar(v) for v in value) + "]"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, float):
        text = repr(value)
        # YAML 1.1 reads 1e-05 as a string: the mantissa needs a decimal point.
        mantissa, _, exponent = text.partition("e")
        return text if "." in mantissa else f"{mantissa}.0" + (f"e{exponent}" if exponent else "")
    return str(value)


def changed_fields(old: Any, new: Any) -> Mapping[str, Any]:
    """Fields of two dataclass instances of one type that differ, with their new values."""
    return {
        f.name: getattr(new, f.name)
        for f in dataclasses.fields(old)
        if getattr(old, f.name) != getattr(new, f.name)
    }


def own_arguments(argv: Sequence[str]) -> list[str]:
    """``argv`` (the program's name first) less its ROS arguments: the command's own.

    Raises:
        ConfigError: the ROS arguments do not parse (``-p name`` without a value,
            an unknown option such as ``--param-file``): rclpy's own error is a
            traceback.
    """
    try:
        return list(rclpy.utilities.remove_ros_args(list(argv))[1:])
    except rclpy_implementation.UnknownROSArgsError as err:
        raise ConfigError(
            f"unknown ROS arguments {err} (after --ros-args: -p name:=value, "
            "--params-file FILE, -r from:=to, --log-level LEVEL)"
        ) from err
    except rclpy_implementation.RCLError as err:  # a rule that does not parse, ...
        raise ConfigError(f"invalid ROS arguments: {' '.join(str(err).split())}") from err
