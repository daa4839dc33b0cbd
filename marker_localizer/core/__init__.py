"""Detector core: numpy, OpenCV and scipy only (no ROS), one module per stage of the paper.

Modules in pipeline order: :mod:`image` (input), :mod:`preprocessing` (section 3.1),
:mod:`screening` and :mod:`verification` (3.2), :mod:`template` and :mod:`subpixel`
(3.3); :mod:`pipeline` chains them into :class:`~marker_localizer.core.pipeline.Detector`.
"""
