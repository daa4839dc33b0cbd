"""Flight simulator: a UAV with five pinhole cameras over a marked, textured ground plane.

Frames (metres, radians):

* world: ENU, x east, y north, z up; the ground is the plane z = 0;
* body (``base_link``, REP-103): x forward, y left, z up;
* camera optical frame (``<cam>_optical``, REP-103): x right, y down, z along
  the optical axis.

A camera sees the ground through the plane -> image homography
``H = K [r1 r2 t]`` (``r1``, ``r2`` the first two columns of the world -> camera
rotation, ``t`` the world origin in camera coordinates), from ground metres
(x, y) to pixels. Everything drawn goes through it: the ground texture (a
seamlessly repeated mosaic of scikit-image photographs, warped with
``cv2.warpPerspective`` from the pyramid level whose sampling matches the
camera's), the markers (``H`` times the marker's own plane -> ground map, painted
with area-integrated supersampling by :func:`~marker_localizer.synthetic.scene.composite_target`)
and a world-fixed light field (cloud illumination and soft shadows, so the same
shadow falls on the same ground in every camera). The imaging chain of
:func:`~marker_localizer.synthetic.scene.apply_imaging` then adds the Gaussian
PSF, the motion blur of the aircraft's displacement during the exposure,
vignetting, Poisson-Gaussian noise and 8-bit quantisation.

Ground truth is exact: a marker's centre in a camera is ``H`` applied to the
marker's world origin, for the pose at mid-exposure (the frame stamp). A camera
frame's truth lists the markers whose whole plate lies inside the frame and in
front of the camera; markers cut by the border are listed apart (``partial``),
so an evaluation can ignore detections there instead of calling them false.

Coordinates in images: float64 pixels, x right, y down, (0, 0) at the centre of
the top-left pixel (the convention of ROS CameraInfo and OpenCV as well).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from marker_localizer.config import DetectorConfig
from marker_localizer.core.image import BAYER_PATTERNS
from marker_localizer.errors import ConfigError
from marker_localizer.synthetic.scene import (
    BRIGHT_REFLECTANCE_RANGE,
    DARK_REFLECTANCE_RANGE,
    DEFAULT_FULL_WELL_E,
    MARKER_KINDS,
    PATTERNS,
    PLATE_HALF_SIDE,
    ImagingConditions,
    MarkerTruth,
    PlanarTarget,
    apply_imaging,
    bayer_gain,
    composite_target,
    illumination_field,
    shadow_field,
)
from marker_localizer.synthetic.textures import (
    GROUND_REFLECTANCE_LIMITS,
    periodic_component,
    texture_background,
)

#: Camera names of the multi-aperture rig, in layout order: nadir, forward, backward,
#: left, right. The node's default ``cameras`` parameter uses the same names.
CAMERA_NAMES: tuple[str, ...] = ("cam0", "cam1", "cam2", "cam3", "cam4")
#: Direction each camera is tilted towards, as a rotation vector axis in the body
#: frame (the sign turns the optical axis from straight down towards the named side).
_TILT_AXES: tuple[tuple[float, float, float], ...] = (
    (0.0, 0.0, 0.0),  # nadir
    (0.0, -1.0, 0.0),  # forward: about -y turns -z towards +x
    (0.0, 1.0, 0.0),  # backward
    (1.0, 0.0, 0.0),  # left: about +x turns -z towards +y
    (-1.0, 0.0, 0.0),  # right
)
#: Nadir camera in the body frame: image x to the aircraft's right, image y
#: backwards (the top of the image looks ahead), optical axis down.
_NADIR_BODY_OPTICAL = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]).T
#: Lever arm of the cameras: 0.1 m below the body origin, the tilted ones 0.08 m
#: out towards their side, like a compact five-lens oblique camera head.
_LEVER_ARM_M = 0.08
_MOUNT_DEPTH_M = 0.1
#: Pixels across the world light field (clouds and shadows): it is smooth, so a
#: coarse grid warped per camera is enough.
_LIGHT_FIELD_PX = 512
#: Smallest and largest side of the ground texture mosaic, px (it repeats with this
#: period) ...
_MOSAIC_MIN_PX = 1024
_MOSAIC_MAX_PX = 4096
#: ... a multiple of this, so that each level of its pyramid, down to 64 px, halves
#: the period exactly and repeats without a seam too.
_MOSAIC_MULTIPLE_PX = 64
#: Pixels of the repeated texture read beyond each border by ``cv2.pyrDown`` (its 5x5
#: kernel reaches 2; an even count keeps the halved grid on the texture's).
_PYR_DOWN_REACH_PX = 2
_NS_PER_S = 1_000_000_000


# --------------------------------------------------------------------------- configuration


@dataclass(frozen=True)
class FlightConfig:
    """What to fly and how to image it; validated on construction (raises ConfigError).

    The defaults give a five-camera oblique rig at 4096 x 3000 px flying at
    about 118 m, where 0.5 m markers appear with a radius of 15 px at nadir and
    about 4 to 20 px in the oblique views. Smaller frames keep the field of
    view: with ``altitude_m`` left at None the altitude scales with the focal
    length, so markers keep their size in pixels (320 x 240 flies at ~9 m).

    Attributes:
        width: Frame width, px.
        height: Frame height, px.
        n_frames: Number of synchronised frame sets.
        n_cameras: Cameras used, 1 to 5, taken from :data:`CAMERA_NAMES` in order.
        frame_rate_hz: Frame sets per second.
        horizontal_fov_deg: Horizontal field of view of every camera, degrees;
            sets the focal length ``fx = fy = (width / 2) / tan(fov / 2)``.
        tilt_deg: Off-nadir tilt of the four oblique cameras, degrees.
        marker_radius_m: Radius of the X (centre to the outer edge of the
            quarter disks or checker squares), m; the plate is 1.25 times wider.
        marker_kinds: Marker kinds to draw from (``"quarter_disks"``, ``"checker"``).
        nadir_marker_radius_px: Marker radius at nadir that sets the default
            altitude, px.
        altitude_m: Flying height above the ground, m; None: from
            ``nadir_marker_radius_px``. Either way above 0.1 m, the cameras' depth
            below the aircraft's origin.
        marker_spacing_m: Grid spacing of the markers on the ground, m (each
            jittered by a quarter of it); None: 0.3 times the nadir camera's
            across-track footprint (5 to 9 markers per nadir frame).
        speed_mps: Ground speed, m/s, along a straight line.
        course_deg: Direction of flight in the world, degrees counter-clockwise
            from east (ENU yaw).
        attitude_jitter_deg: Standard deviation of roll, pitch and yaw jitter per
            frame, degrees.
        exposure_s: Exposure time, s; the aircraft's motion during it blurs the frame.
        blur_sigma_px: Gaussian PSF sigma of the optics, px.
        noise_sigma_dn: Read-noise sigma, 8-bit DN.
        full_well_e: Full-well capacity for shot noise, electrons; None: none.
        vignetting: Fraction of light lost in the frame corners.
        illumination_strength: Depth of the smooth world illumination field
            (clouds), 0 to :data:`~marker_localizer.synthetic.scene.MAX_ILLUMINATION_STRENGTH`
            (gain 1 - strength / 2 at its darkest).
        n_shadows: Soft-edged shadows on the ground (world-fixed).
        frame_gain_range: (min, max) global light gain per frame set (sun
            and exposure changes).
        supersampling: Samples per pixel along each axis at marker edges.
        start_time_ns: Stamp of the first frame set, ns since the epoch.
        bayer_pattern: Colour filter array of every camera, one of
            :data:`~marker_localizer.core.image.BAYER_PATTERNS`: the frames are
            its raw mosaic of the achromatic scene, each pixel's signal times its
            colour's :data:`~marker_localizer.synthetic.scene.RAW_BAYER_GAINS` before
            the noise. None: monochrome sensors.
    """

    width: int = 4096
    height: int = 3000
    n_frames: int = 10
    n_cameras: int = 5
    frame_rate_hz: float = 2.0
    horizontal_fov_deg: float = 60.0
    tilt_deg: float = 30.0
    marker_radius_m: float = 0.5
    marker_kinds: tuple[str, ...] = MARKER_KINDS
    nadir_marker_radius_px: float = 15.0
    altitude_m: float | None = None
    marker_spacing_m: float | None = None
    speed_mps: float = 8.0
    course_deg: float = 0.0
    attitude_jitter_deg: float = 1.0
    exposure_s: float = 0.002
    blur_sigma_px: float = 0.7
    noise_sigma_dn: float = 1.5
    full_well_e: float | None = DEFAULT_FULL_WELL_E
    vignetting: float = 0.25
    illumination_strength: float = 0.4
    n_shadows: int = 4
    frame_gain_range: tuple[float, float] = (0.8, 1.0)
    supersampling: int = 8
    start_time_ns: int = 1_700_000_000 * _NS_PER_S
    bayer_pattern: str | None = None

    def __post_init__(self) -> None:
        positive = {
            "width": self.width,
            "height": self.height,
            "n_frames": self.n_frames,
            "frame_rate_hz": self.frame_rate_hz,
            "marker_radius_m": self.marker_radius_m,
            "nadir_marker_radius_px": self.nadir_marker_radius_px,
            "supersampling": self.supersampling,
        }
        for name, value in positive.items():
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"{name}={value!r} must be positive and finite")
        if self.frame_rate_hz > _NS_PER_S:
            # Stamps are whole nanoseconds: two frame sets would share one.
            raise ConfigError(f"frame_rate_hz={self.frame_rate_hz!r} must be at most 1e9")
        # The altitude follows from the frame's width; a frame narrower than a marker's
        # plate at nadir makes a flight of thousands of markers no frame shows whole.
        plate_px = 2.0 * PLATE_HALF_SIDE * self.nadir_marker_radius_px
        if min(self.width, self.height) < plate_px:
            raise ConfigError(
                f"width x height {self.width}x{self.height} must hold a marker's plate at "
                f"nadir, {plate_px:g} px (nadir_marker_radius_px={self.nadir_marker_radius_px:g})"
            )
        if self.width * self.height > DetectorConfig.max_pixels:
            # Frames the node and replay refuse at their default, and memory for the
            # render (OpenCV's warp fails at some 10^10 px without saying why).
            raise ConfigError(
                f"width x height {self.width}x{self.height} is over the "
                f"{DetectorConfig.max_pixels} px the detector takes (max_pixels)"
            )
        if not 1 <= self.n_cameras <= len(CAMERA_NAMES):
            raise ConfigError(f"n_cameras={self.n_cameras!r} must be in [1, {len(CAMERA_NAMES)}]")
        if not 1.0 <= self.horizontal_fov_deg <= 120.0:
            raise ConfigError(f"horizontal_fov_deg={self.horizontal_fov_deg!r} must be in [1, 120]")
        if not 0.0 <= self.tilt_deg <= 45.0:
            raise ConfigError(f"tilt_deg={self.tilt_deg!r} must be in [0, 45]")
        if self.altitude_m is not None and not (
            math.isfinite(self.altitude_m) and self.altitude_m > 0
        ):
            raise ConfigError(f"altitude_m={self.altitude_m!r} must be positive and finite")
        # The cameras hang below the body origin: at or under the ground they see no
        # ground (an empty flight) or blur it over more pixels than memory holds.
        if not self.flight_altitude_m > _MOUNT_DEPTH_M:
            raise ConfigError(
                f"flight altitude {self.flight_altitude_m:g} m must exceed the cameras' "
                f"{_MOUNT_DEPTH_M:g} m below the aircraft's origin (altitude_m="
                f"{self.altitude_m!r}, marker_radius_m={self.marker_radius_m:g})"
            )
        if self.marker_spacing_m is not None and not (
            self.marker_spacing_m > 2 * PLATE_HALF_SIDE * self.marker_radius_m
        ):
            raise ConfigError(
                f"marker_spacing_m={self.marker_spacing_m!r} must exceed the plate width "
                f"{2 * PLATE_HALF_SIDE * self.marker_radius_m:g} m"
            )
        unknown = set(self.marker_kinds) - set(MARKER_KINDS)
        if not self.marker_kinds or unknown:
            raise ConfigError(
                f"marker_kinds must be a non-empty subset of {MARKER_KINDS}, "
                f"got {self.marker_kinds!r}"
            )
        low, high = self.frame_gain_range
        if not 0.0 < low <= high <= 1.0:
            raise ConfigError(
                f"frame_gain_range={self.frame_gain_range!r} must be 0 < min <= max <= 1"
            )
        if self.full_well_e is not None and not self.full_well_e > 0:
            raise ConfigError(f"full_well_e={self.full_well_e!r} must be positive or None")
        for name in ("speed_mps", "exposure_s", "attitude_jitter_deg"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ConfigError(f"{name}={value!r} must be finite and >= 0")
        if self.bayer_pattern is not None and self.bayer_pattern not in BAYER_PATTERNS:
            raise ConfigError(
                f"bayer_pattern={self.bayer_pattern!r} must be one of {BAYER_PATTERNS} or None"
            )
        # The imaging fields are checked by the renderer's own rules.
        ImagingConditions(
            blur_sigma_px=self.blur_sigma_px,
            illumination_strength=self.illumination_strength,
            n_shadows=self.n_shadows,
            vignetting=self.vignetting,
            noise_sigma_dn=self.noise_sigma_dn,
            shot_noise_gain_dn=self.shot_noise_gain_dn,
        )

    @property
    def shot_noise_gain_dn(self) -> float:
        """Shot-noise variance per DN of signal of the full well, DN (0 without one)."""
        return 0.0 if self.full_well_e is None else 255.0 / self.full_well_e

    @property
    def focal_px(self) -> float:
        """Focal length of every camera, px."""
        return 0.5 * self.width / math.tan(math.radians(0.5 * self.horizontal_fov_deg))

    @property
    def flight_altitude_m(self) -> float:
        """Flying height above the ground, m (``altitude_m`` or its default)."""
        if self.altitude_m is not None:
            return self.altitude_m
        return self.marker_radius_m * self.focal_px / self.nadir_marker_radius_px

    @property
    def marker_radius_at_nadir_px(self) -> float:
        """A marker's radius in the nadir camera at the flying height, px."""
        return self.marker_radius_m / self.ground_sample_m

    @property
    def ground_sample_m(self) -> float:
        """Ground distance covered by one nadir pixel at the flying height, m."""
        return self.flight_altitude_m / self.focal_px

    @property
    def grid_spacing_m(self) -> float:
        """Marker grid spacing on the ground, m (``marker_spacing_m`` or its default)."""
        if self.marker_spacing_m is not None:
            return self.marker_spacing_m
        footprint_m = self.width * self.ground_sample_m
        return max(0.3 * footprint_m, 4.0 * PLATE_HALF_SIDE * self.marker_radius_m)


