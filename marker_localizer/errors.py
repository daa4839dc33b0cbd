"""Exception tree of marker_localizer.

Every error a user can cause derives from :class:`MarkerLocalizerError`; the
CLI turns these into one line and exit status 1, so only a bug shows a
traceback.
"""


class MarkerLocalizerError(Exception):
    """Base class of every error this package raises on purpose."""


class ConfigError(MarkerLocalizerError, ValueError):
    """A configuration value is unknown, of the wrong type or out of range."""


class ImageError(MarkerLocalizerError, ValueError):
    """An image cannot be read or has a layout the detector cannot use."""


class BagError(MarkerLocalizerError):
    """A bag cannot be read, has no usable topics, or cannot be written."""
