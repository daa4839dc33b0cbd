"""What the node tests share: a spun node, a peer that publishes frames and listens, polls.

Nodes under test run in the test process, each spun by its own executor thread;
a peer node publishes rendered frames with exact ground truth and listens to
every output. Waits are polls with generous deadlines, never fixed sleeps.
"""

import os
import subprocess
import sys
import threading
from collections import defaultdict
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
import rclpy
import waiting
from builtin_interfaces.msg import Time
from rcl_interfaces.srv import (
    GetParameters,
    SetParameters,
    SetParametersAtomically,
)
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image
from std_msgs.msg import Header

from marker_localizer.bench.throughput import process_table
from marker_localizer.ros.conversions import array_to_image, cloud_to_array
from marker_localizer.ros.node import MarkerLocalizerNode
from marker_localizer.ros.processing import FrameProcessor
from marker_localizer.synthetic import SceneConfig, render_scene

REPO = Path(__file__).resolve().parents[2]
PARAMS_FILE = REPO / "config" / "marker_localizer.yaml"
CAMERAS = ("cam0", "cam1", "cam2", "cam3", "cam4")
TIMEOUT_S = 30.0
#: Sub-pixel accuracy the node must deliver on rendered frames, px.
TOLERANCE_PX = 0.1
IMAGE_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
#: The node started as a separate process with ``python -m``, as a user may start it.
NODE_MODULE = [sys.executable, "-m", "marker_localizer.node"]


# --------------------------------------------------------------------------- helpers


def run_to_exit(command):
    """Run ``command`` (a node that refuses its start values, say) to its exit, output as text."""
    return subprocess.run(command, capture_output=True, text=True, timeout=TIMEOUT_S, check=False)


def wait_until(predicate, what, timeout_s=TIMEOUT_S):
    """Poll ``predicate`` for up to this module's timeout."""
    return waiting.wait_until(predicate, what, timeout_s)


def scene(width, height, n_markers, seed):
    """A rendered frame on flat ground with exact marker centres."""
    config = SceneConfig(
        width=width,
        height=height,
        n_markers=n_markers,
        radius_px=(12.0, 30.0),
        max_tilt_deg=30.0,
        noise_sigma_dn=(0.0, 2.0),
        background="flat",
        n_hard_negatives=0,
        supersampling=4,
    )
    return render_scene(config, seed)


def x_marker_64():
    """The analytic X of the Detector docstring: exact centre (31.5, 31.5)."""
    image = np.full((64, 64), 200, np.uint8)
    image[:32, :32] = image[32:, 32:] = 30
    return cv2.GaussianBlur(image, (0, 0), 1.0)


def points_xy(cloud):
    points = cloud_to_array(cloud)
    return np.column_stack([points["x"], points["y"]])


def assert_matches_truth(found_xy, truth_xy):
    """Every marker found within TOLERANCE_PX of its truth, and nothing else found."""
    assert len(found_xy) == len(truth_xy), f"found {found_xy}, truth {truth_xy}"
    distance = np.linalg.norm(found_xy[:, None, :] - truth_xy[None, :, :], axis=2)
    assert distance.min(axis=0).max() < TOLERANCE_PX
    assert distance.min(axis=1).max() < TOLERANCE_PX


def level_of(status):
    return status.level[0]


def values_of(status):
    return {kv.key: kv.value for kv in status.values}


class Spinner:
    """Spin one node with its own executor in a background thread."""

    def __init__(self, node):
        self.node = node
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def stop(self):
        self.executor.shutdown()
        self.thread.join(TIMEOUT_S)
        self.node.destroy_node()


class Peer:
    """The other side of the node: publishes frames, collects outputs, calls services."""

    def __init__(self, name, namespace):
        self.node = rclpy.create_node(name, namespace=namespace)
        self.lock = threading.Lock()
        self.received = defaultdict(list)  # topic -> messages
        self.publishers = {}
        self.subscriptions = {}
        self.spinner = Spinner(self.node)

    def listen(self, topic, msg_type):
        """Subscribe to ``topic`` (once) and wait until a publisher is matched."""
        if topic not in self.subscriptions:

            def collect(msg, topic=topic):
                with self.lock:
                    self.received[topic].append(msg)

            self.subscriptions[topic] = self.node.create_subscription(msg_type, topic, collect, 50)
        sub = self.subscriptions[topic]
        wait_until(lambda: sub.get_publisher_count() > 0, f"a publisher on {topic}")

    def messages(self, topic):
        with self.lock:
            return list(self.received[topic])

    def frame(self, pixels, encoding="mono8", frame_id="camera", stamp=None):
        header = Header(stamp=stamp or self.node.get_clock().now().to_msg(), frame_id=frame_id)
        return array_to_image(pixels, encoding, header)

    def publish(self, topic, msg):
        if topic not in self.publishers:
            self.publishers[topic] = self.node.create_publisher(Image, topic, IMAGE_QOS)
        pub = self.publishers[topic]
        wait_until(lambda: pub.get_subscription_count() > 0, f"the node subscribing {topic}")
        pub.publish(msg)

    def result_for(self, topic, header, timeout_s=TIMEOUT_S):
        """The output on ``topic`` whose stamp is the stamp of ``header``."""
        return wait_until(
            lambda: next((m for m in self.messages(topic) if m.header.stamp == header.stamp), None),
            f"{topic} for stamp {header.stamp.sec}.{header.stamp.nanosec:09d}",
            timeout_s,
        )

    def call(self, srv_type, name, request):
        client = self.node.create_client(srv_type, name)
        try:
            wait_until(lambda: client.wait_for_service(timeout_sec=0.1), f"service {name}")
            future = client.call_async(request)
            wait_until(future.done, f"the answer of {name}")
            return future.result()
        finally:
            self.node.destroy_client(client)

    def set_parameters(self, node_fqn, parameters, atomically=False):
        msgs = [Parameter(name, value=value).to_parameter_msg() for name, value in parameters]
        if atomically:
            request = SetParametersAtomically.Request(parameters=msgs)
            return [
                self.call(
                    SetParametersAtomically, f"{node_fqn}/set_parameters_atomically", request
                ).result
            ]
        request = SetParameters.Request(parameters=msgs)
        return self.call(SetParameters, f"{node_fqn}/set_parameters", request).results

    def get_parameter(self, node_fqn, name):
        request = GetParameters.Request(names=[name])
        (value,) = self.call(GetParameters, f"{node_fqn}/get_parameters", request).values
        return parameter_value_to_python(value)

    def stop(self):
        self.spinner.stop()


