"""Fixtures of the node tests: the node under test in /inproc and a peer beside it."""

import pytest
from node_testing import (
    Peer,
    Spinner,
)
from rclpy.parameter import Parameter

from marker_localizer.ros.node import MarkerLocalizerNode


@pytest.fixture(scope="module")
def localizer(ros):
    """The node under test in namespace /inproc, default cameras, fast diagnostics.

    No age limit and a loose latency limit: on a loaded 2-core machine five
    1280x960 frames may wait longer than the defaults allow for a worker (both
    limits have their own tests).
    """
    node = MarkerLocalizerNode(
        namespace="/inproc",
        parameter_overrides=[
            Parameter("max_frame_age_s", value=0.0),
            Parameter("latency_warn_ms", value=60_000.0),
            Parameter("diagnostics_period_s", value=0.2),
            Parameter("input_timeout_s", value=600.0),
        ],
    )
    spinner = Spinner(node)
    yield node
    spinner.stop()


@pytest.fixture(scope="module")
def tester(ros):
    tester = Peer("tester", "/inproc")
    yield tester
    tester.stop()
