"""Sub-pixel localisation of diagonal (X) ground markers.

The detector core (:mod:`marker_localizer.core`) needs only numpy, OpenCV and
scipy; the ROS adapter (:mod:`marker_localizer.ros`) and the bag tools
(:mod:`marker_localizer.bag`) sit on top of it.

Coordinates everywhere: float64 pixels, x right, y down, (0, 0) at the centre
of the top-left pixel (OpenCV's convention).
"""

from marker_localizer.config import DetectorConfig
from marker_localizer.core.pipeline import Detector
from marker_localizer.core.result import Detection, DetectionResult

__all__ = ["Detection", "DetectionResult", "Detector", "DetectorConfig"]
