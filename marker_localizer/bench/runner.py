"""What every benchmark's command line does around its run: report, time, save."""

from __future__ import annotations

import argparse
import json
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from marker_localizer.errors import ConfigError, OutputError

Report = Callable[[str], None]


def add_json_option(parser: argparse.ArgumentParser) -> None:
    """``--json PATH``, every benchmark's way to save its figures (:func:`run_and_save`)."""
    parser.add_argument(
        "--json",
        type=Path,
        default=None,
        help="also save the figures here, as JSON (default: none saved)",
    )


def print_report(text: str) -> None:
    """Print one table of a benchmark as soon as it is done, a blank line before it."""
    print(f"\n{text}", flush=True)


def _save_whole(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` whole or not at all.

    Through a file beside it, renamed onto it: written in place, a full disk left
    an earlier run's figures cut short. A path that is no regular file
    (``/dev/stdout``, a pipe) is written as it is.

    Raises:
        OutputError: it cannot be written (a full disk, a file size limit).
    """
    partial = path if path.exists() and not path.is_file() else path.with_name(f".{path.name}~")
    try:
        partial.write_text(text)
        if partial != path:
            os.replace(partial, path)
    except OSError as err:
        if partial != path:
            partial.unlink(missing_ok=True)
        raise OutputError(f"--json {path}: cannot write it ({err.strerror})") from err


def _check_writable(json_path: Path) -> bool:
    """Check before the run that ``json_path`` can be written; whether this created it.

    A file that is there is opened for appending and left as it was; one that is
    not is created, empty, for the caller to remove if the run fails.

    Raises:
        ConfigError: it cannot be written.
    """
    try:
        try:
            json_path.open("x").close()
        except FileExistsError:
            json_path.open("a").close()
            return False
    except OSError as err:
        raise ConfigError(f"--json {json_path}: cannot write it ({err.strerror})") from err
    return True


def run_and_save(name: str, run: Callable[[Report], dict[str, Any]], json_path: Path | None) -> int:
    """Run a benchmark, print its tables and its duration, save its figures as JSON.

    Args:
        name: what finished, as the last line says it.
        run: the benchmark, given the report function; returns its figures.
        json_path: where to save the figures (with ``elapsed_s``), or None. A run
            that fails leaves it as it was before: not there, or as it read.

    Returns:
        The exit status, 0.

    Raises:
        ConfigError: ``json_path`` cannot be written, found before the run, not after it.
    """
    created = json_path if json_path is not None and _check_writable(json_path) else None
    try:
        start = time.perf_counter()
        results = run(print_report)
        elapsed = time.perf_counter() - start
        print(f"\n{name} finished in {elapsed:.0f} s", flush=True)
        if json_path is not None:
            results["elapsed_s"] = elapsed
            _save_whole(json_path, json.dumps(results, indent=2))
    except BaseException:
        # An empty file left by a failed run would read as a run that saved nothing.
        if created is not None:
            created.unlink(missing_ok=True)
        raise
    return 0
