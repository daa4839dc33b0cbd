"""The node's console script (``marker_localizer_node``) and ``python -m marker_localizer.node``.

Without ROS 2 Jazzy's Python packages it says what to install, in one line.
Ctrl-C (or SIGTERM) before the node serves, while ROS and the detector are
still being imported, is one line too, and exit status 130 (143).
"""

import sys

from marker_localizer.errors import RosMissingError, import_needing_ros
from marker_localizer.stopping import run_interruptible

#: The console script's name, the first word of the lines it writes outside ROS's log.
PROG = "marker_localizer_node"


def _serve() -> int:
    try:
        node = import_needing_ros("marker_localizer.ros.node")
    except RosMissingError as missing:
        sys.stderr.write(f"{PROG}: error: {missing}\n")
        return 1
    status: int = node.main()
    return status


def main() -> int:
    """Run the ROS 2 node (:func:`marker_localizer.ros.node.main`); its exit status."""
    return run_interruptible(PROG, _serve)


if __name__ == "__main__":
    sys.exit(main())
