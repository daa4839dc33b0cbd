"""``marker-localizer simulate``: fly the simulator and record a rosbag2 with exact truth.

Topics written, per camera ``<cam>`` of the rig (``cam0`` nadir, ``cam1`` to
``cam4`` forward, backward, left, right), each message at bag time = its
header stamp = the frame's mid-exposure time:

* ``/<cam>/image_raw``: sensor_msgs/Image, mono8 (``bayer_<pattern>8`` for a flight of
  Bayer cameras, ``FlightConfig.bayer_pattern``), ``frame_id`` ``<cam>_optical``;
* ``/<cam>/camera_info``: sensor_msgs/CameraInfo, K and P of the pinhole,
  ``plumb_bob`` with D all zero (the renderer has no distortion), R identity;
* ``/<cam>/marker_points_truth``: sensor_msgs/PointCloud2 in the layout of the
  node's ``marker_points`` (:mod:`marker_localizer.ros.conversions`): the exact
  centre of every marker whose plate lies wholly inside the frame, sigma 0,
  score 1, the two line angles of the truth, and a ``marker_id`` field (uint32):
  the marker's index in the flight, the same in every frame and camera that sees it,
  so that an evaluation can tell a marker seen again from another one;
* ``/<cam>/marker_points_partial``: the same, ``marker_id`` included, for markers
  the frame border cuts (a marker cut in one frame keeps the id it has where it is
  whole); an evaluation ignores detections there rather than counting them false.

Once, at the first stamp: ``/tf_static`` (tf2_msgs/TFMessage, offered
transient-local) with each ``base_link -> <cam>_optical`` extrinsic. tf2_msgs
has no wheel here, so that message is serialised with rosbags' typestore
instead of rclpy; the flight configuration and seed are stored in the bag's
``custom_data`` (``marker_localizer.flight``) so the world can be rebuilt
(:func:`recorded_flight`: the aircraft's poses and the markers' world positions).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from builtin_interfaces.msg import Time
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import Header

from marker_localizer.bag.io import DEFAULT_STORAGE, BagWriter, typestore
from marker_localizer.core.result import Detection
from marker_localizer.errors import BagError, described, shorten
from marker_localizer.ros.conversions import (
    CAMERA_INFO_SUFFIX,
    IMAGE_TRANSPORTS,
    array_to_image,
    bayer_encoding,
    detections_to_cloud,
)
from marker_localizer.synthetic.flight import FlightConfig, FlightSimulator, PinholeCamera
from marker_localizer.synthetic.scene import MarkerTruth

#: Suffixes of the per-camera topics: the node's inputs (the raw image transport and
#: the calibration), and the truth beside them.
IMAGE_SUFFIX = IMAGE_TRANSPORTS["raw"][0]
TRUTH_SUFFIX = "marker_points_truth"
PARTIAL_SUFFIX = "marker_points_partial"
TF_STATIC_TOPIC = "/tf_static"
BODY_FRAME = "base_link"
#: custom_data key of the flight configuration and seed (JSON).
FLIGHT_METADATA_KEY = "marker_localizer.flight"
_NS_PER_S = 1_000_000_000
_TF_STATIC_QOS = Qos(
    QosHistory.KEEP_LAST,
    1,
    QosReliability.RELIABLE,
    QosDurability.TRANSIENT_LOCAL,
    QosTime(0, 0),
    QosTime(0, 0),
    QosLiveliness.AUTOMATIC,
    QosTime(0, 0),
    False,
)


@dataclass(frozen=True)
class RecordSummary:
    """What :func:`record_flight` wrote.

    Attributes:
        path: The bag.
        frames: Frame sets.
        cameras: Camera names.
        truth_markers: Markers in the truth topics, all frames and cameras.
        messages: Messages written.
    """

    path: Path
    frames: int
    cameras: list[str]
    truth_markers: int
    messages: int

    @property
    def frame_sets(self) -> str:
        """``"1 frame set"``, ``"4 frame sets"``: how the summaries count them."""
        return f"{self.frames} frame set{'' if self.frames == 1 else 's'}"


def optical_frame(camera: str) -> str:
    """TF frame of a camera's images: ``<cam>_optical``."""
    return f"{camera}_optical"