# --------------------------------------------------------------------------- geometry


@dataclass(frozen=True)
class PinholeCamera:
    """A distortion-free pinhole camera mounted on the aircraft.

    Attributes:
        name: Camera name (topic prefix).
        width: Image width, px.
        height: Image height, px.
        fx_px: Focal length along x, px.
        fy_px: Focal length along y, px.
        cx_px: Principal point x, px ((0, 0) = centre of the top-left pixel).
        cy_px: Principal point y, px.
        rotation_body_camera: (3, 3) rotation from the optical frame to the body
            frame (its columns are the optical x, y, z axes in body coordinates).
        position_body_m: (3,) optical centre in the body frame, m.
    """

    name: str
    width: int
    height: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    rotation_body_camera: np.ndarray = field(compare=False)
    position_body_m: np.ndarray = field(compare=False)

    @property
    def intrinsics(self) -> np.ndarray:
        """(3, 3) camera matrix K."""
        return np.array(
            [[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]]
        )


@dataclass(frozen=True)
class AircraftPose:
    """Pose of the body frame in the world at one instant.

    Attributes:
        stamp_ns: Time, ns since the epoch.
        position_m: (3,) body origin in the world (ENU), m.
        rotation_world_body: (3, 3) rotation from body to world coordinates.
        velocity_mps: (3,) velocity in the world, m/s.
    """

    stamp_ns: int
    position_m: np.ndarray = field(compare=False)
    rotation_world_body: np.ndarray = field(compare=False)
    velocity_mps: np.ndarray = field(compare=False)


