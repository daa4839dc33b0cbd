"""argparse types of the commands' and benchmarks' numbers and keys, checked where read.

A count of 0, a negative seed, a run of no seconds or an unknown key is then one usage
line (exit 2) naming the option, not a traceback from deep inside a run or a table of
no figures.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Sequence


def int_at_least(low: int) -> Callable[[str], int]:
    """An argparse ``type``: an integer of at least ``low``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"must be at least {low}, got {value}")
        return value

    return parse


def positive_float(text: str) -> float:
    """An argparse ``type``: a finite number above 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number above 0, got {text}")
    return value


def comma_keys(choices: Sequence[str], what: str) -> Callable[[str], tuple[str, ...]]:
    """An argparse ``type``: comma-separated keys of ``choices``, refused by ``what`` they are.

    An empty list is refused too: a benchmark would otherwise run none, or all.
    """

    def parse(text: str) -> tuple[str, ...]:
        keys = tuple(key.strip() for key in text.split(",") if key.strip())
        if not keys:
            raise argparse.ArgumentTypeError(f"give at least one of: {','.join(choices)}")
        unknown = sorted(set(keys) - set(choices))
        if unknown:
            raise argparse.ArgumentTypeError(
                f"unknown {what} {unknown}; choose from {','.join(choices)}"
            )
        return keys

    return parse


#: How many of something a run makes or repeats (frames, repeats, workers, pixels).
count_type = int_at_least(1)
#: A random generator's seed: numpy's generators take none below 0.
seed_type = int_at_least(0)