def stamp_msg(stamp_ns: int) -> Time:
    """builtin_interfaces/Time of a stamp in nanoseconds."""
    return Time(sec=stamp_ns // _NS_PER_S, nanosec=stamp_ns % _NS_PER_S)


def camera_info(camera: PinholeCamera, header: Header) -> CameraInfo:
    """sensor_msgs/CameraInfo of a distortion-free pinhole camera."""
    k = camera.intrinsics
    info = CameraInfo()
    info.header = header
    info.width, info.height = camera.width, camera.height
    info.distortion_model = "plumb_bob"
    info.d = [0.0] * 5
    info.k = k.ravel().tolist()
    info.r = np.eye(3).ravel().tolist()
    info.p = np.hstack([k, np.zeros((3, 1))]).ravel().tolist()
    return info


def truth_cloud(
    header: Header, truths: Sequence[MarkerTruth], marker_ids: Sequence[int] | None = None
) -> Any:
    """Truth as the node's PointCloud2: exact centre, sigma 0, score 1, truth angles.

    With ``marker_ids`` (one per truth, :attr:`CameraFrame.marker_ids` or
    :attr:`CameraFrame.partial_ids`), the truth cloud's ``marker_id`` field too
    (:func:`detections_to_cloud`).
    """
    points = [
        Detection(
            x=t.x,
            y=t.y,
            score=1.0,
            sigma=0.0,
            angle1=t.angles[0],
            angle2=t.angles[1],
            radius_px=t.radius_px,
        )
        for t in truths
    ]
    return detections_to_cloud(header, points, marker_ids)


def _tf_static(cameras: Sequence[PinholeCamera], stamp_ns: int) -> bytes:
    """/tf_static (base_link -> <cam>_optical) serialised through rosbags' typestore."""
    store = typestore()
    types = store.types
    time_msg = types["builtin_interfaces/msg/Time"](
        sec=stamp_ns // _NS_PER_S, nanosec=stamp_ns % _NS_PER_S
    )
    transforms = []
    for camera in cameras:
        x, y, z, w = Rotation.from_matrix(camera.rotation_body_camera).as_quat()
        tx, ty, tz = (float(v) for v in camera.position_body_m)
        transforms.append(
            types["geometry_msgs/msg/TransformStamped"](
                header=types["std_msgs/msg/Header"](stamp=time_msg, frame_id=BODY_FRAME),
                child_frame_id=optical_frame(camera.name),
                transform=types["geometry_msgs/msg/Transform"](
                    translation=types["geometry_msgs/msg/Vector3"](x=tx, y=ty, z=tz),
                    rotation=types["geometry_msgs/msg/Quaternion"](
                        x=float(x), y=float(y), z=float(z), w=float(w)
                    ),
                ),
            )
        )
    message = types["tf2_msgs/msg/TFMessage"](transforms=transforms)
    return bytes(store.serialize_cdr(message, "tf2_msgs/msg/TFMessage"))


def record_flight(
    simulator: FlightSimulator,
    out: str | Path,
    *,
    storage: str = DEFAULT_STORAGE,
    progress: Callable[[int], None] | None = None,
) -> RecordSummary:
    """Render every frame set of ``simulator`` into a new bag at ``out``.

    Args:
        simulator: The flight (its config and seed go into the bag's metadata).
        out: Bag directory to create; must not exist.
        storage: ``"mcap"`` or ``"sqlite3"``.
        progress: Called with the number of frame sets written so far.

    Returns:
        What was written.

    Raises:
        BagError: ``out`` exists, is named as a bag file (``.mcap``, ``.db3``,
            ``.bag``) or cannot be written.
    """
    cameras = simulator.rig
    names = [c.name for c in cameras]
    pattern = simulator.config.bayer_pattern
    encoding = "mono8" if pattern is None else bayer_encoding(pattern, 8)
    truth_markers = 0
    with BagWriter(out, storage) as bag:
        bag.set_metadata(
            FLIGHT_METADATA_KEY,
            json.dumps({"seed": simulator.seed, "config": dataclasses.asdict(simulator.config)}),
        )
        bag.add_topic(TF_STATIC_TOPIC, "tf2_msgs/msg/TFMessage", [_TF_STATIC_QOS])
        for name in names:
            bag.add_topic(f"/{name}/{IMAGE_SUFFIX}", "sensor_msgs/msg/Image")
            bag.add_topic(f"/{name}/{CAMERA_INFO_SUFFIX}", "sensor_msgs/msg/CameraInfo")
            bag.add_topic(f"/{name}/{TRUTH_SUFFIX}", "sensor_msgs/msg/PointCloud2")
            bag.add_topic(f"/{name}/{PARTIAL_SUFFIX}", "sensor_msgs/msg/PointCloud2")
        first_ns = simulator.poses[0].stamp_ns
        bag.write_raw(TF_STATIC_TOPIC, first_ns, _tf_static(cameras, first_ns))
        for done, frame in enumerate(simulator, start=1):
            t_ns = frame.pose.stamp_ns
            for view in frame.cameras:
                name = view.camera.name
                header = Header(stamp=stamp_msg(t_ns), frame_id=optical_frame(name))
                bag.write(
                    f"/{name}/{IMAGE_SUFFIX}", t_ns, array_to_image(view.image, encoding, header)
                )
                bag.write(f"/{name}/{CAMERA_INFO_SUFFIX}", t_ns, camera_info(view.camera, header))
                bag.write(
                    f"/{name}/{TRUTH_SUFFIX}",
                    t_ns,
                    truth_cloud(header, view.markers, view.marker_ids),
                )
                bag.write(
                    f"/{name}/{PARTIAL_SUFFIX}",
                    t_ns,
                    truth_cloud(header, view.partial, view.partial_ids),
                )
                truth_markers += len(view.markers)
            if progress is not None:
                progress(done)
        messages = sum(bag.counts.values())
    return RecordSummary(Path(out), len(simulator), names, truth_markers, messages)


def recorded_flight(bag: str | Path) -> FlightSimulator:
    """The simulator that recorded ``bag`` (:func:`record_flight`), rebuilt from its metadata.

    What a pose estimator fed the bag is checked against: its ``poses``, the
    aircraft's at each frame set (``stamp_ns`` the images' header stamps; the
    cameras' extrinsics are the bag's ``/tf_static``), and its ``markers``, their
    centres on the ground plane (``x_m``, ``y_m``; z = 0), indexed as
    ``render(k).cameras[c].marker_ids`` gives them.

    Raises:
        BagError: ``bag`` is no bag directory that ``simulate`` wrote.
    """
    metadata = Path(bag) / "metadata.yaml"
    try:
        info = yaml.safe_load(metadata.read_text(encoding="utf-8"))["rosbag2_bagfile_information"]
        flight = json.loads(info["custom_data"][FLIGHT_METADATA_KEY])
        # JSON gives the tuples back as lists.
        fields: dict[str, Any] = {
            k: tuple(v) if isinstance(v, list) else v for k, v in flight["config"].items()
        }
        return FlightSimulator(FlightConfig(**fields), seed=flight["seed"])
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as err:
        raise BagError(
            f"{bag}: no flight that simulate recorded ({shorten(described(err))})"
        ) from err
