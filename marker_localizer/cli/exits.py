"""Exit statuses of ``marker-localizer``, set in one place: :func:`run_command`.

Every command runs through :func:`run_command`, which turns what can end a
command into its status:

* 0: done; a command that skipped part of its input returns :data:`EXIT_INCOMPLETE`;
* 1 (:data:`EXIT_ERROR`): a :class:`~marker_localizer.errors.MarkerLocalizerError`
  (a bad value, a missing or damaged file, an output that cannot be written: a
  full disk under ``detect --json > results.jsonl``), one line on stderr; only a
  bug shows a traceback;
* 2: a command line argparse refuses (argparse's own status);
* 128 + the signal's number (130, 143): SIGINT or SIGTERM, from the moment the
  command is chosen (its imports included). Both interrupt the command alike: it
  unwinds (an unfinished output bag is removed) and one line names the signal; a
  second signal during the unwinding cuts it short where it waits (the frames in
  flight of a worker pool are abandoned), still one line; a third ends the
  process at once (:mod:`marker_localizer.stopping`);
* 141 (:data:`EXIT_CLOSED_PIPE`, 128 + SIGPIPE): the reader of its output went
  away (``marker-localizer detect *.png --json | head -1``). It stops, silently,
  as a tool that SIGPIPE ends does: Python ignores SIGPIPE, and the next write
  would raise.
"""

from __future__ import annotations

import os
import select
import signal
import sys
from collections.abc import Callable
from typing import Any, TextIO

from marker_localizer.errors import MarkerLocalizerError, OutputError
from marker_localizer.stopping import run_interruptible

#: The console script's name, the first word of every message.
PROG = "marker-localizer"
#: A package error: one line on stderr, nothing (or nothing complete) written.
EXIT_ERROR = 1
#: A command that finished but skipped, failed on or could not read part of its
#: input, its summary saying what.
EXIT_INCOMPLETE = 3
#: The status of a command whose output's reader went away: what a shell reports
#: for a process SIGPIPE ended.
EXIT_CLOSED_PIPE = 128 + signal.SIGPIPE


def _output_reader_gone() -> bool:
    """Whether stdout is a pipe whose reading end is closed (poll reports an error on it)."""
    poller = select.poll()
    poller.register(sys.stdout.fileno(), select.POLLERR)
    return bool(poller.poll(0))


class _CheckedOutput:
    """stdout whose failed writes raise :class:`OutputError`, not the OSError of a traceback.

    A closed pipe stays a :class:`BrokenPipeError`: it ends a command silently.
    """

    def __init__(self, stream: TextIO) -> None:
        self._stream = stream

    def write(self, text: str) -> int:
        return self._checked(self._stream.write, text)

    def flush(self) -> None:
        self._checked(self._stream.flush)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)

    @staticmethod
    def _checked(call: Callable[..., Any], *args: Any) -> Any:
        try:
            return call(*args)
        except BrokenPipeError:
            raise
        except OSError as err:
            raise OutputError(f"cannot write the output ({err.strerror})") from err


def _discard_stdout() -> None:
    """Point stdout at /dev/null, what is still buffered being unwritable too.

    Otherwise the interpreter's flush at exit raises again.
    """
    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


def run_command(label: str, body: Callable[[], int]) -> int:
    """Run a command's body and return its exit status (see the module docstring).

    Args:
        label: What starts its messages: ``"marker-localizer replay"``.
        body: The command; returns its exit status.

    Returns:
        ``body``'s status, :data:`EXIT_ERROR` after a :class:`MarkerLocalizerError`,
        130 after SIGINT (Ctrl-C), 143 after SIGTERM, :data:`EXIT_CLOSED_PIPE` after
        the output's reader went away.
    """
    stdout = sys.stdout
    sys.stdout = _CheckedOutput(stdout)
    try:
        status = run_interruptible(label, body)
        sys.stdout.flush()  # what is buffered fails here, where a line can say so
        return status
    except BrokenPipeError:
        if not _output_reader_gone():
            raise  # another pipe: a worker's, say
        _discard_stdout()
        return EXIT_CLOSED_PIPE
    except MarkerLocalizerError as err:
        if isinstance(err, OutputError):
            _discard_stdout()
        sys.stderr.write(f"{label}: error: {err}\n")
        return EXIT_ERROR
    finally:
        sys.stdout = stdout
