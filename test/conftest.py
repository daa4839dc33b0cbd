"""Test-session set-up: isolate the DDS traffic of tests that start ROS nodes.

Runs before any test module imports rclpy: a random ``ROS_DOMAIN_ID`` per session
keeps two test runs on one machine (or a running robot stack) from seeing each
other's topics, and ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` keeps discovery
off the network. Subprocesses started by tests inherit both.
"""

import os
import random

# 1..101: domain ids whose DDS ports do not collide with ephemeral ports on Linux.
os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(1, 101))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
