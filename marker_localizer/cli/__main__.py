"""``python -m marker_localizer.cli``: the console script without its wrapper."""

import sys

from marker_localizer.cli import main

sys.exit(main())