@dataclass(frozen=True)
class GroundMarker:
    """A marker lying on the ground.

    Attributes:
        marker_id: Index in :attr:`FlightSimulator.markers`.
        x_m: East coordinate of the centre, m.
        y_m: North coordinate of the centre, m.
        yaw_rad: Rotation of the marker's u axis from east, counter-clockwise, rad.
        radius_m: Radius of the X, m.
        kind: ``"quarter_disks"`` or ``"checker"``.
        dark_reflectance: Reflectance of the dark paint.
        bright_reflectance: Reflectance of the plate.
    """

    marker_id: int
    x_m: float
    y_m: float
    yaw_rad: float
    radius_m: float
    kind: str
    dark_reflectance: float
    bright_reflectance: float

    def plane_to_ground(self) -> np.ndarray:
        """(3, 3) map from marker plane units (radius 1) to ground metres."""
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        r = self.radius_m
        return np.array([[r * c, -r * s, self.x_m], [r * s, r * c, self.y_m], [0.0, 0.0, 1.0]])


def camera_rig(config: FlightConfig) -> list[PinholeCamera]:
    """The multi-aperture rig: one nadir camera and up to four oblique ones.

    Args:
        config: Frame size, field of view, tilt and number of cameras.

    Returns:
        ``config.n_cameras`` cameras named after :data:`CAMERA_NAMES`: nadir,
        then tilted by ``tilt_deg`` forward, backward, left and right. Each is
        the nadir camera turned about a body axis, so every image keeps the
        nadir camera's orientation: its top edge towards the aircraft's nose.
    """
    focal = config.focal_px
    cameras = []
    for index in range(config.n_cameras):
        axis = np.array(_TILT_AXES[index])
        tilt = Rotation.from_rotvec(axis * math.radians(config.tilt_deg)).as_matrix()
        rotation = tilt @ _NADIR_BODY_OPTICAL
        # The lever arm points the way the camera leans (horizontal part of its axis).
        lean = rotation[:, 2] * np.array([1.0, 1.0, 0.0])
        norm = float(np.linalg.norm(lean))
        offset = lean / norm * _LEVER_ARM_M if norm > 1e-9 else np.zeros(3)
        cameras.append(
            PinholeCamera(
                name=CAMERA_NAMES[index],
                width=config.width,
                height=config.height,
                fx_px=focal,
                fy_px=focal,
                cx_px=(config.width - 1) / 2.0,
                cy_px=(config.height - 1) / 2.0,
                rotation_body_camera=rotation,
                position_body_m=offset + np.array([0.0, 0.0, -_MOUNT_DEPTH_M]),
            )
        )
    return cameras


