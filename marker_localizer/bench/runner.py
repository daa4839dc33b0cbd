"""What every benchmark's command line does around its run: report, time, save."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from marker_localizer.errors import ConfigError

Report = Callable[[str], None]


def print_report(text: str) -> None:
    """Print one table of a benchmark as soon as it is done, a blank line before it."""
    print(f"\n{text}", flush=True)


def run_and_save(name: str, run: Callable[[Report], dict[str, Any]], json_path: Path | None) -> int:
    """Run a benchmark, print its tables and its duration, save its figures as JSON.

    Args:
        name: what finished, as the last line says it.
        run: the benchmark, given the report function; returns its figures.
        json_path: where to save the figures (with ``elapsed_s``), or None.

    Returns:
        The exit status, 0.

    Raises:
        ConfigError: ``json_path`` cannot be written, found before the run, not after it.
    """
    if json_path is not None:
        try:
            json_path.touch()
        except OSError as err:
            raise ConfigError(f"--json {json_path}: cannot write it ({err.strerror})") from err
    start = time.perf_counter()
    results = run(print_report)
    elapsed = time.perf_counter() - start
    print(f"\n{name} finished in {elapsed:.0f} s", flush=True)
    if json_path is not None:
        results["elapsed_s"] = elapsed
        json_path.write_text(json.dumps(results, indent=2))
    return 0