def holding(camera):
    """A worker pool whose detector holds ``camera``'s frames until the event is set.

    A stand-in for a detector too slow for its camera, whatever the speed of the
    real one: while a worker holds one frame, every newer frame of that camera
    replaces the one waiting in its mailbox.
    """
    release = threading.Event()

    class HeldCameraProcessor(FrameProcessor):
        def detect(self, frame_camera, pixels, stamp_s):
            if frame_camera == camera:
                release.wait(TIMEOUT_S)
            return super().detect(frame_camera, pixels, stamp_s)

    return HeldCameraProcessor, release


def clock_ahead(processor_class):
    """``processor_class`` on the node's clock plus an offset the test moves forward.

    Moving the offset ages the frames waiting in the mailboxes without waiting in
    real time, so an age limit is crossed when the test says so, however loaded
    the machine is.

    Returns:
        (the class, ``advance(seconds)``).
    """
    ahead_ns = [0]

    class ClockAheadProcessor(processor_class):
        def __init__(self, *args, clock_ns, **kwargs):
            super().__init__(*args, clock_ns=lambda: clock_ns() + ahead_ns[0], **kwargs)

    def advance(seconds):
        ahead_ns[0] += round(seconds * 1e9)

    return ClockAheadProcessor, advance


@contextmanager
def serving(name, overrides, processor_class=FrameProcessor):
    """A node ``<name>_localizer`` in namespace ``/<name>``, spun, and a peer beside it."""
    node = MarkerLocalizerNode(
        f"{name}_localizer",
        namespace=f"/{name}",
        processor_class=processor_class,
        parameter_overrides=[Parameter(key, value=value) for key, value in overrides.items()],
    )
    spinner = Spinner(node)
    peer = Peer(f"{name}_peer", f"/{name}")
    try:
        yield node, peer
    finally:
        peer.stop()
        spinner.stop()


class Collector:
    """Result callback that records (camera, stamp sec) and can hold the worker."""

    def __init__(self):
        self.results = []
        self.release = threading.Event()
        self.release.set()
        self.entered = threading.Event()

    def __call__(self, camera, cloud):
        self.entered.set()
        self.release.wait(TIMEOUT_S)
        self.results.append((camera, cloud.header.stamp.sec, cloud.width))


def stamped(sec, pixels=None):
    pixels = x_marker_64() if pixels is None else pixels
    return array_to_image(pixels, "mono8", Header(stamp=Time(sec=sec)))


def clock_at(seconds):
    return lambda: int(seconds * 1e9)


def worker_process_ids(node_pid: int | None = None) -> set[int]:
    """Live processes whose parent is a child of the node's: the fork server's workers."""
    parents = {pid: stat.parent for pid, stat in process_table().items() if stat.state != "Z"}
    node_pid = os.getpid() if node_pid is None else node_pid
    children = {pid for pid, parent in parents.items() if parent == node_pid}
    return {pid for pid, parent in parents.items() if parent in children}


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie does not)."""
    stat = process_table().get(pid)
    return stat is not None and stat.state != "Z"


def shared_memory_blocks() -> set[str]:
    """Python's shared memory blocks now (its semaphores live in /dev/shm too)."""
    return {name for name in os.listdir("/dev/shm") if name.startswith("psm_")}


def mapped_shared_memory_blocks(pid: int) -> set[str]:
    """The shared memory blocks of Python's that process ``pid`` has mapped now.

    Unlike :func:`shared_memory_blocks`, blind to the blocks of other processes on
    the machine (another test run's).
    """
    lines = Path(f"/proc/{pid}/maps").read_text().splitlines()
    return {Path(line.split()[-1]).name for line in lines if "/dev/shm/psm_" in line}
