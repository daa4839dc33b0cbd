"""Test-session set-up: isolate the DDS traffic of tests that start ROS nodes.

Runs before any test module imports rclpy: a random ``ROS_DOMAIN_ID`` per session
keeps two test runs on one machine (or a running robot stack) from seeing each
other's topics, and ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` keeps discovery
off the network. Subprocesses started by tests inherit both.
"""

import os
import random

import pytest

# 1..101: domain ids whose DDS ports do not collide with ephemeral ports on Linux.
os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(1, 101))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"


@pytest.fixture(scope="module")
def ros():
    """rclpy initialised for the module's nodes, shut down after it."""
    import rclpy  # noqa: PLC0415 - after the DDS set-up; the core tests run without ROS

    rclpy.init()
    yield
    rclpy.try_shutdown()


@pytest.fixture(scope="session")
def small_flight(tmp_path_factory):
    """A simulated 3-frame, five-camera, 320x240 flight (MCAP), written once per session."""
    from marker_localizer.cli import main as cli  # noqa: PLC0415 - after the DDS set-up

    path = tmp_path_factory.mktemp("small_flight") / "flight"
    argv = ["--out", str(path), "--frames", "3", "--width", "320", "--height", "240"]
    assert cli(["simulate", *argv, "--seed", "2"]) == 0
    return path
