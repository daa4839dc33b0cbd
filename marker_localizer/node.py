"""The node's console script (``marker_localizer_node``) and ``python -m marker_localizer.node``.

Without ROS 2 Jazzy's Python packages it says what to install, in one line.
"""

import sys

from marker_localizer.errors import RosMissingError


def main() -> int:
    """Run the ROS 2 node (:func:`marker_localizer.ros.node.main`); its exit status."""
    try:
        from marker_localizer.ros.node import main as run_node  # noqa: PLC0415
    except ModuleNotFoundError as err:
        missing = RosMissingError.where_missing(err)
        if missing is None:
            raise
        sys.stderr.write(f"marker_localizer_node: error: {missing}\n")
        return 1
    return run_node()


if __name__ == "__main__":
    sys.exit(main())