def camera_in_world(camera: PinholeCamera, pose: AircraftPose) -> tuple[np.ndarray, np.ndarray]:
    """World pose of a camera.

    Returns:
        (rotation from optical to world coordinates (3, 3), optical centre in the world (3,), m).
    """
    rotation = pose.rotation_world_body @ camera.rotation_body_camera
    centre = pose.position_m + pose.rotation_world_body @ camera.position_body_m
    return rotation, centre


def ground_homography(
    camera: PinholeCamera, pose: AircraftPose, shift_m: np.ndarray | None = None
) -> np.ndarray:
    """Ground plane (x, y in metres, z = 0) -> image homography ``K [r1 r2 t]``.

    Args:
        camera: The camera.
        pose: The aircraft's pose.
        shift_m: (3,) extra displacement of the camera centre in the world, m
            (to image the start or end of an exposure).

    Returns:
        (3, 3) float64, not normalised: its third row gives the depth of a
        ground point along the optical axis, m, positive in front of the camera.
    """
    rotation, centre = camera_in_world(camera, pose)
    if shift_m is not None:
        centre = centre + shift_m
    world_to_camera = rotation.T
    translation = -world_to_camera @ centre
    return camera.intrinsics @ np.column_stack(
        [world_to_camera[:, 0], world_to_camera[:, 1], translation]
    )


