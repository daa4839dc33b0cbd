"""Detector core: numpy, OpenCV and scipy only (no ROS), one module per stage of the paper.

Modules in pipeline order: :mod:`image` (input), :mod:`preprocessing` (section 3.1),
:mod:`screening` and :mod:`search` (3.2's candidates), :mod:`verification` (3.2's
checks), :mod:`template` and :mod:`subpixel` (3.3). The paths a config names chain
them after the screening: :mod:`symmetry_path` (the default), :mod:`paper_path`
(the paper's checks) and :mod:`template_path` (the calibrated decision);
:mod:`pipeline` chains the input, the preprocessing, the screening and the path
into :class:`~marker_localizer.core.pipeline.Detector`, whose passes give back
:mod:`result`'s types.
"""
