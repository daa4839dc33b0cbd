"""The node's console script (``marker_localizer_node``) and ``python -m marker_localizer.node``.

Without ROS 2 Jazzy's Python packages it says what to install, in one line.
"""

import sys

from marker_localizer.errors import RosMissingError, import_needing_ros


def main() -> int:
    """Run the ROS 2 node (:func:`marker_localizer.ros.node.main`); its exit status."""
    try:
        node = import_needing_ros("marker_localizer.ros.node")
    except RosMissingError as missing:
        sys.stderr.write(f"marker_localizer_node: error: {missing}\n")
        return 1
    status: int = node.main()
    return status


if __name__ == "__main__":
    sys.exit(main())
