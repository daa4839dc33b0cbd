"""A one-line progress bar for the long commands (simulate, replay, play)."""

from __future__ import annotations

import math
import sys
import time
from types import TracebackType
from typing import IO


class ProgressBar:
    """A one-line progress bar on a terminal, silent when the stream is not a TTY.

    A context manager: leaving it ends the bar's line, however the work ended, so
    that an error's message starts a line of its own.

    Args:
        total: Number of steps (0: unknown, only the count is shown).
        label: Text before the bar.
        stream: Where to draw (default: ``sys.stderr``).
        min_interval_s: Least time between two redraws, s.
    """

    _WIDTH = 30

    def __init__(
        self,
        total: int,
        label: str,
        stream: IO[str] | None = None,
        min_interval_s: float = 0.1,
    ) -> None:
        self.total = total
        self.label = label
        self._stream = stream if stream is not None else sys.stderr
        self._enabled = bool(getattr(self._stream, "isatty", lambda: False)())
        self._min_interval_s = min_interval_s
        self._start = time.monotonic()
        self._last_draw = -math.inf  # the first update always draws

    def update(self, done: int, total: int | None = None) -> None:
        """Show ``done`` steps completed (of ``total``, once known)."""
        if total is not None:
            self.total = total
        now = time.monotonic()
        too_soon = now - self._last_draw < self._min_interval_s and done < self.total
        if not self._enabled or too_soon:
            return
        self._last_draw = now
        elapsed = now - self._start
        rate = done / elapsed if elapsed > 0 else 0.0
        if self.total > 0:
            filled = round(self._WIDTH * min(done / self.total, 1.0))
            bar = "#" * filled + "." * (self._WIDTH - filled)
            text = f"{self.label} [{bar}] {done}/{self.total} {rate:.1f}/s"
        else:
            text = f"{self.label} {done} {rate:.1f}/s"
        self._stream.write(f"\r{text}\x1b[K")
        self._stream.flush()

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        """End the bar's line."""
        if self._enabled:
            self._stream.write("\n")
            self._stream.flush()