def image_to_ground(homography: np.ndarray, points_px: np.ndarray) -> np.ndarray:
    """Intersect the rays of image points with the ground.

    Args:
        homography: (3, 3) ground -> image, as from :func:`ground_homography`.
        points_px: (N, 2) image points, px.

    Returns:
        (N, 2) ground points (x, y), m; NaN where the ray misses the ground
        (points at or above the horizon).
    """
    points = np.column_stack([points_px, np.ones(len(points_px))])
    ground = points @ np.linalg.inv(homography).T
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = ground[:, :2] / ground[:, 2:]
    # The ray hits the ground in front of the camera only where the depth is positive.
    xy[ground[:, 2] <= 0] = np.nan
    return xy


# --------------------------------------------------------------------------- frames


@dataclass(frozen=True)
class CameraFrame:
    """One camera's image of one frame set, with its exact truth.

    Attributes:
        camera: The camera.
        image: (height, width) uint8 frame.
        markers: Truth of every marker whose plate lies wholly inside the
            frame and in front of the camera; the centre is the image of the
            marker's world origin.
        marker_ids: :attr:`GroundMarker.marker_id` of each entry of ``markers``.
        partial: Truth of markers drawn only partly (cut by the frame border):
            not part of the truth, but a detection there is not false either.
        partial_ids: :attr:`GroundMarker.marker_id` of each entry of ``partial``.
        homography: (3, 3) ground (m) -> image (px) at mid-exposure.
        imaging: The optics and sensor this frame was rendered with.
    """

    camera: PinholeCamera
    image: np.ndarray
    markers: list[MarkerTruth]
    marker_ids: list[int]
    partial: list[MarkerTruth]
    partial_ids: list[int]
    homography: np.ndarray = field(compare=False)
    imaging: ImagingConditions = field(default_factory=ImagingConditions)


@dataclass(frozen=True)
class FlightFrame:
    """All cameras at one instant.

    Attributes:
        index: Frame set number, from 0.
        pose: The aircraft at mid-exposure; ``pose.stamp_ns`` is every image's stamp.
        cameras: One entry per camera of the rig, in rig order.
    """

    index: int
    pose: AircraftPose
    cameras: list[CameraFrame]


