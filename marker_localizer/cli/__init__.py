"""Command line: ``marker-localizer detect|demo|simulate|replay|play|bench``.

Every command's arguments are parsed in this package and its output formatted
here; the work is the library's. Each command is a ``function(argv) -> exit
status`` registered in :data:`COMMANDS` (benchmarks in :data:`BENCHMARKS`) and
imported only when run, so ``detect`` starts without ROS. Every command runs
through :func:`~marker_localizer.cli.exits.run_command`, the one place where
errors and signals become exit statuses.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from typing import NamedTuple

from marker_localizer.cli.exits import PROG, run_command
from marker_localizer.errors import import_needing_ros


class Command(NamedTuple):
    """A command: where its function is, its help, and how its messages begin.

    Attributes:
        module: module that holds the function (imported only when run).
        function: ``function(argv) -> exit status``.
        help: one line for ``marker-localizer --help``.
        named: whether its messages name it (``marker-localizer replay: error: ...``)
            or begin with the program's name alone, as ``detect``'s always did.
    """

    module: str
    function: str
    help: str
    named: bool = True


#: The commands, in the order ``--help`` lists them.
COMMANDS: dict[str, Command] = {
    "detect": Command(
        "marker_localizer.cli.detect", "main", "detect markers in image files", named=False
    ),
    "demo": Command(
        "marker_localizer.cli.demo",
        "main",
        "render frames, detect, print accuracy, write overlays",
        named=False,
    ),
    "simulate": Command(
        "marker_localizer.cli.bag",
        "simulate",
        "render a five-camera flight and record it as a rosbag2",
    ),
    "replay": Command(
        "marker_localizer.cli.bag",
        "replay",
        "run a recorded bag through the node's processing, write the results to a bag",
    ),
    "play": Command(
        "marker_localizer.cli.bag",
        "play",
        "publish a bag's messages on their ROS topics (like 'ros2 bag play')",
    ),
}
#: The benchmarks of ``bench WHICH``: name -> module whose ``main(argv)`` runs it.
BENCHMARKS: dict[str, str] = {
    "accuracy": "marker_localizer.bench.accuracy",
    "bound": "marker_localizer.bench.bound",
    "calibrate": "marker_localizer.bench.calibrate",
    "exposure": "marker_localizer.bench.exposure",
    "paper": "marker_localizer.bench.paper",
    "speed": "marker_localizer.bench.speed",
    "throughput": "marker_localizer.bench.throughput",
}


def _load(module: str, function: str) -> Callable[[list[str]], int]:
    """The command's function (:func:`~marker_localizer.errors.import_needing_ros`)."""
    return getattr(import_needing_ros(module), function)


def build_parser() -> argparse.ArgumentParser:
    """The parser of ``marker-localizer`` itself: it lists the commands (each parses its own)."""
    parser = argparse.ArgumentParser(
        allow_abbrev=False,
        prog=PROG,
        description="Sub-pixel localisation of diagonal (X) ground markers.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, command in COMMANDS.items():
        sub.add_parser(name, help=command.help, add_help=False)
    bench = sub.add_parser(
        "bench",
        help="benchmarks: " + ", ".join(BENCHMARKS),
        description="Benchmarks; each takes its own options: bench WHICH --help.",
    )
    bench.add_argument("which", choices=sorted(BENCHMARKS))
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``marker-localizer`` console script; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in COMMANDS:
        command = COMMANDS[argv[0]]
        label = f"{PROG} {argv[0]}" if command.named else PROG
        return run_command(label, lambda: int(_load(command.module, command.function)(argv[1:])))
    if argv[:1] == ["bench"] and len(argv) > 1 and argv[1] in BENCHMARKS:
        label = f"{PROG} bench {argv[1]}"
        return run_command(label, lambda: int(_load(BENCHMARKS[argv[1]], "main")(argv[2:])))
    build_parser().parse_args(argv)  # --help, or argparse's message and status 2
    return 2
