"""``python -m marker_localizer.node``: run the ROS 2 node (same as ``marker_localizer_node``)."""

import sys

from marker_localizer.ros.node import main

if __name__ == "__main__":
    sys.exit(main())