class _GroundMosaic:
    """Ground texture repeated without seams, with a pyramid, addressed in world metres.

    The texture is its periodic component (:func:`periodic_component`) and repeats
    side by side (``BORDER_WRAP``), every level of the pyramid too. Mirrored
    instead, the ground would be symmetric about every join and point-symmetric
    where two cross (the mosaic's corner lies at the world's origin, under every
    flight): an exact X to a detector that reads grey-level point symmetry, and
    each ground feature near the corner seen four times (measured: docs/accuracy-journal.md,
    "The flight simulator's ground repeated without mirrors").
    """

    def __init__(self, size_px: int, sample_m: float, rng: np.random.Generator) -> None:
        base = periodic_component(texture_background((size_px, size_px), rng))
        np.clip(base, *GROUND_REFLECTANCE_LIMITS, out=base)
        self.levels = [base]
        while min(self.levels[-1].shape) > 64:
            self.levels.append(_wrapped_pyr_down(self.levels[-1]))
        self.sample_m = sample_m

    def warp(self, homography: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """Ground reflectance seen through ``homography`` (ground m -> image px), float32."""
        height, width = shape
        level = self._level_for(homography, width, height)
        texture = self.levels[level]
        scale = 2**level
        sample = self.sample_m * scale
        # Mosaic pixel (col, row) of level L -> ground metres. Level-L pixel centres lie
        # at level-0 coordinate scale * col: pyrDown centres its kernel on every second
        # pixel (an area average's would lie (scale - 1) / 2 further on).
        to_ground = np.diag([sample, sample, 1.0])
        image_to_mosaic = np.linalg.inv(homography @ to_ground)
        # The texture repeats every size pixels: move the frame's centre near the
        # origin so that OpenCV's int16 source coordinates cannot saturate.
        centre = image_to_mosaic @ np.array([(width - 1) / 2, (height - 1) / 2, 1.0])
        period = np.array(texture.shape[::-1], dtype=np.float64)
        shift = np.floor(centre[:2] / centre[2] / period) * period
        image_to_mosaic = np.array([[1, 0, -shift[0]], [0, 1, -shift[1]], [0, 0, 1]]) @ (
            image_to_mosaic
        )
        return cv2.warpPerspective(
            texture,
            image_to_mosaic,
            (width, height),
            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_WRAP,
        )

    def _level_for(self, homography: np.ndarray, width: int, height: int) -> int:
        """Pyramid level whose sampling is closest to the camera's at the frame centre.

        Finer than the camera aliases the texture into noise, coarser blurs it;
        the oblique cameras' far field (up to ~3x coarser than their centre)
        keeps a mild aliasing, which only adds clutter.
        """
        cx, cy = (width - 1) / 2, (height - 1) / 2
        ground = image_to_ground(homography, np.array([[cx, cy], [cx + 1, cy], [cx, cy + 1]]))
        if np.isnan(ground).any():
            return 0
        (ax, ay), (bx, by) = ground[1] - ground[0], ground[2] - ground[0]
        area = abs(float(ax * by - ay * bx))  # ground area of one pixel, m^2
        ratio = math.sqrt(area) / self.sample_m
        return int(np.clip(round(math.log2(max(ratio, 1e-9))), 0, len(self.levels) - 1))


def _wrapped_pyr_down(texture: np.ndarray) -> np.ndarray:
    """``cv2.pyrDown`` of a texture that repeats side by side, read across its joins."""
    reach = _PYR_DOWN_REACH_PX
    padded = cv2.copyMakeBorder(texture, reach, reach, reach, reach, cv2.BORDER_WRAP)
    half = reach // 2
    return cv2.pyrDown(padded)[half:-half, half:-half]


class FlightSimulator:
    """Render a straight flight over a marked ground with exact truth, frame by frame.

    The world (markers, ground texture, light) is drawn once from ``seed``;
    each frame set and camera then has its own random stream (noise, per-frame
    light), so frames can be rendered in any order and give the same pixels.

    Args:
        config: What to fly and how to image it.
        seed: Seed of everything random.

    Example:
        >>> sim = FlightSimulator(FlightConfig(width=320, height=240, n_frames=1), seed=1)
        >>> frame = sim.render(0)
        >>> [c.camera.name for c in frame.cameras]
        ['cam0', 'cam1', 'cam2', 'cam3', 'cam4']
    """

    def __init__(self, config: FlightConfig, seed: int = 0) -> None:
        self.config = config
        self.seed = seed
        self.rig = camera_rig(config)
        world_rng = np.random.default_rng((seed, 0))
        self.poses = [self._pose(k, world_rng) for k in range(config.n_frames)]
        low, high = self._ground_extent()
        self.markers = self._lay_markers(low, high, world_rng)
        self._marker_maps = np.stack([m.plane_to_ground() for m in self.markers]).reshape(-1, 3, 3)
        side = int(np.clip(max(config.width, config.height), _MOSAIC_MIN_PX, _MOSAIC_MAX_PX))
        mosaic_px = -(-side // _MOSAIC_MULTIPLE_PX) * _MOSAIC_MULTIPLE_PX
        self._mosaic = _GroundMosaic(mosaic_px, config.ground_sample_m, world_rng)
        self._light, self._light_to_ground = self._light_field(low, high, world_rng)
        self._frame_gains = world_rng.uniform(*config.frame_gain_range, size=config.n_frames)
        # Every camera's colour filter, the same for every frame: built once.
        self._sensor_gain = (
            None
            if config.bayer_pattern is None
            else bayer_gain((config.height, config.width), config.bayer_pattern)
        )

    def __len__(self) -> int:
        return self.config.n_frames

    def __iter__(self) -> Iterator[FlightFrame]:
        for index in range(self.config.n_frames):
            yield self.render(index)

    def render(self, index: int) -> FlightFrame:
        """Render frame set ``index`` (0-based) for every camera of the rig."""
        if not 0 <= index < self.config.n_frames:
            raise ConfigError(f"frame index {index} outside [0, {self.config.n_frames})")
        pose = self.poses[index]
        cameras = [
            self._render_camera(index, camera_index, camera, pose)
            for camera_index, camera in enumerate(self.rig)
        ]
        return FlightFrame(index, pose, cameras)

    # ------------------------------------------------------------------ world set-up

    def _pose(self, index: int, rng: np.random.Generator) -> AircraftPose:
        cfg = self.config
        t_s = index / cfg.frame_rate_hz
        course = math.radians(cfg.course_deg)
        velocity = cfg.speed_mps * np.array([math.cos(course), math.sin(course), 0.0])
        position = velocity * t_s + np.array([0.0, 0.0, cfg.flight_altitude_m])
        yaw, pitch, roll = rng.normal(0.0, math.radians(cfg.attitude_jitter_deg), 3)
        rotation = Rotation.from_euler("ZYX", [course + yaw, pitch, roll]).as_matrix()
        stamp_ns = cfg.start_time_ns + round(t_s * _NS_PER_S)
        return AircraftPose(stamp_ns, position, rotation, velocity)

    def _ground_extent(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounding box (low, high) of the ground seen by any camera in any frame, m."""
        cfg = self.config
        # The border of each frame, 8 points per side: the footprint is convex.
        t = np.linspace(0.0, 1.0, 8)[:, None]
        xs, ys = t * cfg.width - 0.5, t * cfg.height - 0.5
        left, top = np.full_like(t, -0.5), np.full_like(t, -0.5)
        right, bottom = np.full_like(t, cfg.width - 0.5), np.full_like(t, cfg.height - 0.5)
        border = np.vstack(
            [
                np.hstack([xs, top]),
                np.hstack([xs, bottom]),
                np.hstack([left, ys]),
                np.hstack([right, ys]),
            ]
        )
        seen = [
            image_to_ground(ground_homography(camera, pose), border)
            for pose in self.poses
            for camera in self.rig
        ]
        points = np.vstack(seen)
        points = points[~np.isnan(points).any(axis=1)]
        margin = cfg.grid_spacing_m + PLATE_HALF_SIDE * cfg.marker_radius_m
        return points.min(axis=0) - margin, points.max(axis=0) + margin

    def _lay_markers(
        self, low: np.ndarray, high: np.ndarray, rng: np.random.Generator
    ) -> list[GroundMarker]:
        cfg = self.config
        spacing = cfg.grid_spacing_m
        xs = np.arange(low[0], high[0] + spacing, spacing)
        ys = np.arange(low[1], high[1] + spacing, spacing)
        grid = np.stack(np.meshgrid(xs, ys, indexing="xy"), axis=-1).reshape(-1, 2)
        # A quarter spacing of jitter keeps neighbouring plates apart (the spacing
        # exceeds two plate widths) while breaking the grid's regularity.
        grid += rng.uniform(-0.25 * spacing, 0.25 * spacing, size=grid.shape)
        markers = []
        for index, (x, y) in enumerate(grid):
            dark = float(rng.uniform(*DARK_REFLECTANCE_RANGE))
            bright = float(rng.uniform(*BRIGHT_REFLECTANCE_RANGE))
            if rng.random() < 0.5:  # half are painted the other way round
                dark, bright = bright, dark
            markers.append(
                GroundMarker(
                    marker_id=index,
                    x_m=float(x),
                    y_m=float(y),
                    yaw_rad=float(rng.uniform(0.0, 2.0 * math.pi)),
                    radius_m=cfg.marker_radius_m,
                    kind=str(cfg.marker_kinds[int(rng.integers(len(cfg.marker_kinds)))]),
                    dark_reflectance=dark,
                    bright_reflectance=bright,
                )
            )
        return markers

    def _light_field(
        self, low: np.ndarray, high: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """World-fixed light gain (clouds, shadows) and its grid -> ground map."""
        cfg = self.config
        shape = (_LIGHT_FIELD_PX, _LIGHT_FIELD_PX)
        gain = illumination_field(shape, cfg.illumination_strength, rng)
        if cfg.n_shadows:
            gain *= shadow_field(shape, cfg.n_shadows, rng)
        sample = float(max(high - low)) / (_LIGHT_FIELD_PX - 1)
        to_ground = np.array([[sample, 0.0, low[0]], [0.0, sample, low[1]], [0.0, 0.0, 1.0]])
        return gain, to_ground

    # ------------------------------------------------------------------ rendering

    def _render_camera(
        self, index: int, camera_index: int, camera: PinholeCamera, pose: AircraftPose
    ) -> CameraFrame:
        cfg = self.config
        rng = np.random.default_rng((self.seed, 1, index, camera_index))
        shape = (cfg.height, cfg.width)
        homography = ground_homography(camera, pose)
        radiance = self._mosaic.warp(homography, shape)
        full, partial = self._visible_markers(homography)
        truths: list[MarkerTruth] = []
        cut: list[MarkerTruth] = []
        full_set = set(full)
        for marker_id in (*full, *partial):
            marker = self.markers[marker_id]
            marker_homography = homography @ self._marker_maps[marker_id]
            composite_target(
                radiance,
                PlanarTarget(
                    marker_homography,
                    PATTERNS[marker.kind],
                    marker.dark_reflectance,
                    marker.bright_reflectance,
                ),
                cfg.supersampling,
            )
            # Nominal radius: the marker's size at its depth, before foreshortening.
            radius_px = marker.radius_m * camera.fx_px / float(marker_homography[2, 2])
            truth = MarkerTruth.from_homography(marker_homography, radius_px, marker.kind)
            (truths if marker_id in full_set else cut).append(truth)
        light = cv2.warpPerspective(
            self._light,
            np.linalg.inv(homography @ self._light_to_ground),
            (cfg.width, cfg.height),
            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_REPLICATE,
        )
        radiance *= light
        radiance *= np.float32(self._frame_gains[index])
        imaging = self._imaging(camera, pose, homography)
        image = apply_imaging(radiance, imaging, rng, self._sensor_gain)
        return CameraFrame(
            camera, image, truths, list(full), cut, list(partial), homography, imaging
        )

    def _visible_markers(self, homography: np.ndarray) -> tuple[list[int], list[int]]:
        """Markers wholly inside the frame, and markers that touch it only partly."""
        cfg = self.config
        half = PLATE_HALF_SIDE
        corners = np.array(
            [[-half, -half, 1.0], [half, -half, 1.0], [half, half, 1.0], [-half, half, 1.0]]
        )
        # (markers, 4 corners, 3): plate corners in homogeneous image coordinates.
        projected = np.einsum("ij,mjk,ck->mci", homography, self._marker_maps, corners)
        depth = projected[..., 2]
        in_front = np.all(depth > 0, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = projected[..., :2] / depth[..., None]
        low, high = -0.5, np.array([cfg.width - 0.5, cfg.height - 0.5])
        inside = np.all((xy >= low) & (xy <= high), axis=(1, 2))
        touches = _quad_meets_rectangle(xy, np.array([low, low]), high)
        full = np.flatnonzero(in_front & inside)
        partial = np.flatnonzero(in_front & touches & ~inside)
        return full.tolist(), partial.tolist()

    def _imaging(
        self, camera: PinholeCamera, pose: AircraftPose, homography: np.ndarray
    ) -> ImagingConditions:
        """Optics and sensor, with the motion blur of the exposure at the frame centre."""
        cfg = self.config
        length_px, angle_rad = 0.0, 0.0
        travel = pose.velocity_mps * cfg.exposure_s
        centre = np.array([[camera.cx_px, camera.cy_px]])
        ground = image_to_ground(homography, centre)
        if cfg.exposure_s > 0 and not np.isnan(ground).any():
            # Where the ground point under the principal point appears at the start
            # and at the end of the exposure; the blur kernel is uniform over the
            # frame (for oblique cameras its length varies by ~2x across the frame).
            point = np.append(ground[0], 1.0)
            start = ground_homography(camera, pose, -0.5 * travel) @ point
            end = ground_homography(camera, pose, 0.5 * travel) @ point
            shift = end[:2] / end[2] - start[:2] / start[2]
            length_px = float(np.hypot(*shift))
            angle_rad = float(math.atan2(shift[1], shift[0]))
        return ImagingConditions(
            blur_sigma_px=cfg.blur_sigma_px,
            motion_blur_px=length_px,
            motion_blur_angle_rad=angle_rad,
            vignetting=cfg.vignetting,
            noise_sigma_dn=cfg.noise_sigma_dn,
            shot_noise_gain_dn=cfg.shot_noise_gain_dn,
        )


def _quad_meets_rectangle(quads: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """(M,) whether each convex quadrilateral (M, 4, 2) overlaps the rectangle [low, high].

    Separating axes: the rectangle's two (its box against the quad's) and the quad's
    four edge normals. The boxes alone took a tilted plate whose box, not the plate,
    reached into the frame.
    """
    boxes_meet = np.all(quads.max(axis=1) >= low, axis=1) & np.all(
        quads.min(axis=1) <= high, axis=1
    )
    corners = np.array([[low[0], low[1]], [high[0], low[1]], [high[0], high[1]], [low[0], high[1]]])
    edges = np.roll(quads, -1, axis=1) - quads
    normals = np.stack([edges[..., 1], -edges[..., 0]], axis=-1)
    # Which side of each edge the quad lies on, from its centre.
    inward = np.sign(np.einsum("mkd,mkd->mk", normals, quads.mean(axis=1)[:, None] - quads))
    # (M, 4 edges, 4 rectangle corners): each corner's side of each edge.
    sides = np.einsum("mkd,mkcd->mkc", normals, corners[None, None] - quads[:, :, None])
    separated = np.any(np.all(sides * inward[..., None] < 0, axis=2), axis=1)
    return boxes_meet & ~separated
