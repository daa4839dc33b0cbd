"""``../shared/data`` beside this checkout, for the tests that read real frames.

Found from the tests' own place: the package under test may be installed elsewhere
(the pinned virtual environments' ``pip install .``), and ``real_data.data_root()``'s
default would then look beside site-packages.
"""

from pathlib import Path

import pytest

from marker_localizer.bench import real_data

SHARED_DATA = real_data.data_root(Path(__file__).resolve().parents[1])
needs_shared_data = pytest.mark.skipif(SHARED_DATA is None, reason="../shared/data is absent")
