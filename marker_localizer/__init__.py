"""Sub-pixel localisation of diagonal (X) ground markers.

The detector core (:mod:`marker_localizer.core`) needs only numpy, OpenCV and
scipy; the ROS adapter (:mod:`marker_localizer.ros`) and the bag tools
(:mod:`marker_localizer.bag`) sit on top of it.

Coordinates everywhere: float64 pixels, x right, y down, (0, 0) at the centre
of the top-left pixel (OpenCV's convention).

The names below are imported when first used: the console scripts, which import
this package before any of their own code runs, install their Ctrl-C handling
before the detector's imports (numpy, scipy, OpenCV: about a second).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from marker_localizer.config import DetectorConfig
    from marker_localizer.core.pipeline import Detector
    from marker_localizer.core.result import Detection, DetectionResult

#: Each public name and the module that defines it.
_EXPORTS = {
    "Detection": "marker_localizer.core.result",
    "DetectionResult": "marker_localizer.core.result",
    "Detector": "marker_localizer.core.pipeline",
    "DetectorConfig": "marker_localizer.config",
}

__all__ = ["Detection", "DetectionResult", "Detector", "DetectorConfig"]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
