"""Exception tree of marker_localizer.

Every error a user can cause derives from :class:`MarkerLocalizerError`; the
CLI turns these into one line and exit status 1, so only a bug shows a
traceback. Values that come from outside (an encoding string, an exception's
text) are quoted through :func:`shorten`, so a hostile 1 MB value never
becomes a 1 MB log line or diagnostics message.
"""

from __future__ import annotations

import importlib
from types import ModuleType

#: Longest text an error message quotes from outside, characters: more than any
#: real encoding name, path or OpenCV message.
QUOTE_LIMIT = 200


def shorten(text: str, limit: int = QUOTE_LIMIT) -> str:
    """``text`` cut to ``limit`` characters, saying how long it was when cut."""
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def described(err: BaseException) -> str:
    """``Type: message``: how diagnostics and summaries name a frame's failure."""
    return f"{type(err).__name__}: {err}"


class MarkerLocalizerError(Exception):
    """Base class of every error this package raises on purpose."""


class ConfigError(MarkerLocalizerError, ValueError):
    """A configuration value is unknown, of the wrong type or out of range."""


class ImageError(MarkerLocalizerError, ValueError):
    """An image cannot be read or has a layout the detector cannot use."""


class BagError(MarkerLocalizerError):
    """A bag cannot be read, has no usable topics, or cannot be written."""


class OutputError(MarkerLocalizerError):
    """The command's output (stdout) cannot be written: a full disk, a device gone."""


class WorkerError(MarkerLocalizerError):
    """A worker process ended while it held a frame (killed: out of memory, a signal)."""


#: How a pip venv gets ROS 2 Jazzy's Python packages (README, "Installing").
ROS_WHEELS = "pip install ros-jazzy-rclpy ros-jazzy-common-interfaces ros-jazzy-rmw-fastrtps-cpp"


class RosMissingError(MarkerLocalizerError):
    """A command needs ROS 2 Jazzy's Python packages (the node, the bag tools), not installed."""

    def __init__(self, missing: ModuleNotFoundError) -> None:
        super().__init__(
            f"needs ROS 2 Jazzy's Python packages ({missing}): {ROS_WHEELS}, "
            "or source a ROS 2 Jazzy install"
        )


#: The pip distribution of each imported module whose name differs from its module's.
_DISTRIBUTIONS = {"cv2": "opencv-python-headless", "skimage": "scikit-image", "yaml": "PyYAML"}


class DependencyMissingError(MarkerLocalizerError):
    """A command needs a Python package that is not installed, one pip installs (not ROS)."""

    def __init__(self, missing: ModuleNotFoundError) -> None:
        module = (missing.name or "").partition(".")[0]
        distribution = _DISTRIBUTIONS.get(module, module)
        super().__init__(
            f"needs the Python package {distribution} ({missing}): pip install {distribution}"
        )


def is_ros_module(name: str) -> bool:
    """Whether the module ``name`` is ROS 2's: rclpy and what it loads, a message package."""
    top = name.partition(".")[0]
    return (
        top in {"rclpy", "rpyutils", "ament_index_python"}
        or top.startswith(("rosidl", "rmw"))
        or top.endswith(("_msgs", "_interfaces"))
    )


def missing_dependency(missing: ModuleNotFoundError) -> MarkerLocalizerError:
    """The error that says what to install for a module that was not found.

    Raises:
        ModuleNotFoundError: ``missing`` itself, where the module is one of ours or
            unnamed: a bug, not an installation's gap.
    """
    name = missing.name or ""
    if not name or name.partition(".")[0] == "marker_localizer":
        raise missing
    return RosMissingError(missing) if is_ros_module(name) else DependencyMissingError(missing)


def import_needing_ros(name: str) -> ModuleType:
    """Import the module ``name``, one that imports ROS 2 (the node, the bag tools).

    Raises:
        RosMissingError: the import failed because one of ROS 2's modules is missing.
        DependencyMissingError: it failed because another package is (rosbags,
            scikit-image for a benchmark): the line names that package, not ROS.
        ModuleNotFoundError: a module of ours is missing (a bug).
    """
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as err:
        raise missing_dependency(err) from err
